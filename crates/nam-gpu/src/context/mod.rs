//! Device plumbing: lazily created pipelines, buffers, dispatch recording, submission and
//! readback. The `wgpu::Device`/`Queue` are passed in by the caller (engines own them).
//!
//! This file holds the [`GpuContext`] itself, its pipelines and dispatches (recording,
//! submission, workgroup counts); `memory.rs` its buffers and textures (creation, upload,
//! readback).

use std::collections::HashMap;
use std::sync::{Arc, Mutex, PoisonError};

use crate::error::{GpuError, Result};
use crate::shaders::{Binding, Family, Precision};

mod memory;

pub(crate) use memory::{DeviceBuffer, DeviceTexture};
use memory::{texel_format, texture_desc};

/// Compute workgroup counts beyond this per dimension are split into a second dimension
/// (WebGPU's default `max_compute_workgroups_per_dimension`).
pub(crate) const MAX_GROUPS_PER_DIM: u32 = 65_535;

/// Identifies one compiled pipeline: family, entry point, precision, pipeline constants.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub(crate) struct PipelineKey {
    pub family: Family,
    pub entry: &'static str,
    pub precision: Precision,
    pub constants: Vec<(&'static str, u32)>,
}

#[derive(Debug)]
pub(crate) struct Pipeline {
    pub pipeline: wgpu::ComputePipeline,
    pub layout: wgpu::BindGroupLayout,
}

/// One recorded compute dispatch (pipeline + bound resources + workgroup counts).
#[derive(Debug)]
pub(crate) struct Dispatch {
    pipeline: Arc<Pipeline>,
    bind_group: wgpu::BindGroup,
    groups: [u32; 3],
}

/// One bound resource of a dispatch.
#[derive(Debug, Clone, Copy)]
pub(crate) enum Res<'a> {
    Buf(&'a wgpu::Buffer),
    Tex(&'a wgpu::TextureView),
}

/// Which matmul entry point runs the MLP layers.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MatmulVariant {
    /// 64x64 tiles staged through workgroup memory (GPUs).
    Tiled,
    /// Barrier-free 4x4 register tiles straight from storage (CPU adapters without subgroups).
    Direct,
    /// Texture operands, 16x16 blocks per 8-invocation subgroup with `subgroupBroadcast`
    /// (CPU adapters such as llvmpipe with `Features::SUBGROUP` and subgroups of >= 8).
    /// The render MLP and the U-Net's convolutions (`conv_tex.wgsl`, implicit GEMMs of the
    /// same shape) have texture plans; standalone products use [`MatmulVariant::Direct`].
    Texture,
}

/// Owns the device handles, the lazily built pipelines and shared helper buffers.
#[derive(Debug)]
pub struct GpuContext {
    device: wgpu::Device,
    queue: wgpu::Queue,
    pipelines: Mutex<HashMap<PipelineKey, Arc<Pipeline>>>,
    matmul: MatmulVariant,
    /// Bound where a kernel's optional input is unused (bias, norm, residual).
    dummy: wgpu::Buffer,
    /// 1x1 storage textures (f32, f16) bound where a kernel's texture output is unused.
    dummy_tex: [wgpu::TextureView; 2],
}

/// Pops `scope` (blocking): the validation or out-of-memory error it caught, if any.
fn pop_scope(scope: wgpu::ErrorScopeGuard) -> Option<wgpu::Error> {
    pollster::block_on(scope.pop())
}

impl GpuContext {
    /// Wraps a caller-owned device and queue (cheap clones of wgpu handles).
    ///
    /// `adapter_type` picks kernel variants: `DeviceType::Cpu` (lavapipe) gets the texture +
    /// subgroup matmul when the device has `Features::SUBGROUP` with subgroups of at least 8
    /// invocations, else the barrier-free one; everything else the workgroup-tiled one.
    pub fn new(
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        adapter_type: wgpu::DeviceType,
    ) -> Result<Self> {
        let scope = device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
        let dummy = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("nam-gpu dummy"),
            size: 16,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::UNIFORM,
            mapped_at_creation: false,
        });
        let dummy_tex = [Precision::F32, Precision::F16].map(|p| {
            device
                .create_texture(&texture_desc("nam-gpu dummy texture", 1, 1, p))
                .create_view(&wgpu::TextureViewDescriptor::default())
        });
        if let Some(e) = pop_scope(scope) {
            return Err(GpuError::Device {
                during: "dummy buffer",
                message: e.to_string(),
            });
        }
        // The texture kernel broadcasts within its 8-invocation workgroup.
        let subgroups = device.features().contains(wgpu::Features::SUBGROUP)
            && device.adapter_info().subgroup_min_size >= 8;
        Ok(Self {
            device: device.clone(),
            queue: queue.clone(),
            pipelines: Mutex::new(HashMap::new()),
            matmul: match (adapter_type == wgpu::DeviceType::Cpu, subgroups) {
                (true, true) => MatmulVariant::Texture,
                (true, false) => MatmulVariant::Direct,
                (false, _) => MatmulVariant::Tiled,
            },
            dummy,
            dummy_tex,
        })
    }

    /// The wrapped device.
    pub fn device(&self) -> &wgpu::Device {
        &self.device
    }

    /// The wrapped queue.
    pub fn queue(&self) -> &wgpu::Queue {
        &self.queue
    }

    /// Fails unless the device can run `precision` kernels.
    pub fn check_precision(&self, precision: Precision) -> Result<()> {
        if precision == Precision::F16
            && !self.device.features().contains(wgpu::Features::SHADER_F16)
        {
            return Err(GpuError::MissingFeature {
                feature: "SHADER_F16",
                needed_for: "f16 kernels",
            });
        }
        Ok(())
    }

    /// The matmul variant in use.
    pub fn matmul_variant(&self) -> MatmulVariant {
        self.matmul
    }

    /// Overrides the matmul variant (for comparisons; all compute the same product).
    /// `Texture` needs `Features::SUBGROUP`; without it pipeline creation fails.
    pub fn set_matmul_variant(&mut self, v: MatmulVariant) {
        self.matmul = v;
    }

    pub(crate) fn dummy(&self) -> &wgpu::Buffer {
        &self.dummy
    }

    /// A 1x1 storage texture of `precision`'s format, for unused texture outputs.
    pub(crate) fn dummy_tex(&self, precision: Precision) -> &wgpu::TextureView {
        match precision {
            Precision::F32 => &self.dummy_tex[0],
            Precision::F16 => &self.dummy_tex[1],
        }
    }

    /// Largest storage binding in elements of `precision` the device allows.
    pub(crate) fn max_binding_elems(&self, precision: Precision) -> u64 {
        let limits = self.device.limits();
        limits
            .max_storage_buffer_binding_size
            .min(limits.max_buffer_size)
            / precision.elem_bytes()
    }

    /// Returns the pipeline for `key`, compiling it on first use. Validation errors of the
    /// module or pipeline are captured by an error scope and returned.
    pub(crate) fn pipeline(&self, key: &PipelineKey) -> Result<Arc<Pipeline>> {
        let mut cache = self
            .pipelines
            .lock()
            .unwrap_or_else(PoisonError::into_inner);
        if let Some(p) = cache.get(key) {
            return Ok(p.clone());
        }
        self.check_precision(key.precision)?;
        let name = format!(
            "{}::{} ({:?})",
            key.family.file_name(),
            key.entry,
            key.precision
        );
        let source = key
            .family
            .source(key.precision)
            .ok_or_else(|| GpuError::Pipeline {
                kernel: name.clone(),
                message: "no variant for this precision".into(),
            })?;
        let scope = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let module = self
            .device
            .create_shader_module(wgpu::ShaderModuleDescriptor {
                label: Some(&name),
                source: wgpu::ShaderSource::Wgsl(source),
            });
        let entries: Vec<wgpu::BindGroupLayoutEntry> = key
            .family
            .bindings()
            .iter()
            .enumerate()
            .map(|(i, b)| wgpu::BindGroupLayoutEntry {
                binding: i as u32,
                visibility: wgpu::ShaderStages::COMPUTE,
                ty: match b {
                    Binding::Uniform => wgpu::BindingType::Buffer {
                        ty: wgpu::BufferBindingType::Uniform,
                        has_dynamic_offset: false,
                        min_binding_size: None,
                    },
                    Binding::Read | Binding::ReadWrite => wgpu::BindingType::Buffer {
                        ty: wgpu::BufferBindingType::Storage {
                            read_only: *b == Binding::Read,
                        },
                        has_dynamic_offset: false,
                        min_binding_size: None,
                    },
                    Binding::Texture => wgpu::BindingType::Texture {
                        sample_type: wgpu::TextureSampleType::Float { filterable: false },
                        view_dimension: wgpu::TextureViewDimension::D2,
                        multisampled: false,
                    },
                    Binding::StorageTexture => wgpu::BindingType::StorageTexture {
                        access: wgpu::StorageTextureAccess::WriteOnly,
                        format: texel_format(key.precision),
                        view_dimension: wgpu::TextureViewDimension::D2,
                    },
                },
                count: None,
            })
            .collect();
        let layout = self
            .device
            .create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some(&name),
                entries: &entries,
            });
        let pipeline_layout = self
            .device
            .create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                label: Some(&name),
                bind_group_layouts: &[Some(&layout)],
                immediate_size: 0,
            });
        let constants: Vec<(&str, f64)> = key
            .constants
            .iter()
            .map(|&(k, v)| (k, f64::from(v)))
            .collect();
        let pipeline = self
            .device
            .create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(&name),
                layout: Some(&pipeline_layout),
                module: &module,
                entry_point: Some(key.entry),
                compilation_options: wgpu::PipelineCompilationOptions {
                    constants: &constants,
                    zero_initialize_workgroup_memory: false,
                },
                cache: None,
            });
        if let Some(e) = pop_scope(scope) {
            return Err(GpuError::Pipeline {
                kernel: name,
                message: e.to_string(),
            });
        }
        let p = Arc::new(Pipeline { pipeline, layout });
        cache.insert(key.clone(), p.clone());
        Ok(p)
    }

    /// Records a dispatch of `key` with `uniform` bytes as binding 0 (when the family has one)
    /// followed by `bound` (buffers and texture views) in binding order.
    pub(crate) fn dispatch(
        &self,
        key: &PipelineKey,
        uniform: Option<&[u8]>,
        bound: &[Res<'_>],
        groups: [u32; 3],
    ) -> Result<Dispatch> {
        let pipeline = self.pipeline(key)?;
        let ubuf = uniform.map(|u| self.uniform(u)).transpose()?;
        let mut resources: Vec<Res<'_>> = Vec::with_capacity(bound.len() + 1);
        if let Some(u) = &ubuf {
            resources.push(Res::Buf(u));
        }
        resources.extend_from_slice(bound);
        if resources.len() != key.family.bindings().len() {
            return Err(GpuError::Device {
                during: "bind group",
                message: format!(
                    "{}::{} takes {} bindings, got {}",
                    key.family.file_name(),
                    key.entry,
                    key.family.bindings().len(),
                    resources.len()
                ),
            });
        }
        let entries: Vec<wgpu::BindGroupEntry<'_>> = resources
            .iter()
            .enumerate()
            .map(|(i, r)| wgpu::BindGroupEntry {
                binding: i as u32,
                resource: match r {
                    Res::Buf(b) => b.as_entire_binding(),
                    Res::Tex(v) => wgpu::BindingResource::TextureView(v),
                },
            })
            .collect();
        let scope = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let bind_group = self.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some(key.entry),
            layout: &pipeline.layout,
            entries: &entries,
        });
        if let Some(e) = pop_scope(scope) {
            return Err(GpuError::Device {
                during: "bind group",
                message: format!("{}: {e}", key.entry),
            });
        }
        Ok(Dispatch {
            pipeline,
            bind_group,
            groups,
        })
    }

    /// Encodes `dispatches` in order into one compute pass and submits it. wgpu inserts the
    /// barriers between dependent dispatches. Validation errors come back as `Err`.
    pub(crate) fn run(&self, dispatches: &[Dispatch]) -> Result<()> {
        let scope = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let mut encoder = self
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("nam-gpu"),
            });
        {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("nam-gpu"),
                timestamp_writes: None,
            });
            for d in dispatches {
                pass.set_pipeline(&d.pipeline.pipeline);
                pass.set_bind_group(0, &d.bind_group, &[]);
                pass.dispatch_workgroups(d.groups[0], d.groups[1], d.groups[2]);
            }
        }
        self.queue.submit([encoder.finish()]);
        if let Some(e) = pop_scope(scope) {
            return Err(GpuError::Device {
                during: "submission",
                message: e.to_string(),
            });
        }
        Ok(())
    }

    /// Waits until all submitted work has finished.
    pub fn wait(&self) -> Result<()> {
        self.device
            .poll(wgpu::PollType::wait_indefinitely())
            .map(|_| ())
            .map_err(|e| GpuError::Device {
                during: "poll",
                message: e.to_string(),
            })
    }
}

/// Workgroup counts for `n` invocations of `wg`-wide 1-D workgroups, split over x and y so
/// that neither exceeds [`MAX_GROUPS_PER_DIM`] (shaders use `i = x + y * groups_x * wg`).
pub(crate) fn linear_groups(n: u64, wg: u64) -> Result<[u32; 3]> {
    let groups = n.div_ceil(wg).max(1);
    let max = u64::from(MAX_GROUPS_PER_DIM);
    let x = groups.min(max);
    let y = groups.div_ceil(x);
    if y > max {
        return Err(GpuError::Size {
            what: "dispatch",
            reason: format!("{n} invocations exceed {max}² workgroups"),
        });
    }
    Ok([x as u32, y as u32, 1])
}

/// Ceil-divided workgroup count for one dimension, checked against the dispatch limit.
pub(crate) fn groups_1d(n: u32, wg: u32) -> Result<u32> {
    let g = n.div_ceil(wg).max(1);
    if g > MAX_GROUPS_PER_DIM {
        return Err(GpuError::Size {
            what: "dispatch",
            reason: format!("{n} invocations in one dimension exceed the workgroup limit"),
        });
    }
    Ok(g)
}
