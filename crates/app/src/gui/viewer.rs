//! The app's GPU side, on eframe's own wgpu device: the two volumes, their transfer functions and prefiltered
//! copies, the moving volume's control texture, and the renderer; it draws the 3-D view and the slices into pooled
//! render targets that egui shows as native textures.

use eframe::egui_wgpu;
use warpbench_gpu::glam::Vec3;
use warpbench_gpu::{
    BSplineDesc, Capabilities, ControlEvalPass, ControlGridDesc, GlyphDrawData, GlyphInstance, GlyphRenderer,
    GlyphSettings, GlyphUniforms, GpuContext, GpuControlTexture, GpuEmptySpace, GpuFrame, GpuLayer, GpuPrefiltered,
    GpuTransferFunctions, GpuVolume, LayerStyle, OrbitCamera, PickHit, PickPass, PickRay, PickRequest, PickTarget,
    PrefilterPass, PrefilterSettings, PrefilteredTexels, PreparedControl, PreparedVolume, Preset, Probe, Procedural,
    Quality, RaycastDrawData, RaycastRenderer, RenderSettings, RenderTarget, SlicePlane, TexturePool, TpsDesc,
    ViewDeformation, VolumeBudget,
};
use warpbench_io::Volume;

use crate::project::document::Look;
use crate::scene;

/// What preparing a volume for the GPU needs to know about the device: plain values, so that the preparation can
/// run on a loading thread.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DeviceFacts {
    pub capabilities: Capabilities,
    pub budget: VolumeBudget,
    /// A CPU driver (lavapipe, llvmpipe): the prefilter runs on the CPU, where it is many times faster.
    pub cpu_driver: bool,
}

impl DeviceFacts {
    #[must_use]
    pub fn of(ctx: &GpuContext) -> Self {
        Self {
            capabilities: ctx.capabilities,
            budget: VolumeBudget::for_device(&ctx.limits),
            cpu_driver: ctx.is_cpu_driver(),
        }
    }
}

/// The prefilter's settings for shading gradients.
const PREFILTER: PrefilterSettings = PrefilterSettings { sigma_vox: 1.0, half_resolution: false };

/// One volume prepared for the GPU on any thread: its texels in the texture's format, on a CPU driver its
/// prefiltered copy, and its initial look.
#[derive(Debug)]
pub struct LayerData {
    prepared: PreparedVolume,
    /// Made on the CPU for a CPU driver; `None`: the GPU pass makes it at upload.
    prefiltered: Option<PrefilteredTexels>,
    /// The volume's automatic look ([`Look::auto`]).
    pub look: Look,
}

impl LayerData {
    /// Converts `v` to the texture's format (downsampled to the device's budget) and, for a CPU driver, prefilters
    /// it: the slow part of showing a volume, done here so that a loading thread can do it.
    pub fn prepare(v: &Volume, facts: DeviceFacts) -> anyhow::Result<Self> {
        let prepared =
            PreparedVolume::prepare(&scene::volume_desc(v), facts.capabilities, facts.budget).map_err(gpu_error)?;
        let prefiltered = facts.cpu_driver.then(|| PrefilteredTexels::from_volume(&prepared, PREFILTER));
        Ok(Self { prepared, prefiltered, look: Look::auto(v) })
    }
}

/// One volume on the GPU.
#[derive(Debug)]
pub struct Layer {
    pub volume: GpuVolume,
    pub prefiltered: GpuPrefiltered,
}

impl Layer {
    /// Uploads `data`, prefiltering it with `pass` unless it comes prefiltered.
    fn upload(ctx: &GpuContext, pass: &PrefilterPass, data: &LayerData) -> anyhow::Result<Self> {
        let volume = GpuVolume::upload(ctx, &data.prepared).map_err(gpu_error)?;
        let prefiltered = match &data.prefiltered {
            Some(texels) => GpuPrefiltered::upload(ctx, texels, PREFILTER),
            None => pass.run(ctx, &volume, PREFILTER),
        }
        .map_err(gpu_error)?;
        Ok(Self { volume, prefiltered })
    }
}

/// How a volume with `look` is drawn, its transfer function in row `tf_row`.
fn style(look: &Look, tf_row: u32) -> LayerStyle {
    let window = look.window();
    LayerStyle {
        window,
        tf_row,
        opacity_scale: 1.0,
        visible: look.visible,
        iso_value: window.low() + 0.3 * window.width,
    }
}

/// A rendered image and the egui texture that shows it.
#[derive(Debug)]
pub struct Shown {
    pub target: RenderTarget,
    pub texture_id: eframe::egui::TextureId,
}

/// The renderer and the scene's GPU resources.
#[derive(Debug)]
pub struct Viewer {
    /// Shared with the thread that refines the 3-D view on a CPU driver ([`super::pacing::RefineJob`]).
    pub ctx: std::sync::Arc<GpuContext>,
    renderer: std::sync::Arc<RaycastRenderer>,
    glyphs: GlyphRenderer,
    picker: PickPass,
    prefilter: PrefilterPass,
    pool: TexturePool,
    pub fixed: Layer,
    pub moving: Layer,
    /// The looks the frames are drawn with (fixed, moving), set by [`Self::set_looks`].
    looks: [Look; 2],
    tfs: GpuTransferFunctions,
    /// The presets `tfs` holds, fixed then moving.
    tf_presets: [Preset; 2],
    /// The moving volume's procedural deformation ([`crate::procedural`]), set by [`Self::set_procedural`].
    procedural: Option<Procedural>,
    /// The view deformations the 3-D view's (fixed, moving) layers are drawn and picked through (the attention lens,
    /// the leafer), set by [`Self::set_view_deformations`]; the slices are drawn without them.
    view_deformations: [Option<ViewDeformation>; 2],
    pub control: Option<GpuControlTexture>,
    /// Evaluates TPS pull-backs straight into the control texture, made on first use.
    control_eval: Option<ControlEvalPass>,
    /// `control` came from `control_eval` (so it can be written again in place).
    control_from_eval: bool,
    /// The texels of an uploaded `control` (not of one evaluated on the GPU), for the empty-space grid's
    /// per-brick displacement bounds.
    control_texels: Option<PreparedControl>,
    /// The empty-space grid of the current looks, volumes and warp, rebuilt when they change ([`Self::frame_data`]).
    empty_space: std::sync::Mutex<Option<GpuEmptySpace>>,
}

fn gpu_error(e: warpbench_gpu::GpuError) -> anyhow::Error {
    anyhow::Error::from(e).context("GPU")
}

impl Viewer {
    /// The device of `render_state` (the window's).
    #[must_use]
    pub fn context(render_state: &egui_wgpu::RenderState) -> GpuContext {
        GpuContext::from_device(
            render_state.adapter.get_info(),
            render_state.device.clone(),
            render_state.queue.clone(),
        )
    }

    /// Prepares and uploads both volumes to `ctx`'s device (the window's, or a headless one for benchmarks).
    pub fn with_context(ctx: GpuContext, fixed: &Volume, moving: &Volume) -> anyhow::Result<Self> {
        let facts = DeviceFacts::of(&ctx);
        Self::from_layers(ctx, &LayerData::prepare(fixed, facts)?, &LayerData::prepare(moving, facts)?)
    }

    /// Uploads two prepared volumes to `ctx`'s device.
    pub fn from_layers(ctx: GpuContext, fixed_data: &LayerData, moving_data: &LayerData) -> anyhow::Result<Self> {
        let renderer = RaycastRenderer::new(&ctx).map_err(gpu_error)?;
        let glyphs = GlyphRenderer::new(&ctx).map_err(gpu_error)?;
        let prefilter = PrefilterPass::new(&ctx).map_err(gpu_error)?;
        let picker = PickPass::new(&ctx, &renderer).map_err(gpu_error)?;
        let pool = TexturePool::new(&ctx.device);
        let fixed = Layer::upload(&ctx, &prefilter, fixed_data)?;
        let moving = Layer::upload(&ctx, &prefilter, moving_data)?;
        let looks = [fixed_data.look, moving_data.look];
        let tf_presets = looks.map(|l| l.preset.gpu());
        let tfs = GpuTransferFunctions::upload(&ctx, &tf_presets.map(Preset::transfer_function));
        Ok(Self {
            ctx: std::sync::Arc::new(ctx),
            renderer: std::sync::Arc::new(renderer),
            glyphs,
            picker,
            prefilter,
            pool,
            fixed,
            moving,
            looks,
            tfs,
            tf_presets,
            procedural: None,
            view_deformations: [None; 2],
            control: None,
            control_eval: None,
            control_from_eval: false,
            control_texels: None,
            empty_space: std::sync::Mutex::new(None),
        })
    }

    /// Replaces the fixed (`fixed`) or the moving volume with a prepared one, keeping the other on the GPU.
    pub fn replace_layer(&mut self, fixed: bool, data: &LayerData) -> anyhow::Result<()> {
        let layer = Layer::upload(&self.ctx, &self.prefilter, data)?;
        *(if fixed { &mut self.fixed } else { &mut self.moving }) = layer;
        // The new volume may share the old one's geometry and look: its grid is not the old one's.
        self.forget_empty_space();
        Ok(())
    }

    /// Draws the next frames with `looks` (fixed, moving), uploading the transfer functions when a preset changed.
    pub fn set_looks(&mut self, looks: &[Look; 2]) {
        self.looks = *looks;
        let wanted = looks.map(|l| l.preset.gpu());
        if wanted != self.tf_presets {
            self.tfs = GpuTransferFunctions::upload(&self.ctx, &wanted.map(Preset::transfer_function));
            self.tf_presets = wanted;
        }
    }

    /// Draws and picks the next frames with the moving volume deformed by `procedural` (`None`: undeformed). The
    /// empty-space grid follows by its key.
    pub fn set_procedural(&mut self, procedural: Option<Procedural>) {
        self.procedural = procedural;
    }

    /// Draws and picks the next 3-D frames of the (fixed, moving) volumes through `views` (`None`: undeformed). The
    /// slices are drawn without them.
    pub fn set_view_deformations(&mut self, views: [Option<ViewDeformation>; 2]) {
        self.view_deformations = views;
    }

    /// The view deformations the 3-D view was last drawn through (fixed, moving).
    #[must_use]
    pub fn view_deformations(&self) -> [Option<ViewDeformation>; 2] {
        self.view_deformations
    }

    /// The 3-D view's frame: each volume through its view deformation.
    fn frame(&self) -> GpuFrame<'_> {
        let mut frame = self.slice_frame();
        [frame.fixed.view, frame.moving.view] = self.view_deformations;
        frame
    }

    /// The slices' frame: no view deformation.
    fn slice_frame(&self) -> GpuFrame<'_> {
        GpuFrame {
            fixed: GpuLayer {
                volume: &self.fixed.volume,
                control: None,
                prefiltered: Some(&self.fixed.prefiltered),
                style: style(&self.looks[0], 0),
                procedural: None,
                view: None,
            },
            moving: GpuLayer {
                volume: &self.moving.volume,
                control: self.control.as_ref(),
                prefiltered: Some(&self.moving.prefiltered),
                style: style(&self.looks[1], 1),
                procedural: self.procedural,
                view: None,
            },
            tfs: &self.tfs,
        }
    }

    /// The 3-D view at `size_px`, with `glyphs` over it.
    pub fn render_view(
        &self,
        camera: &OrbitCamera,
        settings: &RenderSettings,
        quality: Quality,
        size_px: (u32, u32),
        glyphs: &[GlyphInstance],
    ) -> anyhow::Result<RenderTarget> {
        let target = self.view_target(size_px);
        let data = self.view_data(camera, settings, quality, size_px);
        self.renderer.render(&self.ctx, &data, &target).map_err(gpu_error)?;
        self.draw_view_glyphs(camera, &target, glyphs)?;
        Ok(target)
    }

    fn view_data(
        &self,
        camera: &OrbitCamera,
        settings: &RenderSettings,
        quality: Quality,
        size_px: (u32, u32),
    ) -> RaycastDrawData {
        self.frame_data(camera, &settings.at(quality), size_px)
    }

    /// A 3-D frame's draw data, skipping empty space by the grid of the current looks (built here when they, the
    /// volumes or the warp changed; the image is the same as without it).
    fn frame_data(&self, camera: &OrbitCamera, settings: &RenderSettings, size_px: (u32, u32)) -> RaycastDrawData {
        let frame = self.frame();
        let box_ref = frame.proxy_box_ref();
        let key = frame.empty_space_key(frame.default_lattice(box_ref));
        let mut grid = self.empty_space.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
        if grid.as_ref().is_none_or(|g| g.key != key) {
            *grid = Some(frame.empty_space(&self.ctx, box_ref, [None, self.control_texels.as_ref()]));
        }
        RaycastDrawData::new_with_empty_space(
            &self.ctx,
            &self.renderer,
            &frame,
            camera,
            settings,
            size_px,
            grid.as_ref(),
        )
    }

    /// Drops the empty-space grid, so that the next frame builds one.
    fn forget_empty_space(&mut self) {
        *self.empty_space.get_mut().unwrap_or_else(std::sync::PoisonError::into_inner) = None;
    }

    /// A render target for the 3-D view at `size_px`, from the pool.
    #[must_use]
    pub fn view_target(&self, size_px: (u32, u32)) -> RenderTarget {
        RenderTarget::from_pool(&self.pool, size_px.0, size_px.1)
    }

    /// Renders the rows `rows` of the 3-D view into `target` (its size is the view's), without glyphs: a band of a
    /// view rendered over several UI frames. A band from row 0 clears the target; later ones keep earlier bands.
    pub fn render_view_rows(
        &self,
        camera: &OrbitCamera,
        settings: &RenderSettings,
        quality: Quality,
        target: &RenderTarget,
        rows: std::ops::Range<u32>,
    ) -> anyhow::Result<()> {
        let data = self.view_data(camera, settings, quality, (target.width, target.height));
        self.renderer.render_rows(&self.ctx, &data, target, rows).map_err(gpu_error)
    }

    /// What a thread needs to render the full-quality 3-D view into `target` band by band
    /// ([`super::pacing::RefineJob`]).
    pub fn refine_work(
        &self,
        camera: &OrbitCamera,
        settings: &RenderSettings,
        target: RenderTarget,
        view_ms_per_px: Option<f64>,
    ) -> super::pacing::RefineWork {
        let data = self.view_data(camera, settings, Quality::Full, (target.width, target.height));
        super::pacing::RefineWork {
            ctx: self.ctx.clone(),
            renderer: self.renderer.clone(),
            data,
            target,
            view_ms_per_px,
        }
    }

    /// Draws `glyphs` over a rendered 3-D view, hidden where the volume's first hit is nearer.
    pub fn draw_view_glyphs(
        &self,
        camera: &OrbitCamera,
        target: &RenderTarget,
        glyphs: &[GlyphInstance],
    ) -> anyhow::Result<()> {
        if glyphs.is_empty() {
            return Ok(());
        }
        let gu = GlyphUniforms::for_view(camera, (target.width, target.height), &GlyphSettings::default());
        let data = GlyphDrawData::new(&self.ctx, &self.glyphs, gu, glyphs, Some(&target.hit_depth_view));
        self.glyphs.render(&self.ctx, &data, target).map_err(gpu_error)
    }

    /// A slice through `plane`, with `glyphs` near it.
    pub fn render_slice(
        &self,
        plane: &SlicePlane,
        settings: &RenderSettings,
        glyphs: &[GlyphInstance],
    ) -> anyhow::Result<RenderTarget> {
        let frame = self.slice_frame();
        let data = RaycastDrawData::for_slice(&self.ctx, &self.renderer, &frame, plane, settings);
        let target = RenderTarget::from_pool(&self.pool, plane.size.0, plane.size.1);
        self.renderer.render_slice(&self.ctx, &data, &target).map_err(gpu_error)?;
        if !glyphs.is_empty() {
            let gu = GlyphUniforms::for_slice(plane, &GlyphSettings::default()).map_err(gpu_error)?;
            let data = GlyphDrawData::new(&self.ctx, &self.glyphs, gu, glyphs, None);
            self.glyphs.render(&self.ctx, &data, &target).map_err(gpu_error)?;
        }
        Ok(target)
    }

    /// Picks the first hit of `probe` in the `target` volume (deformed, for the moving one) along the ray through
    /// framebuffer point `pixel` of the 3-D view (`size_px`, `camera`, `settings` as it was drawn).
    pub fn pick(
        &self,
        camera: &OrbitCamera,
        settings: &RenderSettings,
        size_px: (u32, u32),
        pixel: [f32; 2],
        target: PickTarget,
        probe: Probe,
    ) -> anyhow::Result<Option<PickHit>> {
        // The same grid as the frame's: the pick marches the samples the frame shows, skipping the same bricks.
        let data = self.frame_data(camera, settings, size_px);
        let ray = PickRay::from_pixel(&data.uniforms, pixel).map_err(gpu_error)?;
        let hits = self.picker.pick(&self.ctx, &data, &PickRequest::new(target, probe), &[ray]).map_err(gpu_error)?;
        Ok(hits.first().and_then(PickHit::found).copied())
    }

    /// The first hits of `probe` in the `target` volume along the rays through framebuffer points `pixels` of the 3-D
    /// view, all in one dispatch, as [`Self::pick`] picks one: the hit's point x_ref, or `None` where a ray hits
    /// nothing.
    pub fn pick_points(
        &self,
        camera: &OrbitCamera,
        settings: &RenderSettings,
        size_px: (u32, u32),
        pixels: &[[f32; 2]],
        target: PickTarget,
        probe: Probe,
    ) -> anyhow::Result<Vec<Option<[f64; 3]>>> {
        let data = self.frame_data(camera, settings, size_px);
        let rays = pixels
            .iter()
            .map(|&p| PickRay::from_pixel(&data.uniforms, p).map_err(gpu_error))
            .collect::<anyhow::Result<Vec<_>>>()?;
        let hits = self.picker.pick(&self.ctx, &data, &PickRequest::new(target, probe), &rays).map_err(gpu_error)?;
        Ok(hits.iter().map(|h| h.found().map(|h| h.x_ref.map(f64::from))).collect())
    }

    /// Evaluates the TPS pull-back `tps` into the control texture on `grid` on the GPU (reusing the current
    /// texture when it has the same size), instead of sampling it on the CPU and uploading it.
    pub fn evaluate_control_tps(&mut self, tps: &TpsDesc<'_>, grid: &ControlGridDesc) -> anyhow::Result<()> {
        self.evaluate_control(|pass, ctx, reuse| pass.evaluate_tps(ctx, tps, grid, reuse))
    }

    /// Evaluates the hierarchical B-spline pull-back `bspline` into the control texture on `grid` on the GPU, as
    /// [`Self::evaluate_control_tps`] does for a TPS.
    pub fn evaluate_control_bspline(
        &mut self,
        bspline: &BSplineDesc<'_>,
        grid: &ControlGridDesc,
    ) -> anyhow::Result<()> {
        self.evaluate_control(|pass, ctx, reuse| pass.evaluate_bspline(ctx, bspline, grid, reuse))
    }

    /// Runs `evaluate` with the control-evaluation pass (made on first use) and the texture it may write again.
    fn evaluate_control(
        &mut self,
        evaluate: impl FnOnce(
            &ControlEvalPass,
            &GpuContext,
            Option<GpuControlTexture>,
        ) -> warpbench_gpu::Result<GpuControlTexture>,
    ) -> anyhow::Result<()> {
        if self.control_eval.is_none() {
            self.control_eval = Some(ControlEvalPass::new(&self.ctx).map_err(gpu_error)?);
        }
        let Some(pass) = &self.control_eval else { unreachable!("made just above") };
        // An uploaded texture has other usages: only a texture the pass made is written again in place.
        let reuse = self.control.take().filter(|_| self.control_from_eval);
        self.control_texels = None;
        self.control = Some(evaluate(pass, &self.ctx, reuse).map_err(gpu_error)?);
        self.control_from_eval = true;
        // Written in place: its info (the grid's key) may be unchanged while the displacements are not.
        self.forget_empty_space();
        Ok(())
    }

    /// Whether the control texture was evaluated on the GPU (not uploaded from the CPU).
    #[must_use]
    pub fn control_made_on_gpu(&self) -> bool {
        self.control.is_some() && self.control_from_eval
    }

    /// Uploads a control texture (or removes the warp with `None`).
    pub fn set_control(&mut self, prepared: Option<&PreparedControl>) {
        self.control = prepared.map(|p| GpuControlTexture::upload(&self.ctx, p));
        self.control_texels = prepared.cloned();
        self.control_from_eval = false;
        self.forget_empty_space();
    }

    /// Marks a new UI frame for the texture pool, freeing targets idle for a few frames.
    pub fn begin_frame(&self) {
        self.pool.begin_frame();
        let _freed = self.pool.trim(8);
    }

    /// The box of both volumes, for the camera.
    #[must_use]
    pub fn scene_box(&self) -> (Vec3, Vec3) {
        let f = &self.fixed.volume.info;
        (f.box_min_lps.as_vec3(), f.box_max_lps.as_vec3())
    }
}

/// Shows `target` through egui: registers its colour texture, or re-points `previous` at it.
#[must_use]
pub fn show(render_state: &egui_wgpu::RenderState, target: RenderTarget, previous: Option<Shown>) -> Shown {
    let mut renderer = render_state.renderer.write();
    let texture_id = match previous {
        Some(old) => {
            renderer.update_egui_texture_from_wgpu_texture(
                &render_state.device,
                &target.view,
                eframe::wgpu::FilterMode::Linear,
                old.texture_id,
            );
            old.texture_id
        }
        None => renderer.register_native_texture(&render_state.device, &target.view, eframe::wgpu::FilterMode::Linear),
    };
    Shown { target, texture_id }
}

/// The fits make the viewer's control texture through this ([`crate::fit`] does not know the window).
impl crate::fit::ControlTarget for Viewer {
    fn float32_filterable(&self) -> bool {
        self.ctx.capabilities.float32_filterable
    }

    fn upload(&mut self, prepared: &PreparedControl) {
        self.set_control(Some(prepared));
    }

    fn clear(&mut self) {
        self.set_control(None);
    }

    fn evaluate_tps(&mut self, tps: &TpsDesc<'_>, grid: &ControlGridDesc) -> anyhow::Result<()> {
        self.evaluate_control_tps(tps, grid)
    }

    fn evaluate_bspline(&mut self, bspline: &BSplineDesc<'_>, grid: &ControlGridDesc) -> anyhow::Result<()> {
        self.evaluate_control_bspline(bspline, grid)
    }
}
