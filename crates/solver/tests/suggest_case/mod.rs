//! The synthetic case of the suggested-target measurements (issue 18 item 2), shared by `tests/suggest.rs` (the
//! issue's targets, asserted) and `benches/suggest_confidence.rs` (the table over several point seeds, with the time
//! per suggestion).
//!
//! The moving image is the real head MRI `ch2.nii.gz` (Colin27, 1 mm); the fixed image is the moving one pulled back
//! through a known smooth warp, f(x) = m(u_true(x)), u_true a small rotation plus four Gaussian bumps (up to ~8 mm);
//! the current warp d is the TPS through six true pairs spread over the head. Moving points are seeded strong-gradient
//! voxels; each suggestion is compared with the true fixed point u_true⁻¹(p) (Newton, to 1e-9 mm), in the same
//! contrast and with the fixed intensities remapped non-monotonically (a second modality).

// Each of the two targets that include this module uses part of it.
#![allow(dead_code)]

use std::path::Path;

use nalgebra::{Matrix3, Rotation3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use warpbench_io::geometry::Point3;
use warpbench_solver::image::Image;
use warpbench_solver::suggest::{SuggestParams, Suggestion, suggest};
use warpbench_solver::tps::{Tps, fit_forward};
use warpbench_solver::warp::Parallelism;
use warpbench_solver::{Fixed, Moving};

/// Points measured per seed.
pub const POINTS: usize = 50;
/// Moving points are drawn among the in-head voxels whose gradient magnitude is in this top quantile.
const TOP_GRADIENT_QUANTILE: f64 = 0.10;
/// Moving points stay this far from the volume's faces (patch, search and displacement fit inside), voxels.
const BORDER_VOX: usize = 24;
/// Voxels above this fraction of the largest value are in the head.
const HEAD_FRACTION: f64 = 0.15;
/// A suggestion off by more than this is wrong: the confidence should flag it, mm.
pub const WRONG_MM: f64 = 2.0;

/// The known pull-back u_true = `moving_from_fixed`: c + R(x − c) + Σ aⱼ exp(−|x − cⱼ|²/2σⱼ²).
pub struct TruePullback {
    centre: [f64; 3],
    rotation: Matrix3<f64>,
    bumps: Vec<([f64; 3], f64, [f64; 3])>,
}

impl TruePullback {
    fn new(centre: [f64; 3]) -> Self {
        let c = |d: [f64; 3]| [centre[0] + d[0], centre[1] + d[1], centre[2] + d[2]];
        Self {
            centre,
            rotation: Rotation3::from_euler_angles(0.03, -0.02, 0.035).into_inner(),
            bumps: vec![
                (c([30.0, 20.0, 10.0]), 30.0, [4.0, -3.0, 2.5]),
                (c([-35.0, -10.0, 20.0]), 28.0, [-3.0, 4.5, -2.0]),
                (c([0.0, -40.0, -15.0]), 32.0, [2.5, 2.0, 4.0]),
                (c([5.0, 35.0, -25.0]), 26.0, [-2.0, -3.5, 3.0]),
            ],
        }
    }

    fn apply(&self, x: [f64; 3]) -> [f64; 3] {
        let r = self.rotation * Vector3::from(sub(x, self.centre));
        let mut out = [self.centre[0] + r[0], self.centre[1] + r[1], self.centre[2] + r[2]];
        for (c, sigma, a) in &self.bumps {
            let w = (-dot(sub(x, *c), sub(x, *c)) / (2.0 * sigma * sigma)).exp();
            for i in 0..3 {
                out[i] += w * a[i];
            }
        }
        out
    }

    fn jacobian(&self, x: [f64; 3]) -> Matrix3<f64> {
        let mut j = self.rotation;
        for (c, sigma, a) in &self.bumps {
            let d = sub(x, *c);
            let w = (-dot(d, d) / (2.0 * sigma * sigma)).exp();
            for r in 0..3 {
                for col in 0..3 {
                    j[(r, col)] -= a[r] * w * d[col] / (sigma * sigma);
                }
            }
        }
        j
    }

    /// The fixed point q with u_true(q) = p, by Newton from q = p.
    pub fn invert(&self, p: [f64; 3]) -> [f64; 3] {
        let mut q = p;
        for _ in 0..50 {
            let r = sub(self.apply(q), p);
            if norm(r) < 1e-9 {
                return q;
            }
            let step = self.jacobian(q).try_inverse().expect("u_true is invertible") * Vector3::from(r);
            q = [q[0] - step[0], q[1] - step[1], q[2] - step[2]];
        }
        panic!("Newton did not converge at {p:?}");
    }
}

/// The images, the truth and the current warp.
pub struct Case {
    pub moving: Image<Moving>,
    pub fixed: Image<Fixed>,
    pub fixed_remapped: Image<Fixed>,
    pub truth: TruePullback,
    pub fixed_from_moving: Tps<Fixed, Moving>,
}

impl Case {
    pub fn build() -> Self {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/nifti/ch2.nii.gz");
        let volume = warpbench_io::open(&path).expect("ch2 fixture");
        let moving: Image<Moving> = Image::from_volume(&volume, Parallelism::Rayon).expect("image");
        let dims = moving.dims();
        let centre = {
            let a = moving.voxel_point(0, 0, 0);
            let b = moving.voxel_point(dims[0] - 1, dims[1] - 1, dims[2] - 1);
            [0.5 * (a[0] + b[0]), 0.5 * (a[1] + b[1]), 0.5 * (a[2] + b[2])]
        };
        let truth = TruePullback::new(centre);

        // f(x) = m(u_true(x)) on the moving grid; outside the moving image, 0.
        let slice = dims[0] * dims[1];
        let mut values = vec![0.0f32; slice * dims[2]];
        values.par_chunks_mut(slice).enumerate().for_each(|(k, out)| {
            for j in 0..dims[1] {
                for i in 0..dims[0] {
                    let x = truth.apply(moving.voxel_point(i, j, k));
                    out[i + dims[0] * j] = moving.sample(x).unwrap_or(0.0) as f32;
                }
            }
        });
        let (_, max) = moving.value_range(Parallelism::Rayon).expect("finite values");
        // A second modality: v ↦ |v − c|^0.7, c at 40 % of the range (between the CSF and the grey matter's
        // intensities): contrast folds over at c, so that the CSF turns brighter than the grey matter.
        let c = 0.4 * max;
        let scale = max / (max - c).powf(0.7);
        let remapped: Vec<f32> = values.iter().map(|&v| ((f64::from(v) - c).abs().powf(0.7) * scale) as f32).collect();
        let geometry = *moving.clone().retag::<Fixed>().space_from_index();
        let fixed = Image::new(dims, values, geometry).expect("fixed image");
        let fixed_remapped = Image::new(dims, remapped, geometry).expect("remapped image");

        // Six true pairs spread over the head: the current warp is the TPS through them.
        let spread = [
            [50.0, 0.0, 0.0],
            [-50.0, 0.0, 0.0],
            [0.0, 60.0, 0.0],
            [0.0, -60.0, 0.0],
            [0.0, 0.0, 45.0],
            [10.0, 10.0, -40.0],
        ];
        let p6: Vec<Point3<Moving>> =
            spread.iter().map(|d| Point3::from_array([centre[0] + d[0], centre[1] + d[1], centre[2] + d[2]])).collect();
        let q6: Vec<Point3<Fixed>> = p6.iter().map(|p| Point3::from_array(truth.invert(p.coords()))).collect();
        let fixed_from_moving = fit_forward(&p6, &q6, 0.0).expect("TPS");
        Self { moving, fixed, fixed_remapped, truth, fixed_from_moving }
    }

    /// `n` seeded random in-head voxel centres of the moving image among the top gradient-magnitude quantile, away
    /// from the faces.
    pub fn points(&self, n: usize, seed: u64) -> Vec<[f64; 3]> {
        let image = &self.moving;
        let dims = image.dims();
        let (_, max) = image.value_range(Parallelism::Rayon).expect("finite values");
        let mut candidates: Vec<(f64, [usize; 3])> = Vec::new();
        for k in BORDER_VOX..dims[2] - BORDER_VOX {
            for j in BORDER_VOX..dims[1] - BORDER_VOX {
                for i in BORDER_VOX..dims[0] - BORDER_VOX {
                    if f64::from(image.at(i, j, k)) < HEAD_FRACTION * max {
                        continue;
                    }
                    let d = |a: f32, b: f32| 0.5 * f64::from(a - b);
                    let g = [
                        d(image.at(i + 1, j, k), image.at(i - 1, j, k)),
                        d(image.at(i, j + 1, k), image.at(i, j - 1, k)),
                        d(image.at(i, j, k + 1), image.at(i, j, k - 1)),
                    ];
                    candidates.push((norm(g), [i, j, k]));
                }
            }
        }
        candidates.sort_by(|a, b| b.0.total_cmp(&a.0));
        let top = &candidates[..(TOP_GRADIENT_QUANTILE * candidates.len() as f64) as usize];
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        (0..n)
            .map(|_| {
                let [i, j, k] = top[rng.random_range(0..top.len())].1;
                image.voxel_point(i, j, k)
            })
            .collect()
    }

    /// The suggestion at each of `points` against `fixed`, with its error and the prediction's.
    pub fn measure(&self, fixed: &Image<Fixed>, points: &[[f64; 3]], params: &SuggestParams) -> Vec<Measured> {
        points
            .iter()
            .map(|&p| {
                let suggestion = suggest(&self.moving, fixed, &self.fixed_from_moving, Point3::from_array(p), params)
                    .expect("suggestion");
                let truth = self.truth.invert(p);
                Measured {
                    error_mm: norm(sub(suggestion.fixed.coords(), truth)),
                    predicted_error_mm: norm(sub(suggestion.predicted.coords(), truth)),
                    suggestion,
                }
            })
            .collect()
    }
}

/// One measured suggestion.
pub struct Measured {
    pub suggestion: Suggestion,
    pub error_mm: f64,
    pub predicted_error_mm: f64,
}

/// The figures of one contrast and seed.
pub struct Summary {
    pub predicted_median_mm: f64,
    pub predicted_p90_mm: f64,
    pub median_mm: f64,
    pub p90_mm: f64,
    pub max_mm: f64,
    pub flagged: usize,
    pub median_unflagged_mm: f64,
    pub median_flagged_mm: f64,
    pub p90_unflagged_mm: f64,
    /// Suggestions off by more than [`WRONG_MM`], and how many of them were flagged.
    pub wrong: usize,
    pub wrong_flagged: usize,
}

impl Summary {
    pub fn of(measured: &[Measured]) -> Self {
        let errors: Vec<f64> = measured.iter().map(|m| m.error_mm).collect();
        let predicted: Vec<f64> = measured.iter().map(|m| m.predicted_error_mm).collect();
        let flagged: Vec<f64> = measured.iter().filter(|m| m.suggestion.low_confidence).map(|m| m.error_mm).collect();
        let kept: Vec<f64> = measured.iter().filter(|m| !m.suggestion.low_confidence).map(|m| m.error_mm).collect();
        let wrong = |m: &&Measured| m.error_mm > WRONG_MM;
        Self {
            predicted_median_mm: quantile(&predicted, 0.5),
            predicted_p90_mm: quantile(&predicted, 0.9),
            median_mm: quantile(&errors, 0.5),
            p90_mm: quantile(&errors, 0.9),
            max_mm: errors.iter().copied().fold(0.0, f64::max),
            flagged: flagged.len(),
            median_unflagged_mm: quantile(&kept, 0.5),
            median_flagged_mm: quantile(&flagged, 0.5),
            p90_unflagged_mm: quantile(&kept, 0.9),
            wrong: measured.iter().filter(wrong).count(),
            wrong_flagged: measured.iter().filter(wrong).filter(|m| m.suggestion.low_confidence).count(),
        }
    }

    /// The columns of [`Self::row`], as a Markdown header and rule.
    pub fn header(first: &str) -> String {
        format!(
            "| {first} | prediction error median / P90 (mm) | suggestion error median (mm) | P90 (mm) | max (mm) | \
             flagged (of {POINTS}) | median error unflagged (mm) | median error flagged (mm) | > {WRONG_MM} mm \
             flagged | P90 unflagged (mm) |\n|---|---|---|---|---|---|---|---|---|---|"
        )
    }

    /// A Markdown table row.
    pub fn row(&self, name: &str) -> String {
        format!(
            "| {name} | {:.2} / {:.2} | {:.2} | {:.2} | {:.2} | {} | {:.2} | {:.2} | {} of {} | {:.2} |",
            self.predicted_median_mm,
            self.predicted_p90_mm,
            self.median_mm,
            self.p90_mm,
            self.max_mm,
            self.flagged,
            self.median_unflagged_mm,
            self.median_flagged_mm,
            self.wrong_flagged,
            self.wrong,
            self.p90_unflagged_mm,
        )
    }
}

/// The q-th quantile (linear interpolation) of `v`; NaN when `v` is empty.
pub fn quantile(v: &[f64], q: f64) -> f64 {
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    if s.is_empty() {
        return f64::NAN;
    }
    let x = q * (s.len() - 1) as f64;
    let (lo, hi) = (x.floor() as usize, x.ceil() as usize);
    s[lo] + (x - lo as f64) * (s[hi] - s[lo])
}

pub fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

pub fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

pub fn norm(v: [f64; 3]) -> f64 {
    dot(v, v).sqrt()
}
