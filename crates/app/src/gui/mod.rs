//! The workbench window (eframe/egui): the fixed and the deformed moving volume in a 3-D view and three slice views
//! of the fixed grid, rendered by `warpbench_gpu` on eframe's own wgpu device, with the landmark glyphs, the warp
//! method and the view settings in a side panel.
//!
//! Bare `warpbench` opens the demo pair ([`crate::project::demo`]). Loading runs on a worker thread; the window stays responsive
//! and shows an error (naming the file) instead of the views when it fails. Frames are rendered only when something
//! changed, at the interaction sample rate while the camera is being dragged ([`warpbench_gpu::Quality`]).
//!
//! How it is built:
//! - [`app`]: the eframe app ([`Workbench`]): loading ([`load`](mod@load)), the volume reads and dialogs ([`open`]), the
//!   autosave ([`autosave`]) and, once a pair is shown, the frame: keyboard, [`side_panel`], [`status`], the
//!   [`views`], then the undo step.
//! - [`crate::project`] holds what the user edits ([`crate::project::document::Document`]); [`history`] snapshots it, [`crate::project::session`] saves it
//!   with the camera and slices.
//! - [`commands`]: every change as a [`Command`]; [`Ready::apply`] is the one place that carries them out.
//! - [`interaction`]: what the pointer is doing ([`Interaction`]: adding a pair, dragging a point), and the picking
//!   and dragging that move it.
//! - `images`: the rendered images and the 3-D view's state (stale, reduced, refining, full), with [`pacing`].
//! - [`views`]: the slice strip and the 3-D view; [`panels`]: the side panel's sections; [`viewer`]: the GPU side.
//! - [`places`]: where the views look, their history (Back, Forward) and the named views; [`view_moves`] moves
//!   the views there.

pub mod alignment;
pub mod app;
pub mod attention;
pub mod autosave;
pub mod commands;
pub mod dialog;
pub mod export;
pub mod file_actions;
pub mod files;
pub mod frame_log;
pub mod history;
pub mod hover;
mod images;
pub mod intensity;
pub mod interaction;
pub mod landmark_panel;
pub mod landmark_rows;
pub mod landmark_table;
pub mod layout;
pub mod leafer;
pub mod load;
pub mod open;
pub mod options;
pub mod overlay;
pub mod pacing;
pub mod panels;
pub mod placement;
pub mod places;
pub mod ready;
mod rendering;
pub mod side;
pub mod side_panel;
pub mod slice_habits;
pub mod state;
pub mod status;
pub mod suggestion;
pub mod tool;
pub mod toolbar;
pub mod view_moves;
pub mod viewer;
pub mod views;

use anyhow::anyhow;
use eframe::egui;

pub use crate::fit::{Fitted, fit_warp, fit_warp_on_gpu, gpu_evaluates};
pub use crate::project::fitter::Fitter;
pub use app::Workbench;
pub use commands::Command;
pub use load::{Loaded, LoadedPair, Opened, load};
pub use options::{ControlEval, GuiArgs, GuiOptions};
pub use ready::Ready;
pub use state::{Assist, Pointer, StiffnessChoiceOn, View};
pub use tool::{DragPoint, DragView, End, GRAB_RADIUS, Interaction, Placing, SLICE_SLAB_MM, SculptDrag};

pub use crate::project::document::FitPoints;

/// Opens the window and runs until it is closed.
pub fn run(opts: GuiOptions) -> anyhow::Result<()> {
    let frame_log = opts.frame_log.as_deref().map(frame_log::FrameLog::create).transpose()?;
    let native = eframe::NativeOptions {
        viewport: egui::ViewportBuilder::default().with_inner_size([1280.0, 860.0]).with_title("warpbench"),
        renderer: eframe::Renderer::Wgpu,
        wgpu_options: wgpu_options(),
        ..Default::default()
    };
    eframe::run_native(
        "warpbench",
        native,
        Box::new(move |cc| Ok(Box::new(Workbench::new(cc, opts).with_frame_log(frame_log)))),
    )
    .map_err(|e| anyhow!("the window: {e}"))
}

/// eframe's wgpu set-up with the adapter's own limits and the optional features the renderer uses (the defaults
/// are WebGL2 limits on GL, without compute).
#[must_use]
pub fn wgpu_options() -> eframe::egui_wgpu::WgpuConfiguration {
    use eframe::egui_wgpu::{WgpuSetup, WgpuSetupCreateNew};
    use eframe::wgpu;
    let device_descriptor = std::sync::Arc::new(|adapter: &wgpu::Adapter| wgpu::DeviceDescriptor {
        label: Some("warpbench"),
        required_features: adapter.features() & warpbench_gpu::RaycastRenderer::OPTIONAL_FEATURES,
        required_limits: adapter.limits(),
        ..Default::default()
    });
    eframe::egui_wgpu::WgpuConfiguration {
        wgpu_setup: WgpuSetup::CreateNew(WgpuSetupCreateNew {
            device_descriptor,
            ..WgpuSetupCreateNew::without_display_handle()
        }),
        ..Default::default()
    }
}
