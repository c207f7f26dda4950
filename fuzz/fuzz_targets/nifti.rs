//! Any bytes given to the nifti reader give `Ok` or `Err`, never a panic or an unchecked allocation: as a volume,
//! and as a displacement field (ITK's and ANTs' intents, AFNI's warp told by its extension), whose vectors are then
//! one per voxel and finite.
#![no_main]

use std::path::Path;

use libfuzzer_sys::fuzz_target;
use warpbench_io::LoadOptions;

fuzz_target!(|data: &[u8]| {
    // A small memory cap keeps the fuzzer from allocating what a hostile header claims.
    let mut opts = LoadOptions::new().max_voxel_bytes(64 << 20);
    let _ = warpbench_io::nifti::read_bytes(Path::new("fuzz-input"), data, &mut opts);
    if let Ok((field, _)) = warpbench_io::nifti::read_vector_field_bytes(Path::new("fuzz-input"), data) {
        assert_eq!(field.displacements_lps.len(), field.dims.iter().product::<usize>(), "one vector per voxel");
        assert!(field.displacements_lps.iter().flatten().all(|v| v.is_finite()), "a vector that is not finite");
    }
});
