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

/// A row-major matrix in a 2-D rgba texture: texel (t, r) holds channels 4t .. 4t + 3 of
/// row r (`rgba32float`, or `rgba16float` for f16 storage).
#[derive(Debug, Clone)]
pub(crate) struct DeviceTexture {
    pub texture: wgpu::Texture,
    pub view: wgpu::TextureView,
    /// Width in texels (4 channels each).
    pub texels: u32,
    /// Height: matrix rows.
    pub rows: u32,
    pub precision: Precision,
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
    /// Only the render MLP has a texture plan; standalone products use [`MatmulVariant::Direct`].
    Texture,
}

/// Texel format of `precision` textures.
pub(crate) fn texel_format(precision: Precision) -> wgpu::TextureFormat {
    match precision {
        Precision::F32 => wgpu::TextureFormat::Rgba32Float,
        Precision::F16 => wgpu::TextureFormat::Rgba16Float,
    }
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

    /// A uniform buffer holding `bytes` (a `crate::params` struct), zero-padded to a
    /// multiple of 16 bytes.
    pub(crate) fn uniform(&self, bytes: &[u8]) -> Result<wgpu::Buffer> {
        let mut b = bytes.to_vec();
        b.resize(bytes.len().next_multiple_of(16).max(16), 0);
        let buf = self.create_buffer(
            "nam-gpu params",
            b.len() as u64,
            wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
        )?;
        self.queue.write_buffer(&buf, 0, &b);
        Ok(buf)
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
        let raw = self.readback(bytes, |encoder, staging| {
            encoder.copy_buffer_to_buffer(&buf.buffer, 0, staging, 0, bytes);
        })?;
        let mut out = decode(&raw, buf.precision);
        out.truncate(count as usize);
        Ok(out)
    }

    /// A zero-initialised texture for a `rows x 4 texels` matrix (bindable as sampled and as
    /// storage texture).
    pub(crate) fn texture(
        &self,
        label: &str,
        texels: u32,
        rows: u32,
        precision: Precision,
    ) -> Result<DeviceTexture> {
        let max = self.device.limits().max_texture_dimension_2d;
        if texels == 0 || rows == 0 || texels > max || rows > max {
            return Err(GpuError::Size {
                what: "texture",
                reason: format!("{label}: {texels}x{rows} texels outside 1..={max}"),
            });
        }
        let scope = self.device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
        let texture = self
            .device
            .create_texture(&texture_desc(label, texels, rows, precision));
        if let Some(e) = pop_scope(scope) {
            return Err(GpuError::Device {
                during: "texture allocation",
                message: format!("{label}: {e}"),
            });
        }
        let view = texture.create_view(&wgpu::TextureViewDescriptor::default());
        Ok(DeviceTexture {
            texture,
            view,
            texels,
            rows,
            precision,
        })
    }

    /// A texture holding the `rows x cols` row-major matrix `data`, rows zero-padded to
    /// whole texels.
    pub(crate) fn upload_matrix(
        &self,
        label: &str,
        data: &[f32],
        rows: u32,
        cols: u32,
        precision: Precision,
    ) -> Result<DeviceTexture> {
        let tex = self.texture(label, cols.div_ceil(4), rows, precision)?;
        let (c, w) = (cols as usize, 4 * tex.texels as usize);
        if data.len() != rows as usize * c {
            return Err(GpuError::InputLength {
                what: "matrix",
                expected: rows as usize * c,
                got: data.len(),
            });
        }
        let mut padded = vec![0.0f32; rows as usize * w];
        for (dst, src) in padded.chunks_exact_mut(w).zip(data.chunks_exact(c.max(1))) {
            dst[..c].copy_from_slice(src);
        }
        self.write_texture(&tex, 0, &padded, w)?;
        Ok(tex)
    }

    /// Writes `data`, rows of `width` channels (a multiple of 4), into the texels starting at
    /// column `texel_base` of rows 0.. of `tex`.
    pub(crate) fn write_texture(
        &self,
        tex: &DeviceTexture,
        texel_base: u32,
        data: &[f32],
        width: usize,
    ) -> Result<()> {
        let texels = (width / 4) as u32;
        let rows = data.len().checked_div(width).unwrap_or(0);
        if !width.is_multiple_of(4)
            || width == 0
            || !data.len().is_multiple_of(width)
            || texel_base + texels > tex.texels
            || rows > tex.rows as usize
        {
            return Err(GpuError::Size {
                what: "texture write",
                reason: format!(
                    "{} values in rows of {width} at texel {texel_base} do not fit {}x{} texels",
                    data.len(),
                    tex.texels,
                    tex.rows
                ),
            });
        }
        if rows == 0 {
            return Ok(());
        }
        self.queue.write_texture(
            wgpu::TexelCopyTextureInfo {
                texture: &tex.texture,
                mip_level: 0,
                origin: wgpu::Origin3d {
                    x: texel_base,
                    y: 0,
                    z: 0,
                },
                aspect: wgpu::TextureAspect::All,
            },
            &Self::encode(data, tex.precision),
            wgpu::TexelCopyBufferLayout {
                offset: 0,
                bytes_per_row: Some((width as u64 * tex.precision.elem_bytes()) as u32),
                rows_per_image: None,
            },
            wgpu::Extent3d {
                width: texels,
                height: rows as u32,
                depth_or_array_layers: 1,
            },
        );
        Ok(())
    }

    /// Reads the first `rows` rows of `tex` back as f32, `4 * texels` channels per row.
    pub(crate) fn read_texture(&self, tex: &DeviceTexture, rows: u32) -> Result<Vec<f32>> {
        let rows = rows.min(tex.rows).max(1);
        let row_bytes = u64::from(tex.texels) * 4 * tex.precision.elem_bytes();
        let padded = row_bytes.next_multiple_of(u64::from(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT));
        let raw = self.readback(padded * u64::from(rows), |encoder, staging| {
            encoder.copy_texture_to_buffer(
                tex.texture.as_image_copy(),
                wgpu::TexelCopyBufferInfo {
                    buffer: staging,
                    layout: wgpu::TexelCopyBufferLayout {
                        offset: 0,
                        bytes_per_row: Some(padded as u32),
                        rows_per_image: None,
                    },
                },
                wgpu::Extent3d {
                    width: tex.texels,
                    height: rows,
                    depth_or_array_layers: 1,
                },
            );
        })?;
        let mut out = Vec::with_capacity((row_bytes / tex.precision.elem_bytes()) as usize);
        for row in raw.chunks_exact(padded as usize) {
            out.extend(decode(&row[..row_bytes as usize], tex.precision));
        }
        Ok(out)
    }

    /// Records a copy into a fresh `bytes`-long staging buffer with `record`, submits it,
    /// waits and returns the staging contents.
    fn readback(
        &self,
        bytes: u64,
        record: impl FnOnce(&mut wgpu::CommandEncoder, &wgpu::Buffer),
    ) -> Result<Vec<u8>> {
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
        record(&mut encoder, &staging);
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
        let out = staging
            .get_mapped_range(..)
            .map_err(|e| GpuError::Readback(e.to_string()))?
            .to_vec();
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

/// Stored values of `precision` as f32.
fn decode(bytes: &[u8], precision: Precision) -> Vec<f32> {
    match precision {
        Precision::F32 => bytes
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .collect(),
        Precision::F16 => bytes
            .chunks_exact(2)
            .map(|b| half::f16::from_le_bytes([b[0], b[1]]).to_f32())
            .collect(),
    }
}

fn texture_desc(
    label: &str,
    texels: u32,
    rows: u32,
    precision: Precision,
) -> wgpu::TextureDescriptor<'_> {
    wgpu::TextureDescriptor {
        label: Some(label),
        size: wgpu::Extent3d {
            width: texels,
            height: rows,
            depth_or_array_layers: 1,
        },
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format: texel_format(precision),
        usage: wgpu::TextureUsages::TEXTURE_BINDING
            | wgpu::TextureUsages::STORAGE_BINDING
            | wgpu::TextureUsages::COPY_DST
            | wgpu::TextureUsages::COPY_SRC,
        view_formats: &[],
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
