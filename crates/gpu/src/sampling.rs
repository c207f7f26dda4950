//! Texture sampling as the GPU's filtered lookups do it, in f32 on the CPU: shared by the preparation code
//! ([`crate::control::PreparedControl::displacement`]) and the CPU reference of the passes ([`crate::cpu_reference`]).

use glam::{Vec3, Vec4};

/// Trilinear interpolation at `p_tex` ∈ \[0, 1\]³ of a `dims` grid with texel centres at (i + ½)/n and clamp-to-edge
/// addressing; `texel(i)` returns the texel at linear index i (x fastest).
pub fn trilinear(dims: [u32; 3], p_tex: Vec3, texel: impl Fn(usize) -> Vec4) -> Vec4 {
    let n = Vec3::new(dims[0] as f32, dims[1] as f32, dims[2] as f32);
    let c = (p_tex * n - Vec3::splat(0.5)).clamp(Vec3::ZERO, n - Vec3::ONE);
    let i0 = c.floor();
    let f = c - i0;
    let i0 = [i0.x as usize, i0.y as usize, i0.z as usize];
    let i1 = [0, 1, 2].map(|a| (i0[a] + 1).min(dims[a] as usize - 1));
    let (nx, ny) = (dims[0] as usize, dims[1] as usize);
    let at = |x: usize, y: usize, z: usize| texel(x + nx * (y + ny * z));
    let x00 = at(i0[0], i0[1], i0[2]).lerp(at(i1[0], i0[1], i0[2]), f.x);
    let x10 = at(i0[0], i1[1], i0[2]).lerp(at(i1[0], i1[1], i0[2]), f.x);
    let x01 = at(i0[0], i0[1], i1[2]).lerp(at(i1[0], i0[1], i1[2]), f.x);
    let x11 = at(i0[0], i1[1], i1[2]).lerp(at(i1[0], i1[1], i1[2]), f.x);
    x00.lerp(x10, f.y).lerp(x01.lerp(x11, f.y), f.z)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn texel_centres_are_reproduced_and_edges_clamp() {
        // A 2×1×1 grid of values 1 and 3: centres at tex x = ¼ and ¾, linear between, constant beyond.
        let values = [Vec4::splat(1.0), Vec4::splat(3.0)];
        let at = |x: f32| trilinear([2, 1, 1], Vec3::new(x, 0.5, 0.5), |i| values[i]).x;
        assert!((at(0.25) - 1.0).abs() < 1e-6);
        assert!((at(0.75) - 3.0).abs() < 1e-6);
        assert!((at(0.5) - 2.0).abs() < 1e-6);
        assert!((at(0.0) - 1.0).abs() < 1e-6 && (at(1.0) - 3.0).abs() < 1e-6);
    }
}
