//! What [`super::Command::Place`] does: the views moved Back, Forward or to a named view, and views named and
//! forgotten ([`super::places`]); and where the views look at the end of each frame, handed to the history.

use std::time::Duration;

use super::Ready;
use super::places::{Place, PlaceAction, session_camera, with_session_camera};
use crate::project::session::NamedView;

impl Ready {
    /// Where the views look now.
    #[must_use]
    pub fn place(&self) -> Place {
        Place { camera: self.view.camera, slice_mm: self.view.slice_mm }
    }

    /// Moves the views to `place` and draws them again.
    fn move_views_to(&mut self, place: Place) {
        (self.view.camera, self.view.slice_mm) = (place.camera, place.slice_mm);
        self.invalidate();
        self.crosshair_moved();
    }

    /// Hands where the views look at the end of this frame to the history
    /// ([`super::places::ViewHistory::observe`]; `now`: the window's clock).
    pub(super) fn observe_place(&mut self, held: bool, now: Duration) -> Option<Duration> {
        let place = self.place();
        self.view.places.history.observe(place, held, now)
    }

    /// Carries out `action` ([`super::Command::Place`]).
    pub(super) fn place_action(&mut self, action: PlaceAction) {
        let now = self.place();
        let places = &mut self.view.places;
        match action {
            PlaceAction::Back => {
                if let Some(to) = places.history.back(now) {
                    self.move_views_to(to);
                }
            }
            PlaceAction::Forward => {
                if let Some(to) = places.history.forward(now) {
                    self.move_views_to(to);
                }
            }
            PlaceAction::Save(name) => {
                let name = match name.trim() {
                    "" => format!("View {}", places.named.len() + 1),
                    name => name.to_owned(),
                };
                let view =
                    NamedView { name: name.clone(), camera: session_camera(&now.camera), slice_mm: now.slice_mm };
                match places.named.iter_mut().find(|v| v.name == name) {
                    Some(same) => *same = view,
                    None => places.named.push(view),
                }
                places.name_field.clear();
                self.pointer.notice = Some(format!("Saved the view as \"{name}\""));
            }
            PlaceAction::GoTo(i) => {
                let Some(view) = places.named.get(i) else { return };
                let to = Place { camera: with_session_camera(now.camera, &view.camera), slice_mm: view.slice_mm };
                places.history.boundary();
                self.move_views_to(to);
            }
            PlaceAction::Delete(i) => {
                if i < places.named.len() {
                    let gone = places.named.remove(i);
                    self.pointer.notice = Some(format!("Deleted the view \"{}\"", gone.name));
                }
            }
        }
    }
}
