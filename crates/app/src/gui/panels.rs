//! The side panel's sections, each a `*_ui(ui, …)` function over plain state that returns what it asks for as
//! [`Command`]s, so each can be tested alone. Every widget carries a label that egui_kittest (and screen readers) can
//! find.

use eframe::egui;
use warpbench_io::landmarks::LandmarkPair;

use super::Command;
use super::leafer::{DEFAULT_ANGLE_DEG, Leafer, MAX_ANGLE_DEG};
use super::open::Side;
use crate::procedural::ProceduralSpec;
use crate::project::document::{
    BRUSH_MAX_RADIUS_MM, Look, OBLIQUE_MAX_DEG, Oblique, PROCEDURAL_MAX_MM, StartingTransform, ViewSettings,
};
use crate::settings::{Blend, MethodKind, Preset, Probe, ProceduralKind, Shading};

/// A slice view's oblique controls (labelled "NAME oblique", "NAME tilt", "NAME spin"). Returns whether they
/// changed.
pub fn oblique_ui(ui: &mut egui::Ui, name: &str, o: &mut Oblique) -> bool {
    let before = *o;
    ui.horizontal_wrapped(|ui| {
        ui.spacing_mut().slider_width = (ui.available_width() - 110.0).max(40.0);
        let on = ui.checkbox(&mut o.on, "oblique");
        let on_name = format!("{name} oblique");
        on.widget_info(|| egui::WidgetInfo::selected(egui::Role::CheckBox, true, o.on, &on_name));
        if o.on {
            for (value, what) in [(&mut o.tilt_deg, "tilt"), (&mut o.spin_deg, "spin")] {
                let range = -OBLIQUE_MAX_DEG..=OBLIQUE_MAX_DEG;
                let slider = ui.add(egui::Slider::new(value, range).suffix(" deg").text(what));
                let label = format!("{name} {what}");
                slider.widget_info(|| egui::WidgetInfo::labeled(egui::Role::Slider, true, &label));
            }
        }
    });
    *o != before
}

/// The stiffness slider's largest λ, mm: the largest the automatic choice tries.
pub const STIFFNESS_MAX: f64 = warpbench_solver::stiffness::LAMBDA_MAX;

/// Blend, shading, sample rate, warp method (with "Auto" by the stiffness slider, and the last automatic choice
/// while it holds) and picking; the settings as changed, if they were, or [`Command::AutoStiffness`].
pub fn settings_ui(
    ui: &mut egui::Ui,
    settings: &ViewSettings,
    stiffness_choice: Option<&warpbench_solver::stiffness::StiffnessChoice>,
) -> Option<Command> {
    let s = &mut settings.clone();
    let mut auto = false;
    ui.label("View");
    choice_ui(ui, "Blend mode", &mut s.blend, Blend::ALL);
    match s.blend {
        Blend::Mix => {
            ui.add(egui::Slider::new(&mut s.mix_weight, 0.0..=1.0).text("Moving weight"));
        }
        Blend::Checkerboard => {
            ui.add(egui::Slider::new(&mut s.checker_mm, 2.0..=60.0).text("Checker cell (mm)"));
        }
        _ => {}
    }
    choice_ui(ui, "Shading", &mut s.shading, Shading::ALL);
    ui.add(egui::Slider::new(&mut s.samples_per_voxel, 0.25..=4.0).logarithmic(true).text("Samples per voxel"));
    ui.horizontal(|ui| {
        ui.checkbox(&mut s.show_landmarks, "Show landmarks");
        ui.checkbox(&mut s.follow_pair, "Follow the pair being edited")
            .on_hover_text("Centre the slices on a pair when it is added, moved or selected");
    });
    ui.separator();
    ui.label("Warp");
    choice_ui(ui, "Method", &mut s.method, MethodKind::ALL);
    match s.method {
        MethodKind::Tps => {
            ui.horizontal(|ui| {
                let slider = egui::Slider::new(&mut s.stiffness, 0.0..=STIFFNESS_MAX)
                    .logarithmic(true)
                    .smallest_positive(0.01)
                    .text("Stiffness (lambda)");
                ui.add(slider);
                let button = ui.button("Auto").on_hover_text("choose lambda by the pairs' leave-one-out error");
                auto = button.clicked();
            });
            if let Some(c) = stiffness_choice {
                ui.label(format!(
                    "Auto: leave-one-out RMS {:.2} mm ({:.2} mm at lambda 0) over {} pairs",
                    c.loo_rms_mm, c.loo_rms_interpolating_mm, c.pairs
                ));
            }
        }
        MethodKind::BSpline => {
            ui.add(egui::Slider::new(&mut s.bspline_levels, 1..=6).text("B-spline levels"));
        }
        _ => {}
    }
    ui.add(egui::Slider::new(&mut s.grid_n, 8..=128).text("Control texture texels"));
    ui.separator();
    ui.label("Picking (3-D view)");
    let probe_before = s.pick_probe;
    choice_ui(ui, "Pick probe", &mut s.pick_probe, Probe::ALL);
    if s.pick_probe != probe_before {
        s.pick_threshold = s.pick_probe.default_threshold();
    }
    ui.add(egui::Slider::new(&mut s.pick_threshold, s.pick_probe.threshold_range()).text("Pick threshold"));
    if auto {
        return Some(Command::AutoStiffness);
    }
    (s != settings).then(|| Command::SetSettings(s.clone()))
}

/// The procedural deformation of the moving volume ([`crate::procedural`]): on or off ("Deform the moving volume"),
/// its kind ("Deformation"), amplitude ("Deformation amplitude (mm)") and seed ("Deformation seed"); `problem` is why
/// the current one cannot be drawn (an amplitude the kind cannot take over this volume). The settings as changed, if
/// they were.
pub fn deformation_ui(ui: &mut egui::Ui, settings: &ViewSettings, problem: Option<&str>) -> Option<Command> {
    let s = &mut settings.clone();
    ui.label("Synthetic deformation (view only)");
    let mut on = s.procedural.is_some();
    ui.checkbox(&mut on, "Deform the moving volume")
        .on_hover_text("eval's known warps, computed in the shader; exports use the volume as opened");
    if on != s.procedural.is_some() {
        s.procedural = on.then(ProceduralSpec::default);
    }
    if let Some(p) = &mut s.procedural {
        choice_ui(ui, "Deformation", &mut p.kind, ProceduralKind::ALL);
        // Clamping only edits: showing the panel never changes the document.
        let amplitude =
            egui::Slider::new(&mut p.amplitude_mm, 0.0..=PROCEDURAL_MAX_MM).clamping(egui::SliderClamping::Edits);
        ui.add(amplitude.text("Deformation amplitude (mm)"));
        ui.horizontal(|ui| {
            let seed = ui.add(egui::DragValue::new(&mut p.seed).range(0..=u64::from(u32::MAX)));
            seed.widget_info(|| egui::WidgetInfo::labeled(egui::Role::SpinButton, true, "Deformation seed"));
            ui.label("seed");
        });
        if let Some(problem) = problem {
            ui.colored_label(egui::Color32::from_rgb(240, 200, 80), format!("Not drawn: {problem}"));
        }
    }
    (s != settings).then(|| Command::SetSettings(s.clone()))
}

/// A combo box labelled `label` over `all`, each entry shown by its name.
pub fn choice_ui<T: Copy + PartialEq + std::fmt::Display>(ui: &mut egui::Ui, label: &str, value: &mut T, all: &[T]) {
    egui::ComboBox::from_label(label).selected_text(value.to_string()).show_ui(ui, |ui| {
        for &c in all {
            ui.selectable_value(value, c, c.to_string());
        }
    });
}

/// Per volume: visibility, transfer-function preset and window; the looks as changed, if they were.
pub fn layers_ui(ui: &mut egui::Ui, looks: &[Look; 2]) -> Option<Command> {
    let mut changed = false;
    let mut edited = *looks;
    for (name, layer) in ["Fixed", "Moving"].into_iter().zip(&mut edited) {
        ui.horizontal(|ui| {
            changed |= ui.checkbox(&mut layer.visible, format!("{name} visible")).changed();
        });
        let shown = layer.preset;
        choice_ui(ui, &format!("{name} preset"), &mut layer.preset, Preset::ALL);
        if layer.preset != shown {
            if let Some(w) = layer.preset.gpu().default_window() {
                *layer = Look { visible: layer.visible, ..Look::new(layer.preset, w) };
            }
            changed = true;
        }
        let (mut low, mut high) = (layer.window_low, layer.window_high);
        let span = (high - low).abs().max(1.0);
        let range = (low - span)..=(high + span);
        changed |= ui.add(egui::Slider::new(&mut low, range.clone()).text(format!("{name} window low"))).changed();
        changed |= ui.add(egui::Slider::new(&mut high, range).text(format!("{name} window high"))).changed();
        if high > low {
            (layer.window_low, layer.window_high) = (low, high);
        }
    }
    changed.then_some(Command::SetLooks(edited))
}

/// What the readers found suspicious in the volumes (implausible spacings, a NIfTI sform and qform that disagree,
/// uneven DICOM slices), one line each, named by side; nothing when there is nothing to say.
pub fn volume_warnings_ui(ui: &mut egui::Ui, fixed: &warpbench_io::Volume, moving: &warpbench_io::Volume) {
    let warnings: Vec<String> = [("fixed", fixed), ("moving", moving)]
        .into_iter()
        .flat_map(|(side, v)| v.metadata.warnings.iter().map(move |w| format!("The {side} volume: {w}")))
        .collect();
    if warnings.is_empty() {
        return;
    }
    ui.separator();
    for w in warnings {
        ui.colored_label(egui::Color32::from_rgb(240, 200, 80), w);
    }
}

/// The attention lens ([`super::attention`]): "Pulse the selected pair" (P) switches the 3-D view's pulsing lens
/// about the selected pair on or off; "Show the worst pair" (W) selects the pair with the largest leave-one-out
/// error, centres the views on it and pulses there (offered once there are leave-one-out errors).
pub fn attention_ui(ui: &mut egui::Ui, pulsing: bool, has_loo: bool) -> Option<Command> {
    let mut command = None;
    ui.horizontal_wrapped(|ui| {
        let mut on = pulsing;
        if ui.checkbox(&mut on, "Pulse the selected pair").on_hover_text("P; a lens in the 3-D view only").changed() {
            command = Some(Command::TogglePulse);
        }
        let worst = egui::Button::new("Show the worst pair");
        if ui.add_enabled(has_loo, worst).on_hover_text("W").clicked() {
            command = Some(Command::ShowWorstPair);
        }
    });
    command
}

/// The leafer ([`super::leafer`]): "Open with a leafer" opens the chosen volume ("Leafer on the fixed volume" /
/// "Leafer on the moving volume") in the 3-D view by "Leafer opening (deg)" on each side of the cut through the
/// crosshair along the line of sight.
pub fn leafer_ui(ui: &mut egui::Ui, leafer: Leafer) -> Option<Command> {
    let mut edited = leafer;
    ui.label("Leafer (3-D view only)");
    let mut open = leafer.is_open();
    ui.checkbox(&mut open, "Open with a leafer")
        .on_hover_text("cut along the line of sight through the crosshair and opened like a book, to pick inside");
    if open != leafer.is_open() {
        edited = if open { Leafer::Open { side: Side::Moving, angle_deg: DEFAULT_ANGLE_DEG } } else { Leafer::Closed };
    }
    if let Leafer::Open { side, angle_deg } = &mut edited {
        ui.horizontal(|ui| {
            for (choice, label) in
                [(Side::Fixed, "Leafer on the fixed volume"), (Side::Moving, "Leafer on the moving volume")]
            {
                let shown = ui.radio(*side == choice, choice.name());
                shown.widget_info(|| egui::WidgetInfo::selected(egui::Role::RadioButton, true, *side == choice, label));
                if shown.clicked() {
                    *side = choice;
                }
            }
        });
        ui.add(egui::Slider::new(angle_deg, 0.0..=MAX_ANGLE_DEG).text("Leafer opening (deg)"));
    }
    (edited != leafer).then_some(Command::SetLeafer(edited))
}

/// The starting transform under the landmark warp ([`crate::start`]): "Auto-align" (rigid) and "Auto-align affine"
/// align the moving volume to the fixed one by mutual information ([`super::alignment`]), "Clear alignment" takes the
/// starting transform away; the line below says what it is, or that the alignment is running.
pub fn alignment_ui(ui: &mut egui::Ui, start: Option<&StartingTransform>, aligning: bool) -> Option<Command> {
    use warpbench_solver::align::AlignKind;
    let mut command = None;
    ui.horizontal(|ui| {
        let hover = "align the moving volume to the fixed one by mutual information (MR to CT works)";
        if ui.add_enabled(!aligning, egui::Button::new("Auto-align")).on_hover_text(hover).clicked() {
            command = Some(Command::AutoAlign(AlignKind::Rigid));
        }
        let affine = egui::Button::new("Auto-align affine");
        if ui.add_enabled(!aligning, affine).on_hover_text("rigid, then 12 parameters").clicked() {
            command = Some(Command::AutoAlign(AlignKind::Affine));
        }
        if ui.add_enabled(start.is_some() && !aligning, egui::Button::new("Clear alignment")).clicked() {
            command = Some(Command::SetStart(None));
        }
    });
    ui.label(match (aligning, start) {
        (true, _) => "Starting transform: aligning...".to_owned(),
        (false, Some(s)) => format!("Starting transform: {}; the landmarks refine it", s.origin),
        (false, None) => "Starting transform: none (the landmark warp alone)".to_owned(),
    });
    command
}

/// "Refine pair": the target search ([`super::suggestion`]) again for `selected`, the pair selected while no pair is
/// being added.
pub fn refine_ui(ui: &mut egui::Ui, selected: Option<usize>) -> Option<Command> {
    let mut command = None;
    ui.horizontal(|ui| {
        let hover = "search again for the selected pair's target around where the warp puts its moving point";
        if ui.add_enabled(selected.is_some(), egui::Button::new("Refine pair")).on_hover_text(hover).clicked() {
            command = selected.map(Command::RefinePair);
        }
        ui.label(match selected {
            Some(i) => format!("the target of pair {}", i + 1),
            None => "select a pair to refine its target".to_owned(),
        });
    });
    command
}

/// The displacement brush ([`warpbench_solver::brush`]): "Brush" (B) makes it the tool, "Brush radius (mm)" sets new
/// strokes' reach, "Clear the brush" removes every stroke, and once a stroke has settled the fitted inverse's
/// consistency is shown ("Brush inverse: …").
pub fn brush_ui(ui: &mut egui::Ui, settings: &ViewSettings, (sculpting, strokes): (bool, usize)) -> Option<Command> {
    let mut command = None;
    ui.label("Displacement brush (on top of the warp)");
    ui.horizontal(|ui| {
        let tool = ui.selectable_label(sculpting, "Brush").on_hover_text("B; drag the deformed moving volume");
        if tool.clicked() {
            command = Some(Command::ToggleSculpting);
        }
        if sculpting {
            ui.label("drag the moving volume in the 3-D view or a slice");
        } else {
            ui.label(format!("{strokes} strokes"));
        }
    });
    let mut radius = settings.brush_radius_mm;
    let slider = egui::Slider::new(&mut radius, 2.0..=BRUSH_MAX_RADIUS_MM).text("Brush radius (mm)");
    if ui.add(slider).changed() {
        command = Some(Command::SetSettings(ViewSettings { brush_radius_mm: radius, ..settings.clone() }));
    }
    if ui.add_enabled(strokes > 0, egui::Button::new("Clear the brush")).clicked() {
        command = Some(Command::ClearBrush);
    }
    command
}

/// The accuracy section's line on an inversion the warp needed (the brush's, fitted by scattered-data
/// interpolation): how closely the fitted inverse undoes the forward map.
pub fn inverse_consistency_ui(ui: &mut egui::Ui, consistency: Option<&crate::warp::InverseConsistency>) {
    if let Some(c) = consistency {
        ui.label(format!(
            "Brush inverse: its fit undoes the brush within {:.3} mm (max; rms {:.4} mm, {} points over its reach)",
            c.max_mm, c.rms_mm, c.points
        ));
    }
}

/// The paths typed into the side panel's file section.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct FileFields {
    pub session: String,
    pub landmarks: String,
    pub screenshot: String,
    /// A displacement field to put under the landmarks.
    pub field: String,
}

/// What the file section or the File menu asks for.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum FileAction {
    SaveSession(std::path::PathBuf),
    ImportLandmarks(std::path::PathBuf),
    ExportLandmarks(std::path::PathBuf),
    Screenshot(std::path::PathBuf),
    /// Export the warped moving volume (NIfTI `.nii`/`.nii.gz`), as `warpbench warp` does.
    ExportWarped(std::path::PathBuf),
    /// Export the displacement field (NIfTI), as `warpbench field` does.
    ExportField(std::path::PathBuf),
    /// Put the displacement field read from this file (ITK or ANTs NIfTI, Slicer NRRD) under the landmarks.
    UseField(std::path::PathBuf),
    /// Take the displacement field away.
    RemoveField,
}

/// Session, landmark, screenshot and displacement-field files: a path field and its buttons each; `field` is the
/// document's displacement field, if any.
pub fn files_ui(ui: &mut egui::Ui, fields: &mut FileFields, field: Option<&std::path::Path>) -> Option<FileAction> {
    let mut action = None;
    let path = |s: &str| std::path::PathBuf::from(s.trim());
    ui.label("Files");
    ui.add(egui::TextEdit::singleline(&mut fields.session).hint_text("session.warpbench.json"))
        .labelled_by(ui.label("Session file").id);
    if ui.add_enabled(!fields.session.trim().is_empty(), egui::Button::new("Save session")).clicked() {
        action = Some(FileAction::SaveSession(path(&fields.session)));
    }
    ui.add(egui::TextEdit::singleline(&mut fields.landmarks).hint_text("pairs.csv, pairs.json, or moving.fcsv"))
        .labelled_by(ui.label("Landmark file").id);
    ui.horizontal(|ui| {
        let enabled = !fields.landmarks.trim().is_empty();
        if ui.add_enabled(enabled, egui::Button::new("Import landmarks")).clicked() {
            action = Some(FileAction::ImportLandmarks(path(&fields.landmarks)));
        }
        if ui.add_enabled(enabled, egui::Button::new("Export landmarks")).clicked() {
            action = Some(FileAction::ExportLandmarks(path(&fields.landmarks)));
        }
    });
    ui.add(egui::TextEdit::singleline(&mut fields.screenshot).hint_text("screenshot.png"))
        .labelled_by(ui.label("Screenshot file").id);
    if ui.add_enabled(!fields.screenshot.trim().is_empty(), egui::Button::new("Save screenshot")).clicked() {
        action = Some(FileAction::Screenshot(path(&fields.screenshot)));
    }
    ui.add(egui::TextEdit::singleline(&mut fields.field).hint_text("field.nii.gz (ITK, ANTs) or field.nrrd (Slicer)"))
        .labelled_by(ui.label("Displacement field file").id);
    ui.horizontal(|ui| {
        if ui.add_enabled(!fields.field.trim().is_empty(), egui::Button::new("Use field under landmarks")).clicked() {
            action = Some(FileAction::UseField(path(&fields.field)));
        }
        if ui.add_enabled(field.is_some(), egui::Button::new("Remove field")).clicked() {
            action = Some(FileAction::RemoveField);
        }
    });
    if let Some(f) = field {
        ui.label(format!("Field under the landmarks: {}", f.display()));
    }
    action
}

/// Writes the pairs as BigWarp JSON (`.json`) or BigWarp CSV (any other name), or as a Slicer pair of point lists
/// for `.mrk.json` / `.fcsv`:
/// `NAME.mrk.json` becomes `NAME_moving.mrk.json` and `NAME_fixed.mrk.json`.
pub fn export_landmarks(path: &std::path::Path, pairs: &[LandmarkPair]) -> anyhow::Result<()> {
    match slicer_pair_paths(path) {
        Some((moving, fixed)) => warpbench_io::landmarks::write_slicer_pair(&moving, &fixed, pairs)?,
        None => warpbench_io::landmarks::write_landmark_pairs(path, pairs)?,
    }
    Ok(())
}

/// Reads pairs from a BigWarp CSV or JSON (told apart by content), or from the `_moving` / `_fixed` Slicer lists
/// named like [`export_landmarks`] writes them.
pub fn import_landmarks(path: &std::path::Path) -> anyhow::Result<Vec<LandmarkPair>> {
    Ok(match slicer_pair_paths(path) {
        Some((moving, fixed)) => warpbench_io::landmarks::read_slicer_pair(&moving, &fixed)?,
        None => warpbench_io::landmarks::read_landmark_pairs(path)?,
    })
}

/// For a Slicer name (`.mrk.json` or `.fcsv`), the moving and fixed list paths.
fn slicer_pair_paths(path: &std::path::Path) -> Option<(std::path::PathBuf, std::path::PathBuf)> {
    let name = path.file_name()?.to_str()?;
    let lower = name.to_ascii_lowercase();
    let ext = [".mrk.json", ".fcsv"].into_iter().find(|e| lower.ends_with(e))?;
    let stem = &name[..name.len() - ext.len()];
    let with = |side: &str| path.with_file_name(format!("{stem}_{side}{}", &name[name.len() - ext.len()..]));
    Some((with("moving"), with("fixed")))
}

#[cfg(test)]
mod tests {
    use super::*;
    use warpbench_io::geometry::Point3;

    #[test]
    fn landmarks_round_trip_through_bigwarp_csv_and_a_slicer_pair() {
        let dir = tempfile::tempdir().expect("tempdir");
        let pairs = vec![
            LandmarkPair::new("a", Point3::new(1.0, 2.0, 3.0), Point3::new(4.0, 5.0, 6.0)),
            LandmarkPair {
                active: false,
                ..LandmarkPair::new("b", Point3::new(-1.5, 0.0, 2.25), Point3::new(0.0, 1.0, 0.0))
            },
        ];
        for name in ["pairs.csv", "pairs.json", "pairs.mrk.json", "pairs.fcsv"] {
            let path = dir.path().join(name);
            export_landmarks(&path, &pairs).expect("export");
            let back = import_landmarks(&path).expect("import");
            assert_eq!(back.len(), 2, "{name}");
            for (a, b) in back.iter().zip(&pairs) {
                let close = |x: Option<Point3<warpbench_io::geometry::Lps>>,
                             y: Option<Point3<warpbench_io::geometry::Lps>>| {
                    x.zip(y).is_some_and(|(x, y)| x.distance(&y) < 1e-6)
                };
                assert!(close(a.moving, b.moving) && close(a.fixed, b.fixed), "{name}: {a:?} vs {b:?}");
            }
        }
        assert!(dir.path().join("pairs_moving.mrk.json").is_file() && dir.path().join("pairs_fixed.fcsv").is_file());
        // `.json` is BigWarp's JSON, which BigWarp's Load landmarks reads.
        let json: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(dir.path().join("pairs.json")).expect("read")).expect("JSON");
        assert_eq!(json["landmarks"]["type"], "BigWarpLandmarks", "{json}");
        assert!(import_landmarks(&dir.path().join("missing.csv")).is_err());
    }
}
