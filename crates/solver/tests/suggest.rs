//! Suggested targets (issue 18 item 2) on the real head MRI `ch2.nii.gz` (Colin27, 1 mm): the fixed image is the
//! moving one pulled back through a known smooth warp, f(x) = m(u_true(x)), u_true a small rotation plus four
//! Gaussian bumps (up to ~8 mm); the current warp d is the TPS through six true pairs spread over the head. At 50
//! strong-gradient moving points the suggestion is compared with the true fixed point, u_true⁻¹(p) (Newton, to
//! 1e-9 mm), in the same contrast and with the fixed intensities remapped non-monotonically (a second modality).
//! The figures are in docs/accuracy.md; `cargo test -p warpbench-solver --test suggest -- --nocapture` prints them.

use std::path::Path;
use std::sync::OnceLock;
use std::time::Instant;

use nalgebra::{Matrix3, Rotation3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use warpbench_io::geometry::Point3;
use warpbench_solver::image::Image;
use warpbench_solver::warp::Parallelism;
use warpbench_solver::suggest::{PatchMatcher, SuggestParams, Suggestion, suggest};
use warpbench_solver::tps::{Tps, fit_forward};
use warpbench_solver::{Fixed, Moving};

/// Points measured.
const POINTS: usize = 50;
/// Moving points are drawn among the in-head voxels whose gradient magnitude is in this top quantile.
const TOP_GRADIENT_QUANTILE: f64 = 0.10;
/// Moving points stay this far from the volume's faces (patch, search and displacement fit inside), voxels.
const BORDER_VOX: usize = 24;
/// The seed of the moving points.
const POINT_SEED: u64 = 18;
/// Voxels above this fraction of the largest value are in the head.
const HEAD_FRACTION: f64 = 0.15;

/// The issue's targets, mm.
const MEDIAN_TARGET_MM: f64 = 1.0;
const P90_TARGET_MM: f64 = 2.0;
const MEDIAN_REMAPPED_TARGET_MM: f64 = 1.5;

/// At most this fraction of the suggestions may be flagged (measured: 10 % and 12 %).
const MAX_FLAGGED_FRACTION: f64 = 0.3;

/// How close the refined optimum must be to the brute-force fine grid's, mm, and that grid's step and half-width.
const REFINE_AGREEMENT_MM: f64 = 0.1;
const BRUTE_STEP_MM: f64 = 0.05;
const BRUTE_HALF_WIDTH_MM: f64 = 0.6;
/// On a flat top, the fine grid may beat the refined score by this much (relative) at a point farther than
/// [`REFINE_AGREEMENT_MM`] (measured: at most 6.1·10⁻³).
const FLAT_PEAK_TOLERANCE: f64 = 1e-2;
/// Points checked by brute force, per contrast.
const BRUTE_POINTS: usize = 6;

/// The known pull-back u_true = `moving_from_fixed`: c + R(x − c) + Σ aⱼ exp(−|x − cⱼ|²/2σⱼ²).
struct TruePullback {
    centre: [f64; 3],
    rotation: Matrix3<f64>,
    bumps: Vec<([f64; 3], f64, [f64; 3])>,
}

impl TruePullback {
    fn new(centre: [f64; 3]) -> Self {
        let c = |d: [f64; 3]| [centre[0] + d[0], centre[1] + d[1], centre[2] + d[2]];
        Self {
            centre,
            rotation: Rotation3::from_euler_angles(0.03, -0.02, 0.035).into_inner(),
            bumps: vec![
                (c([30.0, 20.0, 10.0]), 30.0, [4.0, -3.0, 2.5]),
                (c([-35.0, -10.0, 20.0]), 28.0, [-3.0, 4.5, -2.0]),
                (c([0.0, -40.0, -15.0]), 32.0, [2.5, 2.0, 4.0]),
                (c([5.0, 35.0, -25.0]), 26.0, [-2.0, -3.5, 3.0]),
            ],
        }
    }

    fn apply(&self, x: [f64; 3]) -> [f64; 3] {
        let r = self.rotation * Vector3::from(sub(x, self.centre));
        let mut out = [self.centre[0] + r[0], self.centre[1] + r[1], self.centre[2] + r[2]];
        for (c, sigma, a) in &self.bumps {
            let w = (-dot(sub(x, *c), sub(x, *c)) / (2.0 * sigma * sigma)).exp();
            for i in 0..3 {
                out[i] += w * a[i];
            }
        }
        out
    }

    fn jacobian(&self, x: [f64; 3]) -> Matrix3<f64> {
        let mut j = self.rotation;
        for (c, sigma, a) in &self.bumps {
            let d = sub(x, *c);
            let w = (-dot(d, d) / (2.0 * sigma * sigma)).exp();
            for r in 0..3 {
                for col in 0..3 {
                    j[(r, col)] -= a[r] * w * d[col] / (sigma * sigma);
                }
            }
        }
        j
    }

    /// The fixed point q with u_true(q) = p, by Newton from q = p.
    fn invert(&self, p: [f64; 3]) -> [f64; 3] {
        let mut q = p;
        for _ in 0..50 {
            let r = sub(self.apply(q), p);
            if norm(r) < 1e-9 {
                return q;
            }
            let step = self.jacobian(q).try_inverse().expect("u_true is invertible") * Vector3::from(r);
            q = [q[0] - step[0], q[1] - step[1], q[2] - step[2]];
        }
        panic!("Newton did not converge at {p:?}");
    }
}

struct Fixture {
    moving: Image<Moving>,
    fixed: Image<Fixed>,
    fixed_remapped: Image<Fixed>,
    truth: TruePullback,
    fixed_from_moving: Tps<Fixed, Moving>,
    points: Vec<[f64; 3]>,
}

fn fixture() -> &'static Fixture {
    static FIXTURE: OnceLock<Fixture> = OnceLock::new();
    FIXTURE.get_or_init(|| {
        let t = Instant::now();
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/nifti/ch2.nii.gz");
        let volume = warpbench_io::open(&path).expect("ch2 fixture");
        let moving: Image<Moving> = Image::from_volume(&volume, Parallelism::Rayon).expect("image");
        let dims = moving.dims();
        let centre = {
            let a = moving.voxel_point(0, 0, 0);
            let b = moving.voxel_point(dims[0] - 1, dims[1] - 1, dims[2] - 1);
            [0.5 * (a[0] + b[0]), 0.5 * (a[1] + b[1]), 0.5 * (a[2] + b[2])]
        };
        let truth = TruePullback::new(centre);

        // f(x) = m(u_true(x)) on the moving grid; outside the moving image, 0.
        let slice = dims[0] * dims[1];
        let mut values = vec![0.0f32; slice * dims[2]];
        values.par_chunks_mut(slice).enumerate().for_each(|(k, out)| {
            for j in 0..dims[1] {
                for i in 0..dims[0] {
                    let x = truth.apply(moving.voxel_point(i, j, k));
                    out[i + dims[0] * j] = moving.sample(x).unwrap_or(0.0) as f32;
                }
            }
        });
        let (_, max) = moving.value_range(Parallelism::Rayon).expect("finite values");
        // A second modality: v ↦ |v − c|^0.7, c at 40 % of the range (between the CSF and the grey matter's
        // intensities): contrast folds over at c, so that the CSF turns brighter than the grey matter.
        let c = 0.4 * max;
        let scale = max / (max - c).powf(0.7);
        let remapped: Vec<f32> = values.iter().map(|&v| ((f64::from(v) - c).abs().powf(0.7) * scale) as f32).collect();
        let geometry = *moving.clone().retag::<Fixed>().space_from_index();
        let fixed = Image::new(dims, values, geometry).expect("fixed image");
        let fixed_remapped = Image::new(dims, remapped, geometry).expect("remapped image");

        // Six true pairs spread over the head: the current warp is the TPS through them.
        let spread = [
            [50.0, 0.0, 0.0],
            [-50.0, 0.0, 0.0],
            [0.0, 60.0, 0.0],
            [0.0, -60.0, 0.0],
            [0.0, 0.0, 45.0],
            [10.0, 10.0, -40.0],
        ];
        let p6: Vec<Point3<Moving>> =
            spread.iter().map(|d| Point3::from_array([centre[0] + d[0], centre[1] + d[1], centre[2] + d[2]])).collect();
        let q6: Vec<Point3<Fixed>> = p6.iter().map(|p| Point3::from_array(truth.invert(p.coords()))).collect();
        let fixed_from_moving = fit_forward(&p6, &q6, 0.0).expect("TPS");

        let points = strong_gradient_points(&moving, POINTS, POINT_SEED);
        eprintln!("fixture: {:.2} s", t.elapsed().as_secs_f64());
        Fixture { moving, fixed, fixed_remapped, truth, fixed_from_moving, points }
    })
}

/// `n` seeded random in-head voxel centres among the top gradient-magnitude quantile, away from the faces.
fn strong_gradient_points(image: &Image<Moving>, n: usize, seed: u64) -> Vec<[f64; 3]> {
    let dims = image.dims();
    let (_, max) = image.value_range(Parallelism::Rayon).expect("finite values");
    let mut candidates: Vec<(f64, [usize; 3])> = Vec::new();
    for k in BORDER_VOX..dims[2] - BORDER_VOX {
        for j in BORDER_VOX..dims[1] - BORDER_VOX {
            for i in BORDER_VOX..dims[0] - BORDER_VOX {
                if f64::from(image.at(i, j, k)) < HEAD_FRACTION * max {
                    continue;
                }
                let d = |a: f32, b: f32| 0.5 * f64::from(a - b);
                let g = [
                    d(image.at(i + 1, j, k), image.at(i - 1, j, k)),
                    d(image.at(i, j + 1, k), image.at(i, j - 1, k)),
                    d(image.at(i, j, k + 1), image.at(i, j, k - 1)),
                ];
                candidates.push((norm(g), [i, j, k]));
            }
        }
    }
    candidates.sort_by(|a, b| b.0.total_cmp(&a.0));
    let top = &candidates[..(TOP_GRADIENT_QUANTILE * candidates.len() as f64) as usize];
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..n)
        .map(|_| {
            let [i, j, k] = top[rng.random_range(0..top.len())].1;
            image.voxel_point(i, j, k)
        })
        .collect()
}

/// One measured suggestion.
struct Measured {
    suggestion: Suggestion,
    error_mm: f64,
    predicted_error_mm: f64,
}

fn measure(fixed: &Image<Fixed>, params: &SuggestParams) -> (Vec<Measured>, f64) {
    let f = fixture();
    let t = Instant::now();
    let out: Vec<Measured> = f
        .points
        .iter()
        .map(|&p| {
            let suggestion =
                suggest(&f.moving, fixed, &f.fixed_from_moving, Point3::from_array(p), params).expect("suggestion");
            let truth = f.truth.invert(p);
            Measured {
                error_mm: norm(sub(suggestion.fixed.coords(), truth)),
                predicted_error_mm: norm(sub(suggestion.predicted.coords(), truth)),
                suggestion,
            }
        })
        .collect();
    let ms_each = 1e3 * t.elapsed().as_secs_f64() / f.points.len() as f64;
    (out, ms_each)
}

/// The q-th quantile (linear interpolation) of `v`.
fn quantile(v: &[f64], q: f64) -> f64 {
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    if s.is_empty() {
        return f64::NAN;
    }
    let x = q * (s.len() - 1) as f64;
    let (lo, hi) = (x.floor() as usize, x.ceil() as usize);
    s[lo] + (x - lo as f64) * (s[hi] - s[lo])
}

/// What the assertions read from one contrast's row.
struct Row {
    median_mm: f64,
    p90_mm: f64,
    flagged: usize,
    /// Suggestions off by more than 2 mm, and how many of them were flagged.
    bad: usize,
    bad_flagged: usize,
}

/// Prints the table row of one contrast (and each suggestion on stderr).
fn report(name: &str, measured: &[Measured], ms_each: f64) -> Row {
    let errors: Vec<f64> = measured.iter().map(|m| m.error_mm).collect();
    let predicted: Vec<f64> = measured.iter().map(|m| m.predicted_error_mm).collect();
    let flagged: Vec<f64> = measured.iter().filter(|m| m.suggestion.low_confidence).map(|m| m.error_mm).collect();
    let kept: Vec<f64> = measured.iter().filter(|m| !m.suggestion.low_confidence).map(|m| m.error_mm).collect();
    let bad = measured.iter().filter(|m| m.error_mm > 2.0).count();
    let bad_flagged = measured.iter().filter(|m| m.error_mm > 2.0 && m.suggestion.low_confidence).count();
    let (median, p90) = (quantile(&errors, 0.5), quantile(&errors, 0.9));
    println!(
        "| {name} | {:.2} / {:.2} | {median:.2} | {p90:.2} | {:.2} | {} | {:.2} | {:.2} | {bad_flagged} of {bad} | {:.2} \
         | {ms_each:.1} |",
        quantile(&predicted, 0.5),
        quantile(&predicted, 0.9),
        errors.iter().copied().fold(0.0, f64::max),
        flagged.len(),
        quantile(&kept, 0.5),
        quantile(&flagged, 0.5),
        quantile(&kept, 0.9),
    );
    for (i, m) in measured.iter().enumerate() {
        let s = &m.suggestion;
        eprintln!(
            "  {i:2}: pred {:5.2} → {:5.2} mm  S {:.3} (q0 {:.3}, rival {:.3}, evals {})  conf {:.2}{}",
            m.predicted_error_mm,
            m.error_mm,
            s.score,
            s.predicted_score.unwrap_or(f64::NAN),
            s.rival_score,
            s.evaluations,
            s.confidence,
            if s.on_rim { " rim" } else { "" }
        );
    }
    Row { median_mm: median, p90_mm: p90, flagged: flagged.len(), bad, bad_flagged }
}

fn table_header() {
    println!(
        "| fixed contrast | prediction error median / P90 (mm) | suggestion error median (mm) | P90 (mm) | max (mm) | \
         flagged (of {POINTS}) | median error unflagged (mm) | median error flagged (mm) | > 2 mm flagged | P90 \
         unflagged (mm) | ms per suggestion |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|");
}

#[test]
fn suggestions_on_head_mri_meet_the_issue_targets() {
    let f = fixture();
    let params = SuggestParams::default();
    table_header();
    let (measured, ms) = measure(&f.fixed, &params);
    let same = report("same (T1)", &measured, ms);
    let (measured_remapped, ms) = measure(&f.fixed_remapped, &params);
    let remapped = report("remapped |v − c|^0.7", &measured_remapped, ms);
    assert!(same.median_mm <= MEDIAN_TARGET_MM, "median error {:.2} mm > {MEDIAN_TARGET_MM} mm", same.median_mm);
    assert!(same.p90_mm <= P90_TARGET_MM, "P90 error {:.2} mm > {P90_TARGET_MM} mm", same.p90_mm);
    assert!(
        remapped.median_mm <= MEDIAN_REMAPPED_TARGET_MM,
        "remapped median error {:.2} mm > {MEDIAN_REMAPPED_TARGET_MM} mm",
        remapped.median_mm
    );
    // The confidence: every suggestion off by more than 2 mm is flagged, and flagging stays the exception.
    for row in [&same, &remapped] {
        assert_eq!(row.bad_flagged, row.bad, "suggestions off by > 2 mm that were not flagged");
        assert!(row.flagged as f64 <= MAX_FLAGGED_FRACTION * POINTS as f64, "{} of {POINTS} flagged", row.flagged);
    }
}

/// The refinement lands on the optimum of S that a brute-force search of a fine grid finds, in a box around it
/// (centred on the suggestion rounded to 0.1 mm, so that the grid does not hold the suggestion itself), in both
/// contrasts. Where S has a flat top (an edge seen through the patch: near-equal maxima up to a millimetre apart, or
/// a narrow spike beside the peak), the argmax is not defined to 0.1 mm; such a point passes when the fine grid beats
/// the refined score by less than [`FLAT_PEAK_TOLERANCE`] (relative), and at most a quarter of the points may be
/// one. Measured over five point seeds with 12 points per contrast: 105 of 120 within 0.1 mm, the other 15 behind
/// the fine grid by at most 6.1·10⁻³ (docs/accuracy.md).
#[test]
fn refinement_agrees_with_a_brute_force_fine_grid() {
    let f = fixture();
    let params = SuggestParams::default();
    let n = (BRUTE_HALF_WIDTH_MM / BRUTE_STEP_MM).round() as i64;
    let (mut worst_sharp, mut flat): (f64, usize) = (0.0, 0);
    let cases = f.points.iter().take(BRUTE_POINTS).map(|p| (p, &f.fixed));
    let remapped = f.points.iter().skip(BRUTE_POINTS).take(BRUTE_POINTS).map(|p| (p, &f.fixed_remapped));
    for (&p, fixed) in cases.chain(remapped) {
        let p = Point3::from_array(p);
        let matcher = PatchMatcher::new(&f.moving, fixed, &f.fixed_from_moving, p, &params).expect("matcher");
        let s = matcher.search().expect("suggestion");
        let refined = s.fixed.coords();
        let centre = refined.map(|v| (v * 10.0).round() / 10.0);
        let (best_score, best) = (-n..=n)
            .into_par_iter()
            .flat_map_iter(|k| (-n..=n).flat_map(move |j| (-n..=n).map(move |i| [i, j, k])))
            .filter_map(|[i, j, k]| {
                let q = [
                    centre[0] + i as f64 * BRUTE_STEP_MM,
                    centre[1] + j as f64 * BRUTE_STEP_MM,
                    centre[2] + k as f64 * BRUTE_STEP_MM,
                ];
                matcher.score(Point3::from_array(q)).map(|v| (v, q))
            })
            .max_by(|a, b| a.0.total_cmp(&b.0))
            .expect("scores in the box");
        let d = norm(sub(best, refined));
        let deficit = (best_score - s.score) / s.score;
        eprintln!("brute force: refined S {:.5}, fine grid S {best_score:.5}, {d:.3} mm apart", s.score);
        if d <= REFINE_AGREEMENT_MM {
            worst_sharp = worst_sharp.max(d);
        } else {
            assert!(
                deficit < FLAT_PEAK_TOLERANCE,
                "the fine grid's optimum is {d:.3} mm from the refined one and scores {deficit:.2e} (relative) higher"
            );
            flat += 1;
        }
    }
    println!(
        "refined optimum vs the brute-force fine grid's ({BRUTE_STEP_MM} mm step, ±{BRUTE_HALF_WIDTH_MM} mm): {} of {} \
         within {worst_sharp:.3} mm, {flat} flat tops",
        2 * BRUTE_POINTS - flat,
        2 * BRUTE_POINTS
    );
    assert!(4 * flat <= 2 * BRUTE_POINTS, "{flat} flat tops of {}", 2 * BRUTE_POINTS);
}

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn norm(v: [f64; 3]) -> f64 {
    dot(v, v).sqrt()
}
