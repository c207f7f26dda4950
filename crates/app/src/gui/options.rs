//! What the window opens with, and where it makes the control texture.

use std::path::PathBuf;

use crate::inputs::LandmarkSource;

/// What the window opens with.
#[derive(Clone, Debug, Default)]
pub struct GuiOptions {
    /// `None` (with `moving` `None`): the demo pair.
    pub fixed: Option<PathBuf>,
    pub moving: Option<PathBuf>,
    pub landmarks: Option<LandmarkSource>,
    /// Save a screenshot of the window here after `exit_after_frames` frames with the pair shown and fully rendered,
    /// then close.
    pub screenshot: Option<PathBuf>,
    pub exit_after_frames: Option<u32>,
    /// A `.warpbench.json` session to open (its volumes, landmarks and settings); overrides the fields above.
    pub session: Option<PathBuf>,
    /// Where to autosave (`None`: [`crate::project::session::autosave_path`]).
    pub autosave: Option<PathBuf>,
    /// Write one line per frame here ([`super::frame_log`]).
    pub frame_log: Option<PathBuf>,
}

/// Where the window makes the control texture after a fit.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum ControlEval {
    /// A TPS or a B-spline on the GPU when the adapter is a real GPU; otherwise on the CPU (a CPU driver runs the
    /// compute pass slower than the solver's sampling on rayon).
    #[default]
    Auto,
    Cpu,
    /// A TPS or a B-spline on the GPU whatever the adapter (the linear methods on the CPU).
    Gpu,
}
