//! Helpers for the tests that drive the window headlessly through egui_kittest (`gui*.rs`, `placement.rs`).
#![allow(dead_code, reason = "each test binary uses a subset")]

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use eframe::egui;
use egui_kittest::Harness;
use egui_kittest::kittest::Queryable;
use warpbench_app::gui::{GuiOptions, Workbench};
use warpbench_app::inputs::LandmarkSource;

use crate::common::mri;

/// Steps the harness until the pair is loaded and drawn at full quality (or fails, or three minutes pass: the demo
/// pair on a loaded 2-core machine).
pub fn wait_until_shown(harness: &mut Harness<'_, Workbench>) {
    let start = Instant::now();
    loop {
        harness.step();
        if let Some(e) = harness.state().failure() {
            panic!("loading failed: {e}");
        }
        if harness.state().ready().is_some() {
            // A few more frames so the layout settles (clicks go to last frame's positions).
            harness.run_steps(3);
            wait_until_rendered(harness);
            return;
        }
        assert!(start.elapsed() < Duration::from_mins(3), "the pair was not shown within three minutes");
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// Steps the harness until the views are rendered fully (on a CPU driver the 3-D view is refined band by band on a
/// thread) and the fit's diagnostics are shown (they follow on a thread too), or three minutes pass.
pub fn wait_until_rendered(harness: &mut Harness<'_, Workbench>) {
    let start = Instant::now();
    while harness.state().ready().is_some_and(|r| r.needs_render() || r.diagnostics_pending()) {
        harness.step();
        assert!(start.elapsed() < Duration::from_mins(3), "the views were not rendered within three minutes");
    }
}

/// Whether there is no GPU adapter (the test is then skipped, unless REQUIRE_GPU_ADAPTER is set).
pub fn no_adapter() -> bool {
    let missing = std::env::var_os("REQUIRE_GPU_ADAPTER").is_none() && warpbench_gpu::GpuContext::headless().is_err();
    if missing {
        eprintln!("skipped: no GPU adapter");
    }
    missing
}

/// A primary-button event at `pos`.
pub fn button(pos: egui::Pos2, pressed: bool) -> egui::Event {
    egui::Event::PointerButton {
        pos,
        button: egui::PointerButton::Primary,
        pressed,
        modifiers: egui::Modifiers::default(),
    }
}

/// Presses the primary button at `start` and moves the pointer towards `end` through the fractions `steps` of the
/// way, a frame each, leaving the button held (release it with [`button`]`(end, false)`).
pub fn press_and_drag(harness: &mut Harness<'_, Workbench>, start: egui::Pos2, end: egui::Pos2, steps: &[f32]) {
    harness.input_mut().events.push(egui::Event::PointerMoved(start));
    harness.input_mut().events.push(button(start, true));
    harness.step();
    for t in steps {
        harness.input_mut().events.push(egui::Event::PointerMoved(start + (end - start) * *t));
        harness.step();
    }
}

/// A primary-button click at `pos` (window points): press, then release on the next frame.
pub fn click_at(harness: &mut Harness<'_, Workbench>, pos: egui::Pos2) {
    harness.input_mut().events.push(egui::Event::PointerMoved(pos));
    harness.input_mut().events.push(button(pos, true));
    harness.step();
    harness.input_mut().events.push(button(pos, false));
    harness.run_steps(2);
}

/// Five pairs on the MRI, the moving points shifted by a few mm.
pub fn pairs(dir: &Path) -> PathBuf {
    let q = [[0.0, 18.0, 18.0], [40.0, 18.0, 18.0], [-40.0, 30.0, 0.0], [0.0, 70.0, 40.0], [10.0, -40.0, 18.0]];
    let pairs: Vec<([f64; 3], [f64; 3])> =
        q.iter().enumerate().map(|(i, q)| ([q[0] + 3.0, q[1] - 2.0 + i as f64, q[2] + 1.5], *q)).collect();
    let path = dir.join("pairs.csv");
    crate::common::write_pairs_csv(&path, &pairs);
    path
}

/// Steps until loading has failed (or a minute passes: a guard against a hang on a loaded machine, not a timing).
pub fn wait_for_failure(harness: &mut Harness<'_, Workbench>) {
    let start = Instant::now();
    while harness.state().failure().is_none() {
        harness.step();
        assert!(start.elapsed() < Duration::from_mins(1), "no error shown");
        std::thread::sleep(Duration::from_millis(10));
    }
}

/// A window of `size` on the MRI fixture as fixed and moving, with the five pairs of [`pairs`] and an autosave in
/// `dir`, stepped until the pair is shown.
pub fn open_mri_pair(dir: &Path, size: egui::Vec2) -> Harness<'static, Workbench> {
    open_mri_pair_at(dir, size, 1.0)
}

/// [`open_mri_pair`] drawn at `pixels_per_point`.
pub fn open_mri_pair_at(dir: &Path, size: egui::Vec2, pixels_per_point: f32) -> Harness<'static, Workbench> {
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

/// Opens the side panel's section titled `title` (View and Warp are open at the start, the others closed).
pub fn open_section(harness: &mut Harness<'_, Workbench>, title: &str) {
    harness.get_by_label(title).click_accesskit();
    // The section opens over a few frames.
    harness.run_steps(12);
}

/// Steps until the window's export finishes (or 2 min pass); returns the message it left.
pub fn wait_for_export(harness: &mut Harness<'_, Workbench>) -> String {
    let start = Instant::now();
    while harness.state().ready().expect("loaded").files.export.is_some() {
        harness.step();
        assert!(start.elapsed() < Duration::from_mins(2), "the export did not finish");
        std::thread::sleep(Duration::from_millis(20));
    }
    harness.run_steps(2);
    harness.state().ready().expect("loaded").files.message.clone().unwrap_or_default()
}
