//! Solver errors: each says which landmark or parameter is at fault.

/// Why a warp could not be fitted or evaluated.
#[derive(Debug, thiserror::Error, PartialEq)]
#[non_exhaustive]
pub enum SolverError {
    #[error("landmark {index} has a non-finite coordinate")]
    NonFinite { index: usize },
    #[error("{method} needs at least {needed} landmark pairs, got {got}")]
    TooFew { method: &'static str, needed: usize, got: usize },
    #[error("the source and target point lists differ in length ({sources} vs {targets})")]
    LengthMismatch { sources: usize, targets: usize },
    #[error("landmarks {first} and {second} share a source position but have different targets")]
    Duplicate { first: usize, second: usize },
    #[error("degenerate landmark configuration: {0}")]
    Degenerate(String),
    #[error("invalid parameter: {0}")]
    InvalidParameter(String),
}

pub type Result<T, E = SolverError> = std::result::Result<T, E>;
