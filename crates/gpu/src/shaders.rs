//! The shader registry: every WGSL file of the crate ([`ALL`]) and what each pass declares about the one it runs
//! ([`INTERFACES`]). Each pass owns its [`ShaderSource`], the `#[repr(C)]` twins of its WGSL structs and its bind
//! slots (see [`crate::shader`]); this module only lists them, and `tests/shaders.rs` validates every file with naga
//! (no device) and checks every interface against it. Nothing in the crate imports this module.

use crate::{control_eval, export, ffd_samples, filter_probe, glyph, pick, prefilter, raycast};

pub use crate::shader::{BindSlot, ShaderInterface, ShaderSource, Stage, StructLayout, WgslConstant};

/// The ray caster, its slices and the picking pass ([`crate::raycast`], [`crate::slice`], [`crate::pick`]).
pub const RAYCAST: ShaderSource = raycast::SHADER;
/// The gradient prefilter ([`crate::prefilter`]).
pub const PREFILTER: ShaderSource = prefilter::SHADER;
/// Landmark glyphs ([`crate::glyph`]).
pub const GLYPH: ShaderSource = glyph::SHADER;
/// GPU control-texture evaluation ([`crate::control_eval`]).
pub const CONTROL_EVAL: ShaderSource = control_eval::SHADER;
/// The export of the warped volume ([`crate::export`]).
pub const EXPORT: ShaderSource = export::SHADER;

/// The registration's samples under a free-form deformation ([`crate::ffd_samples`]).
pub const FFD_SAMPLES: ShaderSource = ffd_samples::SHADER;

/// The filtering-precision probe ([`crate::filter_probe`]).
pub const FILTER_PROBE: ShaderSource = filter_probe::SHADER;

/// Every shader of the crate.
pub const ALL: &[ShaderSource] = &[RAYCAST, PREFILTER, GLYPH, CONTROL_EVAL, EXPORT, FFD_SAMPLES, FILTER_PROBE];

/// Every pass's interface; together they claim every `@binding` of every shader in [`ALL`].
pub const INTERFACES: &[ShaderInterface] = &[
    raycast::INTERFACE,
    pick::INTERFACE,
    prefilter::INTERFACE,
    glyph::INTERFACE,
    control_eval::INTERFACE,
    export::INTERFACE,
    ffd_samples::INTERFACE,
    filter_probe::INTERFACE,
];
