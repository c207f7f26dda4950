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

use super::field::write_planes;
use super::header::Header;
use super::samples::datatype_code;
use super::source::fill;
use super::write::{Nifti1Content, Shape, nifti1_header_for, write_file};
use crate::error::{Error, Result};
use crate::geometry::{Index, Lps, Transform};
use crate::volume::SampleType;

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

/// Writes a pull-back as AFNI's `3dQwarp` saves a warp named `.nii` or `.nii.gz` (gzip by the name), atomically:
/// float32, dim = [5, X, Y, Z, 1, 3, 1, 1], no intent, the grid's sform and qform (scanner: AFNI's `+orig` view), the
/// LPS vectors as they are (AFNI's DICOM order) one component plane after another, and AFNI's extension naming the
/// sub-bricks [`WARP_LABELS`], with `NIfTI_nums` as AFNI checks it against the header. `3dNwarpApply -nwarp PATH`
/// applies it; non-finite vectors are refused.
pub fn write_afni_warp(
    path: &Path,
    dims: [usize; 3],
    lps_from_index: &Transform<Lps, Index>,
    displacements_lps: &[[f32; 3]],
) -> Result<()> {
    crate::displacement::check::check_field_to_write(path, dims, lps_from_index, displacements_lps)?;
    let what = Nifti1Content {
        type_code: datatype_code(SampleType::F32),
        descrip: b"warpbench warp for AFNI, LPS (DICOM) mm".to_vec(),
        shape: Shape::Vector { intent_code: 0, components: 3 },
    };
    let mut header = nifti1_header_for(path, dims, lps_from_index, &what)?;
    let (datatype, _) = what.type_code;
    let niml = format!(
        "<?xml version='1.0' ?>\n<AFNI_attributes\n  NIfTI_nums=\"{},{},{},1,3,{datatype}\"\n  ni_form=\"ni_group\" >\n\
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
    write_file(path, &header, |w| write_planes(w, displacements_lps, [1.0; 3]))
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

    /// What the writer writes reads back as AFNI's warp: the same vectors, LPS, no intent, the extension at its place.
    #[test]
    fn a_written_warp_reads_back_as_afnis() {
        let dir = tempfile::tempdir().expect("tempdir");
        let dims = [4, 3, 2];
        let grid = Transform::from_scale_translation([2.0, -2.5, 3.0], [10.0, -5.0, 7.0]);
        let vectors: Vec<[f32; 3]> = (0..24).map(|k| [k as f32 * 0.25, -(k as f32), 1.5]).collect();
        for name in ["w.nii", "w.nii.gz"] {
            let path = dir.path().join(name);
            write_afni_warp(&path, dims, &grid, &vectors).expect("write");
            assert!(is_afni_warp(&path).expect("read"));
            let (field, kind) = super::super::read_vector_field(&path).expect("read back");
            assert_eq!(kind, super::super::NiftiFieldKind::AfniWarp);
            assert_eq!((field.dims, field.displacements_lps.as_slice()), (dims, vectors.as_slice()));
        }
        let raw = std::fs::read(dir.path().join("w.nii")).expect("read");
        let vox_offset = f32::from_le_bytes([raw[108], raw[109], raw[110], raw[111]]) as usize;
        assert_eq!((raw[348], vox_offset % 16, raw.len() - vox_offset), (1, 0, 24 * 12));
        assert_eq!(i16::from_le_bytes([raw[68], raw[69]]), 0, "no intent");
        assert_eq!(i32::from_le_bytes([raw[356], raw[357], raw[358], raw[359]]), NIFTI_ECODE_AFNI);
    }
}
