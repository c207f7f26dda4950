//! Reading an elastix transform parameter file and the chain of initial transforms under it ([`read_transform`]),
//! as one affine when all are linear ([`read_affine`]).

use std::path::Path;

use nalgebra::{Matrix3, Matrix4};

use super::deformation_field;
use super::params::{ParameterMap, find_beside, parse_bytes, read_file};
use super::transform::{ElastixTransform, Link, Step, ThinPlateKernel};
use super::write::ElastixGrid;
use crate::error::{Error, Result};
use crate::geometry::Transform;
use crate::itk_tfm::{ItkAffine, ItkBSpline, euler_matrix, versor_matrix};

/// How many files a chain of initial transforms may hold: more is taken for a loop.
const MAX_CHAIN: usize = 32;

/// Reads the elastix transform parameter file at `path` and the chain of `InitialTransformParameterFileName`s under
/// it (module docs of [`super`]): every transform of the table there, composed (`HowToCombineTransforms
/// "Compose"`), and the fixed grid the named file gives. Errors name the file (and the line) and the problem.
pub fn read_transform(path: &Path) -> Result<ElastixTransform> {
    let mut links: Vec<Link> = Vec::new();
    let mut at = path.to_path_buf();
    let mut grid = None;
    loop {
        if links.len() == MAX_CHAIN || links.iter().any(|l| l.file == at) {
            return Err(Error::invalid(
                path,
                format!("its chain of InitialTransformParameterFileName loops or is longer than {MAX_CHAIN} files"),
            ));
        }
        let map = read_file(&at)?;
        if links.is_empty() {
            grid = fixed_grid(&at, &map)?;
        }
        let (step, initial) = one_transform(&at, &map)?;
        let next = initial.map(|file| find_beside(&at, &file, "InitialTransformParameterFileName")).transpose()?;
        links.push(Link { file: at.clone(), step });
        match next {
            Some(next) => at = next,
            None => break,
        }
    }
    // Read from `path` down the chain, so the last read applies first.
    links.reverse();
    Ok(ElastixTransform { links, grid })
}

/// One parameter file's transform from its bytes (`name` is used in errors and as the link's file), as
/// [`read_transform`] reads it, but alone: a file that names an initial transform is refused, as the chain can only
/// be followed from a file. The entry point for fuzzing.
///
/// # Errors
/// As [`read_transform`]; and a file that names an initial transform.
pub fn parse_transform(name: &Path, bytes: &[u8]) -> Result<ElastixTransform> {
    let map = parse_bytes(name, bytes)?;
    if map.text(name, "Transform")? == Some("DeformationFieldTransform") {
        return Err(Error::unsupported(
            name,
            "it is a DeformationFieldTransform, whose field only a file beside it can give",
        ));
    }
    let grid = fixed_grid(name, &map)?;
    let (step, initial) = one_transform(name, &map)?;
    if let Some(file) = initial {
        return Err(Error::unsupported(
            name,
            format!("it names the initial transform {file:?}, which only a file beside it can give"),
        ));
    }
    Ok(ElastixTransform { links: vec![Link { file: name.to_path_buf(), step }], grid })
}

/// [`read_transform`] for a chain of linear transforms only (`TranslationTransform`, `EulerTransform`,
/// `SimilarityTransform`, `AffineTransform`), as one affine T: fixed → moving, LPS mm: what `--initial` takes. A
/// deformable transform is refused with what to do instead.
pub fn read_affine(path: &Path) -> Result<ItkAffine> {
    let chain = read_transform(path)?;
    chain.affine().map_err(|(file, kind)| {
        Error::unsupported(
            file,
            format!(
                "elastix's {kind} is not a linear transform, and a starting transform is one; use the file as a \
                 displacement field instead (warp --field, or the window's Use field), which takes the whole chain"
            ),
        )
    })
}

/// The fixed grid of a file: `Size`, `Spacing`, `Origin`, `Direction` (column by column); `None` when one is
/// missing. `Index` other than 0 is refused.
fn fixed_grid(name: &Path, map: &ParameterMap) -> Result<Option<ElastixGrid>> {
    let (Some(size), Some(spacing), Some(origin)) =
        (map.numbers(name, "Size")?, map.numbers(name, "Spacing")?, map.numbers(name, "Origin")?)
    else {
        return Ok(None);
    };
    let direction = map.numbers(name, "Direction")?.unwrap_or_else(|| Matrix3::<f64>::identity().as_slice().to_vec());
    if let Some(index) = map.numbers(name, "Index")?
        && index.iter().any(|&i| i != 0.0)
    {
        return Err(Error::unsupported(name, format!("Index {index:?}: only grids indexed from 0 are read")));
    }
    let three = |key: &str, v: &[f64]| -> Result<[f64; 3]> {
        <[f64; 3]>::try_from(v)
            .map_err(|_| Error::invalid(name, format!("({key} …) has {} numbers, 3 expected", v.len())))
    };
    let size = three("Size", &size)?;
    let dims = size.map(|n| n as usize);
    if size.iter().any(|&n| n < 1.0 || n.fract() != 0.0 || n > 1e9) {
        return Err(Error::invalid(name, format!("Size {size:?} is not three positive whole numbers")));
    }
    let spacing = three("Spacing", &spacing)?;
    let origin = three("Origin", &origin)?;
    if direction.len() != 9 {
        return Err(Error::invalid(name, format!("(Direction …) has {} numbers, 9 expected", direction.len())));
    }
    // Column by column: column a is index axis a.
    let linear = Matrix3::from_fn(|r, a| direction[3 * a + r] * spacing[a]);
    let mut m = Matrix4::identity();
    m.fixed_view_mut::<3, 3>(0, 0).copy_from(&linear);
    for r in 0..3 {
        m[(r, 3)] = origin[r];
    }
    let lps_from_index = Transform::from_matrix(m);
    if !lps_from_index.is_valid_affine() || spacing.iter().any(|&s| s <= 0.0) {
        return Err(Error::invalid(name, "the fixed grid's Spacing and Direction are singular or not positive"));
    }
    Ok(Some(ElastixGrid { dims, lps_from_index }))
}

/// The transform of one file, and the initial transform's file as it names it, if it does.
fn one_transform(name: &Path, map: &ParameterMap) -> Result<(Step, Option<String>)> {
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
    let step = match kind {
        "TranslationTransform" => {
            let t = p(3)?;
            Step::Linear(ItkAffine::from_offset(Matrix3::identity(), [t[0], t[1], t[2]]))
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
            Step::Linear(ItkAffine {
                matrix: euler_matrix([v[0], v[1], v[2]], zyx),
                translation: [v[3], v[4], v[5]],
                center: center()?,
            })
        }
        "SimilarityTransform" => {
            let v = p(7)?;
            let versor = [v[0], v[1], v[2]];
            let norm2: f64 = versor.iter().map(|x| x * x).sum();
            if norm2 > 1.0 {
                return Err(Error::invalid(name, format!("the versor {versor:?} is longer than 1")));
            }
            Step::Linear(ItkAffine {
                matrix: versor_matrix(versor) * v[6],
                translation: [v[3], v[4], v[5]],
                center: center()?,
            })
        }
        "AffineTransform" => {
            let v = p(12)?;
            Step::Linear(ItkAffine {
                matrix: Matrix3::from_row_slice(&v[..9]),
                translation: [v[9], v[10], v[11]],
                center: center()?,
            })
        }
        "BSplineTransform" | "RecursiveBSplineTransform" => {
            let b = bspline(name, map)?;
            // `bspline` checked the grid's axes: they are not degenerate.
            let index_from_lps = b
                .index_from_lps()
                .ok_or_else(|| Error::invalid(name, "the B-spline's GridDirection and GridSpacing are singular"))?;
            Step::BSpline(b, index_from_lps)
        }
        "SplineKernelTransform" => Step::ThinPlate(kernel(name, map)?),
        "DeformationFieldTransform" => {
            if let Some(cosines) = map.text(name, "UseDirectionCosines")?
                && cosines != "true"
            {
                return Err(Error::unsupported(
                    name,
                    format!("UseDirectionCosines {cosines:?}: only fields read with their directions are read"),
                ));
            }
            Step::Field(Box::new(deformation_field::read(name, map)?))
        }
        other => {
            return Err(Error::unsupported(
                name,
                format!(
                    "elastix's {other} is not read (translation, Euler, similarity, affine, B-spline, thin-plate \
                     spline kernel and deformation field transforms are); have transformix write it as a displacement field \
                     (transformix -def all -tp FILE -out DIR) and give DIR/deformationField.mhd instead"
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
            Some(file.to_owned())
        }
    };
    Ok((step, initial))
}

/// A cubic `BSplineTransform`: `GridSize`, `GridOrigin`, `GridSpacing`, `GridDirection` (column by column) and the
/// coefficients, all x, then all y, then all z (as [`super::write()`] writes them).
fn bspline(name: &Path, map: &ParameterMap) -> Result<ItkBSpline> {
    match map.numbers(name, "BSplineTransformSplineOrder")?.as_deref() {
        None | Some([3.0]) => {}
        Some(other) => {
            return Err(Error::unsupported(
                name,
                format!("BSplineTransformSplineOrder {other:?}: only cubic (3) B-splines are read"),
            ));
        }
    }
    if let Some(cyclic) = map.text(name, "UseCyclicTransform")?
        && cyclic != "false"
    {
        return Err(Error::unsupported(name, format!("UseCyclicTransform {cyclic:?}: cyclic B-splines are not read")));
    }
    if let Some(index) = map.numbers(name, "GridIndex")?
        && index.iter().any(|&i| i != 0.0)
    {
        return Err(Error::unsupported(name, format!("GridIndex {index:?}: only grids indexed from 0 are read")));
    }
    let size = map.numbers_n(name, "GridSize", 3)?;
    if size.iter().any(|&n| n < 4.0 || n.fract() != 0.0 || n > 1e6) {
        return Err(Error::invalid(name, format!("GridSize {size:?}: a cubic B-spline needs whole numbers ≥ 4")));
    }
    let grid_size = [size[0] as usize, size[1] as usize, size[2] as usize];
    let points = grid_size.iter().product::<usize>();
    let origin = map.numbers_n(name, "GridOrigin", 3)?;
    let spacing = map.numbers_n(name, "GridSpacing", 3)?;
    let direction = match map.numbers(name, "GridDirection")? {
        None => Matrix3::<f64>::identity().as_slice().to_vec(),
        Some(_) => map.numbers_n(name, "GridDirection", 9)?,
    };
    let p = map.numbers_n(name, "TransformParameters", 3 * points)?;
    let b = ItkBSpline {
        grid_size,
        grid_origin_lps: [origin[0], origin[1], origin[2]],
        grid_spacing_mm: [spacing[0], spacing[1], spacing[2]],
        // Column a of the file's matrix is grid axis a; ours is stored row by row.
        grid_direction: std::array::from_fn(|r| std::array::from_fn(|a| direction[3 * a + r])),
        coefficients_mm: (0..points).map(|i| [p[i], p[points + i], p[2 * points + i]]).collect(),
    };
    b.check(name)?;
    Ok(b)
}

/// A `SplineKernelTransform` with the `ThinPlateSpline` kernel: `FixedImageLandmarks` → `TransformParameters`,
/// relaxed by `SplineRelaxationFactor`.
fn kernel(name: &Path, map: &ParameterMap) -> Result<ThinPlateKernel> {
    match map.text(name, "SplineKernelType")? {
        None | Some("ThinPlateSpline") => {}
        Some(other) => {
            return Err(Error::unsupported(
                name,
                format!("SplineKernelType {other:?}: only the ThinPlateSpline kernel is read"),
            ));
        }
    }
    let triples = |key: &str| -> Result<Vec<[f64; 3]>> {
        let v = map.numbers(name, key)?.ok_or_else(|| Error::invalid(name, format!("the file has no ({key} …)")))?;
        if v.len() % 3 != 0 {
            return Err(Error::invalid(name, format!("({key} …) has {} numbers, not a multiple of 3", v.len())));
        }
        Ok(v.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect())
    };
    let sources = triples("FixedImageLandmarks")?;
    let targets = triples("TransformParameters")?;
    let stiffness = map.numbers(name, "SplineRelaxationFactor")?.map_or(Ok(0.0), |v| match v.as_slice() {
        [x] => Ok(*x),
        _ => Err(Error::invalid(name, "(SplineRelaxationFactor …) has more than one number")),
    })?;
    ThinPlateKernel::solve(name, sources, &targets, stiffness)
}
