//! The side panel's file section and what it does with files: the session, landmark, screenshot and
//! displacement-field paths typed in, landmark files read and written in every format the window offers, and
//! screenshots written as PNG.

use anyhow::Context as _;
use eframe::egui;
use warpbench_io::landmarks::LandmarkPair;

use super::export;
use super::open::{Purpose, Side};

/// The side panel's file and export section.
#[derive(Debug, Default)]
pub struct Files {
    /// The session, landmark and screenshot paths typed in.
    pub fields: FileFields,
    /// The last message of a file action (saved, or the error).
    pub message: Option<String>,
    /// The export section's fields.
    pub export_fields: export::ExportFields,
    /// The export running on a worker thread.
    pub export: Option<export::ExportJob>,
    /// A session just saved, for the recent sessions (taken by the window each frame).
    pub saved_session: Option<std::path::PathBuf>,
}

/// The paths typed into the side panel's file section.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct FileFields {
    pub session: String,
    pub landmarks: String,
    pub screenshot: String,
    /// A displacement field to put under the landmarks.
    pub field: String,
    /// Whether a NIfTI one is read as Learn2Reg's steps in voxels ("Learn2Reg steps in voxels", shown for a NIfTI
    /// name).
    pub field_in_voxels: bool,
    /// Masks of the fixed and the moving volume for Refine by intensities.
    pub masks: [String; 2],
    /// A starting transform's file to put under the landmarks.
    pub start: String,
}

/// What the file section or the File menu asks for.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum FileAction {
    SaveSession(std::path::PathBuf),
    ImportLandmarks(std::path::PathBuf),
    ExportLandmarks(std::path::PathBuf),
    Screenshot(std::path::PathBuf),
    /// Export the warped moving volume (NIfTI `.nii`/`.nii.gz`), as `warpbench warp` does.
    ExportWarped(std::path::PathBuf),
    /// Export the displacement field (its flavour by the name), as `warpbench field` does.
    ExportField(std::path::PathBuf),
    /// Export the inverse (forward) field on the moving grid, as `warpbench field --direction forward` does.
    ExportInverseField(std::path::PathBuf),
    /// Export the exact transform, as `warpbench transform [--format elastix]` does.
    ExportTransform(crate::transform::TransformFormat, std::path::PathBuf),
    /// Export a map of the warp (det ∇u or |u(x) − x|) as a volume, as `warpbench jacobian` does.
    ExportMap(crate::jacobian::Quantity, std::path::PathBuf),
    /// Put the displacement field read from this file (ITK or ANTs NIfTI, Slicer NRRD) under the landmarks.
    UseField(std::path::PathBuf),
    /// The same, read as Learn2Reg's steps in voxels whatever its form ([`crate::project::field_file`]).
    UseLearn2RegField(std::path::PathBuf),
    /// Take the displacement field away.
    RemoveField,
    /// Read one volume only where this mask volume is not 0 when refining by intensities.
    UseMask(Side, std::path::PathBuf),
    /// Read the whole volume again.
    RemoveMask(Side),
    /// Put the linear transform read from this file (ITK `.tfm`, ANTs `.mat`, elastix parameter file) under the
    /// landmarks as the starting transform, as `--initial` does.
    UseStart(std::path::PathBuf),
}

/// The file action for the path a dialog of `purpose` returned; `None` for the purposes that open a volume, a
/// session or landmarks (the window opens those itself).
#[must_use]
pub fn chosen(purpose: Purpose, path: std::path::PathBuf) -> Option<FileAction> {
    Some(match purpose {
        Purpose::SaveSession => FileAction::SaveSession(path),
        Purpose::ExportLandmarks => FileAction::ExportLandmarks(path),
        Purpose::Screenshot => FileAction::Screenshot(path),
        Purpose::ExportWarped => FileAction::ExportWarped(path),
        Purpose::ExportField => FileAction::ExportField(path),
        Purpose::ExportInverseField => FileAction::ExportInverseField(path),
        Purpose::ExportMap(quantity) => FileAction::ExportMap(quantity, path),
        Purpose::ExportTransform(format) => FileAction::ExportTransform(format, path),
        Purpose::UseStart => FileAction::UseStart(path),
        Purpose::UseField | Purpose::UseFieldFolder => FileAction::UseField(path),
        Purpose::UseMask(side) => FileAction::UseMask(side, path),
        Purpose::OpenFile(_) | Purpose::OpenFolder(_) | Purpose::OpenSession | Purpose::ImportLandmarks => return None,
    })
}

/// Session, landmark and screenshot files: a path field and its buttons each.
pub fn files_ui(ui: &mut egui::Ui, fields: &mut FileFields) -> Option<FileAction> {
    let mut action = None;
    let path = |s: &str| std::path::PathBuf::from(s.trim());
    ui.add(
        egui::TextEdit::singleline(&mut fields.session)
            .desired_width(ui.available_width())
            .hint_text("session.warpbench.json"),
    )
    .labelled_by(ui.label("Session file").id);
    if ui.add_enabled(!fields.session.trim().is_empty(), egui::Button::new("Save session")).clicked() {
        action = Some(FileAction::SaveSession(path(&fields.session)));
    }
    ui.add(
        egui::TextEdit::singleline(&mut fields.landmarks)
            .desired_width(ui.available_width())
            .hint_text("pairs.csv, pairs.json, or moving.fcsv"),
    )
    .labelled_by(ui.label("Landmark file").id);
    ui.horizontal(|ui| {
        let enabled = !fields.landmarks.trim().is_empty();
        if ui.add_enabled(enabled, egui::Button::new("Import landmarks")).clicked() {
            action = Some(FileAction::ImportLandmarks(path(&fields.landmarks)));
        }
        if ui.add_enabled(enabled, egui::Button::new("Export landmarks")).clicked() {
            action = Some(FileAction::ExportLandmarks(path(&fields.landmarks)));
        }
    });
    ui.add(
        egui::TextEdit::singleline(&mut fields.screenshot)
            .desired_width(ui.available_width())
            .hint_text("screenshot.png"),
    )
    .labelled_by(ui.label("Screenshot file").id);
    if ui.add_enabled(!fields.screenshot.trim().is_empty(), egui::Button::new("Save screenshot")).clicked() {
        action = Some(FileAction::Screenshot(path(&fields.screenshot)));
    }
    action
}

/// What a row for one file the document names (a path field, a button to use it and one to take it away) shows.
struct FileRow {
    /// The path field's label.
    label: &'static str,
    hint: &'static str,
    use_button: &'static str,
    remove_button: &'static str,
    /// What the line under the buttons says before the file's path.
    current: &'static str,
}

/// What a [`FileRow`] asks for.
enum RowChoice {
    Use(std::path::PathBuf),
    Remove,
}

/// One [`FileRow`] over `text`, with `current` the document's file, if any.
fn file_row(
    ui: &mut egui::Ui,
    row: &FileRow,
    text: &mut String,
    current: Option<&std::path::Path>,
) -> Option<RowChoice> {
    let mut choice = None;
    ui.add(egui::TextEdit::singleline(text).desired_width(ui.available_width()).hint_text(row.hint))
        .labelled_by(ui.label(row.label).id);
    ui.horizontal(|ui| {
        if ui.add_enabled(!text.trim().is_empty(), egui::Button::new(row.use_button)).clicked() {
            choice = Some(RowChoice::Use(std::path::PathBuf::from(text.trim())));
        }
        if ui.add_enabled(current.is_some(), egui::Button::new(row.remove_button)).clicked() {
            choice = Some(RowChoice::Remove);
        }
    });
    if let Some(f) = current {
        ui.label(format!("{}: {}", row.current, f.display()));
    }
    choice
}

/// The displacement field under the landmarks: its file's path field, "Use field under landmarks" and "Remove
/// field"; `field` is the document's displacement field, if any.
pub fn field_ui(ui: &mut egui::Ui, fields: &mut FileFields, field: Option<&std::path::Path>) -> Option<FileAction> {
    let row = FileRow {
        label: "Displacement field file",
        hint: "field.nii.gz (ITK, ANTs), Composite.h5 (ANTs), field.nrrd or bspline.h5 (Slicer), bspline.tfm \
               (SimpleITK), deformationField.mhd or TransformParameters.1.txt (elastix), disp_0001_0002.npz \
               (Learn2Reg), field.ome.zarr (an OME-Zarr folder)",
        use_button: "Use field under landmarks",
        remove_button: "Remove field",
        current: "Field under the landmarks",
    };
    let choice = file_row(ui, &row, &mut fields.field, field);
    // Only a NIfTI name can be Learn2Reg's form, and only it needs saying so (an .npz is told by its content).
    let nifti = warpbench_io::displacement::FieldFormat::from_extension(std::path::Path::new(fields.field.trim()))
        == Some(warpbench_io::displacement::FieldFormat::Itk);
    if nifti {
        ui.checkbox(&mut fields.field_in_voxels, "Learn2Reg steps in voxels").on_hover_text(
            "Read the file as Learn2Reg's field, steps from the fixed volume's voxels to the moving volume's, as \
             open now: an (X, Y, Z, 3) NIfTI such as disp_0001_0002.nii.gz, which does not say its units",
        );
    }
    choice.map(|c| match c {
        RowChoice::Use(path) if nifti && fields.field_in_voxels => FileAction::UseLearn2RegField(path),
        RowChoice::Use(path) => FileAction::UseField(path),
        RowChoice::Remove => FileAction::RemoveField,
    })
}

/// A starting transform from a file: its path field and "Use as starting transform" (Clear alignment, beside
/// Auto-align, takes it away).
pub fn start_ui(ui: &mut egui::Ui, fields: &mut FileFields) -> Option<FileAction> {
    ui.add(
        egui::TextEdit::singleline(&mut fields.start)
            .desired_width(ui.available_width())
            .hint_text("start.tfm, 0GenericAffine.mat (ANTs), start.h5 (ITK) or TransformParameters.0.txt (elastix)"),
    )
    .labelled_by(ui.label("Starting transform file").id);
    let enabled = !fields.start.trim().is_empty();
    let clicked = ui
        .add_enabled(enabled, egui::Button::new("Use as starting transform"))
        .on_hover_text("A linear transform, fixed to moving, as --initial takes it; the landmarks refine it")
        .clicked();
    clicked.then(|| FileAction::UseStart(std::path::PathBuf::from(fields.start.trim())))
}

/// A volume's mask for Refine by intensities: its file's path field, "Use as fixed mask" (or moving) and "Remove
/// fixed mask"; `mask` is the document's, if any.
pub fn mask_ui(
    ui: &mut egui::Ui,
    fields: &mut FileFields,
    side: Side,
    mask: Option<&std::path::Path>,
) -> Option<FileAction> {
    let row = match side {
        Side::Fixed => FileRow {
            label: "Fixed mask file",
            hint: "mask.nii.gz: read the fixed volume where it is not 0",
            use_button: "Use as fixed mask",
            remove_button: "Remove fixed mask",
            current: "Fixed mask",
        },
        Side::Moving => FileRow {
            label: "Moving mask file",
            hint: "mask.nii.gz: read the moving volume where it is not 0",
            use_button: "Use as moving mask",
            remove_button: "Remove moving mask",
            current: "Moving mask",
        },
    };
    let text = match side {
        Side::Fixed => &mut fields.masks[0],
        Side::Moving => &mut fields.masks[1],
    };
    file_row(ui, &row, text, mask).map(|c| match c {
        RowChoice::Use(path) => FileAction::UseMask(side, path),
        RowChoice::Remove => FileAction::RemoveMask(side),
    })
}

/// Writes the pairs as BigWarp JSON (`.json`), an MNI tag file (`.tag`) or BigWarp CSV (any other name), or as a Slicer
/// pair of point lists
/// for `.mrk.json` / `.fcsv`:
/// `NAME.mrk.json` becomes `NAME_moving.mrk.json` and `NAME_fixed.mrk.json`.
pub fn export_landmarks(path: &std::path::Path, pairs: &[LandmarkPair]) -> anyhow::Result<()> {
    match slicer_pair_paths(path) {
        Some((moving, fixed)) => warpbench_io::landmarks::write_slicer_pair(&moving, &fixed, pairs)?,
        None => warpbench_io::landmarks::write_landmark_pairs(path, pairs)?,
    }
    Ok(())
}

/// Reads pairs from any file of pairs `--landmarks` takes (BigWarp CSV or JSON, the plain CSV, transformix's output, an
/// ITK or 3D Slicer thin-plate-spline file; told apart by content), or from the `_moving` / `_fixed` Slicer lists
/// named like [`export_landmarks`] writes them.
pub fn import_landmarks(path: &std::path::Path) -> anyhow::Result<Vec<LandmarkPair>> {
    Ok(match slicer_pair_paths(path) {
        Some((moving, fixed)) => warpbench_io::landmarks::read_slicer_pair(&moving, &fixed)?,
        None => warpbench_io::landmarks::read_landmark_pairs(path)?,
    })
}

/// For a Slicer name (`.mrk.json` or `.fcsv`), the moving and fixed list paths.
fn slicer_pair_paths(path: &std::path::Path) -> Option<(std::path::PathBuf, std::path::PathBuf)> {
    let name = path.file_name()?.to_str()?;
    let lower = name.to_ascii_lowercase();
    let ext = [".mrk.json", ".fcsv"].into_iter().find(|e| lower.ends_with(e))?;
    let stem = &name[..name.len() - ext.len()];
    let with = |side: &str| path.with_file_name(format!("{stem}_{side}{}", &name[name.len() - ext.len()..]));
    Some((with("moving"), with("fixed")))
}

/// Writes `image` as a PNG at `path`, atomically.
pub(crate) fn save_png(path: &std::path::Path, image: &egui::ColorImage) -> anyhow::Result<()> {
    let [w, h] = image.size;
    let rgba: Vec<u8> = image.pixels.iter().flat_map(egui::Color32::to_array).collect();
    let mut png = Vec::new();
    image::write_buffer_with_format(
        &mut std::io::Cursor::new(&mut png),
        &rgba,
        w as u32,
        h as u32,
        image::ExtendedColorType::Rgba8,
        image::ImageFormat::Png,
    )
    .context("encoding the screenshot")?;
    warpbench_io::atomic::write_atomic(path, |out| out.write_all(&png))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use warpbench_io::geometry::Point3;

    #[test]
    fn a_path_chosen_in_a_dialog_is_the_file_action_of_its_purpose() {
        use crate::jacobian::Quantity;
        use crate::transform::TransformFormat;
        let p = std::path::PathBuf::from("/data/x");
        let cases = [
            (Purpose::ExportInverseField, FileAction::ExportInverseField(p.clone())),
            (Purpose::ExportMap(Quantity::Det), FileAction::ExportMap(Quantity::Det, p.clone())),
            (
                Purpose::ExportTransform(TransformFormat::Elastix),
                FileAction::ExportTransform(TransformFormat::Elastix, p.clone()),
            ),
            (
                Purpose::ExportTransform(TransformFormat::Itk),
                FileAction::ExportTransform(TransformFormat::Itk, p.clone()),
            ),
            (
                Purpose::ExportTransform(TransformFormat::Dicom),
                FileAction::ExportTransform(TransformFormat::Dicom, p.clone()),
            ),
            (Purpose::UseStart, FileAction::UseStart(p.clone())),
            (Purpose::UseField, FileAction::UseField(p.clone())),
            (Purpose::UseFieldFolder, FileAction::UseField(p.clone())),
            (Purpose::UseMask(Side::Moving), FileAction::UseMask(Side::Moving, p.clone())),
            (Purpose::ExportField, FileAction::ExportField(p.clone())),
            (Purpose::SaveSession, FileAction::SaveSession(p.clone())),
        ];
        for (purpose, action) in cases {
            assert_eq!(chosen(purpose, p.clone()), Some(action), "{purpose:?}");
        }
        // What opens a volume, a session or landmarks is the window's own business.
        for purpose in [Purpose::OpenFile(Side::Fixed), Purpose::OpenSession, Purpose::ImportLandmarks] {
            assert_eq!(chosen(purpose, p.clone()), None, "{purpose:?}");
        }
    }

    #[test]
    fn landmarks_round_trip_through_bigwarp_csv_and_a_slicer_pair() {
        let dir = tempfile::tempdir().expect("tempdir");
        let pairs = vec![
            LandmarkPair::new("a", Point3::new(1.0, 2.0, 3.0), Point3::new(4.0, 5.0, 6.0)),
            LandmarkPair {
                active: false,
                ..LandmarkPair::new("b", Point3::new(-1.5, 0.0, 2.25), Point3::new(0.0, 1.0, 0.0))
            },
        ];
        for name in ["pairs.csv", "pairs.json", "pairs.mrk.json", "pairs.fcsv"] {
            let path = dir.path().join(name);
            export_landmarks(&path, &pairs).expect("export");
            let back = import_landmarks(&path).expect("import");
            assert_eq!(back.len(), 2, "{name}");
            for (a, b) in back.iter().zip(&pairs) {
                let close = |x: Option<Point3<warpbench_io::geometry::Lps>>,
                             y: Option<Point3<warpbench_io::geometry::Lps>>| {
                    x.zip(y).is_some_and(|(x, y)| x.distance(&y) < 1e-6)
                };
                assert!(close(a.moving, b.moving) && close(a.fixed, b.fixed), "{name}: {a:?} vs {b:?}");
            }
        }
        assert!(dir.path().join("pairs_moving.mrk.json").is_file() && dir.path().join("pairs_fixed.fcsv").is_file());
        // `.json` is BigWarp's JSON, which BigWarp's Load landmarks reads.
        let json: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(dir.path().join("pairs.json")).expect("read")).expect("JSON");
        assert_eq!(json["landmarks"]["type"], "BigWarpLandmarks", "{json}");
        assert!(import_landmarks(&dir.path().join("missing.csv")).is_err());
    }

    #[test]
    fn a_slicer_spline_file_imports_as_its_pairs() {
        let itk = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/itk");
        let pairs = import_landmarks(&itk.join("tps_slicer.h5")).expect("import");
        assert_eq!(pairs, warpbench_io::landmarks::read_landmark_pairs(&itk.join("tps_slicer.tfm")).expect("tfm"));
        assert_eq!(pairs.len(), 10);
    }
}
