//! Uploading a validated [`nam_weights::Weights`] model to device buffers, once.

use nam_weights::{Scope, Weights};

use crate::context::{DeviceBuffer, DeviceTexture, GpuContext, MatmulVariant};
use crate::error::{GpuError, Result};
use crate::shaders::Precision;

/// A convolution weight on the device: the PyTorch-layout buffer the direct kernels read and,
/// when the context runs texture kernels ([`MatmulVariant::Texture`]), the same taps as the
/// weight texture of `shaders/conv_tex.wgsl` (row = output channel, texel
/// `(ky·k + kx)·⌈cin/4⌉ + l` = input channels `4l .. 4l + 3` of that tap).
#[derive(Debug)]
pub(crate) struct ConvWeight {
    pub buf: DeviceBuffer,
    pub tex: Option<DeviceTexture>,
}

/// Device weights of one HA-Conv (in -> out, stride s).
#[derive(Debug)]
pub(crate) struct HaWeights {
    pub gate: ConvWeight,
    pub feat: ConvWeight,
    pub inc1a: ConvWeight,
    pub inc1b: ConvWeight,
    pub inc2: ConvWeight,
}

/// Device weights of a BasicBlock; `bn*` are interleaved `[out, 2]` (scale, shift).
#[derive(Debug)]
pub(crate) struct BasicWeights {
    pub cin: u32,
    pub cout: u32,
    pub stride: u32,
    pub ha1: HaWeights,
    pub bn1: DeviceBuffer,
    pub ha2: HaWeights,
    pub bn2: DeviceBuffer,
    /// conv1x1 weight and folded-BN bias, when the shape changes.
    pub down: Option<(ConvWeight, DeviceBuffer)>,
}

/// Device weights of a ReverseBlock (weights then folded-BN biases).
#[derive(Debug)]
pub(crate) struct ReverseWeights {
    pub cin: u32,
    pub cout: u32,
    pub up4: (ConvWeight, DeviceBuffer),
    pub conv: (ConvWeight, DeviceBuffer),
    pub up2: (ConvWeight, DeviceBuffer),
}

/// The U-Net `M_est` on the device.
#[derive(Debug)]
pub(crate) struct UnetWeights {
    pub width: u32,
    pub in_channels: u32,
    /// The head convolves `[decoder output, network input]` (`ModelConfig::input_skip`).
    pub input_skip: bool,
    pub param_channels: u32,
    pub eps: f32,
    pub ha_slope: f32,
    pub stem: ConvWeight,
    pub enc: Vec<[BasicWeights; 2]>,
    pub dec_reverse: Vec<ReverseWeights>,
    pub dec_basic: Vec<BasicWeights>,
    pub dec4: [BasicWeights; 2],
    pub head: ConvWeight,
}

impl UnetWeights {
    /// Input channels of the head: the width, plus the network input with the input skip.
    pub fn head_in_channels(&self) -> u32 {
        self.width + if self.input_skip { self.in_channels } else { 0 }
    }

    /// Every convolution weight, in no particular order.
    fn convs(&self) -> impl Iterator<Item = &ConvWeight> {
        fn ha(h: &HaWeights) -> [&ConvWeight; 5] {
            [&h.gate, &h.feat, &h.inc1a, &h.inc1b, &h.inc2]
        }
        fn basic(b: &BasicWeights) -> impl Iterator<Item = &ConvWeight> {
            ha(&b.ha1)
                .into_iter()
                .chain(ha(&b.ha2))
                .chain(b.down.as_ref().map(|d| &d.0))
        }
        let blocks = self
            .enc
            .iter()
            .flatten()
            .chain(&self.dec_basic)
            .chain(&self.dec4)
            .flat_map(basic);
        let reverse = self
            .dec_reverse
            .iter()
            .flat_map(|r| [&r.up4.0, &r.conv.0, &r.up2.0]);
        [&self.stem, &self.head]
            .into_iter()
            .chain(blocks)
            .chain(reverse)
    }

    /// Whether every convolution has its weight texture (uploaded for
    /// [`MatmulVariant::Texture`] contexts).
    pub fn has_conv_textures(&self) -> bool {
        self.convs().all(|w| w.tex.is_some())
    }
}

/// One bias-free linear layer `[out, in]` with the activation slope after it (`None`: none).
#[derive(Debug)]
pub(crate) struct Linear {
    pub weight: DeviceBuffer,
    /// The same matrix as a texture, for the [`MatmulVariant::Texture`] render plan.
    pub tex: Option<DeviceTexture>,
    pub out: u32,
    pub inp: u32,
    pub slope: Option<f32>,
}

/// `M_render` on the device: ND_enc layers and the render MLP with l0·l1 folded.
#[derive(Debug)]
pub(crate) struct RenderWeights {
    pub octaves: u32,
    pub encoding: u32,
    pub param_channels: u32,
    pub nd: Vec<Linear>,
    pub mlp: Vec<Linear>,
}

fn u(v: usize, what: &'static str) -> Result<u32> {
    u32::try_from(v).map_err(|_| GpuError::Size {
        what,
        reason: format!("{v} does not fit in 32 bits"),
    })
}

struct Uploader<'a> {
    ctx: &'a GpuContext,
    precision: Precision,
}

impl Uploader<'_> {
    /// A `[out, in]` linear layer as buffer, and as texture when the context's matmul uses
    /// textures.
    fn linear(
        &self,
        label: &str,
        data: &[f32],
        (out, inp): (usize, usize),
        slope: Option<f32>,
    ) -> Result<Linear> {
        let (o, i) = (u(out, "width")?, u(inp, "width")?);
        let tex = if self.ctx.matmul_variant() == MatmulVariant::Texture {
            Some(self.ctx.upload_matrix(label, data, o, i, self.precision)?)
        } else {
            None
        };
        Ok(Linear {
            weight: self.ctx.upload(label, data, self.precision)?,
            tex,
            out: o,
            inp: i,
            slope,
        })
    }

    fn get(&self, s: &Scope<'_>, name: &str, shape: &[usize]) -> Result<DeviceBuffer> {
        let data = s.get(name, shape)?;
        let label = format!("{}.{name}", s.prefix());
        self.ctx.upload(&label, data, self.precision)
    }

    /// A convolution weight of PyTorch shape `[cout, cin, k, k]`, or `[cin, cout, k, k]` when
    /// `transposed`.
    fn conv(
        &self,
        s: &Scope<'_>,
        name: &str,
        shape: [usize; 4],
        transposed: bool,
    ) -> Result<ConvWeight> {
        let data = s.get(name, &shape)?;
        let label = format!("{}.{name}", s.prefix());
        let tex = if self.ctx.matmul_variant() == MatmulVariant::Texture {
            let (cout, cin) = if transposed {
                (shape[1], shape[0])
            } else {
                (shape[0], shape[1])
            };
            let (m, cols) = conv_weight_matrix(data, cout, cin, shape[2], transposed);
            Some(self.ctx.upload_matrix(
                &label,
                &m,
                u(cout, "channels")?,
                u(cols, "width")?,
                self.precision,
            )?)
        } else {
            None
        };
        Ok(ConvWeight {
            buf: self.ctx.upload(&label, data, self.precision)?,
            tex,
        })
    }

    fn affine(&self, s: &Scope<'_>, name: &str, n: usize) -> Result<DeviceBuffer> {
        let scale = s.get(&format!("{name}.scale"), &[n])?;
        let shift = s.get(&format!("{name}.shift"), &[n])?;
        let ab: Vec<f32> = scale
            .iter()
            .zip(shift)
            .flat_map(|(&a, &b)| [a, b])
            .collect();
        self.ctx
            .upload(&format!("{}.{name}", s.prefix()), &ab, self.precision)
    }

    fn ha(&self, s: &Scope<'_>, cin: usize, cout: usize) -> Result<HaWeights> {
        Ok(HaWeights {
            gate: self.conv(s, "gate.weight", [cout, cin, 3, 3], false)?,
            feat: self.conv(s, "feat.weight", [cout, cin, 3, 3], false)?,
            inc1a: self.conv(s, "inc1a.weight", [cout, cin, 3, 3], false)?,
            inc1b: self.conv(s, "inc1b.weight", [cout / 2, cout, 3, 3], false)?,
            inc2: self.conv(s, "inc2.weight", [cout / 2, cin, 3, 3], false)?,
        })
    }

    fn basic(&self, s: &Scope<'_>, cin: usize, cout: usize, stride: usize) -> Result<BasicWeights> {
        let down = if cin != cout || stride != 1 {
            Some((
                self.conv(s, "down.weight", [cout, cin, 1, 1], false)?,
                self.get(s, "down.bias", &[cout])?,
            ))
        } else {
            None
        };
        Ok(BasicWeights {
            cin: u(cin, "channels")?,
            cout: u(cout, "channels")?,
            stride: u(stride, "stride")?,
            ha1: self.ha(&s.scope("ha1"), cin, cout)?,
            bn1: self.affine(s, "bn1", cout)?,
            ha2: self.ha(&s.scope("ha2"), cout, cout)?,
            bn2: self.affine(s, "bn2", cout)?,
            down,
        })
    }

    fn reverse(&self, s: &Scope<'_>, cin: usize, cout: usize) -> Result<ReverseWeights> {
        Ok(ReverseWeights {
            cin: u(cin, "channels")?,
            cout: u(cout, "channels")?,
            up4: (
                self.conv(s, "up4.weight", [cin, cout, 4, 4], true)?,
                self.get(s, "up4.bias", &[cout])?,
            ),
            conv: (
                self.conv(s, "conv.weight", [cout, cout, 3, 3], false)?,
                self.get(s, "conv.bias", &[cout])?,
            ),
            up2: (
                self.conv(s, "up2.weight", [cin, cout, 2, 2], true)?,
                self.get(s, "up2.bias", &[cout])?,
            ),
        })
    }
}

/// The weight texture layout of `shaders/conv_tex.wgsl` for a `k x k` convolution weight
/// (`[cout, cin, k, k]`, or `[cin, cout, k, k]` when `transposed`): `cout` rows of
/// `k·k·⌈cin/4⌉·4` values, input channels zero-padded to whole texels. Returns the rows and
/// the row length.
pub(crate) fn conv_weight_matrix(
    w: &[f32],
    cout: usize,
    cin: usize,
    k: usize,
    transposed: bool,
) -> (Vec<f32>, usize) {
    let cin4 = cin.div_ceil(4);
    let cols = k * k * cin4 * 4;
    let mut m = vec![0.0f32; cout * cols];
    for co in 0..cout {
        for ci in 0..cin {
            for tap in 0..k * k {
                let src = if transposed {
                    (ci * cout + co) * k * k + tap
                } else {
                    (co * cin + ci) * k * k + tap
                };
                m[co * cols + (tap * cin4 + ci / 4) * 4 + ci % 4] = w[src];
            }
        }
    }
    (m, cols)
}

/// Uploads the U-Net (DESIGN §4, FORMAT.md tensor names).
pub(crate) fn upload_unet(
    ctx: &GpuContext,
    weights: &Weights,
    precision: Precision,
) -> Result<UnetWeights> {
    let cfg = weights.config();
    let c = cfg.width;
    let up = Uploader { ctx, precision };
    let est = weights.scope("est");
    let widths = [c, 2 * c, 4 * c, 8 * c];
    let strides = [1, 2, 2, 2];
    let mut enc = Vec::with_capacity(4);
    let mut cin = c;
    for k in 0..4 {
        let stage = est.scope(&format!("enc{}", k + 1));
        let b0 = up.basic(&stage.scope("0"), cin, widths[k], strides[k])?;
        let b1 = up.basic(&stage.scope("1"), widths[k], widths[k], 1)?;
        enc.push([b0, b1]);
        cin = widths[k];
    }
    // dec1..dec3: ReverseBlock then BasicBlock; inputs 8C, 12C, 6C.
    let dec_io = [(8 * c, 8 * c), (12 * c, 4 * c), (6 * c, 2 * c)];
    let mut dec_reverse = Vec::with_capacity(3);
    let mut dec_basic = Vec::with_capacity(3);
    for (k, &(i, o)) in dec_io.iter().enumerate() {
        let stage = est.scope(&format!("dec{}", k + 1));
        dec_reverse.push(up.reverse(&stage.scope("0"), i, o)?);
        dec_basic.push(up.basic(&stage.scope("1"), o, o, 1)?);
    }
    let dec4 = est.scope("dec4");
    Ok(UnetWeights {
        width: u(c, "width")?,
        in_channels: u(cfg.in_channels, "in_channels")?,
        input_skip: cfg.input_skip,
        param_channels: u(cfg.param_channels, "param_channels")?,
        eps: cfg.norm_eps,
        ha_slope: cfg.slopes.ha,
        stem: up.conv(&est, "stem.weight", [c, cfg.in_channels, 7, 7], false)?,
        enc,
        dec_reverse,
        dec_basic,
        dec4: [
            up.basic(&dec4.scope("0"), 3 * c, c, 1)?,
            up.basic(&dec4.scope("1"), c, c, 1)?,
        ],
        head: up.conv(
            &est,
            "head.weight",
            [cfg.param_channels, cfg.head_in_channels(), 7, 7],
            false,
        )?,
    })
}

/// Uploads `M_render` with `render.l1 · render.l0` folded into one matrix
/// ([`Weights::render_layers`]).
pub(crate) fn upload_render(
    ctx: &GpuContext,
    weights: &Weights,
    precision: Precision,
) -> Result<RenderWeights> {
    let cfg = weights.config();
    let up = Uploader { ctx, precision };
    let layers = weights.render_layers(true)?;
    let upload =
        |l: &nam_weights::LinearLayer| up.linear(&l.name, &l.weight, (l.out, l.inp), l.slope);
    let nd = layers
        .nd_enc
        .iter()
        .map(upload)
        .collect::<Result<Vec<_>>>()?;
    let mlp = layers.mlp.iter().map(upload).collect::<Result<Vec<_>>>()?;
    Ok(RenderWeights {
        octaves: u(cfg.pe_octaves, "pe_octaves")?,
        encoding: u(cfg.encoding_len(), "encoding")?,
        param_channels: u(cfg.param_channels, "param_channels")?,
        nd,
        mlp,
    })
}
