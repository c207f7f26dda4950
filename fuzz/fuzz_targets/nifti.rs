//! Any bytes given to the nifti reader give `Ok` or `Err`, never a panic or an unchecked allocation.
#![no_main]

use std::path::Path;

use libfuzzer_sys::fuzz_target;
use warpbench_io::LoadOptions;

fuzz_target!(|data: &[u8]| {
    // A small memory cap keeps the fuzzer from allocating what a hostile header claims.
    let mut opts = LoadOptions::new().max_voxel_bytes(64 << 20);
    let _ = warpbench_io::nifti::read_bytes(Path::new("fuzz-input"), data, &mut opts);
});
