//! The MetaImage writer: SimpleITK's header, little-endian samples, `.mha` (data after the header) or `.mhd` with a
//! detached data file (see [`super`]).

use std::fmt::Write as _;
use std::io::Write;
use std::path::{Path, PathBuf};

use flate2::Compression;
use flate2::write::ZlibEncoder;

use crate::error::{Error, Result};
use crate::geometry::{Index, Lps, Transform};
use crate::volume::{SampleType, Volume};

/// Options for [`write_with`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MetaImageWriteOptions {
    /// Store the samples as one zlib stream (`CompressedData = True`). A `.mhd`'s data file is then named `.zraw`,
    /// as ITK names it, else `.raw`.
    pub compressed: bool,
}

impl MetaImageWriteOptions {
    /// What [`write()`] does for `path`: compressed for `.mha` (one small file), uncompressed for `.mhd` (whose
    /// detached `.raw` is there to be read as it is).
    #[must_use]
    pub fn for_path(path: &Path) -> Self {
        Self { compressed: !is_mhd(path) }
    }
}

fn is_mhd(path: &Path) -> bool {
    path.extension().is_some_and(|e| e.eq_ignore_ascii_case("mhd"))
}

/// The data file that [`write()`] writes beside `path`: `<stem>.raw` for a `.mhd`, none for a `.mha`. Callers that
/// refuse to overwrite a file check it as well as `path`.
#[must_use]
pub fn detached_data_file(path: &Path) -> Option<PathBuf> {
    let options = MetaImageWriteOptions::for_path(path);
    is_mhd(path).then(|| path.with_extension(if options.compressed { "zraw" } else { "raw" }))
}

/// Writes `volume` as MetaImage: `.mha` with zlib-compressed samples after the header, `.mhd` with an uncompressed
/// `.raw` beside it ([`MetaImageWriteOptions::for_path`]).
pub fn write(path: &Path, volume: &Volume) -> Result<()> {
    write_with(path, volume, MetaImageWriteOptions::for_path(path))
}

/// Writes `volume` as MetaImage at `path` (`.mha` or `.mhd`), compressed or not as `options` say. Each file is written
/// atomically; for `.mhd` the data file first, so that a header never names a data file that is not complete.
pub fn write_with(path: &Path, volume: &Volume, options: MetaImageWriteOptions) -> Result<()> {
    let n = crate::volume::checked_voxel_count(path, volume.dims)?;
    if volume.data.len() != n {
        return Err(Error::invalid(path, format!("{} samples for dims {:?}", volume.data.len(), volume.dims)));
    }
    if !volume.lps_from_index.is_valid_affine() {
        return Err(Error::invalid(path, "the voxel-to-patient matrix is singular or not finite"));
    }
    let element_type = match volume.sample_type() {
        SampleType::U8 => "MET_UCHAR",
        SampleType::I16 => "MET_SHORT",
        SampleType::U16 => "MET_USHORT",
        SampleType::F32 => "MET_FLOAT",
    };
    let samples =
        Samples { element_type, channels: 1, write_le: &|w| volume.data.try_for_each_le_chunk(|b| w.write_all(b)) };
    write_image(path, volume.dims, &volume.lps_from_index, &samples, options)
}

/// What follows a header: the `ElementType`, the samples a voxel (`ElementNumberOfChannels`, interleaved) and a
/// writer of all of them, little-endian, i fastest.
pub(super) struct Samples<'a> {
    pub(super) element_type: &'static str,
    pub(super) channels: usize,
    pub(super) write_le: &'a dyn Fn(&mut dyn Write) -> std::io::Result<()>,
}

/// Writes a header for the grid `dims`, `lps_from_index` and `samples` at `path` (`.mha`, or `.mhd` with its data
/// file), atomically, the data file first.
pub(super) fn write_image(
    path: &Path,
    dims: [usize; 3],
    lps_from_index: &Transform<Lps, Index>,
    samples: &Samples<'_>,
    options: MetaImageWriteOptions,
) -> Result<()> {
    let mhd = is_mhd(path);
    if !mhd && !path.extension().is_some_and(|e| e.eq_ignore_ascii_case("mha")) {
        return Err(Error::invalid(path, "a MetaImage file is named .mha (one file) or .mhd (with a data file)"));
    }
    let data_path = mhd.then(|| data_file_for(path, options.compressed)).transpose()?;
    let compressed = if options.compressed { Some(compress(path, samples.write_le)?) } else { None };
    let data_file = data_path.as_ref().map(|(_, name)| name.as_str());
    let header = header_text(dims, lps_from_index, samples, compressed.as_ref().map(Vec::len), data_file);
    let write_data = |w: &mut dyn Write| match &compressed {
        Some(bytes) => w.write_all(bytes),
        None => (samples.write_le)(w),
    };
    match &data_path {
        Some((data_path, _)) => {
            crate::write_atomic(data_path, write_data)?;
            crate::write_atomic(path, |w| w.write_all(header.as_bytes()))
        }
        None => crate::write_atomic(path, |w| {
            w.write_all(header.as_bytes())?;
            write_data(w)
        }),
    }
}

/// The data file of the header `path`: beside it, with its stem and `.raw` (or `.zraw` when compressed); its path and
/// the name the header gives it.
fn data_file_for(path: &Path, compressed: bool) -> Result<(PathBuf, String)> {
    let data_path = path.with_extension(if compressed { "zraw" } else { "raw" });
    let name = data_path
        .file_name()
        .and_then(|n| n.to_str())
        .filter(|n| !n.contains(['\n', '\r']))
        .ok_or_else(|| Error::invalid(path, "the data file's name must be UTF-8 text on one line"))?;
    Ok((data_path.clone(), name.to_owned()))
}

/// The samples, little-endian, as one zlib stream.
fn compress(path: &Path, write_le: &dyn Fn(&mut dyn Write) -> std::io::Result<()>) -> Result<Vec<u8>> {
    let mut z = ZlibEncoder::new(Vec::new(), Compression::default());
    write_le(&mut z).map_err(|e| Error::io(path, e))?;
    z.finish().map_err(|e| Error::io(path, e))
}

/// `q` with `fl(q · s) == x` when one of q = x / s and its two neighbours gives it, so that the reader's
/// `direction · spacing` is the volume's matrix entry bit for bit; else x / s.
#[allow(clippy::float_cmp, reason = "the product must equal x exactly, bit for bit")]
fn exact_quotient(x: f64, s: f64) -> f64 {
    let q = x / s;
    [q, q.next_up(), q.next_down()].into_iter().find(|c| c * s == x).unwrap_or(q)
}

/// The direction (columns of unit length) and spacing of `lps_from_index`'s linear part.
pub(crate) fn direction_spacing(lps_from_index: &Transform<Lps, Index>) -> ([[f64; 3]; 3], [f64; 3]) {
    let l = lps_from_index.linear();
    let spacing: [f64; 3] = std::array::from_fn(|c| l.column(c).norm());
    let columns = std::array::from_fn(|c| std::array::from_fn(|r| exact_quotient(l[(r, c)], spacing[c])));
    (columns, spacing)
}

/// ITK's `AnatomicalOrientation` of a direction (`SpatialOrientationAdapter::FromDirectionCosines`): for each index
/// axis, the patient axis its column is most along (by more than 0.001), named by where the index axis comes from
/// (L-to-R counted from R: +x is `R`, −x `L`, +y `A`, −y `P`, +z `I`, −z `S`); `None` when two axes get one letter.
fn anatomical_orientation(columns: &[[f64; 3]; 3]) -> Option<String> {
    let mut used = [false; 3];
    let mut code = String::new();
    for col in columns {
        let a = col.map(f64::abs);
        let dominant = if a[0] > 0.001 && a[0] > a[1] && a[0] > a[2] {
            0
        } else if a[1] > 0.001 && a[1] > a[0] && a[1] > a[2] {
            1
        } else if a[2] > 0.001 && a[2] > a[0] && a[2] > a[1] {
            2
        } else {
            0
        };
        if std::mem::replace(&mut used[dominant], true) {
            return None;
        }
        let letters = [['R', 'L'], ['A', 'P'], ['I', 'S']][dominant];
        code.push(letters[usize::from(col[dominant] < 0.0)]);
    }
    Some(code)
}

/// The header, its keys in SimpleITK's order (`ElementNumberOfChannels` only for several samples a voxel, as ITK
/// writes it).
fn header_text(
    dims: [usize; 3],
    lps_from_index: &Transform<Lps, Index>,
    samples: &Samples<'_>,
    compressed_size: Option<usize>,
    data_file: Option<&str>,
) -> String {
    let (columns, spacing) = direction_spacing(lps_from_index);
    let join = |v: &mut dyn Iterator<Item = f64>| v.map(|x| x.to_string()).collect::<Vec<_>>().join(" ");
    let [nx, ny, nz] = dims;
    let mut h = String::from("ObjectType = Image\nNDims = 3\nBinaryData = True\nBinaryDataByteOrderMSB = False\n");
    let _ = writeln!(h, "CompressedData = {}", if compressed_size.is_some() { "True" } else { "False" });
    if let Some(size) = compressed_size {
        let _ = writeln!(h, "CompressedDataSize = {size}");
    }
    let _ = writeln!(h, "TransformMatrix = {}", join(&mut columns.iter().flatten().copied()));
    let _ = writeln!(h, "Offset = {}", join(&mut lps_from_index.translation().into_iter()));
    h.push_str("CenterOfRotation = 0 0 0\n");
    if let Some(code) = anatomical_orientation(&columns) {
        let _ = writeln!(h, "AnatomicalOrientation = {code}");
    }
    let _ = writeln!(h, "ElementSpacing = {}", join(&mut spacing.into_iter()));
    let _ = writeln!(h, "DimSize = {nx} {ny} {nz}");
    if samples.channels != 1 {
        let _ = writeln!(h, "ElementNumberOfChannels = {}", samples.channels);
    }
    let _ = writeln!(h, "ElementType = {}", samples.element_type);
    let _ = writeln!(h, "ElementDataFile = {}", data_file.unwrap_or("LOCAL"));
    h
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn orientation_codes_are_itks() {
        let c = 0.8f64.cos();
        let s = 0.8f64.sin();
        // Columns of the direction (each the LPS direction of one index axis), as SimpleITK 2.5.7 names them.
        let cases: [([[f64; 3]; 3], Option<&str>); 6] = [
            ([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], Some("RAI")),
            ([[-1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, 1.0]], Some("LPI")),
            ([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]], Some("ARS")),
            ([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]], Some("AIR")),
            ([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]], Some("ALI")),
            ([[1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]], None),
        ];
        for (columns, want) in cases {
            assert_eq!(anatomical_orientation(&columns).as_deref(), want, "{columns:?}");
        }
    }

    #[test]
    fn quotients_are_chosen_so_that_the_product_is_exact() {
        for (x, s) in [(0.7, 3.0), (-1.234_567_891_234, 0.987_654_321), (2.5, 2.5), (1e-300, 7.0)] {
            let q = exact_quotient(x, s);
            assert!((q * s - x).abs() <= f64::EPSILON * x.abs(), "{x} / {s}");
        }
    }
}
