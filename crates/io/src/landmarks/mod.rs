//! Landmark pairs and their files: BigWarp CSV and JSON, Slicer `.mrk.json` and Slicer `.fcsv`, elastix point files,
//! transformix's `outputpoints.txt`, and the landmarks of an ITK or 3D Slicer thin-plate-spline transform file.
//!
//! A [`LandmarkPair`] joins a point on the **moving** volume (the source of the warp) to the
//! matching point on the **fixed** volume (the target), both in LPS mm. Either half may be
//! missing while a user is still placing points; [`complete_active_pairs`] returns what a solver
//! can use.
//!
//! # Formats
//!
//! - **BigWarp CSV** (BigWarp `LandmarkTableModel`, written with opencsv): no header, one row per
//!   pair, `Name, Active, mvg-x, mvg-y, mvg-z, fix-x, fix-y, fix-z` — the moving point comes
//!   first. Fields are quoted (`"Pt-0","true","1.0",…`); a missing half is written as `Infinity`
//!   in all three of its columns. 2-D files (6 columns) are refused. BigWarp coordinates are
//!   "world units" with no patient orientation: **we read them as LPS mm** unless
//!   [`BigWarpCsvOptions::ras`] says they are RAS. [`read_bigwarp_csv`], [`write_bigwarp_csv`].
//! - **BigWarp JSON** (BigWarp 9, `LandmarkTableModel.toJson`): `{"type": "BigWarpLandmarks",
//!   "numDimensions": 3, "movingPoints": [[x, y, z], …], "fixedPoints": […], "active": […],
//!   "names": […]}`, alone, under `landmarks` (BigWarp's *Save landmarks* to `.json`) or under
//!   `Transform` → `landmarks` (its settings file); a missing half is a bare `Infinity` ×3, as Gson
//!   writes it. The same world coordinates as the CSV, read the same way, so a CSV and a JSON of
//!   the same table read to the same pairs. [`read_bigwarp_json`], [`write_bigwarp_json`].
//! - **Slicer `.mrk.json`** (markups schema v1, `Modules/Loadable/Markups/Resources/Schema`):
//!   the first markup of type `Fiducial`; `coordinateSystem` `LPS` (the schema's default when
//!   absent, as Slicer reads it) or `RAS`; `coordinateUnits` `mm` (default) or `um` (converted to
//!   mm), as a string or a UCUM code triple (`["um", "UCUM", "micrometer"]`); `controlPoints[]` with
//!   `position`, `label`, `selected` and `positionStatus` — only `defined` points have a
//!   position, `undefined` and `preview` points are missing. [`read_mrk_json`], [`write_mrk_json`].
//! - **Slicer `.fcsv`** (legacy, Slicer `Docs/developer_guide/modules/markups.md`): `#` header
//!   lines `# Markups fiducial file version = 4.11`, `# CoordinateSystem = LPS | RAS | 0 | 1`
//!   (0 = RAS, 1 = LPS), `# columns = id,x,y,z,…`; or a Slicer 3 file (no version line, RAS,
//!   `# columns = label,x,y,z,sel,vis`). The header decides the coordinate system as Slicer does,
//!   and a file whose coordinate system cannot be determined is refused: the table is in
//!   [`parse_fcsv`]. The columns line locates x, y, z, sel and label (other columns are ignored,
//!   except the `positionStatus` that Slicer 5 appends). [`read_fcsv`], [`write_fcsv`].
//! - **elastix point files** (`point` or `index`, the count, then `x y z` a line): the point sets of elastix's
//!   `CorrespondingPointsEuclideanDistanceMetric` and of transformix. `point` rows are ITK physical coordinates, LPS
//!   mm; `index` rows are voxel indices of an image, read and written only through that image's geometry.
//!   [`read_elastix_points`], [`write_elastix_points`], [`ElastixPoints`].
//! - **MNI tag point files** (`.tag`, MINC's `register` and `tagtoxfm`): `Volumes = 2;`, then `Points =` and one
//!   `x1 y1 z1 x2 y2 z2 "label"` entry a pair, RAS mm, **volume 1 the fixed points and volume 2 the moving ones**
//!   (`register` warps volume 2 onto volume 1). [`read_mni_tag`], [`write_mni_tag`].
//! - **transformix's `outputpoints.txt`**: one `Point N ; InputIndex = […] ; InputPoint = […] ; … ; OutputPoint =
//!   […]` line a point; read as pairs, `InputPoint` the fixed point and `OutputPoint` the moving one
//!   ([`read_transformix_output`]).
//!
//! [`read_landmark_pairs`] reads one file of pairs (BigWarp CSV or JSON, plain CSV, an MNI tag file, transformix's output, a
//! thin-plate-spline transform file, [`parse_spline_file`]), telling them apart by content ([`detect_landmark_format`]), and refuses a Slicer list or an elastix point file (one side)
//! or an unknown JSON with what it expected; [`write_landmark_pairs`] writes BigWarp JSON for `.json`, CSV otherwise.
//!
//! A Slicer file, like an elastix point file, holds **one side**: [`read_slicer_pair`] reads a moving and a fixed
//! list (either kind each) and pairs them by index (Slicer's Fiducial Registration Wizard and Landmark Registration
//! do the same, and elastix's metric pairs its fixed and moving point sets so); the pair is active when both points
//! are selected. [`write_slicer_pair`] writes both, a `.txt` name as an elastix `point` file.
//!
//! # Conventions
//!
//! Every reader accepts one leading UTF-8 byte-order mark (each `parse_*` function strips it).
//!
//! Points are stored in LPS; RAS files are converted at I/O (negate x and y). NaN coordinates are
//! refused with [`ErrorKind::Landmark`](crate::ErrorKind::Landmark), whose index is **1-based** (the
//! n-th landmark in the file); the message also gives the landmark's name and, for text formats, its
//! line. Writers go through [`crate::write_atomic`] and print coordinates with Rust's shortest
//! round-trip formatting, so a write/read round trip is exact.
//!
//! # Modules
//! One module per format: `bigwarp_csv`, `bigwarp_json`, `mrk_json`, `fcsv`, `plain_csv`, `point_list`, `mni_tag`,
//! `elastix_points` (elastix's point files and transformix's result), and `slicer_pair`, which pairs two one-side
//! lists. What they share lives in leaves beside them: `points` (the point
//! types), `text` (a file's bounded text, the byte-order mark, numbers), `errors`, and `detect` (which format a
//! text is). This module re-exports them and reads or writes one file of pairs in whichever format it is.

use std::path::Path;

use crate::error::Result;

mod bigwarp_csv;
mod bigwarp_json;
mod detect;
mod elastix_points;
mod errors;
mod fcsv;
mod itk_tps;
mod mni_tag;
mod mrk_json;
mod plain_csv;
mod point_list;
mod points;
mod slicer_pair;
mod text;

pub use bigwarp_csv::{
    BigWarpCsvOptions, parse_bigwarp_csv, read_bigwarp_csv, read_bigwarp_csv_with, to_bigwarp_csv, write_bigwarp_csv,
    write_bigwarp_csv_with,
};
pub use bigwarp_json::{
    BIGWARP_LANDMARKS_TYPE, parse_bigwarp_json, read_bigwarp_json, read_bigwarp_json_with, to_bigwarp_json,
    write_bigwarp_json, write_bigwarp_json_with,
};
pub use detect::{LandmarkFileFormat, detect_landmark_file, detect_landmark_format};
pub use elastix_points::{
    ElastixPointKind, ElastixPoints, TransformixPoint, looks_like_elastix_points, looks_like_transformix_output,
    parse_elastix_points, parse_transformix_output, read_elastix_points, read_transformix_output, to_elastix_points,
    transformix_pairs, write_elastix_points,
};
pub use fcsv::{parse_fcsv, read_fcsv, to_fcsv, write_fcsv};
pub use itk_tps::{SplineFileClass, parse_spline_file};
pub use mni_tag::{looks_like_mni_tag, parse_mni_tag, parse_mni_tag_points, read_mni_tag, to_mni_tag, write_mni_tag};
pub use mrk_json::{MARKUPS_SCHEMA, parse_mrk_json, read_mrk_json, to_mrk_json, write_mrk_json};
pub use plain_csv::{
    CsvCoordinates, looks_like_plain_csv, parse_plain_csv, plain_csv_header, read_plain_csv, to_plain_csv,
    write_plain_csv,
};
pub use point_list::{
    ListedPoint, PointColumn, PointFile, PointFileFormat, PointFileOptions, PointList, SlicerList, detect_point_format,
    parse_point_file, parse_point_list, read_point_file, read_point_list, to_point_list, write_point_file,
    write_point_list,
};
pub use points::{LandmarkPair, SlicerPoint, complete_active_pairs};
pub use slicer_pair::{read_slicer_pair, read_slicer_points, write_slicer_pair};
pub use text::MAX_LANDMARK_FILE_BYTES;

use errors::{elastix_one_side, slicer_one_side};
use text::{read_bytes, utf8};

/// Reads one file of landmark pairs, BigWarp CSV, BigWarp JSON, plain CSV, transformix's `outputpoints.txt` or an ITK
/// or 3D Slicer thin-plate-spline transform file (`.tfm` text or `.h5`), told apart by content; LPS mm.
///
/// A Slicer point list (`.mrk.json`, `.fcsv`) or an elastix point file holds the points of one volume only, and is
/// refused here with a message that says so: read it with its partner through [`read_slicer_pair`].
pub fn read_landmark_pairs(path: &Path) -> Result<Vec<LandmarkPair>> {
    read_landmark_pairs_with(path, BigWarpCsvOptions::default())
}

/// [`read_landmark_pairs`] with `options` for the BigWarp formats (a plain CSV's header states its own coordinate
/// system).
pub fn read_landmark_pairs_with(path: &Path, options: BigWarpCsvOptions) -> Result<Vec<LandmarkPair>> {
    let bytes = read_bytes(path)?;
    if crate::itk_h5::looks_like_hdf5(&bytes) {
        return parse_spline_file(path, bytes);
    }
    let text = utf8(path, bytes)?;
    match detect_landmark_format(path, &text)? {
        LandmarkFileFormat::ItkThinPlateSpline => itk_tps::tfm_pairs(path, &text),
        LandmarkFileFormat::BigWarpCsv => parse_bigwarp_csv(path, &text, options),
        LandmarkFileFormat::BigWarpJson => parse_bigwarp_json(path, &text, options),
        LandmarkFileFormat::PlainCsv => parse_plain_csv(path, &text).map(|(pairs, _)| pairs),
        LandmarkFileFormat::TransformixOutput => transformix_pairs(path, &text),
        LandmarkFileFormat::MniTag => parse_mni_tag(path, &text),
        LandmarkFileFormat::SlicerMarkupsJson | LandmarkFileFormat::SlicerFcsv => Err(slicer_one_side(path)),
        LandmarkFileFormat::ElastixPoints => Err(elastix_one_side(path)),
    }
}

/// Writes `pairs` to one file: BigWarp JSON for a `.json` name, an MNI tag file for `.tag`, BigWarp CSV otherwise. A Slicer name (`.mrk.json`,
/// `.fcsv`) is refused, since a Slicer list holds one side: use [`write_slicer_pair`].
pub fn write_landmark_pairs(path: &Path, pairs: &[LandmarkPair]) -> Result<()> {
    let lower = path.file_name().map(|n| n.to_string_lossy().to_ascii_lowercase()).unwrap_or_default();
    let has = |ext: &str| Path::new(&lower).extension().is_some_and(|e| e == ext);
    if lower.ends_with(".mrk.json") || has("fcsv") {
        Err(slicer_one_side(path))
    } else if has("json") {
        write_bigwarp_json(path, pairs)
    } else if has("tag") {
        write_mni_tag(path, pairs)
    } else {
        write_bigwarp_csv(path, pairs)
    }
}
