//! The slice strip: axial, coronal and sagittal views of the fixed grid (straight or oblique) through the crosshair,
//! each with its position slider and oblique controls. A click moves the other slices through the point (linked
//! navigation) or places the point being added; a press on a landmark glyph drags it within the plane.

use eframe::egui;

use crate::gui::{Command, DragPoint, DragView, Placing, Ready, SLICE_SLAB_MM, panels, placement};

/// Draws the slice strip at the bottom of the window.
pub fn slice_strip(ui: &mut egui::Ui, ready: &mut Ready) {
    let planes = ready.slice_planes();
    let slices_height = (ui.available_height() * 0.4).max(160.0);
    egui::Panel::bottom("slices").exact_size(slices_height).show(ui, |ui| {
        ready.pointer.cursor = None;
        ui.columns(3, |columns| {
            let names = ["Axial", "Coronal", "Sagittal"];
            for (a, col) in columns.iter_mut().enumerate() {
                col.label(names[a]);
                let mut mm = ready.view.slice_mm[a];
                // Narrow columns: the slider leaves room for its value field; its name is for screen readers.
                col.spacing_mut().slider_width = (col.available_width() - 64.0).max(40.0);
                let slider = col.add(egui::Slider::new(&mut mm, -150.0..=150.0).suffix(" mm"));
                let slider_name = format!("{} position", names[a]);
                slider.widget_info(|| egui::WidgetInfo::labeled(egui::Role::Slider, true, &slider_name));
                if (mm - ready.view.slice_mm[a]).abs() > f64::EPSILON {
                    ready.apply(Command::MoveSlice(a, mm));
                }
                let mut settings = ready.document.settings.clone();
                if panels::oblique_ui(col, names[a], &mut settings.oblique[a]) {
                    ready.apply(Command::SetSettings(settings));
                }
                if let Some(shown) = &ready.view.images.slices[a] {
                    let avail = col.available_size();
                    let (w, h) = (shown.target.width as f32, shown.target.height as f32);
                    let scale = (avail.x / w).min(avail.y.max(64.0) / h);
                    // The image exactly fills the rect the response reports, so that pointer positions map to
                    // pixels one to one.
                    let size = egui::vec2(w, h) * scale;
                    // Left-aligned in its own layout, so that the response covers the image and nothing more.
                    let (rect, response) = col
                        .with_layout(egui::Layout::top_down(egui::Align::Min), |ui| {
                            ui.allocate_exact_size(size, egui::Sense::click_and_drag())
                        })
                        .inner;
                    egui::Image::new(egui::load::SizedTexture::new(shown.texture_id, size)).paint_at(col, rect);
                    let label = format!("{} slice", names[a]);
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
                    if response.drag_started()
                        && let Some(press) = col.input(|i| i.pointer.press_origin())
                        && let Some(pair) = ready.grab_ghost(press, on_screen, DragView::Slice(a))
                    {
                        ready.pointer.selected = Some(pair);
                    }
                    if response.drag_started()
                        && let Some(press) = col.input(|i| i.pointer.press_origin())
                        && let Some((pair, end)) = ready.grab(press, on_screen)
                        && ready.pointer.interaction.grab(DragPoint { pair, end, view: DragView::Slice(a) })
                    {
                        ready.pointer.selected = Some(pair);
                    }
                    let dragging_here = ready.drag().is_some_and(|d| d.view == DragView::Slice(a));
                    // Off the image the point stays where it was.
                    if dragging_here
                        && response.dragged()
                        && let Some(x_ref) = response.interact_pointer_pos().and_then(to_ref)
                    {
                        ready.drag_to(x_ref, None);
                    }
                    if response.drag_stopped() {
                        ready.end_drag(DragView::Slice(a));
                    }
                    // The brush: a press on the image starts a stroke there, the drag displaces within the plane.
                    if ready.pointer.interaction.sculpting() {
                        if response.drag_started()
                            && let Some(from) = col.input(|i| i.pointer.press_origin()).and_then(to_ref)
                        {
                            ready.sculpt_press(DragView::Slice(a), from);
                        }
                        if response.dragged()
                            && let Some(x_ref) = response.interact_pointer_pos().and_then(to_ref)
                        {
                            ready.sculpt_to(x_ref);
                        }
                        if response.drag_stopped() {
                            ready.sculpt_release(DragView::Slice(a));
                        }
                    }
                    if response.clicked()
                        && let Some(x_ref) = response.interact_pointer_pos().and_then(to_ref)
                    {
                        if ready.placing() == Placing::Idle {
                            // Linked navigation: the other two slices move through the clicked point.
                            ready.apply(Command::CentreSlices(x_ref));
                        } else {
                            ready.place_at_ref(x_ref, None);
                        }
                    }
                    // The crosshair: where the other two planes cut this one.
                    let centre = [ready.view.slice_mm[2], ready.view.slice_mm[1], ready.view.slice_mm[0]];
                    if let Some(q) = planes[a].pixel_from_ref(centre) {
                        let p = placement::slice_screen(image_rect, scale, q);
                        let stroke = egui::Stroke::new(1.0, egui::Color32::from_rgba_unmultiplied(255, 230, 90, 160));
                        let painter = col.painter_at(response.rect);
                        painter.hline(response.rect.x_range(), p.y, stroke);
                        painter.vline(p.x, response.rect.y_range(), stroke);
                    }
                }
            }
        });
    });
}
