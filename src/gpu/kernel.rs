use super::context::Inner;
use super::shaders::{check_push_layout, PushConstants, ShaderInfo};
use super::{vk_check, Context, GpuError, Result};
use ash::vk;
use std::marker::PhantomData;
use std::sync::Arc;

/// How to build a [`Kernel`].
#[derive(Clone, Debug)]
pub(crate) struct KernelDesc {
    /// The reflected shader (`gpu::shaders::<name>::INFO`).
    pub shader: &'static ShaderInfo,
    /// Workgroup size (x) for shaders that declare `local_size_x_id`; `None` uses the device's
    /// [`DeviceCaps::workgroup_size`](super::DeviceCaps::workgroup_size).
    pub workgroup_size: Option<u32>,
    /// Other specialization constants by name.
    pub constants: Vec<(&'static str, u32)>,
}

impl KernelDesc {
    /// A description with the device's default workgroup size and no other constants.
    pub(crate) fn new(shader: &'static ShaderInfo) -> Self {
        KernelDesc { shader, workgroup_size: None, constants: Vec::new() }
    }
    /// Sets a specialization constant by name.
    pub(crate) fn constant(mut self, name: &'static str, value: u32) -> Self {
        self.constants.push((name, value));
        self
    }
}

/// A compute pipeline whose layout comes from the shader's reflection, with push constants of type `P` (checked
/// against the shader's block at creation).
///
/// Kernels address their arrays by buffer device address (passed in the push constants), so they have no
/// descriptor sets and no limit from `maxStorageBufferRange`.
pub(crate) struct Kernel<P: PushConstants> {
    ctx: Arc<Inner>,
    pub(crate) pipeline: vk::Pipeline,
    pub(crate) layout: vk::PipelineLayout,
    workgroup_size: u32,
    shader: &'static ShaderInfo,
    _push: PhantomData<fn(P)>,
}

impl<P: PushConstants> std::fmt::Debug for Kernel<P> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Kernel")
            .field("shader", &self.shader.name)
            .field("workgroup_size", &self.workgroup_size)
            .finish()
    }
}

impl<P: PushConstants> Kernel<P> {
    /// Builds the pipeline, through the context's pipeline cache ([`Context::pipeline_cache`]) and with the
    /// engine's allocation callbacks, if any.
    ///
    /// Some drivers compile a pipeline only at its first dispatch (lavapipe compiles with LLVM then): time a
    /// kernel's work only after it ran once (see `VulkanBackend::warmup_ms`).
    pub(crate) fn new(ctx: &Context, desc: &KernelDesc) -> Result<Self> {
        let info = desc.shader;
        check_push_layout::<P>(info).map_err(GpuError::Layout)?;
        if !info.bindings.is_empty() {
            return Err(GpuError::Layout(format!(
                "shader {} declares descriptor bindings; engine kernels address buffers by device address",
                info.name
            )));
        }
        let caps = ctx.caps();
        if info.push_constant_size > caps.max_push_constants_size {
            return Err(GpuError::Limit {
                what: format!("push constants of {}", info.name),
                requested: info.push_constant_size as u64,
                limit: caps.max_push_constants_size as u64,
            });
        }
        let mut workgroup_size = info.local_size[0];
        let mut entries = Vec::new();
        let mut data: Vec<u32> = Vec::new();
        if let Some(id) = info.local_size_spec_ids[0] {
            workgroup_size = desc.workgroup_size.unwrap_or_else(|| caps.workgroup_size());
            entries.push(vk::SpecializationMapEntry { constant_id: id, offset: 0, size: 4 });
            data.push(workgroup_size);
        }
        if workgroup_size > caps.max_workgroup_size[0] || workgroup_size > caps.max_workgroup_invocations {
            return Err(GpuError::Limit {
                what: format!("workgroup size of {}", info.name),
                requested: workgroup_size as u64,
                limit: caps.max_workgroup_size[0].min(caps.max_workgroup_invocations) as u64,
            });
        }
        for (name, value) in &desc.constants {
            let id = info.spec_id(name).ok_or_else(|| {
                GpuError::Layout(format!("shader {} has no specialization constant {name}", info.name))
            })?;
            entries.push(vk::SpecializationMapEntry { constant_id: id, offset: 4 * data.len() as u32, size: 4 });
            data.push(*value);
        }
        let dev = ctx.device();
        let alloc = ctx.inner.alloc();
        let code_info = vk::ShaderModuleCreateInfo::default().code(info.spirv);
        // SAFETY: valid SPIR-V produced by shaderc at build time.
        let module = vk_check("vkCreateShaderModule", unsafe { dev.create_shader_module(&code_info, alloc) })?;
        let ranges = [vk::PushConstantRange::default()
            .stage_flags(vk::ShaderStageFlags::COMPUTE)
            .offset(0)
            .size(info.push_constant_size)];
        let layout_info = if info.push_constant_size > 0 {
            vk::PipelineLayoutCreateInfo::default().push_constant_ranges(&ranges)
        } else {
            vk::PipelineLayoutCreateInfo::default()
        };
        // SAFETY: valid device.
        let layout = match unsafe { dev.create_pipeline_layout(&layout_info, alloc) } {
            Ok(l) => l,
            Err(result) => {
                // SAFETY: module of ours, unused.
                unsafe { dev.destroy_shader_module(module, alloc) };
                return Err(GpuError::Vk { call: "vkCreatePipelineLayout", result });
            }
        };
        let bytes: &[u8] = bytemuck::cast_slice(&data);
        let spec = vk::SpecializationInfo::default().map_entries(&entries).data(bytes);
        let entry = std::ffi::CString::new(info.entry).map_err(|e| GpuError::Layout(e.to_string()))?;
        let stage = vk::PipelineShaderStageCreateInfo::default()
            .stage(vk::ShaderStageFlags::COMPUTE)
            .module(module)
            .name(&entry)
            .specialization_info(&spec);
        let pinfo = [vk::ComputePipelineCreateInfo::default().stage(stage).layout(layout)];
        // SAFETY: valid module and layout; the cache is the context's own or the engine's (alive and not externally
        // synchronized, per `Context::from_raw`'s contract), or null.
        let pipeline = unsafe { dev.create_compute_pipelines(ctx.inner.pipeline_cache, &pinfo, alloc) };
        // SAFETY: the module is no longer needed once the pipeline exists (or failed).
        unsafe { dev.destroy_shader_module(module, alloc) };
        let pipeline = match pipeline {
            Ok(p) => p[0],
            Err((_, result)) => {
                // SAFETY: layout of ours, unused.
                unsafe { dev.destroy_pipeline_layout(layout, alloc) };
                return Err(GpuError::Vk { call: "vkCreateComputePipelines", result });
            }
        };
        Ok(Kernel { ctx: ctx.inner.clone(), pipeline, layout, workgroup_size, shader: info, _push: PhantomData })
    }

    /// Invocations per workgroup.
    pub(crate) fn workgroup_size(&self) -> u32 {
        self.workgroup_size
    }

    /// The shader's reflection.
    pub(crate) fn shader(&self) -> &'static ShaderInfo {
        self.shader
    }
}

impl<P: PushConstants> Drop for Kernel<P> {
    fn drop(&mut self) {
        // SAFETY: pipeline and layout of this device; callers wait for submissions before dropping kernels.
        unsafe {
            let alloc = self.ctx.alloc();
            self.ctx.device.destroy_pipeline(self.pipeline, alloc);
            self.ctx.device.destroy_pipeline_layout(self.layout, alloc);
        }
    }
}
