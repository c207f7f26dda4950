//! The bending energy of a cubic B-spline lattice, exactly, and its gradient.
//!
//! For D = Σ φ_{ijk} N_i(x) N_j(y) N_k(z) over the lattice's box Ω (volume V), the thin-plate bending energy
//!
//! E(φ) = (1/V) ∫_Ω Σ_r [ (∂xx D_r)² + (∂yy D_r)² + (∂zz D_r)² + 2 (∂xy D_r)² + 2 (∂xz D_r)² + 2 (∂yz D_r)² ] dx
//!
//! is a quadratic form. Each term is a Kronecker product of 1-D Gram matrices, e.g.
//! ∫ (∂xy D_r)² = φ_rᵀ (G¹_x ⊗ G¹_y ⊗ G⁰_z) φ_r, with G^d_a[i][i'] = ∫ N_i^{(d)} N_{i'}^{(d)} along axis a. The Gram
//! matrices are banded (a basis function meets 3 neighbours on each side) and integrated exactly, cell by cell, by
//! 4-point Gauss–Legendre quadrature (the products are polynomials of degree ≤ 6). E is applied separably, one axis
//! at a time, and ∂E/∂φ = (2/V) K φ. Dividing by V makes the weight independent of the box's size, as ITK's
//! `TransformBendingEnergyPenalty` averages over its samples.

use crate::bspline::ControlLattice;

/// A symmetric banded matrix of half-bandwidth 3: row i holds entries i − 3 ..= i + 3.
#[derive(Clone, Debug)]
struct Banded {
    rows: Vec<[f64; 7]>,
}

/// The second derivatives d²B_a/dt² of the uniform cubic B-spline basis ([`crate::bspline::basis`]).
fn basis_second_derivative(t: f64) -> [f64; 4] {
    [1.0 - t, 3.0 * t - 2.0, 1.0 - 3.0 * t, t]
}

/// 4-point Gauss–Legendre nodes and weights on [0, 1].
const GAUSS: [(f64, f64); 4] = [
    (0.069_431_844_202_973_71, 0.173_927_422_568_726_93),
    (0.330_009_478_207_571_87, 0.326_072_577_431_273_07),
    (0.669_990_521_792_428_1, 0.326_072_577_431_273_07),
    (0.930_568_155_797_026_3, 0.173_927_422_568_726_93),
];

impl Banded {
    /// G^d for `cells` cells of edge `h` mm: ∫ N_i^{(d)} N_{i'}^{(d)} dx over the axis's domain.
    fn gram(cells: usize, h: f64, order: usize) -> Self {
        let mut rows = vec![[0.0; 7]; cells + 3];
        for c in 0..cells {
            for &(t, w) in &GAUSS {
                let values = match order {
                    0 => crate::bspline::basis(t),
                    1 => crate::bspline::basis_derivative(t).map(|v| v / h),
                    _ => basis_second_derivative(t).map(|v| v / (h * h)),
                };
                for a in 0..4 {
                    for b in 0..4 {
                        // Row c + a, column c + b: offset b − a + 3 in the band.
                        rows[c + a][b + 3 - a] += w * h * values[a] * values[b];
                    }
                }
            }
        }
        Self { rows }
    }
}

/// The bending energy of lattices over one box with one number of cells.
#[derive(Clone, Debug)]
pub(crate) struct Bending {
    /// `gram[axis][order]`.
    gram: [[Banded; 3]; 3],
    dims: [usize; 3],
    volume: f64,
}

/// The six terms: derivative orders per axis and their multiplicity.
const TERMS: [([usize; 3], f64); 6] =
    [([2, 0, 0], 1.0), ([0, 2, 0], 1.0), ([0, 0, 2], 1.0), ([1, 1, 0], 2.0), ([1, 0, 1], 2.0), ([0, 1, 1], 2.0)];

impl Bending {
    /// The energy of lattices shaped like `lattice` (its cells and box).
    pub(crate) fn new(lattice: &ControlLattice) -> Self {
        let (cells, h) = (lattice.cells(), lattice.spacing_mm());
        let gram = std::array::from_fn(|a| std::array::from_fn(|d| Banded::gram(cells[a], h[a], d)));
        let (lo, hi) = (lattice.min_mm(), lattice.max_mm());
        Self { gram, dims: lattice.dims(), volume: (0..3).map(|a| hi[a] - lo[a]).product() }
    }

    /// E(φ) for the flat coefficients `phi` (the lattice's layout), and ∂E/∂φ added to `gradient` times `weight`.
    pub(crate) fn energy_adding_gradient(&self, phi: &[f64], weight: f64, gradient: &mut [f64]) -> f64 {
        debug_assert_eq!(phi.len(), gradient.len());
        let mut energy = 0.0;
        let (mut a, mut b) = (vec![0.0; phi.len()], vec![0.0; phi.len()]);
        for (orders, multiplicity) in TERMS {
            apply_axis(phi, self.dims, 0, &self.gram[0][orders[0]], &mut a);
            apply_axis(&a, self.dims, 1, &self.gram[1][orders[1]], &mut b);
            apply_axis(&b, self.dims, 2, &self.gram[2][orders[2]], &mut a);
            let scale = multiplicity / self.volume;
            energy += scale * phi.iter().zip(&a).map(|(p, k)| p * k).sum::<f64>();
            let g = 2.0 * scale * weight;
            for (out, k) in gradient.iter_mut().zip(&a) {
                *out += g * k;
            }
        }
        energy
    }
}

/// `out` = `matrix` applied along `axis` of the 3-component coefficient array `src` (x fastest).
fn apply_axis(src: &[f64], dims: [usize; 3], axis: usize, matrix: &Banded, out: &mut [f64]) {
    let stride = match axis {
        0 => 3,
        1 => 3 * dims[0],
        _ => 3 * dims[0] * dims[1],
    };
    let n = dims[axis];
    for (o, value) in out.iter_mut().enumerate() {
        let i = (o / stride) % n;
        let mut sum = 0.0;
        for (band, &m) in matrix.rows[i].iter().enumerate() {
            let j = i as isize + band as isize - 3;
            if m != 0.0 && (0..n as isize).contains(&j) {
                sum += m * src[(o as isize + (j - i as isize) * stride as isize) as usize];
            }
        }
        *value = sum;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A lattice with seeded coefficients over an anisotropic box.
    fn lattice() -> ControlLattice {
        let mut l = ControlLattice::zeros([3, 4, 2], [-10.0, 5.0, 0.0], [20.0, 45.0, 12.0]).expect("test input");
        let mut state = 7u64;
        for c in l.coefficients_mut() {
            state = state.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
            *c = ((state >> 11) as f64 / (1u64 << 53) as f64 - 0.5) * 4.0;
        }
        l
    }

    /// The energy by brute force: second derivatives of D by central differences of the lattice's own evaluation,
    /// integrated by the midpoint rule on a fine grid.
    fn brute_force(l: &ControlLattice) -> f64 {
        let (lo, hi) = (l.min_mm(), l.max_mm());
        let n = [60, 80, 40];
        let size: [f64; 3] = std::array::from_fn(|a| (hi[a] - lo[a]) / n[a] as f64);
        let e = 1e-3;
        let mut sum = 0.0;
        for k in 0..n[2] {
            for j in 0..n[1] {
                for i in 0..n[0] {
                    let x: [f64; 3] = std::array::from_fn(|a| lo[a] + ([i, j, k][a] as f64 + 0.5) * size[a]);
                    let at = |d: [f64; 3]| l.eval([x[0] + d[0], x[1] + d[1], x[2] + d[2]]);
                    for (orders, m) in TERMS {
                        let axes: Vec<usize> = (0..3).flat_map(|a| std::iter::repeat_n(a, orders[a])).collect();
                        let (p, q) = (axes[0], axes[1]);
                        let step = |a: usize, s: f64| {
                            let mut d = [0.0; 3];
                            d[a] = s;
                            d
                        };
                        let add = |u: [f64; 3], v: [f64; 3]| [u[0] + v[0], u[1] + v[1], u[2] + v[2]];
                        let pp = at(add(step(p, e), step(q, e)));
                        let pm = at(add(step(p, e), step(q, -e)));
                        let mp = at(add(step(p, -e), step(q, e)));
                        let mm = at(add(step(p, -e), step(q, -e)));
                        for r in 0..3 {
                            let d2 = (pp[r] - pm[r] - mp[r] + mm[r]) / (4.0 * e * e);
                            sum += m * d2 * d2;
                        }
                    }
                }
            }
        }
        sum / (n[0] * n[1] * n[2]) as f64
    }

    #[test]
    fn the_energy_is_the_integral_of_the_squared_second_derivatives() {
        let l = lattice();
        let bending = Bending::new(&l);
        let mut g = vec![0.0; l.coefficients().len()];
        let exact = bending.energy_adding_gradient(l.coefficients(), 1.0, &mut g);
        let brute = brute_force(&l);
        // The midpoint rule on a 60 × 80 × 40 grid of a piecewise polynomial: relative error well below 1 %.
        assert!(((exact - brute) / brute).abs() < 0.01, "{exact} vs brute force {brute}");
    }

    #[test]
    fn the_gradient_is_the_derivative_of_the_energy() {
        let l = lattice();
        let bending = Bending::new(&l);
        let mut g = vec![0.0; l.coefficients().len()];
        bending.energy_adding_gradient(l.coefficients(), 1.0, &mut g);
        let mut scratch = vec![0.0; g.len()];
        for index in [0, 5, 17, 40, 77, g.len() - 1] {
            let h = 1e-4;
            let mut phi = l.coefficients().to_vec();
            phi[index] += h;
            let up = bending.energy_adding_gradient(&phi, 0.0, &mut scratch);
            phi[index] -= 2.0 * h;
            let down = bending.energy_adding_gradient(&phi, 0.0, &mut scratch);
            let numeric = (up - down) / (2.0 * h);
            assert!((numeric - g[index]).abs() < 1e-8 + 1e-6 * numeric.abs(), "{index}: {numeric} vs {}", g[index]);
        }
    }

    #[test]
    fn an_affine_displacement_does_not_bend() {
        // Cubic B-splines reproduce linear functions: φ at each knot is the affine map's value there.
        let mut l = ControlLattice::zeros([4, 3, 5], [0.0; 3], [40.0, 30.0, 25.0]).expect("test input");
        let (dims, h, lo) = (l.dims(), l.spacing_mm(), l.min_mm());
        for k in 0..dims[2] {
            for j in 0..dims[1] {
                for i in 0..dims[0] {
                    let x: [f64; 3] = std::array::from_fn(|a| lo[a] + ([i, j, k][a] as f64 - 1.0) * h[a]);
                    let o = ((k * dims[1] + j) * dims[0] + i) * 3;
                    let c = &mut l.coefficients_mut()[o..o + 3];
                    c[0] = 0.1 * x[0] - 0.2 * x[1] + 3.0;
                    c[1] = 0.05 * x[2];
                    c[2] = -0.3 * x[0] + 0.1 * x[1] + 0.2 * x[2] - 1.0;
                }
            }
        }
        let mut g = vec![0.0; l.coefficients().len()];
        let e = Bending::new(&l).energy_adding_gradient(l.coefficients(), 1.0, &mut g);
        assert!(e.abs() < 1e-12, "{e}");
        assert!(g.iter().all(|v| v.abs() < 1e-10));
    }
}
