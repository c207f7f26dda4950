//! Building blocks the compute passes share ([`crate::ControlEvalPass`], [`crate::PrefilterPass`],
//! [`crate::PickPass`], the GPU export): compute-stage bindings, and a pipeline with its layout.

use crate::shader::BindSlot;

/// The layout entry of `slot`, visible to the compute stage.
pub(crate) fn binding(slot: BindSlot, ty: wgpu::BindingType) -> wgpu::BindGroupLayoutEntry {
    slot.layout_entry(wgpu::ShaderStages::COMPUTE, ty)
}

/// A uniform buffer holding a `T`.
pub(crate) fn uniform<T>() -> wgpu::BindingType {
    wgpu::BindingType::Buffer {
        ty: wgpu::BufferBindingType::Uniform,
        has_dynamic_offset: false,
        min_binding_size: wgpu::BufferSize::new(std::mem::size_of::<T>() as u64),
    }
}

/// A storage buffer of at least `min_bytes` (`None`: any size).
pub(crate) fn storage(read_only: bool, min_bytes: Option<u64>) -> wgpu::BindingType {
    wgpu::BindingType::Buffer {
        ty: wgpu::BufferBindingType::Storage { read_only },
        has_dynamic_offset: false,
        min_binding_size: min_bytes.and_then(wgpu::BufferSize::new),
    }
}

/// An unfilterable float texture read with `textureLoad`.
pub(crate) fn texture(view_dimension: wgpu::TextureViewDimension) -> wgpu::BindingType {
    wgpu::BindingType::Texture {
        sample_type: wgpu::TextureSampleType::Float { filterable: false },
        view_dimension,
        multisampled: false,
    }
}

/// A bind group layout of `entries`, named `label`.
pub(crate) fn layout(
    device: &wgpu::Device,
    label: &str,
    entries: &[wgpu::BindGroupLayoutEntry],
) -> wgpu::BindGroupLayout {
    device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor { label: Some(label), entries })
}

/// The compute pipeline of `entry_point` in `module` (`None`: the module's only compute entry point) over the bind
/// groups `layouts` (group i = `layouts[i]`), named `label`.
pub(crate) fn pipeline(
    device: &wgpu::Device,
    label: &str,
    module: &wgpu::ShaderModule,
    entry_point: Option<&str>,
    layouts: &[&wgpu::BindGroupLayout],
) -> wgpu::ComputePipeline {
    pipeline_with(device, label, module, entry_point, layouts, &[])
}

/// [`pipeline`] with the WGSL overrides `constants` set.
pub(crate) fn pipeline_with(
    device: &wgpu::Device,
    label: &str,
    module: &wgpu::ShaderModule,
    entry_point: Option<&str>,
    layouts: &[&wgpu::BindGroupLayout],
    constants: &[(&str, f64)],
) -> wgpu::ComputePipeline {
    let bind_group_layouts: Vec<Option<&wgpu::BindGroupLayout>> = layouts.iter().copied().map(Some).collect();
    let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
        label: Some(label),
        bind_group_layouts: &bind_group_layouts,
        immediate_size: 0,
    });
    device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
        label: Some(label),
        layout: Some(&pipeline_layout),
        module,
        entry_point,
        compilation_options: wgpu::PipelineCompilationOptions { constants, ..Default::default() },
        cache: None,
    })
}
