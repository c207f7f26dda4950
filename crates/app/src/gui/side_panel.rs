//! The side panel once a pair is shown: history and camera buttons, the view and warp settings, the looks, the
//! procedural deformation, adding
//! pairs, the landmark table and its warnings, the accuracy panel with the attention lens, the leafer, the brush,
//! files and export. It returns what was asked for
//! as [`Command`]s; only its own text fields (paths being typed) change in place.

use eframe::egui;

use super::{Command, Placing, Ready, export, panels};

/// Draws the side panel; returns the commands its widgets gave this frame.
pub fn side_panel(ui: &mut egui::Ui, ready: &mut Ready) -> Vec<Command> {
    let mut commands = Vec::new();
    egui::Panel::left("settings").resizable(true).default_size(260.0).show(ui, |ui| {
        egui::ScrollArea::vertical().show(ui, |ui| {
            ui.heading(ready.loaded.title.as_str());
            ui.horizontal(|ui| {
                let undo = egui::Button::new("Undo");
                if ui.add_enabled(ready.history.can_undo(), undo).on_hover_text("Ctrl+Z").clicked() {
                    commands.push(Command::Undo);
                }
                let redo = egui::Button::new("Redo");
                if ui.add_enabled(ready.history.can_redo(), redo).on_hover_text("Ctrl+Shift+Z").clicked() {
                    commands.push(Command::Redo);
                }
                if ui.button("Reset camera").on_hover_text("R").clicked() {
                    commands.push(Command::ResetCamera);
                }
            });
            commands.extend(panels::layout_ui(ui, ready.view.layout));
            commands.extend(panels::settings_ui(ui, &ready.document.settings, ready.current_stiffness_choice()));
            ui.separator();
            commands.extend(panels::layers_ui(ui, &ready.document.layers));
            panels::volume_warnings_ui(ui, &ready.loaded.fixed, &ready.loaded.moving);
            ui.separator();
            ui.horizontal(|ui| {
                let adding = ready.placing() != Placing::Idle;
                if ui.selectable_label(adding, "Add pair").on_hover_text("Space; Esc cancels").clicked() {
                    commands.push(Command::ToggleAdding);
                }
                match ready.placing() {
                    Placing::Idle => ui.label(""),
                    Placing::Source => ui.label("click the point on the moving volume"),
                    Placing::Target { .. } => ui.label("click its partner on the fixed volume"),
                };
            });
            commands.extend(super::landmark_table::landmarks_ui(
                ui,
                &ready.document.pairs,
                &ready.fit.pair_errors,
                ready.pointer.selected,
            ));
            for w in &ready.fit.warnings {
                ui.colored_label(egui::Color32::from_rgb(240, 200, 80), format!("Warning: {w}"));
            }
            ui.separator();
            commands.extend(panels::alignment_ui(ui, ready.document.start.as_ref(), ready.aligning()));
            let can_refine = (ready.placing() == Placing::Idle).then_some(ready.pointer.selected).flatten();
            commands.extend(panels::refine_ui(ui, can_refine));
            ui.separator();
            commands.extend(
                super::landmark_table::accuracy_ui(ui, &ready.document.pairs, &ready.fit.pair_errors)
                    .map(Command::JumpTo),
            );
            commands.extend(super::landmark_table::outliers_ui(ui, ready.fit_pairs().0.len()));
            panels::inverse_consistency_ui(ui, ready.fit.brush_consistency.as_ref());
            let has_loo = !super::landmark_table::loo_ranking(&ready.document.pairs, &ready.fit.pair_errors).is_empty();
            commands.extend(panels::attention_ui(ui, ready.view.attention.is_on(), has_loo));
            ui.separator();
            commands.extend(panels::leafer_ui(ui, ready.view.leafer));
            ui.separator();
            // The tools that deform what is shown come after the landmarks, the registration's own work.
            let problem = ready.procedural().err();
            commands.extend(panels::deformation_ui(ui, &ready.document.settings, problem.as_deref()));
            ui.separator();
            let tool = (ready.pointer.interaction.sculpting(), ready.document.brush.len());
            commands.extend(panels::brush_ui(ui, &ready.document.settings, tool));
            ui.separator();
            commands.extend(
                super::files::files_ui(ui, &mut ready.files.fields, ready.document.field.as_deref()).map(Command::File),
            );
            ui.separator();
            let asked = export::export_ui(ui, &mut ready.files.export_fields, ready.files.export.as_ref());
            commands.extend(asked.map(|(kind, out)| Command::Export(kind, out)));
            if let Some(m) = &ready.files.message {
                ui.label(m.as_str());
            }
        });
    });
    commands
}
