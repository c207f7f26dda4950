//! NRRD (`.nrrd`, `.nhdr`): reader and writer.
//!
//! # The format
//!
//! A NRRD file is a text header followed by the samples (Kindlmann, *Definition of NRRD File
//! Format*, teem.sourceforge.net/nrrd/format.html):
//!
//! ```text
//! NRRD0004                         magic, NRRD0001 … NRRD0005
//! # a comment
//! type: short                      sample type (C names and their aliases)
//! dimension: 3
//! space: left-posterior-superior   or right-anterior-superior, left-anterior-superior
//! sizes: 512 512 48                fastest axis first
//! space directions: (0.57,0,0) (0,0.57,0) (0,0,5)   one column of lps_from_index per axis, `none` for non-spatial axes
//! space origin: (-146,-325,-777.5) position of the centre of the first sample
//! endian: little
//! encoding: gzip                   raw, gzip (gz), ascii (text, txt), hex; bzip2 is refused
//! key:=value                       free key/value pairs, ignored
//!                                  a blank line ends the header; the data follow
//! ```
//!
//! A detached header (`.nhdr`) names its data with `data file: name`, relative to the header's
//! folder; `line skip` and `byte skip` skip lines and bytes before the data (`byte skip: -1` means
//! "the data are the last bytes of the file", raw only). For compressed encodings the byte skip
//! counts decompressed bytes, as in teem and pynrrd.
//!
//! # Our conventions
//!
//! - Geometry: `lps_from_index = [d_0 d_1 d_2 | o]` with the space directions `d_a` as columns
//!   and the origin `o`, both converted to LPS from the `space` field (RAS negates x and y, LAS
//!   negates y) → [`crate::GeometrySource::NrrdSpace`]. Without a space, `spacings` give an
//!   axis-aligned diagonal with origin 0 → [`crate::GeometrySource::NrrdSpacings`] (unit spacing, with a
//!   warning, when even those are missing).
//! - Dimension 3, or 4 with one non-spatial axis of size 1 (anywhere), which is dropped; real
//!   vector or time-series data are refused.
//! - Sample types follow `docs/fixture-manifest.md`: u8, i16, u16 and f32 are kept, i8 becomes
//!   i16, every other type becomes f32. NRRD has no rescale.
//! - Bad input never panics: the header is capped at [`MAX_HEADER_BYTES`], numbers are checked,
//!   [`crate::volume::check_allocation`] runs before any voxel buffer exists, raw data are checked
//!   against the file length first, and samples are converted in chunks, so the peak memory is
//!   the output plus one chunk. The output buffer is allocated fallibly
//!   ([`crate::volume::try_with_capacity`]): memory the system refuses is an error naming the file.
//! - No hang: the header and a detached data file must be regular files (a named pipe or a device
//!   such as `/dev/zero` is refused before it is opened), and every skip and scan of the data
//!   (line skip, byte skip, gzip, hex, ASCII) reads at most the bytes the file had when it was
//!   opened; a `line skip` whose line does not end before them is a truncated file.
//! - The writer ([`write()`], [`write_with`]) writes NRRD0004 in LPS with the directions and the
//!   origin printed with Rust's shortest round-trip formatting (exact f64), little-endian,
//!   gzip-compressed unless asked otherwise, through [`crate::write_atomic`].
//!
//! # Modules
//! `header` reads and parses the text header, `geometry` turns it into `lps_from_index`, `data` finds and
//! decodes the samples (raw, gzip, ASCII, hex), `write` writes NRRD0004.

mod data;
pub mod field;
mod geometry;
mod header;
mod write;

use std::fs::File;
use std::io::{BufRead, BufReader};
use std::path::Path;

pub use header::MAX_HEADER_BYTES;
pub use write::{NrrdWriteOptions, write, write_with};

use crate::error::{Error, ErrorKind, Result};
use crate::options::LoadOptions;
use crate::volume::{Metadata, Volume, check_allocation};
use data::{decode_payload, preflight_size};
use header::{parse_header, read_header_lines};

/// Reads the NRRD file (attached `.nrrd` or detached `.nhdr`) at `path`.
pub fn read(path: &Path, opts: &mut LoadOptions) -> Result<Volume> {
    crate::files::read_header_file(path, |r, len, folder| read_from(path, r, len, Some(folder), opts))
}

/// Reads a NRRD file held in memory; `name` is used in errors. Detached data files are refused.
pub fn read_bytes(name: &Path, bytes: &[u8], opts: &mut LoadOptions) -> Result<Volume> {
    read_from(name, bytes, bytes.len() as u64, None, opts)
}

fn read_from<R: BufRead>(
    name: &Path,
    mut r: R,
    total_len: u64,
    base_dir: Option<&Path>,
    opts: &mut LoadOptions,
) -> Result<Volume> {
    let (lines, header_bytes) = read_header_lines(name, &mut r)?;
    let mut h = parse_header(name, &lines)?;
    let g = geometry::geometry(name, &mut h)?;
    let out_type = h.stored.unscaled();
    preflight_size(name, g.dims, out_type.bytes(), opts.max_voxel_bytes)?;
    let n = check_allocation(name, g.dims, out_type.bytes(), opts.max_voxel_bytes)?;
    let need = (n as u64).checked_mul(h.stored.bytes() as u64).ok_or_else(|| {
        Error::new(
            name,
            ErrorKind::TooLarge {
                what: format!("dims {:?}", g.dims),
                bytes: n as u128 * h.stored.bytes() as u128,
                limit: opts.max_voxel_bytes,
            },
        )
    })?;

    let data = if let Some(df) = &h.data_file {
        let Some(base) = base_dir else {
            return Err(Error::unsupported(name, format!("detached data file {df:?} cannot be read from memory")));
        };
        let data_path = base.join(df);
        // A pipe would block and a device such as /dev/zero never ends: refused before it is opened.
        crate::files::check_regular_file(&data_path)?;
        let file = File::open(&data_path).map_err(|e| Error::io(&data_path, e))?;
        let len = file.metadata().map_err(|e| Error::io(&data_path, e))?.len();
        decode_payload(&data_path, BufReader::new(file), len, &h, n, need, opts)?
    } else {
        decode_payload(name, r, total_len.saturating_sub(header_bytes), &h, n, need, opts)?
    };

    let mut volume = Volume::new(name, g.dims, data, g.lps_from_index, g.source)?;
    let mut warnings = std::mem::take(&mut h.warnings);
    warnings.append(&mut volume.metadata.warnings); // the geometry's, from Volume::new
    volume.metadata = Metadata {
        description: h.content.clone(),
        value_units: h.sample_units.clone().filter(|s| !s.is_empty()),
        warnings,
        ..Metadata::default()
    };
    Ok(volume)
}
