//! The demo pair the app opens with no files: the real head CT (fixed, `tests/data/nifti/cranium_ct.nii.gz`) and
//! head MRI (moving, `tests/data/nifti/ch2.nii.gz`) from the fixtures, with ten landmark pairs placed around each
//! head's centre of mass plus a few mm of local deformation, so a newcomer sees a deformable registration at once.
//! When the fixtures are absent (an installed binary), a procedural phantom pair takes their place.

use std::path::{Path, PathBuf};

use warpbench_io::Volume;
use warpbench_io::geometry::{Index, Lps, Point3, Transform};
use warpbench_io::landmarks::LandmarkPair;
use warpbench_io::volume::{GeometrySource, Modality, VoxelData};

/// The fixture folder the binary was built from.
#[must_use]
pub fn fixture_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/nifti")
}

/// The demo's fixed (CT) and moving (MR) files, when both exist.
#[must_use]
pub fn demo_paths() -> Option<(PathBuf, PathBuf)> {
    let dir = fixture_dir();
    let (ct, mr) = (dir.join("cranium_ct.nii.gz"), dir.join("ch2.nii.gz"));
    (ct.is_file() && mr.is_file()).then_some((ct, mr))
}

/// LPS centroid of the voxels above `threshold` (every 2nd voxel).
fn centroid_above(v: &Volume, threshold: f64) -> [f64; 3] {
    let (mut sum, mut n) = ([0.0; 3], 0.0);
    for k in (0..v.dims[2]).step_by(2) {
        for j in (0..v.dims[1]).step_by(2) {
            for i in (0..v.dims[0]).step_by(2) {
                if v.data.get_f64(v.offset(i, j, k)) > threshold {
                    let p = v.voxel_lps(i, j, k).coords();
                    for a in 0..3 {
                        sum[a] += p[a];
                    }
                    n += 1.0;
                }
            }
        }
    }
    if n > 0.0 { sum.map(|s| s / n) } else { [0.0; 3] }
}

/// Ten pairs: the same pattern about each volume's centre of mass (bone in a CT, tissue otherwise), the moving
/// points displaced by a few mm each, so the warp is visibly non-rigid.
#[must_use]
pub fn demo_landmarks(fixed: &Volume, moving: &Volume) -> Vec<LandmarkPair> {
    let threshold = |v: &Volume| {
        if crate::scene::looks_like_ct(v) {
            300.0
        } else {
            let (lo, hi) = v.data.finite_range().unwrap_or((0.0, 1.0));
            lo + 0.25 * (hi - lo)
        }
    };
    let (c_fixed, c_moving) = (centroid_above(fixed, threshold(fixed)), centroid_above(moving, threshold(moving)));
    let pattern = [
        [40.0, 0.0, 0.0],
        [-40.0, 0.0, 0.0],
        [0.0, 50.0, 0.0],
        [0.0, -50.0, 0.0],
        [0.0, 0.0, 40.0],
        [0.0, 0.0, -30.0],
        [30.0, 30.0, 25.0],
        [-30.0, -30.0, 25.0],
        [30.0, -35.0, -20.0],
        [-30.0, 35.0, -20.0],
    ];
    let local = [[3.0, 0.0, 1.0], [-2.0, 1.0, 0.0], [0.0, 3.0, -1.0], [1.0, -2.5, 0.0], [0.0, 0.0, 3.0]];
    pattern
        .iter()
        .enumerate()
        .map(|(i, o)| {
            let l = local[i % local.len()];
            let q: Point3<Lps> = Point3::from_array(std::array::from_fn(|a| c_fixed[a] + o[a]));
            let p: Point3<Lps> = Point3::from_array(std::array::from_fn(|a| c_moving[a] + o[a] + l[a]));
            LandmarkPair::new(format!("demo-{}", i + 1), p, q)
        })
        .collect()
}

/// A procedural head: an ellipsoid of "tissue" inside a shell of "bone" with two "ventricles", on an n³ grid of
/// `spacing_mm`, centred on `centre_lps`. `ct` gives Hounsfield-like i16 values, otherwise MR-like u8 values.
#[must_use]
pub fn phantom(n: usize, spacing_mm: f64, centre_lps: [f64; 3], ct: bool) -> Volume {
    let h = (n as f64 - 1.0) / 2.0;
    let radii = [0.38, 0.45, 0.4].map(|r| r * n as f64 * spacing_mm);
    let value = |p: [f64; 3]| -> f64 {
        let r = (0..3).map(|a| (p[a] / radii[a]).powi(2)).sum::<f64>().sqrt();
        let ventricle = |dx: f64| ((p[0] - dx) / 8.0).powi(2) + (p[1] / 20.0).powi(2) + (p[2] / 10.0).powi(2) < 1.0;
        match (r, ct) {
            (r, true) if r > 1.0 => -1000.0,
            (r, true) if r > 0.9 => 1200.0,
            (_, true) if ventricle(12.0) || ventricle(-12.0) => 10.0,
            (_, true) => 40.0,
            (r, false) if r > 1.0 => 0.0,
            (r, false) if r > 0.9 => 60.0,
            (_, false) if ventricle(12.0) || ventricle(-12.0) => 30.0,
            (_, false) => 150.0,
        }
    };
    let mut i16s = Vec::new();
    let mut u8s = Vec::new();
    for k in 0..n {
        for j in 0..n {
            for i in 0..n {
                let p = [i, j, k].map(|x| (x as f64 - h) * spacing_mm);
                let v = value(p);
                if ct {
                    i16s.push(v as i16);
                } else {
                    u8s.push(v as u8);
                }
            }
        }
    }
    let data = if ct { VoxelData::I16(i16s) } else { VoxelData::U8(u8s) };
    let lps_from_index: Transform<Lps, Index> =
        Transform::from_scale_translation([spacing_mm; 3], std::array::from_fn(|a| centre_lps[a] - h * spacing_mm));
    let mut v = Volume::new(Path::new("phantom"), [n; 3], data, lps_from_index, GeometrySource::Assumed)
        .unwrap_or_else(|e| unreachable!("a phantom is a valid volume: {e}"));
    v.modality = if ct { Modality::Ct } else { Modality::Mr };
    v
}
