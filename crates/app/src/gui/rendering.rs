//! Rendering the 3-D view's and the slices' images ([`super::images`]), and what must be rendered again: on a GPU a
//! changed view is drawn again at once; on a CPU driver it is drawn reduced and then refined band by band
//! ([`super::pacing`]); and the slices' warp overlays ([`super::overlay`]).

use anyhow::{Context as _, anyhow};
use eframe::egui;
use warpbench_gpu::{PickTarget, Quality, SlicePlane};

use super::Ready;
use super::images::ViewImage;
use super::overlay::{GRID_MM, OverlayKey, SliceOverlay, ViewOverlay, ViewOverlayKey, colour_of, samples_of};
use super::pacing::{self, RefineJob, interactive_size};
use super::viewer;
use crate::settings::Overlay;

impl Ready {
    /// Renders what changed (the 3-D view at `view_px`, the slices) and hands the images to egui.
    ///
    /// On a GPU a changed view is drawn again at once: at the interaction sample rate while the user interacts
    /// (`interacting`: a button is held), fully otherwise. On a CPU driver a changed view is drawn reduced (the
    /// interaction rate, at a size that renders in about [`pacing::INTERACTIVE_BUDGET_MS`]), and then a thread
    /// renders the full view band by band ([`pacing::RefineJob`]); the frame after it is done shows it. `egui` is
    /// woken by that thread.
    pub(crate) fn render(
        &mut self,
        egui: &eframe::egui::Context,
        rs: &eframe::egui_wgpu::RenderState,
        view_px: (u32, u32),
        interacting: bool,
    ) -> anyhow::Result<()> {
        let cpu = self.viewer.ctx.is_cpu_driver();
        let shown_size = self.view.images.view.as_ref().map(|v| (v.target.width, v.target.height));
        let reduced = !self.view.images.view_state.full_shown();
        // A pane's size can jitter by a pixel from one frame to the next as egui settles its layout: the view is drawn
        // again only when it changed by more (the image is stretched over its pane either way).
        let resized = |size: (u32, u32)| size.0.abs_diff(view_px.0) > 2 || size.1.abs_diff(view_px.1) > 2;
        let stale = match &self.view.images.view_state {
            ViewImage::Stale { .. } => true,
            ViewImage::Refining(r) => resized(r.size()),
            ViewImage::Full => shown_size.is_none_or(resized),
            ViewImage::Reduced => false,
        };
        // Not while the pointer is held: on a CPU driver a refinement would take the CPU from the next reduced view.
        let refine = reduced && !interacting;
        if !stale && !refine && !self.view.images.slices_dirty {
            return Ok(());
        }
        let start = std::time::Instant::now();
        let views = self.begin_viewer_frame();
        let glyphs = self.glyphs_through(views);
        let slice_glyphs = self.glyphs();
        let settings = self.document.settings.render_settings();
        if stale {
            let (quality, px) = if interacting || cpu {
                let measured = self.view.images.view_ms_per_px.or(Some(pacing::CPU_GUESS_MS_PER_PX));
                (Quality::Interactive, interactive_size(view_px, if cpu { measured } else { None }))
            } else {
                (Quality::Full, view_px)
            };
            let target = self.viewer.render_view(&self.view.camera, &settings, quality, px, &glyphs)?;
            self.show_view(rs, target);
            self.view.images.view_state = if quality == Quality::Full { ViewImage::Full } else { ViewImage::Reduced };
        } else if refine && !cpu {
            let target = self.viewer.render_view(&self.view.camera, &settings, Quality::Full, view_px, &glyphs)?;
            self.show_view(rs, target);
            self.view.images.view_state = ViewImage::Full;
        } else if refine {
            self.refine_in_background(egui, rs, view_px, &settings, &glyphs)?;
        }
        if self.view.images.slices_dirty {
            self.render_slice_images(rs, &settings, &slice_glyphs)?;
        }
        self.viewer.ctx.check_errors().map_err(|e| anyhow!("{e}"))?;
        self.view.last_render_ms = start.elapsed().as_secs_f64() * 1e3;
        Ok(())
    }

    /// Renders the slices if they changed, for a layout without the 3-D view (which otherwise renders them with
    /// itself, [`Self::render`]).
    pub(crate) fn render_slices(&mut self, rs: &eframe::egui_wgpu::RenderState) -> anyhow::Result<()> {
        if !self.view.images.slices_dirty {
            return Ok(());
        }
        let start = std::time::Instant::now();
        self.begin_viewer_frame();
        let settings = self.document.settings.render_settings();
        self.render_slice_images(rs, &settings, &self.glyphs())?;
        self.viewer.ctx.check_errors().map_err(|e| anyhow!("{e}"))?;
        self.view.last_render_ms = start.elapsed().as_secs_f64() * 1e3;
        Ok(())
    }

    /// Hands a rendered 3-D view to egui as the one shown, counting it ([`super::images::Images::view_generation`]).
    fn show_view(&mut self, rs: &eframe::egui_wgpu::RenderState, target: warpbench_gpu::RenderTarget) {
        self.view.images.view = Some(viewer::show(rs, target, self.view.images.view.take()));
        self.view.images.view_generation += 1;
    }

    /// Starts the viewer's frame with the document's looks, the synthetic deformation and the view deformations (lens,
    /// leafer) of this instant, which it returns.
    fn begin_viewer_frame(&mut self) -> [Option<warpbench_gpu::ViewDeformation>; 2] {
        self.viewer.begin_frame();
        self.viewer.set_looks(&self.document.layers);
        self.viewer.set_procedural(self.procedural().ok().flatten());
        let views = self.view_deformations(std::time::Instant::now());
        self.viewer.set_view_deformations(views);
        views
    }

    /// The three slices rendered and handed to egui.
    fn render_slice_images(
        &mut self,
        rs: &eframe::egui_wgpu::RenderState,
        settings: &warpbench_gpu::RenderSettings,
        glyphs: &[warpbench_gpu::GlyphInstance],
    ) -> anyhow::Result<()> {
        let planes = self.slice_planes();
        for (slot, plane) in self.view.images.slices.iter_mut().zip(planes) {
            let target = self.viewer.render_slice(&plane, settings, glyphs)?;
            *slot = Some(viewer::show(rs, target, slot.take()));
        }
        let panes = super::layout::panes(self.view.layout, self.view.maximised);
        if panes.iter().any(|p| matches!(p, super::layout::Pane::Compare(_))) {
            let s = &self.document.settings;
            let alone = [crate::settings::Blend::FixedOnly, crate::settings::Blend::MovingOnly];
            for (slot, blend) in self.view.images.compare.iter_mut().zip(alone) {
                let settings =
                    warpbench_gpu::RenderSettings { blend: blend.mode(s.mix_weight, s.checker_mm), ..*settings };
                let target = self.viewer.render_slice(&planes[0], &settings, glyphs)?;
                *slot = Some(viewer::show(rs, target, slot.take()));
            }
        }
        self.view.images.slices_dirty = false;
        Ok(())
    }

    /// On a CPU driver: starts the thread that renders the full 3-D view band by band, or shows its view once it is
    /// done (a failure starts it again at the next frame).
    pub(crate) fn refine_in_background(
        &mut self,
        egui: &eframe::egui::Context,
        rs: &eframe::egui_wgpu::RenderState,
        view_px: (u32, u32),
        settings: &warpbench_gpu::RenderSettings,
        glyphs: &[warpbench_gpu::GlyphInstance],
    ) -> anyhow::Result<()> {
        let ViewImage::Refining(job) = &self.view.images.view_state else {
            let target = self.viewer.view_target(view_px);
            let work = self.viewer.refine_work(&self.view.camera, settings, target, self.view.images.view_ms_per_px);
            let egui = egui.clone();
            let job = RefineJob::start(work, move || egui.request_repaint())
                .context("starting the thread that refines the 3-D view")?;
            // Until this frame's work is done ([`Self::hold_refinement`]).
            job.hold(true);
            self.view.images.view_state = ViewImage::Refining(job);
            return Ok(());
        };
        let Some(result) = job.poll() else { return Ok(()) };
        self.view.images.view_state = ViewImage::Reduced;
        let done = result.map_err(|e| anyhow!(e))?;
        self.view.images.view_ms_per_px = done.ms_per_px;
        self.viewer.draw_view_glyphs(&self.view.camera, &done.target, glyphs)?;
        self.show_view(rs, done.target);
        self.view.images.view_state = ViewImage::Full;
        Ok(())
    }

    /// On a CPU driver, how much of the full 3-D view is rendered while it is rendered band by band (0..1).
    #[must_use]
    pub fn view_refine_progress(&self) -> Option<f32> {
        match &self.view.images.view_state {
            ViewImage::Refining(job) => Some(job.progress()),
            _ => None,
        }
    }

    /// What the 3-D view shows, for the frame log ([`super::frame_log`]): `stale`, `reduced`, `refining <fraction>`
    /// or `full`.
    #[must_use]
    pub fn view_state_name(&self) -> String {
        match &self.view.images.view_state {
            ViewImage::Stale { .. } => "stale".into(),
            ViewImage::Reduced => "reduced".into(),
            ViewImage::Refining(job) => format!("refining {:.2}", job.progress()),
            ViewImage::Full => "full".into(),
        }
    }

    /// The 3-D view's image shown now, read back (premultiplied RGBA8, rows top to bottom).
    pub fn read_view(&self) -> anyhow::Result<Vec<u8>> {
        let shown = self.view.images.view.as_ref().context("no 3-D view is shown")?;
        shown.target.read_back(&self.viewer.ctx).map_err(|e| anyhow!("{e}"))
    }

    /// The size of the 3-D view's image shown now, and whether it is the full-quality one.
    #[must_use]
    pub fn view_shown(&self) -> Option<((u32, u32), bool)> {
        let v = self.view.images.view.as_ref()?;
        Some(((v.target.width, v.target.height), self.view.images.view_state.full_shown()))
    }

    /// Marks the 3-D view and the slices for re-rendering.
    pub fn invalidate(&mut self) {
        self.invalidate_view();
        self.view.images.slices_dirty = true;
    }

    /// Marks the 3-D view only (the camera moved).
    pub fn invalidate_view(&mut self) {
        let full_shown = self.view.images.view_state.full_shown();
        self.view.images.view_state = ViewImage::Stale { full_shown };
    }

    /// Marks the slices only (a slice moved or turned).
    pub fn invalidate_slices(&mut self) {
        self.view.images.slices_dirty = true;
    }

    /// Whether something waits to be rendered.
    #[must_use]
    pub fn needs_render(&self) -> bool {
        let view_shown =
            super::layout::panes(self.view.layout, self.view.maximised).contains(&super::layout::Pane::View3d);
        self.view.images.slices_dirty || (view_shown && !matches!(self.view.images.view_state, ViewImage::Full))
    }

    /// Holds the thread refining the 3-D view back from its next band while `held` (set for the time of a frame's
    /// work on the UI thread, [`RefineJob::hold`]).
    pub fn hold_refinement(&self, held: bool) {
        if let ViewImage::Refining(job) = &self.view.images.view_state {
            job.hold(held);
        }
    }

    /// Whether the only thing that waits is the full 3-D view a thread is rendering: it wakes the window when done,
    /// so the window need not draw frames meanwhile.
    #[must_use]
    pub fn refining_in_background(&self) -> bool {
        !self.view.images.slices_dirty && matches!(self.view.images.view_state, ViewImage::Refining(_))
    }
}

/// The slices' warp overlays ([`super::overlay`]), computed from the status bar's read-outs.
impl Ready {
    /// Slice view `a`'s overlay for `plane`, computed again when the choice, the fit or the plane changed; `None`
    /// with no overlay chosen.
    pub(crate) fn slice_overlay(&mut self, ctx: &egui::Context, a: usize, plane: &SlicePlane) -> Option<&SliceOverlay> {
        let overlay = self.document.settings.overlay;
        if overlay == Overlay::None {
            self.view.overlays[a] = None;
            return None;
        }
        let key = OverlayKey::new(overlay, self.fit.generation, plane);
        if self.view.overlays[a].as_ref().is_none_or(|o| o.key != key) {
            // A drag keeps the last overlay until the pointer lets go: the samples cost a few fits' worth.
            if self.drag().is_some() && self.view.overlays[a].is_some() {
                return self.view.overlays[a].as_ref();
            }
            let computed = self.compute_overlay(ctx, a, key, plane);
            self.view.overlays[a] = Some(computed);
        }
        self.view.overlays[a].as_ref()
    }

    /// The 3-D view's overlay for the view as shown, computed again when the choice, the fit, the camera or the
    /// view's size changed (kept while the pointer is held: an orbit would pick every frame); `None` with no
    /// overlay chosen or no view shown.
    pub(crate) fn view_overlay(&mut self, ctx: &egui::Context, held: bool) -> Option<&ViewOverlay> {
        let overlay = self.document.settings.overlay;
        let Some((size, _)) = self.view_shown().filter(|_| overlay != Overlay::None) else {
            self.view.view_overlay = None;
            return None;
        };
        let key = ViewOverlayKey {
            overlay,
            fit_generation: self.fit.generation,
            view_generation: self.view.images.view_generation,
            probe: self.document.settings.probe(),
            camera: self.view.camera,
            size,
        };
        let stale = self.view.view_overlay.as_ref().is_none_or(|o| o.key != key);
        if stale && !(held && self.view.view_overlay.is_some()) {
            match self.compute_view_overlay(ctx, key) {
                Ok(o) => self.view.view_overlay = Some(o),
                Err(e) => {
                    self.fit.error = Some(format!("the 3-D view's overlay: {e:#}"));
                    self.view.view_overlay = None;
                }
            }
        }
        self.view.view_overlay.as_ref()
    }

    fn compute_view_overlay(&self, ctx: &egui::Context, key: ViewOverlayKey) -> anyhow::Result<ViewOverlay> {
        let samples = samples_of(key.size, super::overlay::VIEW_SAMPLES);
        let mut overlay =
            ViewOverlay { key, samples, points: Vec::new(), values: Vec::new(), max_mm: 0.0, texture: None };
        if key.overlay == Overlay::Grid {
            return Ok(overlay);
        }
        let pixels: Vec<[f32; 2]> = (0..samples.1)
            .flat_map(|j| (0..samples.0).map(move |i| (i, j)))
            .map(|(i, j)| overlay.pixel_of(i, j))
            .collect();
        let settings = self.document.settings.render_settings();
        overlay.points =
            self.viewer.pick_points(&key.camera, &settings, key.size, &pixels, PickTarget::Moving, key.probe)?;
        let (values, max_mm, texture) = self.read_outs(ctx, "3-D warp overlay", key.overlay, samples, &overlay.points);
        (overlay.values, overlay.max_mm, overlay.texture) = (values, max_mm, Some(texture));
        Ok(overlay)
    }

    fn compute_overlay(&self, ctx: &egui::Context, a: usize, key: OverlayKey, plane: &SlicePlane) -> SliceOverlay {
        let samples = samples_of(plane.size, super::overlay::MAX_SAMPLES);
        let mut overlay =
            SliceOverlay { key, samples, values: Vec::new(), lines: Vec::new(), max_mm: 0.0, texture: None };
        match overlay.key.overlay {
            Overlay::None => {}
            kind @ (Overlay::Jacobian | Overlay::Displacement) => {
                let points: Vec<Option<[f64; 3]>> = (0..samples.1)
                    .flat_map(|j| (0..samples.0).map(move |i| (i, j)))
                    .map(|(i, j)| {
                        let [px, py] = overlay.pixel_of(i, j);
                        Some(plane.ref_from_pixel(px, py))
                    })
                    .collect();
                let (values, max_mm, texture) =
                    self.read_outs(ctx, &format!("warp overlay {a}"), kind, samples, &points);
                (overlay.values, overlay.max_mm, overlay.texture) = (values, max_mm, Some(texture));
            }
            Overlay::Grid => overlay.lines = self.deformed_grid(plane),
        }
        overlay
    }

    /// The status bar's read-out of `kind` (det ∇u, or |u(x) − x| mm) at each of `points` (`NaN` at none, and without
    /// a warp), their largest displacement, and their colours as an image of `samples` named `name`.
    fn read_outs(
        &self,
        ctx: &egui::Context,
        name: &str,
        kind: Overlay,
        samples: (u32, u32),
        points: &[Option<[f64; 3]>],
    ) -> (Vec<f64>, f64, egui::TextureHandle) {
        let fitted = self.fitted().is_some();
        let values: Vec<f64> = points
            .iter()
            .map(|p| match (p, fitted) {
                (Some(x), true) => {
                    let cursor = self.cursor_at(*x);
                    if kind == Overlay::Jacobian {
                        cursor.det_jacobian.unwrap_or(f64::NAN)
                    } else {
                        cursor.displacement_mm()
                    }
                }
                _ => f64::NAN,
            })
            .collect();
        let max_mm = values.iter().copied().filter(|v| v.is_finite()).fold(0.0, f64::max);
        let pixels: Vec<egui::Color32> = values.iter().map(|&v| colour_of(kind, v, max_mm)).collect();
        let image = egui::ColorImage::new([samples.0 as usize, samples.1 as usize], pixels);
        (values, max_mm, ctx.load_texture(name, image, egui::TextureOptions::LINEAR))
    }

    /// The lines of a [`GRID_MM`] grid over `plane`, each point x moved to where the warp takes it within the plane
    /// (the in-plane part of u(x) − x), in slice pixels.
    fn deformed_grid(&self, plane: &SlicePlane) -> Vec<Vec<[f64; 2]>> {
        let len = |d: [f64; 3]| (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        let (du, dv) = (len(plane.u_ref).max(f64::MIN_POSITIVE), len(plane.v_ref).max(f64::MIN_POSITIVE));
        let (w, h) = (f64::from(plane.size.0), f64::from(plane.size.1));
        let moved = |px: f64, py: f64| {
            let x = plane.ref_from_pixel(px, py);
            let m = self.moving_shown_at(x);
            let d = [m[0] - x[0], m[1] - x[1], m[2] - x[2]];
            let dot = |a: [f64; 3], b: [f64; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
            [px + dot(d, plane.u_ref) / (du * du), py + dot(d, plane.v_ref) / (dv * dv)]
        };
        let step_u = GRID_MM / du;
        let step_v = GRID_MM / dv;
        // Points every few pixels along a line of `n` pixels.
        let along = |n: f64| {
            let count = (n / 4.0).ceil().clamp(2.0, 64.0);
            (0..=count as usize).map(move |k| k as f64 * n / count)
        };
        let mut lines = Vec::new();
        let mut py = 0.0;
        while py <= h {
            lines.push(along(w).map(|px| moved(px - 0.5, py - 0.5)).collect());
            py += step_v;
        }
        let mut px = 0.0;
        while px <= w {
            lines.push(along(h).map(|py| moved(px - 0.5, py - 0.5)).collect());
            px += step_u;
        }
        lines
    }
}
