//! Undo and redo over everything the user changes: the [`Document`] (the landmark pairs, the view and warp settings,
//! each volume's look and path) and which volume each side shows (opening another one is a step too).
//!
//! The window records a [`Snapshot`] once a change has settled (no pointer button held, so a slider drag is one
//! step, not one per frame). [`History::undo`] and [`History::redo`] walk back and forth; a new change after an undo
//! drops the redo branch, as every editor does.

use std::sync::Arc;

use warpbench_io::Volume;

use crate::project::document::Document;

/// Everything undo restores: the document, and the volumes its paths were read into. Two are equal when their
/// documents are and they show the same reads (the same `Arc`s), not merely equal voxels: undo then swaps volumes
/// without comparing their data. The history keeps a replaced volume in memory for as long as a step refers to it.
#[derive(Clone, Debug)]
pub struct Snapshot {
    pub document: Document,
    /// Fixed, moving.
    pub volumes: [Arc<Volume>; 2],
}

impl PartialEq for Snapshot {
    fn eq(&self, other: &Self) -> bool {
        self.document == other.document && self.volumes.iter().zip(&other.volumes).all(|(a, b)| Arc::ptr_eq(a, b))
    }
}

/// Past and future snapshots around the current one.
#[derive(Clone, Debug)]
pub struct History {
    past: Vec<Snapshot>,
    current: Snapshot,
    future: Vec<Snapshot>,
    /// Oldest steps are dropped beyond this.
    limit: usize,
}

impl History {
    #[must_use]
    pub fn new(current: Snapshot) -> Self {
        Self { past: Vec::new(), current, future: Vec::new(), limit: 500 }
    }

    /// Records `now` as a new step if it differs from the current one; returns whether it did.
    pub fn record(&mut self, now: &Snapshot) -> bool {
        if *now == self.current {
            return false;
        }
        let previous = std::mem::replace(&mut self.current, now.clone());
        self.past.push(previous);
        if self.past.len() > self.limit {
            self.past.remove(0);
        }
        self.future.clear();
        true
    }

    /// The state before the current one, which becomes current; `None` at the start.
    pub fn undo(&mut self) -> Option<&Snapshot> {
        let previous = self.past.pop()?;
        let current = std::mem::replace(&mut self.current, previous);
        self.future.push(current);
        Some(&self.current)
    }

    /// The state undone last, which becomes current again; `None` when nothing was undone.
    pub fn redo(&mut self) -> Option<&Snapshot> {
        let next = self.future.pop()?;
        let current = std::mem::replace(&mut self.current, next);
        self.past.push(current);
        Some(&self.current)
    }

    #[must_use]
    pub fn can_undo(&self) -> bool {
        !self.past.is_empty()
    }

    #[must_use]
    pub fn can_redo(&self) -> bool {
        !self.future.is_empty()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::PathBuf;
    use warpbench_io::geometry::Point3;
    use warpbench_io::landmarks::LandmarkPair;

    fn volume() -> Arc<Volume> {
        Arc::new(crate::project::demo::phantom(4, 1.0, [0.0; 3], false))
    }

    fn snapshot_with(n: usize, volumes: [Arc<Volume>; 2], moving: Option<PathBuf>) -> Snapshot {
        let pairs = (0..n)
            .map(|i| {
                let p = Point3::new(i as f64, 0.0, 0.0);
                LandmarkPair::new(format!("p{i}"), p, p)
            })
            .collect();
        let document = Document::new([None, moving], [&volumes[0], &volumes[1]], pairs);
        Snapshot { document, volumes }
    }

    thread_local! {
        static PAIR: [Arc<Volume>; 2] = [volume(), volume()];
    }

    fn snapshot(n: usize) -> Snapshot {
        snapshot_with(n, PAIR.with(Clone::clone), None)
    }

    #[test]
    fn undo_redo_walk_the_steps_and_a_new_change_drops_the_redo_branch() {
        let mut h = History::new(snapshot(0));
        assert!(!h.record(&snapshot(0)), "no change, no step");
        assert!(h.record(&snapshot(1)) && h.record(&snapshot(2)));
        assert_eq!(h.undo().map(|s| s.document.pairs.len()), Some(1));
        assert_eq!(h.undo().map(|s| s.document.pairs.len()), Some(0));
        assert!(h.undo().is_none() && !h.can_undo());
        assert_eq!(h.redo().map(|s| s.document.pairs.len()), Some(1));
        assert!(h.can_redo());
        assert!(h.record(&snapshot(5)), "a new change after an undo");
        assert!(!h.can_redo(), "drops the redo branch");
        assert_eq!(h.undo().map(|s| s.document.pairs.len()), Some(1));
    }

    #[test]
    fn another_volume_is_a_step_and_volumes_compare_by_identity() {
        let mut h = History::new(snapshot(1));
        // Equal voxels, another read: a change (a file reopened is a step, as in an editor).
        let [fixed, moving] = PAIR.with(Clone::clone);
        let reread = Arc::new((*moving).clone());
        assert_eq!(reread.dims, moving.dims);
        assert!(h.record(&snapshot_with(1, [fixed.clone(), reread.clone()], None)));
        // The same read from another path is a change too; the same read and path is not.
        let elsewhere = Some(PathBuf::from("/data/mr.nii"));
        assert!(h.record(&snapshot_with(1, [fixed.clone(), reread.clone()], elsewhere.clone())));
        assert!(!h.record(&snapshot_with(1, [fixed.clone(), reread.clone()], elsewhere)));
        let back = h.undo().expect("a step").clone();
        assert!(Arc::ptr_eq(&back.volumes[1], &reread) && !Arc::ptr_eq(&back.volumes[1], &moving));
        assert!(back.document.moving.is_none());
        assert!(Arc::ptr_eq(&h.undo().expect("a step").volumes[1], &moving));
    }
}
