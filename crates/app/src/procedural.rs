//! The procedural deformation of the moving volume by name: a [`ProceduralSpec`] (kind, amplitude A, seed) becomes the
//! renderer's [`Procedural`] over the moving volume's box Ω ([`ProceduralSpec::build`]).
//!
//! For `sine`, `twist`, `bend` and `bump` the deformation is **exactly `eval`'s synthetic warp** of that kind,
//! amplitude and seed over the same box ([`warpbench_solver::synthetic::SyntheticWarp`], its
//! [`ClosedForm`] parameters handed to the shader): `render --procedural bend --procedural-amplitude-mm 5
//! --procedural-seed 1` of a volume V shows the moving volume M = V∘d that `eval --kind bend --amplitude-mm 5 --seed
//! 1` builds from V and tests. `shift` is a constant offset of length A in a seeded direction (uniform on the sphere).
//!
//! The renderer reads the moving volume at p(u(x)), u the landmark warp's pull-back (see
//! [`warpbench_gpu::procedural`]): the deformation acts on the volume's data, the landmarks live in the deformed
//! volume's space, and nothing is resampled. It is a view: `warp`, `field` and the window's exports resample the volume
//! that was opened, without it.

use anyhow::{Context, anyhow};
use serde::{Deserialize, Serialize};
use warpbench_gpu::glam::Vec3;
use warpbench_gpu::{Axis, Procedural};
use warpbench_solver::spaces::{Aabb, Moving};
use warpbench_solver::synthetic::{ClosedForm, SyntheticKind, SyntheticWarp};

use crate::eval::sampling::SplitMix64;
use crate::settings::ProceduralKind;

/// The random stream of a shift's direction ([`SplitMix64`]).
const SHIFT_STREAM: u64 = 0x0053_4849_4654;

/// A procedural deformation by name, as the command line and the session give it.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ProceduralSpec {
    pub kind: ProceduralKind,
    /// The largest displacement over the moving volume's box, mm (`eval`'s `--amplitude-mm`).
    pub amplitude_mm: f64,
    pub seed: u64,
}

impl Default for ProceduralSpec {
    fn default() -> Self {
        Self { kind: ProceduralKind::default(), amplitude_mm: 5.0, seed: 1 }
    }
}

impl ProceduralSpec {
    /// The deformation over the moving volume's box `domain` (the box of its voxel edges, as `eval` takes it).
    ///
    /// Errors: an amplitude that is negative or not finite, or above what the kind takes over this box (the synthetic
    /// warps' fold-free limits, `eval`'s refusals), named in the message.
    pub fn build(&self, domain: Aabb<Moving>) -> anyhow::Result<Procedural> {
        let a = self.amplitude_mm;
        if !(a.is_finite() && a >= 0.0) {
            return Err(anyhow!("the procedural amplitude must be a finite number of mm ≥ 0, got {a}"));
        }
        let synthetic = match self.kind {
            ProceduralKind::Shift => {
                let mut rng = SplitMix64::new(self.seed, SHIFT_STREAM);
                // Uniform on the sphere: z uniform in [−1, 1], the azimuth uniform.
                let z = 2.0 * rng.unit() - 1.0;
                let phi = std::f64::consts::TAU * rng.unit();
                let r = (1.0 - z * z).max(0.0).sqrt();
                let t = [r * phi.cos(), r * phi.sin(), z].map(|c| (a * c) as f32);
                return Ok(Procedural::Shift { offset_mm: Vec3::from_array(t) });
            }
            ProceduralKind::Sine => SyntheticKind::Sine,
            ProceduralKind::Twist => SyntheticKind::Twist,
            ProceduralKind::Bend => SyntheticKind::Bend,
            ProceduralKind::Bump => SyntheticKind::Bump,
        };
        let warp = SyntheticWarp::new(synthetic, domain, a, self.seed)
            .with_context(|| format!("procedural {} of {a} mm", self.kind))?;
        let form = warp.closed_form().ok_or_else(|| anyhow!("{} has no closed form", self.kind))?;
        Ok(procedural_of(&form))
    }
}

/// The renderer's form of a synthetic warp's closed form (f64 → the shader's f32).
#[must_use]
pub fn procedural_of(form: &ClosedForm) -> Procedural {
    let v = |a: [f64; 3]| Vec3::from_array(a.map(|c| c as f32));
    match *form {
        ClosedForm::Sine { origin, wavenumber_per_mm, phase_rad, amp_mm } => Procedural::Sine {
            origin_mm: v(origin),
            amplitude_mm: amp_mm as f32,
            wavenumber_per_mm: v(wavenumber_per_mm),
            phase_rad: v(phase_rad),
        },
        ClosedForm::Twist { centre, axis, rate_rad_per_mm } => Procedural::Twist {
            centre_mm: v(centre),
            axis: Axis::from_index(axis),
            rate_rad_per_mm: rate_rad_per_mm as f32,
        },
        ClosedForm::Bend { centre, axial, normal, normal_sign, curvature_per_mm } => Procedural::bend(
            v(centre),
            Axis::from_index(axial),
            Axis::from_index(normal),
            normal_sign > 0.0,
            curvature_per_mm as f32,
        ),
        ClosedForm::Bump { centre, sigma_mm, vector_mm } => {
            Procedural::Bump { centre_mm: v(centre), sigma_mm: sigma_mm as f32, vector_mm: v(vector_mm) }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use warpbench_io::geometry::Point3;
    use warpbench_solver::warp::Warp;

    fn domain() -> Aabb<Moving> {
        Aabb::new(Point3::new(-91.0, -126.0, -72.0), Point3::new(91.0, 91.0, 109.0))
    }

    /// The shader's formulas (their f32 CPU twin) are the solver's synthetic warps: the same d at random points of
    /// the box and around it, within f32 rounding of coordinates up to ~200 mm (and the trigonometry's).
    #[test]
    fn each_kind_is_evals_synthetic_warp() {
        let mut rng = SplitMix64::new(5, 9);
        for kind in [ProceduralKind::Sine, ProceduralKind::Twist, ProceduralKind::Bend, ProceduralKind::Bump] {
            for seed in 1..=4 {
                let spec = ProceduralSpec { kind, amplitude_mm: 8.0, seed };
                let p = spec.build(domain()).expect("build");
                let synthetic = match kind {
                    ProceduralKind::Sine => SyntheticKind::Sine,
                    ProceduralKind::Twist => SyntheticKind::Twist,
                    ProceduralKind::Bend => SyntheticKind::Bend,
                    _ => SyntheticKind::Bump,
                };
                let warp = SyntheticWarp::new(synthetic, domain(), 8.0, seed).expect("warp");
                let (lo, hi) = (domain().min.coords(), domain().max.coords());
                let mut worst: f64 = 0.0;
                for _ in 0..2000 {
                    let x: [f64; 3] = std::array::from_fn(|a| lo[a] - 20.0 + (hi[a] - lo[a] + 40.0) * rng.unit());
                    let exact = warp.apply_raw(x);
                    let d = p.displacement(Vec3::from_array(x.map(|c| c as f32)));
                    let shader: [f64; 3] = std::array::from_fn(|a| x[a] + f64::from(d[a]));
                    worst = worst.max((0..3).map(|a| (shader[a] - exact[a]).abs()).fold(0.0, f64::max));
                }
                assert!(worst < 2e-4, "{kind} seed {seed}: shader form off by {worst} mm");
            }
        }
    }

    #[test]
    fn a_shift_has_the_amplitude_and_a_seeded_direction() {
        let shift =
            |seed| match (ProceduralSpec { kind: ProceduralKind::Shift, amplitude_mm: 6.0, seed }).build(domain()) {
                Ok(Procedural::Shift { offset_mm }) => offset_mm,
                other => panic!("{other:?}"),
            };
        assert!((shift(1).length() - 6.0).abs() < 1e-5);
        assert_eq!(shift(3), shift(3));
        assert!(shift(3).distance(shift(4)) > 0.1);
    }

    #[test]
    fn amplitudes_a_kind_cannot_take_are_refused() {
        for (kind, a) in
            [(ProceduralKind::Sine, 500.0), (ProceduralKind::Bump, -1.0), (ProceduralKind::Shift, f64::NAN)]
        {
            let err = ProceduralSpec { kind, amplitude_mm: a, seed: 1 }.build(domain()).expect_err("refused");
            eprintln!("{kind} {a}: {err:#}");
        }
    }
}
