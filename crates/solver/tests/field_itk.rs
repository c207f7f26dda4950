//! [`SampledField`] against ITK's `DisplacementFieldTransform` on the same file.
//!
//! Oracle: `tests/data/itk/field_input_reference.json`, made by `data-scripts/field_input_sitk.py` (SimpleITK 2.5.7,
//! ITK 5.4): an oblique 9×8×7 DISPVECT field read by ITK's NIfTI reader and mapped with `TransformPoint` at probes
//! inside the grid, in its outer half voxel (taps clamped) and outside it (zero displacement).

// ITK returns the input point bit for bit outside the grid: exact equality tells the outside probes.
#![allow(clippy::unwrap_used, clippy::float_cmp)]

use std::path::Path;

use warpbench_io::nifti::read_displacement_field;
use warpbench_solver::field::SampledField;
use warpbench_solver::{Fixed, Moving, Warp};

/// ITK evaluates in f64 from the same f32 vectors; the geometry goes through the file's f32 sform.
const ITK_TOL_MM: f64 = 1e-4;

#[test]
fn transform_point_matches_itk_inside_at_the_edge_and_outside() {
    let dir = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../../tests/data/itk"));
    let field = read_displacement_field(&dir.join("field_input_field.nii.gz")).unwrap();
    let warp = SampledField::<Moving, Fixed>::from_displacement_field(field).unwrap();
    let text = std::fs::read_to_string(dir.join("field_input_reference.json")).unwrap();
    let reference: serde_json::Value = serde_json::from_str(&text).unwrap();
    let probes = reference["probes"].as_array().unwrap();
    assert!(probes.len() >= 7);
    let triple = |v: &serde_json::Value| -> [f64; 3] { std::array::from_fn(|a| v[a].as_f64().unwrap()) };
    let (mut inside, mut outside) = (0, 0);
    for probe in probes {
        let (c, x, want) = (triple(&probe["index"]), triple(&probe["x"]), triple(&probe["T(x)"]));
        let got = warp.apply_raw(x);
        let err = (0..3).map(|a| (got[a] - want[a]).abs()).fold(0.0, f64::max);
        assert!(err < ITK_TOL_MM, "index {c:?}: warpbench {got:?}, ITK {want:?}");
        if want == x {
            outside += 1;
            assert!(warp.displacement_raw(x).is_none(), "ITK leaves {c:?} in place: outside the grid");
        } else {
            inside += 1;
        }
    }
    assert!(inside >= 3 && outside >= 3, "{inside} probes inside, {outside} outside");
}
