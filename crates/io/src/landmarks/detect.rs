//! Which kind of landmark file a text is, told by its content ([`detect_landmark_format`]).

use std::path::Path;

use super::bigwarp_json::{bigwarp_table, not_bigwarp, parse_gson_json};
use super::elastix_points::{looks_like_elastix_points, looks_like_transformix_output};
use super::itk_tps::looks_like_tfm;
use super::mni_tag::looks_like_mni_tag;
use super::plain_csv::looks_like_plain_csv;
use super::text::{read_bytes, strip_bom, utf8};
use crate::error::Result;
use crate::itk_h5::looks_like_hdf5;

/// The kinds of landmark file, as [`detect_landmark_format`] tells them apart.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LandmarkFileFormat {
    /// BigWarp CSV: pairs.
    BigWarpCsv,
    /// BigWarp JSON (alone, under `landmarks`, or in a settings file): pairs.
    BigWarpJson,
    /// A Slicer `.mrk.json`: the points of one volume.
    SlicerMarkupsJson,
    /// A Slicer `.fcsv`: the points of one volume.
    SlicerFcsv,
    /// A plain CSV with a header naming its columns and coordinate system
    /// ([`read_plain_csv`](super::read_plain_csv)): pairs.
    PlainCsv,
    /// An elastix point file (`point` or `index`, the count, the points): the points of one image.
    ElastixPoints,
    /// transformix's `outputpoints.txt`: pairs (each input point, on the fixed image, and its image on the moving one).
    TransformixOutput,
    /// An MNI tag point file (`.tag`): pairs when it has two volumes.
    MniTag,
    /// An ITK or 3D Slicer thin-plate-spline transform file (`.tfm` text or `.h5`): pairs, its landmarks
    /// ([`parse_spline_file`](super::parse_spline_file)).
    ItkThinPlateSpline,
}

impl LandmarkFileFormat {
    /// Whether the file holds pairs (BigWarp) rather than one side (Slicer).
    #[must_use]
    pub fn holds_pairs(self) -> bool {
        matches!(
            self,
            Self::BigWarpCsv
                | Self::BigWarpJson
                | Self::PlainCsv
                | Self::TransformixOutput
                | Self::ItkThinPlateSpline
                | Self::MniTag
        )
    }

    /// The format's name in messages and in `warpbench landmarks --json`.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Self::BigWarpCsv => "bigwarp-csv",
            Self::BigWarpJson => "bigwarp-json",
            Self::SlicerMarkupsJson => "slicer-mrk-json",
            Self::SlicerFcsv => "slicer-fcsv",
            Self::PlainCsv => "plain-csv",
            Self::ElastixPoints => "elastix-points",
            Self::TransformixOutput => "transformix-output",
            Self::ItkThinPlateSpline => "itk-tps",
            Self::MniTag => "mni-tag",
        }
    }
}

/// Tells the landmark format of `text` by its content, not its name: JSON (after one BOM and white space, an
/// `{` or `[`) is BigWarp when it holds a BigWarp landmark table (see
/// [`parse_bigwarp_json`](super::parse_bigwarp_json)), Slicer when it has a `markups` list, and refused otherwise
/// with what was expected; text whose first line is `#Insight Transform File V1.0` is an ITK transform file (a
/// thin-plate spline's landmarks), text that starts `MNI Tag Point File` an MNI tag file, other text whose first line starts with `#` a Slicer `.fcsv`, and text whose
/// first line's first field is an unquoted `name` a plain CSV (BigWarp's CSV quotes every field, so its lines start
/// with `"`); text whose first word is `point` or `index` (or whose first line is a lone count) an elastix point
/// file, and text whose first line is transformix's `Point 0 ; … ; OutputPoint = […]` its `outputpoints.txt`;
/// anything else is BigWarp CSV.
pub fn detect_landmark_format(name: &Path, text: &str) -> Result<LandmarkFileFormat> {
    let body = strip_bom(text).trim_start();
    if body.starts_with(['{', '[']) {
        let root = parse_gson_json(name, body)?;
        return if bigwarp_table(&root).is_some() {
            Ok(LandmarkFileFormat::BigWarpJson)
        } else if root.get("markups").is_some() {
            Ok(LandmarkFileFormat::SlicerMarkupsJson)
        } else {
            Err(not_bigwarp(name, &root))
        };
    }
    if looks_like_tfm(body) {
        return Ok(LandmarkFileFormat::ItkThinPlateSpline);
    }
    if looks_like_mni_tag(body) {
        return Ok(LandmarkFileFormat::MniTag);
    }
    if body.starts_with('#') {
        return Ok(LandmarkFileFormat::SlicerFcsv);
    }
    if looks_like_transformix_output(body) {
        return Ok(LandmarkFileFormat::TransformixOutput);
    }
    if looks_like_elastix_points(body) {
        return Ok(LandmarkFileFormat::ElastixPoints);
    }
    if looks_like_plain_csv(body) {
        return Ok(LandmarkFileFormat::PlainCsv);
    }
    Ok(LandmarkFileFormat::BigWarpCsv)
}

/// [`detect_landmark_format`] of the file at `path`; an HDF5 file is an ITK transform file (`.h5`).
pub fn detect_landmark_file(path: &Path) -> Result<LandmarkFileFormat> {
    let bytes = read_bytes(path)?;
    if looks_like_hdf5(&bytes) {
        return Ok(LandmarkFileFormat::ItkThinPlateSpline);
    }
    detect_landmark_format(path, &utf8(path, bytes)?)
}
