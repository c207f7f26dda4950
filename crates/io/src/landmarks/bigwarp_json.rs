//! BigWarp JSON (`landmarks.json`), as BigWarp's Gson writes and reads it.

use std::fmt::Write as _;
use std::path::Path;

use serde_json::Value;

use super::bigwarp_csv::{BigWarpCsvOptions, axis, check_finite, half_point, parse_java_double};
use super::errors::landmark_error;
use super::points::{LandmarkPair, flip_xy};
use super::text::{num, read_text, strip_bom};
use crate::error::{Error, Result};

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
pub(super) fn parse_gson_json(name: &Path, text: &str) -> Result<Value> {
    serde_json::from_str(&quote_nonfinite_tokens(strip_bom(text)))
        .map_err(|e| Error::invalid(name, format!("not JSON: {e}")))
}

/// The BigWarp landmark table inside `root`: `root` itself when its `type` is `BigWarpLandmarks`, or the object
/// under `landmarks` (BigWarp's Save landmarks to `.json`, `TransformWriterJson`), or under `Transform` →
/// `landmarks` (a BigWarp settings or project file, `BigwarpSettings`).
pub(super) fn bigwarp_table(root: &Value) -> Option<&serde_json::Map<String, Value>> {
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
pub(super) fn json_keys(root: &Value) -> String {
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

pub(super) fn not_bigwarp(name: &Path, root: &Value) -> Error {
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
