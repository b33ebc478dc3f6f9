//! Buffers and textures of a [`GpuContext`]: storage and uniform buffers, matrix textures,
//! f32/f16 encoding, uploads and blocking readbacks.

use super::{GpuContext, pop_scope};
use crate::error::{GpuError, Result};
use crate::shaders::Precision;

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

/// Texel format of `precision` textures.
pub(crate) fn texel_format(precision: Precision) -> wgpu::TextureFormat {
    match precision {
        Precision::F32 => wgpu::TextureFormat::Rgba32Float,
        Precision::F16 => wgpu::TextureFormat::Rgba16Float,
    }
}

impl GpuContext {
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
            // Copies and mapping work in 4-byte units, and kernels bind some buffers as
            // arrays of vec4: sizes round up to 16 bytes.
            size: size.max(16).next_multiple_of(16),
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

/// A 2-D `rows x texels` rgba texture of `precision`, bindable, writable as storage and
/// copyable both ways.
pub(super) fn texture_desc(
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
