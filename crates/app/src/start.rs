//! The starting transform of a registration (issue 18, item 1): an affine pull-back T₀ = `moving_from_fixed`, found
//! by `warpbench align` or the window's Auto-align (or any ITK affine `.tfm`, ANTs' `.mat` of one, or FSL's, AFNI's and
//! FreeSurfer's files, read against the two volumes: [`StartFile`]), that the landmark warp refines.
//!
//! With pairs (pᵢ moving, qᵢ fixed) the landmark warp is fitted on top of T₀ in each direction, in the frame where
//! T₀ has already acted, and put after it:
//!
//! - pull-back: u = T₀ ∘ r, r fitted on qᵢ → T₀⁻¹(pᵢ) over the fixed box (so u(qᵢ) ≈ pᵢ);
//! - forward: d = T₀⁻¹ ∘ s, s fitted on pᵢ → T₀(qᵢ) over the moving box (so d(pᵢ) ≈ qᵢ).
//!
//! Each is the fitted warp followed by an affine map, which stays in the method's family
//! ([`FittedWarp::followed_by`]): the GPU, the exporters and the ITK transform file take it as any fit. A TPS
//! (interpolating or smoothing) and an affine fit are linear in their data and fit affine data exactly, so on any T₀
//! they are the same warps as without it ([`tps_ignores`]); the rigid and similarity fits are for a rigid T₀. What T₀
//! changes is everything else: with fewer pairs than the method needs, T₀ alone is the warp (u = T₀, d = T₀⁻¹), and
//! the hierarchical B-spline refines the aligned volumes instead of undoing the whole offset.

use std::path::Path;

use anyhow::{Context, anyhow};
use nalgebra::Matrix4;
use warpbench_io::geometry::Point3;
use warpbench_io::{Volume, afni, dicom_reg, elastix, fsl, itk_h5, lta, mni_xfm};
use warpbench_solver::linear::AffineWarp;
use warpbench_solver::method::{FittedWarp, Method};
use warpbench_solver::spaces::{Aabb, Fixed, Moving};
use warpbench_solver::warp::Warp;

/// A starting transform and where it came from.
#[derive(Clone, Debug, PartialEq)]
pub struct Start {
    moving_from_fixed: AffineWarp<Moving, Fixed>,
    fixed_from_moving: AffineWarp<Fixed, Moving>,
    /// How messages and reports name it: the file's path, or the window's "Auto-align (rigid)".
    pub origin: String,
}

impl Start {
    /// T₀ = `moving_from_fixed`, named `origin`.
    ///
    /// # Errors
    /// When T₀ is not finite or not invertible.
    pub fn new(moving_from_fixed: AffineWarp<Moving, Fixed>, origin: &str) -> anyhow::Result<Self> {
        let finite =
            moving_from_fixed.linear().iter().chain(moving_from_fixed.translation().iter()).all(|v| v.is_finite());
        let fixed_from_moving = moving_from_fixed
            .inverse()
            .ok()
            .filter(|_| finite)
            .ok_or_else(|| anyhow!("{origin}: the starting transform is not invertible"))?;
        Ok(Self { moving_from_fixed, fixed_from_moving, origin: origin.to_owned() })
    }

    /// Reads an ITK affine transform file (`AffineTransform_double_3_3`, as `warpbench align` and `transform` write
    /// it; a `.tfm`, or ANTs' MATLAB `.mat`), ITK's HDF5 transform file of one or more affines (`.h5`,
    /// [`warpbench_io::itk_h5::read_affine`]), a DICOM Spatial Registration ([`warpbench_io::dicom_reg::read_affine`]),
    /// or an elastix transform parameter file holding a linear transform (and
    /// its chain of initial transforms, [`warpbench_io::elastix::read_affine`]): fixed points to moving points, LPS mm.
    /// A FLIRT or AFNI matrix, which needs the two volumes, is refused here ([`Self::read_on`] takes it). An MNI
    /// transform file (`.xfm`, [`warpbench_io::mni_xfm`]) maps the moving volume's world to the fixed one's, and is
    /// read as its inverse.
    ///
    /// # Errors
    /// When the file cannot be read, holds another kind of transform, or is not invertible; the message names it.
    pub fn read(path: &Path) -> anyhow::Result<Self> {
        match StartFile::read(path)? {
            StartFile::Lps(start) => Ok(start),
            StartFile::Flirt { origin, .. } => Err(anyhow!(
                "{origin}: an FSL FLIRT matrix is in the voxel coordinates of the two images it was made with: it \
                 needs the fixed volume (FLIRT's -ref) and the moving one (its -in)"
            )),
            StartFile::Afni { origin, .. } => Err(anyhow!(
                "{origin}: an AFNI matrix is read with the two volumes, to refuse oblique ones (whose coordinates \
                 AFNI takes otherwise): it needs the fixed volume (AFNI's base) and the moving one (its source)"
            )),
            StartFile::Lta { origin, .. } => Err(anyhow!(
                "{origin}: a FreeSurfer LTA is read with the two volumes, whose grids tell which way it maps: it needs \
                 the fixed volume (FreeSurfer's --dst or --targ) and the moving one (its --mov)"
            )),
        }
    }

    /// [`Self::read`], FLIRT's and AFNI's matrices and FreeSurfer's LTA too: read against `fixed` (FLIRT's reference,
    /// AFNI's base, the LTA's dst) and `moving` (FLIRT's input, AFNI's source, the LTA's src).
    ///
    /// # Errors
    /// As [`Self::read`] and [`StartFile::on`].
    pub fn read_on(path: &Path, fixed: &Volume, moving: &Volume) -> anyhow::Result<Self> {
        StartFile::read(path)?.on(fixed, moving)
    }

    /// [`Self::read`] of a file that states its transform in patient space.
    fn read_lps(path: &Path, head: &[u8]) -> anyhow::Result<Self> {
        let name = path.display().to_string();
        let reader: Option<Reader> = if elastix::looks_like_parameter_file(head) {
            Some(elastix::read_affine)
        } else if mni_xfm::looks_like_xfm(head) {
            Some(mni_xfm::read_affine)
        } else if itk_h5::looks_like_hdf5(head) {
            Some(itk_h5::read_affine)
        } else if dicom_reg::looks_like_dicom(head) {
            Some(dicom_reg::read_affine)
        } else {
            None
        };
        if let Some(read) = reader {
            let affine = read(path).with_context(|| format!("--initial {name}"))?;
            return Self::new(AffineWarp::new(affine.matrix, affine.offset()), &name);
        }
        // A .tfm of one transform or a composite (SimpleITK writes a registration's result so), or a .mat.
        let chain = warpbench_io::transform_file::read_chain(path).with_context(|| format!("--initial {name}"))?;
        let affine = chain.affine().map_err(|kind| {
            anyhow!(
                "{name}: --initial takes an affine or another linear transform (AffineTransform_double_3_3, as \
                 `warpbench align` writes it, or a composite of ITK's linear classes); this file holds a {kind}{}",
                if kind.contains("BSpline") { " (give it to --field or --initial-field)" } else { "" }
            )
        })?;
        Self::new(AffineWarp::new(affine.matrix, affine.offset()), &name)
    }

    /// T₀: fixed → moving.
    #[must_use]
    pub fn moving_from_fixed(&self) -> &AffineWarp<Moving, Fixed> {
        &self.moving_from_fixed
    }

    /// T₀⁻¹: moving → fixed.
    #[must_use]
    pub fn fixed_from_moving(&self) -> &AffineWarp<Fixed, Moving> {
        &self.fixed_from_moving
    }
}

/// A starting transform's file, read: T₀ itself, in patient space; FSL's FLIRT matrix, which is in the voxel
/// coordinates of the two images it was made with and becomes T₀ with them ([`warpbench_io::fsl`]); AFNI's matrix,
/// T₀ between volumes that are not oblique; or FreeSurfer's LTA, whose direction the two volumes tell.
#[derive(Clone, Debug, PartialEq)]
pub enum StartFile {
    Lps(Start),
    Flirt {
        matrix: Matrix4<f64>,
        origin: String,
    },
    /// AFNI's `.aff12.1D`: T₀ itself (base-to-source in DICOM's LPS), taken only between volumes that are not
    /// oblique ([`warpbench_io::afni`]).
    Afni {
        matrix: Matrix4<f64>,
        origin: String,
    },
    /// FreeSurfer's `.lta`: its src and dst geometries say which of the two volumes it maps to the other
    /// ([`warpbench_io::lta`]).
    Lta {
        lta: Box<lta::Lta>,
        origin: String,
    },
}

impl StartFile {
    /// Reads a starting transform's file ([`Start::read`]), a FLIRT matrix (told by its content: four lines of four
    /// numbers), an AFNI matrix file (rows of twelve numbers) or a FreeSurfer LTA (`type = …` first).
    ///
    /// # Errors
    /// As [`Start::read`]; a FLIRT or AFNI matrix or an LTA that cannot be read.
    pub fn read(path: &Path) -> anyhow::Result<Self> {
        let head = head(path);
        if lta::looks_like_lta(&head) {
            let lta = lta::read(path).with_context(|| format!("--initial {}", path.display()))?;
            return Ok(Self::Lta { lta: Box::new(lta), origin: path.display().to_string() });
        }
        if fsl::looks_like_flirt_matrix(&head) {
            let matrix = fsl::read(path).with_context(|| format!("--initial {}", path.display()))?;
            return Ok(Self::Flirt { matrix, origin: path.display().to_string() });
        }
        if afni::looks_like_afni_matrix(&head) {
            let matrix = afni::read(path).with_context(|| format!("--initial {}", path.display()))?;
            return Ok(Self::Afni { matrix, origin: path.display().to_string() });
        }
        Start::read_lps(path, &head).map(Self::Lps)
    }

    /// T₀, with a FLIRT matrix read against `fixed` (its reference, `-ref`) and `moving` (its input, `-in`), an AFNI
    /// matrix taken between them when neither is oblique, and an LTA read the way their grids say.
    ///
    /// # Errors
    /// A FLIRT matrix or a grid that cannot be inverted; an oblique volume under an AFNI matrix; an LTA whose src and
    /// dst are neither volume.
    pub fn on(self, fixed: &Volume, moving: &Volume) -> anyhow::Result<Start> {
        match self {
            Self::Lps(start) => Ok(start),
            Self::Flirt { matrix, origin } => {
                let grid = |v: &Volume| (v.dims, v.lps_from_index);
                let (f, m) = (grid(fixed), grid(moving));
                let u = fsl::moving_from_fixed(Path::new(&origin), &matrix, (f.0, &f.1), (m.0, &m.1))?;
                start_of(&u, &origin)
            }
            Self::Afni { matrix, origin } => {
                afni::check_cardinal(Path::new(&origin), "fixed", &fixed.lps_from_index)?;
                afni::check_cardinal(Path::new(&origin), "moving", &moving.lps_from_index)?;
                start_of(&matrix, &origin)
            }
            Self::Lta { lta, origin } => {
                let grid = |v: &Volume| (v.dims, v.lps_from_index);
                let (f, m) = (grid(fixed), grid(moving));
                let u = lta::moving_from_fixed(Path::new(&origin), &lta, (f.0, &f.1), (m.0, &m.1))?;
                start_of(&u, &origin)
            }
        }
    }
}

/// T₀ of the pull-back `u` (a 4 × 4 matrix in LPS mm), named `origin`.
fn start_of(u: &Matrix4<f64>, origin: &str) -> anyhow::Result<Start> {
    let linear = u.fixed_view::<3, 3>(0, 0).into_owned();
    Start::new(AffineWarp::new(linear, [u[(0, 3)], u[(1, 3)], u[(2, 3)]]), origin)
}

/// A reader of one kind of linear transform file.
type Reader = fn(&Path) -> warpbench_io::Result<warpbench_io::itk_tfm::ItkAffine>;

/// The first 4 KiB of the regular file at `path`, to tell an elastix parameter file and an HDF5 file by; empty for
/// a file that cannot be read, which is left to the ITK reader, which says why.
fn head(path: &Path) -> Vec<u8> {
    use std::io::Read;
    let mut head = Vec::new();
    let read = std::fs::metadata(path).is_ok_and(|m| m.is_file())
        && std::fs::File::open(path).and_then(|f| f.take(4096).read_to_end(&mut head)).is_ok();
    if read { head } else { Vec::new() }
}

/// The starting transform a subcommand was given: a session's (already read with it), else `--initial`'s file, read
/// (a FLIRT or AFNI matrix against `fixed` and `moving`).
///
/// # Errors
/// As [`Start::read_on`].
pub fn resolve(
    session: Option<&Start>,
    initial: Option<&Path>,
    fixed: &Volume,
    moving: &Volume,
) -> anyhow::Result<Option<Start>> {
    match session {
        Some(s) => Ok(Some(s.clone())),
        None => initial.map(|path| Start::read_on(path, fixed, moving)).transpose(),
    }
}

/// Whether `pairs` pairs are enough for `method` to refine the starting transform.
#[must_use]
pub fn refines(method: &Method, pairs: usize) -> bool {
    pairs >= method.needs().min_pairs
}

/// Whether the pairs refine T₀ with a TPS, which makes T₀ vanish from the warp: a TPS fit (interpolating or
/// smoothing, λ fixed) is linear in its data and fits affine data exactly, so T₀ ∘ (the fit of qᵢ → T₀⁻¹(pᵢ)) is
/// the fit of qᵢ → pᵢ, and likewise for the forward map, to rounding. A landmark drag then takes its O(N²) path on the
/// raw pairs ([`crate::fit::DragFit`]).
#[must_use]
pub fn tps_ignores(method: &Method, pairs: usize) -> bool {
    matches!(method, Method::Tps { .. }) && refines(method, pairs)
}

/// The pull-back u = T₀ ∘ r (module docs); T₀ alone when there are too few pairs for `method`.
///
/// # Errors
/// The fit's, as [`Method::fit`].
pub fn pullback(
    start: &Start,
    method: &Method,
    fixed: &[Point3<Fixed>],
    moving: &[Point3<Moving>],
    fixed_box: Aabb<Fixed>,
) -> Result<FittedWarp<Moving, Fixed>, warpbench_solver::SolverError> {
    if !refines(method, moving.len()) {
        return Ok(FittedWarp::Linear(start.moving_from_fixed));
    }
    let aligned: Vec<Point3<Fixed>> = moving.iter().map(|p| start.fixed_from_moving.apply(*p)).collect();
    let residual: FittedWarp<Fixed, Fixed> = method.fit(fixed, &aligned, fixed_box)?;
    Ok(residual.followed_by(&start.moving_from_fixed))
}

/// The forward map d = T₀⁻¹ ∘ s (module docs); T₀⁻¹ alone when there are too few pairs for `method`.
///
/// # Errors
/// The fit's, as [`Method::fit`].
pub fn forward(
    start: &Start,
    method: &Method,
    fixed: &[Point3<Fixed>],
    moving: &[Point3<Moving>],
    moving_box: Aabb<Moving>,
) -> Result<FittedWarp<Fixed, Moving>, warpbench_solver::SolverError> {
    if !refines(method, moving.len()) {
        return Ok(FittedWarp::Linear(start.fixed_from_moving));
    }
    let aligned: Vec<Point3<Moving>> = fixed.iter().map(|q| start.moving_from_fixed.apply(*q)).collect();
    let residual: FittedWarp<Moving, Moving> = method.fit(moving, &aligned, moving_box)?;
    Ok(residual.followed_by(&start.fixed_from_moving))
}

/// The warp's name in reports: `method`, `method on <origin>` with a starting transform it refines, or
/// `<origin> alone (N pairs; method needs K)` when the pairs are too few.
#[must_use]
pub fn describe(method: &dyn std::fmt::Display, needs: usize, pairs: usize, start: Option<&Start>) -> String {
    match start {
        None => method.to_string(),
        Some(s) if pairs >= needs => format!("{method} on {}", s.origin),
        Some(s) => format!("{} alone ({pairs} pairs; {method} needs {needs})", s.origin),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Matrix3, Rotation3};
    use warpbench_solver::linear::LinearKind;

    fn start() -> Start {
        let r = Rotation3::from_euler_angles(0.1, -0.2, 0.15).into_inner() * Matrix3::from_diagonal_element(1.02);
        Start::new(AffineWarp::new(r, [5.0, -3.0, 8.0]), "test").expect("invertible")
    }

    /// With too few pairs the warp is T₀ itself; with enough, u hits every pair (interpolating TPS) and d does too.
    #[test]
    fn the_landmark_warp_refines_the_start_and_hits_the_pairs() {
        let s = start();
        let fixed: Vec<Point3<Fixed>> =
            [[0.0, 0.0, 0.0], [40.0, 5.0, -3.0], [-20.0, 30.0, 10.0], [5.0, -25.0, 30.0], [10.0, 10.0, -35.0]]
                .map(Point3::from_array)
                .to_vec();
        let moving: Vec<Point3<Moving>> = fixed
            .iter()
            .enumerate()
            .map(|(i, q)| {
                let p = s.moving_from_fixed().apply(*q).coords();
                Point3::new(p[0] + i as f64, p[1] - 0.5 * i as f64, p[2] + 2.0)
            })
            .collect();
        let fixed_box = Aabb::new(Point3::new(-60.0, -60.0, -60.0), Point3::new(60.0, 60.0, 60.0));
        let moving_box = Aabb::new(Point3::new(-70.0, -70.0, -70.0), Point3::new(70.0, 70.0, 70.0));
        let tps = Method::Tps { stiffness: 0.0 };
        let alone = pullback(&s, &tps, &fixed[..3], &moving[..3], fixed_box).expect("T0");
        let x = [3.0, 4.0, 5.0];
        let want = s.moving_from_fixed().apply_raw(x);
        let got = alone.as_ref().apply_raw(x);
        assert!((0..3).all(|a| (got[a] - want[a]).abs() < 1e-12), "{got:?} vs {want:?}");
        let u = pullback(&s, &tps, &fixed, &moving, fixed_box).expect("fit");
        let d = forward(&s, &tps, &fixed, &moving, moving_box).expect("fit");
        for (q, p) in fixed.iter().zip(&moving) {
            assert!(u.as_ref().apply(*q).distance(p) < 1e-8);
            assert!(d.as_ref().apply(*p).distance(q) < 1e-8);
        }
        // A rigid fit on top of T0 (rigid residual r) is T0 ∘ r, not the rigid fit of the raw pairs.
        let rigid = Method::Linear(LinearKind::Rigid);
        assert_eq!(describe(&rigid, 3, 2, Some(&s)), "test alone (2 pairs; rigid needs 3)");
        assert_eq!(describe(&rigid, 3, 5, Some(&s)), "rigid on test");
    }

    /// A TPS fit and an affine fit are linear in their data and keep affine data exactly, so on top of any affine T₀
    /// (here sheared and scaled) each is the fit of the raw pairs, the TPS interpolating or smoothing: what lets a
    /// landmark drag take its O(N²) path with a starting transform ([`tps_ignores`]).
    #[test]
    fn a_tps_on_an_affine_start_is_the_tps_of_the_raw_pairs() {
        let linear = Matrix3::new(1.1, 0.2, -0.05, 0.0, 0.9, 0.15, 0.1, -0.1, 1.3);
        let s = Start::new(AffineWarp::new(linear, [5.0, -3.0, 8.0]), "sheared").expect("invertible");
        let fixed: Vec<Point3<Fixed>> = (0..12)
            .map(|i| {
                let t = f64::from(i);
                Point3::new(40.0 * (0.7 * t).sin(), 35.0 * (1.3 * t).cos(), 3.0 * t - 18.0)
            })
            .collect();
        let moving: Vec<Point3<Moving>> = fixed
            .iter()
            .map(Point3::coords)
            .map(|[x, y, z]| Point3::new(x + 3.0 * (y / 20.0).sin(), y - 2.0, z + 0.1 * x))
            .collect();
        let fixed_box = Aabb::new(Point3::new(-60.0, -60.0, -60.0), Point3::new(60.0, 60.0, 60.0));
        let moving_box = Aabb::new(Point3::new(-70.0, -70.0, -70.0), Point3::new(70.0, 70.0, 70.0));
        let affine = Method::Linear(LinearKind::Affine);
        for method in [Method::Tps { stiffness: 0.0 }, Method::Tps { stiffness: 2.5 }, affine] {
            assert_eq!(tps_ignores(&method, fixed.len()), method != affine);
            let (u, d) =
                (pullback(&s, &method, &fixed, &moving, fixed_box), forward(&s, &method, &fixed, &moving, moving_box));
            let (u, d) = (u.expect("fit"), d.expect("fit"));
            let raw_u = method.fit(&fixed, &moving, fixed_box).expect("fit");
            let raw_d = method.fit(&moving, &fixed, moving_box).expect("fit");
            for i in 0..40 {
                let x = [f64::from(i) * 2.9 - 55.0, 30.0 - f64::from(i) * 1.7, f64::from(i % 9) * 12.0 - 48.0];
                let (a, b) = (u.as_ref().apply_raw(x), raw_u.as_ref().apply_raw(x));
                let (c, e) = (d.as_ref().apply_raw(x), raw_d.as_ref().apply_raw(x));
                assert!((0..3).all(|k| (a[k] - b[k]).abs() < 1e-9 && (c[k] - e[k]).abs() < 1e-9), "{method}: {x:?}");
            }
        }
        assert!(!tps_ignores(&Method::Tps { stiffness: 0.0 }, 3), "too few pairs: T₀ alone");
        assert!(!tps_ignores(&Method::Linear(LinearKind::Rigid), 12));
    }
}
