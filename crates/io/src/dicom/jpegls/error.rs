//! [`JpegLsError`], the decoder's `Result` and the helpers that build its errors: shared by the marker parser, the
//! scan decoder and [`decode`](super::decode).

use thiserror::Error;

/// Why a JPEG-LS stream could not be decoded.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum JpegLsError {
    /// The stream ends before the header or the scan is complete.
    #[error("jpeg-ls stream is truncated: {0}")]
    Truncated(String),
    /// The stream breaks the standard (bad marker, bad parameter, bad code).
    #[error("invalid jpeg-ls stream: {0}")]
    Invalid(String),
    /// A valid feature this decoder does not implement (colour, point transform, ...).
    #[error("unsupported jpeg-ls stream: {0}")]
    Unsupported(String),
    /// The frame's size is not the one the caller expects.
    #[error("jpeg-ls frame is {width}x{height}, but {expected_width}x{expected_height} was expected")]
    SizeMismatch { width: usize, height: usize, expected_width: usize, expected_height: usize },
    /// The memory for the frame's samples could not be allocated (the allocation is fallible, so this is an
    /// error, not an abort).
    #[error("not enough memory for the frame's samples: {bytes} bytes could not be allocated")]
    OutOfMemory { bytes: u128 },
}

pub(super) type Result<T> = std::result::Result<T, JpegLsError>;

pub(super) fn invalid<T>(msg: impl Into<String>) -> Result<T> {
    Err(JpegLsError::Invalid(msg.into()))
}

pub(super) fn unsupported<T>(msg: impl Into<String>) -> Result<T> {
    Err(JpegLsError::Unsupported(msg.into()))
}

pub(super) fn truncated<T>(msg: impl Into<String>) -> Result<T> {
    Err(JpegLsError::Truncated(msg.into()))
}
