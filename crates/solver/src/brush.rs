//! The local displacement brush (Westermann & Rezk-Salama 2001 §3.2: the user grabs a region of the volume and
//! displaces it, the displacement falling off smoothly with a B-spline): a forward warp b of the fixed (render) space,
//! applied on top of the landmark warp, so the window shows the moving volume at u(b⁻¹(x)).
//!
//! Stroke k (centre c_k, displacement t_k, radius R_k, fixed LPS mm) is
//!
//!   b_k(y) = y + t_k β(‖y − c_k‖ / R_k),   β(s) = (3/2) B₃(2s) for s < 1, 0 for s ≥ 1,
//!
//! with B₃ the cubic B-spline (B₃(u) = 2/3 − u² + |u|³/2 on |u| ≤ 1, (2 − |u|)³/6 on 1 ≤ |u| ≤ 2), so β(0) = 1,
//! β(1) = 0 and β is C² everywhere: the grabbed centre moves by t_k exactly and nothing beyond R_k moves. Strokes
//! compose in the order they were made, b = b_n ∘ … ∘ b_1: each deforms what the previous ones produced, as the user
//! drags what is shown.
//!
//! **Fold-free.** |β'(s)| ≤ 2 (its largest slope, at s = 1/3), so the displacement of b_k has the Lipschitz constant
//! 2‖t_k‖/R_k, and b_k is a bijection with det ∇b_k > 0 when ‖t_k‖ < R_k/2; a composition of bijections is one.
//! A stroke is limited to ‖t_k‖ ≤ [`MAX_STRENGTH`]·R_k ([`BrushStroke::clamped`]), which also keeps its inverse
//! smooth enough to fit closely; a longer move is several strokes, or a wider one.
//!
//! **Inverse.** The renderer pulls back, so it needs b⁻¹, which has no closed form: [`Brush::inverse`] fits it by
//! scattered-data interpolation ([`crate::invert`], Brunet, Nowak & Gleicher 2006 §3.3) over the fixed box and
//! reports the inverse consistency ‖b(b⁻¹(y)) − y‖.

use serde::{Deserialize, Serialize};

use crate::bspline::HierarchicalBSpline;
use crate::invert::{InverseReport, InvertParams, invert};
use crate::spaces::{Aabb, Fixed};
use crate::{Result, SolverError, Warp};

/// The largest stroke, as a fraction of its radius. Below 1/2 every stroke is fold-free; 0.3 (det ∇b_k ≥ 0.4) also
/// keeps its inverse smooth enough for [`Brush::inverse`] to fit within 0.01 mm: the largest error over the reach of
/// one stroke of radius 20 mm was 0.0025 mm at 0.2, 0.006 mm at 0.3, 0.012 mm at 0.35, 0.064 mm at 0.4 and 0.29 mm
/// at 0.45, with the default [`InvertParams`] (docs/accuracy.md).
pub const MAX_STRENGTH: f64 = 0.3;

/// The falloff β(s) of the module docs.
#[must_use]
pub fn falloff(s: f64) -> f64 {
    let u = 2.0 * s.abs();
    let b3 = if u <= 1.0 {
        2.0 / 3.0 - u * u + 0.5 * u * u * u
    } else if u < 2.0 {
        (2.0 - u).powi(3) / 6.0
    } else {
        0.0
    };
    1.5 * b3
}

/// dβ/ds at s ≥ 0.
fn falloff_slope(s: f64) -> f64 {
    let u = 2.0 * s.abs();
    let db3 = if u <= 1.0 {
        -2.0 * u + 1.5 * u * u
    } else if u < 2.0 {
        -0.5 * (2.0 - u).powi(2)
    } else {
        0.0
    };
    3.0 * db3
}

/// One drag of the brush: the points near `centre_mm` move by `displacement_mm`, falling off to nothing at
/// `radius_mm` (fixed LPS).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct BrushStroke {
    pub centre_mm: [f64; 3],
    pub displacement_mm: [f64; 3],
    pub radius_mm: f64,
}

impl BrushStroke {
    /// The stroke with its displacement shortened to at most [`MAX_STRENGTH`]·radius (kept fold-free).
    #[must_use]
    pub fn clamped(self) -> Self {
        let t = self.displacement_mm;
        let len = (t[0] * t[0] + t[1] * t[1] + t[2] * t[2]).sqrt();
        let limit = MAX_STRENGTH * self.radius_mm;
        if len <= limit || len == 0.0 {
            return self;
        }
        Self { displacement_mm: t.map(|c| c * limit / len), ..self }
    }

    /// b_k(y).
    #[must_use]
    pub fn apply(&self, y: [f64; 3]) -> [f64; 3] {
        let r = distance(y, self.centre_mm);
        if r >= self.radius_mm {
            return y;
        }
        let w = falloff(r / self.radius_mm);
        std::array::from_fn(|a| y[a] + w * self.displacement_mm[a])
    }

    /// ∇b_k(y) = I + t ⊗ ∇β.
    fn jacobian(&self, y: [f64; 3]) -> nalgebra::Matrix3<f64> {
        let mut j = nalgebra::Matrix3::identity();
        let r = distance(y, self.centre_mm);
        if r >= self.radius_mm || r == 0.0 {
            return j;
        }
        let slope = falloff_slope(r / self.radius_mm) / (self.radius_mm * r);
        for row in 0..3 {
            for col in 0..3 {
                j[(row, col)] += self.displacement_mm[row] * slope * (y[col] - self.centre_mm[col]);
            }
        }
        j
    }

    fn check(&self, index: usize) -> Result<()> {
        let finite = self.centre_mm.iter().chain(&self.displacement_mm).all(|v| v.is_finite());
        if !(finite && self.radius_mm.is_finite() && self.radius_mm > 0.0) {
            return Err(SolverError::InvalidParameter(format!(
                "brush stroke {}: its centre, displacement and radius must be finite, the radius > 0 mm",
                index + 1
            )));
        }
        let t = self.displacement_mm;
        let len = (t[0] * t[0] + t[1] * t[1] + t[2] * t[2]).sqrt();
        if len > MAX_STRENGTH * self.radius_mm * (1.0 + 1e-9) {
            return Err(SolverError::InvalidParameter(format!(
                "brush stroke {}: a displacement of {len:.3} mm is more than {MAX_STRENGTH} of its radius \
                 {:.3} mm, which could fold the volume",
                index + 1,
                self.radius_mm
            )));
        }
        Ok(())
    }
}

fn distance(a: [f64; 3], b: [f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

/// The brush's strokes in the order they were made; the forward warp b = b_n ∘ … ∘ b_1 of the fixed space.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Brush {
    strokes: Vec<BrushStroke>,
}

impl Brush {
    /// The brush of `strokes`. Errors: a stroke that is not finite, has no radius, or moves more than
    /// [`MAX_STRENGTH`] of its radius (named by its 1-based number).
    pub fn new(strokes: Vec<BrushStroke>) -> Result<Self> {
        for (i, s) in strokes.iter().enumerate() {
            s.check(i)?;
        }
        Ok(Self { strokes })
    }

    #[must_use]
    pub fn strokes(&self) -> &[BrushStroke] {
        &self.strokes
    }

    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.strokes.is_empty()
    }

    /// The box the brush can move: every point it displaces lies within it (the strokes' balls, grown by the
    /// strokes before them).
    #[must_use]
    pub fn reach(&self) -> Option<Aabb<Fixed>> {
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        for s in &self.strokes {
            for a in 0..3 {
                lo[a] = lo[a].min(s.centre_mm[a] - s.radius_mm);
                hi[a] = hi[a].max(s.centre_mm[a] + s.radius_mm);
            }
        }
        self.strokes.first().map(|_| {
            Aabb::new(warpbench_io::geometry::Point3::from_array(lo), warpbench_io::geometry::Point3::from_array(hi))
        })
    }

    /// An approximate inverse b⁻¹ by scattered-data interpolation ([`crate::invert`]) over the brush's reach (grown
    /// by its largest stroke and a margin: b is the identity beyond it, and so is the inverse), with its inverse
    /// consistency ‖b(b⁻¹(y)) − y‖ there. `None` for a brush without strokes.
    pub fn inverse(&self, params: &InvertParams) -> Result<Option<(BrushInverse, InverseReport)>> {
        let Some(reach) = self.reach() else { return Ok(None) };
        let grow =
            self.strokes.iter().map(|s| s.displacement_mm.iter().map(|v| v * v).sum::<f64>().sqrt()).sum::<f64>() + 2.0;
        let (lo, hi) = (reach.min.coords(), reach.max.coords());
        let domain = Aabb::new(
            warpbench_io::geometry::Point3::from_array(lo.map(|v| v - grow)),
            warpbench_io::geometry::Point3::from_array(hi.map(|v| v + grow)),
        );
        let (spline, report) = invert(self, domain, domain, params)?;
        Ok(Some((BrushInverse { spline, domain }, report)))
    }
}

impl BrushStroke {
    /// b_k⁻¹(y) by the fixed-point iteration x ← y − t β(‖x − c‖/R), a contraction of rate 2‖t‖/R ≤ 0.9
    /// (module docs), to 10⁻⁹ mm or 400 iterations.
    #[must_use]
    pub fn invert_point(&self, y: [f64; 3]) -> [f64; 3] {
        let mut x = y;
        for _ in 0..400 {
            let w = falloff(distance(x, self.centre_mm) / self.radius_mm);
            let next: [f64; 3] = std::array::from_fn(|a| y[a] - w * self.displacement_mm[a]);
            let step = distance(next, x);
            x = next;
            if step <= 1e-9 {
                break;
            }
        }
        x
    }
}

impl Brush {
    /// b⁻¹(y) point by point, each stroke undone by its fixed-point iteration in reverse order
    /// ([`BrushStroke::invert_point`]): exact to 10⁻⁹ mm but a loop per point, so the window uses it only while a
    /// stroke is being dragged; a settled brush is inverted by [`Brush::inverse`].
    #[must_use]
    pub fn invert_point(&self, y: [f64; 3]) -> [f64; 3] {
        self.strokes.iter().rev().fold(y, |x, s| s.invert_point(x))
    }
}

/// b⁻¹ point by point ([`Brush::invert_point`]), as a warp.
#[derive(Clone, Copy, Debug)]
pub struct PointwiseInverse<'a>(pub &'a Brush);

impl Warp<Fixed, Fixed> for PointwiseInverse<'_> {
    fn apply_raw(&self, x: [f64; 3]) -> [f64; 3] {
        self.0.invert_point(x)
    }
}

/// b⁻¹ of a [`Brush`]: the fitted B-spline inside the box it was fitted over, the identity outside (where b is).
#[derive(Clone, Debug)]
pub struct BrushInverse {
    spline: HierarchicalBSpline<Fixed, Fixed>,
    domain: Aabb<Fixed>,
}

impl BrushInverse {
    /// The box outside which the inverse is the identity.
    #[must_use]
    pub fn domain(&self) -> Aabb<Fixed> {
        self.domain
    }
}

impl Warp<Fixed, Fixed> for BrushInverse {
    fn apply_raw(&self, x: [f64; 3]) -> [f64; 3] {
        let (lo, hi) = (self.domain.min.coords(), self.domain.max.coords());
        if (0..3).all(|a| x[a] >= lo[a] && x[a] <= hi[a]) { self.spline.apply_raw(x) } else { x }
    }
}

impl Warp<Fixed, Fixed> for Brush {
    fn apply_raw(&self, x: [f64; 3]) -> [f64; 3] {
        self.strokes.iter().fold(x, |y, s| s.apply(y))
    }

    /// The chain rule over the strokes: ∇b = ∇b_n(y_{n−1}) ⋯ ∇b_1(x).
    fn jacobian_raw(&self, x: [f64; 3]) -> nalgebra::Matrix3<f64> {
        let mut y = x;
        let mut j = nalgebra::Matrix3::identity();
        for s in &self.strokes {
            j = s.jacobian(y) * j;
            y = s.apply(y);
        }
        j
    }
}

#[cfg(test)]
#[allow(clippy::float_cmp, reason = "β(0) = 1 and β(s ≥ 1) = 0 exactly, so these points move exactly or not at all")]
mod tests {
    use super::*;

    fn stroke(c: [f64; 3], t: [f64; 3], r: f64) -> BrushStroke {
        BrushStroke { centre_mm: c, displacement_mm: t, radius_mm: r }
    }

    /// β is the cubic B-spline: 1 at the centre, 0 from the radius on, C² across it, largest slope 2 at 1/3.
    #[test]
    fn the_falloff_is_a_cubic_b_spline_bump() {
        assert!((falloff(0.0) - 1.0).abs() < 1e-15 && falloff(1.0).abs() < 1e-15 && falloff(1.5) == 0.0);
        // The cubic B-spline's values at the knots: B₃(1) = 1/6, so β(1/2) = 1/4.
        assert!((falloff(0.5) - 0.25).abs() < 1e-15);
        let h = 1e-6;
        let steepest = (1..1000).map(|i| falloff_slope(f64::from(i) / 1000.0).abs()).fold(0.0, f64::max);
        assert!((steepest - 2.0).abs() < 1e-3, "{steepest}");
        for s in [0.1, 0.3, 0.5, 0.7, 0.99] {
            let numeric = (falloff(s + h) - falloff(s - h)) / (2.0 * h);
            assert!((numeric - falloff_slope(s)).abs() < 1e-6, "slope at {s}");
        }
        // C²: the second difference is continuous through s = 1/2 and s = 1.
        let second = |s: f64| (falloff(s + 1e-4) - 2.0 * falloff(s) + falloff(s - 1e-4)) / 1e-8;
        assert!((second(0.5 - 1e-3) - second(0.5 + 1e-3)).abs() < 0.1);
        assert!(second(1.0 - 1e-3).abs() < 0.1);
    }

    /// A stroke moves its centre by t exactly, nothing beyond its radius, and its Jacobian is the analytic one.
    #[test]
    fn a_stroke_moves_its_centre_and_nothing_beyond_its_radius() {
        let s = stroke([10.0, -5.0, 2.0], [3.0, 1.0, -2.0], 20.0);
        let b = Brush::new(vec![s]).expect("brush");
        assert_eq!(b.apply_raw(s.centre_mm), [13.0, -4.0, 0.0]);
        assert_eq!(b.apply_raw([31.0, -5.0, 2.0]), [31.0, -5.0, 2.0]);
        let x = [18.0, 2.0, -3.0];
        let numeric = {
            let h = 1e-5;
            let mut j = nalgebra::Matrix3::zeros();
            for c in 0..3 {
                let (mut p, mut m) = (x, x);
                p[c] += h;
                m[c] -= h;
                let (fp, fm) = (b.apply_raw(p), b.apply_raw(m));
                for r in 0..3 {
                    j[(r, c)] = (fp[r] - fm[r]) / (2.0 * h);
                }
            }
            j
        };
        assert!((numeric - b.jacobian_raw(x)).abs().max() < 1e-6);
    }

    /// Strokes at the limit, composed over each other, never fold: det ∇b > 0 on a fine grid.
    #[test]
    fn strokes_at_the_limit_never_fold() {
        let r = 15.0;
        let strokes = vec![
            stroke([0.0, 0.0, 0.0], [r, 0.0, 0.0], r).clamped(),
            stroke([5.0, 0.0, 0.0], [0.0, -r, r], r).clamped(),
            stroke([3.0, -4.0, 4.0], [-r, r, 0.0], r).clamped(),
        ];
        for s in &strokes {
            let t = s.displacement_mm;
            assert!(((t[0] * t[0] + t[1] * t[1] + t[2] * t[2]).sqrt() - MAX_STRENGTH * r).abs() < 1e-9);
        }
        let b = Brush::new(strokes).expect("brush");
        let mut worst = f64::INFINITY;
        for i in 0..41 {
            for j in 0..41 {
                for k in 0..41 {
                    let x = [-20.0 + f64::from(i), -20.0 + f64::from(j), -20.0 + f64::from(k)];
                    worst = worst.min(b.jacobian_raw(x).determinant());
                }
            }
        }
        assert!(worst > 0.05, "det ∇b down to {worst}");
        // One stroke alone: det ∇b_k ≥ 1 − 2·MAX_STRENGTH.
        let single = Brush::new(vec![stroke([0.0; 3], [r, 0.0, 0.0], r).clamped()]).expect("brush");
        let det =
            (0..41).map(|i| single.jacobian_raw([-20.0 + f64::from(i), 1.0, -2.0]).determinant()).fold(9.0, f64::min);
        assert!(det >= 1.0 - 2.0 * MAX_STRENGTH - 1e-9, "{det}");
    }

    /// The inverse by scattered-data interpolation undoes the brush within its report, and the report is honest:
    /// measured again here at points of our own.
    #[test]
    fn the_inverse_undoes_the_brush() {
        let b = Brush::new(vec![
            stroke([0.0, 0.0, 0.0], [5.5, 2.0, 0.0], 20.0),
            stroke([5.5, 2.0, 0.0], [0.0, 0.0, 4.0], 15.0),
        ])
        .expect("brush");
        let (inverse, report) = b.inverse(&InvertParams::default()).expect("inverse").expect("strokes");
        eprintln!(
            "brush inverse: rms {:.5} mm, max {:.5} mm over {:?}",
            report.rms_mm,
            report.max_mm,
            inverse.domain()
        );
        assert!(report.max_mm < 0.01 && report.rms_mm < 0.001, "{report:?}");
        let mut worst: f64 = 0.0;
        for i in 0..13 {
            for j in 0..13 {
                for k in 0..13 {
                    let y = [-57.0 + 9.5 * f64::from(i), -57.0 + 9.5 * f64::from(j), -57.0 + 9.5 * f64::from(k)];
                    worst = worst.max(distance(b.apply_raw(inverse.apply_raw(y)), y));
                }
            }
        }
        assert!(worst <= report.max_mm + 0.01, "{worst} mm against the report's {}", report.max_mm);
        assert_eq!(inverse.apply_raw([100.0, 0.0, 0.0]), [100.0, 0.0, 0.0], "the identity beyond the reach");
        assert!(Brush::default().inverse(&InvertParams::default()).expect("nothing to invert").is_none());
    }

    #[test]
    fn the_pointwise_inverse_undoes_every_stroke() {
        let b = Brush::new(vec![
            stroke([0.0, 0.0, 0.0], [6.0, 0.0, 0.0], 20.0),
            stroke([6.0, 0.0, 0.0], [0.0, 3.5, 2.0], 15.0),
        ])
        .expect("brush");
        for y in [[6.0, 3.5, 2.0], [0.0, 0.0, 0.0], [12.0, -3.0, 5.0], [40.0, 40.0, 40.0]] {
            let x = PointwiseInverse(&b).apply_raw(y);
            assert!(distance(b.apply_raw(x), y) < 1e-8, "b(b⁻¹({y:?})) = {:?}", b.apply_raw(x));
        }
        // The grabbed point comes back exactly where it was.
        assert!(distance(b.invert_point([6.0, 3.5, 2.0]), [0.0, 0.0, 0.0]) < 1e-8);
    }

    #[test]
    fn bad_strokes_are_refused_by_number() {
        let err = Brush::new(vec![stroke([0.0; 3], [1.0, 0.0, 0.0], 10.0), stroke([0.0; 3], [4.0, 0.0, 0.0], 10.0)])
            .expect_err("too strong");
        assert!(err.to_string().contains("brush stroke 2"), "{err}");
        assert!(Brush::new(vec![stroke([f64::NAN, 0.0, 0.0], [1.0, 0.0, 0.0], 10.0)]).is_err());
        assert!(Brush::new(vec![stroke([0.0; 3], [1.0, 0.0, 0.0], 0.0)]).is_err());
    }
}
