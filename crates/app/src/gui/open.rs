//! Opening files from the window: volumes read on a worker thread with a progress bar and a cancel button, a chooser
//! when a DICOM folder holds several series or a file several frames, the File menu of native file dialogs
//! ([`super::dialog`]), files dropped on the window, and the dialog that reports a file that could not be opened.
//!
//! Everything here is state plus `*_ui` functions that return what the user asked for ([`OpenEvent`]); the
//! workbench ([`super::Workbench`]) acts on the events.

use std::ops::ControlFlow;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{Receiver, TryRecvError};
use std::sync::{Arc, Mutex, PoisonError};

pub use super::dialog::{DialogJob, Purpose};
pub use super::side::Side;
use super::viewer::{DeviceFacts, LayerData};
use crate::jacobian::Quantity;
pub use crate::project::document::VolumeSource;
use crate::transform::TransformFormat;
use eframe::egui;
use warpbench_io::error::ErrorKind;
use warpbench_io::{LoadOptions, Part, Progress, SeriesSummary, Volume};

/// Progress and cancellation shared between a worker thread and the window.
#[derive(Debug, Default)]
pub struct Watch {
    /// The file being read (its name) and how far.
    progress: Mutex<Option<(String, Progress)>>,
    cancel: AtomicBool,
}

impl Watch {
    /// [`LoadOptions`] that report to this watch and stop when it is cancelled.
    #[must_use]
    pub fn load_options(self: &Arc<Self>, path: &Path) -> LoadOptions<'static> {
        let watch = Arc::clone(self);
        let name = file_name(path);
        LoadOptions::new().progress(move |p| {
            watch.report(&name, p);
            if watch.cancelled() { ControlFlow::Break(()) } else { ControlFlow::Continue(()) }
        })
    }

    /// Records that `what` is at `p`.
    pub fn report(&self, what: &str, p: Progress) {
        *self.progress.lock().unwrap_or_else(PoisonError::into_inner) = Some((what.to_owned(), p));
    }

    /// The last report.
    #[must_use]
    pub fn progress(&self) -> Option<(String, Progress)> {
        self.progress.lock().unwrap_or_else(PoisonError::into_inner).clone()
    }

    /// Asks the worker to stop.
    pub fn cancel(&self) {
        self.cancel.store(true, Ordering::Relaxed);
    }

    #[must_use]
    pub fn cancelled(&self) -> bool {
        self.cancel.load(Ordering::Relaxed)
    }
}

/// The file name of `path` for messages (the whole path when it has none).
#[must_use]
pub fn file_name(path: &Path) -> String {
    path.file_name().map_or_else(|| path.display().to_string(), |n| n.to_string_lossy().into_owned())
}

/// A progress bar for `watch` with a Cancel button (labelled "Cancel loading" for tests and screen readers).
/// Returns whether Cancel was clicked.
pub fn progress_ui(ui: &mut egui::Ui, watch: &Watch) -> bool {
    let mut clicked = false;
    ui.horizontal(|ui| {
        ui.spinner();
        let (text, fraction) = match watch.progress() {
            Some((name, p)) => (format!("Reading {name}: {} {} of {}", p.stage, p.done, p.total), p.fraction()),
            None => ("Starting...".to_owned(), 0.0),
        };
        ui.add(egui::ProgressBar::new(fraction).desired_width(220.0).show_percentage());
        ui.label(text);
        let cancel = ui.button("Cancel");
        cancel.widget_info(|| egui::WidgetInfo::labeled(egui::Role::Button, true, "Cancel loading"));
        if cancel.clicked() {
            watch.cancel();
            clicked = true;
        }
    });
    clicked
}

/// One volume read on a worker thread.
#[derive(Debug)]
pub struct VolumeJob {
    pub side: Side,
    pub source: VolumeSource,
    pub watch: Arc<Watch>,
    rx: Receiver<warpbench_io::Result<ReadVolume>>,
}

/// A volume read by a [`VolumeJob`], and prepared for the window's device when it was known (an error there is the
/// GPU's: the file itself was read).
#[derive(Debug)]
pub struct ReadVolume {
    pub volume: Volume,
    pub layer: Option<anyhow::Result<LayerData>>,
}

impl VolumeJob {
    /// Starts reading `source` (its part: the frame of a 4-D file, the series of a DICOM folder with several), and
    /// preparing it for a device like `facts`.
    #[must_use]
    pub fn start(ctx: &egui::Context, side: Side, source: VolumeSource, facts: Option<DeviceFacts>) -> Self {
        let watch = Arc::new(Watch::default());
        let (tx, rx) = std::sync::mpsc::channel();
        let (worker_watch, worker_source, ctx) = (Arc::clone(&watch), source.clone(), ctx.clone());
        std::thread::spawn(move || {
            let path = &worker_source.path;
            let read = worker_watch.load_options(path).part(worker_source.part.as_ref()).open(path).map(|volume| {
                let layer = facts.map(|facts| LayerData::prepare(&volume, facts));
                ReadVolume { volume, layer }
            });
            let _ = tx.send(read);
            ctx.request_repaint();
        });
        Self { side, source, watch, rx }
    }

    /// The result, once the worker is done.
    #[must_use]
    pub fn poll(&self) -> Option<warpbench_io::Result<ReadVolume>> {
        match self.rx.try_recv() {
            Ok(result) => Some(result),
            Err(TryRecvError::Empty) => None,
            Err(TryRecvError::Disconnected) => Some(Err(warpbench_io::Error::new(
                &self.source.path,
                ErrorKind::Io(std::io::Error::other("the loading thread stopped")),
            ))),
        }
    }
}

/// What a dropped (or chosen) file is: a session or a landmark file by its name, a displacement field by what its
/// first bytes say unambiguously, or else a volume (a folder is a DICOM series or an OME-Zarr image).
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum FileKind {
    Session,
    Landmarks,
    /// A NIfTI of intent `DISPVECT` (1006: ITK, Slicer) or one of FSL's (an FNIRT warp), a Learn2Reg `.npz`, or an
    /// AFNI dataset labelled as `3dQwarp`'s warp: used as the displacement field under the landmarks. (ANTs'
    /// `VECTOR`, 1007, is any vector image, so it stays a volume.)
    Field,
    Volume,
}

#[must_use]
pub fn classify(path: &Path) -> FileKind {
    let name = file_name(path).to_ascii_lowercase();
    if path.is_dir() {
        FileKind::Volume
    } else if name.ends_with(".warpbench.json") {
        FileKind::Session
    } else if [".csv", ".fcsv", ".json"].iter().any(|e| name.ends_with(e)) {
        FileKind::Landmarks
    } else if is_field_file(path) {
        FileKind::Field
    } else {
        FileKind::Volume
    }
}

/// Whether the file says it is a displacement field ([`FileKind::Field`]); one that cannot be read is not.
fn is_field_file(path: &Path) -> bool {
    let intent = warpbench_io::nifti::intent_code(path).ok().flatten();
    let dispvect = i32::from(warpbench_io::nifti::NIFTI_INTENT_DISPVECT);
    intent.is_some_and(|c| c == dispvect || warpbench_io::nifti::FSL_INTENTS.contains(&c))
        || warpbench_io::learn2reg::is_npz_file(path).unwrap_or(false)
        || warpbench_io::afni_dataset::is_warp_file(path).unwrap_or(false)
        || warpbench_io::nifti::afni_extension::is_afni_warp(path).unwrap_or(false)
}

/// What the user asked for through a menu, a dialog, a drop or a chooser.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum OpenEvent {
    /// Read this volume (this series of a DICOM folder, this frame of a 4-D file) as one side of the pair.
    Volume {
        side: Side,
        source: VolumeSource,
    },
    OpenSession(PathBuf),
    ImportLandmarks(PathBuf),
    /// Use this displacement field under the landmarks (a field dropped on the window).
    UseField(PathBuf),
    /// A dialog for a file action (saving, exporting, a file to use) returned a path.
    Chosen(Purpose, PathBuf),
    /// Start a native dialog.
    Dialog(Purpose),
    /// Open the demo pair.
    Demo,
}

/// The dialogs of opening: the error report, the series and frame choosers and the question a dropped volume asks.
#[derive(Debug, Default)]
pub struct OpenDialogs {
    /// A file that could not be opened, and why.
    pub error: Option<String>,
    /// A DICOM folder with several series: which to read, for which side.
    pub series: Option<(Side, PathBuf, Vec<SeriesSummary>)>,
    /// A 4-D file: which frame to read, for which side.
    pub frames: Option<FrameChoice>,
    /// A dropped volume waiting for "fixed or moving?".
    pub dropped: Option<PathBuf>,
    /// The native dialog that is open.
    pub dialog: Option<DialogJob>,
}

impl OpenDialogs {
    /// Reports a failed read of `path` for `side`: the series chooser when the folder holds several series, the
    /// error dialog otherwise (a cancelled read says nothing).
    pub fn failed(&mut self, side: Side, path: &Path, error: &warpbench_io::Error) {
        match &error.kind {
            ErrorKind::MultipleSeries(list) => self.series = Some((side, path.to_path_buf(), list.clone())),
            ErrorKind::Cancelled => {}
            &ErrorKind::FrameRequired { frames } => self.frames = Some(FrameChoice::new(side, path, frames)),
            _ => self.error = Some(format!("Could not open the {} volume: {error}", side.name())),
        }
    }

    /// Files dropped on the window this frame: sessions, landmark files and displacement fields open directly; a
    /// volume asks which side it is (two volumes dropped together are the fixed and the moving one, in that order).
    pub fn take_dropped(&mut self, ctx: &egui::Context) -> Vec<OpenEvent> {
        let dropped: Vec<PathBuf> = ctx.input(|i| {
            i.raw.dropped_files.iter().map(|f| f.path().to_path_buf()).filter(|p| !p.as_os_str().is_empty()).collect()
        });
        let mut events = Vec::new();
        let mut volumes = Vec::new();
        for path in dropped {
            match classify(&path) {
                FileKind::Session => events.push(OpenEvent::OpenSession(path)),
                FileKind::Landmarks => events.push(OpenEvent::ImportLandmarks(path)),
                FileKind::Field => events.push(OpenEvent::UseField(path)),
                FileKind::Volume => volumes.push(path),
            }
        }
        match <[PathBuf; 2]>::try_from(volumes) {
            Ok([fixed, moving]) => {
                events.push(OpenEvent::Volume { side: Side::Fixed, source: VolumeSource::whole(fixed) });
                events.push(OpenEvent::Volume { side: Side::Moving, source: VolumeSource::whole(moving) });
            }
            Err(mut volumes) => {
                if let Some(last) = volumes.pop() {
                    self.dropped = Some(last);
                }
            }
        }
        events
    }

    /// Polls the native dialog and draws the open dialogs; returns what the user chose.
    pub fn ui(&mut self, ctx: &egui::Context) -> Vec<OpenEvent> {
        let mut events = Vec::new();
        if let Some(job) = &self.dialog
            && let Some(chosen) = job.poll()
        {
            let purpose = job.purpose;
            self.dialog = None;
            if let Some(path) = chosen {
                events.push(match purpose {
                    Purpose::OpenFile(side) | Purpose::OpenFolder(side) => {
                        OpenEvent::Volume { side, source: VolumeSource::whole(path) }
                    }
                    Purpose::OpenSession => OpenEvent::OpenSession(path),
                    Purpose::ImportLandmarks => OpenEvent::ImportLandmarks(path),
                    other => OpenEvent::Chosen(other, path),
                });
            }
        }
        if let Some(message) = self.error.clone() {
            let mut open = true;
            egui::Window::new("Could not open").collapsible(false).open(&mut open).show(ctx, |ui| {
                ui.label(message.as_str());
                if ui.button("OK").clicked() {
                    self.error = None;
                }
            });
            if !open {
                self.error = None;
            }
        }
        if let Some((side, path, list)) = self.series.clone() {
            let mut close = false;
            egui::Window::new("Choose a series").collapsible(false).show(ctx, |ui| {
                ui.label(format!(
                    "{} holds {} series. Open which as the {} volume?",
                    path.display(),
                    list.len(),
                    side.name()
                ));
                for s in &list {
                    let text = format!(
                        "Series {}: {} \"{}\", {} files",
                        s.series_number.map_or_else(|| "?".to_owned(), |n| n.to_string()),
                        s.modality,
                        s.description,
                        s.files
                    );
                    if ui.button(text).clicked() {
                        let part = Some(Part::Series(s.series_instance_uid.clone()));
                        events.push(OpenEvent::Volume { side, source: VolumeSource { path: path.clone(), part } });
                        close = true;
                    }
                }
                if ui.button("Cancel").clicked() {
                    close = true;
                }
            });
            if close {
                self.series = None;
            }
        }
        if let Some(choice) = &mut self.frames {
            let mut close = false;
            egui::Window::new("Choose a frame").collapsible(false).show(ctx, |ui| {
                if let Some(source) = choice.ui(ui, &mut close) {
                    events.push(OpenEvent::Volume { side: choice.side, source });
                }
            });
            if close {
                self.frames = None;
            }
        }
        if let Some(path) = self.dropped.clone() {
            let mut close = false;
            egui::Window::new("Open the dropped volume").collapsible(false).show(ctx, |ui| {
                ui.label(format!("Open {} as:", file_name(&path)));
                ui.horizontal(|ui| {
                    for side in [Side::Fixed, Side::Moving] {
                        if ui.button(format!("the {} volume", side.name())).clicked() {
                            events.push(OpenEvent::Volume { side, source: VolumeSource::whole(path.clone()) });
                            close = true;
                        }
                    }
                    if ui.button("Cancel").clicked() {
                        close = true;
                    }
                });
            });
            if close {
                self.dropped = None;
            }
        }
        events
    }
}

/// The frame chooser of a 4-D file (an AFNI dataset's sub-bricks, with their labels).
#[derive(Debug)]
pub struct FrameChoice {
    pub side: Side,
    pub path: PathBuf,
    pub frames: usize,
    /// The frame the chooser shows, 0-based.
    pub chosen: usize,
    /// Each frame's label, where the file names them (AFNI's sub-brick labels); empty otherwise.
    labels: Vec<String>,
}

impl FrameChoice {
    /// Frame 0 of the `frames` of `path`, for `side`.
    #[must_use]
    pub fn new(side: Side, path: &Path, frames: usize) -> Self {
        let labels = if warpbench_io::afni_dataset::has_afni_name(path) {
            warpbench_io::afni_dataset::Header::read(path).map(|h| h.labels()).unwrap_or_default()
        } else {
            Vec::new()
        };
        Self { side, path: path.to_path_buf(), frames, chosen: 0, labels }
    }

    /// The chooser: the frame's number (and label), Open and Cancel. Returns the source to read when Open is
    /// clicked; sets `close` when the chooser is done.
    fn ui(&mut self, ui: &mut egui::Ui, close: &mut bool) -> Option<VolumeSource> {
        let what = if self.labels.is_empty() { "frames" } else { "sub-bricks" };
        ui.label(format!(
            "{} holds {} {what}, and the window shows one 3-D volume. Open which as the {} volume?",
            self.path.display(),
            self.frames,
            self.side.name()
        ));
        let last = self.frames.saturating_sub(1);
        let mut opened = None;
        ui.horizontal(|ui| {
            let label = ui.label(format!("Frame (0 to {last})"));
            ui.add(egui::DragValue::new(&mut self.chosen).range(0..=last)).labelled_by(label.id);
            if let Some(name) = self.labels.get(self.chosen) {
                ui.label(format!("\"{name}\""));
            }
        });
        ui.horizontal(|ui| {
            if ui.button("Open").clicked() {
                let part = Some(Part::Frame(self.chosen.min(last)));
                opened = Some(VolumeSource { path: self.path.clone(), part });
                *close = true;
            }
            if ui.button("Cancel").clicked() {
                *close = true;
            }
        });
        opened
    }
}

/// The File menu. Items that need a path open a native dialog (their text fields in the side panel do the same
/// without one); *Open recent session* lists `recent`, newest first (a file no longer there is shown disabled).
pub fn file_menu(ui: &mut egui::Ui, ready: bool, dialog_open: bool, recent: &[PathBuf]) -> Option<OpenEvent> {
    let mut event = None;
    let mut chosen_recent = None;
    ui.menu_button("File", |ui| {
        let mut item = |ui: &mut egui::Ui, text: &str, enabled: bool, e: OpenEvent| {
            if ui.add_enabled(enabled && !dialog_open, egui::Button::new(text)).clicked() {
                event = Some(e);
                ui.close();
            }
        };
        for side in [Side::Fixed, Side::Moving] {
            item(ui, &format!("Open {} volume...", side.name()), true, OpenEvent::Dialog(Purpose::OpenFile(side)));
            item(
                ui,
                &format!("Open {} folder (DICOM, OME-Zarr)...", side.name()),
                true,
                OpenEvent::Dialog(Purpose::OpenFolder(side)),
            );
        }
        item(ui, "Open the demo pair", true, OpenEvent::Demo);
        ui.separator();
        item(ui, "Open session...", true, OpenEvent::Dialog(Purpose::OpenSession));
        ui.add_enabled_ui(!dialog_open && !recent.is_empty(), |ui| {
            ui.menu_button("Open recent session", |ui| {
                for path in recent {
                    let name =
                        path.file_name().map_or_else(|| path.display().to_string(), |n| n.to_string_lossy().into());
                    let folder = path.parent().map(|f| f.display().to_string()).unwrap_or_default();
                    let button = ui.add_enabled(path.is_file(), egui::Button::new(format!("{name}  ({folder})")));
                    if button.on_disabled_hover_text("This session file is no longer there.").clicked() {
                        chosen_recent = Some(OpenEvent::OpenSession(path.clone()));
                        ui.close();
                    }
                }
            });
        });
        item(ui, "Save session...", ready, OpenEvent::Dialog(Purpose::SaveSession));
        ui.separator();
        item(ui, "Import landmarks...", ready, OpenEvent::Dialog(Purpose::ImportLandmarks));
        item(ui, "Export landmarks...", ready, OpenEvent::Dialog(Purpose::ExportLandmarks));
        ui.separator();
        item(ui, "Export warped volume...", ready, OpenEvent::Dialog(Purpose::ExportWarped));
        item(ui, "Export displacement field...", ready, OpenEvent::Dialog(Purpose::ExportField));
        item(ui, "Export inverse field...", ready, OpenEvent::Dialog(Purpose::ExportInverseField));
        item(ui, "Export Jacobian map...", ready, OpenEvent::Dialog(Purpose::ExportMap(Quantity::Det)));
        item(ui, "Export warp magnitude...", ready, OpenEvent::Dialog(Purpose::ExportMap(Quantity::Magnitude)));
        item(ui, "Export transform...", ready, OpenEvent::Dialog(Purpose::ExportTransform(TransformFormat::Itk)));
        item(ui, "Export for elastix...", ready, OpenEvent::Dialog(Purpose::ExportTransform(TransformFormat::Elastix)));
        item(
            ui,
            "Export DICOM registration...",
            ready,
            OpenEvent::Dialog(Purpose::ExportTransform(TransformFormat::Dicom)),
        );
        item(ui, "Export for FSL...", ready, OpenEvent::Dialog(Purpose::ExportTransform(TransformFormat::Fsl)));
        item(ui, "Export for AFNI...", ready, OpenEvent::Dialog(Purpose::ExportTransform(TransformFormat::Afni)));
        item(ui, "Export for FreeSurfer...", ready, OpenEvent::Dialog(Purpose::ExportTransform(TransformFormat::Lta)));
        item(ui, "Export for MINC...", ready, OpenEvent::Dialog(Purpose::ExportTransform(TransformFormat::Minc)));
        ui.separator();
        item(ui, "Use starting transform...", ready, OpenEvent::Dialog(Purpose::UseStart));
        item(ui, "Use displacement field...", ready, OpenEvent::Dialog(Purpose::UseField));
        item(ui, "Use displacement field folder (OME-Zarr)...", ready, OpenEvent::Dialog(Purpose::UseFieldFolder));
        for side in [Side::Fixed, Side::Moving] {
            item(ui, &format!("Use {} mask...", side.name()), ready, OpenEvent::Dialog(Purpose::UseMask(side)));
        }
        ui.separator();
        item(ui, "Save screenshot...", ready, OpenEvent::Dialog(Purpose::Screenshot));
    });
    event.or(chosen_recent)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_4d_file_asks_for_a_frame_and_an_afni_dataset_shows_its_labels() {
        let mut dialogs = OpenDialogs::default();
        let path = Path::new("/data/bold.nii.gz");
        let error = warpbench_io::Error::new(path, ErrorKind::FrameRequired { frames: 3 });
        dialogs.failed(Side::Moving, path, &error);
        assert!(dialogs.error.is_none(), "{:?}", dialogs.error);
        let choice = dialogs.frames.expect("the frame chooser");
        assert_eq!((choice.side, choice.path.as_path(), choice.frames, choice.chosen), (Side::Moving, path, 3, 0));
        assert!(choice.labels.is_empty());
        // AFNI's sub-brick labels, as nibabel's copy of its dataset has them.
        let afni = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/afni/example4d+orig.HEAD");
        let choice = FrameChoice::new(Side::Fixed, &afni, 3);
        assert_eq!(choice.labels.len(), 3, "{:?}", choice.labels);
        let header = warpbench_io::afni_dataset::Header::read(&afni).expect("the header");
        assert_eq!(choice.labels, header.labels());
    }

    #[test]
    fn files_are_classified_by_name_and_fields_by_content() {
        let dir = tempfile::tempdir().expect("tempdir");
        assert_eq!(classify(&dir.path().join("a.warpbench.json")), FileKind::Session);
        assert_eq!(classify(&dir.path().join("pairs.CSV")), FileKind::Landmarks);
        assert_eq!(classify(&dir.path().join("moving.mrk.json")), FileKind::Landmarks);
        assert_eq!(classify(&dir.path().join("ct.nii.gz")), FileKind::Volume);
        // A field by what its header or its first bytes say: ITK's DISPVECT, FSL's warps, Learn2Reg's .npz, AFNI's
        // 3dQwarp warps (by either file); a plain NIfTI, Learn2Reg's NIfTI form (no intent) and AFNI's other
        // datasets stay volumes.
        let data = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data");
        for field in [
            "itk/field_input_field.nii.gz",
            "fnirt/coef_neuro.nii.gz",
            "fnirt/field_rel.nii.gz",
            "learn2reg/disp_f16.npz",
            "afni_made/warp_rai+tlrc.HEAD",
            "afni_made/warp_lps+orig.BRIK.gz",
            "afni_made/warp_rai_WARP.nii.gz",
        ] {
            assert_eq!(classify(&data.join(field)), FileKind::Field, "{field}");
        }
        for volume in [
            "fnirt/src.nii.gz",
            "learn2reg/disp_nibabel_f32.nii.gz",
            "itk/field_input_fixed.nii.gz",
            "afni/example4d+orig.HEAD",
            "afni/scaled+tlrc.BRIK",
        ] {
            assert_eq!(classify(&data.join(volume)), FileKind::Volume, "{volume}");
        }
        // A folder is a DICOM series, whatever its name.
        let folder = dir.path().join("series.csv");
        std::fs::create_dir(&folder).expect("mkdir");
        assert_eq!(classify(&folder), FileKind::Volume);
    }

    #[test]
    fn a_watch_reports_and_cancels_a_real_read() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/nifti/avg152T1_LR_nifti.nii");
        let watch = Arc::new(Watch::default());
        let volume = watch.load_options(&path).open(&path).expect("read the fixture");
        let (name, p) = watch.progress().expect("progress was reported");
        assert_eq!(name, "avg152T1_LR_nifti.nii");
        assert!(p.total > 0 && p.done == p.total, "{p:?}");
        assert_eq!(volume.dims, [91, 109, 91]);
        watch.cancel();
        let err = watch.load_options(&path).open(&path).expect_err("cancelled");
        assert!(matches!(err.kind, ErrorKind::Cancelled), "{err}");
    }
}
