//! Any bytes given to the DICOM reader give `Ok` or `Err`, never a panic or an unchecked allocation.
#![no_main]

use std::path::Path;

use libfuzzer_sys::fuzz_target;
use warpbench_io::LoadOptions;

fuzz_target!(|data: &[u8]| {
    let mut opts = LoadOptions::new().max_voxel_bytes(64 << 20);
    let _ = warpbench_io::dicom::read_file_bytes(Path::new("fuzz-input.dcm"), data, &mut opts);
});
