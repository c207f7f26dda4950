//! Any bytes given to the ITK HDF5 transform reader give `Ok` or `Err`, never a panic or a hang; a chain it reads
//! maps points without a panic and composes into an affine or says why not. What it reads, written again by
//! `itk_h5::write`, reads back to the same map within rounding (or the writer refuses it, writing nothing); a chain
//! with 3D Slicer's inverse members, whose points are found by Newton's method to a tolerance (and at a jump, to the
//! nearest point found), reads back to the same members. The same
//! bytes read as a thin-plate spline's landmark pairs give `Ok` or `Err`, and pairs with both points, finite. The chain
//! inverted at a few points, and sampled as a field on a small grid (or refused), never panics.
#![no_main]

use std::path::Path;

use libfuzzer_sys::fuzz_target;
use warpbench_io::displacement::FieldSource;
use warpbench_io::itk_h5::{self, H5Transform, ItkStep};

mod chain_checks;

fuzz_target!(|data: &[u8]| {
    let name = Path::new("fuzz-input.h5");
    if let Ok(pairs) = warpbench_io::landmarks::parse_spline_file(name, data.to_vec()) {
        let finite =
            |p: Option<warpbench_io::geometry::Point3<_>>| p.is_some_and(|q| q.coords().iter().all(|v| v.is_finite()));
        assert!(pairs.iter().all(|p| finite(p.moving) && finite(p.fixed)), "a pair without two finite points");
    }
    let Ok(chain) = itk_h5::parse(name, data.to_vec()) else { return };
    chain_checks::exercise(&chain, name, FieldSource::ItkHdf5);
    let points = chain_checks::POINTS;
    let out = std::env::temp_dir().join(format!("fuzz-itk-h5-{}.h5", std::process::id()));
    let steps: Vec<H5Transform> = chain.steps.iter().map(H5Transform::from).collect();
    match itk_h5::write(&out, &steps) {
        Ok(()) => {
            let again = itk_h5::read(&out).unwrap_or_else(|e| panic!("what was written does not read back: {e}"));
            let kind = |s: &ItkStep| std::mem::discriminant(s);
            assert!(chain.steps.iter().map(kind).eq(again.steps.iter().map(kind)), "written again, other members");
            if chain.steps.iter().any(|s| matches!(s, ItkStep::Inverse(_))) {
                let _ = std::fs::remove_file(&out);
                return;
            }
            for x in points {
                let (a, b) = (chain.apply(x), again.apply(x));
                // A field's grid is written as spacing and unit directions, which round its index-to-LPS map.
                let same =
                    |p: f64, q: f64| p == q || (p.is_nan() && q.is_nan()) || (p - q).abs() <= 1e-9 * p.abs().max(1.0);
                assert!((0..3).all(|i| same(a[i], b[i])), "written again, the chain maps {x:?} to {b:?}, not {a:?}");
            }
        }
        Err(_) => assert!(!out.exists(), "a refused write left a file"),
    }
    let _ = std::fs::remove_file(&out);
});
