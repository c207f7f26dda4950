//! What a frame is: the [`Header`] its marker segments give and the [`FrameSpec`] the caller expects of it.

/// What the caller expects of a frame (from DICOM Rows, Columns and BitsAllocated).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FrameSpec {
    /// Samples per line (X; DICOM Columns).
    pub width: usize,
    /// Lines (Y; DICOM Rows).
    pub height: usize,
    /// The largest sample precision P accepted (DICOM BitsAllocated, at most 16 here).
    pub max_precision: u8,
}

/// The parameters of a frame and its scan, as read from the marker segments.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Header {
    /// X: samples per line.
    pub width: usize,
    /// Y: lines.
    pub height: usize,
    /// P: sample precision in bits (2..=16).
    pub precision: u8,
    /// Nf: components in the frame (only 1 is decoded).
    pub components: u8,
    /// NEAR: the largest reconstruction error (0 = lossless).
    pub near: u16,
    /// ILV: the interleave mode of the scan.
    pub interleave: u8,
    /// MAXVAL: the largest sample value.
    pub maxval: u16,
    /// T1, T2, T3: the gradient quantisation thresholds in effect.
    pub thresholds: [u16; 3],
    /// RESET: the context counter limit.
    pub reset: u16,
    /// Offset of the first byte of entropy-coded data.
    pub(super) scan_start: usize,
}
