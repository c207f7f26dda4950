//! The fit's diagnostics off the UI thread: the residuals, leave-one-out errors and folding that follow a fit.
//!
//! With a thousand pairs they take a good part of a second (leave-one-out in closed form for a TPS, refits for the
//! other methods, a 32³ Jacobian grid), which would freeze the window after every change. The fit itself stays on
//! the UI thread (the view needs its control texture at once); its diagnostics run on a thread of their own and
//! reach the table, the accuracy histogram and the status bar when they are done. A newer fit drops the job whose
//! results would describe an older document.

use warpbench_io::geometry::Point3;
use warpbench_io::landmarks::LandmarkPair;
use warpbench_solver::Aabb;
use warpbench_solver::diagnostics::{JacobianReport, jacobian_determinants, residuals};
use warpbench_solver::method::Method;
use warpbench_solver::spaces::{Fixed, Moving};
use warpbench_solver::warp::Parallelism;

use super::stack::StackPullback;

/// One pair's errors after a fit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PairErrors {
    /// |u(qᵢ) − pᵢ|: zero for an interpolating warp.
    pub residual_mm: f64,
    /// The error at pᵢ of the warp refitted without pair i; `None` when the refit fails (too few pairs left).
    pub leave_one_out_mm: Option<f64>,
}

/// The leave-one-out errors of the pairs that have one, largest first, with the pair's index.
#[must_use]
pub fn loo_ranking(pairs: &[LandmarkPair], errors: &[Option<PairErrors>]) -> Vec<(f64, usize)> {
    let mut loo: Vec<(f64, usize)> = errors
        .iter()
        .enumerate()
        .take(pairs.len())
        .filter_map(|(i, e)| Some((e.as_ref()?.leave_one_out_mm?, i)))
        .collect();
    loo.sort_by(|a, b| b.0.total_cmp(&a.0));
    loo
}

/// The grid over the fixed volume's box on which folding (det ∇u ≤ 0) is looked for.
pub const JACOBIAN_GRID: [usize; 3] = [32; 3];

/// What a fit's diagnostics found.
#[derive(Clone, Debug, PartialEq)]
pub struct Diagnostics {
    /// (row in the document's pairs, its errors), for the pairs the fit used.
    pub pair_errors: Vec<(usize, PairErrors)>,
    /// The pull-back's Jacobian over the fixed box.
    pub jacobian: JacobianReport,
}

/// What the diagnostics of one fit need: the fit's pairs and pull-back.
#[derive(Clone, Debug)]
pub struct DiagnosticsInput {
    pub method: Method,
    /// The document's row of each pair the fit used.
    pub rows: Vec<usize>,
    pub fixed: Vec<Point3<Fixed>>,
    pub moving: Vec<Point3<Moving>>,
    pub fixed_box: Aabb<Fixed>,
    pub pullback: StackPullback,
}

impl DiagnosticsInput {
    /// Residuals of the pull-back at the targets, leave-one-out errors (TPS in closed form from one factorisation,
    /// the other methods by refits without each pair) and the Jacobian on [`JACOBIAN_GRID`].
    #[must_use]
    pub fn compute(&self) -> Diagnostics {
        let residuals = residuals(&self.pullback, &self.fixed, &self.moving);
        let loo = self.method.leave_one_out(&self.fixed, &self.moving, self.fixed_box, Parallelism::Rayon);
        let pair_errors = self
            .rows
            .iter()
            .zip(residuals)
            .zip(loo)
            .map(|((&row, residual_mm), leave_one_out_mm)| (row, PairErrors { residual_mm, leave_one_out_mm }))
            .collect();
        let jacobian = jacobian_determinants(&self.pullback, &self.fixed_box, JACOBIAN_GRID, Parallelism::Rayon);
        Diagnostics { pair_errors, jacobian }
    }
}

/// A fit's diagnostics being computed on a thread of their own.
#[derive(Debug)]
pub struct DiagnosticsJob {
    done: std::sync::mpsc::Receiver<Diagnostics>,
}

impl DiagnosticsJob {
    /// Starts computing `input`'s diagnostics on a new thread, which calls `wake` when they are done.
    ///
    /// # Errors
    /// When the thread cannot be started.
    pub fn start(input: DiagnosticsInput, wake: impl FnOnce() + Send + 'static) -> std::io::Result<Self> {
        let (send, done) = std::sync::mpsc::channel();
        std::thread::Builder::new().name("fit diagnostics".into()).spawn(move || {
            // The receiver is gone when a newer fit replaced this one: nothing to hand back.
            if send.send(input.compute()).is_ok() {
                wake();
            }
        })?;
        Ok(Self { done })
    }

    /// The diagnostics once they are done; `Some(None)` when the thread ended without them (it panicked).
    #[must_use]
    pub fn poll(&self) -> Option<Option<Diagnostics>> {
        match self.done.try_recv() {
            Ok(d) => Some(Some(d)),
            Err(std::sync::mpsc::TryRecvError::Empty) => None,
            Err(std::sync::mpsc::TryRecvError::Disconnected) => Some(None),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use warpbench_solver::spaces::{as_fixed, as_moving};

    fn lps(p: [f64; 3]) -> warpbench_io::geometry::Point3<warpbench_io::geometry::Lps> {
        warpbench_io::geometry::Point3::new(p[0], p[1], p[2])
    }

    fn input() -> DiagnosticsInput {
        // Eight corners and a centre, moved by a smooth bump: a TPS that interpolates them.
        let mut fixed = Vec::new();
        let mut moving = Vec::new();
        for i in 0..9 {
            let p = if i == 8 {
                [0.0, 0.0, 0.0]
            } else {
                [f64::from(i & 1) * 40.0 - 20.0, f64::from((i >> 1) & 1) * 40.0 - 20.0, f64::from(i >> 2) * 40.0 - 20.0]
            };
            fixed.push(as_fixed(lps(p)));
            let bump = 3.0 * (-(p[0] * p[0] + p[1] * p[1] + p[2] * p[2]) / 800.0).exp();
            moving.push(as_moving(lps([p[0] + bump, p[1] - 0.5 * bump, p[2] + 1.0])));
        }
        let method = Method::Tps { stiffness: 0.0 };
        let fixed_box = Aabb::new(as_fixed(lps([-30.0; 3])), as_fixed(lps([30.0; 3])));
        let pullback = method.fit(&fixed, &moving, fixed_box).expect("fit");
        let pullback = StackPullback::folded(pullback);
        DiagnosticsInput { method, rows: (0..9).map(|i| i * 2).collect(), fixed, moving, fixed_box, pullback }
    }

    #[test]
    fn the_thread_hands_back_what_the_calling_thread_computes() {
        let input = input();
        let here = input.compute();
        assert_eq!(here.pair_errors.len(), 9);
        assert!(here.pair_errors.iter().all(|(_, e)| e.residual_mm < 1e-6), "interpolating: {here:?}");
        assert!(here.pair_errors.iter().any(|(_, e)| e.leave_one_out_mm.is_some_and(|l| l > 0.0)), "{here:?}");
        assert_eq!(here.pair_errors.iter().map(|(row, _)| *row).collect::<Vec<_>>(), [0, 2, 4, 6, 8, 10, 12, 14, 16]);
        let (wake, woken) = std::sync::mpsc::channel();
        let job = DiagnosticsJob::start(input, move || {
            wake.send(()).ok();
        })
        .expect("thread");
        woken.recv().expect("woken");
        assert_eq!(job.poll(), Some(Some(here)));
    }
}
