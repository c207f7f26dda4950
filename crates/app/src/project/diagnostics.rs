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

/// The rule of "Exclude outliers": a pair is an outlier when its leave-one-out error is far above the others', by the
/// modified z-score of Iglewicz & Hoaglin (1993), 0.6745 · (e − median) / MAD > [`OUTLIER_Z`], and above
/// [`OUTLIER_FLOOR_MM`] (so that a tight set does not lose pairs to sub-millimetre noise). The worst such pair is
/// dropped and the errors of the rest computed again without it, until none is left or a quarter of the pairs is
/// gone: one wrong pair inflates its neighbours' errors, which fall back once it is out.
pub const OUTLIER_Z: f64 = 3.5;
/// The smallest leave-one-out error that can make a pair an outlier, mm.
pub const OUTLIER_FLOOR_MM: f64 = 1.0;

/// The rule of [`OUTLIER_Z`] in words, for the window to show beside the button.
pub const OUTLIER_RULE: &str = "leave-one-out error above 1 mm and more than 3.5 robust deviations above the median \
    (modified z-score, Iglewicz & Hoaglin), worst first, refitting after each";

/// Which of the pairs (`fixed[i]` ↔ `moving[i]`) are outliers by [`OUTLIER_Z`]'s rule for `method` over `fixed_box`,
/// as indices into the lists, worst first.
#[must_use]
pub fn outliers(
    method: &Method,
    fixed: &[Point3<Fixed>],
    moving: &[Point3<Moving>],
    fixed_box: Aabb<Fixed>,
) -> Vec<usize> {
    let mut kept: Vec<usize> = (0..fixed.len()).collect();
    let mut out = Vec::new();
    let most = fixed.len() / 4;
    while out.len() < most && kept.len() > method.needs().min_pairs + 1 {
        let f: Vec<Point3<Fixed>> = kept.iter().map(|&i| fixed[i]).collect();
        let m: Vec<Point3<Moving>> = kept.iter().map(|&i| moving[i]).collect();
        let errors = method.leave_one_out(&f, &m, fixed_box, Parallelism::Rayon);
        let known: Vec<(usize, f64)> = errors.iter().enumerate().filter_map(|(k, e)| Some((k, (*e)?))).collect();
        let Some(&(worst, e)) = known.iter().max_by(|a, b| a.1.total_cmp(&b.1)) else { break };
        let values: Vec<f64> = known.iter().map(|&(_, e)| e).collect();
        let median = median(&values);
        let mad = median_of(values.iter().map(|v| (v - median).abs()).collect());
        let z = if mad > 0.0 { 0.6745 * (e - median) / mad } else { f64::INFINITY };
        if e <= OUTLIER_FLOOR_MM || z <= OUTLIER_Z {
            break;
        }
        out.push(kept.remove(worst));
    }
    out
}

fn median(values: &[f64]) -> f64 {
    median_of(values.to_vec())
}

fn median_of(mut v: Vec<f64>) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 { v[n / 2] } else { 0.5 * (v[n / 2 - 1] + v[n / 2]) }
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

    /// One pair moved by 8 mm among 20 that follow a smooth warp is found, and only it; the consistent set alone has
    /// none.
    #[test]
    fn the_one_wrong_pair_is_the_only_outlier() {
        let h = |i: usize, s: u64| {
            let x = (i as u64 + 1).wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ s.wrapping_mul(0xBF58_476D_1CE4_E5B9);
            ((x ^ (x >> 29)).wrapping_mul(0x94D0_49BB_1331_11EB) >> 11) as f64 / (1u64 << 53) as f64
        };
        let fixed: Vec<Point3<Fixed>> = (0..21)
            .map(|i| as_fixed(lps([120.0 * h(i, 1) - 60.0, 120.0 * h(i, 2) - 60.0, 120.0 * h(i, 3) - 60.0])))
            .collect();
        let smooth = |q: [f64; 3]| [q[0] + 3.0 * (q[1] / 40.0).sin(), q[1] - 2.0 * (q[2] / 35.0).cos(), q[2] + 1.5];
        let mut moving: Vec<Point3<Moving>> = fixed.iter().map(|q| as_moving(lps(smooth(q.coords())))).collect();
        let method = Method::Tps { stiffness: 0.0 };
        let fixed_box = Aabb::new(as_fixed(lps([-70.0; 3])), as_fixed(lps([70.0; 3])));
        assert!(outliers(&method, &fixed, &moving, fixed_box).is_empty(), "a consistent set has no outlier");
        let c = moving[13].coords();
        moving[13] = as_moving(lps([c[0] + 8.0, c[1], c[2]]));
        assert_eq!(outliers(&method, &fixed, &moving, fixed_box), vec![13]);
    }
}
