//! A pure-Rust JPEG-LS decoder for one grayscale frame: ISO/IEC 14495-1 | ITU-T T.87 (LOCO-I),
//! lossless and near-lossless, as used by the DICOM transfer syntaxes 1.2.840.10008.1.2.4.80 and .81.
//!
//! Entry points: [`read_header`] (the frame and scan parameters, without decoding) and [`decode`]
//! (the samples, row by row, checked against the [`FrameSpec`] the caller expects).
//!
//! # The algorithm (T.87 Annex A; Weinberger, Seroussi & Sapiro 2000)
//! Each sample x is predicted from its causal neighbours, in the standard's notation
//!
//! ```text
//!        Rc  Rb  Rd
//!        Ra  x
//! ```
//!
//! (Ra left, Rb above, Rc above-left, Rd above-right, all reconstructed values). On the first
//! line the line above is taken as zeros; at the start of a line Ra = Rb and Rc is the Ra of the
//! previous line's first sample; at the end of a line Rd = Rb.
//!
//! - **Context** (A.3): the local gradients D1 = Rd − Rb, D2 = Rb − Rc, D3 = Rc − Ra are quantised
//!   by the thresholds T1, T2, T3 and NEAR into Q1, Q2, Q3 ∈ {−4..4}. If all three are 0 the sample
//!   is coded in **run mode**, otherwise in **regular mode** with context Q = 81·Q1 + 9·Q2 + Q3,
//!   sign-merged (if the first non-zero Qi is negative, SIGN = −1 and Q = −Q): 365 contexts.
//! - **Prediction** (A.4): the median edge detector (MED) gives Px = min(Ra, Rb) if Rc ≥ max(Ra, Rb),
//!   max(Ra, Rb) if Rc ≤ min(Ra, Rb), else Ra + Rb − Rc; then the bias correction adds SIGN·C\[Q\]
//!   and clamps to 0..=MAXVAL.
//! - **Coding** (A.5): the prediction error Errval (quantised as (Errval ± NEAR) / (2·NEAR + 1)
//!   and reduced modulo RANGE) is mapped to a non-negative MErrval (with the special mapping when
//!   NEAR = 0, k = 0 and 2·B\[Q\] ≤ −N\[Q\]) and Golomb-Rice coded with parameter k, the least k
//!   with N\[Q\]·2^k ≥ A\[Q\]. Codes are length-limited: a unary prefix of LIMIT − qbpp − 1 zeros
//!   escapes to MErrval − 1 in qbpp bits.
//! - **Adaptation** (A.6): per context, A accumulates |Errval|, B accumulates Errval·(2·NEAR + 1),
//!   N counts; when N reaches RESET, A, B and N are halved. The bias C moves by ±1 (within
//!   −128..=127) whenever B/N leaves (−1, 0].
//! - **Run mode** (A.7): a run of samples equal to Ra (within NEAR) is coded in segments of
//!   2^J\[RUNindex\] samples (a 1 bit each, RUNindex moving up the 32-entry table J), ended by the end
//!   of the line or by a 0 bit plus the remainder in J\[RUNindex\] bits. The sample that interrupts a
//!   run is coded against Px = Ra (if |Ra − Rb| ≤ NEAR, context 366) or Px = Rb (context 365) with
//!   its own error mapping and the limit LIMIT − J\[RUNindex\] − 1; then RUNindex decreases by one.
//! - **Reconstruction**: Rx = Px + SIGN·Errval·(2·NEAR + 1), brought back into range modulo
//!   RANGE·(2·NEAR + 1) and clamped to 0..=MAXVAL.
//!
//! Parameters: MAXVAL = 2^P − 1, RANGE = ⌊(MAXVAL + 2·NEAR) / (2·NEAR + 1)⌋ + 1, qbpp = ⌈log2 RANGE⌉,
//! bpp = max(2, ⌈log2(MAXVAL + 1)⌉), LIMIT = 2·(bpp + max(8, bpp)). MAXVAL, T1..T3 and RESET may be
//! preset by an LSE marker segment (id 1); absent or zero values take the defaults of C.2.4.1.1.
//!
//! The scan is bit-stuffed: after a 0xFF byte the next byte carries only 7 bits (its most
//! significant bit is a stuffed 0), so a 0xFF followed by a byte ≥ 0x80 is a marker and ends the scan.
//!
//! # Scope
//! One component (Nf = 1), one scan, no point transform (Al = 0), no restart intervals, no
//! mapping tables: anything else is refused with [`JpegLsError::Unsupported`]. Every read is
//! bounds-checked and the frame size is compared with the caller's [`FrameSpec`] before the output
//! is allocated; a scan that runs out of bits is [`JpegLsError::Truncated`]. Hostile input gives an
//! error, never a panic.
//!
//! References: ISO/IEC 14495-1:1999 | ITU-T T.87 (06/98), "Lossless and near-lossless compression of
//! continuous-tone still images — Baseline"; M. J. Weinberger, G. Seroussi, G. Sapiro, "The LOCO-I
//! lossless image compression algorithm: principles and standardization into JPEG-LS", IEEE Trans.
//! Image Processing 9(8), 1309–1324, 2000.

mod error;
mod frame;
mod header;
mod scan;

pub use error::JpegLsError;
use error::{Result, invalid, truncated, unsupported};
pub use frame::{FrameSpec, Header};
pub use header::read_header;
use header::{DNL, EOI, Parser};
use scan::{BitReader, Params, decode_scan};

/// Decodes one single-component JPEG-LS frame into samples (row by row, 0..=MAXVAL).
///
/// The frame must be `expected.width` x `expected.height` with a precision of at most
/// `expected.max_precision` bits; this is checked before anything is allocated.
pub fn decode(data: &[u8], expected: FrameSpec) -> Result<Vec<u16>> {
    let h = read_header(data)?;
    if h.width != expected.width || h.height != expected.height {
        return Err(JpegLsError::SizeMismatch {
            width: h.width,
            height: h.height,
            expected_width: expected.width,
            expected_height: expected.height,
        });
    }
    if h.precision > expected.max_precision {
        return unsupported(format!(
            "sample precision {} bits, at most {} expected",
            h.precision, expected.max_precision
        ));
    }
    let params = Params::from_header(&h);
    // Find the marker that ends the entropy-coded segment: 0xFF followed by a byte >= 0x80.
    let scan = data.get(h.scan_start..).unwrap_or(&[]);
    let end = scan_end(scan);
    let Some(n) = h.width.checked_mul(h.height) else { return invalid("the frame size overflows") };
    let mut out = Vec::new();
    out.try_reserve_exact(n).map_err(|_| JpegLsError::OutOfMemory { bytes: n as u128 * 2 })?;
    out.resize(n, 0u16);
    let mut reader = BitReader::new(&scan[..end]);
    decode_scan(&mut reader, &params, h.width, &mut out)?;
    // After the scan: fill bytes, then EOI.
    let mut p = Parser { data, pos: h.scan_start + end };
    if p.pos >= data.len() {
        return truncated("the stream ends after the scan without EOI");
    }
    match p.marker()? {
        EOI => Ok(out),
        DNL => unsupported("DNL marker after the scan"),
        m => invalid(format!("marker FF{m:02X} after the scan (only one scan of one component is supported)")),
    }
}

/// The offset of the marker ending the entropy-coded data in `scan` (or its length).
fn scan_end(scan: &[u8]) -> usize {
    let mut i = 0;
    while let Some(off) = scan.get(i..).and_then(|s| s.iter().position(|&b| b == 0xFF)) {
        let at = i + off;
        match scan.get(at + 1) {
            Some(&b) if b >= 0x80 => return at,
            Some(_) => i = at + 2,
            None => return scan.len(),
        }
    }
    scan.len()
}
