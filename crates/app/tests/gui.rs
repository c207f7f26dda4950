//! The workbench window driven headlessly through egui_kittest (wgpu on the CPU driver), by accessibility labels:
//! it loads a pair, renders the 3-D view and the slices on egui's own device, and reacts to the blend-mode switch
//! and to a landmark being switched off (the warp is fitted again).

mod common;
#[path = "common/window.rs"]
mod window;

use std::path::Path;
use std::time::{Duration, Instant};

use common::{data, mri};
use window::{click_at, no_adapter, wait_until_rendered, wait_until_shown};

use eframe::egui;
use egui_kittest::Harness;
use egui_kittest::kittest::Queryable;
use warpbench_app::gui::{GuiOptions, Placing, Ready, Workbench};
use warpbench_app::inputs::LandmarkSource;

/// Five pairs on the MRI, the moving points shifted by a few mm.
fn pairs(dir: &Path) -> std::path::PathBuf {
    let q = [[0.0, 18.0, 18.0], [40.0, 18.0, 18.0], [-40.0, 30.0, 0.0], [0.0, 70.0, 40.0], [10.0, -40.0, 18.0]];
    let pairs: Vec<([f64; 3], [f64; 3])> =
        q.iter().enumerate().map(|(i, q)| ([q[0] + 3.0, q[1] - 2.0 + i as f64, q[2] + 1.5], *q)).collect();
    let path = dir.join("pairs.csv");
    common::write_pairs_csv(&path, &pairs);
    path
}

/// Steps until loading has failed (or 20 s pass).
fn wait_for_failure(harness: &mut Harness<'_, Workbench>) {
    let start = Instant::now();
    while harness.state().failure().is_none() {
        harness.step();
        assert!(start.elapsed() < Duration::from_secs(20), "no error shown");
        std::thread::sleep(Duration::from_millis(10));
    }
}

/// A window of `size` on the MRI fixture as fixed and moving, with the five pairs of [`pairs`] and an autosave in
/// `dir`, stepped until the pair is shown.
fn open_mri_pair(dir: &Path, size: egui::Vec2) -> Harness<'static, Workbench> {
    open_mri_pair_at(dir, size, 1.0)
}

/// [`open_mri_pair`] drawn at `pixels_per_point`.
fn open_mri_pair_at(dir: &Path, size: egui::Vec2, pixels_per_point: f32) -> Harness<'static, Workbench> {
    let opts = GuiOptions {
        fixed: Some(mri()),
        moving: Some(mri()),
        landmarks: Some(LandmarkSource::Pairs(pairs(dir))),
        autosave: Some(dir.join("autosave.warpbench.json")),
        ..GuiOptions::default()
    };
    let mut harness = Harness::builder()
        .with_size(size)
        .with_pixels_per_point(pixels_per_point)
        .wgpu()
        .build_eframe(|cc| Workbench::new(cc, opts));
    wait_until_shown(&mut harness);
    harness
}

#[test]
fn loads_a_pair_renders_it_and_follows_the_controls() {
    if no_adapter() {
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let mut harness = open_mri_pair(dir.path(), egui::vec2(1100.0, 760.0));
    let ready = harness.state().ready().expect("loaded");
    assert_eq!(ready.fitted_pairs(), 5, "the TPS is fitted on the five pairs: {:?}", ready.fit.error);
    assert!(ready.fit.error.is_none());

    // The table's errors: TPS interpolates (residual ~0); every pair has a leave-one-out error.
    for (i, e) in ready.fit.pair_errors.iter().enumerate() {
        let e = e.expect("errors for an active pair");
        assert!(e.residual_mm < 1e-6, "pair {i}: residual {}", e.residual_mm);
        assert!(e.leave_one_out_mm.is_some_and(|l| l > 0.0 && l < 50.0), "pair {i}: {e:?}");
    }
    // Go to a pair: the slices move to its fixed point.
    harness.get_by_label("Go to Pt-1").click();
    harness.run_steps(2);
    let ready = harness.state().ready().expect("loaded");
    assert!((ready.slice_mm[0] - 18.0).abs() < 1e-9 && (ready.slice_mm[2] - 40.0).abs() < 1e-9, "{:?}", ready.slice_mm);
    // Delete a pair, and undo it.
    harness.get_by_label("Delete Pt-0").click();
    harness.run_steps(2);
    assert_eq!(harness.state().ready().expect("loaded").fitted_pairs(), 4);
    harness.get_by_label("Undo").click();
    harness.run_steps(2);
    assert_eq!(harness.state().ready().expect("loaded").fitted_pairs(), 5);

    // Blend mode: open the combo box and choose "difference".
    harness.get_by_label("Blend mode").click();
    harness.run_steps(3);
    harness.get_by_label("difference").click();
    harness.run_steps(3);
    let ready = harness.state().ready().expect("loaded");
    assert_eq!(ready.document.settings.blend.name(), "difference");

    // Undo (the button) brings the mix blend back, redo (Ctrl+Shift+Z) the difference again, Ctrl+Z undoes again.
    harness.get_by_label("Undo").click();
    harness.run_steps(2);
    let blend = |h: &Harness<'_, Workbench>| h.state().ready().expect("loaded").document.settings.blend.name();
    assert_eq!(blend(&harness), "mix");
    let key = |h: &mut Harness<'_, Workbench>, modifiers: egui::Modifiers| {
        for pressed in [true, false] {
            h.input_mut().events.push(egui::Event::Key {
                key: egui::Key::Z,
                physical_key: None,
                pressed,
                repeat: false,
                modifiers,
            });
            h.run_steps(2);
        }
    };
    key(&mut harness, egui::Modifiers::COMMAND | egui::Modifiers::SHIFT);
    assert_eq!(blend(&harness), "difference");
    key(&mut harness, egui::Modifiers::COMMAND);
    assert_eq!(blend(&harness), "mix");
    key(&mut harness, egui::Modifiers::COMMAND | egui::Modifiers::SHIFT);
    assert_eq!(blend(&harness), "difference");

    // Switching a pair off refits the warp on the other four.
    harness.get_by_label("Use Pt-2").click();
    harness.run_steps(3);
    let ready = harness.state().ready().expect("loaded");
    assert!(!ready.document.pairs[2].active);
    assert_eq!(ready.fitted_pairs(), 4);
    harness.get_by_label("Undo").click();
    harness.run_steps(2);
    let ready = harness.state().ready().expect("loaded");
    assert!(ready.document.pairs[2].active, "undo switches the pair back on");
    assert_eq!(ready.fitted_pairs(), 5, "and refits");
    harness.get_by_label("Redo").click();
    harness.run_steps(2);
    assert_eq!(harness.state().ready().expect("loaded").fitted_pairs(), 4);
    // Rigid needs at least 3 pairs; with 4 active it fits.
    harness.get_by_label("Method").click();
    harness.run_steps(3);
    harness.get_by_label("rigid").click();
    harness.run_steps(3);
    let ready = harness.state().ready().expect("loaded");
    assert_eq!(ready.document.settings.method().to_string(), "rigid");
    assert_eq!(ready.fitted_pairs(), 4, "{:?}", ready.fit.error);
}

#[test]
fn a_missing_file_is_reported_in_the_window() {
    let opts = GuiOptions {
        fixed: Some(Path::new("/nonexistent/fixed.nii").to_path_buf()),
        moving: Some(mri()),
        ..GuiOptions::default()
    };
    let mut harness =
        Harness::builder().with_size(egui::vec2(600.0, 300.0)).build_eframe(|cc| Workbench::new(cc, opts));
    wait_for_failure(&mut harness);
    let message = harness.state().failure().expect("failed").to_owned();
    assert!(message.contains("/nonexistent/fixed.nii"), "{message}");
    harness.get_by_label("No volumes are open");
    harness.get_by_label("Open the demo pair");
}

#[test]
fn adds_a_pair_by_clicking_a_slice_and_by_picking_in_3d() {
    if no_adapter() {
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let mut harness = open_mri_pair(dir.path(), egui::vec2(1100.0, 760.0));
    let axial_mm = harness.state().ready().expect("loaded").slice_mm[0];

    // Without Add pair, a click in a slice moves the other two slices through the clicked point (linked views).
    let rect = harness.get_by_label("Axial slice").rect();
    let before = harness.state().ready().expect("loaded").slice_mm;
    click_at(&mut harness, rect.center() + egui::vec2(rect.width() * 0.2, -rect.height() * 0.1));
    let after = harness.state().ready().expect("loaded").slice_mm;
    assert!((after[0] - before[0]).abs() < 1e-9, "the axial plane stays: {before:?} -> {after:?}");
    assert!(after[2] > before[2] + 5.0, "the sagittal plane moves to the right (+L): {before:?} -> {after:?}");
    // Rows follow the fixed grid's j axis (here P decreases with j), so a click above the centre is more posterior.
    assert!(after[1] > before[1] + 2.0, "the coronal plane moves with the click: {before:?} -> {after:?}");
    harness.run_steps(2);
    harness.get_by_label_contains("cursor LPS");

    // In a slice: the source at the centre of the axial slice, the target a little to its right.
    harness.get_by_label("Add pair").click();
    harness.run_steps(2);
    let rect = harness.get_by_label("Axial slice").rect();
    click_at(&mut harness, rect.center());
    assert!(
        matches!(harness.state().ready().expect("loaded").placing(), warpbench_app::gui::Placing::Target { .. }),
        "the first click places the source"
    );
    click_at(&mut harness, rect.center() + egui::vec2(rect.width() * 0.1, 0.0));
    let ready = harness.state().ready().expect("loaded");
    assert_eq!(ready.placing(), warpbench_app::gui::Placing::Idle);
    assert_eq!(ready.document.pairs.len(), 6, "a sixth pair");
    assert_eq!(ready.fitted_pairs(), 6, "{:?}", ready.fit.error);
    let pair = ready.document.pairs.last().expect("pair");
    let (p, q) = (pair.moving.expect("source").coords(), pair.fixed.expect("target").coords());
    // Both clicks lie on the axial plane of the fixed grid (voxel centres, 2 mm apart); the source went through the
    // pull-back, which moves it by a few mm at most.
    assert!((q[2] - axial_mm).abs() <= 1.0, "target S {} vs slice {axial_mm}", q[2]);
    assert!((p[2] - q[2]).abs() < 10.0 && p[0] < q[0], "source {p:?}, target {q:?}");
    // The new pair is on disk at once, without another frame (the autosave follows every change of the document).
    let autosave = dir.path().join("autosave.warpbench.json");
    let start = Instant::now();
    let on_disk = |path: &Path| warpbench_app::gui::session::load(path).map_or(0, |s| s.document.pairs.len());
    while on_disk(&autosave) != 6 {
        assert!(start.elapsed() < Duration::from_secs(5), "the sixth pair was not autosaved within 5 s");
        std::thread::sleep(Duration::from_millis(20));
    }

    // In the 3-D view: the brain at the centre of the view is hit on both volumes.
    harness.get_by_label("Add pair").click();
    harness.run_steps(2);
    let view = harness.get_by_label("3-D view").rect();
    click_at(&mut harness, view.center());
    click_at(&mut harness, view.center());
    let ready = harness.state().ready().expect("loaded");
    assert!(ready.fit.error.is_none(), "{:?}", ready.fit.error);
    assert_eq!(ready.document.pairs.len(), 7, "a seventh pair from the 3-D view");
    let pair = ready.document.pairs.last().expect("pair");
    let inside = |c: [f64; 3]| c[0].abs() < 91.0 && (-91.0..127.0).contains(&c[1]) && (-73.0..109.0).contains(&c[2]);
    assert!(inside(pair.moving.expect("source").coords()) && inside(pair.fixed.expect("target").coords()));
}

#[test]
fn the_readers_warnings_are_shown_in_the_window() {
    if no_adapter() {
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    // jhu189's sform and qform disagree by a left-right flip: the window says so, and which one it uses.
    let opts = GuiOptions {
        fixed: Some(data("nifti/jhu189.nii.gz")),
        moving: Some(mri()),
        autosave: Some(dir.path().join("autosave.warpbench.json")),
        ..GuiOptions::default()
    };
    let mut harness =
        Harness::builder().with_size(egui::vec2(1100.0, 760.0)).wgpu().build_eframe(|cc| Workbench::new(cc, opts));
    wait_until_shown(&mut harness);
    harness.get_by_label_contains("The fixed volume: the sform (code 2) and the qform (code 2) disagree");
    assert!(harness.query_by_label_contains("The moving volume:").is_none(), "the MRI has nothing to warn about");
}

#[test]
fn suspicious_and_degenerate_pairs_are_named_by_their_rows_in_the_table() {
    if no_adapter() {
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let mut harness = open_mri_pair(dir.path(), egui::vec2(1100.0, 760.0));
    // Row 1 off (so the fit's own numbering differs from the table's), and row 6 repeats row 3.
    {
        let ready = harness.state_mut().ready_mut().expect("loaded");
        ready.document.pairs[0].active = false;
        let again = ready.document.pairs[2].clone();
        ready.document.pairs.push(warpbench_io::landmarks::LandmarkPair { name: "again".into(), ..again });
        ready.refit();
    }
    harness.run_steps(2);
    let ready = harness.state().ready().expect("loaded");
    assert!(ready.fit.error.is_none(), "a repeated pair still fits: {:?}", ready.fit.error);
    assert_eq!(ready.fit.warnings.len(), 1, "{:?}", ready.fit.warnings);
    assert!(ready.fit.warnings[0].contains("landmarks 3 and 6 are the same pair"), "{:?}", ready.fit.warnings);
    harness.get_by_label_contains("Warning: landmarks 3 and 6 are the same pair");
    // Row 6 now sends row 3's moving point elsewhere: no warp does that; the status bar says which rows.
    {
        let ready = harness.state_mut().ready_mut().expect("loaded");
        ready.document.pairs[5].fixed = Some(warpbench_io::geometry::Point3::new(5.0, 5.0, 5.0));
        ready.refit();
    }
    harness.run_steps(2);
    let ready = harness.state().ready().expect("loaded");
    let e = ready.fit.error.clone().expect("refused");
    assert!(e.contains("landmarks 3 and 6") && e.contains("moving point"), "{e}");
    assert!(!e.contains("source") && !e.contains("target"), "one vocabulary: {e}");
    harness.get_by_label_contains("warp off:");
}

#[test]
fn an_idle_window_says_so_in_the_status_bar() {
    if no_adapter() {
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let mut harness = open_mri_pair(dir.path(), egui::vec2(1100.0, 760.0));
    // Frames were just drawn: a rate is shown.
    harness.get_by_label_contains(" fps");
    // Step as the event loop would: at once when asked to, after the delay the window asks for, and not at all
    // once it asks for nothing. The window then stands idle, and its status bar must say so.
    let start = Instant::now();
    loop {
        let delay =
            harness.output().viewport_output.get(&egui::ViewportId::ROOT).map_or(Duration::MAX, |v| v.repaint_delay);
        if delay == Duration::MAX {
            break;
        }
        assert!(start.elapsed() < Duration::from_secs(20), "the window never went idle");
        std::thread::sleep(delay.min(Duration::from_secs(2)));
        harness.step();
    }
    harness.get_by_label("idle");
}

#[test]
fn sessions_save_and_reopen_and_a_crash_is_recovered() {
    if no_adapter() {
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let autosave = dir.path().join("autosave.warpbench.json");
    let opts = GuiOptions {
        fixed: Some(mri()),
        moving: Some(mri()),
        landmarks: Some(LandmarkSource::Pairs(pairs(dir.path()))),
        autosave: Some(autosave.clone()),
        ..GuiOptions::default()
    };
    let mut harness =
        Harness::builder().with_size(egui::vec2(900.0, 640.0)).wgpu().build_eframe(|cc| Workbench::new(cc, opts));
    wait_until_shown(&mut harness);
    assert!(harness.state().recovery.is_none(), "no crashed session to offer");
    // Change things: the method, a pair switched off, the camera; then save the session.
    {
        let ready = harness.state_mut().ready_mut().expect("loaded");
        ready.document.settings.method = warpbench_app::settings::MethodKind::Rigid;
        ready.document.settings.oblique[1] =
            warpbench_app::gui::document::Oblique { on: true, tilt_deg: 20.0, spin_deg: -10.0 };
        ready.document.pairs[1].active = false;
        ready.camera.azimuth_rad = 1.0;
        ready.refit();
    }
    let saved = harness.state().ready().expect("loaded").to_session(true);
    let session_path = dir.path().join("project.warpbench.json");
    warpbench_app::gui::session::save(&session_path, &saved).expect("save");
    // The window autosaves, then "crashes" (no clean exit).
    harness.state_mut().autosave_now(false);
    drop(harness);

    // Reopening the project restores it.
    let opts = GuiOptions {
        session: Some(session_path),
        autosave: Some(dir.path().join("other-autosave.json")),
        ..GuiOptions::default()
    };
    let mut harness =
        Harness::builder().with_size(egui::vec2(900.0, 640.0)).wgpu().build_eframe(|cc| Workbench::new(cc, opts));
    wait_until_shown(&mut harness);
    let ready = harness.state().ready().expect("loaded");
    assert_eq!(ready.to_session(true), saved, "the reopened session is the saved one");
    assert_eq!(ready.fitted_pairs(), 4);
    drop(harness);

    // A new window on the crashed autosave offers recovery, and recovering brings the pairs back.
    let opts = GuiOptions { autosave: Some(autosave), ..GuiOptions::default() };
    let mut harness =
        Harness::builder().with_size(egui::vec2(900.0, 640.0)).wgpu().build_eframe(|cc| Workbench::new(cc, opts));
    assert!(harness.state().recovery.is_some(), "a crashed session is offered");
    wait_until_shown(&mut harness);
    harness.get_by_label("Recover the last session").click();
    harness.run_steps(2);
    wait_until_shown(&mut harness);
    let ready = harness.state().ready().expect("loaded");
    assert_eq!(ready.document.pairs, saved.document.pairs);
    assert_eq!(ready.document.settings.method().to_string(), "rigid");
}

#[test]
fn a_folding_warp_is_flagged_with_its_location() {
    if no_adapter() {
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let mut harness = open_mri_pair(dir.path(), egui::vec2(1100.0, 700.0));
    assert!(harness.state().ready().expect("loaded").fit.jacobian.is_some_and(|j| j.min_det > 0.0), "no folding yet");
    assert!(harness.query_by_label_contains("the warp folds").is_none());
    // Two pairs 6 mm apart whose sources cross over (each moves 10 mm past the other): the pull-back folds there.
    {
        let ready = harness.state_mut().ready_mut().expect("loaded");
        let pt = |x: f64| warpbench_io::geometry::Point3::new(x, 18.0, 30.0);
        ready.document.pairs.push(warpbench_io::landmarks::LandmarkPair::new("x1", pt(13.0), pt(0.0)));
        ready.document.pairs.push(warpbench_io::landmarks::LandmarkPair::new("x2", pt(-7.0), pt(6.0)));
        ready.refit();
    }
    harness.run_steps(2);
    // The folding check follows the fit on a thread of its own.
    wait_until_rendered(&mut harness);
    let j = harness.state().ready().expect("loaded").fit.jacobian.expect("a fit");
    assert!(j.min_det <= 0.0 && j.fraction_folded > 0.0, "{j:?}");
    // The minimum lies between the crossing pairs.
    assert!((j.min_at[0] - 3.0).abs() < 15.0 && (j.min_at[2] - 30.0).abs() < 15.0, "{j:?}");
    harness.get_by_label_contains("the warp folds");
}

/// A file dropped on the window (egui leaves the type to the integration).
#[derive(Debug)]
struct Dropped(std::path::PathBuf);

impl egui::DroppedFile for Dropped {
    fn path(&self) -> &Path {
        &self.0
    }
    fn bytes(&self) -> Result<Vec<u8>, String> {
        std::fs::read(&self.0).map_err(|e| e.to_string())
    }
}

fn drop_files(harness: &mut Harness<'_, Workbench>, paths: &[std::path::PathBuf]) {
    for p in paths {
        harness.input_mut().dropped_files.push(std::sync::Arc::new(Dropped(p.clone())));
    }
    harness.run_steps(2);
}

/// Steps until no volume is being read (or 60 s pass).
fn wait_for_reads(harness: &mut Harness<'_, Workbench>) {
    let start = Instant::now();
    while harness.state().reading() > 0 {
        harness.step();
        assert!(start.elapsed() < Duration::from_mins(1), "a read did not finish within a minute");
        std::thread::sleep(Duration::from_millis(10));
    }
    harness.run_steps(3);
}

#[test]
fn opens_volumes_by_drop_reports_bad_files_and_chooses_a_dicom_series() {
    if no_adapter() {
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let mut harness = open_mri_pair(dir.path(), egui::vec2(1100.0, 760.0));
    harness.get_by_label("File");

    // A corrupt volume: asked which side, read on a worker, refused in a dialog that names it; the pair stays.
    drop_files(&mut harness, &[data("bad/random.nii")]);
    harness.get_by_label("the moving volume").click();
    harness.run_steps(2);
    wait_for_reads(&mut harness);
    let message = harness.state().dialogs.error.clone().expect("an error dialog");
    assert!(message.contains("random.nii") && message.contains("moving"), "{message}");
    harness.get_by_label("OK").click();
    harness.run_steps(2);
    assert!(harness.state().dialogs.error.is_none());
    assert_eq!(harness.state().ready().expect("the pair stays").loaded.moving.dims, [91, 109, 91]);

    // A DICOM folder with a CT and an MR series: the chooser lists both; the MR becomes the moving volume.
    let folder = data("dicom/mixed_ct5n_mr_small");
    drop_files(&mut harness, std::slice::from_ref(&folder));
    harness.get_by_label("the moving volume").click();
    harness.run_steps(2);
    wait_for_reads(&mut harness);
    let (side, _, series) = harness.state().dialogs.series.clone().expect("the series chooser");
    assert_eq!((side, series.len()), (warpbench_app::gui::open::Side::Moving, 2));
    harness.get_by_label_contains(": MR ").click();
    harness.run_steps(2);
    wait_for_reads(&mut harness);
    let ready = harness.state().ready().expect("loaded");
    assert_eq!(ready.document.moving.as_deref(), Some(folder.as_path()));
    assert_eq!(ready.loaded.moving.modality, warpbench_io::Modality::Mr);
    assert!(ready.loaded.title.contains("mixed_ct5n_mr_small"), "{}", ready.loaded.title);
    // The landmarks stay (patient space), and the warp is fitted again against the new volume.
    assert_eq!(ready.document.pairs.len(), 5);
    // Opening a volume is an undo step: undo shows the MRI again, redo the DICOM series.
    harness.get_by_label("Undo").click();
    harness.run_steps(2);
    let ready = harness.state().ready().expect("loaded");
    assert_eq!(ready.document.moving.as_deref(), Some(mri().as_path()));
    assert_eq!(ready.loaded.moving.dims, [91, 109, 91]);
    assert!(!ready.loaded.title.contains("mixed_ct5n_mr_small"), "{}", ready.loaded.title);
    assert!(ready.fit.error.is_none(), "{:?}", ready.fit.error);
    harness.get_by_label("Redo").click();
    harness.run_steps(2);
    let ready = harness.state().ready().expect("loaded");
    assert_eq!(ready.document.moving.as_deref(), Some(folder.as_path()));
    assert_ne!(ready.loaded.moving.dims, [91, 109, 91]);

    // Two volumes dropped together: the first is the fixed one, the second the moving one.
    let ct = data("nifti/avg152T1_LR_nifti2.nii.gz");
    drop_files(&mut harness, &[ct.clone(), mri()]);
    wait_for_reads(&mut harness);
    let ready = harness.state().ready().expect("loaded");
    assert_eq!(ready.document.fixed.as_deref(), Some(ct.as_path()));
    assert_eq!(ready.document.moving.as_deref(), Some(mri().as_path()));
    assert!(ready.fit.error.is_none(), "{:?}", ready.fit.error);
}

#[test]
fn landmarks_are_renamed_dragged_within_a_slice_and_ranked() {
    if no_adapter() {
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let mut harness = open_mri_pair(dir.path(), egui::vec2(1100.0, 820.0));
    // The accuracy panel: a histogram and the worst pairs.
    harness.get_by_label("Leave-one-out histogram");
    harness.get_by_label_contains("Leave-one-out error: mean");

    // Rename pair 1; undo brings the old name back.
    harness.get_by_label("Name of pair 1").focus();
    harness.run_steps(2);
    harness.get_by_label("Name of pair 1").type_text("nasion");
    harness.run_steps(2);
    assert!(harness.state().ready().expect("loaded").document.pairs[0].name.contains("nasion"));
    // The typed text arrived in one frame: one undo step.
    harness.get_by_label("Undo").click();
    harness.run_steps(2);
    assert_eq!(harness.state().ready().expect("loaded").document.pairs[0].name, "Pt-0");

    // Drag Pt-1's fixed point 30 points to the right within the axial slice through it.
    harness.get_by_label("Go to Pt-1").click();
    harness.run_steps(3);
    let ready = harness.state().ready().expect("loaded");
    let q = ready.document.pairs[1].fixed.expect("fixed").coords();
    let plane = ready.slice_plane(0);
    let rect = harness.get_by_label("Axial slice").rect();
    let scale = rect.width() / plane.size.0 as f32;
    let px = plane.pixel_from_ref(q).expect("on the plane");
    assert!(px[2].abs() < 1.0, "the axial slice goes through the pair: {px:?}");
    let start = rect.min + egui::vec2((px[0] as f32 + 0.5) * scale, (px[1] as f32 + 0.5) * scale);
    let end = start + egui::vec2(30.0, 0.0);
    let button = |pos, pressed| egui::Event::PointerButton {
        pos,
        button: egui::PointerButton::Primary,
        pressed,
        modifiers: egui::Modifiers::default(),
    };
    harness.input_mut().events.push(egui::Event::PointerMoved(start));
    harness.input_mut().events.push(button(start, true));
    harness.step();
    for t in [0.25f32, 0.5, 0.75, 1.0] {
        harness.input_mut().events.push(egui::Event::PointerMoved(start + (end - start) * t));
        harness.step();
    }
    let during = harness.state().ready().expect("loaded");
    assert!(during.drag().is_some(), "the press grabbed the glyph");
    harness.input_mut().events.push(button(end, false));
    harness.run_steps(3);
    wait_until_rendered(&mut harness);
    let ready = harness.state().ready().expect("loaded");
    assert!(ready.drag().is_none());
    let moved = ready.document.pairs[1].fixed.expect("fixed").coords();
    let expected = plane.ref_from_pixel(px[0] + f64::from(30.0 / scale), px[1]);
    for a in 0..3 {
        assert!((moved[a] - expected[a]).abs() < 1.0, "dragged to {moved:?}, expected {expected:?}");
    }
    assert!((moved[0] - q[0]).abs() > 10.0, "it moved: {q:?} -> {moved:?}");
    // The drag refitted the warp and, once released, the diagnostics.
    assert_eq!(ready.fitted_pairs(), 5);
    assert!(ready.fit.pair_errors[1].is_some_and(|e| e.leave_one_out_mm.is_some()));
    // One drag is one undo step.
    harness.get_by_label("Undo").click();
    harness.run_steps(2);
    let back = harness.state().ready().expect("loaded").document.pairs[1].fixed.expect("fixed").coords();
    assert_eq!(back.map(f64::to_bits), q.map(f64::to_bits), "undo puts the point back exactly");
}

#[test]
fn an_oblique_slice_turns_about_the_crosshair() {
    if no_adapter() {
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let mut harness = open_mri_pair(dir.path(), egui::vec2(1100.0, 820.0));
    let straight = harness.state().ready().expect("loaded").slice_plane(0);
    harness.get_by_label("Axial oblique").click();
    harness.run_steps(2);
    harness.get_by_label("Axial tilt");
    harness.state_mut().ready_mut().expect("loaded").document.settings.oblique[0].tilt_deg = 30.0;
    harness.state_mut().ready_mut().expect("loaded").invalidate();
    harness.run_steps(3);
    let ready = harness.state().ready().expect("loaded");
    assert!(ready.fit.error.is_none(), "{:?}", ready.fit.error);
    let turned = ready.slice_plane(0);
    let dot: f64 = (0..3).map(|i| straight.normal_ref().expect("n")[i] * turned.normal_ref().expect("n")[i]).sum();
    assert!((dot.abs() - 30f64.to_radians().cos()).abs() < 1e-6, "normals at {} deg", dot.abs().acos().to_degrees());
    // It turns about the crosshair: the crosshair point lies on the turned plane.
    let s = ready.slice_mm;
    let d = turned.pixel_from_ref([s[2], s[1], s[0]]).expect("plane")[2];
    assert!(d.abs() < 1e-6, "crosshair {d} mm off the plane");
    assert_eq!(turned.size, straight.size);
}

/// Steps until the window's export finishes (or 2 min pass); returns the message it left.
fn wait_for_export(harness: &mut Harness<'_, Workbench>) -> String {
    let start = Instant::now();
    while harness.state().ready().expect("loaded").files.export.is_some() {
        harness.step();
        assert!(start.elapsed() < Duration::from_mins(2), "the export did not finish");
        std::thread::sleep(Duration::from_millis(20));
    }
    harness.run_steps(2);
    harness.state().ready().expect("loaded").files.message.clone().unwrap_or_default()
}

#[test]
fn exports_the_warped_volume_and_the_field_as_the_command_line_does() {
    if no_adapter() {
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let mut harness = open_mri_pair(dir.path(), egui::vec2(1100.0, 900.0));
    let csv = dir.path().join("pairs.csv");

    // A bad name is refused before anything runs. (The export section is at the bottom of the side panel.)
    harness.get_by_label("Export file").scroll_to_me();
    harness.run_steps(3);
    harness.get_by_label("Export file").focus();
    harness.get_by_label("Export file").type_text(&dir.path().join("warped.txt").display().to_string());
    harness.run_steps(2);
    harness.get_by_label("Export warped volume").click();
    harness.run_steps(2);
    let message = harness.state().ready().expect("loaded").files.message.clone().unwrap_or_default();
    assert!(message.contains(".nii"), "{message}");
    assert!(!dir.path().join("warped.txt").exists());

    let warped = dir.path().join("warped.nii.gz");
    harness.state_mut().ready_mut().expect("loaded").files.export_fields.out = warped.display().to_string();
    harness.run_steps(2);
    harness.get_by_label("Export warped volume").click();
    harness.run_steps(1);
    let message = wait_for_export(&mut harness);
    assert!(message.starts_with("wrote ") && message.contains("5 pairs"), "{message}");

    let field_out = dir.path().join("field.nii.gz");
    harness.state_mut().ready_mut().expect("loaded").files.export_fields.out = field_out.display().to_string();
    harness.run_steps(2);
    harness.get_by_label("Export displacement field").scroll_to_me();
    harness.run_steps(3);
    harness.get_by_label("Export displacement field").click();
    harness.run_steps(1);
    let message = wait_for_export(&mut harness);
    assert!(message.contains("displacement field"), "{message}");

    // The same files as `warpbench warp --exact` and `warpbench field` write for the same inputs, byte for byte.
    let cli = |args: &[&str]| {
        let out = std::process::Command::new(env!("CARGO_BIN_EXE_warpbench")).args(args).output().expect("run");
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    };
    let (m, c) = (mri().display().to_string(), csv.display().to_string());
    let cli_warped = dir.path().join("cli_warped.nii.gz");
    let cli_field = dir.path().join("cli_field.nii.gz");
    let common = ["--fixed", m.as_str(), "--moving", m.as_str(), "--landmarks", c.as_str(), "--quiet"];
    let warped_arg = cli_warped.display().to_string();
    cli(&[&["warp"], &common[..], &["--exact", "--interp", "linear", "--out", warped_arg.as_str()]].concat());
    let field_arg = cli_field.display().to_string();
    cli(&[&["field"], &common[..], &["--out", field_arg.as_str()]].concat());
    assert!(std::fs::read(&warped).expect("window's") == std::fs::read(&cli_warped).expect("CLI's"), "warped volume");
    assert!(std::fs::read(&field_out).expect("window's") == std::fs::read(&cli_field).expect("CLI's"), "field");
}

#[test]
fn snapshot_with_nothing_open() {
    if no_adapter() {
        return;
    }
    // Nothing open: the menu, the message and the demo button.
    let opts = GuiOptions {
        fixed: Some(Path::new("/nonexistent/fixed.nii").to_path_buf()),
        moving: Some(mri()),
        ..GuiOptions::default()
    };
    let mut harness =
        Harness::builder().with_size(egui::vec2(640.0, 240.0)).wgpu().build_eframe(|cc| Workbench::new(cc, opts));
    wait_for_failure(&mut harness);
    harness.run_steps(2);
    harness.snapshot("no_volumes");
}

#[test]
fn the_3d_view_is_shown_reduced_at_once_then_refined_to_the_one_pass_image() {
    if no_adapter() {
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let mut harness = open_mri_pair(dir.path(), egui::vec2(900.0, 600.0));
    let cpu = harness.state().ready().expect("ready").viewer.ctx.is_cpu_driver();
    let ((full_w, full_h), full) = harness.state().ready().and_then(Ready::view_shown).expect("a view");
    assert!(full, "the view is not refined after loading");
    harness.get_by_label("Reset camera").click();
    harness.step();
    harness.step();
    let ready = harness.state().ready().expect("ready");
    let (size, full) = ready.view_shown().expect("a view");
    if cpu {
        // The camera moved: a reduced view at once, the full one still to come.
        assert!(!full && size.0 <= full_w && size.1 <= full_h, "{size:?} full {full}");
        assert!(ready.needs_render(), "nothing left to refine");
    }
    // A thread adds bands until the full view is shown.
    let mut progress = vec![ready.view_refine_progress().unwrap_or(0.0)];
    let start = Instant::now();
    while harness.state().ready().is_some_and(Ready::needs_render) {
        harness.step();
        if let Some(p) = harness.state().ready().and_then(Ready::view_refine_progress) {
            progress.push(p);
        }
        assert!(start.elapsed() < Duration::from_mins(1), "not refined within a minute");
    }
    eprintln!("refined in {} frames: {progress:?}", progress.len());
    assert!(progress.windows(2).all(|w| w[1] >= w[0]), "the progress went back: {progress:?}");
    let ready = harness.state().ready().expect("ready");
    assert_eq!(ready.view_shown(), Some(((full_w, full_h), true)));
    // The refined image is the one-pass full-quality render, glyphs included, bit for bit.
    let shown = ready.read_view().expect("read the view");
    let once = ready
        .viewer
        .render_view(
            &ready.camera,
            &ready.document.settings.render_settings(),
            warpbench_gpu::Quality::Full,
            (full_w, full_h),
            &ready.glyphs(),
        )
        .expect("render at once");
    let once = once.read_back(&ready.viewer.ctx).expect("read back");
    let alpha = shown.chunks(4).filter(|p| p[3] > 0).count();
    assert!(alpha * 10 > shown.len() / 4, "the view is mostly empty: {alpha} px");
    let differ = shown.iter().zip(&once).filter(|(a, b)| a != b).count();
    assert_eq!(differ, 0, "the refined view differs from the one-pass view in {differ} channels");
}

#[test]
fn keyboard_shortcuts_add_cancel_delete_and_reset() {
    if no_adapter() {
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let mut harness = open_mri_pair(dir.path(), egui::vec2(1100.0, 820.0));
    let placing = |h: &Harness<'_, Workbench>| h.state().ready().expect("ready").placing();
    // Space starts adding a pair, Esc cancels it.
    harness.key_press(egui::Key::Space);
    harness.run_steps(2);
    assert_eq!(placing(&harness), Placing::Source);
    harness.key_press(egui::Key::Escape);
    harness.run_steps(2);
    assert_eq!(placing(&harness), Placing::Idle);
    // Delete removes the selected pair (here Pt-1, the second, selected by its Go to button); Ctrl+Z brings it back.
    harness.get_by_label("Go to Pt-1").click();
    harness.run_steps(2);
    assert_eq!(harness.state().ready().expect("ready").selected, Some(1));
    harness.key_press(egui::Key::Delete);
    harness.run_steps(3);
    let names = |h: &Harness<'_, Workbench>| -> Vec<String> {
        h.state().ready().expect("ready").document.pairs.iter().map(|p| p.name.clone()).collect()
    };
    assert_eq!(names(&harness), ["Pt-0", "Pt-2", "Pt-3", "Pt-4"]);
    assert_eq!(harness.state().ready().expect("ready").fitted_pairs(), 4);
    harness.key_press_modifiers(egui::Modifiers::COMMAND, egui::Key::Z);
    harness.run_steps(3);
    assert_eq!(names(&harness), ["Pt-0", "Pt-1", "Pt-2", "Pt-3", "Pt-4"]);
    // With nothing selected, Delete deletes nothing.
    harness.key_press(egui::Key::Escape);
    harness.run_steps(2);
    assert_eq!(harness.state().ready().expect("ready").selected, None);
    harness.key_press(egui::Key::Delete);
    harness.run_steps(2);
    assert_eq!(names(&harness).len(), 5);
    // R puts a turned camera back.
    harness.state_mut().ready_mut().expect("ready").camera.azimuth_rad = 2.0;
    harness.key_press(egui::Key::R);
    harness.run_steps(2);
    assert!((harness.state().ready().expect("ready").camera.azimuth_rad - 0.6).abs() < 1e-6);
    // A single key typed into a text field stays there: R into a pair's name does not reset the camera.
    harness.state_mut().ready_mut().expect("ready").camera.azimuth_rad = 2.0;
    harness.get_by_label("Name of pair 1").click();
    harness.run_steps(2);
    harness.key_press(egui::Key::R);
    harness.run_steps(2);
    assert!((harness.state().ready().expect("ready").camera.azimuth_rad - 2.0).abs() < 1e-6, "R reset the camera");
}

#[test]
fn snapshot_of_the_pair() {
    if no_adapter() {
        return;
    }
    // The MRI pair with its five landmarks; the status bar (adapter name, frame time) is masked. The 900×600 window
    // is drawn at 0.28 pixels per point, so that the golden image stays within 256² (252×168).
    let dir = tempfile::tempdir().expect("tempdir");
    let mut harness = open_mri_pair_at(dir.path(), egui::vec2(900.0, 600.0), 0.28);
    let status = harness.get_by_label_contains("last frame").rect();
    harness.mask(egui::Rect::from_x_y_ranges(0.0..=900.0, (status.top() - 4.0)..=600.0));
    harness.snapshot("mri_pair");
}

#[test]
fn a_landmark_is_dragged_along_the_surface_in_the_3d_view() {
    if no_adapter() {
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let mut harness = open_mri_pair(dir.path(), egui::vec2(1100.0, 820.0));
    let rect = harness.get_by_label("3-D view").rect();
    let ready = harness.state().ready().expect("loaded");
    // Where pair 3's fixed point is drawn: the camera's projection onto the view's rect.
    let q = ready.document.pairs[3].fixed.expect("fixed").coords();
    let clip = ready.camera.clip_from_ref(rect.width() / rect.height())
        * warpbench_gpu::glam::Vec3::from_array(q.map(|v| v as f32)).extend(1.0);
    let (x, y) = (clip.x / clip.w, clip.y / clip.w);
    let start = rect.min + egui::vec2((x * 0.5 + 0.5) * rect.width(), (0.5 - y * 0.5) * rect.height());
    let end = start + egui::vec2(0.0, 25.0);
    let camera_before = ready.camera.azimuth_rad;
    let button = |pos, pressed| egui::Event::PointerButton {
        pos,
        button: egui::PointerButton::Primary,
        pressed,
        modifiers: egui::Modifiers::default(),
    };
    harness.input_mut().events.push(egui::Event::PointerMoved(start));
    harness.input_mut().events.push(button(start, true));
    harness.step();
    for t in [0.3f32, 0.6, 1.0] {
        harness.input_mut().events.push(egui::Event::PointerMoved(start + (end - start) * t));
        harness.step();
    }
    let during = harness.state().ready().expect("loaded");
    assert_eq!(during.drag().map(|d| (d.pair, d.end)), Some((3, warpbench_app::gui::End::Fixed)), "grabbed");
    harness.input_mut().events.push(button(end, false));
    harness.run_steps(3);
    let ready = harness.state().ready().expect("loaded");
    assert!(ready.fit.error.is_none(), "{:?}", ready.fit.error);
    assert!((ready.camera.azimuth_rad - camera_before).abs() < 1e-6, "a landmark drag does not orbit the camera");
    let moved = ready.document.pairs[3].fixed.expect("fixed").coords();
    // The pointer went down the screen: the point moved, to the visible surface (picked on the fixed volume), and
    // stays inside the head.
    let d: f64 = (0..3).map(|a| (moved[a] - q[a]).powi(2)).sum::<f64>().sqrt();
    assert!(d > 5.0, "moved {d} mm: {q:?} -> {moved:?}");
    assert!(moved[2] < q[2], "down the screen is inferior here: {q:?} -> {moved:?}");
    let inside = |c: [f64; 3]| c[0].abs() < 91.0 && (-91.0..127.0).contains(&c[1]) && (-73.0..109.0).contains(&c[2]);
    assert!(inside(moved), "{moved:?}");
    assert_eq!(ready.fitted_pairs(), 5);

    // Orbit away, then Reset camera brings the starting view back.
    harness.state_mut().ready_mut().expect("loaded").camera.azimuth_rad = 2.5;
    harness.get_by_label("Reset camera").click();
    harness.run_steps(2);
    let camera = harness.state().ready().expect("loaded").camera;
    assert!((camera.azimuth_rad - 0.6).abs() < 1e-6 && (camera.elevation_rad - 0.25).abs() < 1e-6, "{camera:?}");
}

#[test]
fn the_control_texture_made_on_the_gpu_equals_the_cpu_one() {
    if no_adapter() {
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let mut harness = open_mri_pair(dir.path(), egui::vec2(900.0, 640.0));
    for method in ["tps", "hbspline"] {
        let ready = harness.state_mut().ready_mut().expect("loaded");
        ready.document.settings.method = method.parse().expect("a method");
        // The CPU's texels: the same fit and grid, sampled by the solver (f64), as the window's CPU path uploads them.
        let (fixed, moving): (Vec<_>, Vec<_>) = ready
            .document
            .pairs
            .iter()
            .map(|p| {
                (
                    warpbench_solver::spaces::as_fixed(p.fixed.expect("fixed")),
                    warpbench_solver::spaces::as_moving(p.moving.expect("moving")),
                )
            })
            .unzip();
        let boxes = (
            warpbench_app::inputs::volume_box(&ready.loaded.fixed),
            warpbench_app::inputs::volume_box(&ready.loaded.moving),
        );
        let n = ready.document.settings.grid_n;
        let (fitted, _) =
            warpbench_app::gui::fit_warp(&ready.document.settings.method(), &fixed, &moving, boxes, n, true)
                .expect("fit");
        let (_, texture) = warpbench_app::scene::control_texture(fitted.pullback.as_ref(), boxes.0, n).expect("sample");
        let cpu: Vec<[f32; 4]> = texture.as_f32s().chunks_exact(4).map(|c| [c[0], c[1], c[2], c[3]]).collect();
        // The GPU's: evaluated into the window's control texture.
        ready.control_eval = warpbench_app::gui::ControlEval::Gpu;
        ready.refit();
        assert!(ready.fit.error.is_none(), "{method}: {:?}", ready.fit.error);
        assert!(ready.viewer.control_made_on_gpu(), "{method}: the texture was not evaluated on the GPU");
        let control = ready.viewer.control.as_ref().expect("a control texture");
        assert_eq!(control.info.dims.map(|d| d as usize), [n; 3]);
        let gpu = warpbench_gpu::control_eval::read_back_texels(&ready.viewer.ctx, control).expect("read back");
        assert_eq!(gpu.len(), cpu.len());
        let largest = cpu.iter().flat_map(|t| t[..3].iter()).fold(0.0f32, |m, v| m.max(v.abs()));
        assert!(largest > 1.0, "{method}: the warp moves things: {largest} mm");
        let worst =
            cpu.iter().zip(&gpu).flat_map(|(a, b)| (0..3).map(move |i| (a[i] - b[i]).abs())).fold(0.0f32, f32::max);
        // The same function on the same grid: f64 on the CPU against f32 on the GPU (a TPS about the box centre),
        // and f16 storage where float32 textures do not filter.
        assert!(
            worst < 0.01 + 1e-3 * largest,
            "{method}: worst texel difference {worst} mm (largest displacement {largest} mm)"
        );
        harness.run_steps(2);
        assert!(harness.state().ready().expect("loaded").fit.error.is_none());
    }
}

#[test]
fn undo_of_every_command_gives_the_document_back_and_view_commands_leave_it() {
    use warpbench_app::gui::Command;
    use warpbench_app::gui::panels::FileAction;
    use warpbench_io::geometry::Point3;
    if no_adapter() {
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let mut harness = open_mri_pair(dir.path(), egui::vec2(900.0, 640.0));
    let imported = dir.path().join("three.csv");
    common::write_pairs_csv(&imported, &[([1.0, 2.0, 3.0], [4.0, 5.0, 6.0]); 3]);
    let ready = harness.state_mut().ready_mut().expect("loaded");
    let mut settings = ready.document.settings.clone();
    settings.method = warpbench_app::settings::MethodKind::Rigid;
    settings.blend = warpbench_app::settings::Blend::Difference;
    settings.oblique[2].on = true;
    let mut looks = ready.document.layers;
    (looks[1].visible, looks[0].window_high) = (false, looks[0].window_high + 10.0);
    let edits = [
        Command::AddPair { moving: Point3::new(1.0, 10.0, 20.0), fixed: Point3::new(2.0, 10.0, 20.0) },
        Command::MovePoint { pair: 0, end: warpbench_app::gui::End::Fixed, to: [1.0, 2.0, 3.0], settled: true },
        Command::MovePoint { pair: 1, end: warpbench_app::gui::End::Moving, to: [4.0, 5.0, 6.0], settled: false },
        Command::DeletePair(2),
        Command::RenamePair(0, "renamed".into()),
        Command::SetActive(1, false),
        Command::SetSettings(settings),
        Command::SetLooks(looks),
        Command::File(FileAction::ImportLandmarks(imported)),
    ];
    for command in edits {
        let before = ready.document.clone();
        ready.apply(command.clone());
        ready.settle(false);
        let after = ready.document.clone();
        assert_ne!(after, before, "{command:?} changes the document");
        ready.apply(Command::Undo);
        assert_eq!(ready.document, before, "undo of {command:?}");
        ready.apply(Command::Redo);
        assert_eq!(ready.document, after, "redo of {command:?}");
    }
    let views = [
        Command::ToggleAdding,
        Command::Cancel,
        Command::Select(1),
        Command::JumpTo(0),
        Command::MoveSlice(1, 12.0),
        Command::CentreSlices([1.0, 2.0, 3.0]),
        Command::ResetCamera,
        Command::ShowWorstPair,
        Command::TogglePulse,
    ];
    for command in views {
        let before = ready.document.clone();
        ready.apply(command.clone());
        ready.settle(false);
        assert_eq!(ready.document, before, "{command:?} leaves the document");
    }
    // None of the view commands was an undo step: undo goes back to before the import.
    ready.apply(Command::Undo);
    assert_eq!(ready.document.pairs.len(), 5, "{:?}", ready.document.pairs);
}

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
            .render_view(&ready.camera, &settings, warpbench_gpu::Quality::Full, (64, 64), &[])
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
    use warpbench_app::gui::panels::loo_ranking;
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
    harness.get_by_label("Show the worst pair").click_accesskit();
    harness.run_steps(3);
    let ready = harness.state_mut().ready_mut().expect("ready");
    assert_eq!(ready.selected, Some(worst));
    assert!(ready.attention.is_on(), "the lens pulses");
    let q = ready.document.pairs[worst].fixed.expect("a fixed point").coords();
    assert!((ready.slice_mm[0] - q[2]).abs() < 1e-9 && (ready.slice_mm[2] - q[0]).abs() < 1e-9, "the views go there");
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
        let t = ready.viewer.render_view(&ready.camera, &settings, warpbench_gpu::Quality::Full, (64, 64), &[]);
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

    harness.get_by_label("Pulse the selected pair").click_accesskit();
    harness.run_steps(3);
    let ready = harness.state().ready().expect("ready");
    assert!(!ready.attention.is_on() && ready.view_lens(Instant::now()).is_none(), "switched off");
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
    harness.get_by_label("Open with a leafer").click_accesskit();
    harness.run_steps(3);
    let ready = harness.state().ready().expect("ready");
    assert_eq!(ready.leafer, Leafer::Open { side: Side::Moving, angle_deg: 30.0 });
    let [None, Some(leafer @ warpbench_gpu::ViewDeformation::Leafer { .. })] =
        ready.view_deformations(std::time::Instant::now())
    else {
        panic!("the leafer on the moving volume")
    };
    wait_until_rendered(&mut harness);

    // The pick the click makes, through the leafer: its point x_ref on the ray is shown turned, w(x) ≠ x, and what
    // it reports is the undeformed moving volume's point u(w(x)), which the warp shows at w(x).
    let offset = 0.2;
    let ready = harness.state().ready().expect("ready");
    let (size, _) = ready.view_shown().expect("a view");
    let pixel = [size.0 as f32 * (0.5 + offset), size.1 as f32 * 0.5];
    let settings = ready.document.settings.render_settings();
    let probe = ready.document.settings.probe();
    let hit = ready
        .viewer
        .pick(&ready.camera, &settings, size, pixel, warpbench_gpu::PickTarget::Moving, probe)
        .expect("pick")
        .expect("a hit on the opened moving volume");
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
        panic!("the click placed no source: {:?} {:?}", ready.fit.error, ready.notice)
    };
    let stored = warpbench_gpu::glam::DVec3::from_array(moving.coords());
    assert!(stored.distance(warpbench_gpu::glam::Vec3::from_array(hit.p_lps).as_dvec3()) < 1e-3, "{stored}");
    assert_eq!(ready.document, before, "the leafer is not part of the document");

    harness.get_by_label("Open with a leafer").click_accesskit();
    harness.run_steps(3);
    assert_eq!(harness.state().ready().expect("ready").leafer, Leafer::Closed);
}
