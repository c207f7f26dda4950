//! The workbench window driven headlessly through egui_kittest (wgpu on the CPU driver), by accessibility labels:
//! it loads a pair, renders the 3-D view and the slices on egui's own device, reacts to the controls, reports bad
//! files, opens dropped files and exports as the command line does. The window's tests are split over `gui*.rs`
//! so that no one process holds too much: lavapipe keeps about 3 MB per ray-cast draw until the process ends
//! (docs/benchmarks.md).

mod common;
#[path = "common/window.rs"]
mod window;

use std::path::Path;
use std::time::{Duration, Instant};

use common::{data, mri};
use window::{no_adapter, open_mri_pair, open_mri_pair_at, wait_for_export, wait_for_failure, wait_until_shown};

use eframe::egui;
use egui_kittest::Harness;
use egui_kittest::kittest::Queryable;
use warpbench_app::gui::export::FieldForm;
use warpbench_app::gui::{GuiOptions, Workbench};

#[test]
fn loads_a_pair_renders_it_and_follows_the_controls() {
    if no_adapter() {
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let mut harness = open_mri_pair(dir.path(), egui::vec2(1100.0, 760.0));
    let ready = harness.state().ready().expect("loaded");
    assert_eq!(ready.fitted_pairs(), 5, "the TPS is fitted on the five pairs: {:?}", ready.fit.error);
    assert!(ready.fit.error.is_none());

    // The table's errors: TPS interpolates (residual ~0); every pair has a leave-one-out error.
    for (i, e) in ready.fit.pair_errors.iter().enumerate() {
        let e = e.expect("errors for an active pair");
        assert!(e.residual_mm < 1e-6, "pair {i}: residual {}", e.residual_mm);
        assert!(e.leave_one_out_mm.is_some_and(|l| l > 0.0 && l < 50.0), "pair {i}: {e:?}");
    }
    // Go to a pair: the slices move to its fixed point.
    harness.get_by_label("Go to Pt-1").click();
    harness.run_steps(2);
    let ready = harness.state().ready().expect("loaded");
    assert!(
        (ready.view.slice_mm[0] - 18.0).abs() < 1e-9 && (ready.view.slice_mm[2] - 40.0).abs() < 1e-9,
        "{:?}",
        ready.view.slice_mm
    );
    // Delete a pair, and undo it.
    harness.get_by_label("Delete Pt-0").click();
    harness.run_steps(2);
    assert_eq!(harness.state().ready().expect("loaded").fitted_pairs(), 4);
    harness.get_by_label("Undo").click();
    harness.run_steps(2);
    assert_eq!(harness.state().ready().expect("loaded").fitted_pairs(), 5);

    // Blend mode: open the combo box and choose "difference".
    harness.get_by_label("Blend mode").click();
    harness.run_steps(3);
    harness.get_by_label("difference").click();
    harness.run_steps(3);
    let ready = harness.state().ready().expect("loaded");
    assert_eq!(ready.document.settings.blend.name(), "difference");

    // Undo (the button) brings the mix blend back, redo (Ctrl+Shift+Z) the difference again, Ctrl+Z undoes again.
    harness.get_by_label("Undo").click();
    harness.run_steps(2);
    let blend = |h: &Harness<'_, Workbench>| h.state().ready().expect("loaded").document.settings.blend.name();
    assert_eq!(blend(&harness), "mix");
    let key = |h: &mut Harness<'_, Workbench>, modifiers: egui::Modifiers| {
        for pressed in [true, false] {
            h.input_mut().events.push(egui::Event::Key {
                key: egui::Key::Z,
                physical_key: None,
                pressed,
                repeat: false,
                modifiers,
            });
            h.run_steps(2);
        }
    };
    key(&mut harness, egui::Modifiers::COMMAND | egui::Modifiers::SHIFT);
    assert_eq!(blend(&harness), "difference");
    key(&mut harness, egui::Modifiers::COMMAND);
    assert_eq!(blend(&harness), "mix");
    key(&mut harness, egui::Modifiers::COMMAND | egui::Modifiers::SHIFT);
    assert_eq!(blend(&harness), "difference");

    // Switching a pair off refits the warp on the other four.
    harness.get_by_label("Use Pt-2").click();
    harness.run_steps(3);
    let ready = harness.state().ready().expect("loaded");
    assert!(!ready.document.pairs[2].active);
    assert_eq!(ready.fitted_pairs(), 4);
    harness.get_by_label("Undo").click();
    harness.run_steps(2);
    let ready = harness.state().ready().expect("loaded");
    assert!(ready.document.pairs[2].active, "undo switches the pair back on");
    assert_eq!(ready.fitted_pairs(), 5, "and refits");
    harness.get_by_label("Redo").click();
    harness.run_steps(2);
    assert_eq!(harness.state().ready().expect("loaded").fitted_pairs(), 4);
    // Rigid needs at least 3 pairs; with 4 active it fits.
    harness.get_by_label("Method").click();
    harness.run_steps(3);
    harness.get_by_label("rigid").click();
    harness.run_steps(3);
    let ready = harness.state().ready().expect("loaded");
    assert_eq!(ready.document.settings.method().to_string(), "rigid");
    assert_eq!(ready.fitted_pairs(), 4, "{:?}", ready.fit.error);
}

#[test]
fn a_missing_file_is_reported_in_the_window() {
    let opts = GuiOptions {
        fixed: Some(Path::new("/nonexistent/fixed.nii").to_path_buf()),
        moving: Some(mri()),
        ..GuiOptions::default()
    };
    let mut harness =
        Harness::builder().with_size(egui::vec2(600.0, 300.0)).build_eframe(|cc| Workbench::new(cc, opts));
    wait_for_failure(&mut harness);
    let message = harness.state().failure().expect("failed").to_owned();
    assert!(message.contains("/nonexistent/fixed.nii"), "{message}");
    harness.get_by_label("No volumes are open");
    harness.get_by_label("Open the demo pair");
}

#[test]
fn the_readers_warnings_are_shown_in_the_window() {
    if no_adapter() {
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    // jhu189's sform and qform disagree by a left-right flip: the window says so, and which one it uses.
    let opts = GuiOptions {
        fixed: Some(data("nifti/jhu189.nii.gz")),
        moving: Some(mri()),
        autosave: Some(dir.path().join("autosave.warpbench.json")),
        ..GuiOptions::default()
    };
    let mut harness =
        Harness::builder().with_size(egui::vec2(1100.0, 760.0)).wgpu().build_eframe(|cc| Workbench::new(cc, opts));
    wait_until_shown(&mut harness);
    harness.get_by_label_contains("The fixed volume: the sform (code 2) and the qform (code 2) disagree");
    assert!(harness.query_by_label_contains("The moving volume:").is_none(), "the MRI has nothing to warn about");
}

/// A file dropped on the window (egui leaves the type to the integration).
#[derive(Debug)]
struct Dropped(std::path::PathBuf);

impl egui::DroppedFile for Dropped {
    fn path(&self) -> &Path {
        &self.0
    }
    fn bytes(&self) -> Result<Vec<u8>, String> {
        std::fs::read(&self.0).map_err(|e| e.to_string())
    }
}

fn drop_files(harness: &mut Harness<'_, Workbench>, paths: &[std::path::PathBuf]) {
    for p in paths {
        harness.input_mut().dropped_files.push(std::sync::Arc::new(Dropped(p.clone())));
    }
    harness.run_steps(2);
}

/// Steps until no volume is being read (or 60 s pass).
fn wait_for_reads(harness: &mut Harness<'_, Workbench>) {
    let start = Instant::now();
    while harness.state().reading() > 0 {
        harness.step();
        assert!(start.elapsed() < Duration::from_mins(1), "a read did not finish within a minute");
        std::thread::sleep(Duration::from_millis(10));
    }
    harness.run_steps(3);
}

#[test]
fn opens_volumes_by_drop_reports_bad_files_and_chooses_a_dicom_series() {
    if no_adapter() {
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let mut harness = open_mri_pair(dir.path(), egui::vec2(1100.0, 760.0));
    harness.get_by_label("File");

    // A corrupt volume: asked which side, read on a worker, refused in a dialog that names it; the pair stays.
    drop_files(&mut harness, &[data("bad/random.nii")]);
    harness.get_by_label("the moving volume").click();
    harness.run_steps(2);
    wait_for_reads(&mut harness);
    let message = harness.state().dialogs.error.clone().expect("an error dialog");
    assert!(message.contains("random.nii") && message.contains("moving"), "{message}");
    harness.get_by_label("OK").click();
    harness.run_steps(2);
    assert!(harness.state().dialogs.error.is_none());
    assert_eq!(harness.state().ready().expect("the pair stays").loaded.moving.dims, [91, 109, 91]);

    // A DICOM folder with a CT and an MR series: the chooser lists both; the MR becomes the moving volume.
    let folder = data("dicom/mixed_ct5n_mr_small");
    drop_files(&mut harness, std::slice::from_ref(&folder));
    harness.get_by_label("the moving volume").click();
    harness.run_steps(2);
    wait_for_reads(&mut harness);
    let (side, _, series) = harness.state().dialogs.series.clone().expect("the series chooser");
    assert_eq!((side, series.len()), (warpbench_app::gui::open::Side::Moving, 2));
    harness.get_by_label_contains(": MR ").click();
    harness.run_steps(2);
    wait_for_reads(&mut harness);
    let ready = harness.state().ready().expect("loaded");
    assert_eq!(ready.document.moving.as_deref(), Some(folder.as_path()));
    assert_eq!(ready.loaded.moving.modality, warpbench_io::Modality::Mr);
    assert!(ready.loaded.title.contains("mixed_ct5n_mr_small"), "{}", ready.loaded.title);
    // The landmarks stay (patient space), and the warp is fitted again against the new volume.
    assert_eq!(ready.document.pairs.len(), 5);
    // Opening a volume is an undo step: undo shows the MRI again, redo the DICOM series.
    harness.get_by_label("Undo").click();
    harness.run_steps(2);
    let ready = harness.state().ready().expect("loaded");
    assert_eq!(ready.document.moving.as_deref(), Some(mri().as_path()));
    assert_eq!(ready.loaded.moving.dims, [91, 109, 91]);
    assert!(!ready.loaded.title.contains("mixed_ct5n_mr_small"), "{}", ready.loaded.title);
    assert!(ready.fit.error.is_none(), "{:?}", ready.fit.error);
    harness.get_by_label("Redo").click();
    harness.run_steps(2);
    let ready = harness.state().ready().expect("loaded");
    assert_eq!(ready.document.moving.as_deref(), Some(folder.as_path()));
    assert_ne!(ready.loaded.moving.dims, [91, 109, 91]);

    // Two volumes dropped together: the first is the fixed one, the second the moving one.
    let ct = data("nifti/avg152T1_LR_nifti2.nii.gz");
    drop_files(&mut harness, &[ct.clone(), mri()]);
    wait_for_reads(&mut harness);
    let ready = harness.state().ready().expect("loaded");
    assert_eq!(ready.document.fixed.as_deref(), Some(ct.as_path()));
    assert_eq!(ready.document.moving.as_deref(), Some(mri().as_path()));
    assert!(ready.fit.error.is_none(), "{:?}", ready.fit.error);

    // A displacement field dropped on the window goes under the landmarks, told by its header (ITK's DISPVECT); an
    // FNIRT warp made for other images is refused in the status bar, naming it, and the field stays.
    let field = data("itk/field_input_field.nii.gz");
    drop_files(&mut harness, std::slice::from_ref(&field));
    let ready = harness.state().ready().expect("loaded");
    assert_eq!(ready.document.field.as_ref().map(|f| f.path.as_path()), Some(field.as_path()));
    let message = ready.files.message.clone().unwrap_or_default();
    assert!(message.contains("is the displacement field under the landmarks"), "{message}");
    drop_files(&mut harness, &[data("fnirt/coef_neuro.nii.gz")]);
    let ready = harness.state().ready().expect("loaded");
    let message = ready.files.message.clone().unwrap_or_default();
    assert!(message.contains("coef_neuro.nii.gz") && message.contains("fnirt's --ref"), "{message}");
    assert_eq!(ready.document.field.as_ref().map(|f| f.path.as_path()), Some(field.as_path()));
    // With FNIRT's reference and input open, it is used, and the status bar says how it is read.
    drop_files(&mut harness, &[data("fnirt/ref_neuro.nii.gz"), data("fnirt/src.nii.gz")]);
    wait_for_reads(&mut harness);
    drop_files(&mut harness, &[data("fnirt/coef_neuro.nii.gz")]);
    let ready = harness.state().ready().expect("loaded");
    let message = ready.files.message.clone().unwrap_or_default();
    assert!(message.contains("an FSL FNIRT warp, with this fixed volume as its reference"), "{message}");
    assert!(ready.document.field.as_ref().is_some_and(|f| f.voxel_grids.is_some()), "the grids are recorded");
}

/// A session saved (or opened) is offered again under File > Open recent session, in a window started later with
/// the same state folder; choosing it opens it.
#[test]
fn a_saved_session_is_offered_again_under_open_recent_session() {
    use warpbench_app::gui::Command;
    use warpbench_app::gui::files::FileAction;
    if no_adapter() {
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let session = dir.path().join("case.warpbench.json");
    {
        let mut harness = open_mri_pair(dir.path(), egui::vec2(900.0, 640.0));
        let ready = harness.state_mut().ready_mut().expect("loaded");
        ready.apply(Command::File(FileAction::SaveSession(session.clone())));
        harness.run_steps(2);
    }
    let recent = std::fs::read_to_string(dir.path().join("recent.json")).expect("the recent sessions");
    assert!(recent.contains("case.warpbench.json"), "{recent}");
    // A later window (the demo pair) offers it, and opens it when chosen.
    let opts = GuiOptions { autosave: Some(dir.path().join("later.warpbench.json")), ..GuiOptions::default() };
    let mut harness =
        Harness::builder().with_size(egui::vec2(900.0, 640.0)).wgpu().build_eframe(|cc| Workbench::new(cc, opts));
    wait_until_shown(&mut harness);
    assert_eq!(harness.state().ready().expect("the demo pair").document.fixed, None);
    harness.get_by_label("File").click();
    harness.run_steps(2);
    harness.get_by_label("Open recent session").click();
    harness.run_steps(2);
    harness.get_by_label_contains("case.warpbench.json").click();
    harness.run_steps(2);
    wait_until_shown(&mut harness);
    let ready = harness.state().ready().expect("the session");
    assert_eq!(ready.document.fixed.as_deref(), Some(mri().as_path()));
    assert_eq!(ready.document.pairs.len(), 5, "the session's pairs");
}

#[test]
fn a_4d_file_asks_for_a_frame_and_the_session_reads_the_same_frame_again() {
    if no_adapter() {
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let mut harness = open_mri_pair(dir.path(), egui::vec2(1100.0, 760.0));
    let functional = data("nifti/functional.nii");
    let frame = |t: usize| warpbench_io::LoadOptions::new().frame(t).open(&functional).expect("the fixture's frame");

    // A 4-D file of 20 frames: the chooser asks which, the frame is read and becomes the moving volume.
    drop_files(&mut harness, std::slice::from_ref(&functional));
    harness.get_by_label("the moving volume").click();
    harness.run_steps(2);
    wait_for_reads(&mut harness);
    assert!(harness.state().dialogs.error.is_none(), "{:?}", harness.state().dialogs.error);
    harness.get_by_label_contains("holds 20 frames");
    // As a screen reader sets it; past the last frame is kept to the last.
    harness.get_by_label("Frame (0 to 19)").set_value_accesskit(25.0);
    harness.run_steps(2);
    assert_eq!(harness.state().dialogs.frames.as_ref().map(|c| c.chosen), Some(19));
    harness.get_by_label("Frame (0 to 19)").set_value_accesskit(3.0);
    harness.run_steps(2);
    assert_eq!(harness.state().dialogs.frames.as_ref().map(|c| c.chosen), Some(3));
    harness.get_by_label("Open").click();
    harness.run_steps(2);
    wait_for_reads(&mut harness);
    let ready = harness.state().ready().expect("loaded");
    assert_eq!(ready.document.moving.as_deref(), Some(functional.as_path()));
    assert_eq!(ready.document.moving_part, Some(warpbench_io::Part::Frame(3)));
    assert_eq!(ready.loaded.moving.data, frame(3).data, "frame 3, not another");
    assert_ne!(frame(3).data, frame(0).data, "the fixture's frames differ");
    assert!(ready.loaded.title.ends_with("functional.nii [frame 3]"), "{}", ready.loaded.title);

    // Undo gives the MRI back whole; redo the frame.
    harness.get_by_label("Undo").click();
    harness.run_steps(2);
    let ready = harness.state().ready().expect("loaded");
    assert_eq!((ready.document.moving.as_deref(), &ready.document.moving_part), (Some(mri().as_path()), &None));
    harness.get_by_label("Redo").click();
    harness.run_steps(2);
    assert_eq!(harness.state().ready().expect("loaded").document.moving_part, Some(warpbench_io::Part::Frame(3)));

    // The autosave keeps which frame; opened as a session, the same frame is read again.
    harness.state_mut().autosave_now(false);
    let autosave = dir.path().join("autosave.warpbench.json");
    let reopened_autosave = Some(dir.path().join("reopened.warpbench.json"));
    let opts = GuiOptions { session: Some(autosave), autosave: reopened_autosave, ..GuiOptions::default() };
    let mut reopened =
        Harness::builder().with_size(egui::vec2(1100.0, 760.0)).wgpu().build_eframe(|cc| Workbench::new(cc, opts));
    wait_until_shown(&mut reopened);
    let ready = reopened.state().ready().expect("the session opened");
    assert_eq!(ready.document.moving_part, Some(warpbench_io::Part::Frame(3)));
    assert_eq!(ready.loaded.moving.data, frame(3).data);

    // An AFNI dataset's chooser shows each sub-brick's label.
    drop_files(&mut reopened, &[data("afni/example4d+orig.HEAD")]);
    reopened.get_by_label("the fixed volume").click();
    reopened.run_steps(2);
    wait_for_reads(&mut reopened);
    reopened.get_by_label_contains("holds 3 sub-bricks");
    let header = warpbench_io::afni_dataset::Header::read(&data("afni/example4d+orig.HEAD")).expect("the header");
    reopened.get_by_label(&format!("\"{}\"", header.labels()[0]));
    reopened.get_by_label("Cancel").click();
    reopened.run_steps(2);
    assert!(reopened.state().dialogs.frames.is_none());
}

/// Scrolls the check box `label` into view and clicks it.
fn tick(harness: &mut Harness<'_, Workbench>, label: &str) {
    harness.get_by_label(label).scroll_to_me();
    harness.run_steps(3);
    harness.get_by_label(label).click();
    harness.run_steps(2);
}

/// Types `out` into the export section and presses `button`; the status bar's message once the export is done.
fn export(harness: &mut Harness<'_, Workbench>, button: &str, out: &Path) -> String {
    harness.state_mut().ready_mut().expect("loaded").files.export_fields.out = out.display().to_string();
    harness.run_steps(2);
    harness.get_by_label(button).scroll_to_me();
    harness.run_steps(3);
    harness.get_by_label(button).click();
    harness.run_steps(1);
    wait_for_export(harness)
}

#[test]
fn exports_the_warped_volume_the_fields_and_the_transform_as_the_command_line_does() {
    if no_adapter() {
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let mut harness = open_mri_pair(dir.path(), egui::vec2(1100.0, 900.0));
    let csv = dir.path().join("pairs.csv");

    // A bad name is refused before anything runs. (The export section is at the bottom of the side panel.)
    window::open_section(&mut harness, "Files");
    harness.get_by_label("Export file").scroll_to_me();
    harness.run_steps(3);
    harness.get_by_label("Export file").focus();
    harness.get_by_label("Export file").type_text(&dir.path().join("warped.txt").display().to_string());
    harness.run_steps(2);
    harness.get_by_label("Export warped volume").click();
    harness.run_steps(2);
    let message = harness.state().ready().expect("loaded").files.message.clone().unwrap_or_default();
    assert!(message.contains(".nii"), "{message}");
    assert!(!dir.path().join("warped.txt").exists());

    let warped = dir.path().join("warped.nii.gz");
    harness.state_mut().ready_mut().expect("loaded").files.export_fields.out = warped.display().to_string();
    harness.run_steps(2);
    harness.get_by_label("Export warped volume").click();
    harness.run_steps(1);
    let message = wait_for_export(&mut harness);
    assert!(message.starts_with("wrote ") && message.contains("5 pairs"), "{message}");

    // The File menu offers every export and every file the document can use, each through a native dialog.
    harness.get_by_label("File").click();
    harness.run_steps(2);
    for item in [
        "Export inverse field...",
        "Export Jacobian map...",
        "Export warp magnitude...",
        "Export transform...",
        "Export for elastix...",
        "Export DICOM registration...",
        "Use starting transform...",
        "Use displacement field...",
        "Use displacement field folder (OME-Zarr)...",
        "Use fixed mask...",
        "Use moving mask...",
    ] {
        use egui_kittest::kittest::NodeT as _;
        assert!(!harness.get_by_label(item).accesskit_node().is_disabled(), "{item} is offered");
    }
    harness.key_press(egui::Key::Escape);
    harness.run_steps(2);
    // A field's name picks its flavour: NIfTI is ITK's, .nrrd Slicer's (stating the direction), .mha MetaImage.
    let field_out = dir.path().join("field.nii.gz");
    let message = export(&mut harness, "Export displacement field", &field_out);
    assert!(message.contains("displacement field"), "{message}");
    let metaimage_out = dir.path().join("field.mha");
    let message = export(&mut harness, "Export displacement field", &metaimage_out);
    assert!(message.contains("displacement field"), "{message}");
    // .h5: ITK's HDF5 transform file, holding the same vectors as a DisplacementFieldTransform.
    let h5_out = dir.path().join("field.h5");
    let message = export(&mut harness, "Export displacement field", &h5_out);
    assert!(message.contains("displacement field"), "{message}");
    let (nifti, _) = warpbench_io::displacement::read_field(&field_out).expect("the NIfTI field");
    let chain = warpbench_io::itk_h5::read(&h5_out).unwrap_or_else(|e| panic!("{e}"));
    let [nx, ny, _] = nifti.dims;
    for v in [0, nifti.displacements_lps.len() / 3, nifti.displacements_lps.len() - 1] {
        let ijk = [(v % nx) as f64, ((v / nx) % ny) as f64, (v / (nx * ny)) as f64];
        let x = nifti.lps_from_index.apply_point(warpbench_io::geometry::Point3::new(ijk[0], ijk[1], ijk[2])).coords();
        let (y, d) = (chain.apply(x), nifti.displacements_lps[v]);
        assert!((0..3).all(|a| (y[a] - x[a] - f64::from(d[a])).abs() < 1e-4), "voxel {ijk:?}: {y:?}, D {d:?}");
    }
    // .npz: Learn2Reg's field, the pull-back's steps in voxels (the inverse is refused under that name, below).
    let npz_out = dir.path().join("disp_0001_0002.npz");
    let message = export(&mut harness, "Export displacement field", &npz_out);
    assert!(message.contains("displacement field"), "{message}");
    // A NIfTI name with Learn2Reg steps in voxels ticked: the challenge's NIfTI form of the same steps (and the
    // inverse, which that form cannot hold, is not offered meanwhile).
    let l2r_nifti_out = dir.path().join("disp_0001_0002.nii.gz");
    harness.state_mut().ready_mut().expect("loaded").files.export_fields.out = l2r_nifti_out.display().to_string();
    harness.run_steps(2);
    tick(&mut harness, "Learn2Reg steps in voxels");
    assert_eq!(harness.state().ready().expect("loaded").files.export_fields.field_form, FieldForm::Learn2Reg, "ticked");
    {
        use egui_kittest::kittest::NodeT as _;
        assert!(harness.get_by_label("Export inverse field").accesskit_node().is_disabled(), "inverse offered");
    }
    let message = export(&mut harness, "Export displacement field", &l2r_nifti_out);
    assert!(message.contains("displacement field"), "{message}");
    tick(&mut harness, "Learn2Reg steps in voxels");
    assert_eq!(harness.state().ready().expect("loaded").files.export_fields.field_form, FieldForm::ByName);
    // A NIfTI name with FSL FNIRT field ticked: FNIRT's relative field of the same warp, which reads back against the
    // pair to the ITK field above; ticking Learn2Reg's form unticks it (one form at a time).
    let fnirt_out = dir.path().join("warp_fnirt.nii.gz");
    harness.state_mut().ready_mut().expect("loaded").files.export_fields.out = fnirt_out.display().to_string();
    harness.run_steps(2);
    tick(&mut harness, "FSL FNIRT field");
    {
        use egui_kittest::kittest::NodeT as _;
        assert!(harness.get_by_label("Export inverse field").accesskit_node().is_disabled(), "inverse offered");
    }
    let message = export(&mut harness, "Export displacement field", &fnirt_out);
    assert!(message.contains("displacement field"), "{message}");
    let (fixed, moving) = {
        let loaded = &harness.state().ready().expect("loaded").loaded;
        ((loaded.fixed.dims, loaded.fixed.lps_from_index), (loaded.moving.dims, loaded.moving.lps_from_index))
    };
    let read = warpbench_io::fnirt::read_pullback(&fnirt_out, (fixed.0, &fixed.1), (moving.0, &moving.1))
        .unwrap_or_else(|e| panic!("{e}"));
    let worst = read
        .field
        .displacements_lps
        .iter()
        .zip(&nifti.displacements_lps)
        .map(|(a, b)| (0..3).map(|c| (a[c] - b[c]).abs()).fold(0.0f32, f32::max))
        .fold(0.0f32, f32::max);
    assert!(worst < 1e-4, "{worst} mm from the ITK field");
    // A NIfTI name with AFNI warp ticked: AFNI's warp of the same vectors, read back as AFNI's; ticking it unticked
    // FNIRT's form (one form at a time).
    let afni_out = dir.path().join("anat_WARP.nii.gz");
    harness.state_mut().ready_mut().expect("loaded").files.export_fields.out = afni_out.display().to_string();
    harness.run_steps(2);
    tick(&mut harness, "AFNI warp");
    assert_eq!(harness.state().ready().expect("loaded").files.export_fields.field_form, FieldForm::Afni);
    let message = export(&mut harness, "Export displacement field", &afni_out);
    assert!(message.contains("displacement field"), "{message}");
    let afni = warpbench_io::displacement::read_field_info(&afni_out).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(afni.source.name(), "afni");
    assert_eq!(afni.field.displacements_lps, nifti.displacements_lps, "the ITK field's vectors");
    for _ in 0..2 {
        tick(&mut harness, "Learn2Reg steps in voxels");
        let fields = &harness.state().ready().expect("loaded").files.export_fields;
        assert_ne!(fields.field_form, FieldForm::Afni, "one form at a time");
    }
    assert_eq!(harness.state().ready().expect("loaded").files.export_fields.field_form, FieldForm::ByName);
    let inverse_out = dir.path().join("inverse.nrrd");
    let message = export(&mut harness, "Export inverse field", &inverse_out);
    assert!(message.contains("inverse (forward) displacement field"), "{message}");
    let tfm_out = dir.path().join("moving_from_fixed.tfm");
    let message = export(&mut harness, "Export transform", &tfm_out);
    assert!(message.contains("ThinPlateSplineKernelTransform_double_3_3 (5 pairs"), "{message}");
    let elastix_out = dir.path().join("TransformParameters.0.txt");
    let message = export(&mut harness, "Export for elastix", &elastix_out);
    assert!(message.contains("SplineKernelTransform (5 pairs"), "{message}");
    // A DICOM registration relates two DICOM series: two NIfTI volumes are refused.
    let reg_out = dir.path().join("reg.dcm");
    let message = export(&mut harness, "Export DICOM registration", &reg_out);
    assert!(message.contains("reg.dcm") && message.contains("is not DICOM"), "{message}");
    assert!(!reg_out.exists());
    let det_out = dir.path().join("det.nii.gz");
    let message = export(&mut harness, "Export Jacobian map", &det_out);
    assert!(
        message.contains("Jacobian determinant map of the tps warp (5 pairs)") && message.contains("% folded"),
        "{message}"
    );
    let magnitude_out = dir.path().join("moved.nrrd");
    let message = export(&mut harness, "Export warp magnitude", &magnitude_out);
    assert!(message.contains("warp magnitude (mm) map"), "{message}");
    // Names a button refuses (no export starts): the status bar says why, and nothing is written. Learn2Reg's .npz
    // holds the pull-back only.
    for (button, name, says) in [
        ("Export inverse field", "inverse.npz", "inverse.npz: a Learn2Reg field (.npz) holds the pull-back"),
        (
            "Export displacement field",
            "field.txt",
            "NIfTI (.nii, .nii.gz), NRRD (.nrrd), MetaImage (.mha, .mhd), ITK's HDF5",
        ),
        ("Export for elastix", "elastix.tfm", "an elastix transform parameter file is a .txt"),
    ] {
        let out = dir.path().join(name);
        let message = export(&mut harness, button, &out);
        assert!(message.contains(says) && !out.exists(), "{button}: {message}");
    }

    // The same files as `warpbench warp --exact`, `warpbench field` (and `field --direction forward`), `transform`
    // and `jacobian` write for the same inputs, byte for byte.
    let cli = |args: &[&str]| {
        let out = std::process::Command::new(env!("CARGO_BIN_EXE_warpbench")).args(args).output().expect("run");
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    };
    let (m, c) = (mri().display().to_string(), csv.display().to_string());
    let cli_warped = dir.path().join("cli_warped.nii.gz");
    let cli_field = dir.path().join("cli_field.nii.gz");
    let common = ["--fixed", m.as_str(), "--moving", m.as_str(), "--landmarks", c.as_str(), "--quiet"];
    let warped_arg = cli_warped.display().to_string();
    cli(&[&["warp"], &common[..], &["--exact", "--interp", "linear", "--out", warped_arg.as_str()]].concat());
    let field_arg = cli_field.display().to_string();
    cli(&[&["field"], &common[..], &["--out", field_arg.as_str()]].concat());
    assert!(std::fs::read(&warped).expect("window's") == std::fs::read(&cli_warped).expect("CLI's"), "warped volume");
    assert!(std::fs::read(&field_out).expect("window's") == std::fs::read(&cli_field).expect("CLI's"), "field");
    let cli_metaimage = dir.path().join("cli_field.mha").display().to_string();
    cli(&[&["field"], &common[..], &["--format", "metaimage", "--out", cli_metaimage.as_str()]].concat());
    assert!(std::fs::read(&metaimage_out).expect("window's") == std::fs::read(&cli_metaimage).expect("CLI's"), "mha");
    let cli_npz = dir.path().join("cli_field.npz").display().to_string();
    cli(&[&["field"], &common[..], &["--out", cli_npz.as_str()]].concat());
    assert!(std::fs::read(&npz_out).expect("window's") == std::fs::read(&cli_npz).expect("CLI's"), "npz");
    let cli_l2r_nifti = dir.path().join("cli_disp.nii.gz").display().to_string();
    cli(&[&["field"], &common[..], &["--format", "learn2reg", "--out", cli_l2r_nifti.as_str()]].concat());
    let same = std::fs::read(&l2r_nifti_out).expect("window's") == std::fs::read(&cli_l2r_nifti).expect("CLI's");
    assert!(same, "Learn2Reg's NIfTI form");
    let cli_inverse = dir.path().join("cli_inverse.nrrd").display().to_string();
    let forward = ["--direction", "forward", "--format", "nrrd", "--out", cli_inverse.as_str()];
    cli(&[&["field"], &common[..], &forward[..]].concat());
    assert!(std::fs::read(&inverse_out).expect("window's") == std::fs::read(&cli_inverse).expect("CLI's"), "inverse");
    let cli_tfm = dir.path().join("cli.tfm").display().to_string();
    cli(&[&["transform"], &common[..], &["--out", cli_tfm.as_str()]].concat());
    assert!(std::fs::read(&tfm_out).expect("window's") == std::fs::read(&cli_tfm).expect("CLI's"), "transform");
    let cli_elastix = dir.path().join("cli_elastix.txt").display().to_string();
    cli(&[&["transform"], &common[..], &["--format", "elastix", "--out", cli_elastix.as_str()]].concat());
    assert!(std::fs::read(&elastix_out).expect("window's") == std::fs::read(&cli_elastix).expect("CLI's"), "elastix");
    for (quantity, window_out) in [("det", &det_out), ("magnitude", &magnitude_out)] {
        let cli_map = dir.path().join(format!("cli_{}", window_out.file_name().expect("name").to_string_lossy()));
        let cli_map_arg = cli_map.display().to_string();
        cli(&[&["jacobian"], &common[..], &["--quantity", quantity, "--out", cli_map_arg.as_str()]].concat());
        assert!(std::fs::read(window_out).expect("window's") == std::fs::read(&cli_map).expect("CLI's"), "{quantity}");
    }
    let header = String::from_utf8_lossy(&std::fs::read(&inverse_out).expect("read")).into_owned();
    assert!(header.contains("displacement field type:=modeling"), "the inverse says it is a forward map");
}

#[test]
fn snapshot_with_nothing_open() {
    if no_adapter() {
        return;
    }
    // Nothing open: the menu, the message and the demo button.
    let opts = GuiOptions {
        fixed: Some(Path::new("/nonexistent/fixed.nii").to_path_buf()),
        moving: Some(mri()),
        ..GuiOptions::default()
    };
    let mut harness =
        Harness::builder().with_size(egui::vec2(640.0, 240.0)).wgpu().build_eframe(|cc| Workbench::new(cc, opts));
    wait_for_failure(&mut harness);
    harness.run_steps(2);
    harness.snapshot("no_volumes");
}

#[test]
fn snapshot_of_the_pair() {
    if no_adapter() {
        return;
    }
    // The MRI pair with its five landmarks; the status bar (adapter name, frame time) is masked. The 900×600 window
    // is drawn at 0.28 pixels per point, so that the golden image stays within 256² (252×168).
    let dir = tempfile::tempdir().expect("tempdir");
    let mut harness = open_mri_pair_at(dir.path(), egui::vec2(900.0, 600.0), 0.28);
    let status = harness.get_by_label_contains("last frame").rect();
    harness.mask(egui::Rect::from_x_y_ranges(0.0..=900.0, (status.top() - 4.0)..=600.0));
    harness.snapshot("mri_pair");
}

#[test]
fn an_idle_window_says_so_in_the_status_bar() {
    if no_adapter() {
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let mut harness = open_mri_pair(dir.path(), egui::vec2(1100.0, 760.0));
    // Frames were just drawn: a rate is shown.
    harness.get_by_label_contains(" fps");
    // Step as the event loop would: at once when asked to, after the delay the window asks for, and not at all
    // once it asks for nothing. The window then stands idle, and its status bar must say so.
    let start = Instant::now();
    loop {
        let delay =
            harness.output().viewport_output.get(&egui::ViewportId::ROOT).map_or(Duration::MAX, |v| v.repaint_delay);
        if delay == Duration::MAX {
            break;
        }
        assert!(start.elapsed() < Duration::from_mins(1), "the window never went idle");
        std::thread::sleep(delay.min(Duration::from_secs(2)));
        harness.step();
    }
    harness.get_by_label_contains("| idle");
}
