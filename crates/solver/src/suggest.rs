//! Suggested targets: where a source point p of the moving volume most likely lies in the fixed volume, found from
//! the current warp's prediction q₀ = d(p) and a local multi-modal similarity search around it.
//!
//! The similarity is the local normalised gradient field (NGF) measure of Haber & Modersitzki (2006, "Intensity
//! gradient based registration and fusion of multi-modal images", Methods Inf. Med. 46(3)): two images match where
//! their edges are parallel, whatever their intensities. On a patch of K offsets oₖ (a ball of radius
//! `patch_radius_mm` sampled every `patch_step_mm`) and with A = ∇d(p), the current warp's local linear part,
//!
//! S(q) = (1/K) Σₖ (∇mₖ · Aᵀ∇fₖ)² / ((|∇mₖ|² + ε_m²)(|Aᵀ∇fₖ|² + ε_f²)),  ∇mₖ = ∇m(p + oₖ),  ∇fₖ = ∇f(q + A oₖ),
//!
//! in [0, 1): the mean squared cosine between the moving gradients and the fixed gradients pulled back by the
//! chain rule (if f(d(x)) = m(x) near p, then ∇m(x) = Aᵀ∇f(d(x))). Squaring makes a contrast inversion match as well
//! as the same contrast; ε (Haber & Modersitzki's edge parameter) is `epsilon_fraction` times the mean gradient
//! magnitude, over the moving patch for ε_m and over the fixed search region for ε_f, so that edges weaker than it
//! (noise) count little. Both images are smoothed by a Gaussian of `smoothing_sigma_mm` on a local block before
//! their gradients are taken by central differences, and the gradient field is interpolated trilinearly, so that S
//! is continuous in q. The patch lattice is turned ([`PATCH_LATTICE_ROTATION_RAD`]) so that its samples do not all
//! cross voxel faces together. A fixed sample outside the fixed image counts as 0; a candidate with fewer than
//! [`MIN_VALID_FRACTION`] of its samples inside has no score.
//!
//! The search covers the ball of `search_radius_mm` around q₀ with a coarse grid (`coarse_step_mm`); the prediction
//! q₀ and the best `coarse_peaks` local maxima of that grid climb (steepest ascent over 26 neighbours) on the fine
//! grid (`search_step_mm`) to their local maxima; the best of these is refined by one Newton step on the
//! finite-difference quadratic of its 3×3×3 neighbourhood, then by a pattern search with halving steps (Kolda,
//! Lewis & Torczon 2003, "Optimization by direct search", SIAM Review 45(3)) down to [`REFINE_TOLERANCE_MM`].
//!
//! The confidence is the peak's distinctness, (S_best − S_rival) / S_best, where S_rival is the best score of another
//! local maximum (climbed, or coarse) farther than `exclusion_radius_mm` from the best: a second structure that
//! matches nearly as well. It is divided by `distinct_margin` and clipped to [0, 1]; a best grid point on the search
//! ball's rim (the optimum may lie outside it) has confidence 0. Below `low_confidence_below` the suggestion is
//! flagged. The defaults were measured on the Colin27 head MRI (`tests/suggest.rs`, docs/accuracy.md): nearly every
//! suggestion more than 2 mm off had a distinctness below 0.03.
//!
//! One suggestion samples the patch (about 500 samples with the defaults) at about 300 candidates and smooths two
//! local blocks of about 10⁵ voxels; it runs on the calling thread.

use nalgebra::{Matrix3, Vector3};
use warpbench_io::geometry::{Point3, Space};

use crate::image::Image;
use crate::spaces::{Fixed, Moving};
use crate::warp::Warp;
use crate::{Result, SolverError};

/// A candidate needs at least this fraction of its patch samples inside the fixed image to have a score.
pub const MIN_VALID_FRACTION: f64 = 0.5;

/// The compass search stops once its step is below this, mm.
pub const REFINE_TOLERANCE_MM: f64 = 0.01;

/// The most patch samples one search may use (bounds the time of one suggestion).
pub const MAX_PATCH_SAMPLES: usize = 4096;

/// The most grid candidates one search may evaluate.
pub const MAX_CANDIDATES: usize = 35_000;

/// The most voxels of the local block of either image (smoothed and differentiated per suggestion).
pub const MAX_BLOCK_VOXELS: usize = 1 << 21;

/// The patch lattice is turned by these Euler angles (roll, pitch, yaw), so that its samples fall at different
/// fractions of the voxels: on an axis-aligned lattice whose step is a whole number of voxels, every sample crosses
/// a cell face at once, and the kinks of trilinear interpolation add up in S instead of averaging out.
pub const PATCH_LATTICE_ROTATION_RAD: [f64; 3] = [0.41, 0.27, 0.63];

/// The most pattern-search iterations.
const MAX_REFINE_ITERATIONS: usize = 200;

/// The parameters of one search; the default suits 1 mm head MRI.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SuggestParams {
    /// Radius of the ball of patch offsets oₖ, mm.
    pub patch_radius_mm: f64,
    /// Spacing of the patch offsets, mm.
    pub patch_step_mm: f64,
    /// Radius of the ball of candidates around q₀ = d(p), mm: how far the current warp may be wrong.
    pub search_radius_mm: f64,
    /// Spacing of the fine candidate grid before refinement, mm.
    pub search_step_mm: f64,
    /// Spacing of the coarse candidate grid that covers the whole ball first, mm (rounded to a multiple of
    /// `search_step_mm`; equal to it for an exhaustive fine search).
    pub coarse_step_mm: f64,
    /// How many of the coarse grid's best local maxima climb to their fine-grid maximum.
    pub coarse_peaks: usize,
    /// σ of the Gaussian applied to both images before their gradients are taken, mm (0: none).
    pub smoothing_sigma_mm: f64,
    /// ε as a fraction of the mean gradient magnitude.
    pub epsilon_fraction: f64,
    /// Grid scores within this distance of the best belong to its peak; the rival is the best beyond, mm.
    pub exclusion_radius_mm: f64,
    /// The distinctness (S_best − S_rival)/S_best that counts as full confidence.
    pub distinct_margin: f64,
    /// A suggestion whose confidence is below this is flagged.
    pub low_confidence_below: f64,
}

impl Default for SuggestParams {
    fn default() -> Self {
        Self {
            patch_radius_mm: 10.0,
            patch_step_mm: 2.0,
            search_radius_mm: 7.0,
            search_step_mm: 1.0,
            coarse_step_mm: 2.0,
            coarse_peaks: 4,
            smoothing_sigma_mm: 0.6,
            epsilon_fraction: 0.2,
            exclusion_radius_mm: 3.0,
            distinct_margin: 0.1,
            low_confidence_below: 0.3,
        }
    }
}

impl SuggestParams {
    /// Refuses parameters that are not finite and positive where they must be, or that would make one search too
    /// long ([`MAX_PATCH_SAMPLES`], [`MAX_CANDIDATES`]).
    ///
    /// # Errors
    /// [`SolverError::InvalidParameter`] naming the parameter.
    pub fn validate(&self) -> Result<()> {
        let positive = [
            ("patch_radius_mm", self.patch_radius_mm),
            ("patch_step_mm", self.patch_step_mm),
            ("search_step_mm", self.search_step_mm),
            ("coarse_step_mm", self.coarse_step_mm),
            ("epsilon_fraction", self.epsilon_fraction),
            ("distinct_margin", self.distinct_margin),
        ];
        let non_negative = [
            ("search_radius_mm", self.search_radius_mm),
            ("smoothing_sigma_mm", self.smoothing_sigma_mm),
            ("exclusion_radius_mm", self.exclusion_radius_mm),
            ("low_confidence_below", self.low_confidence_below),
        ];
        for (name, v) in positive {
            if !(v.is_finite() && v > 0.0) {
                return Err(SolverError::InvalidParameter(format!("{name} must be finite and positive, got {v}")));
            }
        }
        for (name, v) in non_negative {
            if !(v.is_finite() && v >= 0.0) {
                return Err(SolverError::InvalidParameter(format!("{name} must be finite and ≥ 0, got {v}")));
            }
        }
        if self.coarse_peaks == 0 {
            return Err(SolverError::InvalidParameter("coarse_peaks must be at least 1".into()));
        }
        let patch = ball_count(self.patch_radius_mm / self.patch_step_mm);
        if patch > MAX_PATCH_SAMPLES {
            return Err(SolverError::InvalidParameter(format!(
                "a patch of radius {} mm sampled every {} mm has more than {MAX_PATCH_SAMPLES} samples",
                self.patch_radius_mm, self.patch_step_mm
            )));
        }
        let candidates = ball_count(self.search_radius_mm / self.search_step_mm);
        if candidates > MAX_CANDIDATES {
            return Err(SolverError::InvalidParameter(format!(
                "a search of radius {} mm every {} mm has more than {MAX_CANDIDATES} candidates",
                self.search_radius_mm, self.search_step_mm
            )));
        }
        Ok(())
    }
}

/// One suggested target.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Suggestion {
    /// The suggested fixed point.
    pub fixed: Point3<Fixed>,
    /// The current warp's prediction q₀ = d(p).
    pub predicted: Point3<Fixed>,
    /// S at the suggestion, in [0, 1).
    pub score: f64,
    /// S at the prediction (`None` when too few of its samples are inside the fixed image).
    pub predicted_score: Option<f64>,
    /// The best score of another local maximum of the grid farther than the exclusion radius from the best
    /// (0 when there is none).
    pub rival_score: f64,
    /// In [0, 1] (module docs).
    pub confidence: f64,
    /// Confidence below the parameters' threshold.
    pub low_confidence: bool,
    /// The best grid point is on the search ball's rim: the optimum may lie outside it.
    pub on_rim: bool,
    /// |suggestion − prediction|, mm.
    pub shift_mm: f64,
    /// The search radius used, mm.
    pub search_radius_mm: f64,
    /// How many grid candidates were evaluated (the refinement's evaluations not counted).
    pub evaluations: usize,
}

/// Suggests the fixed point matching the moving point `p` (module docs): the current warp's prediction
/// d(p) refined by the local NGF search.
///
/// # Errors
/// [`SolverError::InvalidParameter`] for bad parameters or a non-finite `p`; [`SolverError::Degenerate`] when the
/// warp's Jacobian at `p` is not finite or not invertible; [`SolverError::Image`] when the moving patch or the
/// prediction is outside its image, a patch is flat, or no candidate has a score.
pub fn suggest(
    moving: &Image<Moving>,
    fixed: &Image<Fixed>,
    fixed_from_moving: &dyn Warp<Fixed, Moving>,
    p: Point3<Moving>,
    params: &SuggestParams,
) -> Result<Suggestion> {
    PatchMatcher::new(moving, fixed, fixed_from_moving, p, params)?.search()
}

/// The similarity S(q) of one moving patch, ready to be evaluated at any fixed candidate q (module docs); the
/// search of [`suggest`] and its tests use it.
#[derive(Clone, Debug)]
pub struct PatchMatcher {
    params: SuggestParams,
    predicted: [f64; 3],
    /// Aᵀ, raw.
    a_transpose: Matrix3<f64>,
    /// A ∇mₖ for the moving samples inside the moving image, and 1/(|∇mₖ|² + ε_m²).
    moving_terms: Vec<([f64; 3], f64)>,
    /// Offsets A oₖ in the fixed block's index space, for the same samples.
    fixed_offsets_index: Vec<[f64; 3]>,
    fixed_block: GradientBlock,
    /// ε_f².
    epsilon_f_sq: f64,
}

impl PatchMatcher {
    /// Samples the moving patch at `p` and prepares the fixed block around d(p).
    ///
    /// # Errors
    /// As [`suggest`].
    pub fn new(
        moving: &Image<Moving>,
        fixed: &Image<Fixed>,
        fixed_from_moving: &dyn Warp<Fixed, Moving>,
        p: Point3<Moving>,
        params: &SuggestParams,
    ) -> Result<Self> {
        params.validate()?;
        if !p.is_finite() {
            return Err(SolverError::InvalidParameter(format!("the source point {p:?} is not finite")));
        }
        let p_mm = p.coords();
        let predicted = fixed_from_moving.apply_raw(p_mm);
        if !predicted.iter().all(|c| c.is_finite()) {
            return Err(SolverError::Degenerate(format!("the warp maps {p:?} to a point that is not finite")));
        }
        let a = fixed_from_moving.jacobian_raw(p_mm);
        let det = a.determinant();
        if !(a.iter().all(|v| v.is_finite()) && det.is_finite() && det > 0.0) {
            return Err(SolverError::Degenerate(format!(
                "the warp's Jacobian at {p:?} has determinant {det:.3e}: it folds or collapses there"
            )));
        }

        // The patch offsets oₖ, and the moving gradients at p + oₖ.
        let offsets = ball_offsets(params.patch_radius_mm, params.patch_step_mm);
        let smoothing = params.smoothing_sigma_mm;
        let moving_block =
            GradientBlock::around(moving, p_mm, params.patch_radius_mm + params.patch_step_mm, smoothing)?.ok_or_else(
                || {
                    SolverError::Image(format!(
                        "the source point {p:?} is outside the moving image (its patch is empty)"
                    ))
                },
            )?;
        let mut moving_samples = Vec::with_capacity(offsets.len());
        for o in &offsets {
            let x = [p_mm[0] + o[0], p_mm[1] + o[1], p_mm[2] + o[2]];
            if let Some(g) = moving_block.gradient_at_mm(x) {
                moving_samples.push((*o, g));
            }
        }
        if (moving_samples.len() as f64) < MIN_VALID_FRACTION * offsets.len() as f64 {
            return Err(SolverError::Image(format!(
                "only {} of the {} patch samples around {p:?} are inside the moving image: too close to its edge",
                moving_samples.len(),
                offsets.len()
            )));
        }
        let mean_m = moving_samples.iter().map(|(_, g)| norm(*g)).sum::<f64>() / moving_samples.len() as f64;
        if !(mean_m.is_finite() && mean_m > 0.0) {
            return Err(SolverError::Image(format!(
                "the moving patch around {p:?} is flat (mean gradient {mean_m:.3e}): nothing to match"
            )));
        }
        let epsilon_m = params.epsilon_fraction * mean_m;

        // The fixed block covers every sample of every candidate the search may reach.
        let reach_mm = offsets.iter().map(|o| norm(mul(&a, *o))).fold(0.0, f64::max);
        let search_reach_mm = params.search_radius_mm + params.search_step_mm;
        let fixed_block = GradientBlock::around(fixed, predicted, search_reach_mm + reach_mm + 1.0, smoothing)?
            .ok_or_else(|| {
                SolverError::Image(format!(
                    "the predicted point ({:.1}, {:.1}, {:.1}) mm is outside the fixed image",
                    predicted[0], predicted[1], predicted[2]
                ))
            })?;
        let mean_f = fixed_block.mean_magnitude(&a.transpose());
        if !(mean_f.is_finite() && mean_f > 0.0) {
            return Err(SolverError::Image(format!(
                "the fixed image around ({:.1}, {:.1}, {:.1}) mm is flat: nothing to match",
                predicted[0], predicted[1], predicted[2]
            )));
        }
        let epsilon_f = params.epsilon_fraction * mean_f;

        let moving_terms =
            moving_samples.iter().map(|(_, g)| (mul(&a, *g), 1.0 / (dot(*g, *g) + epsilon_m * epsilon_m))).collect();
        let fixed_offsets_index =
            moving_samples.iter().map(|(o, _)| mul(&fixed_block.index_from_space_linear, mul(&a, *o))).collect();
        Ok(Self {
            params: *params,
            predicted,
            a_transpose: a.transpose(),
            moving_terms,
            fixed_offsets_index,
            fixed_block,
            epsilon_f_sq: epsilon_f * epsilon_f,
        })
    }

    /// The current warp's prediction d(p).
    #[must_use]
    pub fn predicted(&self) -> Point3<Fixed> {
        Point3::from_array(self.predicted)
    }

    /// The number of patch samples inside the moving image (K).
    #[must_use]
    pub fn sample_count(&self) -> usize {
        self.moving_terms.len()
    }

    /// S(q), or `None` when fewer than [`MIN_VALID_FRACTION`] of the samples at `q` are inside the fixed image (or
    /// outside the region prepared for the search, [`Self::search`]'s ball grown by one grid step).
    #[must_use]
    pub fn score(&self, q: Point3<Fixed>) -> Option<f64> {
        self.score_raw(q.coords())
    }

    fn score_raw(&self, q: [f64; 3]) -> Option<f64> {
        if !q.iter().all(|c| c.is_finite()) {
            return None;
        }
        let block = &self.fixed_block;
        let base = block.block_index(q);
        let at = &self.a_transpose;
        let mut sum = 0.0;
        let mut valid = 0usize;
        for ((a_grad_m, inv_m), off) in self.moving_terms.iter().zip(&self.fixed_offsets_index) {
            let Some(g) = block.gradient_at_index([base[0] + off[0], base[1] + off[1], base[2] + off[2]]) else {
                continue;
            };
            valid += 1;
            // ∇m · Aᵀ∇f = (A∇m) · ∇f.
            let c = dot(*a_grad_m, g);
            let gt = mul(at, g);
            sum += c * c * inv_m / (dot(gt, gt) + self.epsilon_f_sq);
        }
        let k = self.moving_terms.len();
        ((valid as f64) >= MIN_VALID_FRACTION * k as f64).then(|| sum / k as f64)
    }

    /// The grid search over the ball around d(p), its refinement and the confidence (module docs).
    ///
    /// # Errors
    /// [`SolverError::Image`] when no candidate has a score.
    pub fn search(&self) -> Result<Suggestion> {
        let params = &self.params;
        let mut grid = CandidateGrid::new(self);
        let (n, c) = (grid.n, grid.coarse);

        // The coarse grid over the ball, and its local maxima, best first.
        let coarse_range = || (-(n / c)..=n / c).map(|v| v * c);
        for k in coarse_range() {
            for j in coarse_range() {
                for i in coarse_range() {
                    grid.score([i, j, k]);
                }
            }
        }
        let mut coarse_peaks: Vec<(f64, [i64; 3])> = Vec::new();
        for k in coarse_range() {
            for j in coarse_range() {
                for i in coarse_range() {
                    let Some(s) = grid.known([i, j, k]) else { continue };
                    let is_peak = NEIGHBOURS
                        .iter()
                        .all(|d| grid.known([i + c * d[0], j + c * d[1], k + c * d[2]]).is_none_or(|o| o <= s));
                    if is_peak {
                        coarse_peaks.push((s, [i, j, k]));
                    }
                }
            }
        }
        if coarse_peaks.is_empty() {
            let q0 = self.predicted;
            return Err(SolverError::Image(format!(
                "no candidate within {} mm of the predicted point ({:.1}, {:.1}, {:.1}) mm has its patch inside the \
                 fixed image",
                params.search_radius_mm, q0[0], q0[1], q0[2]
            )));
        }
        coarse_peaks.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
        // The prediction climbs too: the answer most likely lies in its basin, and a narrow peak there may hide
        // between coarse points.
        let from_prediction = grid.score([0, 0, 0]).map(|s| (s, [0, 0, 0]));
        if let Some(d) = from_prediction {
            coarse_peaks.insert(0, d);
        }

        // The best few climb to their fine-grid local maximum; the others keep their coarse position.
        let peaks: Vec<(f64, [i64; 3])> = coarse_peaks
            .iter()
            .enumerate()
            .map(|(rank, &(s, at))| if rank <= params.coarse_peaks { grid.climb(s, at) } else { (s, at) })
            .collect();
        let &(best_grid_score, best) =
            peaks.iter().max_by(|a, b| a.0.total_cmp(&b.0).then(b.1.cmp(&a.1))).unwrap_or(&peaks[0]);
        let excl_sq = (params.exclusion_radius_mm / grid.h).powi(2);
        let far = |at: [i64; 3]| {
            ((at[0] - best[0]).pow(2) + (at[1] - best[1]).pow(2) + (at[2] - best[2]).pow(2)) as f64 > excl_sq
        };
        let rival_score = peaks.iter().filter(|(_, at)| far(*at)).map(|(s, _)| *s).fold(0.0, f64::max);
        let on_rim = n > 0 && {
            let r2 = best.iter().map(|v| v * v).sum::<i64>();
            (r2 as f64).sqrt() > n as f64 - 1.0 + 1e-9
        };

        // Refinement: one Newton step on the 3×3×3 neighbourhood's finite-difference quadratic, then a pattern
        // search, within the ball grown by one step (the region the fixed block covers).
        let h = grid.h;
        let q0 = self.predicted;
        let limit_mm = params.search_radius_mm + h;
        let inside = |q: [f64; 3]| norm(sub(q, q0)) <= limit_mm;
        let mut q_best = grid.point(best);
        let mut s_best = best_grid_score;
        let newton = newton_step(|di, dj, dk| grid.score([best[0] + di, best[1] + dj, best[2] + dk]));
        if let Some(step) = newton {
            let q = std::array::from_fn(|a| q_best[a] + h * step[a]);
            if inside(q)
                && let Some(s) = self.score_raw(q)
                && s > s_best
            {
                (q_best, s_best) = (q, s);
            }
        }
        // At h/2 and h/4, steepest ascent over all 26 neighbours (S may have narrow peaks between grid points); below,
        // the six axis directions first and the twenty diagonals only when no axis improves.
        let (axes, diagonals) = NEIGHBOURS.split_at(6);
        let mut step_mm = 0.5 * h;
        for _ in 0..MAX_REFINE_ITERATIONS {
            if step_mm < REFINE_TOLERANCE_MM {
                break;
            }
            let thorough = step_mm > 0.2 * h;
            let origin = q_best;
            let mut moved = false;
            for directions in [axes, diagonals] {
                for d in directions {
                    let q = std::array::from_fn(|a| origin[a] + step_mm * d[a] as f64);
                    if inside(q)
                        && let Some(s) = self.score_raw(q)
                        && s > s_best
                    {
                        (q_best, s_best) = (q, s);
                        moved = true;
                    }
                }
                if moved && !thorough {
                    break;
                }
            }
            if !moved {
                step_mm *= 0.5;
            }
        }

        let distinctness = if s_best > 0.0 { ((s_best - rival_score) / s_best).max(0.0) } else { 0.0 };
        let confidence = if on_rim { 0.0 } else { (distinctness / params.distinct_margin).clamp(0.0, 1.0) };
        Ok(Suggestion {
            fixed: Point3::from_array(q_best),
            predicted: Point3::from_array(q0),
            score: s_best,
            predicted_score: self.score_raw(q0),
            rival_score,
            confidence,
            low_confidence: confidence < params.low_confidence_below,
            on_rim,
            shift_mm: norm(sub(q_best, q0)),
            search_radius_mm: params.search_radius_mm,
            evaluations: grid.evaluations,
        })
    }
}

/// The 26 neighbours of a grid point, the six along the axes first.
const NEIGHBOURS: [[i64; 3]; 26] = {
    let mut out = [[0; 3]; 26];
    let axes = [[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]];
    let mut n = 0;
    while n < 6 {
        out[n] = axes[n];
        n += 1;
    }
    let mut code = 0;
    while code < 27 {
        let d = [code % 3 - 1, (code / 3) % 3 - 1, code / 9 - 1];
        let nonzero = (d[0] != 0) as i64 + (d[1] != 0) as i64 + (d[2] != 0) as i64;
        if nonzero >= 2 {
            out[n] = d;
            n += 1;
        }
        code += 1;
    }
    out
};

/// S on the fine candidate grid q₀ + h·(i, j, k), |(i, j, k)| ≤ n, evaluated lazily and kept.
struct CandidateGrid<'a> {
    matcher: &'a PatchMatcher,
    h: f64,
    n: i64,
    /// The coarse grid's step, in fine steps.
    coarse: i64,
    side: usize,
    /// NaN: not evaluated; −∞: no score (outside the ball or the fixed image).
    values: Vec<f64>,
    evaluations: usize,
}

impl<'a> CandidateGrid<'a> {
    fn new(matcher: &'a PatchMatcher) -> Self {
        let params = &matcher.params;
        let h = params.search_step_mm;
        let n = (params.search_radius_mm / h).floor() as i64;
        let coarse = ((params.coarse_step_mm / h).round() as i64).max(1);
        let side = (2 * n + 1) as usize;
        Self { matcher, h, n, coarse, side, values: vec![f64::NAN; side * side * side], evaluations: 0 }
    }

    fn point(&self, at: [i64; 3]) -> [f64; 3] {
        std::array::from_fn(|a| self.matcher.predicted[a] + at[a] as f64 * self.h)
    }

    fn slot(&self, at: [i64; 3]) -> Option<usize> {
        let n = self.n;
        if at.iter().any(|v| v.abs() > n) || at.iter().map(|v| v * v).sum::<i64>() > n * n {
            return None;
        }
        let [i, j, k] = at.map(|v| (v + n) as usize);
        Some(i + self.side * (j + self.side * k))
    }

    /// S at grid point `at`, evaluated on first use; `None` outside the ball or without a score.
    fn score(&mut self, at: [i64; 3]) -> Option<f64> {
        let slot = self.slot(at)?;
        if self.values[slot].is_nan() {
            self.evaluations += 1;
            self.values[slot] = self.matcher.score_raw(self.point(at)).unwrap_or(f64::NEG_INFINITY);
        }
        Some(self.values[slot]).filter(|v| v.is_finite())
    }

    /// S at `at` if it has been evaluated and has a score.
    fn known(&self, at: [i64; 3]) -> Option<f64> {
        self.slot(at).map(|s| self.values[s]).filter(|v| v.is_finite())
    }

    /// Steepest ascent over the 26 neighbours on the fine grid from `at` (score `s`) to a local maximum.
    fn climb(&mut self, mut s: f64, mut at: [i64; 3]) -> (f64, [i64; 3]) {
        for _ in 0..self.side * 3 {
            let mut next = None;
            for d in NEIGHBOURS {
                let q = [at[0] + d[0], at[1] + d[1], at[2] + d[2]];
                if let Some(v) = self.score(q)
                    && v > next.map_or(s, |(b, _)| b)
                {
                    next = Some((v, q));
                }
            }
            match next {
                Some((v, q)) => (s, at) = (v, q),
                None => break,
            }
        }
        (s, at)
    }
}

/// The Newton step (in grid steps) to the maximum of the quadratic through a grid point's 3×3×3 neighbourhood
/// (`s(di, dj, dk)`, `None` where unknown), by central differences; `None` when a value is missing, the quadratic
/// has no maximum, or the step leaves the neighbourhood.
fn newton_step(mut s: impl FnMut(i64, i64, i64) -> Option<f64>) -> Option<[f64; 3]> {
    let unit = |a: usize, sign: i64| -> [i64; 3] { std::array::from_fn(|b| if a == b { sign } else { 0 }) };
    let mut at = |d: [i64; 3]| s(d[0], d[1], d[2]);
    let centre = at([0, 0, 0])?;
    let mut gradient = Vector3::zeros();
    let mut hessian = Matrix3::zeros();
    for a in 0..3 {
        let (plus, minus) = (at(unit(a, 1))?, at(unit(a, -1))?);
        gradient[a] = 0.5 * (plus - minus);
        hessian[(a, a)] = plus - 2.0 * centre + minus;
        for b in (a + 1)..3 {
            let mut corner = [0.0; 4];
            for (c, (sa, sb)) in corner.iter_mut().zip([(1, 1), (1, -1), (-1, 1), (-1, -1)]) {
                let mut d = [0; 3];
                d[a] = sa;
                d[b] = sb;
                *c = at(d)?;
            }
            let mixed = 0.25 * (corner[0] - corner[1] - corner[2] + corner[3]);
            hessian[(a, b)] = mixed;
            hessian[(b, a)] = mixed;
        }
    }
    // A maximum needs −H positive definite.
    (-hessian).cholesky()?;
    let step = -(hessian.try_inverse()? * gradient);
    (step.iter().all(|v| v.is_finite() && v.abs() <= 1.0)).then(|| [step[0], step[1], step[2]])
}

/// The number of integer points in the ball of radius `r` (in steps), or `usize::MAX` from r = 24 on (over 57 000
/// points, above both [`MAX_PATCH_SAMPLES`] and [`MAX_CANDIDATES`]), where counting would take long.
fn ball_count(r: f64) -> usize {
    if !(r.is_finite() && r < 24.0) {
        return usize::MAX;
    }
    let n = r.floor() as i64;
    let r2 = r * r;
    let mut count = 0;
    for k in -n..=n {
        for j in -n..=n {
            for i in -n..=n {
                if ((i * i + j * j + k * k) as f64) <= r2 {
                    count += 1;
                }
            }
        }
    }
    count
}

/// The offsets of step `step_mm` in the ball of `radius_mm` (k slowest), on a lattice turned by
/// [`PATCH_LATTICE_ROTATION_RAD`].
fn ball_offsets(radius_mm: f64, step_mm: f64) -> Vec<[f64; 3]> {
    let [roll, pitch, yaw] = PATCH_LATTICE_ROTATION_RAD;
    let rotation = nalgebra::Rotation3::from_euler_angles(roll, pitch, yaw).into_inner();
    let r = radius_mm / step_mm;
    let n = r.floor() as i64;
    let mut out = Vec::new();
    for k in -n..=n {
        for j in -n..=n {
            for i in -n..=n {
                if ((i * i + j * j + k * k) as f64) <= r * r {
                    out.push(mul(&rotation, [i as f64 * step_mm, j as f64 * step_mm, k as f64 * step_mm]));
                }
            }
        }
    }
    out
}

/// The Gaussian-smoothed gradient of an image (in its space's mm) at the voxels of a block around a point, read
/// back by trilinear interpolation.
#[derive(Clone, Debug)]
struct GradientBlock {
    dims: [usize; 3],
    /// ∇ in value units per mm, i fastest; NaN where the smoothed image is not finite.
    gradients: Vec<[f32; 3]>,
    /// The image's index_from_space, linear part.
    index_from_space_linear: Matrix3<f64>,
    /// Its translation, less the block's first voxel: block index = linear · x + translation.
    block_translation: [f64; 3],
}

impl GradientBlock {
    /// The block of the voxels within `radius_mm` of `centre_mm` along every index axis (with the smoothing's
    /// margin), clipped to the image; `None` when that leaves fewer than 2 voxels along an axis (the point is
    /// outside the image).
    fn around<S: Space>(image: &Image<S>, centre_mm: [f64; 3], radius_mm: f64, sigma_mm: f64) -> Result<Option<Self>> {
        let linear = image.space_from_index().linear();
        let index_from_space_linear = linear.try_inverse().ok_or_else(|| {
            SolverError::Image(format!("the {} image's voxel-to-patient matrix is singular", S::NAME))
        })?;
        let spacing = image.spacing_mm();
        let centre = image.index_of(centre_mm);
        let dims = image.dims();
        let sigma_vox: [f64; 3] = std::array::from_fn(|a| sigma_mm / spacing[a]);
        let taps: [usize; 3] = std::array::from_fn(|a| (3.0 * sigma_vox[a]).ceil() as usize);
        let mut lo = [0usize; 3];
        let mut block_dims = [0usize; 3];
        for a in 0..3 {
            // A ball of radius r spans r·|row a of index_from_space| along index axis a.
            let extent = radius_mm * index_from_space_linear.row(a).norm() + 1.0 + taps[a] as f64;
            let (from, to) = ((centre[a] - extent).floor(), (centre[a] + extent).ceil());
            let top = (dims[a] - 1) as f64;
            let (from, to) = (from.max(0.0), to.min(top));
            if (to - from).is_nan() || to - from < 1.0 {
                return Ok(None);
            }
            lo[a] = from as usize;
            block_dims[a] = (to - from) as usize + 1;
        }
        let n = block_dims[0] * block_dims[1] * block_dims[2];
        if n > MAX_BLOCK_VOXELS {
            return Err(SolverError::InvalidParameter(format!(
                "the search needs a block of {n} voxels of the {} image (at most {MAX_BLOCK_VOXELS}): smaller radii, \
                 or a shrunk image",
                S::NAME
            )));
        }
        let [bx, by, bz] = block_dims;
        let mut values: Vec<f64> = Vec::with_capacity(n);
        for k in 0..bz {
            for j in 0..by {
                for i in 0..bx {
                    values.push(f64::from(image.at(lo[0] + i, lo[1] + j, lo[2] + k)));
                }
            }
        }
        let strides = [1, bx, bx * by];
        let mut scratch = vec![0.0; n];
        for a in 0..3 {
            if taps[a] > 0 {
                let kernel = gaussian_kernel(sigma_vox[a], taps[a]);
                smooth_axis(&values, &mut scratch, block_dims, a, &kernel);
                std::mem::swap(&mut values, &mut scratch);
            }
        }
        // Central differences in index space (one-sided at the block's faces), then ∇ = Lᵀ⁻¹ ∂v/∂ξ.
        let l_inv_t = index_from_space_linear.transpose();
        let mut gradients = Vec::with_capacity(n);
        for k in 0..bz {
            for j in 0..by {
                for i in 0..bx {
                    let o = i + bx * (j + by * k);
                    let d = [
                        central_difference(&values, o, i, bx, strides[0]),
                        central_difference(&values, o, j, by, strides[1]),
                        central_difference(&values, o, k, bz, strides[2]),
                    ];
                    let g = l_inv_t * Vector3::from(d);
                    gradients.push([g[0] as f32, g[1] as f32, g[2] as f32]);
                }
            }
        }
        let full = image.index_of([0.0; 3]);
        Ok(Some(Self {
            dims: block_dims,
            gradients,
            index_from_space_linear,
            block_translation: std::array::from_fn(|a| full[a] - lo[a] as f64),
        }))
    }

    /// The block index of `x_mm`.
    fn block_index(&self, x_mm: [f64; 3]) -> [f64; 3] {
        let v = mul(&self.index_from_space_linear, x_mm);
        std::array::from_fn(|a| v[a] + self.block_translation[a])
    }

    fn gradient_at_mm(&self, x_mm: [f64; 3]) -> Option<[f64; 3]> {
        self.gradient_at_index(self.block_index(x_mm))
    }

    /// The trilinear gradient at block index `xi`; `None` outside the block or where a corner is not finite.
    #[inline]
    fn gradient_at_index(&self, xi: [f64; 3]) -> Option<[f64; 3]> {
        let [nx, ny, nz] = self.dims;
        // NaN fails every comparison: outside.
        if !(xi[0] >= 0.0 && xi[1] >= 0.0 && xi[2] >= 0.0) {
            return None;
        }
        if !(xi[0] <= (nx - 1) as f64 && xi[1] <= (ny - 1) as f64 && xi[2] <= (nz - 1) as f64) {
            return None;
        }
        // Non-negative: truncation is the floor. The last plane belongs to the cell below it.
        let (bx, by, bz) = ((xi[0] as usize).min(nx - 2), (xi[1] as usize).min(ny - 2), (xi[2] as usize).min(nz - 2));
        let (fx, fy, fz) = (xi[0] - bx as f64, xi[1] - by as f64, xi[2] - bz as f64);
        let o = bx + nx * (by + ny * bz);
        let (sj, sk) = (nx, nx * ny);
        let g = &self.gradients;
        let corners =
            [g[o], g[o + 1], g[o + sj], g[o + sj + 1], g[o + sk], g[o + sk + 1], g[o + sk + sj], g[o + sk + sj + 1]];
        let (fx, fy, fz) = (fx as f32, fy as f32, fz as f32);
        let mut out = [0.0; 3];
        for (c, v) in out.iter_mut().enumerate() {
            let x00 = corners[0][c] + fx * (corners[1][c] - corners[0][c]);
            let x10 = corners[2][c] + fx * (corners[3][c] - corners[2][c]);
            let x01 = corners[4][c] + fx * (corners[5][c] - corners[4][c]);
            let x11 = corners[6][c] + fx * (corners[7][c] - corners[6][c]);
            let y0 = x00 + fy * (x10 - x00);
            let y1 = x01 + fy * (x11 - x01);
            *v = f64::from(y0 + fz * (y1 - y0));
        }
        out.iter().all(|v| v.is_finite()).then_some(out)
    }

    /// The mean of |M ∇| over the block's finite gradients (0 when none is).
    fn mean_magnitude(&self, m: &Matrix3<f64>) -> f64 {
        let (sum, count) = self
            .gradients
            .iter()
            .filter(|g| g.iter().all(|v| v.is_finite()))
            .fold((0.0, 0usize), |(s, c), g| (s + norm(mul(m, g.map(f64::from))), c + 1));
        if count == 0 { 0.0 } else { sum / count as f64 }
    }
}

/// ∂v/∂ξ along one axis at flat index `o`, position `at` of `len` (≥ 2) on that axis: central, one-sided at the ends.
#[inline]
fn central_difference(values: &[f64], o: usize, at: usize, len: usize, stride: usize) -> f64 {
    if at == 0 {
        values[o + stride] - values[o]
    } else if at + 1 == len {
        values[o] - values[o - stride]
    } else {
        0.5 * (values[o + stride] - values[o - stride])
    }
}

/// The normalised Gaussian taps w(−t..=t) of σ (voxels).
fn gaussian_kernel(sigma_vox: f64, taps: usize) -> Vec<f64> {
    let t = taps as i64;
    let raw: Vec<f64> = (-t..=t).map(|d| (-0.5 * (d as f64 / sigma_vox).powi(2)).exp()).collect();
    let total: f64 = raw.iter().sum();
    raw.into_iter().map(|w| w / total).collect()
}

/// One separable Gaussian pass along `axis`; near the block's faces and non-finite values the kernel is
/// renormalised over the taps that remain (NaN when none does).
fn smooth_axis(input: &[f64], out: &mut [f64], dims: [usize; 3], axis: usize, kernel: &[f64]) {
    let strides = [1, dims[0], dims[0] * dims[1]];
    let (a1, a2) = ((axis + 1) % 3, (axis + 2) % 3);
    let (len, stride) = (dims[axis], strides[axis]);
    let t = kernel.len() / 2;
    let mut line = Vec::with_capacity(len);
    for i2 in 0..dims[a2] {
        for i1 in 0..dims[a1] {
            let start = i1 * strides[a1] + i2 * strides[a2];
            line.clear();
            line.extend((0..len).map(|x| input[start + x * stride]));
            let all_finite = line.iter().all(|v| v.is_finite());
            for x in 0..len {
                let v = if all_finite && x >= t && x + t < len {
                    line[x - t..=x + t].iter().zip(kernel).map(|(v, w)| v * w).sum()
                } else {
                    let (mut sum, mut weight) = (0.0, 0.0);
                    for (d, w) in kernel.iter().enumerate() {
                        let Some(&v) = (x + d).checked_sub(t).and_then(|q| line.get(q)) else { continue };
                        if v.is_finite() {
                            sum += w * v;
                            weight += w;
                        }
                    }
                    if weight > 0.0 { sum / weight } else { f64::NAN }
                };
                out[start + x * stride] = v;
            }
        }
    }
}

fn mul(m: &Matrix3<f64>, v: [f64; 3]) -> [f64; 3] {
    std::array::from_fn(|r| m[(r, 0)] * v[0] + m[(r, 1)] * v[1] + m[(r, 2)] * v[2])
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn norm(v: [f64; 3]) -> f64 {
    dot(v, v).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;
    use warpbench_io::geometry::Transform;

    /// A blob image: a sum of Gaussians of different widths, so that every patch has a distinct structure.
    fn blobs<S: Space>(dims: [usize; 3], shift_mm: [f64; 3], map: impl Fn(f64) -> f64) -> Image<S> {
        let centres = [([12.0, 14.0, 15.0], 3.0), ([20.0, 11.0, 17.0], 2.0), ([15.0, 20.0, 12.0], 2.5)];
        let mut values = Vec::new();
        for k in 0..dims[2] {
            for j in 0..dims[1] {
                for i in 0..dims[0] {
                    let x = [i as f64 - shift_mm[0], j as f64 - shift_mm[1], k as f64 - shift_mm[2]];
                    let v: f64 = centres
                        .iter()
                        .map(|(c, s)| (-(norm(sub(x, *c)).powi(2)) / (2.0 * s * s)).exp() * 100.0 * s)
                        .sum();
                    values.push(map(v) as f32);
                }
            }
        }
        Image::new(dims, values, Transform::identity()).expect("blob image")
    }

    /// The identity as a forward warp.
    struct Identity;
    impl Warp<Fixed, Moving> for Identity {
        fn apply_raw(&self, x: [f64; 3]) -> [f64; 3] {
            x
        }
    }

    /// A forward warp whose prediction is far outside the fixed image.
    struct Far;
    impl Warp<Fixed, Moving> for Far {
        fn apply_raw(&self, x: [f64; 3]) -> [f64; 3] {
            [x[0] + 500.0, x[1], x[2]]
        }
    }

    /// A forward warp that mirrors (negative Jacobian determinant).
    struct Mirror;
    impl Warp<Fixed, Moving> for Mirror {
        fn apply_raw(&self, x: [f64; 3]) -> [f64; 3] {
            [31.0 - x[0], x[1], x[2]]
        }
    }

    /// A translated copy is found to well under a voxel, with an inverted contrast as well.
    #[test]
    fn a_translation_is_recovered_in_both_contrasts() {
        let dims = [32, 32, 32];
        let moving: Image<Moving> = blobs(dims, [0.0; 3], |v| v);
        let shift = [1.6, -2.3, 0.7];
        for map in [(|v: f64| v) as fn(f64) -> f64, |v: f64| 500.0 - v] {
            let fixed: Image<Fixed> = blobs(dims, shift, map);
            let p = Point3::new(15.0, 15.0, 15.0);
            let s = suggest(&moving, &fixed, &Identity, p, &SuggestParams::default()).expect("suggestion");
            let want = [15.0 + shift[0], 15.0 + shift[1], 15.0 + shift[2]];
            let err = norm(sub(s.fixed.coords(), want));
            assert!(err < 0.2, "error {err} mm: {s:?}");
            assert!(s.shift_mm > 2.0 && !s.on_rim);
        }
    }

    /// Bad input is refused with an error, never a panic.
    #[test]
    fn bad_input_is_refused() {
        let dims = [32, 32, 32];
        let moving: Image<Moving> = blobs(dims, [0.0; 3], |v| v);
        let fixed: Image<Fixed> = blobs(dims, [0.0; 3], |v| v);
        let params = SuggestParams::default();
        let inside = Point3::new(15.0, 15.0, 15.0);
        assert!(matches!(
            suggest(&moving, &fixed, &Identity, Point3::new(f64::NAN, 0.0, 0.0), &params),
            Err(SolverError::InvalidParameter(_))
        ));
        assert!(matches!(
            suggest(&moving, &fixed, &Identity, Point3::new(-50.0, 15.0, 15.0), &params),
            Err(SolverError::Image(_))
        ));
        let flat: Image<Moving> = Image::new(dims, vec![3.0; 32 * 32 * 32], Transform::identity()).expect("flat image");
        assert!(matches!(suggest(&flat, &fixed, &Identity, inside, &params), Err(SolverError::Image(_))));
        for bad in [
            SuggestParams { patch_radius_mm: -1.0, ..params },
            SuggestParams { patch_step_mm: 0.0, ..params },
            SuggestParams { search_radius_mm: f64::NAN, ..params },
            SuggestParams { patch_radius_mm: 100.0, ..params },
            SuggestParams { search_step_mm: 0.01, ..params },
        ] {
            assert!(matches!(suggest(&moving, &fixed, &Identity, inside, &bad), Err(SolverError::InvalidParameter(_))));
        }
        // The prediction leaves the fixed image.
        assert!(matches!(suggest(&moving, &fixed, &Far, inside, &params), Err(SolverError::Image(_))));
        // A folding warp.
        assert!(matches!(suggest(&moving, &fixed, &Mirror, inside, &params), Err(SolverError::Degenerate(_))));
    }

    #[test]
    fn the_newton_step_finds_a_quadratic_maximum() {
        let peak = [0.3, -0.2, 0.45];
        let q = |i: i64, j: i64, k: i64| {
            let d = [i as f64 - peak[0], j as f64 - peak[1], k as f64 - peak[2]];
            Some(5.0 - 2.0 * d[0] * d[0] - d[1] * d[1] - 3.0 * d[2] * d[2] + 0.5 * d[0] * d[1])
        };
        let step = newton_step(q).expect("a maximum");
        for a in 0..3 {
            assert!((step[a] - peak[a]).abs() < 1e-9, "{step:?}");
        }
        assert!(newton_step(|i, _, _| Some(i as f64 * i as f64)).is_none(), "a minimum is no maximum");
    }
}
