//! Helpers for the tests that drive the window headlessly through egui_kittest (`gui.rs`, `placement.rs`).
#![allow(dead_code, reason = "each test binary uses a subset")]

use std::time::{Duration, Instant};

use eframe::egui;
use egui_kittest::Harness;
use warpbench_app::gui::Workbench;

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

/// A primary-button click at `pos` (window points): press, then release on the next frame.
pub fn click_at(harness: &mut Harness<'_, Workbench>, pos: egui::Pos2) {
    harness.input_mut().events.push(egui::Event::PointerMoved(pos));
    harness.input_mut().events.push(button(pos, true));
    harness.step();
    harness.input_mut().events.push(button(pos, false));
    harness.run_steps(2);
}
