//! The automatic stiffness (`stiffness::choose_stiffness`) against the best λ found by brute force: known smooth
//! warps of the MRI fixture's box (5 mm), N pairs with Gaussian localisation noise on both sides, and the TRE of the
//! fitted forward warp at 1 000 held-out points for λ = 0, for the chosen λ and for every λ of a fine grid (8 a
//! decade, 10⁻² to 10⁵ mm). The table it prints is the one in docs/accuracy.md.

#![allow(clippy::float_cmp, reason = "the noise levels are exact literals, and λ = 0 is the exact fallback")]

use crate::common;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use warpbench_io::geometry::{Point3, Space};
use warpbench_solver::stiffness::choose_stiffness;
use warpbench_solver::synthetic::{SyntheticKind, SyntheticWarp, held_out_pairs, sample_pairs};
use warpbench_solver::tps::Tps;
use warpbench_solver::{Aabb, Fixed, Moving, Warp};

const AMPLITUDE_MM: f64 = 5.0;
const HELD_OUT: usize = 1000;

/// The box of the MRI fixture's voxel centres (a head, 180 × 216 × 180 mm).
fn head_box() -> Aabb<Moving> {
    common::volume_box("nifti/avg152T1_LR_nifti.nii")
}

/// `points` moved by isotropic Gaussian noise whose 3-D RMS is `fle_mm` (σ = FLE/√3 per axis; Box–Muller).
fn jitter<S: Space>(points: &[Point3<S>], fle_mm: f64, rng: &mut ChaCha8Rng) -> Vec<Point3<S>> {
    let sigma = fle_mm / 3f64.sqrt();
    let mut normal = || {
        let (u, v): (f64, f64) = (rng.random::<f64>().max(f64::MIN_POSITIVE), rng.random());
        (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
    };
    points
        .iter()
        .map(|p| {
            let c = p.coords();
            Point3::from_array(std::array::from_fn(|a| c[a] + sigma * normal()))
        })
        .collect()
}

/// RMS of ‖f(x) − d(x)‖ over the held-out points, f the smoothing TPS with `lambda` fitted on the noisy pairs.
fn tre_rms(
    p: &[Point3<Moving>],
    q: &[Point3<Fixed>],
    lambda: f64,
    held_out: &(Vec<Point3<Moving>>, Vec<Point3<Fixed>>),
) -> f64 {
    let f = Tps::<Fixed, Moving>::fit_smoothing(p, q, lambda).expect("fit");
    let sum: f64 = held_out.0.iter().zip(&held_out.1).map(|(x, y)| f.apply(*x).distance(y).powi(2)).sum();
    (sum / held_out.0.len() as f64).sqrt()
}

#[test]
fn the_chosen_stiffness_is_near_the_best_and_never_hurts_noise_free_pairs() {
    let domain = head_box();
    let fine: Vec<f64> = std::iter::once(0.0).chain((-16..=40).map(|k| 10f64.powf(f64::from(k) / 8.0))).collect();
    let mut rows = Vec::new();
    let mut failures = Vec::new();
    for kind in [SyntheticKind::TpsRandom, SyntheticKind::Sine] {
        let warp = SyntheticWarp::new(kind, domain, AMPLITUDE_MM, 7).expect("warp");
        let held_out = held_out_pairs(&warp, domain, HELD_OUT, 7);
        for n in [50, 200] {
            let (p, q) = sample_pairs(&warp, domain, n, 7);
            for fle in [0.0, 1.0, 2.0] {
                let mut rng = ChaCha8Rng::seed_from_u64(1000 * n as u64 + (10.0 * fle) as u64);
                let (p, q) = (jitter(&p, fle, &mut rng), jitter(&q, fle, &mut rng));
                let choice = choose_stiffness(&p, &q).expect("a choice");
                let at_zero = tre_rms(&p, &q, 0.0, &held_out);
                let chosen = tre_rms(&p, &q, choice.lambda, &held_out);
                let (best_lambda, best) = fine
                    .iter()
                    .map(|&l| (l, tre_rms(&p, &q, l, &held_out)))
                    .fold((0.0, f64::INFINITY), |a, b| if b.1 < a.1 { b } else { a });
                rows.push(format!(
                    "| {} | {n} | {fle} | {:.3} | {:.3} ({:.3}) | {:.3} ({best_lambda:.3}) | {:.2} | {:.2} |",
                    kind.name(),
                    at_zero,
                    chosen,
                    choice.lambda,
                    best,
                    chosen / best,
                    chosen / at_zero
                ));
                let case = format!("{} N={n} FLE={fle}", kind.name());
                if fle > 0.0 && chosen > 1.10 * best {
                    failures.push(format!("{case}: TRE {chosen:.3} (λ {:.3}), best {best:.3}", choice.lambda));
                }
                // Where smoothing matters most (many noisy pairs) the choice must make a real difference.
                if fle == 2.0 && n == 200 && chosen > 0.8 * at_zero {
                    failures.push(format!("{case}: TRE {chosen:.3} against {at_zero:.3} at λ = 0"));
                }
                if fle == 0.0 && chosen > 1.05 * at_zero {
                    failures.push(format!("{case}: noise-free TRE {chosen:.3} against {at_zero:.3} at λ = 0"));
                }
            }
        }
    }
    eprintln!("| warp | N | FLE (mm) | TRE λ=0 | TRE auto (λ) | best TRE (λ) | auto / best | auto / λ=0 |");
    eprintln!("|---|---|---|---|---|---|---|---|");
    for r in &rows {
        eprintln!("{r}");
    }
    assert!(failures.is_empty(), "{failures:#?}");
}

/// Too few pairs (four, spread in 3-D) are refused with the solver's own message, not a guess.
#[test]
fn too_few_pairs_are_refused() {
    let p: Vec<Point3<Moving>> =
        [[0.0, 0.0, 0.0], [10.0, 0.0, 0.0], [0.0, 10.0, 0.0], [0.0, 0.0, 10.0]].map(Point3::from_array).to_vec();
    let q: Vec<Point3<Fixed>> = p.iter().map(|x| Point3::from_array(x.coords())).collect();
    let e = choose_stiffness(&p, &q).expect_err("four pairs");
    assert!(e.to_string().contains("pairs"), "{e}");
}

/// Five pairs: each refit has four, which a TPS fits affinely whatever λ is, so leave-one-out cannot tell the λ apart
/// and the choice stays at interpolation.
#[test]
fn a_choice_leave_one_out_cannot_make_stays_at_zero() {
    let q: Vec<Point3<Fixed>> =
        [[0.0, 18.0, 18.0], [40.0, 18.0, 18.0], [-40.0, 30.0, 0.0], [0.0, 70.0, 40.0], [10.0, -40.0, 18.0]]
            .map(Point3::from_array)
            .to_vec();
    let p: Vec<Point3<Moving>> = q
        .iter()
        .enumerate()
        .map(|(i, x)| {
            let c = x.coords();
            Point3::from_array([c[0] + 3.0, c[1] - 2.0 + i as f64, c[2] + 1.5])
        })
        .collect();
    let choice = choose_stiffness(&q, &p).expect("a choice");
    assert!(choice.lambda == 0.0 && choice.loo_rms_mm == choice.loo_rms_interpolating_mm, "{choice:?}");
}

/// Cases the choice was not designed on (issue 31, item 4): six warp families, three seeds each, N = 50 and 2 mm of
/// noise on both sides. The TRE at the chosen λ against the best of the fine grid: measured 2026-12-05, mean 1.034,
/// median 1.014, worst 1.253 (a single local bump, seed 13, where little of the warp reaches the pairs); the
/// leave-one-out choice used before gave mean 1.042, median 1.022, worst 1.350 on the same cases.
#[test]
fn on_cases_it_was_not_made_on_the_chosen_stiffness_stays_near_the_best() {
    let domain = head_box();
    let fine: Vec<f64> = std::iter::once(0.0).chain((-16..=40).map(|k| 10f64.powf(f64::from(k) / 8.0))).collect();
    let mut ratios = Vec::new();
    let kinds = [
        SyntheticKind::Bump,
        SyntheticKind::BSplineRandom,
        SyntheticKind::Twist,
        SyntheticKind::Bend,
        SyntheticKind::TpsRandom,
        SyntheticKind::Sine,
    ];
    for kind in kinds {
        for seed in [11u64, 12, 13] {
            let warp = SyntheticWarp::new(kind, domain, AMPLITUDE_MM, seed).expect("warp");
            let held_out = held_out_pairs(&warp, domain, HELD_OUT, seed);
            let (p, q) = sample_pairs(&warp, domain, 50, seed);
            let mut rng = ChaCha8Rng::seed_from_u64(seed * 77);
            let (p, q) = (jitter(&p, 2.0, &mut rng), jitter(&q, 2.0, &mut rng));
            let choice = choose_stiffness(&p, &q).expect("a choice");
            let chosen = tre_rms(&p, &q, choice.lambda, &held_out);
            let best = fine.iter().map(|&l| tre_rms(&p, &q, l, &held_out)).fold(f64::INFINITY, f64::min);
            eprintln!(
                "{} seed {seed}: auto {chosen:.3} (λ {:.1}), best {best:.3}: {:.3}",
                kind.name(),
                choice.lambda,
                chosen / best
            );
            ratios.push(chosen / best);
        }
    }
    ratios.sort_by(f64::total_cmp);
    let mean = ratios.iter().sum::<f64>() / ratios.len() as f64;
    let (median, worst) = (ratios[ratios.len() / 2], ratios[ratios.len() - 1]);
    eprintln!("mean {mean:.3}, median {median:.3}, worst {worst:.3}");
    assert!(mean <= 1.05 && median <= 1.03, "mean {mean:.3}, median {median:.3}");
    assert!(worst <= 1.3, "worst {worst:.3}");
}
