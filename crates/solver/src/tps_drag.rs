//! Dragging one landmark of a TPS pair in O(N²) per event instead of two O(N³) refits.
//!
//! # The formulas
//!
//! A TPS solves L c = b with L = [K̃ P̂; P̂ᵀ 0], c = [W; Â], b = [Y; 0] ([`crate::tps`], "Solve"). A
//! [`FactoredTps`] keeps the pieces of that solve (the QR of P̂, Qᵀ K̃ Q's first four rows, the Cholesky or LU
//! factor of the reduced matrix), so that L⁻¹ b costs O(N²) for any b. With pairs (pᵢ moving, qᵢ fixed), the
//! pull-back u has centres qᵢ and data pᵢ, the forward warp d centres pᵢ and data qᵢ. Dragging pair k's point
//! changes, in one direction, a **datum** and, in the other, a **centre**:
//!
//! - Datum yₖ → yₖ + Δ: only b changes, by eₖ Δᵀ, so c′ = c + gₖ Δᵀ with gₖ = L⁻¹ eₖ. The warp changes by
//!   φₖ(x) Δ, where φₖ(x) = Σⱼ gₖⱼ U(‖x − cⱼ‖) + (affine part of gₖ)(x) is pair k's cardinal function (1 at
//!   centre k, 0 at the others when interpolating). For the pull-back, the control texture changes by φₖ Δ, so
//!   [`DragTexture`] samples φₖ on the grid once, when the drag starts, and each event is an axpy over the texels.
//! - Centre cₖ → z: row and column k of L change by δ = κ(z) − κ(cₖ) with δₖ = 0 (κ(z) = [U(‖cⱼ − z‖)ⱼ; p̂(z)]),
//!   so L′ = L + eₖ δᵀ + δ eₖᵀ, a rank-2 change. Woodbury's identity with U = [eₖ δ], V = [δ eₖ] gives
//!   c′ = c − [gₖ h] S⁻¹ [δᵀ c; cₖ], h = L⁻¹ δ, S = I₂ + Vᵀ[gₖ h] = [1 + δ·gₖ, δ·h; gₖₖ, 1 + hₖ]: one O(N²)
//!   solve per event. Each event starts from the kept factorisation (never from the previous event), so errors do not
//!   accumulate. The pull-back's texture must then be evaluated again, N kernel terms per texel; [`DragTexture`]
//!   evaluates only the change u′ − u (whose weights are small) in SIMD over texels, in f64 (an f32 sum lost
//!   10⁻⁴ mm to cancelling weights), and adds it to the f64 texture of the drag's start.
//!
//! # Two parts
//!
//! [`PairDrag`] holds both directions factorised and gives each event's coefficients, hence both warps
//! ([`PairDrag::step`], O(N²): one solve with the kept factorisation). What the renderer samples, the pull-back's
//! control texture, is made by the caller: on the GPU from the new coefficients (the app's `ControlEvalPass` route),
//! or on the CPU by [`DragTexture`], which samples the drag start's texture and φₖ once and updates them per event
//! ([`DragTexture::fill`]) as above.
//!
//! # When the fast path refuses
//!
//! A dragged point that comes to coincide with another point of its side (within
//! [`crate::pairs::SAME_POSITION_RTOL`] of that side's extent), or a rank-2 update whose 2×2 matrix S is
//! numerically singular, gives [`SolverError::Degenerate`]: the caller refits in full, whose error names the pairs.
//! Pairs given twice are refused when the drag starts ([`PairDrag::new`]).
//!
//! # On a base
//!
//! Under a displacement field B (the warp stack's base), the landmark layers are r, fitted on qᵢ → B⁻¹(pᵢ), and s,
//! on pᵢ → B(qᵢ), and u = B ∘ r, d = B⁻¹ ∘ s. A drag still changes one datum and one centre of each: a moving point
//! moves r's datum to B⁻¹(p′) and s's centre to p′, a fixed point r's centre to q′ and s's datum to B(q′), so the
//! same updates serve ([`PairDrag::on_base`], [`PairDrag::step_on_base`]); the caller evaluates B.

#![allow(
    clippy::inline_always,
    reason = "the grid kernel inlines into its AVX2 build (target_feature), where it is vectorised with AVX2 and FMA"
)]

use std::fmt;

use nalgebra::{DMatrix, DVector, Matrix2, Matrix3};
use rayon::prelude::*;
use warpbench_io::geometry::{Point3, Space};

use crate::control::{ControlGrid, ControlTexture};
use crate::pairs::SAME_POSITION_RTOL;
use crate::spaces::{Fixed, Moving};
use crate::tps::{self, Factor, Reflector, Regularisation, Solution, Tps};
use crate::{Result, SolverError};

/// Smallest accepted |det S| of the rank-2 update relative to the size of S's terms.
pub const UPDATE_RCOND_MIN: f64 = 1e-10;

/// A TPS whose system L stays factorised: [`FactoredTps::solve_in_place`] applies L⁻¹ in O(N²).
pub struct FactoredTps<To: Space, From: Space> {
    /// The centres, raw mm in `From`.
    centres: Vec<[f64; 3]>,
    /// The data, raw mm in `To`.
    data: Vec<[f64; 3]>,
    regularisation: Regularisation,
    /// Centre and scale of the affine block's coordinates p̂ = ((x − c)/s, 1).
    centre: [f64; 3],
    scale: f64,
    reflectors: Vec<Reflector>,
    /// R⁻¹ of P̂ = Q [R; 0].
    r_inv: DMatrix<f64>,
    /// Rows 0..4 of M = Qᵀ K̃ Q (4 × N).
    m_top: DMatrix<f64>,
    /// The reduced matrix M₂₂'s factor; `None` for N = 4.
    factor: Option<Factor>,
    /// c = L⁻¹ [Y; 0], (N + 4) × 3.
    coefficients: DMatrix<f64>,
    tps: Tps<To, From>,
}

impl<To: Space, From: Space> fmt::Debug for FactoredTps<To, From> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("FactoredTps")
            .field("centres", &self.centres.len())
            .field("regularisation", &self.regularisation)
            .finish_non_exhaustive()
    }
}

#[inline]
fn distance(a: [f64; 3], b: [f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

impl<To: Space, From: Space> FactoredTps<To, From> {
    /// Fits f(`src[i]`) ≈ `dst[i]` as [`Tps::fit_regularised`] does (the same checks and the same map, to rounding),
    /// keeping the factorisation. Pairs given twice are refused: a drag moves one copy away from the other.
    pub fn fit(src: &[Point3<From>], dst: &[Point3<To>], regularisation: Regularisation) -> Result<Self> {
        let (checked, p, q) = tps::checked_pairs(src, dst, regularisation)?;
        if checked.distinct.len() != src.len() {
            return Err(SolverError::InvalidParameter(
                "a TPS kept for dragging needs distinct pairs (a pair is given twice)".into(),
            ));
        }
        let (centre, scale) = tps::centre_and_scale(&p)?;
        let d = regularisation.k_diagonal();
        let n = p.len();
        let parallelism = tps::solve_parallelism(n);
        let mut k_mat = tps::kernel_matrix(&p, d, parallelism);
        let mut p_hat = DMatrix::<f64>::from_fn(n, 4, |i, k| if k < 3 { (p[i][k] - centre[k]) / scale } else { 1.0 });
        let (reflectors, r) = tps::householder_qr(&mut p_hat)?;
        let mut y = DMatrix::<f64>::from_fn(n, 3, |i, k| q[i][k]);
        tps::apply_qt_s_q(&mut k_mat, &reflectors, parallelism);
        for h in &reflectors {
            h.apply_left(&mut y);
        }
        let m = n - 4;
        let factor = if m == 0 {
            None
        } else {
            Some(tps::solve_symmetric(tps::trailing_block(&k_mat, 4), &y.rows(4, m).clone_owned(), d)?.1)
        };
        let r_inv =
            r.try_inverse().ok_or_else(|| SolverError::Degenerate("the TPS affine block P is singular".into()))?;
        let mut this = Self {
            centres: p.clone(),
            data: q.clone(),
            regularisation,
            centre,
            scale,
            reflectors,
            r_inv: DMatrix::from_fn(4, 4, |i, j| r_inv[(i, j)]),
            m_top: k_mat.rows(0, 4).clone_owned(),
            factor,
            coefficients: DMatrix::zeros(n + 4, 3),
            tps: Tps::from_raw(&p, &vec![[0.0; 3]; n], Matrix3::zeros(), [0.0; 3], regularisation),
        };
        let mut c = DMatrix::<f64>::zeros(n + 4, 3);
        c.rows_mut(0, n).copy_from(&DMatrix::from_fn(n, 3, |i, k| q[i][k]));
        if !this.solve_in_place(&mut c) {
            return Err(SolverError::Degenerate("the TPS system could not be solved".into()));
        }
        let (w, a, b) = this.parts(&c);
        let tps = Tps::from_raw(&p, &w, a, b, regularisation);
        let diameter = tps::bounding_diagonal(&p);
        tps.check_solution(&p, &q, &Solution { w, a, b, diameter })?;
        this.coefficients = c;
        this.tps = tps;
        Ok(this)
    }

    /// The fitted TPS.
    #[must_use]
    pub fn tps(&self) -> &Tps<To, From> {
        &self.tps
    }

    /// Number of centres N.
    #[must_use]
    pub fn len(&self) -> usize {
        self.centres.len()
    }

    /// Never true: a TPS has at least 4 centres.
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.centres.is_empty()
    }

    /// b ← L⁻¹ b for b of N + 4 rows (any number of columns): O(N²) per column. False when the LU factor is singular.
    pub fn solve_in_place(&self, b: &mut DMatrix<f64>) -> bool {
        let n = self.centres.len();
        let m = n - 4;
        assert_eq!(b.nrows(), n + 4, "solve_in_place: b needs N + 4 rows");
        // With W = Q ω: Rᵀ ω₁ = z, M₂₂ ω₂ = (Qᵀy)₂ − M₂₁ ω₁, R Â = (Qᵀy)₁ − M₁₁ ω₁ − M₁₂ ω₂.
        let mut y = b.rows(0, n).clone_owned();
        for h in &self.reflectors {
            h.apply_left(&mut y);
        }
        let omega1 = self.r_inv.transpose() * b.rows(n, 4);
        let m11 = self.m_top.columns(0, 4);
        let m12 = self.m_top.columns(4, m);
        let mut omega2 = y.rows(4, m) - m12.transpose() * &omega1;
        if let Some(factor) = &self.factor
            && !factor.solve_in_place(&mut omega2)
        {
            return false;
        }
        let a_hat = &self.r_inv * (y.rows(0, 4) - m11 * &omega1 - m12 * &omega2);
        let mut w = DMatrix::<f64>::zeros(n, b.ncols());
        w.rows_mut(0, 4).copy_from(&omega1);
        w.rows_mut(4, m).copy_from(&omega2);
        for h in self.reflectors.iter().rev() {
            h.apply_left(&mut w);
        }
        b.rows_mut(0, n).copy_from(&w);
        b.rows_mut(n, 4).copy_from(&a_hat);
        true
    }

    /// gₖ = L⁻¹ eₖ: the coefficients of centre k's cardinal function.
    fn unit_response(&self, k: usize) -> Result<DVector<f64>> {
        let mut e = DMatrix::<f64>::zeros(self.centres.len() + 4, 1);
        e[(k, 0)] = 1.0;
        if !self.solve_in_place(&mut e) {
            return Err(SolverError::Degenerate("the TPS system could not be solved".into()));
        }
        Ok(e.column(0).into_owned())
    }

    /// Weights, A and b in raw mm from coefficients [W; Â] (N + 4 rows, 3 columns).
    fn parts(&self, c: &DMatrix<f64>) -> (Vec<[f64; 3]>, Matrix3<f64>, [f64; 3]) {
        let n = self.centres.len();
        let (centre, s) = (self.centre, self.scale);
        let w = (0..n).map(|i| [c[(i, 0)], c[(i, 1)], c[(i, 2)]]).collect();
        let a = Matrix3::from_fn(|row, col| c[(n + col, row)] / s);
        let b = std::array::from_fn(|row| c[(n + 3, row)] - (0..3).map(|col| a[(row, col)] * centre[col]).sum::<f64>());
        (w, a, b)
    }

    /// The affine part of one column of coefficients as (a, b) in raw mm: x ↦ a·x + b.
    fn affine_of(&self, c: &DVector<f64>) -> ([f64; 3], f64) {
        let n = self.centres.len();
        let a: [f64; 3] = std::array::from_fn(|k| c[n + k] / self.scale);
        let b = c[n + 3] - (0..3).map(|k| a[k] * self.centre[k]).sum::<f64>();
        (a, b)
    }

    /// Refuses a dragged point `z` of pair k that is not finite or lands on another point of its side.
    fn check_moved(points: &[[f64; 3]], k: usize, z: [f64; 3]) -> Result<()> {
        if !z.iter().all(|v| v.is_finite()) {
            return Err(SolverError::NonFinite { pair: k + 1 });
        }
        let tol = SAME_POSITION_RTOL * tps::bounding_diagonal(points).max(1.0);
        if let Some(j) = points.iter().enumerate().position(|(j, p)| j != k && distance(*p, z) <= tol) {
            return Err(SolverError::Degenerate(format!(
                "dragged point {} lands on point {}; refit to check the pairs",
                k + 1,
                j + 1
            )));
        }
        Ok(())
    }

    /// The coefficients with datum k at `to` instead of its own: c + gₖ (to − yₖ)ᵀ.
    fn with_datum(&self, g: &DVector<f64>, k: usize, to: [f64; 3]) -> DMatrix<f64> {
        let step = [to[0] - self.data[k][0], to[1] - self.data[k][1], to[2] - self.data[k][2]];
        let mut c = self.coefficients.clone();
        for (col, s) in step.iter().enumerate() {
            c.column_mut(col).axpy(*s, g, 1.0);
        }
        c
    }

    /// The coefficients with centre k at `z` (the same data): the rank-2 Woodbury update of the module docs,
    /// c′ = c − gₖ t₀ᵀ − h t₁ᵀ; returns c′, h and the rows t₀, t₁.
    fn with_centre(&self, g: &DVector<f64>, k: usize, z: [f64; 3]) -> Result<CentreUpdate> {
        let n = self.centres.len();
        let ck = self.centres[k];
        let mut delta = DMatrix::<f64>::zeros(n + 4, 1);
        for (j, cj) in self.centres.iter().enumerate() {
            if j != k {
                delta[(j, 0)] = distance(*cj, z) - distance(*cj, ck);
            }
        }
        for a in 0..3 {
            delta[(n + a, 0)] = (z[a] - ck[a]) / self.scale;
        }
        let delta_v = delta.column(0).into_owned();
        let mut h = delta;
        if !self.solve_in_place(&mut h) {
            return Err(SolverError::Degenerate("the TPS system could not be solved".into()));
        }
        let h = h.column(0).into_owned();
        let s = Matrix2::new(1.0 + delta_v.dot(g), delta_v.dot(&h), g[k], 1.0 + h[k]);
        let size = s.iter().fold(0.0_f64, |m, v| m.max(v.abs()));
        let det = s.determinant();
        if !(det.is_finite() && det.abs() > UPDATE_RCOND_MIN * size * size) {
            return Err(SolverError::Degenerate(format!(
                "moving centre {} makes the TPS system singular (|det S| = {:.1e})",
                k + 1,
                det.abs()
            )));
        }
        let s_inv = s.try_inverse().ok_or_else(|| SolverError::Degenerate("the rank-2 update is singular".into()))?;
        let mut c = self.coefficients.clone();
        let mut t = [[0.0; 3]; 2];
        for col in 0..3 {
            let rhs = nalgebra::Vector2::new(delta_v.dot(&self.coefficients.column(col)), self.coefficients[(k, col)]);
            let tc = s_inv * rhs;
            c.column_mut(col).axpy(-tc[0], g, 1.0);
            c.column_mut(col).axpy(-tc[1], &h, 1.0);
            for (row, v) in t.iter_mut().zip([tc[0], tc[1]]) {
                row[col] = v;
            }
        }
        Ok(CentreUpdate { coefficients: c, h, t })
    }

    /// A TPS on `centres` with coefficients `c`.
    fn tps_with(&self, centres: &[[f64; 3]], c: &DMatrix<f64>) -> Tps<To, From> {
        let (w, a, b) = self.parts(c);
        Tps::from_raw(centres, &w, a, b, self.regularisation)
    }
}

/// What [`FactoredTps::with_centre`] finds: c′ = c − gₖ t₀ᵀ − h t₁ᵀ.
struct CentreUpdate {
    coefficients: DMatrix<f64>,
    h: DVector<f64>,
    t: [[f64; 3]; 2],
}

/// Which point of the pair a drag moves.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DraggedEnd {
    /// The moving point pₖ: a datum of the pull-back, a centre of the forward warp.
    Moving,
    /// The fixed point qₖ: a centre of the pull-back, a datum of the forward warp.
    Fixed,
}

/// One pair's drag: both directions kept factorised, with pair k's unit responses gₖ = L⁻¹ eₖ. [`PairDrag::step`]
/// gives both warps with the pair's point at a new position in O(N²) (module docs); the pull-back's control texture
/// is the caller's ([`DragTexture`] on the CPU, or the GPU from the step's pull-back).
///
/// On a base B under the landmark warp (a displacement field, [`PairDrag::on_base`]) the two directions are the
/// landmark layers r and s, fitted on data the base has moved: r on qᵢ → B⁻¹(pᵢ), in `U`, and s on pᵢ → B(qᵢ), in
/// `D`; without one, `U` = [`Moving`] and `D` = [`Fixed`], and they are u and d themselves.
#[derive(Debug)]
pub struct PairDrag<U: Space = Moving, D: Space = Fixed> {
    pair: usize,
    end: DraggedEnd,
    /// u = `moving_from_fixed` (or r): centres qᵢ, data pᵢ (or B⁻¹(pᵢ)).
    pullback: FactoredTps<U, Fixed>,
    /// d = `fixed_from_moving` (or s): centres pᵢ, data qᵢ (or B(qᵢ)).
    forward: FactoredTps<D, Moving>,
    /// L⁻¹ eₖ of each.
    g_pullback: DVector<f64>,
    g_forward: DVector<f64>,
}

/// Both warps of one drag event, and how the pull-back changed (for [`DragTexture::fill`]).
#[derive(Clone, Debug)]
pub struct DragStep<U: Space = Moving, D: Space = Fixed> {
    pub pullback: Tps<U, Fixed>,
    pub forward: Tps<D, Moving>,
    /// The dragged pair and the number of pairs, so that a step is never filled into another drag's texture.
    pair: usize,
    pairs: usize,
    change: PullbackChange,
}

/// How a drag event changed the pull-back u (module docs).
#[derive(Clone, Debug)]
enum PullbackChange {
    /// Datum k moved by Δ: u′ = u + φₖ Δ.
    Datum { delta: [f64; 3] },
    /// Centre k moved to z.
    Centre(CentreMove),
}

/// A moved pull-back centre: u′ − u = −t₀ φₖ − t₁ ψ + c′ₖ (U(‖x − z‖) − U(‖x − qₖ‖)), ψ being h's function.
#[derive(Clone, Debug)]
struct CentreMove {
    z: [f64; 3],
    h: DVector<f64>,
    t: [[f64; 3]; 2],
    c_k: [f64; 3],
}

impl PairDrag {
    /// Fits both directions on the pairs (`fixed[i]` ↔ `moving[i]`, all distinct), kept factorised, and solves for
    /// pair `pair`'s unit responses: the cost of two fits, once per drag.
    ///
    /// # Errors
    /// `pair` out of range, pairs given twice, or a fit that fails ([`Tps::fit_regularised`]'s errors).
    pub fn new(
        fixed: &[Point3<Fixed>],
        moving: &[Point3<Moving>],
        pair: usize,
        end: DraggedEnd,
        regularisation: Regularisation,
    ) -> Result<Self> {
        Self::on_base((fixed, moving), (moving, fixed), (pair, end), regularisation)
    }

    /// Both warps with the dragged point at `to` (LPS mm, in its own volume's space) and the other points where the
    /// drag started: one datum update (an axpy) in one direction and one rank-2 update (one O(N²) solve) in the
    /// other.
    ///
    /// # Errors
    /// [`SolverError::Degenerate`] or [`SolverError::NonFinite`] when the fast path refuses (module docs): refit.
    pub fn step(&self, to: [f64; 3]) -> Result<DragStep> {
        self.step_on_base(to, to)
    }
}

impl<U: Space, D: Space> PairDrag<U, D> {
    /// Fits both directions kept factorised on a base under the landmarks: the pull-back's on the fixed points →
    /// `pullback_data` (B⁻¹(pᵢ)), the forward's on the moving points → `forward_data` (B(qᵢ)), all distinct; pair
    /// `pair`'s `end` is dragged. The cost of two fits, once per drag.
    ///
    /// # Errors
    /// `pair` out of range, lists of different lengths, pairs given twice, or a fit that fails
    /// ([`Tps::fit_regularised`]'s errors).
    pub fn on_base(
        (fixed, pullback_data): (&[Point3<Fixed>], &[Point3<U>]),
        (moving, forward_data): (&[Point3<Moving>], &[Point3<D>]),
        (pair, end): (usize, DraggedEnd),
        regularisation: Regularisation,
    ) -> Result<Self> {
        let n = moving.len();
        if [fixed.len(), pullback_data.len(), forward_data.len()].iter().any(|&m| m != n) {
            return Err(SolverError::InvalidParameter("a drag's point lists differ in length".into()));
        }
        if pair >= n {
            return Err(SolverError::InvalidParameter(format!("dragged pair {} of {n} pairs", pair + 1)));
        }
        let (pullback, forward) = rayon::join(
            || FactoredTps::<U, Fixed>::fit(fixed, pullback_data, regularisation),
            || FactoredTps::<D, Moving>::fit(moving, forward_data, regularisation),
        );
        Self::from_factored((pullback?, forward?), (pair, end))
    }

    /// The drag of pair `pair`'s `end` on both directions already factorised (`pullback` on the fixed points,
    /// `forward` on the moving points, as [`PairDrag::on_base`] fits them, perhaps before the drag began): only pair
    /// k's unit responses are solved, O(N²).
    ///
    /// # Errors
    /// `pair` out of range, directions of different sizes, or a unit response that cannot be solved.
    pub fn from_factored(
        (pullback, forward): (FactoredTps<U, Fixed>, FactoredTps<D, Moving>),
        (pair, end): (usize, DraggedEnd),
    ) -> Result<Self> {
        let n = pullback.len();
        if forward.len() != n {
            return Err(SolverError::InvalidParameter("a drag's two directions differ in size".into()));
        }
        if pair >= n {
            return Err(SolverError::InvalidParameter(format!("dragged pair {} of {n} pairs", pair + 1)));
        }
        let g_pullback = pullback.unit_response(pair)?;
        let g_forward = forward.unit_response(pair)?;
        Ok(Self { pair, end, pullback, forward, g_pullback, g_forward })
    }

    /// The dragged pair (0-based, in the pairs given to [`PairDrag::new`] or [`PairDrag::on_base`]).
    #[must_use]
    pub fn pair(&self) -> usize {
        self.pair
    }

    /// Which of its points is dragged.
    #[must_use]
    pub fn end(&self) -> DraggedEnd {
        self.end
    }

    /// The fixed points qᵢ the drag started from (raw LPS mm).
    #[must_use]
    pub fn fixed_points(&self) -> &[[f64; 3]] {
        &self.pullback.centres
    }

    /// The moving points pᵢ the drag started from (raw LPS mm).
    #[must_use]
    pub fn moving_points(&self) -> &[[f64; 3]] {
        &self.forward.centres
    }

    /// Both directions with the dragged point moved, on a base: `pullback_to` is where the point goes for the
    /// pull-back's layer (a moving point: B⁻¹(p′), its datum; a fixed point: q′, its centre), `forward_to` for the
    /// forward's (a moving point: p′, its centre; a fixed point: B(q′), its datum). Without a base both are the new
    /// position ([`PairDrag::step`]).
    ///
    /// # Errors
    /// [`SolverError::Degenerate`] or [`SolverError::NonFinite`] when the fast path refuses (module docs): refit.
    pub fn step_on_base(&self, pullback_to: [f64; 3], forward_to: [f64; 3]) -> Result<DragStep<U, D>> {
        let k = self.pair;
        let pairs = self.pullback.len();
        match self.end {
            DraggedEnd::Moving => {
                let to = forward_to;
                FactoredTps::<D, Moving>::check_moved(&self.forward.centres, k, to)?;
                let c_u = self.pullback.with_datum(&self.g_pullback, k, pullback_to);
                let c_d = self.forward.with_centre(&self.g_forward, k, to)?;
                let mut moved = self.forward.centres.clone();
                moved[k] = to;
                let p = self.pullback.data[k];
                Ok(DragStep {
                    pullback: self.pullback.tps_with(&self.pullback.centres, &c_u),
                    forward: self.forward.tps_with(&moved, &c_d.coefficients),
                    pair: k,
                    pairs,
                    change: PullbackChange::Datum { delta: std::array::from_fn(|a| pullback_to[a] - p[a]) },
                })
            }
            DraggedEnd::Fixed => {
                let to = pullback_to;
                FactoredTps::<U, Fixed>::check_moved(&self.pullback.centres, k, to)?;
                let update = self.pullback.with_centre(&self.g_pullback, k, to)?;
                let c_d = self.forward.with_datum(&self.g_forward, k, forward_to);
                let mut moved = self.pullback.centres.clone();
                moved[k] = to;
                let c_k = std::array::from_fn(|a| update.coefficients[(k, a)]);
                Ok(DragStep {
                    pullback: self.pullback.tps_with(&moved, &update.coefficients),
                    forward: self.forward.tps_with(&self.forward.centres, &c_d),
                    pair: k,
                    pairs,
                    change: PullbackChange::Centre(CentreMove { z: to, h: update.h, t: update.t, c_k }),
                })
            }
        }
    }
}

/// The pull-back's control texture through one drag, made on the CPU: the texture at the drag's start (u(x) − x at
/// the texel centres, f64) and pair k's cardinal function φₖ there, sampled once ([`DragTexture::new`]); each event
/// then adds the pull-back's change ([`DragTexture::fill`]): an axpy over the texels for a moving point, one f64 sum
/// of N terms per texel for a fixed point (module docs). On a base ([`PairDrag::on_base`]) it holds the landmark
/// layer r(x) − x; the caller puts the base after it.
#[derive(Debug)]
pub struct DragTexture {
    grid: ControlGrid,
    /// The drag this texture belongs to: its pair and number of pairs.
    pair: usize,
    pairs: usize,
    /// u(x) − x at the texel centres at the drag's start, f64.
    base: Vec<[f64; 3]>,
    /// The pull-back's cardinal function φₖ at the texel centres, f64.
    cardinal: Vec<f64>,
    /// For a fixed-point drag, the pull-back's centres about the grid's centre, for the evaluation of h's function;
    /// empty for a moving-point drag.
    centres_psi: Vec<[PsiReal; 3]>,
}

impl DragTexture {
    /// Samples `drag`'s pull-back and its cardinal function φₖ on `grid`: one pass of N kernel terms per texel, once
    /// per drag.
    #[must_use]
    pub fn new<U: Space, D: Space>(drag: &PairDrag<U, D>, grid: ControlGrid) -> Self {
        let pullback = &drag.pullback;
        let origin = grid_origin(&grid);
        // One f64 pass: the pull-back's kernel sums (3 channels) and φₖ's (the fourth).
        let centres: Vec<[f64; 3]> =
            pullback.centres.iter().map(|c| std::array::from_fn(|a| c[a] - origin[a])).collect();
        let n = pullback.len();
        let weights: Vec<[f64; 4]> = (0..n)
            .map(|j| {
                let c = &pullback.coefficients;
                [c[(j, 0)], c[(j, 1)], c[(j, 2)], drag.g_pullback[j]]
            })
            .collect();
        let mut sums = vec![[0.0f64; 4]; grid.texel_count()];
        radial_grid(&grid, origin, &centres, &weights, &mut sums);
        let t = pullback.tps();
        let (a, b) = (t.linear(), t.translation());
        let (ga, gb) = pullback.affine_of(&drag.g_pullback);
        let mut base = vec![[0.0; 3]; grid.texel_count()];
        let mut cardinal = vec![0.0; grid.texel_count()];
        for_texels(&grid, |i, x| {
            let s = sums[i];
            base[i] =
                std::array::from_fn(|r| a[(r, 0)] * x[0] + a[(r, 1)] * x[1] + a[(r, 2)] * x[2] + b[r] + s[r] - x[r]);
            cardinal[i] = ga[0] * x[0] + ga[1] * x[1] + ga[2] * x[2] + gb + s[3];
        });
        let centres_psi = match drag.end {
            DraggedEnd::Moving => Vec::new(),
            DraggedEnd::Fixed => centres.iter().map(|c| c.map(PsiReal::from_f64)).collect(),
        };
        Self { grid, pair: drag.pair, pairs: n, base, cardinal, centres_psi }
    }

    /// The control texture's grid.
    #[must_use]
    pub fn grid(&self) -> &ControlGrid {
        &self.grid
    }

    /// The pull-back's control texture for `step` (made by `drag`, the drag this texture was sampled for) into
    /// `texels` (`grid().texel_count()` of them).
    ///
    /// # Panics
    /// When `texels` does not match the grid or `step` comes from another drag (a bug of the caller).
    pub fn fill<U: Space, D: Space>(&self, drag: &PairDrag<U, D>, step: &DragStep<U, D>, texels: &mut [[f32; 4]]) {
        assert_eq!(texels.len(), self.grid.texel_count(), "DragTexture::fill: texels must match the grid");
        assert!(
            (step.pair, step.pairs) == (self.pair, self.pairs)
                && (drag.pair, drag.pullback.len()) == (self.pair, self.pairs),
            "DragTexture::fill: the step and the drag must be the texture's own"
        );
        match &step.change {
            PullbackChange::Datum { delta } => {
                texels.par_iter_mut().zip(&self.base).zip(&self.cardinal).for_each(|((t, b), f)| {
                    *t =
                        [(b[0] + f * delta[0]) as f32, (b[1] + f * delta[1]) as f32, (b[2] + f * delta[2]) as f32, 0.0];
                });
            }
            PullbackChange::Centre(moved) => self.fill_centre(drag, moved, texels),
        }
    }

    /// The texture for a moved pull-back centre z: the drag start's texels plus
    /// u′ − u = −t₀ φₖ − t₁ ψ + c′ₖ (U(‖x − z‖) − U(‖x − qₖ‖)), where ψ is h's function on the drag start's centres,
    /// the one sum of N terms per texel (about the grid's centre); the rest is f64.
    fn fill_centre<U: Space, D: Space>(&self, drag: &PairDrag<U, D>, moved: &CentreMove, texels: &mut [[f32; 4]]) {
        let CentreMove { z, ref h, t, c_k: ck } = *moved;
        let n = self.pairs;
        let origin = grid_origin(&self.grid);
        let weights: Vec<[PsiReal; 1]> = (0..n).map(|j| [PsiReal::from_f64(h[j])]).collect();
        let mut psi = vec![[PsiReal::default(); 1]; self.grid.texel_count()];
        radial_grid(&self.grid, origin, &self.centres_psi, &weights, &mut psi);
        let (ha, hb) = drag.pullback.affine_of(h);
        let qk = drag.pullback.centres[self.pair];
        let grid = self.grid;
        let [nx, ny, _] = grid.dims;
        texels.par_chunks_mut(nx).enumerate().for_each(|(row, out)| {
            let (j, kz) = (row % ny, row / ny);
            for (i, texel) in out.iter_mut().enumerate() {
                let x = grid.texel_centre([i, j, kz]);
                let idx = row * nx + i;
                let psi = psi[idx][0].to_f64() + ha[0] * x[0] + ha[1] * x[1] + ha[2] * x[2] + hb;
                let (rz, rk) = (distance(x, z), distance(x, qk));
                // U(‖x − z‖) − U(‖x − qₖ‖) without cancellation.
                let dr = if rz + rk > 0.0 {
                    (0..3).map(|a| (qk[a] - z[a]) * (2.0 * x[a] - z[a] - qk[a])).sum::<f64>() / (rz + rk)
                } else {
                    0.0
                };
                let (b, phi) = (self.base[idx], self.cardinal[idx]);
                *texel = [0, 1, 2, 3]
                    .map(|r| if r == 3 { 0.0 } else { (b[r] - t[0][r] * phi - t[1][r] * psi + ck[r] * dr) as f32 });
            }
        });
    }

    /// A texture for this grid from `texels` (as [`DragTexture::fill`] filled them).
    #[must_use]
    pub fn texture(&self, texels: Vec<[f32; 4]>) -> ControlTexture {
        ControlTexture { grid: self.grid, texels }
    }
}

/// The grid's centre: the origin of the f32 evaluation.
fn grid_origin(grid: &ControlGrid) -> [f64; 3] {
    let (lo, hi) = (grid.domain.min.coords(), grid.domain.max.coords());
    std::array::from_fn(|a| 0.5 * (lo[a] + hi[a]))
}

/// Calls `f(index, x)` for every texel centre x, x fastest.
fn for_texels(grid: &ControlGrid, mut f: impl FnMut(usize, [f64; 3])) {
    let [nx, ny, nz] = grid.dims;
    for kz in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                f(i + nx * (j + ny * kz), grid.texel_centre([i, j, kz]));
            }
        }
    }
}

/// The real types the grid kernel runs in.
pub(crate) trait Real:
    Copy
    + Send
    + Sync
    + Default
    + std::ops::Add<Output = Self>
    + std::ops::Sub<Output = Self>
    + std::ops::Mul<Output = Self>
{
    fn from_f64(v: f64) -> Self;
    fn to_f64(self) -> f64;
    fn sqrt(self) -> Self;
    fn mul_add(self, a: Self, b: Self) -> Self;
}

impl Real for f32 {
    fn from_f64(v: f64) -> Self {
        v as f32
    }
    fn to_f64(self) -> f64 {
        f64::from(self)
    }
    #[inline(always)]
    fn sqrt(self) -> Self {
        f32::sqrt(self)
    }
    #[inline(always)]
    fn mul_add(self, a: Self, b: Self) -> Self {
        f32::mul_add(self, a, b)
    }
}

impl Real for f64 {
    fn from_f64(v: f64) -> Self {
        v
    }
    fn to_f64(self) -> f64 {
        self
    }
    #[inline(always)]
    fn sqrt(self) -> Self {
        f64::sqrt(self)
    }
    #[inline(always)]
    fn mul_add(self, a: Self, b: Self) -> Self {
        f64::mul_add(self, a, b)
    }
}

/// The type h's function is summed in for a fixed-point drag.
type PsiReal = f64;

/// Texels per SIMD block of the grid kernel.
const GRID_LANES: usize = 16;

/// a·b + c, fused where the instruction set has it.
#[inline(always)]
fn madd<T: Real, const FMA: bool>(a: T, b: T, c: T) -> T {
    if FMA { a.mul_add(b, c) } else { a * b + c }
}

/// `out[t][ch]` = Σⱼ `weights[j][ch]` ‖xₜ − `centres[j]`‖ for the texels xₜ of one row (x coordinates `xs`, the
/// row's y and z), all coordinates about the grid's centre. Texels in blocks of [`GRID_LANES`], the form LLVM
/// vectorises.
#[inline(always)]
#[allow(clippy::needless_range_loop)] // one lane index over the accumulators: the form LLVM vectorises
fn row_sums<T: Real, const C: usize, const FMA: bool>(
    xs: &[T],
    (y, z): (T, T),
    centres: &[[T; 3]],
    weights: &[[T; C]],
    out: &mut [[T; C]],
) {
    for (xs, out) in xs.chunks(GRID_LANES).zip(out.chunks_mut(GRID_LANES)) {
        let mut lanes = [T::default(); GRID_LANES];
        for (l, x) in lanes.iter_mut().zip(xs.iter().chain(std::iter::repeat(&xs[xs.len() - 1]))) {
            *l = *x;
        }
        let mut acc = [[T::default(); GRID_LANES]; C];
        for (c, w) in centres.iter().zip(weights) {
            let (dy, dz) = (y - c[1], z - c[2]);
            let e = madd::<T, FMA>(dy, dy, dz * dz);
            for l in 0..GRID_LANES {
                let dx = lanes[l] - c[0];
                let r = madd::<T, FMA>(dx, dx, e).sqrt();
                for ch in 0..C {
                    acc[ch][l] = madd::<T, FMA>(w[ch], r, acc[ch][l]);
                }
            }
        }
        for (l, o) in out.iter_mut().enumerate() {
            *o = std::array::from_fn(|ch| acc[ch][l]);
        }
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn row_sums_avx2<T: Real, const C: usize>(
    xs: &[T],
    yz: (T, T),
    centres: &[[T; 3]],
    weights: &[[T; C]],
    out: &mut [[T; C]],
) {
    row_sums::<T, C, true>(xs, yz, centres, weights, out);
}

/// `out[t]` = Σⱼ `weights[j]` ‖xₜ − `centres[j]`‖ at every texel centre xₜ of `grid`, with `centres` given about
/// `origin` (x fastest; rows on rayon's pool; AVX2 + FMA where the CPU has them).
pub(crate) fn radial_grid<T: Real, const C: usize>(
    grid: &ControlGrid,
    origin: [f64; 3],
    centres: &[[T; 3]],
    weights: &[[T; C]],
    out: &mut [[T; C]],
) {
    assert_eq!(out.len(), grid.texel_count(), "radial_grid: out must match the grid");
    assert_eq!(centres.len(), weights.len(), "radial_grid: one weight per centre");
    #[cfg(target_arch = "x86_64")]
    let avx2 = std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma");
    let [nx, ny, _] = grid.dims;
    let xs: Vec<T> = (0..nx).map(|i| T::from_f64(grid.texel_centre([i, 0, 0])[0] - origin[0])).collect();
    out.par_chunks_mut(nx).enumerate().for_each(|(row, out)| {
        let x = grid.texel_centre([0, row % ny, row / ny]);
        let yz = (T::from_f64(x[1] - origin[1]), T::from_f64(x[2] - origin[2]));
        #[cfg(target_arch = "x86_64")]
        if avx2 {
            #[allow(unsafe_code, reason = "runtime dispatch to the AVX2 build of the same safe code")]
            // SAFETY: the only requirement of a `target_feature` function is that the CPU has the features, and
            // they were detected above.
            unsafe {
                row_sums_avx2(&xs, yz, centres, weights, out);
            }
            return;
        }
        row_sums::<T, C, false>(&xs, yz, centres, weights, out);
    });
}
