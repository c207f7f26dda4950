//! Automatic initial alignment: the rigid (or affine) pull-back that maximises the **Mattes mutual information**
//! between the fixed and the moving image, multi-resolution, from a centre-of-mass start (issue 18, item 1).
//!
//! # Metric
//!
//! Mattes, Haynor, Vesselle, Lewellen & Eubank (2003, "PET-CT image registration in the chest using free-form
//! deformations", IEEE TMI 22(1):120–128), as in ITK's `MattesMutualInformationImageToImageMetric`. Over a set of
//! fixed sample points x (seeded, jittered inside their voxels) and the pull-back T (fixed → moving), the joint
//! histogram of B bins uses a zero-order (box) Parzen window on the fixed values and a cubic B-spline β³ on the
//! moving ones:
//!
//! p(ι, κ; μ) = (1/n) Σ_x β⁰(ι − f̃(x)) · β³(κ − m̃(T(x; μ))),  f̃ = (f − f_min)/Δf + 2,  m̃ = (m − m_min)/Δm + 2,
//!
//! MI(μ) = Σ_{ι,κ} p(ι, κ) log( p(ι, κ) / (p_f(ι) p_m(κ)) ).
//!
//! Samples whose T(x) leaves the moving image are dropped (n counts the rest). Because Σ_ι p(ι, κ) = p_m(κ) and
//! Σ dp = 0, the derivative is
//!
//! ∂MI/∂μ = Σ_{ι,κ} ∂p(ι, κ)/∂μ · log( p(ι, κ) / p_m(κ) )
//!        = −(1/(n Δm)) Σ_x [ Σ_κ β³′(κ − m̃(T(x))) log( p(ι_x, κ) / p_m(κ) ) ] ∇m(T(x)) · ∂T/∂μ,
//!
//! two passes over the samples: the histogram, then one weight per sample. ∇m is the exact gradient of the
//! trilinear interpolant ([`crate::image`]).
//!
//! # Transform and optimiser
//!
//! T(x) = R (x − c) + c + t with c the fixed image's centre of mass, starting at R = I, t = c_m − c_f (the two
//! centres of mass over intensities above each image's minimum). The rotation is updated on the left,
//! R ← exp(\[δω\]×) R, so ∂T/∂δω · ∇m = r × ∇m with r = R (x − c); affine alignment replaces R by a free A, with
//! ∂T/∂A_rc · ∇m = ∇m_r (x − c)_c. Parameters are scaled so a unit step moves a point at the samples' RMS radius ρ
//! from c by about 1 mm (δω̃ = ρ δω, Ã = ρ A, as ITK's `SetOptimizerScalesFromPhysicalShift`).
//!
//! Each level runs a regular-step gradient ascent: a step of s mm along the scaled gradient, kept when MI rises and
//! undone with s halved otherwise (s is also halved when the gradient turns back), until s falls below
//! [`AlignParams::min_step_vox`] voxels of the level or [`AlignParams::max_iterations`]. The levels shrink both
//! images by box-averaging ([`Image::shrink`]), coarse to fine, each starting where the last one stopped.

use std::borrow::Cow;

use nalgebra::{Matrix3, Rotation3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use warpbench_io::geometry::Transform;

use crate::image::Image;
use crate::spaces::{Fixed, Moving};
use crate::warp::Parallelism;
use crate::{Result, SolverError};

/// The family the alignment searches.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum AlignKind {
    /// Rotation and translation (6 parameters).
    Rigid,
    /// Rigid first, then a free linear part and translation (12 parameters).
    Affine,
}

impl std::fmt::Display for AlignKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::Rigid => "rigid",
            Self::Affine => "affine",
        })
    }
}

/// Histogram padding bins on each side, so that β³'s support (±2 bins) stays inside.
pub(crate) const PAD_BINS: usize = 2;

/// How the alignment runs. [`Default`] suits head MRI and CT of about 1 mm.
#[derive(Clone, Debug, PartialEq)]
pub struct AlignParams {
    pub kind: AlignKind,
    /// Histogram bins per image, padding included (ITK's default is 50).
    pub bins: usize,
    /// Shrink factors, coarse to fine.
    pub shrink_factors: Vec<usize>,
    /// Fixed sample points per level (fewer when the level has fewer voxels).
    pub samples: usize,
    /// Gradient-ascent iterations per level, at most.
    pub max_iterations: usize,
    /// First step per level, in voxels of that level.
    pub first_step_vox: f64,
    /// A level stops when its step falls below this many of its voxels.
    pub min_step_vox: f64,
    /// The seed of the sample points.
    pub seed: u64,
    pub parallelism: Parallelism,
}

impl Default for AlignParams {
    fn default() -> Self {
        Self {
            kind: AlignKind::Rigid,
            bins: 50,
            shrink_factors: vec![4, 2, 1],
            samples: 40_000,
            max_iterations: 200,
            first_step_vox: 1.0,
            min_step_vox: 0.005,
            seed: 1,
            parallelism: Parallelism::Rayon,
        }
    }
}

/// What one resolution level did.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct LevelReport {
    pub shrink: usize,
    /// The family searched at this level.
    pub kind: AlignKind,
    pub iterations: usize,
    /// Fixed sample points that fell inside the moving image at the end.
    pub samples_inside: usize,
    pub samples: usize,
    pub mutual_information: f64,
    /// The step when the level stopped, in mm.
    pub final_step_mm: f64,
}

/// The result: the pull-back and how it was found.
#[derive(Clone, Debug)]
pub struct Alignment {
    /// T: fixed → moving (what a resampler and ITK's registration output are).
    pub moving_from_fixed: Transform<Moving, Fixed>,
    /// The centre-of-mass start.
    pub initial_moving_from_fixed: Transform<Moving, Fixed>,
    /// The mutual information at the end of the finest level (nats).
    pub mutual_information: f64,
    pub levels: Vec<LevelReport>,
}

/// T(x) = L (x − c) + c + t.
#[derive(Clone, Copy, Debug)]
struct Pose {
    linear: Matrix3<f64>,
    translation: Vector3<f64>,
    centre: Vector3<f64>,
}

impl Pose {
    fn apply(&self, x: &Vector3<f64>) -> Vector3<f64> {
        self.linear * (x - self.centre) + self.centre + self.translation
    }

    fn transform(&self) -> Transform<Moving, Fixed> {
        let t = self.centre + self.translation - self.linear * self.centre;
        Transform::from_linear_translation(self.linear, [t[0], t[1], t[2]])
    }
}

/// One fixed sample: its position and its fixed histogram bin.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Sample {
    pub(crate) x: Vector3<f64>,
    pub(crate) bin: usize,
}

/// Per sample, what pass 2 needs from pass 1.
#[derive(Clone, Copy, Debug, Default)]
struct Hit {
    inside: bool,
    fixed_bin: usize,
    /// m̃(T(x)), in bins.
    moving_bin: f64,
    gradient: Vector3<f64>,
}

/// The cubic B-spline β³(u), support (−2, 2).
pub(crate) fn bspline3(u: f64) -> f64 {
    let a = u.abs();
    if a < 1.0 {
        (4.0 - 6.0 * a * a + 3.0 * a * a * a) / 6.0
    } else if a < 2.0 {
        let b = 2.0 - a;
        b * b * b / 6.0
    } else {
        0.0
    }
}

/// dβ³/du.
pub(crate) fn bspline3_derivative(u: f64) -> f64 {
    let a = u.abs();
    let d = if a < 1.0 {
        -2.0 * a + 1.5 * a * a
    } else if a < 2.0 {
        let b = 2.0 - a;
        -0.5 * b * b
    } else {
        0.0
    };
    d * u.signum()
}

/// The metric over one level's samples.
struct Metric<'a> {
    moving: &'a Image<Moving>,
    samples: Vec<Sample>,
    bins: usize,
    moving_min: f64,
    moving_bin_width: f64,
    parallelism: Parallelism,
}

/// MI and its gradient in the pose's raw parameters: (δω, t) for rigid, (A row-major, t) for affine.
struct Evaluation {
    mutual_information: f64,
    gradient: Vec<f64>,
    inside: usize,
}

impl Metric<'_> {
    fn hit(&self, pose: &Pose, s: &Sample) -> Hit {
        let y = pose.apply(&s.x);
        match self.moving.sample_with_gradient([y[0], y[1], y[2]]) {
            Some((m, g)) => Hit {
                inside: true,
                fixed_bin: s.bin,
                moving_bin: ((m - self.moving_min) / self.moving_bin_width + PAD_BINS as f64)
                    .clamp(PAD_BINS as f64, (self.bins - PAD_BINS - 1) as f64),
                gradient: Vector3::from(g),
            },
            None => Hit::default(),
        }
    }

    fn evaluate(&self, pose: &Pose, kind: AlignKind, hits: &mut Vec<Hit>) -> Option<Evaluation> {
        let b = self.bins;
        hits.clear();
        hits.resize(self.samples.len(), Hit::default());
        let fill = |(h, s): (&mut Hit, &Sample)| *h = self.hit(pose, s);
        match self.parallelism {
            Parallelism::Rayon => hits.par_iter_mut().zip(self.samples.par_iter()).with_min_len(1024).for_each(fill),
            Parallelism::Sequential => hits.iter_mut().zip(self.samples.iter()).for_each(fill),
        }
        // Pass 1: the joint histogram, a partial one per chunk, added in the chunks' order.
        let histogram = |(hits, _): (&[Hit], &[Sample])| {
            let mut joint = vec![0.0f64; b * b];
            let mut inside = 0usize;
            for h in hits.iter().filter(|h| h.inside) {
                inside += 1;
                let row = &mut joint[h.fixed_bin * b..(h.fixed_bin + 1) * b];
                let k0 = h.moving_bin.floor() as usize;
                for (k, bin) in row.iter_mut().enumerate().skip(k0 - 1).take(4) {
                    *bin += bspline3(k as f64 - h.moving_bin);
                }
            }
            (joint, inside)
        };
        let (mut joint, inside) = self.by_chunks(hits, histogram).into_iter().fold(
            (vec![0.0f64; b * b], 0usize),
            |(mut joint, inside), (part, n)| {
                joint.iter_mut().zip(part).for_each(|(x, y)| *x += y);
                (joint, inside + n)
            },
        );
        if inside < MIN_SAMPLES_INSIDE {
            return None;
        }
        let norm = 1.0 / inside as f64;
        let (mi, log_ratio) = mutual_information(&mut joint, b, norm);
        // Pass 2: one weight per sample, then the chain rule through T.
        let params = match kind {
            AlignKind::Rigid => 6,
            AlignKind::Affine => 12,
        };
        let scale = -norm / self.moving_bin_width;
        let accumulate = |mut acc: Vec<f64>, (h, s): (&Hit, &Sample)| {
            if !h.inside {
                return acc;
            }
            let row = &log_ratio[h.fixed_bin * b..(h.fixed_bin + 1) * b];
            let k0 = h.moving_bin.floor() as usize;
            let w: f64 = (k0 - 1..=k0 + 2).map(|k| bspline3_derivative(k as f64 - h.moving_bin) * row[k]).sum();
            let g = h.gradient * (w * scale);
            let offset = s.x - pose.centre;
            match kind {
                AlignKind::Rigid => {
                    let r = pose.linear * offset;
                    let torque = r.cross(&g);
                    for a in 0..3 {
                        acc[a] += torque[a];
                        acc[3 + a] += g[a];
                    }
                }
                AlignKind::Affine => {
                    for row_i in 0..3 {
                        for col in 0..3 {
                            acc[row_i * 3 + col] += g[row_i] * offset[col];
                        }
                        acc[9 + row_i] += g[row_i];
                    }
                }
            }
            acc
        };
        let add = |mut a: Vec<f64>, b: Vec<f64>| {
            a.iter_mut().zip(b).for_each(|(x, y)| *x += y);
            a
        };
        // Fixed chunks summed in their order ([`Self::by_chunks`]).
        let chunk_sum = |(h, s): (&[Hit], &[Sample])| h.iter().zip(s).fold(vec![0.0; params], accumulate);
        let gradient = self.by_chunks(hits, chunk_sum).into_iter().fold(vec![0.0; params], add);
        Some(Evaluation { mutual_information: mi, gradient, inside })
    }

    /// `f` of each chunk of [`SAMPLE_CHUNK`] hits and their samples, in the chunks' order (computed on the threads
    /// `parallelism` allows): a sum over the results in this order does not depend on how the threads shared the
    /// work, so the same inputs and seed give the same alignment, bit for bit.
    fn by_chunks<T: Send>(&self, hits: &[Hit], f: impl Fn((&[Hit], &[Sample])) -> T + Sync + Send) -> Vec<T> {
        match self.parallelism {
            Parallelism::Rayon => {
                hits.par_chunks(SAMPLE_CHUNK).zip(self.samples.par_chunks(SAMPLE_CHUNK)).map(f).collect()
            }
            Parallelism::Sequential => {
                hits.chunks(SAMPLE_CHUNK).zip(self.samples.chunks(SAMPLE_CHUNK)).map(f).collect()
            }
        }
    }
}

/// MI of the joint histogram `joint` (b × b counts, fixed-major) scaled by `norm` (1/n) into probabilities in place,
/// and log(p(ι, κ) / p_m(κ)) where p > 0 (0 elsewhere): the per-bin weights of the gradient's pass (module docs).
pub(crate) fn mutual_information(joint: &mut [f64], b: usize, norm: f64) -> (f64, Vec<f64>) {
    for p in joint.iter_mut() {
        *p *= norm;
    }
    let (mut p_fixed, mut p_moving) = (vec![0.0; b], vec![0.0; b]);
    for i in 0..b {
        for k in 0..b {
            p_fixed[i] += joint[i * b + k];
            p_moving[k] += joint[i * b + k];
        }
    }
    let mut mi = 0.0;
    let mut log_ratio = vec![0.0; b * b];
    for i in 0..b {
        for k in 0..b {
            let p = joint[i * b + k];
            if p > 0.0 {
                mi += p * (p / (p_fixed[i] * p_moving[k])).ln();
                log_ratio[i * b + k] = (p / p_moving[k]).ln();
            }
        }
    }
    (mi, log_ratio)
}

/// Samples per chunk of the histogram's and the gradient's sums (the unit of their parallel work, summed in order).
pub(crate) const SAMPLE_CHUNK: usize = 2048;

/// Fewer fixed samples than this inside the moving image and the images are taken not to overlap.
pub const MIN_SAMPLES_INSIDE: usize = 500;

/// The intensity-weighted centre of mass over values above the image's minimum, in mm.
fn centre_of_mass<S: warpbench_io::geometry::Space>(
    image: &Image<S>,
    parallelism: Parallelism,
) -> Option<Vector3<f64>> {
    let (lo, _) = image.value_range(parallelism)?;
    let [nx, ny, nz] = image.dims();
    // Each slice (constant k) is summed on its own (in parallel where allowed); the slices' sums are added in
    // order, so the centre is the same to the bit on every run and either way.
    let slice = |k: usize| {
        let mut sum = Vector3::zeros();
        let mut mass = 0.0;
        for j in 0..ny {
            for i in 0..nx {
                let v = f64::from(image.at(i, j, k));
                if v.is_finite() && v > lo {
                    let w = v - lo;
                    sum += Vector3::from(image.voxel_point(i, j, k)) * w;
                    mass += w;
                }
            }
        }
        (sum, mass)
    };
    let slices: Vec<(Vector3<f64>, f64)> = match parallelism {
        Parallelism::Sequential => (0..nz).map(slice).collect(),
        Parallelism::Rayon => (0..nz).into_par_iter().map(slice).collect(),
    };
    let (sum, mass) = slices.iter().fold((Vector3::zeros(), 0.0), |(s, m), (ds, dm)| (s + ds, m + dm));
    (mass > 0.0).then(|| sum / mass)
}

/// Seeded fixed samples: points drawn uniformly over the box of `fixed`'s voxel centres, with their box bin.
pub(crate) fn draw_samples(
    fixed: &Image<Fixed>,
    count: usize,
    bins: usize,
    seed: u64,
) -> Result<(Vec<Sample>, Vec<Vector3<f64>>)> {
    let [nx, ny, nz] = fixed.dims();
    let total = nx * ny * nz;
    let count = count.min(total);
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut points = Vec::new();
    points.try_reserve_exact(count).map_err(|_| SolverError::Image(format!("no memory for {count} samples")))?;
    let mut values = Vec::with_capacity(count);
    // Bounded: at most 4 draws per sample (non-finite values are skipped).
    for _ in 0..count * 4 {
        if points.len() == count {
            break;
        }
        // Uniform over the box of voxel centres: a voxel's jitter is its neighbours' half voxels, and nothing is
        // clamped onto the box's faces. A sample on a face leaves the image under any outward step, so the measures
        // would jump at the very point a minimiser starts from (as they did until 2026-12-06).
        let mut along = |n: usize| if n > 1 { rng.random_range(0.0..(n - 1) as f64) } else { 0.0 };
        let xi = [along(nx), along(ny), along(nz)];
        if let Some(v) = fixed.sample_index(xi).filter(|v| v.is_finite()) {
            let x = fixed.space_from_index().apply_point(warpbench_io::geometry::Point3::from_array(xi)).coords();
            points.push(Vector3::from(x));
            values.push(v);
        }
    }
    let (lo, hi) = values.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &v| (lo.min(v), hi.max(v)));
    if hi <= lo || !hi.is_finite() {
        return Err(SolverError::Image("the fixed image has a single value: nothing to match".into()));
    }
    let width = (hi - lo) / (bins - 2 * PAD_BINS - 1) as f64;
    let samples = points
        .iter()
        .zip(&values)
        .map(|(x, v)| Sample {
            x: *x,
            bin: (((v - lo) / width).round() as usize).min(bins - 2 * PAD_BINS - 1) + PAD_BINS,
        })
        .collect();
    Ok((samples, points))
}

/// Aligns `moving` to `fixed`: the pull-back T (fixed → moving) that maximises their Mattes mutual information.
///
/// # Errors
/// [`SolverError::InvalidParameter`] for unusable parameters; [`SolverError::Image`] when an image is flat, the
/// images do not overlap (fewer than [`MIN_SAMPLES_INSIDE`] samples inside the moving image at the start of a
/// level), or there is no memory for a level.
pub fn align(fixed: &Image<Fixed>, moving: &Image<Moving>, params: &AlignParams) -> Result<Alignment> {
    if params.bins < 2 * PAD_BINS + 4 || params.bins > 1024 {
        return Err(SolverError::InvalidParameter(format!("{} histogram bins (8 to 1024)", params.bins)));
    }
    if params.shrink_factors.is_empty() || params.shrink_factors.iter().any(|&s| s == 0 || s > 64) {
        return Err(SolverError::InvalidParameter(format!(
            "shrink factors {:?} (each 1 to 64, at least one level)",
            params.shrink_factors
        )));
    }
    if params.samples < MIN_SAMPLES_INSIDE {
        return Err(SolverError::InvalidParameter(format!(
            "{} samples (at least {MIN_SAMPLES_INSIDE})",
            params.samples
        )));
    }
    let no_mass = |name: &str| SolverError::Image(format!("the {name} image has a single value: nothing to align"));
    let c_fixed = centre_of_mass(fixed, params.parallelism).ok_or_else(|| no_mass("fixed"))?;
    let c_moving = centre_of_mass(moving, params.parallelism).ok_or_else(|| no_mass("moving"))?;
    let mut pose = Pose { linear: Matrix3::identity(), translation: c_moving - c_fixed, centre: c_fixed };
    let initial = pose.transform();

    let mut levels = Vec::new();
    let mut mutual_information = 0.0;
    for (level, &shrink) in params.shrink_factors.iter().enumerate() {
        // The finest level reads the images themselves: no copy of a full volume.
        let fixed_level =
            if shrink == 1 { Cow::Borrowed(fixed) } else { Cow::Owned(fixed.shrink(shrink, params.parallelism)?) };
        let moving_level =
            if shrink == 1 { Cow::Borrowed(moving) } else { Cow::Owned(moving.shrink(shrink, params.parallelism)?) };
        let (moving_min, moving_max) = moving_level.value_range(params.parallelism).ok_or_else(|| no_mass("moving"))?;
        if moving_max <= moving_min {
            return Err(no_mass("moving"));
        }
        let (samples, points) =
            draw_samples(&fixed_level, params.samples, params.bins, params.seed.wrapping_add(level as u64))?;
        let radius_mm =
            (points.iter().map(|x| (x - c_fixed).norm_squared()).sum::<f64>() / points.len() as f64).sqrt().max(1.0);
        let metric = Metric {
            moving: &moving_level,
            samples,
            bins: params.bins,
            moving_min,
            moving_bin_width: (moving_max - moving_min) / (params.bins - 2 * PAD_BINS - 1) as f64,
            parallelism: params.parallelism,
        };
        let spacing_mm =
            fixed_level.spacing_mm().iter().chain(moving_level.spacing_mm().iter()).fold(0.0f64, |a, &b| a.max(b));
        // Affine refines a rigid result: the finest level only, after the rigid pass on it.
        let kinds: &[AlignKind] = match (params.kind, level + 1 == params.shrink_factors.len()) {
            (AlignKind::Affine, true) => &[AlignKind::Rigid, AlignKind::Affine],
            _ => &[AlignKind::Rigid],
        };
        for &kind in kinds {
            let report = ascend(&metric, &mut pose, kind, radius_mm, spacing_mm, shrink, params)?;
            mutual_information = report.mutual_information;
            levels.push(report);
        }
    }
    Ok(Alignment {
        moving_from_fixed: pose.transform(),
        initial_moving_from_fixed: initial,
        mutual_information,
        levels,
    })
}

/// The angle of the rotation in `linear`'s polar decomposition (the nearest rotation), in degrees; NaN when the
/// decomposition fails (a non-finite matrix).
#[must_use]
pub fn rotation_angle_deg(linear: &Matrix3<f64>) -> f64 {
    let svd = linear.svd(true, true);
    match (svd.u, svd.v_t) {
        (Some(u), Some(v_t)) => Rotation3::from_matrix(&(u * v_t)).angle().to_degrees(),
        _ => f64::NAN,
    }
}

/// The pose after a step of the scaled parameters `delta` (raw gradient direction already scaled).
fn stepped(pose: &Pose, kind: AlignKind, delta: &[f64], radius_mm: f64) -> Pose {
    let mut next = *pose;
    match kind {
        AlignKind::Rigid => {
            let omega = Vector3::new(delta[0], delta[1], delta[2]) / radius_mm;
            next.linear = Rotation3::new(omega).into_inner() * pose.linear;
            next.translation += Vector3::new(delta[3], delta[4], delta[5]);
        }
        AlignKind::Affine => {
            for r in 0..3 {
                for c in 0..3 {
                    next.linear[(r, c)] += delta[r * 3 + c] / radius_mm;
                }
                next.translation[r] += delta[9 + r];
            }
        }
    }
    next
}

/// One level's regular-step gradient ascent.
fn ascend(
    metric: &Metric<'_>,
    pose: &mut Pose,
    kind: AlignKind,
    radius_mm: f64,
    spacing_mm: f64,
    shrink: usize,
    params: &AlignParams,
) -> Result<LevelReport> {
    let mut hits = Vec::new();
    let overlap = || {
        SolverError::Image(format!(
            "fewer than {MIN_SAMPLES_INSIDE} of {} fixed samples fall inside the moving image: the images do not \
             overlap (are they in the same patient space?)",
            metric.samples.len()
        ))
    };
    let mut current = metric.evaluate(pose, kind, &mut hits).ok_or_else(overlap)?;
    // Gradient in scaled parameters: rotations (and the linear part) per radius, translations per mm.
    let scaled = |g: &[f64]| -> Vec<f64> {
        let linear = if kind == AlignKind::Rigid { 3 } else { 9 };
        g.iter().enumerate().map(|(i, v)| if i < linear { v / radius_mm } else { *v }).collect()
    };
    let mut step_mm = params.first_step_vox * spacing_mm;
    let min_step_mm = params.min_step_vox * spacing_mm;
    let mut previous_direction: Option<Vec<f64>> = None;
    let mut iterations = 0;
    while iterations < params.max_iterations && step_mm >= min_step_mm {
        iterations += 1;
        let g = scaled(&current.gradient);
        let norm = g.iter().map(|v| v * v).sum::<f64>().sqrt();
        if norm <= 0.0 || !norm.is_finite() {
            break;
        }
        let direction: Vec<f64> = g.iter().map(|v| v / norm).collect();
        if previous_direction.as_ref().is_some_and(|d| d.iter().zip(&direction).map(|(a, b)| a * b).sum::<f64>() < 0.0)
        {
            step_mm *= 0.5;
        }
        let delta: Vec<f64> = direction.iter().map(|d| d * step_mm).collect();
        let candidate = stepped(pose, kind, &delta, radius_mm);
        match metric.evaluate(&candidate, kind, &mut hits) {
            Some(next) if next.mutual_information >= current.mutual_information => {
                *pose = candidate;
                current = next;
                previous_direction = Some(direction);
            }
            _ => {
                step_mm *= 0.5;
                previous_direction = None;
            }
        }
    }
    Ok(LevelReport {
        shrink,
        kind,
        iterations,
        samples_inside: current.inside,
        samples: metric.samples.len(),
        mutual_information: current.mutual_information,
        final_step_mm: step_mm,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A smooth test image: a few Gaussian blobs on a 1.5 mm grid.
    fn blobs<S: warpbench_io::geometry::Space>(remap: impl Fn(f64) -> f64) -> Image<S> {
        let dims = [28, 26, 24];
        let centres =
            [([12.0, 14.0, 10.0], 6.0, 100.0), ([24.0, 20.0, 20.0], 5.0, 60.0), ([16.0, 28.0, 24.0], 7.0, 80.0)];
        let mut values = Vec::new();
        for k in 0..dims[2] {
            for j in 0..dims[1] {
                for i in 0..dims[0] {
                    let x = [i as f64 * 1.5, j as f64 * 1.5, k as f64 * 1.5];
                    let v: f64 = centres
                        .iter()
                        .map(|(c, s, a)| {
                            a * (-(0..3).map(|d| (x[d] - c[d]).powi(2)).sum::<f64>() / (2.0 * s * s)).exp()
                        })
                        .sum();
                    values.push(remap(v) as f32);
                }
            }
        }
        Image::new(dims, values, Transform::from_scale_translation([1.5; 3], [0.0; 3])).expect("test image")
    }

    /// The analytic gradient of MI equals central differences of MI in every parameter, rigid and affine, for the
    /// same modality and a remapped one (the sample set is fixed, so MI is a smooth function of the pose away from
    /// the trilinear cells' faces; the step is small enough that few samples cross one).
    #[test]
    fn the_mutual_information_gradient_matches_central_differences() {
        let fixed: Image<Fixed> = blobs(|v| v);
        for remap in [(|v| v) as fn(f64) -> f64, |v: f64| (v - 50.0).abs().sqrt()] {
            let moving: Image<Moving> = blobs(remap);
            let (samples, _) = draw_samples(&fixed, 4000, 32, 7).expect("samples");
            let (lo, hi) = moving.value_range(Parallelism::Sequential).expect("range");
            let metric = Metric {
                moving: &moving,
                samples,
                bins: 32,
                moving_min: lo,
                moving_bin_width: (hi - lo) / (32 - 2 * PAD_BINS - 1) as f64,
                parallelism: Parallelism::Sequential,
            };
            let pose = Pose {
                linear: Rotation3::new(Vector3::new(0.05, -0.03, 0.04)).into_inner(),
                translation: Vector3::new(0.7, -0.4, 0.3),
                centre: Vector3::new(20.0, 19.0, 17.0),
            };
            for (kind, n) in [(AlignKind::Rigid, 6), (AlignKind::Affine, 12)] {
                let mut hits = Vec::new();
                let at = metric.evaluate(&pose, kind, &mut hits).expect("overlap");
                for p in 0..n {
                    let h = 1e-5;
                    let mut delta = vec![0.0; n];
                    delta[p] = h;
                    let plus = metric.evaluate(&stepped(&pose, kind, &delta, 1.0), kind, &mut hits).expect("overlap");
                    delta[p] = -h;
                    let minus = metric.evaluate(&stepped(&pose, kind, &delta, 1.0), kind, &mut hits).expect("overlap");
                    let fd = (plus.mutual_information - minus.mutual_information) / (2.0 * h);
                    let scale = at.gradient.iter().fold(0.0f64, |a, g| a.max(g.abs()));
                    // Rotation steps are exp([δω]×) R: the same first-order parameters as the analytic gradient.
                    assert!(
                        (fd - at.gradient[p]).abs() < 0.02 * scale,
                        "{kind} parameter {p}: finite difference {fd} vs analytic {}",
                        at.gradient[p]
                    );
                }
            }
        }
    }

    /// Every sample lies strictly inside the image's box, so that no move small enough takes it out: a sample on the
    /// box's face (a jitter clamped onto the outermost voxel centres, as drawn until 2026-12-06) left the image under
    /// any outward step, and the measures jumped at the point a minimiser starts from. Each voxel still gets its
    /// share: the edge voxels, which lose half their jitter, about half the share of the others, not more.
    #[test]
    fn samples_lie_strictly_inside_the_box_in_their_voxels_share() {
        let fixed: Image<Fixed> = blobs(|v| v);
        let (samples, _) = draw_samples(&fixed, 20_000, 32, 3).expect("samples");
        let index_from_space = fixed.space_from_index().inverse().expect("invertible");
        let dims = fixed.dims();
        let (mut edge, mut interior) = (0usize, 0usize);
        for s in &samples {
            let xi = index_from_space.apply_point(warpbench_io::geometry::Point3::from_array(s.x.into())).coords();
            for a in 0..3 {
                let tiny = 1e-9;
                assert!(xi[a] > tiny && xi[a] < (dims[a] - 1) as f64 - tiny, "{xi:?} is on or past the box's face");
            }
            let on_edge = (0..3).any(|a| xi[a] < 0.5 || xi[a] > dims[a] as f64 - 1.5);
            if on_edge { edge += 1 } else { interior += 1 }
        }
        // Per voxel: the voxels within half a voxel of a face hold a sample with half (or less) the chance.
        let interior_voxels: usize = dims.iter().map(|n| n - 2).product();
        let edge_voxels = dims.iter().product::<usize>() - interior_voxels;
        let (per_edge, per_interior) = (edge as f64 / edge_voxels as f64, interior as f64 / interior_voxels as f64);
        assert!(per_edge < 0.6 * per_interior, "edge {per_edge:.3} vs interior {per_interior:.3} samples a voxel");
        assert!(per_edge > 0.3 * per_interior, "edge {per_edge:.3} vs interior {per_interior:.3} samples a voxel");
    }

    /// β³ sums to one over integer shifts and its derivative matches central differences.
    #[test]
    fn the_parzen_window_is_a_partition_of_unity_with_the_right_derivative() {
        for u in [0.0, 0.13, 0.5, 0.77] {
            let s: f64 = (-3..=3).map(|k| bspline3(f64::from(k) - u)).sum();
            assert!((s - 1.0).abs() < 1e-12);
            let h = 1e-6;
            for x in [u - 1.7, u - 0.4, u + 0.9, u + 1.5] {
                let fd = (bspline3(x + h) - bspline3(x - h)) / (2.0 * h);
                assert!((fd - bspline3_derivative(x)).abs() < 1e-6, "{x}");
            }
        }
    }
}
