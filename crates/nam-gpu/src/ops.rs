//! Typed launchers for every kernel: they check shapes and record one [`Dispatch`] each.
//! Tensors are NCHW with batch 1, addressed as (buffer, element offset) views so that
//! concatenations are channel offsets into one buffer.

use crate::context::{
    DeviceTexture, Dispatch, GpuContext, MatmulVariant, PipelineKey, Res, groups_1d, linear_groups,
};
use crate::error::{GpuError, Result};
use crate::params::{
    ConvParams, ConvTParams, ConvTexParams, EwParams, GateParams, MatmulParams, NormParams,
    PackParams, PeParams, TexMatmulParams,
};
use crate::shaders::{Family, Precision};
use bytemuck::Pod;

/// A tensor view: a storage buffer and the element offset where the tensor starts.
#[derive(Debug, Clone, Copy)]
pub(crate) struct View<'a> {
    pub buf: &'a wgpu::Buffer,
    pub base: u32,
}

impl<'a> View<'a> {
    pub fn new(buf: &'a wgpu::Buffer, base: u64) -> Result<Self> {
        let base = u32::try_from(base).map_err(|_| GpuError::Size {
            what: "tensor offset",
            reason: format!("{base} does not fit in 32 bits"),
        })?;
        Ok(Self { buf, base })
    }
}

/// Activation fused into a kernel's epilogue (codes match the shaders).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum Act {
    None,
    /// LeakyReLU with this negative slope.
    Leaky(f32),
}

impl Act {
    fn code(self) -> (u32, f32) {
        match self {
            Act::None => (0, 0.0),
            Act::Leaky(s) => (2, s),
        }
    }
}

/// Geometry of a 2-D convolution (input [cin, h, w], kernel k x k, output [cout, ho, wo]).
#[derive(Debug, Clone, Copy)]
pub(crate) struct ConvShape {
    pub cin: u32,
    pub h: u32,
    pub w: u32,
    pub cout: u32,
    pub k: u32,
    pub stride: u32,
    pub pad: u32,
}

impl ConvShape {
    /// Output height and width (PyTorch's floor formula).
    pub fn out_hw(&self) -> (u32, u32) {
        (
            (self.h + 2 * self.pad - self.k) / self.stride + 1,
            (self.w + 2 * self.pad - self.k) / self.stride + 1,
        )
    }
}

/// Records `kernel` with `params` as its uniform (binding 0) and `bound` after it.
fn launch<P: Pod>(
    ctx: &GpuContext,
    kernel: PipelineKey,
    params: &P,
    bound: &[Res<'_>],
    groups: [u32; 3],
) -> Result<Dispatch> {
    ctx.dispatch(&kernel, Some(bytemuck::bytes_of(params)), bound, groups)
}

/// Conv2d with replicate padding: `dst = act(conv(src * norm_scale + norm_shift) + bias)`.
#[allow(clippy::too_many_arguments)]
pub(crate) fn conv2d(
    ctx: &GpuContext,
    precision: Precision,
    src: View<'_>,
    weight: &wgpu::Buffer,
    bias: Option<&wgpu::Buffer>,
    norm: Option<&wgpu::Buffer>,
    dst: View<'_>,
    s: ConvShape,
    act: Act,
) -> Result<Dispatch> {
    if s.k == 0 || s.stride == 0 || s.h + 2 * s.pad < s.k || s.w + 2 * s.pad < s.k {
        return Err(GpuError::Size {
            what: "conv2d",
            reason: format!("{s:?} has no output"),
        });
    }
    let (ho, wo) = s.out_hw();
    let flags = u32::from(bias.is_some()) | (u32::from(norm.is_some()) << 1);
    let (act_code, slope) = act.code();
    let params = ConvParams {
        cin: s.cin,
        h: s.h,
        w: s.w,
        cout: s.cout,
        ho,
        wo,
        stride: s.stride,
        pad: s.pad,
        in_base: src.base,
        out_base: dst.base,
        flags,
        act: act_code,
        slope,
        _pad0: 0,
        _pad1: 0,
        _pad2: 0,
    };
    let key = PipelineKey {
        family: Family::Conv2d,
        entry: "conv2d",
        precision,
        constants: vec![("K", s.k)],
    };
    let groups = [groups_1d(wo, 8)?, groups_1d(ho, 8)?, groups_1d(s.cout, 4)?];
    launch(
        ctx,
        key,
        &params,
        &[
            Res::Buf(src.buf),
            Res::Buf(weight),
            Res::Buf(bias.unwrap_or(ctx.dummy())),
            Res::Buf(norm.unwrap_or(ctx.dummy())),
            Res::Buf(dst.buf),
        ],
        groups,
    )
}

/// Transposed conv (PyTorch ConvTranspose2d, weight [cin, cout, k, k]) + bias + optional ReLU.
/// Output is `(h - 1) * stride - 2 pad + k` per side.
#[allow(clippy::too_many_arguments)]
pub(crate) fn conv_transpose2d(
    ctx: &GpuContext,
    precision: Precision,
    src: View<'_>,
    weight: &wgpu::Buffer,
    bias: Option<&wgpu::Buffer>,
    dst: View<'_>,
    s: ConvShape,
    relu: bool,
) -> Result<Dispatch> {
    if s.k == 0 || s.stride == 0 || (s.h - 1) * s.stride + s.k <= 2 * s.pad {
        return Err(GpuError::Size {
            what: "conv_transpose2d",
            reason: format!("{s:?} has no output"),
        });
    }
    let ho = (s.h - 1) * s.stride + s.k - 2 * s.pad;
    let wo = (s.w - 1) * s.stride + s.k - 2 * s.pad;
    let params = ConvTParams {
        cin: s.cin,
        h: s.h,
        w: s.w,
        cout: s.cout,
        ho,
        wo,
        pad: s.pad,
        in_base: src.base,
        out_base: dst.base,
        flags: u32::from(bias.is_some()),
        act: u32::from(relu),
        _pad0: 0,
    };
    let key = PipelineKey {
        family: Family::ConvTranspose,
        entry: "conv_transpose2d",
        precision,
        constants: vec![("K", s.k), ("S", s.stride)],
    };
    let groups = [groups_1d(wo, 8)?, groups_1d(ho, 8)?, groups_1d(s.cout, 1)?];
    launch(
        ctx,
        key,
        &params,
        &[
            Res::Buf(src.buf),
            Res::Buf(weight),
            Res::Buf(bias.unwrap_or(ctx.dummy())),
            Res::Buf(dst.buf),
        ],
        groups,
    )
}

/// Rows of the channel-block texture of a `[channels, h, w]` tensor (`shaders/tex_pack.wgsl`):
/// one `h`-row band per block of 4 channels.
pub(crate) fn channel_block_rows(channels: u32, h: u32) -> u32 {
    channels.div_ceil(4) * h
}

/// Packs `src` (`[channels, h, w]`) into `dst` as `shaders/tex_pack.wgsl` lays it out,
/// applying `norm` (f32 `[channels, 2]`: scale, shift) on the way when given.
pub(crate) fn pack_tex(
    ctx: &GpuContext,
    src: View<'_>,
    (channels, h, w): (u32, u32, u32),
    norm: Option<&wgpu::Buffer>,
    dst: &DeviceTexture,
) -> Result<Dispatch> {
    let rows = channel_block_rows(channels, h);
    if channels == 0 || w > dst.texels || rows > dst.rows {
        return Err(GpuError::Size {
            what: "pack_tex",
            reason: format!(
                "[{channels}, {h}, {w}] needs {w}x{rows} texels, the texture has {}x{}",
                dst.texels, dst.rows
            ),
        });
    }
    let params = PackParams {
        channels,
        h,
        w,
        in_base: src.base,
        use_norm: u32::from(norm.is_some()),
        vec4_ok: u32::from(w.is_multiple_of(4) && src.base.is_multiple_of(4)),
        _pad1: 0,
        _pad2: 0,
    };
    launch(
        ctx,
        PipelineKey {
            family: Family::TexPack,
            entry: "pack_tex",
            precision: dst.precision,
            constants: vec![],
        },
        &params,
        &[
            Res::Buf(src.buf),
            Res::Buf(norm.unwrap_or(ctx.dummy())),
            Res::Tex(&dst.view),
        ],
        [groups_1d(w, 32)?, groups_1d(rows, 8)?, 1],
    )
}

/// Which convolution [`conv_tex`] runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum ConvKind {
    /// Conv2d with replicate padding (weight `[cout, cin, k, k]`).
    Direct,
    /// ConvTranspose2d with stride 2 and output `2h x 2w` (weight `[cin, cout, k, k]`).
    Transposed,
}

/// `dst = act(conv(x) + bias)` with `x` packed by [`pack_tex`] and `w` a weight texture from
/// [`crate::weights`] (`shaders/conv_tex.wgsl`).
#[allow(clippy::too_many_arguments)]
pub(crate) fn conv_tex(
    ctx: &GpuContext,
    kind: ConvKind,
    x: &DeviceTexture,
    w: &DeviceTexture,
    bias: Option<&wgpu::Buffer>,
    dst: View<'_>,
    s: ConvShape,
    act: Act,
) -> Result<Dispatch> {
    let cin4 = s.cin.div_ceil(4);
    let (ho, wo, entry) = match kind {
        ConvKind::Direct => {
            if s.k == 0 || s.stride == 0 || s.h + 2 * s.pad < s.k || s.w + 2 * s.pad < s.k {
                return Err(GpuError::Size {
                    what: "conv_tex",
                    reason: format!("{s:?} has no output"),
                });
            }
            let (ho, wo) = s.out_hw();
            (ho, wo, "conv_tex")
        }
        ConvKind::Transposed => {
            if s.stride != 2 || s.k != 2 * s.pad + 2 {
                return Err(GpuError::Size {
                    what: "conv_t_tex",
                    reason: format!("{s:?} is not a stride-2 upsampling by exactly 2"),
                });
            }
            (2 * s.h, 2 * s.w, "conv_t_tex")
        }
    };
    if s.w > x.texels
        || channel_block_rows(s.cin, s.h) > x.rows
        || w.rows < s.cout
        || w.texels < s.k * s.k * cin4
    {
        return Err(GpuError::Size {
            what: "conv_tex",
            reason: format!(
                "{s:?} does not fit input {}x{} or weight {}x{} texels",
                x.texels, x.rows, w.texels, w.rows
            ),
        });
    }
    let (act_code, slope) = act.code();
    let phase_blocks = (s.h * s.w).div_ceil(16);
    let params = ConvTexParams {
        cin4,
        h: s.h,
        w: s.w,
        cout: s.cout,
        ho,
        wo,
        stride: s.stride,
        pad: s.pad,
        out_base: dst.base,
        flags: u32::from(bias.is_some()),
        act: act_code,
        slope,
        phase_blocks,
        _pad0: 0,
        _pad1: 0,
        _pad2: 0,
    };
    let pixel_blocks = match kind {
        ConvKind::Direct => u64::from(ho * wo).div_ceil(16),
        ConvKind::Transposed => 4 * u64::from(phase_blocks),
    };
    let [gx, gy, _] = linear_groups(pixel_blocks, 1)?;
    launch(
        ctx,
        PipelineKey {
            family: Family::ConvTex,
            entry,
            precision: w.precision,
            constants: vec![("K", s.k)],
        },
        &params,
        &[
            Res::Tex(&x.view),
            Res::Tex(&w.view),
            Res::Buf(bias.unwrap_or(ctx.dummy())),
            Res::Buf(dst.buf),
        ],
        [gx, gy, groups_1d(s.cout, 16)?],
    )
}

/// InstanceNorm statistics of `src` [channels, hw] into `norm` (f32 [channels, 2]).
pub(crate) fn instance_norm_stats(
    ctx: &GpuContext,
    precision: Precision,
    src: View<'_>,
    channels: u32,
    hw: u32,
    eps: f32,
    norm: &wgpu::Buffer,
) -> Result<Dispatch> {
    let params = NormParams {
        channels,
        hw,
        in_base: src.base,
        eps,
    };
    let key = PipelineKey {
        family: Family::InstanceNorm,
        entry: "instance_norm_stats",
        precision,
        constants: vec![],
    };
    launch(
        ctx,
        key,
        &params,
        &[Res::Buf(src.buf), Res::Buf(norm)],
        [groups_1d(channels, 1)?, 1, 1],
    )
}

/// Block tail after an HA-Conv: see `shaders/ha_gate.wgsl`.
#[derive(Debug, Clone, Copy)]
pub(crate) enum GateTail<'a> {
    /// `relu(y)`
    Relu,
    /// `relu(y + res)`
    Residual(View<'a>),
}

/// `dst = tail((sigmoid(a) * leaky(b) + c) * affine_scale + affine_shift)`, all [channels, hw].
#[allow(clippy::too_many_arguments)]
pub(crate) fn ha_gate(
    ctx: &GpuContext,
    precision: Precision,
    a: &wgpu::Buffer,
    b: &wgpu::Buffer,
    c: &wgpu::Buffer,
    affine: &wgpu::Buffer,
    tail: GateTail<'_>,
    dst: View<'_>,
    channels: u32,
    hw: u32,
    slope: f32,
) -> Result<Dispatch> {
    let (mode, res) = match tail {
        GateTail::Relu => (1, None),
        GateTail::Residual(v) => (2, Some(v)),
    };
    let params = GateParams {
        channels,
        hw,
        mode,
        res_base: res.map_or(0, |v| v.base),
        out_base: dst.base,
        slope,
        vec4_ok: u32::from(
            hw.is_multiple_of(4)
                && res.is_none_or(|v| v.base.is_multiple_of(4))
                && dst.base.is_multiple_of(4),
        ),
        _pad0: 0,
    };
    launch(
        ctx,
        PipelineKey {
            family: Family::HaGate,
            entry: "ha_gate",
            precision,
            constants: vec![],
        },
        &params,
        &[
            Res::Buf(a),
            Res::Buf(b),
            Res::Buf(c),
            Res::Buf(affine),
            Res::Buf(res.map_or(ctx.dummy(), |v| v.buf)),
            Res::Buf(dst.buf),
        ],
        linear_groups((u64::from(channels) * u64::from(hw)).div_ceil(4), 256)?,
    )
}

/// Elementwise entry points of `shaders/elementwise.wgsl`.
#[derive(Debug, Clone, Copy)]
pub(crate) enum Elementwise<'a> {
    /// `relu(x + other)`.
    AddRelu(View<'a>),
    /// Arc tangent.
    Atan,
}

/// Applies `op` to `n` elements of `src`, writing `dst`.
pub(crate) fn elementwise(
    ctx: &GpuContext,
    precision: Precision,
    op: Elementwise<'_>,
    src: View<'_>,
    dst: View<'_>,
    n: u32,
) -> Result<Dispatch> {
    let (entry, src2) = match op {
        Elementwise::AddRelu(v) => ("add_relu", Some(v)),
        Elementwise::Atan => ("atan_act", None),
    };
    let params = EwParams {
        n,
        in_base: src.base,
        in2_base: src2.map_or(0, |v| v.base),
        out_base: dst.base,
    };
    launch(
        ctx,
        PipelineKey {
            family: Family::Elementwise,
            entry,
            precision,
            constants: vec![],
        },
        &params,
        &[
            Res::Buf(src.buf),
            Res::Buf(src2.map_or(ctx.dummy(), |v| v.buf)),
            Res::Buf(dst.buf),
        ],
        linear_groups(u64::from(n), 256)?,
    )
}

/// Positional encoding of `n` rows of 9 direction values into rows of `9 + 18 octaves`
/// values starting at `dst.base + r * out_stride`.
pub(crate) fn pos_enc(
    ctx: &GpuContext,
    precision: Precision,
    dirs: &wgpu::Buffer,
    n: u32,
    octaves: u32,
    dst: View<'_>,
    out_stride: u32,
) -> Result<Dispatch> {
    let params = PeParams {
        n,
        out_stride,
        out_base: dst.base,
        _pad0: 0,
    };
    launch(
        ctx,
        PipelineKey {
            family: Family::PosEnc,
            entry: "pos_enc",
            precision,
            constants: vec![("OCTAVES", octaves)],
        },
        &params,
        &[
            Res::Buf(dirs),
            Res::Buf(dst.buf),
            Res::Tex(ctx.dummy_tex(precision)),
        ],
        linear_groups(u64::from(n) * 9, 64)?,
    )
}

/// Positional encoding of `n` rows into the texture `dst` (texel (t, r) = channels 4t..4t+3
/// of row r, zero past the `9 + 18 octaves` channels), over all of its texel columns.
pub(crate) fn pos_enc_tex(
    ctx: &GpuContext,
    dirs: &wgpu::Buffer,
    n: u32,
    octaves: u32,
    dst: &DeviceTexture,
) -> Result<Dispatch> {
    if n > dst.rows {
        return Err(GpuError::Size {
            what: "pos_enc_tex",
            reason: format!("{n} rows into a texture of {}", dst.rows),
        });
    }
    let params = PeParams {
        n,
        out_stride: dst.texels,
        out_base: 0,
        _pad0: 0,
    };
    launch(
        ctx,
        PipelineKey {
            family: Family::PosEnc,
            entry: "pos_enc_tex",
            precision: dst.precision,
            constants: vec![("OCTAVES", octaves)],
        },
        &params,
        &[Res::Buf(dirs), Res::Buf(ctx.dummy()), Res::Tex(&dst.view)],
        linear_groups(u64::from(n) * u64::from(dst.texels), 64)?,
    )
}

/// Where [`matmul_tex`] writes `y`.
#[derive(Debug, Clone, Copy)]
pub(crate) enum TexOut<'a> {
    /// Texture texels from column `texel_base` on.
    Texture {
        tex: &'a DeviceTexture,
        texel_base: u32,
    },
    /// Row-major buffer rows `stride` elements apart.
    Buffer { buf: &'a wgpu::Buffer, stride: u32 },
}

/// `y[m, n] = act(sum_k x[m, k] * w[n, k])` with texture operands (`shaders/matmul_tex.wgsl`):
/// `x` texels 0 .. ceil(inner / 4) of rows 0 .. rows, `w` a `[cols, inner]` matrix texture.
#[allow(clippy::too_many_arguments)]
pub(crate) fn matmul_tex(
    ctx: &GpuContext,
    x: &DeviceTexture,
    w: &DeviceTexture,
    y: TexOut<'_>,
    rows: u32,
    cols: u32,
    inner: u32,
    act: Act,
) -> Result<Dispatch> {
    let inner4 = inner.div_ceil(4);
    let fits_out = match y {
        TexOut::Texture { tex, texel_base } => {
            tex.rows >= rows && texel_base + cols.div_ceil(4) <= tex.texels
        }
        TexOut::Buffer { stride, .. } => stride >= cols,
    };
    if x.rows < rows || x.texels < inner4 || w.rows < cols || w.texels < inner4 || !fits_out {
        return Err(GpuError::Size {
            what: "matmul_tex",
            reason: format!(
                "{rows}x{cols}x{inner} does not fit x {}x{}, w {}x{} texels or the output",
                x.texels, x.rows, w.texels, w.rows
            ),
        });
    }
    let (act_code, slope) = act.code();
    let (base, out_buf, stride, yt, yb) = match y {
        TexOut::Texture { tex, texel_base } => (texel_base, 0, 0, &tex.view, ctx.dummy()),
        TexOut::Buffer { buf, stride } => (0, 1, stride, ctx.dummy_tex(w.precision), buf),
    };
    let params = TexMatmulParams {
        rows,
        cols,
        inner4,
        y_texel_base: base,
        out_buf,
        y_stride: stride,
        act: act_code,
        slope,
    };
    launch(
        ctx,
        PipelineKey {
            family: Family::MatmulTex,
            entry: "matmul_tex",
            precision: w.precision,
            constants: vec![],
        },
        &params,
        &[
            Res::Tex(&x.view),
            Res::Tex(&w.view),
            Res::Tex(yt),
            Res::Buf(yb),
        ],
        [groups_1d(cols, 16)?, groups_1d(rows, 16)?, 1],
    )
}

/// Row-major matrix layout of one operand: `rows` rows of which columns
/// `[base, base + width)` are used, `stride` elements apart.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Rows<'a> {
    pub view: View<'a>,
    pub stride: u32,
}

/// `y[m, n] = act(sum_k x[m, k] * w[n, k])` with the context's matmul variant.
#[allow(clippy::too_many_arguments)]
pub(crate) fn matmul(
    ctx: &GpuContext,
    precision: Precision,
    x: Rows<'_>,
    w: &wgpu::Buffer,
    y: Rows<'_>,
    rows: u32,
    cols: u32,
    inner: u32,
    act: Act,
) -> Result<Dispatch> {
    matmul_as(
        ctx,
        ctx.matmul_variant(),
        precision,
        x,
        w,
        y,
        rows,
        cols,
        inner,
        act,
    )
}

/// `y[m, n] = act(sum_k x[m, k] * w[n, k])` for `m < rows`, `n < cols`, `k < inner`.
#[allow(clippy::too_many_arguments)]
pub(crate) fn matmul_as(
    ctx: &GpuContext,
    variant: MatmulVariant,
    precision: Precision,
    x: Rows<'_>,
    w: &wgpu::Buffer,
    y: Rows<'_>,
    rows: u32,
    cols: u32,
    inner: u32,
    act: Act,
) -> Result<Dispatch> {
    let (act_code, slope) = act.code();
    let params = MatmulParams {
        rows,
        cols,
        inner,
        x_stride: x.stride,
        x_base: x.view.base,
        y_stride: y.stride,
        y_base: y.view.base,
        act: act_code,
        slope,
        _pad0: 0,
        _pad1: 0,
        _pad2: 0,
    };
    let (entry, row_tile) = match variant {
        MatmulVariant::Tiled => ("matmul", 64),
        // Buffer operands: the texture variant's buffer-only stand-in.
        MatmulVariant::Direct | MatmulVariant::Texture => ("matmul_direct", 4),
    };
    launch(
        ctx,
        PipelineKey {
            family: Family::Matmul,
            entry,
            precision,
            constants: vec![],
        },
        &params,
        &[Res::Buf(x.view.buf), Res::Buf(w), Res::Buf(y.view.buf)],
        [groups_1d(cols, 64)?, groups_1d(rows, row_tile)?, 1],
    )
}
