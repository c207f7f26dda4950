//! Any AFNI dataset gives `Ok` or `Err`, never a panic, a hang or an allocation the bytes do not back: as a volume
//! (its first sub-brick) whose samples fill its grid, and as a 3dQwarp warp whose vectors are finite, one per voxel.
//! The input is the dataset's two files in one: a little-endian u32, the `.HEAD`'s length, then the `.HEAD`, then the
//! `.BRIK` (named `.BRIK.gz` when it starts with gzip's magic bytes).
#![no_main]

use libfuzzer_sys::fuzz_target;
use warpbench_io::LoadOptions;
use warpbench_io::displacement::read_field_info;

fuzz_target!(|data: &[u8]| {
    let Some((len, rest)) = data.split_first_chunk::<4>() else { return };
    let len = (u32::from_le_bytes(*len) as usize).min(rest.len());
    let (head, brik) = rest.split_at(len);
    let dir = std::env::temp_dir().join(format!("fuzz-afni-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("a temporary folder");
    for old in ["x+orig.BRIK", "x+orig.BRIK.gz"] {
        let _ = std::fs::remove_file(dir.join(old));
    }
    let brik_name = if brik.starts_with(&[0x1f, 0x8b]) { "x+orig.BRIK.gz" } else { "x+orig.BRIK" };
    std::fs::write(dir.join("x+orig.HEAD"), head).expect("write");
    std::fs::write(dir.join(brik_name), brik).expect("write");
    let path = dir.join("x+orig.HEAD");
    let mut opts = LoadOptions::new().max_voxel_bytes(64 << 20);
    opts.frame = Some(0);
    if let Ok(v) = opts.open(&path) {
        assert_eq!(v.data.len(), v.dims.iter().product::<usize>(), "one sample per voxel");
    }
    if let Ok(read) = read_field_info(&path) {
        let f = &read.field;
        assert_eq!(f.displacements_lps.len(), f.dims.iter().product::<usize>(), "one vector per voxel");
        assert!(f.displacements_lps.iter().flatten().all(|v| v.is_finite()), "a vector that is not finite");
    }
});
