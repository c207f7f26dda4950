//! The papers' deformation tools in the window through egui_kittest: the synthetic deformation, the attention lens,
//! the leafer and the brush.

mod common;
#[path = "common/window.rs"]
mod window;

use std::time::{Duration, Instant};

use window::{button, click_at, no_adapter, open_mri_pair, press_and_drag, wait_until_rendered};

use eframe::egui;
use egui_kittest::Harness;
use egui_kittest::kittest::Queryable;
use warpbench_app::gui::{Ready, Workbench};

/// The procedural deformation of the moving volume (issue 17, item 1) through the side panel: switched on by its
/// label it is the document's (undoable, a view setting the exports leave out), the viewer draws the moving volume
/// deformed, a kind it cannot take over this volume is named in the panel instead of drawn, and undo puts it off.
#[test]
fn a_procedural_deformation_is_switched_on_drawn_and_undone() {
    use warpbench_app::procedural::ProceduralSpec;
    use warpbench_app::settings::ProceduralKind;
    if no_adapter() {
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let mut harness = open_mri_pair(dir.path(), egui::vec2(640.0, 480.0));
    wait_until_rendered(&mut harness);
    let frame = |h: &Harness<'_, Workbench>| {
        let ready = h.state().ready().expect("ready");
        let settings = warpbench_gpu::RenderSettings {
            blend: warpbench_gpu::BlendMode::MovingOnly,
            ..ready.document.settings.render_settings()
        };
        let target = ready
            .viewer
            .render_view(&ready.view.camera, &settings, warpbench_gpu::Quality::Full, (64, 64), &[])
            .expect("render");
        target.read_back(&ready.viewer.ctx).expect("read back")
    };
    let undeformed = frame(&harness);

    // Below the fold of the side panel: clicked through accesskit, as a screen reader would.
    harness.get_by_label("Deform the moving volume").click_accesskit();
    harness.run_steps(3);
    harness.get_by_label("Deformation").click_accesskit();
    harness.run_steps(3);
    harness.get_by_label("bend").click_accesskit();
    harness.run_steps(3);
    wait_until_rendered(&mut harness);
    let ready = harness.state().ready().expect("ready");
    let spec = ProceduralSpec { kind: ProceduralKind::Bend, ..ProceduralSpec::default() };
    assert_eq!(ready.document.settings.procedural, Some(spec));
    assert!(matches!(ready.procedural(), Ok(Some(warpbench_gpu::Procedural::Bend { .. }))));
    let bent = frame(&harness);
    let differ = bent.chunks(4).zip(undeformed.chunks(4)).filter(|(a, b)| a != b).count();
    assert!(differ > 200, "the bend changed only {differ} of 4096 pixels");

    // An amplitude the kind cannot take over this volume is said, not drawn.
    let ready = harness.state_mut().ready_mut().expect("ready");
    let mut settings = ready.document.settings.clone();
    settings.procedural = Some(ProceduralSpec { kind: ProceduralKind::Sine, amplitude_mm: 500.0, seed: 1 });
    ready.apply(warpbench_app::gui::Command::SetSettings(settings));
    harness.run_steps(3);
    harness.get_by_label_contains("Not drawn: procedural sine of 500 mm");

    // Undo walks back: the bend, the default sine the switch turned on, then off.
    for expected in [Some(spec), Some(ProceduralSpec::default()), None] {
        harness.get_by_label("Undo").click();
        harness.run_steps(3);
        assert_eq!(harness.state().ready().expect("ready").document.settings.procedural, expected);
    }
    wait_until_rendered(&mut harness);
    assert!(frame(&harness) == undeformed, "undo did not give the undeformed view back");
}

/// The attention lens (issue 17, item 2): "Show the worst pair" selects the pair with the largest leave-one-out error,
/// centres the views on it and pulses the fish-eye lens about its fixed point in the 3-D view; the lens magnifies
/// there and changes neither the slices nor the document; the checkbox switches it off.
#[test]
fn the_worst_pair_is_shown_by_a_pulsing_lens() {
    use std::time::Instant;
    use warpbench_app::gui::landmark_table::loo_ranking;
    if no_adapter() {
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let mut harness = open_mri_pair(dir.path(), egui::vec2(640.0, 480.0));
    wait_until_rendered(&mut harness);
    let before = harness.state().ready().expect("ready").document.clone();
    let worst = {
        let ready = harness.state().ready().expect("ready");
        loo_ranking(&ready.document.pairs, &ready.fit.pair_errors)[0].1
    };
    window::open_section(&mut harness, "Assist");
    harness.get_by_label("Show the worst pair").click_accesskit();
    harness.run_steps(3);
    let ready = harness.state_mut().ready_mut().expect("ready");
    assert_eq!(ready.pointer.selected, Some(worst));
    assert!(ready.view.attention.is_on(), "the lens pulses");
    let q = ready.document.pairs[worst].fixed.expect("a fixed point").coords();
    assert!(
        (ready.view.slice_mm[0] - q[2]).abs() < 1e-9 && (ready.view.slice_mm[2] - q[0]).abs() < 1e-9,
        "the views go there"
    );
    let Some(warpbench_gpu::ViewDeformation::FishEye { centre_ref, radius_mm, .. }) = ready.view_lens(Instant::now())
    else {
        panic!("a lens about the worst pair")
    };
    assert!(centre_ref.distance(warpbench_gpu::glam::Vec3::from_array(q.map(|v| v as f32))) < 1e-6);

    // At its peak the lens magnifies about the pair: the 3-D view changes, the slices do not.
    let peak = warpbench_gpu::ViewDeformation::FishEye {
        centre_ref,
        radius_mm,
        amplitude: warpbench_app::gui::attention::PEAK_AMPLITUDE,
    };
    let settings = ready.document.settings.render_settings();
    let view = |ready: &mut Ready, lens| {
        ready.viewer.set_view_deformations([lens; 2]);
        let t = ready.viewer.render_view(&ready.view.camera, &settings, warpbench_gpu::Quality::Full, (64, 64), &[]);
        let slice = ready.viewer.render_slice(&ready.slice_plane(0), &settings, &[]).expect("slice");
        (
            t.expect("view").read_back(&ready.viewer.ctx).expect("read"),
            slice.read_back(&ready.viewer.ctx).expect("read"),
        )
    };
    let (plain, plain_slice) = view(ready, None);
    let (lensed, lensed_slice) = view(ready, Some(peak));
    let differ = plain.chunks(4).zip(lensed.chunks(4)).filter(|(a, b)| a != b).count();
    assert!(differ > 50, "the lens changed {differ} pixels of the view");
    assert!(plain_slice == lensed_slice, "the lens must not touch the slices");
    assert_eq!(ready.document, before, "the lens is not part of the document");

    harness.get_by_label("Lens").click();
    harness.run_steps(3);
    let ready = harness.state().ready().expect("ready");
    assert!(!ready.view.attention.is_on() && ready.view_lens(Instant::now()).is_none(), "switched off");
}

/// The leafer (issue 17, item 3): opened on the moving volume through the side panel, it cuts the 3-D view along the
/// line of sight through the crosshair and opens it towards the viewer; a click on the opened volume picks through
/// the same deformation the frame draws, and what the pair stores is the point of the undeformed moving volume,
/// u(w(x)), which the warp shows at w(x). It is not part of the document.
#[test]
fn a_landmark_is_placed_inside_the_volume_through_the_leafer() {
    use warpbench_app::gui::Placing;
    use warpbench_app::gui::leafer::Leafer;
    use warpbench_app::gui::open::Side;
    if no_adapter() {
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let mut harness = open_mri_pair(dir.path(), egui::vec2(900.0, 700.0));
    let before = harness.state().ready().expect("ready").document.clone();
    harness.get_by_label("Leafer").click();
    harness.run_steps(3);
    let ready = harness.state().ready().expect("ready");
    assert_eq!(ready.view.leafer, Leafer::Open { side: Side::Moving, angle_deg: 30.0 });
    let [None, Some(leafer @ warpbench_gpu::ViewDeformation::Leafer { .. })] =
        ready.view_deformations(std::time::Instant::now())
    else {
        panic!("the leafer on the moving volume")
    };
    wait_until_rendered(&mut harness);

    // The pick the click makes, through the leafer: its point x_ref on the ray is shown turned, w(x) ≠ x, and what
    // it reports is the undeformed moving volume's point u(w(x)), which the warp shows at w(x).
    // The pixel: right of the centre, past the gap the opened halves leave (its width depends on the view's size),
    // a little into the right half.
    let ready = harness.state().ready().expect("ready");
    let (size, _) = ready.view_shown().expect("a view");
    let settings = ready.document.settings.render_settings();
    let probe = ready.document.settings.probe();
    let pick = |offset: f32| {
        let pixel = [size.0 as f32 * (0.5 + offset), size.1 as f32 * 0.5];
        ready.viewer.pick(&ready.view.camera, &settings, size, pixel, warpbench_gpu::PickTarget::Moving, probe)
    };
    let edge = (1..25).map(|k| k as f32 * 0.02).find(|&o| pick(o).expect("pick").is_some());
    let offset = edge.expect("the right half of the opened moving volume in the view") + 0.06;
    let hit = pick(offset).expect("pick").expect("a hit on the opened moving volume");
    let x = warpbench_gpu::glam::Vec3::from_array(hit.x_ref);
    let w = leafer.pullback(x);
    let shown = warpbench_gpu::glam::DVec3::from_array(ready.shown_at(hit.p_lps.map(f64::from)));
    eprintln!("picked at {x}, turned back to {w}; the stored point is shown at {shown}");
    assert!(w.distance(x) > 5.0, "the hit is on a turned half: moved {} mm", w.distance(x));
    assert!(
        shown.distance(w.as_dvec3()) < 1.0,
        "the stored point is shown {} mm from w(x)",
        shown.distance(w.as_dvec3())
    );

    // Placing a pair by the same click stores that point.
    harness.get_by_label("Add pair").click();
    harness.run_steps(2);
    let view = harness.get_by_label("3-D view").rect();
    click_at(&mut harness, view.center() + egui::vec2(view.width() * offset, 0.0));
    let ready = harness.state().ready().expect("ready");
    let Placing::Target { moving } = ready.placing() else {
        panic!("the click placed no source: {:?} {:?}", ready.fit.error, ready.pointer.notice)
    };
    let stored = warpbench_gpu::glam::DVec3::from_array(moving.coords());
    assert!(stored.distance(warpbench_gpu::glam::Vec3::from_array(hit.p_lps).as_dvec3()) < 1e-3, "{stored}");
    assert_eq!(ready.document, before, "the leafer is not part of the document");

    harness.get_by_label("Leafer").click();
    harness.run_steps(3);
    assert_eq!(harness.state().ready().expect("ready").view.leafer, Leafer::Closed);
}

/// The displacement brush (issue 17, item 4): with "Brush" as the tool, a drag in the axial slice adds one stroke at
/// the press, displaced in the plane by the drag; it settles with the brush's inverse fitted by scattered-data
/// interpolation (its consistency shown), the content at c is then shown at c + t (u(b⁻¹(c + t)) = u(c)), the stroke
/// reaches the autosave, and one undo removes it.
#[test]
fn the_brush_drags_the_moving_volume_in_a_slice() {
    if no_adapter() {
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let mut harness = open_mri_pair(dir.path(), egui::vec2(900.0, 700.0));
    harness.get_by_label("Brush").click_accesskit();
    harness.run_steps(2);
    assert!(harness.state().ready().expect("ready").sculpting());
    let rect = harness.get_by_label("Axial slice").rect();
    let (start, end) = (rect.center(), rect.center() + egui::vec2(rect.width() * 0.08, 0.0));
    press_and_drag(&mut harness, start, end, &[0.25, 0.5, 0.75, 1.0]);
    assert!(harness.state().ready().expect("ready").sculpt_drag().is_some(), "a stroke is being made");
    harness.input_mut().events.push(button(end, false));
    harness.run_steps(3);
    wait_until_rendered(&mut harness);
    let ready = harness.state().ready().expect("ready");
    assert_eq!(ready.document.brush.len(), 1, "one stroke");
    let stroke = ready.document.brush[0];
    let (c, t) = (stroke.centre_mm, stroke.displacement_mm);
    eprintln!("stroke at {c:?} by {t:?} (radius {} mm)", stroke.radius_mm);
    assert!(t[0].abs() > 3.0 && t[1].abs() < 0.5 && t[2].abs() < 1e-6, "dragged to the right within the plane: {t:?}");
    let consistency = ready.fit.brush_consistency.expect("the settled brush's inverse");
    assert!(consistency.max_mm < 0.05, "{consistency:?}");
    window::open_section(&mut harness, "Accuracy");
    harness.get_by_label_contains("Brush inverse:");
    let moved = harness.state().ready().expect("ready").moving_shown_at(std::array::from_fn(|a| c[a] + t[a]));
    let autosave = dir.path().join("autosave.warpbench.json");
    let start_wait = Instant::now();
    while warpbench_app::project::session::load(&autosave).map_or(0, |s| s.document.brush.len()) != 1 {
        assert!(start_wait.elapsed() < Duration::from_secs(30), "the stroke was not autosaved within 30 s");
        std::thread::sleep(Duration::from_millis(20));
    }

    harness.get_by_label("Undo").click();
    harness.run_steps(3);
    wait_until_rendered(&mut harness);
    let ready = harness.state().ready().expect("ready");
    assert!(ready.document.brush.is_empty() && ready.fit.brush.is_none(), "undo removes the stroke");
    let before = ready.moving_shown_at(c);
    let off = (0..3).map(|a| (moved[a] - before[a]).abs()).fold(0.0, f64::max);
    assert!(off < 1e-6, "the brushed point shows the content of its start: {moved:?} vs {before:?}");
}
