//! The one owner of fitting for the window: a document's warp stack fitted ([`Fitter::fit`]), its control texture
//! made on the CPU or the GPU, a TPS drag's O(N²) fast path, the brush and the diagnostics that follow a fit on a
//! thread of their own.
//!
//! The pairs are checked once per fit, here, so that refusals and warnings number them as the landmark table does.
//! Every fit goes through the stack ([`super::stack`]): a starting transform and a displacement field under the
//! landmark fit, the brush on top.

use std::sync::Arc;

use anyhow::anyhow;
use warpbench_io::Volume;
use warpbench_io::geometry::Point3;
use warpbench_solver::brush::Brush;
use warpbench_solver::diagnostics::JacobianReport;
use warpbench_solver::method::Method;
use warpbench_solver::spaces::{Aabb, Fixed, Moving};

use super::diagnostics::{Diagnostics, DiagnosticsInput, DiagnosticsJob, PairErrors};
use super::document::{Document, StartingTransform};
use super::field_file::FieldFile;
use super::stack::{BrushLayer, FieldLayer, Layers};
use crate::brushed::{Brushed, InverseConsistency};
use crate::fit::{self, ControlRoute, ControlTarget, DragBasis, DragEvent, DragFit, Fitted};

/// How much a fit does.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mode {
    /// A drag event: the warp follows the pointer; a TPS drag takes its O(N²) path; no diagnostics.
    Interactive,
    /// A settled change: a full fit, the brush's inverse fitted, and the diagnostics started.
    Full,
}

/// Where the control texture may be made.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Evaluation {
    /// Sampled on the CPU and uploaded.
    Cpu,
    /// A TPS or a B-spline evaluated on the GPU (anything else sampled on the CPU).
    Gpu,
}

/// The fitted warp of a document and what its fit found, for the views, the table and the status bar.
#[derive(Debug, Default)]
pub struct Fitter {
    fitted: Option<Fitted>,
    /// The problem of the last fit (or of the last pick or frame), shown in the status bar.
    pub error: Option<String>,
    /// Per pair (aligned with the document's pairs): the fit's residual and leave-one-out error, for the active pairs.
    pub pair_errors: Vec<Option<PairErrors>>,
    /// The pull-back's Jacobian over the fixed box after the last fit (folding where det ≤ 0).
    pub jacobian: Option<JacobianReport>,
    /// What the last fit found suspicious in the pairs (a pair given twice, a nearly flat set), numbered as the
    /// table's rows.
    pub warnings: Vec<String>,
    /// Counts the fits, so that what was picked under a resting pointer is known to be stale.
    pub generation: u64,
    /// The document's brush as a warp b of the fixed space: the warp shown before there is a fit is b alone.
    pub brush: Option<Brush>,
    /// How well the brush's inverse, fitted by scattered-data interpolation when its last stroke settled, undoes it.
    pub brush_consistency: Option<InverseConsistency>,
    /// The TPS drag in progress, from its first event until the full refit of its release.
    drag: Option<DragFit>,
    /// What the next drag starts from, being factorised on a thread after the last full fit (so that a drag's first
    /// event does no O(N³) work).
    drag_basis: Option<std::sync::mpsc::Receiver<Option<anyhow::Result<DragBasis>>>>,
    /// The last fit's diagnostics being computed; `pair_errors` and `jacobian` wait for them.
    diagnostics: Option<DiagnosticsJob>,
    /// A fit asked for at the end of the frame (the window's `refit_soon`).
    pub pending: bool,
    /// The document's displacement field, read once per file (or why it could not be).
    field: Option<(FieldFile, Result<Arc<FieldLayer>, String>)>,
}

impl Fitter {
    /// The warp shown (both directions and the pairs they were fitted on): `None` before a fit and after one that
    /// failed.
    #[must_use]
    pub fn fitted(&self) -> Option<&Fitted> {
        self.fitted.as_ref()
    }

    /// Whether the last fit's diagnostics are still being computed.
    #[must_use]
    pub fn diagnostics_pending(&self) -> bool {
        self.diagnostics.is_some()
    }

    /// Whether a landmark drag is in progress on the O(N²) path and where it makes its control texture.
    #[must_use]
    pub fn drag_route(&self) -> Option<ControlRoute> {
        self.drag.as_ref().map(DragFit::route)
    }

    /// Takes the last fit's diagnostics once their thread has them; call once per frame.
    pub fn poll_diagnostics(&mut self) {
        let Some(result) = self.diagnostics.as_ref().and_then(DiagnosticsJob::poll) else { return };
        self.diagnostics = None;
        match result {
            Some(d) => self.take_diagnostics(d),
            None => self.error = Some("the fit's diagnostics stopped (a bug): fit again to retry".into()),
        }
    }

    fn take_diagnostics(&mut self, d: Diagnostics) {
        for (row, errors) in d.pair_errors {
            if let Some(slot) = self.pair_errors.get_mut(row) {
                *slot = Some(errors);
            }
        }
        self.jacobian = Some(d.jacobian);
    }

    /// Fits `document`'s warp stack on its active pairs over the boxes of `volumes` (fixed, moving) and makes
    /// `target`'s control texture, where `evaluation` allows. With fewer pairs than the method needs and nothing
    /// under them, the moving volume is shown unwarped and [`Self::error`] says why. In [`Mode::Full`] the
    /// diagnostics follow on a thread that calls `wake` when they are done.
    pub fn fit(
        &mut self,
        document: &Document,
        volumes: (&Volume, &Volume),
        (mode, evaluation): (Mode, Evaluation),
        target: &mut dyn ControlTarget,
        wake: impl FnOnce() + Send + 'static,
    ) {
        self.generation += 1;
        // Whatever a running job finds describes the document before this change.
        self.diagnostics = None;
        let full = mode == Mode::Full;
        if full {
            self.drag = None;
            self.pair_errors = vec![None; document.pairs.len()];
            self.jacobian = None;
        }
        let method = document.settings.method();
        let boxes = (crate::inputs::volume_box::<Fixed>(volumes.0), crate::inputs::volume_box::<Moving>(volumes.1));
        let (used, (fixed, moving)) = document.fit_pairs();
        let row = |n: usize| used.get(n.wrapping_sub(1)).map_or(n, |&i| i + 1);
        let mut problems = Vec::new();
        let layers = self.layers(document, mode, &mut problems);
        let alone = (layers.start.is_some() || layers.field.is_some()) && !crate::start::refines(&method, moving.len());
        match if alone { Ok(Vec::new()) } else { method.check(&fixed, &moving) } {
            Ok(warnings) => self.warnings = warnings.into_iter().map(|w| w.renumber(row).to_string()).collect(),
            Err(e) => {
                target.clear();
                self.fitted = None;
                self.jacobian = None;
                self.warnings.clear();
                self.error = Some(format!("{method}: {}", e.renumber(row)));
                return;
            }
        }
        let plain = layers.brush.is_none() && layers.field.is_none();
        let on_gpu = plain && !alone && evaluation == Evaluation::Gpu && fit::gpu_evaluates(&method);
        // A drag's O(N²) updates take the layers under the pairs (`DragFit::start` says which), not a brush over them.
        let fast = if full {
            None
        } else {
            let route = if on_gpu { ControlRoute::Gpu } else { ControlRoute::Cpu };
            self.drag_event(&method, (&fixed, &moving), (boxes.0, document.settings.grid_n), route, &layers)
        };
        let grid_n = document.settings.grid_n;
        let result = if let (Some(event), Some(drag)) = (fast, &self.drag) {
            drag.show(&event, target).map(|()| event.into_fitted())
        } else if on_gpu {
            fit::fit_warp_on_gpu(&method, &fixed, &moving, boxes, grid_n, target, &layers)
        } else {
            let filterable = target.float32_filterable();
            fit::fit_warp(&method, &fixed, &moving, boxes, grid_n, filterable, &layers).map(|(f, prepared)| {
                target.upload(&prepared);
                f
            })
        };
        match result {
            Ok(fitted) => {
                self.pair_errors.resize(document.pairs.len(), None);
                if full && !alone {
                    self.drag_basis = start_drag_basis(method, (fixed.clone(), moving.clone()), &layers);
                    // Residuals, leave-one-out and folding follow on a thread of their own.
                    let input = DiagnosticsInput {
                        method,
                        rows: used,
                        fixed,
                        moving,
                        fixed_box: boxes.0,
                        pullback: fitted.pullback.clone(),
                    };
                    match DiagnosticsJob::start(input.clone(), wake) {
                        Ok(job) => self.diagnostics = Some(job),
                        // Without a thread, on this one.
                        Err(_) => self.take_diagnostics(input.compute()),
                    }
                }
                self.fitted = Some(fitted);
                self.error = (!problems.is_empty()).then(|| problems.join("; "));
            }
            Err(e) => {
                target.clear();
                self.fitted = None;
                self.jacobian = None;
                problems.push(format!("{e:#}"));
                self.error = Some(problems.join("; "));
            }
        }
    }

    /// The stack's layers around the landmark fit as `document` has them: the starting transform, the field (read
    /// once per path), and the brush (its inverse fitted in [`Mode::Full`], undone point by point during a drag).
    /// What cannot be made is left out and said in `problems`.
    fn layers(&mut self, document: &Document, mode: Mode, problems: &mut Vec<String>) -> Layers {
        let start = match document.start.as_ref().map(StartingTransform::start).transpose() {
            Ok(s) => s,
            Err(e) => {
                problems.push(format!("{e:#}"));
                None
            }
        };
        let field = document.field.as_ref().and_then(|file| match self.field_layer(file) {
            Ok(f) => Some(f),
            Err(e) => {
                problems.push(e);
                None
            }
        });
        self.brush = match Brush::new(document.brush.clone()) {
            Ok(b) if b.is_empty() => None,
            Ok(b) => Some(b),
            Err(e) => {
                problems.push(format!("the brush: {e}"));
                None
            }
        };
        let fitted_brush = match (&self.brush, mode) {
            (Some(_), Mode::Full) => Brushed::new(&document.brush, "the brush").unwrap_or_else(|e| {
                problems.push(format!("{e:#}"));
                None
            }),
            _ => None,
        };
        if mode == Mode::Full {
            self.brush_consistency = fitted_brush.as_ref().map(Brushed::consistency);
        }
        let brush = match (fitted_brush, &self.brush) {
            (Some(fitted), _) => Some(BrushLayer::Fitted(Arc::new(fitted))),
            (None, Some(b)) => Some(BrushLayer::Pointwise(Arc::new(b.clone()))),
            (None, None) => None,
        };
        Layers { start, field, brush }
    }

    /// Reads the displacement field `file` for the next fits (what [`FieldFile::layer`] refuses, in its words), and
    /// returns what its reader assumed ([`FieldLayer::warnings`]).
    ///
    /// # Errors
    /// The file cannot be read as a displacement field.
    pub fn read_field(&mut self, file: &FieldFile) -> Result<Vec<String>, String> {
        self.field = None;
        self.field_layer(file).map(|layer| layer.warnings.clone())
    }

    /// The field of `file`, read the first time it is asked for.
    fn field_layer(&mut self, file: &FieldFile) -> Result<Arc<FieldLayer>, String> {
        if self.field.as_ref().is_none_or(|(f, _)| f != file) {
            let read = file.layer().map(Arc::new).map_err(|e| format!("{e:#}"));
            self.field = Some((file.clone(), read));
        }
        match &self.field {
            Some((_, read)) => read.clone(),
            None => Err(anyhow!("{}: not read", file.path.display()).to_string()),
        }
    }

    /// The drag's fast path for the pairs (`fixed`, `moving`) on `layers` with its texture (box, edge) on `route`: the
    /// drag in progress when only its point moved, else a new drag when exactly one point moved since the last fit;
    /// `None` (and no drag kept) otherwise.
    fn drag_event(
        &mut self,
        method: &Method,
        (fixed, moving): (&[Point3<Fixed>], &[Point3<Moving>]),
        texture: (Aabb<Fixed>, usize),
        route: ControlRoute,
        layers: &Layers,
    ) -> Option<DragEvent> {
        let current = self.drag.as_ref().filter(|d| d.route() == route && d.same_layers(layers));
        if let Some(event) = current.and_then(|d| d.event(fixed, moving)) {
            return Some(event);
        }
        self.drag = None;
        let before = self.fitted.as_ref()?;
        let moved = fit::moved_point((&before.fixed, &before.moving), fixed, moving)?;
        // The basis the last full fit left, on its pairs (the drag's start, before this event's move); it is waited
        // for if its thread is still at work, which costs no more than factorising here.
        let basis = self.drag_basis.take().and_then(|job| job.recv().ok().flatten()?.ok());
        let drag = match basis.filter(|b| b.fits(method, (&before.fixed, &before.moving), layers)) {
            Some(basis) => DragFit::from_basis(basis, texture, moved, route)?.ok()?,
            None => DragFit::start(method, (fixed, moving), texture, moved, route, layers)?.ok()?,
        };
        let event = drag.event(fixed, moving);
        self.drag = Some(drag);
        event
    }
}

/// Starts factorising the next drag's basis ([`DragBasis::new`]) for `method` on the pairs and `layers` on a thread
/// of its own; `None` where a drag keeps the full fit, or where the thread cannot be started (the drag then
/// factorises on its first event).
fn start_drag_basis(
    method: Method,
    (fixed, moving): (Vec<Point3<Fixed>>, Vec<Point3<Moving>>),
    layers: &Layers,
) -> Option<std::sync::mpsc::Receiver<Option<anyhow::Result<DragBasis>>>> {
    if !matches!(method, Method::Tps { .. }) || layers.brush.is_some() {
        return None;
    }
    let layers = Layers { start: layers.start.clone(), field: layers.field.clone(), brush: None };
    let (send, done) = std::sync::mpsc::channel();
    std::thread::Builder::new()
        .name("drag basis".into())
        .spawn(move || {
            // The receiver is gone when a newer fit replaced this one.
            let _ = send.send(DragBasis::new(&method, (&fixed, &moving), &layers));
        })
        .ok()?;
    Some(done)
}
