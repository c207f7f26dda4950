//! BigWarp CSV: one row per pair, the moving point then the fixed point, in the BigWarp column order.

use std::path::Path;

use super::errors::landmark_error;
use super::points::{LandmarkPair, flip_xy};
use super::text::{num, read_text, strip_bom};
use crate::error::{Error, Result};
use crate::geometry::{Lps, Point3};

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

pub(super) fn axis(c: usize) -> &'static str {
    ["x", "y", "z"][c]
}

/// Java's `Double.toString` spellings (`Infinity`, `-Infinity`, `NaN`) and ordinary numbers.
pub(super) fn parse_java_double(s: &str) -> Option<f64> {
    match s {
        "Infinity" | "+Infinity" => Some(f64::INFINITY),
        "-Infinity" => Some(f64::NEG_INFINITY),
        "NaN" => Some(f64::NAN),
        _ => s.parse().ok(),
    }
}

/// All three coordinates infinite → a missing half; all finite → a point; anything else is an error.
pub(super) fn half_point(
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

pub(super) fn check_finite(name: &Path, i: usize, label: &str, side: &str, p: Point3<Lps>) -> Result<()> {
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
