//! L-BFGS (Nocedal & Wright 2006, Algorithm 7.4 and 7.5) with a backtracking Armijo line search, for an objective
//! that is only piecewise smooth.
//!
//! Mutual information through a trilinear interpolant has a gradient that jumps where a sample crosses a voxel face,
//! and a sample that leaves the image changes the sum. Along a search direction the objective is continuous but not
//! smooth, and the curvature pair (s, y) of a step may have sᵀy ≤ 0. A textbook L-BFGS keeps such a pair, its
//! inverse-Hessian estimate stops being positive definite, and the next direction is not a descent direction
//! (`argmin`'s L-BFGS, tried first, stopped that way on the registration tests after 40–80 iterations, far from
//! the optimum). Here:
//!
//! - a pair with sᵀy ≤ 10⁻¹⁰ |s| |y| is skipped (Nocedal & Wright §7.2: the update is skipped when the curvature
//!   condition fails);
//! - a direction that is not a descent direction drops the history and falls back to steepest descent;
//! - the line search is backtracking from the full step, halving until the Armijo condition holds
//!   (f(x + αd) ≤ f(x) + c₁ α gᵀd, c₁ = 10⁻⁴); a point where the objective is not defined counts as no decrease;
//! - every step is capped to move no coordinate by more than `max_step`, so that no trial step throws the
//!   deformation far away;
//! - the first direction (and each restart) is steepest descent scaled so that its largest coordinate moves by
//!   `first_step`.
//!
//! Iterations stop at `max_iterations`, when a line search finds no decrease in [`MAX_HALVINGS`] halvings from
//! steepest descent, or when the decrease over an iteration is below `tolerance` · max(1, |f|).

use std::collections::VecDeque;

/// The most halvings of one line search.
pub(super) const MAX_HALVINGS: usize = 12;

/// Curvature pairs kept.
const MEMORY: usize = 7;

/// Armijo's sufficient-decrease constant.
const C1: f64 = 1e-4;

/// The settings of one minimisation.
#[derive(Clone, Copy, Debug)]
pub(super) struct Settings {
    pub(super) max_iterations: usize,
    /// The largest coordinate's move on the first (steepest-descent) step.
    pub(super) first_step: f64,
    /// The most any coordinate may move in one step.
    pub(super) max_step: f64,
    /// Relative decrease per iteration below which the minimisation stops.
    pub(super) tolerance: f64,
}

/// Why a minimisation ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum End {
    /// The decrease fell below the tolerance, or no step decreased the objective.
    Converged,
    MaxIterations,
    /// The objective asked to stop (a cancel).
    Stopped,
}

/// What an evaluation gives: the value and the gradient, `None` where the objective is not defined, or a request to
/// stop.
pub(super) enum Value {
    At(f64, Vec<f64>),
    Undefined,
    Stop,
}

/// The result: the point, the iterations made and why it ended.
#[derive(Debug)]
pub(super) struct Minimum {
    pub(super) x: Vec<f64>,
    pub(super) iterations: usize,
    pub(super) end: End,
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

fn largest(a: &[f64]) -> f64 {
    a.iter().fold(0.0f64, |m, v| m.max(v.abs()))
}

/// Minimises `f` from `x0`, where `f(x0)` = (`f0`, `g0`).
pub(super) fn minimise(
    x0: Vec<f64>,
    (f0, g0): (f64, Vec<f64>),
    settings: &Settings,
    f: &mut dyn FnMut(&[f64]) -> Value,
) -> Minimum {
    let (mut x, mut fx, mut g) = (x0, f0, g0);
    let mut history: VecDeque<(Vec<f64>, Vec<f64>, f64)> = VecDeque::with_capacity(MEMORY);
    let mut iterations = 0;
    let mut trial = vec![0.0; x.len()];
    let end = loop {
        if iterations >= settings.max_iterations {
            break End::MaxIterations;
        }
        let steepest = |g: &[f64]| {
            let scale = settings.first_step / largest(g).max(f64::MIN_POSITIVE);
            g.iter().map(|v| -v * scale).collect::<Vec<f64>>()
        };
        let mut d = if history.is_empty() { steepest(&g) } else { two_loop(&g, &history) };
        let mut slope = dot(&g, &d);
        if slope.is_nan() || slope >= 0.0 {
            history.clear();
            d = steepest(&g);
            slope = dot(&g, &d);
        }
        if slope.is_nan() || slope >= 0.0 {
            break End::Converged;
        }
        let cap = settings.max_step / largest(&d).max(f64::MIN_POSITIVE);
        if cap < 1.0 {
            for v in &mut d {
                *v *= cap;
            }
            slope *= cap;
        }
        // Backtracking from the full step; from a quasi-Newton direction that fails, once more from steepest descent.
        let mut found = None;
        let mut alpha = 1.0;
        for _ in 0..MAX_HALVINGS {
            trial.iter_mut().zip(&x).zip(&d).for_each(|((t, x), d)| *t = x + alpha * d);
            match f(&trial) {
                Value::Stop => return Minimum { x, iterations, end: End::Stopped },
                Value::At(ft, gt) if ft <= fx + C1 * alpha * slope => {
                    found = Some((ft, gt));
                    break;
                }
                Value::At(..) | Value::Undefined => alpha *= 0.5,
            }
        }
        let Some((f_new, g_new)) = found else {
            if history.is_empty() {
                break End::Converged;
            }
            history.clear();
            continue;
        };
        iterations += 1;
        let s: Vec<f64> = d.iter().map(|v| alpha * v).collect();
        let y: Vec<f64> = g_new.iter().zip(&g).map(|(a, b)| a - b).collect();
        let sy = dot(&s, &y);
        if sy > 1e-10 * dot(&s, &s).sqrt() * dot(&y, &y).sqrt() {
            if history.len() == MEMORY {
                history.pop_front();
            }
            history.push_back((s, y, 1.0 / sy));
        }
        let decrease = fx - f_new;
        std::mem::swap(&mut x, &mut trial);
        fx = f_new;
        g = g_new;
        if decrease < settings.tolerance * fx.abs().max(1.0) {
            break End::Converged;
        }
    };
    Minimum { x, iterations, end }
}

/// −H g by the two-loop recursion over the kept pairs (s, y, 1/sᵀy), with H₀ = (sᵀy / yᵀy) I of the newest.
fn two_loop(g: &[f64], history: &VecDeque<(Vec<f64>, Vec<f64>, f64)>) -> Vec<f64> {
    let mut q = g.to_vec();
    let mut alphas = vec![0.0; history.len()];
    for (i, (s, y, rho)) in history.iter().enumerate().rev() {
        let a = rho * dot(s, &q);
        alphas[i] = a;
        q.iter_mut().zip(y).for_each(|(q, y)| *q -= a * y);
    }
    let (s, y, _) = history.back().expect("not empty");
    let gamma = dot(s, y) / dot(y, y);
    for v in &mut q {
        *v *= gamma;
    }
    for ((s, y, rho), a) in history.iter().zip(&alphas) {
        let b = rho * dot(y, &q);
        q.iter_mut().zip(s).for_each(|(q, s)| *q += (a - b) * s);
    }
    for v in &mut q {
        *v = -*v;
    }
    q
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The Rosenbrock function in 4 dimensions.
    fn rosenbrock(x: &[f64]) -> (f64, Vec<f64>) {
        let mut f = 0.0;
        let mut g = vec![0.0; x.len()];
        for i in 0..x.len() - 1 {
            let (a, b) = (1.0 - x[i], x[i + 1] - x[i] * x[i]);
            f += a * a + 100.0 * b * b;
            g[i] += -2.0 * a - 400.0 * x[i] * b;
            g[i + 1] += 200.0 * b;
        }
        (f, g)
    }

    #[test]
    fn it_finds_the_minimum_of_a_curved_valley() {
        let x0 = vec![-1.2, 1.0, -0.5, 0.8];
        let settings = Settings { max_iterations: 500, first_step: 0.1, max_step: 1.0, tolerance: 1e-16 };
        let at = rosenbrock(&x0);
        let m = minimise(x0, at, &settings, &mut |x| {
            let (f, g) = rosenbrock(x);
            Value::At(f, g)
        });
        assert!(m.x.iter().all(|v| (v - 1.0).abs() < 1e-4), "{m:?}");
    }

    #[test]
    fn it_steps_around_where_the_objective_is_undefined_and_honours_a_stop() {
        // |x − 3|² defined only for x < 2.5: the minimum on the defined part is approached from below.
        let mut calls = 0;
        let settings = Settings { max_iterations: 200, first_step: 1.0, max_step: 1.0, tolerance: 0.0 };
        let m = minimise(vec![0.0], (9.0, vec![-6.0]), &settings, &mut |x| {
            calls += 1;
            if x[0] >= 2.5 { Value::Undefined } else { Value::At((x[0] - 3.0).powi(2), vec![2.0 * (x[0] - 3.0)]) }
        });
        assert!(m.x[0] < 2.5 && m.x[0] > 2.49, "{m:?}");
        assert!(calls > 0);
        let m = minimise(vec![0.0], (9.0, vec![-6.0]), &settings, &mut |_| Value::Stop);
        assert_eq!(m.end, End::Stopped);
        assert_eq!(m.x, vec![0.0]);
    }
}
