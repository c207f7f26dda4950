//! A slice pane: the axial, coronal or sagittal view of the fixed grid (straight or oblique) through the crosshair,
//! with its position slider and oblique controls. A click moves the other slices through the point (linked
//! navigation) or places the point being added; a press on a landmark glyph drags it within the plane.

use eframe::egui;

use warpbench_gpu::SlicePlane;

use crate::gui::layout::SliceAxis;
use crate::gui::open::Side;
use crate::gui::{
    Command, DragPoint, DragView, Placing, Ready, SLICE_SLAB_MM, overlay, panels, placement, slice_habits,
};
use crate::settings::Blend;

/// Draws slice view `axis` in its pane: its position slider and oblique controls, then the image with its
/// overlays, landmarks and crosshair. `planes` are the three slice planes of this frame. `alone`: the pane shows
/// that volume alone (the moving one warped), beside the other in the side-by-side layout; the two share the plane,
/// the crosshair and the pointer's read-out.
pub fn slice_pane(
    ui: &mut egui::Ui,
    ready: &mut Ready,
    axis: SliceAxis,
    planes: &[SlicePlane; 3],
    alone: Option<Side>,
) {
    let a = axis.index();
    let name = match alone {
        None => axis.name().to_owned(),
        Some(side) => {
            format!("{} {}", if side == Side::Fixed { "Fixed" } else { "Moving" }, axis.name().to_lowercase())
        }
    };
    let name = name.as_str();
    // The pane's own rect: the image fits in what its controls leave of it, even where a control is wider.
    let pane = ui.available_rect_before_wrap();
    let mut mm = ready.view.slice_mm[a];
    // The slider leaves room for its value field; its name is for screen readers.
    // (room for "-123.45 mm").
    ui.spacing_mut().slider_width = (ui.available_width() - 100.0).max(40.0);
    let slider = ui.add(egui::Slider::new(&mut mm, -150.0..=150.0).suffix(" mm"));
    let slider_name = format!("{name} position");
    slider.widget_info(|| egui::WidgetInfo::labeled(egui::Role::Slider, true, &slider_name));
    if (mm - ready.view.slice_mm[a]).abs() > f64::EPSILON {
        ready.apply(Command::MoveSlice(a, mm));
    }
    let mut settings = ready.document.settings.clone();
    if panels::oblique_ui(ui, name, &mut settings.oblique[a]) {
        ready.apply(Command::SetSettings(settings));
    }
    let image = match alone {
        None => &ready.view.images.slices[a],
        Some(Side::Fixed) => &ready.view.images.compare[0],
        Some(Side::Moving) => &ready.view.images.compare[1],
    };
    if let Some(shown) = image {
        let avail = pane.max - ui.cursor().min;
        let (w, h) = (shown.target.width as f32, shown.target.height as f32);
        let scale = (avail.x / w).min(avail.y.max(64.0) / h);
        // The image exactly fills the rect the response reports, so that pointer positions map to
        // pixels one to one.
        let size = egui::vec2(w, h) * scale;
        // Left-aligned in its own layout, so that the response covers the image and nothing more.
        let (rect, response) = ui
            .with_layout(egui::Layout::top_down(egui::Align::Min), |ui| {
                ui.allocate_exact_size(size, egui::Sense::click_and_drag())
            })
            .inner;
        egui::Image::new(egui::load::SizedTexture::new(shown.texture_id, size)).paint_at(ui, rect);
        let ctx = ui.ctx().clone();
        if let Some(o) = ready.slice_overlay(&ctx, a, &planes[a]) {
            overlay::draw(ui, o, rect, scale);
        }
        let label = format!("{name} slice");
        response.widget_info(|| egui::WidgetInfo::labeled(egui::Role::Image, true, &label));
        // The ref point under a window position, only when it is over the image ([`placement`]).
        let image_rect = response.rect;
        let to_ref = |pos: egui::Pos2| placement::slice_point(&planes[a], image_rect, scale, pos);
        if let Some(x_ref) = response.hover_pos().and_then(to_ref) {
            ready.pointer.cursor = Some(ready.cursor_at(x_ref));
        }
        // Dragging a landmark within this plane: grab the glyph under the press.
        let plane = planes[a];
        let on_screen = |p_ref: [f64; 3], _end| {
            plane
                .pixel_from_ref(p_ref)
                .filter(|q| q[2].abs() <= SLICE_SLAB_MM)
                .map(|q| placement::slice_screen(image_rect, scale, q))
        };
        // A press on a suggested target's ghost takes it and drags its fixed point.
        let primary = egui::PointerButton::Primary;
        if response.drag_started_by(primary)
            && let Some(press) = ui.input(|i| i.pointer.press_origin())
            && let Some(pair) = ready.grab_ghost(press, on_screen, DragView::Slice(a))
        {
            ready.pointer.selected = Some(pair);
        }
        if response.drag_started_by(primary)
            && let Some(press) = ui.input(|i| i.pointer.press_origin())
            && let Some((pair, end)) = ready.grab(press, on_screen)
            && ready.pointer.interaction.grab(DragPoint { pair, end, view: DragView::Slice(a) })
        {
            ready.pointer.selected = Some(pair);
        }
        let dragging_here = ready.drag().is_some_and(|d| d.view == DragView::Slice(a));
        // Off the image the point stays where it was.
        if dragging_here
            && response.dragged_by(primary)
            && let Some(x_ref) = response.interact_pointer_pos().and_then(to_ref)
        {
            ready.drag_to(x_ref, None);
        }
        if response.drag_stopped_by(primary) {
            ready.end_drag(DragView::Slice(a));
        }
        // The brush: a press on the image starts a stroke there, the drag displaces within the plane.
        if ready.pointer.interaction.sculpting() {
            if response.drag_started_by(primary)
                && let Some(from) = ui.input(|i| i.pointer.press_origin()).and_then(to_ref)
            {
                ready.sculpt_press(DragView::Slice(a), from);
            }
            if response.dragged_by(primary)
                && let Some(x_ref) = response.interact_pointer_pos().and_then(to_ref)
            {
                ready.sculpt_to(x_ref);
            }
            if response.drag_stopped_by(primary) {
                ready.sculpt_release(DragView::Slice(a));
            }
        }
        if response.clicked()
            && let Some(x_ref) = response.interact_pointer_pos().and_then(to_ref)
        {
            if ui.input(|i| i.modifiers.shift) {
                // The linked crosshair: every view, the 3-D view's camera too, moves to the point.
                ready.apply(Command::CentreViews(x_ref));
            } else if ready.placing() == Placing::Idle {
                // Linked navigation: the other two slices move through the clicked point.
                ready.apply(Command::CentreSlices(x_ref));
            } else {
                ready.place_at_ref(x_ref, None);
            }
        }
        // The wheel steps one slice (shift: ten) while the pointer is over the image.
        if response.hovered() {
            let notches = wheel_notches(ui, response.id);
            if notches != 0 {
                let shift = ui.input(|i| i.modifiers.shift);
                let to = slice_habits::stepped(&ready.loaded.fixed, a, ready.view.slice_mm[a], notches, shift);
                ready.apply(Command::MoveSlice(a, to));
            }
        }
        // A right drag sets the window and level of the volume the views show (the fixed one unless
        // the moving one is shown alone), its values written over the image meanwhile.
        let side = slice_habits::window_side(ready.document.settings.blend == Blend::MovingOnly);
        if response.dragged_by(egui::PointerButton::Secondary) {
            let d = response.drag_delta();
            if d != egui::Vec2::ZERO {
                let mut looks = ready.document.layers;
                looks[side] = slice_habits::window_level_dragged(looks[side], d.x, d.y);
                ready.apply(Command::SetLooks(looks));
            }
            let text = slice_habits::window_level_text(&ready.document.layers[side]);
            ui.painter_at(response.rect).text(
                response.rect.left_bottom() + egui::vec2(4.0, -4.0),
                egui::Align2::LEFT_BOTTOM,
                text,
                egui::FontId::proportional(12.0),
                egui::Color32::from_rgb(255, 230, 90),
            );
        }
        // The patient's sides at the image's edges.
        let [left, right, top, bottom] = slice_habits::edge_labels(&planes[a]);
        let painter = ui.painter_at(response.rect);
        let r = response.rect;
        let font = egui::FontId::proportional(12.0);
        let colour = egui::Color32::from_rgb(120, 220, 255);
        for (pos, align, side) in [
            (r.left_center() + egui::vec2(3.0, 0.0), egui::Align2::LEFT_CENTER, left),
            (r.right_center() - egui::vec2(3.0, 0.0), egui::Align2::RIGHT_CENTER, right),
            (r.center_top() + egui::vec2(0.0, 2.0), egui::Align2::CENTER_TOP, top),
            (r.center_bottom() - egui::vec2(0.0, 2.0), egui::Align2::CENTER_BOTTOM, bottom),
        ] {
            painter.text(pos, align, side, font.clone(), colour);
        }
        // The crosshair: where the other two planes cut this one.
        let centre = [ready.view.slice_mm[2], ready.view.slice_mm[1], ready.view.slice_mm[0]];
        if let Some(q) = planes[a].pixel_from_ref(centre) {
            let p = placement::slice_screen(image_rect, scale, q);
            let stroke = egui::Stroke::new(1.0, egui::Color32::from_rgba_unmultiplied(255, 230, 90, 160));
            let painter = ui.painter_at(response.rect);
            painter.hline(response.rect.x_range(), p.y, stroke);
            painter.vline(p.x, response.rect.y_range(), stroke);
        }
    }
}

/// Whole wheel notches this frame over the widget `id` (a trackpad's points carried between frames in egui's memory).
fn wheel_notches(ui: &egui::Ui, id: egui::Id) -> i32 {
    let (delta, lines) = ui.input(|i| {
        i.events.iter().fold((0.0f32, true), |(sum, lines), e| match e {
            egui::Event::MouseWheel { unit, delta, modifiers, .. } => {
                // Shift + wheel arrives as a horizontal scroll on some systems.
                let d = if modifiers.shift && delta.y == 0.0 { delta.x } else { delta.y };
                (sum + d, lines && *unit != egui::MouseWheelUnit::Point)
            }
            _ => (sum, lines),
        })
    });
    if delta == 0.0 {
        return 0;
    }
    let key = id.with("wheel carry");
    let carry = ui.data(|d| d.get_temp::<f32>(key).unwrap_or(0.0));
    let (notches, left) = slice_habits::notches(carry, delta, lines);
    ui.data_mut(|d| d.insert_temp(key, left));
    notches
}
