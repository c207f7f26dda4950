//! Learn2Reg's displacement fields: the `.npz` files the challenge's evaluation read until 2021
//! (`disp_XXXX_YYYY.npz`), the NIfTI files it reads since 2022 (`disp_XXXX_YYYY.nii.gz`), and which learning-based
//! registration methods (ConvexAdam, LapIRN, uniGradICON's Learn2Reg scripts) write.
//!
//! The file is NumPy's `.npz`: a zip archive of `.npy` arrays. The field is the array `arr_0` (what
//! `np.savez_compressed(path, disp)` names it), of shape `(X, Y, Z, 3)`: one vector per voxel of the **fixed** image,
//! indexed as nibabel indexes the NIfTI image (`[i, j, k]`), in **voxels**, not mm. The evaluation maps a fixed voxel
//! index `i` to the moving voxel index `i + d[i]`: a pull-back u = moving_from_fixed, written in the two images' voxel
//! indices. So the file carries no geometry: reading it needs the fixed grid and the moving grid
//! ([`pullback_from_voxels`]), and so does writing one ([`voxels_from_pullback`]).
//!
//! [`read_voxel_field`] takes `float16`, `float32` and `float64` arrays in either byte order and C or Fortran order.
//! [`write_voxel_field`] writes `float16` in C order, deflated, as the challenge's submissions are: each component is
//! rounded to the nearest `float16`, within 2⁻¹¹ of its size (0.01 voxel at 20 voxels).
//!
//! The NIfTI form holds the same array as nibabel writes it (`nib.save(nib.Nifti1Image(disp, affine), path)`): dim =
//! [4, X, Y, Z, 3], no intent, float32 or float64, and whatever affine the method passed (the fixed image's, the
//! identity, none), which the evaluation reads past (`nib.load(path).get_fdata()`). Nothing in such a file says it is
//! in voxels: an (X, Y, Z, 3) NIfTI of another tool may be in mm. So it is read as Learn2Reg's only when the caller
//! says so ([`read_voxel_field`] given a NIfTI), never by guess. [`write_voxel_field_nifti`] writes float32 with the
//! fixed image's affine, as ConvexAdam does.
//!
//! The evaluation interpolates `d` between voxel centres with SciPy's cubic spline (`map_coordinates`, order 3);
//! warpbench, like ITK, interpolates a displacement field trilinearly. The two agree at voxel centres.

use std::io::{Cursor, Read, Seek, Write};
use std::path::Path;

use half::f16;
use npyz::{DType, NpyFile, Order, TypeChar, WriterBuilder};

use crate::error::{Error, ErrorKind, Result};
use crate::geometry::{Index, Lps, Point3, Transform};
use crate::nifti::DisplacementField;
use crate::volume::GeometrySource;

/// The name Learn2Reg's evaluation reads the field from: NumPy's name for the first unnamed array.
pub const ARRAY_NAME: &str = "arr_0";

/// A Learn2Reg field: for each fixed voxel `[i, j, k]` (i fastest), the step to the moving voxel it maps to, in
/// voxels (module docs).
#[derive(Clone, Debug, PartialEq)]
pub struct VoxelField {
    /// Voxels along i, j, k: the fixed image's dims.
    pub dims: [usize; 3],
    /// `d[i]`, i fastest: fixed index `i` maps to moving index `i + d[i]`.
    pub steps_vox: Vec<[f32; 3]>,
}

/// Whether `path` is named as a NumPy archive (`.npz`, any case): the name that makes `warpbench field` write this
/// flavour.
#[must_use]
pub fn is_npz_name(path: &Path) -> bool {
    path.extension().is_some_and(|e| e.eq_ignore_ascii_case("npz"))
}

/// Whether the file at `path` opens as a zip archive, as every `.npz` does: how a reader given a field tells this
/// flavour from the others, by content. Errors name the file.
pub fn is_npz_file(path: &Path) -> Result<bool> {
    if path.is_dir() {
        // A folder (an OME-Zarr field store) is no zip archive.
        return Ok(false);
    }
    let mut head = [0u8; 4];
    let mut file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let n = crate::files::read_up_to(&mut file, &mut head).map_err(|e| Error::io(path, e))?;
    Ok(looks_like_npz(&head[..n]))
}

/// Whether `head` (the first bytes of a file) opens a zip archive, as every `.npz` does.
#[must_use]
pub fn looks_like_npz(head: &[u8]) -> bool {
    head.starts_with(b"PK\x03\x04")
}

/// Whether `head` (a file's first bytes) opens a NIfTI file or a gzip stream, which a `.nii.gz` is.
fn nifti_or_gzip(head: &[u8]) -> bool {
    crate::nifti::looks_like_nifti(head) || head.starts_with(&[0x1f, 0x8b])
}

/// Reads a Learn2Reg field from an `.npz` file, or from a NIfTI file of its 2022 form (module docs), told apart by
/// their first bytes. Errors name the file: neither; for an `.npz`, no `arr_0` (unless the archive holds exactly one
/// array, which is taken), a shape other than `(X, Y, Z, 3)` (the 2021 layout `(3, X, Y, Z)` is named as such), a
/// dtype other than float16/32/64; for a NIfTI, what [`crate::nifti::read_frame_vectors`] refuses; a vector that is
/// not finite (named by its `[i, j, k]`), a field too large for memory.
pub fn read_voxel_field(path: &Path) -> Result<VoxelField> {
    crate::files::check_regular_file(path)?;
    let mut head = [0u8; 4];
    let mut file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let n = crate::files::read_up_to(&mut file, &mut head).map_err(|e| Error::io(path, e))?;
    if !looks_like_npz(&head[..n]) && nifti_or_gzip(&head[..n]) {
        let (dims, steps_vox) = crate::nifti::read_frame_vectors(path)?;
        return Ok(VoxelField { dims, steps_vox });
    }
    drop(file);
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    read_voxel_field_bytes(path, &bytes)
}

/// [`read_voxel_field`] of bytes already read; `name` is only for messages.
pub fn read_voxel_field_bytes(name: &Path, bytes: &[u8]) -> Result<VoxelField> {
    if !looks_like_npz(bytes) {
        if nifti_or_gzip(bytes) {
            let (dims, steps_vox) = crate::nifti::read_frame_vectors_bytes(name, bytes)?;
            return Ok(VoxelField { dims, steps_vox });
        }
        return Err(Error::invalid(
            name,
            "neither a NumPy .npz archive (a zip file) nor a NIfTI file: not a Learn2Reg displacement field",
        ));
    }
    let bad_zip = |e: zip::result::ZipError| Error::invalid(name, format!("a damaged .npz (zip) archive: {e}"));
    let mut archive = zip::ZipArchive::new(Cursor::new(bytes)).map_err(bad_zip)?;
    let arrays: Vec<String> =
        archive.file_names().filter_map(|n| n.ok().and_then(|n| n.strip_suffix(".npy").map(str::to_owned))).collect();
    let member = if arrays.iter().any(|a| a == ARRAY_NAME) {
        ARRAY_NAME.to_owned()
    } else {
        match arrays.as_slice() {
            [only] => only.clone(),
            [] => return Err(Error::invalid(name, "the .npz archive holds no array")),
            many => {
                return Err(Error::invalid(
                    name,
                    format!(
                        "the .npz archive holds {} arrays ({}) and none is named {ARRAY_NAME}, the one Learn2Reg reads",
                        many.len(),
                        many.join(", ")
                    ),
                ));
            }
        }
    };
    let mut entry = archive.by_name(&format!("{member}.npy")).map_err(bad_zip)?;
    let size = entry.size();
    let mut preamble = [0u8; 12];
    let n = crate::files::read_up_to(&mut entry, &mut preamble).map_err(|e| Error::io(name, e))?;
    check_npy_header_size(name, &member, &preamble[..n])?;
    read_npy(name, &member, Cursor::new(&preamble[..n]).chain(entry), size)
}

/// The longest `.npy` header NumPy reads (`numpy.lib.format`'s `max_header_size`, 10 000 bytes): a header is a short
/// Python literal, and its stated length is what a reader allocates before it has read a byte of it.
const MAX_NPY_HEADER_BYTES: u64 = 10_000;

/// Refuses a `.npy` whose preamble (magic, version, header length) states a header longer than
/// [`MAX_NPY_HEADER_BYTES`], as NumPy does; anything else is left to the `.npy` reader's own checks.
fn check_npy_header_size(name: &Path, member: &str, preamble: &[u8]) -> Result<()> {
    let stated = match preamble {
        [0x93, b'N', b'U', b'M', b'P', b'Y', 1, _, a, b, ..] => u64::from(u16::from_le_bytes([*a, *b])),
        [0x93, b'N', b'U', b'M', b'P', b'Y', 2 | 3, _, a, b, c, d] => u64::from(u32::from_le_bytes([*a, *b, *c, *d])),
        _ => return Ok(()),
    };
    if stated > MAX_NPY_HEADER_BYTES {
        return Err(Error::invalid(
            name,
            format!(
                "array {member}: its header claims {stated} bytes, more than the {MAX_NPY_HEADER_BYTES} NumPy reads"
            ),
        ));
    }
    Ok(())
}

/// Reads the `.npy` array `member`, `size` bytes unpacked, from `reader` as a [`VoxelField`].
fn read_npy(name: &Path, member: &str, reader: impl Read, size: u64) -> Result<VoxelField> {
    let npy =
        NpyFile::new(reader).map_err(|e| Error::invalid(name, format!("array {member}: not a .npy array: {e}")))?;
    let shape = npy.shape().to_vec();
    let dims = match shape.as_slice() {
        &[x, y, z, 3] => [x, y, z].map(|d| usize::try_from(d).unwrap_or(usize::MAX)),
        &[3, x, y, z] => {
            return Err(Error::unsupported(
                name,
                format!(
                    "array {member} has shape (3, {x}, {y}, {z}), Learn2Reg's 2021 layout (often at half resolution); \
                     the evaluation now reads (X, Y, Z, 3): transpose it (disp.transpose(1, 2, 3, 0)) and resample \
                     it to the fixed image's size"
                ),
            ));
        }
        other => {
            return Err(Error::invalid(
                name,
                format!("array {member} has shape {other:?}; a Learn2Reg field has shape (X, Y, Z, 3)"),
            ));
        }
    };
    let n = crate::volume::checked_voxel_count(name, dims)?;
    let fortran = npy.order() == Order::Fortran;
    let len = n.checked_mul(3).ok_or_else(|| {
        Error::new(name, ErrorKind::OutOfMemory { what: format!("array {member}"), bytes: (n as u128) * 12 })
    })?;
    let values = read_floats(name, member, npy, len, size)?;
    let mut steps_vox = vec![[0f32; 3]; n];
    let [nx, ny, nz] = dims;
    for (c, plane) in [0usize, 1, 2].into_iter().map(|c| (c, c * n)) {
        for k in 0..nz {
            for j in 0..ny {
                for i in 0..nx {
                    let at = if fortran { plane + i + nx * (j + ny * k) } else { ((i * ny + j) * nz + k) * 3 + c };
                    steps_vox[i + nx * (j + ny * k)][c] = values[at];
                }
            }
        }
    }
    if let Some(ijk) = crate::displacement::check::first_non_finite(dims, &steps_vox) {
        return Err(Error::invalid(
            name,
            format!("array {member}: the vector at voxel {ijk:?} (i, j, k) is not finite"),
        ));
    }
    Ok(VoxelField { dims, steps_vox })
}

/// The `len` values of a float array of any width, as f32; `size` is the array's size in the archive, which must
/// hold them all before anything is allocated.
fn read_floats(name: &Path, member: &str, npy: NpyFile<impl Read>, len: usize, size: u64) -> Result<Vec<f32>> {
    let dtype = npy.dtype();
    let width = match &dtype {
        DType::Plain(t) if t.type_char() == TypeChar::Float => t.size_field(),
        _ => 0,
    };
    let bytes = (len as u128) * u128::from(width);
    if bytes > u128::from(size) {
        return Err(Error::truncated(
            name,
            format!("array {member} is {size} bytes, short of the {bytes} bytes its shape and dtype need"),
        ));
    }
    let short = |e: std::io::Error| Error::io(name, e);
    let mut out = Vec::new();
    out.try_reserve_exact(len).map_err(|_| {
        Error::new(name, ErrorKind::OutOfMemory { what: format!("array {member}"), bytes: (len as u128) * 4 })
    })?;
    match width {
        2 => out.extend(npy.into_vec::<f16>().map_err(short)?.into_iter().map(f16::to_f32)),
        4 => out.extend(npy.into_vec::<f32>().map_err(short)?),
        #[allow(clippy::cast_possible_truncation, reason = "a displacement in voxels; f32 holds what a grid needs")]
        8 => out.extend(npy.into_vec::<f64>().map_err(short)?.into_iter().map(|v| v as f32)),
        _ => {
            return Err(Error::unsupported(
                name,
                format!("array {member} holds {}; a Learn2Reg field is float16, float32 or float64", dtype.descr()),
            ));
        }
    }
    if out.len() != len {
        return Err(Error::truncated(name, format!("array {member} holds {} values, its shape {len}", out.len())));
    }
    Ok(out)
}

/// Writes `field` as Learn2Reg's `.npz`, atomically: the array `arr_0`, float16, C order, shape `(X, Y, Z, 3)`,
/// deflated (as `np.savez_compressed`). A component beyond float16's range (±65504 voxels) or not finite is refused,
/// naming its voxel.
pub fn write_voxel_field(path: &Path, field: &VoxelField) -> Result<()> {
    let n = crate::volume::checked_voxel_count(path, field.dims)?;
    if field.steps_vox.len() != n {
        return Err(Error::invalid(path, format!("{} vectors for dims {:?}", field.steps_vox.len(), field.dims)));
    }
    let [nx, ny, nz] = field.dims;
    let mut halves = Vec::with_capacity(3 * n);
    for i in 0..nx {
        for j in 0..ny {
            for k in 0..nz {
                let v = field.steps_vox[i + nx * (j + ny * k)];
                if !v.iter().all(|c| c.is_finite() && c.abs() <= f16::MAX.to_f32()) {
                    return Err(Error::invalid(
                        path,
                        format!("the vector at voxel {:?} (i, j, k), {v:?} voxels, does not fit float16", [i, j, k]),
                    ));
                }
                halves.extend(v.map(f16::from_f32));
            }
        }
    }
    let shape = [nx, ny, nz, 3].map(|d| d as u64);
    let npy = npy_bytes(&halves, &shape).map_err(|e| Error::io(path, e))?;
    let mut archive = zip::ZipWriter::new(Cursor::new(Vec::new()));
    let options = zip::write::SimpleFileOptions::default()
        .compression_method(zip::CompressionMethod::Deflated)
        .large_file(npy.len() >= u32::MAX as usize);
    let zipped = (|| {
        archive.start_file(format!("{ARRAY_NAME}.npy"), options)?;
        archive.write_all(&npy)?;
        archive.finish()
    })()
    .map_err(|e| Error::invalid(path, format!("cannot build the .npz archive: {e}")))?;
    crate::atomic::write_atomic(path, |w| w.write_all(zipped.get_ref()))
}

/// Writes `field` in Learn2Reg's NIfTI form (module docs), atomically: float32, dim = [4, X, Y, Z, 3], no intent,
/// and the fixed image's grid (`fixed_lps_from_index`) as its sform and qform, which the challenge reads past. A
/// vector that is not finite is refused, naming its voxel.
pub fn write_voxel_field_nifti(
    path: &Path,
    field: &VoxelField,
    fixed_lps_from_index: &Transform<Lps, Index>,
) -> Result<()> {
    crate::nifti::write_frame_vectors(
        path,
        field.dims,
        fixed_lps_from_index,
        &field.steps_vox,
        "Learn2Reg displacement, fixed voxels to moving voxels",
    )
}

/// A `.npy` file of float16 `values` with `shape`, C order, little-endian.
fn npy_bytes(values: &[f16], shape: &[u64]) -> std::io::Result<Vec<u8>> {
    let mut out = Cursor::new(Vec::new());
    let dtype = DType::Plain("<f2".parse().expect("a valid type string"));
    let mut writer = npyz::WriteOptions::new().dtype(dtype).shape(shape).writer(&mut out).begin_nd()?;
    writer.extend(values.iter().copied())?;
    writer.finish()?;
    out.rewind()?;
    Ok(out.into_inner())
}

/// The pull-back field in LPS mm on the fixed grid that a Learn2Reg field states: at fixed voxel i, with x =
/// fixed_lps_from_index(i), D(x) = moving_lps_from_index(i + d\[i\]) − x. `path` names the file in errors: a field whose
/// dims are not the fixed grid's, a step too large for a finite point.
pub fn pullback_from_voxels(
    path: &Path,
    field: &VoxelField,
    fixed_dims: [usize; 3],
    fixed_lps_from_index: &Transform<Lps, Index>,
    moving_lps_from_index: &Transform<Lps, Index>,
) -> Result<DisplacementField> {
    if field.dims != fixed_dims {
        return Err(Error::invalid(
            path,
            format!(
                "the field has shape {:?} and the fixed image {fixed_dims:?}: a Learn2Reg field holds one vector per \
                 fixed voxel",
                field.dims
            ),
        ));
    }
    let displacements_lps = field
        .steps_vox
        .iter()
        .enumerate()
        .map(|(n, &d)| {
            let (i, x) = voxel_centre(n, field.dims, fixed_lps_from_index);
            let u = moving_lps_from_index.apply_point(Point3::from_array(plus(i, d))).coords();
            #[allow(clippy::cast_possible_truncation, reason = "a field's vectors are f32 in every flavour")]
            [0, 1, 2].map(|c| (u[c] - x[c]) as f32)
        })
        .collect::<Vec<_>>();
    if let Some(ijk) = crate::displacement::check::first_non_finite(field.dims, &displacements_lps) {
        return Err(Error::invalid(
            path,
            format!("the step at voxel {ijk:?} (i, j, k) leads beyond any finite point of the moving grid"),
        ));
    }
    Ok(DisplacementField {
        dims: field.dims,
        lps_from_index: *fixed_lps_from_index,
        geometry_source: GeometrySource::Learn2RegFixedImage,
        displacements_lps,
    })
}

/// The Learn2Reg field of a pull-back field in LPS mm on the fixed grid (`dims`, `fixed_lps_from_index`): d\[i\] =
/// moving_index_from_lps(x + D(x)) − i. `path` names the output in errors: a singular moving grid.
pub fn voxels_from_pullback(
    path: &Path,
    dims: [usize; 3],
    fixed_lps_from_index: &Transform<Lps, Index>,
    moving_lps_from_index: &Transform<Lps, Index>,
    displacements_lps: &[[f32; 3]],
) -> Result<VoxelField> {
    let moving_index_from_lps = moving_lps_from_index
        .inverse()
        .ok_or_else(|| Error::invalid(path, "the moving image's voxel-to-patient matrix is singular"))?;
    let steps_vox = displacements_lps
        .iter()
        .enumerate()
        .map(|(n, &d)| {
            let (i, x) = voxel_centre(n, dims, fixed_lps_from_index);
            let j = moving_index_from_lps.apply_point(Point3::from_array(plus(x, d))).coords();
            #[allow(clippy::cast_possible_truncation, reason = "a step in voxels")]
            [0, 1, 2].map(|c| (j[c] - i[c]) as f32)
        })
        .collect();
    Ok(VoxelField { dims, steps_vox })
}

/// The index i of voxel `n` (i fastest) of a grid of `dims`, and its centre x = lps_from_index(i).
fn voxel_centre(n: usize, [nx, ny, _]: [usize; 3], lps_from_index: &Transform<Lps, Index>) -> ([f64; 3], [f64; 3]) {
    let i = [n % nx, (n / nx) % ny, n / (nx * ny)].map(|c| c as f64);
    (i, lps_from_index.apply_point(Point3::from_array(i)).coords())
}

/// a + d, in f64.
fn plus(a: [f64; 3], d: [f32; 3]) -> [f64; 3] {
    [0, 1, 2].map(|c| a[c] + f64::from(d[c]))
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Matrix3;

    fn field() -> VoxelField {
        let dims = [3, 4, 2];
        let steps_vox =
            (0..24).map(|n| [n as f32 * 0.25 - 3.0, 1.0 - n as f32 * 0.125, (n % 5) as f32 * 0.5]).collect();
        VoxelField { dims, steps_vox }
    }

    #[test]
    fn a_written_field_reads_back_within_float16() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("disp_0001_0002.npz");
        let f = field();
        write_voxel_field(&path, &f).expect("write");
        let back = read_voxel_field(&path).expect("read");
        assert_eq!(back.dims, f.dims);
        for (a, b) in back.steps_vox.iter().zip(&f.steps_vox) {
            for c in 0..3 {
                // These values are multiples of 1/8 below 8: float16 holds them exactly.
                assert_eq!(a[c].to_bits(), b[c].to_bits());
            }
        }
    }

    #[test]
    fn the_conversions_are_inverse_and_map_indices_through_both_grids() {
        let (s, c) = 0.4f64.sin_cos();
        let fixed = Transform::from_linear_translation(
            Matrix3::new(c * 1.5, -s * 2.0, 0.0, s * 1.5, c * 2.0, 0.0, 0.0, 0.0, 2.5),
            [-30.0, 12.5, 7.25],
        );
        let moving = Transform::from_linear_translation(Matrix3::from_diagonal_element(0.8), [5.0, -3.0, 1.0]);
        let f = field();
        let path = Path::new("f.npz");
        let pullback = pullback_from_voxels(path, &f, f.dims, &fixed, &moving).expect("pullback");
        // Voxel n = 7 is [1, 2, 0]: it maps to the moving index [1, 2, 0] + d, whose LPS point is x + D(x).
        let d = f.steps_vox[7];
        let want = moving.apply_point(Point3::new(1.0 + f64::from(d[0]), 2.0 + f64::from(d[1]), f64::from(d[2])));
        let x = fixed.apply_point(Point3::new(1.0, 2.0, 0.0)).coords();
        let got = pullback.displacements_lps[7];
        for a in 0..3 {
            assert!((x[a] + f64::from(got[a]) - want.coords()[a]).abs() < 1e-4);
        }
        let back = voxels_from_pullback(path, f.dims, &fixed, &moving, &pullback.displacements_lps).expect("back");
        for (a, b) in back.steps_vox.iter().zip(&f.steps_vox) {
            for c in 0..3 {
                assert!((a[c] - b[c]).abs() < 1e-4, "{a:?} {b:?}");
            }
        }
        let e = pullback_from_voxels(path, &f, [3, 4, 3], &fixed, &moving).expect_err("wrong dims").to_string();
        assert!(e.contains("f.npz") && e.contains("[3, 4, 2]") && e.contains("[3, 4, 3]"), "{e}");
        let mut huge = f.clone();
        huge.steps_vox[5] = [f32::MAX, 0.0, 0.0];
        let coarse = Transform::from_scale_translation([2.5; 3], [0.0; 3]);
        let e = pullback_from_voxels(path, &huge, f.dims, &fixed, &coarse).expect_err("beyond f32").to_string();
        assert!(e.contains("[2, 1, 0]") && e.contains("finite"), "{e}");
    }

    #[test]
    fn bad_archives_are_named() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("not.npz");
        std::fs::write(&path, b"PK\x03\x04 but nothing else").expect("write");
        let e = read_voxel_field(&path).expect_err("damaged").to_string();
        assert!(e.contains("not.npz") && e.contains("damaged"), "{e}");
        let big = VoxelField { dims: [1, 1, 1], steps_vox: vec![[70000.0, 0.0, 0.0]] };
        let e = write_voxel_field(&dir.path().join("big.npz"), &big).expect_err("beyond float16").to_string();
        assert!(e.contains("[0, 0, 0]") && e.contains("float16"), "{e}");
        assert!(!dir.path().join("big.npz").exists());
    }
}
