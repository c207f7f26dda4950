//! The 3-D view's and the slices' images as egui shows them, and what must be rendered again: on a GPU a changed
//! view is drawn again at once; on a CPU driver it is drawn reduced and then refined band by band ([`super::pacing`]).

use super::pacing::RefineJob;
use super::viewer::Shown;

/// Where the 3-D view's image stands. Only the window's rendering ([`super::rendering`]: `render`, `refine_band`,
/// `invalidate_view`) moves it from one state to the next.
#[derive(Debug)]
pub(crate) enum ViewImage {
    /// Must be rendered again (the camera, the warp or a setting changed); `full_shown`: the image still shown until
    /// then is a full-quality one.
    Stale { full_shown: bool },
    /// Shown at the interaction rate and size; a full one is to follow.
    Reduced,
    /// On a CPU driver, the full view being rendered band by band on a thread ([`pacing`]) while the reduced one is
    /// shown.
    Refining(RefineJob),
    /// Shown at full quality and size.
    Full,
}

impl ViewImage {
    /// Whether the image shown is the full-quality one.
    pub(crate) fn full_shown(&self) -> bool {
        match self {
            Self::Stale { full_shown } => *full_shown,
            Self::Full => true,
            Self::Reduced | Self::Refining(_) => false,
        }
    }
}

/// The 3-D view's and the slices' images as egui shows them, and what needs rendering again.
#[derive(Debug)]
pub(crate) struct Images {
    pub(crate) view: Option<Shown>,
    pub(crate) view_state: ViewImage,
    /// How many 3-D views have been shown: what the 3-D view's overlay follows.
    pub(crate) view_generation: u64,
    pub(crate) slices: [Option<Shown>; 3],
    /// The axial plane with the fixed volume alone and the warped moving volume alone, for the side-by-side layout.
    pub(crate) compare: [Option<Shown>; 2],
    pub(crate) slices_dirty: bool,
    /// Measured cost of the 3-D view on a CPU driver (ms per pixel, full quality), for the interaction size and the
    /// bands.
    pub(crate) view_ms_per_px: Option<f64>,
}

impl Default for Images {
    fn default() -> Self {
        Self {
            view: None,
            view_state: ViewImage::Stale { full_shown: true },
            view_generation: 0,
            slices: [None, None, None],
            compare: [None, None],
            slices_dirty: true,
            view_ms_per_px: None,
        }
    }
}
