//! The landmark panel's own state ([`super::landmark_panel`]): how its rows are sorted and filtered, the colour
//! threshold and the marked rows. A view state beside the camera, not the document's.

use std::collections::BTreeSet;

use eframe::egui;
use warpbench_io::landmarks::LandmarkPair;

use crate::project::diagnostics::PairErrors;

/// A column the table can be sorted by.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SortBy {
    /// The order the pairs were placed in.
    Number,
    Active,
    Name,
    Residual,
    LeaveOneOut,
}

impl SortBy {
    pub const ALL: [Self; 5] = [Self::Number, Self::Active, Self::Name, Self::Residual, Self::LeaveOneOut];

    /// Its column's heading.
    pub(super) fn heading(self) -> &'static str {
        match self {
            Self::Number => "#",
            Self::Active => "on",
            Self::Name => "name",
            Self::Residual => "resid.",
            Self::LeaveOneOut => "LOO",
        }
    }

    /// The heading's name for screen readers (and tests).
    pub(super) fn button_name(self) -> &'static str {
        match self {
            Self::Number => "Sort by number",
            Self::Active => "Sort by active",
            Self::Name => "Sort by name",
            Self::Residual => "Sort by residual",
            Self::LeaveOneOut => "Sort by leave-one-out",
        }
    }
}

/// The panel's state: how the rows are sorted and filtered, the colour threshold and the marked rows.
#[derive(Clone, Debug, PartialEq)]
pub struct LandmarkPanel {
    pub sort: SortBy,
    pub descending: bool,
    /// Show only the pairs whose leave-one-out error is above this, mm.
    pub loo_above_mm: Option<f64>,
    /// Leave-one-out errors above it are drawn red, below half of it green, between amber (mm).
    pub threshold_mm: f64,
    /// The rows marked for Activate / Deactivate (pair indices), with the number of pairs they were marked among:
    /// marks lapse when pairs are added or deleted.
    pub marked: (BTreeSet<usize>, usize),
}

impl Default for LandmarkPanel {
    fn default() -> Self {
        Self {
            sort: SortBy::Number,
            descending: false,
            loo_above_mm: None,
            threshold_mm: 2.0,
            marked: Default::default(),
        }
    }
}

impl LandmarkPanel {
    /// The pairs shown, in the order shown: filtered by the leave-one-out filter, sorted by the chosen column (ties
    /// and missing errors in placing order, missing errors last).
    #[must_use]
    pub fn rows(&self, pairs: &[LandmarkPair], errors: &[Option<PairErrors>]) -> Vec<usize> {
        let loo = |i: usize| errors.get(i).copied().flatten().and_then(|e| e.leave_one_out_mm);
        let residual = |i: usize| errors.get(i).copied().flatten().map(|e| e.residual_mm);
        let mut rows: Vec<usize> =
            (0..pairs.len()).filter(|&i| self.loo_above_mm.is_none_or(|x| loo(i).is_some_and(|l| l > x))).collect();
        let by_value = |a: Option<f64>, b: Option<f64>| match (a, b) {
            (Some(a), Some(b)) => a.total_cmp(&b),
            (Some(_), None) => std::cmp::Ordering::Less,
            (None, Some(_)) => std::cmp::Ordering::Greater,
            (None, None) => std::cmp::Ordering::Equal,
        };
        rows.sort_by(|&a, &b| {
            let order = match self.sort {
                SortBy::Number => a.cmp(&b),
                SortBy::Active => pairs[b].active.cmp(&pairs[a].active),
                SortBy::Name => pairs[a].name.cmp(&pairs[b].name),
                SortBy::Residual => by_value(residual(a), residual(b)),
                SortBy::LeaveOneOut => by_value(loo(a), loo(b)),
            };
            let order = if self.descending { order.reverse() } else { order };
            order.then(a.cmp(&b))
        });
        rows
    }

    /// The marked rows among `n` pairs (none once pairs were added or deleted).
    #[must_use]
    pub fn marked(&self, n: usize) -> Vec<usize> {
        if self.marked.1 == n { self.marked.0.iter().copied().filter(|&i| i < n).collect() } else { Vec::new() }
    }

    /// A click on row `i` among `shown` rows of `n` pairs: alone it marks `i` only, with Ctrl it adds or removes `i`,
    /// with Shift it marks the shown rows from `anchor` (the selected pair) to `i`.
    pub fn mark(&mut self, i: usize, modifiers: egui::Modifiers, anchor: Option<usize>, shown: &[usize], n: usize) {
        if self.marked.1 != n {
            self.marked = (BTreeSet::new(), n);
        }
        let set = &mut self.marked.0;
        if modifiers.command {
            if !set.remove(&i) {
                set.insert(i);
            }
        } else if modifiers.shift
            && let Some(a) = anchor.and_then(|a| shown.iter().position(|&r| r == a))
            && let Some(b) = shown.iter().position(|&r| r == i)
        {
            set.extend(&shown[a.min(b)..=a.max(b)]);
        } else {
            *set = BTreeSet::from([i]);
        }
    }
}

#[cfg(test)]
pub(super) mod tests {
    use super::*;
    use warpbench_io::geometry::Point3;

    /// `n` pairs named Pt-0, Pt-1, … along x.
    pub(crate) fn pairs(n: usize) -> Vec<LandmarkPair> {
        (0..n)
            .map(|i| {
                let x = i as f64;
                LandmarkPair::new(format!("Pt-{i}"), Point3::new(x, 0.0, 0.0), Point3::new(x, 1.0, 0.0))
            })
            .collect()
    }

    fn errors(loo: &[Option<f64>]) -> Vec<Option<PairErrors>> {
        loo.iter().map(|&l| Some(PairErrors { residual_mm: l.unwrap_or(0.0) / 10.0, leave_one_out_mm: l })).collect()
    }

    #[test]
    fn rows_sort_by_each_column_filter_by_leave_one_out_and_keep_missing_errors_last() {
        let mut p = pairs(4);
        p[1].active = false;
        p[0].name = "zeta".into();
        let e = errors(&[Some(1.0), Some(4.0), None, Some(2.5)]);
        let mut panel = LandmarkPanel::default();
        assert_eq!(panel.rows(&p, &e), [0, 1, 2, 3]);
        panel.sort = SortBy::LeaveOneOut;
        assert_eq!(panel.rows(&p, &e), [0, 3, 1, 2]);
        panel.descending = true;
        assert_eq!(panel.rows(&p, &e), [2, 1, 3, 0], "reversed, missing first when reversed");
        panel.descending = false;
        panel.sort = SortBy::Residual;
        assert_eq!(panel.rows(&p, &e), [2, 0, 3, 1], "a missing LOO's residual is 0 here");
        panel.sort = SortBy::Name;
        assert_eq!(panel.rows(&p, &e), [1, 2, 3, 0]);
        panel.sort = SortBy::Active;
        assert_eq!(panel.rows(&p, &e), [0, 2, 3, 1], "active first");
        panel.sort = SortBy::Number;
        panel.loo_above_mm = Some(2.0);
        assert_eq!(panel.rows(&p, &e), [1, 3], "only LOO above 2 mm; a pair without one is hidden");
    }

    #[test]
    fn a_click_marks_one_row_ctrl_adds_shift_marks_a_range_and_marks_lapse_when_pairs_change() {
        let mut panel = LandmarkPanel::default();
        let shown = [0, 3, 1, 2];
        panel.mark(3, egui::Modifiers::NONE, None, &shown, 4);
        assert_eq!(panel.marked(4), [3]);
        panel.mark(2, egui::Modifiers::COMMAND, Some(3), &shown, 4);
        assert_eq!(panel.marked(4), [2, 3]);
        panel.mark(2, egui::Modifiers::COMMAND, Some(2), &shown, 4);
        assert_eq!(panel.marked(4), [3]);
        // Shift from the selected pair 0 to pair 1 in the shown order: 0, 3, 1.
        panel.mark(1, egui::Modifiers::SHIFT, Some(0), &shown, 4);
        assert_eq!(panel.marked(4), [0, 1, 3]);
        assert!(panel.marked(5).is_empty(), "a pair was added since");
    }
}
