//! What a frame is drawn with, without GPU resources: the frame-wide [`RenderSettings`] (the [`BlendMode`] of the
//! two volumes, the sample rate and its [`Quality`], the [`Shading`] with its [`ShadingMode`]) and, per volume, its
//! [`LayerStyle`] and the [`LayerParams`] the ray caster's uniforms are built from
//! ([`crate::raycast::RaycastUniforms::new`], which the CPU reference consumes too).

use glam::DVec3;

use crate::control::ControlInfo;
use crate::procedural::Procedural;
use crate::transfer::Window;
use crate::view_deformation::ViewDeformation;
use crate::volume::VolumeInfo;

/// How the two classified samples combine (`RaycastUniforms.blend_mode`, `BLEND_*` in the shader).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum BlendMode {
    /// (1 − w)·fixed + w·moving.
    Mix {
        moving_weight: f32,
    },
    /// fixed + moving, clamped.
    Additive,
    /// |fixed − moving| in colour, max of the opacities: aligned structures go dark.
    Difference,
    /// A 3-D checkerboard of `cell_mm` cells in ref space; cells with an even index sum show fixed.
    Checkerboard {
        cell_mm: f32,
    },
    /// Fixed luminance in red, moving luminance in green and blue.
    RedCyan,
    FixedOnly,
    MovingOnly,
}

impl BlendMode {
    /// One of each, for tests and menus.
    pub const ALL: [Self; 7] = [
        Self::Mix { moving_weight: 0.5 },
        Self::Additive,
        Self::Difference,
        Self::Checkerboard { cell_mm: 12.0 },
        Self::RedCyan,
        Self::FixedOnly,
        Self::MovingOnly,
    ];

    #[must_use]
    pub fn code(self) -> u32 {
        match self {
            Self::Mix { .. } => 0,
            Self::Additive => 1,
            Self::Difference => 2,
            Self::Checkerboard { .. } => 3,
            Self::RedCyan => 4,
            Self::FixedOnly => 5,
            Self::MovingOnly => 6,
        }
    }

    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Self::Mix { .. } => "mix",
            Self::Additive => "additive",
            Self::Difference => "difference",
            Self::Checkerboard { .. } => "checkerboard",
            Self::RedCyan => "red-cyan",
            Self::FixedOnly => "fixed-only",
            Self::MovingOnly => "moving-only",
        }
    }
}

/// How samples are lit (`RaycastUniforms.shading_mode`, `SHADING_*` in the shader).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ShadingMode {
    /// Unlit direct volume rendering: the transfer function's colour as it is.
    None,
    /// Direct volume rendering, each sample with opacity > 0 lit by its gradient.
    Dvr,
    /// Per volume, the first sample whose value ≥ [`LayerStyle::iso_value`], refined by bisection, lit and opaque;
    /// the two volumes' hits are then blended once by the [`BlendMode`].
    Iso,
}

impl ShadingMode {
    pub const ALL: [Self; 3] = [Self::None, Self::Dvr, Self::Iso];

    #[must_use]
    pub fn code(self) -> u32 {
        match self {
            Self::None => 0,
            Self::Dvr => 1,
            Self::Iso => 2,
        }
    }

    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Self::None => "none",
            Self::Dvr => "dvr",
            Self::Iso => "iso",
        }
    }
}

/// Lighting: a headlight (light = view direction), two-sided.
///
/// For a sample with gradient g and n = g/|g|, l = −ray direction:
/// colour' = clamp(colour·(ambient + diffuse·|n·l|) + specular·|n·l|^shininess, 0, 1) (straight colour; with a
/// headlight the Blinn-Phong half vector is l). The gradient is taken through the warp (see [`crate::raycast`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Shading {
    pub mode: ShadingMode,
    pub ambient: f32,
    pub diffuse: f32,
    /// 0 turns specular off.
    pub specular: f32,
    pub shininess: f32,
    /// Central-difference step in ref mm; `None` is one voxel of the finest visible spacing.
    pub gradient_step_mm: Option<f32>,
    /// Iso mode: bisection steps between the last sample below and the first at or above the threshold.
    pub bisection_steps: u32,
}

impl Default for Shading {
    fn default() -> Self {
        Self {
            mode: ShadingMode::None,
            ambient: 0.3,
            diffuse: 0.7,
            specular: 0.2,
            shininess: 24.0,
            gradient_step_mm: None,
            bisection_steps: 6,
        }
    }
}

impl Shading {
    /// The default lighting with `mode`.
    #[must_use]
    pub fn with_mode(mode: ShadingMode) -> Self {
        Self { mode, ..Self::default() }
    }
}

/// How the ray caster classifies what lies between two samples (`RAYCAST_PREINTEGRATED` in the shader).
///
/// Per-sample is the default: `benches/quality.rs` measures pre-integration *worse* at one sample per voxel on the
/// demo pair against an 8-samples-per-voxel reference (mean |diff| over the head 6.5–8.3 grey levels on the CT
/// against 3.8–4.4, 1.0–1.5 against 0.6–0.7 on the MRI, unlit): the table assumes the value linear between two
/// samples, and trilinear interpolation is linear only between voxel centres, so where the samples fall between them
/// (the front view puts them on voxel faces) the segments cut the peaks of thin bright structures. It is exact where
/// the data are linear along the ray (`cpu_reference` tests it) and removes rings that come from the transfer
/// function alone.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Classification {
    /// Each sample's value through the transfer function, opacity-corrected to the step: a sharp transfer function
    /// between samples shows as rings ("wood grain") unless the rate is high.
    #[default]
    PerSample,
    /// Pre-integrated classification (Engel, Kraus & Ertl 2001): each segment between two consecutive samples is
    /// composited from a table of the segment integral of colour and opacity over the transfer function, for the
    /// value going linearly from the front sample's to the back sample's ([`crate::transfer::PreIntegrationTable`]).
    PreIntegrated,
}

impl Classification {
    pub const ALL: [Self; 2] = [Self::PerSample, Self::PreIntegrated];

    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Self::PerSample => "per-sample",
            Self::PreIntegrated => "pre-integrated",
        }
    }
}

/// Which sample rate a frame uses: the full one when the view is still, a lower one while the user drags (Brunet,
/// Nowak & Gleicher 2006 §6.2: their implementation "adjusts sampling rates to provide faster performance at the
/// expense of image quality"). Opacity is corrected to the step, so the picture keeps its brightness and only gets
/// coarser.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Quality {
    #[default]
    Full,
    Interactive,
}

/// Frame-wide settings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RenderSettings {
    pub blend: BlendMode,
    /// Samples per voxel of the finest visible spacing (step = spacing / samples_per_voxel).
    pub samples_per_voxel: f32,
    /// The samples per voxel of [`Quality::Interactive`] frames ([`Self::at`]).
    pub interaction_samples_per_voxel: f32,
    /// `Some(seed)`: jitter ray starts by a fixed per-pixel hash of (pixel, seed). `None` for tests and goldens.
    pub jitter_seed: Option<u32>,
    /// Upper bound on samples per ray.
    pub max_steps: u32,
    /// Replaces the automatic proxy box (the union of both layers' [`LayerParams::box_ref`]: where each volume can
    /// appear after its warp).
    pub box_override_ref: Option<(glam::Vec3, glam::Vec3)>,
    pub shading: Shading,
    /// Per sample, or pre-integrated over each segment between samples (DVR only; iso mode and slices take samples).
    pub classification: Classification,
}

impl Default for RenderSettings {
    fn default() -> Self {
        Self {
            blend: BlendMode::Mix { moving_weight: 0.5 },
            samples_per_voxel: 1.0,
            interaction_samples_per_voxel: 0.5,
            jitter_seed: None,
            max_steps: 4096,
            box_override_ref: None,
            shading: Shading::default(),
            classification: Classification::default(),
        }
    }
}

impl RenderSettings {
    /// These settings at `quality`: [`Quality::Interactive`] samples at [`Self::interaction_samples_per_voxel`]
    /// (never more finely than the full rate).
    #[must_use]
    pub fn at(&self, quality: Quality) -> Self {
        match quality {
            Quality::Full => *self,
            Quality::Interactive => {
                Self { samples_per_voxel: self.interaction_samples_per_voxel.min(self.samples_per_voxel), ..*self }
            }
        }
    }
}

/// How one volume is drawn.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LayerStyle {
    pub window: Window,
    /// Row in the transfer-function texture.
    pub tf_row: u32,
    /// Multiplies the TF opacity.
    pub opacity_scale: f32,
    pub visible: bool,
    /// Iso-surface threshold in this volume's value units (HU for CT), for [`ShadingMode::Iso`].
    pub iso_value: f32,
}

/// Everything about one volume that goes into the uniforms, without GPU resources.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LayerParams {
    pub volume: VolumeInfo,
    /// The pull-back into this volume's LPS space; `None` is the identity fast path.
    pub control: Option<ControlInfo>,
    pub style: LayerStyle,
    /// A prefiltered copy is bound: gradients for shading come from it.
    pub has_prefilter: bool,
    /// A deformation of the layer's data computed in the shader, after the pull-back: the frame reads the volume at
    /// p(u(x)) ([`crate::procedural`]); `None` reads it at u(x).
    pub procedural: Option<Procedural>,
    /// A deformation of the view the layer is drawn through, before its pull-back: the frame reads the volume at
    /// p(u(w(x))) ([`crate::view_deformation`]); `None` is w(x) = x.
    pub view: Option<ViewDeformation>,
}

impl LayerParams {
    /// A ref-space box that contains every point where this layer can have content: the volume is non-transparent
    /// only where p(u(x)) lies in its LPS box [lo, hi] (p the identity without a [`Self::procedural`]), so u(x) lies
    /// in p's preimage box [lo', hi'] ([`Procedural::preimage_box`]); and u(x) = x + d(x) with d(x) componentwise in
    /// [`ControlInfo::disp_min_mm`, `ControlInfo::disp_max_mm`] everywhere (trilinear, clamp-to-edge), so
    /// x ∈ [lo' − d_max, hi' − d_min]; under a [`Self::view`] deformation w, x lies in w's preimage box of that
    /// ([`ViewDeformation::preimage_box`]). Exact for the identity and for a constant displacement; conservative
    /// otherwise.
    #[must_use]
    pub fn box_ref(&self) -> (DVec3, DVec3) {
        let (lo, hi) = (self.volume.box_min_lps, self.volume.box_max_lps);
        let (lo, hi) = self.procedural.map_or((lo, hi), |p| p.preimage_box(lo, hi));
        let (lo, hi) = match self.control {
            Some(c) => (lo - c.disp_max_mm.as_dvec3(), hi - c.disp_min_mm.as_dvec3()),
            None => (lo, hi),
        };
        self.view.map_or((lo, hi), |w| w.preimage_box(lo, hi))
    }
}

/// The automatic proxy box of a frame: the union of both layers' [`LayerParams::box_ref`] (what
/// [`RenderSettings::box_override_ref`] replaces).
#[must_use]
pub fn proxy_box_ref(fixed: &LayerParams, moving: &LayerParams) -> (glam::Vec3, glam::Vec3) {
    let (a, b) = (fixed.box_ref(), moving.box_ref());
    (a.0.min(b.0).as_vec3(), a.1.max(b.1).as_vec3())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::control::{ControlDesc, PreparedControl};
    use crate::device::Capabilities;
    use crate::volume::{PreparedVolume, VolumeBudget, VolumeDesc, VolumeSamples};

    #[test]
    fn proxy_box_covers_the_warped_extent() {
        let samples = vec![0u8; 8];
        let lps_from_index = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]];
        let desc = VolumeDesc { dims: [2, 2, 2], samples: VolumeSamples::U8(&samples), lps_from_index };
        let caps = Capabilities { norm16: true, float32_filterable: true };
        let budget = VolumeBudget { max_dimension: 64, max_bytes: 1 << 20 };
        let vol = PreparedVolume::prepare(&desc, caps, budget).expect("volume");
        // Voxel-edge box [−0.5, 1.5]³; displacements x ∈ [−10, 2], y = 3, z = 0.
        let texels: Vec<f32> = [[-10.0, 3.0, 0.0, 0.0], [2.0, 3.0, 0.0, 0.0]].concat().repeat(4);
        let cdesc = ControlDesc { dims: [2, 2, 2], texels: &texels, box_min_ref: [0.0; 3], box_max_ref: [1.0; 3] };
        let ctrl = PreparedControl::prepare(&cdesc, true).expect("control");
        let style = LayerStyle {
            window: Window::from_range(0.0, 1.0),
            tf_row: 0,
            opacity_scale: 1.0,
            visible: true,
            iso_value: 0.5,
        };
        let plain =
            LayerParams { volume: vol.info, control: None, style, has_prefilter: false, procedural: None, view: None };
        let warped = LayerParams { control: Some(ctrl.info), ..plain };
        assert_eq!(plain.box_ref(), (DVec3::splat(-0.5), DVec3::splat(1.5)));
        let (lo, hi) = warped.box_ref();
        assert_eq!((lo, hi), (DVec3::new(-2.5, -3.5, -0.5), DVec3::new(11.5, -1.5, 1.5)));
    }
}
