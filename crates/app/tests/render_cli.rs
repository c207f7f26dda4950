//! `warpbench render` end to end: the binary on a real MRI fixture (`avg152T1_LR_nifti.nii`, 91×109×91, 2 mm),
//! alone and as a pair with landmarks, in 3-D and as a slice, and its refusals.
//!
//! Without a GPU adapter the render tests skip, unless REQUIRE_GPU_ADAPTER=1 (CI), where they fail.

mod common;

use std::path::Path;

use common::{assert_ok, deformed_pairs as write_pairs, mri as fixture, warpbench};

fn read_png(path: &Path) -> image::RgbaImage {
    image::open(path).expect("a PNG").to_rgba8()
}

/// Pixels close to `rgb` (each channel within 40).
fn count_colour(img: &image::RgbaImage, rgb: [u8; 3]) -> usize {
    img.pixels().filter(|p| (0..3).all(|c| p[c].abs_diff(rgb[c]) <= 40)).count()
}

const ORANGE: [u8; 3] = [255, 140, 0];
const BLUE: [u8; 3] = [38, 140, 255];

#[test]
fn renders_a_volume_alone_and_a_pair_with_glyphs() {
    let dir = tempfile::tempdir().expect("tempdir");
    let fixed = fixture();
    let alone = dir.path().join("alone.png");
    let out = warpbench(
        &["render", "--fixed", fixed.to_str().expect("utf8"), "--size", "96x80", "--quiet", "--out"]
            .into_iter()
            .chain([alone.to_str().expect("utf8")])
            .collect::<Vec<_>>(),
    );
    if common::failed_for_want_of_a_gpu(&out) {
        return;
    }
    assert_ok(&out);
    let img = read_png(&alone);
    assert_eq!(img.dimensions(), (96, 80));
    let lit = img.pixels().filter(|p| p[0] > 20 || p[1] > 20 || p[2] > 20).count();
    assert!(lit > 96 * 80 / 5, "the brain covers only {lit} pixels");
    assert_eq!(count_colour(&img, ORANGE) + count_colour(&img, BLUE), 0, "glyph colours without landmarks");

    let pairs = write_pairs(dir.path(), false);
    let pair_png = dir.path().join("pair.png");
    let f = fixed.to_str().expect("utf8");
    let args = |out: &Path, extra: &[&str]| {
        let mut v = vec!["render", "--fixed", f, "--moving", f, "--landmarks"];
        v.push(pairs.to_str().expect("utf8"));
        v.extend(["--size", "128x128", "--blend", "checkerboard", "--camera", "20,10", "--quiet", "--out"]);
        v.push(out.to_str().expect("utf8"));
        v.extend(extra);
        v.into_iter().map(str::to_owned).collect::<Vec<_>>()
    };
    let run = |a: Vec<String>| warpbench(&a.iter().map(String::as_str).collect::<Vec<_>>());
    assert_ok(&run(args(&pair_png, &["--shading", "iso"])));
    let img = read_png(&pair_png);
    let bare_png = dir.path().join("bare.png");
    assert_ok(&run(args(&bare_png, &["--shading", "iso", "--no-glyphs"])));
    let bare = read_png(&bare_png);
    // The landmarks lie inside the head, behind the iso-surface: their glyphs are ghosts, so the frames differ a
    // little, only around the glyphs.
    let differing = img.pixels().zip(bare.pixels()).filter(|(a, b)| a != b).count();
    assert!(differing > 50 && differing < 128 * 128 / 4, "{differing} pixels differ between glyphs and none");

    // A slice has its grid's size (axial through the fixed grid: 91 × 109), and five of the seven fixed points lie
    // on S = 18 mm: drawn in full, the fixed glyph over the moving one, which the warp puts at d(pᵢ) = qᵢ (TPS
    // interpolates), so no orange shows.
    let slice_png = dir.path().join("slice.png");
    assert_ok(&run(args(&slice_png, &["--slice", "axial:18"])));
    let slice = read_png(&slice_png);
    assert_eq!(slice.dimensions(), (91, 109));
    let (blue, orange) = (count_colour(&slice, BLUE), count_colour(&slice, ORANGE));
    assert!(blue >= 5 * 20 && orange == 0, "glyphs on the slice: {blue} blue and {orange} orange pixels");
    let bare_slice_png = dir.path().join("bare_slice.png");
    assert_ok(&run(args(&bare_slice_png, &["--slice", "axial:18", "--no-glyphs"])));
    assert_eq!(count_colour(&read_png(&bare_slice_png), BLUE), 0, "--no-glyphs drew glyphs");
}

#[test]
fn refuses_bad_landmarks_and_unsafe_outputs() {
    let dir = tempfile::tempdir().expect("tempdir");
    let fixed = fixture();
    let f = fixed.to_str().expect("utf8");
    let outside = write_pairs(dir.path(), true);
    let out_png = dir.path().join("x.png");
    let o = out_png.to_str().expect("utf8");
    let expect_bad = |args: &[&str], needle: &str| {
        let out = warpbench(args);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {stderr}");
        assert!(stderr.contains(needle), "{args:?}: {stderr:?} lacks {needle:?}");
        assert!(!out_png.exists() || needle.contains("exists"), "a refused run wrote {o}");
    };
    let l = outside.to_str().expect("utf8");
    expect_bad(
        &["render", "--fixed", f, "--moving", f, "--landmarks", l, "--quiet", "--out", o],
        "landmark 3 (Pt-2) is outside the moving volume",
    );
    expect_bad(&["render", "--fixed", f, "--quiet", "--out", f], "refusing to overwrite an input");
    expect_bad(
        &["render", "--fixed", f, "--blend", "sideways", "--moving", f, "--quiet", "--out", o],
        "invalid value 'sideways' for '--blend <BLEND>'",
    );
    expect_bad(&["render", "--fixed", f, "--landmarks", l, "--quiet", "--out", o], "landmarks need a moving volume");
    std::fs::write(&out_png, b"keep me").expect("write");
    expect_bad(&["render", "--fixed", f, "--quiet", "--out", o], "exists; use --force");
    assert_eq!(std::fs::read(&out_png).expect("read"), b"keep me", "an existing output was changed");
}
