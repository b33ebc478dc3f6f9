//! Device plumbing: lazily created pipelines, buffers, dispatch recording, submission and
//! readback. The `wgpu::Device`/`Queue` are passed in by the caller (engines own them).

use std::collections::HashMap;
use std::sync::{Arc, Mutex, PoisonError};

use crate::error::{GpuError, Result};
use crate::shaders::{Binding, Family, Precision};

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

/// A storage buffer plus the element count it was created for.
#[derive(Debug, Clone)]
pub(crate) struct DeviceBuffer {
    pub buffer: wgpu::Buffer,
    pub elems: u64,
    pub precision: Precision,
}

/// Which matmul entry point runs the MLP layers.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MatmulVariant {
    /// 64x64 tiles staged through workgroup memory (GPUs).
    Tiled,
    /// Barrier-free 4x4 register tiles straight from storage (CPU adapters such as llvmpipe).
    Direct,
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
}

fn pop_scope(scope: wgpu::ErrorScopeGuard) -> Option<wgpu::Error> {
    pollster::block_on(scope.pop())
}

impl GpuContext {
    /// Wraps a caller-owned device and queue (cheap clones of wgpu handles).
    ///
    /// `adapter_type` picks kernel variants: `DeviceType::Cpu` (lavapipe) gets the
    /// barrier-free matmul, everything else the workgroup-tiled one.
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
        if let Some(e) = pop_scope(scope) {
            return Err(GpuError::Device {
                during: "dummy buffer",
                message: e.to_string(),
            });
        }
        Ok(Self {
            device: device.clone(),
            queue: queue.clone(),
            pipelines: Mutex::new(HashMap::new()),
            matmul: if adapter_type == wgpu::DeviceType::Cpu {
                MatmulVariant::Direct
            } else {
                MatmulVariant::Tiled
            },
            dummy,
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

    /// Overrides the matmul variant (for comparisons; both compute the same product).
    pub fn set_matmul_variant(&mut self, v: MatmulVariant) {
        self.matmul = v;
    }

    pub(crate) fn dummy(&self) -> &wgpu::Buffer {
        &self.dummy
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

    fn create_buffer(
        &self,
        label: &str,
        size: u64,
        usage: wgpu::BufferUsages,
    ) -> Result<wgpu::Buffer> {
        let limits = self.device.limits();
        if size > limits.max_buffer_size {
            return Err(GpuError::Size {
                what: "buffer",
                reason: format!(
                    "{label}: {size} bytes exceed the device's max_buffer_size {}",
                    limits.max_buffer_size
                ),
            });
        }
        let scope = self.device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
        let buffer = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            // Copies and mapping work in 4-byte units; f16 buffers of odd length round up.
            size: size.max(4).next_multiple_of(4),
            usage,
            mapped_at_creation: false,
        });
        if let Some(e) = pop_scope(scope) {
            return Err(GpuError::Device {
                during: "buffer allocation",
                message: format!("{label}: {e}"),
            });
        }
        Ok(buffer)
    }

    /// A zero-initialised storage buffer of `elems` elements.
    pub(crate) fn storage(
        &self,
        label: &str,
        elems: u64,
        precision: Precision,
    ) -> Result<DeviceBuffer> {
        let max = self.max_binding_elems(precision);
        if elems > max {
            return Err(GpuError::Size {
                what: "tensor",
                reason: format!(
                    "{label}: {elems} elements exceed the device's storage binding limit of {max}"
                ),
            });
        }
        let buffer = self.create_buffer(
            label,
            elems * precision.elem_bytes(),
            wgpu::BufferUsages::STORAGE
                | wgpu::BufferUsages::COPY_DST
                | wgpu::BufferUsages::COPY_SRC,
        )?;
        Ok(DeviceBuffer {
            buffer,
            elems,
            precision,
        })
    }

    /// Encodes `data` in `precision` into bytes padded to a multiple of 4.
    fn encode(data: &[f32], precision: Precision) -> Vec<u8> {
        let mut bytes = match precision {
            Precision::F32 => bytemuck::cast_slice::<f32, u8>(data).to_vec(),
            Precision::F16 => {
                let h: Vec<half::f16> = data.iter().map(|&v| half::f16::from_f32(v)).collect();
                bytemuck::cast_slice::<half::f16, u8>(&h).to_vec()
            }
        };
        bytes.resize(bytes.len().next_multiple_of(4), 0);
        bytes
    }

    /// A storage buffer holding `data` converted to `precision`.
    pub(crate) fn upload(
        &self,
        label: &str,
        data: &[f32],
        precision: Precision,
    ) -> Result<DeviceBuffer> {
        let buf = self.storage(label, data.len() as u64, precision)?;
        self.write(&buf, 0, data)?;
        Ok(buf)
    }

    /// Writes `data` at element `offset` of `buf` (offset must keep 4-byte alignment).
    pub(crate) fn write(&self, buf: &DeviceBuffer, offset: u64, data: &[f32]) -> Result<()> {
        let byte_off = offset * buf.precision.elem_bytes();
        if !byte_off.is_multiple_of(4) || offset + data.len() as u64 > buf.elems {
            return Err(GpuError::Size {
                what: "write",
                reason: format!(
                    "{} elements at {offset} do not fit a buffer of {} aligned to 4 bytes",
                    data.len(),
                    buf.elems
                ),
            });
        }
        if data.is_empty() {
            return Ok(());
        }
        self.queue
            .write_buffer(&buf.buffer, byte_off, &Self::encode(data, buf.precision));
        Ok(())
    }

    /// A uniform buffer with the given 32-bit words (padded to 16 bytes).
    pub(crate) fn uniform(&self, words: &[u32]) -> Result<wgpu::Buffer> {
        let mut w = words.to_vec();
        w.resize(words.len().next_multiple_of(4).max(4), 0);
        let buf = self.create_buffer(
            "nam-gpu params",
            (w.len() * 4) as u64,
            wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
        )?;
        self.queue
            .write_buffer(&buf, 0, bytemuck::cast_slice::<u32, u8>(&w));
        Ok(buf)
    }

    /// Records a dispatch of `key` with `uniform` words as binding 0 (when the family has one)
    /// followed by `buffers` in binding order.
    pub(crate) fn dispatch(
        &self,
        key: &PipelineKey,
        uniform: Option<&[u32]>,
        buffers: &[&wgpu::Buffer],
        groups: [u32; 3],
    ) -> Result<Dispatch> {
        let pipeline = self.pipeline(key)?;
        let ubuf = uniform.map(|u| self.uniform(u)).transpose()?;
        let mut resources: Vec<&wgpu::Buffer> = Vec::with_capacity(buffers.len() + 1);
        if let Some(u) = &ubuf {
            resources.push(u);
        }
        resources.extend_from_slice(buffers);
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
            .map(|(i, b)| wgpu::BindGroupEntry {
                binding: i as u32,
                resource: b.as_entire_binding(),
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

    /// Copies the first `count` elements of `buf` back to the host as f32 (waits for the GPU).
    pub(crate) fn read(&self, buf: &DeviceBuffer, count: u64) -> Result<Vec<f32>> {
        if count > buf.elems {
            return Err(GpuError::Size {
                what: "readback",
                reason: format!("{count} elements from a buffer of {}", buf.elems),
            });
        }
        let bytes = (count * buf.precision.elem_bytes())
            .next_multiple_of(4)
            .max(4);
        let staging = self.create_buffer(
            "nam-gpu readback",
            bytes,
            wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        )?;
        let scope = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let mut encoder = self
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("nam-gpu readback"),
            });
        encoder.copy_buffer_to_buffer(&buf.buffer, 0, &staging, 0, bytes);
        self.queue.submit([encoder.finish()]);
        if let Some(e) = pop_scope(scope) {
            return Err(GpuError::Device {
                during: "readback copy",
                message: e.to_string(),
            });
        }
        let (tx, rx) = std::sync::mpsc::channel();
        staging.map_async(wgpu::MapMode::Read, .., move |r| {
            // The receiver outlives the poll below; a send error cannot be acted upon.
            let _ = tx.send(r);
        });
        self.device
            .poll(wgpu::PollType::wait_indefinitely())
            .map_err(|e| GpuError::Readback(e.to_string()))?;
        rx.recv()
            .map_err(|e| GpuError::Readback(e.to_string()))?
            .map_err(|e| GpuError::Readback(e.to_string()))?;
        let out = {
            let view = staging
                .get_mapped_range(..)
                .map_err(|e| GpuError::Readback(e.to_string()))?;
            let n = count as usize;
            match buf.precision {
                Precision::F32 => bytemuck::cast_slice::<u8, f32>(&view)[..n].to_vec(),
                Precision::F16 => bytemuck::cast_slice::<u8, half::f16>(&view)[..n]
                    .iter()
                    .map(|h| h.to_f32())
                    .collect(),
            }
        };
        staging.unmap();
        Ok(out)
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
