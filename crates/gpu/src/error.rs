//! [`GpuError`]: what can go wrong when setting up the device, uploading data or rendering.

/// Errors of the `gpu` crate.
#[derive(Debug, thiserror::Error)]
pub enum GpuError {
    /// No adapter: no GPU driver at all (install `mesa-vulkan-drivers` for lavapipe, or try `WGPU_BACKEND=gl`).
    #[error(
        "no GPU adapter available ({0}); install a Vulkan driver (Debian: mesa-vulkan-drivers, the lavapipe CPU \
         driver) or GL/EGL (libegl1 libegl-mesa0 libgl1-mesa-dri with WGPU_BACKEND=gl)"
    )]
    NoAdapter(String),
    #[error("the adapter refused the device: {0}")]
    RequestDevice(#[from] wgpu::RequestDeviceError),
    /// The device lacks a limit the pass needs.
    #[error("the device does not support this pass: {0}")]
    Unsupported(String),
    /// Caller data that cannot be rendered (wrong sizes, singular matrices, empty volumes).
    #[error("invalid input: {0}")]
    InvalidInput(String),
    /// wgpu reported asynchronous (uncaptured) errors; each distinct message is reported once.
    #[error("wgpu reported {} error(s): {}", .0.len(), .0.join("; "))]
    Wgpu(Vec<String>),
    #[error("reading the image back failed: {0}")]
    Readback(String),
    /// The caller's progress callback asked to stop (the export checks it after each slab).
    #[error("cancelled after {slices_done} of {slices_total} slices")]
    Cancelled { slices_done: usize, slices_total: usize },
}

pub type Result<T, E = GpuError> = std::result::Result<T, E>;
