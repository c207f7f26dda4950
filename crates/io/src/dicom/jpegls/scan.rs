//! The entropy-coded scan (T.87 Annex A): the coding parameters, the bit reader with its unstuffing, the
//! per-context adaptive state, and the regular- and run-mode decoding of every sample.

use super::error::{Result, invalid, truncated};
use super::frame::Header;

/// The run-length order table J (A.7.1.2).
const J: [u32; 32] =
    [0, 0, 0, 0, 1, 1, 1, 1, 2, 2, 2, 2, 3, 3, 3, 3, 4, 4, 5, 5, 6, 6, 7, 7, 8, 9, 10, 11, 12, 13, 14, 15];

/// The coding parameters in effect for the scan.
#[derive(Debug, Clone, Copy)]
pub(super) struct Params {
    pub(super) maxval: i32,
    near: i32,
    pub(super) t1: i32,
    pub(super) t2: i32,
    pub(super) t3: i32,
    pub(super) reset: i32,
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
    pub(super) fn new(precision: u8, near: u16, preset: [u16; 5]) -> Result<Self> {
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

    pub(super) fn from_header(h: &Header) -> Self {
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
pub(super) struct BitReader<'a> {
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
    pub(super) fn new(data: &'a [u8]) -> Self {
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
pub(super) fn decode_scan(r: &mut BitReader, p: &Params, width: usize, out: &mut [u16]) -> Result<()> {
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
