//! Slicer `.fcsv` fiducial lists (the 14-column form Slicer writes, and the 6 columns of Slicer 3).

use std::fmt::Write as _;
use std::path::Path;

use super::bigwarp_csv::{axis, check_finite};
use super::errors::landmark_error;
use super::points::{SlicerPoint, flip_xy};
use super::text::{num, read_text, strip_bom};
use crate::error::{Error, Result};
use crate::geometry::Point3;

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
