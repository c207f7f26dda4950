//! The workstation window (issue 30): the panes' layout chosen, maximised by a double click and saved in the session;
//! the views' history and named views; the toolbar's tools with their shortcuts; the landmark panel's sorting, filter
//! and marked rows; and nothing cut off at 1280 × 720 and 1920 × 1080.

mod common;
#[path = "common/window.rs"]
mod window;

use std::time::{Duration, Instant};

use eframe::egui;
use egui_kittest::Harness;
use egui_kittest::kittest::{NodeT, Queryable};
use warpbench_app::gui::{Command, GuiOptions, Placing, Ready, Workbench};
use warpbench_app::project::session::SessionFile;
use warpbench_app::settings::Layout;
use window::{button, no_adapter, open_mri_pair, press_and_drag, wait_until_rendered, wait_until_shown};

fn ready<'h>(harness: &'h Harness<'_, Workbench>) -> &'h Ready {
    harness.state().ready().expect("loaded")
}

/// Which of the four views are shown.
fn views_shown(harness: &Harness<'_, Workbench>) -> [bool; 4] {
    ["3-D view", "Axial slice", "Coronal slice", "Sagittal slice"].map(|v| harness.query_by_label(v).is_some())
}

/// A double click on the pane titled `title`.
fn double_click(harness: &mut Harness<'_, Workbench>, title: &str) {
    // Two clicks a frame apart (a quarter of a second in the harness's time; a double click is within 0.3 s).
    let pos = harness.get_by_label(title).rect().center();
    harness.input_mut().events.push(egui::Event::PointerMoved(pos));
    harness.step();
    for _ in 0..2 {
        harness.input_mut().events.push(window::button(pos, true));
        harness.input_mut().events.push(window::button(pos, false));
        harness.step();
    }
    harness.run_steps(3);
}

/// Steps until the autosave at `path` holds a session that `holds` (or a minute passes: a guard against a hang, not a
/// timing); returns that session.
fn wait_for_autosave(
    harness: &mut Harness<'_, Workbench>,
    path: &std::path::Path,
    holds: impl Fn(&SessionFile) -> bool,
) -> SessionFile {
    let start = Instant::now();
    loop {
        harness.run_steps(2);
        if let Some(s) = warpbench_app::project::session::load(path).ok().filter(|s| holds(s)) {
            return s;
        }
        let text = std::fs::read_to_string(path).unwrap_or_default();
        assert!(start.elapsed() < Duration::from_mins(1), "the autosave never held it: {text}");
        std::thread::sleep(Duration::from_millis(50));
    }
}

#[test]
fn the_layout_is_chosen_maximised_by_a_double_click_and_saved_in_the_session() {
    if no_adapter() {
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let mut harness = open_mri_pair(dir.path(), egui::vec2(1280.0, 800.0));
    assert_eq!(views_shown(&harness), [true; 4], "four-up at first");

    double_click(&mut harness, "Axial");
    assert_eq!(views_shown(&harness), [false, true, false, false], "the axial pane alone");
    double_click(&mut harness, "Axial");
    assert_eq!(views_shown(&harness), [true; 4], "the layout again");

    harness.get_by_label("Layout").click();
    harness.run_steps(2);
    harness.get_by_label("slices").click();
    harness.run_steps(3);
    assert_eq!(ready(&harness).view.layout, Layout::Slices);
    assert_eq!(views_shown(&harness), [false, true, true, true], "the slices alone");

    // The autosave holds it (it is written once the change has settled), and a window opened on it shows it.
    let autosave = dir.path().join("autosave.warpbench.json");
    wait_for_autosave(&mut harness, &autosave, |s| s.view.layout == Layout::Slices);
    let session = dir.path().join("saved.warpbench.json");
    std::fs::copy(&autosave, &session).expect("copy the session");
    drop(harness);
    let reopened_autosave = Some(dir.path().join("reopened.warpbench.json"));
    let opts = GuiOptions { session: Some(session), autosave: reopened_autosave, ..GuiOptions::default() };
    let mut reopened =
        Harness::builder().with_size(egui::vec2(1280.0, 800.0)).wgpu().build_eframe(|cc| Workbench::new(cc, opts));
    wait_until_shown(&mut reopened);
    assert_eq!(ready(&reopened).view.layout, Layout::Slices, "restored from the session");
    assert_eq!(views_shown(&reopened), [false, true, true, true]);
}

/// Opens the toolbar's Views menu, unless it is open.
fn open_views_menu(harness: &mut Harness<'_, Workbench>) {
    if harness.query_by_label("Save view").is_none() {
        harness.get_by_label("Views").click();
        harness.run_steps(2);
    }
}

/// The views' history and named views (BigWarp #152): an orbit and a jump to a pair are steps that Back (its button,
/// then Alt+Left) walks back through and Forward (Alt+Right) returns; a named view brings the camera and the slices
/// back after they moved, reaches the autosave, is listed by a window opened on that session, and x forgets it. None
/// of it is an undo step.
#[test]
fn the_views_go_back_and_forward_and_named_views_are_kept_in_the_session() {
    if no_adapter() {
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let mut harness = open_mri_pair(dir.path(), egui::vec2(1280.0, 800.0));
    let place = |h: &Harness<'_, Workbench>| ready(h).place();
    let start = place(&harness);
    let undo_steps = ready(&harness).history.can_undo();

    // An orbit: a drag in the 3-D view, away from the glyphs.
    let rect = harness.get_by_label("3-D view").rect();
    let (from, to) = (rect.min + rect.size() * 0.15, rect.min + rect.size() * egui::vec2(0.45, 0.15));
    press_and_drag(&mut harness, from, to, &[0.5, 1.0]);
    harness.input_mut().events.push(button(to, false));
    harness.run_steps(3);
    let orbited = place(&harness);
    assert!((orbited.camera.azimuth_rad - start.camera.azimuth_rad).abs() > 0.1, "orbited: {orbited:?}");
    // A jump: pair 3's "go".
    harness.state_mut().ready_mut().expect("loaded").apply(Command::JumpTo(2));
    harness.run_steps(3);
    let jumped = place(&harness);
    assert_ne!(jumped, orbited);

    harness.get_by_label("Back").click();
    harness.run_steps(3);
    assert_eq!(place(&harness), orbited, "Back: before the jump");
    harness.key_press_modifiers(egui::Modifiers::ALT, egui::Key::ArrowLeft);
    harness.run_steps(3);
    assert_eq!(place(&harness), start, "Alt+Left: before the orbit");
    assert!(harness.get_by_label("Back").accesskit_node().is_disabled(), "nothing further back");
    harness.key_press_modifiers(egui::Modifiers::ALT, egui::Key::ArrowRight);
    harness.run_steps(3);
    assert_eq!(place(&harness), orbited, "Alt+Right: forward again");
    assert_eq!(ready(&harness).history.can_undo(), undo_steps, "moving the views is no undo step");

    // A named view (the toolbar's Views menu): saved where the views are, brought back after Reset camera moved them.
    open_views_menu(&mut harness);
    harness.get_by_label("View name").focus();
    harness.run_steps(2);
    harness.get_by_label("View name").type_text("left side");
    harness.run_steps(2);
    harness.get_by_label("Save view").click();
    harness.run_steps(3);
    harness.get_by_label("Reset camera").click();
    harness.run_steps(3);
    assert_ne!(place(&harness), orbited);
    open_views_menu(&mut harness);
    harness.get_by_label("left side").click();
    harness.run_steps(3);
    assert_eq!(place(&harness), orbited, "the named view");

    let autosave = dir.path().join("autosave.warpbench.json");
    let saved = wait_for_autosave(&mut harness, &autosave, |s| !s.view.named_views.is_empty());
    assert_eq!(saved.view.named_views[0].name, "left side");
    let session = dir.path().join("saved.warpbench.json");
    std::fs::copy(&autosave, &session).expect("copy the session");

    open_views_menu(&mut harness);
    harness.get_by_label("x").click();
    harness.run_steps(3);
    assert!(ready(&harness).view.places.named.is_empty(), "x forgets it");
    assert!(harness.query_by_label("left side").is_none());
    drop(harness);

    let reopened_autosave = Some(dir.path().join("reopened.warpbench.json"));
    let opts = GuiOptions { session: Some(session), autosave: reopened_autosave, ..GuiOptions::default() };
    let mut reopened =
        Harness::builder().with_size(egui::vec2(1280.0, 800.0)).wgpu().build_eframe(|cc| Workbench::new(cc, opts));
    wait_until_shown(&mut reopened);
    open_views_menu(&mut reopened);
    reopened.get_by_label("left side").click();
    reopened.run_steps(3);
    let there = place(&reopened);
    let (a, b) = (there.camera, orbited.camera);
    assert!((a.azimuth_rad - b.azimuth_rad).abs() < 1e-5 && (a.elevation_rad - b.elevation_rad).abs() < 1e-5);
    assert_eq!((a.zoom, a.target_ref, a.pan_mm, there.slice_mm), (b.zoom, b.target_ref, b.pan_mm, orbited.slice_mm));
}

#[test]
fn the_toolbar_shows_the_active_tool_and_its_keys_choose_the_same_tools() {
    if no_adapter() {
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let mut harness = open_mri_pair(dir.path(), egui::vec2(1280.0, 800.0));
    let toggled = |harness: &Harness<'_, Workbench>, tool: &str| {
        harness.get_by_label(tool).accesskit_node().toggled() == Some(egui::accesskit::Toggled::True)
    };
    assert!(toggled(&harness, "Select") && !toggled(&harness, "Add pair"));

    harness.get_by_label("Add pair").click();
    harness.run_steps(2);
    assert_eq!(ready(&harness).placing(), Placing::Source);
    assert!(toggled(&harness, "Add pair") && !toggled(&harness, "Select"), "the active tool is shown");
    harness.get_by_label("Select").click();
    harness.run_steps(2);
    assert_eq!(ready(&harness).placing(), Placing::Idle);

    // The tooltip gives the shortcut.
    harness.get_by_label("Leafer").hover();
    // Tooltips wait for the pointer to rest.
    for _ in 0..10 {
        harness.run_steps(6);
        std::thread::sleep(Duration::from_millis(100));
    }
    harness.get_by_label_contains("open it like a book (L)");

    // The keys choose the same tools.
    harness.key_press(egui::Key::L);
    harness.run_steps(2);
    assert!(ready(&harness).view.leafer.is_open() && toggled(&harness, "Leafer"));
    harness.key_press(egui::Key::L);
    harness.run_steps(2);
    assert!(!ready(&harness).view.leafer.is_open());
    harness.key_press(egui::Key::B);
    harness.run_steps(2);
    assert!(ready(&harness).sculpting() && toggled(&harness, "Brush"));
    harness.key_press(egui::Key::Space);
    harness.run_steps(2);
    assert_eq!(ready(&harness).placing(), Placing::Source, "Add pair takes over from the brush");
    harness.key_press(egui::Key::Escape);
    harness.run_steps(2);
    assert!(toggled(&harness, "Select"));

    // Suggest needs a selected pair: without one neither its button nor T does anything.
    harness.key_press(egui::Key::T);
    harness.run_steps(2);
    assert!(ready(&harness).pointer.notice.is_none(), "{:?}", ready(&harness).pointer.notice);
    harness.key_press(egui::Key::P);
    harness.run_steps(2);
    assert!(ready(&harness).view.attention.is_on() && toggled(&harness, "Lens"));
}

/// The pairs' table rows in the order shown, top to bottom (their numbers' "Select NAME" buttons).
fn rows_shown(harness: &Harness<'_, Workbench>) -> Vec<usize> {
    let names: Vec<String> = ready(harness).document.pairs.iter().map(|p| p.name.clone()).collect();
    let mut rows: Vec<(f32, usize)> = names
        .iter()
        .enumerate()
        .filter_map(|(i, n)| harness.query_by_label(&format!("Select {n}")).map(|node| (node.rect().top(), i)))
        .collect();
    rows.sort_by(|a, b| a.0.total_cmp(&b.0));
    rows.into_iter().map(|(_, i)| i).collect()
}

#[test]
fn the_landmark_panel_sorts_filters_and_switches_marked_pairs_off_in_one_step() {
    if no_adapter() {
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let mut harness = open_mri_pair(dir.path(), egui::vec2(1280.0, 800.0));
    wait_until_rendered(&mut harness);
    let loo: Vec<f64> = ready(&harness)
        .fit
        .pair_errors
        .iter()
        .map(|e| e.and_then(|e| e.leave_one_out_mm).expect("a leave-one-out error per pair"))
        .collect();
    assert_eq!(rows_shown(&harness), [0, 1, 2, 3, 4], "in placing order at first");

    // Sorted by leave-one-out, then reversed: largest first.
    harness.get_by_label("Sort by leave-one-out").click();
    harness.run_steps(2);
    harness.get_by_label("Sort by leave-one-out").click();
    harness.run_steps(2);
    let mut by_loo: Vec<usize> = (0..loo.len()).collect();
    by_loo.sort_by(|&a, &b| loo[b].total_cmp(&loo[a]));
    assert_eq!(rows_shown(&harness), by_loo, "largest leave-one-out first: {loo:?}");

    // The filter at the colour threshold (2 mm): only the pairs above it.
    harness.get_by_label("Only LOO above").click();
    harness.run_steps(2);
    let above: Vec<usize> = by_loo.iter().copied().filter(|&i| loo[i] > 2.0).collect();
    assert_eq!(rows_shown(&harness), above, "{loo:?}");
    harness.get_by_label("Only LOO above").click();
    harness.run_steps(2);

    // Two rows marked (a click, then Ctrl+click) are switched off together, and one undo brings both back.
    let names: Vec<String> = ready(&harness).document.pairs.iter().map(|p| p.name.clone()).collect();
    harness.get_by_label(&format!("Select {}", names[1])).click();
    harness.run_steps(2);
    harness.get_by_label(&format!("Select {}", names[3])).click_modifiers(egui::Modifiers::COMMAND);
    harness.run_steps(2);
    harness.get_by_label_contains("2 marked");
    harness.get_by_label("Deactivate marked").click();
    harness.run_steps(3);
    let active: Vec<bool> = ready(&harness).document.pairs.iter().map(|p| p.active).collect();
    assert_eq!(active, [true, false, true, false, true]);
    wait_until_rendered(&mut harness);
    harness.get_by_label("Undo").click();
    harness.run_steps(3);
    assert!(ready(&harness).document.pairs.iter().all(|p| p.active), "one undo step");
}

/// Every widget of the window on the demo pair at `size`: none extends past the window, and none crosses the
/// border of the settings panel or of the landmark panel (where its text would be cut).
fn assert_nothing_cut_off(size: egui::Vec2) {
    let dir = tempfile::tempdir().expect("tempdir");
    let opts = GuiOptions { autosave: Some(dir.path().join("autosave.warpbench.json")), ..GuiOptions::default() };
    let mut harness = Harness::builder().with_size(size).wgpu().build_eframe(|cc| Workbench::new(cc, opts));
    wait_until_shown(&mut harness);
    // Long values in the slices' position fields.
    for a in 0..3 {
        harness.state_mut().ready_mut().expect("loaded").apply(warpbench_app::gui::Command::MoveSlice(a, -123.45));
    }
    harness.run_steps(3);
    wait_until_rendered(&mut harness);
    // Something long in the status bar: the pointer over a slice (the point, the warp there and the nearest pair).
    let axial = harness.get_by_label("Axial slice").rect();
    harness.input_mut().events.push(egui::Event::PointerMoved(axial.center()));
    harness.run_steps(3);
    harness.get_by_label_contains("cursor LPS fixed");
    let window = egui::Rect::from_min_size(egui::Pos2::ZERO, size).expand(0.5);
    // The panels' borders: where the panes begin and where the landmark panel begins.
    let left_border = harness.get_by_label("3-D").rect().left() - 4.0;
    let right_border = harness.get_by_label_contains("Landmarks (").rect().left() - 4.0;
    // Where the left panes end and the right ones begin.
    let split = harness.get_by_label("Axial").rect().left() - 2.0;
    // The panels' band: below the toolbar and above the status bar (which span the window).
    let band = harness.get_by_label("Select").rect().bottom()..harness.get_by_label_contains("last frame").rect().top();
    let mut checked = 0;
    for node in harness.root().children_recursive() {
        let Some(b) = node.accesskit_node().bounding_box() else { continue };
        let rect = egui::Rect::from_min_max(egui::pos2(b.x0 as f32, b.y0 as f32), egui::pos2(b.x1 as f32, b.y1 as f32));
        if !rect.is_positive() {
            continue;
        }
        let what = format!("{:?} {:?} at {rect:?}", node.accesskit_node().role(), node.accesskit_node().label());
        assert!(window.contains_rect(rect), "{size:?}: {what} extends past the window");
        checked += 1;
        if !(band.contains(&rect.top()) && band.contains(&rect.bottom())) {
            continue;
        }
        let x = rect.center().x;
        if x < left_border {
            assert!(rect.right() <= left_border + 4.0, "{size:?}: {what} crosses the settings panel's border");
        }
        if x > right_border {
            assert!(rect.left() >= right_border, "{size:?}: {what} crosses the landmark panel's border");
        } else {
            assert!(rect.right() <= right_border + 4.0, "{size:?}: {what} crosses into the landmark panel");
        }
        if x > left_border && x < split {
            assert!(rect.right() <= split + 4.0, "{size:?}: {what} crosses into the right-hand panes");
        }
    }
    assert!(checked > 100, "{checked} widgets checked");
    eprintln!("{size:?}: {checked} widgets inside the window and their panels");
}

#[test]
fn nothing_is_cut_off_at_1280_by_720_and_1920_by_1080() {
    if no_adapter() {
        return;
    }
    assert_nothing_cut_off(egui::vec2(1280.0, 720.0));
    assert_nothing_cut_off(egui::vec2(1920.0, 1080.0));
}

/// The fixed point the status bar reads out with the pointer at `pos`.
fn fixed_point_under(harness: &mut Harness<'_, Workbench>, pos: egui::Pos2) -> Vec<f64> {
    harness.input_mut().events.push(egui::Event::PointerMoved(pos));
    harness.run_steps(3);
    let node = harness.get_by_label_contains("cursor LPS fixed");
    let label = node.accesskit_node().label().filter(|l| !l.is_empty());
    let bar = label.or_else(|| node.value()).unwrap_or_default();
    let item = bar
        .split(" | ")
        .find(|i| i.starts_with("cursor LPS fixed"))
        .unwrap_or_else(|| panic!("the read-out in {bar:?}"))
        .to_owned();
    let fixed = item.split("mm,").next().expect("the fixed point");
    fixed
        .split(|c: char| !(c.is_ascii_digit() || c == '.' || c == '-'))
        .filter(|s| !s.is_empty() && *s != "-")
        .map(|s| s.parse().expect("a number"))
        .collect()
}

#[test]
fn side_by_side_shows_the_fixed_and_the_warped_moving_volume_in_one_linked_plane() {
    if no_adapter() {
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let mut harness = open_mri_pair(dir.path(), egui::vec2(1280.0, 800.0));
    harness.get_by_label("Layout").click();
    harness.run_steps(2);
    harness.get_by_label("side by side").click();
    harness.run_steps(3);
    wait_until_rendered(&mut harness);
    assert_eq!(views_shown(&harness), [false; 4], "the two panes alone");
    let fixed = harness.get_by_label("Fixed axial slice").rect();
    let moving = harness.get_by_label("Moving axial slice").rect();
    assert!(fixed.right() <= moving.left(), "side by side: {fixed:?} | {moving:?}");

    // The same place in each pane is the same point: one plane, one read-out.
    let at = |r: egui::Rect| r.min + r.size() * egui::vec2(0.4, 0.55);
    let in_fixed = fixed_point_under(&mut harness, at(fixed));
    let in_moving = fixed_point_under(&mut harness, at(moving));
    assert_eq!(in_fixed, in_moving, "linked panes");

    // The wheel over one pane moves the plane of both.
    let before = ready(&harness).view.slice_mm[0];
    harness.input_mut().events.push(egui::Event::MouseWheel {
        unit: egui::MouseWheelUnit::Line,
        delta: egui::vec2(0.0, 1.0),
        modifiers: egui::Modifiers::NONE,
        phase: egui::TouchPhase::Move,
        source: egui::MouseWheelSource::Wheel,
    });
    harness.run_steps(3);
    let after = ready(&harness).view.slice_mm[0];
    assert!((after - before).abs() > 0.5, "one slice: {before} -> {after}");
    let value = |h: &Harness<'_, Workbench>, label: &str| h.get_by_label(label).accesskit_node().numeric_value();
    assert_eq!(value(&harness, "Fixed axial position"), Some(after));
    assert_eq!(value(&harness, "Moving axial position"), Some(after));

    // A pair placed across the panes: its moving point in the warped moving volume, its partner in the fixed one.
    let n = ready(&harness).document.pairs.len();
    harness.get_by_label("Add pair").click();
    harness.run_steps(2);
    window::click_at(&mut harness, at(moving));
    assert!(matches!(ready(&harness).placing(), Placing::Target { .. }), "{:?}", ready(&harness).pointer.notice);
    window::click_at(&mut harness, at(fixed));
    assert_eq!(ready(&harness).document.pairs.len(), n + 1, "{:?}", ready(&harness).pointer.notice);
}
