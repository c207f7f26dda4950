//! The real binary opens its window under Xvfb on the CPU drivers, shows the demo pair, saves a screenshot and
//! exits: the picture must be the window (its size), not empty, and must vary (the rendered pair, not a blank or
//! single-colour frame).
//!
//! Runs when `xvfb-run` is on the PATH; CI installs it and sets REQUIRE_XVFB=1, so there a missing Xvfb fails.

use std::process::Command;

fn xvfb_run_available() -> bool {
    Command::new("sh").args(["-c", "command -v xvfb-run"]).output().is_ok_and(|o| o.status.success())
}

#[test]
fn the_window_shows_the_demo_pair_under_xvfb() {
    if !xvfb_run_available() {
        assert!(std::env::var_os("REQUIRE_XVFB").is_none(), "REQUIRE_XVFB=1 but xvfb-run is not installed");
        eprintln!("skipped: no xvfb-run");
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let shot = dir.path().join("shot.png");
    let out = Command::new("xvfb-run")
        .args(["-a", "-s", "-screen 0 1280x900x24"])
        .arg(env!("CARGO_BIN_EXE_warpbench"))
        .arg("--screenshot")
        .arg(&shot)
        .args(["--exit-after-frames", "3"])
        .env("XDG_RUNTIME_DIR", dir.path())
        .env("WARPBENCH_STATE_DIR", dir.path())
        .output()
        .expect("run xvfb-run");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "the window failed: {stderr}");
    let img = image::open(&shot).unwrap_or_else(|e| panic!("no screenshot ({e}); stderr: {stderr}")).to_rgba8();
    let (w, h) = img.dimensions();
    assert!(w >= 1000 && h >= 700, "the screenshot is {w}×{h}, not the window");
    // The window's background is uniform; the rendered pair, slices and text make many distinct colours.
    let mut colours: Vec<u32> = img.pixels().map(|p| u32::from_le_bytes(p.0)).collect();
    colours.sort_unstable();
    colours.dedup();
    assert!(colours.len() > 500, "only {} distinct colours: the views are empty", colours.len());
    // The 3-D view (the window's right part, above the slice strip) shows the pair: bright, varied pixels.
    let bright = (w / 3..w)
        .flat_map(|x| (h / 8..h / 2).map(move |y| (x, y)))
        .filter(|&(x, y)| img.get_pixel(x, y).0[..3].iter().map(|&c| u32::from(c)).sum::<u32>() > 300)
        .count();
    assert!(bright > 5_000, "the 3-D view has only {bright} bright pixels");
    // The exit was normal: the autosave says so (a crash would leave clean_exit false, and the next start offers
    // recovery).
    let autosave = dir.path().join("autosave.warpbench.json");
    let text = std::fs::read_to_string(&autosave).expect("the window autosaves on exit");
    assert!(text.contains("\"clean_exit\": true"), "{text}");
}
