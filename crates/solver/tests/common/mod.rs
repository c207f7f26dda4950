//! Helpers shared by the solver's integration tests.

use std::path::Path;

use warpbench_io::geometry::Point3;
use warpbench_solver::{Aabb, Moving};

/// The box spanned by a fixture volume's voxel centres (`rel` under `tests/data`), in its LPS space.
pub fn volume_box(rel: &str) -> Aabb<Moving> {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data").join(rel);
    let v = warpbench_io::open(&path).expect("fixture volume");
    let corners: Vec<Point3<Moving>> = (0..8)
        .map(|c| {
            let ijk = [0, 1, 2].map(|a| if c >> a & 1 == 1 { (v.dims[a] - 1) as f64 } else { 0.0 });
            Point3::from_array(v.lps_from_index.apply_point(Point3::from_array(ijk)).coords())
        })
        .collect();
    Aabb::around(&corners, 0.0).expect("eight corners")
}
