//! Two Slicer point lists, a moving and a fixed one, read and written as pairs by index.

use std::path::Path;

use super::bigwarp_csv::{BigWarpCsvOptions, parse_bigwarp_csv};
use super::detect::{LandmarkFileFormat, detect_landmark_format};
use super::errors::bigwarp_not_slicer;
use super::fcsv::{parse_fcsv, to_fcsv};
use super::mrk_json::{parse_mrk_json, to_mrk_json};
use super::points::{LandmarkPair, SlicerPoint};
use super::text::read_text;
use crate::error::{Error, Result};

fn is_fcsv(path: &Path) -> bool {
    path.extension().is_some_and(|e| e.eq_ignore_ascii_case("fcsv"))
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
        Ok(LandmarkFileFormat::PlainCsv) => Err(Error::unsupported(
            path,
            "a plain CSV of landmark pairs (its header names moving and fixed columns), not a Slicer point list: \
             read it as a file of pairs",
        )),
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
