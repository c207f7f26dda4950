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

type Result<T> = std::result::Result<T, JpegLsError>;

fn invalid<T>(msg: impl Into<String>) -> Result<T> {
    Err(JpegLsError::Invalid(msg.into()))
}

fn unsupported<T>(msg: impl Into<String>) -> Result<T> {
    Err(JpegLsError::Unsupported(msg.into()))
}

fn truncated<T>(msg: impl Into<String>) -> Result<T> {
    Err(JpegLsError::Truncated(msg.into()))
}

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
    scan_start: usize,
}

const SOI: u8 = 0xD8;
const EOI: u8 = 0xD9;
const SOS: u8 = 0xDA;
const DNL: u8 = 0xDC;
const DRI: u8 = 0xDD;
const SOF55: u8 = 0xF7;
const LSE: u8 = 0xF8;

/// The run-length order table J (A.7.1.2).
const J: [u32; 32] =
    [0, 0, 0, 0, 1, 1, 1, 1, 2, 2, 2, 2, 3, 3, 3, 3, 4, 4, 5, 5, 6, 6, 7, 7, 8, 9, 10, 11, 12, 13, 14, 15];

/// Reads the frame and scan parameters of a single-component JPEG-LS stream, without decoding.
pub fn read_header(data: &[u8]) -> Result<Header> {
    let mut p = Parser { data, pos: 0 };
    if p.u8("SOI")? != 0xFF || p.u8("SOI")? != SOI {
        return invalid("the stream does not start with SOI (FFD8)");
    }
    let mut frame: Option<(u8, usize, usize, u8)> = None;
    // LSE id 1 values, 0 = default.
    let mut preset = [0u16; 5];
    let mut after_app8 = false;
    loop {
        let marker = p.marker()?;
        let follows_app8 = std::mem::replace(&mut after_app8, marker == 0xE8);
        match marker {
            SOF55 => {
                if frame.is_some() {
                    return invalid("more than one SOF55 frame header");
                }
                let seg = p.segment("SOF55")?;
                if seg.len() < 6 {
                    return invalid("SOF55 segment is too short");
                }
                let precision = seg[0];
                let height = usize::from(u16::from_be_bytes([seg[1], seg[2]]));
                let width = usize::from(u16::from_be_bytes([seg[3], seg[4]]));
                let nf = seg[5];
                if seg.len() != 6 + 3 * usize::from(nf) {
                    return invalid(format!("SOF55 length {} does not fit {nf} component(s)", seg.len() + 2));
                }
                if !(2..=16).contains(&precision) {
                    return invalid(format!("sample precision P = {precision} (2..16 allowed)"));
                }
                if nf != 1 {
                    return unsupported(format!("{nf} components (only single-component grayscale is decoded)"));
                }
                if height == 0 {
                    return unsupported("Y = 0 (the height is given later by a DNL marker)");
                }
                if width == 0 {
                    return invalid("X = 0 samples per line");
                }
                frame = Some((precision, width, height, nf));
            }
            LSE => {
                let seg = p.segment("LSE")?;
                match seg.first() {
                    Some(1) => {
                        if seg.len() != 11 {
                            return invalid(format!("LSE preset parameters segment of length {}", seg.len() + 2));
                        }
                        for (i, v) in preset.iter_mut().enumerate() {
                            *v = u16::from_be_bytes([seg[1 + 2 * i], seg[2 + 2 * i]]);
                        }
                    }
                    Some(2 | 3) => {} // mapping tables: refused below if the scan selects one
                    Some(4) => return unsupported("LSE id 4 (oversize image dimensions)"),
                    Some(id) => return invalid(format!("LSE marker segment with unknown id {id}")),
                    None => return invalid("empty LSE marker segment"),
                }
            }
            SOS => {
                let Some((precision, width, height, nf)) = frame else {
                    return invalid("SOS before the SOF55 frame header");
                };
                let seg = p.segment("SOS")?;
                let ns = usize::from(*seg.first().unwrap_or(&0));
                if ns != 1 || seg.len() != 4 + 2 * ns {
                    return invalid(format!("SOS with {ns} component(s) and length {}", seg.len() + 2));
                }
                let table = seg[2];
                let (near, ilv, al_ah) = (seg[3], seg[4], seg[5]);
                if table != 0 {
                    return unsupported(format!("mapping table {table} (palettised images)"));
                }
                if ilv > 2 {
                    return invalid(format!("interleave mode ILV = {ilv}"));
                }
                if al_ah >> 4 != 0 {
                    return invalid(format!("SOS Ah = {} (must be 0)", al_ah >> 4));
                }
                if al_ah & 0x0F != 0 {
                    return unsupported(format!("point transform Al = {}", al_ah & 0x0F));
                }
                let params = Params::new(precision, u16::from(near), preset)?;
                return Ok(Header {
                    width,
                    height,
                    precision,
                    components: nf,
                    near: u16::from(near),
                    interleave: ilv,
                    maxval: params.maxval as u16,
                    thresholds: [params.t1 as u16, params.t2 as u16, params.t3 as u16],
                    reset: params.reset as u16,
                    scan_start: p.pos,
                });
            }
            DRI => {
                let seg = p.segment("DRI")?;
                if seg.iter().any(|&b| b != 0) {
                    return unsupported("restart intervals (DRI)");
                }
            }
            0xE0..=0xEF | 0xFE => {
                p.segment("APP/COM")?;
            }
            // A SPIFF header's end-of-directory entry (an APP8 segment) is followed by SOI.
            SOI if follows_app8 && frame.is_none() => {}
            SOI => return invalid("a second SOI marker"),
            EOI => return invalid("EOI before the scan"),
            0xC0..=0xCF => {
                return invalid(format!(
                    "marker FF{marker:02X}: a JPEG (not JPEG-LS) frame; JPEG-LS frames use SOF55 (FFF7)"
                ));
            }
            m => return invalid(format!("unexpected marker FF{m:02X} in the header")),
        }
    }
}

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

/// Marker-segment reader for the header.
struct Parser<'a> {
    data: &'a [u8],
    pos: usize,
}

impl<'a> Parser<'a> {
    fn u8(&mut self, what: &str) -> Result<u8> {
        let b = self.data.get(self.pos).copied();
        self.pos += 1;
        b.map_or_else(|| truncated(format!("the stream ends in {what}")), Ok)
    }

    /// The next marker code, skipping 0xFF fill bytes.
    fn marker(&mut self) -> Result<u8> {
        if self.u8("a marker")? != 0xFF {
            return invalid(format!("expected a marker at offset {}", self.pos - 1));
        }
        loop {
            match self.u8("a marker")? {
                0xFF => {}
                0x00 => return invalid(format!("expected a marker at offset {}", self.pos - 2)),
                m => return Ok(m),
            }
        }
    }

    /// The payload of a marker segment (after its two length bytes).
    fn segment(&mut self, what: &str) -> Result<&'a [u8]> {
        let hi = self.u8(what)?;
        let lo = self.u8(what)?;
        let len = usize::from(u16::from_be_bytes([hi, lo]));
        if len < 2 {
            return invalid(format!("{what} segment length {len}"));
        }
        let seg = self.data.get(self.pos..self.pos + len - 2);
        self.pos += len - 2;
        seg.map_or_else(|| truncated(format!("the stream ends in the {what} segment")), Ok)
    }
}

/// The coding parameters in effect for the scan.
#[derive(Debug, Clone, Copy)]
struct Params {
    maxval: i32,
    near: i32,
    t1: i32,
    t2: i32,
    t3: i32,
    reset: i32,
    range: i32,
    qbpp: u32,
    limit: u32,
}

/// ⌈log2 n⌉ for n ≥ 1.
fn ceil_log2(n: i32) -> u32 {
    debug_assert!(n >= 1);
    32 - (n - 1).leading_zeros()
}

impl Params {
    /// Parameters from P, NEAR and the LSE preset values (MAXVAL, T1, T2, T3, RESET; 0 = default).
    fn new(precision: u8, near: u16, preset: [u16; 5]) -> Result<Self> {
        let full = (1i32 << precision) - 1;
        let maxval = if preset[0] == 0 { full } else { i32::from(preset[0]) };
        if maxval > full {
            return invalid(format!("MAXVAL {maxval} exceeds 2^P - 1 = {full}"));
        }
        let near = i32::from(near);
        if near > (maxval / 2).min(255) {
            return invalid(format!("NEAR = {near} (at most min(255, MAXVAL/2) = {})", (maxval / 2).min(255)));
        }
        let [d1, d2, d3] = default_thresholds(maxval, near);
        let pick = |v: u16, d: i32| if v == 0 { d } else { i32::from(v) };
        let (t1, t2, t3) = (pick(preset[1], d1), pick(preset[2], d2), pick(preset[3], d3));
        if !(near < t1 && t1 <= t2 && t2 <= t3 && t3 <= maxval) {
            return invalid(format!(
                "thresholds T1 = {t1}, T2 = {t2}, T3 = {t3} (NEAR + 1 <= T1 <= T2 <= T3 <= MAXVAL = {maxval} needed)"
            ));
        }
        let reset = pick(preset[4], 64);
        if reset < 3 || reset > maxval.max(255) {
            return invalid(format!("RESET = {reset} (3..=max(255, MAXVAL) allowed)"));
        }
        let range = (maxval + 2 * near) / (2 * near + 1) + 1;
        let qbpp = ceil_log2(range);
        let bpp = ceil_log2(maxval + 1).max(2);
        let limit = 2 * (bpp + bpp.max(8));
        Ok(Self { maxval, near, t1, t2, t3, reset, range, qbpp, limit })
    }

    fn from_header(h: &Header) -> Self {
        let near = i32::from(h.near);
        let maxval = i32::from(h.maxval);
        let range = (maxval + 2 * near) / (2 * near + 1) + 1;
        let bpp = ceil_log2(maxval + 1).max(2);
        Self {
            maxval,
            near,
            t1: i32::from(h.thresholds[0]),
            t2: i32::from(h.thresholds[1]),
            t3: i32::from(h.thresholds[2]),
            reset: i32::from(h.reset),
            range,
            qbpp: ceil_log2(range),
            limit: 2 * (bpp + bpp.max(8)),
        }
    }
}

/// The default thresholds T1, T2, T3 for MAXVAL and NEAR (C.2.4.1.1.1).
#[allow(clippy::identity_op, reason = "written as the standard's FACTOR·(BASIC_T1 − 2) + 2 + 3·NEAR")]
fn default_thresholds(maxval: i32, near: i32) -> [i32; 3] {
    let clamp = |i: i32, j: i32| if i > maxval || i < j { j } else { i };
    if maxval >= 128 {
        let factor = (maxval.min(4095) + 128) / 256;
        let t1 = clamp(factor * (3 - 2) + 2 + 3 * near, near + 1);
        let t2 = clamp(factor * (7 - 3) + 3 + 5 * near, t1);
        let t3 = clamp(factor * (21 - 4) + 4 + 7 * near, t2);
        [t1, t2, t3]
    } else {
        let factor = 256 / (maxval + 1);
        let t1 = clamp((3 / factor + 3 * near).max(2), near + 1);
        let t2 = clamp((7 / factor + 5 * near).max(3), t1);
        let t3 = clamp((21 / factor + 7 * near).max(4), t2);
        [t1, t2, t3]
    }
}

/// Reads the entropy-coded segment MSB first, dropping the stuffed bit after each 0xFF.
///
/// Past the end it supplies zero bits and counts them, so the decoder can tell a scan that ran
/// out of data ([`BitReader::overran`]) without checking every read.
struct BitReader<'a> {
    data: &'a [u8],
    pos: usize,
    /// Valid bits, left-aligned (the next bit is bit 63).
    cache: u64,
    bits: u32,
    /// Zero bits appended past the end of the data (the last `pad` of the `bits`).
    pad: u32,
    prev_ff: bool,
}

impl<'a> BitReader<'a> {
    fn new(data: &'a [u8]) -> Self {
        Self { data, pos: 0, cache: 0, bits: 0, pad: 0, prev_ff: false }
    }

    /// Fills the cache to more than 56 bits.
    #[inline]
    fn refill(&mut self) {
        while self.bits <= 56 {
            if let Some(&b) = self.data.get(self.pos) {
                self.pos += 1;
                if self.prev_ff {
                    // A stuffed 0 bit, then 7 data bits (b < 0x80: the scan end was cut before markers).
                    self.cache |= u64::from(b & 0x7F) << (57 - self.bits);
                    self.bits += 7;
                    self.prev_ff = false;
                } else {
                    self.cache |= u64::from(b) << (56 - self.bits);
                    self.bits += 8;
                    self.prev_ff = b == 0xFF;
                }
            } else {
                self.bits += 8;
                self.pad += 8;
            }
        }
    }

    /// True if zero bits past the end of the data were consumed.
    fn overran(&self) -> bool {
        self.pad > self.bits
    }

    #[inline]
    fn consume(&mut self, n: u32) {
        self.cache = self.cache.checked_shl(n).unwrap_or(0);
        self.bits -= n;
    }

    /// Reads `n` ≤ 32 bits.
    #[inline]
    fn bits(&mut self, n: u32) -> u32 {
        if n == 0 {
            return 0;
        }
        if self.bits < n {
            self.refill();
        }
        let v = (self.cache >> (64 - n)) as u32;
        self.consume(n);
        v
    }

    #[inline]
    fn bit(&mut self) -> bool {
        self.bits(1) == 1
    }

    /// Counts zero bits up to and including the next 1 bit; errors past `max` zeros.
    #[inline]
    fn unary(&mut self, max: u32) -> Result<u32> {
        let mut zeros = 0;
        loop {
            if self.bits == 0 {
                self.refill();
            }
            let lz = self.cache.leading_zeros();
            if lz < self.bits {
                zeros += lz;
                self.consume(lz + 1);
                break;
            }
            zeros += self.bits;
            self.cache = 0;
            self.bits = 0;
            if zeros > max {
                break;
            }
        }
        if zeros > max {
            if self.overran() {
                return truncated("the scan ends before the last sample");
            }
            return invalid(format!("a code with {zeros} leading zeros (at most {max} allowed)"));
        }
        Ok(zeros)
    }

    /// A length-limited Golomb code with parameter `k` (A.5.3): MErrval.
    #[inline]
    fn golomb(&mut self, k: u32, limit: u32, qbpp: u32) -> Result<u32> {
        let max_prefix = limit.saturating_sub(qbpp + 1);
        let zeros = self.unary(max_prefix)?;
        if zeros < max_prefix {
            let v = (u64::from(zeros) << k) | u64::from(self.bits(k.min(32)));
            if v > (1u64 << qbpp) {
                return invalid(format!("coded error {v} out of range"));
            }
            Ok(v as u32)
        } else {
            Ok(self.bits(qbpp) + 1)
        }
    }
}

/// Context statistics: 365 regular contexts and the two run-interruption contexts (365, 366).
struct Contexts {
    a: [u32; 367],
    b: [i32; 365],
    c: [i32; 365],
    n: [u32; 367],
    nn: [u32; 2],
}

/// Gradient quantisation (A.3.3) as a lookup table over −MAXVAL..=MAXVAL.
fn quantisation_table(p: &Params) -> Vec<i8> {
    (-p.maxval..=p.maxval)
        .map(|d| {
            if d <= -p.t3 {
                -4
            } else if d <= -p.t2 {
                -3
            } else if d <= -p.t1 {
                -2
            } else if d < -p.near {
                -1
            } else if d <= p.near {
                0
            } else if d < p.t1 {
                1
            } else if d < p.t2 {
                2
            } else if d < p.t3 {
                3
            } else {
                4
            }
        })
        .collect()
}

/// Golomb parameter k: the least k with N·2^k ≥ `a`.
#[inline]
fn golomb_k(n: u32, a: u32) -> u32 {
    if n >= a {
        return 0;
    }
    // n < a, so n·2^k reaches a at k = lz(n) − lz(a) or one more (n ≥ 1, so k ≤ 32).
    let k = n.leading_zeros() - a.leading_zeros();
    if (u64::from(n) << k) < u64::from(a) { k + 1 } else { k }
}

/// Decodes the scan into `out` (width x height, row by row).
fn decode_scan(r: &mut BitReader, p: &Params, width: usize, out: &mut [u16]) -> Result<()> {
    let qt = quantisation_table(p);
    let q = |d: i32| i32::from(qt[(d + p.maxval) as usize]);
    let a0 = ((p.range + 32) / 64).max(2) as u32;
    let mut ctx = Contexts { a: [a0; 367], b: [0; 365], c: [0; 365], n: [1; 367], nn: [0; 2] };
    let near = p.near;
    let step = 2 * near + 1;
    let reset = p.reset as u32;
    // Brings Px + error back into 0..=MAXVAL (A.4.5 modulo reduction, then clamping).
    let fix = |x: i32| {
        let x = if x < -near {
            x + p.range * step
        } else if x > p.maxval + near {
            x - p.range * step
        } else {
            x
        };
        x.clamp(0, p.maxval)
    };
    let mut prev = vec![0i32; width + 2];
    let mut cur = vec![0i32; width + 2];
    let mut run_index = 0usize;
    for line in out.chunks_exact_mut(width) {
        std::mem::swap(&mut prev, &mut cur);
        prev[width + 1] = prev[width];
        cur[0] = prev[1];
        let mut x = 1;
        while x <= width {
            let ra = cur[x - 1];
            let rb = prev[x];
            let rc = prev[x - 1];
            let rd = prev[x + 1];
            let (d1, d2, d3) = (rd - rb, rb - rc, rc - ra);
            if d1.abs() <= near && d2.abs() <= near && d3.abs() <= near {
                // Run mode (A.7).
                let remaining = width + 1 - x;
                let mut count = 0;
                let mut interrupted = false;
                loop {
                    if !r.bit() {
                        interrupted = true;
                        break;
                    }
                    let rm = 1usize << J[run_index];
                    let n = rm.min(remaining - count);
                    count += n;
                    if n == rm && run_index < 31 {
                        run_index += 1;
                    }
                    if count == remaining {
                        break;
                    }
                }
                if interrupted {
                    count += r.bits(J[run_index]) as usize;
                    if count > remaining {
                        return invalid("a run longer than the line");
                    }
                }
                cur[x..x + count].fill(ra);
                x += count;
                if !interrupted || x > width {
                    continue;
                }
                // Run interruption sample (A.7.2).
                let rb = prev[x];
                let ri = usize::from((ra - rb).abs() <= near);
                let qi = 365 + ri;
                let temp = if ri == 1 { ctx.a[qi] + (ctx.n[qi] >> 1) } else { ctx.a[qi] };
                let k = golomb_k(ctx.n[qi], temp);
                let limit = p.limit.saturating_sub(J[run_index] + 1);
                let em = r.golomb(k, limit, p.qbpp)?;
                let t = em + ri as u32;
                let map = t & 1;
                let abs = u32::midpoint(t, map) as i32;
                let negative = (k != 0 || 2 * ctx.nn[ri] >= ctx.n[qi]) == (map == 1);
                let errval = if negative { -abs } else { abs };
                if errval < 0 {
                    ctx.nn[ri] += 1;
                }
                ctx.a[qi] += (em + 1 - ri as u32) >> 1;
                if ctx.n[qi] == reset {
                    ctx.a[qi] >>= 1;
                    ctx.n[qi] >>= 1;
                    ctx.nn[ri] >>= 1;
                }
                ctx.n[qi] += 1;
                let (px, sign) = if ri == 1 { (ra, 1) } else { (rb, if ra > rb { -1 } else { 1 }) };
                cur[x] = fix(px + sign * errval * step);
                x += 1;
                run_index = run_index.saturating_sub(1);
                continue;
            }
            // Regular mode (A.3 to A.6).
            let mut qc = 81 * q(d1) + 9 * q(d2) + q(d3);
            let sign = if qc < 0 {
                qc = -qc;
                -1
            } else {
                1
            };
            let qc = qc as usize;
            let mut px = if rc >= ra.max(rb) {
                ra.min(rb)
            } else if rc <= ra.min(rb) {
                ra.max(rb)
            } else {
                ra + rb - rc
            };
            px = (px + sign * ctx.c[qc]).clamp(0, p.maxval);
            let (a, n) = (ctx.a[qc], ctx.n[qc]);
            let k = golomb_k(n, a);
            let m = r.golomb(k, p.limit, p.qbpp)? as i32;
            let special = near == 0 && k == 0 && 2 * ctx.b[qc] <= -(n as i32);
            let mut errval = if m & 1 == 0 { m >> 1 } else { -((m + 1) >> 1) };
            if special {
                errval = -errval - 1;
            }
            // Context update (A.6.1) and bias correction (A.6.2).
            let mut b = ctx.b[qc] + errval * step;
            let mut a = a + errval.unsigned_abs();
            let mut n = n;
            if n == reset {
                a >>= 1;
                b >>= 1;
                n >>= 1;
            }
            n += 1;
            let ni = n as i32;
            if b <= -ni {
                b += ni;
                if ctx.c[qc] > -128 {
                    ctx.c[qc] -= 1;
                }
                if b <= -ni {
                    b = -ni + 1;
                }
            } else if b > 0 {
                b -= ni;
                if ctx.c[qc] < 127 {
                    ctx.c[qc] += 1;
                }
                if b > 0 {
                    b = 0;
                }
            }
            ctx.a[qc] = a;
            ctx.b[qc] = b;
            ctx.n[qc] = n;
            cur[x] = fix(px + sign * errval * step);
            x += 1;
        }
        if r.overran() {
            return truncated("the scan ends before the last sample");
        }
        for (o, &v) in line.iter_mut().zip(&cur[1..=width]) {
            *o = v as u16;
        }
    }
    Ok(())
}
