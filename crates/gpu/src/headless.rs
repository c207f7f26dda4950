//! The headless device of this crate's passes: [`GpuContext::headless`] requests the optional features they use
//! ([`RaycastRenderer::OPTIONAL_FEATURES`]: [`wgpu::Features::TEXTURE_FORMAT_16BIT_NORM`] for exact 16-bit volumes in
//! `R16Unorm`, [`wgpu::Features::FLOAT32_FILTERABLE`] for filtered `R32Float` volumes and `Rgba32Float` control
//! textures) where the adapter has them, and [`headless_or_skip`] is the tests' and examples' way to get one.

use crate::device::{FeatureRequest, GpuContext};
use crate::error::{GpuError, Result};
use crate::raycast::RaycastRenderer;

impl GpuContext {
    /// A device without a window (see [`Self::headless_requesting`]) with every optional feature the passes use that
    /// the adapter has.
    pub fn headless() -> Result<Self> {
        Self::headless_with(FeatureRequest::default())
    }

    /// As [`Self::headless`], requesting only the optional features `request` allows.
    pub fn headless_with(request: FeatureRequest) -> Result<Self> {
        Self::headless_requesting(RaycastRenderer::OPTIONAL_FEATURES, request)
    }
}

/// Whether tests must fail rather than skip without an adapter (CI sets `REQUIRE_GPU_ADAPTER=1`).
#[must_use]
pub fn adapter_required() -> bool {
    std::env::var("REQUIRE_GPU_ADAPTER").is_ok_and(|v| v == "1")
}

/// For tests and examples: a headless context, or `None` with a printed note when there is no adapter and
/// `REQUIRE_GPU_ADAPTER=1` is not set. Panics on any other failure.
#[must_use]
pub fn headless_or_skip(request: FeatureRequest) -> Option<GpuContext> {
    match GpuContext::headless_with(request) {
        Ok(ctx) => Some(ctx),
        Err(GpuError::NoAdapter(why)) if !adapter_required() => {
            eprintln!("note: skipping GPU test, no adapter ({why}); set REQUIRE_GPU_ADAPTER=1 to make this fail");
            None
        }
        Err(e) => panic!("GPU context: {e}"),
    }
}
