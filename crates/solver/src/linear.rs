//! Affine, similarity and rigid least-squares fits between landmark pairs, and the predicted
//! target registration error (TRE) of such a fit.
//!
//! # Fits
//!
//! Given pairs (p_i ∈ `From`, q_i ∈ `To`), i = 1…N, each fit minimises Σ_i ‖f(p_i) − q_i‖² over its
//! family f(x) = A x + b:
//!
//! - **affine** ([`fit_affine`]): A ∈ ℝ³ˣ³ free (12 parameters). With centred points p'_i = p_i − p̄,
//!   q'_i = q_i − q̄ the normal equations give A = (Σ q'_i p'_iᵀ)(Σ p'_i p'_iᵀ)⁻¹ and b = q̄ − A p̄ (solved by
//!   Cholesky with one step of iterative refinement). Needs N ≥ 4 points that are not coplanar.
//! - **similarity** ([`fit_similarity`]) and **rigid** ([`fit_rigid`]): A = c R with R ∈ SO(3), after
//!   Umeyama (1991, "Least-squares estimation of transformation parameters between two point
//!   patterns", IEEE TPAMI 13(4):376–380). With Σ_xy = (1/N) Σ q'_i p'_iᵀ = U D Vᵀ (SVD) and
//!   σ_p² = (1/N) Σ ‖p'_i‖²:
//!
//!   R = U S Vᵀ,  S = diag(1, 1, det U · det V),  c = tr(D S) / σ_p²,  b = q̄ − c R p̄,
//!
//!   where the sign in S is the reflection fix that keeps det R = +1 even when the best orthogonal
//!   fit would be a reflection (noisy or mirrored inputs). Rigid fixes c = 1. The rotation is unique
//!   when rank Σ_xy ≥ 2 (Umeyama's condition), which needs N ≥ 3 points that are not collinear:
//!   with one or two points, or a collinear set, a rotation about the points' line leaves every
//!   residual unchanged, so these inputs are rejected with [`SolverError::TooFew`] or
//!   [`SolverError::Flat`] instead of returning an arbitrary rotation.
//!
//! Every fit first checks its pairs with [`crate::pairs::validate`] and [`LinearKind::needs`], as every method
//! does: too few distinct pairs, a coincident, collinear or (affine) coplanar side, or one point with two partners
//! is refused; a repeated pair counts once (so N below is the number of distinct pairs). The same ratio,
//! [`DEGENERACY_RATIO`] (= [`crate::pairs::FLAT_RTOL`]), judges the fits' own checks: the RMS spread of the points
//! along their second (rigid, similarity) or third (affine) principal axis against the spread along the first.
//!
//! Every fit reports its fiducial registration error FRE = √((1/N) Σ ‖f(p_i) − q_i‖²) (RMS, mm).
//!
//! The pull-back (fixed → moving) is fitted directly from the reversed pairs ([`fit_pullback`]),
//! not by inverting the forward fit; for rigid fits the two agree exactly, for similarity and affine
//! fits only when the residuals vanish (least squares is not symmetric in its two point sets).
//!
//! # Predicted TRE
//!
//! Fitzpatrick, West & Maurer (1998, "Predicting error in rigid-body point-based registration",
//! IEEE TMI 17(5):694–702) give, to first order in the fiducial localisation error (FLE), for the
//! rigid fit:
//!
//! ⟨TRE²(r)⟩ ≈ (⟨FLE²⟩ / N) · (1 + (1/3) Σ_{k=1..3} d_k² / f_k²),
//!
//! where d_k is the distance of the target r from principal axis k of the fiducial configuration
//! (through the centroid) and f_k the RMS distance of the fiducials from that axis. In the principal
//! frame, with λ_k the mean squared fiducial coordinate along axis k and x_k the target's
//! coordinate, f_k² = Σ_{j≠k} λ_j and d_k² = Σ_{j≠k} x_j². The same paper gives
//! ⟨FRE²⟩ ≈ (1 − 2/N) ⟨FLE²⟩, so we estimate ⟨FLE²⟩ ≈ FRE² · N/(N − 2) ([`fle_from_fre`]).
//!
//! For the other two kinds we use the analogous first-order (exact for the affine fit) expressions
//! for isotropic, independent FLE of variance ⟨FLE²⟩/3 per axis in the target points; they are our
//! derivations, in the same notation, and are checked against Monte-Carlo simulation in the tests:
//!
//! - **affine**: the fit is an ordinary linear regression per output coordinate, so the prediction
//!   variance at r is the regression leverage: ⟨TRE²(r)⟩ = (⟨FLE²⟩/N) · (1 + Σ_k x_k² / λ_k).
//!   It grows much faster than the rigid prediction away from the fiducials, and in the flattest
//!   direction of the configuration in particular.
//! - **similarity**: the scale error is uncorrelated with the rotation error to first order (it uses
//!   the radial, the rotation the tangential part of the FLE), which adds a radial term:
//!   ⟨TRE²(r)⟩ ≈ (⟨FLE²⟩/N) · (1 + (1/3) Σ_k d_k²/f_k² + (1/3) ‖r − p̄‖² / Σ_k λ_k).
//!
//! The FLE estimator generalises the same way: ⟨FRE²⟩ ≈ (1 − m/(3N)) ⟨FLE²⟩ with m = 6, 7, 12
//! parameters (rigid, similarity, affine). When both point sets carry localisation error, ⟨FLE²⟩ is
//! the sum of the two spaces' FLE² (exact for rigid fits, first order for the others).

use std::fmt;
use std::marker::PhantomData;
use std::ops::Mul;
use std::str::FromStr;

use nalgebra::{Matrix3, SymmetricEigen, Vector3};
use warpbench_io::geometry::{Point3, Space, Transform};

use crate::pairs::{self, Needs, Spread};
use crate::spaces::{Fixed, Moving};
use crate::{Result, SolverError, Warp};

/// Degeneracy threshold: a configuration whose RMS spread along a needed principal axis is below
/// this fraction of the spread along the first axis is treated as collinear (rigid, similarity) or
/// coplanar (affine). 1e-6 keeps well above floating-point noise (≈ 1e-8 for exactly collinear
/// points) while accepting any configuration a user could click.
pub const DEGENERACY_RATIO: f64 = crate::pairs::FLAT_RTOL;

/// Which family of linear maps to fit.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum LinearKind {
    /// A x + b with A free (12 parameters).
    Affine,
    /// c R x + b with R a rotation and c > 0 a uniform scale (7 parameters).
    Similarity,
    /// R x + b with R a rotation (6 parameters).
    Rigid,
}

impl LinearKind {
    /// Every kind, in a fixed order.
    pub const ALL: [Self; 3] = [Self::Affine, Self::Similarity, Self::Rigid];

    /// The name used on the command line and in reports.
    #[must_use]
    pub const fn name(self) -> &'static str {
        match self {
            Self::Affine => "affine",
            Self::Similarity => "similarity",
            Self::Rigid => "rigid",
        }
    }

    /// The fewest landmark pairs that determine a unique fit (in general position).
    #[must_use]
    pub const fn min_points(self) -> usize {
        match self {
            Self::Affine => 4,
            Self::Similarity | Self::Rigid => 3,
        }
    }

    /// What the fit needs of its pairs ([`crate::pairs`]): affine 4 distinct pairs, neither side coplanar;
    /// similarity and rigid 3, neither side collinear.
    #[must_use]
    pub const fn needs(self) -> Needs {
        let spread = match self {
            Self::Affine => Spread::NotCoplanar,
            Self::Similarity | Self::Rigid => Spread::NotCollinear,
        };
        Needs { method: self.name(), min_pairs: self.min_points(), spread }
    }

    /// Degrees of freedom of the family.
    #[must_use]
    pub const fn parameter_count(self) -> usize {
        match self {
            Self::Affine => 12,
            Self::Similarity => 7,
            Self::Rigid => 6,
        }
    }
}

impl fmt::Display for LinearKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for LinearKind {
    type Err = SolverError;
    fn from_str(s: &str) -> Result<Self> {
        Self::ALL.into_iter().find(|k| k.name().eq_ignore_ascii_case(s.trim())).ok_or_else(|| {
            SolverError::InvalidParameter(format!("unknown linear kind {s:?} (affine, similarity, rigid)"))
        })
    }
}

/// An affine map x ↦ A x + b from space `From` to space `To` (mm), f64. Name values `to_from_*`,
/// e.g. `fixed_from_moving`.
#[derive(Clone, Copy)]
pub struct AffineWarp<To: Space, From: Space> {
    linear: Matrix3<f64>,
    translation: Vector3<f64>,
    spaces: PhantomData<(To, From)>,
}

impl<To: Space, From: Space> PartialEq for AffineWarp<To, From> {
    fn eq(&self, other: &Self) -> bool {
        self.linear == other.linear && self.translation == other.translation
    }
}

impl<To: Space, From: Space> fmt::Debug for AffineWarp<To, From> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct(&format!("AffineWarp<{} <- {}>", To::NAME, From::NAME))
            .field("linear", &self.linear)
            .field("translation", &self.translation)
            .finish()
    }
}

impl<To: Space, From: Space> AffineWarp<To, From> {
    /// x ↦ `linear` · x + `translation`.
    #[must_use]
    pub fn new(linear: Matrix3<f64>, translation: [f64; 3]) -> Self {
        Self { linear, translation: Vector3::from(translation), spaces: PhantomData }
    }

    #[must_use]
    pub fn identity() -> Self {
        Self::new(Matrix3::identity(), [0.0; 3])
    }

    /// Reads the linear part and translation of a homogeneous transform.
    #[must_use]
    pub fn from_transform(to_from: &Transform<To, From>) -> Self {
        Self::new(to_from.linear(), to_from.translation())
    }

    /// The 4×4 homogeneous form.
    #[must_use]
    pub fn to_transform(&self) -> Transform<To, From> {
        Transform::from_linear_translation(self.linear, self.translation.into())
    }

    /// The 3×3 linear part A.
    #[must_use]
    pub fn linear(&self) -> Matrix3<f64> {
        self.linear
    }

    /// The translation b (mm).
    #[must_use]
    pub fn translation(&self) -> [f64; 3] {
        self.translation.into()
    }

    /// The exact inverse x ↦ A⁻¹ (x − b); [`SolverError::Degenerate`] when A is singular (relative
    /// to its size) or not finite.
    pub fn inverse(&self) -> Result<AffineWarp<From, To>> {
        let scale = self.linear.norm();
        let det = self.linear.determinant();
        if !(scale.is_finite() && self.translation.iter().all(|v| v.is_finite()) && det.abs() > 1e-14 * scale.powi(3)) {
            return Err(SolverError::Degenerate(format!("the linear part is singular or not finite (det {det:e})")));
        }
        let inv =
            self.linear.try_inverse().ok_or_else(|| SolverError::Degenerate("the linear part is singular".into()))?;
        let t = -(inv * self.translation);
        Ok(AffineWarp { linear: inv, translation: t, spaces: PhantomData })
    }
}

/// `c_from_b * b_from_a = c_from_a`.
impl<C: Space, B: Space, A: Space> Mul<AffineWarp<B, A>> for AffineWarp<C, B> {
    type Output = AffineWarp<C, A>;
    fn mul(self, rhs: AffineWarp<B, A>) -> AffineWarp<C, A> {
        AffineWarp {
            linear: self.linear * rhs.linear,
            translation: self.linear * rhs.translation + self.translation,
            spaces: PhantomData,
        }
    }
}

impl<To: Space, From: Space> Warp<To, From> for AffineWarp<To, From> {
    fn apply_raw(&self, x: [f64; 3]) -> [f64; 3] {
        (self.linear * Vector3::from(x) + self.translation).into()
    }

    /// The exact, constant Jacobian A.
    fn jacobian_raw(&self, _x: [f64; 3]) -> Matrix3<f64> {
        self.linear
    }
}

/// A fitted linear map with its goodness of fit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LinearFit<To: Space, From: Space> {
    pub kind: LinearKind,
    /// The map, e.g. `fixed_from_moving` for a forward fit.
    pub warp: AffineWarp<To, From>,
    /// The uniform scale c: 1 for rigid, c for similarity, ∛det A for affine.
    pub scale: f64,
    /// Fiducial registration error: RMS residual over the landmark pairs, mm.
    pub fre_rms_mm: f64,
    /// N, the number of landmark pairs.
    pub landmark_count: usize,
}

impl<To: Space, From: Space> LinearFit<To, From> {
    /// The FLE estimated from this fit's FRE ([`fle_from_fre`]); `None` when N is too small for
    /// the residual to carry information (3N ≤ number of parameters).
    #[must_use]
    pub fn estimated_fle_rms_mm(&self) -> Option<f64> {
        fle_from_fre(self.kind, self.fre_rms_mm, self.landmark_count)
    }
}

/// Fits `kind` to the pairs (p_i = `src[i]`, q_i = `dst[i]`).
pub fn fit<To: Space, From: Space>(
    kind: LinearKind,
    src: &[Point3<From>],
    dst: &[Point3<To>],
) -> Result<LinearFit<To, From>> {
    match kind {
        LinearKind::Affine => fit_affine(src, dst),
        LinearKind::Similarity => fit_similarity(src, dst),
        LinearKind::Rigid => fit_rigid(src, dst),
    }
}

/// The forward map `fixed_from_moving`, fitted from (moving, fixed) landmark pairs.
pub fn fit_forward(
    kind: LinearKind,
    moving: &[Point3<Moving>],
    fixed: &[Point3<Fixed>],
) -> Result<LinearFit<Fixed, Moving>> {
    fit(kind, moving, fixed)
}

/// The pull-back `moving_from_fixed`, fitted directly from the reversed pairs (fixed → moving).
pub fn fit_pullback(
    kind: LinearKind,
    moving: &[Point3<Moving>],
    fixed: &[Point3<Fixed>],
) -> Result<LinearFit<Moving, Fixed>> {
    fit(kind, fixed, moving)
}

/// Least-squares affine fit; needs ≥ 4 non-coplanar source points.
pub fn fit_affine<To: Space, From: Space>(src: &[Point3<From>], dst: &[Point3<To>]) -> Result<LinearFit<To, From>> {
    let kind = LinearKind::Affine;
    let (p, q) = prepare(kind, src, dst)?;
    let shape = PrincipalFrame::of(&p);
    shape.require_rank(3, "affine", From::NAME, "coplanar")?;
    let (pm, qm) = (Vector3::from(mean(&p)), Vector3::from(mean(&q)));
    // Normal equations S Aᵀ = Σ p'_i q'_iᵀ with S = Σ p'_i p'_iᵀ, solved by Cholesky (S is
    // positive definite once the configuration is not coplanar), plus one step of iterative
    // refinement on the residuals, which recovers the accuracy the squared condition number costs.
    let mut scatter = Matrix3::zeros();
    for pi in &p {
        let d = Vector3::from(*pi) - pm;
        scatter += d * d.transpose();
    }
    let chol = scatter.cholesky().ok_or_else(|| {
        SolverError::Degenerate(format!("affine: the scatter matrix of the {} points is singular", From::NAME))
    })?;
    let solve_step = |linear: &Matrix3<f64>| {
        let mut rhs = Matrix3::zeros();
        for (pi, qi) in p.iter().zip(&q) {
            let dp = Vector3::from(*pi) - pm;
            let residual = Vector3::from(*qi) - qm - linear * dp;
            rhs += dp * residual.transpose();
        }
        chol.solve(&rhs).transpose()
    };
    let mut linear = solve_step(&Matrix3::zeros());
    linear += solve_step(&linear);
    let translation = qm - linear * pm;
    let warp = AffineWarp { linear, translation, spaces: PhantomData };
    let det = linear.determinant();
    finish(kind, warp, det.signum() * det.abs().cbrt(), &p, &q)
}

/// Least-squares similarity fit (Umeyama 1991); needs ≥ 3 non-collinear source points.
pub fn fit_similarity<To: Space, From: Space>(src: &[Point3<From>], dst: &[Point3<To>]) -> Result<LinearFit<To, From>> {
    umeyama(LinearKind::Similarity, src, dst)
}

/// Least-squares rigid fit (Umeyama 1991 without scale, i.e. Arun/Horn); det R = +1 always; needs
/// ≥ 3 non-collinear source points.
pub fn fit_rigid<To: Space, From: Space>(src: &[Point3<From>], dst: &[Point3<To>]) -> Result<LinearFit<To, From>> {
    umeyama(LinearKind::Rigid, src, dst)
}

fn umeyama<To: Space, From: Space>(
    kind: LinearKind,
    src: &[Point3<From>],
    dst: &[Point3<To>],
) -> Result<LinearFit<To, From>> {
    let (p, q) = prepare(kind, src, dst)?;
    let shape = PrincipalFrame::of(&p);
    shape.require_rank(2, kind.name(), From::NAME, "collinear (the rotation about their line is undetermined)")?;
    let n = p.len() as f64;
    let (pm, qm) = (Vector3::from(mean(&p)), Vector3::from(mean(&q)));
    let mut sigma_xy = Matrix3::zeros();
    let mut var_p = 0.0;
    for (pi, qi) in p.iter().zip(&q) {
        let (dp, dq) = (Vector3::from(*pi) - pm, Vector3::from(*qi) - qm);
        sigma_xy += dq * dp.transpose();
        var_p += dp.norm_squared();
    }
    sigma_xy /= n;
    var_p /= n;
    let svd = sigma_xy.svd(true, true);
    let (Some(u), Some(v_t)) = (svd.u, svd.v_t) else {
        return Err(SolverError::Degenerate("the SVD of the cross-covariance failed".into()));
    };
    let d = svd.singular_values;
    let d_max = d.max();
    let mut sorted = [d[0], d[1], d[2]];
    sorted.sort_by(|a, b| b.total_cmp(a));
    // Umeyama's uniqueness condition rank Σ_xy ≥ 2; Σ_xy's singular values scale like squared
    // spreads, hence the squared ratio.
    if !(d_max > 0.0 && sorted[1] > DEGENERACY_RATIO * DEGENERACY_RATIO * d_max) {
        return Err(SolverError::Degenerate(format!(
            "{}: the {} points are collinear or coincide, so the rotation is undetermined",
            kind.name(),
            To::NAME
        )));
    }
    let mut s = Vector3::new(1.0, 1.0, 1.0);
    if u.determinant() * v_t.determinant() < 0.0 {
        s[d.imin()] = -1.0;
    }
    let rotation = u * Matrix3::from_diagonal(&s) * v_t;
    let scale = match kind {
        LinearKind::Similarity => d.dot(&s) / var_p,
        _ => 1.0,
    };
    if !(scale.is_finite() && scale > 0.0) {
        return Err(SolverError::Degenerate(format!("similarity: the fitted scale is {scale}")));
    }
    let linear = rotation * scale;
    let translation = qm - linear * pm;
    finish(kind, AffineWarp { linear, translation, spaces: PhantomData }, scale, &p, &q)
}

/// Source and target coordinates, raw mm.
type RawPairs = (Vec<[f64; 3]>, Vec<[f64; 3]>);

/// Checks the pairs ([`pairs::validate`] with [`LinearKind::needs`]), returning the raw coordinates of the distinct
/// ones: a repeated pair counts once, as in every method.
fn prepare<To: Space, From: Space>(kind: LinearKind, src: &[Point3<From>], dst: &[Point3<To>]) -> Result<RawPairs> {
    let checked = pairs::validate(&kind.needs(), src, dst)?;
    Ok((checked.distinct_raw(src), checked.distinct_raw(dst)))
}

fn finish<To: Space, From: Space>(
    kind: LinearKind,
    warp: AffineWarp<To, From>,
    scale: f64,
    p: &[[f64; 3]],
    q: &[[f64; 3]],
) -> Result<LinearFit<To, From>> {
    let sum_sq: f64 = p
        .iter()
        .zip(q)
        .map(|(pi, qi)| {
            let r = warp.apply_raw(*pi);
            (0..3).map(|a| (r[a] - qi[a]).powi(2)).sum::<f64>()
        })
        .sum();
    let fre_rms_mm = (sum_sq / p.len() as f64).sqrt();
    if !(fre_rms_mm.is_finite() && warp.linear.iter().chain(warp.translation.iter()).all(|v| v.is_finite())) {
        return Err(SolverError::Degenerate(format!("{}: the fit is not finite", kind.name())));
    }
    Ok(LinearFit { kind, warp, scale, fre_rms_mm, landmark_count: p.len() })
}

fn mean(points: &[[f64; 3]]) -> [f64; 3] {
    let n = points.len() as f64;
    let mut m = [0.0; 3];
    for p in points {
        for a in 0..3 {
            m[a] += p[a];
        }
    }
    m.map(|v| v / n)
}

/// The principal axes of a point configuration: centroid, unit axes (columns, sorted by
/// decreasing spread) and λ_k, the mean squared coordinate along each axis.
#[derive(Clone, Copy, Debug)]
struct PrincipalFrame {
    centroid: Vector3<f64>,
    axes: Matrix3<f64>,
    lambda: [f64; 3],
}

impl PrincipalFrame {
    fn of(points: &[[f64; 3]]) -> Self {
        let centroid = Vector3::from(mean(points));
        let mut cov = Matrix3::zeros();
        for p in points {
            let d = Vector3::from(*p) - centroid;
            cov += d * d.transpose();
        }
        cov /= points.len().max(1) as f64;
        let eig = SymmetricEigen::new(cov);
        let mut order = [0, 1, 2];
        order.sort_by(|&a, &b| eig.eigenvalues[b].total_cmp(&eig.eigenvalues[a]));
        let axes = Matrix3::from_columns(&order.map(|k| eig.eigenvectors.column(k).into_owned()));
        let lambda = order.map(|k| eig.eigenvalues[k].max(0.0));
        Self { centroid, axes, lambda }
    }

    /// Requires spread along the first `rank` axes (relative to [`DEGENERACY_RATIO`]).
    fn require_rank(&self, rank: usize, method: &str, space: &str, shape: &str) -> Result<()> {
        let first = self.lambda[0];
        if !(first.is_finite() && first > 0.0) {
            return Err(SolverError::Degenerate(format!("{method}: all {space} points coincide")));
        }
        let ratio = (self.lambda[rank - 1] / first).sqrt();
        if ratio < DEGENERACY_RATIO {
            return Err(SolverError::Degenerate(format!(
                "{method}: the {space} points are {shape} (spread ratio {ratio:.1e})"
            )));
        }
        Ok(())
    }

    /// The target's coordinates along the principal axes.
    fn coordinates(&self, target: [f64; 3]) -> [f64; 3] {
        let x = self.axes.transpose() * (Vector3::from(target) - self.centroid);
        [x[0], x[1], x[2]]
    }
}

/// ⟨FLE²⟩^{1/2} estimated from an observed FRE (RMS, mm): ⟨FLE²⟩ ≈ FRE² · 3N / (3N − m), with m the
/// parameter count of `kind`. For rigid fits this is Fitzpatrick, West & Maurer's (1998)
/// ⟨FRE²⟩ ≈ (1 − 2/N) ⟨FLE²⟩, i.e. ⟨FLE²⟩ ≈ FRE² · N/(N − 2). `None` when 3N ≤ m (the fit
/// interpolates and FRE says nothing) or FRE is not finite.
#[must_use]
pub fn fle_from_fre(kind: LinearKind, fre_rms_mm: f64, landmark_count: usize) -> Option<f64> {
    let dof = 3 * landmark_count;
    let m = kind.parameter_count();
    (dof > m && fre_rms_mm.is_finite() && fre_rms_mm >= 0.0)
        .then(|| (fre_rms_mm * fre_rms_mm * dof as f64 / (dof - m) as f64).sqrt())
}

/// Predicts the RMS TRE, √⟨TRE²(r)⟩ in mm, of a `kind` fit at many targets for one fiducial
/// configuration and FLE (module docs give the formulas).
#[derive(Clone, Copy, Debug)]
pub struct TrePredictor<S: Space> {
    kind: LinearKind,
    frame: PrincipalFrame,
    fle_sq_over_n: f64,
    space: PhantomData<S>,
}

impl<S: Space> TrePredictor<S> {
    /// `fiducials` are the landmark positions in the fit's source space; `fle_rms_mm` is
    /// √⟨FLE²⟩ (e.g. from [`LinearFit::estimated_fle_rms_mm`]).
    pub fn new(kind: LinearKind, fiducials: &[Point3<S>], fle_rms_mm: f64) -> Result<Self> {
        if !(fle_rms_mm.is_finite() && fle_rms_mm >= 0.0) {
            return Err(SolverError::InvalidParameter(format!("FLE must be finite and ≥ 0, got {fle_rms_mm}")));
        }
        if let Some(index) = fiducials.iter().position(|p| !p.is_finite()) {
            return Err(SolverError::NonFinite { pair: index + 1 });
        }
        if fiducials.len() < kind.min_points() {
            return Err(SolverError::TooFew { method: kind.name(), needed: kind.min_points(), got: fiducials.len() });
        }
        let raw: Vec<[f64; 3]> = fiducials.iter().map(Point3::coords).collect();
        let frame = PrincipalFrame::of(&raw);
        match kind {
            LinearKind::Affine => frame.require_rank(3, "affine TRE", S::NAME, "coplanar")?,
            _ => frame.require_rank(2, kind.name(), S::NAME, "collinear")?,
        }
        let fle_sq_over_n = fle_rms_mm * fle_rms_mm / fiducials.len() as f64;
        Ok(Self { kind, frame, fle_sq_over_n, space: PhantomData })
    }

    /// ⟨TRE²(r)⟩ in mm²; +∞ for a non-finite target.
    #[must_use]
    pub fn expected_tre_sq_mm2(&self, target: Point3<S>) -> f64 {
        if !target.is_finite() {
            return f64::INFINITY;
        }
        let x = self.frame.coordinates(target.coords());
        let l = self.frame.lambda;
        let x2 = x.map(|v| v * v);
        let rigid = || {
            (0..3)
                .map(|k| {
                    let (i, j) = ((k + 1) % 3, (k + 2) % 3);
                    (x2[i] + x2[j]) / (l[i] + l[j])
                })
                .sum::<f64>()
                / 3.0
        };
        let factor = match self.kind {
            LinearKind::Rigid => 1.0 + rigid(),
            LinearKind::Similarity => 1.0 + rigid() + (x2[0] + x2[1] + x2[2]) / (3.0 * (l[0] + l[1] + l[2])),
            LinearKind::Affine => 1.0 + (0..3).map(|k| x2[k] / l[k]).sum::<f64>(),
        };
        self.fle_sq_over_n * factor
    }

    /// √⟨TRE²(r)⟩ in mm.
    #[must_use]
    pub fn rms_tre_mm(&self, target: Point3<S>) -> f64 {
        self.expected_tre_sq_mm2(target).sqrt()
    }
}

/// Fitzpatrick, West & Maurer (1998) predicted RMS TRE (mm) of a **rigid** fit at `target`:
/// √[(⟨FLE²⟩/N)(1 + (1/3) Σ_k d_k²/f_k²)], with `fle_rms_mm` = √⟨FLE²⟩.
///
/// Returns +∞ where the rigid fit itself is undetermined or an input is invalid (fewer than 3
/// fiducials, a collinear configuration, a non-finite coordinate, a negative FLE): the error is
/// then unbounded rather than NaN. Use [`TrePredictor`] for typed errors, other kinds and many
/// targets.
#[must_use]
pub fn predicted_tre<S: Space>(fiducials: &[Point3<S>], fle_rms_mm: f64, target: Point3<S>) -> f64 {
    predicted_tre_for(LinearKind::Rigid, fiducials, fle_rms_mm, target).unwrap_or(f64::INFINITY)
}

/// Predicted RMS TRE (mm) of a `kind` fit at `target` (module docs give the formulas).
pub fn predicted_tre_for<S: Space>(
    kind: LinearKind,
    fiducials: &[Point3<S>],
    fle_rms_mm: f64,
    target: Point3<S>,
) -> Result<f64> {
    if !target.is_finite() {
        return Err(SolverError::InvalidParameter(
            "the point to predict the TRE at has a non-finite coordinate".into(),
        ));
    }
    Ok(TrePredictor::new(kind, fiducials, fle_rms_mm)?.rms_tre_mm(target))
}
