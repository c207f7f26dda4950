//! How the views share the window: panes of [`egui_tiles`] (as rerun lays out its views), four-up by default (the
//! 3-D view and the axial, coronal and sagittal slices in equal panes), the 3-D view alone, the slices alone, or the
//! fixed and the warped moving volume side by side in one linked axial plane ([`Layout`]), any pane maximised by a double click on its title and restored by another. The panes can be
//! resized by their borders. The layout is saved in the session; the maximised pane is not.

use eframe::egui;

use super::open::Side;
use crate::settings::Layout;

/// One pane of the layout.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Pane {
    View3d,
    Slice(SliceAxis),
    /// One volume alone (the moving one warped) in the axial plane, beside the other.
    Compare(Side),
}

/// A slice view's plane through the fixed grid.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SliceAxis {
    Axial,
    Coronal,
    Sagittal,
}

impl SliceAxis {
    pub const ALL: [Self; 3] = [Self::Axial, Self::Coronal, Self::Sagittal];

    /// Its position in the window's slice arrays (`slice_mm`, the slice images): axial, coronal, sagittal.
    #[must_use]
    pub fn index(self) -> usize {
        match self {
            Self::Axial => 0,
            Self::Coronal => 1,
            Self::Sagittal => 2,
        }
    }

    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Self::Axial => "Axial",
            Self::Coronal => "Coronal",
            Self::Sagittal => "Sagittal",
        }
    }
}

impl Pane {
    /// The title its pane shows (double-click it to maximise the pane).
    #[must_use]
    pub fn title(self) -> &'static str {
        match self {
            Self::View3d => "3-D",
            Self::Slice(s) => s.name(),
            Self::Compare(Side::Fixed) => "Fixed",
            Self::Compare(Side::Moving) => "Moving, warped",
        }
    }
}

/// The panes of `layout`, or `maximised` alone.
#[must_use]
pub fn panes(layout: Layout, maximised: Option<Pane>) -> Vec<Pane> {
    if let Some(p) = maximised {
        return vec![p];
    }
    let slices = SliceAxis::ALL.map(Pane::Slice);
    match layout {
        Layout::FourUp => [Pane::View3d].into_iter().chain(slices).collect(),
        Layout::ThreeD => vec![Pane::View3d],
        Layout::Slices => slices.to_vec(),
        Layout::SideBySide => vec![Pane::Compare(Side::Fixed), Pane::Compare(Side::Moving)],
    }
}

/// The tiles of `layout` (with `maximised` alone when one is): a 2 × 2 grid four-up, the slices in a row.
#[must_use]
pub fn tree(layout: Layout, maximised: Option<Pane>) -> egui_tiles::Tree<Pane> {
    let id = egui::Id::unique("warpbench views");
    let panes = panes(layout, maximised);
    if panes.len() == 4 {
        // Two columns whatever the window's shape (egui_tiles' automatic grid stacks narrow areas in one column).
        let mut tiles = egui_tiles::Tiles::default();
        let children = panes.into_iter().map(|p| tiles.insert_pane(p)).collect();
        let mut grid = egui_tiles::Grid::new(children);
        grid.layout = egui_tiles::GridLayout::Columns(2);
        let root = tiles.insert_container(grid);
        egui_tiles::Tree::new(id, root, tiles)
    } else {
        egui_tiles::Tree::new_horizontal(id, panes)
    }
}

/// Which pane a double click on `pane`'s title leaves maximised: `pane` itself, or none when it already was.
#[must_use]
pub fn toggled(maximised: Option<Pane>, pane: Pane) -> Option<Pane> {
    if maximised == Some(pane) { None } else { Some(pane) }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_layouts_hold_their_panes_and_a_double_click_maximises_and_restores() {
        assert_eq!(panes(Layout::FourUp, None).len(), 4);
        assert_eq!(panes(Layout::ThreeD, None), vec![Pane::View3d]);
        assert_eq!(panes(Layout::Slices, None), SliceAxis::ALL.map(Pane::Slice).to_vec());
        assert_eq!(panes(Layout::SideBySide, None), [Side::Fixed, Side::Moving].map(Pane::Compare).to_vec());
        let axial = Pane::Slice(SliceAxis::Axial);
        assert_eq!(panes(Layout::FourUp, Some(axial)), vec![axial]);
        assert_eq!(toggled(None, axial), Some(axial));
        assert_eq!(toggled(Some(axial), axial), None);
        assert_eq!(toggled(Some(axial), Pane::View3d), Some(Pane::View3d));
        assert_eq!(SliceAxis::ALL.map(SliceAxis::index), [0, 1, 2]);
        let tree = tree(Layout::FourUp, None);
        assert_eq!(tree.tiles.tiles().filter(|t| t.is_pane()).count(), 4);
    }
}
