//! The read-out under the pointer in the 3-D view (issue 18, item 5): once the pointer has rested on the view for
//! [`REST`], one pick of the deformed moving volume under it (the same probe a click uses) gives the fixed point shown
//! there, and the status bar reads the warp out at it as it does over a slice. A pick is one compute dispatch, which
//! a CPU driver cannot afford at every pointer move, so a moving pointer picks nothing, a resting one picks once,
//! and the hit is kept until the pointer, the camera, the warp or the look changes.

use std::time::{Duration, Instant};

use eframe::egui;

/// How long the pointer must rest before the 3-D view is picked under it.
pub const REST: Duration = Duration::from_millis(250);

/// What the view under the pointer depends on: the camera, the fit (by its generation) and the settings' look.
#[derive(Clone, Debug, PartialEq)]
pub struct ViewKey {
    pub camera: warpbench_gpu::OrbitCamera,
    pub fit_generation: u64,
    pub settings: crate::project::document::ViewSettings,
}

/// The hover pick's state: where the pointer rests since when, and the last hit.
#[derive(Clone, Debug, Default)]
pub struct HoverPick {
    resting: Option<(egui::Pos2, Instant)>,
    /// The position and view the last pick was for, and its hit (a ref point, or nothing under the pointer).
    picked: Option<(egui::Pos2, ViewKey, Option<[f64; 3]>)>,
}

/// What the view should do this frame about the pointer.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum HoverStep {
    /// Nothing: no pointer over the view, or the last pick still holds.
    Idle,
    /// Ask for a frame after this long: the pointer is resting but not yet for [`REST`].
    Wait(Duration),
    /// Pick at this position now.
    Pick(egui::Pos2),
}

impl HoverPick {
    /// The step for the pointer at `pos` (`None`: not over the view, or a button is held) at `now`, the view being
    /// `key`.
    pub fn step(&mut self, pos: Option<egui::Pos2>, key: &ViewKey, now: Instant) -> HoverStep {
        let Some(pos) = pos else {
            self.resting = None;
            return HoverStep::Idle;
        };
        let since = match self.resting {
            Some((at, since)) if at == pos => since,
            _ => {
                self.resting = Some((pos, now));
                now
            }
        };
        if self.picked.as_ref().is_some_and(|(at, k, _)| *at == pos && k == key) {
            return HoverStep::Idle;
        }
        match REST.checked_sub(now.saturating_duration_since(since)) {
            Some(left) if !left.is_zero() => HoverStep::Wait(left),
            _ => HoverStep::Pick(pos),
        }
    }

    /// Keeps the pick at `pos` for the view `key`: `hit` is the ref point under it, if any.
    pub fn picked(&mut self, pos: egui::Pos2, key: ViewKey, hit: Option<[f64; 3]>) {
        self.picked = Some((pos, key, hit));
    }

    /// The point under the resting pointer, while the pick holds for `key` and the pointer is where it was picked.
    #[must_use]
    pub fn hit(&self, pos: Option<egui::Pos2>, key: &ViewKey) -> Option<[f64; 3]> {
        let (at, k, hit) = self.picked.as_ref()?;
        (Some(*at) == pos && k == key).then_some(*hit).flatten()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn key(zoom: f32) -> ViewKey {
        let mut camera = warpbench_gpu::OrbitCamera::fit(
            warpbench_gpu::glam::Vec3::ZERO,
            warpbench_gpu::glam::Vec3::ONE,
            warpbench_gpu::Projection::Orthographic,
        );
        camera.zoom = zoom;
        ViewKey { camera, fit_generation: 1, settings: crate::project::document::ViewSettings::default() }
    }

    /// A moving pointer picks nothing; one resting for [`REST`] picks once; the hit holds until the pointer or the
    /// view changes.
    #[test]
    fn a_resting_pointer_picks_once_per_view() {
        let mut h = HoverPick::default();
        let t0 = Instant::now();
        let (a, b) = (egui::pos2(10.0, 10.0), egui::pos2(12.0, 10.0));
        let k = key(1.0);
        assert!(matches!(h.step(Some(a), &k, t0), HoverStep::Wait(_)));
        assert!(matches!(h.step(Some(b), &k, t0 + REST), HoverStep::Wait(_)), "moved: the rest starts again");
        assert_eq!(h.step(Some(b), &k, t0 + REST * 2), HoverStep::Pick(b));
        h.picked(b, k.clone(), Some([1.0, 2.0, 3.0]));
        assert_eq!(h.step(Some(b), &k, t0 + REST * 3), HoverStep::Idle);
        assert_eq!(h.hit(Some(b), &k), Some([1.0, 2.0, 3.0]));
        assert_eq!(h.hit(Some(a), &k), None);
        let zoomed = key(2.0);
        assert_eq!(h.hit(Some(b), &zoomed), None);
        assert_eq!(h.step(Some(b), &zoomed, t0 + REST * 3), HoverStep::Pick(b), "the view changed: pick again");
        assert_eq!(h.step(None, &k, t0 + REST * 4), HoverStep::Idle);
    }
}
