//! Any OME-Zarr folder given to the readers, of volumes and of displacement fields (its metadata parsed here, its
//! chunks decoded by `zarrs`), gives `Ok` or `Err`, never a panic, a hang or an unchecked allocation; a volume read has
//! one sample per voxel and a field one finite vector per voxel, each on an invertible grid. The input is a folder packed as entries `PATH\0BYTES` separated by `\n##\n` (`seed.sh` packs the
//! fixtures so); paths are kept inside the folder.
#![no_main]

use std::path::Path;

use libfuzzer_sys::fuzz_target;
use warpbench_io::{LoadOptions, ngff};

const SEPARATOR: &[u8] = b"\n##\n";

/// A path inside the folder: relative, plain names, at most 8 deep.
fn safe(path: &[u8]) -> Option<&str> {
    let path = std::str::from_utf8(path).ok()?;
    let parts: Vec<&str> = path.split('/').collect();
    let plain =
        |p: &&str| !p.is_empty() && *p != "." && *p != ".." && p.bytes().all(|b| b.is_ascii_graphic() && b != b'\\');
    (parts.len() <= 8 && parts.iter().all(plain)).then_some(path)
}

fuzz_target!(|data: &[u8]| {
    let Ok(dir) = tempfile::tempdir() else { return };
    let root = dir.path().join("fuzz.ome.zarr");
    let mut entries = 0;
    let mut rest = data;
    while !rest.is_empty() && entries < 64 {
        let end = rest.windows(SEPARATOR.len()).position(|w| w == SEPARATOR).unwrap_or(rest.len());
        let (entry, next) = rest.split_at(end);
        rest = next.get(SEPARATOR.len()..).unwrap_or_default();
        let Some(nul) = entry.iter().position(|&b| b == 0) else { continue };
        let Some(path) = safe(&entry[..nul]) else { continue };
        let file = root.join(path);
        if file.parent().is_some_and(|p| std::fs::create_dir_all(p).is_ok())
            && std::fs::write(&file, &entry[nul + 1..]).is_ok()
        {
            entries += 1;
        }
    }
    if !root.is_dir() {
        return;
    }
    // A small memory cap keeps the fuzzer from allocating what hostile metadata claims; frame 0 reads a 4-D image.
    let mut opts = LoadOptions::new().max_voxel_bytes(64 << 20).frame(0);
    if let Ok(volume) = ngff::read(Path::new(&root), &mut opts) {
        assert_eq!(volume.data.len(), volume.dims.iter().product::<usize>());
        assert!(volume.lps_from_index.inverse().is_some(), "{:?}", volume.lps_from_index);
    }
    // The same folder as a displacement field (OME-Zarr 0.6): one finite vector per voxel on an invertible grid.
    if let Ok((field, _)) = ngff::read_field_capped(Path::new(&root), 64 << 20) {
        assert_eq!(field.displacements_lps.len(), field.dims.iter().product::<usize>());
        assert!(field.lps_from_index.inverse().is_some(), "{:?}", field.lps_from_index);
        assert!(field.displacements_lps.iter().flatten().all(|v| v.is_finite()));
    }
});
