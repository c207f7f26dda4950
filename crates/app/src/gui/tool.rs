//! What the pointer is doing in the views: adding a pair (with the half already placed), dragging one point of a
//! pair, or sculpting with the displacement brush, and which view the drag belongs to. [`Interaction`] changes only
//! by its transitions; the window carries them out in [`super::interaction`].

use warpbench_io::geometry::{Lps, Point3};

use super::suggestion::Suggested;

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
