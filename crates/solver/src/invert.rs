//! An approximate inverse u ≈ d⁻¹ of a forward warp d by scattered-data interpolation, as Brunet,
//! Nowak & Gleicher 2006 do when only the forward deformation is known (§3, §3.3: "In cases where only
//! the forward deformation function is available, we use scattered data interpolation to approximate
//! the inverse"; §5.1 for the landmark warps it serves). The interpolant is the hierarchical B-spline of
//! [`crate::bspline`] (Lee, Wolberg & Shin 1997).
//!
//! 1. **Reversed samples.** Sample d on a regular grid x_j over the source box (`domain_from`); the pairs
//!    (d(x_j), x_j) are scattered samples of u. Fit u₀(y) = y + D₀(y) to those whose d(x_j) fall in the
//!    target box (`domain_to`) by multilevel B-spline approximation.
//! 2. **Fixed-point refinement.** On a regular grid y_k over `domain_to`, correct u towards a zero of
//!    d(u(y)) − y with one quasi-Newton step per iteration,
//!
//!    u_{k+1}(y) = u_k(y) − J_{u_k}(y) (d(u_k(y)) − y),
//!
//!    where J_{u_k} = I + ∂D_k/∂y is the current inverse's own analytic Jacobian, an estimate of
//!    J_d(u_k(y))⁻¹ that costs no extra evaluation of d. (With J_u = I this is the plain fixed-point
//!    iteration u_{k+1} = u_k − (d(u_k) − y), which converges only at the rate ‖∂D_d‖; the quasi-Newton
//!    step converges at the rate ‖I − J_u J_d‖, which the fit makes small.) The correction field is fitted
//!    on the grid (separably, [`HierarchicalBSpline::fit_grid_raw`]) and added to u's lattice by B-spline
//!    refinement. Fitting the *correction*, not the corrected positions, makes the approximation error
//!    of each refit proportional to the (shrinking) correction, so the iteration does not stall at the
//!    first fit's error.
//! 3. **Report.** The inverse-consistency error ‖d(u(y)) − y‖ over a cell-centred grid of y in
//!    `domain_to` (offset from the fitting grid), as RMS and max, after every iteration.
//!
//! Outside `domain_to`, u follows the B-spline rule: its displacement is held at the box's boundary value.

use rayon::prelude::*;
use warpbench_io::geometry::Space;

use crate::bspline::{BSplineParams, ControlLattice, FitReport, HierarchicalBSpline, RegularGrid};
use crate::spaces::Aabb;
use crate::warp::Parallelism;
use crate::{SolverError, Warp};

/// The most points a sampling grid of [`InvertParams`] may have: 256³.
pub const MAX_SAMPLES: usize = 1 << 24;

/// Parameters of [`invert`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct InvertParams {
    /// Grid over the source box on which d is sampled for the initial scattered fit.
    pub source_samples: [usize; 3],
    /// Grid of targets y over the target box on which the fixed-point corrections are made and fitted.
    pub target_samples: [usize; 3],
    /// The inverse's lattice: over the target box, with these cells and levels; its tolerance stops each
    /// (initial or correction) fit early.
    pub bspline: BSplineParams,
    /// The most fixed-point iterations (each: one correction and one refit).
    pub iterations: usize,
    /// Stop once the max inverse-consistency error on the check grid is below this (mm).
    pub tolerance_mm: f64,
    /// Cell-centred grid of y over the target box on which [`InverseReport`] is measured.
    pub check_samples: [usize; 3],
    /// Threads for evaluating d and the grid kernels.
    pub par: Parallelism,
}

impl Default for InvertParams {
    fn default() -> Self {
        Self {
            source_samples: [16, 16, 16],
            target_samples: [64, 64, 64],
            bspline: BSplineParams { coarsest: [4, 4, 4], levels: 5, tolerance_mm: 1e-3 },
            iterations: 4,
            tolerance_mm: 0.01,
            check_samples: [32, 32, 32],
            par: Parallelism::Rayon,
        }
    }
}

/// How well the inverse undoes the forward warp: ‖d(u(y)) − y‖ over the check grid, mm.
#[derive(Clone, Debug, PartialEq)]
pub struct InverseReport {
    /// Root-mean-square inverse-consistency error after the last iteration, mm.
    pub rms_mm: f64,
    /// Largest inverse-consistency error after the last iteration, mm.
    pub max_mm: f64,
    /// Fixed-point iterations done.
    pub iterations: usize,
    /// RMS error after the initial fit (entry 0) and after each iteration, mm.
    pub rms_history_mm: Vec<f64>,
    /// Max error after the initial fit (entry 0) and after each iteration, mm.
    pub max_history_mm: Vec<f64>,
    /// Points of the check grid.
    pub check_points: usize,
    /// Reversed samples (d(x_j), x_j) that fell in the target box and seeded the initial fit.
    pub initial_samples: usize,
    /// The initial scattered fit.
    pub initial_fit: FitReport,
}

fn check_grid_dims(name: &str, dims: [usize; 3]) -> crate::Result<()> {
    let count = dims.iter().try_fold(1usize, |acc, &d| acc.checked_mul(d));
    match count {
        Some(n) if n > 0 && n <= MAX_SAMPLES => Ok(()),
        _ => Err(SolverError::InvalidParameter(format!(
            "{name} {dims:?} must have 1..={MAX_SAMPLES} points and none of its sizes 0"
        ))),
    }
}

fn check_box<S: Space>(name: &str, b: &Aabb<S>) -> crate::Result<()> {
    if b.is_valid() && b.min.is_finite() && b.max.is_finite() {
        Ok(())
    } else {
        Err(SolverError::InvalidParameter(format!("{name} must be finite with positive size, got {b:?}")))
    }
}

/// Evaluates d at every point, on the threads `par` allows.
fn apply_all<To: Space, From: Space, W: Warp<To, From>>(forward: &W, points: &mut [[f64; 3]], par: Parallelism) {
    match par {
        Parallelism::Sequential => points.iter_mut().for_each(|p| *p = forward.apply_raw(*p)),
        Parallelism::Rayon => points.par_iter_mut().with_min_len(256).for_each(|p| *p = forward.apply_raw(*p)),
    }
}

fn non_finite(what: &str, index: usize) -> SolverError {
    SolverError::Degenerate(format!("the forward warp returned a non-finite point at {what} sample {index}"))
}

/// ‖d(u(y)) − y‖ over `grid`: (rms, max). `scratch` holds u(y) and then d(u(y)).
fn consistency<To: Space, From: Space, W: Warp<To, From>>(
    forward: &W,
    lattice: &ControlLattice,
    grid: &RegularGrid,
    scratch: &mut [[f64; 3]],
    par: Parallelism,
) -> crate::Result<(f64, f64)> {
    lattice.sample_grid_into(grid, true, scratch, par)?;
    apply_all(forward, scratch, par);
    let mut sum = 0.0;
    let mut max = 0.0_f64;
    for (index, d) in scratch.iter().enumerate() {
        let y = grid.point(index);
        let e2 = (d[0] - y[0]).powi(2) + (d[1] - y[1]).powi(2) + (d[2] - y[2]).powi(2);
        if !e2.is_finite() {
            return Err(non_finite("check", index));
        }
        sum += e2;
        max = max.max(e2.sqrt());
    }
    Ok(((sum / scratch.len() as f64).sqrt(), max))
}

/// An approximate inverse of `forward` (d: `From` → `To`) over `domain_to`, with its inverse-consistency
/// report (see the module docs). `domain_from` is where d is sampled for the initial fit: a box in `From`
/// whose image covers `domain_to` well (e.g. the moving volume's bounds when inverting `fixed_from_moving`).
pub fn invert<To: Space, From: Space, W: Warp<To, From>>(
    forward: &W,
    domain_from: Aabb<From>,
    domain_to: Aabb<To>,
    params: &InvertParams,
) -> crate::Result<(HierarchicalBSpline<From, To>, InverseReport)> {
    check_box(&format!("the inverse's {} box", From::NAME), &domain_from)?;
    check_box(&format!("the inverse's {} box", To::NAME), &domain_to)?;
    check_grid_dims(&format!("{} samples", From::NAME), params.source_samples)?;
    check_grid_dims(&format!("{} samples", To::NAME), params.target_samples)?;
    check_grid_dims("check samples", params.check_samples)?;
    params.bspline.finest_cells()?;
    if !(params.tolerance_mm.is_finite() && params.tolerance_mm >= 0.0) {
        return Err(SolverError::InvalidParameter(format!(
            "inverse tolerance must be finite and ≥ 0 mm, got {}",
            params.tolerance_mm
        )));
    }
    let par = params.par;
    let (lo_to, hi_to) = (domain_to.min.coords(), domain_to.max.coords());

    // 1. Reversed samples d(x_j) → x_j.
    let source_grid = RegularGrid::spanning(domain_from.min.coords(), domain_from.max.coords(), params.source_samples);
    let mut images: Vec<[f64; 3]> = (0..source_grid.len()).map(|j| source_grid.point(j)).collect();
    apply_all(forward, &mut images, par);
    let mut points = Vec::with_capacity(images.len());
    let mut displacements = Vec::with_capacity(images.len());
    for (j, y) in images.iter().enumerate() {
        if !y.iter().all(|v| v.is_finite()) {
            return Err(non_finite(From::NAME, j));
        }
        if (0..3).all(|a| y[a] >= lo_to[a] && y[a] <= hi_to[a]) {
            let x = source_grid.point(j);
            points.push(*y);
            displacements.push([x[0] - y[0], x[1] - y[1], x[2] - y[2]]);
        }
    }
    drop(images);
    let initial =
        HierarchicalBSpline::<From, To>::fit_displacements_raw(&points, &displacements, domain_to, &params.bspline)?;
    let initial_fit = *initial.fit_report();
    let initial_samples = points.len();
    drop((points, displacements));
    let mut lattice = initial.into_lattice();

    // 2. Fixed-point (quasi-Newton) refinement on the target grid.
    let target_grid = RegularGrid::spanning(lo_to, hi_to, params.target_samples);
    let check_grid = RegularGrid::cell_centred(lo_to, hi_to, params.check_samples);
    let mut check_scratch = vec![[0.0; 3]; check_grid.len()];
    let (rms, max) = consistency(forward, &lattice, &check_grid, &mut check_scratch, par)?;
    let mut rms_history_mm = vec![rms];
    let mut max_history_mm = vec![max];
    let mut positions = vec![[0.0; 3]; target_grid.len()];
    let mut jacobians = vec![[[0.0; 3]; 3]; target_grid.len()];
    let mut iterations = 0;
    let mut last_fit = initial_fit;
    while iterations < params.iterations && max_history_mm.last().is_some_and(|&m| m >= params.tolerance_mm) {
        lattice.sample_grid_into(&target_grid, true, &mut positions, par)?;
        lattice.sample_jacobian_grid_into(&target_grid, &mut jacobians, par)?;
        // positions: u(y) → d(u(y)) → correction −J_u (d(u(y)) − y).
        apply_all(forward, &mut positions, par);
        let correct = |(index, (p, j)): (usize, (&mut [f64; 3], &[[f64; 3]; 3]))| {
            let y = target_grid.point(index);
            let e = [p[0] - y[0], p[1] - y[1], p[2] - y[2]];
            for r in 0..3 {
                // J_u = I + ∂D.
                p[r] = -(e[r] + j[r][0] * e[0] + j[r][1] * e[1] + j[r][2] * e[2]);
            }
        };
        match par {
            Parallelism::Sequential => positions.iter_mut().zip(&jacobians).enumerate().for_each(correct),
            Parallelism::Rayon => positions.par_iter_mut().zip(&jacobians).enumerate().for_each(correct),
        }
        if let Some(index) = positions.iter().position(|p| !p.iter().all(|v| v.is_finite())) {
            return Err(non_finite(To::NAME, index));
        }
        // Inexact Newton: the next iteration corrects what this fit leaves, so fitting the correction to a
        // tenth of its size suffices (and skips levels or passes that would not change the outcome).
        let largest = positions.iter().map(|c| (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt()).fold(0.0, f64::max);
        let fit_params =
            BSplineParams { tolerance_mm: params.bspline.tolerance_mm.max(0.1 * largest), ..params.bspline };
        let correction =
            HierarchicalBSpline::<From, To>::fit_grid_raw(&target_grid, &positions, domain_to, &fit_params, par)?;
        last_fit = *correction.fit_report();
        lattice = lattice.add(correction.lattice())?;
        iterations += 1;
        let (rms, max) = consistency(forward, &lattice, &check_grid, &mut check_scratch, par)?;
        rms_history_mm.push(rms);
        max_history_mm.push(max);
    }
    let report = InverseReport {
        rms_mm: rms_history_mm.last().copied().unwrap_or(0.0),
        max_mm: max_history_mm.last().copied().unwrap_or(0.0),
        iterations,
        rms_history_mm,
        max_history_mm,
        check_points: check_grid.len(),
        initial_samples,
        initial_fit,
    };
    let cells = lattice.cells();
    let fit = FitReport { cells, ..last_fit };
    Ok((HierarchicalBSpline::from_lattice(lattice, fit), report))
}
