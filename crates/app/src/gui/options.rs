//! What the window opens with (from its command line, [`GuiArgs`]), and where it makes the control texture.

use std::path::PathBuf;

use warpbench_io::Part;

use crate::inputs::LandmarkSource;

/// What the window opens with.
#[derive(Clone, Debug, Default)]
pub struct GuiOptions {
    /// `None` (with `moving` `None`): the demo pair.
    pub fixed: Option<PathBuf>,
    pub moving: Option<PathBuf>,
    /// Which volume of `fixed` and of `moving` to read, when a file holds several (a frame, a DICOM series).
    pub parts: [Option<Part>; 2],
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

/// The window's options (no subcommand).
#[derive(Debug, clap::Args)]
pub struct GuiArgs {
    /// The fixed volume to open (with --moving).
    #[arg(long, requires = "moving")]
    pub fixed: Option<PathBuf>,
    /// The moving volume to open (with --fixed).
    #[arg(long, requires = "fixed")]
    pub moving: Option<PathBuf>,
    #[command(flatten)]
    pub parts: crate::args::PartArgs,
    /// Landmark pairs (BigWarp CSV or BigWarp JSON, also a BigWarp settings file) to open with them.
    #[arg(long, requires = "fixed")]
    pub landmarks: Option<PathBuf>,
    /// A saved session (.warpbench.json) to open: its volumes, landmarks and settings.
    #[arg(long, conflicts_with_all = ["fixed", "moving", "landmarks"])]
    pub session: Option<PathBuf>,
    /// Save a screenshot of the window here, then close (with --exit-after-frames).
    #[arg(long)]
    pub screenshot: Option<PathBuf>,
    /// Close the window after this many frames with the volumes shown, once they are fully rendered (smoke tests).
    #[arg(long)]
    pub exit_after_frames: Option<u32>,
    /// Write one tab-separated line per window frame here (seconds since the window opened, the phase, what the 3-D
    /// view shows, whether a pointer button was released, the frame's UI work in ms): for measuring the window.
    #[arg(long, value_name = "FILE")]
    pub frame_log: Option<PathBuf>,
}

impl From<GuiArgs> for GuiOptions {
    /// The window's options from its command line: a screenshot closes the window after 5 frames unless
    /// `--exit-after-frames` says otherwise.
    fn from(a: GuiArgs) -> Self {
        Self {
            fixed: a.fixed,
            moving: a.moving,
            parts: a.parts.parts(),
            landmarks: a.landmarks.map(LandmarkSource::Pairs),
            exit_after_frames: a.exit_after_frames.or(a.screenshot.is_some().then_some(5)),
            screenshot: a.screenshot,
            session: a.session,
            autosave: None,
            frame_log: a.frame_log,
        }
    }
}
