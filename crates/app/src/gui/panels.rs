//! The side panel's sections, each a `*_ui(ui, …)` function over plain state that returns what it asks for as
//! [`Command`]s, so each can be tested alone. Every widget carries a label that egui_kittest (and screen readers) can
//! find.

use eframe::egui;

use super::Command;
use super::leafer::{Leafer, MAX_ANGLE_DEG};
use super::open::Side;
use crate::procedural::ProceduralSpec;
use crate::project::document::{
    BRUSH_MAX_RADIUS_MM, Look, OBLIQUE_MAX_DEG, Oblique, PROCEDURAL_MAX_MM, StartingTransform, ViewSettings,
};
use crate::settings::{Blend, Layout, MethodKind, Overlay, Preset, Probe, ProceduralKind, Shading};

/// The layout of the views (four-up, the 3-D view alone, the slices alone), as a choice labelled "Layout".
pub fn layout_ui(ui: &mut egui::Ui, layout: Layout) -> Option<Command> {
    let mut chosen = layout;
    choice_ui(ui, "Layout", &mut chosen, Layout::ALL);
    (chosen != layout).then_some(Command::SetLayout(chosen))
}

/// A slice view's oblique controls (labelled "NAME oblique", "NAME tilt", "NAME spin"). Returns whether they
/// changed.
pub fn oblique_ui(ui: &mut egui::Ui, name: &str, o: &mut Oblique) -> bool {
    let before = *o;
    ui.horizontal_wrapped(|ui| {
        ui.spacing_mut().slider_width = (ui.available_width() - 150.0).max(40.0);
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

/// The View section: blend, shading, sample rate, landmarks shown, following the pair, the warp overlay and the 3-D
/// view's picking; the settings as changed, if they were.
pub fn view_ui(ui: &mut egui::Ui, settings: &ViewSettings) -> Option<Command> {
    let s = &mut settings.clone();
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
    ui.horizontal_wrapped(|ui| {
        ui.checkbox(&mut s.show_landmarks, "Show landmarks");
        ui.checkbox(&mut s.follow_pair, "Follow the pair being edited")
            .on_hover_text("Centre the slices on a pair when it is added, moved or selected");
    });
    choice_ui(ui, "Warp overlay", &mut s.overlay, Overlay::ALL);
    let probe_before = s.pick_probe;
    choice_ui(ui, "Pick probe", &mut s.pick_probe, Probe::ALL);
    if s.pick_probe != probe_before {
        s.pick_threshold = s.pick_probe.default_threshold();
    }
    ui.add(egui::Slider::new(&mut s.pick_threshold, s.pick_probe.threshold_range()).text("Pick threshold"));
    (s != settings).then(|| Command::SetSettings(s.clone()))
}

/// The Warp section's method: the method, with "Auto" by the stiffness slider (and the last automatic choice while
/// it holds), the B-spline levels and the control texture's size; the settings as changed, if they were, or
/// [`Command::AutoStiffness`].
pub fn method_ui(
    ui: &mut egui::Ui,
    settings: &ViewSettings,
    stiffness_choice: Option<&warpbench_solver::stiffness::StiffnessChoice>,
) -> Option<Command> {
    let s = &mut settings.clone();
    let mut auto = false;
    choice_ui(ui, "Method", &mut s.method, MethodKind::ALL);
    match s.method {
        MethodKind::Tps => {
            ui.horizontal(|ui| {
                let slider = egui::Slider::new(&mut s.stiffness, 0.0..=STIFFNESS_MAX)
                    .logarithmic(true)
                    .smallest_positive(0.01)
                    .text("Stiffness");
                ui.add(slider).on_hover_text("lambda, mm: 0 interpolates the pairs, more smooths the warp");
                let button = ui
                    .button("Auto")
                    .on_hover_text("choose lambda by the pairs: the smoothing under which they are most likely");
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
    ui.label("Synthetic deformation (view only)").on_hover_text("eval's known warps, computed in the shader");
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

/// "Show the worst pair" (W): selects the pair with the largest leave-one-out error, centres the views on it and
/// pulses the lens there (offered once there are leave-one-out errors). The lens itself is a tool of the toolbar.
pub fn worst_pair_ui(ui: &mut egui::Ui, has_loo: bool) -> Option<Command> {
    let worst = egui::Button::new("Show the worst pair");
    ui.add_enabled(has_loo, worst).on_hover_text("W").clicked().then_some(Command::ShowWorstPair)
}

/// The leafer's settings while it is open (the toolbar's Leafer opens it, [`super::leafer`]): which volume it opens
/// ("Leafer on the fixed volume" / "Leafer on the moving volume") and by how much ("Leafer opening (deg)") on each
/// side of the cut through the crosshair along the line of sight.
pub fn leafer_ui(ui: &mut egui::Ui, leafer: Leafer) -> Option<Command> {
    let mut edited = leafer;
    let Leafer::Open { side, angle_deg } = &mut edited else {
        ui.label("Leafer: closed (L opens the 3-D view like a book)");
        return None;
    };
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
    (edited != leafer).then_some(Command::SetLeafer(edited))
}

/// The starting transform under the landmark warp ([`crate::start`]): "Auto-align affine" aligns the moving volume to
/// the fixed one by mutual information, rigidly then with 12 parameters ([`super::alignment`]; the rigid one is the
/// toolbar's Auto-align), "Clear alignment" takes the starting transform away; the line below says what it is, or
/// that the alignment is running.
pub fn alignment_ui(ui: &mut egui::Ui, start: Option<&StartingTransform>, aligning: bool) -> Option<Command> {
    use warpbench_solver::align::AlignKind;
    let mut command = None;
    ui.horizontal(|ui| {
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

/// Refine by intensities ([`super::intensity`]): what it matches the volumes by, the button that registers the pair
/// under the landmarks, its progress and Cancel while it runs, and what the last refinement did, with the offer to run
/// it again once the pairs moved.
pub fn intensity_ui(
    ui: &mut egui::Ui,
    settings: &ViewSettings,
    running: Option<&super::intensity::IntensityJob>,
    last: Option<&super::intensity::RefinedOn>,
    pairs_moved: bool,
) -> Option<Command> {
    let mut command = None;
    if let Some(job) = running {
        ui.horizontal(|ui| {
            let fraction = job.fraction();
            ui.add(
                egui::ProgressBar::new(fraction)
                    .desired_width(140.0)
                    .text(format!("Refining {:.0} %", fraction * 100.0)),
            );
            if ui.button("Cancel").clicked() {
                command = Some(Command::CancelRefineByIntensities);
            }
        });
        return command;
    }
    let mut metric = settings.refine_metric;
    egui::ComboBox::from_label("Match by").selected_text(metric.label()).show_ui(ui, |ui| {
        for &m in crate::settings::Metric::ALL {
            ui.selectable_value(&mut metric, m, m.label()).on_hover_text(m.hint());
        }
    });
    if metric != settings.refine_metric {
        command = Some(Command::SetSettings(ViewSettings { refine_metric: metric, ..settings.clone() }));
    }
    let label = if last.is_some() && pairs_moved { "Re-run refinement" } else { "Refine by intensities" };
    let hover = "Register the pair by its intensities under the landmarks: the pairs stay put, the images decide \
                 between them. The result is the field under the landmarks.";
    if ui.button(label).on_hover_text(hover).clicked() {
        command = Some(Command::RefineByIntensities);
    }
    if let Some(last) = last {
        if pairs_moved {
            ui.label("The pairs moved since the last refinement: run it again to follow them.");
        }
        ui.add(egui::Label::new(last.refined.summary.as_str()).wrap());
    }
    command
}

/// The displacement brush's settings ([`warpbench_solver::brush`]; the toolbar's Brush makes it the tool): "Brush
/// radius (mm)" sets new strokes' reach and "Clear the brush" removes every stroke.
pub fn brush_ui(ui: &mut egui::Ui, settings: &ViewSettings, strokes: usize) -> Option<Command> {
    let mut command = None;
    ui.label(format!("Displacement brush (on top of the warp): {strokes} strokes"));
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
