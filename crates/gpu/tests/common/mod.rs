//! Shared fixtures for the GPU tests: small synthetic CT/MR-like volumes, a smooth warp, and helpers that render the
//! same frame on the GPU and with the CPU reference.

#![allow(dead_code, reason = "each test binary uses a different subset")]

use glam::{DVec3, Vec3};
use warpbench_gpu::cpu_reference::{self, CpuLayer};
use warpbench_gpu::headless::headless_or_skip;
use warpbench_gpu::{
    ControlDesc, FeatureRequest, FilterPrecision, FilterProbe, GpuContext, GpuControlTexture, GpuFrame, GpuLayer,
    GpuPrefiltered, GpuTransferFunctions, GpuVolume, LayerParams, LayerStyle, OrbitCamera, PrefilterPass,
    PrefilterSettings, PrefilteredTexels, PreparedControl, PreparedVolume, Preset, Procedural, RaycastDrawData,
    RaycastRenderer, RaycastUniforms, RenderSettings, RenderTarget, SlicePlane, TransferFunction, ViewDeformation,
    VolumeBudget, VolumeDesc, VolumeSamples, Window,
};

pub const N: usize = 64;

/// A headless context, or `None` (the test then returns early) without an adapter unless REQUIRE_GPU_ADAPTER=1.
pub fn context(request: FeatureRequest) -> Option<GpuContext> {
    let ctx = headless_or_skip(request)?;
    eprintln!("GPU: {} {:?}", ctx.describe(), ctx.capabilities);
    Some(ctx)
}

/// This device's hardware filter as [`FilterProbe`] measures it: the fractional bits of its weights (the fewest
/// among the formats the ray caster filters in hardware here; [`FilterProbe::RESOLVED_BITS`] when finer than it
/// resolves) and whether 8-bit volumes come back on their 255 steps. The GPU tests derive their tolerances from it
/// ([`Allowance`]).
#[derive(Clone, Copy, Debug)]
pub struct DeviceFilter {
    pub bits: u32,
    pub unorm8_results: bool,
    /// The device's own rounding, when the probe resolved it.
    pub model: Option<FilterPrecision>,
}

impl DeviceFilter {
    /// The device's filter as the probe measures it. `GPU_TEST_FILTER_BITS=b` makes it coarser, never finer: the
    /// tolerances a device with b-bit weights would get, read off this one (how benchmarks.md's 8-bit figures on
    /// lavapipe were made).
    pub fn measure(ctx: &GpuContext) -> Self {
        let measured = FilterProbe::new(ctx).and_then(|p| p.measure(ctx)).expect("filter probe");
        eprintln!("{}", measured.describe());
        let device = Self { bits: measured.bits(), unorm8_results: measured.unorm8_results(), model: measured.model() };
        match std::env::var("GPU_TEST_FILTER_BITS").ok().and_then(|b| b.parse::<u32>().ok()) {
            Some(bits) if bits < device.bits => {
                eprintln!("GPU_TEST_FILTER_BITS: tolerances for {bits}-bit filter weights");
                Self { bits, ..device }
            }
            _ => device,
        }
    }

    /// The models a conformant device like this one may follow ([`FilterPrecision::family`]), and this device's own
    /// when the probe resolved it.
    pub fn family(self) -> Vec<FilterPrecision> {
        let mut family = FilterPrecision::family(self.bits, self.unorm8_results).to_vec();
        family.extend(self.model.filter(|m| !family.contains(m)));
        family
    }
}

/// How far a conformant device may be from the exact CPU reference of one image: the reference computed with the
/// hardware lookups' weights rounded down, up, and each either way, at the device's bits ([`FilterPrecision::family`]),
/// beside the exact one. What remains beyond it is f32 evaluation order and the 8-bit rounding of the result, which
/// [`BASE_TOLERANCE`] covers.
pub struct Allowance {
    pub filter: DeviceFilter,
    pub exact: Vec<u8>,
    pub rounded: Vec<Vec<u8>>,
}

/// Per channel, beyond the filter's rounding: 1/255 because the GPU and the CPU each round their result to 8 bits
/// and may round values an ulp apart to different sides, and 1/255 for f32 evaluation order (exp2/log2, matrix
/// products, fused multiply-adds), accumulated over the ≤ 100 composited samples of a ray.
pub const BASE_TOLERANCE: u8 = 2;

impl Allowance {
    /// The exact image and its rounded variants, each from `render` with the hardware lookups at a precision.
    pub fn new(filter: DeviceFilter, render: impl Fn(FilterPrecision) -> Vec<u8>) -> Self {
        let exact = render(FilterPrecision::EXACT);
        let rounded = filter.family().iter().map(|&p| render(p)).collect();
        Self { filter, exact, rounded }
    }

    /// The largest channel difference between the exact image and a rounded one.
    pub fn filter_spread(&self) -> u8 {
        self.rounded.iter().map(|r| max_diff(&self.exact, r, 0).0).max().unwrap_or(0)
    }

    /// The largest channel difference a conformant device may show against the exact image:
    /// [`BASE_TOLERANCE`] + [`Self::filter_spread`].
    pub fn tolerance(&self) -> u8 {
        BASE_TOLERANCE.saturating_add(self.filter_spread())
    }

    /// The fraction of pixels that some rounded variant moves by more than `bound` in some channel from the exact
    /// image: where a threshold decision (an iso hit, a glyph's depth test) may flip under the filter's rounding. A
    /// device may round each lookup either way, so a pixel that any variant flips may flip on it: the union.
    pub fn fraction_over(&self, bound: u8) -> f32 {
        self.flipped(bound).iter().filter(|&&f| f).count() as f32 / (self.exact.len() / 4).max(1) as f32
    }

    /// Per pixel, whether some rounded variant moves it by more than `bound` in some channel.
    pub fn flipped(&self, bound: u8) -> Vec<bool> {
        let mut flipped = vec![false; self.exact.len() / 4];
        for r in &self.rounded {
            for (i, (p, q)) in self.exact.chunks_exact(4).zip(r.chunks_exact(4)).enumerate() {
                flipped[i] |= p.iter().zip(q).any(|(x, y)| x.abs_diff(*y) > bound);
            }
        }
        flipped
    }

    /// An iso image's per-pixel bound: [`BASE_TOLERANCE`] plus the largest difference between the exact and a
    /// rounded reference over the pixels where the rounding flips no hit. A rounded weight moves a hit along its ray
    /// by a fraction of a voxel, which changes its shade by a few /255 at most (the value there is the iso value, the
    /// normal comes from the same prefiltered texels a fraction of a voxel away); a difference of 16/255 or more is
    /// a flip: a hit on another surface, in another checkerboard cell, or none. Pixels past the bound are then
    /// counted against [`Self::fraction_over`] it, plus [`GRAZING_F32`].
    pub fn iso_bound(&self) -> u8 {
        const FLIP: u8 = 16;
        let spread = self
            .rounded
            .iter()
            .flat_map(|r| {
                self.exact.chunks_exact(4).zip(r.chunks_exact(4)).filter_map(|(p, q)| {
                    let d = p.iter().zip(q).map(|(x, y)| x.abs_diff(*y)).max().unwrap_or(0);
                    (d < FLIP).then_some(d)
                })
            })
            .max()
            .unwrap_or(0);
        BASE_TOLERANCE.saturating_add(spread)
    }

    /// Whether `gpu`, a device's render of the image, is one a conformant device with this filter may draw, and a
    /// line saying how far it is. [`Look::Smooth`]: every channel within [`Self::tolerance`]. [`Look::Thresholded`]
    /// (iso-surfaces): all but [`Self::fraction_over`] + [`GRAZING_F32`] of the pixels within [`Self::iso_bound`].
    pub fn judge(&self, gpu: &[u8], look: Look) -> (bool, String) {
        let pixels = (self.exact.len() / 4).max(1) as f32;
        match look {
            Look::Smooth => {
                let tolerance = self.tolerance();
                let (max, above) = max_diff(gpu, &self.exact, BASE_TOLERANCE);
                let line = format!("max {max}/255 ({above} channels > {BASE_TOLERANCE}); {}", self.describe());
                (max <= tolerance, line)
            }
            Look::Thresholded => {
                let bound = self.iso_bound();
                let over = pixels_over(gpu, &self.exact, bound) as f32 / pixels;
                let allowed = self.fraction_over(bound) + GRAZING_F32;
                let line = format!(
                    "{:.2}% of the pixels > {bound}/255 (allowed {:.2}%); {}",
                    100.0 * over,
                    100.0 * allowed,
                    self.describe()
                );
                (over <= allowed, line)
            }
        }
    }

    /// "filter b bits: spread s/255, tolerance t/255".
    pub fn describe(&self) -> String {
        let unorm8 = if self.filter.unorm8_results { ", 8-bit results" } else { "" };
        format!(
            "filter {} bits{unorm8}: spread {}/255, tolerance {}/255",
            self.filter.bits,
            self.filter_spread(),
            self.tolerance()
        )
    }
}

/// What an image's pixels depend on, for [`Allowance::judge`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Look {
    /// Colours that move smoothly with the filtered values (unlit and DVR frames, slices).
    Smooth,
    /// Threshold decisions (iso-surface hits), which a rounded weight can flip.
    Thresholded,
}

impl Look {
    pub fn of(mode: warpbench_gpu::ShadingMode) -> Self {
        if mode == warpbench_gpu::ShadingMode::Iso { Self::Thresholded } else { Self::Smooth }
    }
}

/// The share of an iso image's pixels whose hit the f32 order of the ray's setup alone may flip, whatever the
/// filter: one in a thousand (four pixels of a 64² image).
pub const GRAZING_F32: f32 = 0.001;

/// Pixels whose largest channel difference is above `limit`.
pub fn pixels_over(a: &[u8], b: &[u8], limit: u8) -> usize {
    a.chunks_exact(4)
        .zip(b.chunks_exact(4))
        .filter(|(p, q)| p.iter().zip(*q).any(|(x, y)| x.abs_diff(*y) > limit))
        .count()
}

/// Row-major `lps_from_index` for an n³ grid of `spacing` mm, centred on `centre`, rotated by `angle_rad` about z.
pub fn grid_lps_from_index(n: usize, spacing: f64, centre: [f64; 3], angle_rad: f64) -> [[f64; 4]; 4] {
    let (s, c) = angle_rad.sin_cos();
    let h = (n as f64 - 1.0) / 2.0;
    // p = R·(spacing·(i − h)) + centre
    let r = [[c * spacing, -s * spacing, 0.0], [s * spacing, c * spacing, 0.0], [0.0, 0.0, spacing]];
    let mut m = [[0.0; 4]; 4];
    for row in 0..3 {
        m[row][..3].copy_from_slice(&r[row]);
        m[row][3] = centre[row] - h * (r[row][0] + r[row][1] + r[row][2]);
    }
    m[3][3] = 1.0;
    m
}

fn smoothstep(e0: f64, e1: f64, x: f64) -> f64 {
    let t = ((x - e0) / (e1 - e0)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// A CT-like head: air −1000 HU, soft tissue 40 HU inside radius 0.42, a bone shell (1200 HU) at 0.36–0.42 of the
/// box, an off-centre dense blob; smooth edges (≈ 1.5 voxels). i16 samples.
pub fn ct_phantom(n: usize) -> Vec<i16> {
    let mut out = Vec::with_capacity(n * n * n);
    for k in 0..n {
        for j in 0..n {
            for i in 0..n {
                let p = DVec3::new(i as f64, j as f64, k as f64) / (n as f64 - 1.0) - DVec3::splat(0.5);
                let r = (p * DVec3::new(1.0, 1.15, 1.05)).length();
                let w = 1.5 / n as f64;
                let head = 1.0 - smoothstep(0.42 - w, 0.42 + w, r);
                let bone = smoothstep(0.36 - w, 0.36 + w, r) * head;
                let blob = 1.0 - smoothstep(0.06, 0.06 + 2.0 * w, (p - DVec3::new(0.12, -0.05, 0.1)).length());
                let hu = -1000.0 + 1040.0 * head + 1160.0 * bone + 600.0 * blob;
                out.push(hu.round() as i16);
            }
        }
    }
    out
}

/// An MR-like head: a bright ellipsoidal "brain" with two darker "ventricles", values 0..255, u8 samples.
pub fn mr_phantom(n: usize) -> Vec<u8> {
    let mut out = Vec::with_capacity(n * n * n);
    for k in 0..n {
        for j in 0..n {
            for i in 0..n {
                let p = DVec3::new(i as f64, j as f64, k as f64) / (n as f64 - 1.0) - DVec3::splat(0.5);
                let w = 1.5 / n as f64;
                let brain = 1.0 - smoothstep(0.33 - w, 0.33 + w, (p * DVec3::new(1.1, 0.9, 1.2)).length());
                let scalp = 1.0 - smoothstep(0.4 - w, 0.4 + w, p.length());
                let vent = |c: DVec3| 1.0 - smoothstep(0.05, 0.05 + 2.0 * w, (p - c).length());
                let v = 60.0 * scalp + 150.0 * brain
                    - 120.0 * (vent(DVec3::new(0.08, 0.0, 0.05)) + vent(DVec3::new(-0.08, 0.0, 0.05)));
                out.push(v.clamp(0.0, 255.0).round() as u8);
            }
        }
    }
    out
}

/// The fixed (CT, 3 mm, centred at 0) and moving (MR, 3.3 mm, rotated 10° and shifted) volume descriptions.
pub struct Phantoms {
    pub ct: Vec<i16>,
    pub mr: Vec<u8>,
    pub ct_lps_from_index: [[f64; 4]; 4],
    pub mr_lps_from_index: [[f64; 4]; 4],
}

impl Phantoms {
    pub fn new() -> Self {
        Self {
            ct: ct_phantom(N),
            mr: mr_phantom(N),
            ct_lps_from_index: grid_lps_from_index(N, 3.0, [0.0, 0.0, 0.0], 0.0),
            mr_lps_from_index: grid_lps_from_index(N, 3.3, [4.0, -3.0, 2.0], 10f64.to_radians()),
        }
    }
    pub fn ct_desc(&self) -> VolumeDesc<'_> {
        VolumeDesc { dims: [N; 3], samples: VolumeSamples::I16(&self.ct), lps_from_index: self.ct_lps_from_index }
    }
    pub fn mr_desc(&self) -> VolumeDesc<'_> {
        VolumeDesc { dims: [N; 3], samples: VolumeSamples::U8(&self.mr), lps_from_index: self.mr_lps_from_index }
    }
}

/// `[dx,dy,dz,0]` texels of `disp` sampled at the texel centres of an n³ grid over [min, max] (the solver's layout).
pub fn sample_control(n: usize, min: [f64; 3], max: [f64; 3], disp: impl Fn(DVec3) -> DVec3) -> Vec<f32> {
    let mut out = Vec::with_capacity(4 * n * n * n);
    for c in 0..n {
        for b in 0..n {
            for a in 0..n {
                let f = DVec3::new(a as f64 + 0.5, b as f64 + 0.5, c as f64 + 0.5) / n as f64;
                let x = DVec3::from_array(min) + f * (DVec3::from_array(max) - DVec3::from_array(min));
                let d = disp(x);
                out.extend([d.x as f32, d.y as f32, d.z as f32, 0.0]);
            }
        }
    }
    out
}

/// A smooth warp of a few mm: the moving phantom's offset plus a sinusoidal bulge.
pub fn smooth_displacement(x: DVec3) -> DVec3 {
    let s = (x / 40.0).map(f64::sin);
    DVec3::new(4.0 + 3.0 * s.y, -3.0 + 2.5 * s.z, 2.0 + 2.0 * s.x)
}

pub const CTRL_MIN: [f64; 3] = [-96.0; 3];
pub const CTRL_MAX: [f64; 3] = [96.0; 3];

/// CPU-side and GPU-side versions of one scene.
pub struct Scene {
    pub fixed: PreparedVolume,
    pub moving: PreparedVolume,
    pub control: Option<PreparedControl>,
    pub tfs: Vec<TransferFunction>,
    pub fixed_style: LayerStyle,
    pub moving_style: LayerStyle,
    /// Prefilter settings: with them, [`GpuScene::new`] runs the GPU pass for each layer that has CPU texels here;
    /// without them it uploads those texels.
    pub prefilter: Option<PrefilterSettings>,
    pub fixed_pf: Option<PrefilteredTexels>,
    pub moving_pf: Option<PrefilteredTexels>,
    /// The moving layer's procedural deformation ([`warpbench_gpu::procedural`]).
    pub moving_procedural: Option<Procedural>,
    /// The view deformations the (fixed, moving) layers are drawn through ([`warpbench_gpu::view_deformation`]).
    pub views: [Option<ViewDeformation>; 2],
}

impl Scene {
    pub fn new(ctx: &GpuContext, p: &Phantoms, warp: Option<&[f32]>, ctrl_n: usize) -> Self {
        let budget = VolumeBudget::for_device(&ctx.limits);
        let fixed = PreparedVolume::prepare(&p.ct_desc(), ctx.capabilities, budget).expect("fixed");
        let moving = PreparedVolume::prepare(&p.mr_desc(), ctx.capabilities, budget).expect("moving");
        let control = warp.map(|texels| {
            let desc = ControlDesc { dims: [ctrl_n; 3], texels, box_min_ref: CTRL_MIN, box_max_ref: CTRL_MAX };
            PreparedControl::prepare(&desc, ctx.capabilities.float32_filterable).expect("control")
        });
        let tfs = vec![Preset::CtBone.transfer_function(), Preset::MrT1.transfer_function()];
        let fixed_style = LayerStyle {
            window: Preset::CtBone.default_window().expect("CT window"),
            tf_row: 0,
            opacity_scale: 1.0,
            visible: true,
            iso_value: 300.0,
        };
        let moving_style = LayerStyle {
            window: Window::from_range(0.0, 220.0),
            tf_row: 1,
            opacity_scale: 1.0,
            visible: true,
            iso_value: 110.0,
        };
        Self {
            fixed,
            moving,
            control,
            tfs,
            fixed_style,
            moving_style,
            prefilter: None,
            fixed_pf: None,
            moving_pf: None,
            moving_procedural: None,
            views: [None; 2],
        }
    }

    /// Gives both layers prefiltered copies (the CPU reference's; the GPU scene runs the pass).
    pub fn with_prefilter(mut self, settings: PrefilterSettings) -> Self {
        self.fixed_pf = Some(PrefilteredTexels::from_volume(&self.fixed, settings));
        self.moving_pf = Some(PrefilteredTexels::from_volume(&self.moving, settings));
        self.prefilter = Some(settings);
        self
    }

    pub fn params(&self) -> (LayerParams, LayerParams) {
        (
            LayerParams {
                volume: self.fixed.info,
                control: None,
                style: self.fixed_style,
                has_prefilter: self.fixed_pf.is_some(),
                procedural: None,
                view: self.views[0],
            },
            LayerParams {
                volume: self.moving.info,
                control: self.control.as_ref().map(|c| c.info),
                style: self.moving_style,
                has_prefilter: self.moving_pf.is_some(),
                procedural: self.moving_procedural,
                view: self.views[1],
            },
        )
    }

    pub fn uniforms(&self, camera: &OrbitCamera, settings: &RenderSettings, size: (u32, u32)) -> RaycastUniforms {
        let (f, m) = self.params();
        RaycastUniforms::new(camera, settings, size, &f, &m, self.tfs.len() as u32)
    }

    /// Uniforms of a slice through `plane` ([`RaycastUniforms::for_slice`]).
    pub fn slice_uniforms(&self, plane: &SlicePlane, settings: &RenderSettings) -> RaycastUniforms {
        let (f, m) = self.params();
        RaycastUniforms::for_slice(plane, settings, &f, &m, self.tfs.len() as u32)
    }

    /// The CPU reference's slice (single-threaded: slices are one sample per pixel).
    pub fn cpu_slice(&self, u: &RaycastUniforms) -> Vec<u8> {
        self.cpu_slice_with(u, FilterPrecision::EXACT)
    }

    /// [`Self::cpu_slice`] with the hardware lookups' weights at `filtering`.
    pub fn cpu_slice_with(&self, u: &RaycastUniforms, filtering: FilterPrecision) -> Vec<u8> {
        let f = CpuLayer::new(&self.fixed, None, None).with_filtering(filtering);
        let m = CpuLayer::new(&self.moving, self.control.as_ref(), None).with_filtering(filtering);
        cpu_reference::render_slice(u, &f, &m, &self.tfs)
    }

    /// What a conformant device with `filter` may draw for the slice `u` ([`Allowance`]).
    pub fn slice_allowance(&self, u: &RaycastUniforms, filter: DeviceFilter) -> Allowance {
        Allowance::new(filter, |p| self.cpu_slice_with(u, p))
    }

    /// The CPU reference's first-hit depth image (single-threaded).
    pub fn cpu_hit_depth(&self, u: &RaycastUniforms) -> Vec<f32> {
        self.cpu_hit_depth_with(u, FilterPrecision::EXACT)
    }

    /// [`Self::cpu_hit_depth`] with the hardware lookups' weights at `filtering`.
    pub fn cpu_hit_depth_with(&self, u: &RaycastUniforms, filtering: FilterPrecision) -> Vec<f32> {
        let f = CpuLayer::new(&self.fixed, None, self.fixed_pf.as_ref()).with_filtering(filtering);
        let m = CpuLayer::new(&self.moving, self.control.as_ref(), self.moving_pf.as_ref()).with_filtering(filtering);
        cpu_reference::render_hit_depth(u, &f, &m, &self.tfs)
    }

    pub fn cpu(&self, u: &RaycastUniforms) -> Vec<u8> {
        self.cpu_with(u, FilterPrecision::EXACT)
    }

    /// What a conformant device with `bits` of filter precision may draw for `u` ([`Allowance`]).
    pub fn allowance(&self, u: &RaycastUniforms, filter: DeviceFilter) -> Allowance {
        Allowance::new(filter, |p| self.cpu_with(u, p))
    }

    /// [`Self::cpu`] with the hardware lookups' weights at `filtering`.
    pub fn cpu_with(&self, u: &RaycastUniforms, filtering: FilterPrecision) -> Vec<u8> {
        let f = CpuLayer::new(&self.fixed, None, self.fixed_pf.as_ref()).with_filtering(filtering);
        let m = CpuLayer::new(&self.moving, self.control.as_ref(), self.moving_pf.as_ref()).with_filtering(filtering);
        // Split the rows over threads: the reference is single-threaded and slow in debug builds.
        let h = u.viewport_px[1] as u32;
        let threads = std::thread::available_parallelism().map_or(1, std::num::NonZero::get).min(8) as u32;
        let chunk = h.div_ceil(threads);
        std::thread::scope(|scope| {
            let handles: Vec<_> = (0..threads)
                .map(|t| {
                    let rows = (t * chunk).min(h)..((t + 1) * chunk).min(h);
                    let (f, m) = (&f, &m);
                    scope.spawn(move || cpu_reference::render_rows(u, f, m, &self.tfs, rows))
                })
                .collect();
            handles.into_iter().flat_map(|h| h.join().expect("reference thread")).collect()
        })
    }
}

/// The GPU resources of a [`Scene`], and a renderer.
pub struct GpuScene {
    pub renderer: RaycastRenderer,
    pub fixed: GpuVolume,
    pub moving: GpuVolume,
    pub control: Option<GpuControlTexture>,
    pub tfs: GpuTransferFunctions,
    pub fixed_pf: Option<GpuPrefiltered>,
    pub moving_pf: Option<GpuPrefiltered>,
}

impl GpuScene {
    /// Uploads the scene; with [`Scene::prefilter`] set, runs the GPU prefilter pass on both volumes.
    pub fn new(ctx: &GpuContext, s: &Scene) -> Self {
        let fixed = GpuVolume::upload(ctx, &s.fixed).expect("upload fixed");
        let moving = GpuVolume::upload(ctx, &s.moving).expect("upload moving");
        // A layer with CPU prefiltered texels gets the GPU pass's output when `s.prefilter` is set, else an upload of
        // the same texels.
        let pass = s.prefilter.map(|_| PrefilterPass::new(ctx).expect("prefilter pass"));
        let prefiltered = |vol: &GpuVolume, texels: Option<&PrefilteredTexels>| {
            let texels = texels?;
            Some(match (&pass, s.prefilter) {
                (Some(pass), Some(settings)) => pass.run(ctx, vol, settings).expect("prefilter"),
                _ => GpuPrefiltered::upload(ctx, texels, PrefilterSettings::default()).expect("upload prefiltered"),
            })
        };
        let (fixed_pf, moving_pf) =
            (prefiltered(&fixed, s.fixed_pf.as_ref()), prefiltered(&moving, s.moving_pf.as_ref()));
        Self {
            renderer: RaycastRenderer::new(ctx).expect("renderer"),
            fixed,
            moving,
            control: s.control.as_ref().map(|c| GpuControlTexture::upload(ctx, c)),
            tfs: GpuTransferFunctions::upload(ctx, &s.tfs),
            fixed_pf,
            moving_pf,
        }
    }

    pub fn render(&self, ctx: &GpuContext, s: &Scene, u: &RaycastUniforms) -> Vec<u8> {
        self.render_by(ctx, &self.renderer, s, u)
    }

    /// The slice `u` ([`Scene::slice_uniforms`]) drawn by `renderer`, read back.
    pub fn render_slice(
        &self,
        ctx: &GpuContext,
        renderer: &RaycastRenderer,
        s: &Scene,
        u: &RaycastUniforms,
    ) -> Vec<u8> {
        let f = GpuLayer {
            volume: &self.fixed,
            control: None,
            prefiltered: None,
            style: s.fixed_style,
            procedural: None,
            view: s.views[0],
        };
        let m = GpuLayer {
            volume: &self.moving,
            control: self.control.as_ref(),
            prefiltered: None,
            style: s.moving_style,
            procedural: s.moving_procedural,
            view: s.views[1],
        };
        let frame = GpuFrame { fixed: f, moving: m, tfs: &self.tfs };
        let data = RaycastDrawData::with_uniforms(ctx, renderer, &frame, *u);
        let target = RenderTarget::new(ctx, u.viewport_px[0] as u32, u.viewport_px[1] as u32);
        renderer.render_slice(ctx, &data, &target).expect("render slice");
        target.read_back(ctx).expect("read back")
    }

    /// As [`Self::render`] with another scene's renderer (saves compiling the same pipeline again).
    pub fn render_by(&self, ctx: &GpuContext, renderer: &RaycastRenderer, s: &Scene, u: &RaycastUniforms) -> Vec<u8> {
        self.render_target(ctx, renderer, s, u).read_back(ctx).expect("read back")
    }

    /// The frame `u` rendered by `renderer` into a new target (colour and first-hit depth), not read back.
    pub fn render_target(
        &self,
        ctx: &GpuContext,
        renderer: &RaycastRenderer,
        s: &Scene,
        u: &RaycastUniforms,
    ) -> RenderTarget {
        let target = RenderTarget::new(ctx, u.viewport_px[0] as u32, u.viewport_px[1] as u32);
        renderer.render(ctx, &self.draw_data(ctx, renderer, s, u), &target).expect("render");
        target
    }

    /// Renders the frame `u` by `renderer` into `target` band by band ([`RaycastRenderer::render_rows`]), in the
    /// order given.
    pub fn render_rows_into(
        &self,
        ctx: &GpuContext,
        renderer: &RaycastRenderer,
        s: &Scene,
        u: &RaycastUniforms,
        target: &RenderTarget,
        bands: &[std::ops::Range<u32>],
    ) {
        let data = self.draw_data(ctx, renderer, s, u);
        for rows in bands {
            renderer.render_rows(ctx, &data, target, rows.clone()).expect("render rows");
        }
    }

    fn draw_data(
        &self,
        ctx: &GpuContext,
        renderer: &RaycastRenderer,
        s: &Scene,
        u: &RaycastUniforms,
    ) -> RaycastDrawData {
        let f = GpuLayer {
            volume: &self.fixed,
            control: None,
            prefiltered: self.fixed_pf.as_ref(),
            style: s.fixed_style,
            procedural: None,
            view: s.views[0],
        };
        let m = GpuLayer {
            volume: &self.moving,
            control: self.control.as_ref(),
            prefiltered: self.moving_pf.as_ref(),
            style: s.moving_style,
            procedural: s.moving_procedural,
            view: s.views[1],
        };
        let frame = GpuFrame { fixed: f, moving: m, tfs: &self.tfs };
        RaycastDrawData::with_uniforms(ctx, renderer, &frame, *u)
    }
}

/// Largest per-channel difference, and how many channels differ by more than `over`.
pub fn max_diff(a: &[u8], b: &[u8], over: u8) -> (u8, usize) {
    assert_eq!(a.len(), b.len());
    let diffs = a.iter().zip(b).map(|(x, y)| x.abs_diff(*y));
    let (mut max, mut count) = (0u8, 0usize);
    for d in diffs {
        max = max.max(d);
        count += usize::from(d > over);
    }
    (max, count)
}

/// Fraction of pixels with any visible content (alpha > 0).
pub fn coverage(img: &[u8]) -> f32 {
    img.chunks_exact(4).filter(|p| p[3] > 0).count() as f32 / (img.len() / 4) as f32
}

pub fn v3(x: f32, y: f32, z: f32) -> Vec3 {
    Vec3::new(x, y, z)
}

/// The analytic ball grid: 32³ voxels of 2 mm.
pub const BALL_N: usize = 32;
pub const BALL_SPACING_MM: f64 = 2.0;
/// The ball's radius (mm).
pub const RADIUS_MM: f32 = 20.0;

/// A [`BALL_N`]³ f32 volume of [`BALL_SPACING_MM`] centred on `centre_lps`, whose value at each voxel is
/// `value(r_mm)` of the voxel centre's distance r to `centre_lps`.
pub fn ball_volume(ctx: &GpuContext, centre_lps: [f64; 3], value: impl Fn(f32) -> f32) -> PreparedVolume {
    let h = (BALL_N as f64 - 1.0) / 2.0;
    let s = BALL_SPACING_MM;
    let c = centre_lps;
    let lps_from_index =
        [[s, 0.0, 0.0, c[0] - h * s], [0.0, s, 0.0, c[1] - h * s], [0.0, 0.0, s, c[2] - h * s], [0.0, 0.0, 0.0, 1.0]];
    let values: Vec<f32> = (0..BALL_N.pow(3))
        .map(|i| {
            let idx = DVec3::new((i % BALL_N) as f64, ((i / BALL_N) % BALL_N) as f64, (i / BALL_N / BALL_N) as f64);
            value(((idx - h) * s).length() as f32)
        })
        .collect();
    let desc = VolumeDesc { dims: [BALL_N; 3], samples: VolumeSamples::F32(&values), lps_from_index };
    PreparedVolume::prepare(&desc, ctx.capabilities, VolumeBudget::for_device(&ctx.limits)).expect("ball")
}

/// The ball scene: the fixed layer is a ball at the origin with values `value(r)`, windowed to `window` and
/// classified by a step transfer function (transparent below the window's middle, opaque grey above); the moving
/// layer is the same volume, hidden.
pub fn ball_scene(ctx: &GpuContext, value: impl Fn(f32) -> f32, window: (f32, f32)) -> Scene {
    let ball = ball_volume(ctx, [0.0; 3], value);
    let grey = [0.6, 0.6, 0.6];
    let tf = TransferFunction::from_points(
        "step",
        &[
            (0.0, [grey[0], grey[1], grey[2], 0.0]),
            (0.49, [grey[0], grey[1], grey[2], 0.0]),
            (0.51, [grey[0], grey[1], grey[2], 1.0]),
            (1.0, [grey[0], grey[1], grey[2], 1.0]),
        ],
    );
    let style = |visible| LayerStyle {
        window: Window::from_range(window.0, window.1),
        tf_row: 0,
        opacity_scale: 1.0,
        visible,
        iso_value: 0.0,
    };
    Scene {
        fixed: ball.clone(),
        moving: ball,
        control: None,
        tfs: vec![tf],
        fixed_style: style(true),
        moving_style: style(false),
        prefilter: None,
        fixed_pf: None,
        moving_pf: None,
        moving_procedural: None,
        views: [None; 2],
    }
}

/// Where the ray origin + t·dir (unit dir) enters the sphere of radius `r` about `centre`, if it does.
pub fn sphere_entry(origin: Vec3, dir: Vec3, centre: Vec3, r: f32) -> Option<f32> {
    let o = origin - centre;
    let b = o.dot(dir);
    let disc = b * b - (o.length_squared() - r * r);
    (disc >= 0.0).then(|| -b - disc.sqrt())
}
