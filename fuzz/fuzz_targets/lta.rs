//! Any text given to the reader of FreeSurfer's LTA gives `Ok` or `Err`, never a panic. An LTA it reads is taken for
//! one by `looks_like_lta`, its matrix is finite with the last row (0, 0, 0, 1), and each volume info it keeps has
//! voxels and positive sizes. Between volumes on its own src and dst grids it gives a pull-back or an error; a
//! pull-back that is finite and well conditioned, written again with those grids, reads back to itself.
#![no_main]

use std::path::Path;

use libfuzzer_sys::fuzz_target;
use warpbench_io::lta;

fuzz_target!(|data: &[u8]| {
    let name = Path::new("fuzz-input.lta");
    let looks = lta::looks_like_lta(data);
    let Ok(text) = std::str::from_utf8(data) else { return };
    let Ok(read) = lta::parse(name, text) else { return };
    assert!(looks, "an LTA read is one by its looks");
    let m = read.matrix;
    assert!(m.iter().all(|v| v.is_finite()), "a number that is not finite");
    assert_eq!([m[(3, 0)], m[(3, 1)], m[(3, 2)], m[(3, 3)]], [0.0, 0.0, 0.0, 1.0], "the last row");
    for info in [&read.src, &read.dst].into_iter().flatten() {
        assert!(info.dims.iter().all(|d| *d >= 1), "a volume info without voxels");
        assert!(info.voxel_size.iter().all(|s| *s > 0.0), "a voxel size that is not positive");
    }
    let (Some(src), Some(dst)) = (&read.src, &read.dst) else { return };
    let (fixed, moving) = (dst.lps_from_index(), src.lps_from_index());
    let Ok(u) = lta::moving_from_fixed(name, &read, (dst.dims, &fixed), (src.dims, &moving)) else { return };
    let scale = u.iter().fold(1.0f64, |a, v| a.max(v.abs()));
    let conditioned = u.try_inverse().is_some_and(|i| i.iter().all(|v| v.abs() < 1e6)) && scale < 1e6;
    let grids_fine = [&fixed, &moving].iter().all(|g| g.matrix().iter().all(|v| v.is_finite() && v.abs() < 1e6));
    if !(conditioned && grids_fine && u.iter().all(|v| v.is_finite())) {
        return;
    }
    let Ok(written) = lta::to_text(name, &u, ((dst.dims, &fixed), ""), ((src.dims, &moving), "")) else { return };
    let again = lta::parse(name, &written).unwrap_or_else(|e| panic!("what is written does not read: {e}\n{written}"));
    if let Ok(back) = lta::moving_from_fixed(name, &again, (dst.dims, &fixed), (src.dims, &moving)) {
        assert!((back - u).abs().max() <= 1e-9 * scale, "{u} written, {back} read back");
    }
});
