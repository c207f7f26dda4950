//! [`Ready`]: the window's state once a pair is shown, in ten typed parts, and what the window does with them
//! besides carrying out commands ([`super::commands`]), the pointer's work ([`super::interaction`]) and rendering
//! (`rendering.rs`): fitting through the [`Fitter`], Auto-align, where glyphs and slices are, and the status
//! bar's read-outs.

use std::sync::Arc;

use eframe::egui;
use warpbench_gpu::glam::Vec3;
use warpbench_gpu::{GlyphInstance, GlyphPair, GlyphStyle, OrbitCamera, SlicePlane, pair_glyphs};
use warpbench_io::Volume;
use warpbench_io::geometry::Point3;
use warpbench_solver::register::RegisterParams;
use warpbench_solver::spaces::{Fixed, Moving, as_moving};
use warpbench_solver::warp::Warp;

use super::files::Files;
use super::history::History;
use super::images::Images;
use super::load::Loaded;
use super::options::ControlEval;
use super::state::{Assist, Pointer, View};
use super::tool::{End, Placing};
use super::viewer::{DeviceFacts, LayerData, Viewer};
use super::{alignment, open, placement, suggestion};
use crate::fit::{self, Fitted};
use crate::project::document::{self, Document, FitPoints};
use crate::project::fitter::{Evaluation, Fitter, Mode};

/// The window's state once the pair is on the GPU: the open pair and its document with their history, the
/// renderer, what the views show, the fit, what the pointer does, the assistants, the file section, and the egui
/// context.
#[derive(Debug)]
pub struct Ready {
    pub loaded: Loaded,
    /// What the user edits; undo, sessions and the autosave keep it.
    pub document: Document,
    /// Undo and redo.
    pub history: History,
    pub viewer: Viewer,
    /// The camera, the slices, their images and the view tools.
    pub view: View,
    /// The fitted warp and what the fit found ([`Fitter`]).
    pub fit: Fitter,
    /// What the pointer is doing and what it is over.
    pub pointer: Pointer,
    /// Auto-align, the suggested targets' search and the automatic stiffness.
    pub assist: Assist,
    /// The side panel's file and export section: its fields, its last message and the running export.
    pub files: Files,
    /// The window's egui context, for work that reports back to it (screenshots, exports).
    pub(super) ctx: egui::Context,
}

impl Ready {
    /// Fits the warp to the active pairs with the current method and uploads its control texture; with fewer pairs
    /// than the method needs, the moving volume is shown unwarped and the status bar says why. Then the diagnostics:
    /// residuals, leave-one-out errors and folding.
    pub fn refit(&mut self) {
        self.fit_now(true);
    }

    /// Shows the last fit's diagnostics once its thread has them; call once per frame.
    pub fn poll_diagnostics(&mut self) {
        self.fit.poll_diagnostics();
    }

    /// Whether Auto-align is running.
    #[must_use]
    pub fn aligning(&self) -> bool {
        self.assist.aligning.is_some()
    }

    /// Starts Auto-align on the pair as loaded, unless it is running; its result arrives through
    /// [`Self::poll_alignment`].
    pub(super) fn start_alignment(&mut self, kind: warpbench_solver::align::AlignKind) {
        if self.assist.aligning.is_some() {
            return;
        }
        let egui = self.ctx.clone();
        let (fixed, moving) = (Arc::clone(&self.loaded.fixed), Arc::clone(&self.loaded.moving));
        match alignment::AlignJob::start(fixed, moving, kind, move || egui.request_repaint()) {
            Ok(job) => {
                self.assist.aligning = Some(job);
                self.pointer.notice = Some(format!("Auto-align ({kind}): aligning the moving volume to the fixed one"));
            }
            Err(e) => self.pointer.notice = Some(format!("Auto-align: could not start its thread: {e}")),
        }
    }

    /// The refinement by intensities running, if one is.
    #[must_use]
    pub fn refining(&self) -> Option<&super::intensity::IntensityJob> {
        self.assist.refining.as_ref()
    }

    /// Starts refining by intensities on the pair as loaded from the document's stack under the brush, unless one is
    /// running; its result arrives through [`Self::poll_intensities`].
    pub(super) fn start_intensities(&mut self) {
        if self.assist.refining.is_some() {
            return;
        }
        let millis = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_millis());
        let input = super::intensity::RefineInput {
            fixed: Arc::clone(&self.loaded.fixed),
            moving: Arc::clone(&self.loaded.moving),
            pairs: self.document.pairs.clone(),
            method: self.document.settings.method(),
            start: self.document.start.clone(),
            field: self.document.field.clone(),
            out: self.assist.refined_dir.join(format!("refined-{millis}.nii.gz")),
            gpu: (!self.viewer.ctx.is_cpu_driver()).then(|| Arc::clone(&self.viewer.ctx)),
            params: RegisterParams {
                similarity: self.document.settings.refine_metric.similarity(),
                ..RegisterParams::default()
            },
            fixed_mask: self.document.fixed_mask.clone(),
            moving_mask: self.document.moving_mask.clone(),
        };
        let egui = self.ctx.clone();
        match super::intensity::IntensityJob::start(input, move || egui.request_repaint()) {
            Ok(job) => {
                self.assist.refining = Some(job);
                self.pointer.notice = Some("Refine by intensities: registering the pair under the landmarks".into());
            }
            Err(e) => self.pointer.notice = Some(format!("Refine by intensities: could not start its thread: {e}")),
        }
    }

    /// Whether the last fit's diagnostics are still being computed.
    #[must_use]
    pub fn diagnostics_pending(&self) -> bool {
        self.fit.diagnostics_pending()
    }

    /// Fits again once this frame is over ([`Self::refit`]): a change of the document reaches the autosave
    /// before the fit and its diagnostics (many fits on a CPU) run, so what a crash can take is only the time of
    /// the write.
    pub fn refit_soon(&mut self) {
        self.fit.pending = true;
        self.invalidate();
    }

    /// Runs the fit [`Self::refit_soon`] asked for; true when there was one.
    pub fn fit_if_pending(&mut self) -> bool {
        let pending = std::mem::take(&mut self.fit.pending);
        if pending {
            self.refit();
        }
        pending
    }

    /// The fit of [`Self::refit`] without leave-one-out and folding (N more fits and a Jacobian grid): what a drag
    /// event runs, so that the warp follows the pointer; the diagnostics follow when the drag ends. With a TPS, the
    /// first event that moves one point starts a [`fit::DragFit`] and the further events of that point take its
    /// O(N²) path, the control texture made where the window makes it ([`ControlEval`]): updated on the CPU, or
    /// evaluated on the GPU from the new coefficients.
    pub fn refit_interactive(&mut self) {
        self.fit_now(false);
    }

    /// Whether a landmark drag is in progress on the O(N²) path ([`fit::DragFit`]) and where it makes its control
    /// texture.
    #[must_use]
    pub fn drag_route(&self) -> Option<fit::ControlRoute> {
        self.fit.drag_route()
    }

    /// The pairs a fit uses (active, both points placed): their rows, and their fixed and moving points.
    #[must_use]
    pub fn fit_pairs(&self) -> (Vec<usize>, FitPoints) {
        self.document.fit_pairs()
    }

    /// The automatic stiffness shown by the slider: the last choice, while the stiffness and the pairs are the ones
    /// it was made for.
    #[must_use]
    pub fn current_stiffness_choice(&self) -> Option<&warpbench_solver::stiffness::StiffnessChoice> {
        let c = self.assist.stiffness_choice.as_ref()?;
        let current = c.choice.lambda.to_bits() == self.document.settings.stiffness.to_bits()
            && self.document.settings.method == crate::settings::MethodKind::Tps
            && self.fit_pairs().1 == c.pairs;
        current.then_some(&c.choice)
    }

    fn fit_now(&mut self, diagnostics: bool) {
        self.invalidate();
        let mode = if diagnostics { Mode::Full } else { Mode::Interactive };
        let evaluation = match self.view.control_eval {
            ControlEval::Auto if !self.viewer.ctx.is_cpu_driver() => Evaluation::Gpu,
            ControlEval::Gpu => Evaluation::Gpu,
            ControlEval::Auto | ControlEval::Cpu => Evaluation::Cpu,
        };
        let egui = self.ctx.clone();
        let volumes = (&*self.loaded.fixed, &*self.loaded.moving);
        self.fit.fit(&self.document, volumes, (mode, evaluation), &mut self.viewer, move || egui.request_repaint());
    }

    /// Replaces one side of the pair with `volume` read from `path` (`layer`: prepared for the GPU on the reading
    /// thread, else here): that side's GPU resources, the views re-centred on a new fixed volume, and the warp fitted
    /// again. The landmarks stay (their points are in patient space).
    pub fn replace_volume(
        &mut self,
        side: open::Side,
        volume: Arc<Volume>,
        layer: Option<LayerData>,
        source: open::VolumeSource,
    ) -> anyhow::Result<()> {
        self.document.layers[side as usize] = self.swap_volume(side, volume, Some(source), layer)?;
        self.refit_soon();
        Ok(())
    }

    /// Shows `volume` read from `path` on `side` (prepared as `layer`, else here) without fitting again: the GPU
    /// layer, the document's path, the title, and for the fixed side the camera and slices re-centred. Returns the
    /// volume's automatic look; the document's look stays.
    pub(super) fn swap_volume(
        &mut self,
        side: open::Side,
        volume: Arc<Volume>,
        source: Option<open::VolumeSource>,
        layer: Option<LayerData>,
    ) -> anyhow::Result<document::Look> {
        self.assist.matching.reset();
        let layer = match layer {
            Some(layer) => layer,
            None => LayerData::prepare(&volume, DeviceFacts::of(&self.viewer.ctx))?,
        };
        self.viewer.replace_layer(side == open::Side::Fixed, &layer)?;
        let (path, part) = source.map_or((None, None), |s| (Some(s.path), s.part));
        let d = &mut self.document;
        match side {
            open::Side::Fixed => (self.loaded.fixed, d.fixed, d.fixed_part) = (volume, path, part),
            open::Side::Moving => (self.loaded.moving, d.moving, d.moving_part) = (volume, path, part),
        }
        let [fixed, moving] = self.document.sources();
        let name = |s: Option<open::VolumeSource>| s.map_or_else(|| "(demo)".to_owned(), |s| s.name());
        self.loaded.title = format!("{} -> {}", name(fixed), name(moving));
        if side == open::Side::Fixed {
            let (lo, hi) = self.viewer.scene_box();
            let (azimuth, elevation) = (self.view.camera.azimuth_rad, self.view.camera.elevation_rad);
            self.view.camera = OrbitCamera::fit(lo, hi, self.view.camera.projection);
            (self.view.camera.azimuth_rad, self.view.camera.elevation_rad) = (azimuth, elevation);
            let mid = (lo + hi) * 0.5;
            self.view.slice_mm = [f64::from(mid.z), f64::from(mid.y), f64::from(mid.x)];
        }
        self.view.images = Images::default();
        Ok(layer.look)
    }

    /// Where pair `i`'s `end` is drawn, ref mm: the fixed point as is, the moving point through the forward warp
    /// (where the deformed moving volume shows it).
    #[must_use]
    pub fn glyph_ref(&self, i: usize, end: End) -> Option<[f64; 3]> {
        let p = self.document.pairs.get(i)?;
        match end {
            End::Fixed => p.fixed.map(|q| q.coords()),
            End::Moving => p.moving.map(|m| self.shown_at(m.coords())),
        }
    }

    /// Where the view shows the moving volume's point `moving_lps`: d(p) through the forward warp (p itself before a
    /// fit).
    #[must_use]
    pub fn shown_at(&self, moving_lps: [f64; 3]) -> [f64; 3] {
        let m = warpbench_io::geometry::Point3::<warpbench_io::geometry::Lps>::from_array(moving_lps);
        match self.fit.fitted() {
            // With a brush on top, b(d(p)) (the stack's forward map).
            Some(f) => f.forward.apply(as_moving(m)).coords(),
            None => self.fit.brush.as_ref().map_or(moving_lps, |b| b.apply_raw(moving_lps)),
        }
    }

    /// The moving volume's procedural deformation over its box, as the settings ask for it (`Ok(None)`: none); an
    /// amplitude the kind cannot take over this volume is the error, for the panel to say.
    pub fn procedural(&self) -> Result<Option<warpbench_gpu::Procedural>, String> {
        let Some(spec) = &self.document.settings.procedural else { return Ok(None) };
        let domain = crate::inputs::volume_box::<warpbench_solver::spaces::Moving>(&self.loaded.moving);
        spec.build(domain).map(Some).map_err(|e| format!("{e:#}"))
    }

    /// The warp shown (both directions and the pairs they were fitted on): `None` before a fit and after one that
    /// failed.
    #[must_use]
    pub fn fitted(&self) -> Option<&Fitted> {
        self.fit.fitted()
    }

    /// Number of pairs the current warp was fitted on.
    #[must_use]
    pub fn fitted_pairs(&self) -> usize {
        self.fit.fitted().map_or(0, |f| f.pairs)
    }

    /// The view deformations of the 3-D view's (fixed, moving) layers at `now`: the leafer on its volume while it is
    /// open ([`super::leafer`]), else the attention lens on both while it pulses.
    #[must_use]
    pub fn view_deformations(&self, now: std::time::Instant) -> [Option<warpbench_gpu::ViewDeformation>; 2] {
        if self.view.leafer.is_open() {
            let crosshair =
                Vec3::new(self.view.slice_mm[2] as f32, self.view.slice_mm[1] as f32, self.view.slice_mm[0] as f32);
            let f = &self.viewer.fixed.volume.info;
            return self.view.leafer.views(&self.view.camera, crosshair, (f.box_min_lps, f.box_max_lps));
        }
        [self.view_lens(now); 2]
    }

    /// The attention lens of the 3-D view at `now` ([`super::attention`]): about the selected pair's fixed point while the
    /// pulse is on and the leafer is closed.
    #[must_use]
    pub fn view_lens(&self, now: std::time::Instant) -> Option<warpbench_gpu::ViewDeformation> {
        if self.view.leafer.is_open() {
            return None;
        }
        let centre = self.pointer.selected.and_then(|i| self.document.pairs.get(i)).and_then(|p| p.fixed);
        let centre = centre.map(|q| Vec3::from_array(q.coords().map(|v| v as f32)));
        let f = &self.viewer.fixed.volume.info;
        let shortest = (f.box_max_lps - f.box_min_lps).min_element() as f32;
        self.view.attention.lens(centre, shortest, now)
    }

    /// The landmark glyphs drawn over the slices (none when landmarks are hidden).
    #[must_use]
    pub fn glyphs(&self) -> Vec<GlyphInstance> {
        self.glyphs_through([None; 2])
    }

    /// The landmark glyphs drawn over the 3-D view through its (fixed, moving) view deformations: each fixed point
    /// where the first shows it and each moving point where the second does, w⁻¹(x).
    #[must_use]
    pub fn glyphs_through(&self, views: [Option<warpbench_gpu::ViewDeformation>; 2]) -> Vec<GlyphInstance> {
        if !self.document.settings.show_landmarks {
            return Vec::new();
        }
        let shown = |c: [f64; 3], view: Option<warpbench_gpu::ViewDeformation>| {
            let x = Vec3::from_array(c.map(|v| v as f32));
            view.map_or(x, |w| w.forward(x))
        };
        let pairs: Vec<GlyphPair> = self
            .document
            .pairs
            .iter()
            .enumerate()
            .map(|(i, p)| GlyphPair {
                moving_ref: p.moving.map(|m| shown(self.shown_at(m.coords()), views[1])),
                fixed_ref: p.fixed.map(|q| shown(q.coords(), views[0])),
                selected: self.pointer.selected == Some(i),
                active: p.active,
            })
            .collect();
        let mut glyphs = pair_glyphs(&pairs, &GlyphStyle::default());
        // The suggested target of the pair being added: a ghost point, joined to its moving point as shown.
        if let (Some(s), Placing::Target { moving }) = (self.pointer.interaction.suggestion(), self.placing()) {
            let style = GlyphStyle::default();
            let colour = if s.low_confidence { suggestion::GHOST_LOW_COLOUR } else { suggestion::GHOST_COLOUR };
            let ghost = shown(s.fixed_lps, views[0]);
            glyphs.push(GlyphInstance::line(
                shown(self.shown_at(moving.coords()), views[1]),
                ghost,
                style.line_width_px,
                colour,
            ));
            glyphs.push(GlyphInstance::point(ghost, 1.3 * style.point_radius_px, colour));
        }
        glyphs
    }

    /// The suggested target of moving point `p` ([`super::suggestion`]): predicted by the current warp's forward map (with
    /// the brush on top; the starting transform alone, or the identity, before there is a fit) and refined by the
    /// local similarity search.
    ///
    /// # Errors
    /// The search's, in the window's words.
    pub fn suggestion_for(&mut self, p: Point3<warpbench_io::geometry::Lps>) -> Result<suggestion::Suggested, String> {
        let identity = warpbench_solver::linear::AffineWarp::<Fixed, Moving>::identity();
        let start = self.document.start.as_ref().and_then(|s| s.start().ok());
        let unfitted: &dyn warpbench_solver::Warp<Fixed, Moving> = match &start {
            Some(s) => s.fixed_from_moving(),
            None => &identity,
        };
        let brushed = self.fit.brush.as_ref().map(|b| warpbench_solver::warp::Composed { first: unfitted, second: b });
        // The stack's forward map has the brush on top already.
        let forward: &dyn warpbench_solver::Warp<Fixed, Moving> = match (self.fit.fitted(), &brushed) {
            (Some(f), _) => &f.forward,
            (None, Some(b)) => b,
            (None, None) => unfitted,
        };
        self.assist.matching.suggest((&self.loaded.fixed, &self.loaded.moving), forward, p)
    }

    /// Slice view `a`'s plane (0 axial, 1 coronal, 2 sagittal).
    #[must_use]
    pub fn slice_plane(&self, a: usize) -> SlicePlane {
        self.slice_planes()[a.min(2)]
    }

    /// The three slice planes: grid planes of the fixed volume through the crosshair, or oblique planes turned
    /// about it (same pixel size and image size as the grid plane).
    pub(super) fn slice_planes(&self) -> [SlicePlane; 3] {
        let f = &self.loaded.fixed;
        let m = f.lps_from_index.rows();
        let grid = [
            SlicePlane::axial(&m, f.dims, self.view.slice_mm[0]),
            SlicePlane::coronal(&m, f.dims, self.view.slice_mm[1]),
            SlicePlane::sagittal(&m, f.dims, self.view.slice_mm[2]),
        ];
        let crosshair = [self.view.slice_mm[2], self.view.slice_mm[1], self.view.slice_mm[0]];
        std::array::from_fn(|a| {
            let (plane, o) = (grid[a], self.document.settings.oblique[a]);
            if !o.on {
                return plane;
            }
            oblique_plane(&plane, crosshair, o).unwrap_or(plane)
        })
    }

    /// The moving point the warp shows at ref point `x_ref`: u(x_ref) through the pull-back (the identity before a
    /// warp is fitted).
    #[must_use]
    pub fn moving_shown_at(&self, x_ref: [f64; 3]) -> [f64; 3] {
        match self.fit.fitted() {
            // With a brush on top, u(b⁻¹(x)), b⁻¹ solved at x.
            Some(f) => f.pullback.apply_exact_raw(x_ref),
            None => self.fit.brush.as_ref().map_or(x_ref, |b| b.invert_point(x_ref)),
        }
    }

    /// What the status bar shows for ref point `x_ref` under the pointer: the two points, det ∇u there and the nearest
    /// pair.
    #[must_use]
    pub fn cursor_at(&self, x_ref: [f64; 3]) -> placement::Cursor {
        placement::Cursor {
            fixed_lps: x_ref,
            moving_lps: self.moving_shown_at(x_ref),
            det_jacobian: self.pullback_det_at(x_ref),
            nearest: self.nearest_pair(x_ref),
        }
    }

    /// det ∇u at `x_ref` for the pull-back shown, u ∘ b⁻¹ with a brush: det ∇u(b⁻¹(x)) / det ∇b(b⁻¹(x)).
    fn pullback_det_at(&self, x_ref: [f64; 3]) -> Option<f64> {
        Some(self.fit.fitted()?.pullback.det_jacobian_at(x_ref))
    }

    /// The pair whose fixed point is nearest `x_ref`, with its leave-one-out error.
    fn nearest_pair(&self, x_ref: [f64; 3]) -> Option<placement::NearestPair> {
        let distance =
            |q: [f64; 3]| ((q[0] - x_ref[0]).powi(2) + (q[1] - x_ref[1]).powi(2) + (q[2] - x_ref[2]).powi(2)).sqrt();
        let (index, distance_mm) = self
            .document
            .pairs
            .iter()
            .enumerate()
            .filter_map(|(i, p)| Some((i, distance(p.fixed?.coords()))))
            .min_by(|a, b| a.1.total_cmp(&b.1))?;
        let leave_one_out_mm = self.fit.pair_errors.get(index).copied().flatten().and_then(|e| e.leave_one_out_mm);
        Some(placement::NearestPair { index, distance_mm, leave_one_out_mm })
    }
}

/// `plane` turned about `centre_ref` by the oblique view's tilt (about the image's horizontal axis) and spin (about
/// its vertical axis), keeping its pixel size and image size; `None` for a degenerate plane.
fn oblique_plane(plane: &SlicePlane, centre_ref: [f64; 3], o: document::Oblique) -> Option<SlicePlane> {
    use warpbench_gpu::glam::{DQuat, DVec3};
    let u = DVec3::from_array(plane.u_ref);
    let up = -DVec3::from_array(plane.v_ref);
    let normal = DVec3::from_array(plane.normal_ref()?);
    let turn = DQuat::from_axis_angle(u.try_normalize()?, f64::from(o.tilt_deg).to_radians())
        * DQuat::from_axis_angle(up.try_normalize()?, f64::from(o.spin_deg).to_radians());
    SlicePlane::oblique(centre_ref, (turn * normal).to_array(), (turn * up).to_array(), u.length(), plane.size).ok()
}
