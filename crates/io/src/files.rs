//! The checks every reader makes on a path before it opens it (a regular file, or a folder for a DICOM series;
//! never a pipe or a device), and [`read_up_to`], the short read that tells a short file from a full one.

use std::fs::File;
use std::io::{BufReader, Read};
use std::path::{Path, PathBuf};

use crate::error::{Error, ErrorKind, Result};

/// Refuses `path` unless it is a regular file (following symbolic links), before anything opens it: a named
/// pipe blocks in `open`, a device such as `/dev/zero` never ends. Returns the file's metadata (its length bounds
/// every read and skip that follows).
pub(crate) fn check_regular_file(path: &Path) -> Result<std::fs::Metadata> {
    let meta = std::fs::metadata(path).map_err(|e| Error::io(path, e))?;
    if meta.is_file() {
        return Ok(meta);
    }
    let what = if meta.is_dir() { "a folder" } else { special_kind(&meta) };
    Err(Error::new(path, ErrorKind::NotARegularFile { what }))
}

/// The text of a file's first bytes `head`, a multi-byte character cut at its end dropped (the cut is not the
/// file's error); `None` when it is not UTF-8.
pub(crate) fn head_text(head: &[u8]) -> Option<&str> {
    match std::str::from_utf8(head) {
        Ok(text) => Some(text),
        Err(e) if e.error_len().is_none() => std::str::from_utf8(&head[..e.valid_up_to()]).ok(),
        Err(_) => None,
    }
}

/// The text of the small regular file `path`: refused, naming `what` it is not, when it is larger than `max` bytes
/// or not UTF-8 (a matrix file of FSL, AFNI or FreeSurfer).
pub(crate) fn read_small_text(path: &Path, max: u64, what: &str) -> Result<String> {
    let meta = check_regular_file(path)?;
    if meta.len() > max {
        return Err(Error::invalid(path, format!("{} bytes: not {what}", meta.len())));
    }
    let mut bytes = Vec::new();
    File::open(path).and_then(|f| f.take(max).read_to_end(&mut bytes)).map_err(|e| Error::io(path, e))?;
    String::from_utf8(bytes).map_err(|_| Error::invalid(path, format!("not text: not {what}")))
}

/// Opens the regular file `path` and hands `read_from` its buffered reader, its length and its folder (where a
/// header's detached data file is looked for): the entry point of the readers of headers with data beside them.
pub(crate) fn read_header_file<T>(
    path: &Path,
    read_from: impl FnOnce(BufReader<File>, u64, &Path) -> Result<T>,
) -> Result<T> {
    check_regular_file(path)?;
    let file = File::open(path).map_err(|e| Error::io(path, e))?;
    let len = file.metadata().map_err(|e| Error::io(path, e))?.len();
    let folder = path.parent().map_or_else(|| PathBuf::from("."), Path::to_path_buf);
    read_from(BufReader::new(file), len, &folder)
}

/// [`check_regular_file`], but a folder (a DICOM series) is accepted too.
pub(crate) fn check_file_or_folder(path: &Path) -> Result<std::fs::Metadata> {
    let meta = std::fs::metadata(path).map_err(|e| Error::io(path, e))?;
    if meta.is_file() || meta.is_dir() {
        return Ok(meta);
    }
    Err(Error::new(path, ErrorKind::NotARegularFile { what: special_kind(&meta) }))
}

/// What a file that is neither regular nor a folder is, in words.
fn special_kind(meta: &std::fs::Metadata) -> &'static str {
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        let t = meta.file_type();
        if t.is_fifo() {
            return "a named pipe (FIFO)";
        }
        if t.is_char_device() {
            return "a character device";
        }
        if t.is_block_device() {
            return "a block device";
        }
        if t.is_socket() {
            return "a socket";
        }
    }
    let _ = meta;
    "a special file"
}

/// Whether `head`, a file's first bytes, is a DICOM file's: the 128-byte preamble and then `DICM` (PS3.10 §7.1).
pub(crate) fn has_dicom_preamble(head: &[u8]) -> bool {
    head.get(128..132).is_some_and(|magic| magic == b"DICM")
}

/// Reads as many bytes as are there, up to `buf.len()` (retrying interrupted reads); the shared
/// helper of every reader that must tell a short file from a full one.
pub(crate) fn read_up_to(r: &mut impl Read, buf: &mut [u8]) -> std::io::Result<usize> {
    let mut n = 0;
    while n < buf.len() {
        match r.read(&mut buf[n..]) {
            Ok(0) => break,
            Ok(k) => n += k,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => return Err(e),
        }
    }
    Ok(n)
}
