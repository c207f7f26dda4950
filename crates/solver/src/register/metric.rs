//! Mattes mutual information between the fixed image and the pulled-back moving image under a free-form
//! deformation, with its gradient in the lattice's coefficients (the module docs of [`super`] give the formulas).

use rayon::prelude::*;

use super::device::SampleDevice;
use super::samples::SampleReader;
use crate::align::{PAD_BINS, Sample, bspline3, bspline3_derivative};
use crate::bspline::ControlLattice;
use crate::image::Image;
use crate::spaces::Fixed;
use crate::warp::Parallelism;

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

/// The metric over one level's fixed samples.
#[derive(Debug)]
pub(super) struct Metric<'a> {
    /// The samples, read in the moving image pulled back by the start u₀ onto the level's fixed grid.
    pub(super) reader: SampleReader<'a>,
    /// Each sample's fixed bin.
    fixed_bins: Vec<usize>,
    bins: usize,
    moving_min: f64,
    moving_bin_width: f64,
    parallelism: Parallelism,
}

/// MI, its gradient in the coefficients, and the samples that stayed inside the warped image.
#[derive(Debug)]
pub(super) struct Evaluation {
    /// The similarity: MI in nats here, the NGF measure in [`super::ngf`].
    pub(super) similarity: f64,
    pub(super) gradient: Vec<f64>,
    pub(super) inside: usize,
}

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
        samples: &[Sample],
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
        let points = samples.iter().map(|s| [s.x[0], s.x[1], s.x[2]]).collect();
        Ok(Self {
            reader: SampleReader::new(warped, points, lattice, parallelism, device)?,
            fixed_bins: samples.iter().map(|s| s.bin).collect(),
            bins,
            moving_min,
            moving_bin_width: (moving_max - moving_min) / (bins - 2 * PAD_BINS - 1) as f64,
            parallelism,
        })
    }

    /// The bin of a moving value, clamped into the histogram's unpadded range.
    fn moving_bin(&self, m: f64) -> f64 {
        ((m - self.moving_min) / self.moving_bin_width + PAD_BINS as f64)
            .clamp(PAD_BINS as f64, (self.bins - PAD_BINS - 1) as f64)
    }

    /// MI at the lattice `phi` (coefficients of a lattice shaped `dims`) and ∂MI/∂φ; `None` when fewer than
    /// [`crate::align::MIN_SAMPLES_INSIDE`] samples land inside the warped image.
    ///
    /// # Errors
    /// [`crate::SolverError::Device`] when the device fails.
    pub(super) fn evaluate(&self, phi: &[f64], dims: [usize; 3]) -> crate::Result<Option<Evaluation>> {
        let b = self.bins;
        let reading = self.reader.read(phi, dims)?;
        let chunk = self.reader.chunk_len();
        let histogram = |(values, fixed_bins): (&[f64], &[usize])| {
            let mut joint = vec![0.0f64; b * b];
            let mut inside = 0usize;
            for (&m, &fixed_bin) in values.iter().zip(fixed_bins).filter(|(m, _)| m.is_finite()) {
                inside += 1;
                let row = &mut joint[fixed_bin * b..(fixed_bin + 1) * b];
                let moving_bin = self.moving_bin(m);
                let k0 = moving_bin.floor() as usize;
                for (k, bin) in row.iter_mut().enumerate().skip(k0 - 1).take(4) {
                    *bin += bspline3(k as f64 - moving_bin);
                }
            }
            (joint, inside)
        };
        let parts: Vec<(Vec<f64>, usize)> = match self.parallelism {
            Parallelism::Rayon => {
                reading.values.par_chunks(chunk).zip(self.fixed_bins.par_chunks(chunk)).map(histogram).collect()
            }
            Parallelism::Sequential => {
                reading.values.chunks(chunk).zip(self.fixed_bins.chunks(chunk)).map(histogram).collect()
            }
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
        // ∂MI/∂φ_c = −(1/(n Δm)) Σ_x [Σ_κ β³′(κ − m̃) log(p(ι_x, κ)/p_m(κ))] ∇m'(x + D(x)) B_c(x): each sample's
        // weight is scale · Σ_κ β³′(κ − m̃) log(p(ι, κ)/p_m(κ)).
        let scale = -norm / self.moving_bin_width;
        let weight = |(&m, &fixed_bin): (&f64, &usize)| {
            if !m.is_finite() {
                return 0.0;
            }
            let moving_bin = self.moving_bin(m);
            let row = &log_ratio[fixed_bin * b..(fixed_bin + 1) * b];
            let k0 = moving_bin.floor() as usize;
            scale * (k0 - 1..=k0 + 2).map(|k| bspline3_derivative(k as f64 - moving_bin) * row[k]).sum::<f64>()
        };
        let weights: Vec<f64> = match self.parallelism {
            Parallelism::Rayon => reading.values.par_iter().zip(self.fixed_bins.par_iter()).map(weight).collect(),
            Parallelism::Sequential => reading.values.iter().zip(self.fixed_bins.iter()).map(weight).collect(),
        };
        let gradient = self.reader.gather(&reading, &weights, dims, phi.len())?;
        Ok(Some(Evaluation { similarity: mi, gradient, inside }))
    }
}
