//! What the screenshot examples (`tool_screenshots.rs`, `assisted_screenshots.rs`) share: waiting for the window to
//! settle and writing what it shows.

use std::path::Path;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use egui_kittest::Harness;
use warpbench_app::gui::Workbench;

/// Steps until the views are drawn fully, the fit's diagnostics are in and no Auto-align or refinement by intensities
/// runs (or `limit` passes).
pub fn settle(harness: &mut Harness<'_, Workbench>, limit: Duration) -> Result<()> {
    let start = Instant::now();
    loop {
        harness.step();
        if let Some(e) = harness.state().failure() {
            bail!("loading failed: {e}");
        }
        let idle = |r: &warpbench_app::gui::Ready| {
            !r.needs_render() && !r.diagnostics_pending() && !r.aligning() && r.refining().is_none()
        };
        if harness.state().ready().is_some_and(idle) {
            harness.run_steps(2);
            return Ok(());
        }
        if start.elapsed() > limit {
            bail!("the window did not settle within {limit:?}");
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// Writes the window as drawn to `out/name` (PNG).
pub fn save(harness: &mut Harness<'_, Workbench>, out: &Path, name: &str) -> Result<()> {
    let image = harness.render().map_err(|e| anyhow::anyhow!("rendering the window: {e}"))?;
    let path = out.join(name);
    image.save(&path).with_context(|| format!("writing {}", path.display()))?;
    eprintln!("wrote {}", path.display());
    Ok(())
}
