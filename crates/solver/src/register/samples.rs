//! The pulled-back moving image read at a level's fixed samples under a deformation, on the CPU's threads or on a
//! [`SampleDevice`]: the values m'(x_s + D(x_s)), and, given a weight w_s per sample, the gathered gradient
//! Σ_s w_s B_k(x_s) ∇m'(x_s + D(x_s)) per coefficient. Every similarity whose derivative in m' at each sample is a
//! weight (mutual information, local correlation) is those two reads around its own formula, so it runs on a device
//! as it does on the CPU.

use nalgebra::Vector3;
use rayon::prelude::*;

use super::device::{DeviceLevel, DeviceSample, DeviceSamples, SampleDevice};
use crate::bspline::ControlLattice;
use crate::image::Image;
use crate::spaces::Fixed;
use crate::warp::Parallelism;

/// The sums are split into this many chunks whatever the number of threads, and the chunks' partial sums are added in
/// their order: the same inputs give the same bits on any machine.
pub(super) const CHUNKS: usize = 16;

/// Where a sample reads the lattice: the first control index per axis and the basis weights (fixed for a level,
/// since the samples and the lattice's cells are).
#[derive(Clone, Copy, Debug)]
pub(super) struct Footprint {
    pub(super) start: [usize; 3],
    pub(super) weights: [[f64; 4]; 3],
}

impl Footprint {
    pub(super) fn of(lattice: &ControlLattice, x: [f64; 3]) -> Self {
        let (start, weights) = lattice.footprint(x);
        Self { start, weights }
    }

    /// D(x) = Σ B_a B_b B_c φ over the 4 × 4 × 4 block.
    #[inline]
    pub(super) fn displacement(&self, phi: &[f64], dims: [usize; 3]) -> [f64; 3] {
        let [bx, by, bz] = &self.weights;
        let mut acc = [0.0; 3];
        for (c, wz) in bz.iter().enumerate() {
            for (b, wy) in by.iter().enumerate() {
                let wzy = wz * wy;
                let row = (((self.start[2] + c) * dims[1] + self.start[1] + b) * dims[0] + self.start[0]) * 3;
                let coef = &phi[row..row + 12];
                for (a, wx) in bx.iter().enumerate() {
                    let w = wzy * wx;
                    acc[0] += w * coef[3 * a];
                    acc[1] += w * coef[3 * a + 1];
                    acc[2] += w * coef[3 * a + 2];
                }
            }
        }
        acc
    }

    /// Adds B_a B_b B_c · `v` to the gradient of each control point of the block.
    #[inline]
    pub(super) fn scatter(&self, v: [f64; 3], dims: [usize; 3], gradient: &mut [f64]) {
        let [bx, by, bz] = &self.weights;
        for (c, wz) in bz.iter().enumerate() {
            for (b, wy) in by.iter().enumerate() {
                let wzy = wz * wy;
                let row = (((self.start[2] + c) * dims[1] + self.start[1] + b) * dims[0] + self.start[0]) * 3;
                let out = &mut gradient[row..row + 12];
                for (a, wx) in bx.iter().enumerate() {
                    let w = wzy * wx;
                    out[3 * a] += w * v[0];
                    out[3 * a + 1] += w * v[1];
                    out[3 * a + 2] += w * v[2];
                }
            }
        }
    }
}

/// The samples of one level and where they are read.
pub(super) struct SampleReader<'a> {
    /// The moving image pulled back by the start u₀ onto the level's fixed grid (NaN where u₀ leaves it).
    warped: &'a Image<Fixed>,
    points: Vec<[f64; 3]>,
    footprints: Vec<Footprint>,
    parallelism: Parallelism,
    /// Where the samples are read when not on the CPU's threads.
    device: Option<Box<dyn DeviceSamples + 'a>>,
}

impl std::fmt::Debug for SampleReader<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SampleReader")
            .field("samples", &self.points.len())
            .field("on_device", &self.device.is_some())
            .finish_non_exhaustive()
    }
}

/// The samples read at one φ.
#[derive(Debug)]
pub(super) struct Reading {
    /// m'(x_s + D(x_s)), NaN where the sample left the image.
    pub(super) values: Vec<f64>,
    /// ∇m' there, on the CPU (a device keeps its own).
    gradients: Vec<Vector3<f64>>,
}

impl<'a> SampleReader<'a> {
    /// The fixed `points` of a level (mm), their footprints in `lattice`, read in `warped`; uploaded to `device` when
    /// one is given.
    ///
    /// # Errors
    /// [`crate::SolverError::Device`] when the device cannot take the level.
    pub(super) fn new(
        warped: &'a Image<Fixed>,
        points: Vec<[f64; 3]>,
        lattice: &ControlLattice,
        parallelism: Parallelism,
        device: Option<&'a dyn SampleDevice>,
    ) -> crate::Result<Self> {
        let footprints: Vec<Footprint> = points.iter().map(|&x| Footprint::of(lattice, x)).collect();
        let device = match device {
            None => None,
            Some(d) => {
                let on_device: Vec<DeviceSample> = points
                    .iter()
                    .zip(&footprints)
                    .map(|(&x, f)| DeviceSample { index: warped.index_of(x), first: f.start, weights: f.weights })
                    .collect();
                let level = DeviceLevel { image: warped, lattice_dims: lattice.dims(), samples: &on_device };
                Some(d.prepare(&level).map_err(crate::SolverError::Device)?)
            }
        };
        Ok(Self { warped, points, footprints, parallelism, device })
    }

    pub(super) fn len(&self) -> usize {
        self.points.len()
    }

    /// The length of the chunks every sum over the samples is split into ([`CHUNKS`]).
    pub(super) fn chunk_len(&self) -> usize {
        self.points.len().div_ceil(CHUNKS).max(1)
    }

    /// The values at the lattice `phi` (shaped `dims`). On the CPU a sample counts as inside where both its value
    /// and its gradient are finite.
    ///
    /// # Errors
    /// [`crate::SolverError::Device`] when the device fails.
    pub(super) fn read(&self, phi: &[f64], dims: [usize; 3]) -> crate::Result<Reading> {
        if let Some(device) = &self.device {
            let mut values = vec![f64::NAN; self.points.len()];
            device.values(phi, &mut values).map_err(crate::SolverError::Device)?;
            return Ok(Reading { values, gradients: Vec::new() });
        }
        let read_one = |(x, f): (&[f64; 3], &Footprint)| {
            let d = f.displacement(phi, dims);
            let y = [x[0] + d[0], x[1] + d[1], x[2] + d[2]];
            match self.warped.sample_with_gradient(y) {
                Some((m, grad)) if m.is_finite() && grad.iter().all(|c| c.is_finite()) => (m, Vector3::from(grad)),
                _ => (f64::NAN, Vector3::zeros()),
            }
        };
        let read: Vec<(f64, Vector3<f64>)> = match self.parallelism {
            Parallelism::Rayon => {
                self.points.par_iter().zip(self.footprints.par_iter()).with_min_len(1024).map(read_one).collect()
            }
            Parallelism::Sequential => self.points.iter().zip(self.footprints.iter()).map(read_one).collect(),
        };
        let (values, gradients) = read.into_iter().unzip();
        Ok(Reading { values, gradients })
    }

    /// Σ_s w_s B_k(x_s) ∇m'(x_s + D(x_s)) for each of the `len` coefficients (lattice shaped `dims`), at the φ of
    /// `reading` (the last one read); a sample outside adds nothing, whatever its weight.
    ///
    /// # Errors
    /// [`crate::SolverError::Device`] when the device fails.
    pub(super) fn gather(
        &self,
        reading: &Reading,
        weights: &[f64],
        dims: [usize; 3],
        len: usize,
    ) -> crate::Result<Vec<f64>> {
        if let Some(device) = &self.device {
            let weights: Vec<f64> =
                reading.values.iter().zip(weights).map(|(m, &w)| if m.is_finite() { w } else { 0.0 }).collect();
            let mut gradient = vec![0.0; len];
            device.weighted_gradient(&weights, &mut gradient).map_err(crate::SolverError::Device)?;
            return Ok(gradient);
        }
        let n = self.points.len();
        let chunk = self.chunk_len();
        let chunks: Vec<std::ops::Range<usize>> = (0..n).step_by(chunk).map(|c| c..(c + chunk).min(n)).collect();
        let gradient_of = |range: &std::ops::Range<usize>| {
            let mut g = vec![0.0; len];
            for s in range.clone().filter(|&s| reading.values[s].is_finite()) {
                let v = reading.gradients[s] * weights[s];
                self.footprints[s].scatter([v[0], v[1], v[2]], dims, &mut g);
            }
            g
        };
        let parts: Vec<Vec<f64>> = match self.parallelism {
            Parallelism::Rayon => chunks.par_iter().map(gradient_of).collect(),
            Parallelism::Sequential => chunks.iter().map(gradient_of).collect(),
        };
        let mut gradient = vec![0.0; len];
        for part in parts {
            gradient.iter_mut().zip(part).for_each(|(x, y)| *x += y);
        }
        Ok(gradient)
    }
}
