//! [`TexturePool`]: textures reused by descriptor, so that per-frame and per-resize targets (the app's 3-D view and
//! slice views, re-created as windows resize and frames come and go) do not allocate GPU memory each time (rerun's
//! `WgpuResourcePools` do the same).
//!
//! A texture is keyed by everything that makes two textures interchangeable ([`TextureKey`]: size, format, usage,
//! dimension, mip levels, sample count). [`TexturePool::acquire`] hands out a free texture with the key or creates
//! one; [`TexturePool::release`] takes it back for the next acquire. [`TexturePool::trim`] frees what has been idle
//! for a number of [`TexturePool::begin_frame`] calls. [`crate::RenderTarget::from_pool`] draws its two textures from a
//! pool and gives them back when dropped.

use std::collections::HashMap;
use std::sync::{Arc, Mutex, PoisonError};

/// What makes two textures interchangeable.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct TextureKey {
    pub size: [u32; 3],
    pub format: wgpu::TextureFormat,
    pub usage: wgpu::TextureUsages,
    pub dimension: wgpu::TextureDimension,
    pub mip_level_count: u32,
    pub sample_count: u32,
}

impl TextureKey {
    /// The key of a single-sample, single-mip 2-D texture.
    #[must_use]
    pub fn d2(width: u32, height: u32, format: wgpu::TextureFormat, usage: wgpu::TextureUsages) -> Self {
        Self {
            size: [width, height, 1],
            format,
            usage,
            dimension: wgpu::TextureDimension::D2,
            mip_level_count: 1,
            sample_count: 1,
        }
    }
}

/// Counts, for tests and the app's status bar.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PoolStats {
    /// Textures created over the pool's life.
    pub created: u64,
    /// Acquires served from the free list.
    pub reused: u64,
    /// Textures now waiting in the free list.
    pub free: usize,
}

#[derive(Debug, Default)]
struct Inner {
    /// Free textures by key, with the frame they were released in.
    free: HashMap<TextureKey, Vec<(wgpu::Texture, u64)>>,
    frame: u64,
    stats: PoolStats,
}

/// A pool of textures keyed by descriptor (module docs). Cheap to clone: clones share the pool.
#[derive(Clone, Debug)]
pub struct TexturePool {
    device: wgpu::Device,
    inner: Arc<Mutex<Inner>>,
}

impl TexturePool {
    #[must_use]
    pub fn new(device: &wgpu::Device) -> Self {
        Self { device: device.clone(), inner: Arc::default() }
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Inner> {
        // A panic while holding the lock leaves only a free list behind: still consistent.
        self.inner.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// A texture with `key`: a released one when there is one, else a new one labelled `label`.
    #[must_use]
    pub fn acquire(&self, key: TextureKey, label: &str) -> wgpu::Texture {
        {
            let mut inner = self.lock();
            if let Some((texture, _)) = inner.free.get_mut(&key).and_then(Vec::pop) {
                inner.stats.reused += 1;
                return texture;
            }
            inner.stats.created += 1;
        }
        self.device.create_texture(&wgpu::TextureDescriptor {
            label: Some(label),
            size: wgpu::Extent3d { width: key.size[0], height: key.size[1], depth_or_array_layers: key.size[2] },
            mip_level_count: key.mip_level_count,
            sample_count: key.sample_count,
            dimension: key.dimension,
            format: key.format,
            usage: key.usage,
            view_formats: &[],
        })
    }

    /// Gives `texture` back for a later [`Self::acquire`] of the same key.
    pub fn release(&self, texture: wgpu::Texture) {
        let key = TextureKey {
            size: [texture.width(), texture.height(), texture.depth_or_array_layers()],
            format: texture.format(),
            usage: texture.usage(),
            dimension: texture.dimension(),
            mip_level_count: texture.mip_level_count(),
            sample_count: texture.sample_count(),
        };
        let mut inner = self.lock();
        let frame = inner.frame;
        inner.free.entry(key).or_default().push((texture, frame));
    }

    /// Marks the start of a frame (for [`Self::trim`]).
    pub fn begin_frame(&self) {
        self.lock().frame += 1;
    }

    /// Destroys free textures released more than `max_idle_frames` frames ago; returns how many.
    #[must_use = "the number of textures freed"]
    pub fn trim(&self, max_idle_frames: u64) -> usize {
        let mut inner = self.lock();
        let now = inner.frame;
        let mut freed = 0;
        for list in inner.free.values_mut() {
            list.retain(|(texture, released)| {
                let keep = now.saturating_sub(*released) <= max_idle_frames;
                if !keep {
                    texture.destroy();
                    freed += 1;
                }
                keep
            });
        }
        inner.free.retain(|_, list| !list.is_empty());
        freed
    }

    #[must_use]
    pub fn stats(&self) -> PoolStats {
        let inner = self.lock();
        PoolStats { free: inner.free.values().map(Vec::len).sum(), ..inner.stats }
    }
}
