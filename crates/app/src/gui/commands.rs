//! Commands: what the panels, the views, the keyboard and the File menu ask for, as values. The UI code returns
//! them; [`Ready::apply`] is the one place that carries them out on the document and the view, marks what must be
//! fitted or rendered again, and walks the undo history.
//!
//! Undo restores snapshots: a change becomes an undo step once it has settled ([`Ready::settle`]: no pointer button
//! held, so a slider drag or a landmark drag is one step), whatever command made it. The autosave sees the document
//! at the end of every frame ([`super::autosave`]), so every command reaches the disk without saying so.

use std::path::PathBuf;
use std::sync::Arc;

use warpbench_gpu::OrbitCamera;
use warpbench_gpu::glam::Vec3;
use warpbench_io::geometry::{Lps, Point3};
use warpbench_io::landmarks::LandmarkPair;
use warpbench_solver::brush::BrushStroke;

use super::files::FileAction;
use super::history::Snapshot;
use super::tool::{End, Placing};
use super::{Ready, export, open};
use crate::project::document::{Look, StartingTransform, ViewSettings};

/// One thing asked of the window once a pair is shown.
#[derive(Clone, Debug, PartialEq)]
pub enum Command {
    /// Ctrl+Z.
    Undo,
    /// Ctrl+Shift+Z.
    Redo,
    /// The whole fixed volume in view, from the front-left, slightly above.
    ResetCamera,
    /// Orbit the camera by a drag of this many points (right: about the superior axis, down: towards the feet).
    Orbit(eframe::egui::Vec2),
    /// Zoom the camera by a wheel scroll of this many points.
    Zoom(f32),
    /// Select pair i and centre the camera and the slices on its fixed point.
    JumpTo(usize),
    /// Highlight pair i in the table and the views.
    Select(usize),
    /// Esc: stop adding a pair, or clear the selection.
    Cancel,
    /// Start adding a pair (the next pick is its moving point), or stop.
    ToggleAdding,
    /// The Select tool: stop adding a pair or brushing (between strokes); the selection stays.
    UseSelect,
    /// Append a completed pair, active.
    AddPair {
        moving: Point3<Lps>,
        fixed: Point3<Lps>,
    },
    /// Put one point of pair `pair` at `to`; `settled`: the last move of a drag, fitted with diagnostics.
    MovePoint {
        pair: usize,
        end: End,
        to: Point3<Lps>,
        settled: bool,
    },
    DeletePair(usize),
    RenamePair(usize, String),
    /// Switch pair i into or out of the fit.
    SetActive(usize, bool),
    /// Switch out of the fit the pairs whose leave-one-out error is far above the rest
    /// ([`crate::project::diagnostics::outliers`]), as one change.
    ExcludeOutliers,
    SetSettings(ViewSettings),
    /// Fixed, moving.
    SetLooks([Look; 2]),
    /// Move slice view `a` (0 axial, 1 coronal, 2 sagittal) to `mm` along its axis.
    MoveSlice(usize, f64),
    /// Move the three slices through ref point `x_ref` (linked navigation).
    CentreSlices([f64; 3]),
    /// Lay the views out as `layout` (and show every pane again).
    SetLayout(crate::settings::Layout),
    /// Show `pane` alone, or the layout again when it already is (a double click on a pane's title).
    ToggleMaximise(super::layout::Pane),
    /// Move every view to ref point `x_ref`: the three slices through it and the 3-D view's camera onto it (the
    /// linked crosshair, a shift-click).
    CentreViews([f64; 3]),
    File(FileAction),
    Export(export::ExportKind, PathBuf),
    /// Start or stop pulsing the attention lens about the selected pair in the 3-D view ([`super::attention`]).
    TogglePulse,
    /// Select the pair with the largest leave-one-out error, centre the views on it and pulse the lens there.
    ShowWorstPair,
    /// Open a volume in the 3-D view with the leafer, change its opening, or close it ([`super::leafer`]).
    SetLeafer(super::leafer::Leafer),
    /// The brush becomes the tool, or stops being it (B).
    ToggleSculpting,
    /// Append a brush stroke to the document's brush (the first move of a drag with the brush).
    AddStroke(BrushStroke),
    /// Replace the last brush stroke (the stroke being dragged); `settled`: the drag's end, fitted with the brush's
    /// inverse by scattered-data interpolation.
    MoveStroke {
        stroke: BrushStroke,
        settled: bool,
    },
    /// Remove every brush stroke.
    ClearBrush,
    /// Set the TPS stiffness to the λ under which the pairs in the fit are most likely (generalised maximum likelihood)
    /// ([`warpbench_solver::stiffness`]).
    AutoStiffness,
    /// Align the moving volume to the fixed one by mutual information on a thread of its own; the result arrives as
    /// [`Command::SetStart`] ([`super::alignment`]).
    AutoAlign(warpbench_solver::align::AlignKind),
    /// Put a starting transform under the landmark warp, or take it away (`None`).
    SetStart(Option<StartingTransform>),
    /// Register the pair by intensities under the landmarks on a thread of its own; the result becomes the
    /// document's displacement field ([`super::intensity`]).
    RefineByIntensities,
    /// Stop the refinement by intensities; the warp stays as it was.
    CancelRefineByIntensities,
    /// Back, Forward, or a named view ([`super::places`]).
    Place(super::places::PlaceAction),
    /// Take the suggested target of the pair being added as its fixed point (Enter; [`super::suggestion`]).
    AcceptSuggestion,
    /// Search again for pair `i`'s target from its moving point and the current warp, and move its fixed point there
    /// unless the search is unsure.
    RefinePair(usize),
}

/// What a settings change costs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Effect {
    None,
    Slices,
    Render,
    Refit,
}

/// The cost of going from `old` to `new` settings: the warp's parameters refit, the probe, the brush's radius and the
/// refinement's measure are only read by the next click, the oblique planes move only the slices, and the rest changes
/// the picture.
fn effect(old: &ViewSettings, new: &ViewSettings) -> Effect {
    let refit = old.method != new.method
        || old.stiffness.to_bits() != new.stiffness.to_bits()
        || old.bspline_levels != new.bspline_levels
        || old.grid_n != new.grid_n;
    let without = |s: &ViewSettings, oblique, overlay| ViewSettings {
        pick_probe: new.pick_probe,
        pick_threshold: new.pick_threshold,
        brush_radius_mm: new.brush_radius_mm,
        follow_pair: new.follow_pair,
        refine_metric: new.refine_metric,
        oblique,
        overlay,
        ..s.clone()
    };
    if refit {
        Effect::Refit
    } else if without(old, new.oblique, new.overlay) != *new {
        Effect::Render
    } else if old.oblique != new.oblique || old.overlay != new.overlay {
        Effect::Slices
    } else {
        Effect::None
    }
}

impl Ready {
    /// Carries out `command`.
    pub fn apply(&mut self, command: Command) {
        if Self::jumps_views(&command) {
            self.view.places.history.boundary();
        }
        match command {
            Command::Undo => {
                if let Some(s) = self.history.undo().cloned() {
                    self.restore(&s);
                }
            }
            Command::Redo => {
                if let Some(s) = self.history.redo().cloned() {
                    self.restore(&s);
                }
            }
            Command::ResetCamera => self.reset_camera(),
            Command::Orbit(drag) => {
                self.view.camera.azimuth_rad -= drag.x * 0.01;
                self.view.camera.elevation_rad = (self.view.camera.elevation_rad + drag.y * 0.01).clamp(-1.5, 1.5);
                self.invalidate_view();
            }
            Command::Zoom(scroll) => {
                self.view.camera.zoom = (self.view.camera.zoom * (1.0 + scroll * 0.002)).clamp(0.2, 20.0);
                self.invalidate_view();
            }
            Command::JumpTo(i) => self.jump_to(i),
            Command::Select(i) => {
                self.pointer.selected = Some(i);
                self.invalidate();
                self.follow(i);
            }
            Command::Cancel => {
                // Esc drops a suggested target first (the partner is then clicked by hand), then stops adding.
                if !self.pointer.interaction.reject_suggestion() && !self.pointer.interaction.stop_adding() {
                    self.pointer.selected = None;
                }
                self.invalidate();
            }
            Command::ToggleAdding => self.pointer.interaction.toggle_adding(),
            Command::UseSelect => {
                self.pointer.interaction.stop_adding();
                self.invalidate();
            }
            Command::AddPair { moving, fixed } => {
                let name = format!("Pt-{}", self.document.pairs.len() + 1);
                self.document.pairs.push(LandmarkPair::new(name, moving, fixed));
                self.refit_soon();
                self.follow(self.document.pairs.len() - 1);
            }
            Command::MovePoint { pair, end, to, settled } => {
                let Some(p) = self.document.pairs.get_mut(pair) else { return };
                match end {
                    End::Fixed => p.fixed = Some(to),
                    End::Moving => p.moving = Some(to),
                }
                if settled {
                    self.refit_soon();
                    self.follow(pair);
                } else {
                    self.refit_interactive();
                }
            }
            Command::DeletePair(i) => {
                if i < self.document.pairs.len() {
                    self.document.pairs.remove(i);
                    self.pointer.selected = None;
                    self.refit_soon();
                }
            }
            Command::RenamePair(i, name) => {
                if let Some(p) = self.document.pairs.get_mut(i) {
                    p.name = name;
                }
            }
            Command::SetActive(i, active) => {
                if let Some(p) = self.document.pairs.get_mut(i) {
                    p.active = active;
                    self.refit_soon();
                }
            }
            Command::SetSettings(new) => {
                let effect = effect(&self.document.settings, &new);
                self.document.settings = new;
                match effect {
                    Effect::None => {}
                    Effect::Slices => self.invalidate_slices(),
                    Effect::Render => self.invalidate(),
                    Effect::Refit => self.refit_soon(),
                }
            }
            Command::SetLooks(looks) => {
                self.document.layers = looks;
                self.invalidate();
            }
            Command::MoveSlice(a, mm) => {
                if let Some(s) = self.view.slice_mm.get_mut(a) {
                    *s = mm;
                    self.invalidate_slices();
                    self.crosshair_moved();
                }
            }
            Command::CentreSlices(x_ref) => {
                self.view.slice_mm = [x_ref[2], x_ref[1], x_ref[0]];
                self.invalidate_slices();
                self.crosshair_moved();
            }
            Command::SetLayout(layout) => {
                (self.view.layout, self.view.maximised) = (layout, None);
                self.invalidate();
            }
            Command::ToggleMaximise(pane) => {
                self.view.maximised = super::layout::toggled(self.view.maximised, pane);
                self.invalidate();
            }
            Command::CentreViews(x_ref) => {
                self.view.slice_mm = [x_ref[2], x_ref[1], x_ref[0]];
                self.view.camera.target_ref = Vec3::from_array(x_ref.map(|v| v as f32));
                self.view.camera.pan_mm = warpbench_gpu::glam::Vec2::ZERO;
                self.crosshair_moved();
                self.invalidate();
            }
            Command::File(action) => self.file_action(action),
            Command::Export(kind, out) => self.start_export(kind, out),
            Command::TogglePulse => {
                self.view.attention = self.view.attention.toggled(std::time::Instant::now());
                self.invalidate_view();
            }
            Command::ExcludeOutliers => self.exclude_outliers(),
            Command::ShowWorstPair => {
                match crate::project::diagnostics::loo_ranking(&self.document.pairs, &self.fit.pair_errors).first() {
                    Some(&(_, i)) => {
                        self.jump_to(i);
                        self.view.attention = self.view.attention.on(std::time::Instant::now());
                    }
                    None => {
                        self.pointer.notice =
                            Some("no leave-one-out errors yet: the worst pair needs a fit of 5 pairs".into());
                    }
                }
            }
            Command::SetLeafer(leafer) => {
                self.view.leafer = leafer;
                self.invalidate_view();
            }
            Command::ToggleSculpting => self.pointer.interaction.toggle_sculpting(),
            Command::AddStroke(stroke) => {
                self.document.brush.push(stroke.clamped());
                self.refit_interactive();
            }
            Command::MoveStroke { stroke, settled } => {
                let Some(last) = self.document.brush.last_mut() else { return };
                *last = stroke.clamped();
                if settled { self.refit_soon() } else { self.refit_interactive() }
            }
            Command::ClearBrush => {
                if !self.document.brush.is_empty() {
                    self.document.brush.clear();
                    self.refit_soon();
                }
            }
            Command::AutoStiffness => self.auto_stiffness(),
            Command::AutoAlign(kind) => self.start_alignment(kind),
            Command::SetStart(start) => {
                if self.document.start != start {
                    self.document.start = start;
                    self.refit_soon();
                }
            }
            Command::RefineByIntensities => self.start_intensities(),
            Command::CancelRefineByIntensities => {
                if let Some(job) = &self.assist.refining {
                    job.cancel();
                }
            }
            Command::AcceptSuggestion => {
                if let Some(s) = self.pointer.interaction.suggestion() {
                    self.place_at_ref(s.fixed_lps, None);
                }
            }
            Command::RefinePair(i) => self.refine_pair(i),
            Command::Place(action) => self.place_action(action),
        }
    }

    /// Whether `command` moves the views in one jump: a step of the views' history of its own
    /// ([`super::places::ViewHistory::boundary`]).
    fn jumps_views(command: &Command) -> bool {
        matches!(
            command,
            Command::ResetCamera
                | Command::JumpTo(_)
                | Command::CentreSlices(_)
                | Command::CentreViews(_)
                | Command::ShowWorstPair
                | Command::File(_)
        )
    }

    /// Chooses the stiffness by the leave-one-out error of the pull-back's pairs (fixed → moving, the errors the
    /// table shows), sets it and fits again; a set of pairs it cannot judge is reported in the status bar.
    fn auto_stiffness(&mut self) {
        let (_, pairs) = self.fit_pairs();
        match warpbench_solver::stiffness::choose_stiffness(&pairs.0, &pairs.1) {
            Ok(choice) => {
                self.document.settings.stiffness = choice.lambda;
                self.assist.stiffness_choice = Some(super::StiffnessChoiceOn { choice, pairs });
                self.pointer.notice = None;
                self.refit_soon();
            }
            Err(e) => self.pointer.notice = Some(format!("Auto stiffness: {e}")),
        }
    }

    /// Runs the target search again for pair `i` ([`super::suggestion`]): its fixed point moves to the suggestion
    /// (one undo step) unless the search is unsure or fails, which the status bar says.
    fn refine_pair(&mut self, i: usize) {
        let Some(p) = self.document.pairs.get(i).and_then(|p| p.moving) else {
            self.pointer.notice = Some(format!("Refine pair: pair {} has no moving point", i + 1));
            return;
        };
        match self.suggestion_for(p) {
            Ok(s) if s.low_confidence => {
                self.pointer.notice = Some(format!(
                    "Refine pair {}: the search is unsure (confidence {:.2}); the pair is left as it was",
                    i + 1,
                    s.confidence
                ));
            }
            Ok(s) => {
                let before = self.document.pairs[i].fixed.map(|q| q.coords());
                let moved = before.map_or(0.0, |q| (0..3).map(|a| (q[a] - s.fixed_lps[a]).powi(2)).sum::<f64>().sqrt());
                self.document.pairs[i].fixed = Some(Point3::from_array(s.fixed_lps));
                self.pointer.notice = Some(format!(
                    "Refine pair {}: its fixed point moved {moved:.2} mm (confidence {:.2})",
                    i + 1,
                    s.confidence
                ));
                self.refit_soon();
            }
            Err(e) => self.pointer.notice = Some(format!("Refine pair {}: {e}", i + 1)),
        }
    }

    /// With "Follow the pair being edited" on, centres the slices on pair `i`'s fixed point; otherwise nothing moves:
    /// the camera and the slices stay where the user put them whatever the warp does.
    fn follow(&mut self, i: usize) {
        if !self.document.settings.follow_pair {
            return;
        }
        let Some(q) = self.document.pairs.get(i).and_then(|p| p.fixed) else { return };
        let c = q.coords();
        self.view.slice_mm = [c[2], c[1], c[0]];
        self.invalidate_slices();
        self.crosshair_moved();
    }

    /// The crosshair moved: the leafer's cut goes through it, so an open leafer redraws the 3-D view.
    pub(super) fn crosshair_moved(&mut self) {
        if self.view.leafer.is_open() {
            self.invalidate_view();
        }
    }

    /// Records the document as an undo step once a change has settled: nothing being placed and no pointer button
    /// held (`pointer_down`).
    pub fn settle(&mut self, pointer_down: bool) {
        if self.placing() == Placing::Idle && !pointer_down {
            let now = self.snapshot();
            self.history.record(&now);
        }
    }

    /// Puts the camera back: the whole fixed volume in view, from the front-left, slightly above.
    pub fn reset_camera(&mut self) {
        let (lo, hi) = self.viewer.scene_box();
        self.view.camera = OrbitCamera::fit(lo, hi, self.view.camera.projection);
        self.view.camera.azimuth_rad = 0.6;
        self.view.camera.elevation_rad = 0.25;
        self.invalidate_view();
    }

    /// [`Command::ExcludeOutliers`]: the outliers among the pairs in the fit switched off, and the status bar says
    /// which (or that there were none).
    fn exclude_outliers(&mut self) {
        let (rows, (fixed, moving)) = self.document.fit_pairs();
        let method = self.document.settings.method();
        let fixed_box = crate::inputs::volume_box(&self.loaded.fixed);
        let out = crate::project::diagnostics::outliers(&method, &fixed, &moving, fixed_box);
        if out.is_empty() {
            self.pointer.notice = Some(format!("No outliers among the {} pairs in the fit.", rows.len()));
            return;
        }
        let names: Vec<String> = out.iter().map(|&k| self.document.pairs[rows[k]].name.clone()).collect();
        for &k in &out {
            self.document.pairs[rows[k]].active = false;
        }
        self.pointer.notice = Some(format!("Excluded {} outlier(s): {}", names.len(), names.join(", ")));
        self.refit_soon();
    }

    /// Selects pair `i` and centres the camera and the three slices on its fixed point.
    fn jump_to(&mut self, i: usize) {
        let Some(q) = self.document.pairs.get(i).and_then(|p| p.fixed) else { return };
        self.pointer.selected = Some(i);
        let c = q.coords();
        self.view.slice_mm = [c[2], c[1], c[0]];
        self.view.camera.target_ref = Vec3::from_array(c.map(|v| v as f32));
        self.view.camera.pan_mm = warpbench_gpu::glam::Vec2::ZERO;
        self.invalidate();
    }

    /// What undo restores, as it is now.
    #[must_use]
    pub fn snapshot(&self) -> Snapshot {
        Snapshot { document: self.document.clone(), volumes: [&self.loaded.fixed, &self.loaded.moving].map(Arc::clone) }
    }

    /// Puts `s` back: the volumes (prepared again for the GPU when they differ) and the document; fits the warp
    /// again.
    fn restore(&mut self, s: &Snapshot) {
        let sources = s.document.sources();
        let now = [&self.loaded.fixed, &self.loaded.moving].map(Arc::clone).into_iter().zip(self.document.sources());
        for (side, ((volume, source), (now_volume, now_source))) in
            [open::Side::Fixed, open::Side::Moving].into_iter().zip(s.volumes.iter().zip(sources).zip(now))
        {
            if (!Arc::ptr_eq(volume, &now_volume) || source != now_source)
                && let Err(e) = self.swap_volume(side, Arc::clone(volume), source, None)
            {
                self.files.message = Some(format!("restoring the {} volume: {e:#}", side.name()));
            }
        }
        self.document = s.document.clone();
        self.pointer.interaction.stop_adding();
        self.refit_soon();
    }
}

/// Auto-align's and the refinement's results become the document's.
impl Ready {
    /// Takes Auto-align's result once its thread has it: the document's starting transform (one undo step), or the
    /// problem in the status bar; call once per frame.
    pub fn poll_alignment(&mut self) {
        let Some(result) = self.assist.aligning.as_ref().and_then(super::alignment::AlignJob::poll) else { return };
        self.assist.aligning = None;
        match result {
            Ok(start) => {
                self.pointer.notice = None;
                self.apply(Command::SetStart(Some(start)));
            }
            Err(e) => self.pointer.notice = Some(e),
        }
    }

    /// Takes the refinement's result once its thread has it: the document's displacement field under the landmarks
    /// (one undo step), or the problem (a cancel) in the status bar; call once per frame.
    pub fn poll_intensities(&mut self) {
        let Some(result) = self.assist.refining.as_ref().and_then(super::intensity::IntensityJob::poll) else { return };
        self.assist.refining = None;
        match result {
            Ok(refined) => {
                self.pointer.notice = Some(refined.summary.clone());
                self.document.field = Some(crate::project::field_file::FieldFile::new(refined.field.clone()));
                let (_, pairs) = self.fit_pairs();
                self.assist.refined = Some(super::intensity::RefinedOn { refined, pairs });
                self.refit_soon();
            }
            Err(e) => self.pointer.notice = Some(e),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::settings::{Blend, MethodKind, Probe};

    #[test]
    fn a_setting_costs_a_refit_a_render_the_slices_or_nothing() {
        let old = ViewSettings::default();
        let with = |f: fn(&mut ViewSettings)| {
            let mut s = old.clone();
            f(&mut s);
            effect(&old, &s)
        };
        assert_eq!(with(|_| {}), Effect::None);
        assert_eq!(with(|s| s.method = MethodKind::Rigid), Effect::Refit);
        assert_eq!(with(|s| s.stiffness = 2.0), Effect::Refit);
        assert_eq!(with(|s| s.bspline_levels += 1), Effect::Refit);
        assert_eq!(with(|s| s.grid_n = 20), Effect::Refit);
        assert_eq!(with(|s| s.blend = Blend::Difference), Effect::Render);
        assert_eq!(with(|s| s.show_landmarks = false), Effect::Render);
        assert_eq!(with(|s| s.oblique[1].on = true), Effect::Slices);
        assert_eq!(with(|s| (s.pick_probe, s.pick_threshold) = (Probe::Gradient, 50.0)), Effect::None);
        assert_eq!(with(|s| s.brush_radius_mm = 35.0), Effect::None);
        assert_eq!(with(|s| (s.oblique[0].tilt_deg, s.mix_weight) = (5.0, 0.1)), Effect::Render);
        assert_eq!(with(|s| s.procedural = Some(crate::procedural::ProceduralSpec::default())), Effect::Render);
    }
}
