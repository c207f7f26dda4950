//! Helpers the test modules share.

use std::path::Path;

use nalgebra::{Matrix3, Vector3};
use serde_json::Value;
use warpbench_io::geometry::{Index, Lps, Transform};
use warpbench_io::{GeometrySource, LoadOptions, Volume, VoxelData};

/// The volume at `path`, frame `frame` of a 4-D file.
pub fn open_frame(path: &Path, frame: Option<usize>) -> warpbench_io::Result<Volume> {
    let mut opts = LoadOptions::new();
    opts.frame = frame;
    opts.open(path)
}

/// A JSON array of numbers (a reference file's), as f64.
pub fn numbers(v: &Value) -> Vec<f64> {
    v.as_array().expect("array").iter().map(|x| x.as_f64().expect("number")).collect()
}

/// Every sample as f64, in the volume's order (i fastest).
pub fn samples_f64(data: &VoxelData) -> Vec<f64> {
    (0..data.len()).map(|i| data.get_f64(i)).collect()
}

/// An oblique, anisotropic grid of either handedness, away from the origin.
pub fn oblique_grid(handed: f64) -> Transform<Lps, Index> {
    let (c, s) = (0.4f64.cos(), 0.4f64.sin());
    let rotation = Matrix3::new(c, -s, 0.0, s * 0.9, c * 0.9, -0.436, s * 0.436, c * 0.436, 0.9);
    let linear = rotation * Matrix3::from_diagonal(&Vector3::new(0.8, 1.7 * handed, 3.1));
    Transform::from_linear_translation(linear, [-81.25, 112.5, -40.0])
}

/// A 6 × 5 × 4 volume of each sample type (u8, i16, u16, f32) on [`oblique_grid`], right- and left-handed in turn,
/// with values over much of each type's range.
pub fn sample_volumes() -> Vec<Volume> {
    let dims = [6, 5, 4];
    let n = 120;
    let data = [
        VoxelData::U8((0..n).map(|i| (i * 37 % 256) as u8).collect()),
        VoxelData::I16((0..n).map(|i| (i as i16 - 60) * 541).collect()),
        VoxelData::U16((0..n).map(|i| (i * 547) as u16).collect()),
        VoxelData::F32((0..n).map(|i| (i as f32 - 33.3).powi(3) * 1e-3).collect()),
    ];
    data.into_iter()
        .zip([1.0, -1.0, 1.0, -1.0])
        .map(|(d, handed)| {
            Volume::new(std::path::Path::new("x"), dims, d, oblique_grid(handed), GeometrySource::Assumed)
                .expect("volume")
        })
        .collect()
}
