//! Deformations of the **view**: maps of the ref space that the ray caster applies to a sample *before* a layer's
//! pull-back, so that the frame shows v(p(u(w(x)))) for the layers they are given to (Brunet, Nowak & Gleicher 2006
//! §5.2–5.3: animated deformations and volume widgets, "computed completely in the shader"; the application "simply
//! has to pass a few floating point parameters defining the deformation for that particular frame").
//!
//! Unlike a [`crate::procedural::Procedural`] deformation (of a layer's data) or the warp (the registration), a view
//! deformation moves what the user sees without moving anything the user edits: picking marches through it, as the
//! frame does, and reports the point of the *undeformed* volume (u(w(x)), [`crate::pick`]), so a landmark placed
//! through it is stored where it is in the volume.
//!
//! Kinds ([`ViewDeformation`]):
//! - **fish-eye** (§5.2, the pulsing attention lens): inside the ball of radius R about c, the pull-back w(x) = x −
//!   (x − c)·a (1 − r/R)², r = ‖x − c‖, 0 ≤ a < 1; the identity outside. Radially ρ(r) = r (1 − a (1 − r/R)²)
//!   has ρ'(r) = 1 − a (1 − q)(1 − 3q) ≥ 1 − a > 0 (q = r/R), ρ(R) = R and ρ'(R) = 1: a C¹ bijection of the ball
//!   onto itself that magnifies its centre by 1/(1 − a). The window animates a over time.
//!
//! - **leafer** (§5.3, after McGuffin, Tancau & Balakrishnan 2003): the volume is cut by the plane through the hinge
//!   line (point o, direction a = f × n) with normal n, and its two halves are turned about the hinge by ±θ, away
//!   from each other, like the pages of a book opened towards the viewer (f points from the hinge towards the viewer):
//!   the cut faces turn to face the viewer, so what lies on the cut plane inside the volume can be seen and picked.
//!   With (u, v) = ((x − o)·f, (x − o)·n) and φ = atan2(v, u), the pull-back turns a point with φ ≥ θ back by −θ
//!   (the n half), one with φ ≤ −θ by +θ (the other half), and shows nothing in the wedge |φ| < θ between the opened
//!   halves (it reads [`VIEW_EMPTY`], a point no volume contains). Written as a displacement (cos θ − 1 = −2 sin²(θ/2)),
//!   so that θ = 0 is the identity bit for bit. Behind the hinge (|φ| > π − θ) the two halves would overlap; there the
//!   n half is shown.
//!
//! Bounds, for the proxy box and empty-space skipping: the fish-eye maps its ball onto itself and is the identity
//! outside, so the points that show a layer's content lie in that content's box or in the ball
//! ([`ViewDeformation::preimage_box`]), and w(x) lies between c and x, so w of a box lies in the box of it and c when
//! it meets the ball ([`ViewDeformation::image_box`]); the leafer turns each half by ±θ about the hinge, so both
//! bounds are the box of the two turned copies of the box (a turn is linear: the turned corners bound it).

use bytemuck::{Pod, Zeroable};
use glam::{DVec3, Vec3};

/// `ViewDeformationUniforms.kind`, the WGSL constants `VIEW_*` of the same names ([`crate::raycast::INTERFACE`]).
pub const VIEW_NONE: u32 = 0;
pub const VIEW_FISH_EYE: u32 = 1;
pub const VIEW_LEAFER: u32 = 2;

/// What a view deformation reads where it shows nothing (the leafer's opening): a point far outside every volume, so
/// that every layer is transparent there (`VIEW_EMPTY` in the shader, −10³⁰ mm on each axis).
pub const VIEW_EMPTY: f32 = -1.0e30;

/// A deformation of the view a layer is drawn through (module docs). Ref mm.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ViewDeformation {
    /// The magnifying lens of radius `radius_mm` about `centre_ref`, of strength `amplitude` in [0, 1) (the centre is
    /// magnified 1/(1 − amplitude) times).
    FishEye { centre_ref: Vec3, radius_mm: f32, amplitude: f32 },
    /// The leafer about the hinge line through `hinge_ref`, opening towards `front` (unit) by `angle_rad` on each
    /// side of the cut plane of unit normal `normal` (⟂ `front`); build it with [`ViewDeformation::leafer`].
    Leafer { hinge_ref: Vec3, front: Vec3, normal: Vec3, angle_rad: f32 },
}

impl ViewDeformation {
    /// The largest fish-eye amplitude the uniforms take (1 would fold the centre to a point).
    pub const MAX_FISH_EYE_AMPLITUDE: f32 = 0.9;
    /// The largest leafer opening the uniforms take, radians (80°: the halves must not meet behind the hinge).
    pub const MAX_LEAFER_ANGLE_RAD: f32 = 1.396_263_4;

    /// The leafer whose cut plane passes through `centre_ref` along `towards_viewer` and `up` (its normal is
    /// up × towards the viewer), hinged `depth_mm` behind the centre along the line of sight, opened by `angle_rad`:
    /// the book opens towards the viewer. `None` when the directions are degenerate (parallel or zero).
    #[must_use]
    pub fn leafer(centre_ref: Vec3, towards_viewer: Vec3, up: Vec3, depth_mm: f32, angle_rad: f32) -> Option<Self> {
        let front = towards_viewer.try_normalize()?;
        let hinge_axis = (up - front * up.dot(front)).try_normalize()?;
        let normal = hinge_axis.cross(front);
        Some(Self::Leafer { hinge_ref: centre_ref - front * depth_mm.max(0.0), front, normal, angle_rad })
    }

    /// w(x) in f32, the shader's arithmetic ([`ViewDeformationUniforms::pullback`]).
    #[must_use]
    pub fn pullback(&self, x_ref: Vec3) -> Vec3 {
        ViewDeformationUniforms::of(Some(self)).pullback(x_ref)
    }

    /// w⁻¹(y): where the view shows the point y (for glyphs drawn over a deformed view); for the fish-eye by
    /// radial bisection on ρ, to f32 precision; for the leafer, y turned with its half.
    #[must_use]
    pub fn forward(&self, y_ref: Vec3) -> Vec3 {
        match *self {
            Self::Leafer { hinge_ref, front, normal, angle_rad } => {
                let theta = angle_rad.clamp(0.0, Self::MAX_LEAFER_ANGLE_RAD);
                let r = y_ref - hinge_ref;
                let (u, v) = (r.dot(front), r.dot(normal));
                let sigma = if v.atan2(u) >= 0.0 { 1.0 } else { -1.0 };
                let (s, c) = (sigma * theta).sin_cos();
                y_ref + front * (u * (c - 1.0) - v * s) + normal * (u * s + v * (c - 1.0))
            }
            Self::FishEye { centre_ref, radius_mm, amplitude } => {
                let (a, big_r) = (f64::from(amplitude.clamp(0.0, Self::MAX_FISH_EYE_AMPLITUDE)), f64::from(radius_mm));
                let d = (y_ref - centre_ref).as_dvec3();
                let target = d.length();
                if big_r.is_nan() || big_r <= 0.0 || target >= big_r || target == 0.0 {
                    return y_ref;
                }
                let rho = |r: f64| r * (1.0 - a * (1.0 - r / big_r).powi(2));
                // ρ is increasing with ρ(0) = 0 and ρ(R) = R: bisect ρ(r) = ‖y − c‖ on [0, R].
                let (mut lo, mut hi) = (0.0, big_r);
                for _ in 0..60 {
                    let mid = 0.5 * (lo + hi);
                    if rho(mid) < target {
                        lo = mid;
                    } else {
                        hi = mid;
                    }
                }
                let r = 0.5 * (lo + hi);
                centre_ref + (d * (r / target)).as_vec3()
            }
        }
    }

    /// A box containing w(X) for the box X = \[lo, hi\] (module docs; the leafer's empty reads left out: they are
    /// transparent).
    #[must_use]
    pub fn image_box(&self, lo: DVec3, hi: DVec3) -> (DVec3, DVec3) {
        match *self {
            Self::Leafer { hinge_ref, front, normal, angle_rad } => {
                turned_boxes(hinge_ref, front, normal, angle_rad, lo, hi)
            }
            Self::FishEye { centre_ref, radius_mm, .. } => {
                let c = centre_ref.as_dvec3();
                let nearest = c.clamp(lo, hi);
                if nearest.distance(c) >= f64::from(radius_mm) { (lo, hi) } else { (lo.min(c), hi.max(c)) }
            }
        }
    }

    /// A box containing every x with w(x) in \[lo, hi\] (module docs).
    #[must_use]
    pub fn preimage_box(&self, lo: DVec3, hi: DVec3) -> (DVec3, DVec3) {
        match *self {
            Self::Leafer { hinge_ref, front, normal, angle_rad } => {
                turned_boxes(hinge_ref, front, normal, angle_rad, lo, hi)
            }
            Self::FishEye { centre_ref, radius_mm, .. } => {
                let c = centre_ref.as_dvec3();
                let r = DVec3::splat(f64::from(radius_mm.max(0.0)));
                let nearest = c.clamp(lo, hi);
                if nearest.distance(c) >= f64::from(radius_mm) { (lo, hi) } else { (lo.min(c - r), hi.max(c + r)) }
            }
        }
    }
}

/// `ViewDeformationUniforms` in shaders/raycast.wgsl ([`crate::raycast::INTERFACE`]): a [`ViewDeformation`] as the
/// shader reads it, per layer (`VIEW_NONE` for a layer drawn without one).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct ViewDeformationUniforms {
    /// fish-eye: the lens's centre; leafer: a point of the hinge line.
    pub centre_ref: [f32; 3],
    /// `VIEW_*`.
    pub kind: u32,
    /// leafer: the unit direction the book opens towards.
    pub front: [f32; 3],
    /// fish-eye: R.
    pub radius_mm: f32,
    /// leafer: the cut plane's unit normal.
    pub normal: [f32; 3],
    /// fish-eye: a; leafer: the opening θ, radians.
    pub amplitude: f32,
}
const _: () = assert!(std::mem::size_of::<ViewDeformationUniforms>() == 48);

impl ViewDeformationUniforms {
    /// The uniforms of `view` (all zero, `VIEW_NONE`, for `None`); the amplitude clamped to
    /// [0, [`ViewDeformation::MAX_FISH_EYE_AMPLITUDE`]], a radius that is not positive makes it the identity.
    #[must_use]
    pub fn of(view: Option<&ViewDeformation>) -> Self {
        match view {
            None => Self::default(),
            Some(&ViewDeformation::FishEye { centre_ref, radius_mm, amplitude }) => Self {
                centre_ref: centre_ref.to_array(),
                kind: if radius_mm > 0.0 { VIEW_FISH_EYE } else { VIEW_NONE },
                radius_mm,
                amplitude: amplitude.clamp(0.0, ViewDeformation::MAX_FISH_EYE_AMPLITUDE),
                ..Self::default()
            },
            Some(&ViewDeformation::Leafer { hinge_ref, front, normal, angle_rad }) => Self {
                centre_ref: hinge_ref.to_array(),
                kind: VIEW_LEAFER,
                front: front.to_array(),
                normal: normal.to_array(),
                amplitude: angle_rad.clamp(0.0, ViewDeformation::MAX_LEAFER_ANGLE_RAD),
                ..Self::default()
            },
        }
    }

    /// The shader's `view_pullback`: w(x) in f32, in the same order of operations.
    #[must_use]
    pub fn pullback(&self, x_ref: Vec3) -> Vec3 {
        match self.kind {
            VIEW_FISH_EYE => {
                let c = Vec3::from_array(self.centre_ref);
                let d = x_ref - c;
                let r = d.length();
                if r >= self.radius_mm {
                    return x_ref;
                }
                let q = 1.0 - r / self.radius_mm;
                // As a displacement, so that a zero amplitude leaves x exactly.
                x_ref - d * (self.amplitude * q * q)
            }
            VIEW_LEAFER => {
                let (front, normal) = (Vec3::from_array(self.front), Vec3::from_array(self.normal));
                let r = x_ref - Vec3::from_array(self.centre_ref);
                let (u, v) = (r.dot(front), r.dot(normal));
                let theta = self.amplitude;
                let phi = v.atan2(u);
                if phi.abs() < theta {
                    return Vec3::splat(VIEW_EMPTY);
                }
                // The n half (φ ≥ θ) turns back by −θ, the other by +θ.
                let sigma = if phi >= 0.0 { 1.0 } else { -1.0 };
                let s = sigma * theta.sin();
                let half = (0.5 * theta).sin();
                let c1 = -2.0 * half * half;
                x_ref + front * (u * c1 + v * s) + normal * (v * c1 - u * s)
            }
            _ => x_ref,
        }
    }
}

/// The box of the box \[lo, hi\] turned by +θ and by −θ about the leafer's hinge line (through `hinge` along front ×
/// normal): the bounding box of the 16 turned corners, widened by 10⁻³ mm against rounding.
fn turned_boxes(hinge: Vec3, front: Vec3, normal: Vec3, angle_rad: f32, lo: DVec3, hi: DVec3) -> (DVec3, DVec3) {
    let (o, f, n) = (hinge.as_dvec3(), front.as_dvec3(), normal.as_dvec3());
    let theta = f64::from(angle_rad.clamp(0.0, ViewDeformation::MAX_LEAFER_ANGLE_RAD));
    let (mut out_lo, mut out_hi) = (DVec3::INFINITY, DVec3::NEG_INFINITY);
    for corner in 0..8 {
        let x = DVec3::new(
            if corner & 1 == 0 { lo.x } else { hi.x },
            if corner & 2 == 0 { lo.y } else { hi.y },
            if corner & 4 == 0 { lo.z } else { hi.z },
        );
        let r = x - o;
        let (u, v) = (r.dot(f), r.dot(n));
        for sigma in [-1.0, 1.0] {
            let (s, c) = (sigma * theta).sin_cos();
            let turned = x + f * (u * (c - 1.0) - v * s) + n * (u * s + v * (c - 1.0));
            (out_lo, out_hi) = (out_lo.min(turned), out_hi.max(turned));
        }
    }
    (out_lo - DVec3::splat(1e-3), out_hi + DVec3::splat(1e-3))
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    const LENS: ViewDeformation =
        ViewDeformation::FishEye { centre_ref: Vec3::new(5.0, -3.0, 8.0), radius_mm: 20.0, amplitude: 0.6 };

    /// The lens is the identity outside its ball, fixes its centre, magnifies it 1/(1 − a) times, and its forward
    /// map inverts its pull-back.
    #[test]
    fn the_fish_eye_magnifies_its_centre_and_inverts() {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let c = Vec3::new(5.0, -3.0, 8.0);
        assert_eq!(LENS.pullback(c), c);
        let h = 1e-3;
        let magnification = h / (LENS.pullback(c + Vec3::X * h) - c).length();
        assert!((magnification - 1.0 / 0.4).abs() < 1e-2, "{magnification}");
        for _ in 0..2000 {
            let x = c + Vec3::new(
                rng.random_range(-30.0..30.0),
                rng.random_range(-30.0..30.0),
                rng.random_range(-30.0..30.0),
            );
            let w = LENS.pullback(x);
            if (x - c).length() >= 20.0 {
                assert_eq!(w, x);
            } else {
                assert!((w - c).length() <= (x - c).length() + 1e-5, "w moves towards the centre");
            }
            assert!((LENS.forward(w) - x).length() < 1e-3, "forward(w({x})) = {}", LENS.forward(w));
        }
    }

    /// The bounds hold every sampled point: image boxes of boxes near and far, and preimages.
    #[test]
    fn image_and_preimage_boxes_hold_their_points() {
        let mut rng = ChaCha8Rng::seed_from_u64(2);
        for (lo, hi) in [
            (DVec3::new(-10.0, -10.0, 0.0), DVec3::new(10.0, 0.0, 12.0)),
            (DVec3::new(40.0, 40.0, 40.0), DVec3::new(50.0, 50.0, 50.0)),
            (DVec3::new(0.0, -20.0, 0.0), DVec3::new(30.0, 10.0, 4.0)),
        ] {
            let image = LENS.image_box(lo, hi);
            let pre = LENS.preimage_box(lo, hi);
            for _ in 0..5000 {
                let x = DVec3::new(
                    rng.random_range(lo.x..hi.x),
                    rng.random_range(lo.y..hi.y),
                    rng.random_range(lo.z..hi.z),
                );
                let w = LENS.pullback(x.as_vec3()).as_dvec3();
                assert!(
                    w.cmpge(image.0 - 1e-4).all() && w.cmple(image.1 + 1e-4).all(),
                    "w({x}) = {w} outside {image:?}"
                );
                let y = LENS.forward(x.as_vec3()).as_dvec3();
                assert!(
                    y.cmpge(pre.0 - 1e-4).all() && y.cmple(pre.1 + 1e-4).all(),
                    "{y} maps into the box, outside {pre:?}"
                );
            }
        }
    }

    fn book() -> ViewDeformation {
        // Cut along the sagittal plane (normal L) seen from the front (towards −P), hinged 60 mm behind, open 35°.
        ViewDeformation::leafer(Vec3::new(2.0, 10.0, -4.0), Vec3::new(0.0, -1.0, 0.0), Vec3::Z, 60.0, 0.61)
            .expect("a leafer")
    }

    /// The leafer turns each half about the hinge, shows nothing in the opening, and its forward map inverts its
    /// pull-back away from the overlap behind the hinge; a point of the cut plane is shown on the turned face.
    #[test]
    fn the_leafer_opens_the_cut_like_a_book() {
        let Some(ViewDeformation::Leafer { hinge_ref, front, normal, angle_rad }) = Some(book()) else { panic!() };
        assert!((front - Vec3::new(0.0, -1.0, 0.0)).length() < 1e-6 && normal.dot(front).abs() < 1e-6);
        assert!((hinge_ref - Vec3::new(2.0, 70.0, -4.0)).length() < 1e-4, "{hinge_ref}");
        let leafer = book();
        let mut rng = ChaCha8Rng::seed_from_u64(4);
        let (mut empty, mut checked) = (0, 0);
        for _ in 0..5000 {
            let x =
                Vec3::new(rng.random_range(-80.0..80.0), rng.random_range(-80.0..80.0), rng.random_range(-80.0..80.0));
            let r = x - hinge_ref;
            let phi = r.dot(normal).atan2(r.dot(front));
            let w = leafer.pullback(x);
            if phi.abs() < angle_rad - 1e-4 {
                assert_eq!(w, Vec3::splat(VIEW_EMPTY), "{x} in the opening");
                empty += 1;
            } else if phi.abs() > angle_rad + 1e-4 {
                // A turn: the distance to the hinge line and the height along it are kept.
                let axis = front.cross(normal);
                let dist = |p: Vec3| (p - hinge_ref - axis * (p - hinge_ref).dot(axis)).length();
                assert!((dist(w) - dist(x)).abs() < 1e-3 && ((w - x).dot(axis)).abs() < 1e-3);
                let back = w - hinge_ref;
                let phi_back = back.dot(normal).atan2(back.dot(front));
                if phi_back.abs() < std::f32::consts::PI - angle_rad - 1e-3 {
                    assert!((leafer.forward(w) - x).length() < 1e-3, "forward(w({x}))");
                    checked += 1;
                }
            }
        }
        assert!(empty > 100 && checked > 2000, "{empty} empty, {checked} checked");
        // A point on the cut plane in front of the hinge is shown on the n half's face, and picked back there.
        let on_cut = hinge_ref + front * 40.0 + Vec3::Z * 5.0;
        let shown = leafer.forward(on_cut);
        assert!((shown - hinge_ref).dot(normal) > 20.0, "turned aside: {shown}");
        assert!((leafer.pullback(shown) - on_cut).length() < 1e-3);
        let closed = ViewDeformation::leafer(Vec3::ONE, Vec3::X, Vec3::Z, 30.0, 0.0).expect("a leafer");
        for _ in 0..1000 {
            let x =
                Vec3::new(rng.random_range(-80.0..80.0), rng.random_range(-80.0..80.0), rng.random_range(-80.0..80.0));
            assert_eq!(closed.pullback(x), x, "closed, the leafer is the identity");
        }
        assert!(ViewDeformation::leafer(Vec3::ONE, Vec3::Z, Vec3::Z, 30.0, 0.5).is_none(), "up along the sight");
    }

    #[test]
    fn the_leafer_bounds_hold_their_points() {
        let leafer = book();
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let (lo, hi) = (DVec3::new(-40.0, -30.0, -20.0), DVec3::new(30.0, 50.0, 25.0));
        let image = leafer.image_box(lo, hi);
        let pre = leafer.preimage_box(lo, hi);
        let inside = |p: DVec3, b: (DVec3, DVec3)| p.cmpge(b.0).all() && p.cmple(b.1).all();
        for _ in 0..20_000 {
            let x =
                DVec3::new(rng.random_range(lo.x..hi.x), rng.random_range(lo.y..hi.y), rng.random_range(lo.z..hi.z));
            let w = leafer.pullback(x.as_vec3());
            if w != Vec3::splat(VIEW_EMPTY) {
                assert!(inside(w.as_dvec3(), image), "w({x}) = {w} outside {image:?}");
            }
            assert!(inside(leafer.forward(x.as_vec3()).as_dvec3(), pre), "shown outside the preimage box");
        }
    }

    #[test]
    fn a_zero_amplitude_or_radius_is_the_identity_exactly() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        for lens in [
            ViewDeformation::FishEye { centre_ref: Vec3::ONE, radius_mm: 30.0, amplitude: 0.0 },
            ViewDeformation::FishEye { centre_ref: Vec3::ONE, radius_mm: 0.0, amplitude: 0.5 },
        ] {
            for _ in 0..1000 {
                let x = Vec3::new(
                    rng.random_range(-40.0..40.0),
                    rng.random_range(-40.0..40.0),
                    rng.random_range(-40.0..40.0),
                );
                assert_eq!(lens.pullback(x), x);
            }
        }
    }
}
