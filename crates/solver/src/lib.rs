//! # warpbench-solver
//!
//! Landmark warps between the moving and the fixed volume, in both directions, and the tools to
//! judge them. A landmark pair is (p_i ∈ moving LPS, q_i ∈ fixed LPS); the forward warp d maps
//! moving to fixed with d(p_i) ≈ q_i, and the **pull-back** u = d⁻¹ maps fixed to moving, because
//! the renderer and the exporter compute v'(x) = v_moving(u(x)) (Brunet, Nowak & Gleicher 2006 §3).
//! Every function says which direction it computes; the types say it too ([`spaces`]).
//!
//! - [`align`]: automatic initial alignment, rigid or affine, by Mattes mutual information, multi-resolution.
//! - [`tps`]: thin-plate spline with the 3-D kernel U(r) = r and a stiffness λ.
//! - [`dense`]: the blocked Cholesky factorisation and triangular inverse under the TPS solve.
//! - [`tps_drag`]: one landmark of a TPS pair dragged in O(N²) per event (factorisation kept, rank-2 updates).
//! - [`bspline`]: hierarchical (multilevel) cubic B-spline approximation (Lee, Wolberg & Shin 1997).
//! - [`linear`]: affine, similarity and rigid least-squares fits (Umeyama 1991) and the predicted TRE.
//! - [`invert`]: an approximate inverse of a forward warp by scattered-data interpolation.
//! - [`brush`]: the local displacement brush, a forward warp of the fixed space made of strokes with a B-spline
//!   falloff, and its inverse through [`invert`].
//! - [`control`]: sampling a pull-back into a control texture for the GPU.
//! - [`field`]: a warp given as a sampled displacement field (ITK's `DisplacementFieldTransform`: trilinear inside
//!   the grid, zero displacement outside).
//! - [`image`]: scalar images in a patient space: trilinear samples with their gradient in mm, a pyramid.
//! - [`method`]: [`Method`], fitting any of the above by name, in either direction, into a [`FittedWarp`] (the
//!   closed set of fitted kinds, a [`Warp`] by delegation).
//! - [`pairs`]: the one validation of landmark pairs that every fit runs first: refusals and warnings.
//! - [`register`]: registration by intensities under the landmarks: a B-spline free-form deformation composed under
//!   the current pull-back, minimising −MI + bending + the pairs' squared distances, multi-resolution, by L-BFGS.
//! - [`diagnostics`]: Jacobian determinant (folding), residuals and leave-one-out errors.
//! - [`stiffness`]: the TPS stiffness chosen automatically, by the leave-one-out error.
//! - [`suggest`]: suggested targets: the fixed point matching a moving point, from the current warp's prediction
//!   refined by a local normalised-gradient-field search, with a confidence.
//! - [`synthetic`]: seeded known warps for accuracy tests.

pub mod align;
pub mod brush;
pub mod bspline;
pub mod control;
pub mod dense;
pub mod diagnostics;
pub mod error;
pub mod field;
pub mod image;
pub mod invert;
pub mod linear;
pub mod method;
pub mod pairs;
pub mod register;
pub mod spaces;
pub mod stiffness;
pub mod suggest;
pub mod synthetic;
pub mod tps;
pub mod tps_drag;
pub mod warp;

pub use error::{Result, SolverError};
pub use method::{FittedWarp, Method};
pub use spaces::{Aabb, Fixed, Moving};
pub use warp::{Parallelism, Warp};
