//! Any bytes given to the Learn2Reg reader give `Ok` or `Err`, never a panic, a hang or an allocation the bytes do not
//! back; a field it reads has finite steps, converts against a pair of grids to a pull-back with finite vectors (or is
//! refused for a step beyond any finite point) and,
//! when float16 holds its steps, is written by `write_voxel_field` and reads back within float16's rounding; in the
//! NIfTI form (`write_voxel_field_nifti`, float32) it reads back exactly. The bytes may be an `.npz` or a NIfTI.
#![no_main]

use std::path::Path;

use libfuzzer_sys::fuzz_target;
use warpbench_io::geometry::{Index, Lps, Transform};
use warpbench_io::learn2reg;

fuzz_target!(|data: &[u8]| {
    let name = Path::new("fuzz-input.npz");
    let Ok(field) = learn2reg::read_voxel_field_bytes(name, data) else { return };
    assert_eq!(field.steps_vox.len(), field.dims.iter().product::<usize>(), "one step per voxel");
    assert!(field.steps_vox.iter().flatten().all(|v| v.is_finite()), "a step that is not finite");
    if field.steps_vox.len() > 1 << 16 {
        return;
    }
    let fixed: Transform<Lps, Index> = Transform::from_scale_translation([2.0, 2.0, 2.0], [-15.0, -13.0, -11.0]);
    let moving: Transform<Lps, Index> = Transform::from_scale_translation([2.5, 2.5, 2.5], [-18.75, -18.75, -18.75]);
    match learn2reg::pullback_from_voxels(name, &field, field.dims, &fixed, &moving) {
        Ok(pullback) => {
            assert!(pullback.displacements_lps.iter().flatten().all(|v| v.is_finite()), "a vector that is not finite");
        }
        // A step near f32::MAX voxels is beyond any finite point at 2.5 mm a voxel; nothing else may be refused.
        Err(e) => assert!(e.to_string().contains("beyond any finite point"), "{e}"),
    }
    let out = std::env::temp_dir().join(format!("fuzz-learn2reg-{}.npz", std::process::id()));
    if learn2reg::write_voxel_field(&out, &field).is_ok() {
        let again =
            learn2reg::read_voxel_field(&out).unwrap_or_else(|e| panic!("what was written does not read back: {e}"));
        assert_eq!(again.dims, field.dims);
        for (a, b) in again.steps_vox.iter().zip(&field.steps_vox) {
            for c in 0..3 {
                // Rounding to float16: half a unit in the last place, or below its smallest normal step.
                let bound = b[c].abs() * 2f32.powi(-11) + 2f32.powi(-25);
                assert!((a[c] - b[c]).abs() <= bound, "{a:?} read back for {b:?}");
            }
        }
        let _ = std::fs::remove_file(&out);
    }
    if field.dims.iter().any(|&d| d > 32767) {
        return; // beyond NIfTI-1's axis limit, which the writer refuses
    }
    let out = std::env::temp_dir().join(format!("fuzz-learn2reg-{}.nii", std::process::id()));
    learn2reg::write_voxel_field_nifti(&out, &field, &fixed).unwrap_or_else(|e| panic!("the NIfTI form: {e}"));
    let again = learn2reg::read_voxel_field(&out).unwrap_or_else(|e| panic!("the NIfTI form does not read back: {e}"));
    assert!(again == field, "the NIfTI form read back differs");
    let _ = std::fs::remove_file(&out);
});
