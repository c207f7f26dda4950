//! The Gaussian prefilter on the GPU vs its CPU reference ([`cpu_prefilter`]) on the 64³ phantoms, at full and half
//! resolution, from every volume format the device gets (R16Unorm CT, R8Unorm MR; R32Float without the optional
//! features).
//!
//! Tolerance: 1e-6 of the texels' largest magnitude (normalised texels in [0,1] for R8/R16Unorm, raw values such as
//! HU for R32Float): the sums run in the same order on both sides; what differs is `exp` and fused multiply-adds.
//! Measured on lavapipe (Mesa 22.3.6, llvmpipe LLVM 15): ≤ 4.2e-7 on normalised texels, ≤ 4.3e-4 HU (1.5e-7
//! relative) on R32Float CT.

mod common;

use common::*;
use warpbench_gpu::prefilter::cpu_prefilter;
use warpbench_gpu::{FeatureRequest, GpuVolume, PrefilterPass, PrefilterSettings, PreparedVolume, VolumeBudget};

/// Relative to the largest texel magnitude.
const TOLERANCE: f32 = 1e-6;

fn compare(request: FeatureRequest) {
    let Some(ctx) = context(request) else { return };
    let p = Phantoms::new();
    let pass = PrefilterPass::new(&ctx).expect("prefilter pass");
    let budget = VolumeBudget::for_device(&ctx.limits);
    let mut failures = Vec::new();
    for (name, desc) in [("ct", p.ct_desc()), ("mr", p.mr_desc())] {
        let vol = PreparedVolume::prepare(&desc, ctx.capabilities, budget).expect("prepare");
        let gpu_vol = GpuVolume::upload(&ctx, &vol).expect("upload");
        for (sigma_vox, half_resolution) in [(1.0, false), (1.5, true)] {
            let settings = PrefilterSettings { sigma_vox, half_resolution };
            let g = pass.run(&ctx, &gpu_vol, settings).expect("run");
            let gpu = g.read_back(&ctx).expect("read back");
            let cpu = cpu_prefilter(vol.info.dims, |i| vol.texels.normalised(i), settings);
            assert_eq!(g.dims, cpu.dims);
            let max = gpu.iter().zip(&cpu.texels).map(|(a, b)| (a - b).abs()).fold(0.0f32, f32::max);
            let line =
                format!("{name} {:?} σ {sigma_vox} half {half_resolution}: max |Δ| {max:.2e}", vol.texels.format());
            eprintln!("{line}");
            let scale = cpu.texels.iter().fold(1.0f32, |m, v| m.max(v.abs()));
            if max > TOLERANCE * scale {
                failures.push(line);
            }
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

#[test]
fn gpu_prefilter_matches_the_cpu_reference() {
    compare(FeatureRequest::default());
}

#[test]
fn gpu_prefilter_matches_the_cpu_reference_without_optional_features() {
    compare(FeatureRequest { allow_norm16: false, allow_float32_filterable: false });
}
