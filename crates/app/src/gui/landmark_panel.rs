//! The landmark panel, at the window's right: the table of pairs with sortable columns (number, active, name,
//! residual, leave-one-out), each row coloured by its leave-one-out error against a threshold the user sets, a filter
//! "only LOO above x mm", rows marked by click, Ctrl+click and Shift+click to activate or deactivate together, each
//! row's rename, go-to and delete, and "Exclude outliers" with its rule. The panel's own choices (sorting, filter,
//! threshold, marks) are the view's, not the document's.

use eframe::egui;
use warpbench_io::landmarks::LandmarkPair;

use super::Command;
pub use super::landmark_rows::{LandmarkPanel, SortBy};
use super::landmark_table::PairErrors;

/// Rows of the table shown at once; a longer table scrolls, and only its visible rows are laid out (a thousand pairs
/// cost what twenty do).
pub const TABLE_ROWS: usize = 20;

/// A leave-one-out error's colour against `threshold_mm`: red above it, amber above half of it, green below.
#[must_use]
pub fn loo_colour(mm: f64, threshold_mm: f64) -> egui::Color32 {
    if mm > threshold_mm {
        egui::Color32::from_rgb(235, 90, 80)
    } else if mm > 0.5 * threshold_mm {
        egui::Color32::from_rgb(230, 180, 60)
    } else {
        egui::Color32::from_rgb(90, 200, 90)
    }
}

/// What the panel shows of the document.
#[derive(Clone, Copy, Debug)]
pub struct PanelInput<'a> {
    pub pairs: &'a [LandmarkPair],
    pub errors: &'a [Option<PairErrors>],
    pub selected: Option<usize>,
    /// The pairs in the fit (Exclude outliers needs six).
    pub pairs_in_fit: usize,
}

/// The landmark panel at the window's right; what it asked for.
pub fn landmark_panel(ui: &mut egui::Ui, input: &PanelInput<'_>, panel: &mut LandmarkPanel) -> Vec<Command> {
    let mut commands = Vec::new();
    egui::Panel::right("landmarks").resizable(true).default_size(290.0).show(ui, |ui| {
        commands = panel_contents(ui, input, panel);
    });
    commands
}

/// The panel's contents, in any ui.
pub fn panel_contents(ui: &mut egui::Ui, input: &PanelInput<'_>, panel: &mut LandmarkPanel) -> Vec<Command> {
    let PanelInput { pairs, errors, selected, pairs_in_fit } = *input;
    let mut commands = Vec::new();
    let rows = panel.rows(pairs, errors);
    ui.heading(format!("Landmarks ({} pairs, {} shown)", pairs.len(), rows.len()));
    ui.horizontal_wrapped(|ui| {
        let mut filter = panel.loo_above_mm.is_some();
        ui.checkbox(&mut filter, "Only LOO above")
            .on_hover_text("Show only the pairs whose leave-one-out error is above this");
        let mut above = panel.loo_above_mm.unwrap_or(panel.threshold_mm);
        let value = ui.add(egui::DragValue::new(&mut above).range(0.0..=100.0).speed(0.05).suffix(" mm"));
        value.widget_info(|| egui::WidgetInfo::labeled(egui::Role::SpinButton, true, "LOO filter (mm)"));
        panel.loo_above_mm = filter.then_some(above);
    });
    ui.horizontal_wrapped(|ui| {
        ui.label("Red above");
        let value = ui.add(egui::DragValue::new(&mut panel.threshold_mm).range(0.05..=100.0).speed(0.05).suffix(" mm"));
        value.widget_info(|| egui::WidgetInfo::labeled(egui::Role::SpinButton, true, "Colour threshold (mm)"));
        ui.label("leave-one-out");
    });
    let marked = panel.marked(pairs.len());
    ui.horizontal_wrapped(|ui| {
        for (label, on) in [("Activate marked", true), ("Deactivate marked", false)] {
            if ui.add_enabled(!marked.is_empty(), egui::Button::new(label)).clicked() {
                commands.extend(marked.iter().map(|&i| Command::SetActive(i, on)));
            }
        }
        ui.label(format!("{} marked", marked.len()))
            .on_hover_text("Click a row's number; Ctrl+click adds, Shift+click a range");
    });
    commands.extend(super::landmark_table::outliers_ui(ui, pairs_in_fit));
    ui.separator();
    let row_height = ui.spacing().interact_size.y.max(18.0) + ui.spacing().item_spacing.y;
    let mut clicked = None;
    let mut table = |ui: &mut egui::Ui, shown: &[usize], commands: &mut Vec<Command>, clicked: &mut Option<usize>| {
        egui::Grid::new("landmarks").striped(true).min_col_width(0.0).show(ui, |ui| {
            for column in SortBy::ALL {
                let arrow = match (panel.sort == column, panel.descending) {
                    (false, _) => "",
                    (true, false) => " ^",
                    (true, true) => " v",
                };
                let heading = ui.selectable_label(panel.sort == column, format!("{}{arrow}", column.heading()));
                heading.widget_info(|| egui::WidgetInfo::labeled(egui::Role::Button, true, column.button_name()));
                if heading.on_hover_text("Sort by this column; again to reverse").clicked() {
                    (panel.sort, panel.descending) = (column, panel.sort == column && !panel.descending);
                }
            }
            ui.label("");
            ui.label("");
            ui.end_row();
            for &i in shown {
                let row =
                    Row { i, pair: &pairs[i], errors: errors.get(i).copied().flatten(), selected: selected == Some(i) };
                let (row_commands, number_clicked) = landmark_row(ui, &row, marked.contains(&i), panel.threshold_mm);
                commands.extend(row_commands);
                if number_clicked {
                    *clicked = Some(i);
                }
                ui.end_row();
            }
        });
    };
    if rows.len() <= TABLE_ROWS {
        table(ui, &rows, &mut commands, &mut clicked);
    } else {
        // The heading takes the place of the first row in view, so the rows are counted one more.
        egui::ScrollArea::vertical()
            .id_salt("landmark rows")
            .max_height(row_height * (TABLE_ROWS + 1) as f32)
            .auto_shrink([false, true])
            .show_rows(ui, row_height, rows.len() + 1, |ui, range| {
                let shown = &rows[range.start..(range.end.saturating_sub(1)).min(rows.len())];
                table(ui, shown, &mut commands, &mut clicked);
            });
    }
    if let Some(i) = clicked {
        let modifiers = ui.input(|input| input.modifiers);
        panel.mark(i, modifiers, selected, &rows, pairs.len());
        commands.push(Command::Select(i));
    }
    if let Some(p) = selected.and_then(|i| pairs.get(i)) {
        ui.separator();
        ui.label(format!("{}: moving {}, fixed {} (LPS mm)", p.name, point_text(p.moving), point_text(p.fixed)));
    }
    commands
}

/// "l, p, s" to one decimal, or "-".
fn point_text(p: Option<warpbench_io::geometry::Point3<warpbench_io::geometry::Lps>>) -> String {
    p.map_or_else(
        || "-".to_owned(),
        |p| {
            let c = p.coords();
            format!("{:.1}, {:.1}, {:.1}", c[0], c[1], c[2])
        },
    )
}

/// One pair of the table.
struct Row<'a> {
    i: usize,
    pair: &'a LandmarkPair,
    errors: Option<PairErrors>,
    selected: bool,
}

/// One row: the pair's number (click: select and mark), whether it is in the fit, its name (editable), its residual
/// and leave-one-out error, go to and delete. The commands it gave and whether its number was clicked.
fn landmark_row(ui: &mut egui::Ui, row: &Row<'_>, marked: bool, threshold_mm: f64) -> (Vec<Command>, bool) {
    let Row { i, pair, errors, selected } = *row;
    let mut commands = Vec::new();
    // Compact widgets, with full names for screen readers and tests.
    let label = |what: &str| format!("{what} {}", pair.name);
    let number = ui.selectable_label(selected || marked, format!("{}", i + 1));
    let number_name = label("Select");
    number.widget_info(|| egui::WidgetInfo::selected(egui::Role::Button, true, marked, &number_name));
    let hover = format!("moving {} mm, fixed {} mm", point_text(pair.moving), point_text(pair.fixed));
    let number_clicked = number.on_hover_text(hover).clicked();
    let mut on = pair.active;
    let active = ui.checkbox(&mut on, "").on_hover_text("In the fit");
    let active_name = label("Use");
    active.widget_info(|| egui::WidgetInfo::selected(egui::Role::CheckBox, true, on, &active_name));
    if active.changed() {
        commands.push(Command::SetActive(i, on));
    }
    let name_name = format!("Name of pair {}", i + 1);
    let mut text = pair.name.clone();
    let loo = errors.and_then(|e| e.leave_one_out_mm);
    let colour = loo.map(|l| loo_colour(l, threshold_mm));
    let name = ui.add_sized([72.0, 18.0], egui::TextEdit::singleline(&mut text).text_color_opt(colour));
    name.widget_info(|| egui::WidgetInfo::labeled(egui::Role::TextInput, true, &name_name));
    if text != pair.name {
        commands.push(Command::RenamePair(i, text));
    }
    match errors {
        Some(e) => ui.label(format!("{:.2}", e.residual_mm)),
        None => ui.label("-"),
    };
    match (loo, colour) {
        (Some(l), Some(c)) => ui.colored_label(c, format!("{l:.2}")),
        _ => ui.label("-"),
    };
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
    (commands, number_clicked)
}

#[cfg(test)]
mod tests {
    use super::super::landmark_rows::tests::pairs;
    use super::*;
    use egui_kittest::kittest::Queryable as _;

    #[test]
    fn thresholds_colour_the_errors() {
        assert_eq!(loo_colour(2.1, 2.0), egui::Color32::from_rgb(235, 90, 80));
        assert_eq!(loo_colour(1.5, 2.0), egui::Color32::from_rgb(230, 180, 60));
        assert_eq!(loo_colour(0.9, 2.0), egui::Color32::from_rgb(90, 200, 90));
        assert_eq!(loo_colour(0.9, 0.5), egui::Color32::from_rgb(235, 90, 80));
    }

    /// A long table builds only the rows in view, with the heading, and scrolling brings the last pairs in.
    #[test]
    fn a_thousand_pairs_lay_out_only_the_rows_in_view() {
        let pairs = pairs(1000);
        let errors = vec![None; pairs.len()];
        let mut panel = LandmarkPanel::default();
        let mut harness = egui_kittest::Harness::builder().with_size(egui::vec2(600.0, 800.0)).build_ui(|ui| {
            let input = PanelInput { pairs: &pairs, errors: &errors, selected: None, pairs_in_fit: 1000 };
            let _ = panel_contents(ui, &input, &mut panel);
        });
        harness.run();
        let built = harness.query_all_by_label_contains("Delete Pt-").count();
        assert!((1..=TABLE_ROWS + 1).contains(&built), "{built} rows built of 1000");
        assert!(harness.query_by_label("Delete Pt-0").is_some(), "the first pair is in view");
        assert!(harness.query_by_label("Delete Pt-999").is_none(), "the last pair is not built");
        assert!(harness.query_by_label("Sort by name").is_some(), "the heading is shown");
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
        assert!(harness.query_by_label("Sort by name").is_some(), "the heading stays on top");
        let built = harness.query_all_by_label_contains("Delete Pt-").count();
        assert!(built <= TABLE_ROWS + 1, "{built} rows built at the end");
    }

    /// A short table is laid out whole, as before there was scrolling.
    #[test]
    fn a_short_table_is_laid_out_whole() {
        let pairs = pairs(TABLE_ROWS);
        let errors = vec![None; pairs.len()];
        let mut panel = LandmarkPanel::default();
        let mut harness = egui_kittest::Harness::builder().with_size(egui::vec2(600.0, 800.0)).build_ui(|ui| {
            let input = PanelInput { pairs: &pairs, errors: &errors, selected: None, pairs_in_fit: TABLE_ROWS };
            let _ = panel_contents(ui, &input, &mut panel);
        });
        harness.run();
        assert_eq!(harness.query_all_by_label_contains("Delete Pt-").count(), TABLE_ROWS);
    }
}
