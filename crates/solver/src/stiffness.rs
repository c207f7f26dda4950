//! Automatic stiffness for the TPS (issues 18 and 31): the λ of the smoothing spline (K − λI,
//! [`Regularisation::Smoothing`]) chosen by **generalised maximum likelihood** (GML; Wahba 1985, "A comparison of GCV
//! and GML for choosing the smoothing parameter in the generalized spline smoothing problem", Ann. Statist.
//! 13(4):1378–1402), the REML criterion of smoothing splines.
//!
//! With localisation noise an interpolating TPS (λ = 0) bends to pass through every noisy point; smoothing takes the
//! bends out until it starts to flatten the deformation itself. The smoothing spline is the posterior mean of a
//! Gaussian process whose prior is the kernel's, observed with white noise, and λ is the ratio of the noise's
//! variance to the prior's: GML picks the λ under which the pairs are most likely.
//!
//! # The criterion
//!
//! With the kernel K (Kᵢⱼ = |pᵢ − pⱼ|, conditionally negative definite), the affine columns P = [1 pᵢᵀ] and Q₂ an
//! orthonormal basis of the m = n − 4 directions orthogonal to them, Σ = −Q₂ᵀ K Q₂ is positive definite. With its
//! eigenvalues sᵢ and z = Vᵀ Q₂ᵀ y in its eigenvectors V, per coordinate c of the targets,
//!
//! GML(λ) = log Σ_c Σᵢ z_cᵢ² / (sᵢ + λ) + (1/m) Σᵢ log(sᵢ + λ)
//!
//! (the profile likelihood of the three coordinates, independent with one noise level). One eigendecomposition, O(n³),
//! serves every λ at O(n) each. It is computed from the projector Π = I − P(PᵀP)⁻¹Pᵀ: the eigenvectors of Π(−K)Π with
//! the m largest eigenvalues span Q₂'s columns.
//!
//! The leave-one-out choice this module made before (Wahba's ordinary cross-validation, each λ judged by the closed
//! form of [`tps::leave_one_out`], Rippa 1999) under-smoothed 50 pairs with 2 mm of noise: on a case of the issue's
//! it was 16 % worse than the best λ. Cross-validation scores of few noisy pairs are flat and noisy near their minimum;
//! GML's is smooth in λ, and Wahba's comparison finds it the more stable of the two at small n. The choice still
//! reports the leave-one-out errors at λ = 0 and at the chosen λ, which the window shows.
//!
//! # Search
//!
//! GML is evaluated at λ = 0 and at a geometric grid from
//! [`LAMBDA_MIN`] to [`LAMBDA_MAX`] with [`PER_DECADE`] values a decade (λ is in the kernel's unit, mm, like the
//! window's slider), and the best grid value is refined by a golden-section search in log λ over its two
//! neighbouring grid cells. λ = 0 wins when nothing beats it by more than a millionth (where leave-one-out cannot
//! tell the λ apart, round-off does not choose).

use nalgebra::{DMatrix, SymmetricEigen};
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

/// The λ chosen, with the leave-one-out errors it gives.
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
    /// λ values at which the criterion was evaluated.
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

/// The spectrum of the pairs' kernel in the non-affine directions (module docs): the eigenvalues sᵢ of
/// Σ = −Q₂ᵀ K Q₂ and the targets' coordinates z in its eigenvectors, one `[f64; 3]` per eigenvalue.
fn spectrum<To: Space, From: Space>(src: &[Point3<From>], dst: &[Point3<To>]) -> Result<(Vec<f64>, Vec<[f64; 3]>)> {
    let n = src.len();
    if n != dst.len() || n < 5 {
        return Err(SolverError::Degenerate(format!("{n} pairs: the smoothing needs at least 5")));
    }
    let p = DMatrix::from_fn(n, 4, |i, c| if c == 0 { 1.0 } else { src[i].coords()[c - 1] });
    let gram = (p.transpose() * &p)
        .try_inverse()
        .ok_or_else(|| SolverError::Degenerate("the fixed points are coplanar: no stiffness can be chosen".into()))?;
    let projector = DMatrix::identity(n, n) - &p * gram * p.transpose();
    let minus_k = DMatrix::from_fn(n, n, |i, j| -src[i].distance(&src[j]));
    let sigma = &projector * minus_k * &projector;
    let eigen = SymmetricEigen::new(sigma);
    // The m = n − 4 largest eigenvalues are Σ's; the 4 left are the affine directions' zeros.
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_by(|&a, &b| eigen.eigenvalues[b].total_cmp(&eigen.eigenvalues[a]));
    let y = DMatrix::from_fn(n, 3, |i, c| dst[i].coords()[c]);
    let mut values = Vec::with_capacity(n - 4);
    let mut coordinates = Vec::with_capacity(n - 4);
    for &k in order.iter().take(n - 4) {
        let s = eigen.eigenvalues[k];
        if !(s.is_finite() && s > 0.0) {
            return Err(SolverError::Degenerate(
                "two fixed points coincide: the kernel is singular, no stiffness can be chosen".into(),
            ));
        }
        let v = eigen.eigenvectors.column(k);
        values.push(s);
        coordinates.push(std::array::from_fn(|c| v.dot(&y.column(c))));
    }
    Ok((values, coordinates))
}

/// GML(λ) over the spectrum (module docs).
fn gml(values: &[f64], coordinates: &[[f64; 3]], lambda: f64) -> f64 {
    let fit: f64 =
        values.iter().zip(coordinates).map(|(s, z)| (z[0] * z[0] + z[1] * z[1] + z[2] * z[2]) / (s + lambda)).sum();
    let log_det: f64 = values.iter().map(|s| (s + lambda).ln()).sum();
    fit.ln() + log_det / values.len() as f64
}

/// The λ that maximises the pairs' likelihood under the smoothing TPS fitted on `src` → `dst` (GML, module docs), with
/// the leave-one-out errors at λ = 0 and at the choice.
///
/// # Errors
/// What [`loo_rms`] refuses (too few pairs, coplanar points, non-finite coordinates).
pub fn choose_stiffness<To: Space, From: Space>(src: &[Point3<From>], dst: &[Point3<To>]) -> Result<StiffnessChoice> {
    let (at_zero, pairs) = loo_rms(src, dst, 0.0)?;
    let (values, coordinates) = spectrum(src, dst)?;
    let mut evaluations = 1;
    let gml_at_zero = gml(&values, &coordinates, 0.0);
    let mut score = |lambda: f64| -> Result<f64> {
        evaluations += 1;
        // Relative to λ = 0 and positive, so MIN_GAIN reads as a fraction as it did for the leave-one-out score.
        Ok((gml(&values, &coordinates, lambda) - gml_at_zero).exp())
    };
    let decades = (LAMBDA_MAX / LAMBDA_MIN).log10().round() as usize;
    let step = std::f64::consts::LN_10 / PER_DECADE as f64;
    let grid: Vec<f64> = (0..=decades * PER_DECADE).map(|k| (LAMBDA_MIN.ln() + k as f64 * step).exp()).collect();
    let mut best = (0.0, 1.0 - MIN_GAIN);
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
    let loo_rms_mm = if best_index.is_some() { loo_rms(src, dst, best.0)?.0 } else { at_zero };
    Ok(StiffnessChoice { lambda: best.0, loo_rms_mm, loo_rms_interpolating_mm: at_zero, pairs, evaluations })
}
