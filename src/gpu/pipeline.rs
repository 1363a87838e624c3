//! Compute pipelines from embedded SPIR-V. Descriptor layouts and workgroup size are read
//! from the SPIR-V (reflection), so Rust never restates what a shader declares; what a pass
//! binds is checked against that, binding by binding.

use std::collections::{BTreeMap, HashMap};
use std::sync::Arc;

use ash::vk;
use serde::Serialize;

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
    /// A uniform block: a table every invocation reads at the same addresses (llvmpipe loads it
    /// once for the SIMD batch where a storage buffer's read is a loop over the lanes,
    /// docs/lavapipe.md). Bound to a [`crate::gpu::Buffer`] as a storage buffer is; at most
    /// `max_uniform_buffer_range` bytes of it are read.
    UniformBuffer,
    StorageImage,
}

impl BindingKind {
    fn vk(self) -> vk::DescriptorType {
        match self {
            BindingKind::StorageBuffer => vk::DescriptorType::STORAGE_BUFFER,
            BindingKind::UniformBuffer => vk::DescriptorType::UNIFORM_BUFFER,
            BindingKind::StorageImage => vk::DescriptorType::STORAGE_IMAGE,
        }
    }
}

/// The interface of a shader, read from its SPIR-V.
#[derive(Clone, Debug)]
pub struct Reflection {
    pub bindings: BTreeMap<u32, (BindingKind, String)>,
    pub push_constant_bytes: usize,
    /// The workgroup size as compiled (a `local_size_*_id` dimension shows its default).
    pub workgroup_size: [u32; 3],
    /// Specialization constants (`layout(constant_id = N)`), by id.
    pub spec_constants: BTreeMap<u32, SpecKind>,
}

/// The type of a specialization constant, as the shader declares it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum SpecKind {
    Bool,
    U32,
    I32,
    F32,
}

/// What Rust knows of a compute kernel: the shader and the interface facts its passes rely on
/// (push-constant block size, the specialization constants it sets). Each is checked against
/// the SPIR-V: the spec ids whenever a pipeline is built ([`Gpu::pipeline`]), the push size at
/// every submission (`Pass::check`), and both for every kernel of every solver by a
/// reflection test without a device ([`Kernel::check`]).
#[derive(Clone, Copy, Debug)]
pub struct Kernel {
    pub shader: ShaderSource,
    /// `size_of` the `#[repr(C)]` push-constant struct its passes push (0: none).
    pub push_bytes: usize,
    /// Every specialization constant its pipelines set, with its type.
    pub spec: &'static [(u32, SpecKind)],
}

impl Kernel {
    /// Check the declared facts against the shader's reflection.
    pub fn check(&self) -> Result<()> {
        let err = |reason: String| GpuError::Shader { shader: self.shader.name.into(), reason };
        let r = reflect(&self.shader)?;
        if r.push_constant_bytes != self.push_bytes {
            return Err(err(format!(
                "Rust pushes {} bytes of push constants but the shader declares {}",
                self.push_bytes, r.push_constant_bytes
            )));
        }
        let declared: BTreeMap<u32, SpecKind> = self.spec.iter().copied().collect();
        if declared != r.spec_constants {
            return Err(err(format!(
                "Rust sets specialization constants {declared:?} but the shader declares {:?}",
                r.spec_constants
            )));
        }
        Ok(())
    }
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
                rspirv_reflect::DescriptorType::UNIFORM_BUFFER => BindingKind::UniformBuffer,
                rspirv_reflect::DescriptorType::STORAGE_IMAGE => BindingKind::StorageImage,
                other => {
                    return Err(err(format!(
                        "binding {index} has descriptor type {other:?}; only storage and uniform buffers and storage images are supported"
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
    let spec_constants = spec_constants(&r.0).map_err(err)?;
    Ok(Reflection { bindings, push_constant_bytes, workgroup_size: [x, y, z], spec_constants })
}

/// Every `SpecId` decoration of the module and the type of the constant it decorates.
fn spec_constants(m: &rspirv_reflect::rspirv::dr::Module) -> std::result::Result<BTreeMap<u32, SpecKind>, String> {
    use rspirv_reflect::rspirv::dr::Operand;
    use rspirv_reflect::spirv::{Decoration, Op};
    let mut out = BTreeMap::new();
    for a in m.annotations.iter().filter(|a| a.class.opcode == Op::Decorate) {
        let (
            Some(Operand::IdRef(target)),
            Some(Operand::Decoration(Decoration::SpecId)),
            Some(Operand::LiteralBit32(id)),
        ) = (a.operands.first(), a.operands.get(1), a.operands.get(2))
        else {
            continue;
        };
        let constant = m
            .types_global_values
            .iter()
            .find(|i| i.result_id == Some(*target))
            .ok_or_else(|| format!("SpecId {id} decorates %{target}, which is not a global constant"))?;
        let kind = match constant.class.opcode {
            Op::SpecConstantTrue | Op::SpecConstantFalse => SpecKind::Bool,
            Op::SpecConstant => {
                let ty = constant.result_type.ok_or_else(|| format!("spec constant {id} has no type"))?;
                let ty = m.types_global_values.iter().find(|i| i.result_id == Some(ty));
                match ty.map(|t| (t.class.opcode, t.operands.as_slice())) {
                    Some((Op::TypeInt, [Operand::LiteralBit32(32), Operand::LiteralBit32(0)])) => SpecKind::U32,
                    Some((Op::TypeInt, [Operand::LiteralBit32(32), Operand::LiteralBit32(1)])) => SpecKind::I32,
                    Some((Op::TypeFloat, [Operand::LiteralBit32(32), ..])) => SpecKind::F32,
                    other => return Err(format!("spec constant {id} has an unsupported type {other:?}")),
                }
            }
            other => return Err(format!("SpecId {id} decorates an {other:?}, not a specialization constant")),
        };
        out.insert(*id, kind);
    }
    Ok(out)
}

/// A specialization constant value (`layout(constant_id = N) const ...`), 4 bytes each.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
#[serde(untagged)]
pub enum Spec {
    Bool(bool),
    U32(u32),
    I32(i32),
    F32(f32),
}

impl Spec {
    pub fn kind(self) -> SpecKind {
        match self {
            Spec::Bool(_) => SpecKind::Bool,
            Spec::U32(_) => SpecKind::U32,
            Spec::I32(_) => SpecKind::I32,
            Spec::F32(_) => SpecKind::F32,
        }
    }

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

/// A pipeline a render asked for: built (its host milliseconds) or taken from those this
/// process built before (`reused`). `Gpu::take_pipeline_records`.
#[derive(Clone, Debug, Serialize)]
pub struct PipelineRecord {
    pub shader: &'static str,
    /// Its specialization constants, `(constant_id, value)`.
    pub spec: Vec<(u32, Spec)>,
    pub ms: f64,
    pub reused: bool,
    /// Why the driver specialised it rather than the host (src/gpu/specialize.rs): `None`
    /// where the host did (every kernel of ours, unless [`super::GpuOptions::driver_specialization`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub driver_specialized: Option<String>,
}

/// The pipelines this process built, by shader and specialization: a pipeline is built once
/// per process (`animate`, `report`, `bench` and the tests render many times on one device),
/// and the records of what each render asked for.
#[derive(Default)]
pub(crate) struct PipelineMemo {
    built: HashMap<(&'static str, Vec<u8>), Pipeline>,
    records: Vec<PipelineRecord>,
}

/// A pipeline built, why the driver specialised it (`None`: the host did), its build's host ms.
type Built = (Pipeline, Option<String>, f64);

fn memo_key(kernel: &Kernel, spec: &[(u32, Spec)]) -> (&'static str, Vec<u8>) {
    let mut bytes = Vec::with_capacity(spec.len() * 8);
    for (id, v) in spec {
        bytes.extend_from_slice(&id.to_le_bytes());
        bytes.extend_from_slice(&v.bytes());
    }
    (kernel.shader.name, bytes)
}

impl Gpu {
    /// Build a compute pipeline of `kernel` with the given specialization constants
    /// `(constant_id, value)`: exactly the ones the kernel declares, each declared by the
    /// shader with the same type (a mismatch is an error naming the shader, never a silent
    /// default). A pipeline this process built before with the same constants is reused.
    pub fn pipeline(&self, kernel: &Kernel, spec: &[(u32, Spec)]) -> Result<Pipeline> {
        Ok(self.pipelines(&[(kernel, spec)])?.remove(0))
    }

    /// [`Gpu::pipeline`] for several at once: those not built yet are built in parallel on
    /// the host's threads (`vkCreateComputePipelines` is thread-safe, the pipeline cache
    /// internally synchronised), so a render's setup waits for its slowest pipeline rather than
    /// for their sum.
    pub fn pipelines(&self, wanted: &[(&Kernel, &[(u32, Spec)])]) -> Result<Vec<Pipeline>> {
        use rayon::prelude::*;
        let started = std::time::Instant::now();
        let keys: Vec<_> = wanted.iter().map(|(k, s)| memo_key(k, s)).collect();
        let mut found: Vec<Option<Pipeline>> = {
            let memo = self.pipeline_memo.lock().expect("pipeline memo lock");
            keys.iter().map(|k| memo.built.get(k).cloned()).collect()
        };
        // Each missing (shader, constants) once, even if asked for twice.
        let mut missing: Vec<usize> = Vec::new();
        for (i, f) in found.iter().enumerate() {
            if f.is_none() && !missing.iter().any(|j| keys[*j] == keys[i]) {
                missing.push(i);
            }
        }
        let built: Vec<(usize, Result<Built>)> = missing
            .par_iter()
            .map(|&i| {
                let t = std::time::Instant::now();
                (i, self.build(wanted[i].0, wanted[i].1).map(|(p, why)| (p, why, t.elapsed().as_secs_f64() * 1e3)))
            })
            .collect();
        let mut memo = self.pipeline_memo.lock().expect("pipeline memo lock");
        let mut new = 0u64;
        for (i, r) in built {
            let (p, driver_specialized, ms) = r?;
            memo.records.push(PipelineRecord {
                shader: p.name,
                spec: wanted[i].1.to_vec(),
                ms,
                reused: false,
                driver_specialized,
            });
            memo.built.insert(keys[i].clone(), p.clone());
            found[i] = Some(p);
            new += 1;
        }
        let mut out = Vec::with_capacity(wanted.len());
        for (i, f) in found.into_iter().enumerate() {
            let p = match f {
                Some(p) => {
                    if !missing.contains(&i) {
                        memo.records.push(PipelineRecord {
                            shader: p.name,
                            spec: wanted[i].1.to_vec(),
                            ms: 0.0,
                            reused: true,
                            driver_specialized: None,
                        });
                    }
                    p
                }
                None => memo.built.get(&keys[i]).cloned().expect("built above"),
            };
            out.push(p);
        }
        drop(memo);
        if new > 0 {
            self.host.lock().expect("host times lock").add_count(super::host::HostKind::Pipelines, new, started);
        }
        Ok(out)
    }

    /// Take the records of the pipelines asked for so far ([`PipelineRecord`]).
    pub fn take_pipeline_records(&self) -> Vec<PipelineRecord> {
        std::mem::take(&mut self.pipeline_memo.lock().expect("pipeline memo lock").records)
    }

    /// Forget the pipelines built so far (the next request builds again, through the pipeline
    /// cache): `report` measures pipeline creation warm and cold with it.
    pub fn forget_pipelines(&self) {
        self.pipeline_memo.lock().expect("pipeline memo lock").built.clear();
    }

    /// The pipeline, and why it was not specialised on the host (`None`: it was).
    fn build(&self, kernel: &Kernel, spec: &[(u32, Spec)]) -> Result<(Pipeline, Option<String>)> {
        let src = &kernel.shader;
        let reflection = reflect(src)?;
        let given: BTreeMap<u32, SpecKind> = spec.iter().map(|(id, v)| (*id, v.kind())).collect();
        let declared: BTreeMap<u32, SpecKind> = kernel.spec.iter().copied().collect();
        if given != declared || given != reflection.spec_constants || given.len() != spec.len() {
            return Err(GpuError::Shader {
                shader: src.name.into(),
                reason: format!(
                    "pipeline built with specialization constants {given:?}; the kernel declares {declared:?} and the \
                        shader {:?}",
                    reflection.spec_constants
                ),
            });
        }
        let s = &self.shared;
        let d = &s.device;
        let words = ash::util::read_spv(&mut std::io::Cursor::new(src.spirv))
            .map_err(|e| GpuError::Shader { shader: src.name.into(), reason: format!("cannot read SPIR-V: {e}") })?;
        // Specialised on the host (src/gpu/specialize.rs says why), unless asked not to or the
        // pass cannot: then the driver specialises the kernel as compiled, the same program.
        let host = if s.driver_specialization {
            Err("asked for (GpuOptions::driver_specialization, SCATTERLAB_SPECIALIZE=driver)".to_string())
        } else {
            super::specialize::specialize(&words, spec)
        };
        let (code, spec) = match &host {
            Ok(specialized) => (specialized.as_slice(), &[][..]),
            Err(_) => (words.as_slice(), spec),
        };
        let module = unsafe { d.create_shader_module(&vk::ShaderModuleCreateInfo::default().code(code), None) }
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
        let cache = s.pipeline_cache.lock().expect("pipeline cache lock").cache;
        let pipeline = unsafe { d.create_compute_pipelines(cache, &[info], None) };
        unsafe { d.destroy_shader_module(module, None) };
        let pipeline = pipeline.map_err(|(_, e)| GpuError::Vk { call: "vkCreateComputePipelines", result: e })?[0];
        s.name_object(pipeline, src.name);
        Ok((
            Pipeline {
                inner: Arc::new(PipelineInner { shared: s.clone(), pipeline, layout, set_layout }),
                name: src.name,
                reflection,
            },
            host.err(),
        ))
    }
}
