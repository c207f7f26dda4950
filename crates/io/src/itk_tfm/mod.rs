//! ITK transform files (`.tfm`, "Insight Transform File V1.0") holding one transform: an affine map, a thin-plate
//! spline or a cubic B-spline ([`ItkTransform`]); [`write()`], [`read`], [`parse`], and for callers that want only an
//! affine [`write_affine`], [`read_affine`], [`parse_affine`]. The same affine in the binary MATLAB v4 file that ANTs
//! and ITK's `MatlabTransformIO` write (`.mat`, module `ants_mat`: [`parse_mat`], [`to_mat_bytes`]) goes through
//! the same four functions: this module is the one entry for transform files, and it tells them apart by the name
//! (`.mat`) and by the content.
//!
//! # The format
//!
//! A text file that ITK's `TransformFileReader`/`Writer` (and SimpleITK's `ReadTransform`, ANTs, 3D Slicer) read:
//!
//! ```text
//! #Insight Transform File V1.0
//! #Transform 0
//! Transform: <class>_double_3_3
//! Parameters: p1 p2 …
//! FixedParameters: f1 f2 …
//! ```
//!
//! Points are in ITK's physical space, which is **LPS mm**, the same as ours: no RAS conversion is involved (3D
//! Slicer flips to its RAS when it loads the file). A transform used for resampling maps output points to input
//! points, so a registration's `.tfm` holds the pull-back `moving_from_fixed`, and that is what `warpbench field
//! --tfm` writes. The three classes:
//!
//! - **`AffineTransform_double_3_3`** ([`ItkAffine`]): the parameters are the matrix A row by row, then the
//!   translation t; the fixed parameters are the centre c. ITK's `MatrixOffsetTransformBase` maps
//!
//!   ```text
//!   T(x) = A (x − c) + c + t = A x + o,    o = t + c − A c   (the "offset")
//!   ```
//!
//!   We write c = 0 (then t = o) and read any centre.
//!
//! - **`ThinPlateSplineKernelTransform_double_3_3`** ([`ItkThinPlateSpline`]): the parameters are the N *source*
//!   landmarks sᵢ (x, y, z each), the fixed parameters the N *target* landmarks tᵢ (ITK's
//!   `KernelTransform::SetParameters` sets the source landmarks, `SetFixedParameters` the target ones). ITK's
//!   `ComputeWMatrix` fits T(x) = x + A x + b + Σᵢ wᵢ ‖x − sᵢ‖ with T(sᵢ) = tᵢ (kernel G(r) = r·I in 3-D, stiffness 0
//!   for a transform read from a file), so T maps source to target; no weights are stored. Neither SimpleITK nor
//!   ITK's Python wrapping registers this class with ITK's `TransformFactory`, so their `ReadTransform` refuses the
//!   file; 3D Slicer registers it (and rebuilds the spline from the landmarks), and a C++ program can call
//!   `itk::TransformFactory<itk::ThinPlateSplineKernelTransform<double, 3>>::RegisterTransform()` before reading and
//!   must call `ComputeWMatrix()` after (until then `TransformPoint` uses no weights).
//!
//! - **`BSplineTransform_double_3_3`** ([`ItkBSpline`], ITK's v4 cubic B-spline): the fixed parameters are 18
//!   numbers, the grid size (control points per axis), the grid origin (LPS mm of control point (0, 0, 0)), the grid
//!   spacing (mm) and the grid direction (row by row); the parameters are the displacement coefficients, all x
//!   components first (control points in image order, x fastest), then all y, then all z. With the continuous grid
//!   index c = (D·diag(spacing))⁻¹ (x − origin), ITK maps
//!
//!   ```text
//!   T(x) = x + Σ_{a,b,c ∈ 0..4} B_a(tₓ) B_b(t_y) B_c(t_z) φ_{(⌊cₓ⌋−1+a)(⌊c_y⌋−1+b)(⌊c_z⌋−1+c)},   t = c − ⌊c⌋
//!   ```
//!
//!   (uniform cubic basis B₀ = (1−t)³/6, …) where 1 ≤ c < size − 2 on every axis — the *transform domain*, whose
//!   origin is one spacing above the grid origin and which is (size − 3) spacings long — and T(x) = x elsewhere
//!   (`BSplineTransform::InsideValidRegion`). [`ItkBSpline::apply`] is that rule.
//!
//! - **ITK's other linear classes**, read (not written) as the [`ItkAffine`] they are, x ↦ M (x − c) + c + t with the
//!   centre c from the fixed parameters: `TranslationTransform` (t; no fixed parameters), `ScaleTransform` (the
//!   diagonal of M; c), `Euler3DTransform` (angles θx, θy, θz and t; c, and ITK 5's ComputeZYX flag: M = Rz Rx Ry,
//!   or Rz Ry Rx with the flag 1), `VersorTransform` (the versor's vector part; c), `VersorRigid3DTransform` (versor,
//!   t; c), `Similarity3DTransform` (versor, t, scale s: M = s R; c), `ScaleVersor3DTransform` (versor, t, scale s;
//!   c: ITK adds the scale to the rotation, M = R + diag(s) − I) and ITK 5's `ScaleSkewVersor3DTransform` (versor, t,
//!   s, six skews k added off the diagonal: M = R + diag(s) − I + K; ITK 6's twelve-parameter form is refused).
//!   These are what SimpleITK's registrations write (an `Euler3DTransform` from `CenteredTransformInitializer`, say).
//!
//! Numbers are written with Rust's shortest round-trip formatting, so a written file reads back bit for bit.
//! A float (`_float_3_3`) variant of each class is read too. Other transform types and files with several transforms
//! (composites) are refused with an error that names the file and what it holds.
//!
//! # The ANTs / ITK `.mat`
//!
//! `antsRegistration`'s `*0GenericAffine.mat`, and what ITK writes for a transform file named `.mat`, hold one
//! affine: a MATLAB v4 variable named after the class (`AffineTransform_double_3_3`, 12 numbers: A row by row, then
//! t) and one named `fixed` (the centre c), the same numbers and the same meaning as the `.tfm` above. [`read`] and
//! [`read_affine`] take such a file wherever they take a `.tfm` (the name `.mat`, or its first bytes, say which),
//! and [`write()`] and [`write_affine`] write one for a name ending in `.mat` (an affine only: a thin-plate spline or
//! a B-spline is refused there). Little-endian doubles, as SimpleITK writes them, so the same transform gives the
//! same bytes; big-endian and float files are read. The layout is in `ants_mat`'s docs.
//!
//! # ITK's HDF5 files
//!
//! ITK's `.h5` transform files (ANTs' `Composite.h5`, 3D Slicer's) hold the same classes in HDF5 datasets and are read
//! and written by [`crate::itk_h5`]; [`crate::transform_file::write`] writes either by the file's name. [`write()`]
//! writes text, so it refuses a name ending in `.h5` ([`is_hdf5_name`]): ITK would read that file as HDF5.

mod ants_mat;

use std::io::Write;
use std::path::Path;

use nalgebra::{Matrix3, Vector3};

use crate::error::{Error, ErrorKind, Result};

use ants_mat::{MatAffine, mat_bytes, parse_mat_numbers};

/// The first line of every ITK transform file.
pub(crate) const MAGIC: &str = "#Insight Transform File V1.0";

/// Transform types read as an affine (all share the 12 + 3 parameter layout).
const AFFINE_TYPES: [&str; 3] =
    ["AffineTransform_double_3_3", "AffineTransform_float_3_3", "MatrixOffsetTransformBase_double_3_3"];

/// ITK's other linear classes, read as the affine they are ([`linear_of`]); their `_float_3_3` twins too.
const LINEAR_TYPES: [&str; 8] = [
    "TranslationTransform_double_3_3",
    "ScaleTransform_double_3_3",
    "Euler3DTransform_double_3_3",
    "VersorTransform_double_3_3",
    "VersorRigid3DTransform_double_3_3",
    "Similarity3DTransform_double_3_3",
    "ScaleVersor3DTransform_double_3_3",
    "ScaleSkewVersor3DTransform_double_3_3",
];

/// Transform types read as a thin-plate spline.
const TPS_TYPES: [&str; 2] = ["ThinPlateSplineKernelTransform_double_3_3", "ThinPlateSplineKernelTransform_float_3_3"];

/// Transform types read as a cubic B-spline (ITK's default spline order is 3).
const BSPLINE_TYPES: [&str; 2] = ["BSplineTransform_double_3_3", "BSplineTransform_float_3_3"];

/// The most control points a B-spline file may hold (all axes together), as many as warpbench's solver builds.
pub const MAX_BSPLINE_CONTROL_POINTS: usize = 1 << 21;

/// The most landmarks a thin-plate-spline file may hold (ITK's solve is O(N³) in 3N unknowns).
pub const MAX_TPS_LANDMARKS: usize = 20_000;

/// The longest file read: a B-spline of [`MAX_BSPLINE_CONTROL_POINTS`] at ~25 characters a number.
const MAX_FILE_BYTES: u64 = 256 << 20;

/// One transform of an ITK transform file (module docs), LPS mm to LPS mm.
#[derive(Clone, Debug, PartialEq)]
pub enum ItkTransform {
    /// `AffineTransform_double_3_3`.
    Affine(ItkAffine),
    /// `ThinPlateSplineKernelTransform_double_3_3`.
    ThinPlateSpline(ItkThinPlateSpline),
    /// `BSplineTransform_double_3_3`.
    BSpline(ItkBSpline),
}

impl ItkTransform {
    /// The ITK class name written on the `Transform:` line.
    #[must_use]
    pub fn type_name(&self) -> &'static str {
        match self {
            Self::Affine(_) => AFFINE_TYPES[0],
            Self::ThinPlateSpline(_) => TPS_TYPES[0],
            Self::BSpline(_) => BSPLINE_TYPES[0],
        }
    }

    /// The file's text (see the module docs).
    #[must_use]
    pub fn to_text(&self) -> String {
        let mut out = Vec::new();
        // Writing into a Vec cannot fail.
        let _ = self.write_text(&mut out);
        String::from_utf8(out).unwrap_or_default()
    }

    fn write_text(&self, w: &mut dyn Write) -> std::io::Result<()> {
        let numbers = |w: &mut dyn Write, values: &[f64]| -> std::io::Result<()> {
            for v in values {
                write!(w, " {v}")?;
            }
            writeln!(w)
        };
        let (params, fixed) = self.parameters();
        write!(w, "{MAGIC}\n#Transform 0\nTransform: {}\nParameters:", self.type_name())?;
        numbers(w, &params)?;
        write!(w, "FixedParameters:")?;
        numbers(w, &fixed)
    }

    /// ITK's `Parameters` and `FixedParameters` of the transform (module docs): what a `.tfm` writes on its two
    /// lines and an `.h5` group in its two datasets ([`crate::itk_h5`]).
    pub(crate) fn parameters(&self) -> (Vec<f64>, Vec<f64>) {
        match self {
            Self::Affine(a) => {
                let m = &a.matrix;
                ((0..3).flat_map(|r| (0..3).map(move |c| m[(r, c)])).chain(a.translation).collect(), a.center.to_vec())
            }
            Self::ThinPlateSpline(t) => {
                (t.source_lps.iter().flatten().copied().collect(), t.target_lps.iter().flatten().copied().collect())
            }
            Self::BSpline(b) => {
                let params = (0..3).flat_map(|c| b.coefficients_mm.iter().map(move |phi| phi[c])).collect();
                let size = b.grid_size.map(|n| n as f64);
                let direction = b.grid_direction.iter().flatten().copied();
                (params, size.into_iter().chain(b.grid_origin_lps).chain(b.grid_spacing_mm).chain(direction).collect())
            }
        }
    }

    /// Checks what ITK needs of the transform (module docs); `name` is used in errors.
    pub(crate) fn check(&self, name: &Path) -> Result<()> {
        match self {
            Self::Affine(a) if !a.is_finite() => {
                Err(Error::invalid(name, format!("the affine transform is not finite: {a:?}")))
            }
            Self::Affine(_) => Ok(()),
            Self::ThinPlateSpline(t) => t.check(name),
            Self::BSpline(b) => b.check(name),
        }
    }
}

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
        ItkTransform::Affine(*self).to_text()
    }

    fn is_finite(&self) -> bool {
        self.matrix.iter().chain(&self.translation).chain(&self.center).all(|v| v.is_finite())
    }
}

/// ITK's thin-plate spline as its file holds it: the landmarks only. T(`source_lps[i]`) = `target_lps[i]`, and the
/// spline between them is the interpolating one with kernel U(r) = r (module docs), which ITK recomputes on reading.
#[derive(Clone, Debug, PartialEq)]
pub struct ItkThinPlateSpline {
    /// sᵢ, the `Parameters` (LPS mm).
    pub source_lps: Vec<[f64; 3]>,
    /// tᵢ, the `FixedParameters` (LPS mm), one per source landmark.
    pub target_lps: Vec<[f64; 3]>,
}

impl ItkThinPlateSpline {
    fn check(&self, name: &Path) -> Result<()> {
        let (n, m) = (self.source_lps.len(), self.target_lps.len());
        if n != m {
            return Err(Error::invalid(name, format!("{n} source landmarks but {m} target landmarks")));
        }
        if n == 0 || n > MAX_TPS_LANDMARKS {
            return Err(Error::invalid(
                name,
                format!("{n} landmarks; a thin-plate spline file holds 1 to {MAX_TPS_LANDMARKS}"),
            ));
        }
        let bad = self.source_lps.iter().chain(&self.target_lps).position(|p| !p.iter().all(|v| v.is_finite()));
        if let Some(i) = bad {
            let (side, k) = if i < n { ("source", i) } else { ("target", i - n) };
            return Err(Error::invalid(name, format!("{side} landmark {} is not finite", k + 1)));
        }
        Ok(())
    }
}

/// ITK's cubic `BSplineTransform` as its file holds it (module docs): a displacement coefficient per control point
/// of a grid, and the grid's geometry.
#[derive(Clone, Debug, PartialEq)]
pub struct ItkBSpline {
    /// Control points per axis (cells of the transform domain + 3), each ≥ 4.
    pub grid_size: [usize; 3],
    /// Where control point (0, 0, 0) is, LPS mm: the transform domain's origin less one spacing (along the grid axes).
    pub grid_origin_lps: [f64; 3],
    /// Distance between control points along each grid axis, mm.
    pub grid_spacing_mm: [f64; 3],
    /// The grid axes in LPS, row by row (column a is grid axis a; the identity for an axis-aligned grid).
    pub grid_direction: [[f64; 3]; 3],
    /// φ, the displacement (LPS mm) at each control point, control points in image order (x fastest).
    pub coefficients_mm: Vec<[f64; 3]>,
}

impl ItkBSpline {
    /// T(x) as ITK's `BSplineTransform::TransformPoint` computes it (module docs): x plus the B-spline inside the
    /// transform domain, x itself outside it.
    #[must_use]
    pub fn apply(&self, x: [f64; 3]) -> [f64; 3] {
        self.index_from_lps().map_or(x, |m| self.apply_with(&m, x))
    }

    /// (D · diag(spacing))⁻¹, which maps a point's offset from the grid's origin to grid units; `None` when the
    /// grid's axes are degenerate. Found once for [`Self::apply_with`], which maps many points.
    #[must_use]
    pub fn index_from_lps(&self) -> Option<Matrix3<f64>> {
        Matrix3::from_fn(|r, c| self.grid_direction[r][c] * self.grid_spacing_mm[c]).try_inverse()
    }

    /// [`Self::apply`] with the grid's `index_from_lps` ([`Self::index_from_lps`]) given.
    #[must_use]
    pub fn apply_with(&self, index_from_lps: &Matrix3<f64>, x: [f64; 3]) -> [f64; 3] {
        let c = self.continuous_index(index_from_lps, x);
        let inside = (0..3).all(|a| c[a] >= 1.0 && c[a] < self.grid_size[a] as f64 - 2.0);
        if !inside {
            return x;
        }
        let floor = c.map(f64::floor);
        let start = floor.map(|f| f as usize - 1);
        let w: [[f64; 4]; 3] = std::array::from_fn(|a| cubic_basis(c[a] - floor[a]));
        let [nx, ny, _] = self.grid_size;
        let mut d = [0.0; 3];
        for (k, wz) in w[2].iter().enumerate() {
            for (j, wy) in w[1].iter().enumerate() {
                let row = ((start[2] + k) * ny + start[1] + j) * nx + start[0];
                for (i, wx) in w[0].iter().enumerate() {
                    let weight = wz * wy * wx;
                    let phi = self.coefficients_mm[row + i];
                    for r in 0..3 {
                        d[r] += weight * phi[r];
                    }
                }
            }
        }
        [x[0] + d[0], x[1] + d[1], x[2] + d[2]]
    }

    /// c = (D · diag(spacing))⁻¹ (x − origin), as ITK's `TransformPhysicalPointToContinuousIndex`, with
    /// `index_from_lps` = (D · diag(spacing))⁻¹. A coordinate within [`SNAP_GRID_UNITS`] of a whole number is that number: the
    /// transform jumps to the identity at the edge of its region, so a point on the edge (a voxel centre placed
    /// there, as a grid one spacing before an image's first voxel does) must not land on either side by rounding.
    /// Exact arithmetic puts it inside, and so does elastix's transformix on such grids.
    fn continuous_index(&self, index_from_lps: &Matrix3<f64>, x: [f64; 3]) -> [f64; 3] {
        let v = Vector3::from(x) - Vector3::from(self.grid_origin_lps);
        let c: [f64; 3] = (index_from_lps * v).into();
        c.map(|c| if (c - c.round()).abs() <= SNAP_GRID_UNITS { c.round() } else { c })
    }

    pub(crate) fn check(&self, name: &Path) -> Result<()> {
        if self.grid_size.iter().any(|&n| n < 4) {
            return Err(Error::invalid(
                name,
                format!("grid size {:?}: a cubic B-spline needs at least 4 control points per axis", self.grid_size),
            ));
        }
        let points = self.grid_size.iter().try_fold(1usize, |acc, &n| acc.checked_mul(n));
        if points.is_none_or(|p| p > MAX_BSPLINE_CONTROL_POINTS) {
            return Err(Error::invalid(
                name,
                format!("grid size {:?} exceeds {MAX_BSPLINE_CONTROL_POINTS} control points", self.grid_size),
            ));
        }
        if points != Some(self.coefficients_mm.len()) {
            return Err(Error::invalid(
                name,
                format!(
                    "{} coefficients for a grid of {:?} control points",
                    self.coefficients_mm.len(),
                    self.grid_size
                ),
            ));
        }
        if !self.grid_spacing_mm.iter().all(|s| s.is_finite() && *s > 0.0) {
            return Err(Error::invalid(name, format!("grid spacing {:?} mm is not positive", self.grid_spacing_mm)));
        }
        let geometry = self.grid_origin_lps.iter().chain(self.grid_direction.iter().flatten());
        if !geometry.chain(self.coefficients_mm.iter().flatten()).all(|v| v.is_finite()) {
            return Err(Error::invalid(name, "the B-spline's grid or coefficients are not finite"));
        }
        if self.index_from_lps().is_none() {
            return Err(Error::invalid(name, format!("grid direction {:?} is singular", self.grid_direction)));
        }
        Ok(())
    }
}

/// How close to a whole number, in grid units, a B-spline's continuous index is taken as that number
/// ([`ItkBSpline::apply`]): rounding in (D · diag(spacing))⁻¹ (x − origin) is about 1e-15 of the grid's extent.
const SNAP_GRID_UNITS: f64 = 1e-9;

/// The uniform cubic B-spline basis B₀..B₃ at t ∈ [0, 1) (ITK's `BSplineKernelFunction<3>` at t + 1, t, 1 − t, 2 − t).
fn cubic_basis(t: f64) -> [f64; 4] {
    let u = 1.0 - t;
    let (t2, t3) = (t * t, t * t * t);
    [u * u * u / 6.0, (3.0 * t3 - 6.0 * t2 + 4.0) / 6.0, (-3.0 * t3 + 3.0 * t2 + 3.0 * t + 1.0) / 6.0, t3 / 6.0]
}

/// Parses the bytes of an ANTs / ITK affine `.mat` (module docs, "The ANTs / ITK `.mat`"); `name` is used in errors.
pub fn parse_mat(name: &Path, bytes: &[u8]) -> Result<ItkAffine> {
    let MatAffine { parameters: p, center } = parse_mat_numbers(name, bytes)?;
    Ok(ItkAffine { matrix: Matrix3::from_row_slice(&p[..9]), translation: [p[9], p[10], p[11]], center })
}

/// The bytes of `affine` as an ANTs / ITK `.mat`, what SimpleITK writes for it (module docs).
#[must_use]
pub fn to_mat_bytes(affine: &ItkAffine) -> Vec<u8> {
    let m = &affine.matrix;
    let mut parameters = [0.0; 12];
    for (i, v) in (0..3).flat_map(|r| (0..3).map(move |c| m[(r, c)])).chain(affine.translation).enumerate() {
        parameters[i] = v;
    }
    mat_bytes(&MatAffine { parameters, center: affine.center })
}

/// Writes `transform` as an ITK transform file, atomically: a `.tfm` (any name but `.mat`), or for a name ending in
/// `.mat` the MATLAB v4 file of ANTs and ITK (an affine only). A transform ITK cannot take (non-finite numbers,
/// mismatched landmark counts, a grid too small for a cubic B-spline) or a `.mat` cannot hold is an error and nothing
/// is written.
pub fn write(path: &Path, transform: &ItkTransform) -> Result<()> {
    transform.check(path)?;
    if is_hdf5_name(path) {
        return Err(Error::unsupported(path, HDF5_NAME_FOR_TEXT));
    }
    if is_mat_name(path) {
        let ItkTransform::Affine(affine) = transform else {
            return Err(Error::unsupported(
                path,
                format!(
                    "a .mat (ANTs, ITK's MatlabTransformIO) holds an affine transform only; write the {} as a .tfm",
                    transform.type_name()
                ),
            ));
        };
        let bytes = to_mat_bytes(affine);
        return crate::write_atomic(path, |w| w.write_all(&bytes));
    }
    crate::write_atomic(path, |w| {
        let mut w = std::io::BufWriter::new(w);
        transform.write_text(&mut w)?;
        w.flush()
    })
}

/// Writes `affine` as an ITK transform file (`.tfm`, or `.mat` for a name ending so), atomically. A non-finite
/// parameter is an error.
pub fn write_affine(path: &Path, affine: &ItkAffine) -> Result<()> {
    write(path, &ItkTransform::Affine(*affine))
}

/// Reads a transform file holding one transform of a class in the module docs: a `.tfm`, or an affine `.mat`. Only a
/// regular file is read (a named pipe would block, a device never end).
pub fn read(path: &Path) -> Result<ItkTransform> {
    match read_file(path)? {
        Contents::Mat(bytes) => parse_mat(path, &bytes).map(ItkTransform::Affine),
        Contents::Text(text) => parse(path, &text),
    }
}

/// Reads a transform file (`.tfm` or `.mat`) holding one affine transform.
pub fn read_affine(path: &Path) -> Result<ItkAffine> {
    match read_file(path)? {
        Contents::Mat(bytes) => parse_mat(path, &bytes),
        Contents::Text(text) => parse_affine(path, &text),
    }
}

/// Why [`write()`] refuses an output named `.h5`: ITK would read a text transform file of that name as HDF5.
const HDF5_NAME_FOR_TEXT: &str = "ITK reads a file named .h5 as HDF5, and a text transform file is not one: write \
                                  ITK's HDF5 transform file with warpbench_io::transform_file::write, or name this \
                                  one .tfm";

/// Whether `head`, a file's first bytes, opens an ITK text transform file (`#Insight Transform File`).
#[must_use]
pub fn looks_like_text(head: &[u8]) -> bool {
    head.starts_with(b"#Insight Transform File")
}

/// Whether `path` is named as an HDF5 file (`.h5`, `.hdf5`, `.hdf`, any case).
#[must_use]
pub fn is_hdf5_name(path: &Path) -> bool {
    path.extension().is_some_and(|e| ["h5", "hdf5", "hdf"].iter().any(|x| e.eq_ignore_ascii_case(x)))
}

/// Whether `path` is named as a MATLAB `.mat` (any case).
fn is_mat_name(path: &Path) -> bool {
    path.extension().is_some_and(|e| e.eq_ignore_ascii_case("mat"))
}

/// A transform file's contents: the text of a `.tfm`, or the bytes of a `.mat`.
pub(crate) enum Contents {
    Text(String),
    Mat(Vec<u8>),
}

/// The contents of the transform file at `path`, a regular file of at most [`MAX_FILE_BYTES`]: a `.mat` by its name
/// or its first bytes, else UTF-8 text.
pub(crate) fn read_file(path: &Path) -> Result<Contents> {
    let len = crate::files::check_regular_file(path)?.len();
    // The largest file we read is a B-spline of MAX_BSPLINE_CONTROL_POINTS; a longer one is not read into memory.
    if len > MAX_FILE_BYTES {
        return Err(Error::invalid(path, format!("{len} bytes is too long for a transform file")));
    }
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    if is_mat_name(path) || ants_mat::looks_like_mat(&bytes) {
        return Ok(Contents::Mat(bytes));
    }
    String::from_utf8(bytes)
        .map(Contents::Text)
        .map_err(|_| Error::invalid(path, "the transform file is not UTF-8 text"))
}

/// The three lines of a one-transform file, numbers parsed but not yet counted.
pub(crate) struct Lines<'a> {
    /// The `Transform:` line's class.
    pub kind: &'a str,
    /// The `Parameters:` line.
    pub params: Vec<f64>,
    /// The `FixedParameters:` line.
    pub fixed: Vec<f64>,
}

/// Parses the text of a `.tfm` holding one transform; `name` is used in errors.
pub fn parse(name: &Path, text: &str) -> Result<ItkTransform> {
    let lines = parse_lines(name, text)?;
    transform_of(name, lines.kind, &lines.params, &lines.fixed)
}

/// The transform of ITK class `kind` with `params` (`Parameters`) and `fixed` (`FixedParameters`), checked as
/// ITK needs it: what a `.tfm`'s three lines and an `.h5` group's three datasets ([`crate::itk_h5`]) hold alike.
/// `name` is used in errors.
pub(crate) fn transform_of(name: &Path, kind: &str, params: &[f64], fixed: &[f64]) -> Result<ItkTransform> {
    let transform = if AFFINE_TYPES.contains(&kind) {
        ItkTransform::Affine(affine_of(name, params, fixed)?)
    } else if TPS_TYPES.contains(&kind) {
        if !params.len().is_multiple_of(3) {
            return Err(Error::invalid(
                name,
                format!("Parameters: {} numbers is not a list of 3-D source landmarks", params.len()),
            ));
        }
        let points = |v: &[f64]| v.chunks_exact(3).map(|p| [p[0], p[1], p[2]]).collect::<Vec<_>>();
        if fixed.len() != params.len() {
            return Err(Error::invalid(
                name,
                format!(
                    "FixedParameters: {} numbers, expected {} (a target landmark per source landmark)",
                    fixed.len(),
                    params.len()
                ),
            ));
        }
        ItkTransform::ThinPlateSpline(ItkThinPlateSpline { source_lps: points(params), target_lps: points(fixed) })
    } else if BSPLINE_TYPES.contains(&kind) {
        ItkTransform::BSpline(bspline_of(name, params, fixed)?)
    } else if let Some(affine) = linear_of(name, kind, params, fixed)? {
        ItkTransform::Affine(affine)
    } else if let Some(plain) = kind.strip_prefix("Inverse") {
        return Err(Error::unsupported(
            name,
            format!(
                "transform type {kind:?}, 3D Slicer's {plain} saved in its modeling direction, which warpbench does \
                 not read as a transform; a thin-plate spline's landmarks are read as pairs (--landmarks), and \
                 otherwise, in Slicer, invert the transform (or harden it) before saving"
            ),
        ));
    } else {
        return Err(Error::unsupported(
            name,
            format!("transform type {kind:?}; only these are read: {}", known_types().join(", ")),
        ));
    };
    transform.check(name)?;
    Ok(transform)
}

/// The classes [`transform_of`] reads (the double ones; each also as `_float_3_3`).
pub(crate) fn known_types() -> Vec<&'static str> {
    AFFINE_TYPES.iter().chain(&LINEAR_TYPES).chain(&TPS_TYPES).chain(&BSPLINE_TYPES).copied().collect()
}

/// Parses the text of a `.tfm` holding one affine transform; `name` is used in errors.
pub fn parse_affine(name: &Path, text: &str) -> Result<ItkAffine> {
    let lines = parse_lines(name, text)?;
    let linear = || AFFINE_TYPES.iter().chain(&LINEAR_TYPES).copied().collect::<Vec<_>>().join(", ");
    if TPS_TYPES.contains(&lines.kind) || BSPLINE_TYPES.contains(&lines.kind) {
        return Err(Error::unsupported(
            name,
            format!("transform type {:?}; only an affine or another linear class ({}) is read", lines.kind, linear()),
        ));
    }
    match transform_of(name, lines.kind, &lines.params, &lines.fixed)? {
        ItkTransform::Affine(a) => Ok(a),
        other => Err(Error::unsupported(name, format!("transform type {:?} is not linear", other.type_name()))),
    }
}

/// ITK's `Euler3DTransform` matrix: Rz Rx Ry, or Rz Ry Rx when `zyx`.
pub(crate) fn euler_matrix(angles: [f64; 3], zyx: bool) -> Matrix3<f64> {
    let [(sx, cx), (sy, cy), (sz, cz)] = angles.map(f64::sin_cos);
    let rx = Matrix3::new(1.0, 0.0, 0.0, 0.0, cx, -sx, 0.0, sx, cx);
    let ry = Matrix3::new(cy, 0.0, sy, 0.0, 1.0, 0.0, -sy, 0.0, cy);
    let rz = Matrix3::new(cz, -sz, 0.0, sz, cz, 0.0, 0.0, 0.0, 1.0);
    if zyx { rz * ry * rx } else { rz * rx * ry }
}

/// The rotation of the unit quaternion (w, x, y, z), w = √(1 − x² − y² − z²): ITK's `Versor::GetMatrix`.
pub(crate) fn versor_matrix([x, y, z]: [f64; 3]) -> Matrix3<f64> {
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

/// ITK's other linear classes, each read as the [`ItkAffine`] it is (module docs); `None` for a class that is not one.
fn linear_of(name: &Path, kind: &str, p: &[f64], f: &[f64]) -> Result<Option<ItkAffine>> {
    let Some(class) = kind.strip_suffix("_double_3_3").or_else(|| kind.strip_suffix("_float_3_3")) else {
        return Ok(None);
    };
    let centre = |f: &[f64]| -> Result<[f64; 3]> {
        count(name, "FixedParameters", f, 3)?;
        Ok([f[0], f[1], f[2]])
    };
    let versor = |v: &[f64]| -> Result<Matrix3<f64>> {
        let versor = [v[0], v[1], v[2]];
        if versor.iter().map(|x| x * x).sum::<f64>() > 1.0 {
            return Err(Error::invalid(name, format!("Parameters: the versor {versor:?} is longer than 1")));
        }
        Ok(versor_matrix(versor))
    };
    let affine = match class {
        "TranslationTransform" => {
            count(name, "Parameters", p, 3)?;
            count(name, "FixedParameters", f, 0)?;
            ItkAffine::from_offset(Matrix3::identity(), [p[0], p[1], p[2]])
        }
        "ScaleTransform" => {
            count(name, "Parameters", p, 3)?;
            let center = centre(f)?;
            ItkAffine { matrix: Matrix3::from_diagonal(&Vector3::new(p[0], p[1], p[2])), translation: [0.0; 3], center }
        }
        "Euler3DTransform" => {
            count(name, "Parameters", p, 6)?;
            // ITK 5 writes the centre and ComputeZYX (0 or 1); older files the centre alone.
            let zyx = match f {
                [_, _, _] => false,
                [_, _, _, flag] if *flag == 0.0 => false,
                [_, _, _, flag] if flag.to_bits() == 1f64.to_bits() => true,
                _ => {
                    return Err(Error::invalid(
                        name,
                        format!("FixedParameters: {f:?} is not a centre and a ComputeZYX flag (0 or 1)"),
                    ));
                }
            };
            let matrix = euler_matrix([p[0], p[1], p[2]], zyx);
            ItkAffine { matrix, translation: [p[3], p[4], p[5]], center: centre(&f[..3])? }
        }
        "VersorTransform" => {
            count(name, "Parameters", p, 3)?;
            ItkAffine { matrix: versor(p)?, translation: [0.0; 3], center: centre(f)? }
        }
        "VersorRigid3DTransform" => {
            count(name, "Parameters", p, 6)?;
            ItkAffine { matrix: versor(p)?, translation: [p[3], p[4], p[5]], center: centre(f)? }
        }
        "Similarity3DTransform" => {
            count(name, "Parameters", p, 7)?;
            ItkAffine { matrix: versor(p)? * p[6], translation: [p[3], p[4], p[5]], center: centre(f)? }
        }
        "ScaleVersor3DTransform" => {
            // ITK adds the scale to the rotation's diagonal: M = R + diag(s) − I (not R · diag(s)).
            count(name, "Parameters", p, 9)?;
            let matrix = versor(p)? + Matrix3::from_diagonal(&Vector3::new(p[6] - 1.0, p[7] - 1.0, p[8] - 1.0));
            ItkAffine { matrix, translation: [p[3], p[4], p[5]], center: centre(f)? }
        }
        "ScaleSkewVersor3DTransform" => {
            // ITK 5's 15 parameters: versor, translation, scale and six skews, added to the rotation like the
            // scale: M = R + diag(s) − I + K, K's off-diagonal entries (0,1), (0,2), (1,0), (1,2), (2,0), (2,1).
            // ITK 6 has 12 (three skews, M = R · diag(s) · K), which SimpleITK 2.5 does not write to check against.
            if p.len() == 12 {
                return Err(Error::unsupported(
                    name,
                    "Parameters: 12 numbers, ITK 6's ScaleSkewVersor3DTransform, which warpbench does not read; \
                     write the transform as an AffineTransform",
                ));
            }
            count(name, "Parameters", p, 15)?;
            let k = &p[9..15];
            let skew = Matrix3::new(0.0, k[0], k[1], k[2], 0.0, k[3], k[4], k[5], 0.0);
            let scale = Matrix3::from_diagonal(&Vector3::new(p[6] - 1.0, p[7] - 1.0, p[8] - 1.0));
            ItkAffine { matrix: versor(p)? + scale + skew, translation: [p[3], p[4], p[5]], center: centre(f)? }
        }
        _ => return Ok(None),
    };
    Ok(Some(affine))
}

fn affine_of(name: &Path, p: &[f64], c: &[f64]) -> Result<ItkAffine> {
    count(name, "Parameters", p, 12)?;
    count(name, "FixedParameters", c, 3)?;
    Ok(ItkAffine {
        matrix: Matrix3::from_row_slice(&p[..9]),
        translation: [p[9], p[10], p[11]],
        center: [c[0], c[1], c[2]],
    })
}

fn bspline_of(name: &Path, p: &[f64], f: &[f64]) -> Result<ItkBSpline> {
    count(name, "FixedParameters", f, 18)?;
    let mut grid_size = [0usize; 3];
    for (n, &v) in grid_size.iter_mut().zip(&f[..3]) {
        if v.fract() != 0.0 || !(4.0..=MAX_BSPLINE_CONTROL_POINTS as f64).contains(&v) {
            return Err(Error::invalid(
                name,
                format!("FixedParameters: grid size {:?} is not 3 whole numbers of at least 4", &f[..3]),
            ));
        }
        *n = v as usize;
    }
    let points = grid_size.iter().try_fold(1usize, |acc, &n| acc.checked_mul(n)).unwrap_or(usize::MAX);
    if points > MAX_BSPLINE_CONTROL_POINTS {
        return Err(Error::invalid(
            name,
            format!("grid size {grid_size:?} exceeds {MAX_BSPLINE_CONTROL_POINTS} control points"),
        ));
    }
    count(name, "Parameters", p, 3 * points)?;
    Ok(ItkBSpline {
        grid_size,
        grid_origin_lps: [f[3], f[4], f[5]],
        grid_spacing_mm: [f[6], f[7], f[8]],
        grid_direction: [[f[9], f[10], f[11]], [f[12], f[13], f[14]], [f[15], f[16], f[17]]],
        coefficients_mm: (0..points).map(|i| [p[i], p[points + i], p[2 * points + i]]).collect(),
    })
}

/// The lines of a `.tfm` holding one transform of any class; `name` is used in errors (a file of several
/// transforms, or a composite, is refused here: [`crate::itk_chain::parse_text`] reads those).
pub(crate) fn parse_lines<'a>(name: &Path, text: &'a str) -> Result<Lines<'a>> {
    let mut blocks = parse_blocks(name, text)?;
    if blocks.len() > 1 {
        let kinds: Vec<&str> = blocks.iter().map(|b| b.kind).collect();
        return Err(Error::unsupported(
            name,
            format!("{} transforms ({}); a single transform was expected here", blocks.len(), kinds.join(", ")),
        ));
    }
    let lines = blocks.remove(0);
    if lines.kind.contains("CompositeTransform") {
        return Err(Error::unsupported(name, format!("{:?}: a composite transform holding nothing", lines.kind)));
    }
    Ok(lines)
}

/// The most transforms a text file may hold (a composite's members).
const MAX_TRANSFORMS: usize = 64;

/// A `#Transform N` block while it is read: its class, parameters and fixed parameters, each once seen.
type PartialLines<'a> = (Option<&'a str>, Option<Vec<f64>>, Option<Vec<f64>>);

/// The transforms of a `.tfm`, each `#Transform N` block's lines in the file's order, numbered 0, 1, …; `name` is
/// used in errors. A composite's block has no numbers (ITK writes none for it).
pub(crate) fn parse_blocks<'a>(name: &Path, text: &'a str) -> Result<Vec<Lines<'a>>> {
    let mut lines = text.lines().map(str::trim).filter(|l| !l.is_empty());
    if lines.next() != Some(MAGIC) {
        return Err(Error::new(
            name,
            ErrorKind::BadMagic { format: "transform (.tfm)", detail: format!("the first line is not {MAGIC:?}") },
        ));
    }
    // Each block's lines so far.
    let mut blocks: Vec<PartialLines<'a>> = Vec::new();
    for line in lines {
        if let Some(n) = line.strip_prefix("#Transform") {
            if n.trim() != blocks.len().to_string() {
                return Err(Error::invalid(
                    name,
                    format!(
                        "{line:?}: the transforms are numbered 0, 1, … in order, and this is not #Transform {}",
                        blocks.len()
                    ),
                ));
            }
            if blocks.len() == MAX_TRANSFORMS {
                return Err(Error::invalid(name, format!("more than {MAX_TRANSFORMS} transforms")));
            }
            blocks.push((None, None, None));
            continue;
        }
        if line.starts_with('#') {
            continue;
        }
        // A file of one transform may leave out "#Transform 0".
        if blocks.is_empty() {
            blocks.push((None, None, None));
        }
        let index = blocks.len() - 1;
        let Some(block) = blocks.last_mut() else { continue };
        if let Some(k) = line.strip_prefix("Transform:") {
            if block.0.is_some() {
                return Err(Error::invalid(name, format!("two \"Transform:\" lines in #Transform {index}")));
            }
            block.0 = Some(k.trim());
        } else if let Some(p) = line.strip_prefix("Parameters:") {
            block.1 = Some(numbers(name, "Parameters", p)?);
        } else if let Some(p) = line.strip_prefix("FixedParameters:") {
            block.2 = Some(numbers(name, "FixedParameters", p)?);
        } else {
            let shown: String = line.chars().take(80).collect();
            return Err(Error::invalid(name, format!("unexpected line {shown:?}")));
        }
    }
    if blocks.is_empty() {
        return Err(Error::invalid(name, "no \"Transform:\" line"));
    }
    blocks
        .into_iter()
        .enumerate()
        .map(|(n, (kind, params, fixed))| {
            let at = if n == 0 { String::new() } else { format!(" in #Transform {n}") };
            let kind = kind.ok_or_else(|| Error::invalid(name, format!("no \"Transform:\" line{at}")))?;
            if kind.contains("CompositeTransform") {
                return Ok(Lines { kind, params: params.unwrap_or_default(), fixed: fixed.unwrap_or_default() });
            }
            let params = params.ok_or_else(|| Error::invalid(name, format!("no \"Parameters:\" line{at}")))?;
            let fixed = fixed.ok_or_else(|| Error::invalid(name, format!("no \"FixedParameters:\" line{at}")))?;
            Ok(Lines { kind, params, fixed })
        })
        .collect()
}

/// Finite numbers separated by white space.
fn numbers(name: &Path, field: &str, text: &str) -> Result<Vec<f64>> {
    text.split_whitespace().map(|v| v.parse::<f64>().ok().filter(|x| x.is_finite())).collect::<Option<_>>().ok_or_else(
        || {
            let shown: String = text.trim().chars().take(80).collect();
            Error::invalid(name, format!("{field}: {shown:?} is not a list of finite numbers"))
        },
    )
}

/// Exactly `expected` numbers.
fn count(name: &Path, field: &str, values: &[f64], expected: usize) -> Result<()> {
    if values.len() == expected {
        Ok(())
    } else {
        Err(Error::invalid(name, format!("{field}: {} numbers, expected {expected}", values.len())))
    }
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
            (&good.replace("#Transform 0", "#Transform 1"), "numbered 0, 1, … in order"),
            (
                &format!(
                    "{good}{}",
                    good.replace("#Insight Transform File V1.0\n", "").replace("#Transform 0", "#Transform 1")
                ),
                "2 transforms (AffineTransform_double_3_3, AffineTransform_double_3_3); a single",
            ),
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

    fn sample_tps() -> ItkThinPlateSpline {
        ItkThinPlateSpline {
            source_lps: vec![[1.5, -2.0, 3.0], [10.0, 0.1, -7.25], [0.0, 0.0, 1e-9], [-4.0, 5.0, 6.0]],
            target_lps: vec![[1.0, -2.5, 3.5], [11.0, 0.0, -7.0], [0.5, 0.25, 0.0], [-4.5, 5.5, 6.125]],
        }
    }

    /// A 4×5×6 grid whose coefficients are a linear function of the control point's position, φ = M p + b: cubic
    /// B-splines reproduce linear functions, so inside the transform domain D(x) = M x + b exactly, which a wrong
    /// index offset or layout would break.
    fn linear_bspline() -> (ItkBSpline, Matrix3<f64>, Vector3<f64>) {
        let m = Matrix3::new(0.01, -0.02, 0.003, 0.02, 0.015, -0.01, -0.005, 0.01, 0.02);
        let b = Vector3::new(1.5, -0.5, 2.0);
        let (size, origin, spacing) = ([4usize, 5, 6], [-30.0, -20.0, 10.0], [20.0, 12.5, 8.0]);
        let mut coefficients = Vec::new();
        for k in 0..size[2] {
            for j in 0..size[1] {
                for i in 0..size[0] {
                    let p = Vector3::new(
                        origin[0] + i as f64 * spacing[0],
                        origin[1] + j as f64 * spacing[1],
                        origin[2] + k as f64 * spacing[2],
                    );
                    coefficients.push((m * p + b).into());
                }
            }
        }
        let grid = ItkBSpline {
            grid_size: size,
            grid_origin_lps: origin,
            grid_spacing_mm: spacing,
            grid_direction: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            coefficients_mm: coefficients,
        };
        (grid, m, b)
    }

    #[test]
    fn every_kind_reads_back_bit_for_bit() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("t.tfm");
        let kinds = [
            ItkTransform::Affine(sample()),
            ItkTransform::ThinPlateSpline(sample_tps()),
            ItkTransform::BSpline(linear_bspline().0),
        ];
        for t in kinds {
            write(&path, &t).expect("write");
            let back = read(&path).expect("read");
            assert_eq!(back, t, "{}", t.type_name());
            let text = std::fs::read_to_string(&path).expect("text");
            assert!(text.starts_with(&format!("{MAGIC}\n#Transform 0\nTransform: {}\n", t.type_name())), "{text}");
        }
    }

    #[test]
    fn tps_landmarks_go_source_to_parameters_and_target_to_fixed_parameters() {
        // ITK's KernelTransform::SetParameters sets the source landmarks, SetFixedParameters the target ones.
        let text = ItkTransform::ThinPlateSpline(sample_tps()).to_text();
        assert!(text.contains("\nParameters: 1.5 -2 3 10 0.1 -7.25 0 0 0.000000001 -4 5 6\n"), "{text}");
        assert!(text.contains("\nFixedParameters: 1 -2.5 3.5 11 0 -7 0.5 0.25 0 -4.5 5.5 6.125\n"), "{text}");
    }

    #[test]
    fn bspline_layout_is_itks() {
        // Fixed parameters: size, origin, spacing, direction; parameters: every x, then every y, then every z.
        let mut grid = linear_bspline().0;
        grid.grid_size = [4, 4, 4];
        grid.coefficients_mm = (0..64).map(|i| [f64::from(i), 100.0 + f64::from(i), 200.0 + f64::from(i)]).collect();
        let text = ItkTransform::BSpline(grid).to_text();
        let line = |key: &str| {
            let l = text.lines().find(|l| l.starts_with(key)).expect("line");
            l[key.len()..].split_whitespace().map(|v| v.parse::<f64>().expect("number")).collect::<Vec<_>>()
        };
        let fixed = line("FixedParameters:");
        assert_eq!(
            fixed,
            [4.0, 4.0, 4.0, -30.0, -20.0, 10.0, 20.0, 12.5, 8.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
        );
        let params = line("Parameters:");
        let want: Vec<f64> = (0..3).flat_map(|c| (0..64).map(move |i| f64::from(100 * c + i))).collect();
        assert_eq!(params, want);
    }

    #[test]
    fn bspline_reproduces_a_linear_displacement_inside_its_domain_and_is_the_identity_outside() {
        let (grid, m, b) = linear_bspline();
        // The transform domain: one spacing in from the grid's first control point, (size − 3) spacings long.
        let lo = [-10.0, -7.5, 18.0];
        let hi = [10.0, 17.5, 42.0];
        let mut worst = 0.0f64;
        for n in 0..500 {
            let t = [f64::from(n) * 0.618_034 % 1.0, f64::from(n) * 0.414_214 % 1.0, f64::from(n) * 0.732_051 % 1.0];
            let x: [f64; 3] = std::array::from_fn(|a| lo[a] + t[a] * (hi[a] - lo[a]));
            let want = Vector3::from(x) + m * Vector3::from(x) + b;
            worst = worst.max((Vector3::from(grid.apply(x)) - want).norm());
        }
        assert!(worst < 1e-12, "{worst}");
        for outside in [[-10.5, 0.0, 30.0], [0.0, 17.6, 30.0], [0.0, 0.0, 42.0], [0.0, 0.0, 100.0]] {
            // Exact on purpose: outside the domain ITK returns the point itself, bit for bit.
            assert!(grid.apply(outside).iter().zip(outside).all(|(p, q)| p.to_bits() == q.to_bits()), "{outside:?}");
        }
        // An oblique grid: the same coefficients on axes rotated 90° about z map the rotated points the same way.
        let mut turned = grid.clone();
        turned.grid_direction = [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]];
        turned.grid_origin_lps = [20.0, -30.0, 10.0];
        let x = [3.0, 4.0, 30.0];
        let x_turned = [20.0 - (x[1] + 20.0), -30.0 + (x[0] + 30.0), x[2]];
        let d = Vector3::from(grid.apply(x)) - Vector3::from(x);
        let d_turned = Vector3::from(turned.apply(x_turned)) - Vector3::from(x_turned);
        assert!((d - d_turned).norm() < 1e-12, "{d:?} vs {d_turned:?}");
    }

    #[test]
    fn refuses_what_itk_cannot_take() {
        let name = Path::new("k.tfm");
        let tps = ItkTransform::ThinPlateSpline(sample_tps()).to_text();
        let bspline = ItkTransform::BSpline(linear_bspline().0).to_text();
        let cases = [
            (tps.replace("Parameters: 1.5 -2 3 ", "Parameters: 1.5 -2 "), "not a list of 3-D source landmarks"),
            (tps.replace("FixedParameters: 1 -2.5 3.5 ", "FixedParameters: "), "expected 12 (a target landmark"),
            (bspline.replace("FixedParameters: 4 5 6", "FixedParameters: 4 5.5 6"), "not 3 whole numbers"),
            (bspline.replace("FixedParameters: 4 5 6", "FixedParameters: 4 3 6"), "not 3 whole numbers"),
            (bspline.replace("FixedParameters: 4 5 6", "FixedParameters: 4 5 7"), "expected 420"),
            (bspline.replace(" 20 12.5 8 ", " 20 0 8 "), "is not positive"),
            (bspline.replace(" 20 12.5 8 1 0 0 0 1 0", " 20 12.5 8 1 0 0 1 0 0"), "is singular"),
            (tps.replace("ThinPlateSplineKernelTransform_double_3_3", "CompositeTransform_double_3_3"), "composite"),
            (
                tps.replace("ThinPlateSplineKernelTransform_double_3_3", "QuaternionRigidTransform_double_3_3"),
                "only these",
            ),
            (tps.replace("ThinPlateSplineKernelTransform_double_3_3", "Euler3DTransform_double_3_3"), "expected 6"),
        ];
        for (text, want) in &cases {
            let e = parse(name, text).expect_err(want);
            assert!(e.to_string().contains(want), "{e} does not say {want:?}");
            assert!(e.to_string().starts_with("k.tfm: "), "{e}");
        }
        let dir = tempfile::tempdir().expect("tempdir");
        let out = dir.path().join("bad.tfm");
        let mut uneven = sample_tps();
        uneven.target_lps.pop();
        assert!(write(&out, &ItkTransform::ThinPlateSpline(uneven)).is_err());
        let mut small = linear_bspline().0;
        small.grid_size = [3, 5, 6];
        assert!(write(&out, &ItkTransform::BSpline(small)).is_err());
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
