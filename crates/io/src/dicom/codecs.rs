//! Codecs: RLE Lossless (decoded here) and JPEG-LS (decoded by [`crate::jpegls`], its frames split and checked
//! here); JPEG and JPEG 2000 frame headers are checked against Rows and Columns before dicom-pixeldata's codecs
//! run, since a mismatch would make its codec adapters panic.

use std::borrow::Cow;
use std::path::Path;

use super::header::PixelFormat;
use super::jpegls;
use crate::error::{Error, ErrorKind, Result};
use crate::volume::try_zeros;

/// Decodes RLE Lossless (PS3.5 Annex G): one fragment per frame, 64-byte header, one PackBits
/// segment per byte of the sample, most significant first. Output is little-endian.
pub(super) fn decode_rle(path: &Path, fragments: &[Vec<u8>], fmt: &PixelFormat, bytes: usize) -> Result<Vec<u8>> {
    let bad = |m: String| Error::new(path, ErrorKind::Dicom(format!("RLE Lossless: {m}")));
    if fragments.len() < fmt.frames {
        return Err(bad(format!("{} fragments for {} frames (one per frame expected)", fragments.len(), fmt.frames)));
    }
    let pixels = fmt.rows * fmt.cols;
    let mut out = try_zeros(path, pixels * bytes * fmt.frames, "the decoded pixel data")?;
    for (f, frag) in fragments.iter().take(fmt.frames).enumerate() {
        let header = frag.get(..64).ok_or_else(|| bad(format!("frame {}: fragment shorter than the header", f + 1)))?;
        let word =
            |i: usize| u32::from_le_bytes([header[4 * i], header[4 * i + 1], header[4 * i + 2], header[4 * i + 3]]);
        let segments = word(0) as usize;
        if segments != bytes {
            return Err(bad(format!("frame {}: {segments} segments, {bytes} expected", f + 1)));
        }
        let out_frame = &mut out[f * pixels * bytes..(f + 1) * pixels * bytes];
        for s in 0..segments {
            let start = word(1 + s) as usize;
            let end = if s + 1 < segments { word(2 + s) as usize } else { frag.len() };
            let seg = frag.get(start..end).ok_or_else(|| {
                bad(format!("frame {}: segment {} offsets {start}..{end} out of range", f + 1, s + 1))
            })?;
            // Segment 0 holds the most significant byte.
            let byte_pos = bytes - 1 - s;
            let written = packbits(seg, |i, v| out_frame[i * bytes + byte_pos] = v, pixels);
            if written < pixels {
                return Err(bad(format!("frame {}: segment {} decodes to {written} of {pixels} bytes", f + 1, s + 1)));
            }
        }
    }
    Ok(out)
}

/// Decodes JPEG-LS (PS3.5 Section 8.2.3, ISO/IEC 14495-1) with [`jpegls`]: one codestream per
/// frame, in one fragment or several. Each frame header is checked against Rows, Columns,
/// SamplesPerPixel and BitsAllocated before its samples are decoded. Output is little-endian.
pub(super) fn decode_jpeg_ls(path: &Path, fragments: &[Vec<u8>], fmt: &PixelFormat, bytes: usize) -> Result<Vec<u8>> {
    let bad = |m: String| Error::new(path, ErrorKind::Dicom(format!("JPEG-LS: {m}")));
    if bytes > 2 {
        return Err(Error::unsupported(path, format!("JPEG-LS with BitsAllocated (0028,0100) {}", fmt.bits_allocated)));
    }
    let frames = jpeg_ls_frames(fragments, fmt.frames).map_err(bad)?;
    let pixels = fmt.rows * fmt.cols;
    let mut out = try_zeros(path, pixels * bytes * fmt.frames, "the decoded pixel data")?;
    for (f, (data, out_frame)) in frames.iter().zip(out.chunks_exact_mut(pixels * bytes)).enumerate() {
        let codec = |e: jpegls::JpegLsError| {
            let m = format!("JPEG-LS frame {}: {e}", f + 1);
            match e {
                jpegls::JpegLsError::Truncated(_) => Error::truncated(path, m),
                jpegls::JpegLsError::Unsupported(_) => Error::unsupported(path, m),
                jpegls::JpegLsError::OutOfMemory { bytes } => Error::new(
                    path,
                    ErrorKind::OutOfMemory { what: format!("the samples of JPEG-LS frame {}", f + 1), bytes },
                ),
                _ => Error::new(path, ErrorKind::Dicom(m)),
            }
        };
        let h = jpegls::read_header(data).map_err(codec)?;
        if h.width != fmt.cols || h.height != fmt.rows || u16::from(h.components) != fmt.samples_per_pixel {
            return Err(Error::invalid(
                path,
                format!(
                    "JPEG-LS frame {} is {}x{} with {} component(s), but Columns x Rows is {}x{} with {} sample(s)",
                    f + 1,
                    h.width,
                    h.height,
                    h.components,
                    fmt.cols,
                    fmt.rows,
                    fmt.samples_per_pixel
                ),
            ));
        }
        if usize::from(h.precision) > 8 * bytes {
            return Err(Error::unsupported(
                path,
                format!("JPEG-LS precision {} bits with BitsAllocated (0028,0100) {}", h.precision, fmt.bits_allocated),
            ));
        }
        let spec = jpegls::FrameSpec { width: fmt.cols, height: fmt.rows, max_precision: 8 * bytes as u8 };
        let samples = jpegls::decode(data, spec).map_err(codec)?;
        if bytes == 1 {
            for (o, &v) in out_frame.iter_mut().zip(&samples) {
                *o = v as u8;
            }
        } else {
            for (o, &v) in out_frame.chunks_exact_mut(2).zip(&samples) {
                o.copy_from_slice(&v.to_le_bytes());
            }
        }
    }
    Ok(out)
}

/// Splits the fragments into one codestream per frame: one fragment each, all of them for a
/// single frame, or else a new frame at each fragment that starts with SOI.
fn jpeg_ls_frames(fragments: &[Vec<u8>], frames: usize) -> std::result::Result<Vec<Cow<'_, [u8]>>, String> {
    if fragments.len() == frames {
        return Ok(fragments.iter().map(|f| Cow::Borrowed(f.as_slice())).collect());
    }
    if frames == 1 {
        return Ok(vec![Cow::Owned(fragments.concat())]);
    }
    let mut out: Vec<Cow<[u8]>> = Vec::new();
    for frag in fragments {
        match out.last_mut() {
            Some(last) if !frag.starts_with(&[0xFF, 0xD8]) => last.to_mut().extend_from_slice(frag),
            _ => out.push(Cow::Borrowed(frag)),
        }
    }
    if out.len() != frames {
        return Err(format!("{} fragments hold {} codestreams for {frames} frames", fragments.len(), out.len()));
    }
    Ok(out)
}

/// PackBits: writes at most `limit` bytes through `put`; returns how many were written.
fn packbits(seg: &[u8], mut put: impl FnMut(usize, u8), limit: usize) -> usize {
    let mut i = 0;
    let mut o = 0;
    while i < seg.len() && o < limit {
        let n = seg[i] as i8;
        i += 1;
        if n >= 0 {
            let count = n as usize + 1;
            for _ in 0..count {
                let Some(&v) = seg.get(i) else { return o };
                if o < limit {
                    put(o, v);
                    o += 1;
                }
                i += 1;
            }
        } else if n != -128 {
            let count = 1 - isize::from(n);
            let Some(&v) = seg.get(i) else { return o };
            i += 1;
            for _ in 0..count {
                if o < limit {
                    put(o, v);
                    o += 1;
                }
            }
        }
    }
    o
}

/// Checks every JPEG frame header (SOF) against Rows, Columns, SamplesPerPixel and BitsAllocated.
///
/// Walks the marker segments (skipping each payload by its length, and entropy-coded data up to
/// the next marker), so bytes inside tables are never taken for markers.
pub(super) fn check_jpeg(path: &Path, fragments: &[Vec<u8>], fmt: &PixelFormat) -> Result<()> {
    let data: Vec<u8> = fragments.iter().flatten().copied().collect();
    let mut found = 0usize;
    let mut i = 0usize;
    while i + 1 < data.len() {
        let m = data[i + 1];
        if data[i] != 0xFF || m == 0x00 || m == 0xFF || (0xD0..=0xD7).contains(&m) {
            // entropy-coded data, stuffing, restart markers or fill bytes
            i += 1;
            continue;
        }
        if m == 0xD8 || m == 0xD9 || m == 0x01 {
            i += 2; // SOI, EOI, TEM: no payload
            continue;
        }
        let Some(&[l1, l0]) = data.get(i + 2..i + 4) else { break };
        let len = usize::from(u16::from_be_bytes([l1, l0]));
        // SOF markers: C0..CF except DHT (C4), JPG (C8) and DAC (CC)
        if (0xC0..=0xCF).contains(&m) && m != 0xC4 && m != 0xC8 && m != 0xCC {
            let Some(&[precision, h1, h0, w1, w0, comps]) = data.get(i + 4..i + 10) else { break };
            let h = usize::from(u16::from_be_bytes([h1, h0]));
            let w = usize::from(u16::from_be_bytes([w1, w0]));
            if (h != fmt.rows && h != 0) || w != fmt.cols || u16::from(comps) != fmt.samples_per_pixel {
                return Err(Error::invalid(
                    path,
                    format!(
                        "JPEG frame is {w}x{h} with {comps} component(s), but Columns x Rows is {}x{} with {} sample(s)",
                        fmt.cols, fmt.rows, fmt.samples_per_pixel
                    ),
                ));
            }
            let bits_needed = if precision <= 8 { 8 } else { 16 };
            if bits_needed != fmt.bits_allocated {
                return Err(Error::unsupported(
                    path,
                    format!("JPEG precision {precision} bits with BitsAllocated (0028,0100) {}", fmt.bits_allocated),
                ));
            }
            found += 1;
        }
        i += 2 + len.max(2);
    }
    if found == 0 {
        return Err(Error::new(path, ErrorKind::Dicom("JPEG pixel data has no frame header (SOF)".into())));
    }
    Ok(())
}

/// Checks each JPEG 2000 codestream's SIZ segment against Rows, Columns and SamplesPerPixel.
pub(super) fn check_j2k(path: &Path, fragments: &[Vec<u8>], fmt: &PixelFormat) -> Result<()> {
    let mut found = 0usize;
    for frag in fragments {
        let start = if frag.starts_with(&[0xFF, 0x4F, 0xFF, 0x51]) {
            Some(0)
        } else if frag.starts_with(&[0, 0, 0, 0x0C, 0x6A, 0x50, 0x20, 0x20]) {
            frag.windows(4).position(|w| w == [0xFF, 0x4F, 0xFF, 0x51])
        } else {
            None // a continuation fragment
        };
        let Some(s) = start else { continue };
        let siz = frag.get(s + 4..s + 42).ok_or_else(|| Error::truncated(path, "JPEG 2000 SIZ segment"))?;
        let u32_at = |o: usize| u32::from_be_bytes([siz[o], siz[o + 1], siz[o + 2], siz[o + 3]]);
        let (xsiz, ysiz, xo, yo) = (u32_at(4), u32_at(8), u32_at(12), u32_at(16));
        let comps = u16::from_be_bytes([siz[36], siz[37]]);
        let w = xsiz.saturating_sub(xo) as usize;
        let h = ysiz.saturating_sub(yo) as usize;
        if w != fmt.cols || h != fmt.rows || comps != fmt.samples_per_pixel {
            return Err(Error::invalid(
                path,
                format!(
                    "JPEG 2000 codestream is {w}x{h} with {comps} component(s), but Columns x Rows is {}x{} with {} sample(s)",
                    fmt.cols, fmt.rows, fmt.samples_per_pixel
                ),
            ));
        }
        // Subsampled components would also be written out of bounds.
        let comp =
            frag.get(s + 42..s + 42 + 3 * usize::from(comps)).ok_or_else(|| Error::truncated(path, "JPEG 2000 SIZ"))?;
        if comp.chunks_exact(3).any(|c| c[1] != 1 || c[2] != 1) {
            return Err(Error::unsupported(path, "subsampled JPEG 2000 components"));
        }
        found += 1;
    }
    if found < fmt.frames {
        return Err(Error::new(
            path,
            ErrorKind::Dicom(format!("{found} JPEG 2000 codestreams for {} frames", fmt.frames)),
        ));
    }
    Ok(())
}
