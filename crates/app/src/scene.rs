//! From loaded volumes and a pull-back to what the renderer takes: plain volume data, transfer-function presets
//! with windows chosen from the data, and a pull-back sampled into a control texture over the fixed volume's box.
//! Shared by `warpbench render` and the app, so both show the same picture. (A fitted warp's own GPU forms, and its
//! control texture through the B-spline's fast sampler, are [`crate::fit`]'s.)
//!
//! Errors are `anyhow` errors that name what is wrong; every one is about the input (the CLI exits with 2).

use anyhow::{Result, anyhow};
use warpbench_gpu::export::ExportSamples;
use warpbench_gpu::{ControlDesc, Preset, VolumeDesc, VolumeSamples, Window};
use warpbench_io::Volume;
use warpbench_io::volume::{Modality, VoxelData};
use warpbench_solver::control::{ControlGrid, ControlTexture};
use warpbench_solver::spaces::{Aabb, Fixed, Moving};
use warpbench_solver::warp::Warp;

/// The renderer's view of a loaded volume (borrowed samples, its `lps_from_index`).
#[must_use]
pub fn volume_desc(v: &Volume) -> VolumeDesc<'_> {
    VolumeDesc { dims: v.dims, samples: volume_samples(&v.data), lps_from_index: v.lps_from_index.rows() }
}

/// A volume's samples, borrowed, as the renderer uploads them: the one conversion from io's [`VoxelData`].
#[must_use]
pub fn volume_samples(data: &VoxelData) -> VolumeSamples<'_> {
    match data {
        VoxelData::U8(d) => VolumeSamples::U8(d),
        VoxelData::I16(d) => VolumeSamples::I16(d),
        VoxelData::U16(d) => VolumeSamples::U16(d),
        VoxelData::F32(d) => VolumeSamples::F32(d),
    }
}

/// A volume's samples, borrowed, as the export resamples them: the one conversion from io's [`VoxelData`] to the
/// export's source type.
#[must_use]
pub fn export_samples(data: &VoxelData) -> ExportSamples<'_> {
    match data {
        VoxelData::U8(d) => ExportSamples::U8(d),
        VoxelData::I16(d) => ExportSamples::I16(d),
        VoxelData::U16(d) => ExportSamples::U16(d),
        VoxelData::F32(d) => ExportSamples::F32(d),
    }
}

/// Whether `v` looks like a CT: DICOM says so, or its values reach into air (below −500, Hounsfield units).
#[must_use]
pub fn looks_like_ct(v: &Volume) -> bool {
    match v.modality {
        Modality::Ct => true,
        Modality::Mr => false,
        _ => v.data.finite_range().is_some_and(|(lo, _)| lo < -500.0),
    }
}

/// The `q`-quantile of the values above `floor`, from every 7th sample (enough for a window).
fn quantile_above(v: &Volume, floor: f64, q: f64) -> Option<f64> {
    let mut vals: Vec<f64> =
        (0..v.data.len()).step_by(7).map(|i| v.data.get_f64(i)).filter(|x| x.is_finite() && *x > floor).collect();
    if vals.is_empty() {
        return None;
    }
    let k = ((vals.len() - 1) as f64 * q.clamp(0.0, 1.0)).round() as usize;
    let (_, x, _) = vals.select_nth_unstable_by(k, f64::total_cmp);
    Some(*x)
}

/// The preset and window to show `v` with: `preset` if given, else CT bone for a CT and MR T1 otherwise. Presets
/// with a fixed window (the CT ones, in HU) use it; the others window the data between the 2nd percentile of the
/// foreground (values above 5 % of the 99th percentile) and its 99th percentile.
#[must_use]
pub fn auto_style(v: &Volume, preset: Option<Preset>) -> (Preset, Window) {
    let preset = preset.unwrap_or(if looks_like_ct(v) { Preset::CtBone } else { Preset::MrT1 });
    if let Some(w) = preset.default_window() {
        return (preset, w);
    }
    let (lo, hi) = v.data.finite_range().unwrap_or((0.0, 1.0));
    let p99 = quantile_above(v, lo, 0.99).unwrap_or(hi);
    let floor = lo + 0.05 * (p99 - lo);
    let low = quantile_above(v, floor, 0.02).unwrap_or(lo);
    let high = if p99 > low { p99 } else { hi.max(low + 1.0) };
    (preset, Window::from_range(low as f32, high as f32))
}

/// The pull-back `moving_from_fixed` sampled texel by texel into an n³ control texture whose texel centres span
/// `fixed_box` (the ref box) edge to edge: the texture's own box is `fixed_box` grown by half a texel on every side.
/// Trilinear lookups then interpolate between samples everywhere in `fixed_box` and never clamp there, so an affine
/// pull-back is reproduced exactly and a smooth one to the interpolation error, up to the box's faces. A fitted
/// pull-back goes through [`crate::fit::control_texture`], which samples a B-spline faster.
pub fn control_texture<W: Warp<Moving, Fixed> + ?Sized>(
    moving_from_fixed: &W,
    fixed_box: Aabb<Fixed>,
    n: usize,
) -> Result<(ControlGrid, ControlTexture)> {
    let grid = control_grid(fixed_box, n)?;
    Ok((grid, ControlTexture::sample(moving_from_fixed, grid)))
}

/// The grid of [`control_texture`]: n³ texels over `fixed_box` grown by half a texel, so that the texel centres
/// span the box edge to edge. The GPU evaluates the same grid ([`warpbench_gpu::ControlGridDesc`]).
pub fn control_grid(fixed_box: Aabb<Fixed>, n: usize) -> Result<ControlGrid> {
    if n < 2 {
        return Err(anyhow!("control texture: {n} texels per axis; at least 2"));
    }
    let (lo, hi) = (fixed_box.min.coords(), fixed_box.max.coords());
    let half_texel: [f64; 3] = std::array::from_fn(|a| (hi[a] - lo[a]) / (2.0 * (n as f64 - 1.0)));
    let grown = Aabb::new(
        warpbench_io::geometry::Point3::from_array(std::array::from_fn(|a| lo[a] - half_texel[a])),
        warpbench_io::geometry::Point3::from_array(std::array::from_fn(|a| hi[a] + half_texel[a])),
    );
    ControlGrid::cube(n, grown).map_err(|e| anyhow!("control texture: {e}"))
}

/// The renderer's view of a control texture (over its grid's box).
#[must_use]
pub fn control_desc<'a>(grid: &ControlGrid, texture: &'a ControlTexture) -> ControlDesc<'a> {
    ControlDesc {
        dims: grid.dims,
        texels: texture.as_f32s(),
        box_min_ref: grid.domain.min.coords(),
        box_max_ref: grid.domain.max.coords(),
    }
}
