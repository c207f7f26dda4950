//! Where a click or a drag puts a landmark point, and whether it may be stored.
//!
//! The law every way of placing a point keeps: the point stored is the point the status bar shows under the pointer.
//! In a slice that is the slice pixel under the pointer mapped through the slice's plane into ref space (the fixed
//! point), and that ref point pulled back through the warp (the moving point); in the 3-D view it is the pick's hit.
//! Both come from one function each ([`slice_point`], the pick), used for the status bar and for the click alike,
//! and a pointer that is not over the image gives no point at all (a press and a release can fall in frames of
//! different layouts; a position off the image is never mapped). A point outside its volume is refused with a
//! message ([`outside_message`]), never stored.

use eframe::egui;
use warpbench_gpu::SlicePlane;
use warpbench_io::Volume;
use warpbench_io::geometry::Point3;

use super::End;

/// What the pointer is over in a slice view: the fixed (ref) point and the moving point the warp shows there.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Cursor {
    pub fixed_lps: [f64; 3],
    pub moving_lps: [f64; 3],
    /// det ∇u at the fixed point, u the pull-back shown (the brush's inverse included); `None` without a warp.
    pub det_jacobian: Option<f64>,
    /// The pair whose fixed point is nearest the fixed point, if any pair has one.
    pub nearest: Option<NearestPair>,
}

/// The pair nearest the pointer ([`Cursor::nearest`]): its row, how far its fixed point is, and its leave-one-out
/// error (how much the warp there leans on it).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NearestPair {
    /// 0-based row of the table.
    pub index: usize,
    pub distance_mm: f64,
    pub leave_one_out_mm: Option<f64>,
}

impl Cursor {
    /// |u(x) − x|: how far the warp moves the point under the pointer, mm.
    #[must_use]
    pub fn displacement_mm(&self) -> f64 {
        let d: [f64; 3] = std::array::from_fn(|a| self.moving_lps[a] - self.fixed_lps[a]);
        (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt()
    }

    /// The status bar's read-out: the displacement, det ∇u and the nearest pair (named `nearest_name`).
    #[must_use]
    pub fn readout(&self, nearest_name: &str) -> String {
        use std::fmt::Write as _;
        let mut out = format!("|u(x) - x| {:.2} mm", self.displacement_mm());
        if let Some(det) = self.det_jacobian {
            let _ = write!(out, ", det {det:.3}");
        }
        if let Some(n) = self.nearest {
            let _ = write!(out, ", nearest pair {nearest_name} {:.1} mm away", n.distance_mm);
            if let Some(loo) = n.leave_one_out_mm {
                let _ = write!(out, " (leave-one-out {loo:.2} mm)");
            }
        }
        out
    }
}

impl Cursor {
    /// The point of `end`.
    #[must_use]
    pub fn point(&self, end: End) -> [f64; 3] {
        match end {
            End::Fixed => self.fixed_lps,
            End::Moving => self.moving_lps,
        }
    }
}

/// The ref point shown under `pos` (window points) in a slice image painted in `image_rect` at `scale` points per
/// image pixel, or `None` when `pos` is not over the image.
#[must_use]
pub fn slice_point(plane: &SlicePlane, image_rect: egui::Rect, scale: f32, pos: egui::Pos2) -> Option<[f64; 3]> {
    if !(image_rect.contains(pos) && scale > 0.0) {
        return None;
    }
    // Pixel centres at i + 1/2 in image pixels.
    let f = (pos - image_rect.min) / scale;
    Some(plane.ref_from_pixel(f64::from(f.x) - 0.5, f64::from(f.y) - 0.5))
}

/// Where slice pixel `q` (`[px, py, distance]` from [`SlicePlane::pixel_from_ref`]) is painted.
#[must_use]
pub fn slice_screen(image_rect: egui::Rect, scale: f32, q: [f64; 3]) -> egui::Pos2 {
    image_rect.min + egui::vec2((q[0] as f32 + 0.5) * scale, (q[1] as f32 + 0.5) * scale)
}

/// Whether `p_lps` lies in `volume`'s box of voxel edges, in its index space (exact for oblique grids).
#[must_use]
pub fn contains(volume: &Volume, p_lps: [f64; 3]) -> bool {
    let Some(index_from_lps) = volume.lps_from_index.inverse() else { return false };
    let idx = index_from_lps.apply_point(Point3::from_array(p_lps)).coords();
    (0..3).all(|a| idx[a] >= -0.5 && idx[a] <= volume.dims[a] as f64 - 0.5)
}

/// The window's message for a point of `end` at `p_lps` that lies outside its volume, `None` when it is inside.
#[must_use]
pub fn outside_message(end: End, volume: &Volume, p_lps: [f64; 3]) -> Option<String> {
    if contains(volume, p_lps) {
        return None;
    }
    let [l, p, s] = p_lps;
    let side = match end {
        End::Fixed => "fixed",
        End::Moving => "moving",
    };
    Some(format!("not placed: the {side} point ({l:.1}, {p:.1}, {s:.1}) mm LPS is outside the {side} volume"))
}

#[cfg(test)]
mod tests {
    use super::*;
    use warpbench_io::geometry::Transform;
    use warpbench_io::volume::{GeometrySource, VoxelData};

    /// 10 × 20 × 30 voxels of 2 mm, i running towards -L, the first centre at (5, 6, 7).
    fn flipped() -> Volume {
        Volume::new(
            std::path::Path::new("flipped.nii"),
            [10, 20, 30],
            VoxelData::U8(vec![0; 6000]),
            Transform::from_scale_translation([-2.0, 2.0, 2.0], [5.0, 6.0, 7.0]),
            GeometrySource::NiftiPixdim,
        )
        .expect("volume")
    }

    #[test]
    fn a_point_is_inside_exactly_to_the_voxel_edges_in_index_space() {
        let v = flipped();
        // Voxel (0, 0, 0)'s centre, and its edge half a voxel along -i (which is +L).
        assert!(contains(&v, [5.0, 6.0, 7.0]));
        assert!(contains(&v, [6.0, 6.0, 7.0]));
        assert!(!contains(&v, [6.1, 6.0, 7.0]));
        // The far corner: index (9.5, 19.5, 29.5).
        let far = [5.0 - 2.0 * 9.5, 6.0 + 2.0 * 19.5, 7.0 + 2.0 * 29.5];
        assert!(contains(&v, far));
        assert!(!contains(&v, [far[0] - 0.1, far[1], far[2]]));
        let m = outside_message(End::Moving, &v, [100.0, 0.0, 0.0]).expect("outside");
        assert!(m.contains("moving point (100.0, 0.0, 0.0) mm LPS is outside the moving volume"), "{m}");
        assert_eq!(outside_message(End::Fixed, &v, [5.0, 6.0, 7.0]), None);
    }

    #[test]
    fn only_a_pointer_over_the_image_gives_a_point() {
        let plane = SlicePlane::oblique([0.0; 3], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0], 2.0, (10, 10)).expect("plane");
        let rect = egui::Rect::from_min_size(egui::pos2(100.0, 50.0), egui::vec2(40.0, 40.0));
        // 4 points per image pixel; the centre of the image is the plane's centre.
        let centre = slice_point(&plane, rect, 4.0, rect.center()).expect("on the image");
        assert!(centre.iter().all(|c| c.abs() < 1e-9), "{centre:?}");
        // Pixel (0, 0)'s centre, and its round trip through the plane.
        let p = slice_point(&plane, rect, 4.0, rect.min + egui::vec2(2.0, 2.0)).expect("on the image");
        let q = plane.pixel_from_ref(p).expect("plane");
        assert!((slice_screen(rect, 4.0, q) - (rect.min + egui::vec2(2.0, 2.0))).length() < 1e-4);
        for off in [egui::pos2(99.0, 60.0), egui::pos2(141.0, 60.0), egui::pos2(120.0, 49.0), egui::pos2(120.0, 91.0)] {
            assert_eq!(slice_point(&plane, rect, 4.0, off), None, "{off:?} is off the image");
        }
    }
}
