//! Thin-plate spline (TPS) with the 3-D kernel U(r) = r.
//!
//! # The formula
//!
//! Given landmark pairs (pᵢ, qᵢ), i = 1…N, the TPS is
//!
//! ```text
//! f(x) = A x + b + Σᵢ wᵢ U(‖x − pᵢ‖),      U(r) = r,
//! ```
//!
//! with A ∈ ℝ³ˣ³, b ∈ ℝ³ and bending weights wᵢ ∈ ℝ³ (Bookstein 1989 in 2-D; U(r) = r is the 3-D
//! biharmonic kernel, Davis et al. 1997). In the notation of ITK's `KernelTransform` (whose 3-D
//! `ThinPlateSplineKernelTransform` uses G(r) = r·I): Kᵢⱼ = U(‖pᵢ − pⱼ‖), P has rows (pᵢᵀ, 1), Y has
//! rows qᵢᵀ, and the weights W (rows wᵢᵀ) and the affine part [Aᵀ; bᵀ] solve
//!
//! ```text
//! L [W; Aᵀ bᵀ] = [Y; 0],     L = [ K + λI   P ]
//!                                [ Pᵀ       0 ],
//! ```
//!
//! i.e. f(pᵢ) + λ wᵢ = qᵢ and Pᵀ W = 0 (the weights carry no affine part).
//!
//! # Stiffness λ: two conventions
//!
//! - [`Regularisation::ItkStiffness`] (what [`Tps::fit`] takes) is ITK's `SetStiffness` exactly: λ is added
//!   to the diagonal of K (ITK `ComputeReflexiveG`). λ = 0 interpolates. **Caveat:** in 3-D, U(r) = r is
//!   conditionally *negative* definite, so on the space Pᵀw = 0 the reduced matrix Q₂ᵀKQ₂ has eigenvalues
//!   −μⱼ < 0, and Q₂ᵀ(K + λI)Q₂ has eigenvalues λ − μⱼ. For 0 < λ < min μⱼ the fit approximates
//!   (|qᵢ − f(pᵢ)| = λ|wᵢ|, shrinking as λ → 0) but the bending energy *grows* with λ; for λ > max μⱼ it
//!   tends to the least-squares affine fit; in between the system passes through singularities (λ = μⱼ),
//!   where [`Tps::fit`] returns [`SolverError::Degenerate`]. ITK behaves the same (its SVD zeroes the
//!   singular value instead). μ_min is typically a few mm for landmarks a few cm apart.
//! - [`Regularisation::Smoothing`] is the well-posed smoothing spline: λ enters as K − λI, so
//!   Q₂ᵀ(K − λI)Q₂ stays negative definite for every λ ≥ 0, and f minimises
//!   Σᵢ ‖qᵢ − f(pᵢ)‖² + λ·E(f) with E(f) = −Σᵢⱼ wᵢ·wⱼ Kᵢⱼ ∝ the thin-plate bending energy (Wahba 1990 §2.4;
//!   Rohr et al. 2001). Residuals qᵢ − f(pᵢ) = −λ wᵢ; E decreases monotonically in λ; λ → ∞ gives the
//!   least-squares affine fit. Prefer this for noisy landmarks.
//!
//! # Directions
//!
//! A [`Tps<To, From>`] maps `From` to `To` and fits f(pᵢ) ≈ qᵢ with pᵢ ∈ `From`, qᵢ ∈ `To`. With landmark
//! pairs (pᵢ ∈ moving, qᵢ ∈ fixed): [`fit_forward`] gives d = `fixed_from_moving`, and [`fit_pullback`]
//! fits the *reversed* pairs qᵢ → pᵢ, giving u = `moving_from_fixed`, exact at the landmarks (it is not
//! d⁻¹ elsewhere). Renderers sample the pull-back into a control texture (Brunet, Nowak & Gleicher 2006
//! §3.3: the TPS is evaluated on the CPU on a regular grid and interpolated by the texture unit).
//!
//! # Solve
//!
//! Coordinates are centred and scaled for the affine block (P̂ rows ((pᵢ − c)/s, 1)), which spans the
//! same functions. With the Householder QR P̂ = Q [R; 0], Q = [Q₁ Q₂], the constraint P̂ᵀW = 0 is W = Q₂Ω,
//! and Ω solves the symmetric (N−4)² system Q₂ᵀ(K ± λI)Q₂ Ω = Q₂ᵀY (Cholesky of its negation; ITK
//! stiffness falls back to Cholesky or LU), then R [Aᵀ; bᵀ]̂ = Q₁ᵀ(Y − (K ± λI)W). The four reflections act on
//! K ± λI at once (compact WY form) and the Cholesky factorisation is blocked ([`crate::dense`]), both in matrix
//! products: ~N³/3 flops for a fit, on rayon's global pool from [`PARALLEL_MIN_LANDMARKS`] centres on (on the calling
//! thread below). Every fit checks the
//! factor's pivot ratio ([`PIVOT_RTOL`]) and estimated condition ([`RCOND_MIN`]) and the backward error of the full system ([`RESIDUAL_RTOL`]),
//! and never returns non-finite coefficients.
//!
//! # Degenerate input (decisions)
//!
//! Every fit first runs [`crate::pairs::validate`] with [`NEEDS`] (4 distinct pairs, neither side coplanar), as
//! every other method does; its errors and warnings number the pairs from 1 and name the sides by their spaces.
//!
//! - Lengths differ → [`SolverError::LengthMismatch`]; a NaN/∞ coordinate → [`SolverError::NonFinite`];
//!   λ negative or not finite → [`SolverError::InvalidParameter`]; more than [`MAX_LANDMARKS`] pairs →
//!   [`SolverError::InvalidParameter`] (the solve is O(N³) time, O(N²) memory).
//! - One point with two different partners → [`SolverError::Conflict`]; the same pair entered twice → counted
//!   once, the first copy kept (ITK's min-norm SVD solution gives the same map), with a
//!   [`crate::pairs::PairWarning::Repeated`] in [`Tps::warnings`]. [`Tps::centres`] lists the distinct centres.
//! - Fewer than 4 distinct pairs → [`SolverError::TooFew`] (no lower-rank fallback: use the rigid or
//!   similarity fits of [`crate::linear`] for 3 pairs).
//! - Either side's points coincident, collinear or coplanar (P is rank-deficient and the affine part undetermined,
//!   or the map collapses a volume) → [`SolverError::Coincident`] or [`SolverError::Flat`].
//!
//! # References
//!
//! - F. L. Bookstein, "Principal warps: thin-plate splines and the decomposition of deformations",
//!   IEEE TPAMI 11(6), 1989.
//! - M. H. Davis, A. Khotanzad, D. P. Flamig, S. E. Harms, "A physics-based coordinate transformation for
//!   3-D image matching", IEEE TMI 16(3), 1997.
//! - ITK `itk::KernelTransform` / `itk::ThinPlateSplineKernelTransform` (p, q, K, P, L, W, Stiffness).
//! - T. Brunet, K. E. Nowak, M. Gleicher, "Integrating dynamic deformations into interactive volume
//!   visualization", EuroVis 2006, §3.3 (TPS warps sampled into deformation textures).
//! - K. Rohr et al., "Landmark-based elastic registration using approximating thin-plate splines",
//!   IEEE TMI 20(6), 2001; G. Wahba, "Spline models for observational data", SIAM 1990.

use std::marker::PhantomData;

use nalgebra::{DMatrix, DMatrixViewMut, DVector, Matrix3, Matrix4x3};
use rayon::prelude::*;
use warpbench_io::geometry::{Point3, Space, Transform};

use crate::pairs::{self, Needs, PairWarning, Spread};
use crate::{Fixed, Moving, Parallelism, Result, SolverError, Warp, dense};

pub use crate::pairs::{FLAT_RTOL, SAME_POSITION_RTOL};

/// The affine part needs 4 non-coplanar landmarks.
pub const MIN_LANDMARKS: usize = 4;
/// Largest accepted N: the dense solve needs 8·N² bytes (200 MB here) and O(N³) time.
pub const MAX_LANDMARKS: usize = 5_000;
/// A factorisation whose smallest/largest pivot ratio is below this is singular.
pub const PIVOT_RTOL: f64 = 1e-13;
/// Smallest accepted estimate of 1/cond(M) for the reduced (N−4)² system (cond ≈ 1e12 loses 4 of 16 digits).
pub const RCOND_MIN: f64 = 1e-12;
/// Largest accepted backward error of the solved system, relative to the size of its terms.
pub const RESIDUAL_RTOL: f64 = 1e-9;

/// Centres per block of the evaluation kernel (f64 lanes; the tail is padded with zero weights).
const LANES: usize = 2;
const METHOD: &str = "thin-plate spline";

/// What a TPS needs of its pairs ([`crate::pairs`]): 4 distinct pairs, neither side coplanar.
pub const NEEDS: Needs = Needs { method: METHOD, min_pairs: MIN_LANDMARKS, spread: Spread::NotCoplanar };

/// How λ enters the TPS system (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Regularisation {
    /// λ = 0: f(pᵢ) = qᵢ exactly.
    Interpolate,
    /// ITK's `Stiffness`: K + λI, ITK's convention (cross-checked to 1e-6 mm); singular at some intermediate λ.
    ItkStiffness(f64),
    /// Smoothing spline: K − λI, minimising Σ‖qᵢ − f(pᵢ)‖² + λ·E(f). Well-posed for every λ ≥ 0.
    Smoothing(f64),
}

impl From<f64> for Regularisation {
    /// A bare λ is ITK's stiffness, as in [`Tps::fit`].
    fn from(stiffness: f64) -> Self {
        Self::ItkStiffness(stiffness)
    }
}

impl Regularisation {
    /// The value added to the diagonal of K.
    #[must_use]
    pub fn k_diagonal(self) -> f64 {
        match self {
            Self::Interpolate => 0.0,
            Self::ItkStiffness(l) => l,
            Self::Smoothing(l) => -l,
        }
    }

    fn validate(self) -> Result<()> {
        let l = match self {
            Self::Interpolate => 0.0,
            Self::ItkStiffness(l) | Self::Smoothing(l) => l,
        };
        if l.is_finite() && l >= 0.0 {
            Ok(())
        } else {
            Err(SolverError::InvalidParameter(format!("TPS stiffness must be finite and ≥ 0, got {l}")))
        }
    }
}

/// One block of [`LANES`] centres and their weights, structure-of-arrays for the evaluation kernel.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct Block {
    px: [f64; LANES],
    py: [f64; LANES],
    pz: [f64; LANES],
    wx: [f64; LANES],
    wy: [f64; LANES],
    wz: [f64; LANES],
}

/// A thin-plate spline f: `From` → `To`, f(x) = A x + b + Σᵢ wᵢ ‖x − pᵢ‖ (module docs).
#[derive(Clone, Debug)]
pub struct Tps<To: Space, From: Space> {
    /// Number of centres (the last block is padded with zero weights).
    n: usize,
    blocks: Vec<Block>,
    /// A: row r, column c = ∂f_r/∂x_c of the affine part.
    a: Matrix3<f64>,
    b: [f64; 3],
    regularisation: Regularisation,
    /// What [`crate::pairs::validate`] found suspicious in the pairs it was fitted on.
    warnings: Vec<PairWarning>,
    spaces: PhantomData<(To, From)>,
}

/// Fits the forward warp d = `fixed_from_moving` with d(pᵢ) ≈ qᵢ (pᵢ moving, qᵢ fixed).
///
/// `regularisation` is a bare f64 (ITK stiffness, as [`Tps::fit`]) or a [`Regularisation`].
pub fn fit_forward(
    moving: &[Point3<Moving>],
    fixed: &[Point3<Fixed>],
    regularisation: impl Into<Regularisation>,
) -> Result<Tps<Fixed, Moving>> {
    Tps::fit_regularised(moving, fixed, regularisation.into())
}

/// Fits the pull-back u = `moving_from_fixed` directly on the reversed pairs, u(qᵢ) ≈ pᵢ: exact at the
/// landmarks for λ = 0 (not the inverse of [`fit_forward`] elsewhere). Errors index the pairs.
pub fn fit_pullback(
    moving: &[Point3<Moving>],
    fixed: &[Point3<Fixed>],
    regularisation: impl Into<Regularisation>,
) -> Result<Tps<Moving, Fixed>> {
    Tps::fit_regularised(fixed, moving, regularisation.into())
}

/// Points as raw LPS coordinates, in the order of the pairs.
pub(crate) type RawPoints = Vec<[f64; 3]>;

/// What every TPS entry point checks first (the regularisation, the pairs by [`pairs::validate`], the size limit),
/// and the distinct pairs as raw coordinates (a repeated pair counts once).
pub(crate) fn checked_pairs<To: Space, From: Space>(
    src: &[Point3<From>],
    dst: &[Point3<To>],
    regularisation: Regularisation,
) -> Result<(pairs::Checked, RawPoints, RawPoints)> {
    regularisation.validate()?;
    let checked = pairs::validate(&NEEDS, src, dst)?;
    if src.len() > MAX_LANDMARKS {
        return Err(SolverError::InvalidParameter(format!(
            "a TPS takes at most {MAX_LANDMARKS} landmark pairs, got {}",
            src.len()
        )));
    }
    let (p, q) = (checked.distinct_raw(src), checked.distinct_raw(dst));
    Ok((checked, p, q))
}

/// The leave-one-out error of every pair, ‖f₋ᵢ(pᵢ) − qᵢ‖ in mm, where f₋ᵢ is the TPS with `regularisation` fitted
/// on every pair but i: the same numbers as [`crate::diagnostics::leave_one_out`] with refits, from **one** solve
/// instead of N.
///
/// # The closed form
///
/// Write the fit as L c = b with c = [W; Â], b = [Y; 0] (module docs). Let f₋ᵢ leave pair i out and put
/// eᵢ = qᵢ − f₋ᵢ(pᵢ). f₋ᵢ has no centre at pᵢ, so its coefficients c′ (with w′ᵢ = 0) solve the full system for the
/// data b′ = b − δᵢ eᵢᵀ: its rows j ≠ i are f₋ᵢ's own equations, row i says f₋ᵢ(pᵢ) + d·0 = qᵢ − eᵢ, and Pᵀ W′ = 0
/// holds. Hence c′ = c − L⁻¹ δᵢ eᵢᵀ, and w′ᵢ = 0 gives
///
/// ```text
/// eᵢ = wᵢ / (L⁻¹)ᵢᵢ,
/// ```
///
/// the radial-basis form of Rippa (1999) for the augmented system, valid for any diagonal d = ±λ. The kernel block
/// of L⁻¹ is G = Q₂ (Q₂ᵀ K̃ Q₂)⁻¹ Q₂ᵀ (W = G Y), so (L⁻¹)ᵢᵢ = Gᵢᵢ comes from the reduced factor the fit already
/// has: the inverse of its triangular factor and four reflections, O(N³) once, where N refits cost O(N⁴). The
/// factorisation and the inverse are the blocked kernels of [`crate::dense`] on rayon's pool, ~2N³/3 flops in all.
///
/// # Which pairs get `None`
///
/// Those whose refit [`pairs::validate`] would refuse: fewer than 5 distinct pairs, or either side coplanar
/// once the pair is gone (judged on the downdated scatter, O(1) per pair). A pair given twice stays in its own
/// refit through its copy, so its error is the full fit's residual, |d|·‖wᵢ‖ (0 when interpolating).
///
/// # Errors
/// What [`Tps::fit_regularised`] refuses (the full set of pairs must fit).
///
/// R. Rippa, "An algorithm for selecting a good value for the parameter c in radial basis function
/// interpolation", Adv. Comput. Math. 11, 1999.
pub fn leave_one_out<To: Space, From: Space>(
    src: &[Point3<From>],
    dst: &[Point3<To>],
    regularisation: Regularisation,
) -> Result<Vec<Option<f64>>> {
    let (checked, p, q) = checked_pairs(src, dst, regularisation)?;
    let d = regularisation.k_diagonal();
    let (solution, g) = solve(&p, &q, centre_and_scale(&p)?, d, true)?;
    let tps = Tps::<To, From>::from_raw(&p, &solution.w, solution.a, solution.b, regularisation);
    tps.check_solution(&p, &q, &solution)?;
    let g = g.ok_or_else(|| SolverError::Degenerate("the TPS system gave no inverse".into()))?;

    // Which distinct pair each given pair is (a repeated pair maps to its first copy), and how many copies it has.
    let mut distinct_of = vec![usize::MAX; src.len()];
    for (k, &i) in checked.distinct.iter().enumerate() {
        distinct_of[i] = k;
    }
    for w in &checked.warnings {
        if let pairs::PairWarning::Repeated { first, second } = *w {
            distinct_of[second - 1] = distinct_of[first - 1];
        }
    }
    let mut copies = vec![0usize; p.len()];
    for &k in &distinct_of {
        if let Some(c) = copies.get_mut(k) {
            *c += 1;
        }
    }
    let refit_ok_p = pairs::valid_without_each(&NEEDS, &p);
    let refit_ok_q = pairs::valid_without_each(&NEEDS, &q);
    let norm = |w: [f64; 3]| (w[0] * w[0] + w[1] * w[1] + w[2] * w[2]).sqrt();
    let error = |k: usize| -> Option<f64> {
        let wk = norm(solution.w[k]);
        if copies[k] > 1 {
            return Some(d.abs() * wk);
        }
        let e = wk / g[k].abs();
        (p.len() > NEEDS.min_pairs && refit_ok_p[k] && refit_ok_q[k] && g[k] != 0.0 && e.is_finite()).then_some(e)
    };
    Ok(distinct_of.iter().map(|&k| if k < p.len() { error(k) } else { None }).collect())
}

impl<To: Space, From: Space> Tps<To, From> {
    /// Fits f(`src[i]`) ≈ `dst[i]` with ITK's stiffness convention (K + λI; λ = 0 interpolates).
    pub fn fit(src: &[Point3<From>], dst: &[Point3<To>], stiffness: f64) -> Result<Self> {
        Self::fit_regularised(src, dst, Regularisation::ItkStiffness(stiffness))
    }

    /// Fits the smoothing spline (K − λI), well-posed for every λ ≥ 0.
    pub fn fit_smoothing(src: &[Point3<From>], dst: &[Point3<To>], lambda: f64) -> Result<Self> {
        Self::fit_regularised(src, dst, Regularisation::Smoothing(lambda))
    }

    /// Fits f(`src[i]`) ≈ `dst[i]` with the given regularisation. From [`PARALLEL_MIN_LANDMARKS`] pairs on, the
    /// O(N³) steps run on rayon's global pool (module docs, "Solve").
    pub fn fit_regularised(src: &[Point3<From>], dst: &[Point3<To>], regularisation: Regularisation) -> Result<Self> {
        let (checked, p, q) = checked_pairs(src, dst, regularisation)?;
        let (centre, scale) = centre_and_scale(&p)?;
        let (solution, _) = solve(&p, &q, (centre, scale), regularisation.k_diagonal(), false)?;
        let mut tps = Self::from_raw(&p, &solution.w, solution.a, solution.b, regularisation);
        tps.check_solution(&p, &q, &solution)?;
        tps.warnings = checked.warnings;
        Ok(tps)
    }

    /// Builds a TPS from its parts, e.g. for synthetic warps: f(x) = A x + b + Σᵢ `weights[i]`·‖x − `centres[i]`‖.
    ///
    /// Checks lengths and finiteness only. The map is smooth for any weights; it is the TPS that
    /// [`Tps::fit`] recovers from samples at its centres only when Σᵢ wᵢ = 0 and Σᵢ wᵢ pᵢᵀ = 0.
    pub fn from_parts(centres: &[Point3<From>], weights: &[[f64; 3]], a: Matrix3<f64>, b: [f64; 3]) -> Result<Self> {
        if centres.len() != weights.len() {
            return Err(SolverError::InvalidParameter(format!(
                "{} TPS centres but {} weights",
                centres.len(),
                weights.len()
            )));
        }
        for (index, (c, w)) in centres.iter().zip(weights).enumerate() {
            if !c.is_finite() || !w.iter().all(|v| v.is_finite()) {
                return Err(SolverError::NonFinite { pair: index + 1 });
            }
        }
        if !a.iter().chain(&b).all(|v| v.is_finite()) {
            return Err(SolverError::InvalidParameter("TPS affine part is not finite".into()));
        }
        let p: Vec<[f64; 3]> = centres.iter().map(Point3::coords).collect();
        Ok(Self::from_raw(&p, weights, a, b, Regularisation::Interpolate))
    }

    pub(crate) fn from_raw(
        p: &[[f64; 3]],
        w: &[[f64; 3]],
        a: Matrix3<f64>,
        b: [f64; 3],
        regularisation: Regularisation,
    ) -> Self {
        let mut blocks = vec![Block::default(); p.len().div_ceil(LANES)];
        for (i, (pi, wi)) in p.iter().zip(w).enumerate() {
            let (blk, l) = (&mut blocks[i / LANES], i % LANES);
            (blk.px[l], blk.py[l], blk.pz[l]) = (pi[0], pi[1], pi[2]);
            (blk.wx[l], blk.wy[l], blk.wz[l]) = (wi[0], wi[1], wi[2]);
        }
        // Padding lanes keep zero weights; centre them on a real centre so r stays small and finite.
        if let (Some(first), Some(last)) = (p.first(), blocks.last_mut()) {
            for l in (p.len() - 1) % LANES + 1..LANES {
                (last.px[l], last.py[l], last.pz[l]) = (first[0], first[1], first[2]);
            }
        }
        Self { n: p.len(), blocks, a, b, regularisation, warnings: Vec::new(), spaces: PhantomData }
    }

    /// What [`crate::pairs::validate`] found suspicious in the pairs (repeated pairs, a nearly flat side), pairs
    /// numbered from 1 as given to the fit; empty for [`Tps::from_parts`].
    #[must_use]
    pub fn warnings(&self) -> &[PairWarning] {
        &self.warnings
    }

    /// Number of centres pᵢ (after merging duplicated pairs).
    #[must_use]
    pub fn num_centres(&self) -> usize {
        self.n
    }

    /// The centres pᵢ, in `From`.
    #[must_use]
    pub fn centres(&self) -> Vec<Point3<From>> {
        (0..self.n)
            .map(|i| {
                let (blk, l) = (&self.blocks[i / LANES], i % LANES);
                Point3::new(blk.px[l], blk.py[l], blk.pz[l])
            })
            .collect()
    }

    /// The bending weights wᵢ (dimensionless: mm of `To` per mm of distance), one per centre.
    #[must_use]
    pub fn weights(&self) -> Vec<[f64; 3]> {
        (0..self.n)
            .map(|i| {
                let (blk, l) = (&self.blocks[i / LANES], i % LANES);
                [blk.wx[l], blk.wy[l], blk.wz[l]]
            })
            .collect()
    }

    /// The linear part A of the affine term (row r, column c).
    #[must_use]
    pub fn linear(&self) -> Matrix3<f64> {
        self.a
    }

    /// The translation b of the affine term, in mm.
    #[must_use]
    pub fn translation(&self) -> [f64; 3] {
        self.b
    }

    /// The affine term x ↦ A x + b as a typed transform.
    #[must_use]
    pub fn affine(&self) -> Transform<To, From> {
        Transform::from_linear_translation(self.a, self.b)
    }

    /// The regularisation it was fitted with ([`Regularisation::Interpolate`] for [`Tps::from_parts`]).
    #[must_use]
    pub fn regularisation(&self) -> Regularisation {
        self.regularisation
    }

    /// E = −Σᵢⱼ wᵢ·wⱼ ‖pᵢ − pⱼ‖ (= −tr WᵀKW), proportional to the thin-plate bending energy; ≥ 0 when
    /// Pᵀ W = 0, zero for an affine map. O(N²).
    #[must_use]
    pub fn bending_energy(&self) -> f64 {
        let (p, w) = (self.centres(), self.weights());
        let mut e = 0.0;
        for (pi, wi) in p.iter().zip(&w) {
            for (pj, wj) in p.iter().zip(&w) {
                e -= pi.distance(pj) * (wi[0] * wj[0] + wi[1] * wj[1] + wi[2] * wj[2]);
            }
        }
        e
    }

    /// Evaluates f at one point (mm in `From` → mm in `To`). No allocation.
    #[inline]
    #[must_use]
    pub fn eval_point(&self, x: [f64; 3]) -> [f64; 3] {
        eval_blocks(&self.blocks, &self.a, &self.b, x)
    }

    /// The kernel: `out[k]` = f(`points[k]`) (mm). Never allocates or spawns threads; split `points` and
    /// `out` into chunks to parallelise.
    ///
    /// # Panics
    /// When `points` and `out` differ in length.
    pub fn eval_into(&self, points: &[[f64; 3]], out: &mut [[f64; 3]]) {
        assert_eq!(points.len(), out.len(), "eval_into: points and out differ in length");
        for (x, y) in points.iter().zip(out.iter_mut()) {
            *y = self.eval_point(*x);
        }
    }

    /// Checks the fitted system: finite coefficients, and a small backward error of f(pᵢ) + λwᵢ = qᵢ.
    pub(crate) fn check_solution(&self, p: &[[f64; 3]], q: &[[f64; 3]], s: &Solution) -> Result<()> {
        let coeffs_finite = s.w.iter().flatten().chain(self.a.iter()).chain(&self.b).all(|v| v.is_finite());
        if !coeffs_finite {
            return Err(SolverError::Degenerate("the TPS system gave non-finite coefficients".into()));
        }
        let d = self.regularisation.k_diagonal();
        let max_abs = |v: &[[f64; 3]]| v.iter().flatten().fold(0.0_f64, |m, x| m.max(x.abs()));
        let (max_w, max_q, diam) = (max_abs(&s.w), max_abs(q), s.diameter);
        let scale = 1.0 + max_q + (p.len() as f64 * diam + d.abs()) * max_w;
        let mut worst = 0.0_f64;
        for ((pi, qi), wi) in p.iter().zip(q).zip(&s.w) {
            let f = self.eval_point(*pi);
            for c in 0..3 {
                worst = worst.max((f[c] + d * wi[c] - qi[c]).abs());
            }
        }
        if worst.is_finite() && worst <= RESIDUAL_RTOL * scale {
            Ok(())
        } else {
            Err(SolverError::Degenerate(format!(
                "the TPS system is too ill-conditioned: residual {worst:.3e} mm exceeds {:.3e} mm",
                RESIDUAL_RTOL * scale
            )))
        }
    }
}

impl<Mid: Space, From: Space> Tps<Mid, From> {
    /// The spline followed by the affine map `then`: then ∘ f. A TPS again, with the same centres: then(f(x)) =
    /// L A x + (L b + t) + Σᵢ (L wᵢ) ‖x − pᵢ‖ for then(y) = L y + t. A starting transform composed after the landmark
    /// warp (issue 18) keeps the spline's form, so the GPU, the exporters and the ITK transform file take it as any TPS.
    #[must_use]
    pub fn followed_by<To: Space>(&self, then: &crate::linear::AffineWarp<To, Mid>) -> Tps<To, From> {
        let l = then.linear();
        let t = then.translation();
        let b = l * nalgebra::Vector3::from(self.b);
        let blocks = self
            .blocks
            .iter()
            .map(|blk| {
                let mut out = *blk;
                for lane in 0..LANES {
                    let w = l * nalgebra::Vector3::new(blk.wx[lane], blk.wy[lane], blk.wz[lane]);
                    out.wx[lane] = w[0];
                    out.wy[lane] = w[1];
                    out.wz[lane] = w[2];
                }
                out
            })
            .collect();
        Tps {
            n: self.n,
            blocks,
            a: l * self.a,
            b: [b[0] + t[0], b[1] + t[1], b[2] + t[2]],
            regularisation: self.regularisation,
            warnings: self.warnings.clone(),
            spaces: PhantomData,
        }
    }
}

impl<To: Space, From: Space> Warp<To, From> for Tps<To, From> {
    fn apply_raw(&self, x: [f64; 3]) -> [f64; 3] {
        self.eval_point(x)
    }

    /// Analytic: ∂f/∂x = A + Σᵢ wᵢ (x − pᵢ)ᵀ / ‖x − pᵢ‖. At a centre (r = 0) U = r is not differentiable;
    /// its term is taken as 0, the symmetric limit that central differences also give.
    fn jacobian_raw(&self, x: [f64; 3]) -> Matrix3<f64> {
        jacobian_blocks(&self.blocks, &self.a, x)
    }
}

// The kernels below are not generic over the spaces, so they are compiled once, here, with this crate's
// optimisation: a caller built without it (a debug build of the app or its tests) still runs them optimised.

/// f(x) = A x + b + Σᵢ wᵢ ‖x − pᵢ‖ over the centres in `blocks`.
#[allow(clippy::needless_range_loop)] // one lane index over six arrays: the form LLVM vectorises
fn eval_blocks(blocks: &[Block], a: &Matrix3<f64>, b: &[f64; 3], x: [f64; 3]) -> [f64; 3] {
    let mut s = [[0.0; LANES]; 3];
    for blk in blocks {
        for l in 0..LANES {
            let (dx, dy, dz) = (x[0] - blk.px[l], x[1] - blk.py[l], x[2] - blk.pz[l]);
            let r = (dx * dx + dy * dy + dz * dz).sqrt();
            s[0][l] += r * blk.wx[l];
            s[1][l] += r * blk.wy[l];
            s[2][l] += r * blk.wz[l];
        }
    }
    let sum = |s: &[f64; LANES]| s.iter().sum::<f64>();
    std::array::from_fn(|r| a[(r, 0)] * x[0] + a[(r, 1)] * x[1] + a[(r, 2)] * x[2] + b[r] + sum(&s[r]))
}

/// ∂f/∂x = A + Σᵢ wᵢ (x − pᵢ)ᵀ / ‖x − pᵢ‖ over the centres in `blocks` (0 for a centre at x).
fn jacobian_blocks(blocks: &[Block], a: &Matrix3<f64>, x: [f64; 3]) -> Matrix3<f64> {
    let mut j = *a;
    for blk in blocks {
        for l in 0..LANES {
            let d = [x[0] - blk.px[l], x[1] - blk.py[l], x[2] - blk.pz[l]];
            let r = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            if r > 0.0 {
                let w = [blk.wx[l], blk.wy[l], blk.wz[l]];
                for (row, wr) in w.iter().enumerate() {
                    for (col, dc) in d.iter().enumerate() {
                        j[(row, col)] += wr * dc / r;
                    }
                }
            }
        }
    }
    j
}

/// Smallest N whose solve runs on rayon's pool. Below it the O(N³) steps take a few milliseconds on one core, and
/// handing each block to the pool can cost more than it saves (2-core VM at load average 4–6: the N = 300 fit took
/// 3.2 ms on the calling thread, 4.1 ms on the pool).
pub const PARALLEL_MIN_LANDMARKS: usize = 400;

/// How a solve of N centres runs its blocked steps ([`PARALLEL_MIN_LANDMARKS`]).
pub(crate) fn solve_parallelism(n: usize) -> Parallelism {
    if n >= PARALLEL_MIN_LANDMARKS { Parallelism::Rayon } else { Parallelism::Sequential }
}

/// The centroid and RMS radius of `p`, which scale the affine block. [`pairs::validate`] has refused coincident,
/// collinear and coplanar sets, so the radius is positive; it is checked anyway, as the solve divides by it.
pub(crate) fn centre_and_scale(p: &[[f64; 3]]) -> Result<([f64; 3], f64)> {
    let n = p.len() as f64;
    let mut c = [0.0; 3];
    for pi in p {
        for k in 0..3 {
            c[k] += pi[k] / n;
        }
    }
    let mean_sq = p.iter().map(|pi| (0..3).map(|k| (pi[k] - c[k]).powi(2)).sum::<f64>()).sum::<f64>() / n;
    let scale = mean_sq.sqrt();
    if scale.is_finite() && scale > 0.0 {
        Ok((c, scale))
    } else {
        Err(SolverError::Degenerate(format!("the {} landmarks have no spread (RMS radius {scale:e} mm)", p.len())))
    }
}

/// The solved coefficients: weights per centre and the affine part in raw mm.
pub(crate) struct Solution {
    pub(crate) w: Vec<[f64; 3]>,
    pub(crate) a: Matrix3<f64>,
    pub(crate) b: [f64; 3],
    /// Largest source extent (bounding-box diagonal), mm; scales the residual check.
    pub(crate) diameter: f64,
}

/// A Householder reflector H = I − τ v vᵀ (v zero above its pivot).
pub(crate) struct Reflector {
    v: DVector<f64>,
    tau: f64,
}

impl Reflector {
    /// Applies H from the left to every column of `m`.
    pub(crate) fn apply_left(&self, m: &mut DMatrix<f64>) {
        let vt_m = self.v.transpose() * &*m;
        m.ger(-self.tau, &self.v, &vt_m.transpose(), 1.0);
    }

    /// S ← H S H for symmetric S, as the rank-2 update S − v zᵀ − z vᵀ with z = τ S v − (τ² vᵀSv / 2) v.
    pub(crate) fn apply_both(&self, s: &mut DMatrix<f64>) {
        let u = &*s * &self.v;
        let gamma = self.v.dot(&u);
        let z = u * self.tau - &self.v * (0.5 * self.tau * self.tau * gamma);
        s.ger(-1.0, &self.v, &z, 1.0);
        s.ger(-1.0, &z, &self.v, 1.0);
    }
}

/// S ← Qᵀ S Q for symmetric n×n S and Q = H₁H₂…Hₖ, in two passes over S where k calls of [`Reflector::apply_both`]
/// take 5k. With the compact WY form Q = I − V T Vᵀ (V = [v₁ … vₖ], T upper triangular: Schreiber & Van Loan 1989,
/// LAPACK `dlarft`) and W = S V,
///
/// ```text
/// Qᵀ S Q = S − V Zᵀ − Z Vᵀ,     Z = W T − ½ V (Tᵀ Vᵀ W T),
/// ```
///
/// one product S V and one rank-2k update, both in column blocks.
pub(crate) fn apply_qt_s_q(s: &mut DMatrix<f64>, reflectors: &[Reflector], parallelism: Parallelism) {
    let (n, k) = (s.nrows(), reflectors.len());
    let v = DMatrix::from_fn(n, k, |i, j| reflectors[j].v[i]);
    let mut t = DMatrix::<f64>::zeros(k, k);
    for (i, h) in reflectors.iter().enumerate() {
        let column = t.view((0, 0), (i, i)) * v.columns(0, i).tr_mul(&h.v) * -h.tau;
        t.view_mut((0, i), (i, 1)).copy_from(&column);
        t[(i, i)] = h.tau;
    }
    // Row r of W = S V is Vᵀ times column r of S (S is symmetric).
    let mut w_t = DMatrix::<f64>::zeros(k, n);
    let s_view = &*s;
    let block = dense::BLOCK;
    dense::for_each_chunk(w_t.as_mut_slice(), k * block, parallelism, |(c, out)| {
        let columns = s_view.columns(c * block, out.len() / k.max(1));
        out.copy_from_slice(v.tr_mul(&columns).as_slice());
    });
    let w = w_t.transpose();
    let z = &w * &t - &v * ((t.transpose() * v.tr_mul(&w) * &t) * 0.5);
    let mut left = DMatrix::<f64>::zeros(n, 2 * k);
    left.columns_mut(0, k).copy_from(&v);
    left.columns_mut(k, k).copy_from(&z);
    let mut right_t = DMatrix::<f64>::zeros(2 * k, n);
    right_t.rows_mut(0, k).copy_from(&z.transpose());
    right_t.rows_mut(k, k).copy_from(&v.transpose());
    dense::for_each_chunk(s.as_mut_slice(), block * n.max(1), parallelism, |(c, columns)| {
        let width = columns.len() / n;
        let mut target = DMatrixViewMut::from_slice(columns, n, width);
        target.gemm(-1.0, &left, &right_t.columns(c * block, width), 1.0);
    });
}

/// The block of `a` from row and column `start` on, copied column by column (a strided view's `clone_owned` goes
/// element by element).
pub(crate) fn trailing_block(a: &DMatrix<f64>, start: usize) -> DMatrix<f64> {
    let (n, m) = (a.nrows(), a.nrows() - start);
    let mut data = Vec::with_capacity(m * m);
    for column in a.as_slice().chunks_exact(n.max(1)).skip(start) {
        data.extend_from_slice(&column[start..]);
    }
    DMatrix::from_vec(m, m, data)
}

/// K̃ = K + dI for the centres `p` (Kᵢⱼ = ‖pᵢ − pⱼ‖), in blocks of columns. ‖pᵢ − pⱼ‖ and ‖pⱼ − pᵢ‖ round alike, so
/// K̃ is exactly symmetric.
pub(crate) fn kernel_matrix(p: &[[f64; 3]], k_diagonal: f64, parallelism: Parallelism) -> DMatrix<f64> {
    let n = p.len();
    // One coordinate per array, so that the loop over a column vectorises.
    let [xs, ys, zs]: [Vec<f64>; 3] = std::array::from_fn(|c| p.iter().map(|pi| pi[c]).collect());
    let mut k = DMatrix::<f64>::zeros(n, n);
    let block = dense::BLOCK;
    dense::for_each_chunk(k.as_mut_slice(), block * n.max(1), parallelism, |(c, columns)| {
        for (j, column) in (c * block..).zip(columns.chunks_exact_mut(n)) {
            let pj = p[j];
            for (((kij, x), y), z) in column.iter_mut().zip(&xs).zip(&ys).zip(&zs) {
                *kij = ((x - pj[0]).powi(2) + (y - pj[1]).powi(2) + (z - pj[2]).powi(2)).sqrt();
            }
            column[j] = k_diagonal;
        }
    });
    k
}

/// Householder QR of the N×4 matrix P̂ (in place): returns the 4 reflectors and R (4×4, upper).
pub(crate) fn householder_qr(p_hat: &mut DMatrix<f64>) -> Result<(Vec<Reflector>, nalgebra::Matrix4<f64>)> {
    let n = p_hat.nrows();
    let mut reflectors = Vec::with_capacity(4);
    for k in 0..4 {
        let x = p_hat.view((k, k), (n - k, 1)).clone_owned();
        let norm = x.norm();
        if norm.is_nan() || norm <= 0.0 {
            return Err(SolverError::Degenerate("the TPS affine block P is rank-deficient".into()));
        }
        let alpha = if x[0] >= 0.0 { -norm } else { norm };
        let mut v = DVector::zeros(n);
        v.rows_mut(k, n - k).copy_from(&x.column(0));
        v[k] -= alpha;
        let tau = 2.0 / v.norm_squared();
        let h = Reflector { v, tau };
        h.apply_left(p_hat);
        reflectors.push(h);
    }
    let r = p_hat.fixed_view::<4, 4>(0, 0).upper_triangle();
    Ok((reflectors, r))
}

/// The length of the diagonal of the axis-aligned box around `p`.
pub(crate) fn bounding_diagonal(p: &[[f64; 3]]) -> f64 {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for pi in p {
        for k in 0..3 {
            lo[k] = lo[k].min(pi[k]);
            hi[k] = hi[k].max(pi[k]);
        }
    }
    ((hi[0] - lo[0]).powi(2) + (hi[1] - lo[1]).powi(2) + (hi[2] - lo[2]).powi(2)).sqrt()
}

/// Solves L [W; Â] = [Y; 0] by eliminating the affine block (module docs, "Solve"). With `kernel_diagonal`, also
/// returns the diagonal of the kernel block of L⁻¹, G = Q₂ M₂₂⁻¹ Q₂ᵀ (see [`leave_one_out`]).
fn solve(
    p: &[[f64; 3]],
    q: &[[f64; 3]],
    (c, s): ([f64; 3], f64),
    k_diagonal: f64,
    kernel_diagonal: bool,
) -> Result<(Solution, Option<Vec<f64>>)> {
    let n = p.len();
    let diameter = bounding_diagonal(p);

    // K̃ = K + dI (d = ±λ), symmetric.
    let parallelism = solve_parallelism(n);
    let mut k_mat = kernel_matrix(p, k_diagonal, parallelism);
    let mut p_hat = DMatrix::<f64>::from_fn(n, 4, |i, k| if k < 3 { (p[i][k] - c[k]) / s } else { 1.0 });
    let mut y = DMatrix::<f64>::from_fn(n, 3, |i, k| q[i][k]);

    let (reflectors, r) = householder_qr(&mut p_hat)?;
    apply_qt_s_q(&mut k_mat, &reflectors, parallelism);
    for h in &reflectors {
        h.apply_left(&mut y);
    }
    // Now k_mat = Qᵀ K̃ Q and y = Qᵀ Y; W = Q [0; Ω] with M₂₂ Ω = y₂.
    let m = n - 4;
    let (omega, factor) = if m == 0 {
        (DMatrix::<f64>::zeros(0, 3), None)
    } else {
        let (omega, factor) = solve_symmetric(trailing_block(&k_mat, 4), &y.rows(4, m).clone_owned(), k_diagonal)?;
        (omega, Some(factor))
    };
    // R Â = y₁ − M₁₂ Ω.
    let rhs1 = y.rows(0, 4) - k_mat.view((0, 4), (4, m)) * &omega;
    // diag G, G = Q [0 0; 0 M₂₂⁻¹] Qᵀ: from the inverse of a Cholesky factor, or (LU, and N = 4) by forming G in K̃'s
    // storage (no longer needed) with the reflectors applied on both sides in reverse.
    let g_diagonal = match (kernel_diagonal, factor) {
        (false, _) => None,
        (true, Some(Factor::NegCholesky(ch))) => Some(kernel_inverse_diagonal(ch.l_dirty(), &reflectors, -1.0)?),
        (true, Some(Factor::Cholesky(ch))) => Some(kernel_inverse_diagonal(ch.l_dirty(), &reflectors, 1.0)?),
        (true, factor) => {
            k_mat.fill(0.0);
            if let Some(factor) = factor {
                let mut block = k_mat.view_mut((4, 4), (m, m));
                block.fill_with_identity();
                if !factor.solve_in_place(&mut block) {
                    return Err(SolverError::Degenerate("the TPS system could not be inverted".into()));
                }
            }
            for h in reflectors.iter().rev() {
                h.apply_both(&mut k_mat);
            }
            Some(k_mat.diagonal().iter().copied().collect())
        }
    };
    let r_inv = r.try_inverse().ok_or_else(|| SolverError::Degenerate("the TPS affine block P is singular".into()))?;
    let a_hat: Matrix4x3<f64> = r_inv * Matrix4x3::from_fn(|i, k| rhs1[(i, k)]);

    let mut w = DMatrix::<f64>::zeros(n, 3);
    w.rows_mut(4, m).copy_from(&omega);
    for h in reflectors.iter().rev() {
        h.apply_left(&mut w);
    }

    // Undo the centring and scaling: f(x) = Σ Â_k((x − c)/s) + Â₃ = A x + b.
    let a = Matrix3::from_fn(|row, col| a_hat[(col, row)] / s);
    let b = std::array::from_fn(|row| a_hat[(3, row)] - (0..3).map(|col| a[(row, col)] * c[col]).sum::<f64>());
    let w = (0..n).map(|i| [w[(i, 0)], w[(i, 1)], w[(i, 2)]]).collect();
    Ok((Solution { w, a, b, diameter }, g_diagonal))
}

/// The diagonal of G = Q₂ M⁻¹ Q₂ᵀ ([`leave_one_out`]) from the Cholesky factor of M = `sign`·L Lᵀ and the
/// reflectors of Q = H₁H₂H₃H₄, in O(N³/3) after the factorisation.
///
/// With X = L⁻¹ ([`dense::lower_triangular_inverse`]), M⁻¹ = `sign`·XᵀX, so Gᵢᵢ = `sign`·‖X Q₂ᵀ eᵢ‖². Since
/// Q₂ᵀ = [0 I] Qᵀ, X Q₂ᵀ = F H₄H₃H₂H₁ with F = [0 X] (m × N). Applying the reflectors one by one from the right keeps
/// the product in the form F − Σₖ aₖ vₖᵀ: with R = F − Σₖ aₖ vₖᵀ, R H = R − τ (R v) vᵀ and R v = F v − Σₖ aₖ (vₖ·v),
/// where F v = X v₄.. (the four products in one pass over X). Column i of it is F eᵢ − Σₖ aₖ vₖ,ᵢ, where F eᵢ is
/// column i − 4 of X (0 for i < 4): a second pass over X gives all N squared norms.
fn kernel_inverse_diagonal(l: &DMatrix<f64>, reflectors: &[Reflector], sign: f64) -> Result<Vec<f64>> {
    let m = l.nrows();
    let n = m + 4;
    let parallelism = solve_parallelism(n);
    let x = dense::lower_triangular_inverse(l, dense::BLOCK, parallelism)
        .ok_or_else(|| SolverError::Degenerate("the TPS system could not be inverted".into()))?;
    let [h1, h2, h3, h4] = reflectors else {
        unreachable!("P̂ has 4 columns, so its QR has 4 reflectors");
    };
    // In the order they apply from the right: H₄ first.
    let order = [h4, h3, h2, h1];
    // F vₖ = X (vₖ)₄.. for the four at once, in one pass over the lower triangle of X.
    let mut a_rows = vec![[0.0; 4]; m];
    for (c, column) in x.as_slice().chunks_exact(m.max(1)).enumerate() {
        let v_c: [f64; 4] = std::array::from_fn(|k| order[k].v[4 + c]);
        for (a_r, x_rc) in a_rows[c..].iter_mut().zip(&column[c..]) {
            for k in 0..4 {
                a_r[k] += x_rc * v_c[k];
            }
        }
    }
    // aₖ = τₖ (F vₖ − Σ_{j<k} aⱼ (vⱼ·vₖ)), row by row.
    let dots: [[f64; 4]; 4] = std::array::from_fn(|j| std::array::from_fn(|k| order[j].v.dot(&order[k].v)));
    for a_r in &mut a_rows {
        for k in 0..4 {
            let earlier: f64 = (0..k).map(|j| a_r[j] * dots[j][k]).sum();
            a_r[k] = order[k].tau * (a_r[k] - earlier);
        }
    }
    let zeros = vec![0.0; m];
    let squared_norm = |i: usize| {
        let c: [f64; 4] = std::array::from_fn(|k| order[k].v[i]);
        let f = if i >= 4 { &x.as_slice()[(i - 4) * m..(i - 3) * m] } else { &zeros[..] };
        let mut sum = 0.0;
        for (f_r, a_r) in f.iter().zip(&a_rows) {
            let t = f_r - (a_r[0] * c[0] + a_r[1] * c[1] + a_r[2] * c[2] + a_r[3] * c[3]);
            sum += t * t;
        }
        sign * sum
    };
    Ok(match parallelism {
        Parallelism::Sequential => (0..n).map(squared_norm).collect(),
        Parallelism::Rayon => (0..n).into_par_iter().with_min_len(dense::BLOCK).map(squared_norm).collect(),
    })
}

/// Solves M Ω = Y for the symmetric reduced matrix M = Q₂ᵀ(K + dI)Q₂.
///
/// M is negative definite for d ≤ μ_min (always for d ≤ 0): Cholesky of −M. ITK stiffness d > 0 may make
/// it positive definite (Cholesky of M) or indefinite (LU with partial pivoting). Each factor is checked by
/// its pivot ratio ([`PIVOT_RTOL`]) and by an estimate of 1/cond(M) from one solve with a fixed ±1 probe
/// (‖v‖ / (‖M‖_F ‖M⁻¹v‖) ≥ 1/(√n·cond₂), [`RCOND_MIN`]).
pub(crate) fn solve_symmetric(m: DMatrix<f64>, y: &DMatrix<f64>, k_diagonal: f64) -> Result<(DMatrix<f64>, Factor)> {
    let pivot_ratio = |diag: &DVector<f64>, power: i32| {
        let (lo, hi) = diag.iter().fold((f64::INFINITY, 0.0_f64), |(lo, hi), d| (lo.min(d.abs()), hi.max(d.abs())));
        if hi > 0.0 { (lo / hi).powi(power) } else { 0.0 }
    };
    let singular = |what: &str, value: f64| {
        let msg = if k_diagonal > 0.0 {
            format!(
                "the TPS system is singular at ITK stiffness {k_diagonal} ({what} {value:.1e}): with U(r) = r, \
                 K + λI loses rank when λ equals an eigenvalue of the reduced kernel; use another λ or \
                 Regularisation::Smoothing"
            )
        } else {
            format!("the TPS system is singular ({what} {value:.1e}): landmarks nearly coincide")
        };
        SolverError::Degenerate(msg)
    };
    let norm_m = m.norm();
    // The pivots of LDLᵀ are L_ii², so the ratio of squared diagonals is comparable to an LU pivot ratio.
    let cholesky = |mut a: DMatrix<f64>| {
        let parallelism = solve_parallelism(a.nrows() + 4);
        dense::cholesky_in_place(&mut a, dense::BLOCK, parallelism).ok().map(|()| nalgebra::Cholesky::pack_dirty(a))
    };
    let mut neg_m = m.clone();
    neg_m.neg_mut();
    let (factor, ratio) = if let Some(ch) = cholesky(neg_m) {
        let r = pivot_ratio(&ch.l_dirty().diagonal(), 2);
        (Factor::NegCholesky(ch), r)
    } else if k_diagonal <= 0.0 {
        return Err(singular("Cholesky failed, pivot ratio", 0.0));
    } else if let Some(ch) = cholesky(m.clone()) {
        let r = pivot_ratio(&ch.l_dirty().diagonal(), 2);
        (Factor::Cholesky(ch), r)
    } else {
        let lu = m.lu();
        let r = pivot_ratio(&lu.u().diagonal(), 1);
        (Factor::Lu(lu), r)
    };
    if ratio.is_nan() || ratio < PIVOT_RTOL {
        return Err(singular("pivot ratio", ratio));
    }
    let solve = |rhs: &DMatrix<f64>| {
        let mut x = rhs.clone();
        factor.solve_in_place(&mut x).then_some(x)
    };
    let probe = DMatrix::from_fn(y.nrows(), 1, |i, _| {
        let h = (i as u64 + 1).wrapping_mul(0x9E37_79B9_7F4A_7C15);
        if h >> 63 == 0 { 1.0 } else { -1.0 }
    });
    let z = solve(&probe).ok_or_else(|| singular("pivot ratio", 0.0))?;
    let rcond = probe.norm() / (norm_m * z.norm());
    if rcond.is_nan() || rcond < RCOND_MIN {
        return Err(singular("estimated 1/cond", rcond));
    }
    let omega = solve(y).ok_or_else(|| singular("pivot ratio", 0.0))?;
    Ok((omega, factor))
}

/// A factorisation of the reduced matrix M = Q₂ᵀ(K + dI)Q₂ ([`solve_symmetric`]).
pub(crate) enum Factor {
    /// −M = L Lᵀ.
    NegCholesky(nalgebra::Cholesky<f64, nalgebra::Dyn>),
    Cholesky(nalgebra::Cholesky<f64, nalgebra::Dyn>),
    Lu(nalgebra::LU<f64, nalgebra::Dyn, nalgebra::Dyn>),
}

impl Factor {
    /// X ← M⁻¹ X; false when the LU factor is singular.
    pub(crate) fn solve_in_place<S>(&self, x: &mut nalgebra::Matrix<f64, nalgebra::Dyn, nalgebra::Dyn, S>) -> bool
    where
        S: nalgebra::StorageMut<f64, nalgebra::Dyn, nalgebra::Dyn>,
    {
        match self {
            Self::NegCholesky(ch) => {
                ch.solve_mut(x);
                x.neg_mut();
                true
            }
            Self::Cholesky(ch) => {
                ch.solve_mut(x);
                true
            }
            Self::Lu(lu) => lu.solve_mut(x),
        }
    }
}

#[cfg(test)]
mod tests {
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    use super::*;

    fn random_points(n: usize, seed: u64) -> Vec<[f64; 3]> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        (0..n).map(|_| std::array::from_fn(|_| rng.random_range(-100.0..100.0))).collect()
    }

    /// The one-pass WY reduction against the reflectors applied one at a time (the slow path it replaces), and the
    /// kernel matrix against its definition; both parallelisms give the same bits. N = 150 spans three column blocks.
    #[test]
    fn wy_reduction_equals_the_reflections_one_by_one() {
        let p = random_points(150, 3);
        let (c, s) = centre_and_scale(&p).expect("spread");
        let mut p_hat = DMatrix::<f64>::from_fn(p.len(), 4, |i, k| if k < 3 { (p[i][k] - c[k]) / s } else { 1.0 });
        let (reflectors, _) = householder_qr(&mut p_hat).expect("rank 4");
        let k_mat = kernel_matrix(&p, -2.5, Parallelism::Sequential);
        assert_eq!(k_mat, kernel_matrix(&p, -2.5, Parallelism::Rayon));
        for (i, j) in [(0, 0), (3, 7), (149, 12), (77, 77)] {
            let expected = if i == j { -2.5 } else { bounding_diagonal(&[p[i], p[j]]) };
            assert!((k_mat[(i, j)] - expected).abs() <= 1e-12 * expected.abs().max(1.0), "K[{i}, {j}]");
        }
        let mut one_by_one = k_mat.clone();
        for h in &reflectors {
            h.apply_both(&mut one_by_one);
        }
        let (mut wy, mut wy_rayon) = (k_mat.clone(), k_mat.clone());
        apply_qt_s_q(&mut wy, &reflectors, Parallelism::Sequential);
        apply_qt_s_q(&mut wy_rayon, &reflectors, Parallelism::Rayon);
        assert_eq!(wy, wy_rayon);
        let err = (&wy - &one_by_one).norm() / k_mat.norm();
        assert!(err <= 64.0 * f64::EPSILON * p.len() as f64, "WY and one-by-one differ by {err:e} (relative)");
    }
}
