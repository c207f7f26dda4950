//! The pull-back as the ITK transform that holds it exactly ([`itk_transform_of`], the mapping of each method to an
//! ITK class is in the [`transform`](super) docs). A leaf: the warp stack ([`crate::project::stack`]) writes its ITK
//! file through it, and the `transform` subcommand fits through the stack.

use warpbench_io::geometry::Point3;
use warpbench_io::itk_tfm::{ItkAffine, ItkBSpline, ItkThinPlateSpline, ItkTransform};
use warpbench_solver::method::FittedWarp;
use warpbench_solver::spaces::{Fixed, Moving};
use warpbench_solver::warp::Warp;

/// The pull-back `moving_from_fixed` as the ITK transform that holds it exactly ([`transform`](super) docs).
#[must_use]
pub fn itk_transform_of(moving_from_fixed: &FittedWarp<Moving, Fixed>) -> ItkTransform {
    match moving_from_fixed {
        FittedWarp::Linear(warp) => ItkTransform::Affine(ItkAffine::from_offset(warp.linear(), warp.translation())),
        FittedWarp::Tps(tps) => {
            let source_lps: Vec<[f64; 3]> = tps.centres().iter().map(Point3::coords).collect();
            let mut target_lps = vec![[0.0; 3]; source_lps.len()];
            tps.apply_batch_raw(&source_lps, &mut target_lps);
            ItkTransform::ThinPlateSpline(ItkThinPlateSpline { source_lps, target_lps })
        }
        FittedWarp::BSpline(spline) => {
            let lattice = spline.lattice();
            let spacing = lattice.spacing_mm();
            let min = lattice.min_mm();
            ItkTransform::BSpline(ItkBSpline {
                grid_size: lattice.dims(),
                grid_origin_lps: std::array::from_fn(|a| min[a] - spacing[a]),
                grid_spacing_mm: spacing,
                grid_direction: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
                coefficients_mm: lattice.coefficients().chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect(),
            })
        }
    }
}
