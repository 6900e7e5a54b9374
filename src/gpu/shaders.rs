//! Compiled shaders, their reflection and the Rust structs they share with the host, generated from `glsl/` and
//! shipped in `src/gpu/generated/` (`shaders.rs` and `spv/<name>.spv`), so that building the crate compiles no
//! GLSL. The cargo feature `compile-glsl` recompiles them with shaderc in `build.rs` and fails the build when the
//! shipped files differ; `MESHCHAR_WRITE_SHADERS=1` rewrites them instead.
//!
//! Each shader is a module (`shaders::bounds`, ...) with `SPIRV` (the words), `INFO` (a [`ShaderInfo`]) and, when
//! it has push constants, `Push`: the `#[repr(C)]` mirror of its push-constant block, generated from the
//! reflection. GLSL structs the host shares ([`BvhNode`]) are generated once at this level, and the layout
//! constants of `glsl/include/bvh.glsl` and `glsl/include/layout.glsl` in [`layout`]. Pipeline layouts are built
//! from `INFO`, never from hand-written duplicates; the push-constant type of a kernel is checked against
//! `INFO.push_constant_members` (names, offsets, sizes and types) by [`check_push_layout`] when the kernel is
//! created, and by a test for every shader.

/// Kind of a descriptor binding.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum DescriptorKind {
    /// `buffer` block (storage buffer).
    StorageBuffer,
    /// `uniform` block.
    UniformBuffer,
}

/// One descriptor binding of a shader.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct BindingInfo {
    /// Variable name in GLSL.
    pub name: &'static str,
    /// Descriptor set.
    pub set: u32,
    /// Binding number.
    pub binding: u32,
    /// Kind.
    pub kind: DescriptorKind,
    /// Array count (1 for a plain binding).
    pub count: u32,
}

/// One member of the push-constant block or of a struct.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct MemberInfo {
    /// Member name in GLSL.
    pub name: &'static str,
    /// Byte offset.
    pub offset: u32,
    /// Byte size.
    pub size: u32,
    /// The Rust type that mirrors it (`u32`, `i32`, `f32`, `u64` for `uint64_t` and buffer references, `[f32; 3]`
    /// for a `vec3`, arrays as `[T; N]`, a struct by its name; `?` for what has no `#[repr(C)]` mirror).
    pub ty: &'static str,
}

/// One specialization constant.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct SpecConstantInfo {
    /// Name in GLSL.
    pub name: &'static str,
    /// `constant_id`.
    pub id: u32,
}

/// A struct declared in a shader with explicit member offsets (a buffer block or a struct inside one).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct StructInfo {
    /// Struct (or block) name in GLSL.
    pub name: &'static str,
    /// Members in declaration order.
    pub members: &'static [MemberInfo],
}

/// Everything the engine needs to know about a compiled compute shader.
#[derive(Clone, Copy, Debug)]
pub(crate) struct ShaderInfo {
    /// File stem (`glsl/<name>.comp`).
    pub name: &'static str,
    /// Entry point.
    pub entry: &'static str,
    /// SPIR-V words.
    pub spirv: &'static [u32],
    /// Default local size.
    pub local_size: [u32; 3],
    /// Specialization ids of the local size dimensions, where the shader uses `local_size_*_id`.
    pub local_size_spec_ids: [Option<u32>; 3],
    /// Descriptor bindings, sorted by (set, binding).
    pub bindings: &'static [BindingInfo],
    /// Size of the push-constant block in bytes (0 when there is none).
    pub push_constant_size: u32,
    /// Members of the push-constant block in declaration order.
    pub push_constant_members: &'static [MemberInfo],
    /// Specialization constants.
    pub spec_constants: &'static [SpecConstantInfo],
    /// Structs with explicit layouts (buffer blocks and the structs inside them).
    pub structs: &'static [StructInfo],
}

impl ShaderInfo {
    /// The id of the specialization constant named `name`.
    pub(crate) fn spec_id(&self, name: &str) -> Option<u32> {
        self.spec_constants.iter().find(|s| s.name == name).map(|s| s.id)
    }
}

/// One field of a Rust mirror of a shader struct, as [`PushConstants::members`] lists it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub(crate) struct FieldLayout {
    /// Field name (the GLSL member name).
    pub name: &'static str,
    /// Byte offset.
    pub offset: usize,
    /// Byte size.
    pub size: usize,
    /// The field's type, spelled as [`MemberInfo::ty`].
    pub ty: String,
}

/// A type that can be a field of a Rust mirror of a shader struct: its spelling, compared with [`MemberInfo::ty`].
pub(crate) trait FieldType {
    /// The type's name (`u32`, `[f32; 3]`, a struct's name).
    fn type_name() -> String;
}

macro_rules! field_types {
    ($($t:ty),*) => { $(impl FieldType for $t { fn type_name() -> String { stringify!($t).into() } })* };
}
field_types!(u8, u16, u32, u64, i8, i16, i32, i64, f32, f64);

impl<T: FieldType, const N: usize> FieldType for [T; N] {
    fn type_name() -> String {
        format!("[{}; {N}]", T::type_name())
    }
}

/// A Rust struct that mirrors a shader's push-constant block or another struct of a shader (a BVH node, say).
///
/// The generated mirrors (`shaders::<name>::Push`, [`BvhNode`]) implement it; a hand-written one does with
/// `push_layout!`, which lists the members so the engine can compare their names, offsets,
/// sizes and types with the reflected block ([`check_push_layout`]) or struct ([`check_struct_layout`]).
pub(crate) trait PushConstants: bytemuck::Pod {
    /// Every field but padding, in declaration order.
    fn members() -> Vec<FieldLayout>;
}

/// Implements [`PushConstants`] (and [`FieldType`], with the struct's name) for a `#[repr(C)]` struct by listing
/// its fields, which must carry the GLSL member names.
macro_rules! push_layout {
    ($ty:ty { $($field:ident),* $(,)? }) => {
        impl $crate::gpu::shaders::PushConstants for $ty {
            fn members() -> Vec<$crate::gpu::shaders::FieldLayout> {
                fn field<T: $crate::gpu::shaders::FieldType>(
                    name: &'static str,
                    offset: usize,
                    _: impl Fn(&$ty) -> &T,
                ) -> $crate::gpu::shaders::FieldLayout {
                    $crate::gpu::shaders::FieldLayout {
                        name,
                        offset,
                        size: std::mem::size_of::<T>(),
                        ty: <T as $crate::gpu::shaders::FieldType>::type_name(),
                    }
                }
                vec![$(field(stringify!($field), std::mem::offset_of!($ty, $field), |s: &$ty| &s.$field)),*]
            }
        }
        impl $crate::gpu::shaders::FieldType for $ty {
            fn type_name() -> String {
                stringify!($ty).into()
            }
        }
    };
}
pub(crate) use push_layout;

fn same(rust: &FieldLayout, glsl: &MemberInfo) -> bool {
    rust.name == glsl.name
        && rust.offset == glsl.offset as usize
        && rust.size == glsl.size as usize
        && rust.ty == glsl.ty
}

fn describe(rust: &[FieldLayout], glsl: &[MemberInfo]) -> String {
    let r: Vec<_> = rust.iter().map(|f| (f.name, f.offset, f.size, f.ty.as_str())).collect();
    let g: Vec<_> = glsl.iter().map(|m| (m.name, m.offset as usize, m.size as usize, m.ty)).collect();
    format!("Rust {r:?} against GLSL {g:?}")
}

/// Compares a Rust push-constant struct with the reflected block: same member names in the same order, same
/// offsets, sizes and types, and a total size that covers the block.
pub(crate) fn check_push_layout<P: PushConstants>(info: &ShaderInfo) -> Result<(), String> {
    let rust = P::members();
    let glsl = info.push_constant_members;
    let describe = || format!("shader {}: {}", info.name, describe(&rust, glsl));
    if rust.len() != glsl.len() {
        return Err(format!("member count differs: {}", describe()));
    }
    for (r, m) in rust.iter().zip(glsl) {
        if !same(r, m) {
            return Err(format!("member {} differs: {}", m.name, describe()));
        }
    }
    if std::mem::size_of::<P>() < info.push_constant_size as usize {
        return Err(format!(
            "Rust struct is {} bytes, block is {}: {}",
            std::mem::size_of::<P>(),
            info.push_constant_size,
            describe()
        ));
    }
    Ok(())
}

/// Compares a Rust struct with the shader struct named `glsl_name`: same member names, offsets, sizes and types.
pub(crate) fn check_struct_layout<P: PushConstants>(info: &ShaderInfo, glsl_name: &str) -> Result<(), String> {
    let s = info
        .structs
        .iter()
        .find(|s| s.name == glsl_name)
        .ok_or_else(|| format!("shader {} has no struct {glsl_name}", info.name))?;
    let rust = P::members();
    if rust.len() != s.members.len() || !rust.iter().zip(s.members).all(|(r, m)| same(r, m)) {
        return Err(format!("shader {} struct {glsl_name}: {}", info.name, describe(&rust, s.members)));
    }
    Ok(())
}

/// The SPIR-V words of a shipped `.spv` file (little-endian words), at compile time.
const fn spirv_words<const N: usize>(bytes: &[u8]) -> [u32; N] {
    assert!(bytes.len() == 4 * N, "a shipped .spv file does not have the word count of generated/shaders.rs");
    let mut words = [0u32; N];
    let mut i = 0;
    while i < N {
        words[i] = u32::from_le_bytes([bytes[4 * i], bytes[4 * i + 1], bytes[4 * i + 2], bytes[4 * i + 3]]);
        i += 1;
    }
    words
}

include!("generated/shaders.rs");
