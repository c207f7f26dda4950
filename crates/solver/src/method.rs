//! [`Method`]: one name for "fit this kind of warp to these pairs", in either direction.
//!
//! The CLI's `--method`, the app's method switch, leave-one-out and the accuracy tests all fit a
//! warp without caring which kind it is; they go through [`Method::fit`], which returns a
//! [`FittedWarp`]: one of the closed set of fitted warps, a [`Warp`] by delegation, and matchable
//! where the kind matters (a TPS or a B-spline lattice handed to the GPU, the lattice's separable
//! grid sampler in [`crate::control`]). For a forward warp d = `fixed_from_moving` pass (p_i, q_i);
//! for the pull-back u = `moving_from_fixed` pass the reversed pairs (q_i, p_i): every method fits
//! the pull-back directly, so it is exact (or, for the approximating methods, as close) at the
//! landmarks.

use std::fmt;

use nalgebra::Matrix3;
use warpbench_io::geometry::{Point3, Space};

use crate::bspline::{self, BSplineParams, HierarchicalBSpline};
use crate::diagnostics;
use crate::error::Result;
use crate::linear::{self, AffineWarp, LinearKind};
use crate::pairs::{self, Needs, PairWarning};
use crate::spaces::Aabb;
use crate::tps::{self, Tps};
use crate::warp::{Parallelism, Warp};

/// A warp model and its parameters.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Method {
    /// Thin-plate spline with stiffness λ ≥ 0: 0 interpolates; λ > 0 is the smoothing spline
    /// `Regularisation::Smoothing(λ)` (K − λI), whose bending energy falls monotonically as λ grows.
    /// ITK's `Stiffness` (K + λI) is not used here: for U(r) = r it makes the warp rougher as λ grows
    /// and is singular at the kernel's eigenvalues (see [`crate::tps`]).
    Tps { stiffness: f64 },
    /// Hierarchical cubic B-spline over the source domain.
    BSpline(BSplineParams),
    /// Affine, similarity or rigid least squares.
    Linear(LinearKind),
}

impl fmt::Display for Method {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Tps { stiffness } if *stiffness == 0.0 => write!(f, "tps"),
            Self::Tps { stiffness } => write!(f, "tps(λ={stiffness})"),
            Self::BSpline(p) => write!(f, "hbspline({} levels)", p.levels),
            Self::Linear(k) => write!(f, "{k}"),
        }
    }
}

impl Method {
    /// The default of each kind, by the CLI names `tps`, `hbspline`, `affine`, `similarity`, `rigid`.
    #[must_use]
    pub fn from_name(name: &str) -> Option<Self> {
        match name {
            "tps" => Some(Self::Tps { stiffness: 0.0 }),
            "hbspline" => Some(Self::BSpline(BSplineParams::default())),
            other => other.parse().ok().map(Self::Linear),
        }
    }

    /// What this method needs of its pairs ([`crate::pairs`]).
    #[must_use]
    pub fn needs(&self) -> Needs {
        match self {
            Self::Tps { .. } => tps::NEEDS,
            Self::BSpline(_) => bspline::NEEDS,
            Self::Linear(kind) => kind.needs(),
        }
    }

    /// Checks the pairs as [`Method::fit`] does, in either direction alike: the warnings the fit would give (pairs
    /// numbered from 1), or the error it would refuse them with. Callers show the warnings (the CLI on stderr, the
    /// window in its status).
    pub fn check<To: Space, From: Space>(&self, src: &[Point3<From>], dst: &[Point3<To>]) -> Result<Vec<PairWarning>> {
        Ok(pairs::validate(&self.needs(), src, dst)?.warnings)
    }

    /// Fits the warp taking `src` to `dst`. `domain` bounds where it will be evaluated (the `From`
    /// volume's box); only the B-spline uses it. The pairs are checked first ([`Method::check`]).
    pub fn fit<To: Space, From: Space>(
        &self,
        src: &[Point3<From>],
        dst: &[Point3<To>],
        domain: Aabb<From>,
    ) -> Result<FittedWarp<To, From>> {
        Ok(match self {
            Self::Tps { stiffness } => FittedWarp::Tps(Tps::fit_smoothing(src, dst, *stiffness)?),
            Self::BSpline(params) => FittedWarp::BSpline(HierarchicalBSpline::fit(src, dst, domain, params)?),
            Self::Linear(kind) => FittedWarp::Linear(linear::fit(*kind, src, dst)?.warp),
        })
    }

    /// The leave-one-out error of every pair (pairs as for [`Method::fit`]): ‖w₋ᵢ(`src[i]`) − `dst[i]`‖ in mm, w₋ᵢ
    /// fitted with this method on every other pair; `None` where that refit is refused. A TPS takes the closed form
    /// of [`tps::leave_one_out`] (one solve instead of N, the same numbers); the other methods, and a TPS whose full
    /// fit fails, refit N times ([`diagnostics::leave_one_out`], cheap for them), on the threads `parallelism`
    /// allows.
    #[must_use]
    pub fn leave_one_out<To: Space, From: Space>(
        &self,
        src: &[Point3<From>],
        dst: &[Point3<To>],
        domain: Aabb<From>,
        parallelism: Parallelism,
    ) -> Vec<Option<f64>> {
        self.leave_one_out_reporting(src, dst, domain, parallelism, &|| {})
    }

    /// [`Method::leave_one_out`], calling `refitted` after each refit when it refits (not for the closed form).
    #[must_use]
    pub fn leave_one_out_reporting<To: Space, From: Space>(
        &self,
        src: &[Point3<From>],
        dst: &[Point3<To>],
        domain: Aabb<From>,
        parallelism: Parallelism,
        refitted: &(dyn Fn() + Sync),
    ) -> Vec<Option<f64>> {
        if let Self::Tps { stiffness } = *self
            && let Ok(errors) = tps::leave_one_out(src, dst, tps::Regularisation::Smoothing(stiffness))
        {
            return errors;
        }
        let fit = |s: &[Point3<From>], d: &[Point3<To>]| self.fit(s, d, domain);
        diagnostics::leave_one_out_reporting(src, dst, fit, parallelism, refitted)
    }
}

/// A warp as [`Method::fit`] gives it: one of the fitted kinds, each the [`Warp`] of its module. It is a [`Warp`] by
/// delegation (every method, so a kind's faster batch kernel and analytic Jacobian are kept); match on it where the
/// kind matters.
#[derive(Clone, Debug)]
pub enum FittedWarp<To: Space, From: Space> {
    /// [`Method::Tps`].
    Tps(Tps<To, From>),
    /// [`Method::BSpline`].
    BSpline(HierarchicalBSpline<To, From>),
    /// [`Method::Linear`]: every linear kind is an affine map (its fit's other figures are [`linear::LinearFit`]'s).
    Linear(AffineWarp<To, From>),
}

impl<Mid: Space, From: Space> FittedWarp<Mid, From> {
    /// The warp followed by the affine map `then` (then ∘ w), in the same family: how a starting transform (an
    /// automatic alignment) is put after the landmark warp fitted on top of it ([`Tps::followed_by`],
    /// [`HierarchicalBSpline::followed_by`], a product of affine maps).
    #[must_use]
    pub fn followed_by<To: Space>(&self, then: &AffineWarp<To, Mid>) -> FittedWarp<To, From> {
        match self {
            Self::Tps(tps) => FittedWarp::Tps(tps.followed_by(then)),
            Self::BSpline(spline) => FittedWarp::BSpline(spline.followed_by(then)),
            Self::Linear(affine) => FittedWarp::Linear(*then * *affine),
        }
    }
}

/// The fitted warp as a trait object, for code that takes any warp.
impl<To: Space, From: Space> AsRef<dyn Warp<To, From>> for FittedWarp<To, From> {
    fn as_ref(&self) -> &(dyn Warp<To, From> + 'static) {
        match self {
            Self::Tps(w) => w,
            Self::BSpline(w) => w,
            Self::Linear(w) => w,
        }
    }
}

impl<To: Space, From: Space> Warp<To, From> for FittedWarp<To, From> {
    fn apply_raw(&self, x: [f64; 3]) -> [f64; 3] {
        AsRef::<dyn Warp<To, From>>::as_ref(self).apply_raw(x)
    }
    fn apply_batch_raw(&self, xs: &[[f64; 3]], out: &mut [[f64; 3]]) {
        AsRef::<dyn Warp<To, From>>::as_ref(self).apply_batch_raw(xs, out);
    }
    fn jacobian_raw(&self, x: [f64; 3]) -> Matrix3<f64> {
        AsRef::<dyn Warp<To, From>>::as_ref(self).jacobian_raw(x)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::spaces::{Fixed, Moving};
    use nalgebra::Rotation3;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// then ∘ w, built in closed form by [`FittedWarp::followed_by`], equals applying w and then `then`, for every
    /// method (within rounding), at random points inside the domain, and so does its Jacobian (chain rule).
    #[test]
    fn following_a_warp_by_an_affine_map_stays_in_its_family_and_is_exact() {
        let mut rng = ChaCha8Rng::seed_from_u64(18);
        let point = |r: &mut ChaCha8Rng| {
            Point3::<Fixed>::new(r.random_range(-50.0..50.0), r.random_range(-60.0..60.0), r.random_range(-40.0..40.0))
        };
        let fixed: Vec<Point3<Fixed>> = (0..30).map(|_| point(&mut rng)).collect();
        let moving: Vec<Point3<Fixed>> = fixed
            .iter()
            .map(|q| {
                let c = q.coords();
                Point3::new(c[0] + 3.0 * (c[1] / 20.0).sin(), c[1] + 2.0 * (c[2] / 15.0).cos(), c[2] + 0.05 * c[0])
            })
            .collect();
        let domain = Aabb::new(Point3::new(-55.0, -65.0, -45.0), Point3::new(55.0, 65.0, 45.0));
        let linear = Rotation3::from_euler_angles(0.2, -0.1, 0.3).into_inner()
            * Matrix3::from_diagonal(&nalgebra::Vector3::new(1.05, 0.97, 1.02));
        let then: AffineWarp<Moving, Fixed> = AffineWarp::new(linear, [12.0, -7.0, 4.0]);
        for method in [
            Method::Tps { stiffness: 0.0 },
            Method::Tps { stiffness: 2.0 },
            Method::BSpline(BSplineParams::default()),
            Method::Linear(LinearKind::Affine),
            Method::Linear(LinearKind::Rigid),
        ] {
            let w: FittedWarp<Fixed, Fixed> = method.fit(&fixed, &moving, domain).expect("fit");
            let composed = w.followed_by(&then);
            for _ in 0..200 {
                let x = point(&mut rng).coords();
                let want = then.apply_raw(w.as_ref().apply_raw(x));
                let got = composed.as_ref().apply_raw(x);
                let err = (0..3).map(|a| (want[a] - got[a]).abs()).fold(0.0, f64::max);
                assert!(err < 1e-9, "{method}: {err} mm at {x:?}");
                let jw = then.linear() * w.as_ref().jacobian_raw(x);
                let jc = composed.as_ref().jacobian_raw(x);
                assert!((jw - jc).abs().max() < 1e-6, "{method}: Jacobian {jw} vs {jc}");
            }
        }
    }
}
