//! Slicer Markups JSON (`.mrk.json`): one point list.

use std::path::Path;

use serde_json::{Value, json};

use super::bigwarp_csv::{axis, check_finite};
use super::bigwarp_json::{bigwarp_table, json_keys, parse_gson_json};
use super::errors::{bigwarp_not_slicer, landmark_error};
use super::points::SlicerPoint;
use super::text::{read_text, strip_bom};
use crate::error::{Error, Result};
use crate::geometry::Point3;

/// The schema URL written into `.mrk.json` files.
pub const MARKUPS_SCHEMA: &str = "https://raw.githubusercontent.com/slicer/slicer/master/Modules/Loadable/Markups/Resources/Schema/markups-schema-v1.0.3.json#";

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
