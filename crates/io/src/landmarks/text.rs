//! The text of a landmark file: read bounded by [`MAX_LANDMARK_FILE_BYTES`], one byte-order mark stripped, and
//! numbers printed so that they read back exactly.

use std::path::Path;

use crate::error::{Error, Result};

/// The largest landmark file read, in bytes. BigWarp and Slicer files hold at most thousands of points (5 000
/// pairs, the TPS limit, are about 1 MB of CSV), so a larger file is refused before it is read into memory.
pub const MAX_LANDMARK_FILE_BYTES: u64 = 256 << 20;

/// The text of the landmark file at `path`: a regular file (a named pipe would block, a device never end) of at
/// most [`MAX_LANDMARK_FILE_BYTES`], checked before it is opened and bounded while it is read.
pub(super) fn read_text(path: &Path) -> Result<String> {
    utf8(path, read_bytes(path)?)
}

/// `bytes` of the file at `path` as text, or an error that names the file.
pub(super) fn utf8(path: &Path, bytes: Vec<u8>) -> Result<String> {
    String::from_utf8(bytes).map_err(|e| Error::invalid(path, format!("not UTF-8 text: {e}")))
}

/// The bytes of the landmark file at `path`, bounded as [`read_text`] reads them.
pub(super) fn read_bytes(path: &Path) -> Result<Vec<u8>> {
    let too_big = |bytes: u64| {
        Error::invalid(
            path,
            format!(
                "the file has {bytes} bytes, more than the {MAX_LANDMARK_FILE_BYTES} bytes a landmark file may have"
            ),
        )
    };
    let meta = crate::files::check_regular_file(path)?;
    if meta.len() > MAX_LANDMARK_FILE_BYTES {
        return Err(too_big(meta.len()));
    }
    let file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let mut bytes = Vec::new();
    std::io::Read::read_to_end(&mut std::io::Read::take(file, MAX_LANDMARK_FILE_BYTES + 1), &mut bytes)
        .map_err(|e| Error::io(path, e))?;
    if bytes.len() as u64 > MAX_LANDMARK_FILE_BYTES {
        return Err(too_big(bytes.len() as u64));
    }
    Ok(bytes)
}

/// `text` without one leading UTF-8 byte-order mark (U+FEFF), which Windows editors write and Slicer, BigWarp and
/// spreadsheet programs accept. Every `parse_*` function of [`crate::landmarks`] starts here, so every reader (file
/// or text) accepts it; a second mark is content.
pub(super) fn strip_bom(text: &str) -> &str {
    text.strip_prefix('\u{feff}').unwrap_or(text)
}

/// Shortest text that parses back to the same f64 (`1.0`, `-0.5`, `1e-7`).
pub(super) fn num(x: f64) -> String {
    format!("{x:?}")
}
