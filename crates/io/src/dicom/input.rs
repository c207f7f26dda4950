//! Where one DICOM object comes from (a file or a buffer), the regular files of a series folder, and opening an
//! object with dicom-rs once [`super::prescan`] has checked its element lengths.

use std::borrow::Cow;
use std::io::Read;
use std::ops::Range;
use std::path::{Path, PathBuf};

use dicom_dictionary_std::tags;
use dicom_object::file::ReadPreamble;
use dicom_object::{DefaultDicomObject, OpenFileOptions};

use super::prescan::{Checked, check_lengths};
use crate::error::{Error, ErrorKind, Result};
use crate::volume;

/// Where one DICOM object comes from.
pub(super) enum Source<'a> {
    File(PathBuf),
    Bytes(PathBuf, &'a [u8]),
}

impl Source<'_> {
    pub(super) fn path(&self) -> &Path {
        match self {
            Self::File(p) | Self::Bytes(p, _) => p,
        }
    }

    /// Bytes the source holds (the file size on disk).
    pub(super) fn byte_len(&self) -> Result<u64> {
        match self {
            Self::File(p) => std::fs::metadata(p).map(|m| m.len()).map_err(|e| Error::io(p, e)),
            Self::Bytes(_, b) => Ok(b.len() as u64),
        }
    }

    /// True when the data carries the 128-byte preamble and `DICM`.
    pub(super) fn has_preamble(&self) -> Result<bool> {
        match self {
            Self::File(p) => {
                let mut head = [0u8; 132];
                let mut f = std::fs::File::open(p).map_err(|e| Error::io(p, e))?;
                let n = crate::files::read_up_to(&mut f, &mut head).map_err(|e| Error::io(p, e))?;
                Ok(crate::files::has_dicom_preamble(&head[..n]))
            }
            Self::Bytes(_, b) => Ok(crate::files::has_dicom_preamble(b)),
        }
    }

    /// The file's bytes, after checking the preamble and every element length ([`check_lengths`]).
    fn read_checked(&self) -> Result<(Cow<'_, [u8]>, Checked)> {
        let path = self.path();
        let bytes: Cow<'_, [u8]> = match self {
            Self::File(p) => Cow::Owned(read_whole_file(p)?),
            Self::Bytes(_, b) => Cow::Borrowed(b),
        };
        if !crate::files::has_dicom_preamble(&bytes) {
            return Err(Error::new(
                path,
                ErrorKind::BadMagic { format: "DICOM", detail: "no 'DICM' after the 128-byte preamble".into() },
            ));
        }
        let checked = check_lengths(&bytes[128..]).map_err(|(truncated, msg)| {
            if truncated { Error::truncated(path, msg) } else { Error::new(path, ErrorKind::Dicom(msg)) }
        })?;
        Ok((bytes, checked))
    }

    /// Opens the object; `header_only` stops before PixelData, otherwise right after it.
    ///
    /// The element lengths are checked first ([`check_lengths`]): dicom-rs allocates whatever a
    /// length field claims (up to 4 GiB) before reading, and reads on past PixelData into any
    /// trailing padding. The parser gets the bytes up to the end of the top-level PixelData only.
    pub(super) fn open(&self, header_only: bool) -> Result<DefaultDicomObject> {
        let (bytes, checked) = self.read_checked()?;
        let data = checked.replacement.as_deref().unwrap_or(&bytes[128..]);
        let options = OpenFileOptions::new().read_preamble(ReadPreamble::Never);
        let options =
            if header_only { options.read_until(tags::PIXEL_DATA) } else { options.read_to(tags::PIXEL_DATA) };
        options
            .from_reader(&data[..checked.end])
            .map_err(|e| Error::new(self.path(), ErrorKind::Dicom(error_chain(&e))))
    }

    /// For native (uncompressed) pixel data with a defined length: the header parsed by dicom-rs,
    /// and the file's bytes with the PixelData value's range in them. The pixels are not copied
    /// into a parsed object, so a large multi-frame file costs its size once, not twice.
    pub(super) fn open_native_pixels(&self) -> Result<(DefaultDicomObject, Cow<'_, [u8]>, Range<usize>)> {
        let (bytes, checked) = self.read_checked()?;
        let Some(value) = checked.pixel_value.clone() else {
            return Err(Error::invalid(self.path(), "PixelData (7FE0,0010) is missing or has no defined length"));
        };
        let options = OpenFileOptions::new().read_preamble(ReadPreamble::Never).read_until(tags::PIXEL_DATA);
        let obj = options
            .from_reader(&bytes[128..128 + checked.end])
            .map_err(|e| Error::new(self.path(), ErrorKind::Dicom(error_chain(&e))))?;
        Ok((obj, bytes, 128 + value.start..128 + value.end))
    }
}

/// The bytes of the file at `path`, into a buffer allocated fallibly for its length: memory the system refuses is
/// an [`ErrorKind::OutOfMemory`] naming the file.
fn read_whole_file(path: &Path) -> Result<Vec<u8>> {
    let mut file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let len = file.metadata().map_err(|e| Error::io(path, e))?.len();
    let capacity =
        usize::try_from(len).map_err(|_| Error::invalid(path, format!("{len} bytes do not fit in memory")))?;
    let mut bytes = volume::try_with_capacity(path, capacity, "the file's bytes")?;
    // At most the length seen (a file that grows meanwhile is read as it was).
    (&mut file).take(len).read_to_end(&mut bytes).map_err(|e| Error::io(path, e))?;
    Ok(bytes)
}

/// An error and its sources, joined with ": ".
pub(super) fn error_chain(e: &dyn std::error::Error) -> String {
    let mut s = e.to_string();
    let mut cur = e.source();
    while let Some(c) = cur {
        let t = c.to_string();
        if !s.contains(&t) {
            s.push_str(": ");
            s.push_str(&t);
        }
        cur = c.source();
    }
    s
}

/// The regular files of a folder, sorted by name.
pub(super) fn folder_files(dir: &Path) -> Result<Vec<Source<'static>>> {
    let entries = std::fs::read_dir(dir).map_err(|e| Error::io(dir, e))?;
    let mut files = Vec::new();
    for entry in entries {
        let entry = entry.map_err(|e| Error::io(dir, e))?;
        let p = entry.path();
        if std::fs::metadata(&p).is_ok_and(|m| m.is_file()) {
            files.push(p);
        }
    }
    files.sort();
    Ok(files.into_iter().map(Source::File).collect())
}
