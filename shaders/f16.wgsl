// f32 ↔ IEEE binary16 by hand, appended to the shaders that store halves (crates/gpu/src/control_eval.rs,
// crates/gpu/src/prefilter.rs: their `SHADER` sources are their own file followed by this one). The pack2x16float
// builtin needs the SHADER_FLOAT16_IN_FLOAT32 capability, which a plain WebGPU device does not promise.

// IEEE binary16 bits of x, rounded to nearest, ties to even (as half::f16::from_f32). |x| ≥ 65520 gives infinity.
fn f16_bits(x: f32) -> u32 {
    let bits = bitcast<u32>(x);
    let sign = (bits >> 16u) & 0x8000u;
    let a = bits & 0x7fffffffu;
    if a >= 0x477ff000u {
        return sign | 0x7c00u;
    }
    if a < 0x38800000u {
        // Below 2⁻¹⁴: an f16 subnormal, k·2⁻²⁴ (round() rounds ties to even).
        return sign | u32(round(bitcast<f32>(a) * 16777216.0));
    }
    // Rebias the exponent (127 → 15) and round the mantissa from 23 to 10 bits; a carry moves into the exponent.
    let r = a - 0x38000000u;
    return sign | ((r + 0x0fffu + ((r >> 13u) & 1u)) >> 13u);
}

// The f32 value of binary16 bits `h` (finite).
fn f16_value(h: u32) -> f32 {
    let sign = select(1.0, -1.0, (h & 0x8000u) != 0u);
    let e = (h >> 10u) & 0x1fu;
    let m = h & 0x3ffu;
    if e == 0u {
        return sign * f32(m) * 5.9604645e-8; // 2⁻²⁴
    }
    return bitcast<f32>(((h & 0x8000u) << 16u) | ((e + 112u) << 23u) | (m << 13u));
}
