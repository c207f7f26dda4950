//! MNI transform files (`.xfm`): the transforms of minc-toolkit (`minctracc`, `bestlinreg`, `tagtoxfm`, `xfmconcat`),
//! taken by `mincresample -transformation`, read by ITK's `MINCTransformIO` and VTK's `vtkMNITransformReader`.
//!
//! ```text
//! MNI Transform File
//! % comments
//!
//! Transform_Type = Linear;
//! Linear_Transform =
//!  a b c d
//!  e f g h
//!  i j k l;
//! ```
//!
//! Each `Transform_Type` starts a transform: `Linear` (the 3 × 4 matrix of `Linear_Transform`, rows), `Grid_Transform`
//! (a displacement field in a MINC file, `Displacement_Volume`) or `Thin_Plate_Spline_Transform`; an
//! `Invert_Flag = True;` before or after its matrix inverts it. Several are applied first to last. Points are world
//! RAS mm. **A file maps the source (moving) volume's world to the target (fixed) one's**, as `minctracc source target
//! out.xfm` writes it and `mincresample -transformation out.xfm source -like target` takes it, and as `register` and
//! `tagtoxfm` compute it from a tag file (volume 2 onto volume 1, [`crate::landmarks::read_mni_tag`]).
//!
//! Read: [`read`] (the transforms), [`read_map`] and [`read_affine`] (linear ones composed, the latter as the pull-back
//! `moving_from_fixed` in LPS, the inverse of the file's map), [`read_field`] (one grid transform as the displacement
//! field of its MINC grid: the forward map, or the pull-back when inverted). A thin-plate-spline transform is refused,
//! naming itself. Written ([`to_text`], [`write()`]) as one `Linear` transform, in shortest round-trip numbers.

use std::path::Path;

use nalgebra::{Matrix3, Matrix4};

use crate::error::{Error, Result};
use crate::geometry::{Lps, Ras, Transform, lps_from_ras, ras_from_lps};
use crate::itk_tfm::ItkAffine;

const MAGIC: &str = "MNI Transform File";

/// The longest `.xfm` read: a linear file is a few hundred bytes, a thin-plate spline's some kilobytes.
const MAX_BYTES: u64 = 16 << 20;

/// Whether `path` is named as an MNI transform file (`.xfm`, any case).
#[must_use]
pub fn is_xfm_name(path: &Path) -> bool {
    path.extension().is_some_and(|e| e.eq_ignore_ascii_case("xfm"))
}

/// Whether `head`, a file's first bytes, starts as an MNI transform file does.
#[must_use]
pub fn looks_like_xfm(head: &[u8]) -> bool {
    crate::files::head_text(head).is_some_and(|t| t.trim_start_matches('\u{feff}').trim_start().starts_with(MAGIC))
}

/// One transform of a file.
#[derive(Clone, Debug, PartialEq)]
pub enum XfmStep {
    /// A linear map (RAS mm), already inverted when the file said `Invert_Flag = True`.
    Linear(Matrix4<f64>),
    /// A `Grid_Transform`: x ↦ x + D(x), D the vectors of the MINC file `volume` (its name resolved against the
    /// transform file's folder, as volume_io resolves it), or that map's inverse when `inverted`.
    Grid { volume: std::path::PathBuf, inverted: bool },
    /// A transform warpbench does not read: its `Transform_Type`.
    Other(String),
}

/// The transforms of the file at `path`, in the order they apply.
///
/// # Errors
/// Not an MNI transform file, a malformed statement (named by its line), a singular linear transform under
/// `Invert_Flag`.
pub fn read(path: &Path) -> Result<Vec<XfmStep>> {
    parse(path, &crate::files::read_small_text(path, MAX_BYTES, "an MNI transform file")?)
}

/// [`read`] of a text; `name` is used in errors.
///
/// # Errors
/// As [`read`].
pub fn parse(name: &Path, text: &str) -> Result<Vec<XfmStep>> {
    let body = text.trim_start_matches('\u{feff}').trim_start();
    let Some(rest) = body.strip_prefix(MAGIC) else {
        return Err(Error::invalid(name, format!("not an MNI transform file: it does not start with {MAGIC:?}")));
    };
    // Each transform: its type, its line, its matrix once read, and whether it is inverted (the flag may come before
    // or after the matrix: VTK writes it before, volume_io after).
    let mut raw: Vec<(String, usize, Option<Matrix4<f64>>, bool)> = Vec::new();
    let mut volumes: Vec<(usize, String)> = Vec::new();
    for Statement { line, key, value } in statements(name, rest)? {
        let at = |problem: String| Error::invalid(name, format!("line {line}: {problem}"));
        match key.as_str() {
            "Transform_Type" => raw.push((value, line, None, false)),
            "Linear_Transform" => {
                let numbers: Vec<f64> = value
                    .split_whitespace()
                    .map(|w| w.parse::<f64>().map_err(|_| at(format!("{w:?} in Linear_Transform is not a number"))))
                    .collect::<Result<_>>()?;
                if numbers.len() != 12 || numbers.iter().any(|x| !x.is_finite()) {
                    return Err(at(format!("Linear_Transform has {} numbers; it takes 12 finite ones", numbers.len())));
                }
                match raw.last_mut() {
                    Some((kind, _, matrix @ None, _)) if kind == "Linear" => {
                        let row =
                            |r: usize, c: usize| if r < 3 { numbers[4 * r + c] } else { f64::from(u8::from(c == 3)) };
                        *matrix = Some(Matrix4::from_fn(row));
                    }
                    _ => return Err(at("Linear_Transform outside a Transform_Type = Linear".to_string())),
                }
            }
            "Invert_Flag" => {
                let invert = match value.as_str() {
                    "True" | "TRUE" | "true" => true,
                    "False" | "FALSE" | "false" => false,
                    other => return Err(at(format!("Invert_Flag is {other:?}, not True or False"))),
                };
                let Some((_, _, _, inverted)) = raw.last_mut() else {
                    return Err(at("Invert_Flag before any Transform_Type".to_string()));
                };
                *inverted = invert;
            }
            "Displacement_Volume" => match raw.last() {
                Some((kind, ..)) if kind == "Grid_Transform" => volumes.push((raw.len() - 1, value)),
                _ => return Err(at("Displacement_Volume outside a Transform_Type = Grid_Transform".to_string())),
            },
            // The thin-plate spline's Points and Displacements, …: their transform is refused.
            _ => {}
        }
    }
    if raw.is_empty() {
        return Err(Error::invalid(name, "the file holds no transform (no Transform_Type)"));
    }
    let folder = name.parent().unwrap_or(Path::new(""));
    raw.into_iter()
        .enumerate()
        .map(|(k, (kind, line, matrix, inverted))| match (kind.as_str(), matrix) {
            ("Linear", Some(m)) if inverted => m.try_inverse().map(XfmStep::Linear).ok_or_else(|| {
                Error::invalid(name, format!("line {line}: Invert_Flag on a singular linear transform"))
            }),
            ("Linear", Some(m)) => Ok(XfmStep::Linear(m)),
            ("Linear", None) => {
                Err(Error::invalid(name, format!("line {line}: a Transform_Type = Linear has no Linear_Transform")))
            }
            ("Grid_Transform", _) => match volumes.iter().find(|(step, _)| *step == k) {
                Some((_, file)) => Ok(XfmStep::Grid { volume: folder.join(file), inverted }),
                None => Err(Error::invalid(name, format!("line {line}: a Grid_Transform has no Displacement_Volume"))),
            },
            (_, _) => Ok(XfmStep::Other(if inverted { format!("{kind} (inverted)") } else { kind })),
        })
        .collect()
}

/// One `Key = value;` statement, the value's text with its line breaks.
struct Statement {
    line: usize,
    key: String,
    value: String,
}

/// The statements of `text` (what follows the magic line), `%` comments removed; `name` is used in errors.
fn statements(name: &Path, text: &str) -> Result<Vec<Statement>> {
    let clean: String = text.lines().flat_map(|l| [l.split('%').next().unwrap_or(""), "\n"]).collect();
    let mut out = Vec::new();
    let mut line = 1; // the magic's line
    let mut rest = clean.as_str();
    while let Some(end) = rest.find(';') {
        let piece = &rest[..end];
        let lead = piece.len() - piece.trim_start().len();
        let start = line + piece[..lead].matches('\n').count();
        line += piece.matches('\n').count();
        let Some((key, value)) = piece.split_once('=') else {
            return Err(Error::invalid(name, format!("line {start}: {:?} is not Key = value;", piece.trim())));
        };
        out.push(Statement { line: start, key: key.trim().to_string(), value: value.trim().to_string() });
        rest = &rest[end + 1..];
    }
    if !rest.trim().is_empty() {
        return Err(Error::invalid(name, format!("line {line}: {:?} has no closing ;", rest.trim())));
    }
    Ok(out)
}

/// The map of the file at `path` (its transforms composed, source to target, RAS mm), when every one is linear.
///
/// # Errors
/// As [`read`]; a transform that is not linear (named, with what to do).
pub fn read_map(path: &Path) -> Result<Matrix4<f64>> {
    compose(path, &read(path)?)
}

/// The steps composed, first applied first.
fn compose(name: &Path, steps: &[XfmStep]) -> Result<Matrix4<f64>> {
    steps.iter().try_fold(Matrix4::identity(), |acc, step| match step {
        XfmStep::Linear(m) => Ok(m * acc),
        XfmStep::Grid { .. } => Err(Error::unsupported(
            name,
            "it holds a Grid_Transform, which is nonlinear: give it as a displacement field (--field), not as a \
             starting transform",
        )),
        XfmStep::Other(kind) => Err(Error::unsupported(
            name,
            format!(
                "it holds a {kind} transform; warpbench reads linear MNI transforms and grid transforms (a thin-plate \
                 spline can be sampled into a displacement field by minc-toolkit's `minc_displacement`)"
            ),
        )),
    })
}

/// The displacement field of an MNI transform file holding one `Grid_Transform` (module docs): its grid's vectors in
/// LPS mm, on the grid's own geometry. The file maps the moving volume's world to the fixed one's, so the field is the
/// forward map (moving → fixed) and its caller inverts it; with `Invert_Flag = True` the grid holds the inverse map,
/// and is the pull-back itself.
///
/// # Errors
/// As [`read`]; a file of anything but one grid transform (a linear one with it is refused: give it to `--initial`
/// and the grid alone to `--field`), a displacement volume that cannot be read (named).
pub fn read_field(path: &Path) -> Result<crate::displacement::ReadField> {
    use crate::displacement::{FieldDirection, FieldFormat, FieldSource, ReadField};
    let steps = read(path)?;
    let [XfmStep::Grid { volume, inverted }] = steps.as_slice() else {
        let kinds: Vec<&str> = steps
            .iter()
            .map(|s| match s {
                XfmStep::Linear(_) => "Linear",
                XfmStep::Grid { .. } => "Grid_Transform",
                XfmStep::Other(kind) => kind.as_str(),
            })
            .collect();
        return Err(Error::unsupported(
            path,
            format!(
                "a displacement field is read from an MNI transform file of one Grid_Transform; this one holds {}: \
                 split it (xfminvert, xfmconcat), the linear part for --initial",
                kinds.join(", ")
            ),
        ));
    };
    let field = crate::minc::read_displacements(volume).map_err(|e| {
        Error::invalid(path, format!("its Displacement_Volume {} cannot be read: {e}", volume.display()))
    })?;
    let direction = if *inverted { FieldDirection::Pullback } else { FieldDirection::Forward };
    Ok(ReadField {
        field,
        source: FieldSource::Field(FieldFormat::Minc),
        direction: Some(direction),
        warnings: Vec::new(),
    })
}

/// The grid file [`write_grid`] writes beside the transform file `path`: `NAME_grid_0.mnc` for `NAME.xfm`.
#[must_use]
pub fn grid_file_of(path: &Path) -> std::path::PathBuf {
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let stem = match name.len().checked_sub(4) {
        Some(cut) if name.is_char_boundary(cut) && name[cut..].eq_ignore_ascii_case(".xfm") => &name[..cut],
        _ => name.as_str(),
    };
    path.with_file_name(format!("{stem}_grid_0.mnc"))
}

/// Writes a displacement field as an MNI transform file of one `Grid_Transform` at `path` (`.xfm`), its vectors in the
/// MINC 2 file `NAME_grid_0.mnc` beside it (as ITK names it; [`crate::minc::grid_to_bytes`]): the grid first, then the
/// transform file, each atomically. The file maps the moving volume's world to the fixed one's, so a `Forward` field
/// (moving → fixed) is written as it is and a `Pullback` one with `Invert_Flag = True`.
///
/// # Errors
/// What [`crate::minc::grid_to_bytes`] refuses; the writes.
pub fn write_grid(
    path: &Path,
    direction: crate::displacement::FieldDirection,
    dims: [usize; 3],
    lps_from_index: &crate::geometry::Transform<crate::geometry::Lps, crate::geometry::Index>,
    displacements_lps: &[[f32; 3]],
) -> Result<()> {
    let grid = grid_file_of(path);
    let grid_name = grid.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let bytes = crate::minc::grid_to_bytes(&grid, dims, lps_from_index, displacements_lps)?;
    crate::write_atomic(&grid, |w| w.write_all(&bytes))?;
    let invert = match direction {
        crate::displacement::FieldDirection::Pullback => "Invert_Flag = True;\n",
        crate::displacement::FieldDirection::Forward => "",
    };
    let text = format!(
        "{MAGIC}\n% Written by warpbench: maps the moving (source) volume's world to the fixed (target) one's, RAS mm,\n\
         % as mincresample -transformation takes it.\n\nTransform_Type = Grid_Transform;\n{invert}\
         Displacement_Volume = {grid_name};\n"
    );
    crate::write_atomic(path, |w| w.write_all(text.as_bytes()))
}

/// The map `m` between RAS spaces as the same map between LPS ones (`lps_from_ras · m · ras_from_lps`).
fn lps_of(m: Matrix4<f64>) -> Matrix4<f64> {
    *(lps_from_ras() * Transform::<Ras, Ras>::from_matrix(m) * ras_from_lps()).matrix()
}

/// The starting transform of the file at `path`: the pull-back `moving_from_fixed` in LPS mm, the inverse of the
/// file's map (module docs).
///
/// # Errors
/// As [`read_map`]; a map that cannot be inverted.
pub fn read_affine(path: &Path) -> Result<ItkAffine> {
    let u = lps_of(read_map(path)?)
        .try_inverse()
        .ok_or_else(|| Error::invalid(path, "the transform is singular, so it has no pull-back"))?;
    let matrix = Matrix3::from_fn(|r, c| u[(r, c)]);
    Ok(ItkAffine::from_offset(matrix, [u[(0, 3)], u[(1, 3)], u[(2, 3)]]))
}

/// The text of a linear MNI transform file of the pull-back `moving_from_fixed` (LPS mm): its inverse, the map from the
/// moving volume's world to the fixed one's, in RAS.
///
/// # Errors
/// A pull-back that is not finite or not invertible; `name` is used in the message.
pub fn to_text(name: &Path, moving_from_fixed: &Matrix4<f64>) -> Result<String> {
    let t = moving_from_fixed
        .try_inverse()
        .filter(|m| m.iter().all(|x| x.is_finite()))
        .ok_or_else(|| Error::invalid(name, "the transform is not finite or not invertible"))?;
    let t = *(ras_from_lps() * Transform::<Lps, Lps>::from_matrix(t) * lps_from_ras()).matrix();
    let mut out = format!(
        "{MAGIC}\n% Written by warpbench: maps the moving (source) volume's world to the fixed (target) one's, RAS mm,\n\
         % as mincresample -transformation takes it.\n\nTransform_Type = Linear;\nLinear_Transform =\n"
    );
    for r in 0..3 {
        let row: Vec<String> = (0..4).map(|c| format!("{:?}", t[(r, c)])).collect();
        out.push(' ');
        out.push_str(&row.join(" "));
        out.push_str(if r == 2 { ";\n" } else { "\n" });
    }
    Ok(out)
}

/// Writes [`to_text`] at `path`, atomically.
///
/// # Errors
/// As [`to_text`]; the write's.
pub fn write(path: &Path, moving_from_fixed: &Matrix4<f64>) -> Result<()> {
    let text = to_text(path, moving_from_fixed)?;
    crate::write_atomic(path, |w| w.write_all(text.as_bytes()))
}
