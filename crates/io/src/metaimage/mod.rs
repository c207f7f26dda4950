//! MetaImage (`.mha`, `.mhd` + `.raw`): reader and writer, the format ITK, SimpleITK and elastix write.
//!
//! # The format
//!
//! A MetaImage file is a text header of `Key = Value` lines (MetaIO, `Modules/ThirdParty/MetaIO` in ITK) followed
//! by the samples. This is what SimpleITK 2.5 writes for a 7×6×5 `int16` volume:
//!
//! ```text
//! ObjectType = Image
//! NDims = 3
//! BinaryData = True
//! BinaryDataByteOrderMSB = False                   True: big-endian samples (also ElementByteOrderMSB)
//! CompressedData = True                            zlib (RFC 1950), the whole data as one stream
//! CompressedDataSize = 334                         bytes of compressed data
//! TransformMatrix = 0.955 0.296 0 -0.296 0.955 0 0 0 1   the direction, column by column (also Rotation, Orientation)
//! Offset = -10.5 20.25 3                           LPS mm of voxel (0,0,0)'s centre (also Position, Origin)
//! CenterOfRotation = 0 0 0
//! AnatomicalOrientation = RAI
//! ElementSpacing = 0.7 1.3 2.5                     mm (ElementSize is used when it is missing)
//! DimSize = 7 6 5                                  i fastest
//! ElementType = MET_SHORT
//! ElementDataFile = LOCAL                          LOCAL: the samples follow (.mha); else a file name (.mhd)
//! ```
//!
//! `ElementDataFile` is always the last field; with `LOCAL` the samples start right after its line. A detached
//! header (`.mhd`) names its data file relative to its own folder; `HeaderSize = N` skips N bytes of that file
//! (`-1`: the samples are its last bytes).
//!
//! # Our conventions
//!
//! - **Geometry.** MetaImage's physical space is ITK's, LPS mm, so no conversion is needed:
//!   `lps_from_index = [D · diag(ElementSpacing) | Offset]` → [`crate::GeometrySource::MetaImage`], with D the
//!   direction whose column a (the direction of the a-th index axis) is values 3a … 3a + 2 of `TransformMatrix`
//!   (column-major: ITK writes D's first column first). Missing fields take MetaIO's defaults (identity, unit spacing,
//!   offset 0). `CenterOfRotation` and `AnatomicalOrientation` are ignored on reading, as ITK ignores them.
//! - **Dimensions.** `NDims = 3`; or `NDims = 4`, whose 4th axis is frames: one frame is read, chosen with
//!   [`LoadOptions::frame`] as for a 4-D NIfTI ([`crate::ErrorKind::FrameRequired`] without it when there are
//!   several). A 3-D image of three float channels is a displacement field, read by [`read_displacement_field`]
//!   (transformix's `deformationField.mhd`; module `field`). Other dimensions, other channel counts as volumes
//!   (vector and colour images), text samples (`BinaryData = False`) and several data files (`ElementDataFile =
//!   LIST`, numbered file patterns) are refused with an error that says so.
//! - **Sample types** (`ElementType`) follow `docs/fixture-manifest.md`: `MET_UCHAR` (u8), `MET_SHORT` (i16),
//!   `MET_USHORT` (u16) and `MET_FLOAT` (f32) are kept; `MET_CHAR` becomes i16; `MET_INT`, `MET_UINT`, `MET_LONG`,
//!   `MET_ULONG` (4 bytes in MetaIO), `MET_LONG_LONG`, `MET_ULONG_LONG` and `MET_DOUBLE` become f32. MetaImage has
//!   no rescale.
//! - **Bad input never panics**: the header is capped at [`MAX_HEADER_BYTES`], every field is checked (a field
//!   given twice, or under two of its names with different values, is an error), [`crate::volume::check_allocation`]
//!   runs before any voxel buffer exists, uncompressed data are checked against the file's length first, compressed
//!   data against `CompressedDataSize` and the file's length, and the samples are converted a chunk at a time into a
//!   buffer allocated fallibly. Only regular files are opened, the header and a detached data file alike.
//! - **Writer** ([`write()`], [`write_with`]): what SimpleITK writes, with the same keys in the same order
//!   (`AnatomicalOrientation` computed as ITK does), numbers in Rust's shortest round-trip form (ITK prints 17
//!   significant digits; both read back to the same f64), little-endian, through [`crate::write_atomic`]. `.mha`
//!   holds the samples zlib-compressed after the header (`ElementDataFile = LOCAL`); `.mhd` names a detached `.raw`
//!   beside it, uncompressed ([`MetaImageWriteOptions`] chooses otherwise).
//!
//! # Modules
//! `header` reads and checks the text header, `geometry` turns it into `lps_from_index`, `data` finds, inflates and
//! decodes the samples, `write` writes `.mha` and `.mhd`, `field` reads and writes displacement fields.

mod data;
mod field;
mod geometry;
mod header;
mod write;

use std::io::BufRead;
use std::path::Path;

pub use field::{read_displacement_field, read_displacement_field_bytes, write_displacement_field};
pub use header::{MAX_HEADER_BYTES, looks_like_metaimage};
pub(crate) use write::direction_spacing;
pub use write::{MetaImageWriteOptions, detached_data_file, write, write_with};

use crate::error::{Error, ErrorKind, Result};
use crate::options::LoadOptions;
use crate::volume::{GeometrySource, Metadata, Volume, check_allocation};
use data::FrameChoice;
use header::{parse_header, read_header_lines};

/// Reads the MetaImage file (`.mha`, or a `.mhd` header with its data file) at `path`.
pub fn read(path: &Path, opts: &mut LoadOptions) -> Result<Volume> {
    crate::files::read_header_file(path, |r, len, folder| read_from(path, r, len, Some(folder), opts))
}

/// Reads a MetaImage file held in memory; `name` is used in errors. A detached data file is refused.
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
    let h = parse_header(name, &lines)?;
    if h.channels != 1 {
        return Err(Error::unsupported(
            name,
            format!(
                "ElementNumberOfChannels = {}: a vector or colour image; only scalar volumes (one channel) are read \
                 as volumes (a 3-channel float image is read as a displacement field)",
                h.channels
            ),
        ));
    }
    let g = geometry::geometry(name, &h)?;
    let frame = match (g.frames, opts.frame) {
        (1, None) => 0,
        (frames, None) => return Err(Error::new(name, ErrorKind::FrameRequired { frames })),
        (frames, Some(t)) if t >= frames => {
            return Err(Error::invalid(name, format!("frame {t} of a file of {frames} frames (0 to {})", frames - 1)));
        }
        (_, Some(t)) => t,
    };
    let out_type = h.stored.unscaled();
    // The stored samples may be wider than the output (f64 → f32): both must fit under the limit.
    check_allocation(name, g.dims, h.stored.bytes(), opts.max_voxel_bytes)?;
    let n = check_allocation(name, g.dims, out_type.bytes(), opts.max_voxel_bytes)?;
    let f = FrameChoice { n, frame, frames: g.frames };

    let data = data::samples(name, r, total_len.saturating_sub(header_bytes), base_dir, &h, f, opts)?;

    let mut volume = Volume::new(name, g.dims, data, g.lps_from_index, GeometrySource::MetaImage)?;
    let warnings = std::mem::take(&mut volume.metadata.warnings);
    volume.metadata = Metadata { description: h.comment.clone(), warnings, ..Metadata::default() };
    Ok(volume)
}
