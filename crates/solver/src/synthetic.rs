//! Seeded synthetic warps with known forward maps and inverses, for accuracy tests and `eval`.
//!
//! Each [`SyntheticWarp`] is a forward warp d = `fixed_from_moving`, d(x) = x + u(x), defined over the
//! moving volume's box Ω (an [`Aabb<Moving>`] with edges L = (L_x, L_y, L_z) and centre c), with an
//! amplitude A in mm and a seed. The same (kind, Ω, A, seed) always gives the same warp (ChaCha8).
//! [`SyntheticWarp::pullback`] gives u = d⁻¹ = `moving_from_fixed`: in closed form where one exists,
//! otherwise point by point by damped Newton iteration (falling back to the fixed-point iteration
//! x ← y − u(x)) to [`INVERSE_TOLERANCE_MM`].
//!
//! # Kinds
//!
//! - **`sine`** — a smooth periodic shear, one wavelength across the box (after the procedural
//!   perturbations of the Real-Time Volume Graphics course notes, v(x) = Σ Aᵢ sin(fᵢ x + φᵢ)):
//!   u_a(x) = a · sin(2π (x_b − Ω.min_b)/L_b + φ_a), b = a + 1 mod 3, a = A/√3, random phases φ_a.
//!   Each component depends on another axis, so J = I + N with one off-diagonal entry per row and
//!   det J = 1 + N₀₁N₁₂N₂₀ exactly. The three sines peak independently, so max ‖u‖ = A.
//!   Lipschitz constant of u: ℓ = 2πa / min_b L_b; **fold-free and invertible by fixed-point iteration
//!   iff ℓ < 1**, i.e. A < √3 · min L / (2π) ≈ 0.276 min L (55 mm for a 200 mm box); larger A is
//!   rejected. No closed-form inverse.
//! - **`twist`** — rotation about the line through c along an axis (x, y or z by seed) by an angle
//!   that grows linearly along it: θ(s) = κ (s − s₀), s the axial coordinate, s₀ random in the middle
//!   half of the box, random sign of κ (Barr 1984; the twists of Brunet et al. 2006 §3.3). The
//!   largest displacement is 2R sin(|θ_max|/2), at the corners of the face farthest from s₀, with
//!   R the half-diagonal across the axis and θ_max = κ (L_s/2 + |s₀ − c_s|); so
//!   κ = 2 asin(A/2R) / (L_s/2 + |s₀ − c_s|) reproduces A **exactly**. det J = 1 everywhere (volume
//!   preserving, never folds); A ≤ 2R is required. Inverse in closed form: rotate back by −θ(s)
//!   (the twist leaves s unchanged).
//! - **`bend`** — the axial line through c is bent into a circular arc of curvature κ (radius ρ = 1/κ)
//!   in the plane of the axial axis s and a normal axis n (chosen by seed, with a random sign), the
//!   third axis untouched (Barr 1984; Westermann & Rezk-Salama 2001 and Brunet et al. §3.3 bends).
//!   With s measured from s₀ (random in the middle half of the box) and n from c:
//!   φ = κ s,  s' = (ρ − n) sin φ,  n' = ρ − (ρ − n) cos φ.
//!   det J = 1 − κ n, so the bend is **fold-free iff κ · L_n/2 < 1**; we also keep κ max|s| < π so
//!   the arc does not wrap. κ is found by bisection so that the largest displacement (at a corner:
//!   ‖d(x) − x‖² is convex in n and grows with |s|) equals A **exactly**; amplitudes that need
//!   κ > 0.9 of either limit are rejected. Inverse in closed form: polar coordinates about the centre
//!   of curvature, r = √(s'² + (ρ − n')²), φ = atan2(s', ρ − n'), s = ρ φ, n = ρ − r.
//! - **`bump`** — a Gaussian bump: u(x) = A exp(−‖x − c_b‖²/(2σ²)) v, v a random unit vector, c_b
//!   random in the middle half of the box, σ = L_min · U(1/8, 1/5). max ‖u‖ = A at c_b. The
//!   Lipschitz constant of u is ℓ = A e^{−1/2}/σ; det J = 1 + A⟨v, ∇g⟩ ≥ 1 − ℓ, and the fixed-point
//!   iteration x ← y − u(x) contracts with rate ℓ: **fold-free and convergent iff A < √e · σ**
//!   (always when A < 0.206 L_min); larger A is rejected.
//! - **`tps-random`** — a random thin-plate spline with the identity as its affine part,
//!   f(x) = x + Σᵢ wᵢ ‖x − cᵢ‖ (U(r) = r in 3-D; Davis et al. 1997), evaluated by
//!   [`crate::tps::Tps::from_parts`]: 8 centres, one per octant of the box, jittered by ±10 % of L;
//!   random weights projected onto the TPS side conditions Σ wᵢ = 0, Σ wᵢ cᵢᵀ = 0 (so the spline is
//!   the minimum-bending-energy interpolant of its own values), then scaled so that the largest
//!   displacement on the [`AMPLITUDE_GRID`]³ grid is A exactly. Lipschitz bound ℓ ≤ Σᵢ ‖wᵢ‖.
//! - **`bspline-random`** — a cubic B-spline displacement on a 3×3×3-cell lattice over the box
//!   (6³ control points; Lee, Wolberg & Shin 1997; evaluated by [`crate::bspline::ControlLattice`]),
//!   coefficients uniform in the unit ball, scaled like `tps-random`. Lipschitz bound
//!   ℓ ≤ ‖(max |Δ_b φ_a| / h_b)_{ab}‖_F.
//!
//! Amplitudes above the box's shortest edge are rejected for every kind.
//!
//! For every kind [`SyntheticWarp::displacement_lipschitz_bound`] gives ℓ where it is known; ℓ < 1
//! guarantees d is injective with det J > 0 and that the numerical inverse converges. In practice all
//! six kinds are fold-free at A = 10 mm over a 200 mm box (tested); `tps-random` and
//! `bspline-random` have no closed-form condition, so check ℓ or the Jacobian for larger A.
//!
//! # Amplitude
//!
//! A is the largest displacement ‖d(x) − x‖ over Ω, in mm: exact for `twist` and `bend` (attained at a
//! corner), exact on the measuring grid for `tps-random` and `bspline-random` (by scaling), and the
//! analytic peak for `sine` and `bump` (the grid sees slightly less: within 2 % on the 41³ grid).
//! [`SyntheticWarp::max_displacement_mm`] measures it.
//!
//! # References
//!
//! - A. H. Barr, "Global and local deformations of solid primitives", SIGGRAPH 1984.
//! - R. Westermann, C. Rezk-Salama, "Real-time volume deformations", Eurographics 2001.
//! - T. Brunet, K. E. Nowak, M. Gleicher, "Integrating dynamic deformations into interactive volume
//!   visualization", EuroVis 2006, §3.3.
//! - Real-Time Volume Graphics course notes, "Volume Modeling, Deformation and Animation" (procedural
//!   perturbation).
//! - M. H. Davis et al., "A physics-based coordinate transformation for 3-D image matching", IEEE TMI
//!   16(3), 1997; S. Lee, G. Wolberg, S. Y. Shin, "Scattered data interpolation with multilevel
//!   B-splines", IEEE TVCG 3(3), 1997.

use std::f64::consts::{PI, TAU};
use std::fmt;
use std::str::FromStr;
use std::sync::atomic::{AtomicUsize, Ordering};

use nalgebra::{Matrix3, Matrix4, Vector3, Vector4};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use warpbench_io::geometry::Point3;

use crate::bspline::ControlLattice;
use crate::spaces::{Aabb, Fixed, Moving};
use crate::tps::Tps;
use crate::warp::JACOBIAN_STEP_MM;
use crate::{Result, SolverError, Warp};

/// Points per axis of the grid on which amplitudes are measured and normalised (41³ = 68 921 points;
/// the grid includes the box corners).
pub const AMPLITUDE_GRID: usize = 41;

/// The numerical inverse stops once ‖d(x) − y‖ is at most this, mm.
pub const INVERSE_TOLERANCE_MM: f64 = 1e-9;

/// The most Newton / fixed-point iterations per inverted point.
pub const MAX_INVERSE_ITERATIONS: usize = 100;

/// Cells per axis of the `bspline-random` lattice.
const BSPLINE_CELLS: usize = 3;

/// Fraction of a bend's curvature limits (fold, wrap) that an amplitude may use.
const BEND_LIMIT_FRACTION: f64 = 0.9;

/// The six synthetic warp families (module docs give their formulas).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum SyntheticKind {
    Sine,
    Twist,
    Bend,
    Bump,
    TpsRandom,
    BSplineRandom,
}

impl SyntheticKind {
    /// Every kind, in a fixed order.
    pub const ALL: [Self; 6] = [Self::Sine, Self::Twist, Self::Bend, Self::Bump, Self::TpsRandom, Self::BSplineRandom];

    /// The name used on the command line: "sine", "twist", "bend", "bump", "tps-random", "bspline-random".
    #[must_use]
    pub const fn name(self) -> &'static str {
        match self {
            Self::Sine => "sine",
            Self::Twist => "twist",
            Self::Bend => "bend",
            Self::Bump => "bump",
            Self::TpsRandom => "tps-random",
            Self::BSplineRandom => "bspline-random",
        }
    }

    /// True when the pull-back is in closed form (`twist`, `bend`); the others are inverted numerically.
    #[must_use]
    pub const fn has_analytic_inverse(self) -> bool {
        matches!(self, Self::Twist | Self::Bend)
    }
}

impl fmt::Display for SyntheticKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for SyntheticKind {
    type Err = SolverError;
    fn from_str(s: &str) -> Result<Self> {
        let wanted = s.trim();
        Self::ALL.into_iter().find(|k| k.name().eq_ignore_ascii_case(wanted)).ok_or_else(|| {
            let names: Vec<&str> = Self::ALL.iter().map(|k| k.name()).collect();
            SolverError::InvalidParameter(format!("unknown synthetic warp {s:?} (one of {})", names.join(", ")))
        })
    }
}

/// The parameters of one warp (raw mm).
#[derive(Clone, Debug)]
enum Field {
    Sine { origin: [f64; 3], wavenumber_per_mm: [f64; 3], phase_rad: [f64; 3], amp_mm: f64 },
    Twist { centre: [f64; 3], axis: usize, rate_rad_per_mm: f64 },
    Bend(Bend),
    Bump { centre: [f64; 3], sigma_mm: f64, vector_mm: [f64; 3] },
    Tps(Tps<Fixed, Moving>),
    BSpline(ControlLattice),
}

/// A bend in the (axial, normal) plane through `centre`; `sign` flips the normal direction.
#[derive(Clone, Copy, Debug)]
struct Bend {
    centre: [f64; 3],
    axial: usize,
    normal: usize,
    sign: f64,
    curvature_per_mm: f64,
}

impl Bend {
    /// (s, n) local → (s', n') bent.
    fn local(kappa: f64, s: f64, n: f64) -> (f64, f64) {
        if kappa == 0.0 {
            return (s, n);
        }
        let phi = kappa * s;
        let (sin, cos) = phi.sin_cos();
        let half = (0.5 * phi).sin();
        (sin / kappa - n * sin, 2.0 * half * half / kappa + n * cos)
    }

    /// (s', n') bent → (s, n) local; exact inverse of [`Bend::local`] for n < ρ, |φ| < π.
    fn local_inverse(kappa: f64, s1: f64, n1: f64) -> (f64, f64) {
        if kappa == 0.0 {
            return (s1, n1);
        }
        let rho = 1.0 / kappa;
        let m = rho - n1;
        let r = s1.hypot(m);
        let phi = s1.atan2(m);
        // n = ρ − r, written without cancellation when ρ is large: r − m = s'²/(r + m).
        let n = if r + m > 0.5 * rho { n1 - s1 * s1 / (r + m) } else { rho - r };
        (phi * rho, n)
    }

    fn split(&self, x: [f64; 3]) -> (f64, f64) {
        (x[self.axial] - self.centre[self.axial], self.sign * (x[self.normal] - self.centre[self.normal]))
    }

    fn join(&self, x: [f64; 3], s: f64, n: f64) -> [f64; 3] {
        let mut out = x;
        out[self.axial] = self.centre[self.axial] + s;
        out[self.normal] = self.centre[self.normal] + self.sign * n;
        out
    }

    fn apply(&self, x: [f64; 3]) -> [f64; 3] {
        let (s, n) = self.split(x);
        let (s1, n1) = Self::local(self.curvature_per_mm, s, n);
        self.join(x, s1, n1)
    }

    fn inverse(&self, y: [f64; 3]) -> [f64; 3] {
        let (s1, n1) = self.split(y);
        let (s, n) = Self::local_inverse(self.curvature_per_mm, s1, n1);
        self.join(y, s, n)
    }

    fn jacobian(&self, x: [f64; 3]) -> Matrix3<f64> {
        let (s, n) = self.split(x);
        let k = self.curvature_per_mm;
        let (sin, cos) = (k * s).sin_cos();
        let stretch = 1.0 - k * n;
        let (a, b) = (self.axial, self.normal);
        let mut j = Matrix3::identity();
        j[(a, a)] = stretch * cos;
        j[(a, b)] = -sin * self.sign;
        j[(b, a)] = self.sign * stretch * sin;
        j[(b, b)] = cos;
        j
    }

    /// The largest displacement over the box s ∈ `s_range`, |n| ≤ hn in the bend plane: at a corner.
    fn max_displacement(kappa: f64, s_range: [f64; 2], hn: f64) -> f64 {
        let mut worst: f64 = 0.0;
        for s in s_range {
            for n in [-hn, hn] {
                let (s1, n1) = Self::local(kappa, s, n);
                worst = worst.max((s1 - s).hypot(n1 - n));
            }
        }
        worst
    }
}

/// The parameters of a kind whose forward map has a closed form a renderer can evaluate per sample (`sine`, `twist`,
/// `bend`, `bump`), in the module docs' formulas; the random spline kinds have none ([`SyntheticWarp::closed_form`]).
/// Axes are 0, 1, 2 for x, y, z; lengths in mm.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ClosedForm {
    /// dₐ(x) = xₐ + a sin(kₐ (x_b − o_b) + φₐ), b = a + 1 mod 3.
    Sine { origin: [f64; 3], wavenumber_per_mm: [f64; 3], phase_rad: [f64; 3], amp_mm: f64 },
    /// A rotation about the line through `centre` along `axis` by θ = rate · (x_axis − centre_axis).
    Twist { centre: [f64; 3], axis: usize, rate_rad_per_mm: f64 },
    /// The bend with s = x_axial − c_axial, n = `normal_sign` · (x_normal − c_normal).
    Bend { centre: [f64; 3], axial: usize, normal: usize, normal_sign: f64, curvature_per_mm: f64 },
    /// d(x) = x + exp(−‖x − c‖²/2σ²) w.
    Bump { centre: [f64; 3], sigma_mm: f64, vector_mm: [f64; 3] },
}

/// A seeded synthetic forward warp d = `fixed_from_moving` over a moving-space box (module docs).
#[derive(Clone, Debug)]
pub struct SyntheticWarp {
    kind: SyntheticKind,
    domain: Aabb<Moving>,
    amplitude_mm: f64,
    seed: u64,
    field: Field,
}

impl SyntheticWarp {
    /// Builds the `kind` warp over `domain` whose largest displacement is `amplitude_mm`, from `seed`.
    ///
    /// Errors ([`SolverError::InvalidParameter`]): a box that is not finite with positive edges, an
    /// amplitude that is negative or not finite, or one above the kind's limit (module docs: `sine`,
    /// `bump` when not fold-free; `twist` above 2R; `bend` above 0.9 of its curvature limits).
    pub fn new(kind: SyntheticKind, domain: Aabb<Moving>, amplitude_mm: f64, seed: u64) -> Result<Self> {
        if !domain.is_valid() || !domain.min.is_finite() {
            return Err(SolverError::InvalidParameter(format!(
                "synthetic warp box must be finite with positive edges, got {:?}..{:?}",
                domain.min, domain.max
            )));
        }
        if !(amplitude_mm.is_finite() && amplitude_mm >= 0.0) {
            return Err(SolverError::InvalidParameter(format!(
                "synthetic warp amplitude must be finite and ≥ 0 mm, got {amplitude_mm}"
            )));
        }
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let (lo, size) = (domain.min.coords(), domain.size());
        let centre: [f64; 3] = std::array::from_fn(|a| lo[a] + 0.5 * size[a]);
        let min_edge = size.iter().copied().fold(f64::INFINITY, f64::min);
        if amplitude_mm > min_edge {
            return Err(too_large(kind, amplitude_mm, min_edge));
        }
        let field = match kind {
            SyntheticKind::Sine => {
                let amp_mm = amplitude_mm / 3.0_f64.sqrt();
                let wavenumber_per_mm: [f64; 3] = std::array::from_fn(|a| TAU / size[(a + 1) % 3]);
                let phase_rad: [f64; 3] = std::array::from_fn(|_| TAU * rng.random::<f64>());
                let lipschitz = amp_mm * wavenumber_per_mm.iter().copied().fold(0.0, f64::max);
                if lipschitz >= 1.0 {
                    return Err(too_large(kind, amplitude_mm, 3.0_f64.sqrt() * min_edge / TAU));
                }
                Field::Sine { origin: lo, wavenumber_per_mm, phase_rad, amp_mm }
            }
            SyntheticKind::Twist => {
                let axis = rng.random_range(0..3usize);
                let sign = if rng.random::<bool>() { 1.0 } else { -1.0 };
                let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
                let radius = (0.5 * size[u]).hypot(0.5 * size[v]);
                if amplitude_mm > 2.0 * radius {
                    return Err(too_large(kind, amplitude_mm, 2.0 * radius));
                }
                // θ = 0 at a random axial position in the middle half; |θ| is largest at the far face.
                let mut origin = centre;
                origin[axis] += size[axis] * 0.5 * (rng.random::<f64>() - 0.5);
                let reach = 0.5 * size[axis] + (origin[axis] - centre[axis]).abs();
                let theta_max = 2.0 * (amplitude_mm / (2.0 * radius)).asin();
                Field::Twist { centre: origin, axis, rate_rad_per_mm: sign * theta_max / reach }
            }
            SyntheticKind::Bend => {
                let axial = rng.random_range(0..3usize);
                let normal = (axial + 1 + rng.random_range(0..2usize)) % 3;
                let sign = if rng.random::<bool>() { 1.0 } else { -1.0 };
                // The arc starts at a random axial position in the middle half of the box.
                let mut origin = centre;
                origin[axial] += size[axial] * 0.5 * (rng.random::<f64>() - 0.5);
                let s_range = [lo[axial] - origin[axial], lo[axial] + size[axial] - origin[axial]];
                let hn = 0.5 * size[normal];
                let hs = s_range[0].abs().max(s_range[1].abs());
                let kappa_max = BEND_LIMIT_FRACTION * (1.0 / hn).min(PI / hs);
                let reachable = Bend::max_displacement(kappa_max, s_range, hn);
                if amplitude_mm > reachable {
                    return Err(too_large(kind, amplitude_mm, reachable));
                }
                let (mut k_lo, mut k_hi) = (0.0, kappa_max);
                for _ in 0..200 {
                    let mid = 0.5 * (k_lo + k_hi);
                    if mid <= k_lo || mid >= k_hi {
                        break;
                    }
                    if Bend::max_displacement(mid, s_range, hn) < amplitude_mm {
                        k_lo = mid;
                    } else {
                        k_hi = mid;
                    }
                }
                let curvature_per_mm = if amplitude_mm == 0.0 { 0.0 } else { 0.5 * (k_lo + k_hi) };
                Field::Bend(Bend { centre: origin, axial, normal, sign, curvature_per_mm })
            }
            SyntheticKind::Bump => {
                let bump_centre: [f64; 3] =
                    std::array::from_fn(|a| lo[a] + size[a] * (0.25 + 0.5 * rng.random::<f64>()));
                let sigma_mm = min_edge * (1.0 / 8.0 + (1.0 / 5.0 - 1.0 / 8.0) * rng.random::<f64>());
                let v = unit_vector(&mut rng);
                if amplitude_mm * (-0.5_f64).exp() >= sigma_mm {
                    return Err(too_large(kind, amplitude_mm, sigma_mm * 0.5_f64.exp()));
                }
                Field::Bump { centre: bump_centre, sigma_mm, vector_mm: v.map(|c| amplitude_mm * c) }
            }
            SyntheticKind::TpsRandom => {
                let centres = octant_centres(&mut rng, lo, size);
                let weights = side_conditioned_weights(&mut rng, &centres)?;
                let unit = tps_from(&centres, &weights, 1.0)?;
                let scale = amplitude_scale(&|x| unit.apply_raw(x), domain, amplitude_mm)?;
                Field::Tps(tps_from(&centres, &weights, scale)?)
            }
            SyntheticKind::BSplineRandom => {
                let mut lattice = ControlLattice::zeros([BSPLINE_CELLS; 3], lo, domain.max.coords())?;
                for phi in lattice.coefficients_mut().chunks_exact_mut(3) {
                    phi.copy_from_slice(&ball_point(&mut rng));
                }
                let scale = amplitude_scale(&|x| add(x, lattice.eval(x)), domain, amplitude_mm)?;
                for phi in lattice.coefficients_mut() {
                    *phi *= scale;
                }
                Field::BSpline(lattice)
            }
        };
        Ok(Self { kind, domain, amplitude_mm, seed, field })
    }

    #[must_use]
    pub fn kind(&self) -> SyntheticKind {
        self.kind
    }

    /// The moving-space box the warp is defined over.
    #[must_use]
    pub fn domain(&self) -> Aabb<Moving> {
        self.domain
    }

    /// The requested amplitude, mm.
    #[must_use]
    pub fn amplitude_mm(&self) -> f64 {
        self.amplitude_mm
    }

    #[must_use]
    pub fn seed(&self) -> u64 {
        self.seed
    }

    /// The displacement d(x) − x at `x` (moving mm).
    #[must_use]
    pub fn displacement_raw(&self, x: [f64; 3]) -> [f64; 3] {
        let y = self.apply_raw(x);
        [y[0] - x[0], y[1] - x[1], y[2] - x[2]]
    }

    /// The largest displacement ‖d(x) − x‖ over the box, measured on the [`AMPLITUDE_GRID`]³ grid, mm.
    #[must_use]
    pub fn max_displacement_mm(&self) -> f64 {
        grid_max_displacement_mm(self, self.domain, AMPLITUDE_GRID)
    }

    /// An upper bound ℓ on the Lipschitz constant of the displacement x ↦ d(x) − x over the box, where
    /// one is known (`None` for `twist` and `bend`, which are inverted in closed form). ℓ < 1 means d
    /// is injective, det J ≥ (1 − ℓ)³ > 0, and the fixed-point inverse converges at rate ℓ.
    #[must_use]
    pub fn displacement_lipschitz_bound(&self) -> Option<f64> {
        match &self.field {
            Field::Sine { wavenumber_per_mm, amp_mm, .. } => {
                Some(amp_mm * wavenumber_per_mm.iter().copied().fold(0.0, f64::max))
            }
            Field::Bump { sigma_mm, vector_mm, .. } => Some(norm(*vector_mm) * (-0.5_f64).exp() / sigma_mm),
            Field::Tps(tps) => Some(tps.weights().iter().map(|w| norm(*w)).sum()),
            Field::BSpline(lattice) => Some(lattice_lipschitz(lattice)),
            Field::Twist { .. } | Field::Bend(_) => None,
        }
    }

    /// The kind's closed-form parameters, for a renderer that evaluates d per sample (`None` for `tps-random` and
    /// `bspline-random`).
    #[must_use]
    pub fn closed_form(&self) -> Option<ClosedForm> {
        match &self.field {
            Field::Sine { origin, wavenumber_per_mm, phase_rad, amp_mm } => Some(ClosedForm::Sine {
                origin: *origin,
                wavenumber_per_mm: *wavenumber_per_mm,
                phase_rad: *phase_rad,
                amp_mm: *amp_mm,
            }),
            Field::Twist { centre, axis, rate_rad_per_mm } => {
                Some(ClosedForm::Twist { centre: *centre, axis: *axis, rate_rad_per_mm: *rate_rad_per_mm })
            }
            Field::Bend(b) => Some(ClosedForm::Bend {
                centre: b.centre,
                axial: b.axial,
                normal: b.normal,
                normal_sign: b.sign,
                curvature_per_mm: b.curvature_per_mm,
            }),
            Field::Bump { centre, sigma_mm, vector_mm } => {
                Some(ClosedForm::Bump { centre: *centre, sigma_mm: *sigma_mm, vector_mm: *vector_mm })
            }
            Field::Tps(_) | Field::BSpline(_) => None,
        }
    }

    /// The pull-back u = d⁻¹ (`moving_from_fixed`).
    #[must_use]
    pub fn pullback(&self) -> SyntheticPullback {
        SyntheticPullback { forward: self.clone(), non_converged: AtomicUsize::new(0) }
    }

    /// d⁻¹(y): closed form for `twist` and `bend`, else damped Newton from x = y with a fixed-point
    /// fallback, to [`INVERSE_TOLERANCE_MM`] within [`MAX_INVERSE_ITERATIONS`]. Never NaN for finite y.
    #[must_use]
    pub fn invert_point_raw(&self, y: [f64; 3]) -> InverseEstimate {
        let residual = |x: [f64; 3]| sub(self.apply_raw(x), y);
        if !y.iter().all(|v| v.is_finite()) {
            return InverseEstimate { point: y, residual_mm: f64::INFINITY, iterations: 0, converged: false };
        }
        let analytic = match &self.field {
            Field::Twist { centre, axis, rate_rad_per_mm } => Some(twist(*centre, *axis, -*rate_rad_per_mm, y)),
            Field::Bend(bend) => Some(bend.inverse(y)),
            _ => None,
        };
        if let Some(x) = analytic {
            let residual_mm = norm(residual(x));
            return InverseEstimate {
                point: x,
                residual_mm,
                iterations: 0,
                converged: residual_mm <= INVERSE_TOLERANCE_MM,
            };
        }
        let mut x = y;
        let mut r = residual(x);
        let mut r_norm = norm(r);
        let mut iterations = 0;
        while iterations < MAX_INVERSE_ITERATIONS {
            if r_norm <= INVERSE_TOLERANCE_MM {
                break;
            }
            iterations += 1;
            // Newton direction J⁻¹ r, else the fixed-point direction r (x ← y − u(x)); halve the step
            // until the residual decreases.
            let newton = self.jacobian_raw(x).try_inverse().map(|j_inv| <[f64; 3]>::from(j_inv * Vector3::from(r)));
            let mut improved = false;
            for direction in newton.into_iter().chain(std::iter::once(r)) {
                let mut step = 1.0;
                for _ in 0..40 {
                    let candidate: [f64; 3] = std::array::from_fn(|a| x[a] - step * direction[a]);
                    let rc = residual(candidate);
                    let rc_norm = norm(rc);
                    if rc_norm < r_norm {
                        (x, r, r_norm) = (candidate, rc, rc_norm);
                        improved = true;
                        break;
                    }
                    step *= 0.5;
                }
                if improved {
                    break;
                }
            }
            if !improved {
                break;
            }
        }
        InverseEstimate { point: x, residual_mm: r_norm, iterations, converged: r_norm <= INVERSE_TOLERANCE_MM }
    }
}

/// The result of inverting one point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct InverseEstimate {
    /// The best x found (moving mm); finite whenever y is.
    pub point: [f64; 3],
    /// ‖d(x) − y‖, mm.
    pub residual_mm: f64,
    /// Iterations used (0 for a closed form).
    pub iterations: usize,
    /// Whether the residual reached [`INVERSE_TOLERANCE_MM`].
    pub converged: bool,
}

impl Warp<Fixed, Moving> for SyntheticWarp {
    fn apply_raw(&self, x: [f64; 3]) -> [f64; 3] {
        match &self.field {
            Field::Sine { origin, wavenumber_per_mm, phase_rad, amp_mm } => std::array::from_fn(|a| {
                let b = (a + 1) % 3;
                x[a] + amp_mm * (wavenumber_per_mm[a] * (x[b] - origin[b]) + phase_rad[a]).sin()
            }),
            Field::Twist { centre, axis, rate_rad_per_mm } => twist(*centre, *axis, *rate_rad_per_mm, x),
            Field::Bend(bend) => bend.apply(x),
            Field::Bump { centre, sigma_mm, vector_mm } => {
                let g = gaussian(*centre, *sigma_mm, x);
                std::array::from_fn(|a| x[a] + g * vector_mm[a])
            }
            Field::Tps(tps) => tps.apply_raw(x),
            Field::BSpline(lattice) => add(x, lattice.eval(x)),
        }
    }

    /// Analytic for every kind.
    fn jacobian_raw(&self, x: [f64; 3]) -> Matrix3<f64> {
        match &self.field {
            Field::Sine { origin, wavenumber_per_mm, phase_rad, amp_mm } => {
                let mut j = Matrix3::identity();
                for a in 0..3 {
                    let b = (a + 1) % 3;
                    let k = wavenumber_per_mm[a];
                    j[(a, b)] += amp_mm * k * (k * (x[b] - origin[b]) + phase_rad[a]).cos();
                }
                j
            }
            Field::Twist { centre, axis, rate_rad_per_mm } => {
                let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
                let y = twist(*centre, *axis, *rate_rad_per_mm, x);
                let (sin, cos) = (rate_rad_per_mm * (x[*axis] - centre[*axis])).sin_cos();
                let mut j = Matrix3::identity();
                j[(u, u)] = cos;
                j[(u, v)] = -sin;
                j[(v, u)] = sin;
                j[(v, v)] = cos;
                j[(u, *axis)] = -rate_rad_per_mm * (y[v] - centre[v]);
                j[(v, *axis)] = rate_rad_per_mm * (y[u] - centre[u]);
                j
            }
            Field::Bend(bend) => bend.jacobian(x),
            Field::Bump { centre, sigma_mm, vector_mm } => {
                let g = gaussian(*centre, *sigma_mm, x);
                let grad = Vector3::from(std::array::from_fn(|a| -(x[a] - centre[a]) * g / (sigma_mm * sigma_mm)));
                Matrix3::identity() + Vector3::from(*vector_mm) * grad.transpose()
            }
            Field::Tps(tps) => tps.jacobian_raw(x),
            Field::BSpline(lattice) => {
                let mut d = [[0.0; 3]; 3];
                lattice.jacobian_into(x, &mut d);
                Matrix3::identity() + Matrix3::from_fn(|r, c| d[r][c])
            }
        }
    }
}

/// The pull-back of a [`SyntheticWarp`]: u = d⁻¹, `moving_from_fixed`.
///
/// [`Warp::apply_raw`] returns the best estimate even when the iteration did not converge (never NaN
/// for finite input) and counts such points in [`SyntheticPullback::non_converged_count`]; use
/// [`SyntheticPullback::invert_point`] to see the residual of each point.
#[derive(Debug)]
pub struct SyntheticPullback {
    forward: SyntheticWarp,
    non_converged: AtomicUsize,
}

impl Clone for SyntheticPullback {
    fn clone(&self) -> Self {
        Self { forward: self.forward.clone(), non_converged: AtomicUsize::new(self.non_converged_count()) }
    }
}

impl SyntheticPullback {
    /// The forward warp this inverts.
    #[must_use]
    pub fn forward(&self) -> &SyntheticWarp {
        &self.forward
    }

    /// Inverts one point, reporting convergence.
    #[must_use]
    pub fn invert_point(&self, y: Point3<Fixed>) -> InverseEstimate {
        self.forward.invert_point_raw(y.coords())
    }

    /// How many points evaluated through [`Warp`] so far did not reach [`INVERSE_TOLERANCE_MM`].
    #[must_use]
    pub fn non_converged_count(&self) -> usize {
        self.non_converged.load(Ordering::Relaxed)
    }
}

impl Warp<Moving, Fixed> for SyntheticPullback {
    fn apply_raw(&self, y: [f64; 3]) -> [f64; 3] {
        let estimate = self.forward.invert_point_raw(y);
        if !estimate.converged {
            self.non_converged.fetch_add(1, Ordering::Relaxed);
        }
        estimate.point
    }

    /// J_u(y) = J_d(u(y))⁻¹; central differences where J_d is singular.
    fn jacobian_raw(&self, y: [f64; 3]) -> Matrix3<f64> {
        let x = self.apply_raw(y);
        self.forward.jacobian_raw(x).try_inverse().unwrap_or_else(|| {
            let h = JACOBIAN_STEP_MM;
            let mut j = Matrix3::zeros();
            for c in 0..3 {
                let (mut yp, mut ym) = (y, y);
                yp[c] += h;
                ym[c] -= h;
                let (fp, fm) = (self.apply_raw(yp), self.apply_raw(ym));
                for r in 0..3 {
                    j[(r, c)] = (fp[r] - fm[r]) / (2.0 * h);
                }
            }
            j
        })
    }
}

/// Landmark pairs for tests and the CLI: `n` points uniform in `domain` (seeded) and their images under
/// the forward `warp`.
#[must_use]
pub fn sample_pairs<W: Warp<Fixed, Moving> + ?Sized>(
    warp: &W,
    domain: Aabb<Moving>,
    n: usize,
    seed: u64,
) -> (Vec<Point3<Moving>>, Vec<Point3<Fixed>>) {
    let moving = uniform_points(domain, n, seed, 0);
    let fixed = moving.iter().map(|p| warp.apply(*p)).collect();
    (moving, fixed)
}

/// `n` points uniform in `domain` for measuring target errors away from the landmarks: the same
/// seed gives a different stream from [`sample_pairs`], so the points are not landmarks.
#[must_use]
pub fn held_out_points(domain: Aabb<Moving>, n: usize, seed: u64) -> Vec<Point3<Moving>> {
    uniform_points(domain, n, seed, 1)
}

/// [`held_out_points`] together with their true images under `warp`.
#[must_use]
pub fn held_out_pairs<W: Warp<Fixed, Moving> + ?Sized>(
    warp: &W,
    domain: Aabb<Moving>,
    n: usize,
    seed: u64,
) -> (Vec<Point3<Moving>>, Vec<Point3<Fixed>>) {
    let moving = held_out_points(domain, n, seed);
    let fixed = moving.iter().map(|p| warp.apply(*p)).collect();
    (moving, fixed)
}

/// The largest ‖w(x) − x‖ over a regular grid of `points_per_axis`³ points spanning `domain`
/// (corners included; one point, the centre, when `points_per_axis` < 2), mm.
#[must_use]
pub fn grid_max_displacement_mm<W: Warp<Fixed, Moving> + ?Sized>(
    warp: &W,
    domain: Aabb<Moving>,
    points_per_axis: usize,
) -> f64 {
    max_on_grid(&|x| warp.apply_raw(x), domain, points_per_axis)
}

fn max_on_grid(map: &dyn Fn([f64; 3]) -> [f64; 3], domain: Aabb<Moving>, points_per_axis: usize) -> f64 {
    let (lo, size) = (domain.min.coords(), domain.size());
    let n = points_per_axis.max(1);
    let coord = |a: usize, i: usize| {
        if n == 1 { lo[a] + 0.5 * size[a] } else { lo[a] + size[a] * i as f64 / (n - 1) as f64 }
    };
    let mut worst: f64 = 0.0;
    for k in 0..n {
        for j in 0..n {
            for i in 0..n {
                let x = [coord(0, i), coord(1, j), coord(2, k)];
                worst = worst.max(norm(sub(map(x), x)));
            }
        }
    }
    worst
}

fn uniform_points(domain: Aabb<Moving>, n: usize, seed: u64, stream: u64) -> Vec<Point3<Moving>> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    rng.set_stream(stream);
    let (lo, size) = (domain.min.coords(), domain.size());
    (0..n).map(|_| Point3::from_array(std::array::from_fn(|a| lo[a] + size[a] * rng.random::<f64>()))).collect()
}

fn too_large(kind: SyntheticKind, amplitude_mm: f64, limit_mm: f64) -> SolverError {
    SolverError::InvalidParameter(format!(
        "{kind} amplitude {amplitude_mm} mm is too large for this box (limit {limit_mm:.3} mm)"
    ))
}

/// The factor that brings the grid maximum of a unit-amplitude field to `amplitude_mm`.
fn amplitude_scale(map: &dyn Fn([f64; 3]) -> [f64; 3], domain: Aabb<Moving>, amplitude_mm: f64) -> Result<f64> {
    if amplitude_mm == 0.0 {
        return Ok(0.0);
    }
    let unit = max_on_grid(map, domain, AMPLITUDE_GRID);
    if !(unit.is_finite() && unit > 0.0) {
        return Err(SolverError::Degenerate(format!("the random field has no displacement on the grid ({unit})")));
    }
    Ok(amplitude_mm / unit)
}

/// Rotation about the axis through `centre` by θ = rate · (x_axis − centre_axis).
fn twist(centre: [f64; 3], axis: usize, rate_rad_per_mm: f64, x: [f64; 3]) -> [f64; 3] {
    let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
    let (sin, cos) = (rate_rad_per_mm * (x[axis] - centre[axis])).sin_cos();
    let (du, dv) = (x[u] - centre[u], x[v] - centre[v]);
    let mut y = x;
    y[u] = centre[u] + du * cos - dv * sin;
    y[v] = centre[v] + du * sin + dv * cos;
    y
}

fn gaussian(centre: [f64; 3], sigma_mm: f64, x: [f64; 3]) -> f64 {
    let r2: f64 = (0..3).map(|a| (x[a] - centre[a]).powi(2)).sum();
    (-r2 / (2.0 * sigma_mm * sigma_mm)).exp()
}

/// Uniform in the unit ball (rejection sampling; deterministic for a seeded RNG).
fn ball_point(rng: &mut ChaCha8Rng) -> [f64; 3] {
    loop {
        let p: [f64; 3] = std::array::from_fn(|_| 2.0 * rng.random::<f64>() - 1.0);
        if norm(p) <= 1.0 {
            return p;
        }
    }
}

fn unit_vector(rng: &mut ChaCha8Rng) -> [f64; 3] {
    loop {
        let p = ball_point(rng);
        let n = norm(p);
        if n > 0.1 {
            return p.map(|c| c / n);
        }
    }
}

/// One centre per octant of the box, jittered by ±10 % of the edge.
fn octant_centres(rng: &mut ChaCha8Rng, lo: [f64; 3], size: [f64; 3]) -> Vec<[f64; 3]> {
    let mut centres = Vec::with_capacity(8);
    for octant in 0..8usize {
        let cell = [octant & 1, (octant >> 1) & 1, (octant >> 2) & 1];
        centres.push(std::array::from_fn(|a| {
            lo[a] + size[a] * ((2 * cell[a] + 1) as f64 / 4.0 + 0.2 * (rng.random::<f64>() - 0.5))
        }));
    }
    centres
}

/// Random weights (unit ball) projected onto Σ wᵢ = 0 and Σ wᵢ cᵢᵀ = 0: w ← (I − P (PᵀP)⁻¹ Pᵀ) w,
/// P with rows (1, cᵢᵀ) (centred for conditioning).
fn side_conditioned_weights(rng: &mut ChaCha8Rng, centres: &[[f64; 3]]) -> Result<Vec<[f64; 3]>> {
    let n = centres.len() as f64;
    let mean: [f64; 3] = std::array::from_fn(|a| centres.iter().map(|c| c[a]).sum::<f64>() / n);
    let rows: Vec<Vector4<f64>> =
        centres.iter().map(|c| Vector4::new(1.0, c[0] - mean[0], c[1] - mean[1], c[2] - mean[2])).collect();
    let ptp = rows.iter().fold(Matrix4::zeros(), |acc, r| acc + r * r.transpose());
    let inv = ptp.try_inverse().ok_or_else(|| SolverError::Degenerate("random TPS centres are coplanar".into()))?;
    let mut weights: Vec<[f64; 3]> = centres.iter().map(|_| ball_point(rng)).collect();
    for a in 0..3 {
        let ptw = rows.iter().zip(&weights).fold(Vector4::zeros(), |acc, (r, w)| acc + r * w[a]);
        let coeff = inv * ptw;
        for (r, w) in rows.iter().zip(weights.iter_mut()) {
            w[a] -= r.dot(&coeff);
        }
    }
    Ok(weights)
}

fn tps_from(centres: &[[f64; 3]], weights: &[[f64; 3]], scale: f64) -> Result<Tps<Fixed, Moving>> {
    let c: Vec<Point3<Moving>> = centres.iter().map(|p| Point3::from_array(*p)).collect();
    let w: Vec<[f64; 3]> = weights.iter().map(|w| w.map(|v| v * scale)).collect();
    Tps::from_parts(&c, &w, Matrix3::identity(), [0.0; 3])
}

/// ‖(max_cells |Δ_b φ_a| / h_b)_{ab}‖_F: the derivative of a cubic B-spline is a convex combination of
/// coefficient differences over h, so this bounds ‖J_D‖₂ everywhere.
fn lattice_lipschitz(lattice: &ControlLattice) -> f64 {
    let dims = lattice.dims();
    let h = lattice.spacing_mm();
    let coef = lattice.coefficients();
    let at = |i: usize, j: usize, k: usize, a: usize| coef[((k * dims[1] + j) * dims[0] + i) * 3 + a];
    let mut max_diff = [[0.0_f64; 3]; 3];
    for k in 0..dims[2] {
        for j in 0..dims[1] {
            for i in 0..dims[0] {
                for (a, row) in max_diff.iter_mut().enumerate() {
                    let here = at(i, j, k, a);
                    let neighbours = [(i + 1, j, k), (i, j + 1, k), (i, j, k + 1)];
                    for (axis, (ni, nj, nk)) in neighbours.into_iter().enumerate() {
                        if ni < dims[0] && nj < dims[1] && nk < dims[2] {
                            row[axis] = row[axis].max((at(ni, nj, nk, a) - here).abs());
                        }
                    }
                }
            }
        }
    }
    (0..3).flat_map(|a| (0..3).map(move |b| (a, b))).map(|(a, b)| (max_diff[a][b] / h[b]).powi(2)).sum::<f64>().sqrt()
}

fn add(x: [f64; 3], d: [f64; 3]) -> [f64; 3] {
    [x[0] + d[0], x[1] + d[1], x[2] + d[2]]
}

fn sub(x: [f64; 3], y: [f64; 3]) -> [f64; 3] {
    [x[0] - y[0], x[1] - y[1], x[2] - y[2]]
}

fn norm(v: [f64; 3]) -> f64 {
    (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt()
}
