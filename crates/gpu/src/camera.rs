//! [`OrbitCamera`]: an orbit camera around a target in ref space (fixed LPS, mm), orthographic or perspective.
//!
//! Azimuth 0 and elevation 0 look from anterior (−y) towards posterior (+y) with superior (+z) up, so the patient's
//! left (+x) is on the image's right. Azimuth turns about the superior axis; elevation raises the eye towards
//! superior. `clip_from_ref = clip_from_view · view_from_ref`, with glam 0.34's right-handed view and its
//! `directx` projections (WebGPU convention: NDC z ∈ \[0, 1\], y up). The ray caster generates rays with
//! [`OrbitCamera::ref_from_clip`].

use glam::camera::rh::{proj::directx, view::look_at_mat4};
use glam::{Mat4, Vec2, Vec3};

/// The projection.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Projection {
    /// Parallel rays; the view is 2·radius/zoom mm high.
    Orthographic,
    /// Vertical field of view (at zoom 1).
    Perspective { fov_y_rad: f32 },
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OrbitCamera {
    pub target_ref: Vec3,
    pub azimuth_rad: f32,
    pub elevation_rad: f32,
    pub distance_mm: f32,
    /// Radius of the scene around the target: sets the orthographic extent and the near/far planes.
    pub radius_mm: f32,
    /// Magnification (> 1 zooms in).
    pub zoom: f32,
    /// Shift of the target in the view plane (right, up), mm.
    pub pan_mm: Vec2,
    pub projection: Projection,
}

impl OrbitCamera {
    /// Looks at the centre of the box [min, max] from the front, far enough to see all of it.
    #[must_use]
    pub fn fit(box_min_ref: Vec3, box_max_ref: Vec3, projection: Projection) -> Self {
        let radius_mm = (0.5 * (box_max_ref - box_min_ref).length()).max(1e-3);
        let distance_mm = match projection {
            Projection::Orthographic => 2.0 * radius_mm,
            Projection::Perspective { fov_y_rad } => radius_mm / (0.5 * fov_y_rad).sin(),
        };
        Self {
            target_ref: 0.5 * (box_min_ref + box_max_ref),
            azimuth_rad: 0.0,
            elevation_rad: 0.0,
            distance_mm,
            radius_mm,
            zoom: 1.0,
            pan_mm: Vec2::ZERO,
            projection,
        }
    }

    /// Unit vector from the target towards the eye.
    #[must_use]
    pub fn eye_direction(&self) -> Vec3 {
        let el = self.elevation_rad.clamp(-1.5697, 1.5697);
        let (sa, ca) = self.azimuth_rad.sin_cos();
        let (se, ce) = el.sin_cos();
        Vec3::new(sa * ce, -ca * ce, se)
    }

    /// The view's right and up axes in ref space.
    #[must_use]
    pub fn right_up(&self) -> (Vec3, Vec3) {
        let back = self.eye_direction();
        let right = Vec3::Z.cross(back).normalize();
        (right, back.cross(right))
    }

    fn panned_target(&self) -> Vec3 {
        let (right, up) = self.right_up();
        self.target_ref + right * self.pan_mm.x + up * self.pan_mm.y
    }

    #[must_use]
    pub fn eye_ref(&self) -> Vec3 {
        self.panned_target() + self.eye_direction() * self.distance_mm
    }

    #[must_use]
    pub fn view_from_ref(&self) -> Mat4 {
        let (_, up) = self.right_up();
        look_at_mat4(self.eye_ref(), self.panned_target(), up)
    }

    /// `aspect` = width / height.
    #[must_use]
    pub fn clip_from_view(&self, aspect: f32) -> Mat4 {
        let zoom = self.zoom.max(1e-6);
        let reach = 1.05 * self.radius_mm + self.pan_mm.length();
        let far = self.distance_mm + reach;
        match self.projection {
            Projection::Orthographic => {
                let half_h = self.radius_mm / zoom;
                let half_w = half_h * aspect;
                directx::orthographic(-half_w, half_w, -half_h, half_h, self.distance_mm - reach, far)
            }
            Projection::Perspective { fov_y_rad } => {
                let fov = 2.0 * ((0.5 * fov_y_rad).tan() / zoom).atan();
                let near = (self.distance_mm - reach).max(1e-3 * self.radius_mm);
                directx::perspective(fov, aspect, near, far)
            }
        }
    }

    #[must_use]
    pub fn clip_from_ref(&self, aspect: f32) -> Mat4 {
        self.clip_from_view(aspect) * self.view_from_ref()
    }

    #[must_use]
    pub fn ref_from_clip(&self, aspect: f32) -> Mat4 {
        self.clip_from_ref(aspect).inverse()
    }

    /// Orthographic only: the size of one pixel in mm for an image `height_px` high.
    #[must_use]
    pub fn pixel_mm(&self, height_px: u32) -> f32 {
        2.0 * self.radius_mm / self.zoom / height_px as f32
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn front_view_puts_patient_left_right_and_superior_up() {
        let cam = OrbitCamera::fit(Vec3::splat(-50.0), Vec3::splat(50.0), Projection::Orthographic);
        let clip = cam.clip_from_ref(1.0);
        let left = clip.project_point3(Vec3::new(40.0, 0.0, 0.0));
        let sup = clip.project_point3(Vec3::new(0.0, 0.0, 40.0));
        let ant = clip.project_point3(Vec3::new(0.0, -40.0, 0.0));
        let post = clip.project_point3(Vec3::new(0.0, 40.0, 0.0));
        assert!(left.x > 0.3 && left.y.abs() < 1e-5, "{left}");
        assert!(sup.y > 0.3 && sup.x.abs() < 1e-5, "{sup}");
        assert!(ant.z < post.z && ant.z > 0.0 && post.z < 1.0, "anterior is nearer: {ant} {post}");
        let back = cam.ref_from_clip(1.0).project_point3(left);
        assert!((back - Vec3::new(40.0, 0.0, 0.0)).length() < 1e-3);
    }

    #[test]
    fn perspective_sees_the_whole_box() {
        let cam =
            OrbitCamera::fit(Vec3::ZERO, Vec3::new(100.0, 80.0, 60.0), Projection::Perspective { fov_y_rad: 0.6 });
        let cam = OrbitCamera { azimuth_rad: 0.7, elevation_rad: 0.4, ..cam };
        let clip = cam.clip_from_ref(1.0);
        for c in 0..8 {
            let p = Vec3::new((c & 1) as f32 * 100.0, ((c >> 1) & 1) as f32 * 80.0, ((c >> 2) & 1) as f32 * 60.0);
            let q = clip.project_point3(p);
            assert!(q.x.abs() <= 1.0 && q.y.abs() <= 1.0 && (0.0..=1.0).contains(&q.z), "{p} → {q}");
        }
    }
}
