//! The window's document and fit through egui_kittest: sessions and crash recovery, undo, folding, the GPU control
//! texture (also through a drag, against the full refit) and the 3-D view's progressive refinement.

mod common;
#[path = "common/window.rs"]
mod window;

use std::time::{Duration, Instant};

use common::mri;
use window::{no_adapter, open_mri_pair, pairs, wait_until_rendered, wait_until_shown};

use eframe::egui;
use egui_kittest::Harness;
use egui_kittest::kittest::Queryable;
use warpbench_app::fit::ControlRoute;
use warpbench_app::gui::{Command, End, GuiOptions, Ready, Workbench};
use warpbench_app::inputs::LandmarkSource;
use warpbench_app::project::document::StartingTransform;
use warpbench_io::geometry::Point3;
use warpbench_io::landmarks::LandmarkPair;
use warpbench_solver::method::FittedWarp;
use warpbench_solver::spaces::{Fixed, Moving};
use warpbench_solver::tps::Tps;
use warpbench_solver::warp::Warp;

/// The window on `opts`, `size` points large, drawn with wgpu.
fn workbench(opts: GuiOptions, size: egui::Vec2) -> Harness<'static, Workbench> {
    Harness::builder().with_size(size).wgpu().build_eframe(|cc| Workbench::new(cc, opts))
}

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
    let mut harness = workbench(opts, egui::vec2(900.0, 640.0));
    wait_until_shown(&mut harness);
    assert!(harness.state().recovery.is_none(), "no crashed session to offer");
    // Change things: the method, a pair switched off, the camera; then save the session.
    {
        let ready = harness.state_mut().ready_mut().expect("loaded");
        ready.document.settings.method = warpbench_app::settings::MethodKind::Rigid;
        ready.document.settings.oblique[1] =
            warpbench_app::project::document::Oblique { on: true, tilt_deg: 20.0, spin_deg: -10.0 };
        ready.document.pairs[1].active = false;
        ready.view.camera.azimuth_rad = 1.0;
        ready.refit();
    }
    let saved = harness.state().ready().expect("loaded").to_session(true);
    let session_path = dir.path().join("project.warpbench.json");
    warpbench_app::project::session::save(&session_path, &saved).expect("save");
    // The window autosaves, then "crashes" (no clean exit).
    harness.state_mut().autosave_now(false);
    drop(harness);

    // Reopening the project restores it.
    let opts = GuiOptions {
        session: Some(session_path),
        autosave: Some(dir.path().join("other-autosave.json")),
        ..GuiOptions::default()
    };
    let mut harness = workbench(opts, egui::vec2(900.0, 640.0));
    wait_until_shown(&mut harness);
    let ready = harness.state().ready().expect("loaded");
    assert_eq!(ready.to_session(true), saved, "the reopened session is the saved one");
    assert_eq!(ready.fitted_pairs(), 4);
    drop(harness);

    // A new window on the crashed autosave offers recovery, and recovering brings the pairs back.
    let opts = GuiOptions { autosave: Some(autosave), ..GuiOptions::default() };
    let mut harness = workbench(opts, egui::vec2(900.0, 640.0));
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
        let (fitted, _) = warpbench_app::gui::fit_warp(
            &ready.document.settings.method(),
            &fixed,
            &moving,
            boxes,
            n,
            true,
            &warpbench_app::project::stack::Layers::default(),
        )
        .expect("fit");
        let (_, texture) = warpbench_app::scene::control_texture(&fitted.pullback, boxes.0, n).expect("sample");
        let cpu: Vec<[f32; 4]> = texture.as_f32s().chunks_exact(4).map(|c| [c[0], c[1], c[2], c[3]]).collect();
        // The GPU's: evaluated into the window's control texture.
        ready.view.control_eval = warpbench_app::gui::ControlEval::Gpu;
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

/// The unit roundoff of f32.
const F32_UNIT_ROUNDOFF: f64 = f32::EPSILON as f64 / 2.0;
/// Relative error of one of the shader's terms wᵢ ‖x − pᵢ‖ in units of the f32 roundoff, to first order: the weight
/// rounded to f32 (1), the differences x − pᵢ (1), the squares summed (3, so 1.5 on the root), the square root (4.5
/// ULP = 9: Vulkan inherits sqrt's precision from 1/inverseSqrt, 2 ULP, and a division, 2.5 ULP; lavapipe is exact),
/// the product (1).
const TERM_ROUNDINGS: f64 = 1.0 + 1.0 + 1.5 + 9.0 + 1.0;
/// The same for the affine part (A − I) x′ + (A o + b − o): inputs rounded to f32 (1), three products and three sums.
const AFFINE_ROUNDINGS: f64 = 1.0 + 4.0;
/// The drag's warps against the full refit's in f64 (the bound `crates/solver/tests/tps_drag.rs` holds them to).
const WARP_TOL_MM: f64 = 1e-6;

/// A first-order bound, per component, on the error of the GPU's f32 evaluation of the TPS pull-back `tps`'s
/// displacement at the texel centre `x` (`cs_tps` in shaders/control_eval.wgsl, about the grid's centre `origin`):
/// the affine part, then the N terms added in order, so with x′ = x − o, pᵢ′ = pᵢ − o and the partial sums Sₖ,
///
/// |d̂ − d| ≤ u (5 (|A − I| |x′| + |A o + b − o|) + Σᵢ |wᵢ| (14.5 ‖x′ − pᵢ′‖ + ‖pᵢ′‖) + Σₖ |Sₖ|),
///
/// the ‖pᵢ′‖ from the centres rounded to f32 and Σₖ |Sₖ| from rounding each sum.
fn f32_evaluation_bound(tps: &Tps<Moving, Fixed>, origin: [f64; 3], x: [f64; 3]) -> [f64; 3] {
    let (a, b, w) = (tps.linear(), tps.translation(), tps.weights());
    let centres: Vec<[f64; 3]> =
        tps.centres().iter().map(|p| std::array::from_fn(|k| p.coords()[k] - origin[k])).collect();
    let x_local: [f64; 3] = std::array::from_fn(|k| x[k] - origin[k]);
    std::array::from_fn(|r| {
        let offset = (0..3).map(|c| a[(r, c)] * origin[c]).sum::<f64>() + b[r] - origin[r];
        let lin = |c: usize| a[(r, c)] - if r == c { 1.0 } else { 0.0 };
        let mut sum = (0..3).map(|c| lin(c) * x_local[c]).sum::<f64>() + offset;
        let mut bound = AFFINE_ROUNDINGS * ((0..3).map(|c| (lin(c) * x_local[c]).abs()).sum::<f64>() + offset.abs());
        for (p, w) in centres.iter().zip(&w) {
            let dist = (0..3).map(|k| (x_local[k] - p[k]).powi(2)).sum::<f64>().sqrt();
            let norm = (0..3).map(|k| p[k] * p[k]).sum::<f64>().sqrt();
            sum += w[r] * dist;
            bound += w[r].abs() * (TERM_ROUNDINGS * dist + norm) + sum.abs();
        }
        F32_UNIT_ROUNDOFF * bound
    })
}

/// Half the spacing of the values the texture stores around `v`, mm: its rounding error at most (f16 where the
/// device cannot filter f32 textures, as lavapipe; 0 for f32, whose rounding [`f32_evaluation_bound`] counts).
fn storage_rounding(v: f32, half_floats: bool) -> f64 {
    if !half_floats {
        return 0.0;
    }
    // f16 keeps 10 bits after the leading one; below 2⁻¹⁴ its spacing is 2⁻²⁴.
    let exponent = f64::from(v.abs()).log2().floor().max(-14.0);
    0.5 * 2f64.powf(exponent - 10.0)
}

/// The window's TPS pull-back, its control texture read back, and whether the texture stores f16.
fn shown_pullback(ready: &Ready) -> (Tps<Moving, Fixed>, Vec<[f32; 4]>, bool) {
    let fitted = ready.fitted().expect("a fit");
    let Some(FittedWarp::Tps(tps)) = fitted.pullback.as_fitted() else { panic!("a TPS") };
    let control = ready.viewer.control.as_ref().expect("a control texture");
    assert!(ready.viewer.control_made_on_gpu(), "the texture was evaluated on the GPU");
    let texels = warpbench_gpu::control_eval::read_back_texels(&ready.viewer.ctx, control).expect("read back");
    let half_floats = control.texture.format() == eframe::wgpu::TextureFormat::Rgba16Float;
    (tps.clone(), texels, half_floats)
}

/// A drag on the real-GPU route (issue 28): every event updates both warps' coefficients in O(N²) and the GPU
/// evaluates the pull-back into the control texture (no refit, no CPU texture); after a sequence of events that
/// texture equals the one the release's full refit evaluates, within the f32 evaluation bound of both
/// ([`f32_evaluation_bound`]), and the moving glyphs stand where the refit's forward warp puts them. The second drag
/// is on a starting transform.
#[test]
fn a_drag_on_the_gpu_evaluates_the_updated_coefficients_as_a_full_refit_would() {
    if no_adapter() {
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let mut harness = open_mri_pair(dir.path(), egui::vec2(900.0, 640.0));
    let ready = harness.state_mut().ready_mut().expect("loaded");
    // 40 pairs in the central 60 % of the fixed box, the moving points a smooth ~6 mm displacement of them.
    let fixed_box = warpbench_app::inputs::volume_box::<Fixed>(&ready.loaded.fixed);
    let (lo, hi) = (fixed_box.min.coords(), fixed_box.max.coords());
    let unit = |i: usize, axis: usize| {
        let x =
            (i as u64 + 1).wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ (axis as u64 + 1).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        ((x ^ (x >> 29)).wrapping_mul(0x94D0_49BB_1331_11EB) >> 11) as f64 / (1u64 << 53) as f64
    };
    ready.document.pairs = (0..40)
        .map(|i| {
            let q: [f64; 3] = std::array::from_fn(|a| lo[a] + (0.2 + 0.6 * unit(i, a)) * (hi[a] - lo[a]));
            let p = [q[0] + 6.0 * (q[1] / 30.0).sin(), q[1] + 4.0 * (q[2] / 25.0).cos(), q[2] - 3.0];
            LandmarkPair::new(format!("P{i}"), Point3::from_array(p), Point3::from_array(q))
        })
        .collect();
    ready.document.settings.method = warpbench_app::settings::MethodKind::Tps;
    ready.view.control_eval = warpbench_app::gui::ControlEval::Gpu;
    ready.refit();
    assert!(ready.fit.error.is_none(), "{:?}", ready.fit.error);
    let grid = warpbench_app::scene::control_grid(fixed_box, ready.document.settings.grid_n).expect("grid");
    let (gmin, gmax) = (grid.domain.min.coords(), grid.domain.max.coords());
    let origin: [f64; 3] = std::array::from_fn(|k| 0.5 * (gmin[k] + gmax[k]));
    let centres: Vec<[f64; 3]> = (0..grid.texel_count())
        .map(|i| {
            grid.texel_centre([i % grid.dims[0], (i / grid.dims[0]) % grid.dims[1], i / (grid.dims[0] * grid.dims[1])])
        })
        .collect();

    for (pair, end) in [(5, End::Fixed), (17, End::Moving)] {
        let ready = harness.state_mut().ready_mut().expect("loaded");
        if end == End::Moving {
            // On a starting transform (an affine one, as Auto-align's or a read one), which a TPS makes vanish from
            // the warp: the drag keeps its O(N²) path, and the release's refit on the start gives the same warp.
            let linear = nalgebra::Matrix3::new(1.04, 0.03, -0.02, -0.01, 0.97, 0.05, 0.02, -0.04, 1.01);
            let start = StartingTransform::new(linear, [2.0, -1.5, 3.0], "Auto-align (affine)".into());
            ready.document.start = Some(start);
            ready.refit();
            assert!(ready.fit.error.is_none(), "{:?}", ready.fit.error);
        }
        let (_, before, _) = shown_pullback(ready);
        let start = match end {
            End::Fixed => ready.document.pairs[pair].fixed,
            End::Moving => ready.document.pairs[pair].moving,
        }
        .expect("placed")
        .coords();
        let mut to = start;
        for step in [[0.5, 0.0, 0.0], [2.0, -1.0, 0.5], [4.0, -3.0, 2.0], [6.5, -2.0, 3.0]] {
            to = std::array::from_fn(|k| start[k] + step[k]);
            ready.apply(Command::MovePoint { pair, end, to: Point3::from_array(to), settled: false });
            assert!(ready.fit.error.is_none(), "{end:?}: {:?}", ready.fit.error);
            assert_eq!(ready.drag_route(), Some(ControlRoute::Gpu), "{end:?}: the drag's O(N²) path, on the GPU");
        }
        let (fast, during, f16_fast) = shown_pullback(ready);
        let glyphs_during: Vec<[f64; 3]> = (0..40).map(|i| ready.glyph_ref(i, End::Moving).expect("placed")).collect();
        // The release refits in full and evaluates that on the GPU.
        ready.apply(Command::MovePoint { pair, end, to: Point3::from_array(to), settled: true });
        assert!(ready.fit_if_pending(), "the release refits");
        assert_eq!(ready.drag_route(), None, "the release ends the drag");
        let (full, after, f16_full) = shown_pullback(ready);
        for (i, glyph) in glyphs_during.iter().enumerate() {
            let refit = ready.glyph_ref(i, End::Moving).expect("placed");
            assert!(
                (0..3).all(|k| (glyph[k] - refit[k]).abs() <= WARP_TOL_MM),
                "{end:?}: glyph {i} at {glyph:?}, refit {refit:?}"
            );
        }
        let (mut worst, mut moved, mut largest_f32_bound) = (0.0f64, 0.0f64, 0.0f64);
        for (t, x) in centres.iter().enumerate() {
            let (e_fast, e_full) = (f32_evaluation_bound(&fast, origin, *x), f32_evaluation_bound(&full, origin, *x));
            let (u_fast, u_full) = (fast.apply_raw(*x), full.apply_raw(*x));
            for k in 0..3 {
                assert!((u_fast[k] - u_full[k]).abs() <= WARP_TOL_MM, "{end:?}: the warps differ at {x:?}");
                // Both evaluated in f32 at the same texel centre, then stored (rounded to f16 on lavapipe).
                let stored = storage_rounding(during[t][k], f16_fast) + storage_rounding(after[t][k], f16_full);
                let tolerance = e_fast[k] + e_full[k] + WARP_TOL_MM + stored;
                let diff = (f64::from(during[t][k]) - f64::from(after[t][k])).abs();
                worst = worst.max(diff / tolerance);
                largest_f32_bound = largest_f32_bound.max(e_fast[k] + e_full[k]);
                moved = moved.max((f64::from(before[t][k]) - f64::from(after[t][k])).abs());
            }
        }
        eprintln!(
            "{end:?} drag: texel difference at most {worst:.2e} of its tolerance (f32 evaluation bound at most \
             {largest_f32_bound:.2e} mm, f16 storage: {f16_full}); the drag moved texels by up to {moved:.3} mm"
        );
        assert!(worst <= 1.0, "{end:?}: the drag's texture differs from the refit's by {worst} times the f32 bound");
        assert!(moved > 0.5, "{end:?}: the drag changed the warp ({moved} mm)");
    }
}

#[test]
fn undo_of_every_command_gives_the_document_back_and_view_commands_leave_it() {
    use warpbench_app::gui::Command;
    use warpbench_app::gui::files::FileAction;
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
        Command::MovePoint {
            pair: 0,
            end: warpbench_app::gui::End::Fixed,
            to: Point3::from_array([1.0, 2.0, 3.0]),
            settled: true,
        },
        Command::MovePoint {
            pair: 1,
            end: warpbench_app::gui::End::Moving,
            to: Point3::from_array([4.0, 5.0, 6.0]),
            settled: false,
        },
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
            &ready.view.camera,
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
    let mut harness = workbench(opts, egui::vec2(1100.0, 900.0));
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
    let c = ready.pointer.cursor.expect("the pointer is over the slice");
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
    harness.get_by_label_contains(&label);

    // In the 3-D view: once the pointer rests, the point picked under it is read out, and it lies under the pointer.
    let view = harness.get_by_label("3-D view").rect();
    let pos = view.center() + egui::vec2(0.05 * view.width(), 0.03 * view.height());
    harness.input_mut().events.push(egui::Event::PointerMoved(pos));
    harness.run_steps(2);
    std::thread::sleep(warpbench_app::gui::hover::REST + Duration::from_millis(50));
    harness.run_steps(3);
    let ready = harness.state().ready().expect("loaded");
    let c = ready.pointer.cursor.expect("the pointer rests over the head in the 3-D view");
    let x = warpbench_gpu::glam::Vec3::from_array(c.fixed_lps.map(|v| v as f32));
    let clip = ready.view.camera.clip_from_ref(view.width() / view.height()) * x.extend(1.0);
    let on_screen = view.min
        + egui::vec2((clip.x / clip.w * 0.5 + 0.5) * view.width(), (0.5 - clip.y / clip.w * 0.5) * view.height());
    assert!((on_screen - pos).length() < 3.0, "picked {:?} shows at {on_screen:?}, pointer at {pos:?}", c.fixed_lps);
    assert!(c.det_jacobian.is_some_and(f64::is_finite));
    let name = c.nearest.map_or(String::new(), |n| ready.document.pairs[n.index].name.clone());
    harness.get_by_label_contains(&c.readout(&name));
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
    let mut harness = workbench(opts, egui::vec2(1100.0, 900.0));
    wait_until_shown(&mut harness);
    window::open_section(&mut harness, "Assist");
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
    let saved = warpbench_app::project::session::load(&autosave).expect("the autosave");
    assert_eq!(saved.document.start.as_ref(), Some(&found));
    let got = common::map_through_session(dir.path(), [&mri(), &moved, &autosave], [10.0, -20.0, 15.0]);
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

/// A starting transform from a file, as `--initial` takes it: an elastix parameter file (an affine chained over a
/// rigid, as elastix writes them) typed into Assist becomes the document's starting transform, which with no pairs is
/// the warp shown, equal to the file's map; it is one undo step, in the autosave, and the command line's `--session`
/// maps as the window does. A file that holds no linear transform is refused in the panel, and the document keeps
/// none.
#[test]
fn a_starting_transform_from_a_file_sits_under_the_landmarks() {
    if no_adapter() {
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let autosave = dir.path().join("autosave.warpbench.json");
    let opts = GuiOptions {
        fixed: Some(mri()),
        moving: Some(mri()),
        autosave: Some(autosave.clone()),
        ..GuiOptions::default()
    };
    let mut harness = workbench(opts, egui::vec2(1100.0, 900.0));
    wait_until_shown(&mut harness);
    window::open_section(&mut harness, "Assist");
    harness.get_by_label("Starting transform from a file").click();
    harness.run_steps(2);
    let not_a_transform = dir.path().join("start.txt");
    std::fs::write(&not_a_transform, "no transform here").expect("write");
    let elastix = common::data("elastix/affine.txt");
    for path in [&not_a_transform, &elastix] {
        harness.state_mut().ready_mut().expect("ready").files.fields.start.clear();
        harness.get_by_label("Starting transform file").scroll_to_me();
        harness.run_steps(2);
        harness.get_by_label("Starting transform file").focus();
        harness.run_steps(2);
        harness.get_by_label("Starting transform file").type_text(&path.display().to_string());
        harness.run_steps(2);
        harness.get_by_label("Use as starting transform").click();
        harness.run_steps(3);
        let ready = harness.state().ready().expect("ready");
        let message = ready.files.message.clone().unwrap_or_default();
        if path == &not_a_transform {
            assert!(
                message.contains("not used as the starting transform") && message.contains("start.txt"),
                "{message}"
            );
            assert!(ready.document.start.is_none());
        } else {
            assert!(message.contains("is the starting transform"), "{message}");
        }
    }
    wait_until_rendered(&mut harness);
    harness.get_by_label_contains("Starting transform: affine.txt");
    let ready = harness.state().ready().expect("loaded");
    let found = ready.document.start.clone().expect("a starting transform");
    let affine = warpbench_io::elastix::read_affine(&elastix).expect("the file");
    // With no pairs the warp is the starting transform: the moving point shown at x is the file's map of x.
    for x in [[10.0, -20.0, 15.0], [-60.0, 40.0, -30.0], [0.0, 0.0, 0.0]] {
        let (shown, want) = (ready.moving_shown_at(x), affine.apply(x));
        assert!((0..3).all(|a| (shown[a] - want[a]).abs() < 1e-9), "shown {shown:?}, the file {want:?}");
    }
    let saved = warpbench_app::project::session::load(&autosave).expect("the autosave");
    assert_eq!(saved.document.start.as_ref(), Some(&found));
    let got = common::map_through_session(dir.path(), [&mri(), &mri(), &autosave], [10.0, -20.0, 15.0]);
    let want = ready.moving_shown_at([10.0, -20.0, 15.0]);
    assert!((0..3).all(|a| (got[a] - want[a]).abs() < 1e-6), "{got:?} vs {want:?}");
    harness.get_by_label("Undo").click();
    harness.run_steps(2);
    assert!(harness.state().ready().expect("loaded").document.start.is_none());
    harness.get_by_label("Redo").click();
    harness.run_steps(2);
    assert_eq!(harness.state().ready().expect("loaded").document.start.as_ref(), Some(&found));

    // FSL's FLIRT matrix is in the voxels of the two images: the window reads it against the open volumes, and keeps
    // the transform it is on them (the session holds no grids to read it against again).
    let flirt = common::data("fsl/oblique_from_las.mat");
    harness.state_mut().ready_mut().expect("ready").files.fields.start.clear();
    harness.get_by_label("Starting transform file").focus();
    harness.run_steps(2);
    harness.get_by_label("Starting transform file").type_text(&flirt.display().to_string());
    harness.run_steps(2);
    harness.get_by_label("Use as starting transform").click();
    harness.run_steps(3);
    let ready = harness.state().ready().expect("ready");
    let message = ready.files.message.clone().unwrap_or_default();
    assert!(message.contains("oblique_from_las.mat is the starting transform"), "{message}");
    let (fixed, moving) = (&ready.loaded.fixed, &ready.loaded.moving);
    let matrix = warpbench_io::fsl::read(&flirt).expect("the matrix");
    let u = warpbench_io::fsl::moving_from_fixed(
        &flirt,
        &matrix,
        (fixed.dims, &fixed.lps_from_index),
        (moving.dims, &moving.lps_from_index),
    )
    .expect("the pull-back");
    for x in [[10.0, -20.0, 15.0], [-60.0, 40.0, -30.0], [0.0, 0.0, 0.0]] {
        let want = u * nalgebra::Vector4::new(x[0], x[1], x[2], 1.0);
        let shown = ready.moving_shown_at(x);
        assert!((0..3).all(|a| (shown[a] - want[a]).abs() < 1e-9), "shown {shown:?}, the FLIRT matrix {want:?}");
    }
    // File > Export for FSL writes it back: the same matrix, to the twelve decimals written (and doubles' rounding
    // through the volumes' matrices, at translations of tens of mm).
    let out = dir.path().join("back.mat");
    let export = warpbench_app::gui::files::FileAction::ExportTransform(
        warpbench_app::transform::TransformFormat::Fsl,
        out.clone(),
    );
    harness.state_mut().ready_mut().expect("ready").apply(Command::File(export));
    let message = window::wait_for_export(&mut harness);
    assert!(message.contains("back.mat"), "{message}");
    let back = warpbench_io::fsl::read(&out).unwrap_or_else(|e| panic!("{e}: {message}"));
    assert!((back - matrix).abs().max() < 1e-10, "{back} written, {matrix} read");
    // File > Export for FreeSurfer: an LTA with the two open volumes as its dst (fixed) and src (moving), which reads
    // back to the same pull-back (sixteen significant digits); and, read as the starting transform, is shown so.
    let lta_out = dir.path().join("back.lta");
    let export = warpbench_app::gui::files::FileAction::ExportTransform(
        warpbench_app::transform::TransformFormat::Lta,
        lta_out.clone(),
    );
    harness.state_mut().ready_mut().expect("ready").apply(Command::File(export));
    let message = window::wait_for_export(&mut harness);
    assert!(message.contains("back.lta") && message.contains("as LTA"), "{message}");
    let ready = harness.state().ready().expect("ready");
    let (fixed, moving) = (&ready.loaded.fixed, &ready.loaded.moving);
    let lta = warpbench_io::lta::read(&lta_out).unwrap_or_else(|e| panic!("{e}: {message}"));
    let grids = ((fixed.dims, &fixed.lps_from_index), (moving.dims, &moving.lps_from_index));
    let from_lta = warpbench_io::lta::moving_from_fixed(&lta_out, &lta, grids.0, grids.1).expect("the pull-back");
    assert!((from_lta - u).abs().max() < 1e-9, "{from_lta} written, {u} shown");
    // File > Export for MINC: an MNI transform file, the moving volume's world to the fixed one's, which reads back as
    // the same pull-back.
    let xfm_out = dir.path().join("back.xfm");
    let export = warpbench_app::gui::files::FileAction::ExportTransform(
        warpbench_app::transform::TransformFormat::Minc,
        xfm_out.clone(),
    );
    harness.state_mut().ready_mut().expect("ready").apply(Command::File(export));
    let message = window::wait_for_export(&mut harness);
    assert!(message.contains("back.xfm") && message.contains("MNI transform"), "{message}");
    let from_xfm = warpbench_io::mni_xfm::read_affine(&xfm_out).unwrap_or_else(|e| panic!("{e}: {message}"));
    for x in [[10.0, -20.0, 15.0], [-60.0, 40.0, -30.0]] {
        let want = u * nalgebra::Vector4::new(x[0], x[1], x[2], 1.0);
        let got = from_xfm.apply(x);
        assert!((0..3).all(|a| (got[a] - want[a]).abs() < 1e-9), "{got:?} from the .xfm, {want:?} shown");
    }
}

/// A displacement field under the landmarks (issue 29, item 2, as BigWarp's transform sequences): "Use field under
/// landmarks" puts it in the document, the landmarks refine on top of it (the window's pull-back is the stack written
/// out here: the field after a TPS fitted on the fixed points and the moving points taken back through the field), a
/// session saved with it opens with it, and undo takes it away; a file that is not a field is refused in the panel
/// and the document keeps none.
#[test]
fn a_displacement_field_sits_under_the_landmarks_saves_and_undoes() {
    use warpbench_app::gui::files::FileAction;
    use warpbench_app::project::field_file::{FieldFile, VoxelGrid, VoxelGrids};
    use warpbench_app::project::stack::FieldLayer;
    use warpbench_app::transform::TransformFormat;
    use warpbench_io::displacement::{FieldFormat, write_field};
    use warpbench_io::geometry::{Index, Lps, Transform};
    use warpbench_io::learn2reg::{VoxelField, write_voxel_field};
    if no_adapter() {
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let mut harness = open_mri_pair(dir.path(), egui::vec2(800.0, 600.0));
    wait_until_rendered(&mut harness);
    let ready = harness.state().ready().expect("ready");
    let fixed_box = warpbench_app::inputs::volume_box::<Fixed>(&ready.loaded.fixed);
    let (lo, hi) = (fixed_box.min.coords(), fixed_box.max.coords());
    // A smooth field of up to 2 mm on a 12³ grid over the fixed box, written as ITK writes one.
    let dims = [12usize; 3];
    let step: [f64; 3] = std::array::from_fn(|a| (hi[a] - lo[a]) / 11.0);
    let grid = Transform::<Lps, Index>::from_linear_translation(
        nalgebra::Matrix3::from_diagonal(&nalgebra::Vector3::new(step[0], step[1], step[2])),
        lo,
    );
    let mut vectors = Vec::new();
    for k in 0..12 {
        for j in 0..12 {
            for i in 0..12 {
                let x = [lo[0] + step[0] * i as f64, lo[1] + step[1] * j as f64, lo[2] + step[2] * k as f64];
                vectors.push([
                    (2.0 * (x[1] / 30.0).sin()) as f32,
                    (-1.5 * (x[2] / 25.0).cos()) as f32,
                    (1.0 * (x[0] / 20.0).sin()) as f32,
                ]);
            }
        }
    }
    let field_path = dir.path().join("field.nii.gz");
    write_field(&field_path, FieldFormat::Itk, dims, &grid, &vectors).expect("field written");

    let apply = |harness: &mut Harness<'_, Workbench>, command: Command| {
        harness.state_mut().ready_mut().expect("ready").apply(command);
        harness.run_steps(3);
        wait_until_rendered(harness);
    };
    // Not a field: refused, said, nothing kept.
    apply(&mut harness, Command::File(FileAction::UseField(dir.path().join("pairs.csv"))));
    let ready = harness.state().ready().expect("ready");
    assert!(ready.document.field.is_none());
    let message = ready.files.message.clone().unwrap_or_default();
    assert!(message.contains("pairs.csv"), "the refusal names the file: {message}");
    let plain_at = |ready: &Ready, x: [f64; 3]| ready.fitted().expect("a fit").pullback.apply_raw(x);
    let probes = [[0.0, 10.0, 20.0], [30.0, -20.0, 10.0], [-25.0, 40.0, -5.0]];
    let before: Vec<[f64; 3]> = probes.iter().map(|&x| plain_at(ready, x)).collect();

    apply(&mut harness, Command::File(FileAction::UseField(field_path.clone())));
    let ready = harness.state().ready().expect("ready");
    assert_eq!(ready.document.field_path(), Some(field_path.as_path()));
    assert!(ready.fit.error.is_none(), "{:?}", ready.fit.error);
    // The stack written out: u = F ∘ r, r fitted on qᵢ → F⁻¹(pᵢ).
    let layer = FieldLayer::read(&field_path).expect("read");
    let (_, (fixed, moving)) = ready.fit_pairs();
    let unbased: Vec<Point3<Fixed>> =
        moving.iter().map(|p| Point3::from_array(layer.fixed_from_moving_raw(p.coords()))).collect();
    let method = ready.document.settings.method();
    let r: FittedWarp<Fixed, Fixed> = method.fit(&fixed, &unbased, fixed_box).expect("r");
    for &x in &probes {
        let want = layer.moving_from_fixed_raw(r.as_ref().apply_raw(x));
        let got = plain_at(ready, x);
        assert!((0..3).all(|a| (got[a] - want[a]).abs() < 1e-9), "u({x:?}) = {got:?}, written out {want:?}");
    }
    for (q, p) in fixed.iter().zip(&moving) {
        let u = plain_at(ready, q.coords());
        assert!(u.iter().zip(p.coords()).all(|(a, b)| (a - b).abs() < 1e-5), "u({q:?}) = {u:?}, not {p:?}");
    }

    // Export for elastix: no transform file holds the field exactly, so it is a DeformationFieldTransform over the
    // pull-back sampled on the fixed grid, the field beside it. Read back, it is u at the grid's voxel centres.
    let elastix_out = dir.path().join("with_field.txt");
    let export = Command::File(FileAction::ExportTransform(TransformFormat::Elastix, elastix_out.clone()));
    harness.state_mut().ready_mut().expect("ready").apply(export);
    let message = window::wait_for_export(&mut harness);
    let ready = harness.state().ready().expect("ready");
    assert!(
        message.contains("as DeformationFieldTransform over") && message.contains("with_field.field.mha"),
        "{message}"
    );
    let chain = warpbench_io::elastix::read_transform(&elastix_out).unwrap_or_else(|e| panic!("{e}"));
    let grid = chain.grid.as_ref().expect("the fixed grid").lps_from_index;
    for ijk in [[45.0, 54.0, 45.0], [20.0, 70.0, 30.0], [0.0, 0.0, 0.0]] {
        let x = grid.apply_point(Point3::new(ijk[0], ijk[1], ijk[2])).coords();
        let (got, want) = (chain.apply(x), plain_at(ready, x));
        assert!((0..3).all(|a| (got[a] - want[a]).abs() < 1e-5), "at {x:?}: the file maps to {got:?}, u = {want:?}");
    }
    // Export transform to an .h5: ITK's composite of the field itself and the TPS over it sampled on the fixed grid
    // (ITK's own readers take no TPS), so at the grid's voxel centres it is u; to a .tfm it is refused, the message
    // saying what to do.
    let tfm_out = dir.path().join("with_field.tfm");
    let export = Command::File(FileAction::ExportTransform(TransformFormat::Itk, tfm_out.clone()));
    harness.state_mut().ready_mut().expect("ready").apply(export);
    let message = window::wait_for_export(&mut harness);
    assert!(message.contains(".h5") && !tfm_out.exists(), "{message}");
    // FSL's FLIRT matrix holds an affine only: refused, saying so, and nothing written.
    let flirt_out = dir.path().join("with_field.mat");
    let export = Command::File(FileAction::ExportTransform(TransformFormat::Fsl, flirt_out.clone()));
    harness.state_mut().ready_mut().expect("ready").apply(export);
    let refused = window::wait_for_export(&mut harness);
    assert!(refused.contains("holds an affine only") && !flirt_out.exists(), "{refused}");
    let h5_out = dir.path().join("with_field.h5");
    let export = Command::File(FileAction::ExportTransform(TransformFormat::Itk, h5_out.clone()));
    harness.state_mut().ready_mut().expect("ready").apply(export);
    let message = window::wait_for_export(&mut harness);
    let ready = harness.state().ready().expect("ready");
    let members = "DisplacementFieldTransform_float_3_3, DisplacementFieldTransform_float_3_3, the last on the fixed";
    assert!(message.contains(&format!("as CompositeTransform_double_3_3 of {members} grid")), "{message}");
    let h5 = warpbench_io::itk_h5::read(&h5_out).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(h5.steps.len(), 2, "the field, then the TPS sampled");
    for ijk in [[45.0, 54.0, 45.0], [20.0, 70.0, 30.0], [0.0, 0.0, 0.0]] {
        let x = grid.apply_point(Point3::new(ijk[0], ijk[1], ijk[2])).coords();
        let (got, want) = (h5.apply(x), plain_at(ready, x));
        assert!((0..3).all(|a| (got[a] - want[a]).abs() < 1e-5), "at {x:?}: the .h5 maps to {got:?}, u = {want:?}");
    }

    let session = dir.path().join("with_field.warpbench.json");
    apply(&mut harness, Command::File(FileAction::SaveSession(session.clone())));
    let saved = warpbench_app::project::session::load(&session).expect("saved");
    assert_eq!(saved.document.field_path(), Some(field_path.as_path()), "the session keeps the field");

    harness.get_by_label("Undo").click();
    harness.run_steps(3);
    wait_until_rendered(&mut harness);
    let ready = harness.state().ready().expect("ready");
    assert!(ready.document.field.is_none(), "undo takes the field away");
    for (x, was) in probes.iter().zip(&before) {
        let now = plain_at(ready, *x);
        assert!((0..3).all(|a| (now[a] - was[a]).abs() < 1e-9), "u({x:?}) back to the landmarks alone");
    }

    // An elastix transform parameter file is a field too: its chain sampled on its fixed grid, as transformix writes
    // it. Here a B-spline over the MRI's grid, as `transform --format elastix` writes one.
    let elastix_file = dir.path().join("TransformParameters.0.txt");
    let pairs_file = common::data("itk/field_pairs.csv");
    common::assert_ok(&common::warpbench(&[
        "transform",
        "--fixed",
        common::utf8(&mri()),
        "--moving",
        common::utf8(&mri()),
        "--landmarks",
        common::utf8(&pairs_file),
        "--method",
        "hbspline",
        "--format",
        "elastix",
        "--quiet",
        "--out",
        common::utf8(&elastix_file),
    ]));
    apply(&mut harness, Command::File(FileAction::UseField(elastix_file.clone())));
    let ready = harness.state().ready().expect("ready");
    assert_eq!(ready.document.field_path(), Some(elastix_file.as_path()));
    assert!(ready.fit.error.is_none(), "{:?}", ready.fit.error);
    let layer = FieldLayer::read(&elastix_file).expect("read");
    let chain = warpbench_io::elastix::read_transform(&elastix_file).expect("the transform");
    let grid = chain.grid.as_ref().expect("its grid").lps_from_index;
    // At voxel centres the field is the transform, to f32's rounding of millimetres.
    for ijk in [[45.0, 54.0, 45.0], [20.0, 70.0, 30.0], [60.0, 30.0, 60.0]] {
        let x = grid.apply_point(Point3::new(ijk[0], ijk[1], ijk[2])).coords();
        let (got, want) = (layer.moving_from_fixed_raw(x), chain.apply(x));
        assert!((0..3).all(|a| (got[a] - want[a]).abs() < 1e-5), "at {x:?}: {got:?}, elastix {want:?}");
        assert!((0..3).any(|a| (want[a] - x[a]).abs() > 0.1), "the transform moves {x:?}");
    }

    // An ITK text transform file of an affine and a B-spline (SimpleITK's composite) has no grid: the layer is the
    // transform itself, at any point, inside the fixed box or not; the autosave maps a point as the window shows it.
    let loaded = &harness.state().ready().expect("ready").loaded;
    let grids = VoxelGrids { fixed: VoxelGrid::of(&loaded.fixed), moving: VoxelGrid::of(&loaded.moving) };
    let (dims, fixed_lps_from_index) = (loaded.fixed.dims, loaded.fixed.lps_from_index);
    let tfm = common::data("itk/tfm_composite.tfm");
    apply(&mut harness, Command::File(FileAction::UseField(tfm.clone())));
    let ready = harness.state().ready().expect("ready");
    assert!(ready.fit.error.is_none(), "{:?}", ready.fit.error);
    assert_eq!(ready.document.field, Some(FieldFile::new(tfm.clone())));
    let chain = warpbench_io::transform_file::read_chain(&tfm).expect("the chain");
    let layer = ready.document.field.as_ref().expect("the field").layer().expect("read");
    let autosave = dir.path().join("autosave.warpbench.json");
    // The last point lies outside the fixed volume, where only the affine acts (a sampled field would be 0 there).
    for (n, x) in
        [[0.5, -3.25, 7.0], [-12.0, 15.0, -4.0], [10.0, 2.0, 3.0], [140.0, -190.0, 120.0]].into_iter().enumerate()
    {
        let (got, want) = (layer.moving_from_fixed_raw(x), chain.apply(x));
        assert!((0..3).all(|a| (got[a] - want[a]).abs() < 1e-12), "at {x:?}: {got:?}, ITK's {want:?}");
        let back = layer.fixed_from_moving_raw(got);
        assert!((0..3).all(|a| (back[a] - x[a]).abs() < 1e-5), "F⁻¹(F({x:?})) = {back:?}");
        if n < 3 {
            let (shown, saved) =
                (plain_at(ready, x), common::map_through_session(dir.path(), [&mri(), &mri(), &autosave], x));
            assert!((0..3).all(|a| (saved[a] - shown[a]).abs() < 1e-6), "{saved:?} vs the window's {shown:?}");
        }
    }
    let (_, (fixed, moving)) = ready.fit_pairs();
    for (q, p) in fixed.iter().zip(&moving) {
        let u = plain_at(ready, q.coords());
        assert!(u.iter().zip(p.coords()).all(|(a, b)| (a - b).abs() < 1e-5), "u({q:?}) = {u:?}, not {p:?}");
    }

    // A Learn2Reg field (.npz) is in the voxels of the pair open when it is chosen, whose grids the document keeps with
    // it; the autosave then maps a point as the window shows it. One of another shape is refused, naming it.
    let steps_vox = (0..dims.iter().product::<usize>())
        .map(|n| [1.5 * (((n / dims[0]) % dims[1]) as f32 / 9.0).sin(), 0.5, -1.0])
        .collect();
    let npz = dir.path().join("disp.npz");
    write_voxel_field(&npz, &VoxelField { dims, steps_vox }).expect("npz written");
    let wrong = dir.path().join("wrong.npz");
    write_voxel_field(&wrong, &VoxelField { dims: [4; 3], steps_vox: vec![[0.0; 3]; 64] }).expect("npz written");
    apply(&mut harness, Command::File(FileAction::UseField(wrong)));
    let ready = harness.state().ready().expect("ready");
    let message = ready.files.message.clone().unwrap_or_default();
    assert!(message.contains("wrong.npz") && message.contains("shape"), "{message}");
    assert_eq!(ready.document.field_path(), Some(tfm.as_path()), "the refused field is not kept");
    apply(&mut harness, Command::File(FileAction::UseField(npz.clone())));
    let ready = harness.state().ready().expect("ready");
    assert_eq!(ready.document.field, Some(FieldFile { path: npz.clone(), voxel_grids: Some(Box::new(grids)) }));
    assert!(ready.files.message.as_deref().is_some_and(|m| m.contains("Learn2Reg")), "{:?}", ready.files.message);
    assert!(ready.fit.error.is_none(), "{:?}", ready.fit.error);
    let probes = [[10.0, -20.0, 15.0], [-30.0, 25.0, -5.0]];
    let through_npz: Vec<[f64; 3]> = probes.iter().map(|&x| plain_at(ready, x)).collect();
    for (&x, want) in probes.iter().zip(&through_npz) {
        let got = common::map_through_session(dir.path(), [&mri(), &mri(), &autosave], x);
        assert!((0..3).all(|a| (got[a] - want[a]).abs() < 1e-6), "{got:?} vs the window's {want:?}");
    }

    // The NIfTI form (an (X, Y, Z, 3) array of the same steps) says nothing of its units: typed in the panel it is
    // refused as a field in mm, naming what it may be; with "Learn2Reg steps in voxels" ticked it is the same warp.
    let steps = warpbench_io::learn2reg::read_voxel_field(&npz).expect("the steps");
    let form = dir.path().join("disp_0001_0001.nii.gz");
    warpbench_io::learn2reg::write_voxel_field_nifti(&form, &steps, &fixed_lps_from_index).expect("written");
    for ticked in [false, true] {
        harness.state_mut().ready_mut().expect("ready").files.fields.field = form.display().to_string();
        harness.run_steps(2);
        if ticked {
            harness.get_by_label("Learn2Reg steps in voxels").click_accesskit();
            harness.run_steps(2);
        }
        harness.get_by_label("Use field under landmarks").click_accesskit();
        harness.run_steps(3);
        wait_until_rendered(&mut harness);
        let ready = harness.state().ready().expect("ready");
        let message = ready.files.message.clone().unwrap_or_default();
        if ticked {
            assert_eq!(
                ready.document.field,
                Some(FieldFile { path: form.clone(), voxel_grids: Some(Box::new(grids)) })
            );
            for (&x, want) in probes.iter().zip(&through_npz) {
                let got = plain_at(ready, x);
                assert!((0..3).all(|a| (got[a] - want[a]).abs() < 1e-9), "{got:?} vs the .npz's {want:?}");
            }
        } else {
            assert!(message.contains("disp_0001_0001.nii.gz") && message.contains("tick Learn2Reg"), "{message}");
            assert_eq!(ready.document.field_path().and_then(|p| p.file_name()), Some("disp.npz".as_ref()));
        }
    }

    // An OME-Zarr 0.6 field folder that gives no unit or orientation goes under the landmarks, and the status bar says
    // what its reader assumed.
    let zarr = common::data("ngff/field_plain.ome.zarr");
    apply(&mut harness, Command::File(FileAction::UseField(zarr.clone())));
    let ready = harness.state().ready().expect("ready");
    let message = ready.files.message.clone().unwrap_or_default();
    assert!(message.contains("field_plain.ome.zarr is the displacement field"), "{message}");
    assert!(message.contains("warning:") && message.contains("taken as mm"), "{message}");
    assert_eq!(ready.document.field_path(), Some(zarr.as_path()));
}

/// Warp overlays (issue 30, item 5): chosen by label, each slice draws det ∇u or |u(x) − x| over its image, and the
/// overlay's value at sampled pixels is what the status bar reads out there; the deformed grid's lines move by the
/// in-plane displacement; "none" takes them away.
#[test]
fn the_warp_overlays_show_the_status_bars_values() {
    use warpbench_app::settings::Overlay;
    if no_adapter() {
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let mut harness = open_mri_pair(dir.path(), egui::vec2(900.0, 800.0));
    wait_until_rendered(&mut harness);
    harness.get_by_label("Warp overlay").click_accesskit();
    harness.run_steps(2);
    harness.get_by_label("jacobian").click_accesskit();
    harness.run_steps(3);
    wait_until_rendered(&mut harness);
    for overlay in [Overlay::Jacobian, Overlay::Displacement] {
        if overlay == Overlay::Displacement {
            let ready = harness.state_mut().ready_mut().expect("ready");
            let settings =
                warpbench_app::project::document::ViewSettings { overlay, ..ready.document.settings.clone() };
            ready.apply(Command::SetSettings(settings));
            harness.run_steps(3);
            wait_until_rendered(&mut harness);
        }
        let ready = harness.state().ready().expect("ready");
        assert_eq!(ready.document.settings.overlay, overlay);
        for a in 0..3 {
            let o = ready.view.overlays[a].as_ref().expect("an overlay on every slice");
            assert_eq!(o.key.overlay, overlay);
            let plane = ready.slice_plane(a);
            let mut finite = 0;
            for (i, j) in [(0, 0), (o.samples.0 / 2, o.samples.1 / 3), (o.samples.0 - 1, o.samples.1 - 1), (7, 11)] {
                let [px, py] = o.pixel_of(i, j);
                let cursor = ready.cursor_at(plane.ref_from_pixel(px, py));
                let value = o.values[(j * o.samples.0 + i) as usize];
                let read_out = match overlay {
                    Overlay::Jacobian => cursor.det_jacobian.expect("a warp"),
                    _ => cursor.displacement_mm(),
                };
                assert_eq!(value.to_bits(), read_out.to_bits(), "{overlay:?} slice {a} sample ({i}, {j})");
                finite += usize::from(value.is_finite());
            }
            assert_eq!(finite, 4, "{overlay:?}: values everywhere on slice {a}");
        }
        // The 3-D view: each sample is the read-out at the point a click at its pixel picks (one pick each here,
        // against the overlay's one dispatch of all), transparent where the ray misses the head.
        let o = ready.view.view_overlay.as_ref().expect("an overlay on the 3-D view");
        assert_eq!(o.key.overlay, overlay);
        let (size, _) = ready.view_shown().expect("a view");
        assert_eq!(o.key.size, size, "computed for the view as shown");
        let settings = ready.document.settings.render_settings();
        let probe = ready.document.settings.probe();
        let (mut hits, mut misses) = (0, 0);
        for j in (0..o.samples.1).step_by(5) {
            for i in (0..o.samples.0).step_by(5) {
                let pixel = o.pixel_of(i, j);
                let k = (j * o.samples.0 + i) as usize;
                let picked = ready
                    .viewer
                    .pick(&ready.view.camera, &settings, size, pixel, warpbench_gpu::PickTarget::Moving, probe)
                    .expect("pick");
                let point = picked.map(|h| h.x_ref.map(f64::from));
                assert_eq!(o.points[k], point, "{overlay:?}: the 3-D sample ({i}, {j}) is the click's pick");
                let value = o.values[k];
                if let Some(x) = point {
                    let cursor = ready.cursor_at(x);
                    let read_out = match overlay {
                        Overlay::Jacobian => cursor.det_jacobian.expect("a warp"),
                        _ => cursor.displacement_mm(),
                    };
                    assert_eq!(value.to_bits(), read_out.to_bits(), "{overlay:?} 3-D sample ({i}, {j})");
                    hits += 1;
                } else {
                    assert!(value.is_nan(), "nothing drawn where the ray misses");
                    misses += 1;
                }
            }
        }
        assert!(hits > 3 && misses > 3, "{overlay:?}: {hits} samples on the head, {misses} beside it");
    }
    // The deformed grid: lines whose points moved by the in-plane displacement (the pairs move by a few mm).
    let ready = harness.state_mut().ready_mut().expect("ready");
    let settings =
        warpbench_app::project::document::ViewSettings { overlay: Overlay::Grid, ..ready.document.settings.clone() };
    ready.apply(Command::SetSettings(settings));
    harness.run_steps(3);
    let ready = harness.state().ready().expect("ready");
    let o = ready.view.overlays[0].as_ref().expect("a grid");
    assert!(o.lines.len() > 4 && o.lines.iter().all(|l| l.len() >= 2), "{} lines", o.lines.len());
    let ready = harness.state_mut().ready_mut().expect("ready");
    let settings =
        warpbench_app::project::document::ViewSettings { overlay: Overlay::None, ..ready.document.settings.clone() };
    ready.apply(Command::SetSettings(settings));
    harness.run_steps(3);
    assert!(harness.state().ready().expect("ready").view.overlays.iter().all(Option::is_none));
}

/// Export DICOM registration from the window, on two DICOM series (pydicom's CT and an MR in its own Frame of
/// Reference) with a rigid fit: the file is the one `warpbench transform --format dicom` writes for the same pairs,
/// read back to the same matrix (`gui.rs` checks that a NIfTI pair is refused).
#[test]
fn export_dicom_registration_writes_what_the_command_line_writes() {
    use warpbench_app::gui::files::FileAction;
    use warpbench_app::settings::MethodKind;
    use warpbench_app::transform::TransformFormat;
    if no_adapter() {
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let (ct, mr, csv) = (
        common::data("dicom/pydicom_ct5n"),
        common::data("dicom/mixed_ct5n_mr_small/MR_small.dcm"),
        common::data("dicom_reg/pairs.csv"),
    );
    let opts = GuiOptions {
        fixed: Some(ct.clone()),
        moving: Some(mr.clone()),
        landmarks: Some(LandmarkSource::Pairs(csv.clone())),
        autosave: Some(dir.path().join("autosave.warpbench.json")),
        ..GuiOptions::default()
    };
    let mut harness = workbench(opts, egui::vec2(900.0, 640.0));
    wait_until_shown(&mut harness);
    {
        let ready = harness.state_mut().ready_mut().expect("loaded");
        ready.document.settings.method = MethodKind::Rigid;
        ready.refit();
    }
    let out = dir.path().join("window_reg.dcm");
    harness
        .state_mut()
        .ready_mut()
        .expect("ready")
        .apply(Command::File(FileAction::ExportTransform(TransformFormat::Dicom, out.clone())));
    let message = window::wait_for_export(&mut harness);
    assert!(message.contains("DICOM Spatial Registration (RIGID"), "{message}");
    let cli = dir.path().join("cli_reg.dcm");
    common::assert_ok(&common::warpbench(&[
        "transform".as_ref(),
        "--fixed".as_ref(),
        ct.as_os_str(),
        "--moving".as_ref(),
        mr.as_os_str(),
        "--landmarks".as_ref(),
        csv.as_os_str(),
        "--method".as_ref(),
        "rigid".as_ref(),
        "--format".as_ref(),
        "dicom".as_ref(),
        "--quiet".as_ref(),
        "--out".as_ref(),
        cli.as_os_str(),
    ]));
    let read = |p: &std::path::Path| warpbench_io::dicom_reg::read_affine(p).unwrap_or_else(|e| panic!("{e}"));
    let (ours, theirs) = (read(&out), read(&cli));
    for p in [[-69.0, -84.0, 6.6], [-60.0, -90.0, 7.0], [0.0, 0.0, 0.0]] {
        let (a, b) = (ours.apply(p), theirs.apply(p));
        // The same fit written through the same writer: the DS strings' 16 characters are all that round.
        assert!((0..3).all(|i| (a[i] - b[i]).abs() < 1e-9), "at {p:?}: window {a:?}, command line {b:?}");
    }
}
