//! `warpbench render`: one frame of the fixed volume, or of the fixed and the deformed moving volume blended, to a
//! PNG, headless, with the renderer and options of the app. This is how docs and bug reports get pictures.
//!
//! Without `--moving` only the fixed volume is drawn. With `--moving` and landmarks, the moving volume is pulled
//! back through the fitted warp (a control texture of `--grid`³ texels over the fixed box) and the landmark glyphs
//! are drawn: each fixed (target) point qᵢ in blue, each moving (source) point where the warp shows it, d(pᵢ), in
//! orange, and a line between them (the residual; zero length for an interpolating warp). With `--field F` instead of
//! landmarks, the moving volume is pulled back through the displacement field (u(x) = x + D(x), read by
//! [`crate::warp::read_pullback_field`], or for a Learn2Reg `.npz` against the two volumes' voxels, or an FNIRT warp
//! in their FSL coordinates, by [`crate::warp::read_pair_field`]) sampled into the same control texture, and no glyphs
//! are drawn. `--slice`
//! draws a slice of the fixed grid instead of the 3-D view. `--procedural KIND` deforms the moving volume in the shader
//! by `eval`'s synthetic warp of that kind ([`crate::procedural`]), read at p(u(x)) after the warp.

use std::path::{Path, PathBuf};

use anyhow::{Context, anyhow};
use warpbench_gpu::glam::{Vec2, Vec3};
use warpbench_gpu::{
    BlendMode, GlyphDrawData, GlyphPair, GlyphRenderer, GlyphSettings, GlyphStyle, GlyphUniforms, GpuContext,
    GpuControlTexture, GpuFrame, GpuLayer, GpuTransferFunctions, GpuVolume, LayerStyle, OrbitCamera, PrefilterPass,
    PrefilterSettings, PreparedControl, PreparedVolume, Preset, Projection, RaycastDrawData, RaycastRenderer,
    RenderSettings, RenderTarget, Shading, SlicePlane, VolumeBudget, pair_glyphs,
};
use warpbench_io::Volume;
use warpbench_solver::control::{ControlGrid, ControlTexture};
use warpbench_solver::spaces::{Fixed, Moving};
use warpbench_solver::warp::Warp;

use crate::args::{PairArgs, RenderSettingsArgs, SliceSpec};
use crate::brushed::Brushed;
use crate::exit::Failure;
use crate::inputs::{self, LandmarkWarp, OutputFile, Role, VolumeArg};
use crate::project::stack::Layers;
use crate::{fit, scene, settings};

/// What `warpbench render --help` says above the options; its first paragraph is the summary that `-h` and
/// `warpbench --help` show.
const HELP: &str = "\
Render one frame of the fixed volume, or of the fixed and the deformed moving volume blended, to PNG,
headless, with the app's renderer.

With --moving and landmarks the moving volume is pulled back through the fitted warp and the landmark pairs
are drawn (fixed points blue, moving points orange where the warp shows them); with --field instead, through
that pull-back displacement field, without glyphs (a Learn2Reg .npz is read in the two volumes' voxels).
--slice draws a slice of the fixed grid instead of the
3-D view. Examples:

    warpbench render --fixed ct.nii.gz --out ct.png
    warpbench render --fixed ct.nii.gz --moving mr.nii.gz --landmarks pairs.csv --blend checkerboard --out pair.png
    warpbench render --fixed ct.nii.gz --moving mr.nii.gz --landmarks pairs.csv --slice axial:40 --out ax.png
    warpbench render --fixed ct.nii.gz --moving mr.nii.gz --field mr_to_ct1Warp.nii.gz --slice axial --out ax.png";

/// The arguments of `warpbench render`.
#[derive(Debug, clap::Args)]
#[command(about = crate::args::summary(HELP), long_about = HELP)]
pub struct RenderArgs {
    /// The fixed volume (the render space): NIfTI, NRRD or a DICOM series folder; with --session, the session's by
    /// default.
    #[arg(long, required_unless_present = "session")]
    pub fixed: Option<PathBuf>,
    /// The moving volume, shown deformed by the landmark warp; with --session, the session's by default.
    #[arg(long)]
    pub moving: Option<PathBuf>,
    #[command(flatten)]
    pub parts: crate::args::PartArgs,
    #[command(flatten)]
    pub pairs: PairArgs,
    /// A pull-back displacement field to show the moving volume through instead of landmarks (ITK or ANTs NIfTI,
    /// NRRD, MetaImage, elastix, ITK HDF5, or Learn2Reg's .npz in the two volumes' voxels); no glyphs are drawn.
    #[arg(long, conflicts_with_all = ["landmarks", "moving_points", "fixed_points", "session", "method", "stiffness", "levels", "initial", "initial_field"])]
    pub field: Option<PathBuf>,
    #[command(flatten)]
    pub field_format: crate::warp::FieldFormatArgs,
    /// Control-texture texels per axis over the fixed box (2..=256).
    #[arg(long, default_value_t = 64)]
    pub grid: usize,
    #[command(flatten)]
    pub settings: RenderSettingsArgs,
    /// The PNG to write.
    #[arg(long)]
    pub out: PathBuf,
    /// Overwrite --out if it exists.
    #[arg(long)]
    pub force: bool,
    /// No progress bars or messages.
    #[arg(long, short)]
    pub quiet: bool,
}

/// What was rendered, for the caller's message.
#[derive(Clone, Debug)]
pub struct Rendered {
    pub size: (u32, u32),
    pub adapter: String,
    pub pairs: usize,
}

/// One volume on the GPU with its style.
struct Layer {
    gpu: GpuVolume,
    prefiltered: Option<warpbench_gpu::GpuPrefiltered>,
    style: LayerStyle,
}

fn upload(
    ctx: &GpuContext,
    volume: &Volume,
    preset: Option<Preset>,
    tf_row: u32,
    prefilter: Option<&PrefilterPass>,
    quiet: bool,
) -> Result<(Layer, Preset), Failure> {
    let prepared =
        PreparedVolume::prepare(&scene::volume_desc(volume), ctx.capabilities, VolumeBudget::for_device(&ctx.limits))
            .map_err(|e| Failure::BadInput(anyhow!("preparing the volume for the GPU: {e}")))?;
    if !quiet {
        for w in &prepared.warnings {
            eprintln!("warning: {w}");
        }
    }
    let gpu = GpuVolume::upload(ctx, &prepared).map_err(gpu_failure)?;
    let prefiltered = match prefilter {
        Some(pass) => {
            let settings = PrefilterSettings { sigma_vox: 1.0, half_resolution: false };
            Some(pass.run(ctx, &gpu, settings).map_err(gpu_failure)?)
        }
        None => None,
    };
    let (preset, window) = scene::auto_style(volume, preset);
    let iso_value = window.low() + 0.3 * window.width;
    let style = LayerStyle { window, tf_row, opacity_scale: 1.0, visible: true, iso_value };
    Ok((Layer { gpu, prefiltered, style }, preset))
}

fn gpu_failure(e: warpbench_gpu::GpuError) -> Failure {
    Failure::Internal(anyhow::Error::from(e).context("GPU"))
}

/// Renders and writes the PNG. Loads, fits, renders, then writes atomically; says what it wrote on stderr unless
/// `--quiet`.
pub fn run(args: RenderArgs) -> Result<Rendered, Failure> {
    let RenderArgs {
        fixed: fixed_path,
        moving: moving_path,
        parts,
        pairs,
        field: field_path,
        field_format,
        grid: grid_n,
        settings: view,
        out,
        force,
        quiet,
    } = args;
    let given = LandmarkWarp::try_from(pairs).map_err(Failure::BadInput)?;
    let ([fixed_path, moving_path], parts) =
        given.resolve_volumes([fixed_path, moving_path], parts, quiet).map_err(Failure::BadInput)?;
    let fixed_path = fixed_path.ok_or_else(|| Failure::BadInput(anyhow!("give --fixed")))?;
    let output = OutputFile { path: out, force };
    let procedural_spec = view.procedural_spec();
    let mut inputs_paths: Vec<&Path> = vec![&fixed_path];
    inputs_paths.extend(moving_path.as_deref());
    inputs_paths.extend(given.paths());
    inputs_paths.extend(field_path.as_deref());
    output.check(&inputs_paths).map_err(Failure::BadInput)?;
    let base = given
        .warp
        .initial
        .as_deref()
        .map(|p| (p, "--initial"))
        .or_else(|| given.warp.base_field.as_ref().map(|f| (f.path(), "--initial-field")));
    if let (Some((path, flag)), None) = (base, &given.landmarks) {
        return Err(Failure::BadInput(anyhow!(
            "{}: {flag} starts a landmark warp: give landmarks too (a file with no pairs shows it alone)",
            path.display()
        )));
    }
    if given.landmarks.is_some() && field_path.is_some() {
        return Err(Failure::BadInput(anyhow!(
            "give either --field or landmarks (--landmarks, or --moving-points with --fixed-points), not both"
        )));
    }
    if given.landmarks.is_some() && moving_path.is_none() {
        return Err(Failure::BadInput(anyhow!("landmarks need a moving volume (--moving)")));
    }
    if field_path.is_some() && moving_path.is_none() {
        return Err(Failure::BadInput(anyhow!("--field needs a moving volume (--moving)")));
    }
    if procedural_spec.is_some() && moving_path.is_none() {
        return Err(Failure::BadInput(anyhow!(
            "--procedural deforms the moving volume: give --moving (the --fixed file itself shows the volume eval tests)"
        )));
    }
    // Read before the volumes: a field `render` refuses costs no loading. A Learn2Reg field or an FNIRT warp (in the
    // volumes' voxels or FSL coordinates) and an ITK transform file, which may need the fixed grid, are read after
    // them.
    let after = match &field_path {
        Some(path) => crate::warp::read_after_volumes(path, field_format.format)?,
        None => false,
    };
    let mut field = field_path
        .as_deref()
        .filter(|_| !after)
        .map(|p| crate::warp::read_pullback_field(p, None, quiet))
        .transpose()?;
    given.warp.check_start().map_err(Failure::BadInput)?;
    let [fixed_part, moving_part] = parts.parts();
    let fixed = VolumeArg { path: &fixed_path, part: fixed_part.as_ref(), role: Role::Fixed };
    let fixed = inputs::load_volume(&fixed, quiet).map_err(Failure::BadInput)?;
    let moving = moving_path
        .as_deref()
        .map(|path| inputs::load_volume(&VolumeArg { path, part: moving_part.as_ref(), role: Role::Moving }, quiet))
        .transpose()
        .map_err(Failure::BadInput)?;
    if let (true, Some(path), Some(moving)) = (after, &field_path, &moving) {
        field = Some(if field_format.format.reads_against_pair(path)? {
            crate::warp::read_pair_field(path, &fixed, moving, quiet)?
        } else {
            crate::warp::read_pullback_field(path, Some(&fixed), quiet)?
        });
    }
    let fixed_box = inputs::volume_box::<Fixed>(&fixed);
    let procedural = match (&procedural_spec, &moving) {
        (Some(spec), Some(m)) => Some(
            spec.build(inputs::volume_box::<Moving>(m))
                .with_context(|| format!("{}", moving_path.as_deref().unwrap_or(Path::new("")).display()))
                .map_err(Failure::BadInput)?,
        ),
        _ => None,
    };

    // The warp's control texture, and the glyphs when there are landmarks.
    let method = given.method().map_err(Failure::BadInput)?;
    let mut sampled: Option<(ControlGrid, ControlTexture)> = None;
    if let Some(field) = &field {
        sampled = Some(scene::control_texture(field, fixed_box, grid_n).map_err(Failure::BadInput)?);
    }
    let mut glyph_pairs = Vec::new();
    if let (Some(landmarks), Some(moving)) = (&given.landmarks, &moving) {
        let pairs = landmarks.pairs().map_err(Failure::BadInput)?;
        let start = given.warp.start(&fixed, moving).map_err(Failure::BadInput)?;
        let source = &landmarks.source;
        let c = inputs::correspondences(source, pairs, moving, &fixed, given.warp.min_pairs(&method))
            .map_err(Failure::BadInput)?;
        if !quiet {
            for w in fit::fit_warnings(&method, &c) {
                eprintln!("warpbench: warning: {w}");
            }
        }
        let brushed = Brushed::new(&given.warp.brush, &source.describe()).map_err(Failure::BadInput)?;
        if let (Some(b), false) = (&brushed, quiet) {
            let c = b.consistency();
            eprintln!("brush: its inverse undoes it within {:.4} mm (max; rms {:.5} mm)", c.max_mm, c.rms_mm);
        }
        // The stack: u (with a brush, u ∘ b⁻¹) into the texture, and the moving glyphs at d(p) (b(d(p))).
        let mut layers = Layers::new(start, brushed);
        layers.field = given.warp.field(&fixed, moving).map_err(Failure::BadInput)?;
        crate::inputs::note_field_warnings(layers.field.as_deref(), quiet);
        let pullback = fit::pullback_stack(&method, &c, fixed_box, layers.clone()).map_err(Failure::BadInput)?;
        let forward =
            fit::forward_stack(&method, &c, inputs::volume_box::<Moving>(moving), layers).map_err(Failure::BadInput)?;
        sampled = Some(pullback.control_texture(fixed_box, grid_n).map_err(Failure::BadInput)?);
        let shown = |p: &warpbench_io::geometry::Point3<Moving>| forward.apply(*p).coords();
        glyph_pairs = c
            .moving
            .iter()
            .zip(&c.fixed)
            .map(|(p, q)| GlyphPair {
                moving_ref: Some(Vec3::from_array(shown(p).map(|v| v as f32))),
                fixed_ref: Some(Vec3::from_array(q.coords().map(|v| v as f32))),
                selected: false,
                active: true,
            })
            .collect();
    }

    let ctx = GpuContext::headless().map_err(gpu_failure)?;
    let renderer = RaycastRenderer::new(&ctx).map_err(gpu_failure)?;
    let prefilter = match view.shading {
        settings::Shading::None => None,
        _ => Some(PrefilterPass::new(&ctx).map_err(gpu_failure)?),
    };
    let preset = view.preset.map(settings::Preset::gpu);
    let moving_preset = view.moving_preset.map(settings::Preset::gpu);
    let (fixed_layer, fixed_preset) = upload(&ctx, &fixed, preset, 0, prefilter.as_ref(), quiet)?;
    let moving_layer = match &moving {
        Some(m) => Some(upload(&ctx, m, moving_preset, 1, prefilter.as_ref(), quiet)?),
        None => None,
    };
    let moving_preset = moving_layer.as_ref().map_or(fixed_preset, |(_, p)| *p);
    let tfs =
        GpuTransferFunctions::upload(&ctx, &[fixed_preset.transfer_function(), moving_preset.transfer_function()]);
    let prepared_control = match &sampled {
        Some((grid, texture)) => {
            let desc = scene::control_desc(grid, texture);
            Some(PreparedControl::prepare(&desc, ctx.capabilities.float32_filterable).map_err(gpu_failure)?)
        }
        None => None,
    };
    let control = prepared_control.as_ref().map(|p| GpuControlTexture::upload(&ctx, p));

    let fixed_gpu = GpuLayer {
        volume: &fixed_layer.gpu,
        control: None,
        prefiltered: fixed_layer.prefiltered.as_ref(),
        style: fixed_layer.style,
        procedural: None,
        view: None,
    };
    let moving_gpu = match &moving_layer {
        Some((layer, _)) => GpuLayer {
            volume: &layer.gpu,
            control: control.as_ref(),
            prefiltered: layer.prefiltered.as_ref(),
            style: layer.style,
            procedural,
            view: None,
        },
        // Without a moving volume the fixed one fills the slot, hidden.
        None => GpuLayer { style: LayerStyle { visible: false, ..fixed_layer.style }, ..fixed_gpu },
    };
    let blend = if moving.is_some() {
        view.blend.mode(view.mix_weight.clamp(0.0, 1.0), view.checker_mm.max(0.1))
    } else {
        BlendMode::FixedOnly
    };
    let frame = GpuFrame { fixed: fixed_gpu, moving: moving_gpu, tfs: &tfs };
    let settings = RenderSettings {
        blend,
        samples_per_voxel: view.samples_per_voxel,
        shading: Shading::with_mode(view.shading.mode()),
        ..Default::default()
    };
    let glyph_renderer = GlyphRenderer::new(&ctx).map_err(gpu_failure)?;
    let glyphs = if view.no_glyphs { Vec::new() } else { pair_glyphs(&glyph_pairs, &GlyphStyle::default()) };

    let (target, glyph_uniforms, hit_depth) = if let Some(spec) = view.slice {
        let m = fixed.lps_from_index.rows();
        let mid = |a: usize| 0.5 * (fixed_box.min.coords()[a] + fixed_box.max.coords()[a]);
        let pos = |p: f64, a| if p.is_nan() { mid(a) } else { p };
        let plane = match spec {
            SliceSpec::Axial(p) => SlicePlane::axial(&m, fixed.dims, pos(p, 2)),
            SliceSpec::Coronal(p) => SlicePlane::coronal(&m, fixed.dims, pos(p, 1)),
            SliceSpec::Sagittal(p) => SlicePlane::sagittal(&m, fixed.dims, pos(p, 0)),
        };
        let data = RaycastDrawData::for_slice(&ctx, &renderer, &frame, &plane, &settings);
        let target = RenderTarget::new(&ctx, plane.size.0, plane.size.1);
        renderer.render_slice(&ctx, &data, &target).map_err(gpu_failure)?;
        let gu = GlyphUniforms::for_slice(&plane, &GlyphSettings::default()).map_err(gpu_failure)?;
        (target, gu, false)
    } else {
        let (lo, hi) = (fixed_box.min.coords(), fixed_box.max.coords());
        let lo = Vec3::from_array(lo.map(|v| v as f32));
        let hi = Vec3::from_array(hi.map(|v| v as f32));
        let projection =
            if view.perspective { Projection::Perspective { fov_y_rad: 0.6 } } else { Projection::Orthographic };
        let mut camera = OrbitCamera::fit(lo, hi, projection);
        if let Some(c) = view.camera {
            camera.azimuth_rad = c.azimuth_deg.to_radians();
            camera.elevation_rad = c.elevation_deg.to_radians();
            if let Some(d) = c.distance_mm {
                camera.distance_mm = d;
            }
        }
        camera.pan_mm = Vec2::ZERO;
        // Empty-space skipping: the same image, fewer samples.
        let empty_space = frame.empty_space(&ctx, frame.proxy_box_ref(), [None, prepared_control.as_ref()]);
        let data = RaycastDrawData::new_with_empty_space(
            &ctx,
            &renderer,
            &frame,
            &camera,
            &settings,
            view.size,
            Some(&empty_space),
        );
        let target = RenderTarget::new(&ctx, view.size.0, view.size.1);
        renderer.render(&ctx, &data, &target).map_err(gpu_failure)?;
        (target, GlyphUniforms::for_view(&camera, view.size, &GlyphSettings::default()), true)
    };
    if !glyphs.is_empty() {
        let view = hit_depth.then_some(&target.hit_depth_view);
        let data = GlyphDrawData::new(&ctx, &glyph_renderer, glyph_uniforms, &glyphs, view);
        glyph_renderer.render(&ctx, &data, &target).map_err(gpu_failure)?;
    }
    let mut rgba = target.read_back(&ctx).map_err(gpu_failure)?;
    // Premultiplied over black: the colour channels are the picture; make it opaque.
    for px in rgba.chunks_exact_mut(4) {
        px[3] = 255;
    }
    write_png(&output.path, &rgba, target.width, target.height)?;
    let rendered = Rendered { size: (target.width, target.height), adapter: ctx.describe(), pairs: glyph_pairs.len() };
    if !quiet {
        let warp = match &field_path {
            Some(field) => format!("field {}", field.display()),
            None => format!("{} landmark pairs", rendered.pairs),
        };
        let (width, height) = rendered.size;
        eprintln!("wrote {} ({width}×{height}, {warp}, {})", output.path.display(), rendered.adapter);
    }
    Ok(rendered)
}

/// Encodes RGBA8 as PNG and writes it atomically.
fn write_png(out: &Path, rgba: &[u8], width: u32, height: u32) -> Result<(), Failure> {
    let mut png = Vec::new();
    image::write_buffer_with_format(
        &mut std::io::Cursor::new(&mut png),
        rgba,
        width,
        height,
        image::ExtendedColorType::Rgba8,
        image::ImageFormat::Png,
    )
    .context("encoding the PNG")
    .map_err(Failure::Internal)?;
    warpbench_io::atomic::write_atomic(out, |w| w.write_all(&png))?;
    Ok(())
}
