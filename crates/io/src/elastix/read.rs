//! Reading a linear elastix transform, and the chain of initial transforms under it, as one affine.

use std::path::{Path, PathBuf};

use nalgebra::{Matrix3, Vector3};

use super::params::{ParameterMap, read_file};
use crate::error::{Error, Result};
use crate::itk_tfm::ItkAffine;

/// How many files a chain of initial transforms may hold: more is taken for a loop.
const MAX_CHAIN: usize = 32;

/// Reads the elastix transform parameter file at `path` and the chain of `InitialTransformParameterFileName`s under
/// it as one affine T: fixed → moving, LPS mm (module docs). Every transform in the chain must be linear
/// (`TranslationTransform`, `EulerTransform`, `SimilarityTransform`, `AffineTransform`) and composed
/// (`HowToCombineTransforms "Compose"`). Errors name the file (and the line) and the problem; a deformable transform
/// is refused with what to do instead.
pub fn read_affine(path: &Path) -> Result<ItkAffine> {
    let mut chain: Vec<PathBuf> = Vec::new();
    let mut at = path.to_path_buf();
    let mut transforms = Vec::new();
    loop {
        if chain.len() == MAX_CHAIN || chain.contains(&at) {
            return Err(Error::invalid(
                path,
                format!("its chain of InitialTransformParameterFileName loops or is longer than {MAX_CHAIN} files"),
            ));
        }
        let map = read_file(&at)?;
        let (affine, initial) = one_transform(&at, &map)?;
        chain.push(at.clone());
        transforms.push(affine);
        match initial {
            Some(next) => at = next,
            None => break,
        }
    }
    // Read from `path` down the chain, so the last read applies first: T = T_path ∘ … ∘ T_last.
    let (mut matrix, mut offset) = (Matrix3::identity(), Vector3::zeros());
    for t in transforms.iter().rev() {
        offset = t.matrix * offset + Vector3::from(t.offset());
        matrix = t.matrix * matrix;
    }
    Ok(ItkAffine::from_offset(matrix, offset.into()))
}

/// The linear transform of one file, and the file of its initial transform if it names one.
fn one_transform(name: &Path, map: &ParameterMap) -> Result<(ItkAffine, Option<PathBuf>)> {
    if let Some(d) = map.numbers(name, "FixedImageDimension")?
        && d != [3.0]
    {
        return Err(Error::unsupported(name, format!("FixedImageDimension {d:?}: only 3-D transforms are read")));
    }
    let kind = map.text(name, "Transform")?.ok_or_else(|| Error::invalid(name, "the file has no (Transform …)"))?;
    let p = |count: usize| map.numbers_n(name, "TransformParameters", count);
    let center = || -> Result<[f64; 3]> {
        Ok(match map.numbers(name, "CenterOfRotationPoint")? {
            None => [0.0; 3],
            Some(c) if c.len() == 3 => [c[0], c[1], c[2]],
            Some(c) => {
                return Err(Error::invalid(name, format!("CenterOfRotationPoint has {} numbers, 3 expected", c.len())));
            }
        })
    };
    let affine = match kind {
        "TranslationTransform" => {
            let t = p(3)?;
            ItkAffine::from_offset(Matrix3::identity(), [t[0], t[1], t[2]])
        }
        "EulerTransform" => {
            let v = p(6)?;
            let zyx = match map.text(name, "ComputeZYX")? {
                None | Some("false") => false,
                Some("true") => true,
                Some(other) => {
                    return Err(Error::invalid(
                        name,
                        format!("ComputeZYX {other:?} is neither \"true\" nor \"false\""),
                    ));
                }
            };
            ItkAffine {
                matrix: euler_matrix([v[0], v[1], v[2]], zyx),
                translation: [v[3], v[4], v[5]],
                center: center()?,
            }
        }
        "SimilarityTransform" => {
            let v = p(7)?;
            let versor = [v[0], v[1], v[2]];
            let norm2: f64 = versor.iter().map(|x| x * x).sum();
            if norm2 > 1.0 {
                return Err(Error::invalid(name, format!("the versor {versor:?} is longer than 1")));
            }
            ItkAffine { matrix: versor_matrix(versor) * v[6], translation: [v[3], v[4], v[5]], center: center()? }
        }
        "AffineTransform" => {
            let v = p(12)?;
            ItkAffine { matrix: Matrix3::from_row_slice(&v[..9]), translation: [v[9], v[10], v[11]], center: center()? }
        }
        other => {
            return Err(Error::unsupported(
                name,
                format!(
                    "elastix's {other} is not a linear transform, and a starting transform is one; have transformix \
                     write it as a displacement field (transformix -def all -tp FILE -out DIR) and give \
                     DIR/deformationField.mhd to warp --field"
                ),
            ));
        }
    };
    let initial = match map.text(name, "InitialTransformParameterFileName")? {
        None | Some("NoInitialTransform" | "") => None,
        Some(file) => {
            match map.text(name, "HowToCombineTransforms")? {
                None | Some("Compose") => {}
                Some(other) => {
                    return Err(Error::unsupported(
                        name,
                        format!("HowToCombineTransforms {other:?}: only \"Compose\" chains are read"),
                    ));
                }
            }
            Some(find_initial(name, file)?)
        }
    };
    Ok((affine, initial))
}

/// The initial transform's file: beside `name`, else as given.
fn find_initial(name: &Path, file: &str) -> Result<PathBuf> {
    let given = PathBuf::from(file);
    let beside = name.parent().map(|d| d.join(&given));
    beside.filter(|p| p.is_file()).or_else(|| given.is_file().then_some(given.clone())).ok_or_else(|| {
        Error::invalid(
            name,
            format!("its InitialTransformParameterFileName {file:?} is neither beside it nor where it says"),
        )
    })
}

/// ITK's `Euler3DTransform` matrix: Rz Rx Ry, or Rz Ry Rx when `zyx`.
fn euler_matrix(angles: [f64; 3], zyx: bool) -> Matrix3<f64> {
    let [(sx, cx), (sy, cy), (sz, cz)] = angles.map(f64::sin_cos);
    let rx = Matrix3::new(1.0, 0.0, 0.0, 0.0, cx, -sx, 0.0, sx, cx);
    let ry = Matrix3::new(cy, 0.0, sy, 0.0, 1.0, 0.0, -sy, 0.0, cy);
    let rz = Matrix3::new(cz, -sz, 0.0, sz, cz, 0.0, 0.0, 0.0, 1.0);
    if zyx { rz * ry * rx } else { rz * rx * ry }
}

/// The rotation of the unit quaternion (w, x, y, z), w = √(1 − x² − y² − z²): ITK's `Versor::GetMatrix`.
fn versor_matrix([x, y, z]: [f64; 3]) -> Matrix3<f64> {
    let w = (1.0 - x * x - y * y - z * z).max(0.0).sqrt();
    Matrix3::new(
        1.0 - 2.0 * (y * y + z * z),
        2.0 * (x * y - z * w),
        2.0 * (x * z + y * w),
        2.0 * (x * y + z * w),
        1.0 - 2.0 * (x * x + z * z),
        2.0 * (y * z - x * w),
        2.0 * (x * z - y * w),
        2.0 * (y * z + x * w),
        1.0 - 2.0 * (x * x + y * y),
    )
}
