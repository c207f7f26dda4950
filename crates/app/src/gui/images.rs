//! The 3-D view's and the slices' images as egui shows them, and what must be rendered again: on a GPU a changed
//! view is drawn again at once; on a CPU driver it is drawn reduced and then refined band by band ([`super::pacing`]).

use anyhow::{Context as _, anyhow};
use warpbench_gpu::Quality;

use super::Ready;
use super::pacing::{self, Refine, interactive_size};
use super::viewer::{self, Shown};

/// Where the 3-D view's image stands. Only [`Ready::render`], [`Ready::refine_band`] and [`Ready::invalidate_view`]
/// move it from one state to the next.
#[derive(Debug)]
pub(crate) enum ViewImage {
    /// Must be rendered again (the camera, the warp or a setting changed); `full_shown`: the image still shown until
    /// then is a full-quality one.
    Stale { full_shown: bool },
    /// Shown at the interaction rate and size; a full one is to follow.
    Reduced,
    /// On a CPU driver, the full view being rendered band by band ([`pacing`]) while the reduced one is shown.
    Refining(Box<Refine>),
    /// Shown at full quality and size.
    Full,
}

impl ViewImage {
    /// Whether the image shown is the full-quality one.
    fn full_shown(&self) -> bool {
        match self {
            Self::Stale { full_shown } => *full_shown,
            Self::Full => true,
            Self::Reduced | Self::Refining(_) => false,
        }
    }
}

/// The 3-D view's and the slices' images as egui shows them, and what needs rendering again.
#[derive(Debug)]
pub(crate) struct Images {
    pub(crate) view: Option<Shown>,
    pub(crate) view_state: ViewImage,
    pub(crate) slices: [Option<Shown>; 3],
    pub(crate) slices_dirty: bool,
    /// Measured cost of the 3-D view on a CPU driver (ms per pixel, full quality), for the interaction size and the
    /// bands.
    pub(crate) view_ms_per_px: Option<f64>,
}

impl Default for Images {
    fn default() -> Self {
        Self {
            view: None,
            view_state: ViewImage::Stale { full_shown: true },
            slices: [None, None, None],
            slices_dirty: true,
            view_ms_per_px: None,
        }
    }
}

impl Ready {
    /// Renders what changed (the 3-D view at `view_px`, the slices) and hands the images to egui.
    ///
    /// On a GPU a changed view is drawn again at once: at the interaction sample rate while the user interacts
    /// (`interacting`: a button is held), fully otherwise. On a CPU driver a changed view is drawn reduced (the
    /// interaction rate, at a size that renders in about [`pacing::INTERACTIVE_BUDGET_MS`]), and then each frame
    /// renders one band of the full view until it is done and shown ([`pacing`]).
    pub(crate) fn render(
        &mut self,
        rs: &eframe::egui_wgpu::RenderState,
        view_px: (u32, u32),
        interacting: bool,
    ) -> anyhow::Result<()> {
        let cpu = self.viewer.ctx.is_cpu_driver();
        let shown_size = self.images.view.as_ref().map(|v| (v.target.width, v.target.height));
        let reduced = !self.images.view_state.full_shown();
        let stale = match &self.images.view_state {
            ViewImage::Stale { .. } => true,
            ViewImage::Refining(r) => r.size() != view_px,
            ViewImage::Full => shown_size != Some(view_px),
            ViewImage::Reduced => false,
        };
        let refine = reduced && (cpu || !interacting);
        if !stale && !refine && !self.images.slices_dirty {
            return Ok(());
        }
        let start = std::time::Instant::now();
        self.viewer.begin_frame();
        self.viewer.set_looks(&self.document.layers);
        let glyphs = self.glyphs();
        let settings = self.document.settings.render_settings();
        if stale {
            let (quality, px) = if interacting || cpu {
                let measured = self.images.view_ms_per_px.or(Some(pacing::CPU_GUESS_MS_PER_PX));
                (Quality::Interactive, interactive_size(view_px, if cpu { measured } else { None }))
            } else {
                (Quality::Full, view_px)
            };
            let target = self.viewer.render_view(&self.camera, &settings, quality, px, &glyphs)?;
            self.images.view = Some(viewer::show(rs, target, self.images.view.take()));
            self.images.view_state = if quality == Quality::Full { ViewImage::Full } else { ViewImage::Reduced };
        } else if refine && !cpu {
            let target = self.viewer.render_view(&self.camera, &settings, Quality::Full, view_px, &glyphs)?;
            self.images.view = Some(viewer::show(rs, target, self.images.view.take()));
            self.images.view_state = ViewImage::Full;
        } else if refine {
            self.refine_band(rs, view_px, &settings, &glyphs)?;
        }
        if self.images.slices_dirty {
            let planes = self.slice_planes();
            for (slot, plane) in self.images.slices.iter_mut().zip(planes) {
                let target = self.viewer.render_slice(&plane, &settings, &glyphs)?;
                *slot = Some(viewer::show(rs, target, slot.take()));
            }
            self.images.slices_dirty = false;
        }
        self.viewer.ctx.check_errors().map_err(|e| anyhow!("{e}"))?;
        self.last_render_ms = start.elapsed().as_secs_f64() * 1e3;
        Ok(())
    }

    /// Renders the next band of the full 3-D view on a CPU driver, waits for it (so that it is measured and the UI
    /// frame does not queue behind more than one band), and shows the view once the last band is done.
    pub(crate) fn refine_band(
        &mut self,
        rs: &eframe::egui_wgpu::RenderState,
        view_px: (u32, u32),
        settings: &warpbench_gpu::RenderSettings,
        glyphs: &[warpbench_gpu::GlyphInstance],
    ) -> anyhow::Result<()> {
        if !matches!(self.images.view_state, ViewImage::Refining(_)) {
            self.images.view_state = ViewImage::Refining(Box::new(Refine::new(self.viewer.view_target(view_px))));
        }
        let ViewImage::Refining(refine) = &mut self.images.view_state else { return Ok(()) };
        let band = refine.bands.next(self.images.view_ms_per_px);
        let band_start = std::time::Instant::now();
        self.viewer.render_view_rows(&self.camera, settings, Quality::Full, &refine.target, band.clone())?;
        self.viewer.ctx.wait_idle().map_err(|e| anyhow!("{e}"))?;
        refine.bands.rendered(&band, band_start.elapsed().as_secs_f64() * 1e3);
        // Done: back to the reduced state until the full image is shown (a failure here starts the bands again).
        if refine.bands.done()
            && let ViewImage::Refining(done) = std::mem::replace(&mut self.images.view_state, ViewImage::Reduced)
        {
            self.images.view_ms_per_px = done.bands.ms_per_px();
            self.viewer.draw_view_glyphs(&self.camera, &done.target, glyphs)?;
            self.images.view = Some(viewer::show(rs, done.target, self.images.view.take()));
            self.images.view_state = ViewImage::Full;
        }
        Ok(())
    }

    /// On a CPU driver, how much of the full 3-D view is rendered while it is rendered band by band (0..1).
    #[must_use]
    pub fn view_refine_progress(&self) -> Option<f32> {
        match &self.images.view_state {
            ViewImage::Refining(r) => Some(r.bands.progress()),
            _ => None,
        }
    }

    /// The 3-D view's image shown now, read back (premultiplied RGBA8, rows top to bottom).
    pub fn read_view(&self) -> anyhow::Result<Vec<u8>> {
        let shown = self.images.view.as_ref().context("no 3-D view is shown")?;
        shown.target.read_back(&self.viewer.ctx).map_err(|e| anyhow!("{e}"))
    }

    /// The size of the 3-D view's image shown now, and whether it is the full-quality one.
    #[must_use]
    pub fn view_shown(&self) -> Option<((u32, u32), bool)> {
        let v = self.images.view.as_ref()?;
        Some(((v.target.width, v.target.height), self.images.view_state.full_shown()))
    }

    /// Marks the 3-D view and the slices for re-rendering.
    pub fn invalidate(&mut self) {
        self.invalidate_view();
        self.images.slices_dirty = true;
    }

    /// Marks the 3-D view only (the camera moved).
    pub fn invalidate_view(&mut self) {
        let full_shown = self.images.view_state.full_shown();
        self.images.view_state = ViewImage::Stale { full_shown };
    }

    /// Marks the slices only (a slice moved or turned).
    pub fn invalidate_slices(&mut self) {
        self.images.slices_dirty = true;
    }

    /// Whether something waits to be rendered.
    #[must_use]
    pub fn needs_render(&self) -> bool {
        self.images.slices_dirty || !matches!(self.images.view_state, ViewImage::Full)
    }
}
