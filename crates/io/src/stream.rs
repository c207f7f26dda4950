//! What the binary volume readers (NIfTI, MGH) read their samples through: a byte [`Source`] that may skip forward
//! without reading (a plain file, a buffer) or not (a gzip stream), and the [`Extent`] that bounds what it can
//! deliver, checked before the samples are allocated.

use std::fs::File;
use std::io::{self, BufReader, Read};

use flate2::read::MultiGzDecoder;

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
