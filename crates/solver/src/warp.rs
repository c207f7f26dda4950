//! [`Warp`]: a map between two spaces that can be evaluated point by point.
//!
//! Every fitted or synthetic warp implements it, in one direction. Kernels work on raw `[f64; 3]`
//! (mm); the typed [`Warp::apply`] keeps the spaces straight at API boundaries.

use nalgebra::Matrix3;
use warpbench_io::geometry::{Point3, Space};

/// Which threads a kernel may use. Kernels never spawn threads or use a pool unless asked.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Parallelism {
    /// The calling thread only.
    #[default]
    Sequential,
    /// Rayon's global pool.
    Rayon,
}

/// Step for the central-difference Jacobian, in mm.
pub const JACOBIAN_STEP_MM: f64 = 1e-3;

/// A map from space `From` to space `To`, e.g. `Warp<Moving, Fixed>` for a pull-back.
pub trait Warp<To: Space, From: Space>: Send + Sync {
    /// Evaluates the map at `x` (mm in `From`), returning mm in `To`.
    fn apply_raw(&self, x: [f64; 3]) -> [f64; 3];

    /// Evaluates the map at every point of `xs` into `out` (same length). Warps with a faster batch
    /// kernel override this; it must not allocate or spawn threads (callers parallelise).
    fn apply_batch_raw(&self, xs: &[[f64; 3]], out: &mut [[f64; 3]]) {
        debug_assert_eq!(xs.len(), out.len());
        for (x, o) in xs.iter().zip(out.iter_mut()) {
            *o = self.apply_raw(*x);
        }
    }

    /// The typed evaluation.
    fn apply(&self, p: Point3<From>) -> Point3<To> {
        Point3::from_array(self.apply_raw(p.coords()))
    }

    /// The Jacobian ∂w/∂x at `x` (row r, column c: ∂w_r/∂x_c). The default uses central differences
    /// with [`JACOBIAN_STEP_MM`]; warps with an analytic derivative override it.
    fn jacobian_raw(&self, x: [f64; 3]) -> Matrix3<f64> {
        let h = JACOBIAN_STEP_MM;
        let mut j = Matrix3::zeros();
        for c in 0..3 {
            let (mut xp, mut xm) = (x, x);
            xp[c] += h;
            xm[c] -= h;
            let (fp, fm) = (self.apply_raw(xp), self.apply_raw(xm));
            for r in 0..3 {
                j[(r, c)] = (fp[r] - fm[r]) / (2.0 * h);
            }
        }
        j
    }
}

impl<To: Space, From: Space, W: Warp<To, From> + ?Sized> Warp<To, From> for Box<W> {
    fn apply_raw(&self, x: [f64; 3]) -> [f64; 3] {
        (**self).apply_raw(x)
    }
    fn apply_batch_raw(&self, xs: &[[f64; 3]], out: &mut [[f64; 3]]) {
        (**self).apply_batch_raw(xs, out);
    }
    fn jacobian_raw(&self, x: [f64; 3]) -> Matrix3<f64> {
        (**self).jacobian_raw(x)
    }
}

/// The composition `second ∘ first`: first `first` (From → Mid), then `second` (Mid → To). Its Jacobian is the chain
/// rule, ∇second(first(x)) · ∇first(x).
#[allow(missing_debug_implementations, reason = "it borrows two trait objects, which need not be Debug")]
pub struct Composed<'a, To: Space, Mid: Space, From: Space> {
    pub first: &'a dyn Warp<Mid, From>,
    pub second: &'a dyn Warp<To, Mid>,
}

impl<To: Space, Mid: Space, From: Space> Warp<To, From> for Composed<'_, To, Mid, From> {
    fn apply_raw(&self, x: [f64; 3]) -> [f64; 3] {
        self.second.apply_raw(self.first.apply_raw(x))
    }

    fn jacobian_raw(&self, x: [f64; 3]) -> Matrix3<f64> {
        self.second.jacobian_raw(self.first.apply_raw(x)) * self.first.jacobian_raw(x)
    }
}
