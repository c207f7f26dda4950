//! The parts of the window's state besides the document and the fit ([`super::Ready`]): what the views show, what
//! the pointer does, and the assistants' jobs.

use warpbench_gpu::OrbitCamera;

use super::images::Images;
use super::options::ControlEval;
use super::tool::Interaction;
use super::{alignment, attention, hover, intensity, leafer, pacing, placement, suggestion};
use crate::project::document::FitPoints;

/// What the views show: the camera, the slice positions, the rendered images and their pacing, and the view tools
/// that change only the picture (never the document).
#[derive(Debug)]
pub struct View {
    pub camera: OrbitCamera,
    /// Slice positions (mm along S, P, L through the fixed grid).
    pub slice_mm: [f64; 3],
    /// The rendered images and what needs rendering again.
    pub(super) images: Images,
    pub last_render_ms: f64,
    /// The window's frame rate, for the status bar.
    pub(super) frame_rate: pacing::FrameRate,
    /// Whether the 3-D view pulses the attention lens about the selected pair ([`attention`]).
    pub attention: attention::Attention,
    /// Whether the 3-D view opens a volume with the leafer ([`leafer`]).
    pub leafer: leafer::Leafer,
    /// Where the control texture is made.
    pub control_eval: ControlEval,
    /// The pick under the pointer resting on the 3-D view, for the status bar's read-out ([`hover`]).
    pub hover: hover::HoverPick,
    /// Each slice's warp overlay, kept until the warp, the plane or the choice changes ([`super::overlay`]).
    pub overlays: [Option<super::overlay::SliceOverlay>; 3],
    /// The 3-D view's warp overlay, kept until the warp, the camera, the view's size or the choice changes.
    pub view_overlay: Option<super::overlay::ViewOverlay>,
    /// How the views share the window (saved in the session).
    pub layout: crate::settings::Layout,
    /// The pane shown alone, if one is maximised.
    pub maximised: Option<super::layout::Pane>,
    /// The landmark panel's sorting, filter, colour threshold and marked rows.
    pub landmarks: super::landmark_rows::LandmarkPanel,
    /// The panes' tiles, made for the layout and the maximised pane they hold.
    pub(super) tiles: Option<(PaneKey, egui_tiles::Tree<super::layout::Pane>)>,
    /// The views' history and the named views ([`super::places`]).
    pub places: super::places::Places,
}

/// What the panes' tiles were made for: the layout and the maximised pane.
pub(super) type PaneKey = (crate::settings::Layout, Option<super::layout::Pane>);

impl View {
    /// The views of a pair whose fixed volume fills `camera`, with the slices through `slice_mm`.
    #[must_use]
    pub fn new(camera: OrbitCamera, slice_mm: [f64; 3]) -> Self {
        Self {
            camera,
            slice_mm,
            images: Images::default(),
            last_render_ms: 0.0,
            frame_rate: pacing::FrameRate::default(),
            attention: attention::Attention::default(),
            leafer: leafer::Leafer::default(),
            control_eval: ControlEval::default(),
            hover: hover::HoverPick::default(),
            overlays: [None, None, None],
            view_overlay: None,
            layout: crate::settings::Layout::FourUp,
            maximised: None,
            landmarks: super::landmark_rows::LandmarkPanel::default(),
            tiles: None,
            places: super::places::Places::default(),
        }
    }
}

/// What the pointer is doing in the views and what it is over.
#[derive(Debug, Default)]
pub struct Pointer {
    /// The tool's state ([`super::Ready::placing`], [`super::Ready::drag`]).
    pub(super) interaction: Interaction,
    /// What the pointer is over in a slice view (the fixed point and the moving point shown there), for the status
    /// bar; a click there stores exactly these points ([`placement`]).
    pub cursor: Option<placement::Cursor>,
    /// Why the last click or drag did not place its point (outside its volume), shown in the status bar until the
    /// next point is placed.
    pub notice: Option<String>,
    /// The pair selected in the table or by clicking its glyph.
    pub selected: Option<usize>,
}

/// The assistants' state: Auto-align's job, the refinement by intensities, the suggested targets' images, and the last
/// automatic stiffness.
#[derive(Debug, Default)]
pub struct Assist {
    /// Auto-align running on its thread ([`alignment`]); its result becomes the document's starting transform.
    pub(super) aligning: Option<alignment::AlignJob>,
    /// Refine by intensities running on its thread ([`intensity`]); its result becomes the document's field.
    pub(super) refining: Option<intensity::IntensityJob>,
    /// The last refinement and the pairs it was made on: the Assist section offers to run it again once they moved.
    pub refined: Option<intensity::RefinedOn>,
    /// Where refinements write their fields: beside the autosave.
    pub refined_dir: std::path::PathBuf,
    /// The images the suggested targets' search reads ([`suggestion`]), made when first needed.
    pub(super) matching: suggestion::Matching,
    /// The last automatic stiffness ([`super::Command::AutoStiffness`]) with the pairs it was chosen on: shown by the slider
    /// while the stiffness and the pairs are still those.
    pub stiffness_choice: Option<StiffnessChoiceOn>,
}

/// A stiffness chosen by the leave-one-out error ([`warpbench_solver::stiffness`]) and the pairs (fixed, moving)
/// it was chosen on.
#[derive(Clone, Debug, PartialEq)]
pub struct StiffnessChoiceOn {
    pub choice: warpbench_solver::stiffness::StiffnessChoice,
    pub pairs: FitPoints,
}
