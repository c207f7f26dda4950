//! Any bytes given to the elastix transform parameter reader give `Ok` or `Err`, never a panic or a hang; a transform
//! it reads maps points without a panic, and, on a small fixed grid, samples to a field or refuses to.
#![no_main]

use std::path::Path;

use libfuzzer_sys::fuzz_target;

/// The largest fixed grid sampled here, voxels: the reader itself allows what memory allows.
const MAX_SAMPLED_VOXELS: usize = 4096;

fuzz_target!(|data: &[u8]| {
    let name = Path::new("fuzz-input.txt");
    let Ok(transform) = warpbench_io::elastix::parse_transform(name, data) else { return };
    for x in [[0.0, 0.0, 0.0], [12.5, -40.0, 7.0], [1e6, -1e6, 3e5], [f64::NAN, 0.0, 1.0]] {
        let _ = transform.apply(x);
    }
    let _ = transform.affine();
    if transform.grid.as_ref().is_some_and(|g| g.dims.iter().product::<usize>() <= MAX_SAMPLED_VOXELS) {
        let _ = warpbench_io::elastix::sample(name, &transform);
    }
});
