//! [`GpuContext`]: the wgpu device and queue, what they can do, and the uncaptured errors they reported.
//!
//! A headless device requests the optional features its caller names (the passes of this crate name theirs in
//! [`crate::headless`]), each only when the adapter has it, and the adapter's own limits (so that large 3-D textures
//! are allowed). Works on lavapipe (Vulkan on the CPU), on GL (`WGPU_BACKEND=gl`) and on real GPUs.

use std::collections::BTreeSet;
use std::sync::{Arc, Mutex, PoisonError};

use crate::error::{GpuError, Result};

/// Optional features the device has, as the upload code needs to know them.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Capabilities {
    /// `R16Unorm` textures (`TEXTURE_FORMAT_16BIT_NORM`).
    pub norm16: bool,
    /// Linear filtering of `R32Float` and `Rgba32Float` (`FLOAT32_FILTERABLE`).
    pub float32_filterable: bool,
}

impl Capabilities {
    #[must_use]
    pub fn from_features(features: wgpu::Features) -> Self {
        Self {
            norm16: features.contains(wgpu::Features::TEXTURE_FORMAT_16BIT_NORM),
            float32_filterable: features.contains(wgpu::Features::FLOAT32_FILTERABLE),
        }
    }

    /// True when every volume format this crate chooses can be filtered by the sampler; otherwise volumes are
    /// `R32Float` and the shader filters by hand (see [`crate::volume`]).
    #[must_use]
    pub fn volumes_filterable(&self) -> bool {
        self.norm16 || self.float32_filterable
    }
}

/// Which of the optional features a headless device may request ([`GpuContext::headless_requesting`]). Turning one
/// off exercises the fallback paths (the tests do this on lavapipe, which has both).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FeatureRequest {
    pub allow_norm16: bool,
    pub allow_float32_filterable: bool,
}

impl Default for FeatureRequest {
    fn default() -> Self {
        Self { allow_norm16: true, allow_float32_filterable: true }
    }
}

impl FeatureRequest {
    /// The features of `optional` to request from an adapter that offers `available`.
    #[must_use]
    pub fn features(&self, optional: wgpu::Features, available: wgpu::Features) -> wgpu::Features {
        let mut wanted = optional;
        if !self.allow_norm16 {
            wanted.remove(wgpu::Features::TEXTURE_FORMAT_16BIT_NORM);
        }
        if !self.allow_float32_filterable {
            wanted.remove(wgpu::Features::FLOAT32_FILTERABLE);
        }
        wanted & available
    }
}

/// Uncaptured wgpu errors, each distinct message kept once.
#[derive(Debug, Default)]
struct ErrorLog {
    seen: BTreeSet<String>,
    pending: Vec<String>,
}

/// The device, its queue and what they support. Cheap to share by reference; resources created from it
/// (volumes, renderers, draw data) borrow it only while they are created or used.
#[derive(Debug)]
pub struct GpuContext {
    pub adapter_info: wgpu::AdapterInfo,
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
    pub limits: wgpu::Limits,
    pub capabilities: Capabilities,
    /// `R32Float` can be a (write-only) storage texture: what [`crate::prefilter::PrefilterPass`] writes. From the
    /// adapter's `get_texture_format_features` in [`Self::headless_requesting`]; [`Self::from_device`] assumes it
    /// (the WebGPU core format table guarantees it), [`Self::with_r32float_storage`] overrides it.
    pub r32float_storage: bool,
    errors: Arc<Mutex<ErrorLog>>,
}

impl GpuContext {
    /// A device without a window: the adapter chosen by `WGPU_BACKEND`/`WGPU_ADAPTER_NAME`/`WGPU_POWER_PREF`
    /// (wgpu's environment variables) or the default one, with those of the `optional` features that `request`
    /// allows and the adapter has. [`GpuContext::headless`] names the features of this crate's passes.
    pub fn headless_requesting(optional: wgpu::Features, request: FeatureRequest) -> Result<Self> {
        let instance = wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env());
        let options = wgpu::RequestAdapterOptions {
            power_preference: wgpu::PowerPreference::from_env().unwrap_or_default(),
            ..Default::default()
        };
        let adapter =
            pollster::block_on(instance.request_adapter(&options)).map_err(|e| GpuError::NoAdapter(e.to_string()))?;
        let descriptor = wgpu::DeviceDescriptor {
            label: Some("warpbench-gpu"),
            required_features: request.features(optional, adapter.features()),
            required_limits: adapter.limits(),
            ..Default::default()
        };
        let (device, queue) = pollster::block_on(adapter.request_device(&descriptor))?;
        let r32float_storage = adapter
            .get_texture_format_features(wgpu::TextureFormat::R32Float)
            .allowed_usages
            .contains(wgpu::TextureUsages::STORAGE_BINDING);
        Ok(Self::from_device(adapter.get_info(), device, queue).with_r32float_storage(r32float_storage))
    }

    /// Wraps a device someone else created (the app's eframe device). Installs the uncaptured-error handler:
    /// errors are collected and returned once by [`Self::take_errors`] / [`Self::check_errors`] instead of panicking.
    #[must_use]
    pub fn from_device(adapter_info: wgpu::AdapterInfo, device: wgpu::Device, queue: wgpu::Queue) -> Self {
        let errors = Arc::new(Mutex::new(ErrorLog::default()));
        let sink = Arc::clone(&errors);
        device.on_uncaptured_error(Arc::new(move |e: wgpu::Error| {
            let message = e.to_string();
            let mut log = sink.lock().unwrap_or_else(PoisonError::into_inner);
            if log.seen.insert(message.clone()) {
                log.pending.push(message);
            }
        }));
        let limits = device.limits();
        let capabilities = Capabilities::from_features(device.features());
        Self { adapter_info, device, queue, limits, capabilities, r32float_storage: true, errors }
    }

    /// Sets [`Self::r32float_storage`] (from the adapter's `get_texture_format_features`).
    #[must_use]
    pub fn with_r32float_storage(mut self, supported: bool) -> Self {
        self.r32float_storage = supported;
        self
    }

    /// A buffer of `size` bytes for `usage`, not mapped.
    #[must_use]
    pub fn buffer(&self, label: &str, size: u64, usage: wgpu::BufferUsages) -> wgpu::Buffer {
        self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            size,
            usage,
            mapped_at_creation: false,
        })
    }

    /// A uniform buffer holding `value` (its write queued).
    #[must_use]
    pub fn uniform_buffer<T: bytemuck::Pod>(&self, label: &str, value: &T) -> wgpu::Buffer {
        let usage = wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST;
        let buffer = self.buffer(label, std::mem::size_of::<T>() as u64, usage);
        self.queue.write_buffer(&buffer, 0, bytemuck::bytes_of(value));
        buffer
    }

    /// A 3-D texture of `dims` texels of `format`, one mip level, for `usage`.
    #[must_use]
    pub fn texture_3d(
        &self,
        label: &str,
        dims: [u32; 3],
        format: wgpu::TextureFormat,
        usage: wgpu::TextureUsages,
    ) -> wgpu::Texture {
        self.device.create_texture(&wgpu::TextureDescriptor {
            label: Some(label),
            size: wgpu::Extent3d { width: dims[0], height: dims[1], depth_or_array_layers: dims[2] },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D3,
            format,
            usage,
            view_formats: &[],
        })
    }

    /// Errors reported since the last call; a message already returned once is not returned again.
    #[must_use]
    pub fn take_errors(&self) -> Vec<String> {
        std::mem::take(&mut self.errors.lock().unwrap_or_else(PoisonError::into_inner).pending)
    }

    /// `Err` with the new uncaptured errors, if any.
    pub fn check_errors(&self) -> Result<()> {
        let errors = self.take_errors();
        if errors.is_empty() { Ok(()) } else { Err(GpuError::Wgpu(errors)) }
    }

    /// Waits for all submitted work. GL can time out a single wait on long submissions (stack.md gotcha 2), so a
    /// timeout is retried a few times.
    pub fn wait_idle(&self) -> Result<()> {
        let mut last = None;
        for _ in 0..8 {
            match self.device.poll(wgpu::PollType::wait_indefinitely()) {
                Ok(_) => return Ok(()),
                Err(wgpu::PollError::Timeout) => last = Some(wgpu::PollError::Timeout),
                Err(e) => return Err(GpuError::Readback(e.to_string())),
            }
        }
        Err(GpuError::Readback(format!("device poll kept timing out: {last:?}")))
    }

    /// Copies `texture` (`width × height × layers` texels of `bytes_per_texel` bytes: a 2-D texture, a 2-D array
    /// or a 3-D texture) back to the CPU, tightly packed, rows top to bottom, layer after layer (the copy's
    /// 256-byte row alignment removed). Waits for the GPU.
    pub fn read_texture(&self, texture: &wgpu::Texture, size: [u32; 3], bytes_per_texel: u32) -> Result<Vec<u8>> {
        let [width, height, layers] = size;
        let row = bytes_per_texel * width;
        let padded = row.div_ceil(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT) * wgpu::COPY_BYTES_PER_ROW_ALIGNMENT;
        let rows = height * layers;
        let buffer = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("readback"),
            size: u64::from(padded) * u64::from(rows),
            usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
            mapped_at_creation: false,
        });
        let mut encoder =
            self.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("readback") });
        encoder.copy_texture_to_buffer(
            texture.as_image_copy(),
            wgpu::TexelCopyBufferInfo {
                buffer: &buffer,
                layout: wgpu::TexelCopyBufferLayout {
                    offset: 0,
                    bytes_per_row: Some(padded),
                    rows_per_image: Some(height),
                },
            },
            wgpu::Extent3d { width, height, depth_or_array_layers: layers },
        );
        self.queue.submit([encoder.finish()]);
        self.map_read(&buffer, buffer.size(), |mapped| {
            let mut out = Vec::with_capacity((row * rows) as usize);
            for r in 0..rows as usize {
                out.extend_from_slice(&mapped[r * padded as usize..r * padded as usize + row as usize]);
            }
            out
        })
    }

    /// Maps the first `bytes` of `buffer` (a `MAP_READ` buffer whose filling work is already submitted), waits for
    /// the GPU, hands the bytes to `read`, unmaps, and reports wgpu's errors. Every readback goes through here.
    pub fn map_read<T>(&self, buffer: &wgpu::Buffer, bytes: u64, read: impl FnOnce(&[u8]) -> T) -> Result<T> {
        let slice = buffer.slice(..bytes);
        let (tx, rx) = std::sync::mpsc::channel();
        slice.map_async(wgpu::MapMode::Read, move |r| {
            let _ = tx.send(r);
        });
        self.wait_idle()?;
        rx.recv().map_err(|e| GpuError::Readback(e.to_string()))?.map_err(|e| GpuError::Readback(e.to_string()))?;
        let out = {
            let mapped = slice.get_mapped_range().map_err(|e| GpuError::Readback(e.to_string()))?;
            read(&mapped)
        };
        buffer.unmap();
        self.check_errors()?;
        Ok(out)
    }

    /// Whether the adapter is a CPU driver (lavapipe, llvmpipe, WARP): fine for tests and small frames, slower than
    /// native CPU code for bulk work such as exports.
    #[must_use]
    pub fn is_cpu_driver(&self) -> bool {
        self.adapter_info.device_type == wgpu::DeviceType::Cpu
    }

    /// A one-line description of the adapter, e.g. "llvmpipe (LLVM 15.0.6, 256 bits) (Vulkan, Cpu)".
    #[must_use]
    pub fn describe(&self) -> String {
        format!("{} ({:?}, {:?})", self.adapter_info.name, self.adapter_info.backend, self.adapter_info.device_type)
    }
}
