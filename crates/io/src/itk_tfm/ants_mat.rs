//! The affine transform as ANTs and ITK's `MatlabTransformIO` store it: a MATLAB v4 binary file (`.mat`) of two
//! variables, the same numbers as an ITK `.tfm`'s `AffineTransform_double_3_3` (the parent module turns them into
//! its `ItkAffine`; this one knows only the twelve parameters and the centre, so that neither imports the other).
//!
//! # The format
//!
//! A MATLAB v4 file is a sequence of variables (MathWorks, *MAT-File Format*, "Level 4 MAT-Files"), each a header of
//! five 32-bit integers in the file's byte order, the name, then the values column by column:
//!
//! ```text
//! type      M·1000 + O·100 + P·10 + T: M = 0 little-endian IEEE, 1 big-endian IEEE; O = 0;
//!           P = 0 double, 1 float (others refused); T = 0 a full numeric matrix
//! mrows     rows
//! ncols     columns
//! imagf     0 (1 would mean imaginary parts follow)
//! namlen    bytes of the name, its NUL included
//! name      e.g. "AffineTransform_double_3_3\0"
//! real      mrows · ncols values of precision P
//! ```
//!
//! ITK (`itkMatlabTransformIO.hxx`, as SimpleITK's `WriteTransform(t, "t.mat")` and antsRegistration's
//! `*GenericAffine.mat` use it) writes the parameters as a 12 × 1 variable named after the transform class, the
//! matrix A row by row then the translation t, and the fixed parameters, the centre c, as a 3 × 1 variable `fixed`.
//! The transform is ITK's `MatrixOffsetTransformBase`: x ↦ A (x − c) + c + t, LPS mm to LPS mm, fixed points to
//! moving points for a registration's result, exactly as in a `.tfm`.
//!
//! We read `AffineTransform_double_3_3`, `AffineTransform_float_3_3` and `MatrixOffsetTransformBase_double_3_3`
//! (and their `float` twins), stored as double or float, in either byte order; the two variables in either order,
//! each exactly once, and nothing else. We write what SimpleITK writes for an `AffineTransform_double_3_3`,
//! little-endian doubles, so that the same transform gives the same bytes.

use std::path::Path;

use crate::error::{Error, ErrorKind, Result};

/// The numbers of an affine `.mat`: the 12 parameters (A row by row, then t) and the centre c.
pub(super) struct MatAffine {
    pub(super) parameters: [f64; 12],
    pub(super) center: [f64; 3],
}

/// The names the parameters' variable may have.
const PARAMETER_NAMES: [&str; 4] = [
    "AffineTransform_double_3_3",
    "AffineTransform_float_3_3",
    "MatrixOffsetTransformBase_double_3_3",
    "MatrixOffsetTransformBase_float_3_3",
];

/// The fixed parameters' variable.
const FIXED_NAME: &str = "fixed";

/// The longest variable name read, in bytes (ITK's are under 64).
const MAX_NAME_BYTES: usize = 4096;

/// One variable of a MATLAB v4 file.
struct Variable {
    name: String,
    rows: usize,
    cols: usize,
    values: Vec<f64>,
}

/// Whether `bytes` start as a MATLAB v4 variable of doubles or floats (little- or big-endian), so that a `.mat`
/// renamed to something else is still recognised.
pub(super) fn looks_like_mat(bytes: &[u8]) -> bool {
    bytes.len() >= 20 && type_code(bytes).is_some()
}

/// The byte order and the precision (bytes per value) of the variable header at the start of `bytes`.
fn type_code(bytes: &[u8]) -> Option<(bool, usize)> {
    let word: [u8; 4] = bytes.get(..4)?.try_into().ok()?;
    for (big_endian, value) in [(false, i32::from_le_bytes(word)), (true, i32::from_be_bytes(word))] {
        // In i64: any word read from a file, i32::MIN included, less 1000.
        let m = i64::from(big_endian);
        match i64::from(value) - m * 1000 {
            0 => return Some((big_endian, 8)),
            10 => return Some((big_endian, 4)),
            _ => {}
        }
    }
    None
}

/// Reads one variable at `at`; returns it and where the next one starts.
fn variable(name: &Path, bytes: &[u8], at: usize, index: usize) -> Result<(Variable, usize)> {
    let truncated =
        |what: &str| Error::truncated(name, format!("the file ends within variable {} ({what})", index + 1));
    let header = bytes.get(at..at + 20).ok_or_else(|| truncated("its 20-byte header"))?;
    let word = |i: usize| -> [u8; 4] { [header[4 * i], header[4 * i + 1], header[4 * i + 2], header[4 * i + 3]] };
    let Some((big_endian, size)) = type_code(header) else {
        let (le, be) = (i32::from_le_bytes(word(0)), i32::from_be_bytes(word(0)));
        return Err(Error::invalid(
            name,
            format!(
                "variable {}: type code {le} (read little-endian; {be} big-endian) is not a MATLAB v4 matrix of \
                 doubles or floats (0 or 10 little-endian, 1000 or 1010 big-endian)",
                index + 1
            ),
        ));
    };
    let int = |i: usize| if big_endian { i32::from_be_bytes(word(i)) } else { i32::from_le_bytes(word(i)) };
    let (rows, cols, imagf, namlen) = (int(1), int(2), int(3), int(4));
    if imagf != 0 {
        return Err(Error::unsupported(name, format!("variable {}: complex values (imagf = {imagf})", index + 1)));
    }
    let bad_size = || Error::invalid(name, format!("variable {}: {rows} × {cols} values", index + 1));
    let rows = usize::try_from(rows).map_err(|_| bad_size())?;
    let cols = usize::try_from(cols).map_err(|_| bad_size())?;
    let namlen = usize::try_from(namlen)
        .ok()
        .filter(|&n| (1..=MAX_NAME_BYTES).contains(&n))
        .ok_or_else(|| Error::invalid(name, format!("variable {}: a name of {namlen} bytes", index + 1)))?;
    let start = at + 20;
    let raw_name = bytes.get(start..start + namlen).ok_or_else(|| truncated("its name"))?;
    let text = raw_name.strip_suffix(&[0]).unwrap_or(raw_name);
    let var_name = String::from_utf8_lossy(text).into_owned();
    let count = rows.checked_mul(cols).filter(|&n| n <= 1 << 20).ok_or_else(bad_size)?;
    let data_start = start + namlen;
    let data = bytes
        .get(data_start..data_start + count * size)
        .ok_or_else(|| truncated(&format!("the {count} values of {var_name:?}")))?;
    let values = data
        .chunks_exact(size)
        .map(|b| match (size, big_endian) {
            (8, false) => f64::from_le_bytes(b.try_into().unwrap_or_default()),
            (8, true) => f64::from_be_bytes(b.try_into().unwrap_or_default()),
            (_, false) => f64::from(f32::from_le_bytes(b.try_into().unwrap_or_default())),
            (_, true) => f64::from(f32::from_be_bytes(b.try_into().unwrap_or_default())),
        })
        .collect();
    Ok((Variable { name: var_name, rows, cols, values }, data_start + count * size))
}

/// Parses the bytes of an affine `.mat` (module docs); `name` is used in errors.
pub(super) fn parse_mat_numbers(name: &Path, bytes: &[u8]) -> Result<MatAffine> {
    if !looks_like_mat(bytes) {
        let plausible = |v: i32| (0..5000).contains(&v);
        let detail = if bytes.len() < 20 {
            format!("{} bytes, fewer than a MATLAB v4 variable header", bytes.len())
        } else if bytes.starts_with(b"#Insight Transform File") {
            "it is an ITK text transform file: name it .tfm".to_owned()
        } else if [i32::from_le_bytes, i32::from_be_bytes]
            .iter()
            .any(|f| plausible(f([bytes[0], bytes[1], bytes[2], bytes[3]])))
        {
            // A MATLAB v4 header of another type (integers, text, sparse): the variable says which.
            String::new()
        } else {
            "the first bytes are not a MATLAB v4 variable header".to_owned()
        };
        if !detail.is_empty() {
            return Err(Error::new(name, ErrorKind::BadMagic { format: "MATLAB v4 affine (.mat)", detail }));
        }
    }
    let (mut parameters, mut fixed): (Option<Variable>, Option<Variable>) = (None, None);
    let mut at = 0;
    let mut index = 0;
    while at < bytes.len() {
        let (v, next) = variable(name, bytes, at, index)?;
        let slot = if PARAMETER_NAMES.contains(&v.name.as_str()) {
            &mut parameters
        } else if v.name == FIXED_NAME {
            &mut fixed
        } else if v.name.contains("_3_3") || v.name.contains("Transform") {
            return Err(Error::unsupported(
                name,
                format!("transform type {:?}; only an affine ({}) is read", v.name, PARAMETER_NAMES.join(", ")),
            ));
        } else {
            return Err(Error::invalid(
                name,
                format!(
                    "variable {} is named {:?}; an affine .mat holds the parameters ({}) and \"fixed\"",
                    index + 1,
                    v.name,
                    PARAMETER_NAMES.join(", ")
                ),
            ));
        };
        if let Some(first) = slot.replace(v) {
            return Err(Error::invalid(name, format!("variable {:?} given twice", first.name)));
        }
        at = next;
        index += 1;
    }
    let parameters = parameters
        .ok_or_else(|| Error::invalid(name, format!("no parameters variable ({})", PARAMETER_NAMES.join(", "))))?;
    let fixed = fixed.ok_or_else(|| Error::invalid(name, "no \"fixed\" variable (the centre)"))?;
    for (v, want) in [(&parameters, 12), (&fixed, 3)] {
        if v.values.len() != want || v.rows.min(v.cols) != 1 {
            return Err(Error::invalid(
                name,
                format!("{:?} is {} × {}; it must hold {want} values (a {want} × 1 column)", v.name, v.rows, v.cols),
            ));
        }
        if let Some(i) = v.values.iter().position(|x| !x.is_finite()) {
            return Err(Error::invalid(name, format!("{:?}: value {} is not finite", v.name, i + 1)));
        }
    }
    let p = &parameters.values;
    let c = &fixed.values;
    Ok(MatAffine { parameters: std::array::from_fn(|i| p[i]), center: [c[0], c[1], c[2]] })
}

/// The bytes of one little-endian variable of doubles, `n` × 1.
fn put_variable(out: &mut Vec<u8>, var_name: &str, values: &[f64]) {
    let namlen = var_name.len() + 1;
    for word in [0, values.len(), 1, 0, namlen] {
        out.extend_from_slice(&(word as i32).to_le_bytes());
    }
    out.extend_from_slice(var_name.as_bytes());
    out.push(0);
    for v in values {
        out.extend_from_slice(&v.to_le_bytes());
    }
}

/// The `.mat` bytes of an affine as SimpleITK writes an `AffineTransform_double_3_3` (module docs).
pub(super) fn mat_bytes(affine: &MatAffine) -> Vec<u8> {
    let mut out = Vec::with_capacity(256);
    put_variable(&mut out, PARAMETER_NAMES[0], &affine.parameters);
    put_variable(&mut out, FIXED_NAME, &affine.center);
    out
}
