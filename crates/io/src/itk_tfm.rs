//! ITK transform files (`.tfm`, "Insight Transform File V1.0") holding one affine transform: [`write_affine`],
//! [`read_affine`], [`parse_affine`].
//!
//! # The format
//!
//! A text file that ITK's `TransformFileReader`/`Writer` (and SimpleITK's `ReadTransform`, ANTs, 3D Slicer) read:
//!
//! ```text
//! #Insight Transform File V1.0
//! #Transform 0
//! Transform: AffineTransform_double_3_3
//! Parameters: a11 a12 a13 a21 a22 a23 a31 a32 a33 t1 t2 t3
//! FixedParameters: c1 c2 c3
//! ```
//!
//! The parameters are the matrix A row by row, then the translation t; the fixed parameters are the centre c.
//! ITK's `MatrixOffsetTransformBase` maps a point x to
//!
//! ```text
//! T(x) = A (x − c) + c + t = A x + o,    o = t + c − A c   (the "offset")
//! ```
//!
//! in ITK's physical space, which is **LPS mm**, the same as ours: no RAS conversion is involved. A transform used
//! for resampling maps output points to input points, so a registration's `.tfm` holds the pull-back
//! `moving_from_fixed`. We write c = 0 (then t = o) and read any centre.
//!
//! Numbers are written with Rust's shortest round-trip formatting, so a written file reads back bit for bit.
//! Only a single affine (`AffineTransform_double_3_3`, `AffineTransform_float_3_3` or
//! `MatrixOffsetTransformBase_double_3_3`) is read; other transform types and files with several transforms
//! (composites) are refused with an error that names the file and what it holds.

use std::path::Path;

use nalgebra::{Matrix3, Vector3};

use crate::error::{Error, ErrorKind, Result};

/// The first line of every ITK transform file.
const MAGIC: &str = "#Insight Transform File V1.0";

/// Transform types read as an affine (all share the 12 + 3 parameter layout).
const AFFINE_TYPES: [&str; 3] =
    ["AffineTransform_double_3_3", "AffineTransform_float_3_3", "MatrixOffsetTransformBase_double_3_3"];

/// A 3-D affine transform in ITK's parameterisation: x ↦ A (x − c) + c + t, LPS mm to LPS mm.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ItkAffine {
    /// A.
    pub matrix: Matrix3<f64>,
    /// t (mm).
    pub translation: [f64; 3],
    /// c, the centre of rotation (mm).
    pub center: [f64; 3],
}

impl ItkAffine {
    /// The map x ↦ `matrix` · x + `offset`, with centre 0.
    #[must_use]
    pub fn from_offset(matrix: Matrix3<f64>, offset: [f64; 3]) -> Self {
        Self { matrix, translation: offset, center: [0.0; 3] }
    }

    /// o = t + c − A c, so that T(x) = A x + o.
    #[must_use]
    pub fn offset(&self) -> [f64; 3] {
        let c = Vector3::from(self.center);
        (Vector3::from(self.translation) + c - self.matrix * c).into()
    }

    /// T(x) = A (x − c) + c + t.
    #[must_use]
    pub fn apply(&self, x: [f64; 3]) -> [f64; 3] {
        (self.matrix * Vector3::from(x) + Vector3::from(self.offset())).into()
    }

    /// The file's text (see the module docs).
    #[must_use]
    pub fn to_text(&self) -> String {
        let a = &self.matrix;
        let mut params: Vec<String> = (0..3).flat_map(|r| (0..3).map(move |c| a[(r, c)].to_string())).collect();
        params.extend(self.translation.iter().map(f64::to_string));
        let fixed: Vec<String> = self.center.iter().map(f64::to_string).collect();
        format!(
            "{MAGIC}\n#Transform 0\nTransform: {}\nParameters: {}\nFixedParameters: {}\n",
            AFFINE_TYPES[0],
            params.join(" "),
            fixed.join(" ")
        )
    }

    fn is_finite(&self) -> bool {
        self.matrix.iter().chain(&self.translation).chain(&self.center).all(|v| v.is_finite())
    }
}

/// Writes `affine` as an ITK transform file, atomically. A non-finite parameter is an error.
pub fn write_affine(path: &Path, affine: &ItkAffine) -> Result<()> {
    if !affine.is_finite() {
        return Err(Error::invalid(path, format!("the affine transform is not finite: {affine:?}")));
    }
    let text = affine.to_text();
    crate::write_atomic(path, |w| w.write_all(text.as_bytes()))
}

/// Reads a `.tfm` holding one affine transform. Only a regular file is read (a named pipe would block, a device
/// never end).
pub fn read_affine(path: &Path) -> Result<ItkAffine> {
    let len = crate::check_regular_file(path)?.len();
    // A single affine is a few hundred bytes; a large file is not one (and is not read into memory).
    if len > 1 << 20 {
        return Err(Error::invalid(path, format!("{len} bytes is too long for an affine transform file")));
    }
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    let text = String::from_utf8(bytes).map_err(|_| Error::invalid(path, "the transform file is not UTF-8 text"))?;
    parse_affine(path, &text)
}

/// Parses the text of a `.tfm` holding one affine transform; `name` is used in errors.
pub fn parse_affine(name: &Path, text: &str) -> Result<ItkAffine> {
    let mut lines = text.lines().map(str::trim).filter(|l| !l.is_empty());
    if lines.next() != Some(MAGIC) {
        return Err(Error::new(
            name,
            ErrorKind::BadMagic { format: "transform (.tfm)", detail: format!("the first line is not {MAGIC:?}") },
        ));
    }
    let (mut kind, mut params, mut fixed) = (None, None, None);
    for line in lines {
        if let Some(n) = line.strip_prefix("#Transform") {
            if n.trim() != "0" {
                return Err(Error::unsupported(
                    name,
                    format!("more than one transform ({line:?}); only a single affine transform is read"),
                ));
            }
        } else if let Some(k) = line.strip_prefix("Transform:") {
            kind = Some(k.trim());
        } else if let Some(p) = line.strip_prefix("Parameters:") {
            params = Some(numbers(name, "Parameters", p, 12)?);
        } else if let Some(p) = line.strip_prefix("FixedParameters:") {
            fixed = Some(numbers(name, "FixedParameters", p, 3)?);
        } else if !line.starts_with('#') {
            return Err(Error::invalid(name, format!("unexpected line {line:?}")));
        }
    }
    let kind = kind.ok_or_else(|| Error::invalid(name, "no \"Transform:\" line"))?;
    if !AFFINE_TYPES.contains(&kind) {
        return Err(Error::unsupported(
            name,
            format!("transform type {kind:?}; only an affine ({}) is read", AFFINE_TYPES.join(", ")),
        ));
    }
    let p = params.ok_or_else(|| Error::invalid(name, "no \"Parameters:\" line"))?;
    let c = fixed.ok_or_else(|| Error::invalid(name, "no \"FixedParameters:\" line"))?;
    Ok(ItkAffine {
        matrix: Matrix3::from_row_slice(&p[..9]),
        translation: [p[9], p[10], p[11]],
        center: [c[0], c[1], c[2]],
    })
}

/// Exactly `count` finite numbers separated by white space.
fn numbers(name: &Path, field: &str, text: &str, count: usize) -> Result<Vec<f64>> {
    let values: Vec<f64> = text
        .split_whitespace()
        .map(|v| v.parse::<f64>().ok().filter(|x| x.is_finite()))
        .collect::<Option<_>>()
        .ok_or_else(|| Error::invalid(name, format!("{field}: {:?} is not a list of finite numbers", text.trim())))?;
    if values.len() != count {
        return Err(Error::invalid(name, format!("{field}: {} numbers, expected {count}", values.len())));
    }
    Ok(values)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> ItkAffine {
        let matrix = Matrix3::new(1.02, -0.05, 0.001, 0.04, 0.98, -0.3, 1e-7, 0.31, 1.1);
        ItkAffine::from_offset(matrix, [3.25, -2.0 / 3.0, 1e-9])
    }

    #[test]
    fn written_file_reads_back_bit_for_bit() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("pull.tfm");
        let affine = sample();
        write_affine(&path, &affine).expect("write");
        let text = std::fs::read_to_string(&path).expect("read text");
        assert!(
            text.starts_with("#Insight Transform File V1.0\n#Transform 0\nTransform: AffineTransform_double_3_3\n")
        );
        assert!(text.contains("\nFixedParameters: 0 0 0\n"), "{text}");
        let back = read_affine(&path).expect("read");
        assert_eq!(back.matrix.map(f64::to_bits), affine.matrix.map(f64::to_bits));
        assert_eq!(back.translation.map(f64::to_bits), affine.translation.map(f64::to_bits));
        let x = [10.0, -20.0, 30.0];
        let expected = affine.matrix * Vector3::from(x) + Vector3::from(affine.translation);
        assert!((Vector3::from(back.apply(x)) - expected).norm() < 1e-12);
    }

    #[test]
    fn a_centre_is_folded_into_the_offset() {
        // ITK's convention: T(x) = A (x − c) + c + t. A rotation by 90° about z around c = (10, 0, 0), no t.
        let text = "#Insight Transform File V1.0\n#Transform 0\nTransform: AffineTransform_float_3_3\n\
                    Parameters: 0 -1 0 1 0 0 0 0 1 0 0 0\nFixedParameters: 10 0 0\n";
        let a = parse_affine(Path::new("c.tfm"), text).expect("parse");
        let y = a.apply([11.0, 0.0, 5.0]);
        assert!((y[0] - 10.0).abs() < 1e-12 && (y[1] - 1.0).abs() < 1e-12 && (y[2] - 5.0).abs() < 1e-12, "{y:?}");
        assert!(a.apply(a.center).iter().zip(a.center).all(|(p, q)| (p - q).abs() < 1e-12));
    }

    #[test]
    fn refuses_other_files_naming_them() {
        let name = Path::new("x.tfm");
        let good = sample().to_text();
        let cases = [
            ("not a transform\n", "not a transform (.tfm) file"),
            (&good.replace("AffineTransform_double_3_3", "BSplineTransform_double_3_3"), "transform type"),
            (&good.replace("#Transform 0", "#Transform 1"), "more than one transform"),
            (&good.replace("Parameters: 1.02", "Parameters: nan"), "finite numbers"),
            (&good.replace("FixedParameters: 0 0 0", "FixedParameters: 0 0"), "2 numbers, expected 3"),
            (&good.replace("FixedParameters: 0 0 0\n", ""), "no \"FixedParameters:\" line"),
            (&format!("{good}garbage\n"), "unexpected line"),
        ];
        for (text, needle) in cases {
            let e = parse_affine(name, text).expect_err(needle);
            let msg = e.to_string();
            assert!(msg.starts_with("x.tfm: ") && msg.contains(needle), "{msg:?} lacks {needle:?}");
        }
        let dir = tempfile::tempdir().expect("tempdir");
        let out = dir.path().join("inf.tfm");
        let bad = ItkAffine::from_offset(Matrix3::identity(), [f64::INFINITY, 0.0, 0.0]);
        assert!(write_affine(&out, &bad).is_err());
        assert!(!out.exists());
    }

    #[test]
    fn a_named_pipe_is_refused_without_blocking() {
        let dir = tempfile::tempdir().expect("tempdir");
        let fifo = dir.path().join("pipe.tfm");
        let status = std::process::Command::new("mkfifo").arg(&fifo).status().expect("run mkfifo");
        assert!(status.success(), "mkfifo {}", fifo.display());
        // Opening a FIFO for reading blocks until a writer comes: read on another thread, so a hang fails the
        // test instead of stalling it.
        let (tx, rx) = std::sync::mpsc::channel();
        let path = fifo.clone();
        std::thread::spawn(move || {
            let _ = tx.send(read_affine(&path));
        });
        let result =
            rx.recv_timeout(std::time::Duration::from_secs(20)).expect("the read ends (a pipe must not block)");
        let e = result.expect_err("a pipe holds no transform");
        assert!(matches!(e.kind, ErrorKind::NotARegularFile { what: "a named pipe (FIFO)" }), "{e}");
        assert!(e.to_string().starts_with(&format!("{}: a named pipe (FIFO), not a regular file", fifo.display())));
    }
}
