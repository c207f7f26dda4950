//! The side panel once a pair is shown: the settings only, in collapsible sections (the tools are in the toolbar
//! and the landmarks in their own panel): View, Volumes, Warp (the method, a displacement field under the landmarks,
//! the brush's settings and the synthetic deformation), Assist (the alignment, the worst pair, the leafer's
//! settings), Accuracy, and Files (session, landmarks, screenshot, export). The readers' warnings stay above the
//! sections. It returns what was asked for as [`Command`]s; only its own text fields (paths being typed) change in
//! place.

use eframe::egui;

use super::{Command, Ready, export, panels};

/// A section of the side panel: its title, and whether it is open when the window starts.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Section {
    View,
    Volumes,
    Warp,
    Assist,
    Accuracy,
    Files,
}

impl Section {
    pub const ALL: [Self; 6] = [Self::View, Self::Volumes, Self::Warp, Self::Assist, Self::Accuracy, Self::Files];

    #[must_use]
    pub fn title(self) -> &'static str {
        match self {
            Self::View => "View",
            Self::Volumes => "Volumes",
            Self::Warp => "Warp",
            Self::Assist => "Assist",
            Self::Accuracy => "Accuracy",
            Self::Files => "Files",
        }
    }

    /// View and Warp start open: what a session changes most; the others start closed so that the panel fits a
    /// 720-pixel-high window without scrolling.
    #[must_use]
    pub fn open_at_start(self) -> bool {
        matches!(self, Self::View | Self::Warp)
    }
}

/// Draws the side panel; returns the commands its widgets gave this frame.
pub fn side_panel(ui: &mut egui::Ui, ready: &mut Ready) -> Vec<Command> {
    let mut commands = Vec::new();
    egui::Panel::left("settings").resizable(true).default_size(270.0).show(ui, |ui| {
        egui::ScrollArea::vertical().show(ui, |ui| {
            ui.heading(ready.loaded.title.as_str());
            panels::volume_warnings_ui(ui, &ready.loaded.fixed, &ready.loaded.moving);
            for w in &ready.fit.warnings {
                ui.colored_label(egui::Color32::from_rgb(240, 200, 80), format!("Warning: {w}"));
            }
            for section in Section::ALL {
                egui::CollapsingHeader::new(section.title()).default_open(section.open_at_start()).show(ui, |ui| {
                    commands.extend(section_ui(ui, section, ready));
                });
            }
        });
    });
    commands
}

/// The widgets of one section.
fn section_ui(ui: &mut egui::Ui, section: Section, ready: &mut Ready) -> Vec<Command> {
    let mut commands = Vec::new();
    match section {
        Section::View => commands.extend(panels::view_ui(ui, &ready.document.settings)),
        Section::Volumes => commands.extend(panels::layers_ui(ui, &ready.document.layers)),
        Section::Warp => {
            commands.extend(panels::method_ui(ui, &ready.document.settings, ready.current_stiffness_choice()));
            ui.separator();
            commands.extend(
                super::files::field_ui(ui, &mut ready.files.fields, ready.document.field_path()).map(Command::File),
            );
            ui.separator();
            commands.extend(panels::brush_ui(ui, &ready.document.settings, ready.document.brush.len()));
            ui.separator();
            let problem = ready.procedural().err();
            commands.extend(panels::deformation_ui(ui, &ready.document.settings, problem.as_deref()));
        }
        Section::Assist => {
            commands.extend(panels::alignment_ui(ui, ready.document.start.as_ref(), ready.aligning()));
            // Closed by default, as the masks, so the Assist buttons stay in view.
            egui::CollapsingHeader::new("Starting transform from a file").id_salt("start file").show(ui, |ui| {
                commands.extend(super::files::start_ui(ui, &mut ready.files.fields).map(Command::File));
            });
            ui.separator();
            let last = ready.assist.refined.as_ref();
            let moved = last.is_some_and(|l| l.pairs != ready.fit_pairs().1);
            let masks = [
                (super::open::Side::Fixed, ready.document.fixed_mask.clone()),
                (super::open::Side::Moving, ready.document.moving_mask.clone()),
            ];
            let set: Vec<&str> = masks.iter().filter(|(_, m)| m.is_some()).map(|(side, _)| side.name()).collect();
            let title = if set.is_empty() { "Masks: none".to_owned() } else { format!("Masks: {}", set.join(", ")) };
            // Closed by default (the id keeps it open or closed as its title changes), so the button stays in view.
            egui::CollapsingHeader::new(title).id_salt("refine masks").show(ui, |ui| {
                for (side, mask) in masks {
                    let action = super::files::mask_ui(ui, &mut ready.files.fields, side, mask.as_deref());
                    commands.extend(action.map(Command::File));
                }
            });
            commands.extend(panels::intensity_ui(ui, &ready.document.settings, ready.refining(), last, moved));
            ui.separator();
            let has_loo = !super::landmark_table::loo_ranking(&ready.document.pairs, &ready.fit.pair_errors).is_empty();
            commands.extend(panels::worst_pair_ui(ui, has_loo));
            commands.extend(panels::leafer_ui(ui, ready.view.leafer));
        }
        Section::Accuracy => {
            commands.extend(
                super::landmark_table::accuracy_ui(ui, &ready.document.pairs, &ready.fit.pair_errors)
                    .map(Command::JumpTo),
            );
            panels::inverse_consistency_ui(ui, ready.fit.brush_consistency.as_ref());
        }
        Section::Files => {
            commands.extend(super::files::files_ui(ui, &mut ready.files.fields).map(Command::File));
            ui.separator();
            let asked = export::export_ui(ui, &mut ready.files.export_fields, ready.files.export.as_ref());
            commands.extend(asked.map(|(kind, out)| Command::Export(kind, out)));
            if let Some(m) = &ready.files.message {
                ui.label(m.as_str());
            }
        }
    }
    commands
}
