//! The 3-D view: the fixed and the deformed moving volume rendered at the view's pixels (reduced while interacting),
//! with the landmark glyphs. A click picks the point being added on the surface; a press on a glyph drags it along
//! the surface; elsewhere a drag orbits the camera and the wheel zooms.

use eframe::egui;
use warpbench_gpu::glam::Vec3;

use crate::gui::{Command, DragPoint, DragView, End, Ready};

/// Renders what changed and draws the 3-D view in its pane.
pub fn view3d(ui: &mut egui::Ui, ready: &mut Ready, render_state: Option<&eframe::egui_wgpu::RenderState>) {
    let avail = ui.available_size();
    let ppp = ui.ctx().pixels_per_point();
    // A GPU renders the view at the screen's pixels; a CPU driver (about 1 Mpixel·step per second) at most at
    // 1024² so that its reduced view (a quarter per side at least) still fits the frame budget.
    let cap = if ready.viewer.ctx.is_cpu_driver() { 1024.0 } else { 8192.0 };
    let px = (avail * ppp).min(egui::vec2(cap, cap)).max(egui::vec2(32.0, 32.0));
    let view_px = (px.x as u32, px.y as u32);
    let interacting = ui.input(|i| i.pointer.any_down()) || ready.drag().is_some();
    if let Some(rs) = render_state
        && let Err(e) = ready.render(ui.ctx(), rs, view_px, interacting)
    {
        ready.fit.error = Some(format!("rendering: {e:#}"));
    }
    if let Some(shown) = &ready.view.images.view {
        let response = ui.add(
            egui::Image::new(egui::load::SizedTexture::new(shown.texture_id, avail))
                .sense(egui::Sense::click_and_drag()),
        );
        response.widget_info(|| egui::WidgetInfo::labeled(egui::Role::Image, true, "3-D view"));
        let (w, h) = (shown.target.width as f32, shown.target.height as f32);
        let ctx = ui.ctx().clone();
        if let Some(o) = ready.view_overlay(&ctx, interacting) {
            crate::gui::overlay::draw_view(ui, o, response.rect);
        }
        let to_pixel = |pos: egui::Pos2| {
            let f = (pos - response.rect.min) / response.rect.size();
            [f.x * w, f.y * h]
        };
        if response.clicked()
            && let Some(pos) = response.interact_pointer_pos()
        {
            if ui.input(|i| i.modifiers.shift) {
                // The linked crosshair: every view moves to the surface point under the click.
                if let Some(x_ref) = ready.pick_moving_at(to_pixel(pos)) {
                    ready.apply(Command::CentreViews(x_ref));
                }
            } else {
                ready.pick_in_view(to_pixel(pos));
            }
        }
        // A press on a landmark glyph drags it along the surface; elsewhere a drag orbits the camera.
        let clip_from_ref = ready.view.camera.clip_from_ref(w / h);
        let rect = response.rect;
        // Where the view shows a point: through the view deformation its volume was drawn with.
        let views = ready.viewer.view_deformations();
        let on_screen = |p_ref: [f64; 3], end: End| {
            let x = Vec3::from_array(p_ref.map(|v| v as f32));
            let view = match end {
                End::Fixed => views[0],
                End::Moving => views[1],
            };
            let c = clip_from_ref * view.map_or(x, |w| w.forward(x)).extend(1.0);
            (c.w > 0.0).then(|| {
                let (x, y) = (c.x / c.w, c.y / c.w);
                rect.min + egui::vec2((x * 0.5 + 0.5) * rect.width(), (0.5 - y * 0.5) * rect.height())
            })
        };
        // A press on a suggested target's ghost takes it and drags its fixed point along the surface.
        if response.drag_started()
            && let Some(press) = ui.input(|i| i.pointer.press_origin())
            && let Some(pair) = ready.grab_ghost(press, on_screen, DragView::ThreeD)
        {
            ready.pointer.selected = Some(pair);
        }
        if response.drag_started()
            && let Some(press) = ui.input(|i| i.pointer.press_origin())
            && let Some((pair, end)) = ready.grab(press, on_screen)
            && ready.pointer.interaction.grab(DragPoint { pair, end, view: DragView::ThreeD })
        {
            ready.pointer.selected = Some(pair);
        }
        // The brush: a press on the deformed moving volume starts a stroke at the point picked there; the drag
        // moves it within the plane through that point facing the camera.
        if ready.pointer.interaction.sculpting() {
            if response.drag_started()
                && let Some(press) = ui.input(|i| i.pointer.press_origin())
                && let Some(from) = ready.pick_moving_at(to_pixel(press))
            {
                ready.sculpt_press(DragView::ThreeD, from);
            }
            if let Some(stroke) = ready.pointer.interaction.sculpt_drag().filter(|d| d.view == DragView::ThreeD)
                && response.dragged()
                && let Some(pos) = response.interact_pointer_pos()
            {
                let px = to_pixel(pos);
                let ndc = Vec3::new(px[0] / w * 2.0 - 1.0, 1.0 - px[1] / h * 2.0, 0.0);
                let ref_from_clip = ready.view.camera.ref_from_clip(w / h);
                let near = ref_from_clip.project_point3(ndc);
                let far = ref_from_clip.project_point3(Vec3::new(ndc.x, ndc.y, 1.0));
                let dir = (far - near).normalize_or_zero();
                let view_dir = (ref_from_clip.project_point3(Vec3::Z) - ref_from_clip.project_point3(Vec3::ZERO))
                    .normalize_or_zero();
                let from = Vec3::from_array(stroke.from_ref.map(|v| v as f32));
                let along = dir.dot(view_dir);
                if along.abs() > 1e-6 {
                    let to = near + dir * ((from - near).dot(view_dir) / along);
                    ready.sculpt_to(to.to_array().map(f64::from));
                }
            }
            if response.drag_stopped() {
                ready.sculpt_release(DragView::ThreeD);
            }
        }
        let landmark_drag = ready.drag().is_some_and(|d| d.view == DragView::ThreeD);
        if landmark_drag
            && response.dragged()
            && response.drag_delta() != egui::Vec2::ZERO
            && let Some(pos) = response.interact_pointer_pos()
        {
            ready.drag_in_view(to_pixel(pos));
        }
        let stroking = ready.pointer.interaction.sculpt_drag().is_some();
        let drag = if landmark_drag || stroking { egui::Vec2::ZERO } else { response.drag_delta() };
        if drag != egui::Vec2::ZERO {
            ready.apply(Command::Orbit(drag));
        }
        if response.drag_stopped() {
            ready.end_drag(DragView::ThreeD);
            // Back to the full sample rate once the drag ends.
            ready.invalidate_view();
        }
        // The read-out under a resting pointer: one pick once it has rested ([`crate::gui::hover`]).
        let resting = response.hover_pos().filter(|_| !ui.input(|i| i.pointer.any_down()) && !interacting);
        let key = crate::gui::hover::ViewKey {
            camera: ready.view.camera,
            fit_generation: ready.fit.generation,
            settings: ready.document.settings.clone(),
        };
        match ready.view.hover.step(resting, &key, std::time::Instant::now()) {
            crate::gui::hover::HoverStep::Pick(pos) => {
                let hit = ready.pick_moving_at(to_pixel(pos));
                ready.view.hover.picked(pos, key.clone(), hit);
            }
            crate::gui::hover::HoverStep::Wait(after) => ui.ctx().request_repaint_after(after),
            crate::gui::hover::HoverStep::Idle => {}
        }
        if let Some(x_ref) = ready.view.hover.hit(resting, &key) {
            ready.pointer.cursor = Some(ready.cursor_at(x_ref));
        }
        if response.hovered() {
            let scroll = ui.input(|i| i.smooth_scroll_delta.y);
            if scroll != 0.0 {
                ready.apply(Command::Zoom(scroll));
            }
        }
    }
}
