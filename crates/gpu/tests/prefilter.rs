//! The Gaussian prefilter and its gradient on the GPU vs the CPU reference ([`cpu_prefilter`],
//! [`PrefilteredTexels::gradients`]) on the 64³ phantoms, at full and half resolution, from every volume format the
//! device gets (R16Unorm CT, R8Unorm MR; R32Float without the optional features).
//!
//! Tolerance, per gradient component: the filtered texels agree within 1e-6 of their largest magnitude (the sums run
//! in the same order on both sides; what differs is `exp` and fused multiply-adds: measured ≤ 4.2e-7 on normalised
//! texels on lavapipe), so a central difference scaled by n/2 agrees within n·1e-6 of it; then each side rounds to
//! f16 to nearest even, which moves values that close apart by at most one f16 step of the larger.

mod common;

use common::*;
use warpbench_gpu::prefilter::cpu_prefilter;
use warpbench_gpu::{FeatureRequest, GpuVolume, PrefilterPass, PrefilterSettings, PreparedVolume, VolumeBudget};

/// Of the filtered texels, relative to their largest magnitude.
const TOLERANCE: f32 = 1e-6;

/// One f16 step at |v| (the spacing of f16 values around it).
fn f16_step(v: f32) -> f32 {
    let h = half::f16::from_f32(v.abs());
    (half::f16::from_bits(h.to_bits() + 1).to_f32() - h.to_f32()).abs()
}

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
            assert_eq!(gpu.len(), cpu.gradients.len());
            let scale = cpu.texels.iter().fold(1.0f32, |m, v| m.max(v.abs()));
            let n = cpu.dims.iter().copied().max().unwrap_or(1) as f32;
            let (mut worst, mut largest) = (0.0f32, 0.0f32);
            for (a, b) in gpu.iter().zip(&cpu.gradients) {
                for c in 0..3 {
                    let allowed = n * TOLERANCE * scale + f16_step(a[c].abs().max(b[c].abs()));
                    worst = worst.max((a[c] - b[c]).abs() / allowed);
                    largest = largest.max(b[c].abs());
                }
                assert_eq!(a[3].to_bits(), 0, "the fourth component is zero");
            }
            let line = format!(
                "{name} {:?} σ {sigma_vox} half {half_resolution}: gradients up to {largest:.3}, worst |Δ| {worst:.2} \
                 of the allowed",
                vol.texels.format()
            );
            eprintln!("{line}");
            if worst > 1.0 || largest == 0.0 {
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
