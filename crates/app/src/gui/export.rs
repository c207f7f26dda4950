//! Exporting from the window: the warped moving volume (NIfTI, and optionally a DICOM series), the displacement
//! field, the exact transform and the maps of det ∇u and |u(x) − x| (`warpbench jacobian`, [`crate::jacobian`]), on a worker thread with a progress bar and a cancel button, through the same code
//! as `warpbench warp` ([`crate::warp::resample`], [`crate::warp::write_outputs`]), `warpbench field`
//! ([`crate::field::displacement_field`], [`crate::field::write_field`]) and `warpbench transform`
//! ([`crate::transform::exact_transform`], [`crate::transform::write_transform`]).
//!
//! The warped volume is resampled on the fixed grid with the window's method: exactly per voxel for TPS and the
//! linear warps, through a 64³ control texture for the hierarchical B-spline (as the CLI's defaults do), trilinear,
//! in the moving volume's sample type. Outputs are written atomically; an input is never overwritten.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::mpsc::{Receiver, TryRecvError};

use eframe::egui;
use warpbench_io::displacement::{FieldDirection, FieldFormat};
use warpbench_io::itk_tfm;
use warpbench_io::landmarks::LandmarkPair;
use warpbench_io::learn2reg;
use warpbench_io::{Progress, Volume};
use warpbench_solver::method::Method;

use super::open::{Watch, file_name};
use crate::exit::Failure;
use crate::field;
use crate::inputs::{self, Names};
use crate::jacobian::{self, Quantity};
use crate::transform::{self, TransformFormat};
use crate::warp::{self, Backend, PullBackMode, WarpSettings};

/// What to export.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum ExportKind {
    /// The warped moving volume as NIfTI, NRRD or MetaImage (by the name), and as a DICOM series in this (new or
    /// empty) folder when given.
    Warped { dicom: Option<PathBuf> },
    /// The pull-back as a displacement field: in mm, in the flavour its name picks ([`field_format`]), or in
    /// Learn2Reg's voxel steps.
    Field { form: FieldForm },
    /// The inverse, the forward map as a displacement field on the moving grid (NIfTI), as `warpbench field
    /// --direction forward` writes it: what moving points and meshes need.
    InverseField,
    /// The pull-back as the exact transform file of `format`, as `warpbench transform` writes it: ITK's `.tfm`
    /// (its HDF5 file for a name ending `.h5`, over the sampled field for a warp with a field or the brush; ANTs'
    /// `.mat` for a linear warp named so), or elastix's parameter file.
    Transform { format: TransformFormat },
    /// A map of the pull-back on the fixed grid (det ∇u, or |u(x) − x|) as a volume, as `warpbench jacobian`
    /// writes it.
    Map { quantity: Quantity },
}

/// The pair and the warp to export, as the window has them.
#[derive(Clone, Debug)]
pub struct ExportInput {
    pub fixed: Arc<Volume>,
    pub moving: Arc<Volume>,
    pub fixed_path: Option<PathBuf>,
    pub moving_path: Option<PathBuf>,
    pub pairs: Vec<LandmarkPair>,
    pub method: Method,
    /// The brush's strokes on top of the landmark warp ([`crate::brushed`]).
    pub brush: Vec<warpbench_solver::brush::BrushStroke>,
    /// The starting transform under the landmark warp (Auto-align, [`crate::start`]).
    pub start: Option<crate::project::document::StartingTransform>,
    /// The displacement field under the landmark warp ([`crate::project::field_file::FieldFile::layer`]).
    pub field: Option<crate::project::field_file::FieldFile>,
}

/// How an exported displacement field is written.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum FieldForm {
    /// In mm, in the flavour its name picks; a name ending `.npz` is Learn2Reg's.
    #[default]
    ByName,
    /// Learn2Reg's steps from the fixed voxels to the moving voxels, `.npz` or the NIfTI form by the name
    /// ([`field::write_learn2reg`]): "Learn2Reg steps in voxels", for a NIfTI name.
    Learn2Reg,
    /// FSL FNIRT's relative deformation field, for `applywarp --rel` ([`warpbench_io::fnirt::write_pullback`]): "FSL
    /// FNIRT field", for a NIfTI name.
    Fnirt,
    /// AFNI's warp, for `3dNwarpApply -nwarp` ([`FieldFormat::Afni`]): "AFNI warp", for a NIfTI name.
    Afni,
}

impl FieldForm {
    /// Whether a field exported to `out` is Learn2Reg's.
    #[must_use]
    pub fn is_learn2reg(self, out: &Path) -> bool {
        self == Self::Learn2Reg || learn2reg::is_npz_name(out)
    }

    /// The field written against the pair's grids that a field exported to `out` is, if any.
    #[must_use]
    pub fn pair_output(self, out: &Path) -> Option<field::PairOutput> {
        if self == Self::Fnirt {
            Some(field::PairOutput::Fnirt)
        } else {
            self.is_learn2reg(out).then_some(field::PairOutput::Learn2Reg)
        }
    }
}

/// An export running on a worker thread.
#[derive(Debug)]
pub struct ExportJob {
    pub kind: ExportKind,
    pub out: PathBuf,
    pub watch: Arc<Watch>,
    rx: Receiver<Result<String, String>>,
}

impl ExportJob {
    /// Checks the output path and starts the export; a bad path is refused at once.
    ///
    /// # Errors
    /// The output is not named as a volume (`.nii`, `.nii.gz`, `.nrrd`, `.mha`, `.mhd`, `.mgh`, `.mgz`, `.mnc`, `.ome.zarr`; a field's name picks its
    /// flavour: [`field_format`]), is one of the inputs, or the DICOM folder is not empty.
    pub fn start(ctx: &egui::Context, kind: ExportKind, out: PathBuf, input: ExportInput) -> Result<Self, String> {
        let inputs: Vec<&Path> = input.fixed_path.iter().chain(&input.moving_path).map(PathBuf::as_path).collect();
        match &kind {
            ExportKind::Warped { dicom } => {
                warp::check_outputs(&out, dicom.as_deref()).map_err(|e| format!("{e:#}"))?;
            }
            ExportKind::Map { .. } => warp::check_outputs(&out, None).map_err(|e| format!("{e:#}"))?,
            // Learn2Reg's field holds the pull-back on the fixed voxels ([`field::write_learn2reg`]), as an .npz or
            // the NIfTI form.
            ExportKind::Field { form: form @ (FieldForm::Fnirt | FieldForm::Afni) } => {
                if FieldFormat::from_extension(&out) != Some(FieldFormat::Itk) {
                    let whose = if *form == FieldForm::Fnirt { "FNIRT's field" } else { "AFNI's warp" };
                    return Err(format!("{}: {whose} is a NIfTI file: name it .nii or .nii.gz", out.display()));
                }
            }
            ExportKind::Field { form } if form.is_learn2reg(&out) => {
                let nifti = FieldFormat::from_extension(&out) == Some(FieldFormat::Itk);
                if !learn2reg::is_npz_name(&out) && !nifti {
                    return Err(format!(
                        "{}: Learn2Reg's field is an .npz (the challenge's form until 2021) or a .nii.gz (its form \
                         since 2022)",
                        out.display()
                    ));
                }
            }
            ExportKind::InverseField if learn2reg::is_npz_name(&out) => {
                return Err(format!(
                    "{}: a Learn2Reg field (.npz) holds the pull-back on the fixed grid: export it with Export \
                     displacement field",
                    out.display()
                ));
            }
            ExportKind::Field { .. } | ExportKind::InverseField => {
                field::check_field_name(&out, field_format(&out)?).map_err(|f| format!("{:#}", f.error()))?;
            }
            ExportKind::Transform { format } => check_transform_output(&out, *format)?,
        }
        inputs::check_output(&out, &inputs, true)
            .and_then(|()| warp::check_data_file(&out, &inputs, true))
            .map_err(|e| format!("{e:#}"))?;
        let watch = Arc::new(Watch::default());
        let (tx, rx) = std::sync::mpsc::channel();
        let (worker_watch, worker_kind, worker_out, ctx) = (Arc::clone(&watch), kind.clone(), out.clone(), ctx.clone());
        std::thread::spawn(move || {
            let result = run(&worker_kind, &worker_out, &input, &worker_watch).map_err(|e| format!("{:#}", e.error()));
            let _ = tx.send(result);
            ctx.request_repaint();
        });
        Ok(Self { kind, out, watch, rx })
    }

    /// `Ok(message)` or `Err(message)` once the worker is done.
    #[must_use]
    pub fn poll(&self) -> Option<Result<String, String>> {
        match self.rx.try_recv() {
            Ok(result) => Some(result),
            Err(TryRecvError::Empty) => None,
            Err(TryRecvError::Disconnected) => Some(Err("the export thread stopped".into())),
        }
    }
}

/// The export itself (on the worker): the CLI's core, then its writer.
fn run(kind: &ExportKind, out: &Path, input: &ExportInput, watch: &Watch) -> Result<String, Failure> {
    let moving_name = input.moving_path.as_deref().map_or_else(|| "the moving volume".to_owned(), file_name);
    let names =
        Names { moving: moving_name.clone(), landmarks: "the window's landmarks".into(), out: out.to_path_buf() };
    let (fixed, moving) = (input.fixed.as_ref(), input.moving.as_ref());
    let brushed = crate::brushed::Brushed::new(&input.brush, "the window's brush").map_err(Failure::BadInput)?;
    let consistency = brushed.as_ref().map_or_else(String::new, |b| {
        let c = b.consistency();
        format!("; the brush's inverse undoes it within {:.3} mm (max; rms {:.4} mm)", c.max_mm, c.rms_mm)
    });
    let start = input
        .start
        .as_ref()
        .map(crate::project::document::StartingTransform::start)
        .transpose()
        .map_err(Failure::BadInput)?;
    let mut layers = crate::project::stack::Layers::new(start, brushed);
    layers.field = input.field.as_ref().map(|f| f.layer().map(Arc::new)).transpose().map_err(Failure::BadInput)?;
    let pairs_and_brush = (input.pairs.as_slice(), &layers);
    let made_of = field::FieldInputs {
        fixed,
        moving,
        pairs: &input.pairs,
        names: &names,
        method: &input.method,
        layers: &layers,
    };
    match kind {
        ExportKind::Warped { dicom } => {
            let settings = WarpSettings {
                method: input.method,
                pullback: if matches!(input.method, Method::BSpline(_)) {
                    PullBackMode::Grid(64)
                } else {
                    PullBackMode::Exact
                },
                interpolation: warpbench_gpu::Interpolation::Trilinear,
                float: false,
                backend: Backend::Auto,
                outside_value: None,
            };
            let mut progress = |p: warpbench_gpu::Progress| {
                let (done, total) = (p.slices_done as u64, p.slices_total as u64);
                watch.report(&file_name(out), Progress { stage: "resampling slices", done, total });
                !watch.cancelled()
            };
            let resampled = warp::resample(fixed, fixed, moving, pairs_and_brush, &names, &settings, &mut progress)?;
            let description = warp::series_description(&resampled.method, Path::new(&moving_name));
            let source = input.moving_path.as_deref().map(|p| (p, moving));
            warp::write_outputs(&resampled.volume, out, dicom.as_deref(), &description, source)?;
            let also = dicom.as_ref().map_or_else(String::new, |d| format!(" and a DICOM series in {}", d.display()));
            Ok(format!(
                "wrote {}{also}: {} warp of {} pairs, {}, {}{consistency}",
                out.display(),
                resampled.method,
                resampled.pairs,
                resampled.pullback,
                resampled.backend
            ))
        }
        ExportKind::Transform { format: TransformFormat::Itk }
            if (layers.field.is_some() || layers.brush.is_some()) && itk_tfm::is_hdf5_name(out) =>
        {
            let mut progress = |done: u64, total: u64| {
                watch.report(&file_name(out), Progress { stage: "field slices", done, total });
                !watch.cancelled()
            };
            let written = transform::write_h5_stack(out, &made_of, &mut progress)?;
            let how = match written.members.as_slice() {
                [_] if written.sampled => format!("{} on the fixed grid", written.itk_class),
                [one] => (*one).to_owned(),
                members if written.sampled => {
                    format!("{} of {}, the last on the fixed grid", written.itk_class, members.join(", "))
                }
                members => format!("{} of {}", written.itk_class, members.join(", ")),
            };
            Ok(format!(
                "wrote {}: {} as {how} ({} pairs; maps fixed points to moving points, LPS mm){consistency}",
                out.display(),
                written.method,
                written.pairs,
            ))
        }
        ExportKind::Transform { format: TransformFormat::Elastix }
            if layers.field.is_some() || layers.brush.is_some() =>
        {
            let mut progress = |done: u64, total: u64| {
                watch.report(&file_name(out), Progress { stage: "field slices", done, total });
                !watch.cancelled()
            };
            let f = field::sample_field(fixed, &made_of, FieldDirection::Pullback, &mut progress)?;
            let field_path = transform::field_file_beside(out);
            transform::write_field_transform(out, &field_path, &f)?;
            Ok(format!(
                "wrote {}: {} as DeformationFieldTransform over {} ({} pairs; no transform file holds a field or a \
                 brush exactly)",
                out.display(),
                layers.describe(&input.method, f.pairs),
                field_path.display(),
                f.pairs
            ))
        }
        ExportKind::Transform { format: TransformFormat::Dicom } => {
            let pair = transform::VolumePair {
                fixed,
                moving,
                fixed_path: input.fixed_path.as_deref(),
                moving_path: input.moving_path.as_deref(),
            };
            let mut sample = |m: &field::FieldInputs| {
                let mut progress = |done: u64, total: u64| {
                    watch.report(&file_name(out), Progress { stage: "field slices", done, total });
                    !watch.cancelled()
                };
                field::sample_field(fixed, m, FieldDirection::Pullback, &mut progress)
            };
            let export = transform::write_dicom(out, &made_of, pair, &mut sample)?;
            let what = match export.registration {
                transform::DicomRegistration::Spatial(kind) => {
                    format!("a DICOM Spatial Registration ({}, moving to fixed)", kind.name())
                }
                transform::DicomRegistration::Deformable { max_displacement_mm } => format!(
                    "a DICOM Deformable Spatial Registration (the fixed grid, largest {max_displacement_mm:.1} mm)"
                ),
            };
            Ok(format!(
                "wrote {}: {} as {what} ({} pairs){consistency}",
                out.display(),
                layers.describe(&input.method, export.pairs),
                export.pairs
            ))
        }
        ExportKind::Transform { format } => {
            let layered = layers.field.is_some() || layers.brush.is_some();
            if let Some(refusal) = transform::affine_only(out, *format, layers.field.is_some()).filter(|_| layered) {
                return Err(refusal);
            }
            let exact = transform::exact_transform(&made_of)?;
            let pair = transform::VolumePair {
                fixed,
                moving,
                fixed_path: input.fixed_path.as_deref(),
                moving_path: input.moving_path.as_deref(),
            };
            let written = transform::write_transform(out, &exact, *format, pair)?;
            let maps = match format {
                TransformFormat::Dicom => "moving patient coordinates to fixed ones",
                TransformFormat::Fsl => "the moving volume's FSL coordinates to the fixed one's",
                TransformFormat::Lta => "the moving volume (src) to the fixed one (dst), RAS mm",
                TransformFormat::Minc => "the moving volume's world to the fixed one's, RAS mm",
                TransformFormat::Itk | TransformFormat::Elastix | TransformFormat::Afni => {
                    "fixed points to moving points, LPS mm"
                }
            };
            Ok(format!(
                "wrote {}: {} as {} ({} pairs; maps {maps})",
                out.display(),
                exact.method,
                written.class(exact.transform.type_name()),
                exact.pairs
            ))
        }
        ExportKind::Map { quantity } => {
            let map = jacobian::jacobian_map(fixed, &made_of, *quantity, FieldDirection::Pullback)?;
            warpbench_io::write_volume(out, &map.volume)?;
            let folded = map.fraction_folded.map_or_else(String::new, |f| format!(", {:.2} % folded", 100.0 * f));
            Ok(format!(
                "wrote {}: {} map of the {} warp ({} pairs), from {:.4} to {:.4}{folded}{consistency}",
                out.display(),
                quantity.describe(),
                map.method,
                map.pairs,
                map.min,
                map.max
            ))
        }
        ExportKind::Field { .. } | ExportKind::InverseField => {
            let mut progress = |done: u64, total: u64| {
                watch.report(&file_name(out), Progress { stage: "field slices", done, total });
                !watch.cancelled()
            };
            let (direction, grid, what) = match kind {
                ExportKind::InverseField => (FieldDirection::Forward, moving, "inverse (forward) displacement field"),
                _ => (FieldDirection::Pullback, fixed, "displacement field"),
            };
            let f = field::sample_field(grid, &made_of, direction, &mut progress)?;
            let pair_output = match kind {
                ExportKind::Field { form } => form.pair_output(out),
                _ => None,
            };
            if let Some(pair) = pair_output {
                let moving_grid = (moving.dims, &moving.lps_from_index);
                pair.write(out, (f.dims, &f.lps_from_index), moving_grid, &f.displacements_lps)?;
            } else {
                let format = match kind {
                    ExportKind::Field { form: FieldForm::Afni } => FieldFormat::Afni,
                    _ => field_format(out).map_err(|e| Failure::BadInput(anyhow::anyhow!(e)))?,
                };
                field::write_field(&f, out, format, None)?;
            }
            Ok(format!(
                "wrote {}: {} {what} of {} pairs, largest {:.1} mm{consistency}",
                out.display(),
                f.method,
                f.pairs,
                f.max_displacement_mm
            ))
        }
    }
}

/// Refuses a transform export's name, in words for the status bar: an ITK transform is a `.tfm`, `.txt`, `.h5`
/// (HDF5) or `.mat` (ANTs'), an elastix parameter file a `.txt`.
fn check_transform_output(out: &Path, format: TransformFormat) -> Result<(), String> {
    let extension = out.extension().map(|e| e.to_string_lossy().to_ascii_lowercase()).unwrap_or_default();
    let fits = match format {
        TransformFormat::Itk => matches!(extension.as_str(), "tfm" | "txt" | "h5" | "mat"),
        TransformFormat::Elastix => extension == "txt",
        TransformFormat::Dicom => extension == "dcm",
        TransformFormat::Fsl => matches!(extension.as_str(), "mat" | "txt" | "xfm"),
        TransformFormat::Afni => extension == "1d",
        TransformFormat::Lta => extension == "lta",
        TransformFormat::Minc => extension == "xfm",
    };
    if fits {
        return transform::check_transform_name(out, format).map_err(|f| format!("{:#}", f.error()));
    }
    Err(match format {
        TransformFormat::Itk => {
            format!("{}: a transform is exported as ITK's .tfm (or .txt) or .h5 (HDF5), or ANTs' .mat", out.display())
        }
        TransformFormat::Elastix => {
            format!("{}: an elastix transform parameter file is a .txt (e.g. TransformParameters.0.txt)", out.display())
        }
        TransformFormat::Dicom => format!("{}: a DICOM registration is a .dcm (e.g. mr_to_ct_reg.dcm)", out.display()),
        TransformFormat::Fsl => format!("{}: FSL's FLIRT matrix is a .mat (e.g. mr_to_ct.mat)", out.display()),
        TransformFormat::Afni => format!("{}: AFNI's matrix file is a .1D (e.g. mr_to_ct.aff12.1D)", out.display()),
        TransformFormat::Lta => format!("{}: FreeSurfer's LTA is a .lta (e.g. mr_to_t1.lta)", out.display()),
        TransformFormat::Minc => format!("{}: an MNI transform file is a .xfm (e.g. mr_to_t1.xfm)", out.display()),
    })
}

/// The flavour a field exported to `out` is written in, by its name: `.nii`, `.nii.gz` ITK's (NIfTI `DISPVECT`,
/// what ITK, ANTs and Slicer read), `.nrrd` Slicer's (which also records the direction), `.mha`, `.mhd` MetaImage
/// (elastix's and ITK's); `.h5` is ITK's HDF5 transform file holding the field ([`field::write_displacements`]).
/// (`.npz`, Learn2Reg's field, is written apart, against the moving grid: [`field::write_learn2reg`].)
///
/// # Errors
/// Any other name, in words for the status bar.
pub fn field_format(out: &Path) -> Result<FieldFormat, String> {
    if itk_tfm::is_hdf5_name(out) {
        // ITK's HDF5 transform file ([`field::write_displacements`]); its flavour is the default's.
        return Ok(FieldFormat::Itk);
    }
    FieldFormat::from_extension(out).ok_or_else(|| {
        format!(
            "{}: a displacement field is exported as NIfTI (.nii, .nii.gz), NRRD (.nrrd), MetaImage (.mha, .mhd), \
             ITK's HDF5 transform file (.h5), an MNI grid transform (.xfm), OME-Zarr (a folder named .ome.zarr) or \
             Learn2Reg's .npz",
            out.display()
        )
    })
}

/// The export section of the side panel: the output fields and buttons, or the running export's progress bar and
/// Cancel button. Returns the export asked for.
pub fn export_ui(
    ui: &mut egui::Ui,
    fields: &mut ExportFields,
    running: Option<&ExportJob>,
) -> Option<(ExportKind, PathBuf)> {
    ui.label("Export (fixed grid; the inverse field on the moving grid)");
    if let Some(job) = running {
        ui.label(format!("Exporting {}", file_name(&job.out)));
        super::open::progress_ui(ui, &job.watch);
        return None;
    }
    ui.add(egui::TextEdit::singleline(&mut fields.out).desired_width(ui.available_width()).hint_text("warped.nii.gz"))
        .labelled_by(ui.label("Export file").id);
    ui.add(
        egui::TextEdit::singleline(&mut fields.dicom)
            .desired_width(ui.available_width())
            .hint_text("optional: a new folder"),
    )
    .labelled_by(ui.label("DICOM series folder").id);
    let path = PathBuf::from(fields.out.trim());
    let enabled = !fields.out.trim().is_empty();
    let nifti = FieldFormat::from_extension(&path) == Some(FieldFormat::Itk);
    let mut asked = None;
    ui.horizontal(|ui| {
        if ui.add_enabled(enabled, egui::Button::new("Export warped volume")).clicked() {
            let dicom = Some(PathBuf::from(fields.dicom.trim())).filter(|d| !d.as_os_str().is_empty());
            asked = Some((ExportKind::Warped { dicom }, path.clone()));
        }
        if ui.add_enabled(enabled, egui::Button::new("Export displacement field")).clicked() {
            let form = if nifti { fields.field_form } else { FieldForm::ByName };
            asked = Some((ExportKind::Field { form }, path.clone()));
        }
    });
    ui.horizontal_wrapped(|ui| {
        // The forms a NIfTI name can take besides ITK's hold the pull-back only.
        let pullback_only = nifti && fields.field_form != FieldForm::ByName;
        let inverse = ui.add_enabled(enabled && !pullback_only, egui::Button::new("Export inverse field"));
        if inverse
            .on_hover_text("The forward map on the moving grid: where each moving point goes (points, meshes)")
            .on_disabled_hover_text(
                "Learn2Reg's, FNIRT's and AFNI's forms here hold the pull-back only: untick the form to export the \
                 inverse (warpbench field --direction forward writes any flavour)",
            )
            .clicked()
        {
            asked = Some((ExportKind::InverseField, path.clone()));
        }
        // Only a NIfTI name can take these forms, and only it needs saying so (an .npz is Learn2Reg's). One form at a
        // time: ticking one unticks the others.
        if nifti {
            for (form, label, hover) in [
                (
                    FieldForm::Learn2Reg,
                    "Learn2Reg steps in voxels",
                    "Export displacement field writes Learn2Reg's form: at each fixed voxel, the step to the moving \
                     voxel it reads, in voxels (float32, the fixed volume's affine), as the challenge's evaluation \
                     reads disp_XXXX_YYYY.nii.gz",
                ),
                (
                    FieldForm::Fnirt,
                    "FSL FNIRT field",
                    "Export displacement field writes FSL FNIRT's relative deformation field, in the FSL coordinates \
                     of the fixed volume and the moving one: applywarp --ref=FIXED --in=MOVING --warp=FILE --rel",
                ),
                (
                    FieldForm::Afni,
                    "AFNI warp",
                    "Export displacement field writes AFNI's warp as 3dQwarp saves one to NIfTI: 3dNwarpApply -nwarp \
                     FILE -source MOVING -master FIXED",
                ),
            ] {
                let mut on = fields.field_form == form;
                if ui.checkbox(&mut on, label).on_hover_text(hover).changed() {
                    fields.field_form = if on { form } else { FieldForm::ByName };
                }
            }
        }
    });
    ui.horizontal(|ui| {
        for (label, quantity, hover) in [
            (
                "Export Jacobian map",
                Quantity::Det,
                "The Jacobian determinant at every voxel: below 1 squeezed, above 1 stretched, 0 or below folded",
            ),
            ("Export warp magnitude", Quantity::Magnitude, "How far the warp moves each voxel, in mm"),
        ] {
            if ui.add_enabled(enabled, egui::Button::new(label)).on_hover_text(hover).clicked() {
                asked = Some((ExportKind::Map { quantity }, path.clone()));
            }
        }
    });
    ui.horizontal(|ui| {
        let itk = ui.add_enabled(enabled, egui::Button::new("Export transform")).on_hover_text(
            "The exact warp, not a sampled field: an ITK transform file (.tfm) for ITK, ANTs and Slicer; .h5 for \
             ITK's HDF5 file, which also holds a warp with a field or the brush (over its field); .mat for ANTs \
             (linear methods)",
        );
        if itk.clicked() {
            asked = Some((ExportKind::Transform { format: TransformFormat::Itk }, path.clone()));
        }
        let elastix = ui.add_enabled(enabled, egui::Button::new("Export for elastix")).on_hover_text(
            "The warp as an elastix transform parameter file (.txt) that transformix applies: exact, or over a \
                 field beside it when a field or the brush is in the warp",
        );
        if elastix.clicked() {
            asked = Some((ExportKind::Transform { format: TransformFormat::Elastix }, path.clone()));
        }
        let dicom = ui.add_enabled(enabled, egui::Button::new("Export DICOM registration")).on_hover_text(
            "A DICOM registration (.dcm, modality REG) between the two DICOM series, for planning systems and PACS: a \
             matrix for the linear methods, the warp on the fixed grid for any other",
        );
        if dicom.clicked() {
            asked = Some((ExportKind::Transform { format: TransformFormat::Dicom }, path.clone()));
        }
    });
    asked
}

/// The paths typed into the export section.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct ExportFields {
    pub out: String,
    pub dicom: String,
    /// The form of a field exported under a NIfTI name: ITK's ([`FieldForm::ByName`]), Learn2Reg's steps in voxels,
    /// FSL FNIRT's or AFNI's, by the check box ticked.
    pub field_form: FieldForm,
}
