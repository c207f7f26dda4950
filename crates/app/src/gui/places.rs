//! Where the views look, and the ways back there (BigWarp #152: in a long session one stray drag loses the view):
//! the views' history, walked with Back (Alt+Left) and Forward (Alt+Right) as in a browser, and named views, saved
//! in the session and the autosave.
//!
//! A step of the history is one move of the views: an orbit or a slider drag from press to release, wheel
//! turns until the views have been still for [`QUIET`], or one jump (Reset camera, go to a pair, a click or
//! Shift+click that centres the views, a named view). Back returns to where the views were before the last step,
//! Forward undoes a Back, and a new step after Back drops the steps ahead. The history lasts as long as the window;
//! it never touches the document, so Undo and Redo are not affected by it.

use std::time::Duration;

use eframe::egui;
use warpbench_gpu::OrbitCamera;
use warpbench_gpu::glam::{Vec2, Vec3};

use crate::project::session::{NamedView, SessionCamera};

/// How long the views must stay still, with no button held, before the next move is a step of its own.
pub const QUIET: Duration = Duration::from_millis(400);

/// The most steps Back goes through; older ones are forgotten.
pub const MAX_STEPS: usize = 100;

/// Where the views look: the 3-D view's camera and the three slices' positions (mm along S, P, L).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Place {
    pub camera: OrbitCamera,
    pub slice_mm: [f64; 3],
}

/// What the views' Back, Forward and named views were asked to do.
#[derive(Clone, Debug, PartialEq)]
pub enum PlaceAction {
    /// To where the views were before the last step (Alt+Left).
    Back,
    /// Undo a Back (Alt+Right).
    Forward,
    /// Name where the views look now; a view of the same name is replaced.
    Save(String),
    /// To named view i.
    GoTo(usize),
    /// Forget named view i.
    Delete(usize),
}

/// The views' history and named views, and the name being typed for the next one.
#[derive(Debug, Default)]
pub struct Places {
    pub history: ViewHistory,
    pub named: Vec<NamedView>,
    /// The Save view field.
    pub name_field: String,
}

/// The views' history: the places before each step (Back) and those Back left (Forward).
#[derive(Debug, Default)]
pub struct ViewHistory {
    back: Vec<Place>,
    forward: Vec<Place>,
    /// The place at the last [`Self::observe`].
    seen: Option<Place>,
    /// When the views last moved (the window's clock), while a step is under way.
    moved_at: Option<Duration>,
    /// Whether a button was held at the last [`Self::observe`].
    held: bool,
}

impl ViewHistory {
    /// Sees where the views look at the end of a frame (`held`: a pointer button is down). A move from where they
    /// were last seen starts a step, unless one is under way; a step ends when a button is pressed, at a
    /// [`Self::boundary`], or once the views have been still for [`QUIET`] with no button held. `now` is the
    /// window's clock (egui's input time). Returns how long until a step under way could end, for the window to look
    /// again then.
    pub fn observe(&mut self, place: Place, held: bool, now: Duration) -> Option<Duration> {
        if held && !self.held {
            self.end_step();
        }
        self.held = held;
        let seen = self.seen.replace(place)?;
        if place != seen {
            if self.moved_at.is_none() {
                self.push_back(seen);
            }
            self.moved_at = Some(now);
        } else if let Some(at) = self.moved_at
            && !held
            && now.saturating_sub(at) >= QUIET
        {
            self.end_step();
        }
        match self.moved_at {
            Some(at) if !held => Some(QUIET.saturating_sub(now.saturating_sub(at))),
            _ => None,
        }
    }

    /// The next move is a step of its own (a jump is about to move the views).
    pub fn boundary(&mut self) {
        self.end_step();
    }

    /// Where Back goes from `now`, if anywhere; `now` becomes Forward's.
    pub fn back(&mut self, now: Place) -> Option<Place> {
        self.walk(Way::Back, now)
    }

    /// Where Forward goes from `now`, if anywhere; `now` becomes Back's.
    pub fn forward(&mut self, now: Place) -> Option<Place> {
        self.walk(Way::Forward, now)
    }

    /// One place along `way` from `now`, which the other way gets.
    fn walk(&mut self, way: Way, now: Place) -> Option<Place> {
        self.end_step();
        let (from, to) = match way {
            Way::Back => (&mut self.back, &mut self.forward),
            Way::Forward => (&mut self.forward, &mut self.back),
        };
        let place = from.pop()?;
        to.push(now);
        self.seen = Some(place);
        Some(place)
    }

    #[must_use]
    pub fn can_go_back(&self) -> bool {
        !self.back.is_empty()
    }

    #[must_use]
    pub fn can_go_forward(&self) -> bool {
        !self.forward.is_empty()
    }

    /// Ends the step under way; one that ended where it began is forgotten.
    fn end_step(&mut self) {
        if self.moved_at.take().is_some() && self.back.last() == self.seen.as_ref() {
            self.back.pop();
        }
    }

    /// A step begins at `from`: Back will return there, and the steps Back left are dropped.
    fn push_back(&mut self, from: Place) {
        self.forward.clear();
        self.back.push(from);
        if self.back.len() > MAX_STEPS {
            self.back.remove(0);
        }
    }
}

/// Which way [`ViewHistory::walk`] goes.
#[derive(Clone, Copy, Debug)]
enum Way {
    Back,
    Forward,
}

/// The session's form of `camera`.
#[must_use]
pub fn session_camera(camera: &OrbitCamera) -> SessionCamera {
    SessionCamera {
        azimuth_deg: camera.azimuth_rad.to_degrees(),
        elevation_deg: camera.elevation_rad.to_degrees(),
        zoom: camera.zoom,
        target_lps: camera.target_ref.to_array(),
        pan_mm: camera.pan_mm.to_array(),
    }
}

/// `camera` turned, zoomed and shifted as `saved` says; the projection and the scene's size stay.
#[must_use]
pub fn with_session_camera(camera: OrbitCamera, saved: &SessionCamera) -> OrbitCamera {
    OrbitCamera {
        azimuth_rad: saved.azimuth_deg.to_radians(),
        elevation_rad: saved.elevation_deg.to_radians(),
        zoom: saved.zoom,
        target_ref: Vec3::from_array(saved.target_lps),
        pan_mm: Vec2::from_array(saved.pan_mm),
        ..camera
    }
}

/// The toolbar's views: Back and Forward, and the Views menu with the named views (each a button that goes there,
/// and x to forget it) and a field and button to name the view as it is; what was asked for.
pub fn places_ui(ui: &mut egui::Ui, places: &mut Places) -> Option<PlaceAction> {
    let mut asked = None;
    let back = ui.add_enabled(places.history.can_go_back(), egui::Button::new("Back"));
    if back.on_hover_text("Where the views were before the last move (Alt+Left)").clicked() {
        asked = Some(PlaceAction::Back);
    }
    let forward = ui.add_enabled(places.history.can_go_forward(), egui::Button::new("Forward"));
    if forward.on_hover_text("Undo Back (Alt+Right)").clicked() {
        asked = Some(PlaceAction::Forward);
    }
    ui.menu_button("Views", |ui| {
        if places.named.is_empty() {
            ui.weak("No named views yet");
        }
        for (i, view) in places.named.iter().enumerate() {
            ui.horizontal(|ui| {
                let go = ui.button(view.name.as_str()).on_hover_text("Move the camera and the slices to this view");
                if go.clicked() {
                    asked = Some(PlaceAction::GoTo(i));
                }
                let delete = egui::Button::new("x").small();
                if ui.add(delete).on_hover_text(format!("Forget the view \"{}\"", view.name)).clicked() {
                    asked = Some(PlaceAction::Delete(i));
                }
            });
        }
        ui.separator();
        ui.horizontal(|ui| {
            let field = egui::TextEdit::singleline(&mut places.name_field).hint_text("name").desired_width(140.0);
            let typed = ui.add(field.id_salt("view name")).labelled_by(ui.label("View name").id);
            let entered = typed.lost_focus() && ui.input(|i| i.key_pressed(egui::Key::Enter));
            let save = ui.button("Save view").on_hover_text("Name where the camera and the slices are now");
            if save.clicked() || entered {
                asked = Some(PlaceAction::Save(places.name_field.clone()));
            }
        });
    })
    .response
    .on_hover_text("Named views: save where the camera and the slices are, and go back there");
    asked
}

/// Alt+Left and Alt+Right: Back and Forward.
pub fn place_keys(ui: &mut egui::Ui) -> Option<PlaceAction> {
    let key = |ui: &mut egui::Ui, k| ui.input_mut(|i| i.consume_key(egui::Modifiers::ALT, k));
    if key(ui, egui::Key::ArrowLeft) {
        Some(PlaceAction::Back)
    } else if key(ui, egui::Key::ArrowRight) {
        Some(PlaceAction::Forward)
    } else {
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use warpbench_gpu::Projection;

    fn place(azimuth_rad: f32) -> Place {
        let mut camera = OrbitCamera::fit(Vec3::ZERO, Vec3::ONE, Projection::Orthographic);
        camera.azimuth_rad = azimuth_rad;
        Place { camera, slice_mm: [0.0; 3] }
    }

    fn at(ms: u64) -> Duration {
        Duration::from_millis(ms)
    }

    /// A history that has seen `place(0)` at 0 ms and then the moves `steps` (azimuth, held, ms).
    fn seen(steps: &[(f32, bool, u64)]) -> ViewHistory {
        let mut h = ViewHistory::default();
        h.observe(place(0.0), false, at(0));
        for &(azimuth, held, ms) in steps {
            h.observe(place(azimuth), held, at(ms));
        }
        h
    }

    #[test]
    fn a_drag_is_one_step_that_back_leaves_and_forward_returns_to() {
        // Pressed, dragged over three frames, released and still.
        let mut h = seen(&[(0.0, true, 10), (0.1, true, 20), (0.2, true, 30), (0.3, true, 40), (0.3, false, 50)]);
        assert_eq!(h.back.len(), 1, "one step");
        assert_eq!(h.back(place(0.3)), Some(place(0.0)));
        assert!(!h.can_go_back() && h.can_go_forward());
        assert_eq!(h.forward(place(0.0)), Some(place(0.3)));
        assert_eq!(h.forward(place(0.3)), None, "nothing ahead");
    }

    #[test]
    fn wheel_turns_are_one_step_until_the_views_are_still() {
        // Three turns 100 ms apart, then still for QUIET, then two more.
        let mut h = seen(&[(0.1, false, 100), (0.2, false, 200), (0.3, false, 300)]);
        let wait = h.observe(place(0.3), false, at(350)).expect("a step under way");
        assert_eq!(Some(wait), QUIET.checked_sub(Duration::from_millis(50)), "looked at again when it can end");
        assert_eq!(h.observe(place(0.3), false, at(700)), None, "ended");
        h.observe(place(0.4), false, at(800));
        h.observe(place(0.5), false, at(900));
        assert_eq!(h.back(place(0.5)), Some(place(0.3)));
        assert_eq!(h.back(place(0.3)), Some(place(0.0)));
        assert_eq!(h.back(place(0.0)), None);
    }

    #[test]
    fn a_press_or_a_jump_begins_a_step_of_its_own() {
        let mut h = seen(&[(0.1, false, 100)]);
        // A press at once after the wheel: the drag is a step of its own.
        h.observe(place(0.1), true, at(150));
        h.observe(place(0.2), true, at(200));
        h.observe(place(0.2), false, at(250));
        // A jump at once after the release.
        h.boundary();
        h.observe(place(1.0), false, at(260));
        let walked: Vec<Place> = std::iter::from_fn(|| h.back(place(9.0))).collect();
        assert_eq!(walked, [place(0.2), place(0.1), place(0.0)]);
    }

    #[test]
    fn a_step_after_back_drops_the_steps_ahead_and_a_round_trip_is_no_step() {
        let mut h = seen(&[(0.1, false, 10), (0.1, false, 500), (0.2, false, 510)]);
        assert_eq!(h.back(place(0.2)), Some(place(0.1)));
        h.observe(place(0.1), false, at(600));
        h.observe(place(0.7), false, at(610));
        assert!(!h.can_go_forward(), "the new step dropped Forward's");
        // There and back again in one step leaves nothing to go back to.
        let h = seen(&[(0.5, true, 10), (0.0, true, 20), (0.0, false, 30), (0.0, false, 500)]);
        assert!(!h.can_go_back(), "{h:?}");
    }

    #[test]
    fn back_forgets_the_oldest_steps_past_its_limit() {
        let mut h = ViewHistory::default();
        h.observe(place(0.0), false, at(0));
        for k in 1..=MAX_STEPS + 5 {
            h.boundary();
            h.observe(place(k as f32), false, at(k as u64));
        }
        let walked: Vec<Place> = std::iter::from_fn(|| h.back(place(-1.0))).collect();
        assert_eq!(walked.len(), MAX_STEPS);
        assert_eq!(walked.last(), Some(&place(5.0)), "the five oldest are forgotten");
    }

    #[test]
    fn a_camera_survives_the_session_form() {
        let mut camera = OrbitCamera::fit(Vec3::ZERO, Vec3::splat(100.0), Projection::Orthographic);
        (camera.azimuth_rad, camera.elevation_rad, camera.zoom) = (0.7, -0.3, 2.5);
        (camera.target_ref, camera.pan_mm) = (Vec3::new(1.0, 2.0, 3.0), Vec2::new(-4.0, 5.0));
        let back = with_session_camera(OrbitCamera::fit(Vec3::ZERO, Vec3::splat(100.0), camera.projection), &{
            session_camera(&camera)
        });
        assert!((back.azimuth_rad - camera.azimuth_rad).abs() < 1e-6);
        assert!((back.elevation_rad - camera.elevation_rad).abs() < 1e-6);
        assert_eq!((back.zoom, back.target_ref, back.pan_mm), (camera.zoom, camera.target_ref, camera.pan_mm));
        assert_eq!((back.distance_mm, back.radius_mm), (camera.distance_mm, camera.radius_mm));
    }
}
