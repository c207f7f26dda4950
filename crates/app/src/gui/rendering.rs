//! Rendering the 3-D view's and the slices' images ([`super::images`]), and what must be rendered again: on a GPU a
//! changed view is drawn again at once; on a CPU driver it is drawn reduced and then refined band by band
//! ([`super::pacing`]).

use anyhow::{Context as _, anyhow};
use warpbench_gpu::Quality;

use super::Ready;
use super::images::ViewImage;
use super::pacing::{self, RefineJob, interactive_size};
use super::viewer;

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
        let stale = match &self.view.images.view_state {
            ViewImage::Stale { .. } => true,
            ViewImage::Refining(r) => r.size() != view_px,
            ViewImage::Full => shown_size != Some(view_px),
            ViewImage::Reduced => false,
        };
        // Not while the pointer is held: on a CPU driver a refinement would take the CPU from the next reduced view.
        let refine = reduced && !interacting;
        if !stale && !refine && !self.view.images.slices_dirty {
            return Ok(());
        }
        let start = std::time::Instant::now();
        self.viewer.begin_frame();
        self.viewer.set_looks(&self.document.layers);
        self.viewer.set_procedural(self.procedural().ok().flatten());
        let views = self.view_deformations(std::time::Instant::now());
        self.viewer.set_view_deformations(views);
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
            self.view.images.view = Some(viewer::show(rs, target, self.view.images.view.take()));
            self.view.images.view_state = if quality == Quality::Full { ViewImage::Full } else { ViewImage::Reduced };
        } else if refine && !cpu {
            let target = self.viewer.render_view(&self.view.camera, &settings, Quality::Full, view_px, &glyphs)?;
            self.view.images.view = Some(viewer::show(rs, target, self.view.images.view.take()));
            self.view.images.view_state = ViewImage::Full;
        } else if refine {
            self.refine_in_background(egui, rs, view_px, &settings, &glyphs)?;
        }
        if self.view.images.slices_dirty {
            let planes = self.slice_planes();
            for (slot, plane) in self.view.images.slices.iter_mut().zip(planes) {
                let target = self.viewer.render_slice(&plane, &settings, &slice_glyphs)?;
                *slot = Some(viewer::show(rs, target, slot.take()));
            }
            self.view.images.slices_dirty = false;
        }
        self.viewer.ctx.check_errors().map_err(|e| anyhow!("{e}"))?;
        self.view.last_render_ms = start.elapsed().as_secs_f64() * 1e3;
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
        self.view.images.view = Some(viewer::show(rs, done.target, self.view.images.view.take()));
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
        self.view.images.slices_dirty || !matches!(self.view.images.view_state, ViewImage::Full)
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
