//! Native file dialogs (rfd) on their own thread, so that the window keeps drawing: what each is for
//! ([`Purpose`]: its title, its filters, whether it saves, picks a file or picks a folder) and the one open
//! ([`DialogJob`]).

use std::path::PathBuf;
use std::sync::mpsc::{Receiver, TryRecvError};

use eframe::egui;

use super::side::Side;
use crate::jacobian::Quantity;
use crate::transform::TransformFormat;

/// What a native file dialog is for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Purpose {
    /// A volume file (NIfTI, NRRD, MetaImage) for one side.
    OpenFile(Side),
    /// A DICOM series folder for one side.
    OpenFolder(Side),
    OpenSession,
    ImportLandmarks,
    SaveSession,
    ExportLandmarks,
    ExportWarped,
    ExportField,
    ExportInverseField,
    /// A map of the warp (det ∇u or |u(x) − x|) as a volume.
    ExportMap(Quantity),
    /// The exact transform, in ITK's or elastix's format.
    ExportTransform(TransformFormat),
    Screenshot,
    /// A starting transform's file to put under the landmarks.
    UseStart,
    /// A displacement field to put under the landmarks.
    UseField,
    /// An OME-Zarr displacement field folder to put under the landmarks.
    UseFieldFolder,
    /// A mask of one volume for Refine by intensities.
    UseMask(Side),
}

impl Purpose {
    fn dialog(self) -> rfd::FileDialog {
        let d = rfd::FileDialog::new();
        let volumes = |d: rfd::FileDialog| {
            d.add_filter(
                "Volumes (NIfTI, NRRD, MetaImage, MGH, MINC, AFNI)",
                &["nii", "gz", "hdr", "img", "nrrd", "nhdr", "mha", "mhd", "mgh", "mgz", "mnc", "HEAD", "BRIK"],
            )
            .add_filter("All files", &["*"])
        };
        match self {
            Self::OpenFile(side) => volumes(d.set_title(format!("Open the {} volume", side.name()))),
            Self::OpenFolder(side) => d.set_title(format!("Open a DICOM or OME-Zarr folder: {}", side.name())),
            Self::OpenSession | Self::SaveSession => d.add_filter("warpbench session", &["json"]),
            Self::ImportLandmarks => d
                .add_filter("Landmarks (BigWarp CSV or JSON, Slicer, MNI tag)", &["csv", "json", "fcsv", "tag"])
                .add_filter("Thin-plate spline saved by 3D Slicer or ITK", &["h5", "tfm"])
                .add_filter("transformix's outputpoints.txt", &["txt"]),
            Self::ExportLandmarks => {
                d.add_filter("Landmarks (BigWarp CSV or JSON, Slicer, MNI tag)", &["csv", "json", "fcsv", "tag"])
            }
            Self::ExportWarped | Self::ExportMap(_) => d
                .add_filter(
                    "NIfTI, NRRD, MetaImage, MGH or MINC",
                    &["nii", "gz", "nrrd", "mha", "mhd", "mgh", "mgz", "mnc"],
                )
                .add_filter("OME-Zarr 0.5 folder (name it .ome.zarr)", &["zarr"]),
            Self::ExportField | Self::ExportInverseField => d
                .add_filter("Displacement fields (NIfTI, NRRD, MetaImage)", &["nii", "gz", "nrrd", "mha", "mhd"])
                .add_filter("ITK transform holding the field (HDF5), MNI grid transform", &["h5", "xfm"])
                .add_filter("OME-Zarr 0.6 field folder (name it .ome.zarr)", &["zarr"]),
            Self::UseField => d
                .set_title("A displacement field, or an elastix or ITK transform, to put under the landmarks")
                .add_filter("Displacement fields (NIfTI, NRRD, MetaImage)", &["nii", "gz", "nrrd", "mha", "mhd"])
                .add_filter("elastix transform parameter file", &["txt"])
                .add_filter("ITK transform with a field (ANTs Composite.h5)", &["h5"])
                .add_filter("DICOM Deformable Spatial Registration", &["dcm"])
                .add_filter("MINC grid transform", &["xfm"])
                .add_filter("AFNI 3dQwarp warp", &["HEAD", "BRIK"]),
            Self::UseFieldFolder => d.set_title("An OME-Zarr displacement field folder to put under the landmarks"),
            Self::ExportTransform(TransformFormat::Itk) => {
                d.add_filter("ITK or ANTs transform", &["tfm", "txt", "h5", "mat"])
            }
            Self::ExportTransform(TransformFormat::Elastix) => {
                d.add_filter("elastix transform parameter file", &["txt"]).set_file_name("TransformParameters.0.txt")
            }
            Self::ExportTransform(TransformFormat::Fsl) => d.add_filter("FSL FLIRT matrix", &["mat"]),
            Self::ExportTransform(TransformFormat::Afni) => d.add_filter("AFNI matrix file", &["1D"]),
            Self::ExportTransform(TransformFormat::Lta) => d.add_filter("FreeSurfer LTA", &["lta"]),
            Self::ExportTransform(TransformFormat::Minc) => d.add_filter("MNI transform (MINC)", &["xfm"]),
            Self::ExportTransform(TransformFormat::Dicom) => {
                d.add_filter("DICOM Spatial Registration", &["dcm"]).set_file_name("registration.dcm")
            }
            Self::UseStart => d
                .set_title("A linear transform to start from")
                .add_filter("ITK, ANTs or elastix transform", &["tfm", "txt", "mat", "h5"])
                .add_filter("FSL, AFNI or FreeSurfer matrix", &["mat", "1D", "lta"])
                .add_filter("DICOM Spatial Registration", &["dcm"]),
            Self::UseMask(side) => volumes(d.set_title(format!("A mask of the {} volume", side.name()))),
            Self::Screenshot => d.add_filter("PNG image", &["png"]),
        }
    }

    fn saves(self) -> bool {
        matches!(
            self,
            Self::SaveSession
                | Self::ExportLandmarks
                | Self::ExportWarped
                | Self::ExportField
                | Self::ExportInverseField
                | Self::ExportMap(_)
                | Self::ExportTransform(_)
                | Self::Screenshot
        )
    }
}

/// A native dialog running on its own thread (rfd's dialogs block their thread; through the XDG portal on Linux,
/// any thread may open one).
#[derive(Debug)]
pub struct DialogJob {
    pub purpose: Purpose,
    rx: Receiver<Option<PathBuf>>,
}

impl DialogJob {
    #[must_use]
    pub fn start(ctx: &egui::Context, purpose: Purpose) -> Self {
        let (tx, rx) = std::sync::mpsc::channel();
        let ctx = ctx.clone();
        std::thread::spawn(move || {
            let dialog = purpose.dialog();
            let chosen = match purpose {
                Purpose::OpenFolder(_) | Purpose::UseFieldFolder => dialog.pick_folder(),
                p if p.saves() => dialog.save_file(),
                _ => dialog.pick_file(),
            };
            let _ = tx.send(chosen);
            ctx.request_repaint();
        });
        Self { purpose, rx }
    }

    /// `Some(Some(path))` when a path was chosen, `Some(None)` when the dialog was dismissed (or no dialog could be
    /// shown), `None` while it is open.
    #[must_use]
    pub fn poll(&self) -> Option<Option<PathBuf>> {
        match self.rx.try_recv() {
            Ok(chosen) => Some(chosen),
            Err(TryRecvError::Empty) => None,
            Err(TryRecvError::Disconnected) => Some(None),
        }
    }
}
