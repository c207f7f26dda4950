//! The window's tools on the demo pair, drawn headlessly through egui_kittest (wgpu: the GPU, or Mesa's CPU driver)
//! and written as the screenshots of `docs/user-guide.md`:
//!
//! ```text
//! cargo run --release -p warpbench-app --example tool_screenshots -- docs/images
//! ```
//!
//! - `procedural.png`: the synthetic deformation, the MRI alone bent by 20 mm (seed 2), seen from the left.
//! - `attention.png`: "Show the worst pair": the attention lens pulsing about the pair with the largest leave-one-out
//!   error, taken when the pulse is near its peak. On a CPU driver a pulsing view is drawn at the interaction size.
//! - `leafer.png`: the moving volume (the MRI, alone) opened by the leafer, 35° each way, seen from the front.
//! - `brush.png`: the displacement brush on, one stroke of radius 40 mm at the crosshair pushing the MRI (alone) 12 mm
//!   to the patient's left on top of the landmark warp, settled (its inverse fitted), in a window 1 500 pixels tall.

#[path = "shots/mod.rs"]
mod shots;

use std::path::PathBuf;
use std::time::{Duration, Instant};

use shots::{save, settle};

use anyhow::{Context, Result, bail};
use eframe::egui;
use egui_kittest::Harness;
use warpbench_app::gui::attention::PEAK_AMPLITUDE;
use warpbench_app::gui::leafer::Leafer;
use warpbench_app::gui::open::Side;
use warpbench_app::gui::{Command, GuiOptions, Workbench};
use warpbench_app::procedural::ProceduralSpec;
use warpbench_app::settings::{Blend, ProceduralKind};
use warpbench_solver::brush::BrushStroke;

fn main() -> Result<()> {
    let Some(out) = std::env::args().nth(1).map(PathBuf::from) else { bail!("usage: tool_screenshots OUT_DIR") };
    let state = tempfile::tempdir().context("a temporary folder for the autosave")?;
    let opts = GuiOptions { autosave: Some(state.path().join("autosave.warpbench.json")), ..GuiOptions::default() };
    let mut harness =
        Harness::builder().with_size(egui::vec2(1280.0, 900.0)).wgpu().build_eframe(|cc| Workbench::new(cc, opts));
    settle(&mut harness, Duration::from_mins(10))?;

    // The synthetic deformation.
    let ready = harness.state_mut().ready_mut().context("the demo pair")?;
    let plain = ready.document.settings.clone();
    let mut settings = plain.clone();
    settings.blend = Blend::MovingOnly;
    settings.procedural = Some(ProceduralSpec { kind: ProceduralKind::Bend, amplitude_mm: 20.0, seed: 2 });
    ready.apply(Command::SetSettings(settings));
    ready.view.camera.azimuth_rad = std::f32::consts::FRAC_PI_2;
    ready.view.camera.elevation_rad = 0.17;
    ready.invalidate();
    settle(&mut harness, Duration::from_mins(10))?;
    save(&mut harness, &out, "procedural.png")?;

    // The attention lens about the worst pair, near its peak.
    let ready = harness.state_mut().ready_mut().context("the demo pair")?;
    let plain_look = plain.clone();
    ready.apply(Command::SetSettings(plain));
    ready.apply(Command::ResetCamera);
    ready.apply(Command::ShowWorstPair);
    let start = Instant::now();
    loop {
        harness.step();
        let ready = harness.state().ready().context("the demo pair")?;
        if ready.view.attention.amplitude(Instant::now()) > 0.8 * PEAK_AMPLITUDE {
            break;
        }
        if start.elapsed() > Duration::from_mins(1) {
            bail!("the lens did not pulse");
        }
    }
    save(&mut harness, &out, "attention.png")?;

    // The leafer on the MRI, seen from the front.
    let ready = harness.state_mut().ready_mut().context("the demo pair")?;
    ready.apply(Command::TogglePulse);
    let mut settings = ready.document.settings.clone();
    settings.blend = Blend::MovingOnly;
    ready.apply(Command::SetSettings(settings));
    ready.apply(Command::ResetCamera);
    ready.view.camera.azimuth_rad = 0.0;
    ready.view.camera.elevation_rad = 0.1;
    ready.apply(Command::SetLeafer(Leafer::Open { side: Side::Moving, angle_deg: 35.0 }));
    settle(&mut harness, Duration::from_mins(10))?;
    save(&mut harness, &out, "leafer.png")?;

    // The brush: one settled stroke at the crosshair.
    let ready = harness.state_mut().ready_mut().context("the demo pair")?;
    ready.apply(Command::SetLeafer(Leafer::Closed));
    let mut settings = plain_look;
    settings.blend = Blend::MovingOnly;
    ready.apply(Command::SetSettings(settings));
    ready.apply(Command::ResetCamera);
    ready.apply(Command::ToggleSculpting);
    let centre_mm = [ready.view.slice_mm[2], ready.view.slice_mm[1], ready.view.slice_mm[0]];
    let stroke = BrushStroke { centre_mm, displacement_mm: [12.0, 0.0, 0.0], radius_mm: 40.0 };
    ready.apply(Command::AddStroke(stroke));
    ready.apply(Command::MoveStroke { stroke, settled: true });
    // Taller, so that the side panel shows the brush's section and the accuracy section's inverse consistency.
    harness.set_size(egui::vec2(1280.0, 1500.0));
    settle(&mut harness, Duration::from_mins(10))?;
    save(&mut harness, &out, "brush.png")?;
    Ok(())
}
