//! The one way the app fits a warp: landmark pairs and a [`Method`] give the pull-back u = `moving_from_fixed` and
//! the forward warp d = `fixed_from_moving` as [`FittedWarp`]s, and beside them what the GPU takes of the pull-back.
//!
//! Pairs are always given as two aligned lists, the fixed points qᵢ and the moving points pᵢ. The pull-back is
//! fitted on the reversed pairs (qᵢ → pᵢ) over the fixed box, the forward warp on (pᵢ → qᵢ) over the moving box
//! ([`pullback`], [`forward`]), so each is exact (or, for the approximating methods, as close) at its own landmarks.
//!
//! - The window and the drag bench fit both directions on every landmark change: [`fit_warp`] samples the pull-back
//!   into a control texture on the CPU, [`fit_warp_on_gpu`] has the GPU evaluate it. Their errors read
//!   `N active pairs; <method> needs K` and `<method>: <problem>`.
//! - The CLI's pair subcommands fit pairs checked against the volumes ([`Correspondences`]): [`pullback_of`] and
//!   [`forward_of`], whose errors read `<landmark file>: fitting the <method> warp: <problem>` with the pairs
//!   numbered as in the file ([`fit_error`]), and [`fit_warnings`].
//! - What the GPU takes: [`control_texture`] (the pull-back sampled over a box; a B-spline through its lattice's
//!   separable sampler), [`TpsParts`] (a TPS, evaluated exactly per voxel by the export or into a control texture by
//!   the GPU), [`lattice_desc`] (a B-spline's lattice) and [`control_grid_desc`].

use std::fmt;

use anyhow::anyhow;
use warpbench_gpu::{BSplineDesc, ControlGridDesc, LatticeDesc, PreparedControl, TpsDesc};
use warpbench_io::geometry::Point3;
use warpbench_solver::SolverError;
use warpbench_solver::bspline::HierarchicalBSpline;
use warpbench_solver::control::{ControlGrid, ControlTexture};
use warpbench_solver::method::{FittedWarp, Method};
use warpbench_solver::spaces::{Aabb, Fixed, Moving};
use warpbench_solver::tps::Tps;

use crate::gui::viewer::Viewer;
use crate::inputs::{self, Correspondences};
use crate::scene;

/// The pull-back u = `moving_from_fixed` fitted on the reversed pairs (`fixed[i]` → `moving[i]`) over `fixed_box`.
pub fn pullback(
    method: &Method,
    fixed: &[Point3<Fixed>],
    moving: &[Point3<Moving>],
    fixed_box: Aabb<Fixed>,
) -> Result<FittedWarp<Moving, Fixed>, SolverError> {
    method.fit(fixed, moving, fixed_box)
}

/// The forward warp d = `fixed_from_moving` (where a moving point appears in the deformed view), fitted on the pairs
/// (`moving[i]` → `fixed[i]`) over `moving_box`.
pub fn forward(
    method: &Method,
    fixed: &[Point3<Fixed>],
    moving: &[Point3<Moving>],
    moving_box: Aabb<Moving>,
) -> Result<FittedWarp<Fixed, Moving>, SolverError> {
    method.fit(moving, fixed, moving_box)
}

/// The warp fitted on the active pairs in both directions: the pull-back the renderer uses and the forward map that
/// places the moving glyphs.
pub struct Fitted {
    /// u = moving_from_fixed: where a point of the deformed view comes from in the moving volume.
    pub pullback: FittedWarp<Moving, Fixed>,
    /// d = fixed_from_moving.
    pub forward: FittedWarp<Fixed, Moving>,
    /// How many pairs both were fitted on.
    pub pairs: usize,
}

impl fmt::Debug for Fitted {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Fitted").field("pairs", &self.pairs).finish_non_exhaustive()
    }
}

/// What one landmark change costs before the frame: the pull-back and the forward warp fitted on the pairs
/// (`fixed[i]` ↔ `moving[i]`), and the pull-back sampled into a `grid_n`³ control texture over the fixed box, ready to
/// upload. The window runs this on every drag event; `benches/drag.rs` times it with the frame.
///
/// # Errors
/// Too few pairs for the method, a fit that fails (degenerate pairs), or a control texture that cannot be made.
pub fn fit_warp(
    method: &Method,
    fixed: &[Point3<Fixed>],
    moving: &[Point3<Moving>],
    (fixed_box, moving_box): (Aabb<Fixed>, Aabb<Moving>),
    grid_n: usize,
    float32_filterable: bool,
) -> anyhow::Result<(Fitted, PreparedControl)> {
    enough_pairs(method, moving.len())?;
    let pullback = pullback(method, fixed, moving, fixed_box).map_err(|e| anyhow!("{method}: {e}"))?;
    let forward = forward(method, fixed, moving, moving_box).map_err(|e| anyhow!("{method}: {e}"))?;
    let (grid, texture) = control_texture(&pullback, fixed_box, grid_n)?;
    let prepared = PreparedControl::prepare(&scene::control_desc(&grid, &texture), float32_filterable)
        .map_err(|e| anyhow!("{e}"))?;
    Ok((Fitted { pullback, forward, pairs: moving.len() }, prepared))
}

/// Refuses fewer pairs than `method` needs, in the window's words.
fn enough_pairs(method: &Method, pairs: usize) -> anyhow::Result<()> {
    let need = inputs::min_pairs(method);
    if pairs < need {
        return Err(anyhow!("{pairs} active pairs; {method} needs {need}"));
    }
    Ok(())
}

/// Whether [`fit_warp_on_gpu`] can evaluate `method`'s control texture on the GPU: a TPS or a hierarchical B-spline.
#[must_use]
pub fn gpu_evaluates(method: &Method) -> bool {
    matches!(method, Method::Tps { .. } | Method::BSpline(_))
}

fn not_on_gpu(method: &Method) -> anyhow::Error {
    anyhow!("the GPU evaluates TPS and B-spline control textures only, not {method}")
}

/// [`fit_warp`] with the control texture evaluated on the GPU ([`warpbench_gpu::ControlEvalPass`], into `viewer`'s
/// texture) instead of sampled on the CPU and uploaded: the same grid, the same function (a TPS evaluated in f32
/// about the box's centre, or the B-spline's refined lattice).
///
/// # Errors
/// Not a TPS or a hierarchical B-spline, too few pairs, a fit that fails, or the GPU pass failing.
pub fn fit_warp_on_gpu(
    method: &Method,
    fixed: &[Point3<Fixed>],
    moving: &[Point3<Moving>],
    (fixed_box, moving_box): (Aabb<Fixed>, Aabb<Moving>),
    grid_n: usize,
    viewer: &mut Viewer,
) -> anyhow::Result<Fitted> {
    if !gpu_evaluates(method) {
        return Err(not_on_gpu(method));
    }
    enough_pairs(method, moving.len())?;
    let desc = control_grid_desc(&scene::control_grid(fixed_box, grid_n)?);
    let forward = forward(method, fixed, moving, moving_box).map_err(|e| anyhow!("{method}: {e}"))?;
    let pullback = pullback(method, fixed, moving, fixed_box).map_err(|e| anyhow!("{method}: {e}"))?;
    match &pullback {
        FittedWarp::Tps(tps) => viewer.evaluate_control_tps(&TpsParts::new(tps).desc(), &desc)?,
        FittedWarp::BSpline(spline) => {
            viewer.evaluate_control_bspline(&BSplineDesc { lattices: &[lattice_desc(spline)] }, &desc)?;
        }
        FittedWarp::Linear(_) => return Err(not_on_gpu(method)),
    }
    Ok(Fitted { pullback, forward, pairs: moving.len() })
}

/// The message for a fit of `c` that failed with `e`: `<landmark file>: fitting the <method> warp: <problem>`, the
/// pairs numbered as in the file.
#[must_use]
pub fn fit_error(method: &Method, c: &Correspondences, e: SolverError) -> anyhow::Error {
    let e = e.renumber(|n| c.file_number(n));
    anyhow!("{}: fitting the {method} warp: {e}", c.origin)
}

/// What the solver finds suspicious in `c` for `method` (a pair given twice, a nearly flat set of points), as
/// messages: `<landmark file>: <warning>`, the pairs numbered as in the file. The same for either direction of the
/// fit; empty when there is nothing to say or when the fit will refuse the pairs (its error says why). The CLI
/// prints each as `warning: …` on stderr.
#[must_use]
pub fn fit_warnings(method: &Method, c: &Correspondences) -> Vec<String> {
    method
        .check(&c.fixed, &c.moving)
        .unwrap_or_default()
        .into_iter()
        .map(|w| format!("{}: {}", c.origin, w.renumber(|n| c.file_number(n))))
        .collect()
}

/// [`pullback`] on checked pairs, its error in the CLI's words ([`fit_error`]).
pub fn pullback_of(
    method: &Method,
    c: &Correspondences,
    fixed_box: Aabb<Fixed>,
) -> anyhow::Result<FittedWarp<Moving, Fixed>> {
    pullback(method, &c.fixed, &c.moving, fixed_box).map_err(|e| fit_error(method, c, e))
}

/// [`forward`] on checked pairs, its error in the CLI's words ([`fit_error`]).
pub fn forward_of(
    method: &Method,
    c: &Correspondences,
    moving_box: Aabb<Moving>,
) -> anyhow::Result<FittedWarp<Fixed, Moving>> {
    forward(method, &c.fixed, &c.moving, moving_box).map_err(|e| fit_error(method, c, e))
}

/// A fitted pull-back sampled into the n³ control texture of [`scene::control_grid`] over `fixed_box`: a
/// hierarchical B-spline through its lattice's separable sampler ([`ControlTexture::sample_fitted`]), the other
/// kinds texel by texel. The same texels as [`scene::control_texture`], to rounding.
pub fn control_texture(
    moving_from_fixed: &FittedWarp<Moving, Fixed>,
    fixed_box: Aabb<Fixed>,
    n: usize,
) -> anyhow::Result<(ControlGrid, ControlTexture)> {
    let grid = scene::control_grid(fixed_box, n)?;
    Ok((grid, ControlTexture::sample_fitted(moving_from_fixed, grid)))
}

/// The grid of a control texture as the GPU evaluates it.
#[must_use]
pub fn control_grid_desc(grid: &ControlGrid) -> ControlGridDesc {
    ControlGridDesc { dims: grid.dims, box_min_ref: grid.domain.min.coords(), box_max_ref: grid.domain.max.coords() }
}

/// A B-spline pull-back's (refined, single) lattice, borrowed, for the GPU.
#[must_use]
pub fn lattice_desc(spline: &HierarchicalBSpline<Moving, Fixed>) -> LatticeDesc<'_> {
    let l = spline.lattice();
    LatticeDesc { cells: l.cells(), min_mm: l.min_mm(), max_mm: l.max_mm(), coefficients: l.coefficients() }
}

/// A TPS pull-back as plain arrays, for the GPU crate (which does not depend on the solver).
#[derive(Clone, Debug)]
pub struct TpsParts {
    centres: Vec<[f64; 3]>,
    weights: Vec<[f64; 3]>,
    linear: [[f64; 3]; 3],
    translation: [f64; 3],
}

impl TpsParts {
    #[must_use]
    pub fn new(tps: &Tps<Moving, Fixed>) -> Self {
        let a = tps.linear();
        Self {
            centres: tps.centres().iter().map(Point3::coords).collect(),
            weights: tps.weights(),
            linear: std::array::from_fn(|r| std::array::from_fn(|c| a[(r, c)])),
            translation: tps.translation(),
        }
    }

    #[must_use]
    pub fn desc(&self) -> TpsDesc<'_> {
        TpsDesc {
            centres_ref: &self.centres,
            weights: &self.weights,
            linear: self.linear,
            translation: self.translation,
        }
    }
}
