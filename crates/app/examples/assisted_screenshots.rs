//! The assisted workflow of `docs/user-guide.md` on the demo volumes (the Cranium head CT as fixed, the Colin27 head
//! MRI as moving, no landmarks), drawn headlessly through egui_kittest and written as its screenshots:
//!
//! ```text
//! cargo run --release -p warpbench-app --example assisted_screenshots -- docs/images
//! ```
//!
//! - `auto-align.png`: after **Auto-align affine** (MRI to CT by mutual information), the MRI shown through the
//!   starting transform alone, blended with the CT.
//! - `suggested-target.png`: **Add pair**, the moving point placed where the aligned MRI shows the scalp at the side of
//!   the head level with the CT's centre, and the suggested target drawn as a ghost, waiting for Enter.
//! - `refine-by-intensities.png`: that pair given up (Esc), then **Refine by intensities** from the alignment: the MRI
//!   registered to the CT deformably by mutual information, the *Assist* section saying what it did.

#[path = "shots/mod.rs"]
mod shots;

use std::path::{Path, PathBuf};
use std::time::Duration;

use anyhow::{Context, Result, bail};
use eframe::egui;
use egui_kittest::Harness;
use egui_kittest::kittest::Queryable;
use shots::{save, settle};
use warpbench_app::gui::{Command, GuiOptions, Workbench};
use warpbench_solver::align::AlignKind;

fn main() -> Result<()> {
    let Some(out) = std::env::args().nth(1).map(PathBuf::from) else { bail!("usage: assisted_screenshots OUT_DIR") };
    let data = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/nifti");
    let state = tempfile::tempdir().context("a temporary folder for the autosave")?;
    let opts = GuiOptions {
        fixed: Some(data.join("cranium_ct.nii.gz")),
        moving: Some(data.join("ch2.nii.gz")),
        autosave: Some(state.path().join("autosave.warpbench.json")),
        ..GuiOptions::default()
    };
    let mut harness =
        Harness::builder().with_size(egui::vec2(1280.0, 900.0)).wgpu().build_eframe(|cc| Workbench::new(cc, opts));
    settle(&mut harness, Duration::from_mins(10))?;

    // Auto-align affine: the MRI onto the CT by mutual information.
    let ready = harness.state_mut().ready_mut().context("the pair")?;
    ready.apply(Command::AutoAlign(AlignKind::Affine));
    settle(&mut harness, Duration::from_mins(10))?;
    let ready = harness.state().ready().context("the pair")?;
    let start = ready.document.start.clone().context("Auto-align gave no starting transform")?;
    eprintln!("{}", start.origin);
    save(&mut harness, &out, "auto-align.png")?;

    // A new pair: the moving point where the aligned MRI shows the scalp beside the CT's centre, and its suggestion.
    let ready = harness.state_mut().ready_mut().context("the pair")?;
    let fixed = std::sync::Arc::clone(&ready.loaded.fixed);
    let centre = [fixed.dims[0] / 2, fixed.dims[1] / 2, fixed.dims[2] / 2];
    // Along the i axis from the centre until the CT reads air: the scalp at the side of the head.
    let mut top = None;
    for i in centre[0]..fixed.dims[0] {
        let v =
            fixed.data.get_f64(fixed.offset(i, centre[1], centre[2])) * fixed.rescale.slope + fixed.rescale.intercept;
        if v < -500.0 {
            top = Some(fixed.voxel_lps(i.saturating_sub(2), centre[1], centre[2]).coords());
            break;
        }
    }
    let x_ref = top.context("no scalp beside the CT's centre")?;
    ready.view.slice_mm = [x_ref[2], x_ref[1], x_ref[0]];
    ready.apply(Command::ToggleAdding);
    ready.place_at_ref(x_ref, None);
    let suggestion = ready.suggestion().context("no suggestion (the status bar says why)")?;
    eprintln!("suggested {:?}, confidence {:.2}", suggestion.fixed_lps, suggestion.confidence);
    ready.invalidate();
    settle(&mut harness, Duration::from_mins(10))?;
    save(&mut harness, &out, "suggested-target.png")?;

    // Refine by intensities from the alignment (no pairs), with the Assist section open to show what it did.
    let ready = harness.state_mut().ready_mut().context("the pair")?;
    ready.apply(Command::Cancel);
    ready.apply(Command::UseSelect);
    ready.apply(Command::RefineByIntensities);
    // Warp closed and Assist open, so the section's summary fits the panel.
    harness.get_by_label("Warp").click_accesskit();
    harness.get_by_label("Assist").click_accesskit();
    settle(&mut harness, Duration::from_mins(10))?;
    let ready = harness.state().ready().context("the pair")?;
    let refined = ready.assist.refined.as_ref().context("the refinement gave no field (the status bar says why)")?;
    eprintln!("{}", refined.refined.summary);
    save(&mut harness, &out, "refine-by-intensities.png")?;
    Ok(())
}
