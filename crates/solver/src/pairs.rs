//! Checking landmark pairs before a fit: one validation for every method and both directions.
//!
//! A fit takes pairs (pᵢ ∈ `From`, qᵢ ∈ `To`), i = 1…N. Every fitting entry point ([`crate::Method::fit`],
//! [`crate::tps::Tps::fit_regularised`], [`crate::bspline::HierarchicalBSpline::fit`], [`crate::linear::fit`] and
//! the forward and pull-back helpers over them) calls [`validate`] with what its method needs ([`Needs`]) before it
//! solves anything, so a set of pairs is refused, or warned about, the same way whichever method and whichever
//! direction fits it. Errors and warnings name the pairs by their 1-based position in the lists given and the sides
//! by their spaces' names (`moving`, `fixed`); a caller that fits a subset of a file's pairs renumbers them with
//! [`SolverError::renumber`] and [`PairWarning::renumber`].
//!
//! # Refused ([`SolverError`]), checked in this order
//!
//! 1. Lists of different lengths ([`SolverError::LengthMismatch`]); a coordinate that is NaN or ±∞
//!    ([`SolverError::NonFinite`]).
//! 2. Fewer pairs than the method needs ([`SolverError::TooFew`]).
//! 3. All points of one side at one position ([`SolverError::Coincident`]): the warp would collapse the whole volume
//!    onto a point (or blow a point up into the volume). The hierarchical B-spline accepted this before, with
//!    displacements of kilometres.
//! 4. One point with two different partners, on either side ([`SolverError::Conflict`]): no map sends one point to
//!    two places, and its inverse folds two places onto one point.
//! 5. Fewer *distinct* pairs than the method needs, repeated pairs counted once ([`SolverError::TooFew`]).
//! 6. Either side collinear, or coplanar where the method needs 3-D extent ([`SolverError::Flat`]): the part of the
//!    warp across the line or plane is then undetermined.
//!
//! The two sides are checked alike, so fitting the pull-back (qᵢ → pᵢ) refuses exactly what fitting the forward
//! warp (pᵢ → qᵢ) refuses.
//!
//! # Warned ([`PairWarning`])
//!
//! - The same pair given twice (both points repeat): every method counts it once.
//! - Either side nearly flat (its RMS spread across the line or plane below [`NEARLY_FLAT_RATIO`] of its largest):
//!   the warp across it rests on very little and extrapolates steeply.
//!
//! # Tolerances
//!
//! They scale with the point cloud. Two points of one side are at the same position when they are closer than
//! [`SAME_POSITION_RTOL`] × that side's extent (its bounding-box diagonal), or than the rounding of their coordinates
//! (4 ε · max |x|). A side coincides when its extent is below [`SAME_POSITION_RTOL`] · (1 + max |x|) mm. Flatness
//! compares the RMS spreads σ₁ ≥ σ₂ ≥ σ₃ along the principal axes of the side's distinct points: collinear when
//! σ₂ < [`FLAT_RTOL`] · σ₁, coplanar when σ₃ < [`FLAT_RTOL`] · σ₁.

use std::fmt;

use nalgebra::{Matrix3, Vector3};
use warpbench_io::geometry::{Point3, Space};

use crate::{Result, SolverError};

/// Two points of one side closer than this × the side's extent are at the same position (module docs).
pub const SAME_POSITION_RTOL: f64 = 1e-9;
/// A side whose RMS spread across its line (plane) is below this × its largest spread is collinear (coplanar).
pub const FLAT_RTOL: f64 = 1e-6;
/// A side whose RMS spread across its line (plane) is below this × its largest spread draws a warning.
pub const NEARLY_FLAT_RATIO: f64 = 0.01;

/// The spread a method needs in each point set.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Spread {
    /// Not all on one line: rigid and similarity fits (the rotation about the line is undetermined).
    NotCollinear,
    /// Not all in one plane: a full affine part (affine, TPS, the B-spline's affine initial approximation).
    NotCoplanar,
}

/// What a method needs of its pairs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Needs {
    /// The method as messages name it, e.g. "thin-plate spline".
    pub method: &'static str,
    /// The fewest distinct pairs.
    pub min_pairs: usize,
    pub spread: Spread,
}

/// A set of pairs that fits, but looks wrong. Pair numbers are 1-based positions in the lists given.
#[derive(Clone, Debug, PartialEq)]
#[non_exhaustive]
pub enum PairWarning {
    /// Pair `second` repeats pair `first` (both points at the same positions); it is counted once.
    Repeated { first: usize, second: usize },
    /// One side is nearly `shape` ("collinear" or "coplanar"): its RMS spread across is `across_mm`, against
    /// `extent_mm` along its main axis.
    NearlyFlat { space: &'static str, shape: &'static str, across_mm: f64, extent_mm: f64 },
}

impl PairWarning {
    /// The same warning with every pair number n replaced by `f(n)` (both 1-based), e.g. to number the pairs as
    /// in the file they came from.
    #[must_use]
    pub fn renumber(self, f: impl Fn(usize) -> usize) -> Self {
        match self {
            Self::Repeated { first, second } => Self::Repeated { first: f(first), second: f(second) },
            other @ Self::NearlyFlat { .. } => other,
        }
    }
}

impl fmt::Display for PairWarning {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Repeated { first, second } => {
                write!(f, "landmarks {first} and {second} are the same pair (both points repeat); it is counted once")
            }
            Self::NearlyFlat { space, shape, across_mm, extent_mm } => write!(
                f,
                "the {space} points are nearly {shape} (RMS spread {across_mm:.3} mm across, {extent_mm:.1} mm \
                 along): the warp away from that {} is poorly determined",
                if *shape == "collinear" { "line" } else { "plane" }
            ),
        }
    }
}

/// What [`validate`] found in pairs it accepts.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Checked {
    /// The 0-based indices of the distinct pairs, in order (a repeated pair keeps its first copy).
    pub distinct: Vec<usize>,
    pub warnings: Vec<PairWarning>,
}

impl Checked {
    /// `points` restricted to the distinct pairs, as raw mm.
    #[must_use]
    pub fn distinct_raw<S: Space>(&self, points: &[Point3<S>]) -> Vec<[f64; 3]> {
        self.distinct.iter().map(|&i| points[i].coords()).collect()
    }
}

/// Checks (pᵢ = `src[i]`, qᵢ = `dst[i]`) against `needs` (module docs): the distinct pairs and the warnings, or
/// the first reason the pairs have no meaningful warp.
pub fn validate<From: Space, To: Space>(needs: &Needs, src: &[Point3<From>], dst: &[Point3<To>]) -> Result<Checked> {
    if src.len() != dst.len() {
        return Err(SolverError::LengthMismatch {
            from_space: From::NAME,
            from_len: src.len(),
            to_space: To::NAME,
            to_len: dst.len(),
        });
    }
    if let Some(i) = src.iter().zip(dst).position(|(p, q)| !(p.is_finite() && q.is_finite())) {
        return Err(SolverError::NonFinite { pair: i + 1 });
    }
    let too_few = |got: usize| SolverError::TooFew { method: needs.method, needed: needs.min_pairs, got };
    if src.len() < needs.min_pairs {
        return Err(too_few(src.len()));
    }
    let p: Vec<[f64; 3]> = src.iter().map(Point3::coords).collect();
    let q: Vec<[f64; 3]> = dst.iter().map(Point3::coords).collect();
    let side_p = Side::new(&p, From::NAME)?;
    let side_q = Side::new(&q, To::NAME)?;
    let (twin_p, twin_q) = (side_p.earlier_twins(), side_q.earlier_twins());

    let mut checked = Checked::default();
    for j in 0..p.len() {
        // The earliest pair that shares pᵢ (or qᵢ) with pair j but not its partner is a conflict.
        let conflict = |twin: Option<usize>, same_partner: &dyn Fn(usize) -> bool, space, other| {
            twin.filter(|&i| !same_partner(i)).map(|i| SolverError::Conflict {
                space,
                other,
                first: i + 1,
                second: j + 1,
            })
        };
        if let Some(e) = conflict(twin_p[j], &|i| side_q.same(i, j), From::NAME, To::NAME)
            .or_else(|| conflict(twin_q[j], &|i| side_p.same(i, j), To::NAME, From::NAME))
        {
            return Err(e);
        }
        match twin_p[j] {
            Some(i) => checked.warnings.push(PairWarning::Repeated { first: i + 1, second: j + 1 }),
            None => checked.distinct.push(j),
        }
    }
    if checked.distinct.len() < needs.min_pairs {
        return Err(too_few(checked.distinct.len()));
    }
    for side in [&side_p, &side_q] {
        if let Some(w) = side.check_spread(needs, &checked.distinct)? {
            checked.warnings.push(w);
        }
    }
    Ok(checked)
}

/// One point set of the pairs, with its tolerance.
struct Side<'a> {
    points: &'a [[f64; 3]],
    space: &'static str,
    /// Two points closer than this are at the same position, mm.
    tol_mm: f64,
}

impl<'a> Side<'a> {
    /// Refuses a side whose points all coincide.
    fn new(points: &'a [[f64; 3]], space: &'static str) -> Result<Self> {
        let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
        for p in points {
            for a in 0..3 {
                lo[a] = lo[a].min(p[a]);
                hi[a] = hi[a].max(p[a]);
            }
        }
        let extent_mm = (0..3).map(|a| (hi[a] - lo[a]).powi(2)).sum::<f64>().sqrt();
        let max_abs = points.iter().flatten().fold(0.0_f64, |m, v| m.max(v.abs()));
        if points.len() > 1 && extent_mm <= SAME_POSITION_RTOL * (1.0 + max_abs) {
            return Err(SolverError::Coincident { space, count: points.len(), at_mm: points[0] });
        }
        let tol_mm = (SAME_POSITION_RTOL * extent_mm).max(4.0 * f64::EPSILON * max_abs);
        Ok(Self { points, space, tol_mm })
    }

    fn same(&self, i: usize, j: usize) -> bool {
        let (a, b) = (self.points[i], self.points[j]);
        (0..3).map(|k| (a[k] - b[k]).powi(2)).sum::<f64>() <= self.tol_mm * self.tol_mm
    }

    /// For each point, the earliest other point at the same position before it (0-based), by a sweep along x.
    fn earlier_twins(&self) -> Vec<Option<usize>> {
        let n = self.points.len();
        let mut order: Vec<usize> = (0..n).collect();
        order.sort_by(|&a, &b| self.points[a][0].total_cmp(&self.points[b][0]).then(a.cmp(&b)));
        let mut twin: Vec<Option<usize>> = vec![None; n];
        for (k, &i) in order.iter().enumerate() {
            let x = self.points[i][0];
            for &j in order[k + 1..].iter().take_while(|&&j| self.points[j][0] - x <= self.tol_mm) {
                if self.same(i, j) {
                    let (first, later) = (i.min(j), i.max(j));
                    if twin[later].is_none_or(|t| first < t) {
                        twin[later] = Some(first);
                    }
                }
            }
        }
        twin
    }

    /// Refuses a collinear (or, where `needs` says so, coplanar) side; warns about a nearly flat one.
    fn check_spread(&self, needs: &Needs, distinct: &[usize]) -> Result<Option<PairWarning>> {
        let sigma = principal_spreads(distinct.iter().map(|&i| self.points[i]));
        let flat = |across: f64, shape: &'static str| -> Result<Option<PairWarning>> {
            if !(sigma[0] > 0.0 && across >= FLAT_RTOL * sigma[0]) {
                return Err(SolverError::Flat {
                    method: needs.method,
                    space: self.space,
                    shape,
                    count: distinct.len(),
                    across_mm: across,
                    extent_mm: sigma[0],
                });
            }
            Ok((across < NEARLY_FLAT_RATIO * sigma[0]).then_some(PairWarning::NearlyFlat {
                space: self.space,
                shape,
                across_mm: across,
                extent_mm: sigma[0],
            }))
        };
        let line = flat(sigma[1], "collinear")?;
        if line.is_some() || needs.spread == Spread::NotCollinear {
            return Ok(line);
        }
        flat(sigma[2], "coplanar")
    }
}

/// For each point k of `points` (distinct positions), whether the set without it still has the spread `needs`
/// asks for (and at least two points): the check [`validate`] would make of a leave-one-out refit, from the
/// scatter downdated by point k, O(1) per point.
#[must_use]
pub fn valid_without_each(needs: &Needs, points: &[[f64; 3]]) -> Vec<bool> {
    let n = points.len();
    if n < 3 {
        return vec![false; n];
    }
    let mean = points.iter().fold(Vector3::zeros(), |m, p| m + Vector3::from(*p)) / n as f64;
    let scatter = points.iter().fold(Matrix3::zeros(), |s, p| {
        let d = Vector3::from(*p) - mean;
        s + d * d.transpose()
    });
    let rest = (n - 1) as f64;
    points
        .iter()
        .map(|p| {
            // Without p: the mean moves by −d/(n−1), and Σ (x − mean′)(x − mean′)ᵀ = S − d dᵀ − (n−1) m mᵀ.
            let d = Vector3::from(*p) - mean;
            let shift = -d / rest;
            let cov = (scatter - d * d.transpose()) / rest - shift * shift.transpose();
            let mut sigma: Vec<f64> = cov.symmetric_eigenvalues().iter().map(|e| e.max(0.0).sqrt()).collect();
            sigma.sort_by(|a, b| b.total_cmp(a));
            let across = match needs.spread {
                Spread::NotCollinear => sigma[1],
                Spread::NotCoplanar => sigma[2],
            };
            sigma[0] > 0.0 && across >= FLAT_RTOL * sigma[0]
        })
        .collect()
}

/// The RMS spreads σ₁ ≥ σ₂ ≥ σ₃ (mm) of `points` along their principal axes.
fn principal_spreads(points: impl Iterator<Item = [f64; 3]> + Clone) -> [f64; 3] {
    let n = points.clone().count().max(1) as f64;
    let mut mean = Vector3::zeros();
    for p in points.clone() {
        mean += Vector3::from(p) / n;
    }
    let mut scatter = Matrix3::zeros();
    for p in points {
        let d = Vector3::from(p) - mean;
        scatter += d * d.transpose() / n;
    }
    let mut ev: Vec<f64> = scatter.symmetric_eigenvalues().iter().map(|e| e.max(0.0).sqrt()).collect();
    ev.sort_by(|a, b| b.total_cmp(a));
    [ev[0], ev[1], ev[2]]
}
