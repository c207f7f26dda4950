//! What the binary volume readers (NIfTI, MGH) read their samples through: a byte [`Source`] that may skip forward
//! without reading (a plain file, a buffer) or not (a gzip stream), the [`Extent`] that bounds what it can deliver,
//! checked before the samples are allocated, and [`fill`], whose errors tell a short file from corrupt gzip data.

use std::fs::File;
use std::io::{self, BufReader, Read};
use std::path::Path;

use flate2::read::MultiGzDecoder;

use crate::error::{Error, Result};

/// gzip's first two bytes.
pub(crate) const GZIP_MAGIC: [u8; 2] = [0x1f, 0x8b];

/// Deflate's largest expansion: 258-byte matches coded in about 2 bits give about 1032:1.
pub(crate) const MAX_DEFLATE_RATIO: u64 = 1032;

/// What bounds the bytes a source can deliver, checked before the samples are allocated.
#[derive(Clone, Copy, Debug)]
pub(crate) enum Extent {
    /// An uncompressed file or buffer of this many bytes: the data must end inside it.
    Exact(u64),
    /// A gzip stream of this many compressed bytes: it cannot inflate to more than [`MAX_DEFLATE_RATIO`] times that,
    /// so a tiny file claiming gigabytes fails early.
    Gzip(u64),
}

/// A byte stream that may be able to skip forward without reading.
pub(crate) trait Source: Read {
    /// Skips `n` bytes if the source can seek; `Ok(false)` means the caller must read through them.
    fn seek_forward(&mut self, n: u64) -> io::Result<bool> {
        let _ = n;
        Ok(false)
    }
}

impl Source for BufReader<File> {
    fn seek_forward(&mut self, n: u64) -> io::Result<bool> {
        self.seek_relative(i64::try_from(n).map_err(io::Error::other)?)?;
        Ok(true)
    }
}

impl Source for &[u8] {
    fn seek_forward(&mut self, n: u64) -> io::Result<bool> {
        let n = usize::try_from(n).unwrap_or(usize::MAX).min(self.len());
        *self = &self[n..];
        Ok(true)
    }
}

impl<R: Read> Source for MultiGzDecoder<R> {}

/// Fills `buf` from `r`; `what` names the part of the file in errors ([`read_error`]).
pub(crate) fn fill(path: &Path, r: &mut impl Read, buf: &mut [u8], what: &str) -> Result<()> {
    r.read_exact(buf).map_err(|e| read_error(path, e, what))
}

/// The error of a failed read of `what`: a short stream is a truncated file, corrupt gzip data invalid.
pub(crate) fn read_error(path: &Path, e: io::Error, what: &str) -> Error {
    match e.kind() {
        io::ErrorKind::UnexpectedEof => Error::truncated(path, format!("the file ends inside {what}")),
        io::ErrorKind::InvalidData | io::ErrorKind::InvalidInput => {
            Error::invalid(path, format!("corrupt compressed data in {what}: {e}"))
        }
        _ => Error::io(path, e),
    }
}
