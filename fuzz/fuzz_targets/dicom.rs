//! Any bytes given to the DICOM reader give `Ok` or `Err`, never a panic or an unchecked allocation.
//!
//! JPEG 2000 (transfer syntaxes 1.2.840.10008.1.2.4.90 to .93, and HTJ2K .201 to .203) is skipped: openjp2 0.6.1,
//! which dicom-pixeldata decodes it with, passes a null pointer to `std::alloc::dealloc` when it frees a code block
//! that was never decoded (`opj_tcd_code_block_dec_deallocate`). That is `free(NULL)` in practice, but undefined
//! behaviour, which the debug UB checks of a nightly build abort on with the first JPEG 2000 seed
//! (`tests/data/dicom/single/MR_small_jp2klossless.dcm`), so the campaign could not go past it.
#![no_main]

use std::path::Path;

use libfuzzer_sys::fuzz_target;
use warpbench_io::LoadOptions;

/// The prefixes of the JPEG 2000 transfer syntax UIDs.
const JPEG_2000_UIDS: [&[u8]; 2] = [b"1.2.840.10008.1.2.4.9", b"1.2.840.10008.1.2.4.20"];

fuzz_target!(|data: &[u8]| {
    if JPEG_2000_UIDS.iter().any(|uid| data.windows(uid.len()).any(|w| w == *uid)) {
        return;
    }
    let mut opts = LoadOptions::new().max_voxel_bytes(64 << 20);
    let _ = warpbench_io::dicom::read_file_bytes(Path::new("fuzz-input.dcm"), data, &mut opts);
});
