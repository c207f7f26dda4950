//! `Warp`: landmark pairs fitted by a method, on a starting transform, in both directions, by the functions the
//! command line fits with (`warpbench_app::fit`), and what follows from it: mapped points (`points`), displacement
//! fields (`field`), the resampled moving volume (`warp`), the ITK transform file (`transform`), leave-one-out
//! errors and folding (the window's diagnostics).
//!
//! Only a volume's geometry is needed to fit, sample a field or check folding. Those arguments are `(dims,
//! lps_from_index)`, and where a core takes a whole volume it gets a volume of zeros on that grid, which nothing
//! reads (the operating system maps a zeroed allocation lazily).

use std::path::{Path, PathBuf};

use anyhow::anyhow;
use numpy::ndarray::{Array2, Array4, ShapeBuilder};
use numpy::{PyArray, PyReadonlyArray2};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use warpbench_app::field::{self, Field};
use warpbench_app::fit;
use warpbench_app::inputs::{self, Correspondences, Names};
use warpbench_app::jacobian;
use warpbench_app::project::diagnostics::DiagnosticsInput;
use warpbench_app::project::field_file::{FieldFile, FieldReadFormat};
use warpbench_app::project::stack::{ItkRest, Layers, StackForward, StackPullback};
use warpbench_app::settings::MethodKind;
use warpbench_app::start::{Start, StartFile};
use warpbench_app::transform;
use warpbench_app::warp::{self as warp_cmd, Backend, PullBackMode, WarpSettings};
use warpbench_io::dicom_source::DicomSource;
use warpbench_io::displacement::{FieldDirection, FieldFormat};
use warpbench_io::elastix::{self, ElastixGrid};
use warpbench_io::geometry::Space;
use warpbench_io::geometry::{Index, Lps, Point3, Transform};
use warpbench_io::itk_tfm::ItkTransform;
use warpbench_io::landmarks::LandmarkPair;
use warpbench_io::volume::{GeometrySource, VoxelData};
use warpbench_io::{Volume, transform_file};
use warpbench_solver::diagnostics::jacobian_determinants;
use warpbench_solver::method::Method;
use warpbench_solver::spaces::{Aabb, Fixed};
use warpbench_solver::warp::{Parallelism, Warp as _};

use crate::errors::{bad_input, guarded, io, to_py};
use crate::landmarks::pairs_from_arrays;
use crate::volume::{lps_from_index, samples_to_numpy, volume_from_numpy};

/// `fit`'s `initial_field`: a file, or a `Field`'s arrays.
#[derive(Debug, FromPyObject)]
pub enum InitialField<'py> {
    Path(PathBuf),
    Arrays(crate::field::FieldArrays<'py>),
}

/// A grid: voxels along i, j, k and the 4×4 `lps_from_index`.
type Grid = ([usize; 3], Transform<Lps, Index>);

/// A fitted warp: u = moving_from_fixed (the pull-back) and d = fixed_from_moving (the forward map).
#[pyclass(module = "warpbench._warpbench", name = "Warp", frozen)]
pub struct Warp {
    method: Method,
    /// The pairs as given (every row, for messages and the resampling's own check).
    pairs: Vec<LandmarkPair>,
    /// The active, complete pairs the warp is fitted on.
    used: Correspondences,
    layers: Layers,
    pullback: StackPullback,
    forward: StackForward,
    fixed_box: Aabb<Fixed>,
    /// The grids the pairs were checked against (fixed, moving), when given.
    grids: Option<(Grid, Grid)>,
}

impl std::fmt::Debug for Warp {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Warp")
            .field("method", &self.method)
            .field("pairs", &self.used.moving.len())
            .finish_non_exhaustive()
    }
}

/// A volume of zeros on `grid`: what a core that reads only geometry takes.
fn geometry_volume(name: &Path, (dims, lps): &Grid) -> PyResult<Volume> {
    let n = dims.iter().try_fold(1usize, |n, &d| n.checked_mul(d));
    let n = n.ok_or_else(|| PyValueError::new_err(format!("{}: the grid {dims:?} is too large", name.display())))?;
    Volume::new(name, *dims, VoxelData::U8(vec![0; n]), *lps, GeometrySource::NiftiSform { code: 1 }).map_err(io)
}

/// `(dims, lps_from_index)` from Python.
/// Where [`Warp::field`] writes the field it samples, and how.
enum Written<'a> {
    Nothing,
    /// A file of an image flavour.
    Flavour(&'a Path, FieldFormat),
    /// Learn2Reg's field or FNIRT's, in the voxels or the FSL coordinates of the moving grid given.
    Pair(field::PairOutput, &'a Path, ([usize; 3], Transform<Lps, Index>)),
}

fn grid(name: &Path, (dims, lps): (Vec<usize>, PyReadonlyArray2<'_, f64>)) -> PyResult<Grid> {
    let dims: [usize; 3] = dims
        .try_into()
        .map_err(|d: Vec<usize>| PyValueError::new_err(format!("{}: a grid has 3 sizes, not {d:?}", name.display())))?;
    Ok((dims, lps_from_index(name, &lps)?))
}

/// The box of voxel edges of a grid.
fn grid_box<S: Space>(name: &Path, g: &Grid) -> PyResult<Aabb<S>> {
    Ok(inputs::volume_box(&geometry_volume(name, g)?))
}

/// The points' bounding box, grown by a tenth of its size and at least 10 mm on each side: the domain of a fit
/// with no volume at hand (it matters only to the hierarchical B-spline, whose lattice covers it).
fn points_box<S: Space>(points: &[Point3<S>]) -> Aabb<S> {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for p in points {
        let c = p.coords();
        for a in 0..3 {
            lo[a] = lo[a].min(c[a]);
            hi[a] = hi[a].max(c[a]);
        }
    }
    let pad: [f64; 3] = std::array::from_fn(|a| (0.1 * (hi[a] - lo[a])).max(10.0));
    Aabb::new(
        Point3::from_array(std::array::from_fn(|a| lo[a] - pad[a])),
        Point3::from_array(std::array::from_fn(|a| hi[a] + pad[a])),
    )
}

/// N×3 points from numpy.
fn points_in(what: &str, points: &PyReadonlyArray2<'_, f64>) -> PyResult<Vec<[f64; 3]>> {
    let view = points.as_array();
    if view.ncols() != 3 {
        return Err(PyValueError::new_err(format!("{what}: points must be N×3, not {:?}", view.shape())));
    }
    Ok(view.rows().into_iter().map(|r| [r[0], r[1], r[2]]).collect())
}

/// N×3 points to numpy.
fn points_out(py: Python<'_>, points: &[[f64; 3]]) -> Py<PyAny> {
    PyArray::from_owned_array(py, Array2::from_shape_fn((points.len(), 3), |(i, a)| points[i][a])).into_any().unbind()
}

/// `stiffness` from Python: a number ≥ 0, or `"auto"`.
enum StiffnessArg {
    Value(f64),
    Auto,
}

fn stiffness_arg(value: &Bound<'_, PyAny>) -> PyResult<StiffnessArg> {
    if let Ok(text) = value.extract::<String>() {
        return if text.trim().eq_ignore_ascii_case("auto") {
            Ok(StiffnessArg::Auto)
        } else {
            Err(PyValueError::new_err(format!("stiffness={text:?}: give a number ≥ 0, or \"auto\"")))
        };
    }
    let v: f64 = value.extract().map_err(|_| PyValueError::new_err("stiffness: give a number ≥ 0, or \"auto\""))?;
    Ok(StiffnessArg::Value(v))
}

#[pymethods]
impl Warp {
    /// Fits `method` on the pairs (see `warpbench.fit`). `fixed_grid` and `moving_grid` are `(dims,
    /// lps_from_index)`: with them the pairs are checked against the volumes and the fit's domains are their boxes,
    /// as on the command line. `initial_field` (a file, or a `Field`'s `(array, lps_from_index, forward)`) lies under
    /// the fit, and `initial` after it (`--initial-field`); a Learn2Reg `.npz` is read against the two grids.
    #[staticmethod]
    #[pyo3(signature = (moving, fixed, names, active, origin, method = "tps", stiffness = None, levels = None,
        initial = None, fixed_grid = None, moving_grid = None, initial_field = None))]
    #[allow(clippy::too_many_arguments, reason = "the Python signature of warpbench.fit")]
    fn fit(
        py: Python<'_>,
        moving: PyReadonlyArray2<'_, f64>,
        fixed: PyReadonlyArray2<'_, f64>,
        names: Vec<String>,
        active: Vec<bool>,
        origin: String,
        method: &str,
        stiffness: Option<&Bound<'_, PyAny>>,
        levels: Option<usize>,
        initial: Option<PathBuf>,
        fixed_grid: Option<(Vec<usize>, PyReadonlyArray2<'_, f64>)>,
        moving_grid: Option<(Vec<usize>, PyReadonlyArray2<'_, f64>)>,
        initial_field: Option<InitialField<'_>>,
    ) -> PyResult<Self> {
        let pairs = pairs_from_arrays(&origin, &moving, &fixed, &names, &active)?;
        let kind = <MethodKind as clap::ValueEnum>::from_str(method, true).map_err(|_| {
            PyValueError::new_err(format!("method={method:?}: give tps, hbspline, affine, similarity or rigid"))
        })?;
        let stiffness = stiffness.map(stiffness_arg).transpose()?.unwrap_or(StiffnessArg::Value(0.0));
        let grids = match (fixed_grid, moving_grid) {
            (Some(f), Some(m)) => Some((grid(Path::new("fixed"), f)?, grid(Path::new("moving"), m)?)),
            (None, None) => None,
            _ => return Err(PyValueError::new_err("give both the fixed and the moving volume, or neither")),
        };
        // A `Field`'s arrays become the layer here, while the GIL is held; a file is read below.
        let (initial_path, given_layer) = match initial_field {
            Some(InitialField::Path(path)) => (Some(path), None),
            Some(InitialField::Arrays(parts)) => {
                (None, Some(std::sync::Arc::new(crate::field::field_layer("initial_field", &parts)?)))
            }
            None => (None, None),
        };
        guarded(py, move || {
            let zeros = grids
                .as_ref()
                .map(|(f, m)| {
                    Ok::<_, PyErr>((geometry_volume(Path::new("fixed"), f)?, geometry_volume(Path::new("moving"), m)?))
                })
                .transpose()?;
            let start = match (initial.as_deref(), &zeros) {
                (None, _) => None,
                (Some(path), Some((f, m))) => Some(Start::read_on(path, f, m).map_err(bad_input)?),
                (Some(path), None) => match StartFile::read(path).map_err(bad_input)? {
                    StartFile::Lps(start) => Some(start),
                    StartFile::Flirt { .. } => {
                        return Err(PyValueError::new_err(format!(
                            "initial={}: an FSL FLIRT matrix is in the voxels of the two images it was made with: \
                             give fixed= (FLIRT's -ref) and moving= (its -in)",
                            path.display()
                        )));
                    }
                    StartFile::Afni { .. } => {
                        return Err(PyValueError::new_err(format!(
                            "initial={}: an AFNI matrix is read with the two volumes, to refuse oblique ones: give \
                             fixed= (AFNI's base) and moving= (its source)",
                            path.display()
                        )));
                    }
                    StartFile::Lta { .. } => {
                        return Err(PyValueError::new_err(format!(
                            "initial={}: a FreeSurfer LTA is read with the two volumes, whose grids tell which way it \
                             maps: give fixed= (FreeSurfer's --dst or --targ) and moving= (its --mov)",
                            path.display()
                        )));
                    }
                },
            };
            let mut layers = Layers::new(start, None);
            layers.field = given_layer;
            if let Some(path) = initial_path {
                let file = match &zeros {
                    Some((f, m)) => FieldFile::chosen(path, FieldReadFormat::Auto, f, m).map_err(bad_input)?,
                    None if FieldReadFormat::Auto.reads_against_pair(&path).map_err(io)? => {
                        return Err(PyValueError::new_err(format!(
                            "initial_field={}: a Learn2Reg field (steps in voxels) or an FSL FNIRT warp (in FSL's \
                             coordinates) is read against its fixed and moving images: give fixed= and moving=",
                            path.display()
                        )));
                    }
                    None => FieldFile::new(path),
                };
                layers.field = Some(std::sync::Arc::new(file.layer().map_err(bad_input)?));
            }
            let within = zeros.as_ref().map(|(f, m)| (m, f));
            // Checked with the fewest pairs any method needs on this base; the method's own count is checked by
            // the fit, whose message names it.
            let used = inputs::collect_pairs(&origin, &pairs, within, 0).map_err(bad_input)?;
            let method = match stiffness {
                StiffnessArg::Value(lambda) => inputs::checked_method(kind, lambda, levels).map_err(bad_input)?,
                StiffnessArg::Auto if kind == MethodKind::Tps => {
                    let choice = warpbench_solver::stiffness::choose_stiffness(&used.fixed, &used.moving)
                        .map_err(|e| bad_input(anyhow!("{origin}: stiffness=\"auto\": {e}")))?;
                    Method::Tps { stiffness: choice.lambda }
                }
                StiffnessArg::Auto => {
                    return Err(PyValueError::new_err(format!(
                        "stiffness=\"auto\" chooses the TPS's λ: it needs method=\"tps\", not {method:?}"
                    )));
                }
            };
            let needs = layers.min_pairs(&method);
            if used.moving.len() < needs {
                return Err(bad_input(anyhow!(
                    "{origin}: {} active pairs with both points; {method} needs at least {needs}",
                    used.moving.len()
                )));
            }
            let (fixed_box, moving_box) = match &zeros {
                Some((f, m)) => (inputs::volume_box(f), inputs::volume_box(m)),
                None => (points_box(&used.fixed), points_box(&used.moving)),
            };
            let pullback = fit::pullback_stack(&method, &used, fixed_box, layers.clone()).map_err(bad_input)?;
            let forward = fit::forward_stack(&method, &used, moving_box, layers.clone()).map_err(bad_input)?;
            Ok(Self { method, pairs, used, layers, pullback, forward, fixed_box, grids })
        })
    }

    /// The method as fitted, e.g. `tps`, `tps(λ=12.5)`, `affine`.
    #[getter]
    fn method(&self) -> String {
        self.layers.describe(&self.method, self.used.moving.len())
    }

    /// The 1-based rows (in the pairs given) of the pairs the warp is fitted on.
    #[getter]
    fn rows(&self) -> Vec<usize> {
        self.used.labels.iter().map(|(row, _)| *row).collect()
    }

    /// u(x) for the N×3 fixed points `points` (LPS mm): where each comes from in the moving volume.
    fn pullback(&self, py: Python<'_>, points: PyReadonlyArray2<'_, f64>) -> PyResult<Py<PyAny>> {
        let xs = points_in("pullback", &points)?;
        let mut out = vec![[0.0; 3]; xs.len()];
        guarded(py, || {
            self.pullback.apply_batch_raw(&xs, &mut out);
            Ok(())
        })?;
        Ok(points_out(py, &out))
    }

    /// d(y) for the N×3 moving points `points` (LPS mm): where each appears in the fixed volume.
    fn forward(&self, py: Python<'_>, points: PyReadonlyArray2<'_, f64>) -> PyResult<Py<PyAny>> {
        let ys = points_in("forward", &points)?;
        let mut out = vec![[0.0; 3]; ys.len()];
        guarded(py, || {
            self.forward.apply_batch_raw(&ys, &mut out);
            Ok(())
        })?;
        Ok(points_out(py, &out))
    }

    /// The displacement field on `reference` (`(dims, lps_from_index)`): u(x) − x (`direction="pullback"`) or
    /// d(y) − y (`"forward"`) at every voxel centre, as a (ni, nj, nk, 3) float32 array of LPS vectors, written to
    /// `path` in `format` (`itk`, `ants`, `nrrd`, `metaimage`, `minc`, `ngff`, `learn2reg`) when given, as `warpbench
    /// field` writes it.
    /// Learn2Reg's field (`learn2reg`, or a `path` ending `.npz`) is the pull-back's steps from `reference`'s voxels to
    /// those of `moving` (`(dims, lps_from_index)`), which it needs.
    #[pyo3(signature = (reference, direction = "pullback", path = None, format = "itk", moving = None))]
    fn field(
        &self,
        py: Python<'_>,
        reference: (Vec<usize>, PyReadonlyArray2<'_, f64>),
        direction: &str,
        path: Option<PathBuf>,
        format: &str,
        moving: Option<(Vec<usize>, PyReadonlyArray2<'_, f64>)>,
    ) -> PyResult<Py<PyAny>> {
        let (dims, lps) = grid(Path::new("reference"), reference)?;
        let moving = moving.map(|m| grid(Path::new("moving"), m)).transpose()?;
        let direction =
            <field::DirectionArg as clap::ValueEnum>::from_str(direction, true)
                .map(FieldDirection::from)
                .map_err(|_| PyValueError::new_err(format!("direction={direction:?}: give pullback or forward")))?;
        let arg = <field::FormatArg as clap::ValueEnum>::from_str(format, true).map_err(|_| {
            PyValueError::new_err(format!(
                "format={format:?}: give itk, ants, nrrd, metaimage, minc, ngff, learn2reg or fnirt"
            ))
        })?;
        let to = match &path {
            Some(path) if let Some(kind) = arg.pair_output(path) => {
                let (what, pullback) = match kind {
                    field::PairOutput::Learn2Reg => (
                        "Learn2Reg's field holds steps into the moving volume's voxels",
                        "Learn2Reg's field maps fixed voxels to moving ones (the pull-back)",
                    ),
                    field::PairOutput::Fnirt => (
                        "FNIRT's field is in the moving volume's FSL coordinates",
                        "FNIRT's field maps the reference (fixed) grid into the input (the pull-back)",
                    ),
                };
                let Some(moving) = moving else {
                    return Err(PyValueError::new_err(format!(
                        "{}: {what}: fit the warp with moving=",
                        path.display()
                    )));
                };
                if direction == FieldDirection::Forward {
                    return Err(PyValueError::new_err(format!(
                        "{}: {pullback}: leave out direction=\"forward\"",
                        path.display()
                    )));
                }
                if kind == field::PairOutput::Fnirt
                    && warpbench_io::displacement::FieldFormat::from_extension(path)
                        != Some(warpbench_io::displacement::FieldFormat::Itk)
                {
                    return Err(PyValueError::new_err(format!(
                        "{}: format=\"fnirt\" writes FNIRT's deformation field, a NIfTI file: name it .nii or .nii.gz",
                        path.display()
                    )));
                }
                Written::Pair(kind, path, moving)
            }
            Some(path) => Written::Flavour(path, arg.flavour_for(path)),
            None => Written::Nothing,
        };
        let field = guarded(py, || match direction {
            FieldDirection::Pullback => self.sample(&self.pullback, dims, &lps, direction, &to),
            FieldDirection::Forward => self.sample(&self.forward, dims, &lps, direction, &to),
        })?;
        let mut flat = Vec::with_capacity(3 * field.displacements_lps.len());
        for a in 0..3 {
            flat.extend(field.displacements_lps.iter().map(|d| d[a]));
        }
        let array = Array4::from_shape_vec((dims[0], dims[1], dims[2], 3).f(), flat)
            .map_err(|e| PyValueError::new_err(format!("field: {e}")))?;
        Ok(PyArray::from_owned_array(py, array).into_any().unbind())
    }

    /// `quantity` (`det`: det ∇u; `magnitude`: |u(x) − x|, mm) at every voxel centre of `reference` (`(dims,
    /// lps_from_index)`), as a (ni, nj, nk) float32 array: what `warpbench jacobian` writes; of d (det ∇d, |d(y) −
    /// y|) with `direction="forward"`.
    #[pyo3(signature = (reference, quantity = "det", direction = "pullback"))]
    fn jacobian(
        &self,
        py: Python<'_>,
        reference: (Vec<usize>, PyReadonlyArray2<'_, f64>),
        quantity: &str,
        direction: &str,
    ) -> PyResult<Py<PyAny>> {
        let name = Path::new("reference");
        let grid = grid(name, reference)?;
        let quantity = <jacobian::Quantity as clap::ValueEnum>::from_str(quantity, true)
            .map_err(|_| PyValueError::new_err(format!("quantity={quantity:?}: give det or magnitude")))?;
        let direction =
            <field::DirectionArg as clap::ValueEnum>::from_str(direction, true)
                .map(FieldDirection::from)
                .map_err(|_| PyValueError::new_err(format!("direction={direction:?}: give pullback or forward")))?;
        let volume = geometry_volume(name, &grid)?;
        let out = Path::new("jacobian");
        let map = guarded(py, || {
            match direction {
                FieldDirection::Pullback => jacobian::sample_map(&self.pullback, quantity, &volume, out),
                FieldDirection::Forward => {
                    jacobian::sample_map_with(|p| quantity.at_forward(&self.forward, p), quantity, &volume, out)
                }
            }
            .map_err(|f| to_py(&f))
        })?;
        samples_to_numpy(py, map.volume.dims, map.volume.data)
    }

    /// The moving volume (`array`, `lps_from_index`) resampled through the pull-back on `reference`'s grid (or the
    /// fixed volume's), as `warpbench warp` resamples it: `(array, lps_from_index, report)`.
    #[pyo3(signature = (moving, lps, reference = None, interpolation = "linear", exact = false, grid_n = 64,
        float = false, outside = None, modality = None, backend = "cpu"))]
    #[allow(clippy::too_many_arguments, reason = "the Python signature of Warp.resample")]
    fn resample(
        &self,
        py: Python<'_>,
        moving: &Bound<'_, PyAny>,
        lps: PyReadonlyArray2<'_, f64>,
        reference: Option<(Vec<usize>, PyReadonlyArray2<'_, f64>)>,
        interpolation: &str,
        exact: bool,
        grid_n: usize,
        float: bool,
        outside: Option<f64>,
        modality: Option<&str>,
        backend: &str,
    ) -> PyResult<(Py<PyAny>, Py<PyAny>, String)> {
        let mut moving = volume_from_numpy(Path::new("moving"), moving, &lps)?;
        moving.modality =
            modality.map_or(warpbench_io::volume::Modality::Unknown, warpbench_io::volume::Modality::from_dicom);
        let reference = reference.map(|r| grid(Path::new("reference"), r)).transpose()?;
        let interp = <warp_cmd::InterpArg as clap::ValueEnum>::from_str(interpolation, true).map_err(|_| {
            PyValueError::new_err(format!("interpolation={interpolation:?}: give nearest, linear or cubic"))
        })?;
        let backend = match backend {
            "cpu" => Backend::Cpu,
            "gpu" => Backend::Gpu,
            "auto" => Backend::Auto,
            other => return Err(PyValueError::new_err(format!("backend={other:?}: give cpu, gpu or auto"))),
        };
        if !(2..=256).contains(&grid_n) {
            return Err(PyValueError::new_err(format!("grid_n={grid_n}: give 2 to 256 texels per axis")));
        }
        let settings = WarpSettings {
            method: self.method,
            pullback: if exact { PullBackMode::Exact } else { PullBackMode::Grid(grid_n) },
            interpolation: interp.into(),
            float,
            backend,
            outside_value: outside,
        };
        let resampled = guarded(py, || {
            let fixed_grid = match (&self.grids, &reference) {
                (Some((fixed, _)), _) => *fixed,
                (None, Some(r)) => *r,
                (None, None) => {
                    return Err(PyValueError::new_err(
                        "resample: give reference=, or fit the warp with the fixed and the moving volume",
                    ));
                }
            };
            let fixed = geometry_volume(Path::new("fixed"), &fixed_grid)?;
            let grid_volume = reference.as_ref().map(|r| geometry_volume(Path::new("reference"), r)).transpose()?;
            let names = Names { moving: "moving".into(), landmarks: "pairs".into(), out: PathBuf::from("resampled") };
            warp_cmd::resample(
                grid_volume.as_ref().unwrap_or(&fixed),
                &fixed,
                &moving,
                (&self.pairs, &self.layers),
                &names,
                &settings,
                &mut |_| true,
            )
            .map_err(|f| to_py(&f))
        })?;
        let report = serde_json::json!({
            "method": resampled.method,
            "pairs": resampled.pairs,
            "pullback": resampled.pullback,
            "interpolation": resampled.interpolation,
            "backend": resampled.backend,
            "outside_value": resampled.outside_value,
            "warnings": resampled.warnings,
        })
        .to_string();
        let volume = resampled.volume;
        let lps_out = crate::volume::matrix(py, &volume.lps_from_index.rows());
        Ok((samples_to_numpy(py, volume.dims, volume.data)?, lps_out, report))
    }

    /// Writes the pull-back as the ITK transform file that holds it exactly (thin-plate spline, B-spline, affine),
    /// as `warpbench transform` writes it: text, ITK's HDF5 file for a name ending `.h5`, ANTs' `.mat` for one
    /// ending `.mat`.
    fn to_itk_tfm(&self, py: Python<'_>, path: PathBuf) -> PyResult<()> {
        guarded(py, || {
            let no_transform = match self.pullback.itk_transform() {
                Ok(transform) => return transform_file::write(&path, &transform).map_err(io),
                Err(e) => e,
            };
            // A warp on a field: ITK's composite of its layers, in an .h5 only.
            let Some(composite) = self.pullback.itk_composite() else { return Err(bad_input(no_transform)) };
            if !warpbench_io::itk_tfm::is_hdf5_name(&path) {
                return Err(PyValueError::new_err(format!(
                    "{}: a text ITK transform file cannot hold this warp exactly (it lies on a displacement field): \
                     name the file .h5 for ITK's composite of its layers",
                    path.display()
                )));
            }
            let sampled = matches!(composite.rest, ItkRest::Sampled(_));
            if sampled && self.grids.is_none() {
                return Err(PyValueError::new_err(format!(
                    "{}: the TPS over the field is written sampled on the fixed grid: fit with fixed= and moving=",
                    path.display()
                )));
            }
            let grid = self.grids.as_ref().map(|((dims, lps), _)| (*dims, lps));
            transform::write_h5_composite(&path, &composite, grid, &path, &mut |_, _| true).map_err(|f| to_py(&f))?;
            Ok(())
        })
    }

    /// Writes the pull-back, a linear warp, as FSL's FLIRT matrix between the fixed grid (FLIRT's reference) and the
    /// moving one (its input) the warp was fitted with, as `warpbench transform --format fsl` writes it.
    fn to_fsl(&self, py: Python<'_>, path: PathBuf) -> PyResult<()> {
        let Some(((fixed_dims, fixed_lps), (moving_dims, moving_lps))) = &self.grids else {
            return Err(PyValueError::new_err(format!(
                "{}: a FLIRT matrix is in the voxels of the two images: fit the warp with fixed= and moving=",
                path.display()
            )));
        };
        guarded(py, || {
            let transform = self.pullback.itk_transform().map_err(bad_input)?;
            transform::write_flirt(&path, &transform, (*fixed_dims, fixed_lps), (*moving_dims, moving_lps))
                .map_err(|f| to_py(&f))
        })
    }

    /// Writes the pull-back, a linear warp, as AFNI's matrix file (`.aff12.1D`) between the volumes the warp was
    /// fitted with, as `warpbench transform --format afni` writes it.
    fn to_afni(&self, py: Python<'_>, path: PathBuf) -> PyResult<()> {
        let Some(((_, fixed_lps), (_, moving_lps))) = &self.grids else {
            return Err(PyValueError::new_err(format!(
                "{}: an AFNI matrix is written between two volumes that are not oblique: fit the warp with fixed= \
                 and moving=",
                path.display()
            )));
        };
        guarded(py, || {
            let transform = self.pullback.itk_transform().map_err(bad_input)?;
            transform::write_afni(&path, &transform, fixed_lps, moving_lps).map_err(|f| to_py(&f))
        })
    }

    /// Writes the pull-back, a linear warp, as an MNI transform file (`.xfm`): the moving volume's world to the fixed
    /// one's, RAS mm, as `warpbench transform --format minc` writes it for `mincresample -transformation`.
    fn to_xfm(&self, py: Python<'_>, path: PathBuf) -> PyResult<()> {
        guarded(py, || {
            let transform = self.pullback.itk_transform().map_err(bad_input)?;
            transform::write_xfm(&path, &transform).map_err(|f| to_py(&f))
        })
    }

    /// Writes the pull-back, a linear warp, as FreeSurfer's LTA (`LINEAR_RAS_TO_RAS`), src the moving volume and dst
    /// the fixed one the warp was fitted with, each named by `fixed_name` and `moving_name` (its file, or empty), as
    /// `warpbench transform --format lta` writes it.
    #[pyo3(signature = (path, fixed_name, moving_name))]
    fn to_lta(&self, py: Python<'_>, path: PathBuf, fixed_name: String, moving_name: String) -> PyResult<()> {
        let Some(((fixed_dims, fixed_lps), (moving_dims, moving_lps))) = &self.grids else {
            return Err(PyValueError::new_err(format!(
                "{}: an LTA states the grids of the two volumes: fit the warp with fixed= and moving=",
                path.display()
            )));
        };
        guarded(py, || {
            let transform = self.pullback.itk_transform().map_err(bad_input)?;
            let fixed = ((*fixed_dims, fixed_lps), fixed_name.as_str());
            let moving = ((*moving_dims, moving_lps), moving_name.as_str());
            transform::write_lta(&path, &transform, fixed, moving).map_err(|f| to_py(&f))
        })
    }

    /// Writes the pull-back as the elastix transform parameter file that holds it exactly (`SplineKernelTransform`,
    /// `BSplineTransform`, `AffineTransform`) over `reference`'s grid (where transformix resamples), as `warpbench
    /// transform --format elastix` writes it.
    fn to_elastix(
        &self,
        py: Python<'_>,
        path: PathBuf,
        reference: (Vec<usize>, PyReadonlyArray2<'_, f64>),
    ) -> PyResult<()> {
        let (dims, lps_from_index) = grid(Path::new("reference"), reference)?;
        guarded(py, || {
            let transform = self.pullback.itk_transform().map_err(bad_input)?;
            elastix::write(&path, &transform, &ElastixGrid { dims, lps_from_index }).map_err(io)
        })
    }

    /// Writes the pull-back as a DICOM registration from the DICOM series at `moving_path` onto the one at
    /// `fixed_path`, as `warpbench transform --format dicom` writes it: a Spatial Registration (its matrix u⁻¹) for a
    /// linear warp, else a Deformable Spatial Registration of the pull-back sampled on `reference` (`(dims,
    /// lps_from_index)`, the fixed volume's grid). Returns `RIGID`, `RIGID_SCALE`, `AFFINE` or `DEFORMABLE`.
    fn to_dicom(
        &self,
        py: Python<'_>,
        path: PathBuf,
        fixed_path: PathBuf,
        moving_path: PathBuf,
        reference: (Vec<usize>, PyReadonlyArray2<'_, f64>),
    ) -> PyResult<String> {
        let (dims, lps) = grid(Path::new("reference"), reference)?;
        let is_dcm = path.extension().is_some_and(|e| e.eq_ignore_ascii_case("dcm"));
        if !is_dcm {
            return Err(PyValueError::new_err(format!(
                "{}: a DICOM registration is written to one file named .dcm",
                path.display()
            )));
        }
        guarded(py, || {
            let fixed = DicomSource::read(&fixed_path, None).map_err(io)?;
            let moving = DicomSource::read(&moving_path, None).map_err(io)?;
            if let Ok(ItkTransform::Affine(u)) = self.pullback.itk_transform() {
                let description = format!("{} of {} pairs (warpbench)", self.method, self.used.moving.len());
                let kind = transform::write_spatial_registration(&path, &fixed, &moving, &u, &description)
                    .map_err(|f| to_py(&f))?;
                return Ok(kind.name().to_owned());
            }
            let field = self.sample(&self.pullback, dims, &lps, FieldDirection::Pullback, &Written::Nothing)?;
            transform::write_deformable_registration(&path, &fixed, &moving, &field).map_err(|f| to_py(&f))?;
            Ok("DEFORMABLE".to_owned())
        })
    }

    /// For each pair fitted on: `(row, residual_mm, leave_one_out_mm)`, the row 1-based in the pairs given, the
    /// leave-one-out error `None` where the fit without the pair fails; as the window's landmark table shows them.
    fn leave_one_out(&self, py: Python<'_>) -> PyResult<Vec<(usize, f64, Option<f64>)>> {
        guarded(py, || {
            let input = DiagnosticsInput {
                method: self.method,
                rows: self.rows(),
                fixed: self.used.fixed.clone(),
                moving: self.used.moving.clone(),
                fixed_box: self.fixed_box,
                pullback: self.pullback.clone(),
            };
            let diagnostics = input.compute();
            Ok(diagnostics.pair_errors.into_iter().map(|(row, e)| (row, e.residual_mm, e.leave_one_out_mm)).collect())
        })
    }

    /// det ∇u at the centres of an n³ grid of cells over `reference`'s box (or the fit's fixed domain):
    /// `(min_det, min_at, max_det, fraction_folded, points)`.
    #[pyo3(signature = (reference = None, n = 64))]
    fn folding(
        &self,
        py: Python<'_>,
        reference: Option<(Vec<usize>, PyReadonlyArray2<'_, f64>)>,
        n: usize,
    ) -> PyResult<(f64, [f64; 3], f64, f64, usize)> {
        if !(2..=512).contains(&n) {
            return Err(PyValueError::new_err(format!("n={n}: give 2 to 512 points per axis")));
        }
        let domain = match reference {
            Some(r) => grid_box(Path::new("reference"), &grid(Path::new("reference"), r)?)?,
            None => self.fixed_box,
        };
        let report = guarded(py, || Ok(jacobian_determinants(&self.pullback, &domain, [n; 3], Parallelism::Rayon)))?;
        Ok((report.min_det, report.min_at, report.max_det, report.fraction_folded, report.points))
    }
}

impl Warp {
    /// Samples `warp` on the grid into a [`Field`] and writes it to `path` in `format` when given.
    fn sample<To: Space, From: Space>(
        &self,
        warp: &dyn warpbench_solver::warp::Warp<To, From>,
        dims: [usize; 3],
        lps: &Transform<Lps, Index>,
        direction: FieldDirection,
        to: &Written<'_>,
    ) -> PyResult<Field> {
        let out = match to {
            Written::Flavour(path, _) | Written::Pair(_, path, _) => path,
            Written::Nothing => Path::new("field"),
        };
        warpbench_io::volume::check_allocation(out, dims, 12, warpbench_io::volume::DEFAULT_MAX_VOXEL_BYTES)
            .map_err(io)?;
        let sampled = field::sample_displacements(warp, dims, lps, &mut |_, _| true)
            .ok_or_else(|| PyValueError::new_err("sampling the displacement field: cancelled"))?;
        let Some(max_displacement_mm) = sampled.max_norm_mm else {
            return Err(to_py(&warpbench_app::exit::Failure::Internal(anyhow!(
                "the {} warp is not finite somewhere in the output grid",
                self.method
            ))));
        };
        let transform = match direction {
            FieldDirection::Pullback => self.pullback.itk_transform().ok(),
            FieldDirection::Forward => None,
        };
        let field = Field {
            dims,
            spacing_mm: warpbench_io::geometry::spacing_mm(lps),
            lps_from_index: *lps,
            displacements_lps: sampled.displacements_lps,
            direction,
            max_displacement_mm,
            method: self.layers.describe(&self.method, self.used.moving.len()),
            pairs: self.used.moving.len(),
            transform,
            warnings: fit::fit_warnings(&self.method, &self.used),
        };
        match to {
            Written::Flavour(path, format) => field::write_field(&field, path, *format, None).map_err(|f| to_py(&f))?,
            Written::Pair(kind, path, (moving_dims, moving_lps)) => {
                kind.write(path, (dims, lps), (*moving_dims, moving_lps), &field.displacements_lps)
                    .map_err(|f| to_py(&f))?;
            }
            Written::Nothing => {}
        }
        Ok(field)
    }
}
