//! The marker segments of a JPEG-LS stream (T.87 Annex C): SOI, the SOF55 frame header, LSE preset parameters, SOS,
//! and the checks that refuse what the decoder does not support.

use super::error::{Result, invalid, truncated, unsupported};
use super::frame::Header;
use super::scan::Params;

const SOI: u8 = 0xD8;
pub(super) const EOI: u8 = 0xD9;
const SOS: u8 = 0xDA;
pub(super) const DNL: u8 = 0xDC;
const DRI: u8 = 0xDD;
const SOF55: u8 = 0xF7;
const LSE: u8 = 0xF8;

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

/// Marker-segment reader for the header.
pub(super) struct Parser<'a> {
    pub(super) data: &'a [u8],
    pub(super) pos: usize,
}

impl<'a> Parser<'a> {
    fn u8(&mut self, what: &str) -> Result<u8> {
        let b = self.data.get(self.pos).copied();
        self.pos += 1;
        b.map_or_else(|| truncated(format!("the stream ends in {what}")), Ok)
    }

    /// The next marker code, skipping 0xFF fill bytes.
    pub(super) fn marker(&mut self) -> Result<u8> {
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
