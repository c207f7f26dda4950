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
//! - The CLI's pair subcommands fit pairs checked against the volumes ([`Correspondences`]) on the warp stack:
//!   [`pullback_stack`] and [`forward_stack`], whose errors read `<landmark file>: fitting the <method> warp: <problem>` with the pairs
//!   numbered as in the file ([`fit_error`]), and [`fit_warnings`].
//! - A landmark drag with a TPS: [`DragFit`] keeps both directions factorised from the drag's first event and gives
//!   each further event's coefficients in O(N²) ([`warpbench_solver::tps_drag`]), the same warps as [`fit_warp`] to
//!   1e-6 mm; its control texture is updated on the CPU or evaluated on the GPU from the new coefficients
//!   ([`ControlRoute`]), never refitted.
//! - What the GPU takes: [`control_texture`] (the pull-back sampled over a box; a B-spline through its lattice's
//!   separable sampler), [`TpsParts`] (a TPS, evaluated exactly per voxel by the export or into a control texture by
//!   the GPU), [`lattice_desc`] (a B-spline's lattice) and [`control_grid_desc`].

use std::fmt;

use anyhow::anyhow;
use rayon::prelude::*;
use warpbench_gpu::{BSplineDesc, ControlGridDesc, LatticeDesc, PreparedControl, TpsDesc};
use warpbench_io::geometry::Point3;
use warpbench_solver::SolverError;
use warpbench_solver::bspline::HierarchicalBSpline;
use warpbench_solver::control::{ControlGrid, ControlTexture};
use warpbench_solver::method::{FittedWarp, Method};
use warpbench_solver::spaces::{Aabb, Fixed, Moving};
use warpbench_solver::tps::{Regularisation, Tps};
use warpbench_solver::tps_drag::{DragStep, DragTexture, DraggedEnd, FactoredTps, PairDrag};

use crate::inputs::{self, Correspondences};
use crate::project::stack::{Layers, StackForward, StackPullback};
use crate::scene;

/// Where a fitted pull-back's control texture goes: the renderer that draws with it (the window's viewer, the drag
/// bench's). It takes a texture sampled on the CPU, or evaluates a TPS or a B-spline into its texture on the GPU.
pub trait ControlTarget {
    /// Whether the device filters f32 textures (else the texture is uploaded as f16).
    fn float32_filterable(&self) -> bool;
    /// Uploads a control texture sampled on the CPU.
    fn upload(&mut self, prepared: &PreparedControl);
    /// Removes the warp: the moving volume is shown unwarped.
    fn clear(&mut self);
    /// Evaluates the TPS pull-back `tps` on `grid` into the texture on the GPU.
    ///
    /// # Errors
    /// The GPU pass failing.
    fn evaluate_tps(&mut self, tps: &TpsDesc<'_>, grid: &ControlGridDesc) -> anyhow::Result<()>;
    /// Evaluates the B-spline pull-back `bspline` on `grid` into the texture on the GPU.
    ///
    /// # Errors
    /// The GPU pass failing.
    fn evaluate_bspline(&mut self, bspline: &BSplineDesc<'_>, grid: &ControlGridDesc) -> anyhow::Result<()>;
}

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

/// The warp fitted on the active pairs in both directions, on the stack's other layers: the pull-back the renderer
/// uses and the forward map that places the moving glyphs.
pub struct Fitted {
    /// u = moving_from_fixed: where a point of the deformed view comes from in the moving volume.
    pub pullback: StackPullback,
    /// d = fixed_from_moving.
    pub forward: StackForward,
    /// How many pairs both were fitted on.
    pub pairs: usize,
    /// The pairs both were fitted on, for telling which point a drag moves ([`moved_point`]).
    pub fixed: Vec<Point3<Fixed>>,
    pub moving: Vec<Point3<Moving>>,
}

impl fmt::Debug for Fitted {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Fitted").field("pairs", &self.pairs).finish_non_exhaustive()
    }
}

/// What one landmark change costs before the frame: the pull-back and the forward warp fitted on the pairs
/// (`fixed[i]` ↔ `moving[i]`) on the stack's other `layers` (a starting transform or a field under them, a brush on
/// top; [`crate::project::stack`]), and the pull-back sampled into a `grid_n`³ control texture over the fixed box,
/// ready to upload. The window runs this on every drag event; `benches/drag.rs` times it with the frame.
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
    layers: &Layers,
) -> anyhow::Result<(Fitted, PreparedControl)> {
    let (pullback, forward) = fit_both(method, (fixed, moving), (fixed_box, moving_box), layers)?;
    let (grid, texture) = pullback.control_texture(fixed_box, grid_n)?;
    let prepared = PreparedControl::prepare(&scene::control_desc(&grid, &texture), float32_filterable)
        .map_err(|e| anyhow!("{e}"))?;
    Ok((Fitted { pullback, forward, pairs: moving.len(), fixed: fixed.to_vec(), moving: moving.to_vec() }, prepared))
}

/// The one point in which the pairs (`fixed`, `moving`) differ from (`fixed_before`, `moving_before`): its pair
/// (0-based) and end; `None` when the lists differ in length or in anything else.
#[must_use]
pub fn moved_point(
    (fixed_before, moving_before): (&[Point3<Fixed>], &[Point3<Moving>]),
    fixed: &[Point3<Fixed>],
    moving: &[Point3<Moving>],
) -> Option<(usize, DraggedEnd)> {
    if fixed.len() != fixed_before.len() || moving.len() != moving_before.len() || fixed.len() != moving.len() {
        return None;
    }
    let mut moved = None;
    for i in 0..fixed.len() {
        for (end, same) in
            [(DraggedEnd::Fixed, fixed[i] == fixed_before[i]), (DraggedEnd::Moving, moving[i] == moving_before[i])]
        {
            if !same {
                if moved.is_some() {
                    return None;
                }
                moved = Some((i, end));
            }
        }
    }
    moved
}

/// Where a landmark drag's control texture is made (the window's choice for the whole drag).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ControlRoute {
    /// On the CPU: the solver's [`DragTexture`] (the drag start's texture, updated per event) uploaded to the viewer.
    Cpu,
    /// On the GPU: the pull-back's updated centres and weights uploaded and evaluated at every texel by
    /// [`warpbench_gpu::ControlEvalPass`]; nothing sampled on the CPU.
    Gpu,
}

/// How a [`DragFit`] makes its control texture.
#[derive(Debug)]
enum DragControl {
    /// [`ControlRoute::Cpu`]: the drag start's texture and φₖ sampled once on the CPU.
    Cpu(DragTexture),
    /// [`ControlRoute::Gpu`]: the grid the GPU evaluates the pull-back on.
    Gpu(ControlGridDesc),
}

/// A TPS landmark drag in progress: both directions factorised on the pairs of the drag's first event, so that each
/// further event costs one O(N²) update of both warps' coefficients ([`PairDrag`]) instead of two fits, and its
/// control texture costs one pass over the texels on the CPU ([`DragTexture`]) or one dispatch on the GPU. Only the
/// dragged point may change; the release refits in full ([`fit_warp`], [`fit_warp_on_gpu`]), so the diagnostics
/// never see the fast path.
#[derive(Debug)]
pub struct DragFit {
    drag: DragPairs,
    control: DragControl,
    fixed: Vec<Point3<Fixed>>,
    moving: Vec<Point3<Moving>>,
}

/// What a [`DragFit`] updates.
#[derive(Debug)]
enum DragPairs {
    /// u and d themselves: no layer under the pairs, or a starting transform alone, which a TPS makes vanish
    /// ([`crate::start::tps_ignores`]).
    Plain(PairDrag),
    /// The landmark layers on a field (and perhaps a starting transform) B: r fitted on qᵢ → B⁻¹(pᵢ), s on
    /// pᵢ → B(qᵢ), and u = B ∘ r, d = B⁻¹ ∘ s ([`crate::project::stack`]).
    OnField { drag: PairDrag<Fixed, Moving>, layers: Box<Layers> },
}

/// One drag event's warps ([`DragFit::event`]), before its control texture is made ([`DragFit::show`]).
#[derive(Debug)]
pub struct DragEvent {
    step: EventStep,
    fixed: Vec<Point3<Fixed>>,
    moving: Vec<Point3<Moving>>,
}

/// The coefficients of one event, as [`DragPairs`] holds them.
#[derive(Debug)]
enum EventStep {
    Plain(DragStep),
    OnField(DragStep<Fixed, Moving>, Box<Layers>),
}

impl DragEvent {
    /// Both warps as [`fit_warp`] gives them.
    #[must_use]
    pub fn into_fitted(self) -> Fitted {
        let (pullback, forward) = match self.step {
            EventStep::Plain(step) => (
                StackPullback::folded(FittedWarp::Tps(step.pullback)),
                StackForward::folded(FittedWarp::Tps(step.forward)),
            ),
            EventStep::OnField(step, layers) => (
                StackPullback::on_field((*layers).clone(), FittedWarp::Tps(step.pullback)),
                StackForward::on_field(*layers, FittedWarp::Tps(step.forward)),
            ),
        };
        Fitted { pairs: self.moving.len(), pullback, forward, fixed: self.fixed, moving: self.moving }
    }
}

/// Both directions of a TPS fit kept factorised on a set of pairs and the layers under them: what a drag starts from.
/// [`DragFit::start`] makes one on the drag's first event (the O(N³) part of a drag's start); the window makes one
/// after each full fit on a thread of its own ([`DragBasis::new`]), so that the next drag finds it ready
/// ([`DragFit::from_basis`]).
#[derive(Debug)]
pub struct DragBasis {
    kind: BasisKind,
    method: Method,
    fixed: Vec<Point3<Fixed>>,
    moving: Vec<Point3<Moving>>,
}

/// [`DragBasis`]'s factorisations, as [`DragPairs`] takes them.
#[derive(Debug)]
enum BasisKind {
    Plain(FactoredTps<Moving, Fixed>, FactoredTps<Fixed, Moving>),
    OnField { pullback: FactoredTps<Fixed, Fixed>, forward: FactoredTps<Moving, Moving>, layers: Box<Layers> },
}

impl DragBasis {
    /// Factorises both directions of a TPS `method` on the pairs (`fixed`, `moving`) and the stack's other `layers`;
    /// `None` where a drag keeps the full fit: another method, a brush on top, or a starting transform the pairs are
    /// too few to refine.
    ///
    /// # Errors
    /// Too few pairs, or a fit that fails (the full fit's error names the pairs).
    #[must_use]
    pub fn new(
        method: &Method,
        (fixed, moving): (&[Point3<Fixed>], &[Point3<Moving>]),
        layers: &Layers,
    ) -> Option<anyhow::Result<Self>> {
        let Method::Tps { stiffness } = *method else { return None };
        let on_field = layers.field.is_some();
        let start_vanishes = layers.start.is_none() || crate::start::tps_ignores(method, moving.len());
        if layers.brush.is_some() || !(on_field || start_vanishes) {
            return None;
        }
        Some((|| {
            enough_pairs(method, moving.len())?;
            let regularisation = Regularisation::Smoothing(stiffness);
            let failed = |e: SolverError| anyhow!("{method}: {e}");
            let kind = if on_field {
                let unbased: Vec<Point3<Fixed>> =
                    moving.iter().map(|p| Point3::from_array(layers.base_inverse_raw(p.coords()))).collect();
                let based: Vec<Point3<Moving>> =
                    fixed.iter().map(|q| Point3::from_array(layers.base_raw(q.coords()))).collect();
                let (pullback, forward) = rayon::join(
                    || FactoredTps::fit(fixed, &unbased, regularisation),
                    || FactoredTps::fit(moving, &based, regularisation),
                );
                let layers = Box::new(Layers { start: layers.start.clone(), field: layers.field.clone(), brush: None });
                BasisKind::OnField { pullback: pullback.map_err(failed)?, forward: forward.map_err(failed)?, layers }
            } else {
                let (pullback, forward) = rayon::join(
                    || FactoredTps::fit(fixed, moving, regularisation),
                    || FactoredTps::fit(moving, fixed, regularisation),
                );
                BasisKind::Plain(pullback.map_err(failed)?, forward.map_err(failed)?)
            };
            Ok(Self { kind, method: *method, fixed: fixed.to_vec(), moving: moving.to_vec() })
        })())
    }

    /// Whether this basis was made for `method` on the pairs (`fixed`, `moving`) and `layers`' starting transform and
    /// field.
    #[must_use]
    pub fn fits(
        &self,
        method: &Method,
        (fixed, moving): (&[Point3<Fixed>], &[Point3<Moving>]),
        layers: &Layers,
    ) -> bool {
        let same_pairs = self.method == *method && self.fixed == fixed && self.moving == moving;
        same_pairs
            && match &self.kind {
                BasisKind::Plain(..) => layers.field.is_none() && layers.brush.is_none(),
                BasisKind::OnField { layers: own, .. } => same_base(own, layers),
            }
    }
}

/// Whether `layers` has `own`'s starting transform and field (the same one read, not an equal one), and no brush.
fn same_base(own: &Layers, layers: &Layers) -> bool {
    let field = |f: &Option<std::sync::Arc<crate::project::stack::FieldLayer>>| f.as_ref().map(std::sync::Arc::as_ptr);
    own.start == layers.start && field(&own.field) == field(&layers.field) && layers.brush.is_none()
}

impl DragFit {
    /// Starts the drag of pair `pair`'s `end` (0-based among `fixed`/`moving`) for a TPS `method` on the stack's
    /// other `layers` (`None` where [`DragBasis::new`] or [`Self::from_basis`] keep the full fit), with the control
    /// texture of [`fit_warp`] (`grid_n`³ over the fixed box) made on `route`: both directions factorised, and on the
    /// CPU route the drag start's texture sampled.
    ///
    /// # Errors
    /// A fit that fails (the caller refits in full, whose error names the pairs), or a texture grid that cannot be
    /// made.
    #[must_use]
    pub fn start(
        method: &Method,
        pairs: (&[Point3<Fixed>], &[Point3<Moving>]),
        texture: (Aabb<Fixed>, usize),
        moved: (usize, DraggedEnd),
        route: ControlRoute,
        layers: &Layers,
    ) -> Option<anyhow::Result<Self>> {
        if layers.field.is_some() && route == ControlRoute::Gpu {
            return None;
        }
        match DragBasis::new(method, pairs, layers)? {
            Ok(basis) => Self::from_basis(basis, texture, moved, route),
            Err(e) => Some(Err(e)),
        }
    }

    /// Starts the drag of pair `pair`'s `end` from `basis` (the pairs it was made on are the drag's start; an event
    /// moves that point from there): O(N²), and on the CPU route the drag start's texture sampled. `None` for a
    /// field under the pairs on the GPU route, which evaluates a TPS alone: that keeps the full fit.
    ///
    /// # Errors
    /// The pair out of range, a unit response that cannot be solved, or a texture grid that cannot be made.
    #[must_use]
    pub fn from_basis(
        basis: DragBasis,
        (fixed_box, grid_n): (Aabb<Fixed>, usize),
        (pair, end): (usize, DraggedEnd),
        route: ControlRoute,
    ) -> Option<anyhow::Result<Self>> {
        if matches!(basis.kind, BasisKind::OnField { .. }) && route == ControlRoute::Gpu {
            return None;
        }
        let DragBasis { kind, fixed, moving, .. } = basis;
        Some((|| {
            let grid = scene::control_grid(fixed_box, grid_n)?;
            let failed = |e: SolverError| anyhow!("the drag of pair {}: {e}", pair + 1);
            let drag = match kind {
                BasisKind::Plain(pullback, forward) => {
                    DragPairs::Plain(PairDrag::from_factored((pullback, forward), (pair, end)).map_err(failed)?)
                }
                BasisKind::OnField { pullback, forward, layers } => DragPairs::OnField {
                    drag: PairDrag::from_factored((pullback, forward), (pair, end)).map_err(failed)?,
                    layers,
                },
            };
            let control = match route {
                ControlRoute::Cpu => DragControl::Cpu(match &drag {
                    DragPairs::Plain(d) => DragTexture::new(d, grid),
                    DragPairs::OnField { drag, .. } => DragTexture::new(drag, grid),
                }),
                ControlRoute::Gpu => DragControl::Gpu(control_grid_desc(&grid)),
            };
            Ok(Self { drag, control, fixed, moving })
        })())
    }

    /// Where this drag makes its control texture.
    #[must_use]
    pub fn route(&self) -> ControlRoute {
        match self.control {
            DragControl::Cpu(_) => ControlRoute::Cpu,
            DragControl::Gpu(_) => ControlRoute::Gpu,
        }
    }

    /// Whether this drag was started on `layers`' starting transform and field (what a drag event may not change).
    #[must_use]
    pub fn same_layers(&self, layers: &Layers) -> bool {
        match &self.drag {
            DragPairs::Plain(_) => layers.field.is_none() && layers.brush.is_none(),
            DragPairs::OnField { layers: own, .. } => same_base(own, layers),
        }
    }

    /// Both warps for the pairs (`fixed`, `moving`), as [`fit_warp`] fits them, in O(N²); `None` when the pairs
    /// differ from the drag's start in anything but the dragged point, or the fast path refuses (a point landing on
    /// another): then refit in full.
    #[must_use]
    pub fn event(&self, fixed: &[Point3<Fixed>], moving: &[Point3<Moving>]) -> Option<DragEvent> {
        let (pair, end) = match &self.drag {
            DragPairs::Plain(d) => (d.pair(), d.end()),
            DragPairs::OnField { drag, .. } => (drag.pair(), drag.end()),
        };
        match moved_point((&self.fixed, &self.moving), fixed, moving) {
            Some((i, e)) if (i, e) == (pair, end) => {}
            None if fixed == self.fixed.as_slice() && moving == self.moving.as_slice() => {}
            _ => return None,
        }
        let to = match end {
            DraggedEnd::Fixed => fixed[pair].coords(),
            DraggedEnd::Moving => moving[pair].coords(),
        };
        let step = match &self.drag {
            DragPairs::Plain(d) => EventStep::Plain(d.step(to).ok()?),
            // The moved point as each layer sees it: a moving point is r's datum B⁻¹(p′) and s's centre, a fixed
            // point r's centre and s's datum B(q′).
            DragPairs::OnField { drag, layers } => {
                let (pullback_to, forward_to) = match end {
                    DraggedEnd::Moving => (layers.base_inverse_raw(to), to),
                    DraggedEnd::Fixed => (to, layers.base_raw(to)),
                };
                EventStep::OnField(drag.step_on_base(pullback_to, forward_to).ok()?, layers.clone())
            }
        };
        Some(DragEvent { step, fixed: fixed.to_vec(), moving: moving.to_vec() })
    }

    /// On the CPU route, `event`'s control texture prepared for upload (`None` on the GPU route).
    ///
    /// # Errors
    /// A texture the GPU cannot take (a displacement that is not finite).
    #[must_use]
    pub fn control_texture(
        &self,
        event: &DragEvent,
        float32_filterable: bool,
    ) -> Option<anyhow::Result<PreparedControl>> {
        let DragControl::Cpu(texture) = &self.control else { return None };
        Some(self.filled(texture, event, float32_filterable))
    }

    /// `texture` filled for `event` and prepared for upload: on a field, the landmark layer's r(x) − x followed by
    /// the base, u(x) − x = B(r(x)) − x at each texel centre.
    fn filled(
        &self,
        texture: &DragTexture,
        event: &DragEvent,
        float32_filterable: bool,
    ) -> anyhow::Result<PreparedControl> {
        let mut texels = vec![[0.0f32; 4]; texture.grid().texel_count()];
        match (&self.drag, &event.step) {
            (DragPairs::Plain(d), EventStep::Plain(step)) => texture.fill(d, step, &mut texels),
            (DragPairs::OnField { drag, layers }, EventStep::OnField(step, _)) => {
                texture.fill(drag, step, &mut texels);
                let grid = *texture.grid();
                let [nx, ny, _] = grid.dims;
                texels.par_iter_mut().enumerate().for_each(|(i, t)| {
                    let x = grid.texel_centre([i % nx, (i / nx) % ny, i / (nx * ny)]);
                    let u = layers.base_raw(std::array::from_fn(|a| x[a] + f64::from(t[a])));
                    *t = [(u[0] - x[0]) as f32, (u[1] - x[1]) as f32, (u[2] - x[2]) as f32, 0.0];
                });
            }
            _ => return Err(anyhow!("the drag's control texture: an event of another drag (a bug)")),
        }
        let texture = texture.texture(texels);
        PreparedControl::prepare(&scene::control_desc(&texture.grid, &texture), float32_filterable)
            .map_err(|e| anyhow!("the drag's control texture: {e}"))
    }

    /// Makes `event`'s control texture `target`'s: on the CPU route filled and uploaded, on the GPU route the
    /// pull-back's centres and weights uploaded and evaluated into the texture ([`ControlTarget::evaluate_tps`]).
    ///
    /// # Errors
    /// The texture cannot be made (not finite) or the GPU pass fails.
    pub fn show(&self, event: &DragEvent, target: &mut dyn ControlTarget) -> anyhow::Result<()> {
        match (&self.control, &event.step) {
            (DragControl::Cpu(texture), _) => {
                let prepared = self.filled(texture, event, target.float32_filterable())?;
                target.upload(&prepared);
                Ok(())
            }
            (DragControl::Gpu(grid), EventStep::Plain(step)) => {
                target.evaluate_tps(&TpsParts::new(&step.pullback).desc(), grid)
            }
            // A drag on a field is never started on the GPU route (`start`).
            (DragControl::Gpu(_), EventStep::OnField(..)) => {
                Err(anyhow!("the drag's control texture: a field under the pairs on the GPU route (a bug)"))
            }
        }
    }
}

/// Both directions fitted on the pairs on the stack's other `layers`: with a starting transform or a field under
/// them, too few pairs give that base alone; without one they are an error, in the window's words.
fn fit_both(
    method: &Method,
    pairs: (&[Point3<Fixed>], &[Point3<Moving>]),
    (fixed_box, moving_box): (Aabb<Fixed>, Aabb<Moving>),
    layers: &Layers,
) -> anyhow::Result<(StackPullback, StackForward)> {
    if layers.start.is_none() && layers.field.is_none() {
        enough_pairs(method, pairs.1.len())?;
    }
    StackPullback::fit(method, pairs, fixed_box, layers.clone())
        .and_then(|u| Ok((u, StackForward::fit(method, pairs, moving_box, layers.clone())?)))
        .map_err(|e| anyhow!("{method}: {e}"))
}

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

/// [`fit_warp`] with the control texture evaluated on the GPU ([`warpbench_gpu::ControlEvalPass`], into `target`'s
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
    target: &mut dyn ControlTarget,
    layers: &Layers,
) -> anyhow::Result<Fitted> {
    if !gpu_evaluates(method) {
        return Err(not_on_gpu(method));
    }
    let desc = control_grid_desc(&scene::control_grid(fixed_box, grid_n)?);
    let (pullback, forward) = fit_both(method, (fixed, moving), (fixed_box, moving_box), layers)?;
    match pullback.as_fitted() {
        Some(FittedWarp::Tps(tps)) => target.evaluate_tps(&TpsParts::new(tps).desc(), &desc)?,
        Some(FittedWarp::BSpline(spline)) => {
            target.evaluate_bspline(&BSplineDesc { lattices: &[lattice_desc(spline)] }, &desc)?;
        }
        // A field or a brush in the stack, or a linear fit: sampled on the CPU instead.
        Some(FittedWarp::Linear(_)) | None => return Err(not_on_gpu(method)),
    }
    Ok(Fitted { pullback, forward, pairs: moving.len(), fixed: fixed.to_vec(), moving: moving.to_vec() })
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

/// The pull-back of the warp stack on checked pairs ([`StackPullback::fit`]), its error in the CLI's words
/// ([`fit_error`]).
pub fn pullback_stack(
    method: &Method,
    c: &Correspondences,
    fixed_box: Aabb<Fixed>,
    layers: Layers,
) -> anyhow::Result<StackPullback> {
    StackPullback::fit(method, (&c.fixed, &c.moving), fixed_box, layers).map_err(|e| fit_error(method, c, e))
}

/// The forward map of the warp stack on checked pairs ([`StackForward::fit`]), its error in the CLI's words
/// ([`fit_error`]).
pub fn forward_stack(
    method: &Method,
    c: &Correspondences,
    moving_box: Aabb<Moving>,
    layers: Layers,
) -> anyhow::Result<StackForward> {
    StackForward::fit(method, (&c.fixed, &c.moving), moving_box, layers).map_err(|e| fit_error(method, c, e))
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

#[cfg(test)]
mod tests {
    use super::*;
    use warpbench_solver::warp::Warp;

    fn pairs(n: usize) -> (Vec<Point3<Fixed>>, Vec<Point3<Moving>>) {
        let h = |i: usize, s: u64| {
            let x = (i as u64 + 1).wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ s.wrapping_mul(0xBF58_476D_1CE4_E5B9);
            ((x ^ (x >> 29)).wrapping_mul(0x94D0_49BB_1331_11EB) >> 11) as f64 / (1u64 << 53) as f64
        };
        let fixed: Vec<Point3<Fixed>> = (0..n)
            .map(|i| Point3::new(160.0 * h(i, 1) - 80.0, 160.0 * h(i, 2) - 80.0, 160.0 * h(i, 3) - 80.0))
            .collect();
        let moving = fixed
            .iter()
            .map(|q| {
                let [x, y, z] = q.coords();
                Point3::new(x + 4.0 * (y / 30.0).sin(), y + 3.0 * (z / 25.0).cos(), z - 2.0)
            })
            .collect();
        (fixed, moving)
    }

    fn boxes() -> (Aabb<Fixed>, Aabb<Moving>) {
        (
            Aabb::new(Point3::new(-100.0, -100.0, -100.0), Point3::new(100.0, 100.0, 100.0)),
            Aabb::new(Point3::new(-110.0, -110.0, -110.0), Point3::new(110.0, 110.0, 110.0)),
        )
    }

    /// Where a test's drag gets its factorisations.
    #[derive(Clone, Copy, Debug)]
    enum Basis {
        /// [`DragFit::start`] on the drag's pairs.
        AtStart,
        /// [`DragBasis::new`] beforehand (as the window makes one after a full fit), then [`DragFit::from_basis`].
        Made,
    }

    /// A smooth field under the pairs, up to 4 mm, on a 5 mm grid over the fixed box.
    fn field_layers() -> Layers {
        use crate::project::stack::FieldLayer;
        use warpbench_io::geometry::{Index, Lps, Transform};
        use warpbench_solver::field::SampledField;
        let dims = [41, 41, 41];
        let lps_from_index = Transform::<Lps, Index>::from_scale_translation([5.0; 3], [-100.0; 3]);
        let displacements = (0..41 * 41 * 41)
            .map(|i| {
                let [x, y, z] = [i % 41, (i / 41) % 41, i / 1681].map(|n| n as f64 * 5.0 - 100.0);
                [4.0 * (y / 40.0).sin(), 3.0 * (z / 35.0).cos(), 2.0 * (x / 50.0).sin()].map(|v| v as f32)
            })
            .collect();
        let field = SampledField::new(dims, lps_from_index, displacements).expect("field");
        Layers { field: Some(std::sync::Arc::new(FieldLayer::pullback(field, "test field"))), ..Layers::default() }
    }

    /// Each drag event through [`DragFit`] on `layers` gives the warps of the full [`fit_warp`] on them (to 1e-6 mm at
    /// probe points) and its control texture (within f32 rounding), and a change of any other point leaves the fast
    /// path.
    fn check_drags(layers: &Layers, routes: &[(DraggedEnd, ControlRoute, Basis)]) {
        let method = Method::Tps { stiffness: 0.0 };
        let (mut fixed, mut moving) = pairs(40);
        for &(end, route, basis) in routes {
            let texture = (boxes().0, 16);
            let drag = match basis {
                Basis::AtStart => DragFit::start(&method, (&fixed, &moving), texture, (7, end), route, layers),
                Basis::Made => {
                    let basis = DragBasis::new(&method, (&fixed, &moving), layers).expect("a TPS").expect("basis");
                    assert!(basis.fits(&method, (&fixed, &moving), layers));
                    assert!(!basis.fits(&Method::Tps { stiffness: 1.0 }, (&fixed, &moving), layers));
                    assert!(!basis.fits(&method, (&fixed[1..], &moving[1..]), layers));
                    DragFit::from_basis(basis, texture, (7, end), route)
                }
            }
            .expect("a TPS")
            .expect("start");
            assert_eq!(drag.route(), route);
            assert!(drag.same_layers(layers));
            for step in [0.5, 2.0, -6.0] {
                match end {
                    DraggedEnd::Fixed => fixed[7] = Point3::new(fixed[7].coords()[0] + step, 1.0, 2.0),
                    DraggedEnd::Moving => moving[7] = Point3::new(moving[7].coords()[0] - step, 3.0, -1.0),
                }
                let event = drag.event(&fixed, &moving).expect("the fast path");
                // Only the CPU route samples a texture on the CPU; the GPU route evaluates the coefficients.
                let texture = drag.control_texture(&event, true);
                assert_eq!(texture.is_some(), route == ControlRoute::Cpu, "{route:?}");
                let (full, full_texture) =
                    fit_warp(&method, &fixed, &moving, boxes(), 16, true, layers).expect("full fit");
                if let Some(texture) = texture {
                    // f32 texels of the same displacements (tests/tps_drag.rs holds them within 8 ε of the largest;
                    // on a field the base follows r(x), rounded to f32 on the way, whose error the field's slope
                    // (under 0.2 here) carries over: at most 16 ε).
                    let texels = texture.expect("a texture").texels;
                    let largest = full_texture.texels.iter().flatten().fold(0.0f32, |m, v| m.max(v.abs()));
                    let worst = texels
                        .iter()
                        .zip(&full_texture.texels)
                        .flat_map(|(a, b)| (0..4).map(move |c| (a[c] - b[c]).abs()));
                    let tol = if layers.field.is_some() { 16.0 } else { 8.0 } * f32::EPSILON * largest;
                    assert!(worst.fold(0.0f32, f32::max) <= tol, "{end:?}: the drag's texture");
                }
                let fast = event.into_fitted();
                for i in 0..50 {
                    let x = [f64::from(i) * 3.7 - 90.0, 40.0 - f64::from(i) * 1.3, f64::from(i % 7) * 11.0 - 30.0];
                    let (a, b) = (fast.pullback.apply_raw(x), full.pullback.apply_raw(x));
                    let (c, d) = (fast.forward.apply_raw(x), full.forward.apply_raw(x));
                    for k in 0..3 {
                        assert!((a[k] - b[k]).abs() <= 1e-6 && (c[k] - d[k]).abs() <= 1e-6, "{end:?} {step}: {x:?}");
                    }
                }
            }
            let mut other = fixed.clone();
            other[3] = Point3::new(0.0, 0.0, 0.0);
            assert!(drag.event(&other, &moving).is_none(), "another point moved: refit");
            (fixed, moving) = pairs(40);
        }
    }

    #[test]
    fn drag_events_match_the_full_fit() {
        let routes = [
            (DraggedEnd::Fixed, ControlRoute::Cpu, Basis::AtStart),
            (DraggedEnd::Moving, ControlRoute::Cpu, Basis::Made),
            (DraggedEnd::Fixed, ControlRoute::Gpu, Basis::Made),
            (DraggedEnd::Moving, ControlRoute::Gpu, Basis::AtStart),
        ];
        check_drags(&Layers::default(), &routes);
        let (fixed, moving) = pairs(40);
        assert_eq!(moved_point((&fixed, &moving), &fixed, &moving), None);
        let mut two = fixed.clone();
        two[1] = Point3::new(1.0, 1.0, 1.0);
        assert_eq!(moved_point((&fixed, &moving), &two, &moving), Some((1, DraggedEnd::Fixed)));
        two[2] = Point3::new(1.0, 2.0, 1.0);
        assert_eq!(moved_point((&fixed, &moving), &two, &moving), None);
        let other = Method::Linear(warpbench_solver::linear::LinearKind::Affine);
        let start = (0, DraggedEnd::Fixed);
        let none = Layers::default();
        assert!(DragFit::start(&other, (&fixed, &moving), (boxes().0, 16), start, ControlRoute::Gpu, &none).is_none());
    }

    /// On a field under the pairs (the window's Refine by intensities, a field chosen under the landmarks), the
    /// drag updates the landmark layers and puts the field after them, as the full fit does; the GPU route, which
    /// evaluates a TPS alone, keeps the full fit.
    #[test]
    fn drag_events_on_a_field_match_the_full_fit() {
        let layers = field_layers();
        let routes = [
            (DraggedEnd::Fixed, ControlRoute::Cpu, Basis::Made),
            (DraggedEnd::Moving, ControlRoute::Cpu, Basis::AtStart),
        ];
        check_drags(&layers, &routes);
        let (fixed, moving) = pairs(40);
        let tps = Method::Tps { stiffness: 0.0 };
        let moved = (3, DraggedEnd::Fixed);
        assert!(DragFit::start(&tps, (&fixed, &moving), (boxes().0, 16), moved, ControlRoute::Gpu, &layers).is_none());
        let basis = DragBasis::new(&tps, (&fixed, &moving), &layers).expect("a TPS").expect("basis");
        assert!(!basis.fits(&tps, (&fixed, &moving), &field_layers()), "another field read");
        assert!(DragFit::from_basis(basis, (boxes().0, 16), moved, ControlRoute::Gpu).is_none());
        // Another starting transform or field under a drag on a field is another drag.
        let drag = DragFit::start(&tps, (&fixed, &moving), (boxes().0, 16), moved, ControlRoute::Cpu, &layers)
            .expect("a TPS")
            .expect("start");
        let shifted = crate::start::Start::new(
            warpbench_solver::linear::AffineWarp::new(nalgebra::Matrix3::identity(), [1.0, 0.0, 0.0]),
            "shifted",
        )
        .expect("start");
        assert!(!drag.same_layers(&Layers { start: Some(shifted), ..layers.clone() }));
        assert!(!drag.same_layers(&field_layers()), "the same values, another field read");
        assert!(!drag.same_layers(&Layers::default()));
    }
}
