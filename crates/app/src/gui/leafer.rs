//! The leafer widget (issue 17, item 3; Brunet, Nowak & Gleicher 2006 §5.3 after McGuffin, Tancau & Balakrishnan
//! 2003): the 3-D view opens the fixed or the moving volume like a book, so that what lies inside it on the cut can be
//! seen and picked ([`warpbench_gpu::ViewDeformation::Leafer`]).
//!
//! The cut follows the view: it is the plane through the crosshair (where the three slices meet) that contains the
//! line of sight and the camera's up direction, hinged at the back of the fixed volume (the farthest corner of its
//! box along the line of sight), and the two halves turn by the opening angle each, towards the viewer. Orbit to turn
//! the cut, click a slice to move it. For a head seen from the front this is the midsagittal cut opened like a book:
//! both cut faces face the viewer. (A spreader, which pushes the halves apart, keeps them parallel to the line of
//! sight: edge-on, nothing to pick; the leafer was chosen for that.)
//!
//! It deforms only what the 3-D view shows of that volume: a pick through it stores the point of the undeformed
//! volume (on the cut plane when it lands on a face), the glyphs of that volume's points are drawn where it shows
//! them, and the slices, the document, the registration and the exports never see it. While it is open the attention
//! lens does not pulse.

use warpbench_gpu::glam::{DVec3, Vec3};
use warpbench_gpu::{OrbitCamera, ViewDeformation};

use super::open::Side;

/// The opening a new leafer starts with, degrees.
pub const DEFAULT_ANGLE_DEG: f32 = 30.0;
/// The widest opening the panel offers, degrees.
pub const MAX_ANGLE_DEG: f32 = 75.0;

/// Whether the 3-D view opens a volume with the leafer.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub enum Leafer {
    #[default]
    Closed,
    /// `side` opened by `angle_deg` on each side of the cut.
    Open { side: Side, angle_deg: f32 },
}

impl Leafer {
    #[must_use]
    pub fn is_open(self) -> bool {
        matches!(self, Self::Open { .. })
    }

    /// The view deformation of the (fixed, moving) layers: the leafer on its side, cut through `crosshair_ref` as
    /// `camera` looks (module docs), hinged at the back of the fixed box \[`box_min`, `box_max`\].
    #[must_use]
    pub fn views(
        self,
        camera: &OrbitCamera,
        crosshair_ref: Vec3,
        (box_min, box_max): (DVec3, DVec3),
    ) -> [Option<ViewDeformation>; 2] {
        let Self::Open { side, angle_deg } = self else { return [None; 2] };
        let ref_from_clip = camera.ref_from_clip(1.0);
        let near = ref_from_clip.project_point3(Vec3::ZERO);
        let far = ref_from_clip.project_point3(Vec3::Z);
        let up = ref_from_clip.project_point3(Vec3::new(0.0, 0.5, 0.0)) - near;
        let towards_viewer = (near - far).normalize_or_zero();
        let c = crosshair_ref.as_dvec3();
        let depth = (0..8)
            .map(|i| {
                let corner = DVec3::new(
                    if i & 1 == 0 { box_min.x } else { box_max.x },
                    if i & 2 == 0 { box_min.y } else { box_max.y },
                    if i & 4 == 0 { box_min.z } else { box_max.z },
                );
                (c - corner).dot(towards_viewer.as_dvec3())
            })
            .fold(1.0, f64::max);
        let leafer =
            ViewDeformation::leafer(crosshair_ref, towards_viewer, up, depth as f32, angle_deg.to_radians().max(0.0));
        match side {
            Side::Fixed => [leafer, None],
            Side::Moving => [None, leafer],
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use warpbench_gpu::Projection;

    /// Seen from the front (the camera on −P looking towards +P), the leafer cuts the sagittal plane through the
    /// crosshair, hinged at the back of the box, on the chosen side only.
    #[test]
    fn seen_from_the_front_the_cut_is_sagittal_and_hinged_at_the_back() {
        let (lo, hi) = (DVec3::splat(-90.0), DVec3::splat(90.0));
        let mut camera = OrbitCamera::fit(lo.as_vec3(), hi.as_vec3(), Projection::Perspective { fov_y_rad: 0.6 });
        camera.azimuth_rad = 0.0;
        camera.elevation_rad = 0.0;
        let near = camera.ref_from_clip(1.0).project_point3(Vec3::ZERO);
        assert!(near.y < -100.0 && near.x.abs() < 1e-3, "the camera looks from the front: {near}");
        let crosshair = Vec3::new(5.0, -10.0, 3.0);
        let open = Leafer::Open { side: Side::Moving, angle_deg: 30.0 };
        let [fixed, moving] = open.views(&camera, crosshair, (lo, hi));
        assert!(fixed.is_none());
        let Some(ViewDeformation::Leafer { hinge_ref, front, normal, angle_rad }) = moving else {
            panic!("{moving:?}")
        };
        assert!((front - Vec3::new(0.0, -1.0, 0.0)).length() < 1e-4, "{front}");
        assert!(normal.x.abs() > 0.9999, "the cut is sagittal: {normal}");
        assert!((hinge_ref - Vec3::new(5.0, 90.0, 3.0)).length() < 1e-3, "hinged at the back: {hinge_ref}");
        assert!((angle_rad - 30f32.to_radians()).abs() < 1e-6);
        assert_eq!(Leafer::Closed.views(&camera, crosshair, (lo, hi)), [None; 2]);
    }
}
