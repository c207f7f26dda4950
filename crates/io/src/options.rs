//! [`LoadOptions`]: the options builder behind every reader, with progress and cancellation.

use std::fmt;
use std::ops::ControlFlow;
use std::path::Path;

use crate::error::{Error, ErrorKind, Result};
use crate::volume::DEFAULT_MAX_VOXEL_BYTES;

/// One progress report: `done` of `total` units of `stage` (bytes, slices or files).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Progress {
    pub stage: &'static str,
    pub done: u64,
    pub total: u64,
}

impl Progress {
    /// Fraction complete in [0, 1].
    #[must_use]
    pub fn fraction(&self) -> f32 {
        if self.total == 0 { 1.0 } else { (self.done as f64 / self.total as f64).clamp(0.0, 1.0) as f32 }
    }
}

/// Which volume of a file or folder that holds several: one series of a DICOM folder, or one frame of a 4-D file
/// (a sub-brick of an AFNI dataset). Sessions keep it beside the path (as `{"series": UID}` or `{"frame": N}`), so that
/// the same volume is read again.
#[derive(Clone, Debug, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Part {
    /// The DICOM series with this SeriesInstanceUID.
    Series(String),
    /// The frame with this index (0-based), the t index of a 4-D file.
    Frame(usize),
}

/// A progress callback. Returning `ControlFlow::Break(())` cancels the load.
pub type ProgressFn<'a> = dyn FnMut(Progress) -> ControlFlow<()> + Send + 'a;

/// Options for reading a volume. `warpbench_io::open(p)` is `LoadOptions::new().open(p)`.
pub struct LoadOptions<'a> {
    /// For 4-D NIfTI: which frame (t index) to read. `None` fails on a 4-D file with more than one frame.
    pub frame: Option<usize>,
    /// For a DICOM folder with several series: which SeriesInstanceUID to read.
    pub series_instance_uid: Option<String>,
    /// Upper bound on decoded voxel bytes; checked before allocating.
    pub max_voxel_bytes: u64,
    progress: Option<Box<ProgressFn<'a>>>,
}

impl fmt::Debug for LoadOptions<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("LoadOptions")
            .field("frame", &self.frame)
            .field("series_instance_uid", &self.series_instance_uid)
            .field("max_voxel_bytes", &self.max_voxel_bytes)
            .field("progress", &self.progress.is_some())
            .finish()
    }
}

impl Default for LoadOptions<'_> {
    fn default() -> Self {
        Self::new()
    }
}

impl<'a> LoadOptions<'a> {
    #[must_use]
    pub fn new() -> Self {
        Self { frame: None, series_instance_uid: None, max_voxel_bytes: DEFAULT_MAX_VOXEL_BYTES, progress: None }
    }
    #[must_use]
    pub fn frame(mut self, t: usize) -> Self {
        self.frame = Some(t);
        self
    }
    #[must_use]
    pub fn series(mut self, uid: impl Into<String>) -> Self {
        self.series_instance_uid = Some(uid.into());
        self
    }
    /// Reads `part` of the file: [`Self::series`] or [`Self::frame`]; `None` changes nothing.
    #[must_use]
    pub fn part(self, part: Option<&Part>) -> Self {
        match part {
            None => self,
            Some(Part::Series(uid)) => self.series(uid.clone()),
            Some(Part::Frame(t)) => self.frame(*t),
        }
    }
    #[must_use]
    pub fn max_voxel_bytes(mut self, limit: u64) -> Self {
        self.max_voxel_bytes = limit;
        self
    }
    #[must_use]
    pub fn progress(mut self, f: impl FnMut(Progress) -> ControlFlow<()> + Send + 'a) -> Self {
        self.progress = Some(Box::new(f));
        self
    }

    /// Reports progress; returns `Err(Cancelled)` when the callback asks to stop.
    pub fn report(&mut self, path: &Path, stage: &'static str, done: u64, total: u64) -> Result<()> {
        if let Some(f) = self.progress.as_mut()
            && f(Progress { stage, done, total }).is_break()
        {
            return Err(Error::new(path, ErrorKind::Cancelled));
        }
        Ok(())
    }
}
