//! GPU ray casting for warpbench: the fixed and the deformed moving volume rendered together in one pass, with a
//! CPU reference of the same math.
//!
//! # Overview
//!
//! - [`GpuContext`] ([`device`]): a headless device or one the app already has ([`GpuContext::from_device`]);
//!   requests only the optional features its caller names and collects wgpu's uncaptured errors, each reported once.
//!   [`headless`]: [`GpuContext::headless`], with the optional features the passes below use.
//! - [`volume`]: [`PreparedVolume::prepare`] chooses an exact texture format and downsamples oversized volumes;
//!   [`GpuVolume::upload`] makes the 3-D texture.
//! - [`transfer`]: [`TransferFunction`]s, [`Preset`]s and [`Window`]s; [`GpuTransferFunctions`] is the 256×N texture.
//! - [`control`]: control textures (sampled pull-backs) from the solver's layout: [`PreparedControl`],
//!   [`GpuControlTexture`].
//! - [`control_eval`]: [`ControlEvalPass`] evaluates a TPS ([`TpsDesc`]) or hierarchical B-spline ([`BSplineDesc`])
//!   pull-back straight into a control texture on the GPU, its displacement bounds reduced there too.
//! - [`camera`]: [`OrbitCamera`] (`clip_from_ref` and its inverse).
//! - [`settings`]: what a frame is drawn with, as plain data: [`RenderSettings`] ([`BlendMode`], [`Quality`],
//!   [`Shading`] with its [`ShadingMode`]: unlit, lit DVR, lit iso-surface; gradients through the warp), and per
//!   volume [`LayerStyle`] and [`LayerParams`].
//! - [`procedural`]: [`Procedural`] deformations (shift, sine, twist, bend, bump) the shader computes per sample on a
//!   layer's data, with the bounds the proxy box and empty-space skipping need and their control-texture sampling.
//! - [`view_deformation`]: [`ViewDeformation`]s of the view a layer is drawn through (the fish-eye attention lens),
//!   applied before its pull-back, so picks through them land in the undeformed volume.
//! - [`raycast`]: the ray caster (a compute pass, one invocation per pixel), [`RaycastRenderer`] (pipelines) and
//!   [`RaycastDrawData`] (one frame), with its
//!   uniforms ([`RaycastUniforms`], [`VolumeUniforms`]), its shader and its bind slots.
//! - [`target`]: [`RenderTarget`], the image and the first-hit depth the passes draw into.
//! - [`slice`](mod@slice): [`SlicePlane`] (axial/coronal/sagittal planes of the fixed grid, oblique planes,
//!   pixel ↔ ref), drawn by [`RaycastRenderer::render_slice`] with the ray caster's sampling, classification and
//!   blending.
//! - [`prefilter`]: [`PrefilterPass`], a separable Gaussian (compute, optionally half resolution) whose result
//!   ([`GpuPrefiltered`]) the ray caster differentiates for shading; [`prefilter::cpu_prefilter`] is its reference.
//! - [`pick`](mod@pick): [`PickPass`], ray picking in the deformed volumes (probes: opacity, gradient, accumulated
//!   opacity; bisection refinement), returning the hit in ref space and in the volume's own LPS space.
//! - [`pool`]: [`TexturePool`], textures reused by descriptor ([`TextureKey`]); [`RenderTarget::from_pool`].
//! - [`glyph`]: landmark glyphs ([`GlyphRenderer`], [`GlyphDrawData`], [`pair_glyphs`]): points and pair lines over the
//!   3-D view, depth-tested against the ray caster's first hit ([`RenderTarget::hit_depth`]), and over slices.
//! - [`export`]: the warped moving volume resampled onto a target grid, on the CPU ([`export_cpu`]) or the GPU
//!   ([`ExportPass`]).
//! - [`ffd_samples`]: [`FfdSamplesPass`], the per-sample work of an intensity registration under a B-spline
//!   free-form deformation (displaced image values, and the weighted gradient gathered per control point).
//! - [`shader`]: what a pass declares about its WGSL (its [`shader::ShaderSource`], the layouts of its uniform
//!   structs and its [`shader::BindSlot`]s); [`shaders`]: the registry that lists every file and every pass's
//!   declaration, which `tests/shaders.rs` checks against naga's reading of the WGSL.
//! - [`sampling`]: the GPU's trilinear lookup on the CPU, shared by [`control`] and [`cpu_reference`], and the model
//!   of a device's filtering precision ([`FilterPrecision`]); [`filter_probe`]: [`FilterProbe`] measures it.
//! - [`cpu_reference`]: the same math in f32 on the CPU, the oracle of the GPU tests.
//!
//! # Imports
//!
//! No module imports (directly or through others) a module that imports it back. At the bottom, [`error`],
//! [`shader`], [`sampling`], [`camera`], [`pool`] and [`slice`](mod@slice) import nothing but [`error`]; the passes
//! import the data modules and [`shader`]; [`shaders`], [`headless`] and [`cpu_reference`] sit on top, and nothing in
//! the crate imports them. A module of `export/` imports its siblings, never its parent.
//!
//! # Spaces
//!
//! Everything is rendered in **ref** space: the fixed volume's LPS patient space, in mm. A volume's own space is
//! `lps` (for the moving volume, the moving LPS space); `index` is continuous voxel index (0 = centre of the first
//! voxel); `tex` is \[0, 1\]³ texture coordinates with texel centres at (i + ½)/n. The moving volume is pulled back
//! through a control texture: x_ref ↦ u(x_ref) = x_ref + disp(x_ref) in moving `lps` (Brunet, Nowak & Gleicher 2006
//! §3). Transforms are named `b_from_a` (`tex_from_lps`, `ctrl_tex_from_ref`, `ref_from_clip`).
//!
//! This crate takes plain data (dims, sample slices, row-major 4×4 `lps_from_index`, f32 control texels) and does
//! not depend on `warpbench-io` or `warpbench-solver`.

pub mod camera;
mod compute;
pub mod control;
pub mod control_eval;
pub mod cpu_reference;
pub mod device;
pub mod empty_space;
pub mod error;
pub mod export;
pub mod ffd_samples;
pub mod filter_probe;
pub mod glyph;
pub mod headless;
pub mod pick;
pub mod pool;
pub mod prefilter;
pub mod procedural;
pub mod pullback;
pub mod raycast;
pub mod sampling;
pub mod settings;
pub mod shader;
pub mod shaders;
pub mod slice;
pub mod target;
pub mod transfer;
pub mod view_deformation;
pub mod volume;

/// The glam version of this crate's API (matrices and vectors), re-exported for callers.
pub use glam;

pub use camera::{OrbitCamera, Projection};
pub use control::{ControlDesc, ControlInfo, GpuControlTexture, PreparedControl};
pub use control_eval::{ControlEvalPass, ControlGridDesc, PendingControl};
pub use device::{Capabilities, FeatureRequest, GpuContext};
pub use empty_space::{EmptySpaceGrid, GpuEmptySpace, OccupancyLayer};
pub use error::{GpuError, Result};
pub use export::{
    ExportPass, ExportRequest, ExportSamples, ExportedSamples, ExportedVolume, Interpolation, OutputType, Progress,
    PullBack, SampleType, SourceVolume, TargetGrid, export_cpu,
};
pub use ffd_samples::{FfdSamplesPass, PreparedFfd};
pub use filter_probe::{FilterProbe, MeasuredFiltering};
pub use glyph::{
    GlyphDrawData, GlyphInstance, GlyphPair, GlyphRenderer, GlyphSettings, GlyphStyle, GlyphUniforms, pair_glyphs,
};
pub use pick::{PickHit, PickPass, PickRay, PickRequest, PickTarget, Probe};
pub use pool::{PoolStats, TextureKey, TexturePool};
pub use prefilter::{GpuPrefiltered, PrefilterPass, PrefilterSettings, PrefilteredTexels};
pub use procedural::{Axis, Procedural, ProceduralUniforms};
pub use pullback::{BSplineDesc, LatticeDesc, TpsDesc, TpsLocal};
pub use raycast::{GpuFrame, GpuLayer, RaycastDrawData, RaycastRenderer, RaycastUniforms, VolumeUniforms};
pub use sampling::{FilterPrecision, WeightPrecision, WeightRounding};
pub use settings::{BlendMode, Classification, LayerParams, LayerStyle, Quality, RenderSettings, Shading, ShadingMode};
pub use slice::SlicePlane;
pub use target::RenderTarget;
pub use transfer::{GpuTransferFunctions, OpacityTable, Preset, TransferFunction, Window};
pub use view_deformation::{ViewDeformation, ViewDeformationUniforms};
pub use volume::{GpuVolume, PreparedVolume, VolumeBricks, VolumeBudget, VolumeDesc, VolumeInfo, VolumeSamples};
