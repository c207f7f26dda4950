//! Slicing planes: a 2-D image of an arbitrary plane through the deformed, blended pair, for the app's slice views.
//!
//! A slice is a ray with a single sample: pixel (px, py) (x right, y down, integer = pixel centre) shows the ref point
//!
//! x_ref(px, py) = origin + (px + ½)·u + (py + ½)·v
//!
//! ([`SlicePlane::ref_from_pixel`]; `u`, `v` are the ref-space steps of one pixel, in mm, orthogonal or not). At
//! x_ref each visible volume is pulled back through its warp and sampled exactly as the ray caster does
//! ([`crate::raycast`]), windowed and classified by its transfer function, and the two are combined by the same
//! [`crate::BlendMode`]. **Slice colour:** a volume contributes its TF *colour* with opacity forced to 1 inside its
//! texture box (so a slice shows the windowed image whatever the 3-D opacity ramp) and is transparent outside it; no
//! opacity correction, no compositing, no shading. The output is premultiplied RGBA8 like the 3-D view's.
//!
//! The GPU side is the `cs_slice` entry point of `shaders/raycast.wgsl` (the same per-sample functions as
//! `cs_raycast`), drawn by [`crate::RaycastRenderer::render_slice`] with uniforms from
//! [`crate::RaycastUniforms::for_slice`]; the CPU reference is [`crate::cpu_reference::render_slice`].

use glam::{DMat3, DVec3, Mat4, Vec4};

use crate::error::{GpuError, Result};

/// A rectangle of `size` = (width, height) pixels on a plane in ref space (mm).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SlicePlane {
    /// The corner of pixel (0, 0) (not its centre): x_ref(px, py) = origin + (px + ½)·u + (py + ½)·v.
    pub origin_ref: [f64; 3],
    /// One pixel step to the right, ref mm.
    pub u_ref: [f64; 3],
    /// One pixel step down, ref mm.
    pub v_ref: [f64; 3],
    pub size: (u32, u32),
}

/// World (LPS) axes.
const LPS_L: usize = 0;
const LPS_P: usize = 1;
const LPS_S: usize = 2;

impl SlicePlane {
    /// The axial plane (constant S) of the fixed grid nearest `position_mm` (an S coordinate, ref mm), through voxel
    /// centres: pixel (i, j) is voxel (i, j, k) of the index axes closest to L, P and S.
    ///
    /// `lps_from_index` is row-major (the fixed volume's), `dims` its size. The slice index k is the nearest voxel
    /// centre to `position_mm` along the index axis closest to S (measured at in-plane index 0; exact for grids
    /// aligned with LPS), clamped to the grid.
    #[must_use]
    pub fn axial(lps_from_index: &[[f64; 4]; 4], dims: [usize; 3], position_mm: f64) -> Self {
        Self::grid_plane(lps_from_index, dims, LPS_S, position_mm)
    }

    /// The coronal plane (constant P) nearest `position_mm`, through voxel centres; superior is up (the index axis
    /// closest to S runs upwards), the other in-plane axis to the right. See [`Self::axial`].
    #[must_use]
    pub fn coronal(lps_from_index: &[[f64; 4]; 4], dims: [usize; 3], position_mm: f64) -> Self {
        Self::grid_plane(lps_from_index, dims, LPS_P, position_mm)
    }

    /// The sagittal plane (constant L) nearest `position_mm`, through voxel centres; superior is up. See
    /// [`Self::axial`].
    #[must_use]
    pub fn sagittal(lps_from_index: &[[f64; 4]; 4], dims: [usize; 3], position_mm: f64) -> Self {
        Self::grid_plane(lps_from_index, dims, LPS_L, position_mm)
    }

    /// The grid plane normal to the index axis closest to world axis `world`.
    fn grid_plane(m: &[[f64; 4]; 4], dims: [usize; 3], world: usize, position_mm: f64) -> Self {
        let col = |a: usize| DVec3::new(m[0][a], m[1][a], m[2][a]);
        let start = DVec3::new(m[0][3], m[1][3], m[2][3]);
        // The index axis most aligned with `world` (ties: the lowest).
        let along = |a: usize, w: usize| col(a)[w].abs() / col(a).length().max(f64::MIN_POSITIVE);
        let closest = |axes: &[usize], w: usize| {
            axes.iter().copied().fold(axes[0], |best, a| if along(a, w) > along(best, w) { a } else { best })
        };
        let normal_axis = closest(&[0, 1, 2], world);
        let in_plane: Vec<usize> = (0..3).filter(|&a| a != normal_axis).collect();
        // Axial: u, v = the in-plane index axes in order. Coronal/sagittal: v runs down, against the axis closest to S.
        let (u_axis, v_axis, flip_v) = if world == LPS_S {
            (in_plane[0], in_plane[1], false)
        } else {
            let s_axis = closest(&in_plane, LPS_S);
            let other = if s_axis == in_plane[0] { in_plane[1] } else { in_plane[0] };
            (other, s_axis, col(s_axis)[LPS_S] > 0.0)
        };
        let step = col(normal_axis)[world];
        let last = dims[normal_axis].saturating_sub(1) as f64;
        let k = if step.abs() > 0.0 { ((position_mm - start[world]) / step).round().clamp(0.0, last) } else { 0.0 };
        let mut index = DVec3::ZERO;
        index[normal_axis] = k;
        let u = col(u_axis);
        let mut v = col(v_axis);
        if flip_v {
            index[v_axis] = dims[v_axis].saturating_sub(1) as f64;
            v = -v;
        }
        let first_centre = start + index.x * col(0) + index.y * col(1) + index.z * col(2);
        let origin = first_centre - 0.5 * u - 0.5 * v;
        let size = (u32::try_from(dims[u_axis]).unwrap_or(u32::MAX), u32::try_from(dims[v_axis]).unwrap_or(u32::MAX));
        Self { origin_ref: origin.to_array(), u_ref: u.to_array(), v_ref: v.to_array(), size }
    }

    /// An oblique plane centred on `centre_ref` (the centre of the image), perpendicular to `normal_ref`, with
    /// `up_ref` (projected into the plane) pointing up the image, square pixels of `pixel_mm`, `size` pixels. The
    /// image's x axis is normal × up (for normal = S and up = −P, anterior up: x = +L, the patient's left on the
    /// right).
    ///
    /// # Errors
    /// [`GpuError::InvalidInput`] when the normal is zero, `up_ref` is parallel to it, `pixel_mm` is not positive or
    /// the size is empty.
    pub fn oblique(
        centre_ref: [f64; 3],
        normal_ref: [f64; 3],
        up_ref: [f64; 3],
        pixel_mm: f64,
        size: (u32, u32),
    ) -> Result<Self> {
        let n = DVec3::from_array(normal_ref).try_normalize().ok_or_else(|| invalid("the slice normal is zero"))?;
        let up = DVec3::from_array(up_ref);
        let up = (up - up.dot(n) * n).try_normalize().ok_or_else(|| invalid("`up` is parallel to the normal"))?;
        if !(pixel_mm > 0.0 && pixel_mm.is_finite()) || size.0 == 0 || size.1 == 0 {
            return Err(invalid("the pixel size must be positive and the image non-empty"));
        }
        let u = n.cross(up) * pixel_mm;
        let v = -up * pixel_mm;
        let origin = DVec3::from_array(centre_ref) - 0.5 * f64::from(size.0) * u - 0.5 * f64::from(size.1) * v;
        Ok(Self { origin_ref: origin.to_array(), u_ref: u.to_array(), v_ref: v.to_array(), size })
    }

    /// The ref point (mm) shown at pixel (px, py): origin + (px + ½)·u + (py + ½)·v. Integer arguments are pixel
    /// centres; fractional ones are allowed.
    #[must_use]
    pub fn ref_from_pixel(&self, px: f64, py: f64) -> [f64; 3] {
        let (o, u, v) = self.vectors();
        (o + (px + 0.5) * u + (py + 0.5) * v).to_array()
    }

    /// The inverse of [`Self::ref_from_pixel`]: `[px, py, d]` with d the signed distance (mm) of `p_ref` from the
    /// plane along u × v / |u × v|. `None` when u and v are parallel (a degenerate plane).
    #[must_use]
    pub fn pixel_from_ref(&self, p_ref: [f64; 3]) -> Option<[f64; 3]> {
        let (o, u, v) = self.vectors();
        let n = u.cross(v).try_normalize()?;
        let m = DMat3::from_cols(u, v, n);
        let q = m.inverse() * (DVec3::from_array(p_ref) - o);
        Some([q.x - 0.5, q.y - 0.5, q.z])
    }

    /// The plane's normal u × v / |u × v| (towards the viewer for a right-handed image), or `None` if degenerate.
    #[must_use]
    pub fn normal_ref(&self) -> Option<[f64; 3]> {
        let (_, u, v) = self.vectors();
        u.cross(v).try_normalize().map(|n| n.to_array())
    }

    /// Ref from framebuffer coordinates (pixel centres at i + ½, as `@builtin(position)` gives them): the columns
    /// are u, v, 0 and the origin. This is `RaycastUniforms::ref_from_frag_px`.
    #[must_use]
    pub fn ref_from_frag_px(&self) -> Mat4 {
        let (o, u, v) = self.vectors();
        Mat4::from_cols(u.as_vec3().extend(0.0), v.as_vec3().extend(0.0), Vec4::ZERO, o.as_vec3().extend(1.0))
    }

    fn vectors(&self) -> (DVec3, DVec3, DVec3) {
        (DVec3::from_array(self.origin_ref), DVec3::from_array(self.u_ref), DVec3::from_array(self.v_ref))
    }
}

fn invalid(msg: &str) -> GpuError {
    GpuError::InvalidInput(msg.to_owned())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid(spacing: [f64; 3], origin: [f64; 3]) -> [[f64; 4]; 4] {
        [
            [spacing[0], 0.0, 0.0, origin[0]],
            [0.0, spacing[1], 0.0, origin[1]],
            [0.0, 0.0, spacing[2], origin[2]],
            [0.0, 0.0, 0.0, 1.0],
        ]
    }

    fn close(a: [f64; 3], b: [f64; 3], tol: f64) -> bool {
        a.iter().zip(b).all(|(x, y)| (x - y).abs() <= tol)
    }

    #[test]
    fn orthogonal_planes_pass_through_voxel_centres() {
        let m = grid([1.5, 2.0, 3.0], [-10.0, 5.0, 20.0]);
        let dims = [10, 12, 8];
        let centre = |i: f64, j: f64, k: f64| [-10.0 + 1.5 * i, 5.0 + 2.0 * j, 20.0 + 3.0 * k];
        // S = 20 + 3k: 28.9 → k = 3.
        let ax = SlicePlane::axial(&m, dims, 28.9);
        assert_eq!(ax.size, (10, 12));
        assert!(close(ax.ref_from_pixel(0.0, 0.0), centre(0.0, 0.0, 3.0), 1e-12));
        assert!(close(ax.ref_from_pixel(4.0, 7.0), centre(4.0, 7.0, 3.0), 1e-12));
        // Coronal: P = 5 + 2j, 9 → j = 2; x = i, y runs down from the top (k = 7).
        let co = SlicePlane::coronal(&m, dims, 9.0);
        assert_eq!(co.size, (10, 8));
        assert!(close(co.ref_from_pixel(3.0, 0.0), centre(3.0, 2.0, 7.0), 1e-12));
        assert!(close(co.ref_from_pixel(3.0, 7.0), centre(3.0, 2.0, 0.0), 1e-12));
        // Sagittal: L = −10 + 1.5i, far out of range → clamped to i = 9; x = j, superior up.
        let sa = SlicePlane::sagittal(&m, dims, 1e6);
        assert_eq!(sa.size, (12, 8));
        assert!(close(sa.ref_from_pixel(5.0, 1.0), centre(9.0, 5.0, 6.0), 1e-12));
    }

    #[test]
    fn ref_from_pixel_round_trips_with_its_inverse() {
        let planes = [
            SlicePlane::axial(&grid([1.0, 1.0, 2.5], [0.0; 3]), [16, 16, 16], 7.0),
            SlicePlane::oblique([3.0, -2.0, 5.0], [1.0, 2.0, 0.5], [0.0, 0.0, 1.0], 0.7, (40, 30)).expect("plane"),
            // Non-orthogonal u, v.
            SlicePlane { origin_ref: [1.0, 2.0, 3.0], u_ref: [1.0, 0.2, 0.0], v_ref: [0.3, 1.1, 0.4], size: (8, 8) },
        ];
        for plane in planes {
            for (px, py) in [(0.0, 0.0), (3.25, 17.5), (-2.0, 40.0)] {
                let p = plane.ref_from_pixel(px, py);
                let q = plane.pixel_from_ref(p).expect("invertible");
                assert!(close(q, [px, py, 0.0], 1e-9), "{plane:?}: ({px}, {py}) → {p:?} → {q:?}");
                // Off the plane by d along the normal: same pixel, distance d.
                let n = plane.normal_ref().expect("normal");
                let off = [p[0] + 2.5 * n[0], p[1] + 2.5 * n[1], p[2] + 2.5 * n[2]];
                assert!(close(plane.pixel_from_ref(off).expect("invertible"), [px, py, 2.5], 1e-9));
            }
        }
    }

    #[test]
    fn oblique_plane_is_centred_with_up_upwards() {
        let p = SlicePlane::oblique([1.0, 2.0, 3.0], [0.0, 0.0, 2.0], [0.0, -1.0, 0.5], 0.5, (20, 10)).expect("plane");
        // The image centre (10, 5) in continuous pixel coordinates = pixel (9.5, 4.5).
        assert!(close(p.ref_from_pixel(9.5, 4.5), [1.0, 2.0, 3.0], 1e-12));
        assert!(close(p.u_ref, [0.5, 0.0, 0.0], 1e-12), "x = +L");
        assert!(close(p.v_ref, [0.0, 0.5, 0.0], 1e-12), "down = posterior when up is anterior");
        assert!(SlicePlane::oblique([0.0; 3], [0.0; 3], [0.0, 1.0, 0.0], 1.0, (4, 4)).is_err());
        assert!(SlicePlane::oblique([0.0; 3], [0.0, 1.0, 0.0], [0.0, 2.0, 0.0], 1.0, (4, 4)).is_err());
        assert!(SlicePlane::oblique([0.0; 3], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0], 0.0, (4, 4)).is_err());
    }
}
