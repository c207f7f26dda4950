//! The window's document and fit through egui_kittest: sessions and crash recovery, undo, folding, the GPU control
//! texture and the 3-D view's progressive refinement.

mod common;
#[path = "common/window.rs"]
mod window;

use std::time::{Duration, Instant};

use common::mri;
use window::{no_adapter, open_mri_pair, pairs, wait_until_rendered, wait_until_shown};

use eframe::egui;
use egui_kittest::Harness;
use egui_kittest::kittest::Queryable;
use warpbench_app::gui::{GuiOptions, Ready, Workbench};
use warpbench_app::inputs::LandmarkSource;

#[test]
fn sessions_save_and_reopen_and_a_crash_is_recovered() {
    if no_adapter() {
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let autosave = dir.path().join("autosave.warpbench.json");
    let opts = GuiOptions {
        fixed: Some(mri()),
        moving: Some(mri()),
        landmarks: Some(LandmarkSource::Pairs(pairs(dir.path()))),
        autosave: Some(autosave.clone()),
        ..GuiOptions::default()
    };
    let mut harness =
        Harness::builder().with_size(egui::vec2(900.0, 640.0)).wgpu().build_eframe(|cc| Workbench::new(cc, opts));
    wait_until_shown(&mut harness);
    assert!(harness.state().recovery.is_none(), "no crashed session to offer");
    // Change things: the method, a pair switched off, the camera; then save the session.
    {
        let ready = harness.state_mut().ready_mut().expect("loaded");
        ready.document.settings.method = warpbench_app::settings::MethodKind::Rigid;
        ready.document.settings.oblique[1] =
            warpbench_app::gui::document::Oblique { on: true, tilt_deg: 20.0, spin_deg: -10.0 };
        ready.document.pairs[1].active = false;
        ready.camera.azimuth_rad = 1.0;
        ready.refit();
    }
    let saved = harness.state().ready().expect("loaded").to_session(true);
    let session_path = dir.path().join("project.warpbench.json");
    warpbench_app::gui::session::save(&session_path, &saved).expect("save");
    // The window autosaves, then "crashes" (no clean exit).
    harness.state_mut().autosave_now(false);
    drop(harness);

    // Reopening the project restores it.
    let opts = GuiOptions {
        session: Some(session_path),
        autosave: Some(dir.path().join("other-autosave.json")),
        ..GuiOptions::default()
    };
    let mut harness =
        Harness::builder().with_size(egui::vec2(900.0, 640.0)).wgpu().build_eframe(|cc| Workbench::new(cc, opts));
    wait_until_shown(&mut harness);
    let ready = harness.state().ready().expect("loaded");
    assert_eq!(ready.to_session(true), saved, "the reopened session is the saved one");
    assert_eq!(ready.fitted_pairs(), 4);
    drop(harness);

    // A new window on the crashed autosave offers recovery, and recovering brings the pairs back.
    let opts = GuiOptions { autosave: Some(autosave), ..GuiOptions::default() };
    let mut harness =
        Harness::builder().with_size(egui::vec2(900.0, 640.0)).wgpu().build_eframe(|cc| Workbench::new(cc, opts));
    assert!(harness.state().recovery.is_some(), "a crashed session is offered");
    wait_until_shown(&mut harness);
    harness.get_by_label("Recover the last session").click();
    harness.run_steps(2);
    wait_until_shown(&mut harness);
    let ready = harness.state().ready().expect("loaded");
    assert_eq!(ready.document.pairs, saved.document.pairs);
    assert_eq!(ready.document.settings.method().to_string(), "rigid");
}

#[test]
fn a_folding_warp_is_flagged_with_its_location() {
    if no_adapter() {
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let mut harness = open_mri_pair(dir.path(), egui::vec2(1100.0, 700.0));
    assert!(harness.state().ready().expect("loaded").fit.jacobian.is_some_and(|j| j.min_det > 0.0), "no folding yet");
    assert!(harness.query_by_label_contains("the warp folds").is_none());
    // Two pairs 6 mm apart whose sources cross over (each moves 10 mm past the other): the pull-back folds there.
    {
        let ready = harness.state_mut().ready_mut().expect("loaded");
        let pt = |x: f64| warpbench_io::geometry::Point3::new(x, 18.0, 30.0);
        ready.document.pairs.push(warpbench_io::landmarks::LandmarkPair::new("x1", pt(13.0), pt(0.0)));
        ready.document.pairs.push(warpbench_io::landmarks::LandmarkPair::new("x2", pt(-7.0), pt(6.0)));
        ready.refit();
    }
    harness.run_steps(2);
    // The folding check follows the fit on a thread of its own.
    wait_until_rendered(&mut harness);
    let j = harness.state().ready().expect("loaded").fit.jacobian.expect("a fit");
    assert!(j.min_det <= 0.0 && j.fraction_folded > 0.0, "{j:?}");
    // The minimum lies between the crossing pairs.
    assert!((j.min_at[0] - 3.0).abs() < 15.0 && (j.min_at[2] - 30.0).abs() < 15.0, "{j:?}");
    harness.get_by_label_contains("the warp folds");
}

#[test]
fn the_control_texture_made_on_the_gpu_equals_the_cpu_one() {
    if no_adapter() {
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let mut harness = open_mri_pair(dir.path(), egui::vec2(900.0, 640.0));
    for method in ["tps", "hbspline"] {
        let ready = harness.state_mut().ready_mut().expect("loaded");
        ready.document.settings.method = method.parse().expect("a method");
        // The CPU's texels: the same fit and grid, sampled by the solver (f64), as the window's CPU path uploads them.
        let (fixed, moving): (Vec<_>, Vec<_>) = ready
            .document
            .pairs
            .iter()
            .map(|p| {
                (
                    warpbench_solver::spaces::as_fixed(p.fixed.expect("fixed")),
                    warpbench_solver::spaces::as_moving(p.moving.expect("moving")),
                )
            })
            .unzip();
        let boxes = (
            warpbench_app::inputs::volume_box(&ready.loaded.fixed),
            warpbench_app::inputs::volume_box(&ready.loaded.moving),
        );
        let n = ready.document.settings.grid_n;
        let (fitted, _) =
            warpbench_app::gui::fit_warp(&ready.document.settings.method(), &fixed, &moving, boxes, n, true, None)
                .expect("fit");
        let (_, texture) = warpbench_app::scene::control_texture(fitted.pullback.as_ref(), boxes.0, n).expect("sample");
        let cpu: Vec<[f32; 4]> = texture.as_f32s().chunks_exact(4).map(|c| [c[0], c[1], c[2], c[3]]).collect();
        // The GPU's: evaluated into the window's control texture.
        ready.control_eval = warpbench_app::gui::ControlEval::Gpu;
        ready.refit();
        assert!(ready.fit.error.is_none(), "{method}: {:?}", ready.fit.error);
        assert!(ready.viewer.control_made_on_gpu(), "{method}: the texture was not evaluated on the GPU");
        let control = ready.viewer.control.as_ref().expect("a control texture");
        assert_eq!(control.info.dims.map(|d| d as usize), [n; 3]);
        let gpu = warpbench_gpu::control_eval::read_back_texels(&ready.viewer.ctx, control).expect("read back");
        assert_eq!(gpu.len(), cpu.len());
        let largest = cpu.iter().flat_map(|t| t[..3].iter()).fold(0.0f32, |m, v| m.max(v.abs()));
        assert!(largest > 1.0, "{method}: the warp moves things: {largest} mm");
        let worst =
            cpu.iter().zip(&gpu).flat_map(|(a, b)| (0..3).map(move |i| (a[i] - b[i]).abs())).fold(0.0f32, f32::max);
        // The same function on the same grid: f64 on the CPU against f32 on the GPU (a TPS about the box centre),
        // and f16 storage where float32 textures do not filter.
        assert!(
            worst < 0.01 + 1e-3 * largest,
            "{method}: worst texel difference {worst} mm (largest displacement {largest} mm)"
        );
        harness.run_steps(2);
        assert!(harness.state().ready().expect("loaded").fit.error.is_none());
    }
}

#[test]
fn undo_of_every_command_gives_the_document_back_and_view_commands_leave_it() {
    use warpbench_app::gui::Command;
    use warpbench_app::gui::panels::FileAction;
    use warpbench_io::geometry::Point3;
    if no_adapter() {
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let mut harness = open_mri_pair(dir.path(), egui::vec2(900.0, 640.0));
    let imported = dir.path().join("three.csv");
    common::write_pairs_csv(&imported, &[([1.0, 2.0, 3.0], [4.0, 5.0, 6.0]); 3]);
    let ready = harness.state_mut().ready_mut().expect("loaded");
    let mut settings = ready.document.settings.clone();
    settings.method = warpbench_app::settings::MethodKind::Rigid;
    settings.blend = warpbench_app::settings::Blend::Difference;
    settings.oblique[2].on = true;
    let mut looks = ready.document.layers;
    (looks[1].visible, looks[0].window_high) = (false, looks[0].window_high + 10.0);
    let edits = [
        Command::AddPair { moving: Point3::new(1.0, 10.0, 20.0), fixed: Point3::new(2.0, 10.0, 20.0) },
        Command::MovePoint { pair: 0, end: warpbench_app::gui::End::Fixed, to: [1.0, 2.0, 3.0], settled: true },
        Command::MovePoint { pair: 1, end: warpbench_app::gui::End::Moving, to: [4.0, 5.0, 6.0], settled: false },
        Command::DeletePair(2),
        Command::RenamePair(0, "renamed".into()),
        Command::SetActive(1, false),
        Command::SetSettings(settings),
        Command::SetLooks(looks),
        Command::File(FileAction::ImportLandmarks(imported)),
    ];
    for command in edits {
        let before = ready.document.clone();
        ready.apply(command.clone());
        ready.settle(false);
        let after = ready.document.clone();
        assert_ne!(after, before, "{command:?} changes the document");
        ready.apply(Command::Undo);
        assert_eq!(ready.document, before, "undo of {command:?}");
        ready.apply(Command::Redo);
        assert_eq!(ready.document, after, "redo of {command:?}");
    }
    let views = [
        Command::ToggleAdding,
        Command::Cancel,
        Command::Select(1),
        Command::JumpTo(0),
        Command::MoveSlice(1, 12.0),
        Command::CentreSlices([1.0, 2.0, 3.0]),
        Command::ResetCamera,
        Command::ShowWorstPair,
        Command::TogglePulse,
    ];
    for command in views {
        let before = ready.document.clone();
        ready.apply(command.clone());
        ready.settle(false);
        assert_eq!(ready.document, before, "{command:?} leaves the document");
    }
    // None of the view commands was an undo step: undo goes back to before the import.
    ready.apply(Command::Undo);
    assert_eq!(ready.document.pairs.len(), 5, "{:?}", ready.document.pairs);
}

#[test]
fn the_3d_view_is_shown_reduced_at_once_then_refined_to_the_one_pass_image() {
    if no_adapter() {
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let mut harness = open_mri_pair(dir.path(), egui::vec2(900.0, 600.0));
    let cpu = harness.state().ready().expect("ready").viewer.ctx.is_cpu_driver();
    let ((full_w, full_h), full) = harness.state().ready().and_then(Ready::view_shown).expect("a view");
    assert!(full, "the view is not refined after loading");
    harness.get_by_label("Reset camera").click();
    harness.step();
    harness.step();
    let ready = harness.state().ready().expect("ready");
    let (size, full) = ready.view_shown().expect("a view");
    if cpu {
        // The camera moved: a reduced view at once, the full one still to come.
        assert!(!full && size.0 <= full_w && size.1 <= full_h, "{size:?} full {full}");
        assert!(ready.needs_render(), "nothing left to refine");
    }
    // A thread adds bands until the full view is shown.
    let mut progress = vec![ready.view_refine_progress().unwrap_or(0.0)];
    let start = Instant::now();
    while harness.state().ready().is_some_and(Ready::needs_render) {
        harness.step();
        if let Some(p) = harness.state().ready().and_then(Ready::view_refine_progress) {
            progress.push(p);
        }
        assert!(start.elapsed() < Duration::from_mins(1), "not refined within a minute");
    }
    eprintln!("refined in {} frames: {progress:?}", progress.len());
    assert!(progress.windows(2).all(|w| w[1] >= w[0]), "the progress went back: {progress:?}");
    let ready = harness.state().ready().expect("ready");
    assert_eq!(ready.view_shown(), Some(((full_w, full_h), true)));
    // The refined image is the one-pass full-quality render, glyphs included, bit for bit.
    let shown = ready.read_view().expect("read the view");
    let once = ready
        .viewer
        .render_view(
            &ready.camera,
            &ready.document.settings.render_settings(),
            warpbench_gpu::Quality::Full,
            (full_w, full_h),
            &ready.glyphs(),
        )
        .expect("render at once");
    let once = once.read_back(&ready.viewer.ctx).expect("read back");
    let alpha = shown.chunks(4).filter(|p| p[3] > 0).count();
    assert!(alpha * 10 > shown.len() / 4, "the view is mostly empty: {alpha} px");
    let differ = shown.iter().zip(&once).filter(|(a, b)| a != b).count();
    assert_eq!(differ, 0, "the refined view differs from the one-pass view in {differ} channels");
}

/// "Auto" by the stiffness slider: with five pairs, whose refits are affine whatever λ is, it stays at 0; with twenty
/// noisy pairs it sets the λ the solver's
/// `choose_stiffness` gives for the document's pairs (called here on the points as the table lists them), shows its
/// figures while they hold, and is one undo step.
#[test]
fn auto_stiffness_sets_the_leave_one_out_choice() {
    use warpbench_io::geometry::Point3;
    use warpbench_solver::spaces::{Fixed, Moving};

    if no_adapter() {
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let mut harness = open_mri_pair(dir.path(), egui::vec2(1100.0, 900.0));
    harness.get_by_label("Auto").click();
    harness.run_steps(2);
    let ready = harness.state().ready().expect("loaded");
    let choice = ready.current_stiffness_choice().expect("the choice");
    assert!(ready.document.settings.stiffness == 0.0 && choice.lambda == 0.0, "{choice:?}");
    drop(harness);

    let noisy = common::noisy_mri_pairs();
    let csv = dir.path().join("noisy.csv");
    common::write_pairs_csv(&csv, &noisy);
    let opts = GuiOptions {
        fixed: Some(mri()),
        moving: Some(mri()),
        landmarks: Some(LandmarkSource::Pairs(csv)),
        autosave: Some(dir.path().join("autosave2.warpbench.json")),
        ..GuiOptions::default()
    };
    let mut harness =
        Harness::builder().with_size(egui::vec2(1100.0, 900.0)).wgpu().build_eframe(|cc| Workbench::new(cc, opts));
    wait_until_shown(&mut harness);
    harness.get_by_label("Auto").click();
    harness.run_steps(3);
    wait_until_rendered(&mut harness);
    let ready = harness.state().ready().expect("loaded");
    let fixed: Vec<Point3<Fixed>> =
        ready.document.pairs.iter().map(|p| Point3::from_array(p.fixed.expect("fixed").coords())).collect();
    let moving: Vec<Point3<Moving>> =
        ready.document.pairs.iter().map(|p| Point3::from_array(p.moving.expect("moving").coords())).collect();
    let expected = warpbench_solver::stiffness::choose_stiffness(&fixed, &moving).expect("a choice");
    eprintln!(
        "auto stiffness {:.3}: LOO RMS {:.3} mm, {:.3} at 0",
        expected.lambda, expected.loo_rms_mm, expected.loo_rms_interpolating_mm
    );
    assert!(expected.lambda > 0.0 && expected.loo_rms_mm < expected.loo_rms_interpolating_mm, "{expected:?}");
    assert!(
        ready.document.settings.stiffness.to_bits() == expected.lambda.to_bits(),
        "{}",
        ready.document.settings.stiffness
    );
    assert_eq!(ready.current_stiffness_choice(), Some(&expected));
    assert!(ready.fit.error.is_none() && ready.fitted_pairs() == 20, "{:?}", ready.fit.error);
    harness.get_by_label_contains("Auto: leave-one-out RMS");

    harness.get_by_label("Undo").click();
    harness.run_steps(3);
    let ready = harness.state().ready().expect("loaded");
    assert!(ready.document.settings.stiffness == 0.0, "undo gives lambda 0 back");
    assert!(ready.current_stiffness_choice().is_none());
}

/// The status bar's read-out under the pointer in a slice: |u(x) − x| of the two points it shows, det ∇u against
/// central differences of the shown pull-back (h = 0.05 mm), and the nearest pair found by brute force with its
/// leave-one-out error, all in the label the bar shows.
#[test]
fn the_status_bar_reads_out_the_warp_under_the_pointer() {
    if no_adapter() {
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let mut harness = open_mri_pair(dir.path(), egui::vec2(1100.0, 760.0));
    let start = Instant::now();
    while harness.state().ready().expect("loaded").diagnostics_pending() {
        harness.step();
        assert!(start.elapsed() < Duration::from_mins(1), "the diagnostics did not come");
        std::thread::sleep(Duration::from_millis(10));
    }
    let rect = harness.get_by_label("Axial slice").rect();
    let pos = rect.center() + egui::vec2(0.1 * rect.width(), -0.05 * rect.height());
    harness.input_mut().events.push(egui::Event::PointerMoved(pos));
    harness.run_steps(2);
    let ready = harness.state().ready().expect("loaded");
    let c = ready.cursor.expect("the pointer is over the slice");
    let d: f64 = (0..3).map(|a| (c.moving_lps[a] - c.fixed_lps[a]).powi(2)).sum::<f64>().sqrt();
    assert!((c.displacement_mm() - d).abs() < 1e-12 && d > 0.5, "{d}");

    let h = 0.05;
    let mut j = [[0.0; 3]; 3];
    for a in 0..3 {
        let (mut plus, mut minus) = (c.fixed_lps, c.fixed_lps);
        plus[a] += h;
        minus[a] -= h;
        let (up, down) = (ready.moving_shown_at(plus), ready.moving_shown_at(minus));
        for (r, row) in j.iter_mut().enumerate() {
            row[a] = (up[r] - down[r]) / (2.0 * h);
        }
    }
    let det = j[0][0] * (j[1][1] * j[2][2] - j[1][2] * j[2][1]) - j[0][1] * (j[1][0] * j[2][2] - j[1][2] * j[2][0])
        + j[0][2] * (j[1][0] * j[2][1] - j[1][1] * j[2][0]);
    let shown = c.det_jacobian.expect("a warp is fitted");
    eprintln!("det {shown:.6} against central differences {det:.6}");
    assert!((shown - det).abs() < 1e-4, "{shown} vs {det}");

    let (index, distance) = ready
        .document
        .pairs
        .iter()
        .enumerate()
        .map(|(i, p)| {
            let q = p.fixed.expect("fixed").coords();
            (i, (0..3).map(|a| (q[a] - c.fixed_lps[a]).powi(2)).sum::<f64>().sqrt())
        })
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .expect("pairs");
    let nearest = c.nearest.expect("a nearest pair");
    assert_eq!(nearest.index, index);
    assert!((nearest.distance_mm - distance).abs() < 1e-9);
    let loo = ready.fit.pair_errors[index].and_then(|e| e.leave_one_out_mm);
    assert!(loo.is_some() && nearest.leave_one_out_mm == loo, "{nearest:?} vs {loo:?}");
    let label = c.readout(&ready.document.pairs[index].name);
    assert!(label.contains("det ") && label.contains("leave-one-out"), "{label}");
    harness.get_by_label(&label);

    // In the 3-D view: once the pointer rests, the point picked under it is read out, and it lies under the pointer.
    let view = harness.get_by_label("3-D view").rect();
    let pos = view.center() + egui::vec2(0.05 * view.width(), 0.03 * view.height());
    harness.input_mut().events.push(egui::Event::PointerMoved(pos));
    harness.run_steps(2);
    std::thread::sleep(warpbench_app::gui::hover::REST + Duration::from_millis(50));
    harness.run_steps(3);
    let ready = harness.state().ready().expect("loaded");
    let c = ready.cursor.expect("the pointer rests over the head in the 3-D view");
    let x = warpbench_gpu::glam::Vec3::from_array(c.fixed_lps.map(|v| v as f32));
    let clip = ready.camera.clip_from_ref(view.width() / view.height()) * x.extend(1.0);
    let on_screen = view.min
        + egui::vec2((clip.x / clip.w * 0.5 + 0.5) * view.width(), (0.5 - clip.y / clip.w * 0.5) * view.height());
    assert!((on_screen - pos).length() < 3.0, "picked {:?} shows at {on_screen:?}, pointer at {pos:?}", c.fixed_lps);
    assert!(c.det_jacobian.is_some_and(f64::is_finite));
    let name = c.nearest.map_or(String::new(), |n| ready.document.pairs[n.index].name.clone());
    harness.get_by_label(&c.readout(&name));
}

/// Auto-align (issue 18 item 1): on a pair whose moving volume is the fixed one moved by a known rigid transform,
/// "Auto-align" puts the alignment under the landmark warp as the document's starting transform (within half a
/// millimetre of the truth over the fixed box), which with no pairs is the warp shown; it is one undo step, it reaches
/// the autosave, the command line's `--session` takes it, and "Clear alignment" takes it away.
#[test]
fn auto_align_puts_the_alignment_under_the_landmark_warp() {
    use warpbench_io::geometry::{Lps, Point3, Transform};

    if no_adapter() {
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let mut moving = warpbench_io::open(mri()).expect("the fixture");
    let rotation = nalgebra::Rotation3::from_axis_angle(
        &nalgebra::Unit::new_normalize(nalgebra::Vector3::new(0.2, 1.0, -0.3)),
        10f64.to_radians(),
    )
    .into_inner();
    let truth: Transform<Lps, Lps> = Transform::from_linear_translation(rotation, [6.0, -12.0, 9.0]);
    moving.lps_from_index = truth * moving.lps_from_index;
    let moved = dir.path().join("moved.nii");
    warpbench_io::nifti::write(&moved, &moving).expect("write the moved fixture");
    let autosave = dir.path().join("autosave.warpbench.json");
    let opts = GuiOptions {
        fixed: Some(mri()),
        moving: Some(moved.clone()),
        autosave: Some(autosave.clone()),
        ..GuiOptions::default()
    };
    let mut harness =
        Harness::builder().with_size(egui::vec2(1100.0, 900.0)).wgpu().build_eframe(|cc| Workbench::new(cc, opts));
    wait_until_shown(&mut harness);
    harness.get_by_label_contains("Starting transform: none");
    harness.get_by_label("Auto-align").click();
    let start = Instant::now();
    harness.run_steps(2);
    while harness.state().ready().is_some_and(Ready::aligning) {
        harness.step();
        assert!(start.elapsed() < Duration::from_mins(3), "Auto-align did not finish within three minutes");
        std::thread::sleep(Duration::from_millis(20));
    }
    harness.run_steps(3);
    wait_until_rendered(&mut harness);
    let ready = harness.state().ready().expect("loaded");
    let found = ready.document.start.clone().expect("a starting transform");
    assert!(found.origin.starts_with("Auto-align (rigid"), "{}", found.origin);
    harness.get_by_label_contains("Starting transform: Auto-align (rigid");
    // With no pairs the warp is the starting transform: the moving point shown at x is T0(x), near the truth.
    let volume = warpbench_io::open(mri()).expect("fixture");
    for c in 0..8 {
        let ijk = [0, 1, 2].map(|a| if c >> a & 1 == 1 { (volume.dims[a] - 1) as f64 } else { 0.0 });
        let x = volume.lps_from_index.apply_point(Point3::from_array(ijk)).coords();
        let shown = ready.moving_shown_at(x);
        let m = &found.moving_from_fixed;
        let by_rows: [f64; 3] = std::array::from_fn(|r| m[r][0] * x[0] + m[r][1] * x[1] + m[r][2] * x[2] + m[r][3]);
        let want = truth.apply_point(Point3::from_array(x)).coords();
        for a in 0..3 {
            assert!((shown[a] - by_rows[a]).abs() < 1e-6, "shown {shown:?}, T0 {by_rows:?}");
            assert!((shown[a] - want[a]).abs() < 0.5, "corner {c}: shown {shown:?}, truth {want:?}");
        }
    }
    assert!(ready.fit.error.is_none(), "{:?}", ready.fit.error);
    // The autosave holds it, and the command line reads it from the session.
    let saved = warpbench_app::gui::session::load(&autosave).expect("the autosave");
    assert_eq!(saved.document.start.as_ref(), Some(&found));
    let targets = dir.path().join("targets.csv");
    std::fs::write(&targets, "10,-20,15,a\n").expect("write a point");
    let mapped = dir.path().join("mapped.csv");
    let out = common::warpbench(&[
        "points",
        "--fixed",
        common::utf8(&mri()),
        "--moving",
        common::utf8(&moved),
        "--session",
        common::utf8(&autosave),
        "--from",
        "fixed",
        "--in",
        common::utf8(&targets),
        "--out",
        common::utf8(&mapped),
    ]);
    common::assert_ok(&out);
    let line = std::fs::read_to_string(&mapped).expect("mapped");
    let got: Vec<f64> = line
        .lines()
        .find(|l| !l.starts_with('#'))
        .expect("a line")
        .split(',')
        .take(3)
        .map(|v| v.trim().parse().expect("number"))
        .collect();
    let want = ready.moving_shown_at([10.0, -20.0, 15.0]);
    assert!((0..3).all(|a| (got[a] - want[a]).abs() < 1e-6), "{got:?} vs {want:?}");

    // One undo step; then "Clear alignment".
    harness.get_by_label("Undo").click();
    harness.run_steps(2);
    assert!(harness.state().ready().expect("loaded").document.start.is_none());
    harness.get_by_label("Redo").click();
    harness.run_steps(2);
    assert_eq!(harness.state().ready().expect("loaded").document.start.as_ref(), Some(&found));
    harness.get_by_label("Clear alignment").click();
    harness.run_steps(2);
    assert!(harness.state().ready().expect("loaded").document.start.is_none());
}
