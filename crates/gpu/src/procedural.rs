//! Procedural deformations computed per sample in the shader (Brunet, Nowak & Gleicher 2006 §3.3: "simple
//! deformations are best performed directly in the shaders … we implement bends and twists in this manner"; their
//! Table 1 compares "Shader Shift" and "Shader Sine" with the same deformation through a control texture).
//!
//! A [`Procedural`] p deforms a layer's **data**: where the layer's pull-back (its control texture, or the identity)
//! gives the point y = u(x) of the layer's own LPS space, the ray caster reads the volume at p(y) instead of y, so the
//! frame shows v(p(u(x))). For the accuracy suite's synthetic warps this is exactly the moving volume `eval` builds:
//! with v = V and p = d (the synthetic forward warp, `fixed_from_moving`), v∘p = V∘d = M, and a landmark warp fitted
//! to M's pairs then pulls the frame back through u ≈ d⁻¹, so that v(p(u(x))) ≈ V(x). Picking reports y = u(x) (the
//! point a landmark of the deformed volume records, [`crate::pick`]) and the value at p(y).
//!
//! The kinds, with y in mm and every formula written as the displacement p(y) − y the shader adds (so a zero
//! amplitude adds exactly zero and the frame is the undeformed one bit for bit):
//! - **shift**: p(y) = y + t.
//! - **sine** (a shear, the Real-Time Volume Graphics course's procedural perturbation): pₐ(y) = yₐ + A sin(kₐ (y_b −
//!   o_b) + φₐ), b = a + 1 mod 3.
//! - **twist** about the line through c along an axis s, by the angle θ(y) = κ (y_s − c_s) (Barr 1984): the two other
//!   coordinates (u, v) rotate about c by θ; written as (cos θ − 1, sin θ) times (y − c) with cos θ − 1 = −2 sin²(θ/2).
//! - **bend** of the axial line through c into an arc of curvature κ ≥ 0 in the plane of the axial axis s and a
//!   normal axis n whose direction is `normal_sign` (Barr 1984): with s = y_s − c_s, n = ±(y_n − c_n), φ = κ s,
//!   s' = sin φ/κ − n sin φ and n' = 2 sin²(φ/2)/κ + n cos φ (the identity for κ = 0). It is one-to-one for
//!   |φ| < π and n < 1/κ; beyond half a turn it folds, and the proxy box ([`Procedural::preimage_box`]) covers only
//!   the principal branch.
//! - **bump**, a Gaussian: p(y) = y + exp(−‖y − c‖²/2σ²) w.
//!
//! These are `warpbench_solver::synthetic`'s formulas (`sine`, `twist`, `bend`, `bump`), so the app builds them from
//! the same seeded parameters; the shader evaluates them in f32 ([`ProceduralUniforms::displacement`] is its CPU
//! twin, the arithmetic of `procedural_displacement` in `shaders/raycast.wgsl`).
//!
//! The bounds the renderer needs without the shader: [`Procedural::image_box`] (a box containing p(Y) of a box Y:
//! the empty-space classification of a brick) and [`Procedural::preimage_box`] (a box containing every y with p(y)
//! in a box B: the proxy box, where a volume of box B can appear). Both are exact bounding boxes of the sets for
//! shift, twist and bend (each coordinate is linear in a radius and trigonometric in an angle over a rectangle, so
//! its extremes lie at the rectangle's corners or at the angles where sin or cos peaks) and the amplitude bounds for
//! sine and bump, widened by [`BOUND_SLACK_MM`] against the shader's f32 arithmetic.

use bytemuck::{Pod, Zeroable};
use glam::{DVec2, DVec3, Vec3};

/// Added on every side of [`Procedural::image_box`] and [`Procedural::preimage_box`] against f32 rounding in the
/// shader (a few ulps of coordinates up to 10⁴ mm).
pub const BOUND_SLACK_MM: f64 = 0.01;

/// `ProceduralUniforms.kind`, the WGSL constants `PROCEDURAL_*` of the same names ([`crate::raycast::INTERFACE`]).
pub const PROCEDURAL_NONE: u32 = 0;
pub const PROCEDURAL_SHIFT: u32 = 1;
pub const PROCEDURAL_SINE: u32 = 2;
pub const PROCEDURAL_TWIST: u32 = 3;
pub const PROCEDURAL_BEND: u32 = 4;
pub const PROCEDURAL_BUMP: u32 = 5;

/// A coordinate axis of the layer's LPS space.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Axis {
    X,
    Y,
    Z,
}

impl Axis {
    pub const ALL: [Self; 3] = [Self::X, Self::Y, Self::Z];

    /// 0, 1, 2: the component of a vector.
    #[must_use]
    pub const fn index(self) -> usize {
        match self {
            Self::X => 0,
            Self::Y => 1,
            Self::Z => 2,
        }
    }

    /// The axis of component `i` (0, 1 or 2; larger values wrap).
    #[must_use]
    pub const fn from_index(i: usize) -> Self {
        match i % 3 {
            0 => Self::X,
            1 => Self::Y,
            _ => Self::Z,
        }
    }

    /// The next axis, cyclically (x → y → z → x).
    #[must_use]
    pub const fn next(self) -> Self {
        Self::from_index(self.index() + 1)
    }
}

/// A deformation the shader computes per sample (module docs give the formulas). Lengths in mm, in the layer's own
/// LPS space.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Procedural {
    Shift {
        offset_mm: Vec3,
    },
    Sine {
        origin_mm: Vec3,
        amplitude_mm: f32,
        wavenumber_per_mm: Vec3,
        phase_rad: Vec3,
    },
    Twist {
        centre_mm: Vec3,
        axis: Axis,
        rate_rad_per_mm: f32,
    },
    Bend {
        centre_mm: Vec3,
        axial: Axis,
        /// Not `axial`.
        normal: Axis,
        /// Whether n runs along +`normal` (true) or −`normal`.
        normal_positive: bool,
        /// κ ≥ 0 (a negative κ is the same bend with the normal's direction flipped: [`Procedural::bend`]).
        curvature_per_mm: f32,
    },
    Bump {
        centre_mm: Vec3,
        sigma_mm: f32,
        vector_mm: Vec3,
    },
}

impl Procedural {
    /// A bend, normalised to κ ≥ 0: (κ, n) and (−κ, −n) are the same deformation.
    #[must_use]
    pub fn bend(centre_mm: Vec3, axial: Axis, normal: Axis, normal_positive: bool, curvature_per_mm: f32) -> Self {
        let flip = curvature_per_mm < 0.0;
        Self::Bend {
            centre_mm,
            axial,
            normal,
            normal_positive: normal_positive != flip,
            curvature_per_mm: curvature_per_mm.abs(),
        }
    }

    /// Its name: "shift", "sine", "twist", "bend", "bump".
    #[must_use]
    pub fn name(&self) -> &'static str {
        match self {
            Self::Shift { .. } => "shift",
            Self::Sine { .. } => "sine",
            Self::Twist { .. } => "twist",
            Self::Bend { .. } => "bend",
            Self::Bump { .. } => "bump",
        }
    }

    /// Whether every parameter is finite and the bend's axes differ (what the uniforms can carry).
    #[must_use]
    pub fn is_valid(&self) -> bool {
        let u = ProceduralUniforms::of(Some(self));
        let finite = [u.centre_mm, u.vector_mm, u.wavenumber_per_mm, u.phase_rad]
            .iter()
            .flatten()
            .chain(&[u.amplitude_mm, u.rate_per_mm, u.sigma_mm])
            .all(|v| v.is_finite());
        let axes = match self {
            Self::Bend { axial, normal, .. } => axial != normal,
            Self::Bump { sigma_mm, .. } => *sigma_mm > 0.0,
            _ => true,
        };
        finite && axes
    }

    /// p(y) − y at `y`, with the shader's f32 arithmetic.
    #[must_use]
    pub fn displacement(&self, y: Vec3) -> Vec3 {
        ProceduralUniforms::of(Some(self)).displacement(y)
    }

    /// A box containing p(Y) for Y = \[lo, hi\] (module docs), widened by [`BOUND_SLACK_MM`].
    #[must_use]
    pub fn image_box(&self, lo: DVec3, hi: DVec3) -> (DVec3, DVec3) {
        let (a, b) = match *self {
            Self::Shift { offset_mm } => (lo + offset_mm.as_dvec3(), hi + offset_mm.as_dvec3()),
            Self::Sine { amplitude_mm, .. } => {
                let a = f64::from(amplitude_mm.abs());
                (lo - DVec3::splat(a), hi + DVec3::splat(a))
            }
            Self::Bump { vector_mm, .. } => {
                let w = vector_mm.as_dvec3();
                (lo + w.min(DVec3::ZERO), hi + w.max(DVec3::ZERO))
            }
            Self::Twist { centre_mm, axis, rate_rad_per_mm } => {
                twist_box(centre_mm.as_dvec3(), axis, f64::from(rate_rad_per_mm), lo, hi)
            }
            Self::Bend { centre_mm, axial, normal, normal_positive, curvature_per_mm } => {
                let frame = BendFrame { centre: centre_mm.as_dvec3(), axial, normal, normal_positive };
                frame.image_box(f64::from(curvature_per_mm), lo, hi)
            }
        };
        (a - DVec3::splat(BOUND_SLACK_MM), b + DVec3::splat(BOUND_SLACK_MM))
    }

    /// A box containing every y with p(y) in B = \[lo, hi\] (module docs; for a bend, on its principal branch),
    /// widened by [`BOUND_SLACK_MM`].
    #[must_use]
    pub fn preimage_box(&self, lo: DVec3, hi: DVec3) -> (DVec3, DVec3) {
        let (a, b) = match *self {
            Self::Shift { offset_mm } => (lo - offset_mm.as_dvec3(), hi - offset_mm.as_dvec3()),
            // y = p(y) − disp(y) with disp in the image bounds: the same widening, mirrored.
            Self::Sine { .. } => return self.image_box(lo, hi),
            Self::Bump { vector_mm, .. } => {
                let w = vector_mm.as_dvec3();
                (lo - w.max(DVec3::ZERO), hi - w.min(DVec3::ZERO))
            }
            // The inverse twist turns by −θ, and θ depends only on the axial coordinate, which it keeps.
            Self::Twist { centre_mm, axis, rate_rad_per_mm } => {
                twist_box(centre_mm.as_dvec3(), axis, -f64::from(rate_rad_per_mm), lo, hi)
            }
            Self::Bend { centre_mm, axial, normal, normal_positive, curvature_per_mm } => {
                let frame = BendFrame { centre: centre_mm.as_dvec3(), axial, normal, normal_positive };
                frame.preimage_box(f64::from(curvature_per_mm), lo, hi)
            }
        };
        (a - DVec3::splat(BOUND_SLACK_MM), b + DVec3::splat(BOUND_SLACK_MM))
    }

    /// The same deformation sampled into a control texture (Brunet et al. 2006 §3.3's "deformation texture"): p(x) −
    /// x at the texel centres of a `dims` grid over \[`box_min`, `box_max`\] (texel (a, b, c) at min + (a + ½)/n₀ ·
    /// (max − min), …), as `[dx, dy, dz, 0]` per texel, x fastest: the layout of [`crate::control::ControlDesc`].
    #[must_use]
    pub fn control_texels(&self, dims: [usize; 3], box_min: [f64; 3], box_max: [f64; 3]) -> Vec<f32> {
        let u = ProceduralUniforms::of(Some(self));
        let mut texels = Vec::with_capacity(4 * dims.iter().product::<usize>());
        for k in 0..dims[2] {
            for j in 0..dims[1] {
                for i in 0..dims[0] {
                    let x: [f64; 3] = std::array::from_fn(|a| {
                        let t = ([i, j, k][a] as f64 + 0.5) / dims[a] as f64;
                        box_min[a] + t * (box_max[a] - box_min[a])
                    });
                    let d = u.displacement(DVec3::from_array(x).as_vec3());
                    texels.extend_from_slice(&[d.x, d.y, d.z, 0.0]);
                }
            }
        }
        texels
    }
}

/// `ProceduralUniforms` in shaders/raycast.wgsl ([`crate::raycast::INTERFACE`]): a [`Procedural`] as the shader reads
/// it; unused fields are zero.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct ProceduralUniforms {
    /// sine: the origin o; twist, bend, bump: the centre c.
    pub centre_mm: [f32; 3],
    /// `PROCEDURAL_*`.
    pub kind: u32,
    /// shift: the offset t; bump: the vector w.
    pub vector_mm: [f32; 3],
    /// sine: A.
    pub amplitude_mm: f32,
    /// sine: k.
    pub wavenumber_per_mm: [f32; 3],
    /// twist: κ in rad/mm; bend: the curvature κ in 1/mm.
    pub rate_per_mm: f32,
    /// sine: φ.
    pub phase_rad: [f32; 3],
    /// bump: σ.
    pub sigma_mm: f32,
    /// twist: the axis; bend: the axial axis (0, 1, 2 for x, y, z).
    pub axis: u32,
    /// bend: the normal axis.
    pub normal_axis: u32,
    /// bend: +1 or −1, the direction of n along the normal axis.
    pub normal_sign: f32,
    _pad0: u32,
}
const _: () = assert!(std::mem::size_of::<ProceduralUniforms>() == 80);

impl ProceduralUniforms {
    /// The uniforms of `procedural` (all zero, `PROCEDURAL_NONE`, for `None`).
    #[must_use]
    pub fn of(procedural: Option<&Procedural>) -> Self {
        let none = Self::default();
        match procedural {
            None => none,
            Some(&Procedural::Shift { offset_mm }) => {
                Self { kind: PROCEDURAL_SHIFT, vector_mm: offset_mm.to_array(), ..none }
            }
            Some(&Procedural::Sine { origin_mm, amplitude_mm, wavenumber_per_mm, phase_rad }) => Self {
                kind: PROCEDURAL_SINE,
                centre_mm: origin_mm.to_array(),
                amplitude_mm,
                wavenumber_per_mm: wavenumber_per_mm.to_array(),
                phase_rad: phase_rad.to_array(),
                ..none
            },
            Some(&Procedural::Twist { centre_mm, axis, rate_rad_per_mm }) => Self {
                kind: PROCEDURAL_TWIST,
                centre_mm: centre_mm.to_array(),
                rate_per_mm: rate_rad_per_mm,
                axis: axis.index() as u32,
                ..none
            },
            Some(&Procedural::Bend { centre_mm, axial, normal, normal_positive, curvature_per_mm }) => Self {
                kind: PROCEDURAL_BEND,
                centre_mm: centre_mm.to_array(),
                rate_per_mm: curvature_per_mm,
                axis: axial.index() as u32,
                normal_axis: normal.index() as u32,
                normal_sign: if normal_positive { 1.0 } else { -1.0 },
                ..none
            },
            Some(&Procedural::Bump { centre_mm, sigma_mm, vector_mm }) => Self {
                kind: PROCEDURAL_BUMP,
                centre_mm: centre_mm.to_array(),
                sigma_mm,
                vector_mm: vector_mm.to_array(),
                ..none
            },
        }
    }

    /// The shader's `procedural_displacement`: p(y) − y in f32, in the same order of operations.
    #[must_use]
    pub fn displacement(&self, y: Vec3) -> Vec3 {
        let c = Vec3::from_array(self.centre_mm);
        match self.kind {
            PROCEDURAL_SHIFT => Vec3::from_array(self.vector_mm),
            PROCEDURAL_SINE => {
                let r = y - c;
                let arg = Vec3::from_array(self.wavenumber_per_mm) * Vec3::new(r.y, r.z, r.x)
                    + Vec3::from_array(self.phase_rad);
                self.amplitude_mm * Vec3::new(arg.x.sin(), arg.y.sin(), arg.z.sin())
            }
            PROCEDURAL_TWIST => {
                let a = (self.axis % 3) as usize;
                let (ua, va) = ((a + 1) % 3, (a + 2) % 3);
                let theta = self.rate_per_mm * (y[a] - c[a]);
                let (du, dv) = (y[ua] - c[ua], y[va] - c[va]);
                let sin = theta.sin();
                let half = (0.5 * theta).sin();
                let cos_minus_one = -2.0 * half * half;
                let mut d = Vec3::ZERO;
                d[ua] = du * cos_minus_one - dv * sin;
                d[va] = du * sin + dv * cos_minus_one;
                d
            }
            PROCEDURAL_BEND => {
                let k = self.rate_per_mm;
                if k == 0.0 {
                    return Vec3::ZERO;
                }
                let (a, b) = ((self.axis % 3) as usize, (self.normal_axis % 3) as usize);
                let s = y[a] - c[a];
                let n = self.normal_sign * (y[b] - c[b]);
                let phi = k * s;
                let sin = phi.sin();
                let half = (0.5 * phi).sin();
                let s1 = sin / k - n * sin;
                let n1 = 2.0 * half * half / k + n * phi.cos();
                let mut d = Vec3::ZERO;
                d[a] = s1 - s;
                d[b] = self.normal_sign * (n1 - n);
                d
            }
            PROCEDURAL_BUMP => {
                let r = y - c;
                let g = (-r.dot(r) / (2.0 * self.sigma_mm * self.sigma_mm)).exp();
                g * Vec3::from_array(self.vector_mm)
            }
            _ => Vec3::ZERO,
        }
    }
}

/// The bounding box of {r (sin φ, cos φ) : r ∈ \[r0, r1\], φ ∈ \[φ0, φ1\]} (any signs, φ0 ≤ φ1): each coordinate is
/// linear in r, so its extremes over r lie at r0 or r1, and over φ at φ0, φ1 or a multiple of π/2 between them.
fn polar_box(r: [f64; 2], phi: [f64; 2]) -> (DVec2, DVec2) {
    let quarter = std::f64::consts::FRAC_PI_2;
    let mut angles = vec![phi[0], phi[1]];
    // At most 4 multiples of π/2 matter (the rest repeat them); the range is capped to one turn.
    let first = (phi[0] / quarter).ceil();
    let mut m = first;
    while m * quarter < phi[1] && m < first + 4.0 {
        angles.push(m * quarter);
        m += 1.0;
    }
    let (mut lo, mut hi) = (DVec2::INFINITY, DVec2::NEG_INFINITY);
    for &a in &angles {
        let (sin, cos) = a.sin_cos();
        for &radius in &r {
            let p = DVec2::new(radius * sin, radius * cos);
            (lo, hi) = (lo.min(p), hi.max(p));
        }
    }
    (lo, hi)
}

/// The bounding box of the twist by θ(y) = rate·(y_s − c_s) of the box \[lo, hi\]: the axial coordinate is kept; in
/// the (u, v) plane each corner of the box's cross-section turns about c by every θ over the box's axial range (the
/// cross-section is the convex hull of its corners and a rotation is linear, so the corners' arcs bound it).
fn twist_box(c: DVec3, axis: Axis, rate: f64, lo: DVec3, hi: DVec3) -> (DVec3, DVec3) {
    let a = axis.index();
    let (ua, va) = ((a + 1) % 3, (a + 2) % 3);
    let (t0, t1) = (rate * (lo[a] - c[a]), rate * (hi[a] - c[a]));
    let theta = [t0.min(t1), t0.max(t1)];
    let (mut out_lo, mut out_hi) = (lo, hi);
    out_lo[ua] = f64::INFINITY;
    out_lo[va] = f64::INFINITY;
    out_hi[ua] = f64::NEG_INFINITY;
    out_hi[va] = f64::NEG_INFINITY;
    for (du, dv) in [(lo[ua], lo[va]), (hi[ua], lo[va]), (lo[ua], hi[va]), (hi[ua], hi[va])] {
        let (du, dv) = (du - c[ua], dv - c[va]);
        // The corner is r (cos α, sin α); turned by θ it is r (cos(α + θ), sin(α + θ)) = r (sin φ, cos φ) with
        // φ = π/2 − α − θ, polar_box's form: (u, v) = (r sin φ, r cos φ).
        let r = du.hypot(dv);
        let beta = std::f64::consts::FRAC_PI_2 - dv.atan2(du);
        let (b_lo, b_hi) = polar_box([r, r], [beta - theta[1], beta - theta[0]]);
        out_lo[ua] = out_lo[ua].min(c[ua] + b_lo.x);
        out_hi[ua] = out_hi[ua].max(c[ua] + b_hi.x);
        out_lo[va] = out_lo[va].min(c[va] + b_lo.y);
        out_hi[va] = out_hi[va].max(c[va] + b_hi.y);
    }
    (out_lo, out_hi)
}

/// A bend's local frame: s along `axial` from c, n along ±`normal` from c.
struct BendFrame {
    centre: DVec3,
    axial: Axis,
    normal: Axis,
    normal_positive: bool,
}

impl BendFrame {
    fn sign(&self) -> f64 {
        if self.normal_positive { 1.0 } else { -1.0 }
    }

    /// The (s, n) rectangle of the box \[lo, hi\].
    fn local(&self, lo: DVec3, hi: DVec3) -> ([f64; 2], [f64; 2]) {
        let (a, b) = (self.axial.index(), self.normal.index());
        let s = [lo[a] - self.centre[a], hi[a] - self.centre[a]];
        let (n0, n1) = (self.sign() * (lo[b] - self.centre[b]), self.sign() * (hi[b] - self.centre[b]));
        (s, [n0.min(n1), n0.max(n1)])
    }

    /// The box whose (s, n) rectangle is `s` × `n`, other coordinates from \[lo, hi\].
    fn global(&self, lo: DVec3, hi: DVec3, s: [f64; 2], n: [f64; 2]) -> (DVec3, DVec3) {
        let (a, b) = (self.axial.index(), self.normal.index());
        let (mut out_lo, mut out_hi) = (lo, hi);
        out_lo[a] = self.centre[a] + s[0];
        out_hi[a] = self.centre[a] + s[1];
        let (e0, e1) = (self.centre[b] + self.sign() * n[0], self.centre[b] + self.sign() * n[1]);
        out_lo[b] = e0.min(e1);
        out_hi[b] = e0.max(e1);
        (out_lo, out_hi)
    }

    /// The image of \[lo, hi\]: s' = r sin φ and n' = ρ − r cos φ with r = ρ − n, φ = κ s (module docs), so the
    /// (s', ρ − n') rectangle is `polar_box` of r ∈ \[ρ − n₁, ρ − n₀\], φ ∈ κ·\[s₀, s₁\].
    fn image_box(&self, kappa: f64, lo: DVec3, hi: DVec3) -> (DVec3, DVec3) {
        if kappa <= 0.0 {
            return (lo, hi);
        }
        let (s, n) = self.local(lo, hi);
        let rho = 1.0 / kappa;
        let (p_lo, p_hi) = polar_box([rho - n[1], rho - n[0]], [kappa * s[0], kappa * s[1]]);
        self.global(lo, hi, [p_lo.x, p_hi.x], [rho - p_hi.y, rho - p_lo.y])
    }

    /// The principal-branch preimage of \[lo, hi\]: the inverse is polar about the centre of curvature, r =
    /// ‖(s', ρ − n')‖, φ = atan2(s', ρ − n'), s = ρφ, n = ρ − r. r ranges from the rectangle's distance to the centre
    /// to its farthest corner; φ between its corners' angles, or over (−π, π] when the rectangle touches the half-line
    /// s' = 0, ρ − n' ≤ 0 where atan2 jumps.
    fn preimage_box(&self, kappa: f64, lo: DVec3, hi: DVec3) -> (DVec3, DVec3) {
        if kappa <= 0.0 {
            return (lo, hi);
        }
        let (s1, n1) = self.local(lo, hi);
        let rho = 1.0 / kappa;
        let m = [rho - n1[1], rho - n1[0]];
        let corners = [(s1[0], m[0]), (s1[1], m[0]), (s1[0], m[1]), (s1[1], m[1])];
        let r_max = corners.iter().map(|&(s, m)| s.hypot(m)).fold(0.0, f64::max);
        let gap = |v: f64, r: [f64; 2]| (r[0] - v).max(v - r[1]).max(0.0);
        let r_min = gap(0.0, s1).hypot(gap(0.0, m));
        let across_cut = m[0] <= 0.0 && s1[0] <= 0.0 && s1[1] >= 0.0;
        let phi = if across_cut {
            [-std::f64::consts::PI, std::f64::consts::PI]
        } else {
            let angles = corners.map(|(s, m)| s.atan2(m));
            [
                angles.iter().copied().fold(f64::INFINITY, f64::min),
                angles.iter().copied().fold(f64::NEG_INFINITY, f64::max),
            ]
        };
        self.global(lo, hi, [rho * phi[0], rho * phi[1]], [rho - r_max, rho - r_min])
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn kinds() -> Vec<Procedural> {
        let c = Vec3::new(3.0, -4.0, 5.0);
        vec![
            Procedural::Shift { offset_mm: Vec3::new(7.0, -3.0, 1.5) },
            Procedural::Sine {
                origin_mm: c,
                amplitude_mm: 4.0,
                wavenumber_per_mm: Vec3::new(0.05, 0.07, 0.03),
                phase_rad: Vec3::new(0.3, 2.0, 5.0),
            },
            Procedural::Twist { centre_mm: c, axis: Axis::Z, rate_rad_per_mm: 0.02 },
            Procedural::Twist { centre_mm: c, axis: Axis::X, rate_rad_per_mm: -0.05 },
            Procedural::bend(c, Axis::Y, Axis::X, true, 0.015),
            Procedural::bend(c, Axis::Z, Axis::Y, false, -0.02),
            Procedural::Bump { centre_mm: c, sigma_mm: 12.0, vector_mm: Vec3::new(-5.0, 2.0, 3.0) },
        ]
    }

    fn inside(p: DVec3, b: (DVec3, DVec3)) -> bool {
        p.cmpge(b.0).all() && p.cmple(b.1).all()
    }

    /// The image box holds p(y) for every y of the box, and is tight: each face is reached within a few mm by
    /// the image of some sampled point (so it is a bounding box, not a loose bound) for the exact kinds.
    #[test]
    fn image_boxes_hold_every_image_point() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let (lo, hi) = (DVec3::new(-30.0, -20.0, -25.0), DVec3::new(40.0, 35.0, 30.0));
        for p in kinds() {
            let b = p.image_box(lo, hi);
            for _ in 0..20_000 {
                let y = DVec3::new(
                    rng.random_range(lo.x..hi.x),
                    rng.random_range(lo.y..hi.y),
                    rng.random_range(lo.z..hi.z),
                );
                let image = y + p.displacement(y.as_vec3()).as_dvec3();
                assert!(inside(image, b), "{p:?}: p({y}) = {image} outside {b:?}");
            }
        }
    }

    /// Every y with p(y) in B lies in the preimage box: sampled over a region three times B's size.
    #[test]
    fn preimage_boxes_hold_every_point_mapped_into_the_box() {
        let mut rng = ChaCha8Rng::seed_from_u64(8);
        let (lo, hi) = (DVec3::new(-30.0, -20.0, -25.0), DVec3::new(40.0, 35.0, 30.0));
        let (big_lo, big_hi) = (lo - (hi - lo), hi + (hi - lo));
        for p in kinds() {
            let b = p.preimage_box(lo, hi);
            let mut hits = 0;
            for _ in 0..200_000 {
                let y = DVec3::new(
                    rng.random_range(big_lo.x..big_hi.x),
                    rng.random_range(big_lo.y..big_hi.y),
                    rng.random_range(big_lo.z..big_hi.z),
                );
                let image = y + p.displacement(y.as_vec3()).as_dvec3();
                if inside(image, (lo, hi)) {
                    hits += 1;
                    assert!(inside(y, b), "{p:?}: p({y}) = {image} in the box but {y} outside {b:?}");
                }
            }
            assert!(hits > 1000, "{p:?}: only {hits} samples mapped into the box");
        }
    }

    /// The exact kinds' boxes are bounding boxes: sampling the box's surface finely reaches each face of the image
    /// box within a small fraction of its size.
    #[test]
    fn twist_and_bend_image_boxes_are_tight() {
        let (lo, hi) = (DVec3::new(-30.0, -20.0, -25.0), DVec3::new(40.0, 35.0, 30.0));
        for p in kinds().into_iter().filter(|p| matches!(p, Procedural::Twist { .. } | Procedural::Bend { .. })) {
            let b = p.image_box(lo, hi);
            let (mut seen_lo, mut seen_hi) = (DVec3::INFINITY, DVec3::NEG_INFINITY);
            let n = 60;
            for i in 0..=n {
                for j in 0..=n {
                    for k in 0..=n {
                        let t = DVec3::new(f64::from(i), f64::from(j), f64::from(k)) / f64::from(n);
                        let y = lo + t * (hi - lo);
                        let image = y + p.displacement(y.as_vec3()).as_dvec3();
                        (seen_lo, seen_hi) = (seen_lo.min(image), seen_hi.max(image));
                    }
                }
            }
            let slack = (b.1 - b.0) * 0.01 + DVec3::splat(BOUND_SLACK_MM);
            assert!(
                (seen_lo - b.0).cmple(slack).all() && (b.1 - seen_hi).cmple(slack).all(),
                "{p:?}: {b:?} vs seen {seen_lo}..{seen_hi}"
            );
        }
    }

    /// A zero amplitude adds exactly zero at every point: the frame is the undeformed one bit for bit.
    #[test]
    fn zero_amplitude_displaces_by_exactly_zero() {
        let c = Vec3::new(3.0, -4.0, 5.0);
        let zero = [
            Procedural::Shift { offset_mm: Vec3::ZERO },
            Procedural::Sine {
                origin_mm: c,
                amplitude_mm: 0.0,
                wavenumber_per_mm: Vec3::splat(0.1),
                phase_rad: Vec3::ONE,
            },
            Procedural::Twist { centre_mm: c, axis: Axis::Y, rate_rad_per_mm: 0.0 },
            Procedural::bend(c, Axis::X, Axis::Z, true, 0.0),
            Procedural::Bump { centre_mm: c, sigma_mm: 10.0, vector_mm: Vec3::ZERO },
        ];
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        for p in zero {
            for _ in 0..1000 {
                let y = Vec3::new(
                    rng.random_range(-500.0..500.0),
                    rng.random_range(-500.0..500.0),
                    rng.random_range(-500.0..500.0),
                );
                let d = p.displacement(y);
                assert_eq!(y + d, y, "{p:?} at {y}: {d}");
            }
        }
    }

    /// The control-texture samples are the displacement at the texel centres.
    #[test]
    fn control_texels_sample_the_displacement_at_texel_centres() {
        let p = kinds()[1];
        let texels = p.control_texels([4, 3, 2], [0.0, 10.0, 20.0], [8.0, 16.0, 24.0]);
        assert_eq!(texels.len(), 4 * 24);
        // Texel (1, 2, 1): centre (3, 15, 23).
        let t = 4 * (1 + 4 * (2 + 3));
        let d = p.displacement(Vec3::new(3.0, 15.0, 23.0));
        assert_eq!(&texels[t..t + 4], &[d.x, d.y, d.z, 0.0]);
    }

    #[test]
    fn a_negative_curvature_is_the_same_bend_mirrored() {
        let c = Vec3::new(1.0, 2.0, 3.0);
        let (a, b) =
            (Procedural::bend(c, Axis::X, Axis::Y, true, -0.03), Procedural::bend(c, Axis::X, Axis::Y, false, 0.03));
        assert_eq!(a, b);
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let direct = ProceduralUniforms {
            kind: PROCEDURAL_BEND,
            centre_mm: c.to_array(),
            rate_per_mm: -0.03,
            axis: 0,
            normal_axis: 1,
            normal_sign: 1.0,
            ..ProceduralUniforms::default()
        };
        for _ in 0..100 {
            let y =
                Vec3::new(rng.random_range(-40.0..40.0), rng.random_range(-20.0..20.0), rng.random_range(-40.0..40.0));
            assert!((a.displacement(y) - direct.displacement(y)).length() < 1e-3, "at {y}");
        }
    }
}
