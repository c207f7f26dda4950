//! Displacement fields in the four flavours neighbouring tools read and write, behind one reader that tells them
//! apart by content ([`read_field`]) and one writer ([`write_field`]).
//!
//! A field D on a grid holds one vector per voxel centre x, in LPS mm inside warpbench. Which map it samples is the
//! writer's choice ([`FieldDirection`]): a pull-back field holds u(x) − x (ITK's `DisplacementFieldTransform`:
//! the output point x reads the input at x + D(x)), a forward field d(y) − y (a point y moves to y + D(y)).
//!
//! | flavour | file | intent / kinds | vectors in the file | who reads it |
//! |---|---|---|---|---|
//! | [`FieldFormat::Itk`] | NIfTI-1 `.nii(.gz)`, float32, dim `[5, X, Y, Z, 1, 3, 1, 1]` | `intent_code` 1006 `DISPVECT` | RAS | ITK ≥ 5.3 (SimpleITK ≥ 2.3), 3D Slicer ≥ 5.2 |
//! | [`FieldFormat::Ants`] | NIfTI-1 `.nii(.gz)`, float32, dim `[5, X, Y, Z, 1, 3, 1, 1]` | `intent_code` 1007 `VECTOR` | LPS | ANTs (`antsApplyTransforms`, `*Warp.nii.gz`), every ITK |
//! | [`FieldFormat::Nrrd`] | NRRD0004 `.nrrd`, float, sizes `3 X Y Z` | `kinds: vector domain domain domain` | LPS (`space: left-posterior-superior`) | 3D Slicer, ITK's `NrrdImageIO` |
//! | [`FieldFormat::MetaImage`] | MetaImage `.mha`, or `.mhd` + `.raw`, `MET_FLOAT` | `ElementNumberOfChannels = 3` | LPS | elastix and transformix (`deformationField.mhd`), every ITK |
//! | [`FieldFormat::Afni`] | NIfTI-1 `.nii(.gz)`, float32, dim `[5, X, Y, Z, 1, 3, 1, 1]` | none; AFNI's extension (code 4) labels `x_delta`, `y_delta`, `z_delta` | LPS (DICOM) | AFNI (`3dNwarpApply -nwarp`) |
//! | [`FieldFormat::Ngff`] | OME-Zarr 0.6 folder `.ome.zarr`, float32 (c, z, y, x) | RFC-5 `displacements` | along the axes, written L, P, S | ngff-zarr (`ngff_displacement_field_to_itk_transform`) |
//!
//! The component planes of the NIfTI flavours follow one another (all x, then all y, then all z); NRRD and
//! MetaImage interleave them. See [`crate::nifti`] ("Displacement fields"), [`crate::nrrd::field`] and
//! [`crate::metaimage::read_displacement_field`] for the exact layouts and the ITK behaviour they rest on.
//!
//! [`read_field`] detects the flavour from the bytes, not the name: a folder holding a Zarr store is
//! [`FieldFormat::Ngff`] ([`crate::ngff::read_field`]); a NRRD magic is [`FieldFormat::Nrrd`]; a
//! MetaImage header (`ObjectType = …`) is [`FieldFormat::MetaImage`]; a NIfTI header (plain or gzip) with intent 1006
//! is [`FieldFormat::Itk`], with 1007 [`FieldFormat::Ants`]. An elastix transform parameter file (its first line
//! opens with `(`) is read as the field transformix writes for it ([`crate::elastix::read_field`]): its whole chain
//! sampled on its fixed grid. Anything else is refused. It returns LPS vectors whatever the flavour.
//!
//! An AFNI dataset (`.HEAD`/`.BRIK`, by its name) is read as `3dQwarp`'s warp ([`crate::afni_dataset::read_warp`]).
//!
//! Learn2Reg's `.npz` fields ([`crate::learn2reg`]) hold voxel steps from the fixed image's grid to the moving one's,
//! so they are read against the pair ([`crate::learn2reg::pullback_from_voxels`]); [`read_field`] refuses them, as it
//! refuses FSL's FNIRT warps, in the FSL coordinates of the pair ([`crate::fnirt::read_pullback`]).

pub(crate) mod check;
mod flavour;

use std::path::Path;

use crate::error::{Error, Result};
use crate::geometry::{Index, Lps, Transform};
pub use flavour::{FieldDirection, FieldFormat, FieldSource, ReadField, SampleGrid};
pub(crate) use flavour::{head, read_flavoured};

use crate::nifti::{self, DisplacementField, NiftiVectorIntent};
use crate::nrrd::field::{self as nrrd_field, NrrdFieldType};

/// Reads a displacement field of any flavour, told apart by content (module docs); the vectors are LPS.
/// Errors name the file: a wrong intent, wrong dims, non-float samples, non-finite vectors, a field too large for
/// memory.
pub fn read_field(path: &Path) -> Result<(DisplacementField, FieldSource)> {
    read_field_info(path).map(|r| (r.field, r.source))
}

/// [`read_field`], with the direction the file states (NRRD's `displacement field type`).
pub fn read_field_info(path: &Path) -> Result<ReadField> {
    read_field_on(path, None)
}

/// Whether the file at `path` is one of ITK's transform files, HDF5 or text (`.tfm`), by its first bytes: a file that
/// may need a [`SampleGrid`] to be read as a field ([`read_field_on`]).
///
/// # Errors
/// The file cannot be opened.
pub fn is_itk_transform_file(path: &Path) -> Result<bool> {
    if path.is_dir() || crate::afni_dataset::has_afni_name(path) {
        // A folder (an OME-Zarr field store) and an AFNI warp give their own grids.
        return Ok(false);
    }
    let head = flavour::head(path)?;
    Ok(crate::itk_h5::looks_like_hdf5(&head) || crate::itk_tfm::looks_like_text(&head))
}

/// The file read once, as a field ([`read_field_info`]) or, for an ITK transform file of B-splines and affines with no
/// displacement field (which gives no grid to sample on), as its chain.
///
/// # Errors
/// As [`read_field_info`].
pub fn read_field_or_chain(path: &Path) -> Result<crate::itk_chain::FieldOrChain> {
    use crate::itk_chain::FieldOrChain;
    if path.is_dir() || crate::afni_dataset::has_afni_name(path) {
        return read_field_info(path).map(FieldOrChain::Field);
    }
    let head = flavour::head(path)?;
    if crate::itk_h5::looks_like_hdf5(&head) {
        return crate::itk_h5::read_field_or_chain(path);
    }
    if crate::itk_tfm::looks_like_text(&head) {
        return crate::transform_file::read_chain(path).map(FieldOrChain::Chain);
    }
    read_field_info(path).map(FieldOrChain::Field)
}

/// [`read_field_info`], and an ITK transform file of B-splines (`.tfm` or `.h5`, which give no grid of their own)
/// sampled at the voxel centres of `grid` ([`crate::itk_chain::ItkChain::field_on`]).
///
/// # Errors
/// As [`read_field_info`]; such a file without `grid`.
pub fn read_field_on(path: &Path, grid: Option<&SampleGrid>) -> Result<ReadField> {
    if path.is_dir() && crate::ngff::looks_like_zarr(path) {
        let (field, warnings) = crate::ngff::read_field(path)?;
        return Ok(ReadField { field, source: FieldSource::Field(FieldFormat::Ngff), direction: None, warnings });
    }
    if crate::afni_dataset::has_afni_name(path) {
        return crate::afni_dataset::read_warp(path);
    }
    if let Some(code) = nifti::fsl_intent(path)? {
        return Err(Error::unsupported(
            path,
            format!(
                "intent_code {code}: an FSL FNIRT warp (or another FSL field) is in FSL's coordinates of its reference \
                 and input images, which this reader is not given: read it against them (command line: `warpbench \
                 warp --fixed REF --moving IN --field W`; Python: read_field(path, fixed=REF, moving=IN); \
                 docs/formats.md)"
            ),
        ));
    }
    let head = flavour::head(path)?;
    if let Some(read) = flavour::read_flavoured(path, &head)? {
        return Ok(read);
    }
    if crate::mni_xfm::looks_like_xfm(&head) {
        return crate::mni_xfm::read_field(path);
    }
    if crate::elastix::looks_like_parameter_file(&head) {
        let field = crate::elastix::read_field(path)?;
        return Ok(ReadField { field, source: FieldSource::ElastixTransform, direction: None, warnings: Vec::new() });
    }
    if crate::itk_h5::looks_like_hdf5(&head) {
        return crate::itk_h5::read_field_on(path, grid);
    }
    if crate::itk_tfm::looks_like_text(&head) {
        let chain = crate::transform_file::read_chain(path)?;
        return chain.field_on(path, grid, FieldSource::ItkTransform);
    }
    if crate::learn2reg::looks_like_npz(&head) {
        return Err(Error::unsupported(
            path,
            "a Learn2Reg displacement field (.npz) is in the voxels of its fixed and moving images, which this reader \
             is not given: resample with it by `warpbench warp --fixed F --moving M --field` (docs/formats.md)",
        ));
    }
    if crate::dicom_reg::looks_like_dicom(&head) {
        let field = crate::dicom_reg::read_field(path)?;
        return Ok(ReadField {
            field,
            source: FieldSource::DicomRegistration,
            direction: Some(FieldDirection::Pullback),
            warnings: Vec::new(),
        });
    }
    for (looks, what) in [
        (crate::fsl::looks_like_flirt_matrix(&head), "FSL's FLIRT matrix"),
        (crate::afni::looks_like_afni_matrix(&head), "AFNI's matrix file"),
    ] {
        if looks {
            return Err(Error::unsupported(
                path,
                format!(
                    "{what}, an affine and not a displacement field: it is a starting transform (--initial, or the \
                     window's starting transform from a file)"
                ),
            ));
        }
    }
    Err(Error::unsupported(
        path,
        "not a displacement field: neither NIfTI (intent 1006 or 1007), NRRD, MetaImage, an elastix transform \
         parameter file, an ITK transform file (.h5 or .tfm) nor a DICOM Deformable Spatial Registration",
    ))
}

/// Writes a pull-back displacement field (`displacements_lps`, LPS mm, i fastest, one per voxel of the grid `dims`,
/// `lps_from_index`) in `format`, atomically. Same as [`write_field_with`] with [`FieldDirection::Pullback`].
pub fn write_field(
    path: &Path,
    format: FieldFormat,
    dims: [usize; 3],
    lps_from_index: &Transform<Lps, Index>,
    displacements_lps: &[[f32; 3]],
) -> Result<()> {
    write_field_with(path, format, FieldDirection::Pullback, dims, lps_from_index, displacements_lps)
}

/// Writes a displacement field in `format`, atomically. `direction` is what the vectors sample: the NRRD flavour
/// records it (`displacement field type:=resampling` or `modeling`, which Slicer reads); NIfTI and MetaImage have
/// nowhere to say it. A name that is not the flavour's container (`.nrrd` for `nrrd`; `.nii`, `.nii.gz` for `itk`
/// and `ants`; `.mha`, `.mhd` for `metaimage`) is refused, and so is a detached NRRD header (`.nhdr`), which would
/// need a second data file; non-finite vectors are refused, naming the voxel. A `.mhd` writes its `.raw` beside it
/// ([`crate::metaimage::detached_data_file`]), first.
pub fn write_field_with(
    path: &Path,
    format: FieldFormat,
    direction: FieldDirection,
    dims: [usize; 3],
    lps_from_index: &Transform<Lps, Index>,
    displacements_lps: &[[f32; 3]],
) -> Result<()> {
    check_output_name(path, format)?;
    match format {
        FieldFormat::Itk | FieldFormat::Ants => {
            let intent =
                if format == FieldFormat::Itk { NiftiVectorIntent::DispvectRas } else { NiftiVectorIntent::VectorLps };
            nifti::write_vector_field(path, dims, lps_from_index, displacements_lps, intent)
        }
        FieldFormat::Nrrd => {
            let kind = match direction {
                FieldDirection::Pullback => NrrdFieldType::Resampling,
                FieldDirection::Forward => NrrdFieldType::Modeling,
            };
            nrrd_field::write_displacement_field(path, dims, lps_from_index, displacements_lps, kind)
        }
        FieldFormat::MetaImage => {
            crate::metaimage::write_displacement_field(path, dims, lps_from_index, displacements_lps)
        }
        FieldFormat::Minc => crate::mni_xfm::write_grid(path, direction, dims, lps_from_index, displacements_lps),
        FieldFormat::Ngff => crate::ngff::write_field(path, dims, lps_from_index, displacements_lps),
        FieldFormat::Afni => nifti::write_afni_warp(path, dims, lps_from_index, displacements_lps),
    }
}

/// Refuses an output name that cannot hold `format` (see [`write_field_with`]), before anything is computed.
pub fn check_output_name(path: &Path, format: FieldFormat) -> Result<()> {
    if crate::itk_tfm::is_hdf5_name(path) {
        return Err(Error::unsupported(
            path,
            "ITK reads a file named .h5 as an HDF5 transform file, and a displacement field image is not one: name \
             the field .nii.gz, .nrrd or .mha, or export the warp as a transform named .h5, ITK's HDF5 transform file, \
             which holds its field",
        ));
    }
    if crate::learn2reg::is_npz_name(path) {
        return Err(Error::unsupported(
            path,
            "a name ending .npz is Learn2Reg's field, in the voxels of the fixed and moving images: `warpbench field` \
             writes it; name an image field .nii.gz, .nrrd or .mha",
        ));
    }
    if !format.container_matches(path) {
        return Err(Error::invalid(path, format!("the {format} field flavour is written to {}", format.names())));
    }
    let detached = path.file_name().is_some_and(|n| n.to_string_lossy().to_ascii_lowercase().ends_with(".nhdr"));
    if detached {
        return Err(Error::unsupported(
            path,
            "a detached NRRD header (.nhdr) needs a second data file; write the field to a .nrrd file",
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Matrix3;

    /// A small oblique grid and a field whose components differ in every voxel.
    fn sample_field() -> ([usize; 3], Transform<Lps, Index>, Vec<[f32; 3]>) {
        let (s, c) = 0.3f64.sin_cos();
        let linear = Matrix3::new(c * 1.5, -s * 2.0, 0.0, s * 1.5, c * 2.0, 0.0, 0.0, 0.0, 2.5);
        let lps_from_index = Transform::from_linear_translation(linear, [-30.0, 12.5, 7.25]);
        let dims = [3, 4, 2];
        let field = (0..24).map(|i| [i as f32 * 0.25 - 3.0, 1.0 - i as f32 * 0.125, (i * i) as f32 * 0.01]).collect();
        (dims, lps_from_index, field)
    }

    fn bits(v: &[[f32; 3]]) -> Vec<u32> {
        v.iter().flat_map(|d| d.map(|x| (x + 0.0).to_bits())).collect()
    }

    #[test]
    fn every_flavour_round_trips_and_is_told_apart_by_content() {
        let dir = tempfile::tempdir().expect("tempdir");
        let (dims, lps_from_index, field) = sample_field();
        for (format, name, direction) in [
            (FieldFormat::Itk, "f.nii.gz", None),
            (FieldFormat::Itk, "f.nii", None),
            (FieldFormat::Ants, "a.nii.gz", None),
            (FieldFormat::Ants, "a.nii", None),
            (FieldFormat::Nrrd, "n.nrrd", Some(FieldDirection::Pullback)),
            (FieldFormat::MetaImage, "m.mha", None),
            (FieldFormat::MetaImage, "m.mhd", None),
        ] {
            let path = dir.path().join(name);
            write_field(&path, format, dims, &lps_from_index, &field).expect("write");
            // The name says nothing to the reader: a copy under a neutral name reads the same.
            // (A .mhd's header names its data file, which stays beside it.)
            let neutral = dir.path().join(format!("{name}.bin"));
            std::fs::copy(&path, &neutral).expect("copy");
            for p in [&path, &neutral] {
                let r = read_field_info(p).expect("read back");
                assert_eq!((r.source, r.direction), (FieldSource::Field(format), direction), "{name}");
                assert_eq!(r.field.dims, dims);
                assert!(r.field.lps_from_index.max_abs_diff(&lps_from_index) < 1e-4, "{name}");
                assert_eq!(bits(&r.field.displacements_lps), bits(&field), "{name}: LPS vectors bit for bit");
            }
        }
        let forward = dir.path().join("forward.nrrd");
        write_field_with(&forward, FieldFormat::Nrrd, FieldDirection::Forward, dims, &lps_from_index, &field)
            .expect("write");
        assert_eq!(read_field_info(&forward).expect("read").direction, Some(FieldDirection::Forward));
        let text = std::fs::read(&forward).expect("read");
        let header = String::from_utf8_lossy(&text[..text.windows(2).position(|w| w == b"\n\n").expect("blank")]);
        for line in [
            "type: float",
            "dimension: 4",
            "space: left-posterior-superior",
            "sizes: 3 3 4 2",
            "kinds: vector domain domain domain",
            "encoding: gzip",
            "displacement field type:=modeling",
        ] {
            assert!(header.lines().any(|l| l == line), "{line:?} missing from\n{header}");
        }
        assert!(header.lines().any(|l| l.starts_with("space directions: none (")), "{header}");
    }

    #[test]
    fn the_ants_flavour_is_intent_vector_with_lps_planes() {
        let dir = tempfile::tempdir().expect("tempdir");
        let (dims, lps_from_index, field) = sample_field();
        let (itk, ants) = (dir.path().join("itk.nii"), dir.path().join("ants.nii"));
        write_field(&itk, FieldFormat::Itk, dims, &lps_from_index, &field).expect("write");
        write_field(&ants, FieldFormat::Ants, dims, &lps_from_index, &field).expect("write");
        let (itk, ants) = (std::fs::read(itk).expect("read"), std::fs::read(ants).expect("read"));
        let i16_at = |b: &[u8], o: usize| i16::from_le_bytes([b[o], b[o + 1]]);
        let f32_at = |b: &[u8], o: usize| f32::from_le_bytes([b[o], b[o + 1], b[o + 2], b[o + 3]]);
        assert_eq!((i16_at(&itk, 68), i16_at(&ants, 68)), (1006, 1007));
        for b in [&itk, &ants] {
            assert_eq!((0..8).map(|i| i16_at(b, 40 + 2 * i)).collect::<Vec<_>>(), [5, 3, 4, 2, 1, 3, 1, 1]);
        }
        // The same header otherwise, except the intent and the description.
        let differ: Vec<usize> = (0..352).filter(|&o| itk[o] != ants[o]).collect();
        assert!(differ.iter().all(|&o| (68..70).contains(&o) || (148..228).contains(&o)), "{differ:?}");
        for (c, sign) in [(0, -1.0f32), (1, -1.0), (2, 1.0)] {
            for v in [0, 7, 23] {
                let o = 352 + 4 * (c * 24 + v);
                assert_eq!(f32_at(&ants, o).to_bits(), field[v][c].to_bits(), "ants: LPS");
                assert_eq!(f32_at(&itk, o).to_bits(), (sign * field[v][c]).to_bits(), "itk: RAS");
            }
        }
    }

    #[test]
    fn bad_fields_are_refused_naming_the_file() {
        let dir = tempfile::tempdir().expect("tempdir");
        let (dims, lps_from_index, field) = sample_field();
        let nii = dir.path().join("f.nii");
        write_field(&nii, FieldFormat::Ants, dims, &lps_from_index, &field).expect("write");
        let raw = std::fs::read(&nii).expect("read");
        let put = |name: &str, bytes: &[u8]| {
            let p = dir.path().join(name);
            std::fs::write(&p, bytes).expect("write");
            p
        };
        let refused = |p: &Path, needle: &str| {
            let e = read_field(p).expect_err("refused");
            let text = e.to_string();
            assert!(text.starts_with(&format!("{}: ", p.display())) && text.contains(needle), "{text}");
        };
        let mut intent = raw.clone();
        intent[68..70].copy_from_slice(&1005i16.to_le_bytes());
        refused(&put("intent.nii", &intent), "intent_code is 1005");
        let mut four_d = raw.clone();
        four_d[40..42].copy_from_slice(&4i16.to_le_bytes());
        four_d[48..50].copy_from_slice(&3i16.to_le_bytes());
        four_d[50..52].copy_from_slice(&1i16.to_le_bytes());
        refused(&put("four_d.nii", &four_d), "[5, X, Y, Z, 1, 3");
        let mut nan = raw.clone();
        let o = 352 + 4 * (24 + 5); // the y component of voxel 5 = (2, 1, 0)
        nan[o..o + 4].copy_from_slice(&f32::NAN.to_le_bytes());
        refused(&put("nan.nii", &nan), "voxel [2, 1, 0]");
        let mut huge = raw.clone();
        for a in 0..3 {
            huge[42 + 2 * a..44 + 2 * a].copy_from_slice(&32000i16.to_le_bytes());
        }
        let e = read_field(&put("huge.nii", &huge)).expect_err("too large");
        assert!(matches!(e.kind, crate::ErrorKind::TooLarge { .. } | crate::ErrorKind::Truncated(_)), "{e}");
        refused(&put("text.nii", b"hello"), "not a displacement field");

        let nrrd = dir.path().join("f.nrrd");
        write_field(&nrrd, FieldFormat::Nrrd, dims, &lps_from_index, &field).expect("write");
        let text = std::fs::read(&nrrd).expect("read");
        let swap = |from: &str, to: &str| {
            let s = String::from_utf8_lossy(&text).into_owned();
            let at = text.windows(2).position(|w| w == b"\n\n").expect("blank") + 2;
            let mut b = s[..at].replacen(from, to, 1).into_bytes();
            b.extend_from_slice(&text[at..]);
            b
        };
        refused(&put("ras.nrrd", &swap("left-posterior-superior", "right-anterior-superior")), "left-posterior");
        refused(&put("kinds.nrrd", &swap("kinds: vector", "kinds: domain")), "kinds");
        refused(&put("type.nrrd", &swap("type: float", "type: short")), "integer samples");
        refused(&put("sizes.nrrd", &swap("sizes: 3 ", "sizes: 2 ")), "2 components");
        refused(&put("dft.nrrd", &swap(":=resampling", ":=sideways")), "resampling and modeling");
        let mut nan_field = field.clone();
        nan_field[9][2] = f32::INFINITY;
        for format in FieldFormat::ALL {
            let extension = match format {
                FieldFormat::Nrrd => "nrrd",
                FieldFormat::MetaImage => "mha",
                FieldFormat::Itk | FieldFormat::Ants | FieldFormat::Afni => "nii",
                FieldFormat::Minc => "xfm",
                FieldFormat::Ngff => "ome.zarr",
            };
            let p = dir.path().join(format!("nan_{format}.{extension}"));
            let e = write_field(&p, format, dims, &lps_from_index, &nan_field).expect_err("not finite");
            assert!(e.to_string().contains("voxel"), "{e}");
            assert!(!p.exists());
        }
        for (format, name) in [
            (FieldFormat::Nrrd, "x.nii.gz"),
            (FieldFormat::Itk, "x.nrrd"),
            (FieldFormat::Nrrd, "x.nhdr"),
            (FieldFormat::MetaImage, "x.nii"),
            (FieldFormat::MetaImage, "x.field"),
            (FieldFormat::Ants, "x.mha"),
            (FieldFormat::Minc, "x.nii"),
            (FieldFormat::Itk, "x.xfm"),
            (FieldFormat::Ngff, "x.nii"),
            (FieldFormat::Itk, "x.ome.zarr"),
            (FieldFormat::Afni, "x.nrrd"),
        ] {
            let p = dir.path().join(name);
            assert!(write_field(&p, format, dims, &lps_from_index, &field).is_err(), "{format} to {name}");
            assert!(!p.exists());
        }
    }
}
