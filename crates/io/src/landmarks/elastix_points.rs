//! elastix and transformix point files: the input point set of elastix's `CorrespondingPointsEuclideanDistanceMetric`
//! and of `transformix -def`, and transformix's result, `outputpoints.txt`.
//!
//! # The point file
//!
//! ```text
//! point                 or index
//! 3                     the number of points
//! 102.8 -33.4 57.0      one point a line, x y z, white space between
//! 178.1 -10.9 14.5
//! 180.4 -18.1 78.9
//! ```
//!
//! - `point`: physical coordinates in ITK's space, which is **LPS mm**, warpbench's own: read and written as they are.
//! - `index`: voxel indices (i j k) of an image: the fixed image for transformix's input and for elastix's fixed
//!   point set, the moving image for its moving point set. Their LPS position is `lps_from_index · (i, j, k)` of that
//!   image, so an index file is read and written only where a volume is known ([`ElastixPoints::to_lps`],
//!   [`ElastixPoints::set_lps`]); elsewhere it is refused. elastix rounds index values to the nearest voxel; we keep
//!   the fraction (the same for whole indices), and write continuous indices.
//! - A file without the word, whose first line is the count, is an `index` file (elastix before 3.503 wrote these;
//!   elastix still reads them so).
//!
//! elastix reads the numbers as a stream and ignores what follows the count's points. We are stricter: the count must
//! equal the point lines (an error names the count's line and the lines of points), each point line holds exactly 3
//! finite numbers, and blank lines are skipped. Written with Rust's shortest round-trip numbers, so a round trip is
//! exact.
//!
//! # transformix's `outputpoints.txt`
//!
//! One line a point, the fields separated by a tab and `;` (tabs shown as spaces here):
//!
//! ```text
//! Point    0    ; InputIndex = [ 10 20 30 ]    ; InputPoint = [ 10.000000 20.000000 30.000000 ]    ; OutputIndexFixed = [ 9 19 31 ]    ; OutputPoint = [ 9.500000 19.200000 31.100000 ]    ; Deformation = [ -0.500000 -0.800000 1.100000 ]
//! ```
//!
//! transformix maps each input point x of the fixed image by the registration's transform T, which (ITK's
//! convention) takes fixed points to moving points: `OutputPoint` = T(`InputPoint`), both LPS mm. So each line is a
//! landmark pair: the fixed point `InputPoint` and the moving point `OutputPoint` ([`transformix_pairs`]).
//! `OutputIndexMoving` (when transformix had the moving image) and the other fields are read but not needed.

use std::fmt::Write as _;
use std::path::Path;

use super::errors::landmark_error;
use super::points::LandmarkPair;
use super::text::{num, read_text, strip_bom};
use crate::error::{Error, Result};
use crate::geometry::{Index, Lps, Point3, Transform};

/// What an elastix point file's rows are.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ElastixPointKind {
    /// `point`: physical LPS mm.
    Point,
    /// `index`: voxel indices of an image.
    Index,
}

impl ElastixPointKind {
    /// The file's first word.
    #[must_use]
    pub fn word(self) -> &'static str {
        match self {
            Self::Point => "point",
            Self::Index => "index",
        }
    }
}

/// An elastix point file as read: the rows as the file holds them.
#[derive(Clone, Debug, PartialEq)]
pub struct ElastixPoints {
    pub kind: ElastixPointKind,
    /// LPS mm for [`ElastixPointKind::Point`], voxel indices (i, j, k) for [`ElastixPointKind::Index`].
    pub rows: Vec<[f64; 3]>,
    /// The 1-based line of each row (0 for a row made in memory).
    pub lines: Vec<u64>,
}

impl ElastixPoints {
    /// A `point` file of `points` (LPS mm).
    #[must_use]
    pub fn from_lps(points: &[Point3<Lps>]) -> Self {
        Self { kind: ElastixPointKind::Point, rows: points.iter().map(Point3::coords).collect(), lines: Vec::new() }
    }

    /// The rows in LPS mm: as they are for a `point` file; through `lps_from_index`, the image's, for an `index` file,
    /// which is refused without one. `name` is used in errors.
    pub fn to_lps(&self, name: &Path, lps_from_index: Option<&Transform<Lps, Index>>) -> Result<Vec<Point3<Lps>>> {
        match (self.kind, lps_from_index) {
            (ElastixPointKind::Point, _) => Ok(self.rows.iter().map(|&r| Point3::from_array(r)).collect()),
            (ElastixPointKind::Index, Some(t)) => {
                Ok(self.rows.iter().map(|&r| t.apply_point(Point3::from_array(r))).collect())
            }
            (ElastixPointKind::Index, None) => Err(index_needs_a_volume(name)),
        }
    }

    /// Replaces the rows by `points` (LPS mm), in this file's kind: as they are for `point`, through `index_from_lps`
    /// (the image whose indices the file holds) for `index`, which is refused without one.
    pub fn set_lps(
        &mut self,
        name: &Path,
        points: &[Point3<Lps>],
        index_from_lps: Option<&Transform<Index, Lps>>,
    ) -> Result<()> {
        self.rows = match (self.kind, index_from_lps) {
            (ElastixPointKind::Point, _) => points.iter().map(Point3::coords).collect(),
            (ElastixPointKind::Index, Some(t)) => points.iter().map(|&p| t.apply_point(p).coords()).collect(),
            (ElastixPointKind::Index, None) => return Err(index_needs_a_volume(name)),
        };
        Ok(())
    }
}

/// The error for an `index` file where no image says where its voxels are.
pub(super) fn index_needs_a_volume(name: &Path) -> Error {
    Error::unsupported(
        name,
        "an elastix \"index\" file holds voxel indices, which need the image they index to be placed in patient \
         space; here no volume is known: give a \"point\" file (physical LPS mm, as elastix's \"point\")",
    )
}

/// Whether `text` is an elastix point file: its first word is `point` or `index`, or its first line is a lone whole
/// number (a count, elastix before 3.503).
#[must_use]
pub fn looks_like_elastix_points(text: &str) -> bool {
    let mut lines = strip_bom(text).lines().map(str::trim).filter(|l| !l.is_empty());
    let Some(first) = lines.next() else { return false };
    let mut tokens = first.split_whitespace();
    match tokens.next() {
        Some("point" | "index") => tokens.next().is_none_or(|t| t.parse::<u64>().is_ok()),
        Some(t) => t.parse::<u64>().is_ok() && tokens.next().is_none(),
        None => false,
    }
}

/// Reads an elastix point file (module docs).
pub fn read_elastix_points(path: &Path) -> Result<ElastixPoints> {
    parse_elastix_points(path, &read_text(path)?)
}

/// Parses an elastix point file (module docs); `name` is used in errors, which give the line.
pub fn parse_elastix_points(name: &Path, text: &str) -> Result<ElastixPoints> {
    let mut lines =
        strip_bom(text).lines().enumerate().map(|(i, l)| (i as u64 + 1, l.trim())).filter(|(_, l)| !l.is_empty());
    let Some((first_line, first)) = lines.next() else {
        return Err(Error::invalid(
            name,
            "the file is empty: an elastix point file starts with \"point\" or \"index\"",
        ));
    };
    let mut tokens = first.split_whitespace();
    let word = tokens.next().unwrap_or_default();
    let count_token = |line: u64, t: &str| {
        t.parse::<usize>().map_err(|_| {
            Error::invalid(name, format!("line {line}: the number of points is {t:?}, not a whole number"))
        })
    };
    let (kind, count, count_line) = match word {
        "point" | "index" => {
            let kind = if word == "point" { ElastixPointKind::Point } else { ElastixPointKind::Index };
            if let Some(t) = tokens.next() {
                (kind, count_token(first_line, t)?, first_line)
            } else {
                let (line, l) = lines.next().ok_or_else(|| {
                    Error::invalid(
                        name,
                        format!("line {first_line}: \"{word}\" is not followed by the number of points"),
                    )
                })?;
                let mut t = l.split_whitespace();
                let count = count_token(line, t.next().unwrap_or_default())?;
                if t.next().is_some() {
                    return Err(Error::invalid(name, format!("line {line}: {l:?} is not the number of points alone")));
                }
                (kind, count, line)
            }
        }
        w if w.parse::<usize>().is_ok() => (ElastixPointKind::Index, count_token(first_line, w)?, first_line),
        w => {
            let shown: String = w.chars().take(40).collect();
            return Err(Error::invalid(
                name,
                format!(
                    "line {first_line}: {shown:?} is neither \"point\" nor \"index\" (an elastix point file's first word)"
                ),
            ));
        }
    };
    if tokens.next().is_some() {
        return Err(Error::invalid(name, format!("line {first_line}: {first:?} has more than a word and a count")));
    }
    let mut rows = Vec::new();
    let mut row_lines = Vec::new();
    for (line, l) in lines {
        let index0 = rows.len();
        let fields: Vec<&str> = l.split_whitespace().collect();
        let err = |problem: String| landmark_error(name, index0, "", Some(line), problem);
        if fields.len() != 3 {
            return Err(err(format!(
                "{} values; a point line holds x y z (3-D points only){}",
                fields.len(),
                if index0 >= count { format!(", and line {count_line} says {count} points") } else { String::new() }
            )));
        }
        let mut xyz = [0.0; 3];
        for (c, f) in fields.iter().enumerate() {
            xyz[c] = f
                .parse::<f64>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| err(format!("{} is {f:?}, not a finite number", ["x", "y", "z"][c])))?;
        }
        rows.push(xyz);
        row_lines.push(line);
    }
    if rows.len() != count {
        let span = match (row_lines.first(), row_lines.last()) {
            (Some(a), Some(b)) => format!(" (lines {a} to {b})"),
            _ => String::new(),
        };
        return Err(Error::invalid(
            name,
            format!("line {count_line} says {count} points, but the file has {}{span}", rows.len()),
        ));
    }
    Ok(ElastixPoints { kind, rows, lines: row_lines })
}

/// The text of an elastix point file: the word, the count, one row a line.
pub fn to_elastix_points(name: &Path, file: &ElastixPoints) -> Result<String> {
    let mut out = format!("{}\n{}\n", file.kind.word(), file.rows.len());
    for (i, r) in file.rows.iter().enumerate() {
        if !r.iter().all(|v| v.is_finite()) {
            return Err(landmark_error(name, i, "", None, format!("{r:?} is not finite")));
        }
        let _ = writeln!(out, "{} {} {}", num(r[0]), num(r[1]), num(r[2]));
    }
    Ok(out)
}

/// Writes an elastix point file atomically.
pub fn write_elastix_points(path: &Path, file: &ElastixPoints) -> Result<()> {
    let text = to_elastix_points(path, file)?;
    crate::write_atomic(path, |w| w.write_all(text.as_bytes()))
}

/// One line of transformix's `outputpoints.txt`.
#[derive(Clone, Debug, PartialEq)]
pub struct TransformixPoint {
    /// The number transformix gave the point (`Point 0`, …).
    pub number: u64,
    /// `InputPoint`: the fixed image's point, LPS mm.
    pub input_lps: Point3<Lps>,
    /// `OutputPoint`: T(`InputPoint`), the moving image's point, LPS mm.
    pub output_lps: Point3<Lps>,
}

/// Whether `text` is transformix's `outputpoints.txt`: its first line starts with `Point` and has an `OutputPoint`.
#[must_use]
pub fn looks_like_transformix_output(text: &str) -> bool {
    let first = strip_bom(text).lines().map(str::trim).find(|l| !l.is_empty()).unwrap_or_default();
    first.starts_with("Point") && first.contains("OutputPoint")
}

/// Parses transformix's `outputpoints.txt` (module docs); `name` is used in errors, which give the line.
pub fn parse_transformix_output(name: &Path, text: &str) -> Result<Vec<TransformixPoint>> {
    let mut out = Vec::new();
    for (i, l) in strip_bom(text).lines().enumerate() {
        let line = i as u64 + 1;
        let l = l.trim();
        if l.is_empty() {
            continue;
        }
        let index0 = out.len();
        let err = |problem: String| landmark_error(name, index0, "", Some(line), problem);
        let mut fields = l.split(';').map(str::trim);
        let head = fields.next().unwrap_or_default();
        let number = head
            .strip_prefix("Point")
            .and_then(|n| n.trim().parse::<u64>().ok())
            .ok_or_else(|| err(format!("starts {head:?}, not \"Point N\" (a transformix outputpoints.txt line)")))?;
        let (mut input, mut output) = (None, None);
        for f in fields {
            let Some((key, value)) = f.split_once('=') else { continue };
            let key = key.trim();
            if key != "InputPoint" && key != "OutputPoint" {
                continue;
            }
            let inner = value
                .trim()
                .strip_prefix('[')
                .and_then(|v| v.strip_suffix(']'))
                .ok_or_else(|| err(format!("{key} is {:?}, not [ x y z ]", value.trim())))?;
            let v: Vec<f64> = inner
                .split_whitespace()
                .map(|t| t.parse::<f64>().ok().filter(|x| x.is_finite()))
                .collect::<Option<_>>()
                .ok_or_else(|| err(format!("{key} [{inner}] is not a list of finite numbers")))?;
            let [x, y, z] = v[..] else {
                return Err(err(format!("{key} has {} values; 3-D points only", v.len())));
            };
            let p = Some(Point3::new(x, y, z));
            if key == "InputPoint" { input = p } else { output = p }
        }
        let (Some(input_lps), Some(output_lps)) = (input, output) else {
            return Err(err("lacks an InputPoint or an OutputPoint".to_owned()));
        };
        out.push(TransformixPoint { number, input_lps, output_lps });
    }
    if out.is_empty() {
        return Err(Error::invalid(
            name,
            "no points: transformix's outputpoints.txt has one \"Point N ; …\" line each",
        ));
    }
    Ok(out)
}

/// transformix's `outputpoints.txt` as landmark pairs: each line's `InputPoint` is the fixed point and its
/// `OutputPoint` (T of it: the registration maps fixed points to moving points) the moving point, named `Point N`.
pub fn transformix_pairs(name: &Path, text: &str) -> Result<Vec<LandmarkPair>> {
    Ok(parse_transformix_output(name, text)?
        .into_iter()
        .map(|p| LandmarkPair::new(format!("Point {}", p.number), p.output_lps, p.input_lps))
        .collect())
}

/// Reads transformix's `outputpoints.txt` as landmark pairs ([`transformix_pairs`]).
pub fn read_transformix_output(path: &Path) -> Result<Vec<LandmarkPair>> {
    transformix_pairs(path, &read_text(path)?)
}
