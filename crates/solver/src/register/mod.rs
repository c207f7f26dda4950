//! # Registration by intensities under the landmarks
//!
//! A deformable refinement of a pull-back u₀ (`moving_from_fixed`: the start, the landmark fit and any field under
//! it) that matches the images' intensities while it keeps the landmark pairs.
//!
//! ## Model
//!
//! A cubic B-spline free-form deformation T(x) = x + D(x) of the fixed space ([`FreeFormDeformation`], the lattice of
//! [`crate::bspline`] over the fixed image's box), composed *under* the current pull-back:
//!
//! u(x) = u₀(T(x)) = u₀(x + D(x)).
//!
//! Composition (not addition) keeps whatever u₀ already is, however it was made; D = 0 gives u₀ back.
//!
//! ## Objective
//!
//! Over the lattice coefficients φ, minimise
//!
//! E(φ) = −S(φ) + α · B(φ) + β · Σᵢ |u(qᵢ) − pᵢ|²,
//!
//! with (pᵢ moving, qᵢ fixed) the active pairs, α the bending weight and β the landmark weight (per mm²; the given β
//! at the coarsest level and 1/8 of the level before at each finer one, [`level_landmark_weight`]), and S the
//! [`Similarity`]: MI below, normalised gradient fields ([`ngf`]: the edges' alignment, whatever their contrast, read
//! at the same samples of the same pulled-back image), or local normalised cross-correlation ([`lncc`]: over small
//! patches of samples, for one modality under a smooth gain and offset):
//!
//! - **MI** is the Mattes mutual information of [`crate::align`] between the fixed image f and the moving image
//!   pulled back by u₀, m'(y) = m(u₀(y)), sampled at seeded fixed points x as m'(x + D(x)). The pull-back m' is
//!   resampled once per level onto the level's fixed grid (trilinear; NaN where u₀ leaves the moving image, and a
//!   sample there is dropped), so that an evaluation costs one trilinear read per sample whatever u₀ is. Its
//!   gradient is the one of [`crate::align`] with ∂T/∂φ_c = B_c(x) I:
//!   ∂MI/∂φ_c = −(1/(n Δm)) Σ_x [Σ_κ β³′(κ − m̃) log(p(ι_x, κ)/p_m(κ))] ∇m'(x + D(x)) B_c(x).
//! - **B** is the thin-plate bending energy of D per unit volume, exact (`bending`), so α does not depend on the
//!   box's size.
//! - **The landmark term** reads u₀ at the displaced fixed points exactly (not through m'):
//!   ∂/∂φ_c β|u₀(qᵢ + D(qᵢ)) − pᵢ|² = 2β B_c(qᵢ) J_{u₀}(qᵢ + D(qᵢ))ᵀ (u₀(qᵢ + D(qᵢ)) − pᵢ).
//!
//! ## Optimiser and levels
//!
//! Each level runs L-BFGS (Nocedal & Wright 2006, Algorithm 7.5) with a backtracking line search (`lbfgs`: it skips
//! the curvature pairs MI's kinks spoil), whose first step moves the largest coefficient by one voxel of the level and
//! no step by more than two. Each level draws at least [`SAMPLES_PER_COEFFICIENT`] samples per lattice coefficient, so
//! that the deformation cannot fit the images' noise. Levels go
//! coarse to fine: level ℓ of L shrinks both images by 2^(L−1−ℓ) ([`Image::shrink`]) and has a lattice of 2^ℓ times
//! the coarsest cells per axis, the coarsest chosen so that the finest spacing is at most
//! [`RegisterParams::grid_mm`]. A level starts from the previous one's lattice refined exactly
//! ([`ControlLattice::refine`]).
//!
//! ## No folding
//!
//! Where the bending energy alone would let the deformation fold (two volumes of different heads, say), the objective
//! is not defined: a φ whose det(I + ∇D) falls below [`MIN_DETERMINANT`] at any of 2 × 2 × 2 points per lattice cell
//! counts as a step too far, and the line search backs off. So T stays invertible, and u = u₀ ∘ T folds only where
//! u₀ does.
//!
//! ## Reproducibility
//!
//! The samples are drawn from a seeded stream, and every sum over samples is split into a fixed number of chunks
//! whose partial sums are added in order; u₀ and the pulled-back image are evaluated point by point. The same inputs
//! and seed give the same lattice, bit for bit, on any number of threads (tested).

mod bending;
pub mod device;
mod lbfgs;
pub mod lncc;
mod metric;
pub mod ngf;
mod samples;

use std::borrow::Cow;
use std::cell::{Cell, RefCell};
use std::ops::ControlFlow;
use std::time::Instant;

use nalgebra::Matrix3;
use rayon::prelude::*;
use warpbench_io::geometry::{Point3, Space};

use crate::align::{MIN_SAMPLES_INSIDE, PAD_BINS, draw_samples};
use crate::bspline::ControlLattice;
use crate::diagnostics::{JacobianReport, jacobian_determinants};
use crate::image::Image;
use crate::spaces::{Aabb, Fixed, Moving};
use crate::warp::{Composed, Parallelism, Warp};
use crate::{Result, SolverError};
use bending::Bending;
use device::SampleDevice;
use lncc::Lncc;
use metric::{Evaluation, JacobianPoint, Metric};
use ngf::Ngf;
use samples::Footprint;

/// The similarity measure.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Similarity {
    /// Mattes mutual information: any two modalities (MR–CT, T1–T2).
    #[default]
    Mi,
    /// Normalised gradient fields (Haber & Modersitzki 2006): edges aligned whatever their contrast ([`ngf`]).
    Ngf,
    /// Local normalised cross-correlation over small patches ([`lncc`]): one modality under a smooth gain and offset
    /// (MR–MR with different coils or bias fields).
    Lncc,
}

impl std::fmt::Display for Similarity {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::Mi => "mi",
            Self::Ngf => "ngf",
            Self::Lncc => "lncc",
        })
    }
}

/// How the registration runs. [`Default`] suits head MR–CT and MR–MR of about 1 mm.
#[derive(Clone, Debug, PartialEq)]
pub struct RegisterParams {
    pub similarity: Similarity,
    /// The finest control-point spacing, mm (at most; the lattice divides the fixed box evenly).
    pub grid_mm: f64,
    /// Resolution levels, coarse to fine (each halves the control spacing and the image shrink).
    pub levels: usize,
    /// β: the weight of the squared landmark distances, per mm², at the coarsest level (each finer level takes
    /// β / 8 of the one before: [`level_landmark_weight`]).
    pub landmark_weight: f64,
    /// α: the weight of the bending energy (mm²).
    pub bending_weight: f64,
    /// Histogram bins per image, padding included.
    pub bins: usize,
    /// Fixed sample points per level, at least; a level draws [`SAMPLES_PER_COEFFICIENT`] per lattice coefficient when
    /// that is more, and fewer when it has fewer voxels.
    pub samples: usize,
    /// L-BFGS iterations per level, at most.
    pub max_iterations: usize,
    /// The seed of the sample points.
    pub seed: u64,
    pub parallelism: Parallelism,
}

impl Default for RegisterParams {
    fn default() -> Self {
        Self {
            similarity: Similarity::Mi,
            grid_mm: 16.0,
            levels: 3,
            landmark_weight: 1.0,
            bending_weight: 100.0,
            bins: 32,
            samples: 50_000,
            max_iterations: 100,
            seed: 1,
            parallelism: Parallelism::Rayon,
        }
    }
}

/// One landmark pair the registration keeps: pᵢ in the moving volume, qᵢ in the fixed one.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RegisterPair {
    pub moving: Point3<Moving>,
    pub fixed: Point3<Fixed>,
}

/// What one resolution level did.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct LevelReport {
    /// The images' shrink factor.
    pub shrink: usize,
    /// The control spacing along each axis, mm.
    pub control_spacing_mm: [f64; 3],
    /// Control points (each with 3 coefficients).
    pub control_points: usize,
    pub samples: usize,
    /// Samples inside the pulled-back moving image at the end.
    pub samples_inside: usize,
    pub iterations: usize,
    /// Evaluations of the objective and its gradient.
    pub evaluations: usize,
    /// The similarity at the level's start and end: MI in nats, or NGF in [0, 1].
    pub similarity_start: f64,
    pub similarity: f64,
    /// B(φ) at the end, mm⁻².
    pub bending_energy: f64,
    /// The level's β, per mm² ([`level_landmark_weight`]).
    pub landmark_weight: f64,
    /// The RMS of |u(qᵢ) − pᵢ| at the end, mm; 0 without pairs.
    pub landmark_rms_mm: f64,
    /// Wall time, seconds.
    pub seconds: f64,
}

/// Where a registration is, for a progress bar.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RegisterProgress {
    /// 0-based, coarse to fine.
    pub level: usize,
    pub levels: usize,
    /// Evaluations so far in this level, and the most it may take.
    pub evaluation: usize,
    pub max_evaluations: usize,
    /// The similarity at the last evaluation (MI in nats, or NGF).
    pub similarity: f64,
}

impl RegisterProgress {
    /// The fraction done, 0..1, counting each level as an equal share.
    #[must_use]
    pub fn fraction(&self) -> f64 {
        let within = (self.evaluation as f64 / self.max_evaluations.max(1) as f64).min(1.0);
        (self.level as f64 + within) / self.levels.max(1) as f64
    }
}

/// T(x) = x + D(x) over the fixed space: the deformation a registration found, to compose under the pull-back it
/// started from (`u = u₀ ∘ T`, [`Self::pullback`]).
#[derive(Clone, Debug, PartialEq)]
pub struct FreeFormDeformation {
    lattice: ControlLattice,
}

impl FreeFormDeformation {
    /// The deformation of a lattice of displacements over the fixed box.
    #[must_use]
    pub fn new(lattice: ControlLattice) -> Self {
        Self { lattice }
    }

    /// Its control lattice (mm displacements).
    #[must_use]
    pub fn lattice(&self) -> &ControlLattice {
        &self.lattice
    }

    /// The registered pull-back u = u₀ ∘ T.
    #[must_use]
    pub fn pullback<'a>(&'a self, start: &'a dyn Warp<Moving, Fixed>) -> Composed<'a, Moving, Fixed, Fixed> {
        Composed { first: self, second: start }
    }
}

impl Warp<Fixed, Fixed> for FreeFormDeformation {
    fn apply_raw(&self, x: [f64; 3]) -> [f64; 3] {
        self.lattice.warp_raw(x)
    }

    fn jacobian_raw(&self, x: [f64; 3]) -> Matrix3<f64> {
        self.lattice.warp_jacobian(x)
    }
}

/// The result of [`register`].
#[derive(Clone, Debug)]
pub struct Registration {
    pub deformation: FreeFormDeformation,
    pub levels: Vec<LevelReport>,
}

/// Registers `moving` to `fixed` under the pull-back `start` (u₀) while keeping `pairs` (module docs): the
/// deformation T with u = u₀ ∘ T. `progress` hears after each evaluation; [`ControlFlow::Break`] stops the work with
/// [`SolverError::Cancelled`].
///
/// # Errors
/// [`SolverError::InvalidParameter`] for unusable parameters; [`SolverError::NonFinite`] for a pair with a
/// coordinate that is not a number (1-based); [`SolverError::Image`] when an image has a single value or the images
/// do not overlap under u₀ (fewer than [`MIN_SAMPLES_INSIDE`] samples inside the moving image);
/// [`SolverError::Cancelled`].
pub fn register(
    fixed: &Image<Fixed>,
    moving: &Image<Moving>,
    start: &dyn Warp<Moving, Fixed>,
    pairs: &[RegisterPair],
    params: &RegisterParams,
    progress: &mut dyn FnMut(&RegisterProgress) -> ControlFlow<()>,
) -> Result<Registration> {
    register_on(fixed, moving, start, pairs, params, None, progress)
}

/// [`register`], with the samples of the mutual information or the local correlation read on `device` when one is
/// given ([`device`]; the normalised gradient fields always run on the CPU).
///
/// # Errors
/// Those of [`register`], and [`SolverError::Device`] when the device fails.
pub fn register_on(
    fixed: &Image<Fixed>,
    moving: &Image<Moving>,
    start: &dyn Warp<Moving, Fixed>,
    pairs: &[RegisterPair],
    params: &RegisterParams,
    device: Option<&dyn SampleDevice>,
    progress: &mut dyn FnMut(&RegisterProgress) -> ControlFlow<()>,
) -> Result<Registration> {
    check(params)?;
    if let Some(n) = pairs.iter().position(|p| !(p.moving.is_finite() && p.fixed.is_finite())) {
        return Err(SolverError::NonFinite { pair: n + 1 });
    }
    let domain = image_box(fixed);
    let coarsest = coarsest_cells(&domain, params);
    let finest = coarsest.map(|c| c << (params.levels - 1));
    let mut lattice = ControlLattice::zeros(coarsest, domain.min.coords(), domain.max.coords())?;
    let mut levels = Vec::with_capacity(params.levels);
    for level in 0..params.levels {
        if level > 0 {
            lattice = lattice.refine()?;
        }
        let started = Instant::now();
        let shrink = 1usize << (params.levels - 1 - level);
        let par = params.parallelism;
        // The finest level reads the fixed image itself: no copy of a full volume.
        let fixed_level = if shrink == 1 { Cow::Borrowed(fixed) } else { Cow::Owned(fixed.shrink(shrink, par)?) };
        // Level 0 is the coarsest: an image too small for it is refused before any work, and not as "no overlap".
        let voxels: usize = fixed_level.dims().iter().product();
        if voxels < MIN_SAMPLES_INSIDE {
            return Err(SolverError::Image(format!(
                "the fixed image is too small for {} levels: shrunk {shrink}× for the coarsest, it has {voxels} \
                 voxels, and the measure needs at least {MIN_SAMPLES_INSIDE} samples; use fewer levels",
                params.levels
            )));
        }
        let warped = {
            let moving_level =
                if shrink == 1 { Cow::Borrowed(moving) } else { Cow::Owned(moving.shrink(shrink, par)?) };
            pulled_back(&fixed_level, &moving_level, start, par)?
        };
        let wanted = params.samples.max(SAMPLES_PER_COEFFICIENT * lattice.coefficients().len());
        // Local correlation draws patches of points around its samples.
        let draws = if params.similarity == Similarity::Lncc { wanted.div_ceil(lncc::PATCH_POINTS) } else { wanted };
        let (samples, _) = draw_samples(&fixed_level, draws, params.bins, params.seed.wrapping_add(level as u64))?;
        let metric = match params.similarity {
            Similarity::Mi => LevelMetric::Mi(Metric::new(&warped, &samples, &lattice, params.bins, par, device)?),
            Similarity::Ngf => LevelMetric::Ngf(Box::new(Ngf::new(&fixed_level, &warped, &samples, &lattice, par)?)),
            Similarity::Lncc => LevelMetric::Lncc(Lncc::new(&fixed_level, &warped, &samples, &lattice, par, device)?),
        };
        let pins = pairs
            .iter()
            .map(|p| {
                let q = p.fixed.coords();
                Pin { fixed: q, moving: p.moving.coords(), footprint: Footprint::of(&lattice, q) }
            })
            .collect();
        let objective = Objective {
            metric,
            checks: jacobian_points(&lattice, finest),
            bending: Bending::new(&lattice),
            pins,
            start,
            dims: lattice.dims(),
            params,
            evaluations: Cell::new(0),
            level,
            progress: RefCell::new(progress),
            failure: RefCell::new(None),
        };
        let voxel_mm = fixed_level.spacing_mm().into_iter().fold(f64::INFINITY, f64::min);
        let report = objective.optimise(&mut lattice, voxel_mm).map_err(|stop| match stop {
            Stop::Cancelled => SolverError::Cancelled,
            Stop::NoOverlap => metric::no_overlap(),
            Stop::Failed(e) => e,
        })?;
        levels.push(LevelReport { shrink, seconds: started.elapsed().as_secs_f64(), ..report });
    }
    Ok(Registration { deformation: FreeFormDeformation::new(lattice), levels })
}

/// det ∇u of the registered pull-back u = u₀ ∘ T at the centres of a `dims` grid over the fixed image's box.
#[must_use]
pub fn folding(
    registration: &Registration,
    start: &dyn Warp<Moving, Fixed>,
    fixed: &Image<Fixed>,
    dims: [usize; 3],
    parallelism: Parallelism,
) -> JacobianReport {
    jacobian_determinants(&registration.deformation.pullback(start), &image_box(fixed), dims, parallelism)
}

impl RegisterParams {
    /// Refuses unusable parameters, naming them.
    ///
    /// # Errors
    /// [`SolverError::InvalidParameter`].
    pub fn validate(&self) -> Result<()> {
        check(self)
    }
}

fn check(params: &RegisterParams) -> Result<()> {
    let bad = |what: String| Err(SolverError::InvalidParameter(what));
    if !(params.grid_mm.is_finite() && params.grid_mm > 0.0) {
        return bad(format!("control spacing {} mm (must be positive)", params.grid_mm));
    }
    if params.levels == 0 || params.levels > 8 {
        return bad(format!("{} levels (1 to 8)", params.levels));
    }
    if !(params.landmark_weight.is_finite() && params.landmark_weight >= 0.0) {
        return bad(format!("landmark weight {} (must be ≥ 0)", params.landmark_weight));
    }
    if !(params.bending_weight.is_finite() && params.bending_weight >= 0.0) {
        return bad(format!("bending weight {} (must be ≥ 0)", params.bending_weight));
    }
    if params.bins < 2 * PAD_BINS + 4 || params.bins > 1024 {
        return bad(format!("{} histogram bins (8 to 1024)", params.bins));
    }
    if params.samples < MIN_SAMPLES_INSIDE {
        return bad(format!("{} samples (at least {MIN_SAMPLES_INSIDE})", params.samples));
    }
    Ok(())
}

/// The box of the fixed image's voxel centres (the bounding box of its 8 corner centres).
fn image_box<S: Space>(image: &Image<S>) -> Aabb<S> {
    let d = image.dims().map(|n| (n - 1) as f64);
    let corners: Vec<Point3<S>> = (0..8)
        .map(|c| {
            let ijk = [d[0] * (c & 1) as f64, d[1] * ((c >> 1) & 1) as f64, d[2] * ((c >> 2) & 1) as f64];
            Point3::from_array(image.space_from_index().apply_point(Point3::from_array(ijk)).coords())
        })
        .collect();
    Aabb::around(&corners, 0.0).unwrap_or_else(|| Aabb::new(corners[0], corners[0]))
}

/// Cells per axis of the coarsest lattice: the finest (2^(levels − 1) times as many) is at most `grid_mm` apart.
fn coarsest_cells(domain: &Aabb<Fixed>, params: &RegisterParams) -> [usize; 3] {
    let size = domain.size();
    let factor = (1usize << (params.levels - 1)) as f64;
    std::array::from_fn(|a| ((size[a] / params.grid_mm / factor).ceil() as usize).max(1))
}

/// The moving image pulled back by u₀ onto `grid`'s voxels: m(u₀(y)), NaN where u₀(y) leaves the moving image.
fn pulled_back(
    grid: &Image<Fixed>,
    moving: &Image<Moving>,
    start: &dyn Warp<Moving, Fixed>,
    parallelism: Parallelism,
) -> Result<Image<Fixed>> {
    let [nx, ny, nz] = grid.dims();
    let plane = nx * ny;
    let mut values = vec![0.0f32; plane * nz];
    let slice = |(k, out): (usize, &mut [f32])| {
        let xs: Vec<[f64; 3]> = (0..plane).map(|n| grid.voxel_point(n % nx, n / nx, k)).collect();
        let mut ys = vec![[0.0; 3]; plane];
        start.apply_batch_raw(&xs, &mut ys);
        for (o, y) in out.iter_mut().zip(&ys) {
            *o = moving.sample(*y).map_or(f32::NAN, |v| v as f32);
        }
    };
    match parallelism {
        Parallelism::Sequential => values.chunks_mut(plane).enumerate().for_each(slice),
        Parallelism::Rayon => values.par_chunks_mut(plane).enumerate().for_each(slice),
    }
    Image::new(grid.dims(), values, *grid.space_from_index())
}

/// Each level draws at least this many samples per lattice coefficient (fewer when the level has fewer voxels): with
/// fewer, the deformation has the freedom to fit the images' noise.
pub const SAMPLES_PER_COEFFICIENT: usize = 10;

/// One landmark pair as the objective reads it.
#[derive(Clone, Copy, Debug)]
struct Pin {
    fixed: [f64; 3],
    moving: [f64; 3],
    footprint: Footprint,
}

/// Why a level stopped early.
#[derive(Debug)]
enum Stop {
    Cancelled,
    /// Too few samples inside the pulled-back moving image at the level's start.
    NoOverlap,
    /// The device failed.
    Failed(SolverError),
}

/// The landmark weight at `level` (0 the coarsest): β at the coarsest level, and 1/8 of the level before at each finer
/// one, the ratio of their control cells' volumes. The similarity is a mean over the samples, so each coefficient's
/// share of it shrinks with its cell (8 times a level), while a pair pulls on the coefficients around it as hard at
/// every level: with β fixed, the pairs would outweigh the images more at each level, and they hold 6 points of a
/// deformation that the images see everywhere. So the balance of the first level is kept (measured in
/// docs/accuracy.md: on the peer comparison's case the fixed β gave a mean TRE of 0.255 mm, this schedule 0.233).
#[must_use]
pub fn level_landmark_weight(landmark_weight: f64, level: usize) -> f64 {
    landmark_weight * 0.125f64.powi(i32::try_from(level).unwrap_or(i32::MAX))
}

/// A deformation whose det(I + ∇D) falls below this at a check point is refused (module docs).
pub const MIN_DETERMINANT: f64 = 0.1;

/// The points where det(I + ∇D) of `lattice` is checked: 2 × 2 × 2 per cell of the finest level's lattice (`finest`
/// cells per axis), at its quarter points; the same points at every level.
fn jacobian_points(lattice: &ControlLattice, finest: [usize; 3]) -> Vec<JacobianPoint> {
    let (lo, hi) = (lattice.min_mm(), lattice.max_mm());
    let cells = finest;
    let h: [f64; 3] = std::array::from_fn(|a| (hi[a] - lo[a]) / cells[a] as f64);
    let mut out = Vec::with_capacity(8 * cells.iter().product::<usize>());
    for k in 0..2 * cells[2] {
        for j in 0..2 * cells[1] {
            for i in 0..2 * cells[0] {
                let x = [i, j, k].map(|n| 0.5 * n as f64 + 0.25);
                out.push(JacobianPoint::of(lattice, std::array::from_fn(|a| lo[a] + x[a] * h[a])));
            }
        }
    }
    out
}

/// What hears [`register`]'s progress.
type ProgressFn<'p> = dyn FnMut(&RegisterProgress) -> ControlFlow<()> + 'p;

/// The similarity of one level.
#[derive(Debug)]
enum LevelMetric<'a> {
    Mi(Metric<'a>),
    Ngf(Box<Ngf>),
    Lncc(Lncc<'a>),
}

impl LevelMetric<'_> {
    fn evaluate(&self, phi: &[f64], dims: [usize; 3]) -> Result<Option<Evaluation>> {
        match self {
            Self::Mi(m) => m.evaluate(phi, dims),
            Self::Ngf(m) => Ok(m.evaluate(phi, dims)),
            Self::Lncc(m) => m.evaluate(phi, dims),
        }
    }

    fn samples(&self) -> usize {
        match self {
            Self::Mi(m) => m.reader.len(),
            Self::Ngf(m) => m.samples(),
            Self::Lncc(m) => m.samples(),
        }
    }
}

/// E(φ) at one level (module docs).
struct Objective<'a, 'p> {
    metric: LevelMetric<'a>,
    /// Where det(I + ∇D) must stay above [`MIN_DETERMINANT`].
    checks: Vec<JacobianPoint>,
    bending: Bending,
    pins: Vec<Pin>,
    start: &'a dyn Warp<Moving, Fixed>,
    dims: [usize; 3],
    params: &'a RegisterParams,
    evaluations: Cell<usize>,
    level: usize,
    progress: RefCell<&'p mut ProgressFn<'p>>,
    /// The device's error, when an evaluation failed (the optimiser is then stopped).
    failure: RefCell<Option<SolverError>>,
}

/// The terms of E at one φ.
#[derive(Clone, Copy, Debug, Default)]
struct Parts {
    similarity: f64,
    bending_energy: f64,
    /// Σ |u(qᵢ) − pᵢ|², mm².
    landmark_sum_sq: f64,
    inside: usize,
}

impl Objective<'_, '_> {
    /// The smallest det(I + ∇D) over the check points (the order the minimum is taken in does not change it).
    fn min_determinant(&self, phi: &[f64]) -> f64 {
        let dims = self.dims;
        let det = |p: &JacobianPoint| p.determinant(phi, dims);
        match self.params.parallelism {
            Parallelism::Sequential => self.checks.iter().map(det).fold(f64::INFINITY, f64::min),
            Parallelism::Rayon => self.checks.par_iter().with_min_len(256).map(det).reduce(|| f64::INFINITY, f64::min),
        }
    }

    /// E(φ) and ∂E/∂φ, or `None` where E is not defined: too few samples inside, or (`check`) a deformation that
    /// (nearly) folds.
    fn evaluate(&self, phi: &[f64], check: bool) -> Result<Option<(f64, Vec<f64>, Parts)>> {
        if check {
            let det = self.min_determinant(phi);
            if det.is_nan() || det < MIN_DETERMINANT {
                return Ok(None);
            }
        }
        let Some(similar) = self.metric.evaluate(phi, self.dims)? else { return Ok(None) };
        let mut gradient = similar.gradient;
        for g in &mut gradient {
            *g = -*g;
        }
        let alpha = self.params.bending_weight;
        let bending_energy = self.bending.energy_adding_gradient(phi, alpha, &mut gradient);
        let beta = level_landmark_weight(self.params.landmark_weight, self.level);
        let mut landmark_sum_sq = 0.0;
        for pin in &self.pins {
            let d = pin.footprint.displacement(phi, self.dims);
            let y = [pin.fixed[0] + d[0], pin.fixed[1] + d[1], pin.fixed[2] + d[2]];
            let u = self.start.apply_raw(y);
            let r = nalgebra::Vector3::from(std::array::from_fn::<f64, 3, _>(|a| u[a] - pin.moving[a]));
            landmark_sum_sq += r.norm_squared();
            if beta > 0.0 {
                let v = self.start.jacobian_raw(y).transpose() * r * (2.0 * beta);
                pin.footprint.scatter([v[0], v[1], v[2]], self.dims, &mut gradient);
            }
        }
        let cost = -similar.similarity + alpha * bending_energy + beta * landmark_sum_sq;
        let parts = Parts { similarity: similar.similarity, bending_energy, landmark_sum_sq, inside: similar.inside };
        Ok(Some((cost, gradient, parts)))
    }

    /// Minimises E from `lattice`'s coefficients by L-BFGS ([`lbfgs`]) and leaves the result in it. `voxel_mm` is the
    /// level's voxel: the first step moves the largest coefficient by one voxel, and no step by more than 2.
    fn optimise(&self, lattice: &mut ControlLattice, voxel_mm: f64) -> std::result::Result<LevelReport, Stop> {
        let phi0 = lattice.coefficients().to_vec();
        // Where the last level left φ is accepted as it is: the check is for steps.
        let Some((cost0, gradient0, parts0)) = self.evaluate(&phi0, false).map_err(Stop::Failed)? else {
            return Err(Stop::NoOverlap);
        };
        let settings = lbfgs::Settings {
            max_iterations: self.params.max_iterations,
            first_step: voxel_mm,
            max_step: 2.0 * voxel_mm,
            tolerance: COST_TOLERANCE,
        };
        let mut parts = parts0;
        let minimum = lbfgs::minimise(phi0, (cost0, gradient0), &settings, &mut |phi| {
            let n = self.evaluations.get() + 1;
            self.evaluations.set(n);
            let (cost, gradient, at) = match self.evaluate(phi, true) {
                Ok(Some(value)) => value,
                Ok(None) => return lbfgs::Value::Undefined,
                Err(e) => {
                    *self.failure.borrow_mut() = Some(e);
                    return lbfgs::Value::Stop;
                }
            };
            let report = RegisterProgress {
                level: self.level,
                levels: self.params.levels,
                evaluation: n,
                max_evaluations: 2 * self.params.max_iterations,
                similarity: at.similarity,
            };
            if (self.progress.borrow_mut())(&report).is_break() {
                return lbfgs::Value::Stop;
            }
            parts = at;
            lbfgs::Value::At(cost, gradient)
        });
        if minimum.end == lbfgs::End::Stopped {
            return Err(self.failure.take().map_or(Stop::Cancelled, Stop::Failed));
        }
        // The last evaluation may be a rejected trial step: the parts of the point kept are evaluated again.
        let parts = self.evaluate(&minimum.x, false).map_err(Stop::Failed)?.map_or(parts, |(_, _, p)| p);
        lattice.coefficients_mut().copy_from_slice(&minimum.x);
        let pins = self.pins.len().max(1) as f64;
        Ok(LevelReport {
            shrink: 0,
            control_spacing_mm: lattice.spacing_mm(),
            control_points: lattice.dims().iter().product(),
            samples: self.metric.samples(),
            samples_inside: parts.inside,
            iterations: minimum.iterations,
            evaluations: self.evaluations.get(),
            similarity_start: parts0.similarity,
            similarity: parts.similarity,
            bending_energy: parts.bending_energy,
            landmark_weight: level_landmark_weight(self.params.landmark_weight, self.level),
            landmark_rms_mm: (parts.landmark_sum_sq / pins).sqrt(),
            seconds: 0.0,
        })
    }
}

/// A level stops when E decreases by less than this fraction over an iteration.
const COST_TOLERANCE: f64 = 1e-6;

#[cfg(test)]
mod tests {
    use nalgebra::Vector3;
    use warpbench_io::geometry::{Index, Transform};

    use super::*;
    use crate::linear::AffineWarp;

    /// A smooth 24³ image of Gaussian blobs, 3 mm voxels, in space S.
    fn blobs<S: Space>(shift: f64) -> Image<S> {
        let n = 24;
        let centres =
            [[20.0, 30.0, 35.0, 1.0], [45.0, 40.0, 25.0, -0.7], [30.0, 50.0, 45.0, 0.5], [50.0, 20.0, 50.0, 0.8]];
        let values = (0..n * n * n)
            .map(|o| {
                let x = [(o % n) as f64 * 3.0, ((o / n) % n) as f64 * 3.0, (o / (n * n)) as f64 * 3.0];
                centres
                    .iter()
                    .map(|c| {
                        c[3] * (-((x[0] - c[0] - shift).powi(2) + (x[1] - c[1]).powi(2) + (x[2] - c[2]).powi(2))
                            / 200.0)
                            .exp()
                    })
                    .sum::<f64>() as f32
            })
            .collect();
        Image::new([n, n, n], values, Transform::<S, Index>::from_scale_translation([3.0; 3], [0.0; 3]))
            .expect("test input")
    }

    /// A start that shears, scales and shifts a little.
    fn skewed_start() -> AffineWarp<Moving, Fixed> {
        AffineWarp::<Moving, Fixed>::new(
            Matrix3::new(1.01, 0.02, 0.0, -0.01, 0.99, 0.0, 0.0, 0.03, 1.0),
            [0.5, -0.3, 0.2],
        )
    }

    /// The blobs, their shifted copy pulled back through [`skewed_start`], and a 3³-cell lattice of seeded
    /// coefficients up to 5 × `amplitude` mm.
    fn skewed_case(amplitude: f64) -> (Image<Fixed>, Image<Fixed>, ControlLattice) {
        let fixed = blobs::<Fixed>(0.0);
        let moving = blobs::<Moving>(2.0);
        let domain = image_box(&fixed);
        let mut lattice =
            ControlLattice::zeros([3, 3, 3], domain.min.coords(), domain.max.coords()).expect("test input");
        for (n, c) in lattice.coefficients_mut().iter_mut().enumerate() {
            *c = ((n * 37 % 11) as f64 - 5.0) * amplitude;
        }
        let warped = pulled_back(&fixed, &moving, &skewed_start(), Parallelism::Sequential).expect("test input");
        (fixed, warped, lattice)
    }

    /// Central differences of E against its analytic gradient, for `similarity`, with step `h`. NGF's terms are 10⁻⁷
    /// to 10⁻⁵ (a mean of squared cosines over 5 000 samples), so its step is larger, for the rounding of E; the
    /// trilinear gradient it reads jumps across cell faces only by second differences of the smooth blobs.
    fn check_gradient(similarity: Similarity, h: f64) {
        let (fixed, warped, lattice) = skewed_case(0.2);
        let start = skewed_start();
        let params = RegisterParams {
            similarity,
            samples: 5_000,
            bending_weight: 50.0,
            landmark_weight: 0.3,
            ..RegisterParams::default()
        };
        let (samples, _) = draw_samples(&fixed, params.samples, params.bins, 1).expect("test input");
        let metric = match similarity {
            Similarity::Mi => LevelMetric::Mi(
                Metric::new(&warped, &samples, &lattice, params.bins, Parallelism::Sequential, None)
                    .expect("test input"),
            ),
            Similarity::Ngf => LevelMetric::Ngf(Box::new(
                Ngf::new(&fixed, &warped, &samples, &lattice, Parallelism::Sequential).expect("test input"),
            )),
            Similarity::Lncc => {
                let (centres, _) = draw_samples(&fixed, 200, params.bins, 1).expect("test input");
                LevelMetric::Lncc(
                    Lncc::new(&fixed, &warped, &centres, &lattice, Parallelism::Sequential, None).expect("test input"),
                )
            }
        };
        let pins = [[20.0, 25.0, 30.0], [40.0, 45.0, 35.0]]
            .map(|q| Pin { fixed: q, moving: [q[0] + 1.0, q[1], q[2] - 0.5], footprint: Footprint::of(&lattice, q) })
            .to_vec();
        let mut progress = |_: &RegisterProgress| ControlFlow::Continue(());
        let objective = Objective {
            metric,
            checks: jacobian_points(&lattice, lattice.cells()),
            bending: Bending::new(&lattice),
            pins,
            start: &start,
            dims: lattice.dims(),
            params: &params,
            evaluations: Cell::new(0),
            level: 0,
            progress: RefCell::new(&mut progress),
            failure: RefCell::new(None),
        };
        let phi = lattice.coefficients().to_vec();
        let (_, gradient, _) = objective.evaluate(&phi, true).expect("test input").expect("test input");
        for index in (0..phi.len()).step_by(23) {
            let mut p = phi.clone();
            p[index] += h;
            let up = objective.evaluate(&p, true).expect("test input").expect("test input").0;
            p[index] -= 2.0 * h;
            let down = objective.evaluate(&p, true).expect("test input").expect("test input").0;
            let numeric = (up - down) / (2.0 * h);
            assert!(
                // 0.5 %, plus the rounding of E (about 1e-16 of E ≈ 1, over 2h).
                (numeric - gradient[index]).abs() < 5e-3 * gradient[index].abs() + 1e-15 / h,
                "{index}: {numeric} vs {}",
                gradient[index]
            );
        }
    }

    /// A [`SampleDevice`] in f64 on the CPU, written from the trait's contract alone: the device path's plumbing
    /// (the weights, the order of the samples, the signs) against the CPU path's.
    struct F64Device;

    struct F64Level {
        image: Image<Fixed>,
        lattice_dims: [usize; 3],
        samples: Vec<device::DeviceSample>,
        gradients: std::sync::Mutex<Vec<[f64; 3]>>,
    }

    impl SampleDevice for F64Device {
        fn describe(&self) -> String {
            "f64 test device".into()
        }

        fn prepare<'d>(
            &'d self,
            level: &device::DeviceLevel<'_>,
        ) -> std::result::Result<Box<dyn device::DeviceSamples + 'd>, String> {
            Ok(Box::new(F64Level {
                image: level.image.clone(),
                lattice_dims: level.lattice_dims,
                samples: level.samples.to_vec(),
                gradients: std::sync::Mutex::new(vec![[0.0; 3]; level.samples.len()]),
            }))
        }
    }

    impl device::DeviceSamples for F64Level {
        fn values(&self, phi: &[f64], out: &mut [f64]) -> std::result::Result<(), String> {
            let a = self.image.index_from_space_linear();
            let space_from_index = *self.image.space_from_index();
            let mut gradients = self.gradients.lock().map_err(|e| e.to_string())?;
            for ((s, o), g) in self.samples.iter().zip(out.iter_mut()).zip(gradients.iter_mut()) {
                let d = Footprint { start: s.first, weights: s.weights }.displacement(phi, self.lattice_dims);
                let eta = Vector3::from(s.index) + a * Vector3::from(d);
                let y = space_from_index.apply_point(Point3::new(eta[0], eta[1], eta[2])).coords();
                match self.image.sample_with_gradient(y) {
                    Some((v, grad)) if v.is_finite() => (*o, *g) = (v, grad),
                    _ => (*o, *g) = (f64::NAN, [f64::NAN; 3]),
                }
            }
            Ok(())
        }

        fn weighted_gradient(&self, weights: &[f64], out: &mut [f64]) -> std::result::Result<(), String> {
            out.fill(0.0);
            let gradients = self.gradients.lock().map_err(|e| e.to_string())?;
            for ((s, &w), g) in self.samples.iter().zip(weights).zip(gradients.iter()) {
                if w != 0.0 {
                    let v = g.map(|c| c * w);
                    Footprint { start: s.first, weights: s.weights }.scatter(v, self.lattice_dims, out);
                }
            }
            Ok(())
        }
    }

    /// A device that fails at its third evaluation.
    struct FailingDevice(std::sync::atomic::AtomicUsize);

    impl SampleDevice for FailingDevice {
        fn describe(&self) -> String {
            "failing test device".into()
        }

        fn prepare<'d>(
            &'d self,
            level: &device::DeviceLevel<'_>,
        ) -> std::result::Result<Box<dyn device::DeviceSamples + 'd>, String> {
            let inner = F64Device.prepare(level)?;
            Ok(Box::new(Failing { inner, calls: &self.0 }))
        }
    }

    struct Failing<'d> {
        inner: Box<dyn device::DeviceSamples + 'd>,
        calls: &'d std::sync::atomic::AtomicUsize,
    }

    impl device::DeviceSamples for Failing<'_> {
        fn values(&self, phi: &[f64], out: &mut [f64]) -> std::result::Result<(), String> {
            if self.calls.fetch_add(1, std::sync::atomic::Ordering::SeqCst) >= 2 {
                return Err("the test device was lost".into());
            }
            self.inner.values(phi, out)
        }

        fn weighted_gradient(&self, weights: &[f64], out: &mut [f64]) -> std::result::Result<(), String> {
            self.inner.weighted_gradient(weights, out)
        }
    }

    /// `similarity` at the lattice of [`skewed_case`] on the CPU and on [`F64Device`]: the same value and gradient.
    fn read_on_a_device_is_the_cpus(similarity: Similarity, smallest_gradient: f64) {
        let (fixed, warped, lattice) = skewed_case(0.4);
        let seq = Parallelism::Sequential;
        let metric = |device: Option<&'static F64Device>| match similarity {
            Similarity::Mi => {
                let (samples, _) = draw_samples(&fixed, 5_000, 32, 1).expect("test input");
                LevelMetric::Mi(
                    Metric::new(&warped, &samples, &lattice, 32, seq, device.map(|d| d as _)).expect("input"),
                )
            }
            Similarity::Lncc => {
                let (centres, _) = draw_samples(&fixed, 300, 32, 1).expect("test input");
                LevelMetric::Lncc(
                    Lncc::new(&fixed, &warped, &centres, &lattice, seq, device.map(|d| d as _)).expect("input"),
                )
            }
            Similarity::Ngf => unreachable!("NGF has no device path"),
        };
        let phi = lattice.coefficients();
        let a = metric(None).evaluate(phi, lattice.dims()).expect("cpu").expect("inside");
        let b = metric(Some(&F64Device)).evaluate(phi, lattice.dims()).expect("device").expect("inside");
        assert_eq!(a.inside, b.inside);
        assert!((a.similarity - b.similarity).abs() < 1e-12, "{} vs {}", a.similarity, b.similarity);
        let largest = a.gradient.iter().fold(0.0f64, |m, g| m.max(g.abs()));
        assert!(largest > smallest_gradient, "a trivial gradient: {largest}");
        for (i, (x, y)) in a.gradient.iter().zip(&b.gradient).enumerate() {
            assert!((x - y).abs() <= 1e-10 * largest, "coefficient {i}: {x} vs {y}");
        }
    }

    #[test]
    fn mutual_information_read_on_a_device_is_the_cpus() {
        read_on_a_device_is_the_cpus(Similarity::Mi, 1e-3);
    }

    #[test]
    fn local_correlation_read_on_a_device_is_the_cpus() {
        read_on_a_device_is_the_cpus(Similarity::Lncc, 1e-4);
    }

    #[test]
    fn an_image_too_small_for_a_patch_is_refused_by_local_correlation() {
        // 2 × 2 × 2 voxels: a patch's points are 2 voxels apart, so each keeps its centre alone.
        let values = (0..8).map(|v| v as f32).collect();
        let tiny = Image::<Fixed>::new(
            [2, 2, 2],
            values,
            Transform::<Fixed, Index>::from_scale_translation([2.0; 3], [0.0; 3]),
        )
        .expect("test input");
        let domain = image_box(&tiny);
        let lattice = ControlLattice::zeros([1, 1, 1], domain.min.coords(), domain.max.coords()).expect("test input");
        let (centres, _) = draw_samples(&tiny, 20, 32, 1).expect("test input");
        match Lncc::new(&tiny, &tiny, &centres, &lattice, Parallelism::Sequential, None) {
            Err(SolverError::Image(message)) => assert!(message.contains("too small"), "{message}"),
            other => panic!("expected a refusal, got {other:?}"),
        }
    }

    #[test]
    fn an_image_too_small_for_the_levels_is_refused_as_such() {
        // 24³ shrunk 4× for three levels is 6³ = 216 voxels, fewer than the samples MI needs; two levels are 12³.
        let fixed = blobs::<Fixed>(0.0);
        let moving = blobs::<Moving>(1.0);
        let start = AffineWarp::<Moving, Fixed>::identity();
        let mut progress = |_: &RegisterProgress| ControlFlow::Continue(());
        let params = RegisterParams { samples: 1_000, levels: 3, grid_mm: 30.0, ..RegisterParams::default() };
        match register(&fixed, &moving, &start, &[], &params, &mut progress) {
            Err(SolverError::Image(message)) => {
                assert!(message.contains("too small for 3 levels") && message.contains("216 voxels"), "{message}");
            }
            other => panic!("expected a refusal, got {:?}", other.map(|r| r.levels)),
        }
        let params = RegisterParams { levels: 2, max_iterations: 3, ..params };
        register(&fixed, &moving, &start, &[], &params, &mut progress).expect("two levels");
    }

    #[test]
    fn a_device_that_fails_stops_the_registration_with_its_message() {
        let fixed = blobs::<Fixed>(0.0);
        let moving = blobs::<Moving>(2.0);
        let params = RegisterParams { samples: 5_000, levels: 1, grid_mm: 30.0, ..RegisterParams::default() };
        let device = FailingDevice(std::sync::atomic::AtomicUsize::new(0));
        let mut progress = |_: &RegisterProgress| ControlFlow::Continue(());
        let start = AffineWarp::<Moving, Fixed>::identity();
        match register_on(&fixed, &moving, &start, &[], &params, Some(&device), &mut progress) {
            Err(SolverError::Device(message)) => assert_eq!(message, "the test device was lost"),
            other => panic!("expected the device's error, got {:?}", other.map(|r| r.levels)),
        }
        // And on the device, a registration that works converges like the CPU's.
        let on_device = register_on(&fixed, &moving, &start, &[], &params, Some(&F64Device), &mut progress)
            .expect("device registration");
        let cpu = register(&fixed, &moving, &start, &[], &params, &mut progress).expect("cpu registration");
        let (a, b) = (cpu.levels[0].similarity, on_device.levels[0].similarity);
        assert!((a - b).abs() < 1e-6 * a.abs(), "MI {a} on the CPU, {b} on the device");
    }

    #[test]
    fn the_gradient_is_the_derivative_of_the_objective_with_mutual_information() {
        check_gradient(Similarity::Mi, 1e-5);
    }

    #[test]
    fn the_gradient_is_the_derivative_of_the_objective_with_normalised_gradient_fields() {
        check_gradient(Similarity::Ngf, 1e-4);
    }

    #[test]
    fn the_gradient_is_the_derivative_of_the_objective_with_local_correlation() {
        check_gradient(Similarity::Lncc, 1e-5);
    }
}
