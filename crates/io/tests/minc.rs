//! MINC 1 and MINC 2 volumes against nibabel 5.4.2 and SimpleITK 2.5.7 (its libminc 2.4): the fixtures of
//! `tests/data/minc/` (nibabel's own test files, files SimpleITK wrote and edits of them, a MINC 1 file scipy wrote;
//! `data-scripts/minc_fixtures.py`) read to nibabel's affine and real values, and SimpleITK's grid covers the same
//! voxel centres; what we write reads back to the volume written; bad files are refused naming the file.

use std::path::{Path, PathBuf};

use nalgebra::Matrix3;
use serde_json::Value;
use sha2::{Digest, Sha256};
use warpbench_io::geometry::{Transform, ras_from_lps};
use warpbench_io::minc;
use warpbench_io::{ErrorKind, Format, GeometrySource, LoadOptions, SampleType, Volume, VolumeFileKind, VoxelData};

use crate::support::{numbers, open_frame as open, sample_volumes, samples_f64};

fn data_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/minc")
}

fn reference() -> Vec<Value> {
    let path = data_dir().join("reference.json");
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let v: Value = serde_json::from_str(&text).expect("JSON");
    v["files"].as_array().expect("files").clone()
}

/// The RAS position of each of the grid's 8 corner voxels, `ras_from_index` given as a function.
fn corners(dims: [usize; 3], ras_from_index: impl Fn([f64; 3]) -> [f64; 3]) -> Vec<[f64; 3]> {
    let mut out = Vec::new();
    for c in 0..8 {
        let ijk = std::array::from_fn(|a| if c >> a & 1 == 1 { (dims[a] - 1) as f64 } else { 0.0 });
        out.push(ras_from_index(ijk));
    }
    out
}

fn same_points(mut a: Vec<[f64; 3]>, mut b: Vec<[f64; 3]>, tol: f64) -> bool {
    let key = |p: &[f64; 3]| {
        (p[0] * 1e3).round() as i64 * 1_000_000_007 + (p[1] * 1e3).round() as i64 * 1_009 + (p[2] * 1e3).round() as i64
    };
    a.sort_by_key(key);
    b.sort_by_key(key);
    a.iter().zip(&b).all(|(p, q)| (0..3).all(|k| (p[k] - q[k]).abs() <= tol))
}

/// The volume's real values as little-endian f32, i fastest: what the reference hashes (nibabel's float64 values
/// rounded to float32, in C order of the file's spatial axes, the fastest last).
fn f32_sha256(data: &VoxelData) -> String {
    let mut hasher = Sha256::new();
    for x in samples_f64(data) {
        hasher.update((x as f32).to_le_bytes());
    }
    format!("{:x}", hasher.finalize())
}

/// nibabel builds the affine from the same doubles (cosines × step, Σ cosines × start), in another order of the sums.
const AFFINE_REL_TOL: f64 = 1e-12;

#[test]
fn every_fixture_reads_to_what_nibabel_read() {
    let files = reference();
    assert_eq!(files.len(), 20);
    for f in &files {
        let file = f["file"].as_str().expect("file");
        let path = data_dir().join(file);
        assert_eq!(Format::detect(&path).expect("detect"), Format::Minc, "{file}");
        let frames = f["frames"].as_u64().expect("frames") as usize;
        let frame_sums = numbers(&f["frame_sums"]);
        let shape: Vec<usize> = numbers(&f["frame_shape"]).into_iter().map(|x| x as usize).collect();
        let affine = f["affine"].as_array().expect("affine");
        let nib: Vec<Vec<f64>> = affine.iter().map(numbers).collect();
        assert_eq!(frame_sums.len(), frames, "{file}");
        for (frame, &want) in frame_sums.iter().enumerate() {
            let v = open(&path, (frames > 1).then_some(frame)).unwrap_or_else(|e| panic!("{e}"));
            assert_eq!(v.dims, [shape[2], shape[1], shape[0]], "{file}: i is the fastest file axis");
            assert_eq!(v.geometry_source, GeometrySource::Minc, "{file}");
            // nibabel's columns follow the file's spatial axes, slowest first: i is its third column.
            let ras = (ras_from_lps() * v.lps_from_index).rows();
            let scale = nib.iter().flatten().fold(1.0f64, |m, x| m.max(x.abs()));
            for r in 0..3 {
                for (axis, column) in [(0, 2), (1, 1), (2, 0), (3, 3)] {
                    let (got, want) = (ras[r][axis], nib[r][column]);
                    assert!((got - want).abs() <= AFFINE_REL_TOL * scale, "{file} [{r}][{axis}]: {got} vs {want}");
                }
            }
            let values = samples_f64(&v.data);
            let sum: f64 = values.iter().sum();
            // Ours are the f32 (or integer) samples of nibabel's doubles: each within half an f32 ulp of them.
            let largest = values.iter().fold(1.0f64, |m, x| m.max(x.abs()));
            let tol = values.len() as f64 * largest * f64::from(f32::EPSILON);
            assert!((sum - want).abs() <= tol, "{file} frame {frame}: sum {sum} vs {want}");
            if frame == 0 {
                assert_eq!(f32_sha256(&v.data), f["f32_sha256"].as_str().expect("sha"), "{file}: the real values");
                let first = numbers(&f["first"]);
                for (k, (&got, &want)) in values.iter().zip(&first).enumerate() {
                    assert_eq!((got as f32).to_bits(), (want as f32).to_bits(), "{file} value {k}");
                }
            }
            if let Some(s) = f["simpleitk"].as_object() {
                // libminc's grid (its numbers are MINC's RAS ones: ITK reads them unconverted) may order and flip
                // the axes otherwise, but covers the same voxel centres.
                let size: Vec<usize> = numbers(&s["size"]).into_iter().map(|x| x as usize).collect();
                let (origin, spacing, direction) =
                    (numbers(&s["origin"]), numbers(&s["spacing"]), numbers(&s["direction"]));
                let theirs = corners([size[0], size[1], size[2]], |ijk| {
                    std::array::from_fn(|r| {
                        origin[r] + (0..3).map(|c| direction[3 * r + c] * spacing[c] * ijk[c]).sum::<f64>()
                    })
                });
                let ours = corners(v.dims, |ijk| {
                    std::array::from_fn(|r| ras[r][3] + (0..3).map(|c| ras[r][c] * ijk[c]).sum::<f64>())
                });
                let tol = 1e-9 * scale;
                let same_order =
                    size == v.dims && ours.iter().zip(&theirs).all(|(p, q)| (0..3).all(|k| (p[k] - q[k]).abs() <= tol));
                assert!(same_points(ours, theirs, tol), "{file}: SimpleITK's grid");
                // Where libminc keeps the file's axes as they are, its voxels are ours one for one.
                if same_order && frame == 0 {
                    assert_eq!(f32_sha256(&v.data), s["f32_sha256"].as_str().expect("sha"), "{file}: SimpleITK");
                }
            }
        }
    }
}

#[test]
fn geometry_defaults_and_odd_attributes_are_warned_about() {
    let v = warpbench_io::open(data_dir().join("minc2-no-att.mnc")).expect("open");
    let w = v.metadata.warnings.join("\n");
    assert!(w.contains("MINC's defaults") && w.contains("xspace") && w.contains("start"), "{w}");
    let v = warpbench_io::open(data_dir().join("minc2_baddim.mnc")).expect("open");
    let w = v.metadata.warnings.join("\n");
    assert!(w.contains(r#"xspace's spacing says "xspace""#), "{w}");
    // Per-slice scaling is applied slice by slice and said so; SimpleITK's own files map each value to itself.
    let v = warpbench_io::open(data_dir().join("slice_scaled_i16.mnc")).expect("open");
    assert!(v.rescale.applied && v.sample_type() == SampleType::F32, "{:?}", v.rescale);
    assert!(v.metadata.warnings.join("\n").contains("differ between slices"), "{:?}", v.metadata.warnings);
    for (file, t) in
        [("oblique_u8", SampleType::U8), ("oblique_i16", SampleType::I16), ("oblique_u16", SampleType::U16)]
    {
        let v = warpbench_io::open(data_dir().join(format!("{file}.mnc"))).expect("open");
        assert_eq!(v.sample_type(), t, "{file}: kept in its type");
        assert!(v.rescale.is_identity() && v.metadata.warnings.is_empty(), "{file}: {:?}", v.metadata.warnings);
    }
}

#[test]
fn gzip_and_bytes_in_memory_read_as_the_file() {
    let plain = warpbench_io::open(data_dir().join("oblique_minc1_i16.mnc")).expect("plain");
    let gzip = warpbench_io::open(data_dir().join("oblique_minc1_i16.mnc.gz")).expect("gzip");
    assert_eq!(plain, gzip);
    for file in ["oblique_minc1_i16.mnc.gz", "small.mnc", "minc2_1_scale.mnc"] {
        let bytes = std::fs::read(data_dir().join(file)).expect("read");
        let v = minc::read_bytes(Path::new(file), bytes, &mut LoadOptions::new()).expect(file);
        assert_eq!(v, warpbench_io::open(data_dir().join(file)).expect(file), "{file}");
    }
}

#[test]
fn a_file_of_several_frames_needs_a_frame_in_range() {
    for (file, frames) in [("minc2_4d.mnc", 2), ("minc1_4d.mnc", 2), ("minc2-4d-d.mnc", 5)] {
        let path = data_dir().join(file);
        let e = warpbench_io::open(&path).expect_err("frames");
        assert!(matches!(e.kind, ErrorKind::FrameRequired { frames: n } if n == frames), "{e}");
        assert!(e.to_string().starts_with(&path.display().to_string()), "{e}");
        let e = open(&path, Some(frames)).expect_err("out of range");
        assert!(e.to_string().contains(&format!("frame {frames} is out of range")), "{e}");
    }
}

fn assert_close(got: [[f64; 4]; 4], want: [[f64; 4]; 4], what: &str) {
    let scale = want.iter().flatten().fold(1.0f64, |m, x| m.max(x.abs()));
    for r in 0..4 {
        for c in 0..4 {
            assert!((got[r][c] - want[r][c]).abs() <= 1e-12 * scale, "{what} [{r}][{c}]: {got:?} vs {want:?}");
        }
    }
}

#[test]
fn what_we_write_reads_back_to_the_volume_written() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut volumes = sample_volumes();
    // LIA, FreeSurfer's conformed orientation: j runs along z and k along y, so the axes are named so.
    let lia = Transform::from_linear_translation(
        Matrix3::new(1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, -1.0, 0.0),
        [3.0, -2.0, 5.0],
    );
    volumes.push(
        Volume::new(Path::new("x"), [3, 4, 2], VoxelData::U8((0..24).collect()), lia, GeometrySource::Assumed)
            .expect("lia"),
    );
    for file in ["small.mnc", "oblique_f64.mnc", "negative_step_i16.mnc", "permuted_u8.mnc"] {
        volumes.push(warpbench_io::open(data_dir().join(file)).expect(file));
    }
    for (k, v) in volumes.iter().enumerate() {
        let t = v.sample_type().name();
        let path = dir.path().join(format!("out_{k}_{t}.MNC"));
        assert_eq!(VolumeFileKind::of(&path), Some(VolumeFileKind::Minc));
        warpbench_io::write_volume(&path, v).unwrap_or_else(|e| panic!("{e}"));
        let bytes = std::fs::read(&path).expect("read");
        assert_eq!(&bytes[..8], b"\x89HDF\r\n\x1a\n");
        assert_eq!(bytes[8], 2, "superblock 2 (HDF5 1.8), which libminc opens");
        assert_eq!(bytes, minc::to_bytes(&path, v).expect("to_bytes"));
        let back = warpbench_io::open(&path).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(back.dims, v.dims, "{k} {t}");
        assert_eq!(back.data, v.data, "{k} {t}: the sample type and the samples are kept");
        assert!(back.rescale.is_identity(), "{k}: {:?}", back.rescale);
        assert!(back.metadata.warnings.is_empty(), "{k}: {:?}", back.metadata.warnings);
        assert_eq!(back.geometry_source, GeometrySource::Minc);
        assert_close(back.lps_from_index.rows(), v.lps_from_index.rows(), &format!("{k} {t}"));
    }
    // A gzip-compressed name is not one the writer takes: MINC 2 compresses inside the file.
    assert_eq!(VolumeFileKind::of(Path::new("x.mnc.gz")), None);
}

/// `bytes` with the first `from` replaced by `to` (same length).
fn patched(bytes: &[u8], from: &[u8], to: &[u8]) -> Vec<u8> {
    assert_eq!(from.len(), to.len());
    let at = bytes.windows(from.len()).position(|w| w == from).unwrap_or_else(|| panic!("{from:?} not found"));
    let mut out = bytes.to_vec();
    out[at..at + to.len()].copy_from_slice(to);
    out
}

#[test]
fn bad_files_are_refused_naming_the_file_and_the_problem() {
    let dir = tempfile::tempdir().expect("tempdir");
    let minc1 = std::fs::read(data_dir().join("oblique_minc1_i16.mnc")).expect("minc1");
    let minc2 = std::fs::read(data_dir().join("oblique_i16.mnc")).expect("minc2");
    let gz = std::fs::read(data_dir().join("oblique_minc1_i16.mnc.gz")).expect("gz");
    let h5 = std::fs::read(Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/itk/h5_affine.h5"));
    let cases: Vec<(&str, Vec<u8>, &str)> = vec![
        ("empty.mnc", Vec::new(), "neither a MINC 1"),
        ("text.mnc", b"not a volume at all\n".to_vec(), "neither a MINC 1"),
        ("short1.mnc", minc1[..200].to_vec(), "not a readable netCDF file"),
        ("short2.mnc", minc2[..300].to_vec(), "truncated or corrupt"),
        ("short.mnc.gz", gz[..gz.len() / 2].to_vec(), "gzip"),
        ("noimage.mnc", patched(&minc1, b"image\0\0\0", b"imagx\0\0\0"), "without the variable image"),
        ("onerange.mnc", patched(&minc1, b"image-max", b"image-mxx"), "without the other"),
        ("sign.mnc", patched(&minc1, b"signed__", b"signed_x"), "signtype"),
        ("itk.mnc", h5.expect("itk h5"), "/minc-2.0/image/0/image"),
        (
            "huge_chunk.mnc",
            std::fs::read(Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/bad/huge_chunk.mnc"))
                .expect("bad"),
            "past the end of the file",
        ),
    ];
    for (name, bytes, says) in cases {
        let path = dir.path().join(name);
        std::fs::write(&path, &bytes).expect("write");
        let e = warpbench_io::open(&path).expect_err(name);
        let text = e.to_string();
        assert!(text.starts_with(&path.display().to_string()), "{name}: {text}");
        assert!(text.contains(says), "{name}: {text}");
    }
}
