//! The walk over a file's element headers that runs before dicom-rs parses it ([`check_lengths`]): dicom-rs
//! allocates whatever a length field claims before reading, so every defined length is checked against the bytes
//! that are there first, and the parser is given the data up to the end of the top-level PixelData only.

use std::io::{Read, Write};
use std::ops::Range;

use dicom_core::Tag;

use super::TransferSyntax;

/// What [`check_lengths`] found: where the top-level PixelData ends (or the data ends), and the
/// range of its value when it has a defined length (native pixel data).
#[derive(Clone, Debug)]
pub(super) struct Checked {
    pub(super) end: usize,
    pub(super) pixel_value: Option<Range<usize>>,
    /// For a deflated data set with bytes after PixelData: the data (from `DICM`) re-deflated up to
    /// the end of PixelData, to be parsed instead of the file's.
    pub(super) replacement: Option<Vec<u8>>,
}

/// Deepest sequence nesting accepted (dicom-rs builds nested objects recursively).
const MAX_DEPTH: usize = 32;

/// Walks the element headers of `data` (starting at `DICM`) without reading values and checks
/// that every defined length fits in the data. Returns where the top-level PixelData ends (or the
/// data ends). Errors are `(is_truncation, message)`. A deflated data set is checked up to the
/// file meta group only.
pub(super) fn check_lengths(data: &[u8]) -> std::result::Result<Checked, (bool, String)> {
    let mut w = Walker { data, explicit: true, big_endian: false, pixel_end: None, pixel_value: None };
    // File meta group, explicit VR little endian. As dicom-rs reads it (dicom-object `meta.rs`):
    // (0002,0000) with a 4-byte group length first, then elements of any group until that many
    // bytes are consumed. (A walk that stopped at the first element outside group 0002 would
    // leave elements that dicom-rs still reads unchecked: a meta group length that covers a
    // (0003,0012) element makes dicom-rs inflate from another byte than ours, into a data set
    // that can declare a 3 GB element in a 1 KB file.)
    let (tag, len, header) = w.header(4)?;
    if tag != (0x0002, 0x0000) || len != 4 || header != 8 {
        return Err((
            false,
            format!(
                "the file meta group does not start with its group length (0002,0000) but with ({:04X},{:04X})",
                tag.0, tag.1
            ),
        ));
    }
    let group_length = w.u32_at(4 + header, true)?;
    let mut pos = 4 + header + 4;
    let mut consumed = 0u64;
    let mut ts = String::new();
    while consumed < u64::from(group_length) {
        let (tag, len, header) = w.header(pos)?;
        if len == UNDEFINED {
            return Err((false, format!("file meta element ({:04X},{:04X}) has an undefined length", tag.0, tag.1)));
        }
        let value = w.value_range(tag, pos + header, len, data.len())?;
        if tag == (0x0002, 0x0010) {
            // Trimmed as dicom-rs trims it (`FileMetaTable::transfer_syntax`): any trailing whitespace or NUL. A tab
            // among the padding once made this walk take the data set as explicit VR while dicom-rs read it as
            // implicit VR, where a (0000,0000) UL declared 3.6 GB.
            ts = String::from_utf8_lossy(&data[value.clone()])
                .trim_end_matches(|c: char| c.is_whitespace() || c == '\0')
                .to_string();
        }
        consumed += (header as u64) + u64::from(len);
        pos = value.end;
    }
    match TransferSyntax::from_uid(&ts) {
        Some(TransferSyntax::DeflatedExplicitVrLittleEndian) => {
            // dicom-rs inflates the data set and then trusts its lengths (a 5 KB file can claim a
            // 1.9 GB element). Inflate it here, bounded by deflate's largest
            // expansion, and walk the result, so no length can claim more than the data holds.
            let cap = (data.len() as u64).saturating_mul(1032).saturating_add(1024);
            let mut inflated = Vec::new();
            flate2::read::DeflateDecoder::new(&data[pos..])
                .take(cap)
                .read_to_end(&mut inflated)
                .map_err(|e| (false, format!("the deflated data set does not inflate: {e}")))?;
            let mut inner =
                Walker { data: &inflated, explicit: true, big_endian: false, pixel_end: None, pixel_value: None };
            inner.elements(0, inflated.len(), 0, false)?;
            // As for the other syntaxes, dicom-rs must not read past PixelData (trailing padding or
            // garbage): a deflated stream cannot be cut, so re-deflate the part up to its end.
            let replacement = match inner.pixel_end {
                Some(end) if end < inflated.len() => {
                    let mut enc = flate2::write::DeflateEncoder::new(data[..pos].to_vec(), flate2::Compression::fast());
                    enc.write_all(&inflated[..end])
                        .and_then(|()| enc.finish())
                        .map(Some)
                        .map_err(|e| (false, format!("cannot re-deflate the data set: {e}")))?
                }
                _ => None,
            };
            let end = replacement.as_ref().map_or(data.len(), Vec::len);
            return Ok(Checked { end, pixel_value: None, replacement });
        }
        Some(TransferSyntax::ImplicitVrLittleEndian) => w.explicit = false,
        Some(TransferSyntax::ExplicitVrBigEndian) => w.big_endian = true,
        _ => {}
    }
    w.elements(pos, data.len(), 0, false)?;
    Ok(Checked { end: w.pixel_end.unwrap_or(data.len()), pixel_value: w.pixel_value, replacement: None })
}

/// Explicit VRs with a 16-bit length field (PS3.5 Table 7.1-2).
const SHORT_VRS: [&[u8; 2]; 21] = [
    b"AE", b"AS", b"AT", b"CS", b"DA", b"DS", b"DT", b"FL", b"FD", b"IS", b"LO", b"LT", b"PN", b"SH", b"SL", b"SS",
    b"ST", b"TM", b"UI", b"UL", b"US",
];

struct Walker<'a> {
    data: &'a [u8],
    explicit: bool,
    big_endian: bool,
    pixel_end: Option<usize>,
    /// The top-level PixelData value, when its length is defined.
    pixel_value: Option<Range<usize>>,
}

type WalkResult<T> = std::result::Result<T, (bool, String)>;

const UNDEFINED: u32 = u32::MAX;

impl Walker<'_> {
    fn u16_at(&self, pos: usize, le: bool) -> WalkResult<u16> {
        let b = self.data.get(pos..pos + 2).ok_or_else(|| Self::short(pos))?;
        Ok(if le { u16::from_le_bytes([b[0], b[1]]) } else { u16::from_be_bytes([b[0], b[1]]) })
    }
    fn u32_at(&self, pos: usize, le: bool) -> WalkResult<u32> {
        let b = self.data.get(pos..pos + 4).ok_or_else(|| Self::short(pos))?;
        let a = [b[0], b[1], b[2], b[3]];
        Ok(if le { u32::from_le_bytes(a) } else { u32::from_be_bytes(a) })
    }
    fn short(pos: usize) -> (bool, String) {
        (true, format!("the data ends inside an element header at byte {}", pos + 128))
    }

    /// Reads an element or item header at `pos`: (tag, length, header size).
    fn header(&self, pos: usize) -> WalkResult<((u16, u16), u32, usize)> {
        // In the data set every element is read in the transfer syntax, group 0002 included, as dicom-rs's decoders
        // read it (treating a group 0002 element there as explicit little endian, as the file meta group is, let an
        // implicit-VR file hide a 2 GB length from this walk). The meta group is walked with `explicit` set and
        // `big_endian` clear.
        let le = !self.big_endian;
        let tag = (self.u16_at(pos, le)?, self.u16_at(pos + 2, le)?);
        let explicit = self.explicit;
        if tag.0 == 0xFFFE || !explicit {
            return Ok((tag, self.u32_at(pos + 4, le)?, 8));
        }
        let vr = self.data.get(pos + 4..pos + 6).ok_or_else(|| Self::short(pos))?;
        // As dicom-rs (dicom-encoding explicit_le/_be): these VRs have a 16-bit length; all others,
        // unknown ones included (read as UN), have 2 reserved bytes and a 32-bit length.
        if SHORT_VRS.iter().any(|s| s.as_slice() == vr) {
            Ok((tag, u32::from(self.u16_at(pos + 6, le)?), 8))
        } else {
            Ok((tag, self.u32_at(pos + 8, le)?, 12))
        }
    }

    fn value_range(&self, tag: (u16, u16), start: usize, len: u32, limit: usize) -> WalkResult<std::ops::Range<usize>> {
        let end = start.checked_add(len as usize).filter(|&e| e <= limit).ok_or_else(|| {
            (
                limit == self.data.len(),
                format!(
                    "element ({:04X},{:04X}) at byte {} declares {len} bytes, but only {} remain",
                    tag.0,
                    tag.1,
                    start + 128,
                    limit.saturating_sub(start)
                ),
            )
        })?;
        Ok(start..end)
    }

    /// The VR dicom-rs reads the element at `pos` with: the one written (explicit VR), or the dictionary's, relaxed
    /// as dicom-rs's implicit decoder relaxes it (unknown tags are UN).
    fn value_vr(&self, pos: usize, tag: (u16, u16)) -> Option<[u8; 2]> {
        if self.explicit {
            self.data.get(pos + 4..pos + 6).map(|b| [b[0], b[1]])
        } else {
            use dicom_core::dictionary::{DataDictionary, DataDictionaryEntry};
            let vr = dicom_dictionary_std::StandardDataDictionary
                .by_tag(Tag(tag.0, tag.1))
                .map_or(dicom_core::VR::UN, |e| e.vr().relaxed());
            Some(vr.to_bytes())
        }
    }

    /// Refuses a binary numeric value whose length is not a whole number of values. dicom-rs reads such a value as
    /// `len / size` values and leaves the remaining bytes unread, so it would parse the next element from a
    /// different byte than this walk, where any length can appear (an odd-length SS element made it reserve
    /// 3.5 GB). The top-level PixelData is exempt: it is the last element dicom-rs is given.
    fn check_value_size(&self, pos: usize, tag: (u16, u16), len: u32) -> WalkResult<()> {
        let Some(vr) = self.value_vr(pos, tag) else { return Ok(()) };
        let size: u32 = match &vr {
            b"US" | b"SS" | b"OW" => 2,
            b"AT" | b"FL" | b"OF" | b"SL" | b"UL" | b"OL" => 4,
            b"FD" | b"OD" | b"SV" | b"UV" | b"OV" => 8,
            _ => return Ok(()),
        };
        if len.is_multiple_of(size) {
            return Ok(());
        }
        Err((
            false,
            format!(
                "element ({:04X},{:04X}) {} at byte {} has {len} bytes, not a whole number of {size}-byte values",
                tag.0,
                tag.1,
                String::from_utf8_lossy(&vr),
                pos + 128
            ),
        ))
    }

    fn is_sequence(&self, pos: usize, tag: (u16, u16)) -> bool {
        if self.explicit {
            self.data.get(pos + 4..pos + 6) == Some(b"SQ")
        } else {
            use dicom_core::dictionary::{DataDictionary, DataDictionaryEntry, VirtualVr};
            matches!(
                dicom_dictionary_std::StandardDataDictionary.by_tag(Tag(tag.0, tag.1)).map(DataDictionaryEntry::vr),
                Some(VirtualVr::Exact(dicom_core::VR::SQ))
            )
        }
    }

    /// Walks data elements from `pos` to `end` (or to an item delimiter when `until_delimiter`).
    /// Returns the position after the last element (after the delimiter).
    fn elements(&mut self, mut pos: usize, end: usize, depth: usize, until_delimiter: bool) -> WalkResult<usize> {
        if depth > MAX_DEPTH {
            return Err((false, format!("sequences nested deeper than {MAX_DEPTH}")));
        }
        while pos < end {
            if depth == 0 && end - pos < 8 && self.data[pos..end].iter().all(|&b| b == 0) {
                return Ok(end); // trailing zero padding
            }
            let (tag, len, header) = self.header(pos)?;
            let start = pos + header;
            if tag == (0xFFFE, 0xE00D) {
                if until_delimiter {
                    return Ok(start);
                }
                pos = start; // stray item delimiter: dicom-rs skips it
                continue;
            }
            if len == UNDEFINED {
                pos = self.items(start, end, depth + 1, tag == (0x7FE0, 0x0010))?;
            } else {
                let value = self.value_range(tag, start, len, end)?;
                if !(depth == 0 && tag == (0x7FE0, 0x0010)) {
                    self.check_value_size(pos, tag, len)?;
                }
                if self.is_sequence(pos, tag) {
                    self.defined_items(value.clone(), depth + 1)?;
                }
                if depth == 0 && tag == (0x7FE0, 0x0010) {
                    self.pixel_value = Some(value.clone());
                }
                pos = value.end;
            }
            if depth == 0 && tag == (0x7FE0, 0x0010) {
                self.pixel_end = Some(pos);
                return Ok(pos);
            }
        }
        if until_delimiter {
            return Err((true, "the data ends inside a sequence item (no item delimiter)".into()));
        }
        Ok(pos)
    }

    /// Items of a defined-length sequence in `range`.
    fn defined_items(&mut self, range: std::ops::Range<usize>, depth: usize) -> WalkResult<()> {
        let mut pos = range.start;
        while pos < range.end {
            let (tag, len, header) = self.header(pos)?;
            let start = pos + header;
            if tag != (0xFFFE, 0xE000) {
                return Err((
                    false,
                    format!("expected a sequence item at byte {}, found ({:04X},{:04X})", pos + 128, tag.0, tag.1),
                ));
            }
            pos = if len == UNDEFINED {
                self.elements(start, range.end, depth, true)?
            } else {
                let value = self.value_range(tag, start, len, range.end)?;
                self.elements(value.start, value.end, depth, false)?;
                value.end
            };
        }
        Ok(())
    }

    /// Items of an undefined-length sequence (or pixel fragments) up to the sequence delimiter.
    fn items(&mut self, mut pos: usize, end: usize, depth: usize, fragments: bool) -> WalkResult<usize> {
        loop {
            if pos >= end {
                return Err((true, "the data ends inside a sequence (no sequence delimiter)".into()));
            }
            let (tag, len, header) = self.header(pos)?;
            let start = pos + header;
            match tag {
                (0xFFFE, 0xE0DD) => return Ok(start),
                (0xFFFE, 0xE000) if len == UNDEFINED && !fragments => pos = self.elements(start, end, depth, true)?,
                (0xFFFE, 0xE000) if len != UNDEFINED => {
                    let value = self.value_range(tag, start, len, end)?;
                    if !fragments {
                        self.elements(value.start, value.end, depth, false)?;
                    }
                    pos = value.end;
                }
                _ => {
                    return Err((
                        false,
                        format!("expected a sequence item at byte {}, found ({:04X},{:04X})", pos + 128, tag.0, tag.1),
                    ));
                }
            }
        }
    }
}
