//! `warpbench register` end to end (issue 31, item 2): on the MRI fixture pulled back through a known smooth warp,
//! with its intensities remapped as a second modality's, under 6 pairs of the truth. The field it writes is closer
//! to the truth than the TPS through the pairs, keeps the pairs, does not fold, and is what `warpbench warp --field`
//! applies to the same bytes; bad input exits 2, names the file and writes nothing.

mod common;
#[path = "common/register_case.rs"]
mod register_case;

use common::{assert_ok, mri, utf8, warpbench, write_pairs_csv};
use register_case::{case, head_points, truth};
use std::path::Path;
use std::process::Output;

use serde_json::Value;
use warpbench_io::displacement::read_field_info;
use warpbench_io::geometry::{Index, Lps, Point3, Transform};
use warpbench_solver::field::SampledField;
use warpbench_solver::spaces::{Fixed, Moving};
use warpbench_solver::tps::Tps;
use warpbench_solver::warp::Warp;

/// `warpbench register` of the case with the landmarks into `field`, on 2 levels down to 20 mm, with `extra` flags and
/// `--json`.
fn register(fixed: &Path, moving: &Path, pairs: &Path, field: &Path, extra: &[&str]) -> Output {
    let mut args = vec!["register", "--fixed", utf8(fixed), "--moving", utf8(moving), "--landmarks", utf8(pairs)];
    args.extend(["--out-field", utf8(field), "--grid-mm", "20", "--levels", "2", "--json"]);
    args.extend_from_slice(extra);
    warpbench(&args)
}

/// Fewer samples and iterations than the defaults, for the runs whose laws do not hang on how far the optimiser goes
/// (where the samples are read, repeatability, masks). On lavapipe, CI's GPU, a pass over the samples costs about
/// 5 µs a sample, so a run at the defaults takes a minute there. The accuracy law still holds with these (measured
/// 2026-12-06: 0.50 mm for MI on the GPU, 0.70 mm for LNCC, against 0.40 mm at the defaults and 1.82 mm for the TPS).
const QUICK: [&str; 4] = ["--samples", "10000", "--iterations", "30"];

/// Fewer still, for the runs whose law is only which voxels are read (a mask's outside, a second run's bits): a few
/// steps read the same samples as many would, at a fraction of the time.
const TINY: [&str; 4] = ["--samples", "2000", "--iterations", "3"];

fn distance(a: [f64; 3], b: [f64; 3]) -> f64 {
    (0..3).map(|i| (a[i] - b[i]).powi(2)).sum::<f64>().sqrt()
}

/// The mean TRE over the head's points of the field in `field` and of the TPS through the pairs at `qs`, mm.
fn mean_tre(field: &Path, qs: &[[f64; 3]]) -> (f64, f64) {
    let read = read_field_info(field).expect("read the field");
    let u = SampledField::<Moving, Fixed>::from_displacement_field(read.field).expect("a field");
    let volume = warpbench_io::open(mri()).expect("fixture");
    let points = head_points(&volume);
    let q: Vec<Point3<Fixed>> = qs.iter().map(|&q| Point3::from_array(q)).collect();
    let p: Vec<Point3<Moving>> = qs.iter().map(|&q| Point3::from_array(truth(q))).collect();
    let tps = Tps::<Moving, Fixed>::fit(&q, &p, 0.0).expect("tps");
    let mean = |w: &dyn Warp<Moving, Fixed>| {
        points.iter().map(|&x| distance(w.apply_raw(x), truth(x))).sum::<f64>() / points.len() as f64
    };
    let (registered, through_pairs) = (mean(&u), mean(&tps));
    eprintln!("mean TRE over {} head points: registered {registered:.3} mm, TPS {through_pairs:.3} mm", points.len());
    (registered, through_pairs)
}

#[test]
fn the_registered_field_beats_the_tps_keeps_the_pairs_and_is_what_warp_applies() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (fixed, moving, pairs, qs) = case(dir.path());
    let (field, warped) = (dir.path().join("field.nii.gz"), dir.path().join("warped.nii.gz"));
    let run = register(&fixed, &moving, &pairs, &field, &["--out", utf8(&warped)]);
    assert_ok(&run);
    let report: Value = serde_json::from_slice(&run.stdout).expect("JSON on stdout");
    assert_eq!(report["schema"], "warpbench-register/2");
    assert_eq!(report["start"], "tps");
    assert_eq!(report["pairs"], 6);
    let levels = report["levels"].as_array().expect("levels");
    assert_eq!(levels.len(), 2);
    for level in levels {
        let (start, end) = (level["similarity_start"].as_f64(), level["similarity"].as_f64());
        assert!(end > start, "the similarity rises at every level: {level}");
    }
    for r in report["residuals"].as_array().expect("residuals") {
        assert!(r["residual_mm"].as_f64().expect("residual") < 0.5, "{r}");
    }
    assert_eq!(report["jacobian"]["fraction_folded"], 0.0, "{report}");
    assert!(report["jacobian"]["min_det"].as_f64().expect("min det") > 0.0);

    // The field holds u(x) − x: closer to the truth inside the head than the TPS through the same pairs.
    let (registered, through_pairs) = mean_tre(&field, &qs);
    assert!(registered < 0.7 * through_pairs, "registered {registered:.3} mm, TPS {through_pairs:.3} mm");

    // `--out` is the moving volume through that field, as `warpbench warp --field --exact` resamples it.
    let again = dir.path().join("again.nii.gz");
    let warp = warpbench(&[
        "warp",
        "--fixed",
        utf8(&fixed),
        "--moving",
        utf8(&moving),
        "--field",
        utf8(&field),
        "--exact",
        "--backend",
        "cpu",
        "--out",
        utf8(&again),
        "--quiet",
    ]);
    assert_ok(&warp);
    let (a, b) = (warpbench_io::open(&warped).expect("warped"), warpbench_io::open(&again).expect("again"));
    assert_eq!(a.dims, b.dims);
    let same_bits = (0..a.data.len()).all(|i| a.data.get_f64(i).to_bits() == b.data.get_f64(i).to_bits());
    assert!(same_bits, "the same voxels");
}

/// `--backend gpu` (the mutual information's samples read on the GPU, in f32): the same laws as on the CPU ([`QUICK`]),
/// and the same field, byte for byte, when run again (two runs [`TINY`]). Skipped without an adapter unless
/// REQUIRE_GPU_ADAPTER=1.
#[test]
fn on_the_gpu_the_registration_keeps_its_laws_and_repeats_bit_for_bit() {
    if warpbench_gpu::headless::headless_or_skip(warpbench_gpu::FeatureRequest::default()).is_none() {
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let (fixed, moving, pairs, qs) = case(dir.path());
    let gpu = |field: &Path, settings: &[&str]| {
        let run = register(&fixed, &moving, &pairs, field, &[settings, &["--backend", "gpu"]].concat());
        assert_ok(&run);
        serde_json::from_slice::<Value>(&run.stdout).expect("JSON on stdout")
    };
    let field = dir.path().join("gpu.nii.gz");
    let report = &gpu(&field, &QUICK);
    assert!(report["device"].as_str().expect("device").starts_with("gpu: "), "{report}");
    for level in report["levels"].as_array().expect("levels") {
        let (start, end) = (level["similarity_start"].as_f64(), level["similarity"].as_f64());
        assert!(end > start, "the similarity rises at every level: {level}");
    }
    for r in report["residuals"].as_array().expect("residuals") {
        assert!(r["residual_mm"].as_f64().expect("residual") < 0.5, "{r}");
    }
    assert_eq!(report["jacobian"]["fraction_folded"], 0.0, "{report}");
    let (registered, through_pairs) = mean_tre(&field, &qs);
    assert!(registered < 0.7 * through_pairs, "registered {registered:.3} mm, TPS {through_pairs:.3} mm");
    let fields = [dir.path().join("gpu1.nii.gz"), dir.path().join("gpu2.nii.gz")];
    let bytes = fields.map(|f| {
        gpu(&f, &TINY);
        std::fs::read(f).expect("field")
    });
    assert!(bytes[0] == bytes[1], "two runs on one GPU wrote different fields");
}

#[test]
fn bad_input_exits_2_names_the_file_and_writes_nothing() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (fixed, moving, _, _) = case(dir.path());
    let field = dir.path().join("never.nii.gz");
    let register = |extra: &[&str]| {
        let mut args = vec!["register", "--fixed", utf8(&fixed), "--out-field", utf8(&field), "--levels", "1"];
        args.extend_from_slice(extra);
        warpbench(&args)
    };
    let refused = |out: &std::process::Output, names: &[&str]| {
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{stderr}");
        for name in names {
            assert!(stderr.contains(name), "{name} in: {stderr}");
        }
        assert!(!field.exists(), "nothing written");
    };

    // A pair outside the moving volume: the landmark file and the pair, 1-based.
    let outside = dir.path().join("outside.csv");
    write_pairs_csv(&outside, &[([0.0, 0.0, 0.0], [0.0, 0.0, 0.0]), ([500.0, 0.0, 0.0], [10.0, 0.0, 0.0])]);
    refused(
        &register(&["--moving", utf8(&moving), "--landmarks", utf8(&outside)]),
        &["outside.csv", "landmark 2", "outside the moving volume"],
    );

    // No overlap: a starting transform that maps the fixed volume far from the moving one.
    let far = dir.path().join("far.tfm");
    std::fs::write(
        &far,
        "#Insight Transform File V1.0\n#Transform 0\nTransform: AffineTransform_double_3_3\n\
         Parameters: 1 0 0 0 1 0 0 0 1 600 0 0\nFixedParameters: 0 0 0\n",
    )
    .expect("write the tfm");
    refused(
        &register(&["--moving", utf8(&moving), "--initial", utf8(&far)]),
        &["moving.nii", "fixed.nii", "do not overlap"],
    );

    // One value: a moving volume with nothing to match.
    let mut flat = warpbench_io::open(&moving).expect("moving");
    flat.data = warpbench_io::VoxelData::F32(vec![5.0; flat.data.len()]);
    let flat_path = dir.path().join("flat.nii");
    warpbench_io::nifti::write(&flat_path, &flat).expect("write flat");
    refused(&register(&["--moving", utf8(&flat_path)]), &["flat.nii", "single value"]);

    // Unusable settings, and an output that exists.
    refused(&register(&["--moving", utf8(&moving), "--grid-mm", "0"]), &["control spacing"]);
    // Normalised gradient fields have no GPU path.
    refused(
        &register(&["--moving", utf8(&moving), "--metric", "ngf", "--backend", "gpu"]),
        &["--metric mi and lncc only"],
    );
    let exists = dir.path().join("exists.nii.gz");
    std::fs::write(&exists, b"keep").expect("write");
    let out =
        warpbench(&["register", "--fixed", utf8(&fixed), "--moving", utf8(&moving), "--out-field", utf8(&exists)]);
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("exists.nii.gz"));
    assert_eq!(std::fs::read(&exists).expect("read"), b"keep", "the file is untouched");
}

#[test]
fn normalised_gradient_fields_are_a_metric_of_their_own() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (fixed, moving, pairs, _) = case(dir.path());
    let field = dir.path().join("field.nii.gz");
    let run = register(&fixed, &moving, &pairs, &field, &["--metric", "ngf"]);
    assert_ok(&run);
    let report: Value = serde_json::from_slice(&run.stdout).expect("JSON on stdout");
    assert_eq!(report["settings"]["metric"], "ngf");
    // A mean of squared cosines: in [0, 1]. The coarse level raises it; each level lowers the whole objective, whose
    // landmark and bending terms may cost a finer level's similarity a little (levels read differently shrunk images,
    // so their values are not compared with each other).
    let levels = report["levels"].as_array().expect("levels");
    let value = |l: &Value, key: &str| l[key].as_f64().expect("similarity");
    for level in levels {
        assert!((0.0..=1.0).contains(&value(level, "similarity_start")), "{level}");
        assert!((0.0..=1.0).contains(&value(level, "similarity")), "{level}");
    }
    let first = levels.first().expect("a level");
    assert!(value(first, "similarity") > value(first, "similarity_start"), "{levels:?}");
    for r in report["residuals"].as_array().expect("residuals") {
        assert!(r["residual_mm"].as_f64().expect("residual") < 0.5, "{r}");
    }
    assert!(report["jacobian"]["min_det"].as_f64().expect("min det") > 0.0);
}

/// `--metric lncc`: local correlation in [0, 1] that rises, the pairs kept, no fold, closer to the truth than the TPS;
/// and its samples read on the GPU (`--backend gpu`, when an adapter is there) keep the same laws.
#[test]
fn local_correlation_is_a_metric_of_its_own_on_the_cpu_and_the_gpu() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (fixed, moving, pairs, qs) = case(dir.path());
    let gpu = warpbench_gpu::headless::headless_or_skip(warpbench_gpu::FeatureRequest::default()).is_some();
    let backends: &[&str] = if gpu { &["cpu", "gpu"] } else { &["cpu"] };
    for backend in backends {
        let field = dir.path().join(format!("field-{backend}.nii.gz"));
        let run = register(
            &fixed,
            &moving,
            &pairs,
            &field,
            &[&QUICK[..], &["--metric", "lncc", "--backend", backend]].concat(),
        );
        assert_ok(&run);
        let report: Value = serde_json::from_slice(&run.stdout).expect("JSON on stdout");
        assert_eq!(report["settings"]["metric"], "lncc");
        assert!(report["device"].as_str().expect("device").starts_with(backend), "{report}");
        for level in report["levels"].as_array().expect("levels") {
            let (start, end) = (level["similarity_start"].as_f64(), level["similarity"].as_f64());
            assert!((0.0..=1.0).contains(&start.expect("start")) && (0.0..=1.0).contains(&end.expect("end")));
            assert!(end > start, "{backend}: the similarity rises at every level: {level}");
        }
        for r in report["residuals"].as_array().expect("residuals") {
            assert!(r["residual_mm"].as_f64().expect("residual") < 0.5, "{backend}: {r}");
        }
        assert_eq!(report["jacobian"]["fraction_folded"], 0.0, "{report}");
        let (registered, through_pairs) = mean_tre(&field, &qs);
        assert!(
            registered < 0.7 * through_pairs,
            "{backend}: registered {registered:.3} mm, TPS {through_pairs:.3} mm"
        );
    }
}

/// A mask on a grid of its own: 4 mm voxels over `like`'s box, 1 on the central 70 % of it along each axis.
struct CoreMask {
    dims: [usize; 3],
    lps_from_index: Transform<Lps, Index>,
    index_from_lps: Transform<Index, Lps>,
    values: Vec<u8>,
}

impl CoreMask {
    fn over(like: &warpbench_io::Volume) -> Self {
        let corner = |c: [f64; 3]| like.lps_from_index.apply_point(Point3::from_array(c)).coords();
        let (a, b) = (corner([0.0; 3]), corner(like.dims.map(|n| (n - 1) as f64)));
        let lo: [f64; 3] = std::array::from_fn(|i| a[i].min(b[i]));
        let hi: [f64; 3] = std::array::from_fn(|i| a[i].max(b[i]));
        let dims: [usize; 3] = std::array::from_fn(|i| ((hi[i] - lo[i]) / 4.0) as usize + 1);
        let lps_from_index: Transform<Lps, Index> = Transform::from_scale_translation([4.0; 3], lo);
        let in_core = |x: [f64; 3]| (0..3).all(|i| (x[i] - 0.5 * (lo[i] + hi[i])).abs() < 0.35 * (hi[i] - lo[i]));
        let values = (0..dims.iter().product::<usize>())
            .map(|o| {
                let ijk = [o % dims[0], (o / dims[0]) % dims[1], o / (dims[0] * dims[1])].map(|c| c as f64);
                u8::from(in_core(lps_from_index.apply_point(Point3::from_array(ijk)).coords()))
            })
            .collect();
        let index_from_lps = lps_from_index.inverse().expect("invertible");
        Self { dims, lps_from_index, index_from_lps, values }
    }

    /// Writes the mask, or one of its shape with `values`, as `path`.
    fn write(&self, path: &Path, values: Vec<u8>) {
        let volume = warpbench_io::Volume::new(
            path,
            self.dims,
            warpbench_io::VoxelData::U8(values),
            self.lps_from_index,
            warpbench_io::GeometrySource::NiftiSform { code: 1 },
        )
        .expect("mask");
        warpbench_io::nifti::write(path, &volume).expect("write mask");
    }

    /// Whether the mask voxel nearest to `x` is 1 (the rule `--fixed-mask` documents).
    fn keeps(&self, x: [f64; 3]) -> bool {
        let m = self.index_from_lps.apply_point(Point3::from_array(x)).coords();
        let m = m.map(f64::round);
        let d = self.dims;
        (0..3).all(|i| m[i] >= 0.0 && m[i] < d[i] as f64)
            && self.values[m[0] as usize + d[0] * (m[1] as usize + d[1] * m[2] as usize)] != 0
    }

    /// `volume` (read from `from`) with noise wherever the mask is 0, written as `to`.
    fn noisy_outside(&self, from: &Path, to: &Path) {
        let volume = warpbench_io::open(from).expect("volume");
        let [nx, ny, _] = volume.dims;
        let mut state = 12_345u64;
        let values: Vec<f32> = (0..volume.data.len())
            .map(|o| {
                let ijk = [o % nx, (o / nx) % ny, o / (nx * ny)].map(|c| c as f64);
                let x = volume.lps_from_index.apply_point(Point3::from_array(ijk)).coords();
                state = state.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
                if self.keeps(x) {
                    volume.data.get_f64(o) as f32
                } else {
                    (state >> 40) as f32 / (1u64 << 24) as f32 * 300.0
                }
            })
            .collect();
        let mut noisy = volume;
        noisy.data = warpbench_io::VoxelData::F32(values);
        warpbench_io::nifti::write(to, &noisy).expect("write noisy");
    }
}

/// `--fixed-mask` and `--moving-mask`: the registration reads each volume only where its mask (on a grid of its own)
/// is not 0. So what a volume holds outside its mask does not change the field by a bit, while without the mask it
/// does (these runs [`TINY`]); inside both masks around the head the field still beats the TPS ([`QUICK`]); a mask
/// that keeps too little, or is no volume, exits 2 naming it and writes nothing.
#[test]
fn a_mask_leaves_out_what_its_volume_holds_outside_it() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (fixed, moving, pairs, qs) = case(dir.path());
    let core = CoreMask::over(&warpbench_io::open(&fixed).expect("fixed"));
    let mask = dir.path().join("mask.nii.gz");
    core.write(&mask, core.values.clone());
    let field = |name: &str, fixed: &Path, moving: &Path, extra: &[&str]| {
        let path = dir.path().join(name);
        let run = register(fixed, moving, &pairs, &path, extra);
        assert_ok(&run);
        (std::fs::read(&path).expect("field"), serde_json::from_slice::<Value>(&run.stdout).expect("JSON"), path)
    };
    let (plain, _, _) = field("plain.nii.gz", &fixed, &moving, &TINY);
    for (flag, side) in [("--fixed-mask", "fixed"), ("--moving-mask", "moving")] {
        let noisy = dir.path().join(format!("noisy-{side}.nii"));
        core.noisy_outside(if side == "fixed" { &fixed } else { &moving }, &noisy);
        let (f, m) = if side == "fixed" { (&noisy, &moving) } else { (&fixed, &noisy) };
        let masked = [&TINY[..], &[flag, utf8(&mask)]].concat();
        let (a, report, _) = field(&format!("{side}-masked.nii.gz"), &fixed, &moving, &masked);
        let (b, _, _) = field(&format!("{side}-masked-noisy.nii.gz"), f, m, &masked);
        assert!(a == b, "the {side} volume outside its mask changed the field");
        assert_eq!(report["settings"][&flag[2..].replace('-', "_")], utf8(&mask));
        let (c, _, _) = field(&format!("{side}-plain-noisy.nii.gz"), f, m, &TINY);
        assert!(plain != c, "without the mask the {side} noise is read (the law above is not vacuous)");
    }
    let both = ["--fixed-mask", utf8(&mask), "--moving-mask", utf8(&mask)];
    let (_, _, masked) = field("both-masked.nii.gz", &fixed, &moving, &[&QUICK[..], &both].concat());
    let (registered, through_pairs) = mean_tre(&masked, &qs);
    assert!(registered < 0.7 * through_pairs, "both masks: registered {registered:.3} mm, TPS {through_pairs:.3} mm");

    // A mask that keeps nothing, and a file that is no volume: exit 2, named, nothing written.
    let empty = dir.path().join("empty.nii.gz");
    core.write(&empty, vec![0; core.values.len()]);
    let not_a_volume = dir.path().join("mask.txt");
    std::fs::write(&not_a_volume, "not a volume").expect("write");
    for (flag, bad, says) in [
        ("--fixed-mask", &empty, "keeps 0 voxels"),
        ("--moving-mask", &empty, "keeps 0 voxels"),
        ("--fixed-mask", &not_a_volume, "mask.txt"),
    ] {
        let out = dir.path().join("never.nii.gz");
        let run = register(&fixed, &moving, &pairs, &out, &[flag, utf8(bad)]);
        let stderr = String::from_utf8_lossy(&run.stderr);
        assert_eq!(run.status.code(), Some(2), "{stderr}");
        assert!(stderr.contains(utf8(bad)) && stderr.contains(says), "{flag}: {stderr}");
        assert!(!out.exists(), "nothing written");
    }
}

/// `--out-inverse-field`: the forward field d(y) − y on the moving grid undoes the registered pull-back. At the head's
/// points x, d(u(x)) = x within 0.1 mm: the inversion's own error, which `--json` reports (it stops below 0.01 mm),
/// plus the two written fields' trilinear sampling (about h²/8 times their second derivatives: under 0.01 mm for
/// these 20 mm bumps on 2 mm voxels). An inverse named like another output exits 2.
#[test]
fn the_inverse_field_undoes_the_registered_warp() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (fixed, moving, pairs, _) = case(dir.path());
    let (field, inverse) = (dir.path().join("field.nii.gz"), dir.path().join("inverse.nii.gz"));
    let run = register(&fixed, &moving, &pairs, &field, &["--out-inverse-field", utf8(&inverse)]);
    assert_ok(&run);
    let report: Value = serde_json::from_slice(&run.stdout).expect("JSON on stdout");
    assert_eq!(report["out_inverse_field"], utf8(&inverse));
    let max_mm = report["inverse_consistency"]["max_mm"].as_f64().expect("the inverse's consistency");
    assert!(max_mm < 0.05, "{report}");
    let u = SampledField::<Moving, Fixed>::from_displacement_field(read_field_info(&field).expect("field").field)
        .expect("the pull-back");
    let d = SampledField::<Fixed, Moving>::from_displacement_field(read_field_info(&inverse).expect("inverse").field)
        .expect("the inverse");
    let volume = warpbench_io::open(mri()).expect("fixture");
    let points = head_points(&volume);
    let worst = points.iter().map(|&x| distance(d.apply_raw(u.apply_raw(x)), x)).fold(0.0, f64::max);
    eprintln!("d(u(x)) − x over {} head points: at most {worst:.4} mm (inversion: {max_mm:.4} mm)", points.len());
    assert!(worst < 0.1, "d(u(x)) is {worst:.4} mm from x");

    let same = register(&fixed, &moving, &pairs, &field, &["--out-inverse-field", utf8(&field), "--force"]);
    assert_eq!(same.status.code(), Some(2), "{}", String::from_utf8_lossy(&same.stderr));
    assert!(String::from_utf8_lossy(&same.stderr).contains("--out-inverse-field"));
}

/// `--out-field` named `.npz` writes Learn2Reg's field of the same registration: read back against the pair's grids
/// it is the pull-back of a run that writes ITK's NIfTI (the runs repeat bit for bit), within float16's rounding of
/// the steps (2⁻¹¹ of a step, times the 2 mm voxels); `--format learn2reg` to a `.nii.gz` writes the NIfTI form,
/// float32, within f32's rounding; `--format fnirt` writes FSL FNIRT's field, which reads back against the pair to the
/// same pull-back. With `--format ants` to an `.npz`, or `learn2reg` or `fnirt` to a `.nrrd`, it exits 2 and writes
/// nothing.
#[test]
fn an_npz_field_is_learn2regs_of_the_same_registration() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (fixed, moving, pairs, _) = case(dir.path());
    let (npz, nii) = (dir.path().join("disp_0001_0002.npz"), dir.path().join("field.nii.gz"));
    let run = register(&fixed, &moving, &pairs, &npz, &TINY);
    assert_ok(&run);
    assert_ok(&register(&fixed, &moving, &pairs, &nii, &TINY));
    let (f, m) = (warpbench_io::open(&fixed).expect("fixed"), warpbench_io::open(&moving).expect("moving"));
    let steps = warpbench_io::learn2reg::read_voxel_field(&npz).expect("the .npz");
    let read =
        warpbench_io::learn2reg::pullback_from_voxels(&npz, &steps, f.dims, &f.lps_from_index, &m.lps_from_index)
            .expect("against the pair");
    let want = read_field_info(&nii).expect("the NIfTI field").field;
    let mut worst = 0f64;
    for (a, b) in read.displacements_lps.iter().zip(&want.displacements_lps) {
        let size = (0..3).map(|c| f64::from(b[c]).powi(2)).sum::<f64>().sqrt();
        let gap = distance(a.map(f64::from), b.map(f64::from));
        assert!(gap <= size * 2f64.powi(-11) * 2.0 * 3f64.sqrt() + 1e-4, "{a:?} against {b:?}");
        worst = worst.max(size);
    }
    assert!(worst > 2.0, "the registration moved the voxels (largest {worst:.2} mm)");
    let form = dir.path().join("disp_0001_0002.nii.gz");
    let run = register(&fixed, &moving, &pairs, &form, &[&TINY[..], &["--format", "learn2reg"]].concat());
    assert_ok(&run);
    let report: serde_json::Value = serde_json::from_slice(&run.stdout).expect("register JSON");
    assert_eq!(report["format"], "learn2reg");
    let steps = warpbench_io::learn2reg::read_voxel_field(&form).expect("the NIfTI form");
    let read =
        warpbench_io::learn2reg::pullback_from_voxels(&form, &steps, f.dims, &f.lps_from_index, &m.lps_from_index)
            .expect("against the pair");
    for (a, b) in read.displacements_lps.iter().zip(&want.displacements_lps) {
        assert!(distance(a.map(f64::from), b.map(f64::from)) < 1e-4, "{a:?} against {b:?}");
    }
    // FSL FNIRT's relative deformation field of the same run, read back against the pair.
    let fnirt = dir.path().join("warp_fnirt.nii.gz");
    let run = register(&fixed, &moving, &pairs, &fnirt, &[&TINY[..], &["--format", "fnirt"]].concat());
    assert_ok(&run);
    let report: serde_json::Value = serde_json::from_slice(&run.stdout).expect("register JSON");
    assert_eq!(report["format"], "fnirt");
    let read = warpbench_io::fnirt::read_pullback(&fnirt, (f.dims, &f.lps_from_index), (m.dims, &m.lps_from_index))
        .expect("against the pair");
    for (a, b) in read.field.displacements_lps.iter().zip(&want.displacements_lps) {
        assert!(distance(a.map(f64::from), b.map(f64::from)) < 1e-4, "{a:?} against {b:?}");
    }
    for (name, format, what) in
        [("ants.npz", "ants", "Learn2Reg"), ("l2r.nrrd", "learn2reg", "Learn2Reg"), ("fnirt.nrrd", "fnirt", "FNIRT")]
    {
        let refused = dir.path().join(name);
        let run = register(&fixed, &moving, &pairs, &refused, &[&TINY[..], &["--format", format]].concat());
        let stderr = String::from_utf8_lossy(&run.stderr);
        assert_eq!(run.status.code(), Some(2), "{stderr}");
        assert!(stderr.contains(name) && stderr.contains(what), "{stderr}");
        assert!(!refused.exists());
    }
}
