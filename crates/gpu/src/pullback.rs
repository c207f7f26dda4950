//! Pull-backs u = d⁻¹ : ref → moving LPS as plain data, for the passes that evaluate them on the GPU (control-texture
//! evaluation, exact export) and for the CPU export path.
//!
//! A thin-plate spline pull-back (Davis 1997; Brunet et al. 2006 §3.3) is
//!
//! u(x) = A x + b + Σᵢ wᵢ ‖x − pᵢ‖,   x in ref (fixed LPS) mm,
//!
//! with centres pᵢ in ref space and weights wᵢ ∈ ℝ³; it is the solver's `Tps<Moving, Fixed>` (`centres()`,
//! `weights()`, `linear()`, `translation()`), passed here as plain f64 arrays because this crate does not depend on
//! the solver.
//!
//! GPUs evaluate in f32. Absolute LPS coordinates of a few hundred mm and large, cancelling weights would lose
//! digits there, so [`TpsLocal`] re-expresses the same function about an origin o (usually the centre of the
//! evaluated box), in f64 on the CPU: with x = o + x′,
//!
//! u(x) − x = (A − I) x′ + (A o + b − o) + Σᵢ wᵢ ‖x′ − (pᵢ − o)‖,
//!
//! i.e. the *displacement* in local coordinates, the quantity control textures store.
//!
//! A hierarchical B-spline pull-back (Lee, Wolberg & Shin 1997) is u(x) = x + Σ_ℓ D_ℓ(clamp(x, Ω_ℓ)) over control
//! lattices ([`BSplineDesc`], [`LatticeDesc`]); its f32 evaluation works in cell units of each lattice, so it needs
//! no local form.

use glam::{DMat3, DVec3};

use crate::error::{GpuError, Result};

/// A TPS pull-back u(x) = A x + b + Σᵢ wᵢ ‖x − pᵢ‖ (module docs), ref mm → moving LPS mm.
#[derive(Clone, Copy, Debug)]
pub struct TpsDesc<'a> {
    /// pᵢ, ref mm.
    pub centres_ref: &'a [[f64; 3]],
    /// wᵢ, one per centre.
    pub weights: &'a [[f64; 3]],
    /// A, row-major: `linear[r][c]` = ∂u_r/∂x_c of the affine part.
    pub linear: [[f64; 3]; 3],
    /// b, mm.
    pub translation: [f64; 3],
}

impl TpsDesc<'_> {
    /// Checks lengths and finiteness; names the first bad centre.
    pub fn validate(&self) -> Result<()> {
        if self.centres_ref.len() != self.weights.len() {
            return Err(GpuError::InvalidInput(format!(
                "TPS has {} centres but {} weights",
                self.centres_ref.len(),
                self.weights.len()
            )));
        }
        if let Some(i) =
            self.centres_ref.iter().zip(self.weights).position(|(p, w)| !p.iter().chain(w).all(|v| v.is_finite()))
        {
            return Err(GpuError::InvalidInput(format!("TPS centre {i} has a non-finite position or weight")));
        }
        if !self.linear.iter().flatten().chain(&self.translation).all(|v| v.is_finite()) {
            return Err(GpuError::InvalidInput("TPS affine part is not finite".into()));
        }
        Ok(())
    }

    /// u(x) in f64, the reference the f32 paths are compared with.
    #[must_use]
    pub fn eval(&self, x_ref: [f64; 3]) -> [f64; 3] {
        let x = DVec3::from_array(x_ref);
        let a = DMat3::from_cols_array_2d(&self.linear).transpose();
        let mut u = a * x + DVec3::from_array(self.translation);
        for (p, w) in self.centres_ref.iter().zip(self.weights) {
            u += DVec3::from_array(*w) * x.distance(DVec3::from_array(*p));
        }
        u.to_array()
    }

    /// The same function about `origin_ref`, as displacement in local coordinates (module docs), rounded to f32.
    #[must_use]
    pub fn local(&self, origin_ref: [f64; 3]) -> TpsLocal {
        let o = DVec3::from_array(origin_ref);
        let a = DMat3::from_cols_array_2d(&self.linear).transpose();
        let lin = a - DMat3::IDENTITY;
        let offset = a * o + DVec3::from_array(self.translation) - o;
        TpsLocal {
            origin_ref,
            linear_minus_identity: std::array::from_fn(|r| std::array::from_fn(|c| lin.row(r)[c] as f32)),
            offset_mm: offset.as_vec3().to_array(),
            centres_local: self.centres_ref.iter().map(|p| (DVec3::from_array(*p) - o).as_vec3().to_array()).collect(),
            weights: self.weights.iter().map(|w| w.map(|v| v as f32)).collect(),
        }
    }
}

/// A TPS pull-back re-expressed about `origin_ref` in f32: disp(o + x′) = (A − I) x′ + offset + Σᵢ wᵢ ‖x′ − pᵢ′‖.
#[derive(Clone, Debug, PartialEq)]
pub struct TpsLocal {
    pub origin_ref: [f64; 3],
    /// (A − I), row-major.
    pub linear_minus_identity: [[f32; 3]; 3],
    /// A o + b − o, mm.
    pub offset_mm: [f32; 3],
    /// pᵢ − o, mm.
    pub centres_local: Vec<[f32; 3]>,
    pub weights: Vec<[f32; 3]>,
}

impl TpsLocal {
    /// The displacement u(o + x′) − (o + x′) in f32, with the GPU's order of operations (affine, then centres in
    /// order; squared distances as dx² + (dy² + dz²), which lets the CPU export reuse dy² + dz² along a row).
    #[must_use]
    pub fn displacement(&self, x_local: [f32; 3]) -> [f32; 3] {
        let l = &self.linear_minus_identity;
        let mut d: [f32; 3] = std::array::from_fn(|r| {
            l[r][0] * x_local[0] + l[r][1] * x_local[1] + l[r][2] * x_local[2] + self.offset_mm[r]
        });
        for (p, w) in self.centres_local.iter().zip(&self.weights) {
            let (dx, dy, dz) = (x_local[0] - p[0], x_local[1] - p[1], x_local[2] - p[2]);
            let r = (dx * dx + (dy * dy + dz * dz)).sqrt();
            for c in 0..3 {
                d[c] += w[c] * r;
            }
        }
        d
    }
}

/// The most control points one [`LatticeDesc`] may have (the solver's `bspline::MAX_CONTROL_POINTS`, 128³).
pub const MAX_LATTICE_POINTS: usize = 1 << 21;

/// One cubic B-spline control lattice of a hierarchical B-spline pull-back (Lee, Wolberg & Shin 1997), in the
/// solver's layout (`warpbench_solver::bspline::ControlLattice`): `cells` per axis over the box [min, max] (ref mm),
/// edge h = (max − min)/cells, and 3 coefficients (dx, dy, dz mm) per control point, x fastest, with
/// (cells + 3) points per axis; storage index 0 is the paper's index −1, so point (i, j, k) sits at
/// min + (i − 1, j − 1, k − 1)·h.
#[derive(Clone, Copy, Debug)]
pub struct LatticeDesc<'a> {
    pub cells: [usize; 3],
    pub min_mm: [f64; 3],
    pub max_mm: [f64; 3],
    pub coefficients: &'a [f64],
}

/// A hierarchical B-spline pull-back u(x) = x + Σ_ℓ D_ℓ(clamp(x, [min_ℓ, max_ℓ])), ref mm → moving LPS mm, D_ℓ the
/// tensor-product cubic B-spline of lattice ℓ (Lee et al. 1997 eq. 1). The solver refines all its levels onto one
/// lattice (`HierarchicalBSpline::lattice`), so it passes one; unrefined levels can be passed as several. Each lattice
/// is evaluated at x clamped to its own box, as the solver does: the displacement is constant along an axis beyond
/// the box.
#[derive(Clone, Copy, Debug)]
pub struct BSplineDesc<'a> {
    pub lattices: &'a [LatticeDesc<'a>],
}

impl LatticeDesc<'_> {
    /// Control points per axis: cells + 3.
    #[must_use]
    pub fn points(&self) -> [usize; 3] {
        self.cells.map(|c| c.saturating_add(3))
    }

    /// Checks cells, box, coefficient count and finiteness; `index` names the lattice in messages.
    pub fn validate(&self, index: usize) -> Result<()> {
        let bad = |why: String| Err(GpuError::InvalidInput(format!("B-spline lattice {index}: {why}")));
        if self.cells.contains(&0) {
            return bad(format!("needs at least one cell per axis, got {:?}", self.cells));
        }
        if !(0..3).all(|a| self.min_mm[a].is_finite() && self.max_mm[a].is_finite() && self.max_mm[a] > self.min_mm[a])
        {
            return bad(format!("box {:?} .. {:?} is empty or not finite", self.min_mm, self.max_mm));
        }
        let points = self.points().iter().try_fold(1usize, |acc, &n| acc.checked_mul(n));
        match points {
            Some(n) if n <= MAX_LATTICE_POINTS => {
                if self.coefficients.len() != 3 * n {
                    return bad(format!(
                        "{:?} cells need {} coefficients, got {}",
                        self.cells,
                        3 * n,
                        self.coefficients.len()
                    ));
                }
            }
            _ => return bad(format!("{:?} cells exceed {MAX_LATTICE_POINTS} control points", self.cells)),
        }
        if let Some(i) = self.coefficients.iter().position(|c| !c.is_finite()) {
            return bad(format!("coefficient {i} is not finite"));
        }
        Ok(())
    }

    /// D(clamp(x)) in f64 (the solver's `ControlLattice::eval`).
    #[must_use]
    pub fn displacement(&self, x_ref: [f64; 3]) -> [f64; 3] {
        let mut first = [0usize; 3];
        let mut weights = [[0.0f64; 4]; 3];
        for a in 0..3 {
            let (lo, hi, cells) = (self.min_mm[a], self.max_mm[a], self.cells[a]);
            let u = (x_ref[a].clamp(lo, hi) - lo) / (hi - lo) * cells as f64;
            let i = (u.floor() as usize).min(cells - 1);
            let s = u - i as f64;
            first[a] = i;
            weights[a] = [
                (1.0 - s).powi(3),
                3.0 * s.powi(3) - 6.0 * s * s + 4.0,
                -3.0 * s.powi(3) + 3.0 * s * s + 3.0 * s + 1.0,
                s.powi(3),
            ]
            .map(|b| b / 6.0);
        }
        let [n0, n1, _] = self.points();
        let mut d = [0.0; 3];
        for (c, wz) in weights[2].iter().enumerate() {
            for (b, wy) in weights[1].iter().enumerate() {
                for (a, wx) in weights[0].iter().enumerate() {
                    let k = 3 * (((first[2] + c) * n1 + first[1] + b) * n0 + first[0] + a);
                    for (r, dr) in d.iter_mut().enumerate() {
                        *dr += wz * wy * wx * self.coefficients[k + r];
                    }
                }
            }
        }
        d
    }
}

impl BSplineDesc<'_> {
    /// Checks every lattice ([`LatticeDesc::validate`]).
    pub fn validate(&self) -> Result<()> {
        self.lattices.iter().enumerate().try_for_each(|(i, l)| l.validate(i))
    }

    /// u(x) in f64, the reference the f32 paths are compared with.
    #[must_use]
    pub fn eval(&self, x_ref: [f64; 3]) -> [f64; 3] {
        let mut u = x_ref;
        for l in self.lattices {
            let d = l.displacement(x_ref);
            for a in 0..3 {
                u[a] += d[a];
            }
        }
        u
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn example() -> (Vec<[f64; 3]>, Vec<[f64; 3]>) {
        let centres = vec![[-80.0, 120.0, 300.0], [40.0, 130.0, 310.0], [0.0, 90.0, 250.0], [10.0, 150.0, 280.0]];
        let weights = vec![[0.02, -0.01, 0.005], [-0.03, 0.02, 0.0], [0.01, -0.02, -0.01], [0.0, 0.01, 0.005]];
        (centres, weights)
    }

    #[test]
    fn local_form_is_the_same_function() {
        let (centres, weights) = example();
        let tps = TpsDesc {
            centres_ref: &centres,
            weights: &weights,
            linear: [[1.01, 0.02, 0.0], [-0.01, 0.98, 0.03], [0.0, 0.01, 1.02]],
            translation: [3.0, -2.0, 5.0],
        };
        tps.validate().expect("valid TPS");
        let origin = [0.0, 120.0, 280.0];
        let local = tps.local(origin);
        for x in [[-60.0, 100.0, 260.0], [20.0, 140.0, 300.0], [5.0, 121.0, 279.0]] {
            let u = tps.eval(x);
            let x_local = std::array::from_fn(|c| (x[c] - origin[c]) as f32);
            let d = local.displacement(x_local);
            for c in 0..3 {
                assert!((f64::from(d[c]) - (u[c] - x[c])).abs() < 1e-4, "{x:?} component {c}");
            }
        }
    }

    #[test]
    fn constant_lattice_is_a_translation_everywhere_and_validate_names_problems() {
        let coefficients: Vec<f64> = (0..5 * 4 * 6).flat_map(|_| [1.5, -2.0, 0.25]).collect();
        let lattice = LatticeDesc {
            cells: [2, 1, 3],
            min_mm: [-10.0, 0.0, 100.0],
            max_mm: [10.0, 5.0, 130.0],
            coefficients: &coefficients,
        };
        let desc = BSplineDesc { lattices: &[lattice] };
        desc.validate().expect("valid lattice");
        // The bases sum to 1, inside the box and (clamped) far outside it.
        for x in [[0.0, 2.5, 110.0], [-9.9, 4.9, 129.0], [500.0, -300.0, 0.0]] {
            let u = desc.eval(x);
            assert!((u[0] - x[0] - 1.5).abs() < 1e-12 && (u[1] - x[1] + 2.0).abs() < 1e-12, "{x:?}: {u:?}");
        }
        let short = LatticeDesc { coefficients: &coefficients[3..], ..lattice };
        let err = BSplineDesc { lattices: &[lattice, short] }.validate().expect_err("short").to_string();
        assert!(err.contains("lattice 1") && err.contains("360 coefficients"), "{err}");
        let mut nan = coefficients.clone();
        nan[7] = f64::NAN;
        let err = LatticeDesc { coefficients: &nan, ..lattice }.validate(0).expect_err("NaN").to_string();
        assert!(err.contains("coefficient 7"), "{err}");
        assert!(LatticeDesc { cells: [0, 1, 3], ..lattice }.validate(0).is_err());
        assert!(LatticeDesc { max_mm: [-10.0, 5.0, 130.0], ..lattice }.validate(0).is_err());
    }

    #[test]
    fn validate_names_bad_centre() {
        let (mut centres, weights) = example();
        centres[2][1] = f64::NAN;
        let tps =
            TpsDesc { centres_ref: &centres, weights: &weights, linear: [[1.0, 0.0, 0.0]; 3], translation: [0.0; 3] };
        let err = tps.validate().expect_err("NaN centre").to_string();
        assert!(err.contains("centre 2"), "{err}");
        let short = TpsDesc { centres_ref: &centres[..1], ..tps };
        assert!(short.validate().expect_err("short weights").to_string().contains("1 centres but 4 weights"));
    }
}
