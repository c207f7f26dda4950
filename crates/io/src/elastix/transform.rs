//! What an elastix transform parameter file holds once read: one [`Step`] per file, and the chain of them
//! ([`ElastixTransform`]) that transformix applies, with the fixed grid it resamples on.

use std::path::{Path, PathBuf};

use nalgebra::{DMatrix, Matrix3, Vector3};

use super::deformation_field::FieldStep;
use super::write::ElastixGrid;
use crate::error::{Error, Result};
use crate::itk_tfm::{ItkAffine, ItkBSpline};

/// The most landmarks a `SplineKernelTransform` may hold: its system has one row per landmark (and 4), solved once.
pub const MAX_KERNEL_LANDMARKS: usize = 5_000;

/// One file's transform T: fixed → moving, LPS mm.
#[derive(Clone, Debug, PartialEq)]
pub enum Step {
    /// `TranslationTransform`, `EulerTransform`, `SimilarityTransform`, `AffineTransform`.
    Linear(ItkAffine),
    /// `BSplineTransform` (or `RecursiveBSplineTransform`, the same function), cubic, with its grid's
    /// `index_from_lps` ([`ItkBSpline::index_from_lps`]), found once for every point it maps.
    BSpline(ItkBSpline, Matrix3<f64>),
    /// `SplineKernelTransform` with the `ThinPlateSpline` kernel.
    ThinPlate(ThinPlateKernel),
    /// `DeformationFieldTransform`: the field it names.
    Field(Box<FieldStep>),
}

impl Step {
    /// T(x).
    #[must_use]
    pub fn apply(&self, x: [f64; 3]) -> [f64; 3] {
        match self {
            Self::Linear(a) => a.apply(x),
            Self::BSpline(b, index_from_lps) => b.apply_with(index_from_lps, x),
            Self::ThinPlate(k) => k.apply(x),
            Self::Field(f) => f.apply(x),
        }
    }
}

/// One file of a chain: its path, as found, and its transform.
#[derive(Clone, Debug, PartialEq)]
pub struct Link {
    pub file: PathBuf,
    pub step: Step,
}

/// A chain of transforms as transformix applies it, `InitialTransformParameterFileName` first
/// (`HowToCombineTransforms "Compose"`): T(x) = Tₙ(… T₁(T₀(x))), with `links` = [T₀, …, Tₙ].
#[derive(Clone, Debug, PartialEq)]
pub struct ElastixTransform {
    /// The transforms, the first applied first; the last is the file that was named.
    pub links: Vec<Link>,
    /// The named file's `Size`, `Spacing`, `Origin` and `Direction`: the grid transformix resamples on and writes
    /// its deformation field over (`transformix -def all`); `None` when the file does not give them all.
    pub grid: Option<ElastixGrid>,
}

impl ElastixTransform {
    /// T(x), fixed → moving, LPS mm.
    #[must_use]
    pub fn apply(&self, x: [f64; 3]) -> [f64; 3] {
        self.links.iter().fold(x, |p, link| link.step.apply(p))
    }

    /// The chain as one affine when every transform in it is linear; else the first file that is not, with the
    /// `(Transform …)` it holds.
    ///
    /// # Errors
    /// The file that holds a deformable transform, and its kind.
    pub fn affine(&self) -> std::result::Result<ItkAffine, (&Path, &'static str)> {
        let (mut matrix, mut offset) = (Matrix3::identity(), Vector3::zeros());
        for link in &self.links {
            let a = match &link.step {
                Step::Linear(a) => a,
                Step::BSpline(..) => return Err((&link.file, "BSplineTransform")),
                Step::ThinPlate(_) => return Err((&link.file, "SplineKernelTransform")),
                Step::Field(_) => return Err((&link.file, "DeformationFieldTransform")),
            };
            offset = a.matrix * offset + Vector3::from(a.offset());
            matrix = a.matrix * matrix;
        }
        Ok(ItkAffine::from_offset(matrix, offset.into()))
    }
}

/// ITK's `ThinPlateSplineKernelTransform` (3-D) that elastix's `SplineKernelTransform` wraps: through source
/// landmarks sᵢ (`FixedImageLandmarks`) to targets tᵢ (`TransformParameters`),
/// T(x) = x + Σᵢ wᵢ ‖x − sᵢ‖ + A x + b, with the wᵢ, A and b that ITK's `KernelTransform::ComputeWMatrix` solves for:
/// (K + λI) W + P C = T − S, Pᵀ W = 0, where K_ij = ‖sᵢ − sⱼ‖, P's rows are (sᵢ, 1) and λ is the
/// `SplineRelaxationFactor` (ITK's stiffness; 0 interpolates the targets).
#[derive(Clone, Debug, PartialEq)]
pub struct ThinPlateKernel {
    sources: Vec<[f64; 3]>,
    weights: Vec<[f64; 3]>,
    /// A, row by row (component r of the displacement is Σ_c A[r][c] x_c).
    linear: Matrix3<f64>,
    translation: [f64; 3],
}

impl ThinPlateKernel {
    /// Solves the spline through `sources` → `targets` with relaxation `stiffness` (λ ≥ 0). `name` is used in
    /// errors: a count that differs, more than [`MAX_KERNEL_LANDMARKS`], a negative λ, or landmarks the system has
    /// no unique solution for (fewer than 4, all in one plane, or one given twice).
    ///
    /// # Errors
    /// As above, naming the file.
    pub fn solve(name: &Path, sources: Vec<[f64; 3]>, targets: &[[f64; 3]], stiffness: f64) -> Result<Self> {
        let n = sources.len();
        if targets.len() != n {
            return Err(Error::invalid(name, format!("{n} fixed image landmarks but {} targets", targets.len())));
        }
        if n > MAX_KERNEL_LANDMARKS {
            return Err(Error::invalid(
                name,
                format!("{n} landmarks; a spline kernel transform of at most {MAX_KERNEL_LANDMARKS} is read"),
            ));
        }
        if !(stiffness.is_finite() && stiffness >= 0.0) {
            return Err(Error::invalid(name, format!("SplineRelaxationFactor {stiffness} is not ≥ 0")));
        }
        check_spans_space(name, &sources)?;
        let m = n + 4;
        let mut l = DMatrix::<f64>::zeros(m, m);
        let mut rhs = DMatrix::<f64>::zeros(m, 3);
        for (i, s) in sources.iter().enumerate() {
            for (j, t) in sources.iter().enumerate() {
                l[(i, j)] = distance(*s, *t) + if i == j { stiffness } else { 0.0 };
            }
            for c in 0..4 {
                let p = if c < 3 { s[c] } else { 1.0 };
                l[(i, n + c)] = p;
                l[(n + c, i)] = p;
            }
            for c in 0..3 {
                rhs[(i, c)] = targets[i][c] - s[c];
            }
        }
        let unsolvable =
            || Error::invalid(name, format!("the thin-plate spline of its {n} landmarks cannot be solved"));
        let solution = l.lu().solve(&rhs).ok_or_else(unsolvable)?;
        if !solution.iter().all(|v| v.is_finite()) {
            return Err(unsolvable());
        }
        let weights = (0..n).map(|i| [solution[(i, 0)], solution[(i, 1)], solution[(i, 2)]]).collect();
        let linear = Matrix3::from_fn(|r, c| solution[(n + c, r)]);
        let translation = [solution[(n + 3, 0)], solution[(n + 3, 1)], solution[(n + 3, 2)]];
        Ok(Self { sources, weights, linear, translation })
    }

    /// T(x).
    #[must_use]
    pub fn apply(&self, x: [f64; 3]) -> [f64; 3] {
        let mut out: [f64; 3] = (self.linear * Vector3::from(x)).into();
        for r in 0..3 {
            out[r] += x[r] + self.translation[r];
        }
        for (s, w) in self.sources.iter().zip(&self.weights) {
            let g = distance(x, *s);
            for r in 0..3 {
                out[r] += g * w[r];
            }
        }
        out
    }
}

/// Refuses landmarks that leave the spline's system singular: fewer than 4, all in one plane, or one given twice
/// (relative to their extent, so that rounding cannot pass for a solution).
fn check_spans_space(name: &Path, sources: &[[f64; 3]]) -> Result<()> {
    let n = sources.len();
    let refuse = |why: &str| {
        Err(Error::invalid(name, format!("its {n} landmarks give the thin-plate spline no unique solution: {why}")))
    };
    if n < 4 {
        return refuse("it needs at least 4");
    }
    let mean = sources.iter().fold(Vector3::zeros(), |a, s| a + Vector3::from(*s)) / n as f64;
    let centred = DMatrix::from_fn(n, 3, |i, c| sources[i][c] - mean[c]);
    if !centred.iter().all(|v| v.is_finite()) {
        return refuse("their coordinates are too large to solve for");
    }
    // A bounded number of sweeps: the 3 singular values of finite coordinates converge in a few.
    let Some(svd) = centred.try_svd(false, false, f64::EPSILON, 1_000) else {
        return refuse("their spread cannot be measured");
    };
    let singular = svd.singular_values;
    let (largest, smallest) = (singular.max(), singular.min());
    if smallest.is_nan() || smallest <= 1e-9 * largest {
        return refuse("they lie in one plane");
    }
    let tiny = 1e-9 * largest;
    for (i, a) in sources.iter().enumerate() {
        if let Some(j) = sources[i + 1..].iter().position(|b| distance(*a, *b) <= tiny) {
            return refuse(&format!("landmarks {} and {} are one point", i + 1, i + j + 2));
        }
    }
    Ok(())
}

fn distance(a: [f64; 3], b: [f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Landmarks that span the space, and targets moved by an affine plus a bump.
    fn case() -> (Vec<[f64; 3]>, Vec<[f64; 3]>) {
        let sources: Vec<[f64; 3]> = (0..12)
            .map(|i| {
                let t = f64::from(i);
                [10.0 * (t * 1.3).sin(), 8.0 * (t * 0.7).cos() + t, 5.0 * (t * 2.1).sin() - 0.5 * t]
            })
            .collect();
        let targets = sources
            .iter()
            .map(|s| {
                [1.02 * s[0] - 0.1 * s[1] + 2.0, s[1] + 0.05 * s[2] - 1.0, s[2] + 3.0 * (-(s[0] / 6.0).powi(2)).exp()]
            })
            .collect();
        (sources, targets)
    }

    #[test]
    fn the_interpolating_spline_meets_its_targets_and_keeps_an_affine_exactly() {
        let name = Path::new("k.txt");
        let (sources, targets) = case();
        let k = ThinPlateKernel::solve(name, sources.clone(), &targets, 0.0).expect("solve");
        for (s, t) in sources.iter().zip(&targets) {
            let y = k.apply(*s);
            assert!((0..3).all(|r| (y[r] - t[r]).abs() < 1e-9), "{y:?} vs {t:?}");
        }
        // An affine map is the spline's own: no bending, so it holds away from the landmarks too.
        let affine = |p: [f64; 3]| [0.9 * p[0] + 0.2 * p[2] + 1.0, 1.1 * p[1] - 3.0, p[2] - 0.3 * p[0]];
        let moved: Vec<_> = sources.iter().map(|s| affine(*s)).collect();
        let k = ThinPlateKernel::solve(name, sources, &moved, 0.0).expect("solve");
        let y = k.apply([40.0, -25.0, 13.0]);
        let want = affine([40.0, -25.0, 13.0]);
        assert!((0..3).all(|r| (y[r] - want[r]).abs() < 1e-9), "{y:?} vs {want:?}");
    }

    #[test]
    fn relaxation_lets_the_spline_miss_its_targets() {
        let name = Path::new("k.txt");
        let (sources, targets) = case();
        let k = ThinPlateKernel::solve(name, sources.clone(), &targets, 50.0).expect("solve");
        let miss = sources.iter().zip(&targets).map(|(s, t)| distance(k.apply(*s), *t)).fold(0.0, f64::max);
        assert!(miss > 0.01, "a relaxed spline smooths: {miss}");
    }

    #[test]
    fn landmarks_without_a_unique_spline_are_refused() {
        let name = Path::new("k.txt");
        let flat: Vec<[f64; 3]> = (0..6).map(|i| [f64::from(i), f64::from(i * i % 5), 2.0]).collect();
        let e = ThinPlateKernel::solve(name, flat.clone(), &flat, 0.0).expect_err("coplanar");
        assert!(e.to_string().starts_with("k.txt: ") && e.to_string().contains("no unique solution"), "{e}");
        let e = ThinPlateKernel::solve(name, flat[..3].to_vec(), &flat, 0.0).expect_err("counts");
        assert!(e.to_string().contains("3 fixed image landmarks but 6 targets"), "{e}");
        let (s, t) = case();
        assert!(ThinPlateKernel::solve(name, s, &t, -1.0).is_err(), "negative relaxation");
    }
}
