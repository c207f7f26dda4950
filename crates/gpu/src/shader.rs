//! What a pass declares about the WGSL it runs, gathered in one [`ShaderInterface`] per pass: the file
//! ([`ShaderSource`], with its entry points by [`Stage`]), the layouts of the `#[repr(C)]` Rust twins of its WGSL
//! structs ([`StructLayout`], built by `layout!`), its bind slots ([`BindSlot`]) and the WGSL constants that have a
//! Rust twin ([`WgslConstant`]). The registry ([`crate::shaders`]) lists every interface, and `tests/shaders.rs`
//! checks each against naga's reading of the WGSL: the file validates, the entry points exist, each struct has the
//! same size and field offsets, each slot's `@group(G) @binding(N)` is the one the Rust code binds, and each
//! constant has the Rust value.

/// A pipeline stage, as the registry records entry points.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stage {
    Vertex,
    Fragment,
    Compute,
}

/// One WGSL file.
#[derive(Clone, Copy, Debug)]
pub struct ShaderSource {
    /// Label, also used in error messages.
    pub name: &'static str,
    /// Path relative to the workspace root.
    pub path: &'static str,
    pub source: &'static str,
    pub entry_points: &'static [(&'static str, Stage)],
}

impl ShaderSource {
    #[must_use]
    pub fn create_module(&self, device: &wgpu::Device) -> wgpu::ShaderModule {
        device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some(self.name),
            source: wgpu::ShaderSource::Wgsl(self.source.into()),
        })
    }

    /// The name of the entry point for `stage` (the first one listed).
    #[must_use]
    pub fn entry_point(&self, stage: Stage) -> Option<&'static str> {
        self.entry_points.iter().find(|(_, s)| *s == stage).map(|(n, _)| *n)
    }
}

/// A Rust struct's layout, to compare with naga's layout of the WGSL struct of the same name.
#[derive(Clone, Copy, Debug)]
pub struct StructLayout {
    pub name: &'static str,
    pub size: usize,
    /// `(field name, byte offset)`, in declaration order; padding fields (`_pad*`) are left out.
    pub fields: &'static [(&'static str, usize)],
}

/// `layout!(Type { field, field, … })`: the [`StructLayout`] of a Rust struct from `size_of` and `offset_of!`.
macro_rules! layout {
    ($ty:ident { $($field:ident),* $(,)? }) => {
        $crate::shader::StructLayout {
            name: stringify!($ty),
            size: std::mem::size_of::<$ty>(),
            fields: &[$((stringify!($field), std::mem::offset_of!($ty, $field))),*],
        }
    };
}
pub(crate) use layout;

/// One resource slot of a pass: `@group(group) @binding(binding) var … name` in its WGSL. The Rust code builds its
/// bind group layouts and bind groups from these constants, so each number is written once on the Rust side and
/// checked against the WGSL by the registry's test.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BindSlot {
    pub group: u32,
    pub binding: u32,
    /// The WGSL global variable bound there.
    pub name: &'static str,
}

impl BindSlot {
    #[must_use]
    pub const fn new(group: u32, binding: u32, name: &'static str) -> Self {
        Self { group, binding, name }
    }

    /// The layout entry of this slot.
    #[must_use]
    pub fn layout_entry(self, visibility: wgpu::ShaderStages, ty: wgpu::BindingType) -> wgpu::BindGroupLayoutEntry {
        wgpu::BindGroupLayoutEntry { binding: self.binding, visibility, ty, count: None }
    }

    /// The bind group entry that puts `resource` in this slot.
    #[must_use]
    pub fn entry(self, resource: wgpu::BindingResource<'_>) -> wgpu::BindGroupEntry<'_> {
        wgpu::BindGroupEntry { binding: self.binding, resource }
    }
}

/// A module-scope WGSL `const` whose value the Rust code uses too (a flag, a threshold).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WgslConstant {
    pub name: &'static str,
    /// The Rust value, exact for every u32 and f32.
    pub value: f64,
}

impl WgslConstant {
    #[must_use]
    pub const fn u32(name: &'static str, value: u32) -> Self {
        Self { name, value: value as f64 }
    }

    #[must_use]
    pub const fn f32(name: &'static str, value: f32) -> Self {
        Self { name, value: value as f64 }
    }
}

/// Everything one pass declares about its WGSL (module docs).
#[derive(Clone, Copy, Debug)]
pub struct ShaderInterface {
    /// The pass, for messages.
    pub pass: &'static str,
    pub shader: ShaderSource,
    /// The WGSL structs that have a `#[repr(C)]` Rust twin in this pass.
    pub uniform_structs: &'static [StructLayout],
    /// Every slot the pass binds.
    pub slots: &'static [BindSlot],
    /// The WGSL constants that have a Rust twin.
    pub constants: &'static [WgslConstant],
}
