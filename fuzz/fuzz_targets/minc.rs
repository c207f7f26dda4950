//! Any bytes given to the MINC reader (MINC 1's netCDF through `netcdf3`, MINC 2's HDF5 through `hdf5-pure`, either
//! perhaps gzip-compressed) give `Ok` or `Err`, never a panic, a hang or an unchecked allocation; a volume it reads is
//! written by `minc::to_bytes` and reads back to the same dims and samples, and to the same grid within rounding. The
//! same bytes read as a displacement grid (`read_displacements_bytes`) give one vector per voxel, or an error.
#![no_main]

use std::path::Path;

use libfuzzer_sys::fuzz_target;
use warpbench_io::{LoadOptions, minc};

fuzz_target!(|data: &[u8]| {
    let name = Path::new("fuzz-input.mnc");
    // The same bytes as a displacement grid: vectors, finite or not, one per voxel.
    if let Ok(field) =
        minc::read_displacements_bytes(name, data.to_vec(), &LoadOptions::new().max_voxel_bytes(64 << 20))
    {
        assert_eq!(field.displacements_lps.len(), field.dims.iter().product::<usize>());
    }
    // A small memory cap keeps the fuzzer from allocating what a hostile header claims; frame 0 reads a 4-D file.
    let mut opts = LoadOptions::new().max_voxel_bytes(64 << 20).frame(0);
    let Ok(volume) = minc::read_bytes(name, data.to_vec(), &mut opts) else { return };
    let Ok(bytes) = minc::to_bytes(name, &volume) else { return };
    let again = minc::read_bytes(Path::new("again.mnc"), bytes, &mut LoadOptions::new())
        .unwrap_or_else(|e| panic!("what was written does not read back: {e}"));
    assert_eq!(again.dims, volume.dims);
    // Bit for bit (a NaN sample is not equal to itself).
    assert!(again.data.to_le_bytes() == volume.data.to_le_bytes(), "the samples read back differ");
    let rows = volume.lps_from_index.rows();
    let reach =
        rows.iter().flatten().fold(1.0f64, |m, x| m.max(x.abs())) * volume.dims.iter().max().map_or(1.0, |&d| d as f64);
    let back = again.lps_from_index.rows();
    for r in 0..3 {
        for c in 0..4 {
            assert!((back[r][c] - rows[r][c]).abs() <= 1e-9 * reach, "[{r}][{c}]: {back:?} for {rows:?}");
        }
    }
});
