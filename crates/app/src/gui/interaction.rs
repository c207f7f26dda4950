//! The pointer's work on the views as the window carries it out: grabbing and dragging glyphs, placing the points
//! of a new pair, sculpting with the brush; the states themselves are [`super::tool`]'s.

use eframe::egui;
use warpbench_gpu::PickTarget;
use warpbench_io::geometry::Point3;
use warpbench_solver::brush::BrushStroke;

use super::suggestion::Suggested;
use super::tool::{DragPoint, DragView, End, GRAB_RADIUS, Placing, SculptDrag};
use super::{Command, Ready, placement};

/// The pointer's work on the views: grabbing and dragging glyphs, placing the points of a new pair.
impl Ready {
    /// The landmark glyph nearest `pointer` within [`GRAB_RADIUS`], given where each glyph lands on screen
    /// (`screen`: ref mm of a glyph of that end to screen points, `None` when not shown there).
    pub(crate) fn grab(
        &self,
        pointer: egui::Pos2,
        screen: impl Fn([f64; 3], End) -> Option<egui::Pos2>,
    ) -> Option<(usize, End)> {
        let mut best: Option<(f32, usize, End)> = None;
        for i in 0..self.document.pairs.len() {
            for end in [End::Fixed, End::Moving] {
                let Some(at) = self.glyph_ref(i, end).and_then(|p| screen(p, end)) else { continue };
                let d = at.distance(pointer);
                if d <= GRAB_RADIUS && best.is_none_or(|(b, ..)| d < b) {
                    best = Some((d, i, end));
                }
            }
        }
        best.map(|(_, i, end)| (i, end))
    }

    /// A press on the suggested target's ghost ([`super::suggestion`]) within [`GRAB_RADIUS`] of where `screen` shows
    /// it takes the suggestion (the pair is completed there) and grabs its fixed point in `view`, so that the drag
    /// which follows adjusts it; returns the pair.
    pub(crate) fn grab_ghost(
        &mut self,
        pointer: egui::Pos2,
        screen: impl Fn([f64; 3], End) -> Option<egui::Pos2>,
        view: DragView,
    ) -> Option<usize> {
        let s = self.pointer.interaction.suggestion()?;
        if screen(s.fixed_lps, End::Fixed)?.distance(pointer) > GRAB_RADIUS {
            return None;
        }
        let pair = self.document.pairs.len();
        self.apply(Command::AcceptSuggestion);
        (self.document.pairs.len() == pair + 1
            && self.pointer.interaction.grab(DragPoint { pair, end: End::Fixed, view }))
        .then_some(pair)
    }

    /// Moves the dragged point so that it is shown at `x_ref`: the fixed point to x_ref, the moving point to
    /// u(x_ref) (the moving point the warp shows there) unless a pick gives it (`moving_lps`). Refits interactively.
    pub(crate) fn drag_to(&mut self, x_ref: [f64; 3], moving_lps: Option<[f64; 3]>) {
        let Some(drag) = self.pointer.interaction.drag() else { return };
        let moving = moving_lps.unwrap_or_else(|| self.moving_shown_at(x_ref));
        let (volume, p) = match drag.end {
            End::Fixed => (&self.loaded.fixed, x_ref),
            End::Moving => (&self.loaded.moving, moving),
        };
        // Off its volume the point stays where it was.
        if let Some(message) = placement::outside_message(drag.end, volume, p) {
            self.pointer.notice = Some(message);
            return;
        }
        self.pointer.notice = None;
        self.apply(Command::MovePoint { pair: drag.pair, end: drag.end, to: Point3::from_array(p), settled: false });
    }

    /// Ends a drag in `view`: the full fit with its diagnostics.
    pub(crate) fn end_drag(&mut self, view: DragView) {
        if self.pointer.interaction.release(view).is_some() {
            self.refit_soon();
        }
    }

    /// The step of adding a pair.
    #[must_use]
    pub fn placing(&self) -> Placing {
        self.pointer.interaction.placing()
    }

    /// The target suggested for the pair being added ([`super::suggestion`]).
    #[must_use]
    pub fn suggestion(&self) -> Option<Suggested> {
        self.pointer.interaction.suggestion()
    }

    /// The landmark point being dragged.
    #[must_use]
    pub fn drag(&self) -> Option<DragPoint> {
        self.pointer.interaction.drag()
    }

    /// Whether the brush is the tool.
    #[must_use]
    pub fn sculpting(&self) -> bool {
        self.pointer.interaction.sculpting()
    }

    /// The brush stroke being made.
    #[must_use]
    pub fn sculpt_drag(&self) -> Option<SculptDrag> {
        self.pointer.interaction.sculpt_drag()
    }

    /// A drag event in the 3-D view at framebuffer point `pixel`: the dragged point follows the surface under the
    /// pointer (the volume it belongs to, picked with the current probe); off the volume it stays.
    pub(crate) fn drag_in_view(&mut self, pixel: [f32; 2]) {
        let Some(drag) = self.pointer.interaction.drag() else { return };
        let Some(size) = self.view.images.view.as_ref().map(|v| (v.target.width, v.target.height)) else { return };
        let target = match drag.end {
            End::Moving => PickTarget::Moving,
            End::Fixed => PickTarget::Fixed,
        };
        let settings = self.document.settings.render_settings();
        match self.viewer.pick(&self.view.camera, &settings, size, pixel, target, self.document.settings.probe()) {
            Ok(Some(hit)) => {
                let moving = matches!(target, PickTarget::Moving).then(|| hit.p_lps.map(f64::from));
                self.drag_to(picked_ref(&hit), moving);
            }
            Ok(None) => {}
            Err(e) => self.fit.error = Some(format!("picking: {e:#}")),
        }
    }

    /// Places the point at ref position `x_ref` (a click in a slice, or a pick in the 3-D view, already in ref
    /// space): the source through the warp's pull-back (the moving volume's point shown there) unless the pick gives
    /// it (`moving_lps`), the target as is. A completed pair is appended, active, and the warp is fitted again.
    ///
    /// A point outside its volume is refused: nothing is stored, the step stays, and [`Pointer::notice`](super::Pointer::notice) says why.
    pub fn place_at_ref(&mut self, x_ref: [f64; 3], moving_lps: Option<[f64; 3]>) {
        match self.placing() {
            Placing::Idle => {}
            Placing::Source => {
                let p = moving_lps.unwrap_or_else(|| self.moving_shown_at(x_ref));
                if let Some(message) = placement::outside_message(End::Moving, &self.loaded.moving, p) {
                    self.pointer.notice = Some(message);
                    return;
                }
                self.pointer.notice = None;
                self.pointer.interaction.placed_moving(Point3::from_array(p));
                // The suggested target, shown as a ghost that Enter takes.
                match self.suggestion_for(Point3::from_array(p)) {
                    Ok(s) => self.pointer.interaction.suggest(s),
                    Err(e) => self.pointer.notice = Some(e),
                }
            }
            Placing::Target { moving } => {
                if let Some(message) = placement::outside_message(End::Fixed, &self.loaded.fixed, x_ref) {
                    self.pointer.notice = Some(message);
                    return;
                }
                self.pointer.notice = None;
                self.pointer.interaction.placed_fixed();
                self.apply(Command::AddPair { moving, fixed: Point3::from_array(x_ref) });
            }
        }
        self.invalidate();
    }

    /// The point of the deformed moving volume shown at framebuffer point `pixel` of the 3-D view (a pick with the
    /// current probe), in ref space; `None` where the ray hits nothing (or the pick failed: the status bar says so).
    pub(crate) fn pick_moving_at(&mut self, pixel: [f32; 2]) -> Option<[f64; 3]> {
        let size = self.view.images.view.as_ref().map(|v| (v.target.width, v.target.height))?;
        let settings = self.document.settings.render_settings();
        let probe = self.document.settings.probe();
        match self.viewer.pick(&self.view.camera, &settings, size, pixel, PickTarget::Moving, probe) {
            Ok(hit) => hit.map(|h| h.x_ref.map(f64::from)),
            Err(e) => {
                self.fit.error = Some(format!("picking: {e:#}"));
                None
            }
        }
    }

    /// A click at framebuffer point `pixel` of the 3-D view: picks the volume the placing step asks for.
    pub(crate) fn pick_in_view(&mut self, pixel: [f32; 2]) {
        let target = match self.placing() {
            Placing::Idle => return,
            Placing::Source => PickTarget::Moving,
            Placing::Target { .. } => PickTarget::Fixed,
        };
        let Some(size) = self.view.images.view.as_ref().map(|v| (v.target.width, v.target.height)) else { return };
        let settings = self.document.settings.render_settings();
        match self.viewer.pick(&self.view.camera, &settings, size, pixel, target, self.document.settings.probe()) {
            Ok(Some(hit)) => {
                let moving = matches!(target, PickTarget::Moving).then(|| hit.p_lps.map(f64::from));
                self.place_at_ref(picked_ref(&hit), moving);
            }
            Ok(None) => self.fit.error = Some("the click hit nothing: try another point or probe".into()),
            Err(e) => self.fit.error = Some(format!("picking: {e:#}")),
        }
    }
}

/// The brush's pointer work.
impl Ready {
    /// A press with the brush at ref point `from_ref` in `view` (in the 3-D view the deformed moving volume picked
    /// under the pointer, in a slice the point of the plane): the stroke starts there.
    pub(crate) fn sculpt_press(&mut self, view: DragView, from_ref: [f64; 3]) {
        self.pointer.interaction.start_stroke(view, from_ref);
    }

    /// The brush dragged to `to_ref`: the stroke moves its start by to − from (within its radius's limit), added to
    /// the document at the first move, then replaced, each time fitted interactively.
    pub(crate) fn sculpt_to(&mut self, to_ref: [f64; 3]) {
        let Some(drag) = self.pointer.interaction.sculpt_drag() else { return };
        let displacement_mm: [f64; 3] = std::array::from_fn(|a| to_ref[a] - drag.from_ref[a]);
        if displacement_mm.iter().all(|v| v.abs() < 1e-9) && !drag.added {
            return;
        }
        let stroke = BrushStroke {
            centre_mm: drag.from_ref,
            displacement_mm,
            radius_mm: self.document.settings.brush_radius_mm,
        };
        if drag.added {
            self.apply(Command::MoveStroke { stroke, settled: false });
        } else {
            self.pointer.interaction.stroke_added();
            self.apply(Command::AddStroke(stroke));
        }
    }

    /// The brush released in `view`: the stroke settles (the brush's inverse is fitted again).
    pub(crate) fn sculpt_release(&mut self, view: DragView) {
        if let Some(drag) = self.pointer.interaction.end_stroke(view)
            && drag.added
            && let Some(&stroke) = self.document.brush.last()
        {
            self.apply(Command::MoveStroke { stroke, settled: true });
        }
    }
}

/// The ref point a 3-D pick stands for: for the fixed volume its point (w(x) through a view deformation, x
/// without one: the fixed volume is not warped), for the moving volume the ray's point x, whose moving point the
/// pick gives.
fn picked_ref(hit: &warpbench_gpu::PickHit) -> [f64; 3] {
    match hit.target() {
        PickTarget::Fixed => hit.p_lps.map(f64::from),
        PickTarget::Moving => hit.x_ref.map(f64::from),
    }
}
