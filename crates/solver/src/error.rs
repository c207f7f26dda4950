//! Solver errors: each says which landmark pair or parameter is at fault.
//!
//! Pairs are numbered from 1, in the order of the lists given to the fit; the sides are named by their spaces
//! (`moving`, `fixed`). A caller that fitted a subset of a file's pairs renumbers them as in the file with
//! [`SolverError::renumber`].

/// Why a warp could not be fitted or evaluated.
#[derive(Debug, thiserror::Error, PartialEq)]
#[non_exhaustive]
pub enum SolverError {
    #[error("landmark {pair} has a coordinate that is not a number")]
    NonFinite {
        /// 1-based.
        pair: usize,
    },
    #[error("a {method} warp needs at least {needed} distinct landmark pairs, got {got}")]
    TooFew { method: &'static str, needed: usize, got: usize },
    #[error("{from_len} {from_space} points but {to_len} {to_space} points: the lists must pair up")]
    LengthMismatch { from_space: &'static str, from_len: usize, to_space: &'static str, to_len: usize },
    #[error(
        "landmarks {first} and {second} have the same {space} point but different {other} points: no warp maps one \
         point to two"
    )]
    Conflict {
        space: &'static str,
        other: &'static str,
        /// 1-based.
        first: usize,
        /// 1-based.
        second: usize,
    },
    #[error(
        "all {count} {space} points are at one position ({:.2}, {:.2}, {:.2}) mm: the warp would collapse the \
         volume onto a point",
        .at_mm[0],
        .at_mm[1],
        .at_mm[2]
    )]
    Coincident { space: &'static str, count: usize, at_mm: [f64; 3] },
    #[error(
        "the {count} {space} points are {shape} (RMS spread {across_mm:.3e} mm across, {extent_mm:.3e} mm along): a \
         {method} warp needs them {}",
        flat_need(.shape)
    )]
    Flat {
        method: &'static str,
        space: &'static str,
        /// "collinear" or "coplanar".
        shape: &'static str,
        count: usize,
        across_mm: f64,
        extent_mm: f64,
    },
    #[error("degenerate landmark configuration: {0}")]
    Degenerate(String),
    #[error("invalid parameter: {0}")]
    InvalidParameter(String),
    #[error("{0}")]
    Image(String),
    #[error("cancelled")]
    Cancelled,
    /// A device the work was handed to (a GPU) failed; the message says which and why.
    #[error("{0}")]
    Device(String),
}

/// What a set that is `shape` lacks, for [`SolverError::Flat`].
fn flat_need(shape: &str) -> &'static str {
    if shape == "collinear" { "off one line" } else { "spread in 3-D, off one plane" }
}

impl SolverError {
    /// The same error with every pair number n replaced by `f(n)` (both 1-based), e.g. to number the pairs as in
    /// the file they came from.
    #[must_use]
    pub fn renumber(self, f: impl Fn(usize) -> usize) -> Self {
        match self {
            Self::NonFinite { pair } => Self::NonFinite { pair: f(pair) },
            Self::Conflict { space, other, first, second } => {
                Self::Conflict { space, other, first: f(first), second: f(second) }
            }
            other => other,
        }
    }
}

pub type Result<T, E = SolverError> = std::result::Result<T, E>;
