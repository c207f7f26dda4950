//! The samples: where they are (attached, detached, after line and byte skips), checked against the file's
//! length, and decoded from raw, gzip, ASCII or hex into the output type, a chunk at a time.

use std::io::{self, BufRead, BufReader, Read};
use std::path::Path;

use flate2::read::MultiGzDecoder;

use super::header::{Encoding, Header};
use crate::error::{Error, ErrorKind, Result};
use crate::options::LoadOptions;
use crate::sample::{self, StoredType};
use crate::volume::{SampleType, VoxelData};

/// Samples are decoded this many bytes at a time (a multiple of every sample size).
const CHUNK_BYTES: usize = 1 << 20;

/// Deflate cannot expand data by more than about 1032:1; a gzip payload claiming more is truncated.
const MAX_DEFLATE_RATIO: u64 = 1032;

/// Refuses sizes whose byte count overflows even u128 (three huge `usize`s), which
/// [`check_allocation`] cannot yet compute; everything else is left to it.
pub(super) fn preflight_size(name: &Path, dims: [usize; 3], bytes_per_sample: usize, limit: u64) -> Result<()> {
    let bytes = dims.iter().try_fold(bytes_per_sample as u128, |acc, &d| acc.checked_mul(d as u128));
    match bytes {
        Some(_) => Ok(()),
        None => Err(Error::new(name, ErrorKind::TooLarge { what: format!("dims {dims:?}"), bytes: u128::MAX, limit })),
    }
}

/// Decodes the `n` samples (`need` stored bytes) that start at the reader's position, which has
/// `len` bytes left. `path` is the file that holds the data (for errors).
///
/// The reader is cut at those `len` bytes, so every skip and scan below ends with the file, even
/// one that grows or claims a line skip longer than itself.
pub(super) fn decode_payload<R: BufRead>(
    path: &Path,
    r: R,
    mut len: u64,
    h: &Header,
    n: usize,
    need: u64,
    opts: &mut LoadOptions,
) -> Result<VoxelData> {
    let mut r = r.take(len);
    for i in 0..h.line_skip {
        let (skipped, ended) = skip_line(&mut r).map_err(|e| Error::io(path, e))?;
        if !ended {
            return Err(Error::truncated(
                path,
                format!("the data end within line skip ({i} of {} lines skipped)", h.line_skip),
            ));
        }
        len = len.saturating_sub(skipped);
    }
    let byte_skip = if h.byte_skip == -1 {
        len.checked_sub(need).ok_or_else(|| {
            Error::truncated(path, format!("{len} bytes of data for the {need} bytes that {n} samples need"))
        })?
    } else {
        h.byte_skip as u64
    };
    // Cheap plausibility checks on the encoded length, before any voxel buffer is allocated.
    let enough = match h.encoding {
        Encoding::Raw => len >= byte_skip.saturating_add(need),
        Encoding::Gzip => {
            len.saturating_mul(MAX_DEFLATE_RATIO).saturating_add(1 << 16) >= need.saturating_add(byte_skip)
        }
        Encoding::Hex => len >= byte_skip.saturating_add(need.saturating_mul(2)),
        Encoding::Ascii => len >= byte_skip.saturating_add((n as u64).saturating_mul(2).saturating_sub(1)),
    };
    if !enough {
        return Err(Error::truncated(
            path,
            format!("{len} bytes of {:?} data cannot hold {n} samples of {} bytes", h.encoding, h.stored.bytes()),
        ));
    }
    let data = match h.encoding {
        Encoding::Raw => {
            skip_bytes(path, &mut r, byte_skip, "byte skip")?;
            decode_binary(path, &mut r, h, n, opts)?
        }
        Encoding::Gzip => {
            let mut gz = BufReader::new(MultiGzDecoder::new(r));
            skip_bytes(path, &mut gz, byte_skip, "byte skip (decompressed)")?;
            decode_binary(path, &mut gz, h, n, opts)?
        }
        Encoding::Hex => {
            skip_bytes(path, &mut r, byte_skip, "byte skip")?;
            decode_binary(path, &mut HexReader { inner: r }, h, n, opts)?
        }
        Encoding::Ascii => {
            skip_bytes(path, &mut r, byte_skip, "byte skip")?;
            decode_ascii(path, &mut r, h.stored, n, opts)?
        }
    };
    Ok(data)
}

/// Skips one line, through its `\n`; returns the bytes skipped and whether the `\n` was there (not the end of the
/// input first).
fn skip_line(r: &mut impl BufRead) -> io::Result<(u64, bool)> {
    let mut skipped = 0u64;
    loop {
        let buf = match r.fill_buf() {
            Ok(b) => b,
            Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
            Err(e) => return Err(e),
        };
        if buf.is_empty() {
            return Ok((skipped, false));
        }
        let (used, ended) = buf.iter().position(|&b| b == b'\n').map_or((buf.len(), false), |i| (i + 1, true));
        r.consume(used);
        skipped += used as u64;
        if ended {
            return Ok((skipped, true));
        }
    }
}

fn skip_bytes(path: &Path, r: &mut impl Read, count: u64, what: &str) -> Result<()> {
    let skipped = io::copy(&mut r.by_ref().take(count), &mut io::sink()).map_err(|e| data_error(path, e))?;
    if skipped < count {
        return Err(Error::truncated(path, format!("the data end within the {what} of {count} bytes")));
    }
    Ok(())
}

/// Errors while decoding samples: a corrupt gzip stream is invalid data, not an I/O failure.
fn data_error(path: &Path, e: io::Error) -> Error {
    match e.kind() {
        io::ErrorKind::InvalidInput | io::ErrorKind::InvalidData => Error::invalid(path, format!("corrupt data: {e}")),
        _ => Error::io(path, e),
    }
}

fn decode_binary(path: &Path, r: &mut impl Read, h: &Header, n: usize, opts: &mut LoadOptions) -> Result<VoxelData> {
    let size = h.stored.bytes();
    let total = (n * size) as u64;
    let big = h.big_endian;
    let mut out = output_buffer(path, h.stored.unscaled(), n)?;
    let mut buf = vec![0u8; CHUNK_BYTES.min(n * size)];
    let mut done = 0usize;
    opts.report(path, "reading", 0, total)?;
    while done < n {
        let count = (n - done).min(CHUNK_BYTES / size);
        let bytes = &mut buf[..count * size];
        let got = crate::files::read_up_to(r, bytes).map_err(|e| data_error(path, e))?;
        if got < bytes.len() {
            let have = done as u64 * size as u64 + got as u64;
            return Err(Error::truncated(path, format!("the data end after {have} of {total} bytes")));
        }
        sample::with_stored_type!(h.stored, T => out.extend_from(sample::decode::<T>(bytes, big)));
        done += count;
        opts.report(path, "reading", (done * size) as u64, total)?;
    }
    Ok(out)
}

/// Room for `n` samples of `t`, allocated fallibly (an error naming `path`, never an abort).
fn output_buffer(path: &Path, t: SampleType, n: usize) -> Result<VoxelData> {
    VoxelData::try_empty(path, t, n, &format!("{n} samples of {}", t.name()))
}

/// Pushes one ASCII token onto `out`; `None` when it is not a value of the stored type.
fn push_text(out: &mut VoxelData, stored: StoredType, t: &str) -> Option<()> {
    match (out, stored) {
        (VoxelData::U8(v), _) => v.push(t.parse().ok()?),
        (VoxelData::I16(v), StoredType::I8) => v.push(i16::from(t.parse::<i8>().ok()?)),
        (VoxelData::I16(v), _) => v.push(t.parse().ok()?),
        (VoxelData::U16(v), _) => v.push(t.parse().ok()?),
        (VoxelData::F32(v), StoredType::F32) => v.push(t.parse().ok()?),
        (VoxelData::F32(v), StoredType::I32 | StoredType::I64) => v.push(t.parse::<i64>().ok()? as f32),
        (VoxelData::F32(v), StoredType::U32 | StoredType::U64) => v.push(t.parse::<u64>().ok()? as f32),
        (VoxelData::F32(v), _) => v.push(t.parse::<f64>().ok()? as f32),
    }
    Some(())
}

/// Whitespace- (or comma-) separated numbers.
fn decode_ascii(
    path: &Path,
    r: &mut impl BufRead,
    stored: StoredType,
    n: usize,
    opts: &mut LoadOptions,
) -> Result<VoxelData> {
    const MAX_TOKEN: usize = 64;
    let mut out = output_buffer(path, stored.unscaled(), n)?;
    let mut tok = String::new();
    let mut count = 0usize;
    let mut finish_token = |tok: &mut String, count: &mut usize| -> Result<()> {
        if tok.is_empty() || *count >= n {
            tok.clear();
            return Ok(());
        }
        push_text(&mut out, stored, tok).ok_or_else(|| {
            Error::invalid(path, format!("ASCII sample {} is {tok:?}, not a {stored:?} value", *count + 1))
        })?;
        *count += 1;
        tok.clear();
        Ok(())
    };
    let mut last_report = 0usize;
    while count < n {
        let buf = r.fill_buf().map_err(|e| Error::io(path, e))?;
        if buf.is_empty() {
            break;
        }
        let used = buf.len();
        for &b in buf {
            if b.is_ascii_whitespace() || b == b',' {
                finish_token(&mut tok, &mut count)?;
            } else {
                if tok.len() >= MAX_TOKEN {
                    return Err(Error::invalid(
                        path,
                        format!("ASCII sample {} is longer than {MAX_TOKEN} characters", count + 1),
                    ));
                }
                tok.push(char::from(b));
            }
        }
        r.consume(used);
        if count - last_report >= CHUNK_BYTES / 8 {
            last_report = count;
            opts.report(path, "reading", count as u64, n as u64)?;
        }
    }
    finish_token(&mut tok, &mut count)?;
    if count < n {
        return Err(Error::truncated(path, format!("the ASCII data end after {count} of {n} samples")));
    }
    opts.report(path, "reading", n as u64, n as u64)?;
    Ok(out)
}

/// Decodes `hex` encoding: pairs of hex digits, whitespace ignored.
struct HexReader<R> {
    inner: R,
}

impl<R: BufRead> Read for HexReader<R> {
    fn read(&mut self, out: &mut [u8]) -> io::Result<usize> {
        let mut written = 0;
        let mut high: Option<u8> = None;
        while written < out.len() {
            let buf = self.inner.fill_buf()?;
            let Some(&c) = buf.first() else {
                if high.is_some() {
                    return Err(io::Error::new(io::ErrorKind::InvalidData, "odd number of hex digits"));
                }
                break;
            };
            self.inner.consume(1);
            if c.is_ascii_whitespace() {
                continue;
            }
            let v = match c {
                b'0'..=b'9' => c - b'0',
                b'a'..=b'f' => c - b'a' + 10,
                b'A'..=b'F' => c - b'A' + 10,
                _ => {
                    return Err(io::Error::new(
                        io::ErrorKind::InvalidData,
                        format!("{:?} is not a hex digit", char::from(c)),
                    ));
                }
            };
            match high.take() {
                None => high = Some(v),
                Some(hi) => {
                    out[written] = (hi << 4) | v;
                    written += 1;
                }
            }
        }
        Ok(written)
    }
}
