//! The displacement field under the landmark warp as the document keeps it: its file, and for a field that is read
//! against the fixed and moving images (a Learn2Reg field, or an FSL FNIRT warp) the two grids it is read against.
//!
//! A Learn2Reg field (`docs/formats.md`) holds, at each voxel of the fixed image, a step in voxels to the moving
//! image's voxel, and no geometry of its own; an FNIRT warp (`--fout`, `--cout`) maps FSL's coordinates of its
//! reference image to those of its input, which are scaled voxels too. The same file means other millimetres against
//! other images. So when it is chosen in the window, the fixed and moving grids open then are recorded beside its
//! path, and every later reader (the window, `--session` in every subcommand) reads it against those grids, whichever
//! volumes it is given. A session that names such a field without them is refused, never read against a guessed grid
//! (a NIfTI without them is read as a field in mm, which refuses Learn2Reg's form).
//!
//! An ITK transform file (`.tfm` or `.h5`) may hold B-splines and no displacement field: a map in mm with no grid,
//! which the stack applies as ITK does, point by point ([`FieldLayer::read`]); it needs no grids.
//!
//! In the session file a field of any other flavour is its path, as before; a field read against the grids is
//! `{"path": …, "voxel_grids": {"fixed": {"dims": [X, Y, Z], "lps_from_index": [[…], […], […]]}, "moving": …}}`,
//! each matrix the three rows of \[L | t\] with x_LPS = L·(i, j, k) + t.

use std::path::{Path, PathBuf};

use anyhow::{Context, anyhow, bail};
use serde::{Deserialize, Serialize};
use warpbench_io::Volume;
use warpbench_io::geometry::{Index, Lps, Transform};
use warpbench_io::learn2reg;
use warpbench_solver::field::SampledField;
use warpbench_solver::spaces::{Fixed, Moving};

use super::stack::FieldLayer;

/// How a displacement field's file is read (`--field-format`; the window's "Learn2Reg steps in voxels").
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum FieldReadFormat {
    /// Told apart by its content: ITK, ANTs, Slicer, MetaImage, elastix, ITK HDF5, DICOM, or Learn2Reg's `.npz`.
    #[default]
    Auto,
    /// Learn2Reg's field, `.npz` or its NIfTI form (an (X, Y, Z, 3) array), in the voxels of the two volumes: a NIfTI
    /// file says nothing of its units, so it is read so only when told.
    Learn2reg,
}

impl FieldReadFormat {
    /// Whether the field at `path` is read as Learn2Reg's: told so, or an `.npz` by its first bytes.
    ///
    /// # Errors
    /// The file cannot be opened (named).
    pub fn is_learn2reg(self, path: &Path) -> warpbench_io::Result<bool> {
        // A name that is no file (AFNI's bare `warp+tlrc`) is not an .npz; its own reader says what it is.
        Ok(self == Self::Learn2reg || (path.is_file() && learn2reg::is_npz_file(path)?))
    }

    /// Whether the field at `path` is read against the fixed and moving grids ([`pair_pullback`]): a Learn2Reg field
    /// ([`Self::is_learn2reg`]) or an FSL FNIRT warp (a NIfTI file with one of FSL's intent codes).
    ///
    /// # Errors
    /// The file cannot be opened (named).
    pub fn reads_against_pair(self, path: &Path) -> warpbench_io::Result<bool> {
        Ok(self.is_learn2reg(path)? || is_fnirt_file(path)?)
    }
}

/// Whether `path` is one of FSL's NIfTI files (its intent code says so): an FNIRT warp, or a file FSL's reader refuses
/// by name (a TOPUP field).
///
/// # Errors
/// The file cannot be opened (named).
pub fn is_fnirt_file(path: &Path) -> warpbench_io::Result<bool> {
    Ok(path.is_file() && warpbench_io::nifti::fsl_intent(path)?.is_some())
}

/// A displacement field's file under the landmark warp, with the grids of a Learn2Reg field or an FNIRT warp (module
/// docs).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(from = "Form", into = "Form")]
pub struct FieldFile {
    pub path: PathBuf,
    /// The grids a Learn2Reg field's voxel steps are counted in, or an FNIRT warp's FSL coordinates; `None` for every
    /// other flavour, which states its own geometry (or, as an ITK transform file of B-splines, needs none).
    pub voxel_grids: Option<Box<VoxelGrids>>,
}

/// The fixed and the moving grid of a Learn2Reg field or an FNIRT warp.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct VoxelGrids {
    pub fixed: VoxelGrid,
    pub moving: VoxelGrid,
}

/// A volume's voxel grid: its size and where its voxel centres lie in LPS mm.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct VoxelGrid {
    /// Voxels along i, j, k.
    pub dims: [usize; 3],
    /// The rows of \[L | t\]: x_LPS = L·(i, j, k) + t.
    pub lps_from_index: [[f64; 4]; 3],
}

impl VoxelGrid {
    /// The grid of `volume`.
    #[must_use]
    pub fn of(volume: &Volume) -> Self {
        let rows = volume.lps_from_index.rows();
        Self { dims: volume.dims, lps_from_index: [rows[0], rows[1], rows[2]] }
    }

    /// Its voxel-to-patient map, refused (naming `side`) when a hand-edited session made it singular or not finite.
    fn lps_from_index(&self, side: &str) -> anyhow::Result<Transform<Lps, Index>> {
        let m = &self.lps_from_index;
        let t =
            Transform::from_linear_translation(nalgebra::Matrix3::from_fn(|r, c| m[r][c]), [m[0][3], m[1][3], m[2][3]]);
        if !t.is_valid_affine() {
            bail!("the {side} grid recorded for it is not an invertible voxel-to-patient matrix");
        }
        Ok(t)
    }
}

impl FieldFile {
    /// A field of a flavour that states its own geometry (ITK, ANTs, Slicer, MetaImage, elastix, ITK HDF5).
    #[must_use]
    pub fn new(path: PathBuf) -> Self {
        Self { path, voxel_grids: None }
    }

    /// The field at `path` as chosen with `fixed` and `moving` open: a Learn2Reg field (an `.npz` told by content, as
    /// `warp --field` tells it, or any file `read` says is one) or an FNIRT warp keeps their grids. Errors name the
    /// file: one that cannot be opened.
    ///
    /// # Errors
    /// The file cannot be opened to read its first bytes.
    pub fn chosen(path: PathBuf, read: FieldReadFormat, fixed: &Volume, moving: &Volume) -> anyhow::Result<Self> {
        let voxel_grids = read
            .reads_against_pair(&path)?
            .then(|| Box::new(VoxelGrids { fixed: VoxelGrid::of(fixed), moving: VoxelGrid::of(moving) }));
        Ok(Self { path, voxel_grids })
    }

    /// Reads the field as a layer of the stack ([`FieldLayer::read`], or for a Learn2Reg field or an FNIRT warp the
    /// pull-back it states between the recorded grids, [`pair_pullback`]). Errors name the file.
    ///
    /// # Errors
    /// What the readers refuse; a Learn2Reg field or an FNIRT warp without recorded grids, or one that does not
    /// belong on the recorded fixed grid.
    pub fn layer(&self) -> anyhow::Result<FieldLayer> {
        let origin = self.path.display().to_string();
        // Recorded grids are checked before the file is read: a hand-edited session's are refused as such.
        let recorded = match &self.voxel_grids {
            Some(grids) => {
                let fixed = grids.fixed.lps_from_index("fixed").with_context(|| origin.clone())?;
                let moving = grids.moving.lps_from_index("moving").with_context(|| origin.clone())?;
                Some((grids.fixed.dims, fixed, grids.moving.dims, moving))
            }
            None => None,
        };
        let Some((fixed_dims, fixed, moving_dims, moving)) = recorded else {
            if learn2reg::is_npz_name(&self.path) || learn2reg::is_npz_file(&self.path).unwrap_or(false) {
                bail!(
                    "{origin}: a Learn2Reg field's steps are in the voxels of its fixed and moving images, and \
                     nothing here records which: choose it with Use displacement field... in the window with those \
                     two volumes open, or give it with them on the command line (--initial-field {origin} --fixed \
                     F --moving M)"
                );
            }
            if is_fnirt_file(&self.path).unwrap_or(false) {
                bail!(
                    "{origin}: an FSL FNIRT warp is in FSL's coordinates of its reference and input images, and \
                     nothing here records which: choose it with Use displacement field... in the window with the \
                     reference as the fixed volume and the input as the moving one, or give it with them on the \
                     command line (--initial-field {origin} --fixed REF --moving IN)"
                );
            }
            return FieldLayer::read(&self.path);
        };
        let (pullback, warnings) = pair_pullback(&self.path, (fixed_dims, &fixed), (moving_dims, &moving))?;
        let mut layer = FieldLayer::pullback(pullback, &origin);
        layer.warnings = warnings.iter().map(|w| format!("{origin}: {w}")).collect();
        Ok(layer)
    }
}

/// The pull-back u = `moving_from_fixed` that the field at `path`, read against the pair's grids, states on the fixed
/// grid: an FSL FNIRT warp ([`warpbench_io::fnirt::read_pullback`], with the fixed volume FNIRT's reference and the
/// moving one its input), or else a Learn2Reg field ([`learn2reg_pullback`]); with what the reader inferred (an FNIRT
/// deformation field's relative or absolute values).
///
/// # Errors
/// Named by the file: what the readers refuse.
pub fn pair_pullback(
    path: &Path,
    fixed: warpbench_io::fsl::Grid<'_>,
    moving: warpbench_io::fsl::Grid<'_>,
) -> anyhow::Result<(SampledField<Moving, Fixed>, Vec<String>)> {
    if is_fnirt_file(path)? {
        let read = warpbench_io::fnirt::read_pullback(path, fixed, moving)?;
        let field =
            SampledField::from_displacement_field(read.field).map_err(|e| anyhow!("{}: {e}", path.display()))?;
        return Ok((field, read.warnings));
    }
    Ok((learn2reg_pullback(path, fixed.0, fixed.1, moving.1)?, Vec::new()))
}

/// The pull-back u = `moving_from_fixed` that the Learn2Reg field at `path` states between the voxels of the fixed
/// grid (`fixed_dims`, `fixed_lps_from_index`) and those of the moving grid, sampled at the fixed voxel centres.
///
/// # Errors
/// Named by the file: what [`learn2reg::read_voxel_field`] refuses, a shape other than the fixed grid's, a step to
/// no finite point.
pub fn learn2reg_pullback(
    path: &Path,
    fixed_dims: [usize; 3],
    fixed_lps_from_index: &Transform<Lps, Index>,
    moving_lps_from_index: &Transform<Lps, Index>,
) -> anyhow::Result<SampledField<Moving, Fixed>> {
    let steps = learn2reg::read_voxel_field(path)?;
    let field = learn2reg::pullback_from_voxels(path, &steps, fixed_dims, fixed_lps_from_index, moving_lps_from_index)?;
    SampledField::from_displacement_field(field).map_err(|e| anyhow!("{}: {e}", path.display()))
}

/// The session file's form: the path alone, or the path and the grids of a Learn2Reg field (module docs).
#[derive(Serialize, Deserialize)]
#[serde(
    untagged,
    expecting = "a displacement field: its path, or {\"path\": …, \"voxel_grids\": {\"fixed\": …, \"moving\": …}} \
                 for a Learn2Reg field"
)]
enum Form {
    Path(PathBuf),
    WithGrids { path: PathBuf, voxel_grids: Box<VoxelGrids> },
}

impl From<Form> for FieldFile {
    fn from(form: Form) -> Self {
        match form {
            Form::Path(path) => Self::new(path),
            Form::WithGrids { path, voxel_grids } => Self { path, voxel_grids: Some(voxel_grids) },
        }
    }
}

impl From<FieldFile> for Form {
    fn from(file: FieldFile) -> Self {
        match file.voxel_grids {
            None => Self::Path(file.path),
            Some(voxel_grids) => Self::WithGrids { path: file.path, voxel_grids },
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grids() -> VoxelGrids {
        let grid = |d: f64| VoxelGrid {
            dims: [4, 5, 6],
            lps_from_index: [[-d, 0.0, 0.0, 10.0], [0.0, d, 0.1, -20.0], [0.0, 0.0, d, 30.5]],
        };
        VoxelGrids { fixed: grid(2.0), moving: grid(2.5) }
    }

    /// A field of any other flavour is its path in the session, as sessions wrote it before Learn2Reg's; a Learn2Reg
    /// field is a map with its grids, and reads back equal.
    #[test]
    fn a_field_is_its_path_and_a_learn2reg_field_a_map_with_its_grids() {
        let plain = FieldFile::new(PathBuf::from("/data/warp.nii.gz"));
        assert_eq!(serde_json::to_value(&plain).expect("json"), serde_json::json!("/data/warp.nii.gz"));
        let read: FieldFile = serde_json::from_str("\"/data/warp.nii.gz\"").expect("a path");
        assert_eq!(read, plain);

        let l2r = FieldFile { path: PathBuf::from("/data/disp.npz"), voxel_grids: Some(Box::new(grids())) };
        let value = serde_json::to_value(&l2r).expect("json");
        assert_eq!(value["path"], "/data/disp.npz");
        assert_eq!(value["voxel_grids"]["moving"]["dims"], serde_json::json!([4, 5, 6]));
        assert_eq!(value["voxel_grids"]["fixed"]["lps_from_index"][1], serde_json::json!([0.0, 2.0, 0.1, -20.0]));
        assert_eq!(serde_json::from_value::<FieldFile>(value).expect("back"), l2r);
    }

    /// A hand-edited form that is neither says what is expected; grids that are not a voxel-to-patient map are
    /// refused naming the file and the side, before the file is read.
    #[test]
    fn malformed_forms_and_singular_grids_are_refused() {
        let err = serde_json::from_str::<FieldFile>(r#"{"path": "/d.npz", "voxel_grids": {"fixed": 1}}"#)
            .expect_err("malformed");
        assert!(err.to_string().contains("voxel_grids"), "{err}");
        let mut bad = grids();
        bad.moving.lps_from_index[2] = [0.0, 0.0, 0.0, 1.0];
        let file = FieldFile { path: PathBuf::from("/no/such/disp.npz"), voxel_grids: Some(Box::new(bad)) };
        let err = format!("{:#}", file.layer().expect_err("singular"));
        assert!(err.contains("/no/such/disp.npz") && err.contains("moving grid"), "{err}");
    }

    /// An FNIRT warp chosen with its reference and input open keeps their grids, and the session reads it against
    /// them as the file's own reader does; named in a session without them, it is refused, saying what to do.
    #[test]
    fn an_fnirt_warp_keeps_the_grids_it_was_chosen_with() {
        let data = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/fnirt");
        let open = |name: &str| warpbench_io::open(data.join(name)).expect("volume");
        let (fixed, moving) = (open("ref_radio.nii.gz"), open("src.nii.gz"));
        let path = data.join("coef_radio.nii.gz");
        let file = FieldFile::chosen(path.clone(), FieldReadFormat::Auto, &fixed, &moving).expect("chosen");
        let grids = file.voxel_grids.as_ref().expect("grids recorded");
        assert_eq!((grids.fixed.dims, grids.moving.dims), (fixed.dims, moving.dims));
        let (want, _) =
            pair_pullback(&path, (fixed.dims, &fixed.lps_from_index), (moving.dims, &moving.lps_from_index))
                .expect("read");
        let layer = file.layer().expect("the layer");
        let x = fixed.voxel_lps(3, 4, 5).coords();
        let at = warpbench_io::geometry::Point3::<Fixed>::from_array(x);
        let bits = |p: [f64; 3]| p.map(f64::to_bits);
        assert_eq!(bits(layer.moving_from_fixed_raw(x)), bits(warpbench_solver::Warp::apply(&want, at).coords()));
        let err = format!("{:#}", FieldFile::new(path).layer().expect_err("no grids"));
        assert!(err.contains("coef_radio.nii.gz") && err.contains("FNIRT") && err.contains("--fixed REF"), "{err}");
    }
}
