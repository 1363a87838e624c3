//! Compute pipelines from embedded SPIR-V. Descriptor layouts and workgroup size are read
//! from the SPIR-V (reflection), so Rust never restates what a shader declares; what a pass
//! binds is checked against that, binding by binding.

use std::collections::BTreeMap;
use std::sync::Arc;

use ash::vk;

use super::context::{Gpu, Shared};
use super::error::{GpuError, Result, VkContext};

/// An embedded, compiled shader.
#[derive(Clone, Copy, Debug)]
pub struct ShaderSource {
    /// `<solver>/<pass>`, matching `glsl/<solver>/<pass>.comp`.
    pub name: &'static str,
    pub spirv: &'static [u8],
}

/// What a binding holds, as declared by the shader.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BindingKind {
    StorageBuffer,
    StorageImage,
}

impl BindingKind {
    fn vk(self) -> vk::DescriptorType {
        match self {
            BindingKind::StorageBuffer => vk::DescriptorType::STORAGE_BUFFER,
            BindingKind::StorageImage => vk::DescriptorType::STORAGE_IMAGE,
        }
    }
}

/// The interface of a shader, read from its SPIR-V.
#[derive(Clone, Debug)]
pub struct Reflection {
    pub bindings: BTreeMap<u32, (BindingKind, String)>,
    pub push_constant_bytes: usize,
    pub workgroup_size: [u32; 3],
}

/// Read descriptor bindings (set 0 only), push-constant size and workgroup size.
pub fn reflect(src: &ShaderSource) -> Result<Reflection> {
    let err = |reason: String| GpuError::Shader { shader: src.name.into(), reason };
    let r = rspirv_reflect::Reflection::new_from_spirv(src.spirv).map_err(|e| err(format!("invalid SPIR-V: {e}")))?;
    let sets = r.get_descriptor_sets().map_err(|e| err(format!("reflection failed: {e}")))?;
    let mut bindings = BTreeMap::new();
    for (set, b) in sets {
        if set != 0 {
            return Err(err(format!("uses descriptor set {set}; passes bind set 0 only (push descriptors)")));
        }
        for (index, info) in b {
            let kind = match info.ty {
                rspirv_reflect::DescriptorType::STORAGE_BUFFER => BindingKind::StorageBuffer,
                rspirv_reflect::DescriptorType::STORAGE_IMAGE => BindingKind::StorageImage,
                other => {
                    return Err(err(format!(
                        "binding {index} has descriptor type {other:?}; only storage buffers and images are supported"
                    )))
                }
            };
            bindings.insert(index, (kind, info.name));
        }
    }
    let push_constant_bytes = r
        .get_push_constant_range()
        .map_err(|e| err(format!("push-constant reflection failed: {e}")))?
        .map(|p| (p.offset + p.size) as usize)
        .unwrap_or(0);
    let (x, y, z) = r
        .get_compute_group_size()
        .ok_or_else(|| err("no LocalSize execution mode (a fixed local_size is required)".into()))?;
    Ok(Reflection { bindings, push_constant_bytes, workgroup_size: [x, y, z] })
}

/// A specialization constant value (`layout(constant_id = N) const ...`), 4 bytes each.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Spec {
    Bool(bool),
    U32(u32),
    I32(i32),
    F32(f32),
}

impl Spec {
    fn bytes(self) -> [u8; 4] {
        match self {
            Spec::Bool(b) => (b as u32).to_ne_bytes(),
            Spec::U32(v) => v.to_ne_bytes(),
            Spec::I32(v) => v.to_ne_bytes(),
            Spec::F32(v) => v.to_ne_bytes(),
        }
    }
}

pub(crate) struct PipelineInner {
    pub shared: Arc<Shared>,
    pub pipeline: vk::Pipeline,
    pub layout: vk::PipelineLayout,
    pub set_layout: vk::DescriptorSetLayout,
}

impl Drop for PipelineInner {
    fn drop(&mut self) {
        unsafe {
            let d = &self.shared.device;
            d.destroy_pipeline(self.pipeline, None);
            d.destroy_pipeline_layout(self.layout, None);
            d.destroy_descriptor_set_layout(self.set_layout, None);
        }
    }
}

/// A compute pipeline plus the reflected interface passes are checked against.
#[derive(Clone)]
pub struct Pipeline {
    pub(crate) inner: Arc<PipelineInner>,
    pub name: &'static str,
    pub reflection: Reflection,
}

impl Pipeline {
    /// Workgroups needed to cover `n` invocations along each axis.
    pub fn groups_for(&self, n: [u32; 3]) -> [u32; 3] {
        let w = self.reflection.workgroup_size;
        [n[0].div_ceil(w[0]), n[1].div_ceil(w[1]), n[2].div_ceil(w[2])]
    }
}

impl Gpu {
    /// Build a compute pipeline with the given specialization constants `(constant_id, value)`.
    pub fn pipeline(&self, src: &ShaderSource, spec: &[(u32, Spec)]) -> Result<Pipeline> {
        let reflection = reflect(src)?;
        let s = &self.shared;
        let d = &s.device;
        let words = ash::util::read_spv(&mut std::io::Cursor::new(src.spirv))
            .map_err(|e| GpuError::Shader { shader: src.name.into(), reason: format!("cannot read SPIR-V: {e}") })?;
        let module = unsafe { d.create_shader_module(&vk::ShaderModuleCreateInfo::default().code(&words), None) }
            .vk("vkCreateShaderModule")?;
        let layout_bindings: Vec<vk::DescriptorSetLayoutBinding> = reflection
            .bindings
            .iter()
            .map(|(i, (k, _))| {
                vk::DescriptorSetLayoutBinding::default()
                    .binding(*i)
                    .descriptor_type(k.vk())
                    .descriptor_count(1)
                    .stage_flags(vk::ShaderStageFlags::COMPUTE)
            })
            .collect();
        let set_layout = unsafe {
            d.create_descriptor_set_layout(
                &vk::DescriptorSetLayoutCreateInfo::default()
                    .flags(vk::DescriptorSetLayoutCreateFlags::PUSH_DESCRIPTOR_KHR)
                    .bindings(&layout_bindings),
                None,
            )
        }
        .vk("vkCreateDescriptorSetLayout")?;
        let ranges = [vk::PushConstantRange {
            stage_flags: vk::ShaderStageFlags::COMPUTE,
            offset: 0,
            size: reflection.push_constant_bytes as u32,
        }];
        let set_layouts = [set_layout];
        let mut layout_info = vk::PipelineLayoutCreateInfo::default().set_layouts(&set_layouts);
        if reflection.push_constant_bytes > 0 {
            layout_info = layout_info.push_constant_ranges(&ranges);
        }
        let layout = unsafe { d.create_pipeline_layout(&layout_info, None) }.vk("vkCreatePipelineLayout")?;
        let entries: Vec<vk::SpecializationMapEntry> = spec
            .iter()
            .enumerate()
            .map(|(i, (id, _))| vk::SpecializationMapEntry { constant_id: *id, offset: (i * 4) as u32, size: 4 })
            .collect();
        let data: Vec<u8> = spec.iter().flat_map(|(_, v)| v.bytes()).collect();
        let spec_info = vk::SpecializationInfo::default().map_entries(&entries).data(&data);
        let stage = vk::PipelineShaderStageCreateInfo::default()
            .stage(vk::ShaderStageFlags::COMPUTE)
            .module(module)
            .name(c"main")
            .specialization_info(&spec_info);
        let info = vk::ComputePipelineCreateInfo::default().stage(stage).layout(layout);
        let pipeline = unsafe { d.create_compute_pipelines(vk::PipelineCache::null(), &[info], None) };
        unsafe { d.destroy_shader_module(module, None) };
        let pipeline = pipeline.map_err(|(_, e)| GpuError::Vk { call: "vkCreateComputePipelines", result: e })?[0];
        s.name_object(pipeline, src.name);
        Ok(Pipeline {
            inner: Arc::new(PipelineInner { shared: s.clone(), pipeline, layout, set_layout }),
            name: src.name,
            reflection,
        })
    }
}
