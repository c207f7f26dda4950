//! The one error type of `warpbench-io`: every error names the file and the problem.

use std::fmt;
use std::path::{Path, PathBuf};

/// What went wrong, without the file (see [`Error`]).
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ErrorKind {
    /// The OS error is in the message and is not also the error's source, so a chain printed cause by cause
    /// (anyhow's `{:#}`, the window's messages) names it once.
    #[error("cannot read or write: {0}")]
    Io(std::io::Error),
    #[error("file is truncated: {0}")]
    Truncated(String),
    #[error("not a {format} file: {detail}")]
    BadMagic { format: &'static str, detail: String },
    #[error("unsupported: {0}")]
    Unsupported(String),
    #[error("invalid: {0}")]
    Invalid(String),
    #[error("volume too large: {what} needs {bytes} bytes, more than the limit of {limit} bytes")]
    TooLarge { what: String, bytes: u128, limit: u64 },
    /// The allocation was tried (fallibly) and the system refused it.
    #[error("not enough memory for {what}: {bytes} bytes ({}) could not be allocated", gib(*.bytes))]
    OutOfMemory { what: String, bytes: u128 },
    /// A named pipe, a device or a socket: reading it could block or never end, so it is refused before it is
    /// opened. `what` says which kind of file it is.
    #[error("{what}, not a regular file: volumes are read from regular files and DICOM series from folders")]
    NotARegularFile { what: &'static str },
    /// A 4-D file holds several frames and none was chosen. Front ends word the choice their own way
    /// (the CLI's `--frame`, the window's frame field).
    #[error("4-D file with {frames} frames: choose one frame to read (0 to {})", .frames.saturating_sub(1))]
    FrameRequired { frames: usize },
    #[error("the folder holds {} DICOM series; choose one with its SeriesInstanceUID:\n{}", .0.len(), list_series(.0))]
    MultipleSeries(Vec<crate::series::SeriesSummary>),
    #[error("DICOM: {0}")]
    Dicom(String),
    #[error("landmark {index}: {problem}")]
    Landmark { index: usize, problem: String },
    #[error("cancelled")]
    Cancelled,
}

/// `bytes` in GiB with one decimal, for messages.
fn gib(bytes: u128) -> String {
    format!("{:.1} GiB", bytes as f64 / f64::from(1u32 << 30))
}

fn list_series(s: &[crate::series::SeriesSummary]) -> String {
    s.iter().map(|x| format!("  {x}")).collect::<Vec<_>>().join("\n")
}

/// An error in reading or writing one file (or folder).
#[derive(Debug)]
pub struct Error {
    pub path: PathBuf,
    pub kind: ErrorKind,
}

impl fmt::Display for Error {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}: {}", self.path.display(), self.kind)
    }
}

impl std::error::Error for Error {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        self.kind.source()
    }
}

impl Error {
    pub fn new(path: impl AsRef<Path>, kind: ErrorKind) -> Self {
        Self { path: path.as_ref().to_path_buf(), kind }
    }
    pub fn io(path: impl AsRef<Path>, e: std::io::Error) -> Self {
        // A short read is a truncated file, whatever reader hit it.
        if e.kind() == std::io::ErrorKind::UnexpectedEof {
            return Self::new(path, ErrorKind::Truncated(e.to_string()));
        }
        Self::new(path, ErrorKind::Io(e))
    }
    pub fn invalid(path: impl AsRef<Path>, msg: impl Into<String>) -> Self {
        Self::new(path, ErrorKind::Invalid(msg.into()))
    }
    pub fn unsupported(path: impl AsRef<Path>, msg: impl Into<String>) -> Self {
        Self::new(path, ErrorKind::Unsupported(msg.into()))
    }
    pub fn truncated(path: impl AsRef<Path>, msg: impl Into<String>) -> Self {
        Self::new(path, ErrorKind::Truncated(msg.into()))
    }
}

pub type Result<T, E = Error> = std::result::Result<T, E>;

#[cfg(test)]
mod tests {
    use super::*;

    /// What a front end prints of an error and its causes, as anyhow's `{:#}` does: each cause after a colon.
    fn chain(e: &dyn std::error::Error) -> String {
        let mut text = e.to_string();
        let mut cause = e.source();
        while let Some(c) = cause {
            text.push_str(": ");
            text.push_str(&c.to_string());
            cause = c.source();
        }
        text
    }

    #[test]
    fn an_os_error_is_named_once_however_the_chain_is_printed() {
        let e = Error::io("/data/out.nii", std::io::Error::from_raw_os_error(13));
        let text = chain(&e);
        assert_eq!(text.matches("os error 13").count(), 1, "{text}");
        assert!(text.starts_with("/data/out.nii: cannot read or write:"), "{text}");
    }
}
