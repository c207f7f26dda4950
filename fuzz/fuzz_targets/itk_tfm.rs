//! Any bytes given to ITK's text transform reader (one transform, or a composite's chain) and to the ANTs `.mat`
//! reader give `Ok` or `Err`, never a panic or a hang; a chain they read maps points (its inverse members by
//! Newton's method) without a panic and, on a small grid, samples to a field or refuses to.
#![no_main]

use std::path::Path;

use libfuzzer_sys::fuzz_target;
use warpbench_io::displacement::{FieldSource, SampleGrid};
use warpbench_io::geometry::Transform;
use warpbench_io::volume::GeometrySource;

fuzz_target!(|data: &[u8]| {
    let name = Path::new("fuzz-input.tfm");
    let _ = warpbench_io::itk_tfm::parse_mat(name, data);
    let Ok(text) = std::str::from_utf8(data) else { return };
    let _ = warpbench_io::itk_tfm::parse(name, text);
    let Ok(chain) = warpbench_io::itk_chain::parse_text(name, text) else { return };
    for x in [[0.0, 0.0, 0.0], [12.5, -40.0, 7.0], [1e6, -1e6, 3e5], [f64::NAN, 0.0, 1.0]] {
        let _ = chain.apply(x);
        let _ = chain.apply_inverse(x);
    }
    let _ = chain.affine();
    let grid = SampleGrid {
        dims: [4, 3, 2],
        lps_from_index: Transform::from_scale_translation([7.0, 9.0, 11.0], [-12.0, -9.0, -6.0]),
        geometry_source: GeometrySource::Assumed,
    };
    let _ = chain.field_on(name, Some(&grid), FieldSource::ItkTransform);
});
