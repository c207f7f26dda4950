//! The status bar, across the bottom of the window: two lines of text that are never cut off at the window's edge.
//! The most important part comes first (why a point was refused, folding, what the warp is fitted on or why it is
//! off, a suggested target, the point under the pointer with the warp's displacement and Jacobian there and the
//! nearest pair, the 3-D view's refinement), then the GPU, the last frame's time and the frame rate. What does not
//! fit in two lines ends in "…" and is shown whole in the bar's tooltip. Its height never changes, so that the views
//! above it keep their size whatever it says.

use eframe::egui;

use super::Ready;

/// The lines of text the status bar has room for.
pub const STATUS_LINES: usize = 2;

/// The status bar's items, in order of importance, each with its colour (none: the usual text colour).
#[must_use]
pub fn status_items(ready: &Ready) -> Vec<(String, Option<egui::Color32>)> {
    let mut items = Vec::new();
    if let Some(n) = &ready.pointer.notice {
        items.push((n.clone(), Some(egui::Color32::from_rgb(240, 200, 80))));
    }
    if let Some(j) = ready.fit.jacobian.as_ref().filter(|j| j.min_det <= 0.0) {
        let at = j.min_at;
        let text = format!(
            "the warp folds: {:.2} % of the box, det {:.2} at ({:.0}, {:.0}, {:.0}) mm",
            100.0 * j.fraction_folded,
            j.min_det,
            at[0],
            at[1],
            at[2]
        );
        items.push((text, Some(egui::Color32::from_rgb(235, 90, 80))));
    }
    if let Some(e) = &ready.fit.error {
        items.push((format!("warp off: {e}"), Some(egui::Color32::LIGHT_RED)));
    } else {
        let method = ready.document.settings.method();
        let (n, needs) = (ready.fitted_pairs(), crate::inputs::min_pairs(&method));
        let text = match &ready.document.start {
            Some(_) if n < needs => format!("the starting transform alone ({n} pairs; {method} needs {needs})"),
            Some(_) => format!("{method} fitted on {n} pairs over the starting transform"),
            None => format!("{} fitted on {n} pairs", ready.document.settings.method),
        };
        items.push((text, None));
    }
    if let Some(s) = ready.suggestion() {
        let (colour, what) = if s.low_confidence {
            (egui::Color32::from_rgb(255, 190, 64), "amber ghost, unsure")
        } else {
            (egui::Color32::from_rgb(140, 255, 140), "green ghost")
        };
        let text = format!("Suggested target ({what}, confidence {:.2}): Enter takes it, Esc drops it", s.confidence);
        items.push((text, Some(colour)));
    }
    if let Some(c) = ready.pointer.cursor {
        let ([l, p, s], [ml, mp, ms]) = (c.fixed_lps, c.moving_lps);
        items.push((
            format!("cursor LPS fixed ({l:.1}, {p:.1}, {s:.1}) mm, moving ({ml:.1}, {mp:.1}, {ms:.1}) mm"),
            None,
        ));
        let name = c.nearest.and_then(|n| ready.document.pairs.get(n.index)).map_or("", |p| p.name.as_str());
        items.push((c.readout(name), None));
    }
    if let Some(done) = ready.view_refine_progress() {
        items.push((format!("refining the 3-D view: {:.0} %", 100.0 * done), None));
    }
    if ready.diagnostics_pending() {
        items.push(("checking the fit: leave-one-out, folding".to_owned(), None));
    }
    items.push((format!("GPU: {}", ready.viewer.ctx.describe()), None));
    items.push((format!("last frame {:.0} ms", ready.view.last_render_ms), None));
    let fps = ready.view.frame_rate.fps().map_or_else(|| "idle".to_owned(), |f| format!("{f:.0} fps"));
    items.push((fps, None));
    items
}

/// Draws the status bar at the bottom of the window.
pub fn status_bar(ui: &mut egui::Ui, ready: &Ready) {
    let items = status_items(ready);
    let font = egui::TextStyle::Body.resolve(ui.style());
    let row = ui.fonts_mut(|f| f.row_height(&font));
    let margin = egui::Frame::side_top_panel(ui.style()).inner_margin.sum().y;
    let height = STATUS_LINES as f32 * row + margin;
    egui::Panel::bottom("status").exact_size(height).show(ui, |ui| {
        let normal = ui.visuals().text_color();
        let weak = ui.visuals().weak_text_color();
        let mut job = egui::text::LayoutJob::default();
        for (k, (text, colour)) in items.iter().enumerate() {
            if k > 0 {
                job.append("  |  ", 0.0, egui::TextFormat::simple(font.clone(), weak));
            }
            job.append(text, 0.0, egui::TextFormat::simple(font.clone(), colour.unwrap_or(normal)));
        }
        job.wrap = egui::text::TextWrapping {
            max_width: ui.available_width(),
            max_rows: STATUS_LINES,
            break_anywhere: false,
            overflow_character: Some('…'),
        };
        let whole: Vec<&str> = items.iter().map(|(t, _)| t.as_str()).collect();
        let response = ui.add(egui::Label::new(job));
        // Screen readers (and tests) read it whole, as the tooltip shows it.
        response.widget_info(|| egui::WidgetInfo::labeled(egui::Role::Label, true, whole.join(" | ")));
        response.on_hover_text(whole.join("\n"));
    });
    // An idle window draws nothing: one more frame once this second is over shows it idle.
    if let Some(wait) = ready.view.frame_rate.redraw_to_idle_in(std::time::Instant::now()) {
        ui.ctx().request_repaint_after(wait);
    }
}
