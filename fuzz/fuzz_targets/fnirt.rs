//! Any bytes given to the FNIRT reader give `Ok` or `Err`, never a panic, a hang or an allocation the bytes do not
//! back; a file it reads, given a reference grid it fits (its own grid for a deformation field, the recorded
//! reference for coefficients) and an input grid, becomes a pull-back on that grid with finite vectors, or is refused
//! for a warp beyond any finite point or a grid the file itself places elsewhere; that pull-back, written as FNIRT's
//! relative field, reads back to itself within float32's rounding. The bytes are a NIfTI (plain or gzip).
#![no_main]

use std::path::Path;

use libfuzzer_sys::fuzz_target;
use warpbench_io::fnirt;
use warpbench_io::geometry::{Index, Lps, Transform};
use warpbench_io::nifti::{FnirtFile, read_fnirt_file_bytes};

fuzz_target!(|data: &[u8]| {
    let Ok(file) = read_fnirt_file_bytes(Path::new("fuzz-input.nii"), data) else { return };
    let (dims, fixed): ([usize; 3], Transform<Lps, Index>) = match &file {
        FnirtFile::Deformation { dims, lps_from_index, vectors } => {
            assert_eq!(vectors.len(), dims.iter().product::<usize>(), "one vector per voxel");
            let own = lps_from_index.map_or_else(|| Transform::from_scale_translation([2.0; 3], [0.0; 3]), |(t, _)| t);
            (*dims, own)
        }
        FnirtFile::CubicCoefficients(c) => {
            assert_eq!(c.coefficients.len(), c.dims.iter().product::<usize>(), "one coefficient per knot");
            (c.reference_dims, Transform::from_scale_translation(c.reference_spacing_mm, [10.0, -20.0, 5.0]))
        }
    };
    if dims.iter().product::<usize>() > 1 << 16 || !fixed.is_valid_affine() {
        return;
    }
    let moving: Transform<Lps, Index> = Transform::from_scale_translation([-1.5, 2.0, 2.5], [30.0, -18.0, -20.0]);
    let path = std::env::temp_dir().join(format!("fuzz-fnirt-{}.nii", std::process::id()));
    std::fs::write(&path, data).expect("a temporary file");
    match fnirt::read_pullback(&path, (dims, &fixed), ([20, 22, 18], &moving)) {
        Ok(read) => {
            assert_eq!(read.field.dims, dims);
            let d = &read.field.displacements_lps;
            assert!(d.iter().flatten().all(|v| v.is_finite()), "a vector that is not finite");
            let out = std::env::temp_dir().join(format!("fuzz-fnirt-out-{}.nii", std::process::id()));
            // Vectors near f32::MAX overflow on the way to FSL's coordinates; the writer refuses them, never panics.
            if fnirt::write_pullback(&out, (dims, &fixed), ([20, 22, 18], &moving), d).is_ok()
                && dims.iter().all(|&n| n <= 32767)
            {
                let again = fnirt::read_pullback(&out, (dims, &fixed), ([20, 22, 18], &moving));
                let again = again.unwrap_or_else(|e| panic!("what was written does not read back: {e}"));
                // FNIRT's files do not say relative or absolute, and a warp that doubles FSL's coordinates reads as
                // absolute by fslpy's test: the format's ambiguity, not checked here.
                if again.warnings.iter().any(|w| w.starts_with("read as relative")) {
                    // The largest coordinate in play: the vectors are rounded to float32 in FSL's coordinates.
                    let corners = |(n, t): ([usize; 3], &Transform<Lps, Index>)| {
                        warpbench_io::volume::corner_indices(n)
                            .iter()
                            .map(|i| t.apply_point(*i).coords().iter().fold(0f64, |m, c| m.max(c.abs())))
                            .fold(0f64, f64::max)
                    };
                    let scale = corners((dims, &fixed)).max(corners(([20, 22, 18], &moving)));
                    for (a, b) in again.field.displacements_lps.iter().zip(d) {
                        for c in 0..3 {
                            let bound = 1e-6 * (f64::from(b[c].abs()) + 2.0 * scale) + 1e-30;
                            assert!(f64::from((a[c] - b[c]).abs()) <= bound, "{a:?} read back for {b:?}");
                        }
                    }
                }
            }
            let _ = std::fs::remove_file(&out);
        }
        Err(e) => {
            let e = e.to_string();
            assert!(
                e.contains("beyond any finite point")
                    || e.contains("mm from the fixed volume's")
                    || e.contains("cannot be inverted"),
                "{e}"
            );
        }
    }
    let _ = std::fs::remove_file(&path);
});
