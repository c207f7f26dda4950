//! The accuracy section and the landmark panel's "Exclude outliers": the histogram and ranking of the leave-one-out
//! errors, coloured by size, and the outlier rule. Each is a `*_ui(ui, …)` function over plain state that returns what
//! it asks for as [`Command`]s.

use eframe::egui;
use warpbench_io::landmarks::LandmarkPair;

use super::Command;
pub use crate::project::diagnostics::{PairErrors, loo_ranking};

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
}
