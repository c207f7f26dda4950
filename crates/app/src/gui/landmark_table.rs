//! The landmark table and the accuracy section: each pair's row (active, name, points, residual, leave-one-out,
//! go-to, delete), coloured by its leave-one-out error, and the histogram and ranking of those errors. Each is a
//! `*_ui(ui, …)` function over plain state that returns what it asks for as [`Command`]s.

use eframe::egui;
use warpbench_io::landmarks::LandmarkPair;

use super::Command;
pub use crate::project::diagnostics::{PairErrors, loo_ranking};

/// Rows of the landmark table shown at once; a longer table scrolls, and only its visible rows are laid out (a
/// thousand pairs cost what fifteen do).
pub const TABLE_ROWS: usize = 15;

/// Green below 1 mm, amber below 3 mm, red above: how far a pair disagrees with the others.
#[must_use]
pub fn error_colour(mm: f64) -> egui::Color32 {
    if mm < 1.0 {
        egui::Color32::from_rgb(90, 200, 90)
    } else if mm < 3.0 {
        egui::Color32::from_rgb(230, 180, 60)
    } else {
        egui::Color32::from_rgb(235, 90, 80)
    }
}

/// The landmark table: per pair whether it is in the fit, its name (editable), the moving and fixed positions
/// (LPS mm), the residual and leave-one-out error (colour-coded), and buttons to select it, centre the views on it
/// and delete it. `selected` is highlighted. Up to [`TABLE_ROWS`] pairs the table is laid out whole; beyond, it is a
/// scrolled window of that many rows whose heading stays on top, and only the rows in view are built.
pub fn landmarks_ui(
    ui: &mut egui::Ui,
    pairs: &[LandmarkPair],
    errors: &[Option<PairErrors>],
    selected: Option<usize>,
) -> Vec<Command> {
    ui.label(format!("Landmarks ({} pairs)", pairs.len()));
    let mut commands = Vec::new();
    let table = |ui: &mut egui::Ui, rows: std::ops::Range<usize>, commands: &mut Vec<Command>| {
        egui::Grid::new("landmarks").striped(true).show(ui, |ui| {
            for heading in ["on", "name", "moving (mm)", "fixed (mm)", "resid.", "LOO", "", ""] {
                ui.label(heading);
            }
            ui.end_row();
            for i in rows {
                commands.extend(landmark_row(ui, i, &pairs[i], errors.get(i).copied().flatten(), selected == Some(i)));
                ui.end_row();
            }
        });
    };
    if pairs.len() <= TABLE_ROWS {
        table(ui, 0..pairs.len(), &mut commands);
    } else {
        // The heading takes the place of the first row in view, so the rows are counted one more.
        let row_height = ui.spacing().interact_size.y.max(18.0) + ui.spacing().item_spacing.y;
        egui::ScrollArea::vertical()
            .id_salt("landmark rows")
            .max_height(row_height * (TABLE_ROWS + 1) as f32)
            .auto_shrink([false, true])
            .show_rows(ui, row_height, pairs.len() + 1, |ui, shown| {
                table(ui, shown.start..(shown.end.saturating_sub(1)).min(pairs.len()), &mut commands);
            });
    }
    commands
}

/// One row of the landmark table: the widgets of pair `i` and the commands they gave.
fn landmark_row(
    ui: &mut egui::Ui,
    i: usize,
    pair: &LandmarkPair,
    errors: Option<PairErrors>,
    selected: bool,
) -> Vec<Command> {
    let fmt = |p: Option<warpbench_io::geometry::Point3<warpbench_io::geometry::Lps>>| {
        p.map_or_else(
            || "-".to_owned(),
            |p| {
                let c = p.coords();
                format!("{:.1}, {:.1}, {:.1}", c[0], c[1], c[2])
            },
        )
    };
    let mut commands = Vec::new();
    // Compact widgets, with full names for screen readers and tests.
    let label = |what: &str| format!("{what} {}", pair.name);
    let mut on = pair.active;
    let active = ui.checkbox(&mut on, "").on_hover_text("In the fit");
    let active_name = label("Use");
    active.widget_info(|| egui::WidgetInfo::selected(egui::Role::CheckBox, true, on, &active_name));
    if active.changed() {
        commands.push(Command::SetActive(i, on));
    }
    let name_name = format!("Name of pair {}", i + 1);
    let mut text = pair.name.clone();
    let name = ui.add_sized([84.0, 18.0], egui::TextEdit::singleline(&mut text));
    name.widget_info(|| egui::WidgetInfo::labeled(egui::Role::TextInput, true, &name_name));
    if text != pair.name {
        commands.push(Command::RenamePair(i, text));
    }
    let position = ui.selectable_label(selected, fmt(pair.moving));
    if position.clicked() {
        commands.push(Command::Select(i));
    }
    if ui.selectable_label(selected, fmt(pair.fixed)).clicked() {
        commands.push(Command::Select(i));
    }
    if let Some(e) = errors {
        ui.colored_label(error_colour(e.residual_mm), format!("{:.2}", e.residual_mm));
        match e.leave_one_out_mm {
            Some(l) => ui.colored_label(error_colour(l), format!("{l:.2}")),
            None => ui.label("-"),
        };
    } else {
        ui.label("-");
        ui.label("-");
    }
    let go = ui.small_button("go").on_hover_text("Centre the views on this pair");
    let go_name = label("Go to");
    go.widget_info(|| egui::WidgetInfo::labeled(egui::Role::Button, true, &go_name));
    if go.clicked() {
        commands.push(Command::JumpTo(i));
    }
    let delete = ui.small_button("x").on_hover_text("Delete this pair");
    let delete_name = label("Delete");
    delete.widget_info(|| egui::WidgetInfo::labeled(egui::Role::Button, true, &delete_name));
    if delete.clicked() {
        commands.push(Command::DeletePair(i));
    }
    commands
}

/// "Exclude outliers", with the rule it applies said beside it.
pub fn outliers_ui(ui: &mut egui::Ui, pairs_in_fit: usize) -> Option<Command> {
    let rule = crate::project::diagnostics::OUTLIER_RULE;
    let button = egui::Button::new("Exclude outliers");
    let clicked = ui.add_enabled(pairs_in_fit >= 6, button).on_hover_text(rule).clicked();
    ui.small(format!("Outliers: {rule}."));
    clicked.then_some(Command::ExcludeOutliers)
}

/// Histogram bins of `values` (mm): `bins` equal bins from 0 to the largest value (at least 1 mm), as (bin
/// centre, width, count).
#[must_use]
pub fn histogram(values: &[f64], bins: usize) -> Vec<(f64, f64, usize)> {
    let bins = bins.max(1);
    let top = values.iter().copied().fold(1.0f64, f64::max);
    let width = top / bins as f64;
    let mut counts = vec![0usize; bins];
    for &v in values {
        let b = ((v / width) as usize).min(bins - 1);
        counts[b] += 1;
    }
    counts.into_iter().enumerate().map(|(b, n)| ((b as f64 + 0.5) * width, width, n)).collect()
}

/// The accuracy panel: a histogram of the leave-one-out errors, their mean and max, and the worst pairs (each a
/// button that selects it). Returns the pair to select and centre on.
pub fn accuracy_ui(ui: &mut egui::Ui, pairs: &[LandmarkPair], errors: &[Option<PairErrors>]) -> Option<usize> {
    ui.label("Accuracy (leave-one-out)");
    let loo = loo_ranking(pairs, errors);
    if loo.is_empty() {
        ui.label("Leave-one-out needs one pair more than the method's minimum.");
        return None;
    }
    let values: Vec<f64> = loo.iter().map(|(e, _)| *e).collect();
    let mean = values.iter().sum::<f64>() / values.len() as f64;
    ui.label(format!("Leave-one-out error: mean {mean:.2} mm, max {:.2} mm ({} pairs)", values[0], values.len()));
    let bars: Vec<egui_plot::Bar> = histogram(&values, 10)
        .into_iter()
        .map(|(centre, width, n)| egui_plot::Bar::new(centre, n as f64).width(width * 0.95).fill(error_colour(centre)))
        .collect();
    let plot = egui_plot::Plot::new("loo histogram")
        .height(90.0)
        .allow_zoom(false)
        .allow_drag(false)
        .allow_scroll(false)
        .allow_boxed_zoom(false)
        .include_y(0.0)
        .x_axis_label("LOO error (mm)")
        .y_axis_label("pairs");
    let response = plot.show(ui, |p| p.bar_chart(egui_plot::BarChart::new("leave-one-out", bars))).response;
    response.widget_info(|| egui::WidgetInfo::labeled(egui::Role::Image, true, "Leave-one-out histogram"));
    let mut chosen = None;
    ui.horizontal_wrapped(|ui| {
        ui.label("Worst:");
        for &(e, i) in loo.iter().take(3) {
            let text = egui::RichText::new(format!("{} {e:.2} mm", pairs[i].name)).color(error_colour(e));
            if ui.button(text).clicked() {
                chosen = Some(i);
            }
        }
    });
    chosen
}

#[cfg(test)]
mod tests {
    use super::*;
    use warpbench_io::geometry::Point3;

    #[test]
    fn histogram_bins_count_every_value_and_rank_the_worst() {
        let values = [0.2, 0.4, 0.45, 1.9, 2.0, 5.0];
        let bins = histogram(&values, 5);
        assert_eq!(bins.len(), 5);
        assert_eq!(bins.iter().map(|b| b.2).sum::<usize>(), values.len());
        // 0..1, 1..2, 2..3, 3..4, 4..5 mm: the maximum falls in the last bin.
        assert_eq!(bins.iter().map(|b| b.2).collect::<Vec<_>>(), [3, 1, 1, 0, 1]);
        assert!((bins[0].0 - 0.5).abs() < 1e-12 && (bins[0].1 - 1.0).abs() < 1e-12);
        // Below 1 mm the range is 0..1 mm.
        assert_eq!(histogram(&[0.1, 0.3], 2).iter().map(|b| b.2).collect::<Vec<_>>(), [2, 0]);
        let pairs: Vec<LandmarkPair> = (0..3)
            .map(|i| LandmarkPair::new(format!("p{i}"), Point3::new(0.0, 0.0, 0.0), Point3::new(0.0, 0.0, 0.0)))
            .collect();
        let e = |l: Option<f64>| Some(PairErrors { residual_mm: 0.0, leave_one_out_mm: l });
        let ranking = loo_ranking(&pairs, &[e(Some(1.5)), None, e(Some(4.0))]);
        assert_eq!(ranking, [(4.0, 2), (1.5, 0)]);
    }

    /// A long table builds only the rows in view, with the heading, and scrolling brings the last pairs in.
    #[test]
    fn a_thousand_pairs_lay_out_only_the_rows_in_view() {
        use egui_kittest::kittest::Queryable as _;
        let pairs: Vec<LandmarkPair> = (0..1000)
            .map(|i| {
                let x = f64::from(i);
                LandmarkPair::new(format!("Pt-{i}"), Point3::new(x, 0.0, 0.0), Point3::new(x, 1.0, 0.0))
            })
            .collect();
        let errors = vec![None; pairs.len()];
        let mut harness = egui_kittest::Harness::builder().with_size(egui::vec2(600.0, 800.0)).build_ui(|ui| {
            let _ = landmarks_ui(ui, &pairs, &errors, None);
        });
        harness.run();
        let built = harness.query_all_by_label_contains("Delete Pt-").count();
        assert!((1..=TABLE_ROWS + 1).contains(&built), "{built} rows built of 1000");
        assert!(harness.query_by_label("Delete Pt-0").is_some(), "the first pair is in view");
        assert!(harness.query_by_label("Delete Pt-999").is_none(), "the last pair is not built");
        assert!(harness.query_by_label("moving (mm)").is_some(), "the heading is shown");
        // The wheel over the table's rows.
        let over_rows = harness.get_by_label("Delete Pt-3").rect().center();
        harness.event(egui::Event::PointerMoved(over_rows));
        for _ in 0..40 {
            harness.event(egui::Event::MouseWheel {
                unit: egui::MouseWheelUnit::Page,
                delta: egui::vec2(0.0, -10.0),
                modifiers: egui::Modifiers::NONE,
                phase: egui::TouchPhase::Move,
                source: egui::MouseWheelSource::Wheel,
            });
            // The scroll animates over several frames.
            harness.run_steps(10);
        }
        assert!(harness.query_by_label("Delete Pt-999").is_some(), "scrolled to the end, the last pair is built");
        assert!(harness.query_by_label("moving (mm)").is_some(), "the heading stays on top");
        let built = harness.query_all_by_label_contains("Delete Pt-").count();
        assert!(built <= TABLE_ROWS + 1, "{built} rows built at the end");
    }

    /// A short table is laid out whole, as before there was scrolling.
    #[test]
    fn a_short_table_is_laid_out_whole() {
        use egui_kittest::kittest::Queryable as _;
        let pairs: Vec<LandmarkPair> = (0..TABLE_ROWS)
            .map(|i| LandmarkPair::new(format!("Pt-{i}"), Point3::new(0.0, 0.0, 0.0), Point3::new(0.0, 0.0, 0.0)))
            .collect();
        let errors = vec![None; pairs.len()];
        let mut harness = egui_kittest::Harness::builder().with_size(egui::vec2(600.0, 800.0)).build_ui(|ui| {
            let _ = landmarks_ui(ui, &pairs, &errors, None);
        });
        harness.run();
        assert_eq!(harness.query_all_by_label_contains("Delete Pt-").count(), TABLE_ROWS);
    }
}
