//! Pictures of the warp itself over the slices, as BigWarp and Slicer users read it: det ∇u on diverging colours
//! about 1 (folding, det ≤ 0, in a colour of its own), |u(x) − x| in mm, or the slice's grid moved by the warp, each
//! with a legend giving its scale.
//!
//! The values are the status bar's: each sample is [`super::Ready::cursor_at`] at its point, the same det ∇u and the same
//! moving point the read-out shows under the pointer. They are sampled on a coarser grid than the slice's pixels
//! (at most [`MAX_SAMPLES`] a side) and computed again only when the warp, the plane or the choice changes.

use eframe::egui;
use warpbench_gpu::SlicePlane;

use crate::settings::Overlay;

/// The most samples along a side of a slice's overlay.
pub const MAX_SAMPLES: u32 = 96;
/// The det ∇u range the diverging colours span (log scale, 1 in the middle).
pub const JACOBIAN_RANGE: (f64, f64) = (0.5, 2.0);
/// The colour of folding, det ∇u ≤ 0.
pub const FOLDING: egui::Color32 = egui::Color32::from_rgb(200, 0, 255);
/// The spacing of the deformed grid's lines, mm.
pub const GRID_MM: f64 = 10.0;

/// What an overlay was computed for: the choice, the fit and the plane.
#[derive(Clone, Debug, PartialEq)]
pub struct OverlayKey {
    pub overlay: Overlay,
    pub fit_generation: u64,
    pub origin_ref: [f64; 3],
    pub u_ref: [f64; 3],
    pub v_ref: [f64; 3],
    pub size: (u32, u32),
}

impl OverlayKey {
    #[must_use]
    pub fn new(overlay: Overlay, fit_generation: u64, plane: &SlicePlane) -> Self {
        Self {
            overlay,
            fit_generation,
            origin_ref: plane.origin_ref,
            u_ref: plane.u_ref,
            v_ref: plane.v_ref,
            size: plane.size,
        }
    }
}

/// One slice's overlay: its samples' values and, for the colour maps, the image drawn over the slice.
#[derive(Clone)]
pub struct SliceOverlay {
    pub key: OverlayKey,
    /// Samples along the slice's x and y.
    pub samples: (u32, u32),
    /// One value per sample, row by row (det ∇u, or |u − x| mm; `NaN` without a warp); the deformed grid keeps the
    /// displaced points of its lines instead ([`Self::lines`]).
    pub values: Vec<f64>,
    /// The deformed grid: polylines in slice pixels.
    pub lines: Vec<Vec<[f64; 2]>>,
    /// The largest |u − x| (mm), for the displacement legend.
    pub max_mm: f64,
    pub(crate) texture: Option<egui::TextureHandle>,
}

impl std::fmt::Debug for SliceOverlay {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SliceOverlay").field("key", &self.key).field("samples", &self.samples).finish_non_exhaustive()
    }
}

impl SliceOverlay {
    /// The slice pixel (fractional) of sample (i, j): the centres of an even grid over the image.
    #[must_use]
    pub fn pixel_of(&self, i: u32, j: u32) -> [f64; 2] {
        let (w, h) = (self.key.size.0 as f64, self.key.size.1 as f64);
        let (sx, sy) = (f64::from(self.samples.0), f64::from(self.samples.1));
        [(f64::from(i) + 0.5) * w / sx - 0.5, (f64::from(j) + 0.5) * h / sy - 0.5]
    }
}

/// The samples an image of `size` pixels gets: `most` along its longer side, one a pixel when it is smaller
/// ([`MAX_SAMPLES`] for a slice, [`VIEW_SAMPLES`] for the 3-D view).
pub(crate) fn samples_of(size: (u32, u32), most: u32) -> (u32, u32) {
    let longest = size.0.max(size.1).max(1);
    let scale = (f64::from(most) / f64::from(longest)).min(1.0);
    let n = |s: u32| ((f64::from(s) * scale).round() as u32).max(2);
    (n(size.0), n(size.1))
}

/// The colour of det ∇u = `det`: blue below 1, white at 1, red above, on a log scale over [`JACOBIAN_RANGE`];
/// [`FOLDING`] at or below 0.
#[must_use]
pub fn jacobian_colour(det: f64) -> egui::Color32 {
    if det.is_nan() {
        return egui::Color32::TRANSPARENT;
    }
    if det <= 0.0 {
        return FOLDING;
    }
    let (lo, hi) = JACOBIAN_RANGE;
    let t = (det.ln() / if det < 1.0 { -lo.ln() } else { hi.ln() }).clamp(-1.0, 1.0);
    let fade = |c: f64| (255.0 * c) as u8;
    if t < 0.0 {
        egui::Color32::from_rgb(fade(1.0 + t), fade(1.0 + 0.6 * t), 255)
    } else {
        egui::Color32::from_rgb(255, fade(1.0 - 0.6 * t), fade(1.0 - t))
    }
}

/// The colour of a displacement of `mm` out of `max_mm`: dark blue through green to yellow.
#[must_use]
pub fn displacement_colour(mm: f64, max_mm: f64) -> egui::Color32 {
    if mm.is_nan() {
        return egui::Color32::TRANSPARENT;
    }
    let t = if max_mm > 0.0 { (mm / max_mm).clamp(0.0, 1.0) } else { 0.0 };
    let c = |a: f64, b: f64, c: f64| {
        let v = if t < 0.5 { a + (b - a) * 2.0 * t } else { b + (c - b) * (2.0 * t - 1.0) };
        (255.0 * v) as u8
    };
    egui::Color32::from_rgb(c(0.27, 0.13, 0.99), c(0.0, 0.57, 0.91), c(0.33, 0.55, 0.14))
}

/// The 3-D view's samples a side at most: one pick ray each, all in one dispatch.
pub const VIEW_SAMPLES: u32 = 48;

/// What the 3-D view's overlay was computed for: the choice, the fit, the view image shown (whatever changed it:
/// the looks, a view deformation, a refinement), the pick probe, and the camera and size the picks are made with.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ViewOverlayKey {
    pub overlay: Overlay,
    pub fit_generation: u64,
    pub view_generation: u64,
    pub probe: warpbench_gpu::Probe,
    pub camera: warpbench_gpu::OrbitCamera,
    pub size: (u32, u32),
}

/// The 3-D view's overlay: the status bar's read-out at the visible surface of the deformed moving volume, picked
/// at an even grid of the view's pixels (as a click there would pick it); `NaN` where the ray hits nothing.
pub struct ViewOverlay {
    pub key: ViewOverlayKey,
    pub samples: (u32, u32),
    /// The picked point of each sample, row by row (ref mm), `None` where the ray hits nothing.
    pub points: Vec<Option<[f64; 3]>>,
    /// One value per sample (det ∇u, or |u − x| mm) at its point.
    pub values: Vec<f64>,
    /// The largest |u − x| (mm), for the displacement legend.
    pub max_mm: f64,
    pub(crate) texture: Option<egui::TextureHandle>,
}

impl std::fmt::Debug for ViewOverlay {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ViewOverlay").field("key", &self.key).field("samples", &self.samples).finish_non_exhaustive()
    }
}

impl ViewOverlay {
    /// The view pixel (fractional, pixel centres at i + ½) of sample (i, j): the centres of an even grid.
    #[must_use]
    pub fn pixel_of(&self, i: u32, j: u32) -> [f32; 2] {
        let (w, h) = (self.key.size.0 as f32, self.key.size.1 as f32);
        let (sx, sy) = (self.samples.0 as f32, self.samples.1 as f32);
        [(i as f32 + 0.5) * w / sx, (j as f32 + 0.5) * h / sy]
    }
}

/// The colour of sample `value` of `overlay` (half transparent over the image).
pub(crate) fn colour_of(overlay: Overlay, value: f64, max_mm: f64) -> egui::Color32 {
    let c = if overlay == Overlay::Jacobian { jacobian_colour(value) } else { displacement_colour(value, max_mm) };
    c.gamma_multiply(0.55)
}

/// Draws the 3-D view's `overlay` over the view's image at `rect` with its legend (the deformed grid is drawn in the
/// slices only: its legend says so).
pub fn draw_view(ui: &egui::Ui, overlay: &ViewOverlay, rect: egui::Rect) {
    if overlay.key.overlay == Overlay::Grid {
        let at = rect.right_top() + egui::vec2(-4.0, 4.0);
        let (font, text) = (egui::FontId::proportional(11.0), egui::Color32::from_rgb(230, 230, 230));
        ui.painter_at(rect).text(at, egui::Align2::RIGHT_TOP, "deformed grid: in the slices", font, text);
        return;
    }
    let lines = [];
    draw_parts(ui, overlay.key.overlay, overlay.texture.as_ref(), &lines, overlay.max_mm, rect, 1.0);
}

/// Draws `overlay` over the slice image at `rect` (`scale` screen points a slice pixel) with its legend.
pub fn draw(ui: &egui::Ui, overlay: &SliceOverlay, rect: egui::Rect, scale: f32) {
    let kind = overlay.key.overlay;
    draw_parts(ui, kind, overlay.texture.as_ref(), &overlay.lines, overlay.max_mm, rect, scale);
}

/// Draws an overlay's colour image and grid lines over `rect` with its legend.
fn draw_parts(
    ui: &egui::Ui,
    kind: Overlay,
    texture: Option<&egui::TextureHandle>,
    lines: &[Vec<[f64; 2]>],
    max_mm: f64,
    rect: egui::Rect,
    scale: f32,
) {
    let painter = ui.painter_at(rect);
    if let Some(texture) = texture {
        let uv = egui::Rect::from_min_max(egui::pos2(0.0, 0.0), egui::pos2(1.0, 1.0));
        painter.image(texture.id(), rect, uv, egui::Color32::WHITE);
    }
    let to_screen = |p: [f64; 2]| rect.min + egui::vec2((p[0] as f32 + 0.5) * scale, (p[1] as f32 + 0.5) * scale);
    let stroke = egui::Stroke::new(1.0, egui::Color32::from_rgba_unmultiplied(255, 200, 60, 200));
    for line in lines {
        painter.add(egui::Shape::line(line.iter().map(|&p| to_screen(p)).collect(), stroke));
    }
    // The legend: a colour bar with its ends, at the top right.
    let bar = egui::Rect::from_min_size(rect.right_top() + egui::vec2(-92.0, 4.0), egui::vec2(80.0, 8.0));
    let font = egui::FontId::proportional(11.0);
    let text = egui::Color32::from_rgb(230, 230, 230);
    let steps = 16;
    let (left, right, colour): (String, String, Box<dyn Fn(f64) -> egui::Color32>) = match kind {
        Overlay::Jacobian => {
            let (lo, hi) = JACOBIAN_RANGE;
            (format!("{lo}"), format!("{hi} det"), Box::new(move |t| jacobian_colour(lo * (hi / lo).powf(t))))
        }
        Overlay::Displacement => {
            let max = max_mm;
            ("0".to_owned(), format!("{max:.1} mm"), Box::new(move |t| displacement_colour(t * max, max)))
        }
        Overlay::Grid => {
            painter.text(bar.left_top(), egui::Align2::LEFT_TOP, format!("grid {GRID_MM} mm"), font, text);
            return;
        }
        Overlay::None => return,
    };
    for k in 0..steps {
        let t = (f64::from(k) + 0.5) / f64::from(steps);
        let x0 = bar.left() + bar.width() * k as f32 / steps as f32;
        let cell = egui::Rect::from_min_max(
            egui::pos2(x0, bar.top()),
            egui::pos2(x0 + bar.width() / steps as f32, bar.bottom()),
        );
        painter.rect_filled(cell, 0.0, colour(t));
    }
    painter.text(bar.left_bottom() + egui::vec2(0.0, 1.0), egui::Align2::LEFT_TOP, left, font.clone(), text);
    painter.text(bar.right_bottom() + egui::vec2(0.0, 1.0), egui::Align2::RIGHT_TOP, right, font.clone(), text);
    if kind == Overlay::Jacobian {
        let swatch = egui::Rect::from_min_size(bar.left_bottom() + egui::vec2(0.0, 14.0), egui::vec2(8.0, 8.0));
        painter.rect_filled(swatch, 0.0, FOLDING);
        painter.text(swatch.right_center() + egui::vec2(3.0, 0.0), egui::Align2::LEFT_CENTER, "folding", font, text);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_colour_maps_centre_on_no_change_and_mark_folding() {
        assert_eq!(jacobian_colour(1.0), egui::Color32::from_rgb(255, 255, 255), "no change: white");
        assert_eq!(jacobian_colour(0.0), FOLDING);
        assert_eq!(jacobian_colour(-0.3), FOLDING);
        let shrink = jacobian_colour(0.5);
        let grow = jacobian_colour(2.0);
        assert!(shrink.b() == 255 && shrink.r() < 10, "shrinking: blue {shrink:?}");
        assert!(grow.r() == 255 && grow.b() < 10, "growing: red {grow:?}");
        assert_eq!(jacobian_colour(0.25), shrink, "clamped at the range's end");
        assert_eq!(jacobian_colour(f64::NAN), egui::Color32::TRANSPARENT);
        assert_ne!(displacement_colour(0.0, 5.0), displacement_colour(5.0, 5.0));
        assert_eq!(samples_of((256, 128), MAX_SAMPLES), (96, 48));
        assert_eq!(samples_of((480, 240), VIEW_SAMPLES), (48, 24));
        assert_eq!(samples_of((40, 30), MAX_SAMPLES), (40, 30));
    }
}
