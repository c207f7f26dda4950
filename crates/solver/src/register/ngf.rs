//! Normalised gradient fields (Haber & Modersitzki 2006) between the fixed image and the pulled-back moving image
//! under a free-form deformation, with its gradient in the lattice's coefficients.
//!
//! At each fixed sample x, with a = ∇f(x) and the gradient of the deformed moving image
//! b = ∇(m' ∘ T)(x) = (I + ∇D(x))ᵀ ∇m'(y), y = x + D(x):
//!
//! NGF = (1/n) Σ_x r², r = ⟨a, b⟩ / (|a|_η |b|_ε), |v|_ε = √(|v|² + ε²),
//!
//! 1 where the edges are parallel or antiparallel (any contrast, MR–CT too), 0 where they cross or one image is flat.
//! η and ε are [`EDGE_SCALE`] times the mean gradient magnitude of each image at the samples (the moving one at the
//! level's start), so weak gradients, mostly noise, count little.
//!
//! With g = ∇m'(y), H = ∇g(y) and ∂NGF/∂b = (2r/n)(a/|a|_η − r b/|b|_ε)/|b|_ε =: c, the derivative in the
//! coefficient φ_k of control point k (basis B_k) is
//!
//! ∂NGF/∂φ_k = (∇B_k(x) · c) g + B_k(x) Hᵀ (I + ∇D(x)) c,
//!
//! the first term through ∇D, the second through y, with H_ij = ∂g_i/∂y_j. Both images'
//! gradients are their voxels' central differences, interpolated trilinearly ([`Image::central_gradient`]): a gradient
//! continuous in position, so that NGF is continuous in φ. The trilinear interpolant's own gradient jumps on every
//! cell face, and with it NGF wherever a sample crosses one: along a search direction those jumps added up to a slope
//! the analytic gradient does not see, and the minimiser could stall at a level's start. H is then the trilinear
//! derivative of the interpolated gradient.

use rayon::prelude::*;

use super::metric::{Evaluation, JacobianPoint, no_overlap};
use super::samples::CHUNKS;
use crate::align::Sample;
use crate::bspline::ControlLattice;
use crate::image::Image;
use crate::spaces::Fixed;
use crate::warp::Parallelism;

/// η and ε as fractions of each image's mean gradient magnitude at the samples.
pub const EDGE_SCALE: f64 = 0.1;

/// The NGF measure over one level's fixed samples.
#[derive(Debug)]
pub(super) struct Ngf {
    /// The gradient of the moving image pulled back by the start u₀ onto the level's fixed grid, one image per axis
    /// (NaN where u₀ leaves it).
    warped_gradient: [Image<Fixed>; 3],
    points: Vec<[f64; 3]>,
    /// a / |a|_η at each sample.
    fixed_normals: Vec<[f64; 3]>,
    footprints: Vec<JacobianPoint>,
    /// ε of the moving image, squared.
    epsilon_sq: f64,
    parallelism: Parallelism,
}

/// What one sample adds: r², and the two vectors its gradient scatters.
struct Term {
    r_sq: f64,
    /// (∇B_k · c) multiplies `g`; B_k multiplies `w`.
    c: [f64; 3],
    g: [f64; 3],
    w: [f64; 3],
}

impl Ngf {
    /// The measure at `samples` of `fixed` (the level's image) against `warped`, with footprints in `lattice`.
    ///
    /// # Errors
    /// [`crate::SolverError::Image`] when either image has no gradient at the samples (a single value) or no sample
    /// lands in `warped`.
    pub(super) fn new(
        fixed: &Image<Fixed>,
        warped: &Image<Fixed>,
        samples: &[Sample],
        lattice: &ControlLattice,
        parallelism: Parallelism,
    ) -> crate::Result<Self> {
        let points: Vec<[f64; 3]> = samples.iter().map(|s| [s.x[0], s.x[1], s.x[2]]).collect();
        let norm = |g: [f64; 3]| (g[0] * g[0] + g[1] * g[1] + g[2] * g[2]).sqrt();
        let fixed_gradient = fixed.central_gradient(parallelism)?;
        let warped_gradient = warped.central_gradient(parallelism)?;
        let at = |images: &[Image<Fixed>; 3], x: [f64; 3]| -> Option<[f64; 3]> {
            let g = [images[0].sample(x)?, images[1].sample(x)?, images[2].sample(x)?];
            g.iter().all(|v| v.is_finite()).then_some(g)
        };
        let fixed_gradients: Vec<[f64; 3]> =
            points.iter().map(|&x| at(&fixed_gradient, x).unwrap_or([0.0; 3])).collect();
        let mean_fixed = fixed_gradients.iter().map(|&g| norm(g)).sum::<f64>() / points.len().max(1) as f64;
        let moving: Vec<f64> = points.iter().filter_map(|&x| at(&warped_gradient, x)).map(norm).collect();
        if moving.is_empty() {
            return Err(no_overlap());
        }
        let mean_moving = moving.iter().sum::<f64>() / moving.len() as f64;
        if !(mean_fixed > 0.0 && mean_moving > 0.0) {
            return Err(crate::SolverError::Image(
                "an image has a single value where the images overlap: no edges to align".into(),
            ));
        }
        let eta_sq = (EDGE_SCALE * mean_fixed).powi(2);
        let fixed_normals = fixed_gradients
            .iter()
            .map(|&a| {
                let n = (a[0] * a[0] + a[1] * a[1] + a[2] * a[2] + eta_sq).sqrt();
                [a[0] / n, a[1] / n, a[2] / n]
            })
            .collect();
        let footprints = points.iter().map(|&x| JacobianPoint::of(lattice, x)).collect();
        Ok(Self {
            warped_gradient,
            points,
            fixed_normals,
            footprints,
            epsilon_sq: (EDGE_SCALE * mean_moving).powi(2),
            parallelism,
        })
    }

    pub(super) fn samples(&self) -> usize {
        self.points.len()
    }

    /// One sample's term at `phi`, `None` outside the warped image.
    fn term(&self, n: usize, phi: &[f64], dims: [usize; 3]) -> Option<Term> {
        let f = &self.footprints[n];
        let (d, jd) = displacement_and_jacobian(f, phi, dims);
        let x = self.points[n];
        let y = [x[0] + d[0], x[1] + d[1], x[2] + d[2]];
        let mut g = [0.0; 3];
        let mut h = [[0.0; 3]; 3];
        for (i, image) in self.warped_gradient.iter().enumerate() {
            (g[i], h[i]) = image.sample_with_gradient(y)?;
        }
        if !g.iter().chain(h.iter().flatten()).all(|v| v.is_finite()) {
            return None;
        }
        // b = (I + J)ᵀ g.
        let b: [f64; 3] = std::array::from_fn(|col| g[col] + (0..3).map(|r| jd[r][col] * g[r]).sum::<f64>());
        let nb = (b[0] * b[0] + b[1] * b[1] + b[2] * b[2] + self.epsilon_sq).sqrt();
        let a = self.fixed_normals[n];
        let r = (a[0] * b[0] + a[1] * b[1] + a[2] * b[2]) / nb;
        let c: [f64; 3] = std::array::from_fn(|i| 2.0 * r * (a[i] - r * b[i] / nb) / nb);
        // (I + J) c, then Hᵀ times it.
        let jc: [f64; 3] = std::array::from_fn(|r_| c[r_] + (0..3).map(|col| jd[r_][col] * c[col]).sum::<f64>());
        let w: [f64; 3] = std::array::from_fn(|j| (0..3).map(|i| h[i][j] * jc[i]).sum());
        Some(Term { r_sq: r * r, c, g, w })
    }

    /// NGF at the lattice `phi` (coefficients of a lattice shaped `dims`) and ∂NGF/∂φ; `None` when fewer than
    /// [`crate::align::MIN_SAMPLES_INSIDE`] samples land inside the warped image.
    pub(super) fn evaluate(&self, phi: &[f64], dims: [usize; 3]) -> Option<Evaluation> {
        let len = phi.len();
        let chunk = self.points.len().div_ceil(CHUNKS).max(1);
        let part = |range: std::ops::Range<usize>| {
            let mut gradient = vec![0.0; len];
            let (mut sum, mut inside) = (0.0, 0usize);
            for n in range {
                let Some(t) = self.term(n, phi, dims) else { continue };
                inside += 1;
                sum += t.r_sq;
                scatter(&self.footprints[n], &t, dims, &mut gradient);
            }
            (sum, inside, gradient)
        };
        let ranges: Vec<_> =
            (0..self.points.len()).step_by(chunk).map(|s| s..(s + chunk).min(self.points.len())).collect();
        let parts: Vec<(f64, usize, Vec<f64>)> = match self.parallelism {
            Parallelism::Rayon => ranges.into_par_iter().map(part).collect(),
            Parallelism::Sequential => ranges.into_iter().map(part).collect(),
        };
        // Added in the chunks' order: the same bits on any number of threads.
        let (mut sum, mut inside, mut gradient) = (0.0, 0usize, vec![0.0; len]);
        for (s, i, g) in parts {
            sum += s;
            inside += i;
            gradient.iter_mut().zip(g).for_each(|(x, y)| *x += y);
        }
        if inside < crate::align::MIN_SAMPLES_INSIDE {
            return None;
        }
        let norm = 1.0 / inside as f64;
        for g in &mut gradient {
            *g *= norm;
        }
        Some(Evaluation { similarity: sum * norm, gradient, inside })
    }
}

/// D(x) and ∇D(x) (rows: components of D, columns: ∂/∂x, ∂/∂y, ∂/∂z) at a footprint.
fn displacement_and_jacobian(f: &JacobianPoint, phi: &[f64], dims: [usize; 3]) -> ([f64; 3], [[f64; 3]; 3]) {
    let ([bx, by, bz], [dx, dy, dz]) = (&f.weights, &f.derivatives);
    let mut d = [0.0; 3];
    let mut j = [[0.0; 3]; 3];
    for c in 0..4 {
        for b in 0..4 {
            let row = (((f.start[2] + c) * dims[1] + f.start[1] + b) * dims[0] + f.start[0]) * 3;
            for a in 0..4 {
                let w = bx[a] * by[b] * bz[c];
                let gw = [dx[a] * by[b] * bz[c], bx[a] * dy[b] * bz[c], bx[a] * by[b] * dz[c]];
                let coef = &phi[row + 3 * a..row + 3 * a + 3];
                for (r, &v) in coef.iter().enumerate() {
                    d[r] += w * v;
                    for (col, &wc) in gw.iter().enumerate() {
                        j[r][col] += wc * v;
                    }
                }
            }
        }
    }
    (d, j)
}

/// Adds (∇B_k · c) g + B_k w to the gradient of each control point k of the block.
fn scatter(f: &JacobianPoint, t: &Term, dims: [usize; 3], gradient: &mut [f64]) {
    let ([bx, by, bz], [dx, dy, dz]) = (&f.weights, &f.derivatives);
    for c in 0..4 {
        for b in 0..4 {
            let row = (((f.start[2] + c) * dims[1] + f.start[1] + b) * dims[0] + f.start[0]) * 3;
            for a in 0..4 {
                let w = bx[a] * by[b] * bz[c];
                let along = (dx[a] * by[b] * bz[c]) * t.c[0]
                    + (bx[a] * dy[b] * bz[c]) * t.c[1]
                    + (bx[a] * by[b] * dz[c]) * t.c[2];
                let out = &mut gradient[row + 3 * a..row + 3 * a + 3];
                for ((o, g), v) in out.iter_mut().zip(t.g).zip(t.w) {
                    *o += along * g + w * v;
                }
            }
        }
    }
}
