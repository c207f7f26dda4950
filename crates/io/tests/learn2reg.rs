//! Learn2Reg's `.npz` displacement fields, against files NumPy wrote (`data-scripts/learn2reg_numpy.py`): float16
//! deflated as the challenge's submissions are, float32 stored in Fortran order, one big-endian float64 array under
//! another name. The script's JSON holds what `numpy.load` returns. The 2021 layout and an archive of two arrays are
//! refused naming the file; a field warpbench writes is what NumPy's layout says.

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
    for name in ["disp_f16.npz", "disp_f32_fortran.npz", "disp_f64_named.npz"] {
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
    assert!(e.contains("reference.json") && e.contains(".npz"), "{e}");
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
