//! Empty-space skipping: which bricks of the render (ref) space can contribute nothing to a frame, for each volume,
//! through its warp.
//!
//! 1. **Per volume, in its own index space** ([`VolumeBricks`], made once at upload): the min/max of the normalised
//!    texels over bricks of [`crate::volume::BRICK_VOXELS`]³ voxels.
//! 2. **Per frame's look** ([`EmptySpaceGrid::build`], only when a transfer function, window, opacity, volume or warp
//!    changes): a grid of bricks over the proxy box of ref space. For each ref brick B (grown by a margin) and each
//!    volume, the pull-back image u(B) (u(w(B)) under a view deformation w, its image box of B first,
//!    [`crate::view_deformation::ViewDeformation::image_box`]) is bounded by the box B + \[d_min, d_max\], d the displacements of the control
//!    texels whose trilinear support meets B (per texel with [`PreparedControl`]'s texels, else the texture's global
//!    bounds [`ControlInfo::disp_min_mm`] / `disp_max_mm`), then, under a procedural deformation p of the layer's data,
//!    by p's image of that box ([`crate::procedural::Procedural::image_box`]); its bounding box in the volume's index space gives the
//!    voxels a trilinear lookup there can read (the 8 around each point, clamped to the edge), hence the volume bricks
//!    it can reach and a value range \[v_min, v_max\]. The volume is **empty** in B when u(B) lies wholly outside its
//!    texture box (transparent there), or when the transfer function's opacity is zero on every entry the lookups of
//!    \[v_min, v_max\] can touch (entries ⌊255·t⌋ and the next, widened by one entry on each side against rounding;
//!    linear interpolation between two zero entries is exactly zero), or when its opacity scale is ≤ 0.
//! 3. **The ray marcher** (`shaders/raycast.wgsl`): at a sample in a brick where every volume the blend uses is empty,
//!    it jumps to the last sample of its lattice t_k = t_enter + (k + j)·step before the brick's exit, so the samples
//!    it takes are exactly those it takes without skipping, and the skipped ones would have added premultiplied zero:
//!    the image (colour and first-hit depth) is bit for bit the same. Picking skips the same bricks (of its target
//!    volume), except the gradient probe, which does not depend on the transfer function.
//!
//! The grid is stored as an `R8Uint` 3-D texture, one cell per brick: bit [`OCCUPIED_FIXED`] / [`OCCUPIED_MOVING`]
//! set where that volume may be non-transparent.

use glam::{DVec3, Vec3};
use rayon::prelude::*;

use crate::control::{ControlInfo, PreparedControl};
use crate::device::GpuContext;
use crate::settings::{LayerParams, LayerStyle};
use crate::transfer::{OpacityTable, TF_ENTRIES};
use crate::volume::VolumeBricks;

/// Default edge of a ref-space brick, in voxels of the finer volume.
pub const DEFAULT_REF_BRICK_VOXELS: f32 = 8.0;
/// At most this many ref-space bricks per axis (the brick grows to fit).
pub const MAX_REF_BRICKS_PER_AXIS: u32 = 64;
/// Cell bit: the fixed volume may be non-transparent in this brick (`shaders/raycast.wgsl`, [`crate::raycast::INTERFACE`]).
pub const OCCUPIED_FIXED: u32 = 1;
/// Cell bit: the moving volume may be non-transparent in this brick.
pub const OCCUPIED_MOVING: u32 = 2;

/// One volume as the classification sees it.
#[derive(Clone, Copy, Debug)]
pub struct OccupancyLayer<'a> {
    pub params: LayerParams,
    pub bricks: &'a VolumeBricks,
    /// The control texture's texels for per-brick displacement bounds; `None`: the global bounds of
    /// `params.control` (a texture evaluated on the GPU), or the identity without a control texture.
    pub control_texels: Option<&'a PreparedControl>,
    /// The layer's transfer function (row `params.style.tf_row`).
    pub opacity: &'a OpacityTable,
}

/// The ref-space lattice of an [`EmptySpaceGrid`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BrickLattice {
    pub min_ref: Vec3,
    /// Brick edge, ref mm.
    pub brick_mm: f32,
    pub dims: [u32; 3],
}

impl BrickLattice {
    /// Bricks of `brick_mm` (grown so that no axis has more than [`MAX_REF_BRICKS_PER_AXIS`]) covering `box_ref`.
    #[must_use]
    pub fn covering(box_ref: (Vec3, Vec3), brick_mm: f32) -> Self {
        let extent = (box_ref.1 - box_ref.0).max(Vec3::splat(1e-3));
        let brick_mm = brick_mm.max(extent.max_element() / MAX_REF_BRICKS_PER_AXIS as f32).max(1e-3);
        let dims = (extent / brick_mm).ceil().to_array().map(|d| (d as u32).clamp(1, MAX_REF_BRICKS_PER_AXIS));
        Self { min_ref: box_ref.0, brick_mm, dims }
    }

    /// The ref-space box of brick `b`.
    #[must_use]
    pub fn brick_box(&self, b: [u32; 3]) -> (DVec3, DVec3) {
        let lo = self.min_ref.as_dvec3() + DVec3::from_array(b.map(f64::from)) * f64::from(self.brick_mm);
        (lo, lo + DVec3::splat(f64::from(self.brick_mm)))
    }

    #[must_use]
    pub fn count(&self) -> usize {
        self.dims.iter().map(|&d| d as usize).product()
    }
}

/// What a grid was built from: a frame whose layers differ from it in any of these needs a new grid.
#[derive(Clone, Debug, PartialEq)]
pub struct EmptySpaceKey {
    layers: [LayerParams; 2],
    opacity: [OpacityTable; 2],
    lattice: BrickLattice,
}

impl EmptySpaceKey {
    /// The key of a frame with these layers (visibility, prefilter and iso value do not matter) over `lattice`.
    #[must_use]
    pub fn new(fixed: &LayerParams, moving: &LayerParams, opacity: [&OpacityTable; 2], lattice: BrickLattice) -> Self {
        let normal = |l: &LayerParams| LayerParams {
            style: LayerStyle { visible: true, iso_value: 0.0, ..l.style },
            has_prefilter: false,
            ..*l
        };
        Self { layers: [normal(fixed), normal(moving)], opacity: opacity.map(Clone::clone), lattice }
    }
}

/// The occupancy of the ref-space bricks, one cell (bits [`OCCUPIED_FIXED`], [`OCCUPIED_MOVING`]) per brick.
#[derive(Clone, Debug, PartialEq)]
pub struct EmptySpaceGrid {
    pub lattice: BrickLattice,
    /// x fastest.
    pub cells: Vec<u8>,
    pub key: EmptySpaceKey,
}

impl EmptySpaceGrid {
    /// Classifies every brick of `lattice` for both layers (see the module docs).
    #[must_use]
    pub fn build(fixed: &OccupancyLayer<'_>, moving: &OccupancyLayer<'_>, lattice: BrickLattice) -> Self {
        let [nx, ny, _] = lattice.dims;
        // Grow each brick by one voxel of the finer volume: sample positions are rounded to f32, and the marcher's
        // jump is computed in f32 too.
        let finest = [fixed, moving].iter().flat_map(|l| l.params.volume.spacing_mm).fold(f64::INFINITY, f64::min);
        let margin = if finest.is_finite() { finest } else { 1.0 } + 1e-4 * f64::from(lattice.brick_mm);
        let mut cells = vec![0u8; lattice.count()];
        let slab = (nx * ny) as usize;
        cells.par_chunks_mut(slab).enumerate().for_each(|(k, slice)| {
            for (n, cell) in slice.iter_mut().enumerate() {
                let (i, j) = (n as u32 % nx, n as u32 / nx);
                let (lo, hi) = lattice.brick_box([i, j, k as u32]);
                let (lo, hi) = (lo - DVec3::splat(margin), hi + DVec3::splat(margin));
                if layer_may_be_opaque(fixed, lo, hi) {
                    *cell |= OCCUPIED_FIXED as u8;
                }
                if layer_may_be_opaque(moving, lo, hi) {
                    *cell |= OCCUPIED_MOVING as u8;
                }
            }
        });
        let key = EmptySpaceKey::new(&fixed.params, &moving.params, [fixed.opacity, moving.opacity], lattice);
        Self { lattice, cells, key }
    }

    /// The fraction of bricks where neither volume can be seen (for reports).
    #[must_use]
    pub fn empty_fraction(&self) -> f64 {
        let empty: usize = self.cells.iter().map(|&c| usize::from(c == 0)).sum();
        empty as f64 / self.cells.len().max(1) as f64
    }

    /// The cell of brick `b`.
    #[must_use]
    pub fn cell(&self, b: [u32; 3]) -> u8 {
        let [nx, ny, _] = self.lattice.dims.map(|d| d as usize);
        self.cells[b[0] as usize + nx * (b[1] as usize + ny * b[2] as usize)]
    }
}

/// Whether a volume drawn with `style` can be non-transparent somewhere its normalised texels lie in
/// `texels` = \[min, max\], mapped to values by `value_offset + value_scale · t` (the shader's arithmetic).
fn may_be_opaque(
    opacity: &OpacityTable,
    style: &LayerStyle,
    value_offset: f32,
    value_scale: f32,
    texels: [f32; 2],
) -> bool {
    if style.opacity_scale <= 0.0 {
        return false;
    }
    let (a, b) = (value_offset + value_scale * texels[0], value_offset + value_scale * texels[1]);
    // f32 rounding of the interpolated texel and of the mapping; the entries are widened by one as well.
    let slack = 1e-5 * (value_offset.abs() + value_scale.abs());
    let (v_lo, v_hi) = (a.min(b) - slack, a.max(b) + slack);
    let (low, width) = (style.window.low(), style.window.width);
    let t = |v: f32| ((v - low) / width).clamp(0.0, 1.0);
    let (t0, t1) = (t(v_lo), t(v_hi));
    let (t_lo, t_hi) = (t0.min(t1), t0.max(t1));
    if !(t_lo.is_finite() && t_hi.is_finite()) {
        return true;
    }
    let scale = (TF_ENTRIES - 1) as f32;
    let (e_lo, e_hi) = ((t_lo * scale).floor() as i64 - 1, (t_hi * scale).floor() as i64 + 2);
    opacity.any_opaque(e_lo, e_hi)
}

/// The componentwise bounds of the displacements a trilinear, clamp-to-edge lookup of the control texture can return
/// anywhere in the ref box \[lo, hi\].
fn displacement_bounds(
    control: &ControlInfo,
    texels: Option<&PreparedControl>,
    lo: DVec3,
    hi: DVec3,
) -> (DVec3, DVec3) {
    let global = (control.disp_min_mm.as_dvec3(), control.disp_max_mm.as_dvec3());
    let Some(texels) = texels.filter(|t| t.info == *control) else {
        return global;
    };
    let m = control.ctrl_tex_from_ref.as_dmat4();
    let (a, b) = (m.transform_point3(lo), m.transform_point3(hi));
    let n = DVec3::from_array(control.dims.map(f64::from));
    let (c0, c1) = (a.min(b) * n - DVec3::splat(0.5), a.max(b) * n - DVec3::splat(0.5));
    let mut i0 = [0usize; 3];
    let mut i1 = [0usize; 3];
    for ax in 0..3 {
        let last = f64::from(control.dims[ax]) - 1.0;
        i0[ax] = c0[ax].floor().clamp(0.0, last) as usize;
        i1[ax] = (c1[ax].floor() + 1.0).clamp(0.0, last) as usize;
    }
    let [dx, dy, _] = control.dims.map(|d| d as usize);
    let (mut d_lo, mut d_hi) = (DVec3::INFINITY, DVec3::NEG_INFINITY);
    for k in i0[2]..=i1[2] {
        for j in i0[1]..=i1[1] {
            for t in &texels.texels[dx * (j + dy * k) + i0[0]..=dx * (j + dy * k) + i1[0]] {
                let d = DVec3::new(f64::from(t[0]), f64::from(t[1]), f64::from(t[2]));
                (d_lo, d_hi) = (d_lo.min(d), d_hi.max(d));
            }
        }
    }
    (d_lo, d_hi)
}

/// Whether `layer` can be non-transparent anywhere in the ref box \[lo, hi\].
fn layer_may_be_opaque(layer: &OccupancyLayer<'_>, lo: DVec3, hi: DVec3) -> bool {
    let v = &layer.params.volume;
    // The view deformation first: w(B) lies in its image box of the brick.
    let (lo, hi) = layer.params.view.map_or((lo, hi), |w| w.image_box(lo, hi));
    let (p_lo, p_hi) = match &layer.params.control {
        Some(c) => {
            let (d_lo, d_hi) = displacement_bounds(c, layer.control_texels, lo, hi);
            (lo + d_lo, hi + d_hi)
        }
        None => (lo, hi),
    };
    // Then through the procedural deformation of the layer's data: p(u(B)) lies in p's image of that box.
    let (p_lo, p_hi) = layer.params.procedural.map_or((p_lo, p_hi), |p| p.image_box(p_lo, p_hi));
    // The box's bounding box in texture coordinates.
    let tex_from_lps = v.tex_from_lps.as_dmat4();
    let (mut t_lo, mut t_hi) = (DVec3::INFINITY, DVec3::NEG_INFINITY);
    for c in 0..8 {
        let corner = DVec3::new(
            if c & 1 == 0 { p_lo.x } else { p_hi.x },
            if c & 2 == 0 { p_lo.y } else { p_hi.y },
            if c & 4 == 0 { p_lo.z } else { p_hi.z },
        );
        let t = tex_from_lps.transform_point3(corner);
        (t_lo, t_hi) = (t_lo.min(t), t_hi.max(t));
    }
    if !(t_lo.is_finite() && t_hi.is_finite()) {
        return true;
    }
    // Wholly outside the texture box [0, 1]³: transparent (the shader's `outside_tex`).
    let eps = 1e-5;
    if (0..3).any(|a| t_hi[a] < -eps || t_lo[a] > 1.0 + eps) {
        return false;
    }
    let n = DVec3::from_array(v.dims.map(f64::from));
    let (c_lo, c_hi) = (t_lo * n - DVec3::splat(0.5), t_hi * n - DVec3::splat(0.5));
    let i_lo = c_lo.to_array().map(|c| c.floor() as i64);
    let i_hi = c_hi.to_array().map(|c| c.floor() as i64 + 1);
    let Some(texels) = layer.bricks.range(i_lo, i_hi) else {
        return false;
    };
    may_be_opaque(layer.opacity, &layer.params.style, v.value_offset, v.value_scale, texels)
}

/// An [`EmptySpaceGrid`] on the GPU: an `R8Uint` 3-D texture, one texel per brick.
#[derive(Debug)]
pub struct GpuEmptySpace {
    pub lattice: BrickLattice,
    pub key: EmptySpaceKey,
    pub empty_fraction: f64,
    pub texture: wgpu::Texture,
    pub view: wgpu::TextureView,
}

impl GpuEmptySpace {
    #[must_use]
    pub fn upload(ctx: &GpuContext, grid: &EmptySpaceGrid) -> Self {
        let view_and_texture = upload_cells(ctx, grid.lattice.dims, &grid.cells);
        Self {
            lattice: grid.lattice,
            key: grid.key.clone(),
            empty_fraction: grid.empty_fraction(),
            texture: view_and_texture.0,
            view: view_and_texture.1,
        }
    }

    /// A 1×1×1 grid that marks everything occupied, bound where a frame skips nothing.
    #[must_use]
    pub(crate) fn placeholder(ctx: &GpuContext) -> wgpu::TextureView {
        upload_cells(ctx, [1, 1, 1], &[(OCCUPIED_FIXED | OCCUPIED_MOVING) as u8]).1
    }
}

fn upload_cells(ctx: &GpuContext, dims: [u32; 3], cells: &[u8]) -> (wgpu::Texture, wgpu::TextureView) {
    let size = wgpu::Extent3d { width: dims[0], height: dims[1], depth_or_array_layers: dims[2] };
    let texture = ctx.device.create_texture(&wgpu::TextureDescriptor {
        label: Some("empty space"),
        size,
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D3,
        format: wgpu::TextureFormat::R8Uint,
        usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
        view_formats: &[],
    });
    ctx.queue.write_texture(
        texture.as_image_copy(),
        cells,
        wgpu::TexelCopyBufferLayout { offset: 0, bytes_per_row: Some(dims[0]), rows_per_image: Some(dims[1]) },
        size,
    );
    let view = texture.create_view(&wgpu::TextureViewDescriptor::default());
    (texture, view)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::device::Capabilities;
    use crate::transfer::{TransferFunction, Window};
    use crate::volume::{PreparedVolume, VolumeBudget, VolumeDesc, VolumeSamples};

    fn volume(dims: [usize; 3], f: impl Fn(usize, usize, usize) -> u8) -> PreparedVolume {
        let mut samples = Vec::new();
        for k in 0..dims[2] {
            for j in 0..dims[1] {
                for i in 0..dims[0] {
                    samples.push(f(i, j, k));
                }
            }
        }
        let lps_from_index = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]];
        let desc = VolumeDesc { dims, samples: VolumeSamples::U8(&samples), lps_from_index };
        let caps = Capabilities { norm16: true, float32_filterable: true };
        PreparedVolume::prepare(&desc, caps, VolumeBudget { max_dimension: 256, max_bytes: 1 << 24 }).expect("volume")
    }

    #[test]
    fn brick_ranges_equal_brute_force_min_max() {
        let v = volume([13, 9, 17], |i, j, k| ((i * 7 + j * 13 + k * 29) % 251) as u8);
        let bricks = VolumeBricks::of(&v);
        assert_eq!(bricks.dims, [2, 2, 3]);
        for (lo, hi) in [([0, 0, 0], [12, 8, 16]), ([3, 2, 9], [9, 8, 10]), ([-4, -1, 15], [0, 0, 40])] {
            let (mut a, mut b) = (f32::INFINITY, f32::NEG_INFINITY);
            for k in lo[2].max(0)..=hi[2].min(16) {
                for j in lo[1].max(0)..=hi[1].min(8) {
                    for i in lo[0].max(0)..=hi[0].min(12) {
                        let t = v.texels.normalised((i + 13 * (j + 9 * k)) as usize);
                        (a, b) = (a.min(t), b.max(t));
                    }
                }
            }
            let [r0, r1] = bricks.range(lo, hi).expect("non-empty");
            // The bricks are a superset of the voxels: the range contains the voxels' range.
            assert!(r0 <= a && r1 >= b, "{lo:?}..{hi:?}: {r0}..{r1} vs {a}..{b}");
        }
        assert_eq!(bricks.range([0, 0, 0], [12, 8, 16]), Some([0.0, 250.0 / 255.0]));
        assert!(bricks.range([5, 0, 0], [4, 8, 16]).is_none());
    }

    #[test]
    fn opacity_table_answers_ranges_like_a_scan() {
        let clear = [1.0, 1.0, 1.0, 0.0];
        let tf = TransferFunction::from_points("t", &[(0.0, [1.0; 4]), (0.3, clear), (0.5, clear), (0.6, [1.0; 4])]);
        let table = OpacityTable::new(&tf.entries);
        for lo in -3i64..260 {
            for hi in [lo - 1, lo, lo + 1, lo + 40, 300] {
                let scan = (lo.max(0)..=hi.min(255)).any(|i| tf.entries[i as usize][3] > 0);
                assert_eq!(table.any_opaque(lo, hi), scan, "{lo}..={hi}");
            }
        }
        let style = LayerStyle {
            window: Window::from_range(0.0, 255.0),
            tf_row: 0,
            opacity_scale: 1.0,
            visible: true,
            iso_value: 0.0,
        };
        // Values in the transparent gap (entries 77..=127 have zero opacity).
        assert!((77..=127).all(|i| tf.entries[i][3] == 0) && tf.entries[76][3] > 0 && tf.entries[128][3] > 0);
        assert!(!may_be_opaque(&table, &style, 0.0, 255.0, [90.0 / 255.0, 120.0 / 255.0]));
        assert!(may_be_opaque(&table, &style, 0.0, 255.0, [90.0 / 255.0, 130.0 / 255.0]));
        assert!(!may_be_opaque(&table, &LayerStyle { opacity_scale: 0.0, ..style }, 0.0, 255.0, [0.0, 1.0]));
    }

    #[test]
    fn lattice_covers_the_box_with_at_most_the_cap() {
        let l = BrickLattice::covering((Vec3::ZERO, Vec3::new(100.0, 10.0, 3.0)), 0.5);
        assert_eq!(l.dims[0], MAX_REF_BRICKS_PER_AXIS);
        assert!(l.brick_mm * l.dims[0] as f32 >= 100.0 && l.brick_mm * l.dims[1] as f32 >= 10.0);
        let l = BrickLattice::covering((Vec3::ZERO, Vec3::new(16.0, 8.0, 8.0)), 4.0);
        assert_eq!(l.dims, [4, 2, 2]);
    }
}
