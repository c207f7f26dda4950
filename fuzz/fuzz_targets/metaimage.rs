//! Any bytes given to the MetaImage readers (a volume, and a displacement field as transformix writes one) give `Ok`
//! or `Err`, never a panic or an unchecked allocation.
#![no_main]

use std::path::Path;

use libfuzzer_sys::fuzz_target;
use warpbench_io::LoadOptions;

fuzz_target!(|data: &[u8]| {
    let name = Path::new("fuzz-input.mha");
    // A small memory cap keeps the fuzzer from allocating what a hostile header claims.
    let mut opts = LoadOptions::new().max_voxel_bytes(64 << 20);
    let _ = warpbench_io::metaimage::read_bytes(name, data, &mut opts);
    let _ = warpbench_io::metaimage::read_displacement_field_bytes(name, data);
});
