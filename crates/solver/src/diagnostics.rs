//! Accuracy diagnostics for any [`Warp`]: the Jacobian determinant field (folding), residuals at the
//! landmarks, leave-one-out errors, and summary statistics of error samples.
//!
//! - **Folding.** A warp w folds space where det ∇w(x) ≤ 0: it is no longer one-to-one there, and
//!   the pull-back samples the same moving tissue twice. [`jacobian_determinants`] evaluates
//!   det ∇w on a regular grid and reports the minimum, where it occurs, and the fraction ≤ 0.
//! - **Residual** of landmark i: ‖w(p_i) − q_i‖ (zero for an interpolating TPS by construction).
//! - **Leave-one-out error** of landmark i: refit without pair i, then measure ‖w₋ᵢ(p_i) − q_i‖: an
//!   honest estimate of the error at a point the fit did not see (BigWarp ships it as a script; we
//!   compute it live). [`leave_one_out`] takes the fitting method as a closure, so it serves TPS,
//!   B-spline and the linear fits alike.

use rayon::prelude::*;
use warpbench_io::geometry::{Point3, Space};

use crate::error::Result;
use crate::spaces::Aabb;
use crate::warp::Parallelism;
use crate::warp::Warp;

/// Where det ∇w is smallest on a grid, and how much of the grid folds.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct JacobianReport {
    pub min_det: f64,
    /// The grid point (mm, in the warp's source space) where the minimum occurs.
    pub min_at: [f64; 3],
    pub max_det: f64,
    /// Fraction of grid points with det ≤ 0, in [0, 1].
    pub fraction_folded: f64,
    pub points: usize,
}

impl JacobianReport {
    #[must_use]
    pub fn folds(&self) -> bool {
        self.min_det <= 0.0
    }
}

/// Centre of cell (a, b, c) of a `dims` grid over `domain` (the control-texture convention).
fn cell_centre<S: Space>(domain: &Aabb<S>, dims: [usize; 3], abc: [usize; 3]) -> [f64; 3] {
    let (min, size) = (domain.min.coords(), domain.size());
    std::array::from_fn(|i| min[i] + (abc[i] as f64 + 0.5) / dims[i] as f64 * size[i])
}

/// Evaluates det ∇w at the cell centres of a `dims` grid over `domain` (in w's source space).
#[must_use]
pub fn jacobian_determinants<To: Space, From: Space, W: Warp<To, From> + ?Sized>(
    warp: &W,
    domain: &Aabb<From>,
    dims: [usize; 3],
    parallelism: Parallelism,
) -> JacobianReport {
    let n = dims.iter().product::<usize>();
    let det_at = |idx: usize| {
        let abc = [idx % dims[0], (idx / dims[0]) % dims[1], idx / (dims[0] * dims[1])];
        let x = cell_centre(domain, dims, abc);
        (warp.jacobian_raw(x).determinant(), x)
    };
    let fold = |a: Acc, (det, x): (f64, [f64; 3])| a.push(det, x);
    let acc = match parallelism {
        Parallelism::Sequential => (0..n).map(det_at).fold(Acc::default(), fold),
        Parallelism::Rayon => {
            (0..n).into_par_iter().map(det_at).fold(Acc::default, fold).reduce(Acc::default, Acc::merge)
        }
    };
    JacobianReport {
        min_det: acc.min.0,
        min_at: acc.min.1,
        max_det: acc.max,
        fraction_folded: acc.folded as f64 / n.max(1) as f64,
        points: n,
    }
}

/// Running minimum, maximum and fold count of Jacobian determinants.
#[derive(Clone, Copy)]
struct Acc {
    min: (f64, [f64; 3]),
    max: f64,
    folded: usize,
}

impl Default for Acc {
    fn default() -> Self {
        Self { min: (f64::INFINITY, [0.0; 3]), max: f64::NEG_INFINITY, folded: 0 }
    }
}

impl Acc {
    fn push(mut self, det: f64, x: [f64; 3]) -> Self {
        // A non-finite determinant counts as folded: the warp is broken there.
        let det_or_fold = if det.is_finite() { det } else { f64::NEG_INFINITY };
        if det_or_fold < self.min.0 {
            self.min = (det_or_fold, x);
        }
        self.max = self.max.max(det_or_fold);
        self.folded += usize::from(det_or_fold <= 0.0);
        self
    }
    fn merge(self, o: Self) -> Self {
        Self {
            min: if o.min.0 < self.min.0 { o.min } else { self.min },
            max: self.max.max(o.max),
            folded: self.folded + o.folded,
        }
    }
}

/// ‖w(src_i) − dst_i‖ for every pair, in mm.
#[must_use]
pub fn residuals<To: Space, From: Space, W: Warp<To, From> + ?Sized>(
    warp: &W,
    src: &[Point3<From>],
    dst: &[Point3<To>],
) -> Vec<f64> {
    src.iter().zip(dst).map(|(p, q)| warp.apply(*p).distance(q)).collect()
}

/// The leave-one-out error of every pair: refit with `fit` on all other pairs and measure the error
/// at the left-out one. `None` where the refit fails (e.g. too few pairs remain for the method).
pub fn leave_one_out<To, From, W, F>(
    src: &[Point3<From>],
    dst: &[Point3<To>],
    fit: F,
    parallelism: Parallelism,
) -> Vec<Option<f64>>
where
    To: Space,
    From: Space,
    W: Warp<To, From>,
    F: Fn(&[Point3<From>], &[Point3<To>]) -> Result<W> + Sync,
{
    leave_one_out_reporting(src, dst, fit, parallelism, &|| {})
}

/// [`leave_one_out`], calling `refitted` after each of the N refits (from the threads `parallelism` allows), so a
/// caller can show how far it is.
pub fn leave_one_out_reporting<To, From, W, F>(
    src: &[Point3<From>],
    dst: &[Point3<To>],
    fit: F,
    parallelism: Parallelism,
    refitted: &(dyn Fn() + Sync),
) -> Vec<Option<f64>>
where
    To: Space,
    From: Space,
    W: Warp<To, From>,
    F: Fn(&[Point3<From>], &[Point3<To>]) -> Result<W> + Sync,
{
    let one = |i: usize| {
        let keep = |v: usize| v != i;
        let s: Vec<_> = src.iter().enumerate().filter(|(j, _)| keep(*j)).map(|(_, p)| *p).collect();
        let d: Vec<_> = dst.iter().enumerate().filter(|(j, _)| keep(*j)).map(|(_, q)| *q).collect();
        let error = fit(&s, &d).ok().map(|w| w.apply(src[i]).distance(&dst[i]));
        refitted();
        error
    };
    match parallelism {
        Parallelism::Sequential => (0..src.len()).map(one).collect(),
        Parallelism::Rayon => (0..src.len()).into_par_iter().map(one).collect(),
    }
}

/// Summary of error samples in mm (TRE tables, leave-one-out panels).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ErrorStats {
    pub count: usize,
    pub mean: f64,
    pub rms: f64,
    pub median: f64,
    pub p95: f64,
    pub max: f64,
}

impl ErrorStats {
    /// Statistics of the finite values in `errors`; `None` when there is none. Percentiles use the
    /// nearest-rank method.
    #[must_use]
    pub fn of(errors: &[f64]) -> Option<Self> {
        let mut v: Vec<f64> = errors.iter().copied().filter(|e| e.is_finite()).collect();
        if v.is_empty() {
            return None;
        }
        v.sort_by(f64::total_cmp);
        let n = v.len();
        let rank = |q: f64| v[((q * n as f64).ceil() as usize).clamp(1, n) - 1];
        Some(Self {
            count: n,
            mean: v.iter().sum::<f64>() / n as f64,
            rms: (v.iter().map(|e| e * e).sum::<f64>() / n as f64).sqrt(),
            median: rank(0.5),
            p95: rank(0.95),
            max: v[n - 1],
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::spaces::{Fixed, Moving};

    /// A fold: x ↦ (x² scaled) flips orientation where x < 0.
    struct Fold;
    impl Warp<Fixed, Moving> for Fold {
        fn apply_raw(&self, x: [f64; 3]) -> [f64; 3] {
            [x[0] - x[0] * x[0].abs() / 10.0, x[1], x[2]]
        }
    }

    struct Shift;
    impl Warp<Fixed, Moving> for Shift {
        fn apply_raw(&self, x: [f64; 3]) -> [f64; 3] {
            [x[0] + 1.0, x[1], x[2]]
        }
    }

    fn cube() -> Aabb<Moving> {
        Aabb::new(Point3::new(-10.0, -10.0, -10.0), Point3::new(10.0, 10.0, 10.0))
    }

    #[test]
    fn translation_never_folds() {
        let r = jacobian_determinants(&Shift, &cube(), [5, 5, 5], Parallelism::Rayon);
        assert!((r.min_det - 1.0).abs() < 1e-9 && (r.max_det - 1.0).abs() < 1e-9);
        assert!(r.fraction_folded == 0.0 && r.points == 125, "{r:?}");
    }

    #[test]
    fn a_fold_is_found_with_its_location() {
        // d/dx (x − x|x|/10) = 1 − |x|/5 ≤ 0 for |x| ≥ 5: the outer 2 of 8 columns fold on each side.
        let serial = jacobian_determinants(&Fold, &cube(), [8, 3, 3], Parallelism::Sequential);
        let parallel = jacobian_determinants(&Fold, &cube(), [8, 3, 3], Parallelism::Rayon);
        assert_eq!(serial, parallel);
        assert!(serial.folds());
        assert!((serial.fraction_folded - 0.5).abs() < 1e-12, "{serial:?}");
        assert!(serial.min_at[0].abs() > 8.0, "{serial:?}");
    }

    #[test]
    fn stats_use_nearest_rank() {
        let s = ErrorStats::of(&[4.0, 1.0, 3.0, 2.0, f64::NAN]).expect("finite values");
        assert_eq!((s.count, s.median, s.max), (4, 2.0, 4.0));
        assert!((s.mean - 2.5).abs() < 1e-12 && (s.p95 - 4.0).abs() < 1e-12);
        assert!(ErrorStats::of(&[f64::NAN]).is_none());
    }

    #[test]
    fn leave_one_out_refits_without_the_pair() {
        // A "fit" that returns the mean translation of the pairs it is given.
        #[derive(Debug)]
        struct Translate([f64; 3]);
        impl Warp<Fixed, Moving> for Translate {
            fn apply_raw(&self, x: [f64; 3]) -> [f64; 3] {
                [x[0] + self.0[0], x[1] + self.0[1], x[2] + self.0[2]]
            }
        }
        let src = [Point3::new(0.0, 0.0, 0.0), Point3::new(1.0, 0.0, 0.0), Point3::new(2.0, 0.0, 0.0)];
        let dst = [Point3::new(1.0, 0.0, 0.0), Point3::new(2.0, 0.0, 0.0), Point3::new(6.0, 0.0, 0.0)];
        let fit = |s: &[Point3<Moving>], d: &[Point3<Fixed>]| -> Result<Translate> {
            if s.len() < 2 {
                return Err(crate::SolverError::TooFew { method: "mean", needed: 2, got: s.len() });
            }
            let t = s.iter().zip(d).map(|(a, b)| b.coords()[0] - a.coords()[0]).sum::<f64>() / s.len() as f64;
            Ok(Translate([t, 0.0, 0.0]))
        };
        let loo = leave_one_out(&src, &dst, fit, Parallelism::Sequential);
        // Without pair 2 the shift is 1, so pair 2 (shift 4) is off by 3; without pair 0 it is 2.5, off by 1.5.
        assert_eq!(loo, vec![Some(1.5), Some(1.5), Some(3.0)]);
        assert_eq!(leave_one_out(&src[..2], &dst[..2], fit, Parallelism::Rayon), vec![None, None]);
    }
}
