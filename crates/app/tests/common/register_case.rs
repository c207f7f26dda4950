//! The registration's test case on the MRI fixture, shared by `register_cli.rs` and `gui_register.rs`: the fixture
//! pulled back through a known smooth warp (two Gaussian bumps of 5 and 4 mm) as the fixed volume, its contrast
//! inverted as the moving volume (a second modality), and 6 pairs of the truth.
#![allow(dead_code, reason = "each test binary uses a subset")]

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use warpbench_io::Volume;
use warpbench_io::geometry::{Index, Lps, Point3, Transform};

use crate::common::{mri, write_pairs_csv};

/// The known pull-back: u(x) = x + Σ bumps, two Gaussian bumps of 5 and 4 mm (σ 20 mm) inside the head.
pub fn truth(x: [f64; 3]) -> [f64; 3] {
    let bumps = [([10.0, 10.0, 20.0], [3.0, -4.0, 0.0]), ([-25.0, -20.0, 10.0], [0.0, 2.0, 3.5])];
    let mut y = x;
    for (c, w) in bumps {
        let r2: f64 = (0..3).map(|a| (x[a] - c[a]).powi(2)).sum();
        let g = (-r2 / (2.0 * 20.0 * 20.0)).exp();
        for a in 0..3 {
            y[a] += g * w[a];
        }
    }
    y
}

/// Trilinear sample at an LPS point (0 outside) of `values` on a volume's grid, given its `index_from_lps`.
fn sample(v: &Volume, values: &[f32], index_from_lps: &Transform<Index, Lps>, x: [f64; 3]) -> f64 {
    let index = index_from_lps.apply_point(Point3::from_array(x)).coords();
    let mut sum = 0.0;
    let base = index.map(f64::floor);
    for c in 0..8 {
        let corner: [f64; 3] = std::array::from_fn(|a| base[a] + f64::from((c >> a) & 1));
        if (0..3).any(|a| corner[a] < 0.0 || corner[a] > (v.dims[a] - 1) as f64) {
            continue;
        }
        let w: f64 = (0..3).map(|a| 1.0 - (index[a] - corner[a]).abs()).product();
        let [i, j, k] = corner.map(|c| c as usize);
        sum += w * f64::from(values[i + v.dims[0] * (j + v.dims[1] * k)]);
    }
    sum
}

/// The fixed volume (the fixture through the truth) and the moving one (its contrast inverted), made once per test
/// process: unoptimised, the pull-back of the fixture's 900 000 voxels took 9 s, and every test of a binary reads it.
fn volumes() -> &'static (Volume, Volume) {
    static VOLUMES: OnceLock<(Volume, Volume)> = OnceLock::new();
    VOLUMES.get_or_init(|| {
        let base = warpbench_io::open(mri()).expect("fixture");
        let values: Vec<f32> = (0..base.data.len()).map(|o| base.data.get_f64(o) as f32).collect();
        let index_from_lps = base.lps_from_index.inverse().expect("invertible");
        let [nx, ny, nz] = base.dims;
        let mut fixed = base.clone();
        let pulled: Vec<f32> = (0..nx * ny * nz)
            .map(|o| {
                let ijk = [(o % nx) as f64, ((o / nx) % ny) as f64, (o / (nx * ny)) as f64];
                let x = base.lps_from_index.apply_point(Point3::from_array(ijk)).coords();
                sample(&base, &values, &index_from_lps, truth(x)) as f32
            })
            .collect();
        fixed.data = warpbench_io::VoxelData::F32(pulled);
        let mut moving = base;
        moving.data = warpbench_io::VoxelData::F32(values.iter().map(|v| 300.0 - v).collect());
        (fixed, moving)
    })
}

/// The case's files in `dir`: the fixed volume (the fixture through the truth), the moving volume (the fixture with
/// its contrast inverted), and 6 pairs of the truth.
pub fn case(dir: &Path) -> (PathBuf, PathBuf, PathBuf, Vec<[f64; 3]>) {
    let (fixed, moving) = volumes();
    let (f, m) = (dir.join("fixed.nii"), dir.join("moving.nii"));
    warpbench_io::nifti::write(&f, fixed).expect("write fixed");
    warpbench_io::nifti::write(&m, moving).expect("write moving");
    let qs = [
        [30.0, 10.0, 20.0],
        [-30.0, 0.0, 30.0],
        [0.0, 50.0, 10.0],
        [0.0, -60.0, 20.0],
        [10.0, 0.0, 55.0],
        [-5.0, 10.0, -15.0],
    ];
    let pairs: Vec<([f64; 3], [f64; 3])> = qs.iter().map(|&q| (truth(q), q)).collect();
    let l = dir.join("pairs.csv");
    write_pairs_csv(&l, &pairs);
    (f, m, l, qs.to_vec())
}

/// Points inside the head (the fixture above a third of its range), on a coarse grid of the fixed box.
pub fn head_points(v: &Volume) -> Vec<[f64; 3]> {
    let mut out = Vec::new();
    for k in (10..v.dims[2] - 10).step_by(6) {
        for j in (10..v.dims[1] - 10).step_by(6) {
            for i in (10..v.dims[0] - 10).step_by(6) {
                if v.data.get_f64(i + v.dims[0] * (j + v.dims[1] * k)) > 30.0 {
                    out.push(v.lps_from_index.apply_point(Point3::new(i as f64, j as f64, k as f64)).coords());
                }
            }
        }
    }
    out
}
