//! Mattes mutual information between the fixed image and the pulled-back moving image under a free-form
//! deformation, with its gradient in the lattice's coefficients (the module docs of [`super`] give the formulas).

use nalgebra::Vector3;
use rayon::prelude::*;

use super::device::{DeviceLevel, DeviceSample, DeviceSamples, SampleDevice};
use crate::align::{PAD_BINS, Sample, bspline3, bspline3_derivative};
use crate::bspline::ControlLattice;
use crate::image::Image;
use crate::spaces::Fixed;
use crate::warp::Parallelism;

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

/// A point where the deformation's Jacobian determinant is checked: its block of control points and the basis
/// weights and their derivatives there.
#[derive(Clone, Copy, Debug)]
pub(super) struct JacobianPoint {
    pub(super) start: [usize; 3],
    pub(super) weights: [[f64; 4]; 3],
    pub(super) derivatives: [[f64; 4]; 3],
}

impl JacobianPoint {
    pub(super) fn of(lattice: &ControlLattice, x: [f64; 3]) -> Self {
        let (start, weights, derivatives) = lattice.footprint_with_derivatives(x);
        Self { start, weights, derivatives }
    }

    /// det(I + ∇D) at the point.
    pub(super) fn determinant(&self, phi: &[f64], dims: [usize; 3]) -> f64 {
        let ([bx, by, bz], [dx, dy, dz]) = (&self.weights, &self.derivatives);
        let mut j = [[0.0; 3]; 3];
        for c in 0..4 {
            for b in 0..4 {
                let row = (((self.start[2] + c) * dims[1] + self.start[1] + b) * dims[0] + self.start[0]) * 3;
                for a in 0..4 {
                    let g = [dx[a] * by[b] * bz[c], bx[a] * dy[b] * bz[c], bx[a] * by[b] * dz[c]];
                    let coef = &phi[row + 3 * a..row + 3 * a + 3];
                    for (r, &v) in coef.iter().enumerate() {
                        for (col, &w) in g.iter().enumerate() {
                            j[r][col] += w * v;
                        }
                    }
                }
            }
        }
        let m = |r: usize, c: usize| j[r][c] + if r == c { 1.0 } else { 0.0 };
        m(0, 0) * (m(1, 1) * m(2, 2) - m(1, 2) * m(2, 1)) - m(0, 1) * (m(1, 0) * m(2, 2) - m(1, 2) * m(2, 0))
            + m(0, 2) * (m(1, 0) * m(2, 1) - m(1, 1) * m(2, 0))
    }
}

/// The refusal of images that do not overlap under the starting warp.
pub(super) fn no_overlap() -> crate::SolverError {
    crate::SolverError::Image(
        "the images do not overlap under the starting warp: the fixed image's samples fall outside the moving image"
            .into(),
    )
}

/// Per sample, what the gradient pass needs from the histogram pass.
#[derive(Clone, Copy, Debug, Default)]
struct Hit {
    inside: bool,
    /// m̃(x + D(x)), in bins.
    moving_bin: f64,
    gradient: Vector3<f64>,
}

/// The metric over one level's fixed samples.
pub(super) struct Metric<'a> {
    /// The moving image pulled back by the start u₀ onto the level's fixed grid (NaN where u₀ leaves it).
    pub(super) warped: &'a Image<Fixed>,
    pub(super) samples: Vec<Sample>,
    pub(super) footprints: Vec<Footprint>,
    pub(super) bins: usize,
    pub(super) moving_min: f64,
    pub(super) moving_bin_width: f64,
    pub(super) parallelism: Parallelism,
    /// Where the samples are read when not on the CPU's threads ([`super::device`]).
    device: Option<Box<dyn DeviceSamples + 'a>>,
}

impl std::fmt::Debug for Metric<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Metric")
            .field("samples", &self.samples.len())
            .field("bins", &self.bins)
            .field("on_device", &self.device.is_some())
            .finish_non_exhaustive()
    }
}

/// MI, its gradient in the coefficients, and the samples that stayed inside the warped image.
#[derive(Debug)]
pub(super) struct Evaluation {
    /// The similarity: MI in nats here, the NGF measure in [`super::ngf`].
    pub(super) similarity: f64,
    pub(super) gradient: Vec<f64>,
    pub(super) inside: usize,
}

/// The sums are split into this many chunks whatever the number of threads, and the chunks' partial sums are added in
/// their order: the same inputs give the same bits on any machine.
pub(super) const CHUNKS: usize = 16;

impl<'a> Metric<'a> {
    /// The metric of `samples` (with their footprints in `lattice`) against `warped`, its histogram spanning the
    /// finite values of `warped`.
    ///
    /// The samples are read on `device` when one is given.
    ///
    /// # Errors
    /// [`crate::SolverError::Image`] when `warped` has no finite value (the images do not overlap) or a single one;
    /// [`crate::SolverError::Device`] when the device cannot take the level.
    pub(super) fn new(
        warped: &'a Image<Fixed>,
        samples: Vec<Sample>,
        lattice: &ControlLattice,
        bins: usize,
        parallelism: Parallelism,
        device: Option<&'a dyn SampleDevice>,
    ) -> crate::Result<Self> {
        let Some((moving_min, moving_max)) = warped.value_range(parallelism) else { return Err(no_overlap()) };
        if moving_max <= moving_min {
            return Err(crate::SolverError::Image(
                "the moving image has a single value where it overlaps the fixed image: nothing to match".into(),
            ));
        }
        let footprints: Vec<Footprint> =
            samples.iter().map(|s| Footprint::of(lattice, [s.x[0], s.x[1], s.x[2]])).collect();
        let device = match device {
            None => None,
            Some(d) => {
                let points: Vec<DeviceSample> = samples
                    .iter()
                    .zip(&footprints)
                    .map(|(s, f)| DeviceSample {
                        index: warped.index_of([s.x[0], s.x[1], s.x[2]]),
                        first: f.start,
                        weights: f.weights,
                    })
                    .collect();
                let level = DeviceLevel { image: warped, lattice_dims: lattice.dims(), samples: &points };
                Some(d.prepare(&level).map_err(crate::SolverError::Device)?)
            }
        };
        Ok(Self {
            warped,
            samples,
            footprints,
            bins,
            moving_min,
            moving_bin_width: (moving_max - moving_min) / (bins - 2 * PAD_BINS - 1) as f64,
            parallelism,
            device,
        })
    }

    fn hit(&self, s: &Sample, f: &Footprint, phi: &[f64], dims: [usize; 3]) -> Hit {
        let d = f.displacement(phi, dims);
        let y = [s.x[0] + d[0], s.x[1] + d[1], s.x[2] + d[2]];
        match self.warped.sample_with_gradient(y) {
            Some((m, g)) if m.is_finite() && g.iter().all(|v| v.is_finite()) => {
                Hit { inside: true, moving_bin: self.moving_bin(m), gradient: Vector3::from(g) }
            }
            _ => Hit::default(),
        }
    }

    /// The bin of a moving value, clamped into the histogram's unpadded range.
    fn moving_bin(&self, m: f64) -> f64 {
        ((m - self.moving_min) / self.moving_bin_width + PAD_BINS as f64)
            .clamp(PAD_BINS as f64, (self.bins - PAD_BINS - 1) as f64)
    }

    fn chunk_len(&self) -> usize {
        self.samples.len().div_ceil(CHUNKS).max(1)
    }

    /// MI at the lattice `phi` (coefficients of a lattice shaped `dims`) and ∂MI/∂φ; `None` when fewer than
    /// [`crate::align::MIN_SAMPLES_INSIDE`] samples land inside the warped image.
    ///
    /// # Errors
    /// [`crate::SolverError::Device`] when the device fails.
    pub(super) fn evaluate(&self, phi: &[f64], dims: [usize; 3]) -> crate::Result<Option<Evaluation>> {
        let b = self.bins;
        let n = self.samples.len();
        let mut hits = vec![Hit::default(); n];
        if let Some(device) = &self.device {
            // Only the bins: the gradients stay on the device.
            let mut values = vec![0.0; n];
            device.values(phi, &mut values).map_err(crate::SolverError::Device)?;
            for (h, &m) in hits.iter_mut().zip(&values) {
                if m.is_finite() {
                    *h = Hit { inside: true, moving_bin: self.moving_bin(m), gradient: Vector3::zeros() };
                }
            }
        } else {
            let fill = |((h, s), f): ((&mut Hit, &Sample), &Footprint)| *h = self.hit(s, f, phi, dims);
            match self.parallelism {
                Parallelism::Rayon => hits
                    .par_iter_mut()
                    .zip(self.samples.par_iter())
                    .zip(self.footprints.par_iter())
                    .with_min_len(1024)
                    .for_each(fill),
                Parallelism::Sequential => {
                    hits.iter_mut().zip(self.samples.iter()).zip(self.footprints.iter()).for_each(fill);
                }
            }
        }
        let chunk = self.chunk_len();
        let histogram = |(hits, samples): (&[Hit], &[Sample])| {
            let mut joint = vec![0.0f64; b * b];
            let mut inside = 0usize;
            for (h, s) in hits.iter().zip(samples).filter(|(h, _)| h.inside) {
                inside += 1;
                let row = &mut joint[s.bin * b..(s.bin + 1) * b];
                let k0 = h.moving_bin.floor() as usize;
                for (k, bin) in row.iter_mut().enumerate().skip(k0 - 1).take(4) {
                    *bin += bspline3(k as f64 - h.moving_bin);
                }
            }
            (joint, inside)
        };
        let parts: Vec<(Vec<f64>, usize)> = match self.parallelism {
            Parallelism::Rayon => hits.par_chunks(chunk).zip(self.samples.par_chunks(chunk)).map(histogram).collect(),
            Parallelism::Sequential => hits.chunks(chunk).zip(self.samples.chunks(chunk)).map(histogram).collect(),
        };
        let (mut joint, inside) = parts.into_iter().fold((vec![0.0f64; b * b], 0usize), |(mut j, i), (p, n)| {
            j.iter_mut().zip(p).for_each(|(x, y)| *x += y);
            (j, i + n)
        });
        if inside < crate::align::MIN_SAMPLES_INSIDE {
            return Ok(None);
        }
        let norm = 1.0 / inside as f64;
        let (mi, log_ratio) = crate::align::mutual_information(&mut joint, b, norm);
        // ∂MI/∂φ_c = −(1/(n Δm)) Σ_x [Σ_κ β³′(κ − m̃) log(p(ι_x, κ)/p_m(κ))] ∇m'(x + D(x)) B_c(x).
        let scale = -norm / self.moving_bin_width;
        let len = phi.len();
        // The weight of sample s's gradient: scale · Σ_κ β³′(κ − m̃) log(p(ι, κ)/p_m(κ)).
        let weight = |h: &Hit, s: &Sample| {
            let row = &log_ratio[s.bin * b..(s.bin + 1) * b];
            let k0 = h.moving_bin.floor() as usize;
            scale * (k0 - 1..=k0 + 2).map(|k| bspline3_derivative(k as f64 - h.moving_bin) * row[k]).sum::<f64>()
        };
        if let Some(device) = &self.device {
            let weights: Vec<f64> =
                hits.iter().zip(&self.samples).map(|(h, s)| if h.inside { weight(h, s) } else { 0.0 }).collect();
            let mut gradient = vec![0.0; len];
            device.weighted_gradient(&weights, &mut gradient).map_err(crate::SolverError::Device)?;
            return Ok(Some(Evaluation { similarity: mi, gradient, inside }));
        }
        let gradient_of = |((hits, samples), footprints): ((&[Hit], &[Sample]), &[Footprint])| {
            let mut g = vec![0.0; len];
            for ((h, s), f) in hits.iter().zip(samples).zip(footprints).filter(|((h, _), _)| h.inside) {
                let v = h.gradient * weight(h, s);
                f.scatter([v[0], v[1], v[2]], dims, &mut g);
            }
            g
        };
        let parts: Vec<Vec<f64>> = match self.parallelism {
            Parallelism::Rayon => hits
                .par_chunks(chunk)
                .zip(self.samples.par_chunks(chunk))
                .zip(self.footprints.par_chunks(chunk))
                .map(gradient_of)
                .collect(),
            Parallelism::Sequential => hits
                .chunks(chunk)
                .zip(self.samples.chunks(chunk))
                .zip(self.footprints.chunks(chunk))
                .map(gradient_of)
                .collect(),
        };
        let mut gradient = vec![0.0; len];
        for part in parts {
            gradient.iter_mut().zip(part).for_each(|(x, y)| *x += y);
        }
        Ok(Some(Evaluation { similarity: mi, gradient, inside }))
    }
}
