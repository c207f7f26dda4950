//! Point files: the plain CSV point list (`x,y,z[,name]`), and every landmark format read as a list of points to be
//! moved and written back in its own format ([`read_point_file`], [`write_point_file`]), as `warpbench points` does.
//!
//! # The plain CSV point list
//!
//! - UTF-8 text (one leading byte-order mark allowed), one point a line, fields separated by `,`; a field may be
//!   quoted with `"` (a quote inside doubled, as in RFC 4180, but a quoted field stays on its line); spaces around
//!   a field are not part of it. Blank lines are skipped (and counted in the line numbers of messages); there are
//!   no comment lines.
//! - **Header**: the first non-blank line is a header exactly when its first field is not a number. A header names
//!   every column: `x`, `y` and `z` once each and optionally `name` once (any order, any case), nothing else.
//! - Without a header, 3 fields are `x,y,z` and 4 fields are `x,y,z,name`.
//! - Every point line has as many fields as the header (or the first line). Coordinates are finite numbers, mm,
//!   **LPS** unless the caller says RAS ([`PointFileOptions::ras`]: x and y negated on read and write).
//! - Written back with the same columns in the same order, the header (as it was spelled) only if there was one, and
//!   coordinates in Rust's shortest round-trip form, so a read/write round trip is exact.
//!
//! A CSV is a point list when its first non-blank line has 3 or 4 fields; with 8 (or 6) it is a BigWarp CSV of
//! pairs; anything else is refused with its line ([`detect_point_format`]).
//!
//! # Landmark files as point files
//!
//! - BigWarp CSV and JSON hold pairs ([`PointFile::BigWarp`]): the caller reads one side and replaces the other.
//!   They are written back with [`write_bigwarp_csv_with`] / [`write_bigwarp_json_with`] (a BigWarp settings file
//!   is written back as a plain landmarks file: `{"landmarks": {…}}`).
//! - Slicer `.mrk.json` and `.fcsv` ([`PointFile::Slicer`]) are written back as the file was, with only the
//!   positions of the points that had one replaced, in the file's own coordinate system (and, for `.mrk.json`, its
//!   units): every other field, the header and the line endings are kept. (`.mrk.json` is re-serialised: its keys
//!   come out in alphabetical order.)
//! - elastix point files ([`PointFile::Elastix`]) keep their rows as the file holds them, `point` (LPS mm) or `index`
//!   (voxel indices of an image, which the caller converts through that image: [`ElastixPoints::to_lps`],
//!   [`ElastixPoints::set_lps`]), and are written back with the same word.

use std::path::Path;

use serde_json::Value;

use super::bigwarp_csv::{BigWarpCsvOptions, axis, parse_bigwarp_csv, write_bigwarp_csv_with};
use super::bigwarp_json::{parse_bigwarp_json, write_bigwarp_json_with};
use super::detect::{LandmarkFileFormat, detect_landmark_format};
use super::elastix_points::{ElastixPoints, looks_like_transformix_output, parse_elastix_points, to_elastix_points};
use super::errors::landmark_error;
use super::fcsv::parse_fcsv;
use super::mrk_json::parse_mrk_json;
use super::points::{LandmarkPair, SlicerPoint, flip_xy};
use super::text::{num, read_text, strip_bom};
use crate::error::{Error, Result};
use crate::geometry::{Lps, Point3};

/// How plain CSV point lists and BigWarp files are read and written.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PointFileOptions {
    /// The file's coordinates are RAS (x and y negated on read and write). Default: LPS. A Slicer file says its
    /// coordinate system itself, and is refused with this option.
    pub ras: bool,
}

/// One column of a plain CSV point list.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PointColumn {
    X,
    Y,
    Z,
    Name,
}

/// One point of a plain CSV point list.
#[derive(Clone, Debug, PartialEq)]
pub struct ListedPoint {
    /// The `name` field; empty when the list has no name column.
    pub name: String,
    pub position: Point3<Lps>,
    /// The 1-based line the point was read from (0 for a point made in memory).
    pub line: u64,
}

/// A plain CSV point list: its layout and its points.
#[derive(Clone, Debug, PartialEq)]
pub struct PointList {
    /// The columns, in file order.
    pub columns: Vec<PointColumn>,
    /// The header's fields as spelled in the file, or `None` when it had no header.
    pub header: Option<Vec<String>>,
    pub points: Vec<ListedPoint>,
}

/// The formats [`read_point_file`] reads.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PointFileFormat {
    /// The plain CSV point list (module docs).
    PointList,
    /// BigWarp CSV: pairs.
    BigWarpCsv,
    /// BigWarp JSON: pairs.
    BigWarpJson,
    /// Slicer `.mrk.json`: one list of points.
    SlicerMarkupsJson,
    /// Slicer `.fcsv`: one list of points.
    SlicerFcsv,
    /// An elastix point file (`point` or `index`): one list of points.
    ElastixPoints,
}

impl PointFileFormat {
    /// A short name for messages and reports: `point-list`, `bigwarp-csv`, `bigwarp-json`, `slicer-mrk-json`,
    /// `slicer-fcsv`, `elastix-points`.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Self::PointList => "point-list",
            Self::BigWarpCsv => "bigwarp-csv",
            Self::BigWarpJson => "bigwarp-json",
            Self::SlicerMarkupsJson => "slicer-mrk-json",
            Self::SlicerFcsv => "slicer-fcsv",
            Self::ElastixPoints => "elastix-points",
        }
    }

    /// The format a file name says, by its ending: `.mrk.json`, `.fcsv`, `.json` (BigWarp JSON), `.csv` (a plain
    /// point list or a BigWarp CSV, which share it), `.txt` (an elastix point file); `None` for any other name.
    #[must_use]
    #[allow(clippy::case_sensitive_file_extension_comparisons, reason = "the name is lowercased first")]
    pub fn named_by(path: &Path) -> Option<&'static [Self]> {
        let lower = path.file_name()?.to_string_lossy().to_ascii_lowercase();
        if lower.ends_with(".mrk.json") {
            Some(&[Self::SlicerMarkupsJson])
        } else if lower.ends_with(".fcsv") {
            Some(&[Self::SlicerFcsv])
        } else if lower.ends_with(".json") {
            Some(&[Self::BigWarpJson])
        } else if lower.ends_with(".csv") {
            Some(&[Self::PointList, Self::BigWarpCsv])
        } else if lower.ends_with(".txt") {
            Some(&[Self::ElastixPoints])
        } else {
            None
        }
    }
}

/// A Slicer point list as read, kept whole so that it can be written back with new positions.
#[derive(Clone, Debug, PartialEq)]
pub struct SlicerList {
    /// [`PointFileFormat::SlicerMarkupsJson`] or [`PointFileFormat::SlicerFcsv`].
    pub format: PointFileFormat,
    /// The points, LPS mm; replace the positions, keep the count and which ones have a position.
    pub points: Vec<SlicerPoint>,
    /// Whether the file's coordinates are RAS (from its header), which the written file keeps.
    pub ras: bool,
    /// The file's text (without a byte-order mark), which [`write_point_file`] rewrites.
    text: String,
    /// Whether the file began with a byte-order mark, which the written file keeps.
    bom: bool,
}

/// What a point file holds ([`read_point_file`]).
#[derive(Clone, Debug, PartialEq)]
pub enum PointFile {
    /// A plain CSV point list.
    List(PointList),
    /// A BigWarp CSV or JSON file of pairs.
    BigWarp { format: PointFileFormat, pairs: Vec<LandmarkPair> },
    /// A Slicer `.mrk.json` or `.fcsv`.
    Slicer(SlicerList),
    /// An elastix point file.
    Elastix(ElastixPoints),
}

impl PointFile {
    /// The file's format.
    #[must_use]
    pub fn format(&self) -> PointFileFormat {
        match self {
            Self::List(_) => PointFileFormat::PointList,
            Self::BigWarp { format, .. } => *format,
            Self::Slicer(list) => list.format,
            Self::Elastix(_) => PointFileFormat::ElastixPoints,
        }
    }
}

/// Tells the format of a point file by its content, not its name: JSON is a BigWarp or a Slicer file as
/// [`detect_landmark_format`] tells them; text whose first line starts with `#` is a Slicer `.fcsv`; other text is
/// CSV, a point list when its first non-blank line has 3 or 4 fields, a file of pairs when it has more (then
/// [`detect_landmark_format`] names its format), and refused with its line otherwise; text whose first word is `point`
/// or `index` is an elastix point file. A name ending in `.fcsv` is always a Slicer `.fcsv`, so that its header
/// errors are the ones reported.
pub fn detect_point_format(name: &Path, text: &str) -> Result<PointFileFormat> {
    if name.extension().is_some_and(|e| e.eq_ignore_ascii_case("fcsv")) {
        return Ok(PointFileFormat::SlicerFcsv);
    }
    let body = strip_bom(text).trim_start();
    if looks_like_transformix_output(body) {
        return Err(Error::unsupported(
            name,
            "transformix's outputpoints.txt: its points are already mapped (OutputPoint = T(InputPoint)); read it as \
             landmark pairs (InputPoint on the fixed image, OutputPoint on the moving one), or give the point file \
             transformix read",
        ));
    }
    if super::elastix_points::looks_like_elastix_points(body) {
        return Ok(PointFileFormat::ElastixPoints);
    }
    if body.starts_with('#') {
        return Ok(PointFileFormat::SlicerFcsv);
    }
    if !body.starts_with(['{', '[']) {
        let first = csv_lines(name, text).next().transpose()?;
        match first.as_ref().map(|(line, r)| (r.len(), *line)) {
            None | Some((3 | 4, _)) => return Ok(PointFileFormat::PointList),
            Some((n, line)) if n < 6 => {
                return Err(Error::invalid(
                    name,
                    format!(
                        "line {line} has {n} fields: neither a point list (3 or 4: x,y,z or x,y,z,name) nor a \
                         BigWarp landmarks CSV (8: name, active, mvg-x, mvg-y, mvg-z, fix-x, fix-y, fix-z)"
                    ),
                ));
            }
            Some(_) => {}
        }
    }
    match detect_landmark_format(name, text)? {
        LandmarkFileFormat::BigWarpCsv => Ok(PointFileFormat::BigWarpCsv),
        LandmarkFileFormat::BigWarpJson => Ok(PointFileFormat::BigWarpJson),
        LandmarkFileFormat::SlicerMarkupsJson => Ok(PointFileFormat::SlicerMarkupsJson),
        LandmarkFileFormat::ElastixPoints => Ok(PointFileFormat::ElastixPoints),
        // Slicer's .fcsv is told above; any other kind of landmark file is not a point file (yet).
        other => Err(Error::unsupported(
            name,
            format!(
                "a {other:?} landmark file: point files are plain x,y,z point lists, BigWarp CSV or JSON pairs, \
                 Slicer .mrk.json or .fcsv lists and elastix point files"
            ),
        )),
    }
}

/// Reads a point file in any format [`PointFileFormat`] lists, told apart by [`detect_point_format`].
pub fn read_point_file(path: &Path, options: PointFileOptions) -> Result<PointFile> {
    parse_point_file(path, &read_text(path)?, options)
}

/// [`read_point_file`] on text; `name` is used in errors.
pub fn parse_point_file(name: &Path, text: &str, options: PointFileOptions) -> Result<PointFile> {
    let bigwarp = BigWarpCsvOptions { ras: options.ras };
    let format = detect_point_format(name, text)?;
    let slicer = |points: Vec<SlicerPoint>, ras: bool| {
        if options.ras {
            return Err(Error::unsupported(
                name,
                "a Slicer point list names its coordinate system itself (RAS or LPS); the RAS option applies to \
                 plain CSV point lists and BigWarp files only",
            ));
        }
        let bom = text.starts_with('\u{feff}');
        Ok(PointFile::Slicer(SlicerList { format, points, ras, text: strip_bom(text).to_owned(), bom }))
    };
    match format {
        PointFileFormat::PointList => Ok(PointFile::List(parse_point_list(name, text, options)?)),
        PointFileFormat::BigWarpCsv => {
            Ok(PointFile::BigWarp { format, pairs: parse_bigwarp_csv(name, text, bigwarp)? })
        }
        PointFileFormat::BigWarpJson => {
            Ok(PointFile::BigWarp { format, pairs: parse_bigwarp_json(name, text, bigwarp)? })
        }
        PointFileFormat::SlicerMarkupsJson => {
            let points = parse_mrk_json(name, text)?;
            slicer(points, mrk_json_ras(strip_bom(text)))
        }
        PointFileFormat::SlicerFcsv => {
            let points = parse_fcsv(name, text)?;
            slicer(points, FcsvLayout::of(strip_bom(text)).ras)
        }
        PointFileFormat::ElastixPoints => {
            if options.ras {
                return Err(Error::unsupported(
                    name,
                    "an elastix point file is in ITK's physical space, LPS mm (or voxel indices); the RAS option \
                     applies to plain CSV point lists and BigWarp files only",
                ));
            }
            Ok(PointFile::Elastix(parse_elastix_points(name, text)?))
        }
    }
}

/// Writes `file` at `path` in its own format (module docs), atomically. `options` must be the ones it was read with,
/// so that a RAS file stays RAS.
pub fn write_point_file(path: &Path, file: &PointFile, options: PointFileOptions) -> Result<()> {
    let bigwarp = BigWarpCsvOptions { ras: options.ras };
    let text = match file {
        PointFile::List(list) => to_point_list(path, list, options)?,
        PointFile::BigWarp { format: PointFileFormat::BigWarpJson, pairs } => {
            return write_bigwarp_json_with(path, pairs, bigwarp);
        }
        PointFile::BigWarp { pairs, .. } => return write_bigwarp_csv_with(path, pairs, bigwarp),
        PointFile::Slicer(list) => {
            let body = match list.format {
                PointFileFormat::SlicerFcsv => rewrite_fcsv(path, &list.text, &list.points)?,
                _ => rewrite_mrk_json(path, &list.text, &list.points)?,
            };
            if list.bom { format!("\u{feff}{body}") } else { body }
        }
        PointFile::Elastix(points) => to_elastix_points(path, points)?,
    };
    crate::write_atomic(path, |w| w.write_all(text.as_bytes()))
}

/// The non-blank lines of `text` (after one BOM) with their 1-based numbers, each split into fields
/// ([`split_line`]); a line that is not CSV is an error naming it.
fn csv_lines(name: &Path, text: &str) -> impl Iterator<Item = Result<(u64, Vec<String>)>> {
    strip_bom(text).lines().enumerate().filter(|(_, l)| !l.trim().is_empty()).map(move |(i, l)| {
        let line = i as u64 + 1;
        split_line(l).map(|f| (line, f)).map_err(|problem| Error::invalid(name, format!("line {line}: {problem}")))
    })
}

/// One line's fields, RFC 4180 within the line: separated by `,`, spaces around a field dropped, a field in `"`
/// quotes (a quote inside doubled) taken as written. A quoted field cannot span lines.
fn split_line(line: &str) -> std::result::Result<Vec<String>, String> {
    let line = line.trim_end_matches('\r');
    let mut fields = Vec::new();
    let mut rest = line;
    loop {
        let trimmed = rest.trim_start();
        let (field, after) = if let Some(quoted) = trimmed.strip_prefix('"') {
            let mut value = String::new();
            let mut chars = quoted.char_indices();
            let end = loop {
                match chars.next() {
                    None => {
                        return Err(format!("field {} opens a quote that the line does not close", fields.len() + 1));
                    }
                    Some((i, '"')) => {
                        if quoted[i + 1..].starts_with('"') {
                            value.push('"');
                            chars.next();
                        } else {
                            break i + 1;
                        }
                    }
                    Some((_, c)) => value.push(c),
                }
            };
            let after = quoted[end..].trim_start();
            if !(after.is_empty() || after.starts_with(',')) {
                return Err(format!("field {} has text after its closing quote", fields.len() + 1));
            }
            (value, after)
        } else {
            let end = trimmed.find(',').unwrap_or(trimmed.len());
            (trimmed[..end].trim_end().to_owned(), &trimmed[end..])
        };
        fields.push(field);
        match after.strip_prefix(',') {
            Some(next) => rest = next,
            None => return Ok(fields),
        }
    }
}

/// Reads a plain CSV point list (module docs).
pub fn read_point_list(path: &Path, options: PointFileOptions) -> Result<PointList> {
    parse_point_list(path, &read_text(path)?, options)
}

/// Parses a plain CSV point list (module docs); `name` is used in errors, which give the 1-based point and line.
pub fn parse_point_list(name: &Path, text: &str, options: PointFileOptions) -> Result<PointList> {
    let mut layout: Option<(Vec<PointColumn>, Option<Vec<String>>)> = None;
    let mut points = Vec::new();
    for record in csv_lines(name, text) {
        let (line, record) = record?;
        if layout.is_none() {
            let first = record.first().map_or("", String::as_str);
            let l = if first.parse::<f64>().is_ok() {
                match record.len() {
                    3 => (vec![PointColumn::X, PointColumn::Y, PointColumn::Z], None),
                    4 => (vec![PointColumn::X, PointColumn::Y, PointColumn::Z, PointColumn::Name], None),
                    n => {
                        return Err(Error::invalid(
                            name,
                            format!(
                                "line {line}: {n} fields; a point list without a header has 3 (x,y,z) or 4 \
                                 (x,y,z,name)"
                            ),
                        ));
                    }
                }
            } else {
                let header = record.clone();
                (header_columns(name, line, &header)?, Some(header))
            };
            let is_header = l.1.is_some();
            layout = Some(l);
            if is_header {
                continue;
            }
        }
        let Some((columns, _)) = layout.as_ref() else { continue };
        let mut xyz = [f64::NAN; 3];
        let mut label = String::new();
        let index0 = points.len();
        if record.len() != columns.len() {
            let name_field =
                columns.iter().position(|c| *c == PointColumn::Name).and_then(|k| record.get(k)).map(String::as_str);
            return Err(landmark_error(
                name,
                index0,
                name_field.unwrap_or(""),
                Some(line),
                format!("{} fields; this list's lines have {}", record.len(), columns.len()),
            ));
        }
        if let Some(k) = columns.iter().position(|c| *c == PointColumn::Name) {
            label = record.get(k).cloned().unwrap_or_default();
        }
        for (column, field) in columns.iter().zip(record.iter()) {
            let c = match column {
                PointColumn::X => 0,
                PointColumn::Y => 1,
                PointColumn::Z => 2,
                PointColumn::Name => continue,
            };
            let err = |problem: String| landmark_error(name, index0, &label, Some(line), problem);
            let v: f64 = field.parse().map_err(|_| err(format!("{} is {field:?}, not a number", axis(c))))?;
            if !v.is_finite() {
                return Err(err(format!("{} is {field:?}, not a finite number", axis(c))));
            }
            xyz[c] = v;
        }
        let p = Point3::from_array(xyz);
        points.push(ListedPoint { name: label, position: if options.ras { flip_xy(p) } else { p }, line });
    }
    let (columns, header) = layout.unwrap_or_else(|| (vec![PointColumn::X, PointColumn::Y, PointColumn::Z], None));
    Ok(PointList { columns, header, points })
}

/// The columns a header names: `x`, `y`, `z` once each, `name` at most once (any case).
fn header_columns(name: &Path, line: u64, header: &[String]) -> Result<Vec<PointColumn>> {
    let mut columns = Vec::with_capacity(header.len());
    for field in header {
        let column = match field.to_ascii_lowercase().as_str() {
            "x" => PointColumn::X,
            "y" => PointColumn::Y,
            "z" => PointColumn::Z,
            "name" => PointColumn::Name,
            _ => {
                return Err(Error::invalid(
                    name,
                    format!(
                        "line {line}: header field {field:?} is not x, y, z or name (a first line whose first field \
                         is not a number is a header)"
                    ),
                ));
            }
        };
        if columns.contains(&column) {
            return Err(Error::invalid(name, format!("line {line}: the header names {field:?} twice")));
        }
        columns.push(column);
    }
    for (column, n) in [(PointColumn::X, "x"), (PointColumn::Y, "y"), (PointColumn::Z, "z")] {
        if !columns.contains(&column) {
            return Err(Error::invalid(name, format!("line {line}: the header has no {n} column")));
        }
    }
    Ok(columns)
}

/// A name field, quoted when it holds a separator, a quote or surrounding spaces; a line break (which a field cannot
/// hold) becomes a space.
fn csv_text_field(s: &str) -> String {
    let s = s.replace(['\n', '\r'], " ");
    if s.contains([',', '"']) || s.trim() != s || s.is_empty() { format!("\"{}\"", s.replace('"', "\"\"")) } else { s }
}

/// The text of a plain CSV point list (module docs); `name` is used in errors.
pub fn to_point_list(name: &Path, list: &PointList, options: PointFileOptions) -> Result<String> {
    let mut out = String::new();
    if let Some(header) = &list.header {
        out.push_str(&header.iter().map(|f| csv_text_field(f)).collect::<Vec<_>>().join(","));
        out.push('\n');
    }
    for (i, p) in list.points.iter().enumerate() {
        if !p.position.is_finite() {
            return Err(landmark_error(
                name,
                i,
                &p.name,
                None,
                format!("position {:?} is not finite", p.position.coords()),
            ));
        }
        let xyz = if options.ras { flip_xy(p.position) } else { p.position }.coords();
        let fields: Vec<String> = list
            .columns
            .iter()
            .map(|c| match c {
                PointColumn::X => num(xyz[0]),
                PointColumn::Y => num(xyz[1]),
                PointColumn::Z => num(xyz[2]),
                PointColumn::Name => csv_text_field(&p.name),
            })
            .collect();
        out.push_str(&fields.join(","));
        out.push('\n');
    }
    Ok(out)
}

/// Writes a plain CSV point list atomically.
pub fn write_point_list(path: &Path, list: &PointList, options: PointFileOptions) -> Result<()> {
    let text = to_point_list(path, list, options)?;
    crate::write_atomic(path, |w| w.write_all(text.as_bytes()))
}

/// The first Fiducial markup of a `.mrk.json` document, as [`parse_mrk_json`] picks it.
fn fiducial_markup(root: &mut Value) -> Option<&mut Value> {
    root.get_mut("markups")?
        .as_array_mut()?
        .iter_mut()
        .find(|m| m.get("type").and_then(Value::as_str) == Some("Fiducial"))
}

/// Whether a `.mrk.json` text (that [`parse_mrk_json`] read) has RAS coordinates.
fn mrk_json_ras(text: &str) -> bool {
    let Ok(mut root) = serde_json::from_str::<Value>(text) else { return false };
    fiducial_markup(&mut root).and_then(|m| m.get("coordinateSystem")).and_then(Value::as_str) == Some("RAS")
}

/// `.mrk.json` text with the positions of the first Fiducial markup's defined points replaced by `points`'
/// (LPS mm), in the file's coordinate system and units.
fn rewrite_mrk_json(name: &Path, text: &str, points: &[SlicerPoint]) -> Result<String> {
    let mut root: Value = serde_json::from_str(text).map_err(|e| Error::invalid(name, format!("not JSON: {e}")))?;
    let markup = fiducial_markup(&mut root).ok_or_else(|| Error::invalid(name, "no Fiducial markup to write"))?;
    let ras = markup.get("coordinateSystem").and_then(Value::as_str) == Some("RAS");
    let unit = match markup.get("coordinateUnits") {
        Some(Value::String(s)) => s.clone(),
        Some(Value::Array(triple)) => triple.first().and_then(Value::as_str).unwrap_or("mm").to_owned(),
        _ => "mm".to_owned(),
    };
    let units_per_mm = if unit == "um" { 1e3 } else { 1.0 };
    let mut empty = Vec::new();
    let control_points = match markup.get_mut("controlPoints") {
        Some(Value::Array(a)) => a,
        _ => &mut empty,
    };
    if control_points.len() != points.len() {
        return Err(Error::invalid(
            name,
            format!("{} points to write into a list of {}", points.len(), control_points.len()),
        ));
    }
    for (i, (cp, p)) in control_points.iter_mut().zip(points).enumerate() {
        let Some(position) = p.position else { continue };
        if !position.is_finite() {
            return Err(landmark_error(
                name,
                i,
                &p.label,
                None,
                format!("position {:?} is not finite", position.coords()),
            ));
        }
        let xyz = if ras { flip_xy(position) } else { position }.coords().map(|v| v * units_per_mm);
        if let Some(obj) = cp.as_object_mut() {
            obj.insert("position".to_owned(), Value::from(xyz.to_vec()));
        }
    }
    let mut out = serde_json::to_string_pretty(&root).map_err(|e| Error::invalid(name, e.to_string()))?;
    out.push('\n');
    Ok(out)
}

/// Slicer 4+'s default `.fcsv` columns, used when a versioned file has no `# columns` line.
const FCSV_DEFAULT_COLUMNS: [&str; 14] =
    ["id", "x", "y", "z", "ow", "ox", "oy", "oz", "vis", "sel", "lock", "label", "desc", "associatedNodeID"];

/// Slicer 3's columns, used when an unversioned file has no `# columns` line.
const FCSV_SLICER3_COLUMNS: [&str; 6] = ["label", "x", "y", "z", "sel", "vis"];

/// What [`rewrite_fcsv`] needs of a `.fcsv` header that [`parse_fcsv`] accepted: the coordinate system and the
/// columns, decided as [`parse_fcsv`] decides them.
struct FcsvLayout {
    ras: bool,
    columns: Vec<String>,
}

impl FcsvLayout {
    fn of(text: &str) -> Self {
        let (mut version, mut system, mut columns) = (None, None, None);
        for line in text.lines() {
            let Some(comment) = line.trim_end_matches('\r').strip_prefix('#') else { continue };
            let Some((key, value)) = comment.trim().split_once('=') else { continue };
            let value = value.trim().to_owned();
            match key.trim() {
                "Markups fiducial file version" => version = Some(value),
                "CoordinateSystem" => system = Some(value),
                "columns" => columns = Some(value.split(',').map(|c| c.trim().to_owned()).collect::<Vec<_>>()),
                _ => {}
            }
        }
        // A versioned file says LPS or RAS; an accepted unversioned one is Slicer 3's, RAS.
        let ras = !(version.is_some() && matches!(system.as_deref(), Some("LPS" | "1")));
        let columns = columns.unwrap_or_else(|| {
            let default: &[&str] = if version.is_some() { &FCSV_DEFAULT_COLUMNS } else { &FCSV_SLICER3_COLUMNS };
            default.iter().map(ToString::to_string).collect()
        });
        Self { ras, columns }
    }
}

/// The byte ranges of a `.fcsv` row's fields, split as Slicer's `CsvCodec` splits them (a quote opens a quoted
/// field only at its start).
fn fcsv_field_spans(row: &str) -> Vec<(usize, usize)> {
    let mut spans = Vec::new();
    let (mut start, mut quoted, mut at_start) = (0, false, true);
    let mut chars = row.char_indices().peekable();
    while let Some((i, c)) = chars.next() {
        if quoted {
            if c == '"' {
                if chars.peek().is_some_and(|&(_, n)| n == '"') {
                    chars.next();
                } else {
                    quoted = false;
                }
            }
        } else if c == ',' {
            spans.push((start, i));
            start = i + 1;
            at_start = true;
            continue;
        } else if c == '"' && at_start {
            quoted = true;
        }
        at_start = false;
    }
    spans.push((start, row.len()));
    spans
}

/// `.fcsv` text with the x, y, z fields of the points that have a position replaced by `points`' (LPS mm), in the
/// file's coordinate system; header lines, other fields, blank lines and line endings kept.
fn rewrite_fcsv(name: &Path, text: &str, points: &[SlicerPoint]) -> Result<String> {
    let layout = FcsvLayout::of(text);
    let find = |c: &str| layout.columns.iter().position(|x| x == c);
    let (Some(ix), Some(iy), Some(iz)) = (find("x"), find("y"), find("z")) else {
        return Err(Error::invalid(name, "the columns line has no x, y and z"));
    };
    let mut out = String::with_capacity(text.len() + 16 * points.len());
    let mut rows = 0usize;
    for piece in text.split_inclusive('\n') {
        let content = piece.trim_end_matches('\n').trim_end_matches('\r');
        let ending = &piece[content.len()..];
        if content.starts_with('#') || content.trim().is_empty() {
            out.push_str(piece);
            continue;
        }
        let i = rows;
        rows += 1;
        let Some(p) = points.get(i) else { continue };
        let Some(position) = p.position else {
            out.push_str(piece);
            continue;
        };
        if !position.is_finite() {
            return Err(landmark_error(
                name,
                i,
                &p.label,
                None,
                format!("position {:?} is not finite", position.coords()),
            ));
        }
        let xyz = if layout.ras { flip_xy(position) } else { position }.coords();
        let spans = fcsv_field_spans(content);
        let mut row = String::with_capacity(content.len() + 32);
        let mut last = 0;
        let mut replaced = 0;
        for (k, &(a, b)) in spans.iter().enumerate() {
            let value = [(ix, 0), (iy, 1), (iz, 2)].iter().find(|(col, _)| *col == k).map(|&(_, c)| xyz[c]);
            if let Some(v) = value {
                row.push_str(&content[last..a]);
                row.push_str(&num(v));
                last = b;
                replaced += 1;
            }
        }
        if replaced != 3 {
            return Err(landmark_error(name, i, &p.label, None, "has no x, y or z field to write"));
        }
        row.push_str(&content[last..]);
        out.push_str(&row);
        out.push_str(ending);
    }
    if rows != points.len() {
        return Err(Error::invalid(name, format!("{} points to write into a list of {rows}", points.len())));
    }
    Ok(out)
}

#[cfg(test)]
#[allow(
    clippy::unwrap_used,
    clippy::float_cmp,
    reason = "tests: a panic is the failure, and the values compared are exact"
)]
mod tests {
    use super::*;

    fn parse(text: &str) -> Result<PointList> {
        parse_point_list(Path::new("p.csv"), text, PointFileOptions::default())
    }

    #[test]
    fn header_is_the_first_line_whose_first_field_is_not_a_number() {
        let list = parse("Name,Z,x,y\n\"a, b\",3,1,2\nc,6,4,5\n").expect("list");
        assert_eq!(list.columns, [PointColumn::Name, PointColumn::Z, PointColumn::X, PointColumn::Y]);
        assert_eq!(list.points[0].name, "a, b");
        assert_eq!(list.points[0].position.coords(), [1.0, 2.0, 3.0]);
        assert_eq!(list.points[1].line, 3);
        let text = to_point_list(Path::new("o.csv"), &list, PointFileOptions::default()).expect("text");
        assert_eq!(text, "Name,Z,x,y\n\"a, b\",3.0,1.0,2.0\nc,6.0,4.0,5.0\n");

        let bare = parse("\u{feff}1,2,3\n\n-4.5, 5e-3 ,6\n").expect("list");
        assert_eq!(bare.points[1].line, 3, "blank lines count");
        assert_eq!(bare.header, None);
        assert_eq!(bare.points[1].position.coords(), [-4.5, 5e-3, 6.0]);
        assert_eq!(
            to_point_list(Path::new("o.csv"), &bare, PointFileOptions::default()).unwrap(),
            "1.0,2.0,3.0\n-4.5,0.005,6.0\n"
        );
    }

    #[test]
    fn lines_split_as_csv_within_the_line() {
        assert_eq!(split_line(" 1 , \"a \"\"b\"\", c\" ,2\r").unwrap(), ["1", "a \"b\", c", "2"]);
        assert_eq!(split_line("1,,3").unwrap(), ["1", "", "3"]);
        assert!(split_line("1,\"open").unwrap_err().contains("field 2 opens a quote"));
        assert!(split_line("\"a\"b,1").unwrap_err().contains("field 1 has text after its closing quote"));
    }

    #[test]
    fn ras_lists_are_flipped_on_read_and_write() {
        let ras = PointFileOptions { ras: true };
        let list = parse_point_list(Path::new("p.csv"), "1,2,3,a\n", ras).expect("list");
        assert_eq!(list.points[0].position.coords(), [-1.0, -2.0, 3.0]);
        assert_eq!(to_point_list(Path::new("o.csv"), &list, ras).unwrap(), "1.0,2.0,3.0,a\n");
    }

    #[test]
    fn bad_lists_are_refused_with_their_line_and_point() {
        let msg = |text: &str| parse(text).expect_err(text).to_string();
        assert!(msg("x,y,z\n1,2,3\n4,five,6\n").contains("landmark 2: (1-based, \"\", line 3) y is \"five\""));
        assert!(msg("x,y,z\n1,2\n").contains("line 2) 2 fields; this list's lines have 3"));
        assert!(msg("x,y,w\n").contains("line 1: header field \"w\""));
        assert!(msg("x,y,x\n").contains("names \"x\" twice"));
        assert!(msg("x,y,name\n").contains("no z column"));
        assert!(msg("1,2,3,4,5\n").contains("line 1: 5 fields"));
        assert!(msg("1,2,nan\n").contains("not a finite number"));
    }

    #[test]
    fn csv_files_are_told_apart_by_their_first_line() {
        let f = |text: &str| detect_point_format(Path::new("a.csv"), text);
        assert_eq!(f("x,y,z\n").unwrap(), PointFileFormat::PointList);
        assert_eq!(f("\n1,2,3,n\n").unwrap(), PointFileFormat::PointList);
        assert_eq!(f("\"P\",\"true\",\"1\",\"2\",\"3\",\"4\",\"5\",\"6\"\n").unwrap(), PointFileFormat::BigWarpCsv);
        let e = f("\n\n1,2,3,4,5\n").unwrap_err().to_string();
        assert!(e.contains("line 3 has 5 fields"), "{e}");
        assert_eq!(f("# Markups fiducial file version = 4.11\n").unwrap(), PointFileFormat::SlicerFcsv);
    }

    #[test]
    fn fcsv_rewrite_replaces_only_the_coordinates() {
        let text = "# Markups fiducial file version = 4.11\r\n# CoordinateSystem = RAS\r\n\
                    # columns = id,x,y,z,ow,ox,oy,oz,vis,sel,lock,label,desc,associatedNodeID\r\n\
                    1,\"1\",2,3,0,0,0,1,1,1,0,\"F, 1\",a desc,\r\n";
        let name = Path::new("a.fcsv");
        let PointFile::Slicer(mut list) = parse_point_file(name, text, PointFileOptions::default()).unwrap() else {
            panic!("a Slicer list")
        };
        assert!(list.ras);
        assert_eq!(list.points[0].position.unwrap().coords(), [-1.0, -2.0, 3.0]);
        list.points[0].position = Some(Point3::new(-10.5, 20.0, 30.0));
        let out = rewrite_fcsv(name, &list.text, &list.points).unwrap();
        assert!(out.ends_with("1,10.5,-20.0,30.0,0,0,0,1,1,1,0,\"F, 1\",a desc,\r\n"), "{out}");
        assert!(out.starts_with("# Markups fiducial file version = 4.11\r\n# CoordinateSystem = RAS\r\n"));
        let back = parse_fcsv(name, &out).unwrap();
        assert_eq!(back[0].position.unwrap().coords(), [-10.5, 20.0, 30.0]);
        assert_eq!(back[0].label, "F, 1");
    }
}
