//! Any text given to the readers of FSL's FLIRT matrix and AFNI's matrix file gives `Ok` or `Err`, never a panic.
//! FLIRT: a matrix it reads is finite, with the last row (0, 0, 0, 1); one it reads is taken for one by
//! `looks_like_flirt_matrix`; against two grids (one of each handedness) it converts to a pull-back and back to itself,
//! when it can be inverted; and its text reads back to it within the twelve decimals written. AFNI: a matrix it reads
//! is finite and affine, is taken for one by `looks_like_afni_matrix`, and its text reads back to the same doubles.
#![no_main]

use std::path::Path;

use libfuzzer_sys::fuzz_target;
use warpbench_io::geometry::{Index, Lps, Transform};
use warpbench_io::{afni, fsl};

fuzz_target!(|data: &[u8]| {
    let name = Path::new("fuzz-input.mat");
    let afni_looks = afni::looks_like_afni_matrix(data);
    if let Ok(m) = std::str::from_utf8(data).map_err(|_| ()).and_then(|t| afni::parse(name, t).map_err(|_| ())) {
        assert!(afni_looks, "an AFNI matrix read is one by its looks");
        assert!(m.iter().all(|v| v.is_finite()), "a number that is not finite");
        assert_eq!([m[(3, 0)], m[(3, 1)], m[(3, 2)], m[(3, 3)]], [0.0, 0.0, 0.0, 1.0], "the last row");
        let again =
            afni::parse(name, &afni::to_text(&m)).unwrap_or_else(|e| panic!("what is written does not read: {e}"));
        assert!(
            again.iter().zip(m.iter()).all(|(a, b)| a.to_bits() == (b + 0.0).to_bits()),
            "{m} written, {again} read"
        );
    }
    let looks = fsl::looks_like_flirt_matrix(data);
    let Ok(text) = std::str::from_utf8(data) else { return };
    let Ok(m) = fsl::parse(name, text) else { return };
    assert!(looks || data.len() >= 4096, "a matrix read is one by its looks");
    assert!(m.iter().all(|v| v.is_finite()), "a number that is not finite");
    assert_eq!([m[(3, 0)], m[(3, 1)], m[(3, 2)], m[(3, 3)]], [0.0, 0.0, 0.0, 1.0], "the last row");
    let fixed: Transform<Lps, Index> = Transform::from_scale_translation([2.0, 2.0, 2.5], [-15.0, -13.0, -11.0]);
    let moving: Transform<Lps, Index> = Transform::from_scale_translation([1.5, -1.0, 1.1], [-18.0, 10.0, -8.0]);
    let (f, mv) = (([8, 7, 6], &fixed), ([9, 8, 7], &moving));
    if let Ok(u) = fsl::moving_from_fixed(name, &m, f, mv) {
        let scale = m.iter().fold(1.0f64, |a, v| a.max(v.abs()));
        let conditioned = m.try_inverse().is_some_and(|i| i.iter().all(|v| v.abs() < 1e6)) && scale < 1e6;
        if let (true, Ok(back)) = (conditioned && u.iter().all(|v| v.is_finite()), fsl::flirt_from(name, &u, f, mv)) {
            let worst = (back - m).abs().max();
            assert!(worst <= 1e-6 * scale, "{m} read, {back} written back");
        }
    }
    if m.iter().all(|v| v.abs() < 1e12) {
        let again =
            fsl::parse(name, &fsl::to_text(&m)).unwrap_or_else(|e| panic!("what is written does not read: {e}"));
        assert!((again - m).abs().max() <= 5e-13 + 1e-15 * m.abs().max(), "{m} written, {again} read back");
    }
});
