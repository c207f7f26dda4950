//! FreeSurfer's linear transform file (`.lta`), what `mri_robust_register`, `bbregister`, `mri_coreg` and
//! `lta_convert` write and `mri_vol2vol --lta` reads: a 4 × 4 matrix M with the geometry of the two volumes it was made
//! with, its "src" and its "dst". M maps src to dst: with `type = 1` (`LINEAR_RAS_TO_RAS`) a point of the src volume
//! to the dst volume in scanner RAS (mm), with `type = 0` (`LINEAR_VOX_TO_VOX`) a voxel index of src to one of dst,
//! which the two geometries turn into the RAS map R = A_dst · M · A_src⁻¹ (FreeSurfer's `LTAchangeType`).
//!
//! A geometry ("volume info") is FreeSurfer's: the voxels along each axis, the voxel sizes, the direction cosines of
//! the three axes in RAS and the RAS of the volume's centre, c_ras; its voxel-to-RAS matrix is
//! A = [D · diag(sizes) | c_ras − D · diag(sizes) · dims / 2], as FreeSurfer and nibabel compute it.
//!
//! **Which volume is which.** FreeSurfer's registration programs write the moving volume (`--mov`) as src and the
//! fixed one (`--dst`, `--targ`) as dst, so M maps moving points to fixed points and warpbench's pull-back is
//! u = M⁻¹ (in LPS). `lta_convert --invert` swaps them. FreeSurfer's readers tell the direction by the geometry
//! (`mri_vol2vol` inverts an LTA whose src is the volume it moves), and so does warpbench ([`moving_from_fixed`]):
//! each of src and dst is compared with the two volumes (equal dimensions, and sizes, cosines and centre within
//! 10⁻³, FreeSurfer's `vg_isEqual` at the threshold its programs set), and the file is read the way more of them
//! agree with, src = moving when both ways agree as much (the two volumes on one grid). When neither volume is the
//! src or the dst, or the file has no valid volume info, the direction is not guessed: the file is refused, with
//! `lta_convert --src --trg` as the way to name the volumes.
//!
//! Reading takes one transform (`nxforms = 1`) of type 0 or 1, sixteen finite numbers whose last row is (0, 0, 0, 1)
//! within 10⁻⁵ (FreeSurfer writes single precision), FreeSurfer's keys only, in a text file of at most 64 KiB;
//! anything else is refused, naming the file and the line. Writing ([`to_text`]) gives a `LINEAR_RAS_TO_RAS` file
//! laid out as FreeSurfer's `LTAwrite`, src the moving volume and dst the fixed one.

use std::path::Path;

use nalgebra::{Matrix3, Matrix4, RowVector4, Vector3};

use crate::error::{Error, Result};
use crate::files::read_small_text;
use crate::fsl::Grid;
use crate::geometry::{Index, Lps, Transform};

/// The largest file read (FreeSurfer's own are about 1.5 KiB).
const MAX_BYTES: u64 = 65_536;

/// How close two geometries' sizes, cosines and centres must be to be the same volume (FreeSurfer's
/// `vg_isEqual_Threshold`, as `mri_vol2vol`, `mri_concatenate_lta` and `lta_convert` set it).
pub const SAME_GEOMETRY: f64 = 1e-3;

/// What M maps ([`Lta::kind`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LtaType {
    /// `type = 0`: src voxel indices to dst voxel indices.
    VoxToVox,
    /// `type = 1`: src scanner RAS to dst scanner RAS, mm.
    RasToRas,
}

impl LtaType {
    /// The code and FreeSurfer's name, as on the `type` line.
    #[must_use]
    pub const fn code_and_name(self) -> (i32, &'static str) {
        match self {
            Self::VoxToVox => (0, "LINEAR_VOX_TO_VOX"),
            Self::RasToRas => (1, "LINEAR_RAS_TO_RAS"),
        }
    }
}

/// A volume's geometry as an LTA states it (module docs).
#[derive(Clone, Debug, PartialEq)]
pub struct VolumeInfo {
    /// Voxels along i, j, k (`volume`).
    pub dims: [usize; 3],
    /// `voxelsize`, mm.
    pub voxel_size: [f64; 3],
    /// The direction cosines of the i, j and k axes in RAS (`xras`, `yras`, `zras`), as columns.
    pub directions: Matrix3<f64>,
    /// The RAS of the volume's centre (`cras`), mm.
    pub c_ras: [f64; 3],
    /// The file it was read from, as FreeSurfer noted it (may be empty).
    pub filename: String,
}

impl VolumeInfo {
    /// The geometry of a volume on `grid`, named `filename`: sizes the lengths of the voxel-to-RAS matrix's columns,
    /// cosines those columns normalised, centre the RAS of index dims / 2 (nibabel's `VolumeGeometry.from_image`).
    #[must_use]
    pub fn of((dims, lps_from_index): Grid<'_>, filename: &str) -> Self {
        let ras = ras_from_lps() * lps_from_index.matrix();
        let linear: Matrix3<f64> = ras.fixed_view::<3, 3>(0, 0).into_owned();
        let voxel_size = [0, 1, 2].map(|c| linear.column(c).norm());
        let mut directions = linear;
        for (c, size) in voxel_size.iter().enumerate() {
            directions.set_column(c, &(linear.column(c) / *size));
        }
        let centre =
            ras * nalgebra::Vector4::new(dims[0] as f64 / 2.0, dims[1] as f64 / 2.0, dims[2] as f64 / 2.0, 1.0);
        Self { dims, voxel_size, directions, c_ras: [centre[0], centre[1], centre[2]], filename: filename.to_owned() }
    }

    /// The voxel-to-RAS matrix A (module docs).
    #[must_use]
    pub fn ras_from_index(&self) -> Matrix4<f64> {
        let linear = self.directions * Matrix3::from_diagonal(&Vector3::from(self.voxel_size));
        let half = Vector3::new(self.dims[0] as f64, self.dims[1] as f64, self.dims[2] as f64) / 2.0;
        let origin = Vector3::from(self.c_ras) - linear * half;
        let mut a = Matrix4::identity();
        a.fixed_view_mut::<3, 3>(0, 0).copy_from(&linear);
        a.fixed_view_mut::<3, 1>(0, 3).copy_from(&origin);
        a
    }

    /// The voxel-to-LPS matrix of the same grid, as warpbench places volumes.
    #[must_use]
    pub fn lps_from_index(&self) -> Transform<Lps, Index> {
        Transform::from_matrix(ras_from_lps() * self.ras_from_index())
    }

    /// Whether `other` is the same volume: equal dimensions, and sizes, cosines and centres within
    /// [`SAME_GEOMETRY`] (FreeSurfer's `vg_isEqual`).
    #[must_use]
    pub fn matches(&self, other: &Self) -> bool {
        let close = |a: &[f64], b: &[f64]| a.iter().zip(b).all(|(x, y)| (x - y).abs() <= SAME_GEOMETRY);
        self.dims == other.dims
            && close(&self.voxel_size, &other.voxel_size)
            && close(self.directions.as_slice(), other.directions.as_slice())
            && close(&self.c_ras, &other.c_ras)
    }

    /// How messages name it: its file, or its dimensions and voxel size when FreeSurfer noted no file.
    fn describe(&self) -> String {
        let [x, y, z] = self.dims;
        let [a, b, c] = self.voxel_size;
        let grid = format!("{x}×{y}×{z} voxels of {a:.3}×{b:.3}×{c:.3} mm");
        if self.filename.is_empty() { grid } else { format!("{} ({grid})", self.filename) }
    }

    /// The lines FreeSurfer writes for a valid geometry (`writeVolGeom`).
    fn to_text(&self) -> String {
        let [x, y, z] = self.dims;
        let three = |v: [f64; 3]| format!("{:.15e} {:.15e} {:.15e}", v[0] + 0.0, v[1] + 0.0, v[2] + 0.0);
        let column = |c: usize| three([self.directions[(0, c)], self.directions[(1, c)], self.directions[(2, c)]]);
        format!(
            "valid = 1  # volume info valid\nfilename = {}\nvolume = {x} {y} {z}\nvoxelsize = {}\nxras   = {}\n\
             yras   = {}\nzras   = {}\ncras   = {}\n",
            self.filename,
            three(self.voxel_size),
            column(0),
            column(1),
            column(2),
            three(self.c_ras),
        )
    }
}

/// An LTA file's one transform (module docs).
#[derive(Clone, Debug, PartialEq)]
pub struct Lta {
    pub kind: LtaType,
    /// M, whose last row is (0, 0, 0, 1).
    pub matrix: Matrix4<f64>,
    /// The src volume's geometry; `None` when the file has none or marks it not valid.
    pub src: Option<VolumeInfo>,
    /// The dst volume's geometry, likewise.
    pub dst: Option<VolumeInfo>,
}

impl Lta {
    /// M as a map of scanner RAS points, src's to dst's: M itself for `LINEAR_RAS_TO_RAS`, A_dst · M · A_src⁻¹ for
    /// `LINEAR_VOX_TO_VOX`.
    ///
    /// # Errors
    /// A voxel-to-voxel file without both geometries, or one that cannot be inverted (`path` names the file).
    pub fn dst_from_src_ras(&self, path: &Path) -> Result<Matrix4<f64>> {
        match self.kind {
            LtaType::RasToRas => Ok(self.matrix),
            LtaType::VoxToVox => {
                let (Some(src), Some(dst)) = (&self.src, &self.dst) else {
                    return Err(Error::invalid(
                        path,
                        "a LINEAR_VOX_TO_VOX transform without valid src and dst volume info cannot be placed in \
                         patient space",
                    ));
                };
                let src_index = src
                    .ras_from_index()
                    .try_inverse()
                    .ok_or_else(|| Error::invalid(path, "the src volume info's grid cannot be inverted"))?;
                Ok(dst.ras_from_index() * self.matrix * src_index)
            }
        }
    }
}

/// Whether `path` is named as FreeSurfer's programs tell an LTA: ending `.lta`, in any case.
#[must_use]
pub fn is_lta_name(path: &Path) -> bool {
    path.extension().is_some_and(|e| e.eq_ignore_ascii_case("lta"))
}

/// Whether `head` (a file's first bytes) is meant as an LTA: text whose first line that is not blank or a comment
/// sets `type`.
#[must_use]
pub fn looks_like_lta(head: &[u8]) -> bool {
    let Some(text) = crate::files::head_text(head) else { return false };
    text.lines()
        .map(str::trim)
        .find(|l| !l.is_empty() && !l.starts_with('#'))
        .and_then(|l| l.strip_prefix("type"))
        .is_some_and(|rest| rest.trim_start().starts_with('='))
}

/// Reads the LTA at `path` (module docs).
///
/// # Errors
/// A file that is not a regular file or cannot be read, one larger than 64 KiB, or text that is not an LTA of one
/// transform warpbench reads; the message names the file and the line.
pub fn read(path: &Path) -> Result<Lta> {
    parse(path, &read_small_text(path, MAX_BYTES, "a FreeSurfer LTA")?)
}

/// A line of the file: its number (1-based) and its text, trimmed.
type Line<'a> = (usize, &'a str);

/// `key = value` (`key` alone, with FreeSurfer's spacing), with a trailing `# comment` dropped.
fn value_of<'a>(line: &'a str, key: &str) -> Option<&'a str> {
    let rest = line.strip_prefix(key)?.trim_start().strip_prefix('=')?;
    let value = if key == "filename" { rest } else { rest.split('#').next().unwrap_or_default() };
    Some(value.trim())
}

/// `count` finite numbers from `text`, or an error naming `line`.
fn numbers<const N: usize>(path: &Path, (n, text): Line<'_>, what: &str) -> Result<[f64; N]> {
    let values: Vec<&str> = text.split_whitespace().collect();
    if values.len() != N {
        return Err(Error::invalid(path, format!("line {n}: {what} has {} numbers, not {N}", values.len())));
    }
    let mut out = [0.0; N];
    for (slot, v) in out.iter_mut().zip(&values) {
        *slot = v
            .parse()
            .ok()
            .filter(|x: &f64| x.is_finite())
            .ok_or_else(|| Error::invalid(path, format!("line {n}: {v:?} is not a finite number")))?;
    }
    Ok(out)
}

/// Parses an LTA's text (module docs); `path` names it in errors.
///
/// # Errors
/// What is not an LTA of one `LINEAR_VOX_TO_VOX` or `LINEAR_RAS_TO_RAS` transform, naming the line.
pub fn parse(path: &Path, text: &str) -> Result<Lta> {
    let mut lines = text
        .lines()
        .enumerate()
        .map(|(n, l)| (n + 1, l.trim()))
        .filter(|(_, l)| !l.is_empty() && !l.starts_with('#'))
        .peekable();
    let end = |what: &str| Error::invalid(path, format!("the file ends before {what}"));
    let (n, line) = lines.next().ok_or_else(|| end("its `type` line: not a FreeSurfer LTA"))?;
    let code = value_of(line, "type")
        .ok_or_else(|| Error::invalid(path, format!("line {n}: not `type = …`: not a FreeSurfer LTA")))?;
    let kind = match code {
        "0" => LtaType::VoxToVox,
        "1" => LtaType::RasToRas,
        other => {
            let name = match other {
                "2" => "LINEAR_PHYSVOX_TO_PHYSVOX",
                "14" => "REGISTER_DAT (tkregister's RAS)",
                "21" => "LINEAR_COR_TO_COR",
                _ => "unknown",
            };
            return Err(Error::unsupported(
                path,
                format!(
                    "line {n}: type {other} ({name}): warpbench reads LINEAR_VOX_TO_VOX (0) and LINEAR_RAS_TO_RAS (1); \
                     `lta_convert --inlta FILE --outlta NEW.lta` writes the latter"
                ),
            ));
        }
    };
    let (n, line) = lines.next().ok_or_else(|| end("its `nxforms` line"))?;
    match value_of(line, "nxforms") {
        Some("1") => {}
        Some(count) => {
            return Err(Error::unsupported(
                path,
                format!("line {n}: {count} transforms (nxforms): warpbench reads an LTA of one"),
            ));
        }
        None => return Err(Error::invalid(path, format!("line {n}: not `nxforms = …`"))),
    }
    // mean and sigma (FreeSurfer's morphing parameters, unused by linear transforms), then the matrix's shape.
    let mut shape = lines.next().ok_or_else(|| end("the matrix"))?;
    while value_of(shape.1, "mean").is_some() || value_of(shape.1, "sigma").is_some() {
        shape = lines.next().ok_or_else(|| end("the matrix"))?;
    }
    let [_, rows, cols] = numbers::<3>(path, shape, "the matrix's size line (e.g. `1 4 4`)")?;
    if (rows, cols) != (4.0, 4.0) {
        return Err(Error::invalid(path, format!("line {}: a {rows}×{cols} matrix, not 4×4", shape.0)));
    }
    let mut matrix = Matrix4::zeros();
    for r in 0..4 {
        let row = numbers::<4>(path, lines.next().ok_or_else(|| end("the matrix's four rows"))?, "a matrix row")?;
        matrix.set_row(r, &RowVector4::from(row));
    }
    let last = [matrix[(3, 0)], matrix[(3, 1)], matrix[(3, 2)], matrix[(3, 3)] - 1.0];
    if last.iter().any(|v| v.abs() > 1e-5) {
        return Err(Error::invalid(path, "the matrix's last row is not 0 0 0 1: not an affine transform"));
    }
    matrix.set_row(3, &RowVector4::new(0.0, 0.0, 0.0, 1.0));
    let mut lta = Lta { kind, matrix, src: None, dst: None };
    while let Some((n, line)) = lines.next() {
        if value_of(line, "label").is_some() || line.starts_with("subject") || line.starts_with("fscale") {
            continue;
        }
        let slot = match line {
            "src volume info" => &mut lta.src,
            "dst volume info" => &mut lta.dst,
            _ => return Err(Error::invalid(path, format!("line {n}: {line:?} is not a line of a FreeSurfer LTA"))),
        };
        *slot = volume_info(path, &mut lines)?;
    }
    Ok(lta)
}

/// The key lines of a volume info block, up to the next line that is not one; `None` for `valid = 0`.
fn volume_info<'a>(
    path: &Path,
    lines: &mut std::iter::Peekable<impl Iterator<Item = Line<'a>>>,
) -> Result<Option<VolumeInfo>> {
    const KEYS: [&str; 8] = ["valid", "filename", "volume", "voxelsize", "xras", "yras", "zras", "cras"];
    let mut found: [Option<Line<'a>>; 8] = [None; 8];
    while let Some(&(n, line)) = lines.peek() {
        let Some(k) = KEYS.iter().position(|key| value_of(line, key).is_some()) else { break };
        found[k] = Some((n, value_of(line, KEYS[k]).unwrap_or_default()));
        lines.next();
    }
    let valid = match found[0] {
        Some((_, "1")) => true,
        Some((_, "0")) | None => false,
        Some((n, v)) => return Err(Error::invalid(path, format!("line {n}: valid = {v:?}, not 0 or 1"))),
    };
    if !valid {
        return Ok(None);
    }
    let need = |k: usize| {
        found[k].ok_or_else(|| Error::invalid(path, format!("a valid volume info without its `{}` line", KEYS[k])))
    };
    let (n, text) = need(2)?;
    let dims = numbers::<3>(path, (n, text), "volume")?;
    if dims.iter().any(|d| d.fract() != 0.0 || *d < 1.0 || *d > 1e6) {
        return Err(Error::invalid(path, format!("line {n}: volume = {text}: not three counts of voxels")));
    }
    let voxel_size = numbers::<3>(path, need(3)?, "voxelsize")?;
    if voxel_size.iter().any(|s| *s <= 0.0) {
        return Err(Error::invalid(path, format!("line {}: a voxel size that is not positive", need(3)?.0)));
    }
    let mut directions = Matrix3::zeros();
    for (c, k) in [4, 5, 6].into_iter().enumerate() {
        let column = numbers::<3>(path, need(k)?, KEYS[k])?;
        if Vector3::from(column).norm() < 1e-6 {
            return Err(Error::invalid(path, format!("line {}: {} is not a direction", need(k)?.0, KEYS[k])));
        }
        directions.set_column(c, &Vector3::from(column));
    }
    if directions.determinant().abs() < 1e-6 {
        return Err(Error::invalid(path, "a volume info's axes lie in one plane"));
    }
    Ok(Some(VolumeInfo {
        dims: dims.map(|d| d as usize),
        voxel_size,
        directions,
        c_ras: numbers::<3>(path, need(7)?, "cras")?,
        filename: found[1].map(|(_, f)| f.to_owned()).unwrap_or_default(),
    }))
}

/// The pull-back u (fixed points to moving points, LPS mm) of `lta` between the volumes on `fixed` and `moving`, the
/// direction told by the file's geometries (module docs).
///
/// # Errors
/// A file whose src and dst are neither volume, or that has no valid volume info; a matrix that cannot be inverted.
pub fn moving_from_fixed(path: &Path, lta: &Lta, fixed: Grid<'_>, moving: Grid<'_>) -> Result<Matrix4<f64>> {
    let (fixed_info, moving_info) = (VolumeInfo::of(fixed, ""), VolumeInfo::of(moving, ""));
    let is = |info: &Option<VolumeInfo>, volume: &VolumeInfo| info.as_ref().is_some_and(|i| i.matches(volume));
    let src_is_moving = usize::from(is(&lta.src, &moving_info)) + usize::from(is(&lta.dst, &fixed_info));
    let src_is_fixed = usize::from(is(&lta.src, &fixed_info)) + usize::from(is(&lta.dst, &moving_info));
    if src_is_moving == 0 && src_is_fixed == 0 {
        let name =
            |info: &Option<VolumeInfo>| info.as_ref().map_or_else(|| "not stated".to_owned(), VolumeInfo::describe);
        return Err(Error::invalid(
            path,
            format!(
                "neither volume is the LTA's src ({}) or its dst ({}), so which way it maps is not known; give the \
                 volumes it was made with, or name them in it with `lta_convert --inlta FILE --outlta NEW.lta --src \
                 MOVING --trg FIXED`",
                name(&lta.src),
                name(&lta.dst)
            ),
        ));
    }
    let dst_from_src = lps_from_ras_map(&lta.dst_from_src_ras(path)?);
    if src_is_moving >= src_is_fixed {
        dst_from_src.try_inverse().ok_or_else(|| Error::invalid(path, "the matrix cannot be inverted"))
    } else {
        Ok(dst_from_src)
    }
}

/// RAS's map `m` as the same map in LPS.
fn lps_from_ras_map(m: &Matrix4<f64>) -> Matrix4<f64> {
    ras_from_lps() * m * ras_from_lps()
}

/// The diagonal matrix that turns LPS into RAS, and back.
fn ras_from_lps() -> Matrix4<f64> {
    Matrix4::from_diagonal(&nalgebra::Vector4::new(-1.0, -1.0, 1.0, 1.0))
}

/// The text of a `LINEAR_RAS_TO_RAS` LTA of the pull-back `moving_from_fixed` (LPS mm): src the moving volume on
/// `moving` named `moving_name`, dst the fixed one, M = the map of moving RAS points to fixed ones, laid out as
/// FreeSurfer's `LTAwrite`.
///
/// # Errors
/// A pull-back that cannot be inverted (`path` names the output).
pub fn to_text(
    path: &Path,
    moving_from_fixed: &Matrix4<f64>,
    (fixed, fixed_name): (Grid<'_>, &str),
    (moving, moving_name): (Grid<'_>, &str),
) -> Result<String> {
    let fixed_from_moving =
        moving_from_fixed.try_inverse().ok_or_else(|| Error::invalid(path, "the warp cannot be inverted"))?;
    let m = lps_from_ras_map(&fixed_from_moving);
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let mut text = format!(
        "# transform file {name}\n# created by warpbench\n\ntype      = 1 # LINEAR_RAS_TO_RAS\nnxforms   = 1\n\
         mean      = 0.0000 0.0000 0.0000\nsigma     = 1.0000\n1 4 4\n"
    );
    for r in 0..4 {
        let row: Vec<String> = (0..4).map(|c| format!("{:.15e}", m[(r, c)] + 0.0)).collect();
        // FreeSurfer's MatrixAsciiWriteInto ends each number with a space.
        text.push_str(&row.join(" "));
        text.push_str(" \n");
    }
    text.push_str("src volume info\n");
    text.push_str(&VolumeInfo::of(moving, moving_name).to_text());
    text.push_str("dst volume info\n");
    text.push_str(&VolumeInfo::of(fixed, fixed_name).to_text());
    text.push_str("subject \nfscale 0.000000\n");
    Ok(text)
}

/// Writes the pull-back `moving_from_fixed` as an LTA at `path`, atomically ([`to_text`]).
///
/// # Errors
/// A matrix that is not finite or cannot be inverted, a file name with a line break, or the write itself.
pub fn write(
    path: &Path,
    moving_from_fixed: &Matrix4<f64>,
    fixed: (Grid<'_>, &str),
    moving: (Grid<'_>, &str),
) -> Result<()> {
    if !moving_from_fixed.iter().all(|v| v.is_finite()) {
        return Err(Error::invalid(path, "the matrix is not finite"));
    }
    if [fixed.1, moving.1].iter().any(|n| n.contains(['\n', '\r'])) {
        return Err(Error::invalid(path, "a volume's file name has a line break, which an LTA cannot hold"));
    }
    let text = to_text(path, moving_from_fixed, fixed, moving)?;
    crate::write_atomic(path, |w| w.write_all(text.as_bytes()))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid(linear: Matrix3<f64>, origin: [f64; 3]) -> Transform<Lps, Index> {
        Transform::from_linear_translation(linear, origin)
    }

    /// A geometry read back from its own text is the grid it was made of, and matches itself.
    #[test]
    fn a_volume_info_is_the_grid_it_states() {
        let linear = nalgebra::Rotation3::from_euler_angles(0.1, -0.2, 0.3).into_inner()
            * Matrix3::from_diagonal(&Vector3::new(1.2, 0.9, 2.0));
        let lps = grid(linear, [-30.0, 20.0, 10.0]);
        let info = VolumeInfo::of(([4, 5, 3], &lps), "a.nii.gz");
        assert!(info.lps_from_index().max_abs_diff(&lps) < 1e-12);
        let text = format!(
            "type = 1\nnxforms = 1\n1 4 4\n1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\nsrc volume info\n{}",
            info.to_text()
        );
        let read = parse(Path::new("x.lta"), &text).expect("parses").src.expect("valid");
        assert!(read.matches(&info));
        assert_eq!(read.filename, "a.nii.gz");
        assert!(!read.matches(&VolumeInfo::of(([4, 5, 4], &lps), "")));
    }
}
