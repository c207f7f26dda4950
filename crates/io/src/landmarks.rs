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

use std::fmt::Write as _;
use std::path::Path;

use serde_json::{Value, json};

use crate::error::{Error, ErrorKind, Result};
use crate::geometry::{Lps, Point3};

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
    let meta = crate::check_regular_file(path)?;
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

// ---------------------------------------------------------------------------------------------
// BigWarp CSV

/// Options for BigWarp files, CSV and JSON alike.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct BigWarpCsvOptions {
    /// The file's coordinates are RAS (x and y are negated on read and write). Default: LPS.
    pub ras: bool,
}

/// Reads a BigWarp landmarks CSV, taking its coordinates as LPS mm.
pub fn read_bigwarp_csv(path: &Path) -> Result<Vec<LandmarkPair>> {
    read_bigwarp_csv_with(path, BigWarpCsvOptions::default())
}

/// Reads a BigWarp landmarks CSV with `options`.
pub fn read_bigwarp_csv_with(path: &Path, options: BigWarpCsvOptions) -> Result<Vec<LandmarkPair>> {
    parse_bigwarp_csv(path, &read_text(path)?, options)
}

/// Parses BigWarp CSV text; `name` is used in errors.
pub fn parse_bigwarp_csv(name: &Path, text: &str, options: BigWarpCsvOptions) -> Result<Vec<LandmarkPair>> {
    let text = strip_bom(text);
    let mut reader = csv::ReaderBuilder::new().has_headers(false).flexible(true).from_reader(text.as_bytes());
    let mut pairs = Vec::new();
    for (i, record) in reader.records().enumerate() {
        let record = record.map_err(|e| Error::invalid(name, format!("landmark {} (1-based): {e}", i + 1)))?;
        let line = record.position().map(csv::Position::line);
        if record.iter().all(|f| f.trim().is_empty()) {
            continue;
        }
        let label = record.get(0).unwrap_or("").to_string();
        match record.len() {
            8 => {}
            6 => {
                return Err(landmark_error(name, i, &label, line, "2-D landmarks are not supported (6 columns)"));
            }
            n => {
                return Err(landmark_error(
                    name,
                    i,
                    &label,
                    line,
                    format!(
                        "{n} columns; BigWarp 3-D rows have 8: name, active, mvg-x, mvg-y, mvg-z, fix-x, fix-y, fix-z"
                    ),
                ));
            }
        }
        let active = match record.get(1).unwrap_or("").trim().to_ascii_lowercase().as_str() {
            "true" => true,
            "false" => false,
            other => {
                return Err(landmark_error(name, i, &label, line, format!("active is {other:?}, not true or false")));
            }
        };
        let mut halves = [None, None];
        for (h, half) in halves.iter_mut().enumerate() {
            let side = if h == 0 { "moving" } else { "fixed" };
            let mut xyz = [0.0; 3];
            for (c, v) in xyz.iter_mut().enumerate() {
                let s = record.get(2 + 3 * h + c).unwrap_or("").trim();
                *v = parse_java_double(s).ok_or_else(|| {
                    landmark_error(name, i, &label, line, format!("{side} {} is {s:?}, not a number", axis(c)))
                })?;
            }
            *half = half_point(name, i, &label, line, side, xyz)?;
        }
        let [moving, fixed] = halves.map(|p| p.map(|p| if options.ras { flip_xy(p) } else { p }));
        pairs.push(LandmarkPair { name: label, active, moving, fixed });
    }
    Ok(pairs)
}

fn axis(c: usize) -> &'static str {
    ["x", "y", "z"][c]
}

/// Java's `Double.toString` spellings (`Infinity`, `-Infinity`, `NaN`) and ordinary numbers.
fn parse_java_double(s: &str) -> Option<f64> {
    match s {
        "Infinity" | "+Infinity" => Some(f64::INFINITY),
        "-Infinity" => Some(f64::NEG_INFINITY),
        "NaN" => Some(f64::NAN),
        _ => s.parse().ok(),
    }
}

/// All three coordinates infinite → a missing half; all finite → a point; anything else is an error.
fn half_point(
    name: &Path,
    i: usize,
    label: &str,
    line: Option<u64>,
    side: &str,
    xyz: [f64; 3],
) -> Result<Option<Point3<Lps>>> {
    if let Some(c) = xyz.iter().position(|v| v.is_nan()) {
        return Err(landmark_error(name, i, label, line, format!("{side} {} is NaN", axis(c))));
    }
    let infinite = xyz.iter().filter(|v| v.is_infinite()).count();
    match infinite {
        0 => Ok(Some(Point3::from_array(xyz))),
        3 => Ok(None),
        _ => Err(landmark_error(
            name,
            i,
            label,
            line,
            format!("{side} point {xyz:?} is partly infinite (a missing half has Infinity in all three)"),
        )),
    }
}

/// BigWarp CSV text for `pairs`, quoted like opencsv.
pub fn to_bigwarp_csv(name: &Path, pairs: &[LandmarkPair], options: BigWarpCsvOptions) -> Result<String> {
    let quote = |s: &str| format!("\"{}\"", s.replace('"', "\"\""));
    let mut out = String::new();
    for (i, p) in pairs.iter().enumerate() {
        let mut fields = vec![quote(&p.name), quote(if p.active { "true" } else { "false" })];
        for (side, half) in [("moving", p.moving), ("fixed", p.fixed)] {
            match half {
                Some(pt) => {
                    check_finite(name, i, &p.name, side, pt)?;
                    let pt = if options.ras { flip_xy(pt) } else { pt };
                    fields.extend(pt.coords().iter().map(|&v| quote(&num(v))));
                }
                None => fields.extend(std::iter::repeat_n(quote("Infinity"), 3)),
            }
        }
        out.push_str(&fields.join(","));
        out.push('\n');
    }
    Ok(out)
}

fn check_finite(name: &Path, i: usize, label: &str, side: &str, p: Point3<Lps>) -> Result<()> {
    if p.is_finite() {
        Ok(())
    } else {
        Err(landmark_error(name, i, label, None, format!("{side} point {:?} is not finite", p.coords())))
    }
}

/// Writes `pairs` as a BigWarp CSV in LPS.
pub fn write_bigwarp_csv(path: &Path, pairs: &[LandmarkPair]) -> Result<()> {
    write_bigwarp_csv_with(path, pairs, BigWarpCsvOptions::default())
}

/// Writes `pairs` as a BigWarp CSV with `options`.
pub fn write_bigwarp_csv_with(path: &Path, pairs: &[LandmarkPair], options: BigWarpCsvOptions) -> Result<()> {
    let text = to_bigwarp_csv(path, pairs, options)?;
    crate::write_atomic(path, |w| w.write_all(text.as_bytes()))
}

// ---------------------------------------------------------------------------------------------
// BigWarp JSON

/// The `type` of BigWarp's landmark table in JSON (`LandmarkTableModel.toJson`).
pub const BIGWARP_LANDMARKS_TYPE: &str = "BigWarpLandmarks";

/// What an unrecognised JSON file was expected to be, for messages.
const EXPECTED_JSON: &str = "expected BigWarp landmarks ({\"type\": \"BigWarpLandmarks\", \"numDimensions\": 3, \
     \"movingPoints\": […], \"fixedPoints\": […], \"active\": […], \"names\": […]} alone, under \"landmarks\" as \
     BigWarp's Save landmarks writes it, or under \"Transform\" → \"landmarks\" in a BigWarp settings file) or a \
     Slicer markups file (a \"markups\" list)";

/// Reads a BigWarp landmarks JSON file (any of the three shapes of [`parse_bigwarp_json`]), taking its
/// coordinates as LPS mm.
pub fn read_bigwarp_json(path: &Path) -> Result<Vec<LandmarkPair>> {
    read_bigwarp_json_with(path, BigWarpCsvOptions::default())
}

/// Reads a BigWarp landmarks JSON file with `options` (RAS or LPS, as for the CSV).
pub fn read_bigwarp_json_with(path: &Path, options: BigWarpCsvOptions) -> Result<Vec<LandmarkPair>> {
    parse_bigwarp_json(path, &read_text(path)?, options)
}

/// Quotes the bare `Infinity`, `-Infinity` and `NaN` that Gson writes for non-finite numbers (BigWarp's pending
/// halves), which are not JSON, so that serde_json reads them as strings. Text inside strings is left alone.
fn quote_nonfinite_tokens(text: &str) -> std::borrow::Cow<'_, str> {
    if !text.contains("Infinity") && !text.contains("NaN") {
        return std::borrow::Cow::Borrowed(text);
    }
    let bytes = text.as_bytes();
    let word = |b: u8| b.is_ascii_alphanumeric() || b == b'_';
    let mut out = String::with_capacity(text.len() + 64);
    let (mut done, mut i, mut in_string) = (0, 0, false);
    while i < bytes.len() {
        let b = bytes[i];
        if in_string {
            match b {
                b'\\' => i += 1,
                b'"' => in_string = false,
                _ => {}
            }
            i += 1;
            continue;
        }
        if b == b'"' {
            in_string = true;
            i += 1;
            continue;
        }
        let token = ["-Infinity", "Infinity", "NaN"].into_iter().find(|t| {
            bytes[i..].starts_with(t.as_bytes())
                && (i == 0 || !word(bytes[i - 1]))
                && bytes.get(i + t.len()).is_none_or(|&next| !word(next))
        });
        if let Some(t) = token {
            // `i` is at an ASCII byte, so both slices end on character boundaries.
            out.push_str(&text[done..i]);
            out.push('"');
            out.push_str(t);
            out.push('"');
            i += t.len();
            done = i;
        } else {
            i += 1;
        }
    }
    out.push_str(&text[done..]);
    std::borrow::Cow::Owned(out)
}

/// Parses JSON as BigWarp's Gson writes it: strict JSON plus bare non-finite numbers.
fn parse_gson_json(name: &Path, text: &str) -> Result<Value> {
    serde_json::from_str(&quote_nonfinite_tokens(strip_bom(text)))
        .map_err(|e| Error::invalid(name, format!("not JSON: {e}")))
}

/// The BigWarp landmark table inside `root`: `root` itself when its `type` is `BigWarpLandmarks`, or the object
/// under `landmarks` (BigWarp's Save landmarks to `.json`, `TransformWriterJson`), or under `Transform` →
/// `landmarks` (a BigWarp settings or project file, `BigwarpSettings`).
fn bigwarp_table(root: &Value) -> Option<&serde_json::Map<String, Value>> {
    let is_table = |v: &Value| v.get("type").and_then(Value::as_str) == Some(BIGWARP_LANDMARKS_TYPE);
    if is_table(root) {
        return root.as_object();
    }
    [root.get("landmarks"), root.get("Transform").and_then(|t| t.get("landmarks"))]
        .into_iter()
        .flatten()
        .find(|v| v.as_object().is_some_and(|o| o.get("type").is_none_or(|t| t == BIGWARP_LANDMARKS_TYPE)))
        .and_then(Value::as_object)
}

/// The top-level keys of a JSON object, sorted, for messages.
fn json_keys(root: &Value) -> String {
    match root.as_object() {
        Some(o) if o.is_empty() => "an empty object".into(),
        Some(o) => {
            let mut keys: Vec<String> = o.keys().take(12).map(|k| format!("{k:?}")).collect();
            keys.sort();
            format!("keys {}", keys.join(", "))
        }
        None => "not an object".into(),
    }
}

fn not_bigwarp(name: &Path, root: &Value) -> Error {
    let found = json_keys(root);
    let inner = root.get("landmarks").or_else(|| root.get("Transform").and_then(|t| t.get("landmarks")));
    let why = match inner.map(|v| v.get("type")) {
        Some(Some(t)) => format!(" (its landmarks have type {t}, not {BIGWARP_LANDMARKS_TYPE:?})"),
        Some(None) if inner.is_some_and(|v| !v.is_object()) => " (its \"landmarks\" is not an object)".into(),
        _ => String::new(),
    };
    Error::invalid(name, format!("not a landmarks file: {EXPECTED_JSON}; the file has {found}{why}"))
}

/// Parses BigWarp landmarks JSON; `name` is used in errors.
///
/// BigWarp 9 writes its landmark table (`LandmarkTableModel.toJson`) as
/// `{"type": "BigWarpLandmarks", "numDimensions": 3, "movingPoints": [[x, y, z], …], "fixedPoints": […],
/// "active": [true, …], "names": ["Pt-0", …]}`: row *i* of the table is entry *i* of each list, the moving point
/// first as in its CSV. The table is read alone, under `landmarks` (what BigWarp's *Save landmarks* writes to a
/// `.json` file, next to the transform's `type` and `mask`), or under `Transform` → `landmarks` (its settings
/// file). A pending half is `[Infinity, Infinity, Infinity]`, bare, as Gson writes it. Coordinates are BigWarp's
/// world coordinates, read as the CSV reader reads them: LPS mm unless `options.ras`.
pub fn parse_bigwarp_json(name: &Path, text: &str, options: BigWarpCsvOptions) -> Result<Vec<LandmarkPair>> {
    let root = parse_gson_json(name, text)?;
    let table = bigwarp_table(&root).ok_or_else(|| not_bigwarp(name, &root))?;
    match table.get("numDimensions").and_then(Value::as_u64) {
        Some(3) => {}
        Some(2) => return Err(Error::unsupported(name, "2-D landmarks are not supported (numDimensions 2)")),
        Some(n) => return Err(Error::invalid(name, format!("numDimensions is {n}; BigWarp landmarks are 2-D or 3-D"))),
        None => return Err(Error::invalid(name, "the BigWarp landmarks have no numDimensions (a whole number)")),
    }
    let list = |key: &str| -> Result<&Vec<Value>> {
        table
            .get(key)
            .and_then(Value::as_array)
            .ok_or_else(|| Error::invalid(name, format!("the BigWarp landmarks have no {key:?} list")))
    };
    let (names, active, moving, fixed) = (list("names")?, list("active")?, list("movingPoints")?, list("fixedPoints")?);
    for (key, l) in [("active", active), ("movingPoints", moving), ("fixedPoints", fixed)] {
        if l.len() != names.len() {
            return Err(Error::invalid(
                name,
                format!(
                    "{key} has {} entries but names has {}; BigWarp needs one of each per landmark",
                    l.len(),
                    names.len()
                ),
            ));
        }
    }
    let mut pairs = Vec::with_capacity(names.len());
    for i in 0..names.len() {
        let label = names[i]
            .as_str()
            .ok_or_else(|| landmark_error(name, i, "", None, format!("name {} is not a string", names[i])))?
            .to_string();
        let err = |problem: String| landmark_error(name, i, &label, None, problem);
        let is_active =
            active[i].as_bool().ok_or_else(|| err(format!("active is {}, not true or false", active[i])))?;
        let mut halves = [None, None];
        for (half, (side, points)) in halves.iter_mut().zip([("moving", moving), ("fixed", fixed)]) {
            let xyz = points[i]
                .as_array()
                .filter(|a| a.len() == 3)
                .ok_or_else(|| err(format!("{side} point {} is not a list of 3 numbers", points[i])))?;
            let mut p = [0.0; 3];
            for (c, (v, out)) in xyz.iter().zip(&mut p).enumerate() {
                *out = match v {
                    Value::Number(n) => n.as_f64(),
                    // Gson's bare Infinity/NaN, quoted by `quote_nonfinite_tokens`; BigWarp also reads numeric strings.
                    Value::String(s) => parse_java_double(s.trim()),
                    _ => None,
                }
                .ok_or_else(|| err(format!("{side} {} is {v}, not a number", axis(c))))?;
            }
            *half = half_point(name, i, &label, None, side, p)?;
        }
        let [moving, fixed] = halves.map(|p| p.map(|p| if options.ras { flip_xy(p) } else { p }));
        pairs.push(LandmarkPair { name: label, active: is_active, moving, fixed });
    }
    Ok(pairs)
}

/// One number as Gson writes it: shortest round-trip text, `Infinity` for a pending half.
fn gson_number(out: &mut String, v: f64) {
    if v.is_infinite() {
        out.push_str(if v > 0.0 { "Infinity" } else { "-Infinity" });
    } else {
        out.push_str(&num(v));
    }
}

/// BigWarp JSON text for `pairs`: `{"landmarks": {"type": "BigWarpLandmarks", …}}`, what BigWarp's *Load
/// landmarks* reads from a `.json` file (it ignores no field it needs, and the transform type is left to the
/// user), pretty-printed like Gson with a pending half as bare `Infinity`, as BigWarp writes it.
pub fn to_bigwarp_json(name: &Path, pairs: &[LandmarkPair], options: BigWarpCsvOptions) -> Result<String> {
    let mut points: [Vec<[f64; 3]>; 2] = [Vec::with_capacity(pairs.len()), Vec::with_capacity(pairs.len())];
    for (i, p) in pairs.iter().enumerate() {
        for (list, (side, half)) in points.iter_mut().zip([("moving", p.moving), ("fixed", p.fixed)]) {
            list.push(match half {
                Some(pt) => {
                    check_finite(name, i, &p.name, side, pt)?;
                    (if options.ras { flip_xy(pt) } else { pt }).coords()
                }
                None => [f64::INFINITY; 3],
            });
        }
    }
    let list = |out: &mut String, items: &mut dyn Iterator<Item = String>| {
        let items: Vec<String> = items.collect();
        if items.is_empty() {
            out.push_str("[]");
        } else {
            out.push_str("[\n      ");
            out.push_str(&items.join(",\n      "));
            out.push_str("\n    ]");
        }
    };
    let mut out = String::from("{\n  \"landmarks\": {\n");
    let _ = writeln!(out, "    \"type\": \"{BIGWARP_LANDMARKS_TYPE}\",\n    \"numDimensions\": 3,");
    for (key, list_points) in [("movingPoints", &points[0]), ("fixedPoints", &points[1])] {
        let _ = write!(out, "    \"{key}\": ");
        list(
            &mut out,
            &mut list_points.iter().map(|xyz| {
                let mut s = String::from("[\n        ");
                for (c, &v) in xyz.iter().enumerate() {
                    if c > 0 {
                        s.push_str(",\n        ");
                    }
                    gson_number(&mut s, v);
                }
                s.push_str("\n      ]");
                s
            }),
        );
        out.push_str(",\n");
    }
    out.push_str("    \"active\": ");
    list(&mut out, &mut pairs.iter().map(|p| p.active.to_string()));
    out.push_str(",\n    \"names\": ");
    list(&mut out, &mut pairs.iter().map(|p| Value::from(p.name.as_str()).to_string()));
    out.push_str("\n  }\n}\n");
    Ok(out)
}

/// Writes `pairs` as a BigWarp landmarks JSON file in LPS.
pub fn write_bigwarp_json(path: &Path, pairs: &[LandmarkPair]) -> Result<()> {
    write_bigwarp_json_with(path, pairs, BigWarpCsvOptions::default())
}

/// Writes `pairs` as a BigWarp landmarks JSON file with `options`.
pub fn write_bigwarp_json_with(path: &Path, pairs: &[LandmarkPair], options: BigWarpCsvOptions) -> Result<()> {
    let text = to_bigwarp_json(path, pairs, options)?;
    crate::write_atomic(path, |w| w.write_all(text.as_bytes()))
}

// ---------------------------------------------------------------------------------------------
// One file of pairs, by content

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
}

impl LandmarkFileFormat {
    /// Whether the file holds pairs (BigWarp) rather than one side (Slicer).
    #[must_use]
    pub fn holds_pairs(self) -> bool {
        matches!(self, Self::BigWarpCsv | Self::BigWarpJson)
    }
}

/// Tells the landmark format of `text` by its content, not its name: JSON (after one BOM and white space, an
/// `{` or `[`) is BigWarp when it holds a BigWarp landmark table (see [`parse_bigwarp_json`]), Slicer when it has
/// a `markups` list, and refused otherwise with what was expected; text whose first line starts with `#` is a
/// Slicer `.fcsv` (BigWarp's CSV quotes every field, so its lines start with `"`); anything else is BigWarp CSV.
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
    Ok(LandmarkFileFormat::BigWarpCsv)
}

/// [`detect_landmark_format`] of the file at `path`.
pub fn detect_landmark_file(path: &Path) -> Result<LandmarkFileFormat> {
    detect_landmark_format(path, &read_text(path)?)
}

/// Reads one file of landmark pairs, BigWarp CSV or BigWarp JSON, told apart by content; LPS mm.
///
/// A Slicer point list (`.mrk.json`, `.fcsv`) holds the points of one volume only, and is refused here with a
/// message that says so: read it with its partner through [`read_slicer_pair`].
pub fn read_landmark_pairs(path: &Path) -> Result<Vec<LandmarkPair>> {
    read_landmark_pairs_with(path, BigWarpCsvOptions::default())
}

/// [`read_landmark_pairs`] with `options` for the BigWarp formats.
pub fn read_landmark_pairs_with(path: &Path, options: BigWarpCsvOptions) -> Result<Vec<LandmarkPair>> {
    let text = read_text(path)?;
    match detect_landmark_format(path, &text)? {
        LandmarkFileFormat::BigWarpCsv => parse_bigwarp_csv(path, &text, options),
        LandmarkFileFormat::BigWarpJson => parse_bigwarp_json(path, &text, options),
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

// ---------------------------------------------------------------------------------------------
// Slicer .mrk.json

/// Reads the first fiducial (point) list of a Slicer `.mrk.json` file.
pub fn read_mrk_json(path: &Path) -> Result<Vec<SlicerPoint>> {
    parse_mrk_json(path, &read_text(path)?)
}

/// Parses `.mrk.json` text; `name` is used in errors.
pub fn parse_mrk_json(name: &Path, text: &str) -> Result<Vec<SlicerPoint>> {
    let text = strip_bom(text);
    let not_markups = |problem: String| {
        // Say what the file is when it is BigWarp's (whose pending halves make it Gson JSON, not JSON).
        if parse_gson_json(name, text).is_ok_and(|root| bigwarp_table(&root).is_some()) {
            bigwarp_not_slicer(name)
        } else {
            Error::invalid(name, problem)
        }
    };
    let root: Value = serde_json::from_str(text).map_err(|e| not_markups(format!("not JSON: {e}")))?;
    let markups = root.get("markups").and_then(Value::as_array).ok_or_else(|| {
        not_markups(format!(
            "no \"markups\" list: not a Slicer markups file (expected {{\"markups\": [{{\"type\": \"Fiducial\", \
             \"controlPoints\": […]}}]}}); the file has {}",
            json_keys(&root)
        ))
    })?;
    let Some(list) = markups.iter().find(|m| m.get("type").and_then(Value::as_str) == Some("Fiducial")) else {
        let types: Vec<&str> = markups.iter().map(|m| m.get("type").and_then(Value::as_str).unwrap_or("?")).collect();
        return Err(Error::invalid(name, format!("no Fiducial (point list) markup; the file holds {types:?}")));
    };
    let ras = match list.get("coordinateSystem").and_then(Value::as_str) {
        None | Some("LPS") => false,
        Some("RAS") => true,
        Some(other) => return Err(Error::invalid(name, format!("coordinateSystem {other:?} is neither LPS nor RAS"))),
    };
    let mm_per_unit = mrk_json_mm_per_unit(name, list.get("coordinateUnits"))?;
    let empty = Vec::new();
    let points = match list.get("controlPoints") {
        None | Some(Value::Null) => &empty,
        Some(Value::Array(a)) => a,
        Some(_) => return Err(Error::invalid(name, "\"controlPoints\" is not a list")),
    };
    let mut out = Vec::with_capacity(points.len());
    for (i, cp) in points.iter().enumerate() {
        let label = cp.get("label").and_then(Value::as_str).unwrap_or("").to_string();
        let selected = cp.get("selected").and_then(Value::as_bool).unwrap_or(true);
        let status = cp.get("positionStatus").and_then(Value::as_str).unwrap_or("defined");
        let position = if status == "defined" {
            let xyz = cp
                .get("position")
                .and_then(Value::as_array)
                .filter(|a| a.len() == 3)
                .and_then(|a| a.iter().map(Value::as_f64).collect::<Option<Vec<f64>>>())
                .ok_or_else(|| landmark_error(name, i, &label, None, "position is not a list of 3 numbers"))?;
            let mut p = [xyz[0] * mm_per_unit, xyz[1] * mm_per_unit, xyz[2] * mm_per_unit];
            if let Some(c) = p.iter().position(|v| !v.is_finite()) {
                return Err(landmark_error(name, i, &label, None, format!("position {} is not finite", axis(c))));
            }
            if ras {
                p[0] = -p[0];
                p[1] = -p[1];
            }
            Some(Point3::from_array(p))
        } else {
            None
        };
        out.push(SlicerPoint { label, selected, position });
    }
    Ok(out)
}

/// Millimetres per unit of `coordinateUnits`: absent (the schema's default, mm), a string `mm` or `um`, or the
/// schema's coded form, a UCUM code triple such as `["um", "UCUM", "micrometer"]` (Slicer reads both forms).
/// Anything else is refused: a guessed unit would scale every point.
fn mrk_json_mm_per_unit(name: &Path, units: Option<&Value>) -> Result<f64> {
    let code = match units {
        None => return Ok(1.0),
        Some(Value::String(s)) => s.as_str(),
        Some(v @ Value::Array(triple)) => match triple.as_slice() {
            [Value::String(code), Value::String(scheme), Value::String(_)] if scheme == "UCUM" => code.as_str(),
            _ => {
                return Err(Error::invalid(
                    name,
                    format!("coordinateUnits {v} is not a UCUM code triple such as [\"mm\",\"UCUM\",\"millimeter\"]"),
                ));
            }
        },
        Some(other) => {
            return Err(Error::invalid(name, format!("coordinateUnits {other} is neither a string nor a UCUM code")));
        }
    };
    match code {
        "mm" => Ok(1.0),
        "um" => Ok(1e-3),
        other => Err(Error::invalid(name, format!("coordinateUnits {other:?} is neither mm nor um"))),
    }
}

/// `.mrk.json` text (LPS, mm) for `points`.
pub fn to_mrk_json(name: &Path, points: &[SlicerPoint]) -> Result<String> {
    let mut cps = Vec::with_capacity(points.len());
    for (i, p) in points.iter().enumerate() {
        let (position, status) = match p.position {
            Some(pt) => {
                check_finite(name, i, &p.label, "position", pt)?;
                (pt.coords(), "defined")
            }
            None => ([0.0; 3], "undefined"),
        };
        cps.push(json!({
            "id": (i + 1).to_string(),
            "label": p.label,
            "description": "",
            "associatedNodeID": "",
            "position": position,
            // Slicer's identity orientation (in its RAS) expressed in this file's LPS, as Slicer writes it.
            "orientation": [-1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, 1.0],
            "selected": p.selected,
            "locked": false,
            "visibility": true,
            "positionStatus": status,
        }));
    }
    let doc = json!({
        "@schema": MARKUPS_SCHEMA,
        "markups": [{
            "type": "Fiducial",
            "coordinateSystem": "LPS",
            "coordinateUnits": "mm",
            "locked": false,
            "fixedNumberOfControlPoints": false,
            "labelFormat": "%N-%d",
            "lastUsedControlPointNumber": points.len(),
            "controlPoints": cps,
        }],
    });
    let mut text = serde_json::to_string_pretty(&doc).map_err(|e| Error::invalid(name, e.to_string()))?;
    text.push('\n');
    Ok(text)
}

/// Writes `points` as a Slicer `.mrk.json` point list in LPS.
pub fn write_mrk_json(path: &Path, points: &[SlicerPoint]) -> Result<()> {
    let text = to_mrk_json(path, points)?;
    crate::write_atomic(path, |w| w.write_all(text.as_bytes()))
}

// ---------------------------------------------------------------------------------------------
// Slicer .fcsv

const FCSV_DEFAULT_COLUMNS: [&str; 14] =
    ["id", "x", "y", "z", "ow", "ox", "oy", "oz", "vis", "sel", "lock", "label", "desc", "associatedNodeID"];

/// Reads a Slicer `.fcsv` fiducial file.
pub fn read_fcsv(path: &Path) -> Result<Vec<SlicerPoint>> {
    parse_fcsv(path, &read_text(path)?)
}

/// Splits one CSV row as Slicer's `CsvCodec` does: a quote only opens a quoted field at its start.
fn split_csv_row(row: &str) -> Vec<String> {
    let mut fields = Vec::new();
    let mut cur = String::new();
    let mut chars = row.chars().peekable();
    let mut quoted = false;
    while let Some(c) = chars.next() {
        if quoted {
            if c == '"' {
                if chars.peek() == Some(&'"') {
                    cur.push('"');
                    chars.next();
                } else {
                    quoted = false;
                }
            } else {
                cur.push(c);
            }
        } else if c == ',' {
            fields.push(std::mem::take(&mut cur));
        } else if c == '"' && cur.is_empty() {
            quoted = true;
        } else {
            cur.push(c);
        }
    }
    fields.push(cur);
    fields
}

/// Slicer 3's fiducial-list columns (`vtkMRMLFiducialListStorageNode`), used when a Slicer 3 file has no
/// columns line.
const FCSV_SLICER3_COLUMNS: [&str; 6] = ["label", "x", "y", "z", "sel", "vis"];

/// Index of the `positionStatus` value that Slicer 5 appends, undeclared, after the 14 declared columns.
const FCSV_POSITION_STATUS_COLUMN: usize = 14;

/// What a `.fcsv` header says, collected before any row is read.
#[derive(Default)]
struct FcsvHeader {
    /// `# Markups fiducial file version = V` (Slicer 4 and later).
    version: Option<String>,
    /// `# CoordinateSystem = …`, as written.
    coordinate_system: Option<String>,
    /// `# columns = …`.
    columns: Option<Vec<String>>,
    /// A Slicer 3 header line: `# Fiducial List file …` or `# version = …`.
    slicer3: bool,
}

impl FcsvHeader {
    /// Reads one `#` line the way Slicer does: name and value around the first `=`, trimmed.
    fn take(&mut self, comment: &str) {
        let comment = comment.trim();
        if comment.starts_with("Fiducial List file") {
            self.slicer3 = true;
            return;
        }
        let Some((key, value)) = comment.split_once('=') else { return };
        let value = value.trim().to_string();
        match key.trim() {
            "Markups fiducial file version" => self.version = Some(value),
            "CoordinateSystem" => self.coordinate_system = Some(value),
            "columns" => self.columns = Some(value.split(',').map(|c| c.trim().to_string()).collect()),
            "version" => self.slicer3 = true,
            _ => {}
        }
    }

    /// Whether the positions are RAS (`true`) or LPS (`false`): the decision table of [`parse_fcsv`].
    fn ras(&self, name: &Path) -> Result<bool> {
        match (self.version.as_deref(), self.coordinate_system.as_deref()) {
            (Some(""), _) => Err(Error::invalid(name, "the \"# Markups fiducial file version\" line has no version")),
            (Some(_), Some("LPS" | "1")) => Ok(false),
            (Some(_), Some("RAS" | "0")) => Ok(true),
            (Some(_), Some(other)) => {
                Err(Error::invalid(name, format!("CoordinateSystem {other:?} is not LPS, RAS, 0 (RAS) or 1 (LPS)")))
            }
            (Some(version), None) => Err(Error::invalid(
                name,
                format!(
                    "version {version} file with no \"# CoordinateSystem\" line: its points could be RAS or LPS \
                     (Slicer wrote this line from its first versioned .fcsv on, and its default changed from RAS \
                     to LPS in 2020), so it is refused rather than guessed; add \"# CoordinateSystem = RAS\" or \
                     \"= LPS\" after the version line"
                ),
            )),
            (None, Some(cs)) => Err(Error::invalid(
                name,
                format!(
                    "a \"# CoordinateSystem = {cs}\" line without a \"# Markups fiducial file version\" line: neither \
                     a Slicer 4+ file (which has both) nor a Slicer 3 file (RAS, with neither), so its coordinate \
                     system is unclear"
                ),
            )),
            (None, None) if self.slicer3 || self.columns.is_some() => Ok(true),
            (None, None) => Err(Error::unsupported(
                name,
                "no \"# Markups fiducial file version\" line, and no Slicer 3 header (\"# Fiducial List file\" or \
                 \"# columns\"): not a Slicer .fcsv file",
            )),
        }
    }
}

/// Parses `.fcsv` text; `name` is used in errors.
///
/// The coordinate system is decided from the header as Slicer's `vtkMRMLMarkupsFiducialStorageNode` (and, for
/// Slicer 3 files, `vtkMRMLFiducialListStorageNode`) decides it, except that where Slicer falls back on a default
/// that has changed between its versions, the file is refused rather than guessed:
///
/// | `# Markups fiducial file version` | `# CoordinateSystem` | Read as | Slicer |
/// |---|---|---|---|
/// | present | `LPS` or `1` | LPS | LPS |
/// | present | `RAS` or `0` | RAS | RAS |
/// | present | absent | **refused** | the storage node's default: RAS before Slicer 4.11 (commit 6036edbc, 2020), LPS since; every Slicer that writes the version line writes this line too |
/// | present | anything else | **refused** | clamped to RAS |
/// | present but empty | any | **refused** | read as Slicer 3 |
/// | absent, with a Slicer 3 header (`# Fiducial List file`, `# version =` or `# columns =`) | absent | RAS (Slicer 3) | RAS ("assuming Slicer 3 format") |
/// | absent | present | **refused** | RAS, the line ignored |
/// | absent, no Slicer 3 header | absent | **refused**, not a Slicer file | RAS |
///
/// Columns: the `# columns` line when there is one, else `id,x,y,z,ow,ox,oy,oz,vis,sel,lock,label,desc,
/// associatedNodeID` (versioned) or `label,x,y,z,sel,vis` (Slicer 3). In a versioned file with at most the 14
/// declared columns, a 15th value is Slicer 5's `positionStatus`: a point whose status is not 2 (defined) has no
/// position.
pub fn parse_fcsv(name: &Path, text: &str) -> Result<Vec<SlicerPoint>> {
    let text = strip_bom(text);
    let mut header = FcsvHeader::default();
    let mut rows: Vec<(u64, &str)> = Vec::new();
    for (lineno, line) in text.lines().enumerate() {
        let line = line.trim_end_matches('\r');
        if let Some(comment) = line.strip_prefix('#') {
            header.take(comment);
        } else if !line.trim().is_empty() {
            rows.push((lineno as u64 + 1, line));
        }
    }
    let ras = header.ras(name)?;
    let versioned = header.version.is_some();
    let cols: Vec<String> = header.columns.unwrap_or_else(|| {
        let default: &[&str] = if versioned { &FCSV_DEFAULT_COLUMNS } else { &FCSV_SLICER3_COLUMNS };
        default.iter().map(ToString::to_string).collect()
    });
    let find = |c: &str| cols.iter().position(|x| x == c);
    let (Some(ix), Some(iy), Some(iz)) = (find("x"), find("y"), find("z")) else {
        return Err(Error::invalid(name, format!("the columns line {cols:?} has no x, y and z")));
    };
    let (isel, ilabel) = (find("sel"), find("label"));
    let istatus = find("positionStatus")
        .or_else(|| (versioned && cols.len() <= FCSV_POSITION_STATUS_COLUMN).then_some(FCSV_POSITION_STATUS_COLUMN));

    let mut out = Vec::with_capacity(rows.len());
    for (i, (lineno, row)) in rows.into_iter().enumerate() {
        let f = split_csv_row(row);
        let label = ilabel.and_then(|k| f.get(k)).cloned().unwrap_or_default();
        let err = |problem: String| landmark_error(name, i, &label, Some(lineno), problem);
        let selected = match isel.and_then(|k| f.get(k)).map(|s| s.trim()) {
            None | Some("") => true,
            Some(s) => s.parse::<i64>().map_err(|_| err(format!("sel is {s:?}, not 0 or 1")))? != 0,
        };
        let defined = match istatus.and_then(|k| f.get(k)).map(|s| s.trim()) {
            None | Some("" | "2") => true,
            Some("0" | "1" | "3") => false,
            Some(s) => {
                return Err(err(format!(
                    "positionStatus is {s:?}, not 0 (undefined), 1 (preview), 2 (defined) or 3 (missing)"
                )));
            }
        };
        if !defined {
            out.push(SlicerPoint { label, selected, position: None });
            continue;
        }
        let mut xyz = [0.0; 3];
        for (c, &k) in [ix, iy, iz].iter().enumerate() {
            let s = f.get(k).map_or("", |s| s.trim());
            let v: f64 = s.parse().map_err(|_| err(format!("{} is {s:?}, not a number", axis(c))))?;
            if v.is_nan() {
                return Err(err(format!("{} is NaN", axis(c))));
            }
            if !v.is_finite() {
                return Err(err(format!("{} is not finite", axis(c))));
            }
            xyz[c] = v;
        }
        let p = Point3::from_array(xyz);
        out.push(SlicerPoint { label, selected, position: Some(if ras { flip_xy(p) } else { p }) });
    }
    Ok(out)
}

fn fcsv_text_field(s: &str) -> String {
    if s.contains([',', '"', '\n', '\r']) || s.starts_with(' ') {
        format!("\"{}\"", s.replace(['\n', '\r'], " ").replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

/// `.fcsv` text (version 4.11, LPS) for `points`. Points without a position cannot be stored.
pub fn to_fcsv(name: &Path, points: &[SlicerPoint]) -> Result<String> {
    let mut out = String::from("# Markups fiducial file version = 4.11\n# CoordinateSystem = LPS\n");
    out.push_str("# columns = ");
    out.push_str(&FCSV_DEFAULT_COLUMNS.join(","));
    out.push('\n');
    for (i, p) in points.iter().enumerate() {
        let Some(pt) = p.position else {
            return Err(landmark_error(
                name,
                i,
                &p.label,
                None,
                "has no position; .fcsv cannot store a missing point (use .mrk.json)",
            ));
        };
        check_finite(name, i, &p.label, "position", pt)?;
        let [x, y, z] = pt.coords();
        let _ = writeln!(
            out,
            "{},{},{},{},0,0,0,1,1,{},0,{},,",
            i + 1,
            num(x),
            num(y),
            num(z),
            u8::from(p.selected),
            fcsv_text_field(&p.label)
        );
    }
    Ok(out)
}

/// Writes `points` as a Slicer `.fcsv` file (version 4.11, LPS).
pub fn write_fcsv(path: &Path, points: &[SlicerPoint]) -> Result<()> {
    let text = to_fcsv(path, points)?;
    crate::write_atomic(path, |w| w.write_all(text.as_bytes()))
}

// ---------------------------------------------------------------------------------------------
// Slicer pairs

fn is_fcsv(path: &Path) -> bool {
    path.extension().is_some_and(|e| e.eq_ignore_ascii_case("fcsv"))
}

fn bigwarp_not_slicer(path: &Path) -> Error {
    Error::unsupported(
        path,
        "a BigWarp landmarks file (pairs of points), not a Slicer point list: read it as a file of pairs",
    )
}

/// Reads one Slicer point list, `.mrk.json` or `.fcsv`, told apart by content ([`detect_landmark_format`]); a
/// file named `.fcsv` is always read as one, so that its own header errors are the ones reported. A BigWarp file
/// (pairs) is refused, saying what it is.
pub fn read_slicer_points(path: &Path) -> Result<Vec<SlicerPoint>> {
    let text = read_text(path)?;
    if is_fcsv(path) {
        return parse_fcsv(path, &text);
    }
    match detect_landmark_format(path, &text) {
        Ok(LandmarkFileFormat::SlicerFcsv) => parse_fcsv(path, &text),
        Ok(LandmarkFileFormat::BigWarpJson) => Err(bigwarp_not_slicer(path)),
        Ok(LandmarkFileFormat::BigWarpCsv)
            if parse_bigwarp_csv(path, &text, BigWarpCsvOptions::default()).is_ok_and(|p| !p.is_empty()) =>
        {
            Err(bigwarp_not_slicer(path))
        }
        Ok(LandmarkFileFormat::BigWarpCsv) => Err(Error::invalid(
            path,
            "not a Slicer point list: neither a .mrk.json (JSON) nor a .fcsv (text that starts with # header lines)",
        )),
        // Slicer JSON, and JSON that is neither (parse_mrk_json says what it lacks).
        Ok(LandmarkFileFormat::SlicerMarkupsJson) | Err(_) => parse_mrk_json(path, &text),
    }
}

/// Reads a moving and a fixed Slicer point list and pairs them by index.
///
/// The name is the moving label (the fixed one when that is empty); the pair is active when both
/// points are selected. Lists of different lengths are an error that names both files.
pub fn read_slicer_pair(moving_path: &Path, fixed_path: &Path) -> Result<Vec<LandmarkPair>> {
    let moving = read_slicer_points(moving_path)?;
    let fixed = read_slicer_points(fixed_path)?;
    if moving.len() != fixed.len() {
        return Err(Error::invalid(
            fixed_path,
            format!(
                "the moving list {} has {} points but the fixed list {} has {}; Slicer lists are paired by index",
                moving_path.display(),
                moving.len(),
                fixed_path.display(),
                fixed.len()
            ),
        ));
    }
    Ok(moving
        .into_iter()
        .zip(fixed)
        .map(|(m, f)| LandmarkPair {
            name: if m.label.is_empty() { f.label } else { m.label },
            active: m.selected && f.selected,
            moving: m.position,
            fixed: f.position,
        })
        .collect())
}

/// Writes the moving and the fixed halves of `pairs` as two Slicer point lists (format by extension).
pub fn write_slicer_pair(moving_path: &Path, fixed_path: &Path, pairs: &[LandmarkPair]) -> Result<()> {
    let side = |moving: bool| -> Vec<SlicerPoint> {
        pairs
            .iter()
            .map(|p| SlicerPoint {
                label: p.name.clone(),
                selected: p.active,
                position: if moving { p.moving } else { p.fixed },
            })
            .collect()
    };
    let (m, f) = (side(true), side(false));
    // Render both before writing either, so a refused pair leaves neither file behind.
    let render =
        |path: &Path, pts: &[SlicerPoint]| if is_fcsv(path) { to_fcsv(path, pts) } else { to_mrk_json(path, pts) };
    let (mt, ft) = (render(moving_path, &m)?, render(fixed_path, &f)?);
    crate::write_atomic(moving_path, |w| w.write_all(mt.as_bytes()))?;
    crate::write_atomic(fixed_path, |w| w.write_all(ft.as_bytes()))
}
