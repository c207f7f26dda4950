//! Any bytes given to the MGH reader, as a `.mgh` and as a `.mgz`, give `Ok` or `Err`, never a panic, a hang or an
//! unchecked allocation; a volume it reads is written by `mgh::to_bytes` (unless its geometry does not fit MGH's f32
//! fields, which the writer refuses) and reads back to the same dims and samples, and to the same grid within f32's
//! rounding.
#![no_main]

use std::path::Path;

use libfuzzer_sys::fuzz_target;
use warpbench_io::{LoadOptions, mgh};

fuzz_target!(|data: &[u8]| {
    for name in ["fuzz-input.mgh", "fuzz-input.mgz"] {
        let name = Path::new(name);
        // A small memory cap keeps the fuzzer from allocating what a hostile header claims; frame 0 reads a 4-D file.
        let mut opts = LoadOptions::new().max_voxel_bytes(64 << 20).frame(0);
        let Ok(volume) = mgh::read_bytes(name, data, &mut opts) else { continue };
        let Ok(bytes) = mgh::to_bytes(name, &volume, false) else { continue };
        let again = mgh::read_bytes(Path::new("again.mgh"), &bytes, &mut LoadOptions::new())
            .unwrap_or_else(|e| panic!("what was written does not read back: {e}"));
        assert_eq!(again.dims, volume.dims);
        // Bit for bit (a NaN sample is not equal to itself).
        assert!(again.data.to_le_bytes() == volume.data.to_le_bytes(), "the samples read back differ");
        // Each entry within f32's rounding of the coordinates the grid reaches (c_ras is stored, P0 recomputed).
        let rows = volume.lps_from_index.rows();
        let reach = rows.iter().flatten().fold(1.0f64, |m, x| m.max(x.abs()))
            * volume.dims.iter().max().map_or(1.0, |&d| d as f64);
        let back = again.lps_from_index.rows();
        for r in 0..3 {
            for c in 0..4 {
                assert!((back[r][c] - rows[r][c]).abs() <= 1e-5 * reach, "[{r}][{c}]: {back:?} for {rows:?}");
            }
        }
    }
});
