//! What the window does with files: the file section's and the File menu's actions (sessions, landmarks,
//! screenshots, the displacement field under the landmarks), starting an export, and the session's view of the
//! window.

use std::path::PathBuf;
use std::sync::Arc;

use super::files::{self, FileAction, save_png};
use super::{Ready, export};
use crate::project::document::StartingTransform;
use crate::project::field_file::{FieldFile, FieldReadFormat};
use crate::project::session;

/// The document's mask of one volume for Refine by intensities.
fn mask_of(document: &mut crate::project::document::Document, side: super::open::Side) -> &mut Option<PathBuf> {
    match side {
        super::open::Side::Fixed => &mut document.fixed_mask,
        super::open::Side::Moving => &mut document.moving_mask,
    }
}

impl Ready {
    /// Carries out a file action of the side panel or the File menu; the outcome goes to `file_message`.
    pub(super) fn file_action(&mut self, action: FileAction) {
        match action {
            FileAction::SaveSession(path) => {
                let file = self.to_session(true);
                self.files.message = Some(match session::save(&path, &file) {
                    Ok(()) => {
                        let message = format!("saved {}", path.display());
                        self.files.saved_session = Some(path);
                        message
                    }
                    Err(e) => format!("{e:#}"),
                });
            }
            FileAction::ExportLandmarks(path) => {
                self.files.message = Some(match files::export_landmarks(&path, &self.document.pairs) {
                    Ok(()) => format!("wrote {}", path.display()),
                    Err(e) => format!("{e:#}"),
                });
            }
            FileAction::Screenshot(path) => {
                // The window as it is drawn this frame, saved when the integration hands the pixels over.
                self.ctx.request_screenshot(move |image| {
                    if let Err(e) = save_png(&path, &image) {
                        eprintln!("warpbench: {e:#}");
                    }
                });
                self.files.message = Some("screenshot requested".into());
            }
            FileAction::ImportLandmarks(path) => match files::import_landmarks(&path) {
                Ok(pairs) => {
                    self.files.message = Some(format!("read {} pairs from {}", pairs.len(), path.display()));
                    self.document.pairs = pairs;
                    self.refit_soon();
                }
                Err(e) => self.files.message = Some(format!("{e:#}")),
            },
            FileAction::ExportWarped(path) => self.start_export(export::ExportKind::Warped { dicom: None }, path),
            FileAction::ExportField(path) => {
                self.start_export(export::ExportKind::Field { form: export::FieldForm::ByName }, path);
            }
            FileAction::ExportInverseField(path) => self.start_export(export::ExportKind::InverseField, path),
            FileAction::ExportMap(quantity, path) => self.start_export(export::ExportKind::Map { quantity }, path),
            FileAction::ExportTransform(format, path) => {
                self.start_export(export::ExportKind::Transform { format }, path);
            }
            // A field that cannot be read is refused here, so the document never holds one the fit would skip.
            // A Learn2Reg field keeps the grids of the pair open now, in which its steps are counted.
            FileAction::UseField(path) => self.use_field(path, FieldReadFormat::Auto),
            FileAction::UseLearn2RegField(path) => self.use_field(path, FieldReadFormat::Learn2reg),
            // A mask that cannot be read is refused here, so a refinement never starts from one it cannot use.
            FileAction::UseMask(side, path) => match warpbench_io::open(&path) {
                Ok(_) => {
                    self.pointer.notice = Some(format!(
                        "{}: Refine by intensities reads the {} volume where it is not 0",
                        path.display(),
                        side.name()
                    ));
                    *mask_of(&mut self.document, side) = Some(path);
                }
                Err(e) => self.pointer.notice = Some(format!("not used as the {} mask: {e}", side.name())),
            },
            FileAction::RemoveMask(side) => {
                *mask_of(&mut self.document, side) = None;
                self.pointer.notice = Some(format!("Refine by intensities reads the whole {} volume", side.name()));
            }
            // A file that holds no invertible linear transform is refused here, naming it; the document is unchanged.
            // A FLIRT matrix is read against the open volumes, and kept as the transform it is on them.
            FileAction::UseStart(path) => {
                match crate::start::Start::read_on(&path, &self.loaded.fixed, &self.loaded.moving) {
                    Ok(start) => {
                        let t = start.moving_from_fixed();
                        let origin = path
                            .file_name()
                            .map_or_else(|| path.display().to_string(), |n| n.to_string_lossy().into_owned());
                        let document_start = StartingTransform::new(t.linear(), t.translation(), origin);
                        self.files.message =
                            Some(format!("{} is the starting transform under the landmarks", path.display()));
                        if self.document.start.as_ref() != Some(&document_start) {
                            self.document.start = Some(document_start);
                            self.refit_soon();
                        }
                    }
                    Err(e) => self.files.message = Some(format!("not used as the starting transform: {e:#}")),
                }
            }
            FileAction::RemoveField => {
                if self.document.field.take().is_some() {
                    self.files.message = Some("the displacement field is removed".into());
                    self.refit_soon();
                }
            }
        }
    }

    /// Starts exporting the warped moving volume or the displacement field to `out` on a worker thread (one
    /// export at a time), with the current pairs and method.
    pub(super) fn start_export(&mut self, kind: export::ExportKind, out: PathBuf) {
        if self.files.export.is_some() {
            self.files.message = Some("an export is running: wait for it or cancel it".into());
            return;
        }
        let input = export::ExportInput {
            fixed: Arc::clone(&self.loaded.fixed),
            moving: Arc::clone(&self.loaded.moving),
            fixed_path: self.document.fixed.clone(),
            moving_path: self.document.moving.clone(),
            pairs: self.document.pairs.clone(),
            method: self.document.settings.method(),
            brush: self.document.brush.clone(),
            start: self.document.start.clone(),
            field: self.document.field.clone(),
        };
        match export::ExportJob::start(&self.ctx, kind, out, input) {
            Ok(job) => {
                self.files.message = None;
                self.files.export = Some(job);
            }
            Err(e) => self.files.message = Some(e),
        }
    }

    /// Puts the field at `path` under the landmarks, read as `read` says; one that cannot be read is refused in the
    /// status bar and the document keeps what it had.
    fn use_field(&mut self, path: std::path::PathBuf, read: FieldReadFormat) {
        let chosen = FieldFile::chosen(path, read, &self.loaded.fixed, &self.loaded.moving)
            .map_err(|e| format!("{e:#}"))
            .and_then(|file| self.fit.read_field(&file).map(|warnings| (file, warnings)));
        match chosen {
            Ok((file, warnings)) => {
                let grids = match &file.voxel_grids {
                    Some(_) if crate::project::field_file::is_fnirt_file(&file.path).unwrap_or(false) => {
                        " (an FSL FNIRT warp, with this fixed volume as its reference and this moving volume as its \
                         input)"
                    }
                    Some(_) => " (Learn2Reg voxel steps, from this fixed volume's voxels to this moving volume's)",
                    None => "",
                };
                let assumed: String = warnings.iter().flat_map(|w| ["; warning: ", w.as_str()]).collect();
                self.files.message = Some(format!(
                    "{} is the displacement field under the landmarks{grids}{assumed}",
                    file.path.display()
                ));
                self.document.field = Some(file);
                self.refit_soon();
            }
            Err(e) => self.files.message = Some(e),
        }
    }

    /// The session as it is now: the document and where the views look.
    #[must_use]
    pub fn to_session(&self, clean_exit: bool) -> session::SessionFile {
        let view = session::View {
            camera: super::places::session_camera(&self.view.camera),
            slice_mm: self.view.slice_mm,
            layout: self.view.layout,
            named_views: self.view.places.named.clone(),
        };
        session::SessionFile::new(self.document.clone(), view, clean_exit)
    }

    /// Points the camera and the slices where a session's views looked, with its layout and named views.
    pub fn apply_view(&mut self, v: &session::View) {
        self.view.places.history.boundary();
        self.view.camera = super::places::with_session_camera(self.view.camera, &v.camera);
        self.view.slice_mm = v.slice_mm;
        self.view.places.named.clone_from(&v.named_views);
        self.view.layout = v.layout;
        self.view.maximised = None;
        self.invalidate();
    }
}
