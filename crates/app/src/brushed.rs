//! The landmark warp with the window's displacement brush on top ([`warpbench_solver::brush`]; issue 17, items 4 and
//! 5): the brush is a forward warp b of the fixed space, so the registration's pull-back becomes u ∘ b⁻¹ (the moving
//! volume is read at u(b⁻¹(x))) and its forward map b ∘ d (a moving point appears at b(d(p))). b⁻¹ has no closed form:
//! it is fitted by scattered-data interpolation ([`warpbench_solver::invert`], Brunet, Nowak & Gleicher 2006 §3.3)
//! over the brush's reach, and its inverse consistency ‖b(b⁻¹(y)) − y‖ is reported wherever the result is shown or
//! written (the window's accuracy section, `--json`).
//!
//! `warp`, `field` and `render` take the brush from a session (`--session`), and the window's export from its
//! document; [`Brushed::pullback`] and [`Brushed::forward`] are the one composition they all use.

use anyhow::anyhow;
use serde::Serialize;
use warpbench_solver::brush::{Brush, BrushInverse, BrushStroke};
use warpbench_solver::invert::{InverseReport, InvertParams};
use warpbench_solver::spaces::{Fixed, Moving};
use warpbench_solver::warp::{Composed, Warp};

/// How well an inverted forward map is undone, ‖d(u(y)) − y‖ over a grid of where it was inverted (`--json`): a
/// forward field over the output box, or the brush over its reach.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct InverseConsistency {
    pub rms_mm: f64,
    pub max_mm: f64,
    /// Points of the check grid.
    pub points: usize,
}

/// A brush with its fitted inverse.
#[derive(Clone, Debug)]
pub struct Brushed {
    brush: Brush,
    inverse: BrushInverse,
    report: InverseReport,
}

impl Brushed {
    /// The brush of `strokes` and its inverse; `None` without strokes. Errors name `origin` (the session file, or
    /// the window's brush) and the stroke by its 1-based number.
    pub fn new(strokes: &[BrushStroke], origin: &str) -> anyhow::Result<Option<Self>> {
        let brush = Brush::new(strokes.to_vec()).map_err(|e| anyhow!("{origin}: {e}"))?;
        let inverse =
            brush.inverse(&InvertParams::default()).map_err(|e| anyhow!("{origin}: inverting the brush: {e}"))?;
        Ok(inverse.map(|(inverse, report)| Self { brush, inverse, report }))
    }

    /// u ∘ b⁻¹: the pull-back with the brush on top.
    #[must_use]
    pub fn pullback<'a>(
        &'a self,
        moving_from_fixed: &'a dyn Warp<Moving, Fixed>,
    ) -> Composed<'a, Moving, Fixed, Fixed> {
        Composed { first: &self.inverse, second: moving_from_fixed }
    }

    /// b ∘ d: the forward map with the brush on top.
    #[must_use]
    pub fn forward<'a>(&'a self, fixed_from_moving: &'a dyn Warp<Fixed, Moving>) -> Composed<'a, Fixed, Fixed, Moving> {
        Composed { first: fixed_from_moving, second: &self.brush }
    }

    /// b⁻¹, as fitted.
    #[must_use]
    pub fn inverse(&self) -> &BrushInverse {
        &self.inverse
    }

    #[must_use]
    pub fn brush(&self) -> &Brush {
        &self.brush
    }

    /// How well the fitted b⁻¹ undoes b over the brush's reach.
    #[must_use]
    pub fn consistency(&self) -> InverseConsistency {
        InverseConsistency { rms_mm: self.report.rms_mm, max_mm: self.report.max_mm, points: self.report.check_points }
    }
}

/// The warp's name in reports: `method`, with `+ brush (N strokes)` when a brush acts on top.
#[must_use]
pub fn describe(method: &dyn std::fmt::Display, brush: Option<&Brushed>) -> String {
    match brush.map(|b| b.brush().strokes().len()) {
        Some(1) => format!("{method} + brush (1 stroke)"),
        Some(n) => format!("{method} + brush ({n} strokes)"),
        None => method.to_string(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use warpbench_io::geometry::Point3;
    use warpbench_solver::linear::{LinearKind, fit};

    /// With a translation as the landmark warp, the composition reads the moving volume at u(b⁻¹(x)): the brushed
    /// point c + t shows what u shows at c, and b ∘ d puts a moving point where the brush moved its image.
    #[test]
    fn the_brush_acts_on_top_of_the_landmark_warp() {
        let stroke = BrushStroke { centre_mm: [10.0, 0.0, 0.0], displacement_mm: [0.0, 4.0, 0.0], radius_mm: 20.0 };
        let brushed = Brushed::new(&[stroke], "test").expect("brush").expect("a stroke");
        let shift = [3.0, -2.0, 1.0];
        let fixed: Vec<Point3<Fixed>> =
            [[0.0, 0.0, 0.0], [50.0, 0.0, 0.0], [0.0, 50.0, 0.0], [0.0, 0.0, 50.0]].map(Point3::from_array).to_vec();
        let moving: Vec<Point3<Moving>> =
            fixed.iter().map(|q| Point3::from_array(std::array::from_fn(|a| q.coords()[a] + shift[a]))).collect();
        let u = fit::<Moving, Fixed>(LinearKind::Affine, &fixed, &moving).expect("u").warp;
        let d = fit::<Fixed, Moving>(LinearKind::Affine, &moving, &fixed).expect("d").warp;
        let pulled = brushed.pullback(&u).apply_raw([10.0, 4.0, 0.0]);
        let expected = [13.0, -2.0, 1.0];
        assert!((0..3).all(|a| (pulled[a] - expected[a]).abs() < 0.05), "{pulled:?}");
        let shown = brushed.forward(&d).apply_raw([13.0, -2.0, 1.0]);
        assert!((0..3).all(|a| (shown[a] - [10.0, 4.0, 0.0][a]).abs() < 1e-6), "{shown:?}");
        let far = brushed.pullback(&u).apply_raw([-80.0, 0.0, 0.0]);
        assert!((0..3).all(|a| (far[a] - [-77.0, -2.0, 1.0][a]).abs() < 1e-9), "untouched far away: {far:?}");
        assert!(brushed.consistency().max_mm < 0.05);
        assert!(Brushed::new(&[], "test").expect("no strokes").is_none());
        let bad = BrushStroke { displacement_mm: [0.0, 40.0, 0.0], ..stroke };
        let err = Brushed::new(&[stroke, bad], "s.warpbench.json").expect_err("too strong").to_string();
        assert!(err.contains("s.warpbench.json") && err.contains("brush stroke 2"), "{err}");
    }
}
