//! The status bar: the GPU, the last frame's time and the frame rate, the refinement of the 3-D view, the point
//! under the pointer with the warp's displacement and Jacobian there and the nearest pair, why a point was refused, folding, and what the warp is fitted on or why it is off.

use eframe::egui;

use super::Ready;

/// Draws the status bar at the bottom of the window.
pub fn status_bar(ui: &mut egui::Ui, ready: &Ready) {
    egui::Panel::bottom("status").show(ui, |ui| {
        ui.horizontal(|ui| {
            ui.label(format!("GPU: {}", ready.viewer.ctx.describe()));
            ui.separator();
            ui.label(format!("last frame {:.0} ms", ready.view.last_render_ms))
                .on_hover_text("What the views took to render in the last frame that rendered them");
            ui.separator();
            ui.label(ready.view.frame_rate.fps().map_or_else(|| "idle".to_owned(), |f| format!("{f:.0} fps")))
                .on_hover_text("Frames the window drew in the last second (none while nothing changes)");
            // An idle window draws nothing: one more frame once this second is over shows it idle.
            if let Some(wait) = ready.view.frame_rate.redraw_to_idle_in(std::time::Instant::now()) {
                ui.ctx().request_repaint_after(wait);
            }
            ui.separator();
            if let Some(done) = ready.view_refine_progress() {
                ui.label(format!("refining the 3-D view: {:.0} %", 100.0 * done));
                ui.separator();
            }
            if ready.diagnostics_pending() {
                ui.label("checking the fit: leave-one-out, folding")
                    .on_hover_text("The table's errors and the folding check follow the fit on a thread of their own");
                ui.separator();
            }
            if let Some(c) = ready.pointer.cursor {
                let ([l, p, s], [ml, mp, ms]) = (c.fixed_lps, c.moving_lps);
                ui.label(format!(
                    "cursor LPS fixed ({l:.1}, {p:.1}, {s:.1}) mm, moving ({ml:.1}, {mp:.1}, {ms:.1}) mm"
                ))
                .on_hover_text("The fixed point under the pointer, and the moving point the warp shows there");
                let name = c.nearest.and_then(|n| ready.document.pairs.get(n.index)).map_or("", |p| p.name.as_str());
                let readout = c.readout(name);
                ui.label(readout).on_hover_text(
                    "How far the warp moves this point, det of its Jacobian (below 0 it folds, below 1 it shrinks), and \
                     the nearest pair with its leave-one-out error",
                );
                ui.separator();
            }
            if let Some(s) = ready.suggestion() {
                let (colour, what) = if s.low_confidence {
                    (egui::Color32::from_rgb(255, 190, 64), "amber ghost, unsure")
                } else {
                    (egui::Color32::from_rgb(140, 255, 140), "green ghost")
                };
                ui.colored_label(
                    colour,
                    format!(
                        "Suggested target ({what}, confidence {:.2}): Enter takes it, Esc drops it",
                        s.confidence
                    ),
                );
                ui.separator();
            }
            if let Some(n) = &ready.pointer.notice {
                ui.colored_label(egui::Color32::from_rgb(240, 200, 80), n.as_str());
                ui.separator();
            }
            if let Some(j) = ready.fit.jacobian.as_ref().filter(|j| j.min_det <= 0.0) {
                let at = j.min_at;
                ui.colored_label(
                    egui::Color32::from_rgb(235, 90, 80),
                    format!(
                        "the warp folds: {:.2} % of the box, det {:.2} at ({:.0}, {:.0}, {:.0}) mm",
                        100.0 * j.fraction_folded,
                        j.min_det,
                        at[0],
                        at[1],
                        at[2]
                    ),
                );
                ui.separator();
            }
            if let Some(e) = &ready.fit.error {
                ui.colored_label(egui::Color32::LIGHT_RED, format!("warp off: {e}"));
            } else {
                let method = ready.document.settings.method();
                let (n, needs) = (ready.fitted_pairs(), crate::inputs::min_pairs(&method));
                ui.label(match &ready.document.start {
                    Some(_) if n < needs => format!("the starting transform alone ({n} pairs; {method} needs {needs})"),
                    Some(_) => format!("{method} fitted on {n} pairs over the starting transform"),
                    None => format!("{} fitted on {n} pairs", ready.document.settings.method),
                });
            }
        });
    });
}
