//! The attention lens (Brunet, Nowak & Gleicher 2006 §5.2: "a pulsing, fish-eye like deformation … within a sphere
//! of influence around the point of interest … since the human eye is attracted to movement … useful for drawing
//! attention to a region of interest"): the 3-D view magnifies the selected pair's fixed point, opening and closing
//! about it, computed in the shader from a few numbers per frame ([`warpbench_gpu::ViewDeformation::FishEye`]).
//!
//! The lens at time t after it was switched on has the amplitude a(t) = a_peak·½(1 − cos 2πt/T) (T = [`PERIOD`],
//! a_peak = [`PEAK_AMPLITUDE`]: the centre magnified up to 1/(1 − a_peak) times) and the radius [`RADIUS_FRACTION`]
//! of the fixed volume's shortest edge. It deforms only what the 3-D view shows: not the slices (where points are
//! placed exactly), not the document, the registration or any export; a pick through it stores the point of the
//! undeformed volume, and the glyphs are drawn where the lens shows their points.

use std::time::{Duration, Instant};

use warpbench_gpu::ViewDeformation;
use warpbench_gpu::glam::Vec3;

/// One opening and closing of the lens.
pub const PERIOD: Duration = Duration::from_millis(1200);
/// The lens's largest amplitude: its centre magnified up to 1/(1 − 0.45) ≈ 1.8 times.
pub const PEAK_AMPLITUDE: f32 = 0.45;
/// The lens's radius, as a fraction of the fixed volume's shortest edge.
pub const RADIUS_FRACTION: f32 = 0.15;

/// Whether the 3-D view pulses the lens about the selected pair.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Attention {
    #[default]
    Off,
    /// Pulsing since `since`.
    Pulsing { since: Instant },
}

impl Attention {
    /// On if it was off (starting at `now`), off if it was on.
    #[must_use]
    pub fn toggled(self, now: Instant) -> Self {
        match self {
            Self::Off => Self::Pulsing { since: now },
            Self::Pulsing { .. } => Self::Off,
        }
    }

    /// On, keeping the phase of a pulse already running.
    #[must_use]
    pub fn on(self, now: Instant) -> Self {
        match self {
            Self::Off => Self::Pulsing { since: now },
            pulsing @ Self::Pulsing { .. } => pulsing,
        }
    }

    #[must_use]
    pub fn is_on(self) -> bool {
        matches!(self, Self::Pulsing { .. })
    }

    /// a(t) at `now` (module docs); 0 when off.
    #[must_use]
    pub fn amplitude(self, now: Instant) -> f32 {
        match self {
            Self::Off => 0.0,
            Self::Pulsing { since } => {
                let t = now.saturating_duration_since(since).as_secs_f64() / PERIOD.as_secs_f64();
                (f64::from(PEAK_AMPLITUDE) * 0.5 * (1.0 - (std::f64::consts::TAU * t).cos())) as f32
            }
        }
    }

    /// The lens about `centre_ref` at `now` for a fixed volume whose shortest edge is `shortest_edge_mm`; `None`
    /// when off or without a centre.
    #[must_use]
    pub fn lens(self, centre_ref: Option<Vec3>, shortest_edge_mm: f32, now: Instant) -> Option<ViewDeformation> {
        let centre_ref = centre_ref.filter(|_| self.is_on())?;
        Some(ViewDeformation::FishEye {
            centre_ref,
            radius_mm: RADIUS_FRACTION * shortest_edge_mm,
            amplitude: self.amplitude(now),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_lens_pulses_from_nothing_to_its_peak_and_back() {
        let t0 = Instant::now();
        let on = Attention::Off.toggled(t0);
        assert!(on.is_on() && !on.toggled(t0).is_on());
        assert!(on.amplitude(t0).abs() < 1e-9);
        assert!((on.amplitude(t0 + PERIOD / 2) - PEAK_AMPLITUDE).abs() < 1e-6);
        assert!(on.amplitude(t0 + PERIOD) < 1e-6);
        assert!((on.amplitude(t0 + PERIOD / 4) - PEAK_AMPLITUDE / 2.0).abs() < 1e-6);
        assert!(Attention::Off.amplitude(t0 + PERIOD / 2).abs() < 1e-9);
        // Switching on again keeps the phase.
        assert_eq!(on.on(t0 + PERIOD), on);
    }

    #[test]
    fn the_lens_is_about_the_centre_with_a_fraction_of_the_volume() {
        let t0 = Instant::now();
        let on = Attention::Off.toggled(t0);
        let c = Vec3::new(1.0, 2.0, 3.0);
        assert_eq!(on.lens(None, 180.0, t0), None);
        assert_eq!(Attention::Off.lens(Some(c), 180.0, t0), None);
        let Some(ViewDeformation::FishEye { centre_ref, radius_mm, amplitude }) =
            on.lens(Some(c), 180.0, t0 + PERIOD / 2)
        else {
            panic!("a lens")
        };
        assert_eq!(centre_ref, c);
        assert!((radius_mm - 27.0).abs() < 1e-4 && (amplitude - PEAK_AMPLITUDE).abs() < 1e-6);
    }
}
