//! The byte sources of the readers (a file, plain or gzip-compressed, or a buffer), the bound on what each can
//! deliver ([`Extent`]), [`fill`], and the progress [`Reporter`]: shared by the volume reader in [`crate::nifti`]
//! and the stages and field reader beside it.

use std::fs::File;
use std::io::{self, BufReader, Read, Seek, SeekFrom};
use std::path::Path;

use flate2::read::MultiGzDecoder;

use crate::error::{Error, Result};
use crate::options::LoadOptions;

pub(super) const GZIP_MAGIC: [u8; 2] = [0x1f, 0x8b];

/// What bounds the bytes a source can deliver, checked before the voxel buffer is allocated.
#[derive(Clone, Copy, Debug)]
pub(super) enum Extent {
    /// An uncompressed file or buffer of this many bytes: the data must end inside it.
    Exact(u64),
    /// A gzip stream of this many compressed bytes: it cannot inflate to more than
    /// [`MAX_DEFLATE_RATIO`] times that, so a tiny `.nii.gz` claiming gigabytes fails early.
    Gzip(u64),
}

/// Deflate's largest expansion: 258-byte matches coded in about 2 bits give about 1032:1.
pub(super) const MAX_DEFLATE_RATIO: u64 = 1032;

/// A NIfTI file opened for reading: buffered, and through a gzip decoder when it starts with gzip's magic bytes
/// (boxed: zlib-rs's inflate state is a few hundred bytes).
pub(super) enum FileSource {
    Plain(BufReader<File>),
    Gzip(Box<MultiGzDecoder<BufReader<File>>>),
}

impl Read for FileSource {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        match self {
            Self::Plain(r) => r.read(buf),
            Self::Gzip(r) => r.read(buf),
        }
    }
}

impl Source for FileSource {
    fn seek_forward(&mut self, n: u64) -> io::Result<bool> {
        match self {
            Self::Plain(r) => r.seek_forward(n),
            Self::Gzip(r) => r.seek_forward(n),
        }
    }
}

/// Opens the regular file at `path` as a NIfTI source (gzip detected by content) with the bound on what it can
/// deliver. Shared by the volume and the displacement-field readers.
pub(super) fn open_file(path: &Path) -> Result<(FileSource, Extent)> {
    crate::files::check_regular_file(path)?;
    let mut file = File::open(path).map_err(|e| Error::io(path, e))?;
    let file_len = file.metadata().map_err(|e| Error::io(path, e))?.len();
    let mut magic = [0u8; 2];
    let n = crate::files::read_up_to(&mut file, &mut magic).map_err(|e| Error::io(path, e))?;
    file.seek(SeekFrom::Start(0)).map_err(|e| Error::io(path, e))?;
    Ok(if n == 2 && magic == GZIP_MAGIC {
        (FileSource::Gzip(Box::new(MultiGzDecoder::new(BufReader::new(file)))), Extent::Gzip(file_len))
    } else {
        (FileSource::Plain(BufReader::new(file)), Extent::Exact(file_len))
    })
}

/// A byte stream that may be able to skip forward without reading.
pub(super) trait Source: Read {
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

/// Fills `buf` from `r`; a short stream is a truncated file, a corrupt gzip stream invalid data.
pub(super) fn fill(path: &Path, r: &mut impl Read, buf: &mut [u8], what: &str) -> Result<()> {
    r.read_exact(buf).map_err(|e| match e.kind() {
        io::ErrorKind::UnexpectedEof => Error::truncated(path, format!("the file ends inside {what}")),
        io::ErrorKind::InvalidData | io::ErrorKind::InvalidInput => {
            Error::invalid(path, format!("corrupt compressed data in {what}: {e}"))
        }
        _ => Error::io(path, e),
    })
}

/// Reports `"reading"` progress every [`CHUNK_BYTES`](super::samples::CHUNK_BYTES) and at the end.
pub(super) struct Reporter<'o, 'a> {
    pub(super) path: &'o Path,
    pub(super) opts: &'o mut LoadOptions<'a>,
    pub(super) done: u64,
    pub(super) total: u64,
}

impl Reporter<'_, '_> {
    pub(super) fn advance(&mut self, n: usize) -> Result<()> {
        self.done += n as u64;
        self.opts.report(self.path, "reading", self.done, self.total)
    }
}
