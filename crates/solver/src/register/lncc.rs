//! Local normalised cross-correlation between the fixed image and the pulled-back moving image under a free-form
//! deformation, with its gradient in the lattice's coefficients: the measure for two images of one modality whose
//! intensities differ by a smooth gain and offset (MR–MR with different coils or bias fields), as ANTs' `CC` is.
//!
//! The fixed samples come in small patches: a seeded centre and the 3 × 3 × 3 points around it, [`PATCH_STEP`] voxels
//! of the level apart along its axes (the points outside the fixed image are left out, and a patch with fewer than
//! [`MIN_PATCH_POINTS`] is dropped). In a patch p whose points i have fixed values fᵢ and moving values
//! mᵢ = m'(xᵢ + D(xᵢ)) (those inside the moving image), with the sums of products of deviations from the patch's means
//! s_ff, s_mm and s_fm,
//!
//! cc_p = s_fm² / ((s_ff + n_p ε_f) (s_mm + n_p ε_m)),  LNCC = (1/P) Σ_p cc_p,
//!
//! 1 where the moving image is an affine function of the fixed one across the patch (of either sign), 0 where they
//! are unrelated. ε_f and ε_m are the squares of [`NOISE_SCALE`] times each image's standard deviation at the samples
//! (the moving one at the level's start), so that a patch where an image is flat, all noise, counts little.
//!
//! With A = s_ff + n_p ε_f and B = s_mm + n_p ε_m, ∂cc_p/∂mᵢ = 2 s_fm (fᵢ − f̄)/(A B) − 2 s_fm² (mᵢ − m̄)/(A B²), so
//! ∂LNCC/∂φ_k = Σᵢ wᵢ B_k(xᵢ) ∇m'(xᵢ + D(xᵢ)) with wᵢ = (1/P) ∂cc_p/∂mᵢ: a weight per sample, read on a device as
//! the mutual information's are ([`super::device`]).

use rayon::prelude::*;

use super::device::SampleDevice;
use super::metric::{Evaluation, no_overlap};
use super::samples::SampleReader;
use crate::align::{MIN_SAMPLES_INSIDE, Sample};
use crate::bspline::ControlLattice;
use crate::image::Image;
use crate::spaces::Fixed;
use crate::warp::Parallelism;

/// The points of a patch along each axis (3: a centre and one on each side).
const PATCH_SIDE: usize = 3;
/// Points per patch at most.
pub const PATCH_POINTS: usize = PATCH_SIDE * PATCH_SIDE * PATCH_SIDE;
/// The distance between a patch's neighbouring points, in voxels of the level's fixed image: a patch spans 4 voxels
/// (4 mm on the finest level of a 1-mm image, 16 mm on a level shrunk by 4).
pub const PATCH_STEP: f64 = 2.0;
/// A patch with fewer points in the fixed image (or, at an evaluation, in the moving one) is left out.
pub const MIN_PATCH_POINTS: usize = 8;
/// ε of each image as a fraction of its standard deviation at the samples.
pub const NOISE_SCALE: f64 = 0.05;

/// The measure over one level's patches.
#[derive(Debug)]
pub(super) struct Lncc<'a> {
    /// Every patch's points, patch after patch.
    pub(super) reader: SampleReader<'a>,
    /// f at each point.
    fixed_values: Vec<f64>,
    /// Where each patch's points are in `fixed_values` and the reader.
    patches: Vec<std::ops::Range<usize>>,
    epsilon_fixed: f64,
    epsilon_moving: f64,
    parallelism: Parallelism,
}

/// The patch-centred sums of one patch at one φ.
struct PatchSums {
    n: usize,
    f_mean: f64,
    m_mean: f64,
    sff: f64,
    smm: f64,
    sfm: f64,
}

impl<'a> Lncc<'a> {
    /// Patches around `centres` of `fixed` (the level's image), read in `warped` with footprints in `lattice`, on
    /// `device` when one is given.
    ///
    /// # Errors
    /// [`crate::SolverError::Image`] when the image is too small for a patch, either image is flat at the samples or
    /// no sample lands in `warped`; [`crate::SolverError::Device`] when the device cannot take the level.
    pub(super) fn new(
        fixed: &Image<Fixed>,
        warped: &'a Image<Fixed>,
        centres: &[Sample],
        lattice: &ControlLattice,
        parallelism: Parallelism,
        device: Option<&'a dyn SampleDevice>,
    ) -> crate::Result<Self> {
        let axes = fixed.space_from_index().linear();
        let offsets: Vec<[f64; 3]> = (0..PATCH_POINTS)
            .map(|n| {
                let o = [n % PATCH_SIDE, (n / PATCH_SIDE) % PATCH_SIDE, n / (PATCH_SIDE * PATCH_SIDE)]
                    .map(|c| (c as f64 - 1.0) * PATCH_STEP);
                let v = axes * nalgebra::Vector3::from(o);
                [v[0], v[1], v[2]]
            })
            .collect();
        let (mut points, mut fixed_values, mut patches) = (Vec::new(), Vec::new(), Vec::new());
        for c in centres {
            let first = points.len();
            for o in &offsets {
                let x = [c.x[0] + o[0], c.x[1] + o[1], c.x[2] + o[2]];
                if let Some(f) = fixed.sample(x).filter(|f| f.is_finite()) {
                    points.push(x);
                    fixed_values.push(f);
                }
            }
            if points.len() - first < MIN_PATCH_POINTS {
                points.truncate(first);
                fixed_values.truncate(first);
            } else {
                patches.push(first..points.len());
            }
        }
        if patches.is_empty() {
            return Err(crate::SolverError::Image(format!(
                "the fixed image ({} voxels at this level) is too small for local correlation's patches ({PATCH_SIDE} \
                 points a side, {PATCH_STEP} voxels apart): use mutual information, or fewer levels",
                fixed.dims().map(|n| n.to_string()).join(" × ")
            )));
        }
        let variance = |values: &mut dyn Iterator<Item = f64>| {
            let (n, sum, sum_sq) = values.fold((0usize, 0.0, 0.0), |(n, s, q), v| (n + 1, s + v, q + v * v));
            (n > 1).then(|| (sum_sq - sum * sum / n as f64) / (n - 1) as f64)
        };
        let flat = |name: &str| {
            crate::SolverError::Image(format!(
                "the {name} image is flat at the registration's samples: no local correlation to match"
            ))
        };
        let fixed_variance =
            variance(&mut fixed_values.iter().copied()).filter(|&v| v > 0.0).ok_or_else(|| flat("fixed"))?;
        let moving_variance = variance(&mut points.iter().filter_map(|&x| warped.sample(x)).filter(|m| m.is_finite()))
            .ok_or_else(no_overlap)?;
        if moving_variance <= 0.0 {
            return Err(flat("moving"));
        }
        Ok(Self {
            reader: SampleReader::new(warped, points, lattice, parallelism, device)?,
            fixed_values,
            patches,
            epsilon_fixed: NOISE_SCALE * NOISE_SCALE * fixed_variance,
            epsilon_moving: NOISE_SCALE * NOISE_SCALE * moving_variance,
            parallelism,
        })
    }

    /// The sums of the points of `patch` inside the moving image (`values` NaN outside).
    fn sums(&self, patch: &std::ops::Range<usize>, values: &[f64]) -> PatchSums {
        let inside = || patch.clone().filter(|&i| values[i].is_finite());
        let n = inside().count();
        let (f_sum, m_sum) = inside().fold((0.0, 0.0), |(f, m), i| (f + self.fixed_values[i], m + values[i]));
        let (f_mean, m_mean) = (f_sum / n.max(1) as f64, m_sum / n.max(1) as f64);
        let (mut sff, mut smm, mut sfm) = (0.0, 0.0, 0.0);
        for i in inside() {
            let (df, dm) = (self.fixed_values[i] - f_mean, values[i] - m_mean);
            sff += df * df;
            smm += dm * dm;
            sfm += df * dm;
        }
        PatchSums { n, f_mean, m_mean, sff, smm, sfm }
    }

    /// LNCC at the lattice `phi` (shaped `dims`) and ∂LNCC/∂φ; `None` when fewer than [`MIN_SAMPLES_INSIDE`] points
    /// of whole patches land inside the warped image.
    ///
    /// # Errors
    /// [`crate::SolverError::Device`] when the device fails.
    pub(super) fn evaluate(&self, phi: &[f64], dims: [usize; 3]) -> crate::Result<Option<Evaluation>> {
        let reading = self.reader.read(phi, dims)?;
        let values = &reading.values;
        let sums: Vec<PatchSums> = match self.parallelism {
            Parallelism::Rayon => self.patches.par_iter().map(|p| self.sums(p, values)).collect(),
            Parallelism::Sequential => self.patches.iter().map(|p| self.sums(p, values)).collect(),
        };
        let counted = |s: &&PatchSums| s.n >= MIN_PATCH_POINTS;
        let inside: usize = sums.iter().filter(counted).map(|s| s.n).sum();
        let patches = sums.iter().filter(counted).count();
        if inside < MIN_SAMPLES_INSIDE || patches == 0 {
            return Ok(None);
        }
        let per_patch = 1.0 / patches as f64;
        // In the patches' order, so that the same inputs give the same bits; each point's weight depends on its
        // own patch alone.
        let mut weights = vec![0.0; values.len()];
        let mut similarity = 0.0;
        for (patch, s) in self.patches.iter().zip(&sums).filter(|(_, s)| s.n >= MIN_PATCH_POINTS) {
            let a = s.sff + s.n as f64 * self.epsilon_fixed;
            let b = s.smm + s.n as f64 * self.epsilon_moving;
            similarity += s.sfm * s.sfm / (a * b);
            let (cf, cm) = (2.0 * s.sfm / (a * b) * per_patch, 2.0 * s.sfm * s.sfm / (a * b * b) * per_patch);
            for i in patch.clone().filter(|&i| values[i].is_finite()) {
                weights[i] = cf * (self.fixed_values[i] - s.f_mean) - cm * (values[i] - s.m_mean);
            }
        }
        let gradient = self.reader.gather(&reading, &weights, dims, phi.len())?;
        Ok(Some(Evaluation { similarity: similarity * per_patch, gradient, inside }))
    }

    /// The points of all patches.
    pub(super) fn samples(&self) -> usize {
        self.reader.len()
    }
}
