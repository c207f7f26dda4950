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
//! Bounds, for the proxy box and empty-space skipping: w maps the ball onto itself and is the identity outside, so
//! the points that show a layer's content lie in that content's box or in the ball ([`ViewDeformation::preimage_box`]),
//! and w(x) lies between c and x, so w of a box lies in the box of it and c when it meets the ball
//! ([`ViewDeformation::image_box`]).

use bytemuck::{Pod, Zeroable};
use glam::{DVec3, Vec3};

/// `ViewDeformationUniforms.kind`, the WGSL constants `VIEW_*` of the same names ([`crate::raycast::INTERFACE`]).
pub const VIEW_NONE: u32 = 0;
pub const VIEW_FISH_EYE: u32 = 1;

/// A deformation of the view a layer is drawn through (module docs). Ref mm.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ViewDeformation {
    /// The magnifying lens of radius `radius_mm` about `centre_ref`, of strength `amplitude` in [0, 1) (the centre is
    /// magnified 1/(1 − amplitude) times).
    FishEye { centre_ref: Vec3, radius_mm: f32, amplitude: f32 },
}

impl ViewDeformation {
    /// The largest fish-eye amplitude the uniforms take (1 would fold the centre to a point).
    pub const MAX_FISH_EYE_AMPLITUDE: f32 = 0.9;

    /// w(x) in f32, the shader's arithmetic ([`ViewDeformationUniforms::pullback`]).
    #[must_use]
    pub fn pullback(&self, x_ref: Vec3) -> Vec3 {
        ViewDeformationUniforms::of(Some(self)).pullback(x_ref)
    }

    /// w⁻¹(y): where the view shows the point y (for glyphs drawn over a deformed view); radial bisection on ρ,
    /// to f32 precision.
    #[must_use]
    pub fn forward(&self, y_ref: Vec3) -> Vec3 {
        match *self {
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

    /// A box containing w(X) for the box X = \[lo, hi\] (module docs).
    #[must_use]
    pub fn image_box(&self, lo: DVec3, hi: DVec3) -> (DVec3, DVec3) {
        match *self {
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
    /// fish-eye: the lens's centre.
    pub centre_ref: [f32; 3],
    /// `VIEW_*`.
    pub kind: u32,
    /// fish-eye: R.
    pub radius_mm: f32,
    /// fish-eye: a.
    pub amplitude: f32,
    _pad0: [u32; 2],
}
const _: () = assert!(std::mem::size_of::<ViewDeformationUniforms>() == 32);

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
                _pad0: [0; 2],
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
            _ => x_ref,
        }
    }
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
