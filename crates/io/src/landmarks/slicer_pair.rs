//! Two one-side point lists, a moving and a fixed one, read and written as pairs by index: Slicer lists (`.mrk.json`,
//! `.fcsv`) and elastix `point` files (elastix's fixed and moving point sets).

use std::path::Path;

use super::bigwarp_csv::{BigWarpCsvOptions, parse_bigwarp_csv};
use super::detect::{LandmarkFileFormat, detect_landmark_format};
use super::elastix_points::{ElastixPoints, looks_like_elastix_points, parse_elastix_points, to_elastix_points};
use super::errors::bigwarp_not_slicer;
use super::fcsv::{parse_fcsv, to_fcsv};
use super::mni_tag::parse_mni_tag_points;
use super::mrk_json::{parse_mrk_json, to_mrk_json};
use super::points::{LandmarkPair, SlicerPoint};
use super::text::read_text;
use crate::error::{Error, Result};

fn is_fcsv(path: &Path) -> bool {
    path.extension().is_some_and(|e| e.eq_ignore_ascii_case("fcsv"))
}

/// Whether `path` is named as an elastix point file (`.txt`, any case).
fn is_txt(path: &Path) -> bool {
    path.extension().is_some_and(|e| e.eq_ignore_ascii_case("txt"))
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
        Ok(LandmarkFileFormat::ElastixPoints) => Err(Error::unsupported(
            path,
            "an elastix point file, not a Slicer point list: read it as one side of a pair (read_slicer_pair) or as a \
             point file",
        )),
        Ok(LandmarkFileFormat::TransformixOutput) => Err(Error::unsupported(
            path,
            "transformix's outputpoints.txt holds pairs (each input point and its image), not a Slicer point list: \
             read it as a file of pairs",
        )),
        Ok(LandmarkFileFormat::MniTag) => parse_mni_tag_points(path, &text),
        Ok(LandmarkFileFormat::ItkThinPlateSpline) => Err(Error::unsupported(
            path,
            "an ITK transform file, not a Slicer point list: a thin-plate spline's file holds pairs (its landmarks); \
             read it as a file of pairs",
        )),
        // Slicer JSON, and JSON that is neither (parse_mrk_json says what it lacks).
        Ok(LandmarkFileFormat::SlicerMarkupsJson) | Err(_) => parse_mrk_json(path, &text),
    }
}

/// One side of a pair: an elastix `point` file (told by its content; an `index` file is refused, since no image is
/// known here), else a Slicer list ([`read_slicer_points`]). An elastix point is selected and unnamed.
fn read_one_side(path: &Path) -> Result<Vec<SlicerPoint>> {
    let text = read_text(path)?;
    if !is_fcsv(path) && looks_like_elastix_points(&text) {
        let file = parse_elastix_points(path, &text)?;
        let points = file.to_lps(path, None)?;
        return Ok(points
            .into_iter()
            .map(|p| SlicerPoint { label: String::new(), selected: true, position: Some(p) })
            .collect());
    }
    read_slicer_points(path)
}

/// Reads a moving and a fixed one-side list, each a Slicer list (`.mrk.json`, `.fcsv`) or an elastix `point` file,
/// and pairs them by index.
///
/// The name is the moving label (the fixed one when that is empty); the pair is active when both
/// points are selected. Lists of different lengths are an error that names both files.
pub fn read_slicer_pair(moving_path: &Path, fixed_path: &Path) -> Result<Vec<LandmarkPair>> {
    let moving = read_one_side(moving_path)?;
    let fixed = read_one_side(fixed_path)?;
    if moving.len() != fixed.len() {
        return Err(Error::invalid(
            fixed_path,
            format!(
                "the moving list {} has {} points but the fixed list {} has {}; the lists are paired by index",
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

/// Writes the moving and the fixed halves of `pairs` as two one-side lists, format by extension: `.fcsv`, `.txt` (an
/// elastix `point` file), else `.mrk.json`. An elastix file has no names, flags or missing points, so a `.txt` pair
/// holds the active pairs with both points (the ones a warp uses), and both files must then be `.txt`, so that they
/// still pair by order.
pub fn write_slicer_pair(moving_path: &Path, fixed_path: &Path, pairs: &[LandmarkPair]) -> Result<()> {
    match (is_txt(moving_path), is_txt(fixed_path)) {
        (true, true) => {
            let (m, f): (Vec<_>, Vec<_>) =
                pairs.iter().filter(|p| p.active).filter_map(|p| Some((p.moving?, p.fixed?))).unzip();
            let mt = to_elastix_points(moving_path, &ElastixPoints::from_lps(&m))?;
            let ft = to_elastix_points(fixed_path, &ElastixPoints::from_lps(&f))?;
            crate::write_atomic(moving_path, |w| w.write_all(mt.as_bytes()))?;
            return crate::write_atomic(fixed_path, |w| w.write_all(ft.as_bytes()));
        }
        (false, false) => {}
        (true, false) | (false, true) => {
            return Err(Error::invalid(
                if is_txt(moving_path) { fixed_path } else { moving_path },
                "write both lists as elastix point files (.txt) or both as Slicer lists: an elastix file holds only \
                 the active pairs with both points, so it would not pair by order with a Slicer list",
            ));
        }
    }
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
