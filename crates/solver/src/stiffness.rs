//! Automatic stiffness for the TPS (issue 18 item 3): the λ of the smoothing spline (K − λI,
//! [`Regularisation::Smoothing`]) that minimises the leave-one-out error of the pairs, each λ judged from one solve by
//! the closed form of [`tps::leave_one_out`] (Rippa 1999).
//!
//! With localisation noise an interpolating TPS (λ = 0) bends to pass through every noisy point, and leaving a pair
//! out shows it: the refit misses the left-out point by the noise and by the bends the noise put in. Smoothing takes
//! the bends out, so the leave-one-out error first falls as λ grows and then rises once the smoothing also flattens
//! the deformation itself; its minimum is Wahba's ordinary cross-validation choice of λ. With noise-free pairs the
//! interpolant predicts a left-out pair best and the choice stays at or near λ = 0.
//!
//! # Search
//!
//! The score of λ is the RMS of the leave-one-out errors over the pairs whose refit is defined (which pairs those
//! are depends on the geometry only, not on λ). It is evaluated at λ = 0 and at a geometric grid from
//! [`LAMBDA_MIN`] to [`LAMBDA_MAX`] with [`PER_DECADE`] values a decade (λ is in the kernel's unit, mm, like the
//! window's slider), and the best grid value is refined by a golden-section search in log λ over its two
//! neighbouring grid cells. λ = 0 wins when nothing beats it by more than a millionth (where leave-one-out cannot
//! tell the λ apart, round-off does not choose).

use warpbench_io::geometry::{Point3, Space};

use crate::tps::{self, Regularisation};
use crate::{Result, SolverError};

/// The smallest non-zero λ tried, mm.
pub const LAMBDA_MIN: f64 = 1e-3;
/// The largest λ tried, mm: beyond it a TPS over a head is affine to well under a millimetre.
pub const LAMBDA_MAX: f64 = 1e5;
/// Grid values per decade.
pub const PER_DECADE: usize = 4;
/// Golden-section steps after the grid: the bracket shrinks by 0.618 each, to ~0.3 % of a grid cell in log λ.
const REFINE_STEPS: usize = 12;
/// A λ > 0 must lower the score by more than this fraction to be chosen over interpolating: where leave-one-out
/// cannot tell the λ apart (five pairs, whose refits are affine whatever λ is), round-off must not pick one.
const MIN_GAIN: f64 = 1e-6;

/// The λ chosen, with what it was chosen on.
#[derive(Clone, Debug, PartialEq)]
pub struct StiffnessChoice {
    /// The smoothing spline's λ (0: interpolate), mm.
    pub lambda: f64,
    /// RMS leave-one-out error at `lambda`, mm.
    pub loo_rms_mm: f64,
    /// RMS leave-one-out error of the interpolating TPS (λ = 0), mm, for comparison.
    pub loo_rms_interpolating_mm: f64,
    /// Pairs whose leave-one-out error is defined (the RMS is over these).
    pub pairs: usize,
    /// λ values evaluated.
    pub evaluations: usize,
}

/// The RMS leave-one-out error of the smoothing TPS with `lambda` fitted on `src` → `dst`, and how many pairs it is
/// taken over.
///
/// # Errors
/// What [`tps::leave_one_out`] refuses, and a set of pairs none of which can be left out.
pub fn loo_rms<To: Space, From: Space>(src: &[Point3<From>], dst: &[Point3<To>], lambda: f64) -> Result<(f64, usize)> {
    let errors = tps::leave_one_out(src, dst, Regularisation::Smoothing(lambda))?;
    let (sum, n) = errors.iter().flatten().fold((0.0, 0usize), |(s, n), e| (s + e * e, n + 1));
    if n == 0 {
        return Err(SolverError::Degenerate(format!(
            "{} pairs: leaving any one out leaves a set that a TPS refit refuses (too few pairs, or coplanar \
             points), so no stiffness can be chosen by leave-one-out",
            src.len()
        )));
    }
    Ok(((sum / n as f64).sqrt(), n))
}

/// The λ that minimises the RMS leave-one-out error of the smoothing TPS fitted on `src` → `dst` (module docs).
///
/// # Errors
/// What [`loo_rms`] refuses (too few pairs, coplanar points, non-finite coordinates).
pub fn choose_stiffness<To: Space, From: Space>(src: &[Point3<From>], dst: &[Point3<To>]) -> Result<StiffnessChoice> {
    let (at_zero, pairs) = loo_rms(src, dst, 0.0)?;
    let mut evaluations = 1;
    let mut score = |lambda: f64| -> Result<f64> {
        evaluations += 1;
        Ok(loo_rms(src, dst, lambda)?.0)
    };
    let decades = (LAMBDA_MAX / LAMBDA_MIN).log10().round() as usize;
    let step = std::f64::consts::LN_10 / PER_DECADE as f64;
    let grid: Vec<f64> = (0..=decades * PER_DECADE).map(|k| (LAMBDA_MIN.ln() + k as f64 * step).exp()).collect();
    let mut best = (0.0, at_zero * (1.0 - MIN_GAIN));
    let mut best_index = None;
    for (k, &lambda) in grid.iter().enumerate() {
        let s = score(lambda)?;
        if s < best.1 {
            best = (lambda, s);
            best_index = Some(k);
        }
    }
    if let Some(k) = best_index {
        // Golden section in t = ln λ over the best grid value's two cells.
        let centre = grid[k].ln();
        let (mut a, mut b) = (centre - step, centre + step);
        let ratio = (5f64.sqrt() - 1.0) / 2.0;
        let (mut c, mut d) = (b - ratio * (b - a), a + ratio * (b - a));
        let (mut fc, mut fd) = (score(c.exp())?, score(d.exp())?);
        for _ in 0..REFINE_STEPS {
            if fc < fd {
                (b, d, fd) = (d, c, fc);
                c = b - ratio * (b - a);
                fc = score(c.exp())?;
            } else {
                (a, c, fc) = (c, d, fd);
                d = a + ratio * (b - a);
                fd = score(d.exp())?;
            }
        }
        for (t, f) in [(c, fc), (d, fd)] {
            if f < best.1 {
                best = (t.exp(), f);
            }
        }
    }
    let loo_rms_mm = if best_index.is_some() { best.1 } else { at_zero };
    Ok(StiffnessChoice { lambda: best.0, loo_rms_mm, loo_rms_interpolating_mm: at_zero, pairs, evaluations })
}
