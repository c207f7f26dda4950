//! Plain CSV of landmark pairs: a header that names every column and the coordinate system, one row per pair.
//!
//! ```text
//! name,active,moving_l,moving_p,moving_s,fixed_l,fixed_p,fixed_s
//! Pt-0,true,-12.5,30,8.25,-11.75,29.5,10
//! "nasion, left",false,,,,4,5,6
//! ```
//!
//! - The header is required. Its columns may come in any order and are matched without regard to case; other
//!   columns are ignored. The coordinate columns are `moving_l, moving_p, moving_s, fixed_l, fixed_p, fixed_s`
//!   (LPS mm) or `moving_r, moving_a, moving_s, fixed_r, fixed_a, fixed_s` (RAS mm: x and y are negated on read);
//!   a header with some of each is refused, so the coordinate system is never guessed.
//! - `name` is free text (quote it, RFC 4180, when it holds a comma or a quote); `active` is `true` or `false`, and
//!   may be left out (then every pair is active).
//! - A half not placed yet has all three of its fields empty.
//!
//! The writer writes the LPS header (or the RAS one) with Rust's shortest round-trip numbers, quoting only the
//! names that need it, so a write/read round trip is exact.

use std::path::Path;

use super::bigwarp_csv::check_finite;
use super::errors::landmark_error;
use super::points::{LandmarkPair, flip_xy};
use super::text::{num, read_text, strip_bom};
use crate::error::{Error, Result};
use crate::geometry::{Lps, Point3};

/// The coordinate system of a plain CSV's columns.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum CsvCoordinates {
    /// `moving_l, moving_p, moving_s, …`: LPS mm, as stored inside.
    #[default]
    Lps,
    /// `moving_r, moving_a, moving_s, …`: RAS mm.
    Ras,
}

impl CsvCoordinates {
    /// The letters of the three axes, as the header spells them.
    fn letters(self) -> [&'static str; 3] {
        match self {
            Self::Lps => ["l", "p", "s"],
            Self::Ras => ["r", "a", "s"],
        }
    }

    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Self::Lps => "LPS",
            Self::Ras => "RAS",
        }
    }
}

/// The header line [`to_plain_csv`] writes, without the newline.
#[must_use]
pub fn plain_csv_header(coordinates: CsvCoordinates) -> String {
    let [a, b, c] = coordinates.letters();
    format!("name,active,moving_{a},moving_{b},moving_{c},fixed_{a},fixed_{b},fixed_{c}")
}

/// Whether `text` (after one BOM) starts with a plain-CSV header: a first line whose first field is `name`,
/// unquoted. A BigWarp CSV quotes every field, so its first line starts with `"`.
#[must_use]
pub fn looks_like_plain_csv(text: &str) -> bool {
    let first = strip_bom(text).lines().next().unwrap_or("");
    first.split(',').next().is_some_and(|f| f.trim().eq_ignore_ascii_case("name"))
}

/// Reads a plain CSV of landmark pairs (module docs).
pub fn read_plain_csv(path: &Path) -> Result<Vec<LandmarkPair>> {
    parse_plain_csv(path, &read_text(path)?).map(|(pairs, _)| pairs)
}

/// Where each column of a plain CSV is.
struct Columns {
    name: usize,
    active: Option<usize>,
    /// moving x, y, z then fixed x, y, z, in the file's coordinate system.
    coords: [usize; 6],
    coordinates: CsvCoordinates,
}

fn locate_columns(name: &Path, header: &csv::StringRecord) -> Result<Columns> {
    let fields: Vec<String> = header.iter().map(|f| f.trim().to_ascii_lowercase()).collect();
    let find = |want: &str| fields.iter().position(|f| f == want);
    let has_any = |c: CsvCoordinates| {
        let [a, b, _] = c.letters();
        ["moving", "fixed"]
            .iter()
            .any(|side| find(&format!("{side}_{a}")).is_some() || find(&format!("{side}_{b}")).is_some())
    };
    let coordinates = match (has_any(CsvCoordinates::Lps), has_any(CsvCoordinates::Ras)) {
        (true, false) => CsvCoordinates::Lps,
        (false, true) => CsvCoordinates::Ras,
        (true, true) => {
            return Err(Error::invalid(
                name,
                "the header has both LPS (moving_l, moving_p) and RAS (moving_r, moving_a) columns; give one \
                 coordinate system",
            ));
        }
        (false, false) => {
            return Err(Error::invalid(
                name,
                format!(
                    "the header names no coordinate columns; a plain landmark CSV starts with `{}` (LPS mm) or `{}` \
                     (RAS mm)",
                    plain_csv_header(CsvCoordinates::Lps),
                    plain_csv_header(CsvCoordinates::Ras)
                ),
            ));
        }
    };
    let letters = coordinates.letters();
    let mut coords = [0; 6];
    for (k, slot) in coords.iter_mut().enumerate() {
        let want = format!("{}_{}", if k < 3 { "moving" } else { "fixed" }, letters[k % 3]);
        *slot = find(&want).ok_or_else(|| {
            Error::invalid(
                name,
                format!("the header has no `{want}` column (expected `{}`)", plain_csv_header(coordinates)),
            )
        })?;
    }
    let name_column = find("name").ok_or_else(|| Error::invalid(name, "the header has no `name` column"))?;
    Ok(Columns { name: name_column, active: find("active"), coords, coordinates })
}

/// Parses plain-CSV text (module docs); `name` is used in errors. Returns the pairs (LPS) and the file's
/// coordinate system.
pub fn parse_plain_csv(name: &Path, text: &str) -> Result<(Vec<LandmarkPair>, CsvCoordinates)> {
    let text = strip_bom(text);
    let mut reader = csv::ReaderBuilder::new().has_headers(true).flexible(true).from_reader(text.as_bytes());
    let header = reader.headers().map_err(|e| Error::invalid(name, format!("the header line: {e}")))?.clone();
    let columns = locate_columns(name, &header)?;
    let width = header.len();
    let mut pairs = Vec::new();
    for (i, record) in reader.records().enumerate() {
        let record = record.map_err(|e| Error::invalid(name, format!("landmark {} (1-based): {e}", i + 1)))?;
        let line = record.position().map(csv::Position::line);
        if record.iter().all(|f| f.trim().is_empty()) {
            continue;
        }
        let i = pairs.len();
        let label = record.get(columns.name).unwrap_or("").to_string();
        if record.len() != width {
            return Err(landmark_error(
                name,
                i,
                &label,
                line,
                format!("{} fields; the header has {width} columns", record.len()),
            ));
        }
        let active = match columns.active.map(|c| record.get(c).unwrap_or("").trim().to_ascii_lowercase()) {
            None => true,
            Some(a) if a == "true" => true,
            Some(a) if a == "false" => false,
            Some(other) => {
                return Err(landmark_error(name, i, &label, line, format!("active is {other:?}, not true or false")));
            }
        };
        let mut halves = [None, None];
        for (h, half) in halves.iter_mut().enumerate() {
            let side = if h == 0 { "moving" } else { "fixed" };
            let fields: [&str; 3] = std::array::from_fn(|c| record.get(columns.coords[3 * h + c]).unwrap_or("").trim());
            if fields.iter().all(|f| f.is_empty()) {
                continue;
            }
            let mut xyz = [0.0; 3];
            for (c, v) in xyz.iter_mut().enumerate() {
                let s = fields[c];
                let letter = columns.coordinates.letters()[c];
                *v = s.parse::<f64>().ok().filter(|v| v.is_finite()).ok_or_else(|| {
                    let problem = if s.is_empty() {
                        format!("{side}_{letter} is empty but the other two are not (leave all three empty for a point not placed)")
                    } else {
                        format!("{side}_{letter} is {s:?}, not a finite number")
                    };
                    landmark_error(name, i, &label, line, problem)
                })?;
            }
            let p = Point3::<Lps>::from_array(xyz);
            *half = Some(match columns.coordinates {
                CsvCoordinates::Lps => p,
                CsvCoordinates::Ras => flip_xy(p),
            });
        }
        let [moving, fixed] = halves;
        pairs.push(LandmarkPair { name: label, active, moving, fixed });
    }
    Ok((pairs, columns.coordinates))
}

/// Plain-CSV text for `pairs` in `coordinates`; `name` is used in errors (a point that is not finite).
pub fn to_plain_csv(name: &Path, pairs: &[LandmarkPair], coordinates: CsvCoordinates) -> Result<String> {
    let field = |s: &str| {
        if s.contains([',', '"', '\n', '\r']) || s.trim() != s {
            format!("\"{}\"", s.replace('"', "\"\""))
        } else {
            s.to_string()
        }
    };
    let mut out = plain_csv_header(coordinates);
    out.push('\n');
    for (i, p) in pairs.iter().enumerate() {
        let mut fields = vec![field(&p.name), if p.active { "true" } else { "false" }.to_string()];
        for (side, half) in [("moving", p.moving), ("fixed", p.fixed)] {
            match half {
                Some(pt) => {
                    check_finite(name, i, &p.name, side, pt)?;
                    let pt = match coordinates {
                        CsvCoordinates::Lps => pt,
                        CsvCoordinates::Ras => flip_xy(pt),
                    };
                    fields.extend(pt.coords().iter().map(|&v| num(v)));
                }
                None => fields.extend(std::iter::repeat_n(String::new(), 3)),
            }
        }
        out.push_str(&fields.join(","));
        out.push('\n');
    }
    Ok(out)
}

/// Writes `pairs` as a plain CSV in `coordinates`, atomically.
pub fn write_plain_csv(path: &Path, pairs: &[LandmarkPair], coordinates: CsvCoordinates) -> Result<()> {
    let text = to_plain_csv(path, pairs, coordinates)?;
    crate::write_atomic(path, |w| w.write_all(text.as_bytes()))
}

#[cfg(test)]
#[allow(
    clippy::unwrap_used,
    clippy::float_cmp,
    reason = "tests: a panic is the failure, and the values compared are exact"
)]
mod tests {
    use super::*;

    fn p(x: f64, y: f64, z: f64) -> Point3<Lps> {
        Point3::new(x, y, z)
    }

    #[test]
    fn a_round_trip_is_exact_in_both_coordinate_systems() {
        let pairs = vec![
            LandmarkPair::new("Pt-0", p(-12.5, 30.0, 8.25), p(0.1, 1e-7, -3.0)),
            LandmarkPair {
                name: "nasion, \"left\"".into(),
                active: false,
                moving: None,
                fixed: Some(p(4.0, 5.0, 6.0)),
            },
            LandmarkPair { name: " padded".into(), active: true, moving: Some(p(1.0, 2.0, 3.0)), fixed: None },
        ];
        for c in [CsvCoordinates::Lps, CsvCoordinates::Ras] {
            let text = to_plain_csv(Path::new("t.csv"), &pairs, c).unwrap();
            assert!(looks_like_plain_csv(&text));
            let (back, coordinates) = parse_plain_csv(Path::new("t.csv"), &text).unwrap();
            assert_eq!(back, pairs, "{text}");
            assert_eq!(coordinates, c);
        }
    }

    #[test]
    fn ras_columns_are_negated_in_x_and_y_and_columns_may_be_reordered() {
        let text = "\u{feff}Fixed_S,fixed_a,fixed_r,moving_s,moving_a,moving_r,NAME,comment\n3,2,1,6,5,4,a,x\n";
        let (pairs, c) = parse_plain_csv(Path::new("r.csv"), text).unwrap();
        assert_eq!(c, CsvCoordinates::Ras);
        assert_eq!(pairs, vec![LandmarkPair::new("a", p(-4.0, -5.0, 6.0), p(-1.0, -2.0, 3.0))]);
    }

    #[test]
    fn bad_files_are_refused_naming_the_landmark() {
        let err = |text: &str| parse_plain_csv(Path::new("bad.csv"), text).unwrap_err().to_string();
        let lps = plain_csv_header(CsvCoordinates::Lps);
        assert!(err("name,x,y,z\na,1,2,3\n").contains("names no coordinate columns"));
        assert!(err("name,moving_l,moving_p,moving_s,fixed_r,fixed_a,fixed_s\n").contains("both LPS"));
        assert!(err("name,moving_l,moving_p,moving_s,fixed_l,fixed_p\n").contains("no `fixed_s` column"));
        let e = err(&format!("{lps}\na,true,1,2,3,4,5,6\nb,true,1,,3,4,5,6\n"));
        assert!(e.contains("landmark 2") && e.contains("\"b\"") && e.contains("moving_p is empty"), "{e}");
        let e = err(&format!("{lps}\na,maybe,1,2,3,4,5,6\n"));
        assert!(e.contains("landmark 1") && e.contains("not true or false"), "{e}");
        assert!(err(&format!("{lps}\na,true,1,2,NaN,4,5,6\n")).contains("not a finite number"));
        assert!(err(&format!("{lps}\na,true,1,2,3\n")).contains("5 fields"));
        assert!(!looks_like_plain_csv("\"Pt-0\",\"true\",\"1\",\"2\",\"3\",\"4\",\"5\",\"6\"\n"));
    }
}
