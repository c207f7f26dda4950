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

/// `--procedural` shows the moving volume deformed by `eval`'s synthetic warp: with V as both volumes, an axial slice
/// of the moving layer alone is V(d(x)) (d the solver's `SyntheticWarp` of the same kind, amplitude and seed over V's
/// box, sampled here by the test's own trilinear lookup): grey values correlate with it (NCC > 0.99) far better than
/// with the undeformed V(x). A zero amplitude changes nothing, and without `--moving` it is refused.
#[test]
fn procedural_shows_the_volume_eval_tests() {
    use warpbench_io::geometry::Point3;
    use warpbench_solver::spaces::{Aabb, Moving};
    use warpbench_solver::synthetic::{SyntheticKind, SyntheticWarp};
    use warpbench_solver::warp::Warp;

    let dir = tempfile::tempdir().expect("tempdir");
    let fixed = fixture();
    let f = fixed.to_str().expect("utf8");
    let render = |name: &str, extra: &[&str]| {
        let out = dir.path().join(name);
        let mut args = vec!["render", "--fixed", f, "--moving", f, "--slice", "axial", "--blend", "moving-only"];
        args.extend(["--moving-preset", "grey-ramp", "--quiet", "--out", out.to_str().expect("utf8")]);
        args.extend(extra);
        (warpbench(&args), out)
    };
    let (out, plain) = render("plain.png", &[]);
    if common::failed_for_want_of_a_gpu(&out) {
        return;
    }
    assert_ok(&out);
    let (out, zero) = render("zero.png", &["--procedural", "bend", "--procedural-amplitude-mm", "0"]);
    assert_ok(&out);
    assert!(read_png(&plain) == read_png(&zero), "a zero-amplitude bend changed the slice");
    let (out, sine) =
        render("sine.png", &["--procedural", "sine", "--procedural-amplitude-mm", "8", "--procedural-seed", "3"]);
    assert_ok(&out);
    let img = read_png(&sine);

    let volume = warpbench_io::open(&fixed).expect("fixture");
    let values = volume.data.to_f32();
    let [nx, ny, nz] = volume.dims;
    let index_from_lps = volume.lps_from_index.inverse().expect("invertible");
    let value_at = |p: [f64; 3]| -> f64 {
        let c = index_from_lps.apply_point(Point3::from_array(p)).coords();
        let dims = [nx, ny, nz];
        let c: [f64; 3] = std::array::from_fn(|a| c[a].clamp(0.0, dims[a] as f64 - 1.0));
        let i0: [usize; 3] = std::array::from_fn(|a| (c[a].floor() as usize).min(dims[a] - 1));
        let mut sum = 0.0;
        for corner in 0..8 {
            let mut w = 1.0;
            let mut idx = [0; 3];
            for a in 0..3 {
                let up = corner >> a & 1 == 1;
                let t = c[a] - i0[a] as f64;
                idx[a] = if up { (i0[a] + 1).min(dims[a] - 1) } else { i0[a] };
                w *= if up { t } else { 1.0 - t };
            }
            sum += w * f64::from(values[idx[0] + nx * (idx[1] + ny * idx[2])]);
        }
        sum
    };
    let corners = [[-0.5, -0.5, -0.5], [nx as f64 - 0.5, ny as f64 - 0.5, nz as f64 - 0.5]]
        .map(|c| volume.lps_from_index.apply_point(Point3::from_array(c)).coords());
    let lo: [f64; 3] = std::array::from_fn(|a| corners[0][a].min(corners[1][a]));
    let hi: [f64; 3] = std::array::from_fn(|a| corners[0][a].max(corners[1][a]));
    let domain: Aabb<Moving> = Aabb::new(Point3::from_array(lo), Point3::from_array(hi));
    let d = SyntheticWarp::new(SyntheticKind::Sine, domain, 8.0, 3).expect("eval's warp");
    // The axial slice through the centre: pixel (i, j) is voxel (i, j, nz / 2).
    assert_eq!(img.dimensions(), (nx as u32, ny as u32));
    let (mut grey, mut deformed, mut undeformed) = (Vec::new(), Vec::new(), Vec::new());
    for j in 0..ny {
        for i in 0..nx {
            let x = volume.voxel_lps(i, j, nz / 2).coords();
            grey.push(f64::from(img.get_pixel(i as u32, j as u32)[0]));
            deformed.push(value_at(d.apply_raw(x)));
            undeformed.push(value_at(x));
        }
    }
    let ncc = |a: &[f64], b: &[f64]| {
        let (ma, mb) = (a.iter().sum::<f64>() / a.len() as f64, b.iter().sum::<f64>() / b.len() as f64);
        let cov: f64 = a.iter().zip(b).map(|(x, y)| (x - ma) * (y - mb)).sum();
        let va: f64 = a.iter().map(|x| (x - ma).powi(2)).sum();
        let vb: f64 = b.iter().map(|y| (y - mb).powi(2)).sum();
        cov / (va * vb).sqrt()
    };
    let (with_d, without) = (ncc(&grey, &deformed), ncc(&grey, &undeformed));
    eprintln!("NCC of the slice with V∘d {with_d:.4}, with V {without:.4}");
    assert!(with_d > 0.99 && with_d > without + 0.05, "NCC with V∘d {with_d}, with V {without}");

    let out = warpbench(&["render", "--fixed", f, "--procedural", "twist", "--quiet", "--out", "/nonexistent/x.png"]);
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("--procedural deforms the moving volume"));
}
