//! The placement law, on the demo pair (fixed: the Cranium CT, 0.96 × 0.96 × 1.5 mm, i running towards +L and j
//! towards −P; moving: the Colin27 MRI, 1 mm, i towards −L and j towards −P), in a 1280 × 900 window: every way a
//! point is placed or dragged stores the point the status bar shows under the pointer (slices: straight and oblique, each of the three
//! views, the moving and the fixed side) or the pick's hit (3-D view), and a point outside its volume is refused with
//! a message, never stored.

mod common;
#[path = "common/window.rs"]
mod window;

use eframe::egui;
use egui_kittest::Harness;
use egui_kittest::kittest::{NodeT, Queryable};
use warpbench_app::gui::{GuiOptions, Placing, Ready, Workbench};
use warpbench_gpu::PickTarget;
use window::{button, click_at, no_adapter, press_and_drag, wait_until_shown};

/// Moves the pointer to `pos` and lets the status bar show what is under it.
fn hover(harness: &mut Harness<'_, Workbench>, pos: egui::Pos2) {
    harness.input_mut().events.push(egui::Event::PointerMoved(pos));
    harness.run_steps(2);
}

/// The fixed and moving points the status bar shows under the pointer, read from its text
/// ("cursor LPS fixed (l, p, s) mm, moving (l, p, s) mm").
fn shown(harness: &Harness<'_, Workbench>) -> ([f64; 3], [f64; 3]) {
    let text = {
        let node = harness.get_by_label_contains("cursor LPS fixed");
        let label = node.accesskit_node().label().filter(|l| !l.is_empty());
        let bar = label.or_else(|| node.value()).unwrap_or_default();
        // The status bar's items are separated by " | ".
        bar.split(" | ").find(|item| item.starts_with("cursor LPS fixed")).unwrap_or_default().to_owned()
    };
    let numbers: Vec<f64> = text
        .split(|c: char| !(c.is_ascii_digit() || c == '.' || c == '-'))
        .filter(|s| !s.is_empty() && *s != "-")
        .map(|s| s.parse().unwrap_or_else(|_| panic!("{s:?} in {text:?}")))
        .collect();
    assert_eq!(numbers.len(), 6, "{text:?}");
    ([numbers[0], numbers[1], numbers[2]], [numbers[3], numbers[4], numbers[5]])
}

/// The status bar shows one decimal: stored and shown agree to its rounding.
fn assert_shown(stored: [f64; 3], shown: [f64; 3], what: &str) {
    for a in 0..3 {
        assert!((stored[a] - shown[a]).abs() <= 0.051, "{what}: stored {stored:?}, the status bar showed {shown:?}");
    }
}

fn ready<'h>(harness: &'h Harness<'_, Workbench>) -> &'h Ready {
    harness.state().ready().expect("loaded")
}

/// Adds a pair with a source click at `source` and a target click at `target` (window points, over slice images),
/// checking each stored point against the status bar's reading at that position.
fn add_pair_in_slices(harness: &mut Harness<'_, Workbench>, source: egui::Pos2, target: egui::Pos2, what: &str) {
    eprintln!("{what}: source at {source:?}, target at {target:?}");
    let before = ready(harness).document.pairs.len();
    harness.get_by_label("Add pair").click();
    harness.run_steps(2);
    hover(harness, source);
    click_at(harness, source);
    let Placing::Target { moving } = ready(harness).placing() else {
        panic!("{what}: the source click was not taken: {:?}", ready(harness).pointer.notice);
    };
    // What the status bar shows with the pointer where it clicked (read once the click is drawn: the window shows
    // the moving point through the warp as the last render left it, and the click renders again).
    let (_, moving_shown) = shown(harness);
    assert_shown(moving.coords(), moving_shown, &format!("{what}, moving point"));
    hover(harness, target);
    let (fixed_shown, _) = shown(harness);
    click_at(harness, target);
    let r = ready(harness);
    assert_eq!(r.placing(), Placing::Idle, "{what}: {:?}", r.pointer.notice);
    assert_eq!(r.document.pairs.len(), before + 1, "{what}: a pair was added");
    let pair = r.document.pairs.last().expect("pair");
    assert_shown(pair.moving.expect("moving").coords(), moving_shown, &format!("{what}, stored moving point"));
    assert_shown(pair.fixed.expect("fixed").coords(), fixed_shown, &format!("{what}, stored fixed point"));
}

#[test]
fn every_click_and_drag_stores_the_point_under_the_pointer_and_refuses_points_off_their_volume() {
    if no_adapter() {
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let opts = GuiOptions { autosave: Some(dir.path().join("autosave.warpbench.json")), ..GuiOptions::default() };
    let mut harness =
        Harness::builder().with_size(egui::vec2(1280.0, 900.0)).wgpu().build_eframe(|cc| Workbench::new(cc, opts));
    wait_until_shown(&mut harness);
    assert!(ready(&harness).loaded.title.contains("cranium_ct"), "the demo pair: {}", ready(&harness).loaded.title);

    // Each slice view, straight and then oblique: the source at one point, the target at another.
    for (a, name) in ["Axial", "Coronal", "Sagittal"].into_iter().enumerate() {
        for oblique in [false, true] {
            if oblique {
                harness.get_by_label(&format!("{name} oblique")).click();
                harness.run_steps(2);
                let r = harness.state_mut().ready_mut().expect("loaded");
                r.document.settings.oblique[a].tilt_deg = 20.0;
                r.document.settings.oblique[a].spin_deg = -15.0;
                r.invalidate();
                harness.run_steps(2);
            }
            // The image lies inside its pane, with its controls above it, turned or not.
            let window = egui::Rect::from_min_size(egui::Pos2::ZERO, egui::vec2(1280.0, 900.0));
            let rect = harness.get_by_label(&format!("{name} slice")).rect();
            assert!(window.contains_rect(rect), "{name} (oblique: {oblique}): {rect:?} lies in the window");
            let source = rect.center() + egui::vec2(-0.08 * rect.width(), 0.05 * rect.height());
            let target = rect.center() + egui::vec2(0.06 * rect.width(), -0.04 * rect.height());
            add_pair_in_slices(&mut harness, source, target, &format!("{name} (oblique: {oblique})"));
        }
    }

    // A drag within the axial slice: the fixed point follows the pointer and ends where the status bar says.
    let i = ready(&harness).document.pairs.len() - 6;
    // Its Go to (the table's row may lie below the side panel's fold at this window size).
    harness.state_mut().ready_mut().expect("loaded").apply(warpbench_app::gui::Command::JumpTo(i));
    harness.run_steps(2);
    harness.run_steps(2);
    let r = ready(&harness);
    let plane = r.slice_plane(0);
    let q = r.document.pairs[i].fixed.expect("fixed").coords();
    let rect = harness.get_by_label("Axial slice").rect();
    let scale = rect.width() / plane.size.0 as f32;
    let px = plane.pixel_from_ref(q).expect("on the plane");
    assert!(px[2].abs() < 1.0, "the axial slice goes through the pair: {px:?}");
    let start = rect.min + egui::vec2((px[0] as f32 + 0.5) * scale, (px[1] as f32 + 0.5) * scale);
    let end = start + egui::vec2(-25.0, 12.0);
    press_and_drag(&mut harness, start, end, &[0.25, 0.5, 0.75, 1.0]);
    assert!(ready(&harness).drag().is_some(), "the press grabbed the glyph");
    harness.step();
    let (fixed_shown, _) = shown(&harness);
    harness.input_mut().events.push(button(end, false));
    harness.run_steps(3);
    let moved = ready(&harness).document.pairs[i].fixed.expect("fixed").coords();
    assert_shown(moved, fixed_shown, "the dragged fixed point");
    assert!((moved[0] - q[0]).abs() > 5.0, "it moved: {q:?} -> {moved:?}");
    harness.run_steps(2);

    // The 3-D view: both points are the pick's hits at the clicked pixel (of the full view, once it is drawn).
    harness.get_by_label("Add pair").click();
    harness.run_steps(2);
    window::wait_until_rendered(&mut harness);
    let view = harness.get_by_label("3-D view").rect();
    let at = view.center() + egui::vec2(0.05 * view.width(), -0.05 * view.height());
    // The pixel of the view as shown now (its size changes while it is redrawn reduced, then full).
    let pick = |harness: &Harness<'_, Workbench>, target| {
        let ((w, h), _) = ready(harness).view_shown().expect("a view");
        let pixel = [(at.x - view.min.x) / view.width() * w as f32, (at.y - view.min.y) / view.height() * h as f32];
        let r = ready(harness);
        let settings = r.document.settings.render_settings();
        r.viewer
            .pick(&r.view.camera, &settings, (w, h), pixel, target, r.document.settings.probe())
            .expect("pick")
            .expect("a hit")
    };
    let moving_hit = pick(&harness, PickTarget::Moving);
    click_at(&mut harness, at);
    let Placing::Target { moving } = ready(&harness).placing() else { panic!("the 3-D source click was not taken") };
    assert_shown(moving.coords(), moving_hit.p_lps.map(f64::from), "3-D moving point");
    // The target by hand: Esc drops the suggested target (a press on its ghost, near this pixel, would take it).
    if ready(&harness).suggestion().is_some() {
        harness.key_press(egui::Key::Escape);
        harness.run_steps(2);
    }
    window::wait_until_rendered(&mut harness);
    let fixed_hit = pick(&harness, PickTarget::Fixed);
    click_at(&mut harness, at);
    let pair = ready(&harness).document.pairs.last().expect("pair").clone();
    assert_eq!(ready(&harness).placing(), Placing::Idle);
    assert_shown(pair.fixed.expect("fixed").coords(), fixed_hit.x_ref.map(f64::from), "3-D fixed point");
    harness.run_steps(2);

    // Off its volume. The axial slice tilted by 60°: its top and bottom rows leave the CT (162 mm high).
    let r = harness.state_mut().ready_mut().expect("loaded");
    r.document.settings.oblique[0].tilt_deg = 60.0;
    r.document.settings.oblique[0].spin_deg = 0.0;
    r.invalidate();
    harness.run_steps(2);
    // Near the left edge of the CT's slice the moving point the warp shows lies beyond the MRI (180 mm wide, the CT
    // 245 mm): refused, nothing stored, still waiting for the source.
    let n = ready(&harness).document.pairs.len();
    let rect = harness.get_by_label("Axial slice").rect();
    let edge = egui::pos2(rect.min.x + 0.04 * rect.width(), rect.center().y);
    harness.get_by_label("Add pair").click();
    harness.run_steps(2);
    click_at(&mut harness, edge);
    let r = ready(&harness);
    assert_eq!(r.placing(), Placing::Source, "the source off the moving volume was refused");
    let notice = r.pointer.notice.clone().expect("a message");
    assert!(notice.contains("outside the moving volume"), "{notice}");
    assert_eq!(r.document.pairs.len(), n);
    harness.run_steps(2);
    harness.get_by_label_contains(&notice);
    // A source inside, then a target on the top row, outside the CT: refused.
    click_at(&mut harness, rect.center());
    assert!(matches!(ready(&harness).placing(), Placing::Target { .. }), "{:?}", ready(&harness).pointer.notice);
    click_at(&mut harness, egui::pos2(rect.center().x, rect.min.y + 2.0));
    let r = ready(&harness);
    assert!(matches!(r.placing(), Placing::Target { .. }), "the target off the fixed volume was refused");
    assert!(
        r.pointer.notice.as_deref().is_some_and(|m| m.contains("outside the fixed volume")),
        "{:?}",
        r.pointer.notice
    );
    assert_eq!(r.document.pairs.len(), n);
    // Every stored pair lies in its volumes, as the command line checks them.
    let r = ready(&harness);
    for (k, p) in r.document.pairs.iter().enumerate() {
        let (m, f) = (p.moving.expect("moving").coords(), p.fixed.expect("fixed").coords());
        assert!(warpbench_app::gui::placement::contains(&r.loaded.moving, m), "pair {}: moving {m:?}", k + 1);
        assert!(warpbench_app::gui::placement::contains(&r.loaded.fixed, f), "pair {}: fixed {f:?}", k + 1);
    }
}
