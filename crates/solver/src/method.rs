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
