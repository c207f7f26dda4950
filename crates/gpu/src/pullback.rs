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
    /// order).
    #[must_use]
    pub fn displacement(&self, x_local: [f32; 3]) -> [f32; 3] {
        let l = &self.linear_minus_identity;
        let mut d: [f32; 3] = std::array::from_fn(|r| {
            l[r][0] * x_local[0] + l[r][1] * x_local[1] + l[r][2] * x_local[2] + self.offset_mm[r]
        });
        for (p, w) in self.centres_local.iter().zip(&self.weights) {
            let (dx, dy, dz) = (x_local[0] - p[0], x_local[1] - p[1], x_local[2] - p[2]);
            let r = (dx * dx + dy * dy + dz * dz).sqrt();
            for c in 0..3 {
                d[c] += w[c] * r;
            }
        }
        d
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
