//! What the pointer is doing in the views: adding a pair (with the half already placed), dragging one point of a
//! pair, or sculpting with the displacement brush, and which view the drag belongs to.

use eframe::egui;
use warpbench_gpu::PickTarget;
use warpbench_io::geometry::{Lps, Point3};
use warpbench_solver::brush::BrushStroke;

use super::suggestion::Suggested;
use super::{Command, Ready, placement};

/// Adding a pair: the source is picked on the (deformed) moving volume, then the target on the fixed one.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Placing {
    Idle,
    /// The next click picks the source (a point of the moving volume, in moving LPS).
    Source,
    /// The next click picks the target; the source is placed.
    Target {
        moving: Point3<Lps>,
    },
}

/// Which point of a pair.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum End {
    /// The source, on the moving volume (drawn where the warp shows it).
    Moving,
    /// The target, on the fixed volume.
    Fixed,
}

/// Where a landmark is being dragged.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DragView {
    /// Along the visible surface of the 3-D view (a pick per drag event).
    ThreeD,
    /// Within the plane of slice view 0 (axial), 1 (coronal) or 2 (sagittal).
    Slice(usize),
}

/// A landmark point being dragged.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DragPoint {
    pub pair: usize,
    pub end: End,
    pub view: DragView,
}

/// A drag of the displacement brush ([`warpbench_solver::brush`]): pressed at `from_ref` (a point of the deformed
/// moving volume as shown) in `view`; once the pointer has moved, the stroke is the last of the document's brush.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SculptDrag {
    pub view: DragView,
    pub from_ref: [f64; 3],
    /// The stroke was added to the document (the pointer moved).
    pub added: bool,
}

/// How close (points) a press must be to a landmark glyph to grab it.
pub const GRAB_RADIUS: f32 = 8.0;

/// How far (mm) from a slice plane a landmark is still drawn on, and grabbed from, that slice.
pub const SLICE_SLAB_MM: f64 = 3.0;

/// What the pointer is doing in the views. Only the transitions below write it, so a new tool (a brush, a lens, a
/// suggested landmark to accept) is a new variant with its own transitions, not another flag.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub enum Interaction {
    #[default]
    Idle,
    /// Adding a pair: the next click places its moving point, or (`moving` placed) its fixed point; `suggestion`:
    /// the target suggested for the placed moving point ([`super::suggestion`]), which Enter takes.
    Adding { moving: Option<Point3<Lps>>, suggestion: Option<Suggested> },
    /// One point of a pair follows the pointer in a view.
    Dragging(DragPoint),
    /// The brush is the tool: a press and drag on the moving volume displaces it (`drag`: the stroke being made).
    Sculpting { drag: Option<SculptDrag> },
}

impl Interaction {
    /// The step of adding a pair.
    #[must_use]
    pub fn placing(&self) -> Placing {
        match *self {
            Self::Adding { moving: None, .. } => Placing::Source,
            Self::Adding { moving: Some(moving), .. } => Placing::Target { moving },
            Self::Idle | Self::Dragging(_) | Self::Sculpting { .. } => Placing::Idle,
        }
    }

    /// The point being dragged.
    #[must_use]
    pub fn drag(&self) -> Option<DragPoint> {
        match *self {
            Self::Dragging(d) => Some(d),
            Self::Idle | Self::Adding { .. } | Self::Sculpting { .. } => None,
        }
    }

    /// Whether the brush is the tool.
    #[must_use]
    pub fn sculpting(&self) -> bool {
        matches!(self, Self::Sculpting { .. })
    }

    /// The brush stroke being made.
    #[must_use]
    pub fn sculpt_drag(&self) -> Option<SculptDrag> {
        match *self {
            Self::Sculpting { drag } => drag,
            _ => None,
        }
    }

    /// The brush button or B: the brush becomes the tool (instead of nothing or adding a pair), or stops being it.
    /// A drag (of a point or a stroke) goes on.
    pub fn toggle_sculpting(&mut self) {
        *self = match *self {
            Self::Idle | Self::Adding { .. } => Self::Sculpting { drag: None },
            Self::Sculpting { drag: None } => Self::Idle,
            other => other,
        };
    }

    /// A press with the brush at `from_ref` in `view` starts a stroke; returns whether it did.
    pub fn start_stroke(&mut self, view: DragView, from_ref: [f64; 3]) -> bool {
        let idle = *self == Self::Sculpting { drag: None };
        if idle {
            *self = Self::Sculpting { drag: Some(SculptDrag { view, from_ref, added: false }) };
        }
        idle
    }

    /// The stroke being made was added to the document.
    pub fn stroke_added(&mut self) {
        if let Self::Sculpting { drag: Some(d) } = self {
            d.added = true;
        }
    }

    /// The stroke in `view` ends; returns it.
    pub fn end_stroke(&mut self, view: DragView) -> Option<SculptDrag> {
        let drag = self.sculpt_drag().filter(|d| d.view == view)?;
        *self = Self::Sculpting { drag: None };
        Some(drag)
    }

    /// Space or the Add pair button: starts adding a pair, or stops (a placed moving point is dropped). A drag
    /// goes on.
    pub fn toggle_adding(&mut self) {
        *self = match *self {
            Self::Idle | Self::Sculpting { drag: None } => Self::Adding { moving: None, suggestion: None },
            Self::Adding { .. } => Self::Idle,
            other => other,
        };
    }

    /// Stops adding a pair or sculpting between strokes (Esc, undo); returns whether either was the tool.
    pub fn stop_adding(&mut self) -> bool {
        let stopped = matches!(self, Self::Adding { .. } | Self::Sculpting { drag: None });
        if stopped {
            *self = Self::Idle;
        }
        stopped
    }

    /// The pair's moving point is placed at `moving`: its fixed point is next.
    pub fn placed_moving(&mut self, moving: Point3<Lps>) {
        if let Self::Adding { moving: None, .. } = self {
            *self = Self::Adding { moving: Some(moving), suggestion: None };
        }
    }

    /// The pair's fixed point is placed: the pair is complete.
    pub fn placed_fixed(&mut self) {
        if let Self::Adding { moving: Some(_), .. } = self {
            *self = Self::Idle;
        }
    }

    /// The target suggested for the placed moving point, while a pair is being added.
    #[must_use]
    pub fn suggestion(&self) -> Option<Suggested> {
        match *self {
            Self::Adding { moving: Some(_), suggestion } => suggestion,
            _ => None,
        }
    }

    /// Shows `suggestion` for the placed moving point (nothing when no moving point waits for its target).
    pub fn suggest(&mut self, suggestion: Suggested) {
        if let Self::Adding { moving: Some(_), suggestion: slot } = self {
            *slot = Some(suggestion);
        }
    }

    /// Esc with a suggestion shown: drops it (the target is then clicked by hand); returns whether there was one.
    pub fn reject_suggestion(&mut self) -> bool {
        match self {
            Self::Adding { moving: Some(_), suggestion: slot @ Some(_) } => {
                *slot = None;
                true
            }
            _ => false,
        }
    }

    /// A press on a glyph grabs its point, unless a pair is being added or another point dragged; returns whether
    /// it did.
    pub fn grab(&mut self, point: DragPoint) -> bool {
        let idle = *self == Self::Idle;
        if idle {
            *self = Self::Dragging(point);
        }
        idle
    }

    /// The drag in `view` ends; returns the point that was dragged there.
    pub fn release(&mut self, view: DragView) -> Option<DragPoint> {
        let drag = self.drag().filter(|d| d.view == view)?;
        *self = Self::Idle;
        Some(drag)
    }
}

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
        self.apply(Command::MovePoint { pair: drag.pair, end: drag.end, to: p, settled: false });
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    pub(crate) fn adding_a_pair_steps_through_its_two_points_and_a_drag_waits_for_idle() {
        let mut i = Interaction::default();
        let m = Point3::new(1.0, 2.0, 3.0);
        i.toggle_adding();
        assert_eq!(i.placing(), Placing::Source);
        let point = DragPoint { pair: 0, end: End::Fixed, view: DragView::ThreeD };
        assert!(!i.grab(point), "no drag while adding");
        i.placed_moving(m);
        assert_eq!(i.placing(), Placing::Target { moving: m });
        i.placed_fixed();
        assert_eq!(i, Interaction::Idle);
        i.toggle_adding();
        assert!(i.stop_adding() && !i.stop_adding());
        assert!(i.grab(point) && i.drag() == Some(point));
        i.toggle_adding();
        assert_eq!(i.drag(), Some(point), "Space does not end a drag");
        assert_eq!(i.release(DragView::Slice(0)), None, "a drag ends in its own view");
        assert_eq!(i.release(DragView::ThreeD), Some(point));
        assert_eq!(i, Interaction::Idle);
    }

    /// A suggested target belongs to the placed moving point: it is shown only while that point waits for its
    /// target, Esc drops it and leaves the step as it was, and placing the target ends it with the pair.
    #[test]
    fn a_suggested_target_lives_while_its_moving_point_waits() {
        let s =
            Suggested { fixed_lps: [1.0, 2.0, 3.0], predicted_lps: [0.0; 3], confidence: 0.8, low_confidence: false };
        let mut i = Interaction::default();
        i.suggest(s);
        assert_eq!(i.suggestion(), None, "no moving point: nothing to suggest for");
        i.toggle_adding();
        i.suggest(s);
        assert_eq!(i.suggestion(), None);
        let m = Point3::new(4.0, 5.0, 6.0);
        i.placed_moving(m);
        i.suggest(s);
        assert_eq!(i.suggestion(), Some(s));
        assert!(i.reject_suggestion());
        assert_eq!((i.suggestion(), i.placing()), (None, Placing::Target { moving: m }));
        assert!(!i.reject_suggestion());
        i.suggest(s);
        i.placed_fixed();
        assert_eq!((i.suggestion(), i.placing()), (None, Placing::Idle));
    }

    #[test]
    fn the_brush_is_a_tool_whose_strokes_end_in_their_own_view() {
        let mut i = Interaction::default();
        i.toggle_sculpting();
        assert!(i.sculpting() && i.placing() == Placing::Idle && i.drag().is_none());
        let point = DragPoint { pair: 0, end: End::Fixed, view: DragView::ThreeD };
        assert!(!i.grab(point), "no landmark drag while sculpting");
        assert!(i.start_stroke(DragView::Slice(1), [1.0, 2.0, 3.0]));
        assert!(!i.start_stroke(DragView::ThreeD, [0.0; 3]), "one stroke at a time");
        i.toggle_sculpting();
        i.toggle_adding();
        assert!(i.sculpt_drag().is_some(), "neither B nor Space ends a stroke");
        i.stroke_added();
        assert_eq!(i.end_stroke(DragView::ThreeD), None, "a stroke ends in its own view");
        let d = i.end_stroke(DragView::Slice(1)).expect("the stroke");
        assert!(d.added && d.from_ref.iter().zip([1.0, 2.0, 3.0]).all(|(a, b)| (a - b).abs() < 1e-12));
        assert_eq!(i, Interaction::Sculpting { drag: None });
        i.toggle_adding();
        assert_eq!(i.placing(), Placing::Source, "Space switches to adding a pair");
        i.toggle_sculpting();
        assert!(i.stop_adding() && i == Interaction::Idle, "Esc leaves the brush");
    }
}
