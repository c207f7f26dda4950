//! AFNI's NIfTI extension (code 4, `NIFTI_ECODE_AFNI`): the dataset's attributes as NIML text, which is how a NIfTI
//! file written by AFNI keeps its sub-bricks' labels. A `3dQwarp` warp saved as `PREFIX_WARP.nii` is an
//! (X, Y, Z, 1, 3) array with no intent: only the labels `x_delta`, `y_delta`, `z_delta` there say it is a warp.
//!
//! The extensions lie between the header and `vox_offset`: four bytes whose first is non-zero when there are any,
//! then each extension's size (a multiple of 16, its 8-byte head included), its code and its content (nifti1.h,
//! "extension"). AFNI writes the labels as one attribute of its NIML group (`thd_nimlatr.c`):
//!
//! ```text
//! <AFNI_atr
//!   ni_type="String"
//!   ni_dimen="1"
//!   atr_name="BRICK_LABS" >
//!  "x_delta~y_delta~z_delta"
//! </AFNI_atr>
//! ```

use std::io::Read;
use std::path::Path;

use super::header::Header;
use super::source::fill;
use crate::error::{Error, Result};

/// The code of AFNI's extension (`NIFTI_ECODE_AFNI`, nifti1_io.h).
pub const NIFTI_ECODE_AFNI: i32 = 4;

/// The labels of a `3dQwarp` warp's first three sub-bricks (AFNI's `IW3D_to_dataset`).
pub const WARP_LABELS: [&str; 3] = ["x_delta", "y_delta", "z_delta"];

/// The most extension bytes read between the header and the samples.
const MAX_EXTENSION_BYTES: u64 = 16 << 20;

/// Reads the bytes between the header and the samples (`vox_offset`) from `r`, which stands just after the header,
/// and returns the content of AFNI's extension when there is one. The bytes read are returned too, so the samples
/// can be reached after them.
pub(super) fn read_afni_extension(path: &Path, r: &mut impl Read, h: &Header) -> Result<(Option<Vec<u8>>, u64)> {
    let start = h.version.header_bytes() as u64;
    let end = h.vox_offset as u64;
    if !h.vox_offset.is_finite() || end <= start + 4 {
        return Ok((None, 0));
    }
    let n = end - start;
    if n > MAX_EXTENSION_BYTES {
        return Err(Error::invalid(
            path,
            format!("vox_offset {} leaves {n} bytes of extensions, more than {MAX_EXTENSION_BYTES}", h.vox_offset),
        ));
    }
    let mut bytes = vec![0u8; n as usize]; // bounded above
    fill(path, r, &mut bytes, "the header's extensions")?;
    if bytes[0] == 0 {
        return Ok((None, n));
    }
    let int = |b: &[u8]| {
        let a = [b[0], b[1], b[2], b[3]];
        if h.big_endian { i32::from_be_bytes(a) } else { i32::from_le_bytes(a) }
    };
    let mut at = 4usize;
    while at + 8 <= bytes.len() {
        let (size, code) = (int(&bytes[at..]), int(&bytes[at + 4..]));
        let Ok(size) = usize::try_from(size) else { break };
        if size < 8 || at + size > bytes.len() {
            break; // not an extension: what is left is padding, as nibabel takes it
        }
        if code == NIFTI_ECODE_AFNI {
            return Ok((Some(bytes[at + 8..at + size].to_vec()), n));
        }
        at += size;
    }
    Ok((None, n))
}

/// Whether the NIfTI file at `path` is a `3dQwarp` warp: an (X, Y, Z, 1, 3) array whose AFNI extension labels its
/// components [`WARP_LABELS`]. A file that is not NIfTI is not.
///
/// # Errors
/// The file cannot be read, or its extensions are cut short.
pub fn is_afni_warp(path: &Path) -> Result<bool> {
    let (mut src, _) = super::source::open_file(path)?;
    let Ok(h) = super::header::read_header(path, &mut src) else { return Ok(false) };
    if h.pair || !(h.dim[0] == 5 && h.dim[4] == 1 && h.dim[5] == 3) {
        return Ok(false);
    }
    let (afni, _) = read_afni_extension(path, &mut src, &h)?;
    Ok(afni.as_deref().and_then(brick_labels).is_some_and(|l| are_warp_labels(&l)))
}

/// Appends AFNI's extension for a warp of `dims` to `header` (a NIfTI-1 header with its 4-byte extension flag, as
/// written with no extension), sets the flag and moves `vox_offset` past it: the NIML naming the sub-bricks
/// [`WARP_LABELS`], with `NIfTI_nums` (X, Y, Z, 1, 3, float32) as AFNI checks it against the header.
pub(super) fn append_warp_extension(header: &mut Vec<u8>, dims: [usize; 3]) {
    let niml = format!(
        "<?xml version='1.0' ?>\n<AFNI_attributes\n  NIfTI_nums=\"{},{},{},1,3,16\"\n  ni_form=\"ni_group\" >\n\
         <AFNI_atr\n  ni_type=\"String\"\n  ni_dimen=\"1\"\n  atr_name=\"BRICK_LABS\" >\n \"{}\"\n</AFNI_atr>\n\
         </AFNI_attributes>\n",
        dims[0],
        dims[1],
        dims[2],
        WARP_LABELS.join("~")
    );
    // The extension's size counts its 8-byte head and is a multiple of 16; the content ends with a NUL, padded.
    let size = (8 + niml.len() + 1).div_ceil(16) * 16;
    let header_bytes = header.len() - 4;
    header[header_bytes] = 1; // the extension flag
    header.extend_from_slice(&i32::try_from(size).unwrap_or(i32::MAX).to_le_bytes());
    header.extend_from_slice(&NIFTI_ECODE_AFNI.to_le_bytes());
    header.extend_from_slice(niml.as_bytes());
    header.resize(header_bytes + 4 + size, 0);
    let vox_offset = header.len() as f32;
    header[108..112].copy_from_slice(&vox_offset.to_le_bytes());
}

/// The sub-bricks' labels in AFNI's NIML text (`BRICK_LABS`), `None` when it gives none.
#[must_use]
pub fn brick_labels(niml: &[u8]) -> Option<Vec<String>> {
    let text = String::from_utf8_lossy(niml);
    let at = text.find("atr_name=\"BRICK_LABS\"")?;
    let rest = &text[at..];
    let open = rest.find('>')? + 1;
    let close = rest[open..].find("</AFNI_atr>")? + open;
    let body = rest[open..close].trim().trim_matches('"');
    Some(body.trim_end_matches('~').split('~').map(str::to_string).collect())
}

/// Whether `labels` begin as a `3dQwarp` warp's ([`WARP_LABELS`]).
#[must_use]
pub fn are_warp_labels(labels: &[String]) -> bool {
    labels.len() >= 3 && labels[..3].iter().zip(WARP_LABELS).all(|(l, w)| l == w)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The labels of AFNI's NIML attribute, quoted or not, with or without the closing `~`.
    #[test]
    fn labels_come_out_of_afnis_niml() {
        let niml = b"<?xml version='1.0' ?>\n<AFNI_attributes\n  self_idcode=\"XYZ\"\n  ni_form=\"ni_group\" >\n\
            <AFNI_atr\n  ni_type=\"String\"\n  ni_dimen=\"1\"\n  atr_name=\"HISTORY_NOTE\" >\n \"3dQwarp ...\"\n</AFNI_atr>\n\
            <AFNI_atr\n  ni_type=\"String\"\n  ni_dimen=\"1\"\n  atr_name=\"BRICK_LABS\" >\n \"x_delta~y_delta~z_delta~\"\n\
            </AFNI_atr>\n</AFNI_attributes>\n\0";
        let labels = brick_labels(niml).expect("labels");
        assert_eq!(labels, ["x_delta", "y_delta", "z_delta"]);
        assert!(are_warp_labels(&labels));
        assert_eq!(brick_labels(b"atr_name=\"BRICK_LABS\" >a~b</AFNI_atr>").expect("labels"), ["a", "b"]);
        assert!(!are_warp_labels(&["x_delta".to_string(), "y_delta".to_string()]));
        assert_eq!(brick_labels(b"<AFNI_attributes ni_form=\"ni_group\" ></AFNI_attributes>"), None);
    }
}
