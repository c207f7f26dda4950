//! The panes of the layout ([`crate::gui::layout`]) drawn by [`egui_tiles`]: each pane a title (double-click:
//! maximise or restore) over its view.

use eframe::egui;

use super::{slices, view3d};
use crate::gui::layout::{self, Pane, SliceAxis};
use crate::gui::{Command, Ready};

/// What the panes draw with: the window's state, the renderer's wgpu state and this frame's slice planes.
struct Panes<'a> {
    ready: &'a mut Ready,
    render_state: Option<&'a eframe::egui_wgpu::RenderState>,
    planes: [warpbench_gpu::SlicePlane; 3],
}

impl egui_tiles::Behavior<Pane> for Panes<'_> {
    fn pane_ui(&mut self, ui: &mut egui::Ui, _tile_id: egui_tiles::TileId, pane: &mut Pane) -> egui_tiles::UiResponse {
        let title = ui
            .add(
                egui::Label::new(egui::RichText::new(pane.title()).strong())
                    .selectable(false)
                    .sense(egui::Sense::click()),
            )
            .on_hover_text("Double-click to maximise this view, again to restore the layout");
        if title.double_clicked() {
            self.ready.apply(Command::ToggleMaximise(*pane));
        }
        match *pane {
            Pane::View3d => view3d::view3d(ui, self.ready, self.render_state),
            Pane::Slice(axis) => slices::slice_pane(ui, self.ready, axis, &self.planes, None),
            Pane::Compare(side) => slices::slice_pane(ui, self.ready, SliceAxis::Axial, &self.planes, Some(side)),
        }
        egui_tiles::UiResponse::None
    }

    fn tab_title_for_pane(&mut self, pane: &Pane) -> egui::WidgetText {
        pane.title().into()
    }

    fn simplification_options(&self) -> egui_tiles::SimplificationOptions {
        egui_tiles::SimplificationOptions { all_panes_must_have_tabs: false, ..Default::default() }
    }
}

/// Draws the views in the window's central area, in the panes of the layout the window is in.
pub fn show(ui: &mut egui::Ui, ready: &mut Ready, render_state: Option<&eframe::egui_wgpu::RenderState>) {
    let key = (ready.view.layout, ready.view.maximised);
    let mut tree = match ready.view.tiles.take() {
        Some((k, tree)) if k == key => tree,
        _ => layout::tree(key.0, key.1),
    };
    ready.pointer.cursor = None;
    if !layout::panes(key.0, key.1).contains(&Pane::View3d)
        && let Some(rs) = render_state
        && let Err(e) = ready.render_slices(rs)
    {
        ready.fit.error = Some(format!("rendering: {e:#}"));
    }
    let planes = ready.slice_planes();
    egui::CentralPanel::default().show(ui, |ui| {
        let mut panes = Panes { ready, render_state, planes };
        tree.ui(&mut panes, ui);
    });
    ready.view.tiles = Some((key, tree));
}
