//! MNI tag point files (`.tag`): the landmark pairs of the McConnell Brain Imaging Centre's `register`, read by
//! `tagtoxfm` and minc-toolkit, VTK's `vtkMNITagPointReader` and 3D Slicer's MINC extension.
//!
//! ```text
//! MNI Tag Point File
//! Volumes = 2;
//! % comments
//!
//! Points =
//!  x1 y1 z1 x2 y2 z2 [weight structure_id patient_id] ["label"]
//!  … ;
//! ```
//!
//! Coordinates are world RAS mm (MINC's world), converted to LPS here. **Volume 1 is the fixed (target) volume and
//! volume 2 the moving (source) one**: the transform `register` and `tagtoxfm` compute from a file maps volume 2's
//! points onto volume 1's (volume_io's `compute_transform_from_tags`: "the transform is from tag_list2 to tag_list1";
//! `register` keeps it as `v2_to_v1_transform`), so a file of pairs warps volume 2 onto volume 1. The optional weight,
//! structure id and patient id are read and not kept; the label, a double-quoted string with C escapes (as VTK reads
//! it), is the pair's name. A file of one volume holds one side: refused as a file of pairs, it is read as a point list
//! ([`parse_mni_tag_points`]), beside the other side's list. A tag file has no
//! inactive or half-placed points: [`to_mni_tag`] refuses a pair that is either, naming it.

use std::path::Path;

use super::errors::landmark_error;
use super::points::{LandmarkPair, SlicerPoint, flip_xy};
use super::text::{num, read_text, strip_bom};
use crate::error::{Error, Result};
use crate::geometry::{Lps, Point3};

const MAGIC: &str = "MNI Tag Point File";

/// Whether `text` starts as an MNI tag point file does (after a byte-order mark and white space).
#[must_use]
pub fn looks_like_mni_tag(text: &str) -> bool {
    strip_bom(text).trim_start().starts_with(MAGIC)
}

/// Reads the pairs of the two-volume tag file at `path` (module docs).
pub fn read_mni_tag(path: &Path) -> Result<Vec<LandmarkPair>> {
    parse_mni_tag(path, &read_text(path)?)
}

/// [`read_mni_tag`] of a text; `name` is used in errors.
///
/// # Errors
/// Not a tag file, one volume, a malformed entry (named by its 1-based index and line), a coordinate that is not a
/// finite number.
pub fn parse_mni_tag(name: &Path, text: &str) -> Result<Vec<LandmarkPair>> {
    let (volumes, entries) = parse(name, text)?;
    if volumes == 1 {
        return Err(Error::unsupported(
            name,
            "an MNI tag file of one volume holds the points of one side, not pairs; a file of pairs says Volumes = 2 \
             (one of one volume is read as a point list, with the other side's list beside it)",
        ));
    }
    Ok(entries
        .into_iter()
        .map(|(points, label)| LandmarkPair::new(label, flip_xy(points[1]), flip_xy(points[0])))
        .collect())
}

/// The points of a tag file of one volume (`Volumes = 1;`), as a point list of one side (LPS, its labels; every
/// point selected and placed); `name` is used in errors.
///
/// # Errors
/// As [`parse_mni_tag`]; a file of two volumes, which holds pairs.
pub fn parse_mni_tag_points(name: &Path, text: &str) -> Result<Vec<SlicerPoint>> {
    let (volumes, entries) = parse(name, text)?;
    if volumes == 2 {
        return Err(Error::unsupported(
            name,
            "an MNI tag file of two volumes holds pairs (volume 1 the fixed points, volume 2 the moving ones), not \
             the points of one side: read it as a file of pairs",
        ));
    }
    Ok(entries
        .into_iter()
        .map(|(points, label)| SlicerPoint { label, selected: true, position: Some(flip_xy(points[0])) })
        .collect())
}

/// One entry of a tag file: a point per volume (RAS, as stored) and the label.
type Entry = (Vec<Point3<Lps>>, String);

/// The number of volumes and the entries.
fn parse(name: &Path, text: &str) -> Result<(usize, Vec<Entry>)> {
    let mut s = Scanner { text: strip_bom(text), at: 0, line: 1 };
    s.skip_space();
    if !s.rest().starts_with(MAGIC) {
        return Err(Error::invalid(name, format!("not an MNI tag point file: it does not start with {MAGIC:?}")));
    }
    s.at += MAGIC.len();
    let volumes = match s.assignment(name, "Volumes")?.as_str() {
        "1" => 1,
        "2" => 2,
        other => {
            return Err(Error::invalid(name, format!("line {}: Volumes = {other}; a tag file has 1 or 2", s.line)));
        }
    };
    s.keyword(name, "Points")?;
    let mut entries = Vec::new();
    loop {
        s.skip_space();
        if s.rest().starts_with(';') {
            break;
        }
        if s.rest().is_empty() {
            return Err(Error::truncated(name, "the points end without the closing ;"));
        }
        let index = entries.len();
        let line = u64::from(s.line);
        let bad = |problem: String| landmark_error(name, index, "", Some(line), problem);
        let mut xyz = vec![0.0; 3 * volumes];
        for (k, v) in xyz.iter_mut().enumerate() {
            *v = s.number().ok_or_else(|| bad(format!("coordinate {} is missing or not a number", k + 1)))?;
            if !v.is_finite() {
                return Err(bad(format!("coordinate {} is {v}", k + 1)));
            }
        }
        // What follows on the point's own line, as VTK and volume_io read it: weight, structure id and patient id
        // (read, not kept), then the label.
        s.skip_blanks();
        if s.number_follows() {
            for what in ["weight", "structure id", "patient id"] {
                s.skip_blanks();
                if !s.number_follows() {
                    return Err(bad(format!("its {what} is missing or not a number")));
                }
                s.number();
            }
            s.skip_blanks();
        }
        let label = if s.rest().starts_with('"') { s.quoted().map_err(|e| bad(e.to_string()))? } else { String::new() };
        let points = xyz.chunks_exact(3).map(|p| Point3::new(p[0], p[1], p[2])).collect();
        entries.push((points, label));
    }
    Ok((volumes, entries))
}

/// The text of a tag file of `pairs` (module docs): volume 1 the fixed points, volume 2 the moving ones, RAS mm.
///
/// # Errors
/// A pair that is inactive or misses a half (a tag file has no way to say either: BigWarp's files keep them), or whose
/// name holds a double quote, a backslash or a line break (MNI's reader does not unescape them).
pub fn to_mni_tag(name: &Path, pairs: &[LandmarkPair]) -> Result<String> {
    let mut out = format!(
        "{MAGIC}\nVolumes = 2;\n% Written by warpbench: volume 1 holds the fixed (target) points, volume 2 the moving \
         (source) ones, in RAS mm.\n\nPoints =\n"
    );
    for (i, p) in pairs.iter().enumerate() {
        let bad = |problem: &str| landmark_error(name, i, &p.name, None, problem);
        let (Some(fixed), Some(moving)) = (p.fixed, p.moving) else {
            return Err(bad("misses a half; an MNI tag file holds complete pairs only (BigWarp's files keep it)"));
        };
        if !p.active {
            return Err(bad("is inactive; an MNI tag file has no inactive points (BigWarp's files keep the flag)"));
        }
        if p.name.contains(['"', '\\', '\n', '\r']) {
            return Err(bad(
                "has a name with a double quote, a backslash or a line break, which MNI's reader misreads",
            ));
        }
        let coords = flip_xy(fixed).coords().into_iter().chain(flip_xy(moving).coords());
        for x in coords {
            out.push(' ');
            out.push_str(&num(x));
        }
        if !p.name.is_empty() {
            out.push_str(" \"");
            out.push_str(&p.name);
            out.push('"');
        }
        out.push('\n');
    }
    out.push_str(";\n");
    Ok(out)
}

/// Writes `pairs` as an MNI tag file at `path` ([`to_mni_tag`]), atomically.
pub fn write_mni_tag(path: &Path, pairs: &[LandmarkPair]) -> Result<()> {
    let text = to_mni_tag(path, pairs)?;
    crate::write_atomic(path, |w| w.write_all(text.as_bytes()))
}

/// A position in the text, counting lines; `%` starts a comment to the end of its line.
struct Scanner<'a> {
    text: &'a str,
    at: usize,
    line: u32,
}

impl Scanner<'_> {
    fn rest(&self) -> &str {
        &self.text[self.at..]
    }

    fn bump(&mut self, n: usize) {
        self.line += self.text[self.at..self.at + n].matches('\n').count() as u32;
        self.at += n;
    }

    fn skip_space(&mut self) {
        loop {
            let rest = self.rest();
            let ws = rest.len() - rest.trim_start().len();
            self.bump(ws);
            if self.rest().starts_with('%') {
                let end = self.rest().find('\n').unwrap_or(self.rest().len());
                self.bump(end);
            } else {
                return;
            }
        }
    }

    /// Spaces and tabs, not line breaks.
    fn skip_blanks(&mut self) {
        let rest = self.rest();
        let n = rest.len() - rest.trim_start_matches([' ', '\t']).len();
        self.bump(n);
    }

    /// `key = value;`, the value's text.
    fn assignment(&mut self, name: &Path, key: &str) -> Result<String> {
        self.keyword(name, key)?;
        let end = self.rest().find(';').ok_or_else(|| Error::invalid(name, format!("{key} = has no closing ;")))?;
        let value = self.rest()[..end].trim().to_string();
        self.bump(end + 1);
        Ok(value)
    }

    /// `key =`.
    fn keyword(&mut self, name: &Path, key: &str) -> Result<()> {
        self.skip_space();
        let found = self.rest().strip_prefix(key).map(str::trim_start).is_some_and(|r| r.starts_with('='));
        if !found {
            let got: String = self.rest().chars().take(30).collect();
            return Err(Error::invalid(name, format!("line {}: expected {key} =, found {got:?}", self.line)));
        }
        let eq = self.rest().find('=').unwrap_or(0);
        self.bump(eq + 1);
        Ok(())
    }

    fn token(&self) -> &str {
        let rest = self.rest();
        let end = rest.find(|c: char| c.is_whitespace() || c == ';' || c == '"' || c == '%').unwrap_or(rest.len());
        &rest[..end]
    }

    fn number_follows(&self) -> bool {
        self.token().parse::<f64>().is_ok()
    }

    fn number(&mut self) -> Option<f64> {
        self.skip_space();
        let token = self.token();
        let value = token.parse::<f64>().ok()?;
        let n = token.len();
        self.bump(n);
        Some(value)
    }

    /// A double-quoted string with C's escapes (`\"`, `\\`, `\n`, …), as VTK reads it.
    fn quoted(&mut self) -> std::result::Result<String, &'static str> {
        let mut out = String::new();
        let mut chars = self.rest()[1..].char_indices();
        while let Some((k, c)) = chars.next() {
            match c {
                '"' => {
                    self.bump(k + 2);
                    return Ok(out);
                }
                '\n' => return Err("its label runs past the end of its line"),
                '\\' => {
                    let Some((_, e)) = chars.next() else { break };
                    out.push(match e {
                        'n' => '\n',
                        't' => '\t',
                        'r' => '\r',
                        other => other,
                    });
                }
                c => out.push(c),
            }
        }
        Err("its label has no closing quote")
    }
}
