//! Landmark pairs and their files: BigWarp CSV and JSON, Slicer `.mrk.json` and Slicer `.fcsv`.
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
//!
//! [`read_landmark_pairs`] reads one file of pairs, telling BigWarp CSV from BigWarp JSON by
//! content ([`detect_landmark_format`]), and refuses a Slicer list (one side) or an unknown JSON
//! with what it expected; [`write_landmark_pairs`] writes BigWarp JSON for `.json`, CSV otherwise.
//!
//! A Slicer file holds **one side**: [`read_slicer_pair`] reads a moving and a fixed list and
//! pairs them by index (Slicer's Fiducial Registration Wizard and Landmark Registration do the
//! same); the pair is active when both points are selected. [`write_slicer_pair`] writes both.
//!
//! # Conventions
//!
//! Every reader accepts one leading UTF-8 byte-order mark (each `parse_*` function strips it).
//!
//! Points are stored in LPS; RAS files are converted at I/O (negate x and y). NaN coordinates are
//! refused with [`ErrorKind::Landmark`], whose index is **1-based** (the n-th landmark in the
//! file); the message also gives the landmark's name and, for text formats, its line. Writers go
//! through [`crate::write_atomic`] and print coordinates with Rust's shortest round-trip
//! formatting, so a write/read round trip is exact.

use std::path::Path;

use bigwarp_json::{bigwarp_table, not_bigwarp, parse_gson_json};

use crate::error::{Error, ErrorKind, Result};
use crate::geometry::{Lps, Point3};

mod bigwarp_csv;
mod bigwarp_json;
mod fcsv;
mod mrk_json;
mod plain_csv;
mod point_list;
mod slicer_pair;

pub use bigwarp_csv::{
    BigWarpCsvOptions, parse_bigwarp_csv, read_bigwarp_csv, read_bigwarp_csv_with, to_bigwarp_csv, write_bigwarp_csv,
    write_bigwarp_csv_with,
};
pub use bigwarp_json::{
    BIGWARP_LANDMARKS_TYPE, parse_bigwarp_json, read_bigwarp_json, read_bigwarp_json_with, to_bigwarp_json,
    write_bigwarp_json, write_bigwarp_json_with,
};
pub use fcsv::{parse_fcsv, read_fcsv, to_fcsv, write_fcsv};
pub use mrk_json::{parse_mrk_json, read_mrk_json, to_mrk_json, write_mrk_json};
pub use plain_csv::{
    CsvCoordinates, looks_like_plain_csv, parse_plain_csv, plain_csv_header, read_plain_csv, to_plain_csv,
    write_plain_csv,
};
pub use point_list::{
    ListedPoint, PointColumn, PointFile, PointFileFormat, PointFileOptions, PointList, SlicerList, detect_point_format,
    parse_point_file, parse_point_list, read_point_file, read_point_list, to_point_list, write_point_file,
    write_point_list,
};
pub use slicer_pair::{read_slicer_pair, read_slicer_points, write_slicer_pair};

/// The schema URL written into `.mrk.json` files.
pub const MARKUPS_SCHEMA: &str = "https://raw.githubusercontent.com/slicer/slicer/master/Modules/Loadable/Markups/Resources/Schema/markups-schema-v1.0.3.json#";

/// One landmark pair: a point on the moving volume and its match on the fixed volume.
#[derive(Clone, Debug, PartialEq)]
pub struct LandmarkPair {
    /// Free text; may be empty or repeated.
    pub name: String,
    /// Whether the pair takes part in the warp (BigWarp "Active", Slicer "selected").
    pub active: bool,
    /// The point on the moving (source) volume, or `None` when not placed yet.
    pub moving: Option<Point3<Lps>>,
    /// The point on the fixed (target) volume, or `None` when not placed yet.
    pub fixed: Option<Point3<Lps>>,
}

impl LandmarkPair {
    /// An active pair with both halves.
    #[must_use]
    pub fn new(name: impl Into<String>, moving: Point3<Lps>, fixed: Point3<Lps>) -> Self {
        Self { name: name.into(), active: true, moving: Some(moving), fixed: Some(fixed) }
    }

    /// True when both halves are placed.
    #[must_use]
    pub fn is_complete(&self) -> bool {
        self.moving.is_some() && self.fixed.is_some()
    }
}

/// The moving and fixed points of the active pairs that have both halves, in file order.
#[must_use]
pub fn complete_active_pairs(pairs: &[LandmarkPair]) -> (Vec<Point3<Lps>>, Vec<Point3<Lps>>) {
    pairs.iter().filter(|p| p.active).filter_map(|p| Some((p.moving?, p.fixed?))).unzip()
}

/// One Slicer control point (one side of a pair).
#[derive(Clone, Debug, PartialEq)]
pub struct SlicerPoint {
    pub label: String,
    pub selected: bool,
    /// `None` for a point whose position is not defined (`positionStatus` other than `defined`).
    pub position: Option<Point3<Lps>>,
}

/// The most characters of a landmark's name that a message quotes; a longer name is cut with `…`.
const MESSAGE_NAME_CHARS: usize = 60;

fn landmark_error(path: &Path, index0: usize, name: &str, line: Option<u64>, problem: impl AsRef<str>) -> Error {
    let at = line.map(|l| format!(", line {l}")).unwrap_or_default();
    let cut;
    let name = match name.char_indices().nth(MESSAGE_NAME_CHARS) {
        Some((end, _)) => {
            cut = format!("{}…", &name[..end]);
            cut.as_str()
        }
        None => name,
    };
    Error::new(
        path,
        ErrorKind::Landmark { index: index0 + 1, problem: format!("(1-based, {name:?}{at}) {}", problem.as_ref()) },
    )
}

/// The largest landmark file read, in bytes. BigWarp and Slicer files hold at most thousands of points (5 000
/// pairs, the TPS limit, are about 1 MB of CSV), so a larger file is refused before it is read into memory.
pub const MAX_LANDMARK_FILE_BYTES: u64 = 256 << 20;

/// The text of the landmark file at `path`: a regular file (a named pipe would block, a device never end) of at
/// most [`MAX_LANDMARK_FILE_BYTES`], checked before it is opened and bounded while it is read.
fn read_text(path: &Path) -> Result<String> {
    let too_big = |bytes: u64| {
        Error::invalid(
            path,
            format!(
                "the file has {bytes} bytes, more than the {MAX_LANDMARK_FILE_BYTES} bytes a landmark file may have"
            ),
        )
    };
    let meta = crate::files::check_regular_file(path)?;
    if meta.len() > MAX_LANDMARK_FILE_BYTES {
        return Err(too_big(meta.len()));
    }
    let file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let mut bytes = Vec::new();
    std::io::Read::read_to_end(&mut std::io::Read::take(file, MAX_LANDMARK_FILE_BYTES + 1), &mut bytes)
        .map_err(|e| Error::io(path, e))?;
    if bytes.len() as u64 > MAX_LANDMARK_FILE_BYTES {
        return Err(too_big(bytes.len() as u64));
    }
    String::from_utf8(bytes).map_err(|e| Error::invalid(path, format!("not UTF-8 text: {e}")))
}

/// `text` without one leading UTF-8 byte-order mark (U+FEFF), which Windows editors write and Slicer, BigWarp and
/// spreadsheet programs accept. Every `parse_*` function of this module starts here, so every reader (file or text)
/// accepts it; a second mark is content.
fn strip_bom(text: &str) -> &str {
    text.strip_prefix('\u{feff}').unwrap_or(text)
}

/// Shortest text that parses back to the same f64 (`1.0`, `-0.5`, `1e-7`).
fn num(x: f64) -> String {
    format!("{x:?}")
}

fn flip_xy(p: Point3<Lps>) -> Point3<Lps> {
    let [x, y, z] = p.coords();
    Point3::new(-x, -y, z)
}

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
    /// A plain CSV with a header naming its columns and coordinate system ([`read_plain_csv`]): pairs.
    PlainCsv,
}

impl LandmarkFileFormat {
    /// Whether the file holds pairs (BigWarp) rather than one side (Slicer).
    #[must_use]
    pub fn holds_pairs(self) -> bool {
        matches!(self, Self::BigWarpCsv | Self::BigWarpJson | Self::PlainCsv)
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
        }
    }
}

/// Tells the landmark format of `text` by its content, not its name: JSON (after one BOM and white space, an
/// `{` or `[`) is BigWarp when it holds a BigWarp landmark table (see [`parse_bigwarp_json`]), Slicer when it has
/// a `markups` list, and refused otherwise with what was expected; text whose first line starts with `#` is a
/// Slicer `.fcsv`, and text whose first line's first field is an unquoted `name` a plain CSV (BigWarp's CSV quotes
/// every field, so its lines start with `"`); anything else is BigWarp CSV.
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
    if body.starts_with('#') {
        return Ok(LandmarkFileFormat::SlicerFcsv);
    }
    if looks_like_plain_csv(body) {
        return Ok(LandmarkFileFormat::PlainCsv);
    }
    Ok(LandmarkFileFormat::BigWarpCsv)
}

/// [`detect_landmark_format`] of the file at `path`.
pub fn detect_landmark_file(path: &Path) -> Result<LandmarkFileFormat> {
    detect_landmark_format(path, &read_text(path)?)
}

/// Reads one file of landmark pairs, BigWarp CSV, BigWarp JSON or plain CSV, told apart by content; LPS mm.
///
/// A Slicer point list (`.mrk.json`, `.fcsv`) holds the points of one volume only, and is refused here with a
/// message that says so: read it with its partner through [`read_slicer_pair`].
pub fn read_landmark_pairs(path: &Path) -> Result<Vec<LandmarkPair>> {
    read_landmark_pairs_with(path, BigWarpCsvOptions::default())
}

/// [`read_landmark_pairs`] with `options` for the BigWarp formats (a plain CSV's header states its own coordinate
/// system).
pub fn read_landmark_pairs_with(path: &Path, options: BigWarpCsvOptions) -> Result<Vec<LandmarkPair>> {
    let text = read_text(path)?;
    match detect_landmark_format(path, &text)? {
        LandmarkFileFormat::BigWarpCsv => parse_bigwarp_csv(path, &text, options),
        LandmarkFileFormat::BigWarpJson => parse_bigwarp_json(path, &text, options),
        LandmarkFileFormat::PlainCsv => parse_plain_csv(path, &text).map(|(pairs, _)| pairs),
        LandmarkFileFormat::SlicerMarkupsJson | LandmarkFileFormat::SlicerFcsv => Err(slicer_one_side(path)),
    }
}

fn slicer_one_side(path: &Path) -> Error {
    Error::unsupported(
        path,
        "a Slicer point list holds one side of the pairs (the points of one volume); give it together with the \
         list of the other volume, which is paired with it by order",
    )
}

/// Writes `pairs` to one file: BigWarp JSON for a `.json` name, BigWarp CSV otherwise. A Slicer name (`.mrk.json`,
/// `.fcsv`) is refused, since a Slicer list holds one side: use [`write_slicer_pair`].
pub fn write_landmark_pairs(path: &Path, pairs: &[LandmarkPair]) -> Result<()> {
    let lower = path.file_name().map(|n| n.to_string_lossy().to_ascii_lowercase()).unwrap_or_default();
    let has = |ext: &str| Path::new(&lower).extension().is_some_and(|e| e == ext);
    if lower.ends_with(".mrk.json") || has("fcsv") {
        Err(slicer_one_side(path))
    } else if has("json") {
        write_bigwarp_json(path, pairs)
    } else {
        write_bigwarp_csv(path, pairs)
    }
}

/// The error for a BigWarp file read as a Slicer point list.
fn bigwarp_not_slicer(path: &Path) -> Error {
    Error::unsupported(
        path,
        "a BigWarp landmarks file (pairs of points), not a Slicer point list: read it as a file of pairs",
    )
}
