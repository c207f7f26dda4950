//! NIfTI pairs (`.hdr` + `.img`) against nibabel 5.4.2 (`data-scripts/nifti_pair_nibabel.py`): NIfTI-1 and NIfTI-2,
//! either byte order, scaled samples, two frames and gzip-compressed files read by either name to nibabel's values and
//! affine; and what is not a pair warpbench reads refused, naming the file: an Analyze 7.5 header, a missing half, a
//! pair's header named `.nii`, a short `.img`.

use std::path::{Path, PathBuf};

use nalgebra::Matrix4;
use warpbench_io::{ErrorKind, LoadOptions, Volume, nifti};

fn dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/nifti_pair")
}

fn reference() -> serde_json::Value {
    let text = std::fs::read_to_string(dir().join("reference.json")).expect("the reference");
    serde_json::from_str(&text).expect("JSON")
}

fn open(path: &Path, frame: Option<usize>) -> Volume {
    crate::support::open_frame(path, frame).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// nibabel's RAS affine, in LPS.
fn lps(affine: &serde_json::Value) -> Matrix4<f64> {
    let ras = Matrix4::from_fn(|r, c| affine[r][c].as_f64().expect("a number"));
    Matrix4::from_diagonal(&nalgebra::Vector4::new(-1.0, -1.0, 1.0, 1.0)) * ras
}

#[test]
fn every_pair_reads_as_nibabel_reads_it_by_either_name() {
    let reference = reference();
    let pairs = reference["pairs"].as_object().expect("pairs");
    assert_eq!(pairs.len(), 4);
    for (name, case) in pairs {
        let shape: Vec<usize> =
            case["shape"].as_array().expect("shape").iter().map(|v| v.as_u64().expect("n") as usize).collect();
        let values: Vec<f64> =
            case["values"].as_array().expect("values").iter().map(|v| v.as_f64().expect("v")).collect();
        let frames = shape.get(3).copied().unwrap_or(1);
        let per_frame = shape[..3].iter().product::<usize>();
        for file in case["files"].as_array().expect("files") {
            let path = dir().join(file.as_str().expect("a name"));
            for frame in 0..frames {
                let volume = open(&path, (frames > 1).then_some(frame));
                assert_eq!(volume.dims.to_vec(), shape[..3].to_vec(), "{name}");
                // nibabel's affine from the same float32 (NIfTI-1) or float64 (NIfTI-2) sform.
                let got = volume.lps_from_index.matrix();
                let want = lps(&case["affine"]);
                assert!((got - want).abs().max() < 1e-9, "{name}: {got} against nibabel's {want}");
                let read = crate::support::samples_f64(&volume.data);
                let want = &values[frame * per_frame..(frame + 1) * per_frame];
                // Scaled samples become float32 here, unscaled ones keep their type: within float32 of nibabel's
                // float64 values.
                for (i, (a, b)) in read.iter().zip(want).enumerate() {
                    assert!((a - b).abs() <= 1e-6 * b.abs().max(1.0), "{name} frame {frame} voxel {i}: {a} vs {b}");
                }
            }
            if frames > 1 {
                let err = LoadOptions::new().open(&path).expect_err("a frame is needed");
                assert!(matches!(err.kind, ErrorKind::FrameRequired { frames: 2 }), "{err}");
            }
        }
    }
}

#[test]
fn a_half_missing_an_analyze_header_and_a_misnamed_header_are_refused() {
    let out = tempfile::tempdir().expect("temp dir");
    // The .img alone: its header is looked for, and named.
    let img = out.path().join("alone.img");
    std::fs::copy(dir().join("oblique_i16.img"), &img).expect("copy");
    let err = warpbench_io::open(&img).expect_err("no header");
    let message = err.to_string();
    assert!(message.contains("alone.img") && message.contains("header file is missing: alone.hdr"), "{message}");
    // Analyze 7.5: no NIfTI magic, no orientation.
    let err = warpbench_io::open(dir().join("analyze.hdr")).expect_err("Analyze");
    assert!(err.to_string().contains("analyze.hdr") && err.to_string().contains("Analyze 7.5"), "{err}");
    // A pair's header where one file is expected: said so.
    let nii = out.path().join("header_only.nii");
    std::fs::copy(dir().join("oblique_i16.hdr"), &nii).expect("copy");
    let err = warpbench_io::open(&nii).expect_err("a pair's header as .nii");
    assert!(err.to_string().contains("header_only.nii") && err.to_string().contains("NIfTI pair"), "{err}");
    // A short .img names the .img.
    let (hdr, short) = (out.path().join("short.hdr"), out.path().join("short.img"));
    std::fs::copy(dir().join("oblique_i16.hdr"), &hdr).expect("copy");
    std::fs::write(&short, [0u8; 50]).expect("write");
    let err = warpbench_io::open(&hdr).expect_err("short");
    assert!(matches!(err.kind, ErrorKind::Truncated(_)), "{err}");
    assert!(err.to_string().contains("short.img"), "{err}");
    // The name's case is kept: FOO.HDR finds FOO.IMG.
    let (upper_hdr, upper_img) = (out.path().join("UPPER.HDR"), out.path().join("UPPER.IMG"));
    std::fs::copy(dir().join("big_endian_u16.hdr"), &upper_hdr).expect("copy");
    std::fs::copy(dir().join("big_endian_u16.img"), &upper_img).expect("copy");
    let a = open(&upper_hdr, None);
    let b = open(&dir().join("big_endian_u16.img"), None);
    assert_eq!(a.data, b.data);
    assert_eq!(nifti::pair_paths(&upper_img).expect("found"), Some((upper_hdr, upper_img.clone())));
    assert_eq!(nifti::pair_paths(Path::new("x.nii")).expect("not a pair"), None);
}
