//! FreeSurfer's LTA against FreeSurfer's own files and nitransforms 25.1.0 (`data-scripts/lta_nitransforms.py`):
//! files bbregister, mri_robust_register and lta_convert wrote, read between volumes on their src and dst grids to
//! the pull-back nitransforms reads; a voxel-to-voxel file to the RAS file lta_convert made of it; the ITK `.tfm` of
//! the same transform to the same map; the direction told by the volumes; the writer's file read back; and text that
//! is not an LTA refused, naming the file and the line.

use std::path::{Path, PathBuf};

use nalgebra::Matrix4;
use warpbench_io::lta::{self, Lta, VolumeInfo};

fn dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/lta")
}

fn matrix(v: &serde_json::Value) -> Matrix4<f64> {
    Matrix4::from_fn(|r, c| v[r][c].as_f64().expect("a number"))
}

/// RAS ↔ LPS.
fn flip() -> Matrix4<f64> {
    Matrix4::from_diagonal(&nalgebra::Vector4::new(-1.0, -1.0, 1.0, 1.0))
}

/// The largest difference between `a` and `b`, each element against max(1, |b|): FreeSurfer writes and nitransforms
/// reads the matrix in single precision (6e-8 of each number), and lta_convert computes in it.
fn relative(a: &Matrix4<f64>, b: &Matrix4<f64>) -> f64 {
    a.iter().zip(b.iter()).map(|(x, y)| (x - y).abs() / y.abs().max(1.0)).fold(0.0, f64::max)
}

fn read(name: &str) -> (PathBuf, Lta) {
    let path = dir().join(name);
    let head = std::fs::read(&path).expect("the file");
    assert!(lta::looks_like_lta(&head), "{name}");
    let lta = lta::read(&path).expect("reads");
    (path, lta)
}

/// The pull-back between volumes on the LTA's own dst (fixed) and src (moving) grids.
fn pullback(path: &Path, lta: &Lta) -> Matrix4<f64> {
    let fixed = lta.dst.as_ref().expect("a dst").lps_from_index();
    let moving = lta.src.as_ref().expect("a src").lps_from_index();
    let (f, m) = (lta.dst.as_ref().expect("dst").dims, lta.src.as_ref().expect("src").dims);
    lta::moving_from_fixed(path, lta, (f, &fixed), (m, &moving)).expect("the pull-back")
}

#[test]
fn every_lta_reads_as_nitransforms_reads_it() {
    let text = std::fs::read_to_string(dir().join("reference.json")).expect("the reference");
    let reference: serde_json::Value = serde_json::from_str(&text).expect("JSON");
    let cases = reference["ltas"].as_object().expect("the files");
    assert_eq!(cases.len(), 11);
    for (name, case) in cases {
        let (path, lta) = read(name);
        let code = case["type"].as_i64().expect("a type");
        assert_eq!(i64::from(lta.kind.code_and_name().0), code, "{name}");
        for (side, info) in [("src", &lta.src), ("dst", &lta.dst)] {
            let want = matrix(&case["ras_from_index"][side]);
            let got = info.as_ref().expect("valid").ras_from_index();
            assert!(relative(&got, &want) < 1e-6, "{name} {side}: {got} against nitransforms' {want}");
        }
        let u = pullback(&path, &lta);
        let want = flip() * matrix(&case["ras_moving_from_fixed"]) * flip();
        assert!(relative(&u, &want) < 1e-5, "{name}: {u} against nitransforms' {want}");
    }
}

/// lta_convert's RAS file of a voxel-to-voxel one (FreeSurfer's own conversion) is what the geometries make of it.
#[test]
fn a_voxel_to_voxel_lta_is_the_ras_one_lta_convert_made_of_it() {
    for (v2v, ras) in [
        ("bold-to-t1w.v2v.lta", "bold-to-t1w.lta"),
        (
            "regressions_from-fsnative_to-bold_mode-image.lta",
            "regressions_from-fsnative_to-bold_mode-image_type-ras2ras.lta",
        ),
        (
            "regressions_from-scanner_to-bold_mode-image.lta",
            "regressions_from-scanner_to-bold_mode-image_type-ras2ras.lta",
        ),
    ] {
        let (path, voxels) = read(v2v);
        let (_, made) = read(ras);
        assert_eq!(voxels.kind, lta::LtaType::VoxToVox);
        assert_eq!(made.kind, lta::LtaType::RasToRas);
        let got = voxels.dst_from_src_ras(&path).expect("RAS");
        assert!(relative(&got, &made.matrix) < 2e-5, "{v2v}: {got} against lta_convert's {}", made.matrix);
    }
}

/// The ITK `.tfm` beside each of FreeSurfer's files, the same transform, maps as the LTA does.
#[test]
fn the_itk_file_of_the_same_transform_maps_as_the_lta() {
    for name in [
        "regressions_from-fsnative_to-bold_mode-image",
        "regressions_from-scanner_to-bold_mode-image",
        "regressions_from-fsnative_to-scanner_mode-image",
        "regressions_from-scanner_to-fsnative_mode-image",
    ] {
        let (path, lta) = read(&format!("{name}.lta"));
        let u = pullback(&path, &lta);
        let chain = warpbench_io::transform_file::read_chain(&dir().join(format!("{name}.tfm"))).expect("the .tfm");
        let affine = chain.affine().expect("an affine");
        let mut itk = Matrix4::identity();
        itk.fixed_view_mut::<3, 3>(0, 0).copy_from(&affine.matrix);
        itk.fixed_view_mut::<3, 1>(0, 3).copy_from(&nalgebra::Vector3::from(affine.offset()));
        assert!(relative(&u, &itk) < 2e-5, "{name}: {u} against the .tfm's {itk}");
    }
}

/// The volumes tell the direction: the other way round the pull-back is the inverse; volumes that are neither the
/// src nor the dst, and a file without volume info, are refused with what to do.
#[test]
fn the_direction_follows_the_volumes() {
    let (path, lta) = read("bold-to-t1w.lta");
    let (src, dst) = (lta.src.clone().expect("src"), lta.dst.clone().expect("dst"));
    let (s, d) = (src.lps_from_index(), dst.lps_from_index());
    let u = lta::moving_from_fixed(&path, &lta, (dst.dims, &d), (src.dims, &s)).expect("forward");
    let back = lta::moving_from_fixed(&path, &lta, (src.dims, &s), (dst.dims, &d)).expect("backward");
    assert!((u * back - Matrix4::identity()).abs().max() < 1e-12);
    // One of the two is enough: the bold run as moving against another fixed grid.
    let other = warpbench_io::geometry::Transform::from_scale_translation([1.0, 1.0, 1.0], [5.0, 0.0, 0.0]);
    let one = lta::moving_from_fixed(&path, &lta, ([10, 10, 10], &other), (src.dims, &s)).expect("src is moving");
    assert!((one - u).abs().max() < 1e-12);
    let err = lta::moving_from_fixed(&path, &lta, ([10, 10, 10], &other), ([10, 10, 10], &other)).expect_err("refused");
    let message = err.to_string();
    assert!(message.contains("bold-to-t1w.lta"), "{message}");
    assert!(message.contains("neither volume") && message.contains("uni_xform_masked.nii.gz"), "{message}");
    assert!(message.contains("lta_convert"), "{message}");
    // A file without volume info: no direction.
    let text = std::fs::read_to_string(&path).expect("text").replace("valid = 1", "valid = 0");
    let bare = lta::parse(&path, &text).expect("parses");
    assert_eq!((bare.src.is_none(), bare.dst.is_none()), (true, true));
    let err = lta::moving_from_fixed(&path, &bare, (dst.dims, &d), (src.dims, &s)).expect_err("refused");
    assert!(err.to_string().contains("not stated"), "{err}");
}

/// What the writer writes reads back to the pull-back, with the moving volume as src and the fixed one as dst.
#[test]
fn a_written_lta_reads_back() {
    let fixed = warpbench_io::geometry::Transform::from_linear_translation(
        nalgebra::Rotation3::from_euler_angles(0.1, -0.2, 0.3).into_inner()
            * nalgebra::Matrix3::from_diagonal_element(1.2),
        [-30.0, 20.0, 10.0],
    );
    let moving = warpbench_io::geometry::Transform::from_scale_translation([1.5, -1.0, 1.1], [40.0, -25.0, -15.0]);
    let u = Matrix4::new(0.98, 0.05, -0.02, 3.0, -0.04, 1.01, 0.03, -7.5, 0.01, -0.02, 0.99, 12.25, 0.0, 0.0, 0.0, 1.0);
    let out = tempfile::tempdir().expect("temp dir");
    let path = out.path().join("mr_to_ct.lta");
    lta::write(&path, &u, (([4, 5, 3], &fixed), "/data/ct.nii.gz"), (([6, 7, 8], &moving), "mr.mgz")).expect("writes");
    let text = std::fs::read_to_string(&path).expect("text");
    assert!(text.contains("type      = 1 # LINEAR_RAS_TO_RAS\nnxforms   = 1\n"), "{text}");
    let (path, read) = (path.clone(), lta::read(&path).expect("reads"));
    let src = read.src.clone().expect("src");
    assert!(src.matches(&VolumeInfo::of(([6, 7, 8], &moving), "")));
    assert_eq!(
        (src.filename.as_str(), read.dst.clone().expect("dst").filename.as_str()),
        ("mr.mgz", "/data/ct.nii.gz")
    );
    let back = lta::moving_from_fixed(&path, &read, ([4, 5, 3], &fixed), ([6, 7, 8], &moving)).expect("pull-back");
    assert!((back - u).abs().max() < 1e-12, "{back} against {u}");
    let err = lta::write(&path, &Matrix4::zeros(), (([4, 5, 3], &fixed), ""), (([6, 7, 8], &moving), ""))
        .expect_err("refused");
    assert!(err.to_string().contains("cannot be inverted"), "{err}");
}

#[test]
fn text_that_is_not_an_lta_is_refused_by_line() {
    let good = std::fs::read_to_string(dir().join("bold-to-t1w.lta")).expect("text");
    let path = Path::new("reg.lta");
    let cases = [
        (good.replace("type      = 1", "type      = 14"), "line 4: type 14 (REGISTER_DAT"),
        (good.replace("nxforms   = 1", "nxforms   = 2"), "line 5: 2 transforms"),
        (good.replace("1 4 4", "1 3 3"), "line 8: a 3×3 matrix"),
        (good.replace("3.410797119140625e-01", "nan"), "line 9: \"nan\" is not a finite number"),
        (good.replace("1.000000000000000e+00 \n", "2.0 \n"), "last row is not 0 0 0 1"),
        (good.replace("cras   = -4.697326660156250e+00", "cres   = 0"), "a valid volume info without its `cras` line"),
        (good.replace("src volume info", "label = 3\nwhat\nsrc volume info"), "line 14: \"what\" is not a line"),
        (good.replace("volume = 64 64 34", "volume = 64 64 0"), "not three counts of voxels"),
        (good.replace("voxelsize = 3.0", "voxelsize = -3.0"), "not positive"),
        (String::new(), "the file ends before its `type` line"),
        ("hello\n".to_owned(), "line 1: not `type = …`"),
        (good.lines().take(10).collect::<Vec<_>>().join("\n"), "the file ends before the matrix's four rows"),
    ];
    for (text, want) in cases {
        let err = lta::parse(path, &text).expect_err("refused").to_string();
        assert!(err.contains("reg.lta") && err.contains(want), "{want:?}: {err}");
    }
    assert!(!lta::looks_like_lta(b"#Insight Transform File V1.0\n"));
    assert!(!lta::looks_like_lta(b"1 0 0 0\n0 1 0 0\n"));
    assert!(lta::looks_like_lta(b"# comment\n\ntype = 1\n"));
}
