//! Learn2Reg's displacement fields, against files NumPy and nibabel wrote (`data-scripts/learn2reg_numpy.py`): `.npz`
//! float16 deflated as the challenge's submissions were until 2021, float32 stored in Fortran order, one big-endian
//! float64 array under another name; the NIfTI form since 2022 with an image's affine, the identity or none. The
//! script's JSON holds what `numpy.load` and nibabel's `get_fdata` return. The 2021 layout, an archive of two arrays
//! and NIfTI files of other shapes are refused naming the file; a field warpbench writes is what NumPy's and
//! nibabel's layouts say.

use std::path::{Path, PathBuf};

use serde_json::Value;
use warpbench_io::learn2reg::{self, VoxelField};

fn dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/learn2reg")
}

/// NumPy's array, as `[i][j][k][c]`.
type Array4 = Vec<Vec<Vec<Vec<f64>>>>;

fn reference() -> (Vec<usize>, Array4) {
    let text = std::fs::read_to_string(dir().join("reference.json")).expect("reference");
    let v: Value = serde_json::from_str(&text).expect("JSON");
    let shape = v["shape"].as_array().expect("shape").iter().map(|d| d.as_u64().expect("dim") as usize).collect();
    (shape, serde_json::from_value(v["disp"].clone()).expect("disp"))
}

#[test]
fn numpy_files_read_as_numpy_reads_them() {
    let (shape, disp) = reference();
    let names = [
        "disp_f16.npz",
        "disp_f32_fortran.npz",
        "disp_f64_named.npz",
        "disp_nibabel_f32.nii.gz",
        "disp_nibabel_f64_eye.nii",
        "disp_nibabel_noaffine.nii.gz",
    ];
    for name in names {
        let f = learn2reg::read_voxel_field(&dir().join(name)).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(f.dims.to_vec(), shape[..3], "{name}");
        let [nx, ny, _] = f.dims;
        for (n, v) in f.steps_vox.iter().enumerate() {
            let (i, j, k) = (n % nx, (n / nx) % ny, n / (nx * ny));
            for c in 0..3 {
                // Every value is exact in float16, so every dtype reads it exactly.
                assert_eq!(f64::from(v[c]).to_bits(), disp[i][j][k][c].to_bits(), "{name} [{i}, {j}, {k}, {c}]");
            }
        }
    }
}

#[test]
fn the_2021_layout_and_ambiguous_archives_are_refused_by_name() {
    let e = learn2reg::read_voxel_field(&dir().join("disp_2021.npz")).expect_err("2021").to_string();
    assert!(e.contains("disp_2021.npz") && e.contains("(3, 5, 4, 2)") && e.contains("transpose"), "{e}");
    let e = learn2reg::read_voxel_field(&dir().join("two_arrays.npz")).expect_err("two").to_string();
    assert!(e.contains("two_arrays.npz") && e.contains("a, b") && e.contains("arr_0"), "{e}");
    let e = learn2reg::read_voxel_field(&dir().join("reference.json")).expect_err("not a zip").to_string();
    assert!(e.contains("reference.json") && e.contains(".npz") && e.contains("NIfTI"), "{e}");
}

/// A NIfTI file that is not an (X, Y, Z, 3) array is refused as Learn2Reg's field, naming the file: an ITK field in
/// mm (intent DISPVECT, dim [5, X, Y, Z, 1, 3]) as such, a volume by its dim. And the ITK field reader, given
/// Learn2Reg's form, says what it may be instead of reading it as mm.
#[test]
fn nifti_files_of_other_shapes_are_refused_and_the_form_is_named_to_the_field_reader() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let grid = warpbench_io::geometry::Transform::from_scale_translation([2.0; 3], [0.0; 3]);
    let itk = tmp.path().join("itk_field.nii.gz");
    warpbench_io::nifti::write_displacement_field(&itk, [2, 2, 2], &grid, &[[1.0, 0.0, 0.0]; 8]).expect("write");
    let e = learn2reg::read_voxel_field(&itk).expect_err("mm").to_string();
    assert!(e.contains("itk_field.nii.gz") && e.contains("intent_code 1006") && e.contains("in mm"), "{e}");
    let volume = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/nifti/avg152T1_LR_nifti.nii");
    let e = learn2reg::read_voxel_field(&volume).expect_err("a volume").to_string();
    assert!(e.contains("avg152T1_LR_nifti.nii") && e.contains("dim = [3, 91, 109, 91"), "{e}");
    let e = warpbench_io::displacement::read_field(&dir().join("disp_nibabel_f32.nii.gz")).expect_err("voxels");
    let e = e.to_string();
    assert!(e.contains("disp_nibabel_f32.nii.gz") && e.contains("Learn2Reg") && e.contains("learn2reg"), "{e}");
}

/// The NIfTI form warpbench writes is nibabel's layout of an (X, Y, Z, 3) float32 array (dim [4, X, Y, Z, 3], no
/// intent, the components as frames) with the fixed image's grid as its sform, and reads back exactly.
#[test]
fn a_written_nifti_field_is_an_x_y_z_3_array_with_the_fixed_grid() {
    let (_, disp) = reference();
    let dims = [5, 4, 2];
    let steps_vox: Vec<[f32; 3]> = (0..40)
        .map(|n| {
            let (i, j, k) = (n % 5, (n / 5) % 4, n / 20);
            [0, 1, 2].map(|c| disp[i][j][k][c] as f32 + 1e-3)
        })
        .collect();
    let field = VoxelField { dims, steps_vox };
    let fixed = warpbench_io::geometry::Transform::from_scale_translation([1.5, 2.0, 2.5], [-10.0, 20.0, 5.0]);
    let tmp = tempfile::tempdir().expect("tempdir");
    let path = tmp.path().join("disp_0001_0002.nii");
    learn2reg::write_voxel_field_nifti(&path, &field, &fixed).expect("write");
    // float32 keeps what float16 would round.
    assert_eq!(learn2reg::read_voxel_field(&path).expect("read back"), field);
    let raw = std::fs::read(&path).expect("read");
    let i16_at = |o: usize| i16::from_le_bytes([raw[o], raw[o + 1]]);
    let f32_at = |o: usize| f32::from_le_bytes([raw[o], raw[o + 1], raw[o + 2], raw[o + 3]]);
    assert_eq!((0..8).map(|i| i16_at(40 + 2 * i)).collect::<Vec<_>>(), [4, 5, 4, 2, 3, 1, 1, 1]);
    assert_eq!((i16_at(68), i16_at(70), i16_at(254)), (0, 16, 1), "no intent, float32, an sform");
    // The sform in RAS: x and y of LPS negated.
    let srow: Vec<f32> = (0..12).map(|i| f32_at(280 + 4 * i)).collect();
    assert_eq!(srow, [-1.5, 0.0, 0.0, 10.0, 0.0, -2.0, 0.0, -20.0, 0.0, 0.0, 2.5, 5.0]);
    // The second frame (y components) starts after the 40 x components, i fastest.
    assert_eq!(f32_at(352 + 4 * 40).to_bits(), field.steps_vox[0][1].to_bits());
    assert_eq!(f32_at(352 + 4 * 81).to_bits(), field.steps_vox[1][2].to_bits());
}

#[test]
fn a_written_field_is_float16_arr_0_in_c_order() {
    let (_, disp) = reference();
    let dims = [5, 4, 2];
    let steps_vox = (0..40)
        .map(|n| {
            let (i, j, k) = (n % 5, (n / 5) % 4, n / 20);
            [0, 1, 2].map(|c| disp[i][j][k][c] as f32)
        })
        .collect();
    let field = VoxelField { dims, steps_vox };
    let tmp = tempfile::tempdir().expect("tempdir");
    let path = tmp.path().join("disp_0001_0002.npz");
    learn2reg::write_voxel_field(&path, &field).expect("write");
    assert_eq!(learn2reg::read_voxel_field(&path).expect("read back"), field);
    // The archive stamps no time: the same field writes the same bytes (the window's export equals the CLI's).
    let again = tmp.path().join("again.npz");
    learn2reg::write_voxel_field(&again, &field).expect("write again");
    assert!(std::fs::read(&path).expect("first") == std::fs::read(&again).expect("second"));
    // The archive's one member and the .npy header NumPy writes for np.float16 of that shape, C order.
    let bytes = std::fs::read(&path).expect("read");
    let mut zip = zip::ZipArchive::new(std::io::Cursor::new(bytes)).expect("zip");
    assert_eq!(zip.len(), 1);
    let mut member = zip.by_name("arr_0.npy").expect("arr_0.npy");
    assert_eq!(member.compression(), zip::CompressionMethod::Deflated);
    let mut npy = Vec::new();
    std::io::Read::read_to_end(&mut member, &mut npy).expect("inflate");
    let header = String::from_utf8_lossy(&npy[10..npy.iter().position(|&b| b == b'\n').expect("header end")]);
    for part in ["'descr': '<f2'", "'fortran_order': False", "'shape': (5, 4, 2, 3"] {
        assert!(header.contains(part), "{header}");
    }
    // The tuple's form is npyz's (a trailing comma), which NumPy reads: the Python tests load such files.
    // C order: the last axis (the component) fastest, then k, j, i. The second value is d[0, 0, 0, 1].
    let second = half::f16::from_le_bytes([npy[npy.len() - 240 + 2], npy[npy.len() - 240 + 3]]);
    assert_eq!(f64::from(second.to_f32()).to_bits(), disp[0][0][0][1].to_bits());
}

/// A `.npy` whose preamble claims a header of 4 GB is refused before anything is allocated for it, as NumPy refuses
/// a header longer than 10 000 bytes (the fuzzer's finding: the claimed length was allocated at once).
#[test]
fn a_header_longer_than_numpy_reads_is_refused() {
    let mut npy = b"\x93NUMPY\x02\x00".to_vec();
    npy.extend_from_slice(&u32::MAX.to_le_bytes());
    npy.extend_from_slice(b"{'descr': '<f4', 'fortran_order': False, 'shape': (1, 1, 1, 3), }\n");
    let mut archive = zip::ZipWriter::new(std::io::Cursor::new(Vec::new()));
    archive.start_file("arr_0.npy", zip::write::SimpleFileOptions::default()).expect("entry");
    std::io::Write::write_all(&mut archive, &npy).expect("write");
    let bytes = archive.finish().expect("zip").into_inner();
    let e = learn2reg::read_voxel_field_bytes(Path::new("huge_header.npz"), &bytes).expect_err("refused").to_string();
    assert!(e.contains("huge_header.npz") && e.contains("4294967295 bytes") && e.contains("10000"), "{e}");
}
