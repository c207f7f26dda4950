//! Suggested targets (issue 18 item 2) on the real head MRI `ch2.nii.gz` against a known smooth warp of itself
//! ([`suggest_case`]): the issue's targets in the same contrast and with the fixed intensities remapped
//! non-monotonically (a second modality), and the refinement against a brute-force fine grid. The figures are in
//! docs/accuracy.md; `cargo test -p warpbench-solver --test solver suggest:: -- --nocapture` prints them, and
//! `cargo bench -p warpbench-solver --bench suggest_confidence` measures the confidence over more point seeds.

use crate::suggest_case;

use std::sync::OnceLock;

use rayon::prelude::*;
use suggest_case::{Case, Measured, POINTS, Summary, norm, sub};
use warpbench_io::geometry::Point3;
use warpbench_solver::suggest::{PatchMatcher, SuggestParams};

/// The seed of the moving points.
const POINT_SEED: u64 = 18;

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

/// The case and the test's moving points, built once for both tests.
struct Fixture {
    case: Case,
    points: Vec<[f64; 3]>,
}

fn fixture() -> &'static Fixture {
    static FIXTURE: OnceLock<Fixture> = OnceLock::new();
    FIXTURE.get_or_init(|| {
        let case = Case::build();
        let points = case.points(POINTS, POINT_SEED);
        Fixture { case, points }
    })
}

/// Prints the table row of one contrast (and each suggestion on stderr).
fn report(name: &str, measured: &[Measured]) -> Summary {
    let summary = Summary::of(measured);
    println!("{}", summary.row(name));
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
    summary
}

#[test]
fn suggestions_on_head_mri_meet_the_issue_targets() {
    let f = fixture();
    let params = SuggestParams::default();
    println!("{}", Summary::header("fixed contrast"));
    let same = report("same (T1)", &f.case.measure(&f.case.fixed, &f.points, &params));
    let remapped = report("remapped |v − c|^0.7", &f.case.measure(&f.case.fixed_remapped, &f.points, &params));
    assert!(same.median_mm <= MEDIAN_TARGET_MM, "median error {:.2} mm > {MEDIAN_TARGET_MM} mm", same.median_mm);
    assert!(same.p90_mm <= P90_TARGET_MM, "P90 error {:.2} mm > {P90_TARGET_MM} mm", same.p90_mm);
    assert!(
        remapped.median_mm <= MEDIAN_REMAPPED_TARGET_MM,
        "remapped median error {:.2} mm > {MEDIAN_REMAPPED_TARGET_MM} mm",
        remapped.median_mm
    );
    // The confidence: every suggestion off by more than 2 mm is flagged, and flagging stays the exception.
    for row in [&same, &remapped] {
        assert_eq!(row.wrong_flagged, row.wrong, "suggestions off by > 2 mm that were not flagged");
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
    let cases = f.points.iter().take(BRUTE_POINTS).map(|p| (p, &f.case.fixed));
    let remapped = f.points.iter().skip(BRUTE_POINTS).take(BRUTE_POINTS).map(|p| (p, &f.case.fixed_remapped));
    for (&p, fixed) in cases.chain(remapped) {
        let p = Point3::from_array(p);
        let matcher = PatchMatcher::new(&f.case.moving, fixed, &f.case.fixed_from_moving, p, &params).expect("matcher");
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
