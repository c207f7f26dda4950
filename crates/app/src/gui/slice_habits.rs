//! What slice viewers have taught their users, as plain functions the slice views call: the wheel steps one slice
//! (shift: ten), a right drag sets window and level, and each pane names the patient's sides at its edges.
//!
//! Slice positions are mm along S (axial), P (coronal) and L (sagittal) through the fixed grid; a step is one voxel
//! of the grid axis nearest that direction, so a wheel notch always shows the next slice of the grid.

use warpbench_gpu::SlicePlane;
use warpbench_io::Volume;

use crate::project::document::Look;

/// Slices a shift + wheel notch steps.
pub const SHIFT_STEP: i32 = 10;

/// Points of a trackpad's scroll that make one wheel notch (egui's line height for a wheel's "line" unit).
pub const POINTS_PER_NOTCH: f32 = 40.0;

/// The LPS axis slice view `a` moves along: 0 axial → S (2), 1 coronal → P (1), 2 sagittal → L (0).
#[must_use]
pub fn world_axis(a: usize) -> usize {
    2 - a.min(2)
}

/// One slice of `volume`'s grid along slice view `a`'s direction (mm), and the range of slice positions its voxel
/// centres cover (lowest, highest), the grid axis chosen as the slice planes choose it (the index axis most aligned
/// with the direction).
#[must_use]
pub fn slice_step(volume: &Volume, a: usize) -> (f64, (f64, f64)) {
    let m = volume.lps_from_index.rows();
    let world = world_axis(a);
    let column = |j: usize| [m[0][j], m[1][j], m[2][j]];
    let along = |j: usize| {
        let c = column(j);
        c[world].abs() / (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt().max(f64::MIN_POSITIVE)
    };
    let axis = (0..3).fold(0, |best, j| if along(j) > along(best) { j } else { best });
    let step = column(axis)[world];
    let first = m[world][3];
    let last = first + step * volume.dims[axis].saturating_sub(1) as f64;
    (step.abs(), (first.min(last), first.max(last)))
}

/// Slice view `a`'s position after `notches` wheel notches (positive: towards higher positions), `shift` for
/// [`SHIFT_STEP`] slices a notch, kept within the grid.
#[must_use]
pub fn stepped(volume: &Volume, a: usize, from_mm: f64, notches: i32, shift: bool) -> f64 {
    let (step, (lo, hi)) = slice_step(volume, a);
    let per = if shift { SHIFT_STEP } else { 1 };
    (from_mm + f64::from(notches * per) * step).clamp(lo, hi)
}

/// Whole wheel notches in `carry` plus `delta_y` points or lines (`lines`: the wheel's own unit), and what is left
/// over for the next event (a trackpad scrolls in points).
#[must_use]
pub fn notches(carry: f32, delta_y: f32, lines: bool) -> (i32, f32) {
    let total = carry + if lines { delta_y } else { delta_y / POINTS_PER_NOTCH };
    let whole = total.trunc();
    (whole as i32, total - whole)
}

/// Which look a right drag in a slice changes: the fixed volume's, unless the views show the moving volume alone.
#[must_use]
pub fn window_side(moving_only: bool) -> usize {
    usize::from(moving_only)
}

/// `look` after a right drag of (`dx`, `dy`) points, as in Slicer and ITK-SNAP: right widens the window, up brightens
/// (lowers the level); each point moves either by 0.5 % of the window's width, so the feel is the same on a CT in
/// Hounsfield units and on an MR in arbitrary units. The width stays positive.
#[must_use]
pub fn window_level_dragged(look: Look, dx: f32, dy: f32) -> Look {
    let width = (look.window_high - look.window_low).max(f32::EPSILON);
    let level = 0.5 * (look.window_high + look.window_low);
    let new_width = (width * (1.0 + 0.005 * dx)).max(width * 0.01).max(f32::EPSILON);
    let new_level = level + 0.005 * width * dy;
    Look { window_low: new_level - 0.5 * new_width, window_high: new_level + 0.5 * new_width, ..look }
}

/// The window and level of `look` as a slice pane shows them while they are dragged.
#[must_use]
pub fn window_level_text(look: &Look) -> String {
    let width = look.window_high - look.window_low;
    let level = 0.5 * (look.window_high + look.window_low);
    format!("W {width:.0}  L {level:.0}")
}

/// The patient side a direction points to (LPS): L/R, P/A or S/I by its largest component.
#[must_use]
pub fn side_of(d: [f64; 3]) -> char {
    let k = (0..3).fold(0, |best, k| if d[k].abs() > d[best].abs() { k } else { best });
    match (k, d[k] >= 0.0) {
        (0, true) => 'L',
        (0, false) => 'R',
        (1, true) => 'P',
        (1, false) => 'A',
        (_, true) => 'S',
        (_, false) => 'I',
    }
}

/// The sides a slice image's edges face: left, right, top, bottom (the image's x runs along u, its y down along v).
#[must_use]
pub fn edge_labels(plane: &SlicePlane) -> [char; 4] {
    let (u, v) = (plane.u_ref, plane.v_ref);
    let neg = |d: [f64; 3]| d.map(|x| -x);
    [side_of(neg(u)), side_of(u), side_of(neg(v)), side_of(v)]
}

#[cfg(test)]
// Exact equality: the steps and ranges are sums of the grid's own binary-exact spacings.
#[allow(clippy::float_cmp)]
mod tests {
    use super::*;
    use warpbench_io::geometry::{Index, Lps, Transform};
    use warpbench_io::volume::{GeometrySource, VoxelData};

    /// A 10 × 8 × 6 grid of 1.5 × 2 × 2.5 mm voxels, its index axes along L, P and S, off the origin.
    fn volume() -> Volume {
        let m = nalgebra::Matrix3::from_diagonal(&nalgebra::Vector3::new(1.5, 2.0, 2.5));
        let t = Transform::<Lps, Index>::from_linear_translation(m, [-7.0, 3.0, 10.0]);
        let path = std::path::Path::new("grid.nii");
        Volume::new(path, [10, 8, 6], VoxelData::U8(vec![0; 480]), t, GeometrySource::Assumed).expect("volume")
    }

    #[test]
    fn a_notch_is_one_voxel_of_the_axis_along_the_view_and_stops_at_the_grid() {
        let v = volume();
        assert_eq!(slice_step(&v, 0), (2.5, (10.0, 22.5)), "axial: S, the third axis");
        assert_eq!(slice_step(&v, 1), (2.0, (3.0, 17.0)), "coronal: P");
        assert_eq!(slice_step(&v, 2), (1.5, (-7.0, 6.5)), "sagittal: L");
        assert_eq!(stepped(&v, 0, 12.5, 1, false), 15.0);
        assert_eq!(stepped(&v, 0, 12.5, -1, false), 10.0);
        assert_eq!(stepped(&v, 2, -7.0, 2, true), 6.5, "twenty slices stop at the last");
        assert_eq!(notches(0.0, 1.0, true), (1, 0.0));
        assert_eq!(notches(0.0, -3.0, true), (-3, 0.0));
        let (n, carry) = notches(0.0, 30.0, false);
        assert_eq!(n, 0, "a trackpad's 30 points are less than a notch");
        assert_eq!(notches(carry, 30.0, false).0, 1, "and 60 are one");
    }

    #[test]
    fn a_right_drag_widens_to_the_right_and_brightens_upwards() {
        let look = Look {
            window_low: -100.0,
            window_high: 300.0,
            ..Look::new(crate::settings::Preset::default(), warpbench_gpu::Window::from_range(0.0, 1.0))
        };
        let wider = window_level_dragged(look, 50.0, 0.0);
        assert!((wider.window_high - wider.window_low - 500.0).abs() < 1e-3, "{wider:?}");
        assert!((wider.window_high + wider.window_low - 200.0).abs() < 1e-3, "the level stays");
        let up = window_level_dragged(look, 0.0, -20.0);
        assert!((0.5 * (up.window_high + up.window_low) - 60.0).abs() < 1e-3, "level 100 - 40: {up:?}");
        let narrow = window_level_dragged(look, -1000.0, 0.0);
        assert!(narrow.window_high > narrow.window_low, "the width stays positive");
        assert_eq!(window_level_text(&look), "W 400  L 100");
        assert_eq!((window_side(false), window_side(true)), (0, 1));
    }

    /// The grid planes of an LPS-aligned grid face the sides radiologists expect: axial and coronal with the patient's
    /// right on the screen's left and anterior (axial) or superior (coronal, sagittal) up.
    #[test]
    fn each_pane_names_the_sides_it_faces() {
        let v = volume();
        let m = v.lps_from_index.rows();
        assert_eq!(edge_labels(&SlicePlane::axial(&m, v.dims, 12.0)), ['R', 'L', 'A', 'P']);
        assert_eq!(edge_labels(&SlicePlane::coronal(&m, v.dims, 5.0)), ['R', 'L', 'S', 'I']);
        assert_eq!(edge_labels(&SlicePlane::sagittal(&m, v.dims, 0.0)), ['A', 'P', 'S', 'I']);
        assert_eq!(side_of([0.1, -0.2, 0.9]), 'S');
        assert_eq!(side_of([-0.7, 0.2, 0.1]), 'R');
    }
}
