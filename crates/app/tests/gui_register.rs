//! Refine by intensities in the window (issue 31, item 3) through egui_kittest, on the registration's test case (the
//! MRI fixture through two known bumps against its inverted contrast, 6 pairs of the truth): the button runs on a
//! worker with a progress bar and Cancel; its result is the document's field under the landmarks, shown live (closer
//! to the truth than the TPS through the pairs, the pairs kept), one undo step, in the autosave where the command line
//! reads it; a pair moved afterwards offers to run it again; Cancel leaves the warp as it was.

mod common;
#[path = "common/register_case.rs"]
mod register_case;
#[path = "common/window.rs"]
mod window;

use std::path::Path;
use std::time::{Duration, Instant};

use register_case::{case, head_points, truth};
use window::{no_adapter, open_section, wait_until_rendered, wait_until_shown};

use eframe::egui;
use egui_kittest::Harness;
use egui_kittest::kittest::Queryable;
use warpbench_app::gui::{Command, End, GuiOptions, Ready, Workbench};
use warpbench_app::inputs::LandmarkSource;
use warpbench_app::settings::Metric;
use warpbench_io::geometry::Point3;
use warpbench_solver::register::RegisterParams;
use warpbench_solver::spaces::{Fixed, Moving};
use warpbench_solver::tps::Tps;
use warpbench_solver::warp::Warp;

fn open(dir: &Path) -> (Harness<'static, Workbench>, Vec<[f64; 3]>) {
    let (fixed, moving, pairs, qs) = case(dir);
    let opts = GuiOptions {
        fixed: Some(fixed),
        moving: Some(moving),
        landmarks: Some(LandmarkSource::Pairs(pairs)),
        autosave: Some(dir.join("autosave.warpbench.json")),
        ..GuiOptions::default()
    };
    let mut harness =
        Harness::builder().with_size(egui::vec2(1100.0, 900.0)).wgpu().build_eframe(|cc| Workbench::new(cc, opts));
    wait_until_shown(&mut harness);
    open_section(&mut harness, "Assist");
    (harness, qs)
}

/// Steps until no refinement runs (or five minutes pass: a guard against a hang, not a timing).
fn wait_for_refinement(harness: &mut Harness<'_, Workbench>) {
    let start = Instant::now();
    while harness.state().ready().is_some_and(|r| r.refining().is_some()) {
        harness.step();
        assert!(start.elapsed() < Duration::from_mins(5), "the refinement did not finish within five minutes");
        std::thread::sleep(Duration::from_millis(20));
    }
    harness.run_steps(3);
}

fn distance(a: [f64; 3], b: [f64; 3]) -> f64 {
    (0..3).map(|i| (a[i] - b[i]).powi(2)).sum::<f64>().sqrt()
}

/// The warp the window shows is closer to the truth, over the head, than the TPS through the pairs at `qs` (by 30 %),
/// and keeps each pair within 0.5 mm.
fn shown_beats_the_tps_and_keeps_the_pairs(ready: &Ready, qs: &[[f64; 3]]) {
    let volume = warpbench_io::open(common::mri()).expect("fixture");
    let points = head_points(&volume);
    let q: Vec<Point3<Fixed>> = qs.iter().map(|&q| Point3::from_array(q)).collect();
    let p: Vec<Point3<Moving>> = qs.iter().map(|&q| Point3::from_array(truth(q))).collect();
    let tps = Tps::<Moving, Fixed>::fit(&q, &p, 0.0).expect("tps");
    let mean = |f: &dyn Fn([f64; 3]) -> [f64; 3]| {
        points.iter().map(|&x| distance(f(x), truth(x))).sum::<f64>() / points.len() as f64
    };
    let shown = mean(&|x| ready.moving_shown_at(x));
    let through_pairs = mean(&|x| tps.apply_raw(x));
    eprintln!("mean TRE: shown {shown:.3} mm, TPS {through_pairs:.3} mm");
    assert!(shown < 0.7 * through_pairs, "shown {shown:.3} mm, TPS {through_pairs:.3} mm");
    for &q in qs {
        assert!(distance(ready.moving_shown_at(q), truth(q)) < 0.5, "pair at {q:?}");
    }
}

#[test]
fn refine_by_intensities_becomes_the_field_under_the_landmarks_undoes_saves_and_offers_a_rerun() {
    if no_adapter() {
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let (mut harness, qs) = open(dir.path());
    let before = harness.state().ready().expect("ready").document.clone();
    assert!(before.field.is_none());
    harness.get_by_label("Refine by intensities").click();
    harness.run_steps(2);
    // Running: a progress bar and Cancel in its place.
    assert!(harness.state().ready().expect("ready").refining().is_some(), "a worker runs it");
    harness.get_by_label("Cancel");
    wait_for_refinement(&mut harness);
    wait_until_rendered(&mut harness);

    let ready = harness.state().ready().expect("ready");
    let field = ready.document.field_path().expect("the refinement is the document's field").to_owned();
    assert!(field.starts_with(dir.path()) && field.exists(), "{} beside the autosave", field.display());
    assert!(ready.fit.error.is_none(), "{:?}", ready.fit.error);
    // The section and the status bar say what it did.
    assert!(harness.query_all_by_label_contains("Refined by intensities from tps").next().is_some());

    // Shown live: the warp the views show is closer to the truth than the TPS through the pairs, and keeps them.
    shown_beats_the_tps_and_keeps_the_pairs(ready, &qs);

    // In the autosave, where the command line reads it: `points --session` maps as the window shows.
    let autosave = dir.path().join("autosave.warpbench.json");
    let saved = warpbench_app::project::session::load(&autosave).expect("the autosave");
    assert_eq!(saved.document.field_path(), Some(field.as_path()));
    let (f, m) = (dir.path().join("fixed.nii"), dir.path().join("moving.nii"));
    let got = common::map_through_session(dir.path(), [&f, &m, &autosave], [10.0, -20.0, 15.0]);
    let want = ready.moving_shown_at([10.0, -20.0, 15.0]);
    assert!((0..3).all(|a| (got[a] - want[a]).abs() < 1e-6), "{got:?} vs {want:?}");

    // A pair moved afterwards: the section offers to run the refinement again.
    let q0 = qs[0];
    harness.state_mut().ready_mut().expect("ready").apply(Command::MovePoint {
        pair: 0,
        end: End::Fixed,
        to: Point3::new(q0[0] + 2.0, q0[1], q0[2]),
        settled: true,
    });
    harness.run_steps(3);
    harness.get_by_label("Re-run refinement");
    harness.get_by_label_contains("The pairs moved since the last refinement");

    // One undo step each: the move, then the refinement.
    for _ in 0..2 {
        harness.get_by_label("Undo").click();
        harness.run_steps(3);
    }
    assert_eq!(harness.state().ready().expect("ready").document, before, "undo gives the document back");
    harness.get_by_label("Redo").click();
    harness.run_steps(3);
    assert_eq!(harness.state().ready().expect("ready").document.field_path(), Some(field.as_path()));
}

/// "Match by" chooses what the refinement matches: the choice is the document's (one undo step, in the autosave). That
/// the next refinement uses it and says so is the fixed mask's test below, which refines by local correlation.
#[test]
fn match_by_local_correlation_is_the_documents_choice() {
    if no_adapter() {
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let (mut harness, _) = open(dir.path());
    harness.get_by_label("Match by").click();
    harness.run_steps(3);
    harness.get_by_label(Metric::Lncc.label()).click();
    harness.run_steps(3);
    assert_eq!(harness.state().ready().expect("ready").document.settings.refine_metric, Metric::Lncc);
    let autosave = dir.path().join("autosave.warpbench.json");
    let saved = warpbench_app::project::session::load(&autosave).expect("the autosave");
    assert_eq!(saved.document.settings.refine_metric, Metric::Lncc, "the choice reaches the autosave");
    let metric = |h: &Harness<'_, Workbench>| h.state().ready().expect("ready").document.settings.refine_metric;
    harness.get_by_label("Undo").click();
    harness.run_steps(3);
    assert_eq!(metric(&harness), Metric::Mi, "one undo step");
    harness.get_by_label("Redo").click();
    harness.run_steps(3);
    assert_eq!(metric(&harness), Metric::Lncc);
}

/// A fixed mask chosen in Assist is the document's (in the autosave; a file that is no volume is refused), the
/// refinement reads the fixed volume inside it by the session's Match by (local correlation) and says both, and
/// `warpbench register --session` takes the session's mask and Match by.
#[test]
fn a_fixed_mask_chosen_in_the_window_is_the_sessions_and_the_command_lines() {
    if no_adapter() {
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let (mut harness, qs) = open(dir.path());
    let (fixed, moving) = (dir.path().join("fixed.nii"), dir.path().join("moving.nii"));
    // The mask: the fixed grid, 0 on its first ten slices and 1 elsewhere.
    let mut mask_volume = warpbench_io::open(&fixed).expect("fixed");
    let plane = mask_volume.dims[0] * mask_volume.dims[1];
    let ones = (0..mask_volume.data.len()).map(|o| u8::from(o >= 10 * plane)).collect();
    mask_volume.data = warpbench_io::VoxelData::U8(ones);
    let mask = dir.path().join("mask.nii.gz");
    warpbench_io::nifti::write(&mask, &mask_volume).expect("write the mask");
    let fixed_mask = |h: &Harness<'_, Workbench>| h.state().ready().expect("ready").document.fixed_mask.clone();

    let not_a_volume = dir.path().join("mask.txt");
    std::fs::write(&not_a_volume, "no volume").expect("write");
    harness.get_by_label("Masks: none").click();
    harness.run_steps(2);
    for (path, kept) in [(&not_a_volume, None), (&mask, Some(mask.clone()))] {
        harness.state_mut().ready_mut().expect("ready").files.fields.masks[0].clear();
        harness.get_by_label("Fixed mask file").scroll_to_me();
        harness.run_steps(2);
        harness.get_by_label("Fixed mask file").focus();
        harness.run_steps(2);
        harness.get_by_label("Fixed mask file").type_text(&path.display().to_string());
        harness.run_steps(2);
        harness.get_by_label("Use as fixed mask").click();
        harness.run_steps(3);
        let notice = harness.state().ready().expect("ready").pointer.notice.clone().unwrap_or_default();
        assert_eq!(fixed_mask(&harness), kept, "{}: {notice}", path.display());
        let says =
            if kept.is_some() { "reads the fixed volume where it is not 0" } else { "not used as the fixed mask" };
        assert!(notice.contains(says), "{notice}");
    }
    harness.get_by_label_contains("Fixed mask: ");
    // Closed again, the section's title says which masks are set.
    harness.get_by_label("Masks: fixed").click();
    harness.run_steps(2);
    // Local correlation as the session's Match by, for the command line below.
    let ready = harness.state_mut().ready_mut().expect("ready");
    let settings = warpbench_app::project::document::ViewSettings {
        refine_metric: Metric::Lncc,
        ..ready.document.settings.clone()
    };
    ready.apply(Command::SetSettings(settings));
    harness.run_steps(2);

    harness.get_by_label("Refine by intensities").click();
    harness.run_steps(2);
    wait_for_refinement(&mut harness);
    assert!(
        harness.query_all_by_label_contains("inside the fixed mask mask.nii.gz: local correlation").next().is_some(),
        "the summary names the mask"
    );
    let ready = harness.state().ready().expect("ready");
    assert!(ready.document.field.is_some(), "{:?}", ready.fit.error);
    shown_beats_the_tps_and_keeps_the_pairs(ready, &qs);

    let autosave = dir.path().join("autosave.warpbench.json");
    let saved = warpbench_app::project::session::load(&autosave).expect("the autosave");
    assert_eq!(saved.document.fixed_mask.as_deref(), Some(mask.as_path()));
    let field = dir.path().join("cli-field.nii.gz");
    let out = common::warpbench(&[
        "register",
        "--fixed",
        common::utf8(&fixed),
        "--moving",
        common::utf8(&moving),
        "--session",
        common::utf8(&autosave),
        "--out-field",
        common::utf8(&field),
        "--grid-mm",
        "20",
        "--levels",
        "2",
        // What the session's settings become is the law here, not how far the optimiser goes.
        "--iterations",
        "3",
        "--json",
    ]);
    common::assert_ok(&out);
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).expect("JSON");
    assert_eq!(report["settings"]["fixed_mask"], common::utf8(&mask));
    assert_eq!(report["settings"]["metric"], "lncc");
}

#[test]
fn cancel_leaves_the_warp_as_it_was() {
    if no_adapter() {
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let (mut harness, _) = open(dir.path());
    let before = harness.state().ready().expect("ready").document.clone();
    harness.get_by_label("Refine by intensities").click();
    harness.run_steps(2);
    harness.get_by_label("Cancel").click();
    wait_for_refinement(&mut harness);
    let ready: &Ready = harness.state().ready().expect("ready");
    assert_eq!(ready.document, before, "nothing changed");
    assert!(harness.query_all_by_label_contains("cancelled; the warp is as it was").next().is_some());
    let refined = dir.path().join("refined");
    let written = std::fs::read_dir(&refined).map_or(0, Iterator::count);
    assert_eq!(written, 0, "no field written");
}

/// The window hands its GPU to the refinement when it is a hardware one (`Ready::start_intensities`); given a GPU,
/// the refinement reads its samples there and says so. Here lavapipe stands in for it. Skipped without an adapter
/// unless REQUIRE_GPU_ADAPTER=1.
#[test]
fn a_refinement_given_a_gpu_runs_there_and_says_so() {
    let Some(ctx) = warpbench_gpu::headless::headless_or_skip(warpbench_gpu::FeatureRequest::default()) else {
        return;
    };
    let dir = tempfile::tempdir().expect("tempdir");
    let (fixed, moving, _, _) = case(dir.path());
    let out = dir.path().join("refined.nii.gz");
    let input = warpbench_app::gui::intensity::RefineInput {
        fixed: std::sync::Arc::new(warpbench_io::open(&fixed).expect("fixed")),
        moving: std::sync::Arc::new(warpbench_io::open(&moving).expect("moving")),
        pairs: Vec::new(),
        method: warpbench_solver::method::Method::from_name("tps").expect("tps"),
        start: None,
        field: None,
        out: out.clone(),
        gpu: Some(std::sync::Arc::new(ctx)),
        // The law is where the samples are read, not how far the optimiser gets: on lavapipe a pass over the
        // samples costs about 5 µs a sample, and the defaults take a minute and a half there.
        params: RegisterParams { grid_mm: 40.0, levels: 1, max_iterations: 10, ..RegisterParams::default() },
        fixed_mask: None,
        moving_mask: None,
    };
    let refined = warpbench_app::gui::intensity::refine_pair(&input, &mut |_| true).expect("the refinement");
    assert!(refined.summary.ends_with("on the GPU"), "{}", refined.summary);
    assert_eq!(refined.field, out);
    assert!(out.exists(), "the field is written");
}
