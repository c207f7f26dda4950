//! The samples: where they are (after the header, or in the detached data file, after `HeaderSize`), checked
//! against the file's length, inflated when `CompressedData = True`, and decoded into the output type a chunk at a
//! time.

use std::fs::File;
use std::io::{self, BufRead, BufReader, Read};
use std::path::Path;

use flate2::bufread::ZlibDecoder;

use super::header::{DataFile, Header};
use crate::error::{Error, Result};
use crate::options::LoadOptions;
use crate::sample;
use crate::volume::VoxelData;

/// Samples are decoded this many bytes at a time (a multiple of every sample size).
const CHUNK_BYTES: usize = 1 << 20;

/// Deflate cannot expand data by more than about 1032:1; a compressed payload claiming more is truncated.
const MAX_DEFLATE_RATIO: u64 = 1032;

/// Which samples to decode: `n` of them (one frame), after `frame` frames of `n`, in a file of `frames` frames.
#[derive(Clone, Copy, Debug)]
pub(super) struct FrameChoice {
    pub(super) n: usize,
    pub(super) frame: usize,
    pub(super) frames: usize,
}

/// Decodes one frame of samples from `r`, which has `len` bytes left; `path` is the file that holds them (the header
/// for `LOCAL` data, else the data file) and is named in errors. Nothing is read past those `len` bytes.
pub(super) fn decode_payload<R: BufRead>(
    path: &Path,
    r: R,
    len: u64,
    h: &Header,
    f: FrameChoice,
    opts: &mut LoadOptions,
) -> Result<VoxelData> {
    let sample_bytes = h.stored.bytes() as u64;
    let frame_bytes = f.n as u64 * sample_bytes;
    let before = f.frame as u64 * frame_bytes;
    let mut r = r.take(len);
    if !h.compressed {
        let all = (f.frames as u64).saturating_mul(frame_bytes);
        let start = match h.byte_skip {
            Some(s) => s,
            None => len.checked_sub(all).ok_or_else(|| {
                Error::truncated(path, format!("{len} bytes of data for the {all} bytes that HeaderSize = -1 needs"))
            })?,
        };
        let end = start.saturating_add(before).saturating_add(frame_bytes);
        if end > len {
            return Err(Error::truncated(
                path,
                format!(
                    "{len} bytes of data, but {} samples of {sample_bytes} bytes{} need {end}",
                    f.n,
                    if start > 0 { format!(" after HeaderSize = {start}") } else { String::new() }
                ),
            ));
        }
        skip_bytes(path, &mut r, start.saturating_add(before), "the bytes before the samples")?;
        return decode_binary(path, &mut r, h, f.n, opts);
    }
    let header_size = h.byte_skip.unwrap_or(0);
    let after = len
        .checked_sub(header_size)
        .ok_or_else(|| Error::truncated(path, format!("{len} bytes of data, fewer than HeaderSize = {header_size}")))?;
    let compressed = match h.compressed_size {
        Some(c) if c > after => {
            return Err(Error::truncated(
                path,
                format!("CompressedDataSize = {c}, but only {after} bytes of compressed data are there"),
            ));
        }
        Some(c) => c,
        None => after,
    };
    let need = before + frame_bytes;
    if compressed.saturating_mul(MAX_DEFLATE_RATIO).saturating_add(1 << 16) < need {
        return Err(Error::truncated(
            path,
            format!("{compressed} bytes of compressed data cannot hold the {need} bytes of {} samples", f.n),
        ));
    }
    skip_bytes(path, &mut r, header_size, "HeaderSize")?;
    let mut z = ZlibDecoder::new(r.take(compressed));
    let inflate_error = |detail: String| {
        Error::invalid(
            path,
            format!(
                "the zlib data (CompressedDataSize = {compressed} bytes) do not inflate to the {need} bytes the \
                 samples need: {detail}; the file is truncated or CompressedDataSize is wrong"
            ),
        )
    };
    let skipped = io::copy(&mut (&mut z).take(before), &mut io::sink()).map_err(|e| inflate_error(e.to_string()))?;
    if skipped < before {
        return Err(inflate_error(format!("they end after {skipped} bytes")));
    }
    decode_binary(path, &mut z, h, f.n, opts).map_err(|e| match e.kind {
        crate::ErrorKind::Truncated(detail) | crate::ErrorKind::Invalid(detail) => inflate_error(detail),
        kind => Error::new(e.path, kind),
    })
}

fn skip_bytes(path: &Path, r: &mut impl Read, count: u64, what: &str) -> Result<()> {
    let skipped = io::copy(&mut r.by_ref().take(count), &mut io::sink()).map_err(|e| Error::io(path, e))?;
    if skipped < count {
        return Err(Error::truncated(path, format!("the data end within {what} ({count} bytes)")));
    }
    Ok(())
}

/// Decodes `n` samples of the header's type and byte order from `r` into the output type, a chunk at a time.
fn decode_binary(path: &Path, r: &mut impl Read, h: &Header, n: usize, opts: &mut LoadOptions) -> Result<VoxelData> {
    let size = h.stored.bytes();
    let total = (n * size) as u64;
    let t = h.stored.unscaled();
    let mut out = VoxelData::try_empty(path, t, n, &format!("{n} samples of {}", t.name()))?;
    let mut buf = vec![0u8; CHUNK_BYTES.min(n * size)];
    let mut done = 0usize;
    opts.report(path, "reading", 0, total)?;
    while done < n {
        let count = (n - done).min(CHUNK_BYTES / size);
        let bytes = &mut buf[..count * size];
        let got = crate::files::read_up_to(r, bytes).map_err(|e| match e.kind() {
            io::ErrorKind::InvalidInput | io::ErrorKind::InvalidData => {
                Error::invalid(path, format!("corrupt data: {e}"))
            }
            _ => Error::io(path, e),
        })?;
        if got < bytes.len() {
            let have = done as u64 * size as u64 + got as u64;
            return Err(Error::truncated(path, format!("the data end after {have} of {total} bytes")));
        }
        sample::with_stored_type!(h.stored, T => out.extend_from(sample::decode::<T>(bytes, h.big_endian)));
        done += count;
        opts.report(path, "reading", (done * size) as u64, total)?;
    }
    Ok(out)
}

/// Decodes the samples `f` chooses: from `r` (the `len` bytes after the header of `name`) for `LOCAL` data, else from
/// the detached data file in `base_dir` (none when the header was read from memory, which is refused).
pub(super) fn samples<R: BufRead>(
    name: &Path,
    r: R,
    len: u64,
    base_dir: Option<&Path>,
    h: &Header,
    f: FrameChoice,
    opts: &mut LoadOptions,
) -> Result<VoxelData> {
    match &h.data_file {
        DataFile::Local => decode_payload(name, r, len, h, f, opts),
        DataFile::Detached(file_name) => {
            let Some(base) = base_dir else {
                return Err(Error::unsupported(
                    name,
                    format!("the detached data file {file_name:?} cannot be read from memory"),
                ));
            };
            let data_path = base.join(file_name);
            // A pipe would block and a device such as /dev/zero never ends: refused before it is opened.
            let meta = std::fs::metadata(&data_path).map_err(|e| {
                Error::invalid(name, format!("its ElementDataFile {} cannot be read: {e}", data_path.display()))
            })?;
            if !meta.is_file() {
                crate::files::check_regular_file(&data_path)?;
            }
            let file = File::open(&data_path).map_err(|e| Error::io(&data_path, e))?;
            let len = file.metadata().map_err(|e| Error::io(&data_path, e))?.len();
            decode_payload(&data_path, BufReader::new(file), len, h, f, opts)
        }
    }
}
