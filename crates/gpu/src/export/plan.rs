//! A checked [`ExportRequest`] reduced to the f32 numbers both paths use ([`Plan`]), and their progress reports.

use glam::{DMat3, DMat4, DVec3, DVec4};

use super::request::{ExportRequest, Interpolation, MAX_DIMENSION, Progress, PullBack, SampleType};
use crate::control::PreparedControl;
use crate::error::{GpuError, Result};
use crate::pullback::TpsLocal;

/// The pull-back's displacement as both paths evaluate it.
#[derive(Clone, Debug)]
pub(crate) enum PlanPullBack {
    Identity,
    Control { dims: [usize; 3], texels: Vec<[f32; 4]> },
    Tps(TpsLocal),
}

/// A checked request, reduced to the f32 numbers both paths use.
#[derive(Clone, Debug)]
pub(crate) struct Plan {
    pub target_dims: [usize; 3],
    pub source_dims: [usize; 3],
    /// Columns of the affine maps (steps 1 and 2 of the [`crate::export`] docs).
    pub source_index_from_target_index: [[f32; 4]; 4],
    pub pullback_from_target_index: [[f32; 4]; 4],
    pub source_index_from_lps: [[f32; 4]; 4],
    pub pullback: PlanPullBack,
    pub interpolation: Interpolation,
    pub output: SampleType,
    pub outside_value: f64,
    pub output_len: usize,
    pub slab_slices: Option<usize>,
}

fn invalid(message: String) -> GpuError {
    GpuError::InvalidInput(message)
}

/// Checks dims: every axis in 1..=[`MAX_DIMENSION`]; returns the voxel count.
fn check_dims(what: &str, dims: [usize; 3]) -> Result<usize> {
    if dims.iter().any(|&d| d == 0 || d > MAX_DIMENSION) {
        return Err(invalid(format!("{what} dims {dims:?}: every axis needs 1 to {MAX_DIMENSION} voxels")));
    }
    Ok(dims.iter().product())
}

/// A finite, affine, non-singular row-major `lps_from_index` as a glam matrix.
fn check_affine(what: &str, m: &[[f64; 4]; 4]) -> Result<DMat4> {
    let lps_from_index = DMat4::from_cols_array_2d(m).transpose();
    if !lps_from_index.is_finite() {
        return Err(invalid(format!("{what} lps_from_index is not finite: {m:?}")));
    }
    #[allow(clippy::float_cmp, reason = "an affine map's last row is exactly (0, 0, 0, 1)")]
    let affine = m[3] == [0.0, 0.0, 0.0, 1.0];
    if !affine {
        return Err(invalid(format!("{what} lps_from_index is not affine (last row {:?})", m[3])));
    }
    let linear = DMat3::from_mat4(lps_from_index);
    let scale = linear.x_axis.length() * linear.y_axis.length() * linear.z_axis.length();
    if scale.is_nan() || scale <= 0.0 || linear.determinant().abs() <= 1e-9 * scale {
        return Err(invalid(format!("{what} lps_from_index is singular: {m:?}")));
    }
    Ok(lps_from_index)
}

/// Entries within 10⁻⁹ (relative) of an integer become that integer (removes the round-off of `inverse · M`).
fn snap(m: DMat4) -> DMat4 {
    let mut cols = m.to_cols_array();
    for x in &mut cols {
        let r = x.round();
        if (*x - r).abs() <= 1e-9 * x.abs().max(1.0) {
            *x = r;
        }
    }
    DMat4::from_cols_array(&cols)
}

fn columns_f32(m: DMat4) -> [[f32; 4]; 4] {
    m.as_mat4().to_cols_array_2d()
}

/// The affine map index ↦ control-texel index (centres at integers) of a control texture over `[min, max]`.
fn ctrl_index_from_ref(dims: [usize; 3], min: DVec3, max: DVec3) -> DMat4 {
    let n = DVec3::new(dims[0] as f64, dims[1] as f64, dims[2] as f64);
    let scale = n / (max - min);
    DMat4::from_cols(
        DVec4::new(scale.x, 0.0, 0.0, 0.0),
        DVec4::new(0.0, scale.y, 0.0, 0.0),
        DVec4::new(0.0, 0.0, scale.z, 0.0),
        (-min * scale - DVec3::splat(0.5)).extend(1.0),
    )
}

impl Plan {
    /// Checks `request` (sizes before anything is allocated) and composes the maps.
    pub fn new(request: &ExportRequest<'_>) -> Result<Self> {
        let source_count = check_dims("source", request.source.dims)?;
        if request.source.samples.len() != source_count {
            return Err(invalid(format!(
                "source dims {:?} need {source_count} samples, got {}",
                request.source.dims,
                request.source.samples.len()
            )));
        }
        let output_len = check_dims("target", request.target.dims)?;
        let output = request.output_type();
        let output_bytes = (output_len as u64).saturating_mul(output.bytes());
        if output_bytes > request.max_output_bytes {
            return Err(invalid(format!(
                "target {:?} of {output:?} is {output_bytes} bytes, above the limit of {} bytes",
                request.target.dims, request.max_output_bytes
            )));
        }
        if output.is_integer() && !request.outside_value.is_finite() {
            return Err(invalid(format!("outside value {} cannot be stored as {output:?}", request.outside_value)));
        }
        if request.slab_slices == Some(0) {
            return Err(invalid("slab_slices must be at least 1".into()));
        }
        let source_lps_from_index = check_affine("source", &request.source.lps_from_index)?;
        let ref_from_target_index = check_affine("target", &request.target.lps_from_index)?;
        let source_index_from_lps = source_lps_from_index.inverse();
        let source_index_from_target_index = snap(source_index_from_lps * ref_from_target_index);
        let mut linear = snap(source_index_from_lps);
        linear.w_axis = DVec4::W;

        let (pullback, pullback_from_target_index) = match request.pullback {
            PullBack::Identity => (PlanPullBack::Identity, DMat4::IDENTITY),
            PullBack::Control(desc) => {
                let prepared = PreparedControl::prepare(&desc, true)?;
                let (min, max) = (prepared.info.box_min_ref, prepared.info.box_max_ref);
                let map = ctrl_index_from_ref(desc.dims, min, max) * ref_from_target_index;
                (PlanPullBack::Control { dims: desc.dims, texels: prepared.texels }, map)
            }
            PullBack::Tps(desc) => {
                desc.validate()?;
                let [nx, ny, nz] = request.target.dims;
                let centre_index = DVec3::new(nx as f64 - 1.0, ny as f64 - 1.0, nz as f64 - 1.0) * 0.5;
                let origin = ref_from_target_index.transform_point3(centre_index);
                let local = desc.local(origin.to_array());
                let finite = local
                    .centres_local
                    .iter()
                    .chain(&local.weights)
                    .chain(&local.linear_minus_identity)
                    .chain([&local.offset_mm])
                    .all(|v| v.iter().all(|x| x.is_finite()));
                if !finite {
                    return Err(invalid("the TPS overflows f32 about the target's centre".into()));
                }
                (PlanPullBack::Tps(local), DMat4::from_translation(-origin) * ref_from_target_index)
            }
        };
        let maps = [source_index_from_target_index, pullback_from_target_index, linear];
        if maps.iter().any(|m| !m.as_mat4().is_finite()) {
            return Err(invalid("the composed index maps overflow f32".into()));
        }
        Ok(Self {
            target_dims: request.target.dims,
            source_dims: request.source.dims,
            source_index_from_target_index: columns_f32(maps[0]),
            pullback_from_target_index: columns_f32(maps[1]),
            source_index_from_lps: columns_f32(maps[2]),
            pullback,
            interpolation: request.interpolation,
            output,
            outside_value: request.outside_value,
            output_len,
            slab_slices: request.slab_slices,
        })
    }
}

/// Reports `done` of `total` slices; `Err(Cancelled)` when the callback says stop.
pub(crate) fn report(progress: &mut dyn FnMut(Progress) -> bool, done: usize, total: usize) -> Result<()> {
    if progress(Progress { slices_done: done, slices_total: total }) {
        Ok(())
    } else {
        Err(GpuError::Cancelled { slices_done: done, slices_total: total })
    }
}

#[cfg(test)]
#[allow(clippy::float_cmp, reason = "rounding and snapping give exact values")]
mod tests {
    use super::*;

    #[test]
    fn snapping_removes_round_off_only() {
        let m = DMat4::from_cols_array(&[
            1.0 + 1e-13,
            0.0,
            0.0,
            0.0,
            1e-14,
            0.5,
            0.0,
            0.0,
            0.0,
            0.0,
            1.0,
            0.0,
            127.999_999_999_99,
            0.3,
            2.0,
            1.0,
        ]);
        let s = snap(m).to_cols_array();
        assert_eq!(s[0], 1.0);
        assert_eq!(s[4], 0.0);
        assert_eq!(s[5], 0.5);
        assert_eq!(s[12], 128.0);
        assert_eq!(s[13], 0.3);
    }
}
