//! Helpers the test modules share.

use std::path::Path;

use warpbench_io::{LoadOptions, Volume, VoxelData};

/// The volume at `path`, frame `frame` of a 4-D file.
pub fn open_frame(path: &Path, frame: Option<usize>) -> warpbench_io::Result<Volume> {
    let mut opts = LoadOptions::new();
    opts.frame = frame;
    opts.open(path)
}

/// Every sample as f64, in the volume's order (i fastest).
pub fn samples_f64(data: &VoxelData) -> Vec<f64> {
    (0..data.len()).map(|i| data.get_f64(i)).collect()
}
