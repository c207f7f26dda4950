//! What the ITK transform targets do with any chain they read: map and invert a few points (one far away, one not a
//! number), compose it into an affine or say why not, and sample it on a small grid when it holds no field of its own
//! (a field's grid, from the input, may be as large as the input allows). None of it may panic.

use std::path::Path;

use warpbench_io::displacement::{FieldSource, SampleGrid};
use warpbench_io::geometry::Transform;
use warpbench_io::itk_chain::ItkChain;
use warpbench_io::volume::GeometrySource;

/// The points every chain maps.
pub const POINTS: [[f64; 3]; 4] = [[0.0, 0.0, 0.0], [12.5, -40.0, 7.0], [1e6, -1e6, 3e5], [f64::NAN, 0.0, 1.0]];

/// The checks above; `name` and `source` as the reader would report them.
pub fn exercise(chain: &ItkChain, name: &Path, source: FieldSource) {
    for x in POINTS {
        let _ = chain.apply(x);
        let _ = chain.apply_inverse(x);
    }
    let _ = chain.affine();
    if !chain.has_field() {
        let grid = SampleGrid {
            dims: [4, 3, 2],
            lps_from_index: Transform::from_scale_translation([7.0, 9.0, 11.0], [-12.0, -9.0, -6.0]),
            geometry_source: GeometrySource::Assumed,
        };
        let _ = chain.field_on(name, Some(&grid), source);
    }
}
