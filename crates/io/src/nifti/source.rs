//! The NIfTI file as a byte source (plain or gzip-compressed, by content: [`open_file`]), [`fill`], and the progress
//! [`Reporter`], shared by the volume reader in [`crate::nifti`] and the stages and field reader beside it; the
//! sources themselves and the bound on what each can deliver are [`crate::stream`]'s, which MGH shares.

use std::fs::File;
use std::io::{self, BufReader, Read, Seek, SeekFrom};
use std::path::Path;

use flate2::read::MultiGzDecoder;

use crate::error::{Error, Result};
use crate::options::LoadOptions;

pub(super) use crate::stream::{Extent, GZIP_MAGIC, MAX_DEFLATE_RATIO, Source, fill};

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
