//! The whole network on the device: `estimate` (U-Net) and `render` (ND_enc + render MLP).

use std::collections::HashMap;

use nam_weights::{
    DirectionWork, ModelConfig, RenderWork, UNET_MULTIPLE, Weights, radiance_from_log,
};

use crate::context::{DeviceBuffer, DeviceTexture, Dispatch, GpuContext, MatmulVariant};
use crate::error::{GpuError, Result};
use crate::ops::{self, Act, ConvShape, Elementwise, GateTail, Rows, TexOut, View};
use crate::shaders::Precision;
use crate::weights::{
    self, BasicWeights, HaWeights, Linear, RenderWeights, ReverseWeights, UnetWeights,
};

/// Most rows of one render submission. Bounds the [rows, 594] activation buffers
/// (~39 MB in f32) well inside the default 128 MiB storage binding; larger batches are tiled.
pub const MAX_RENDER_ROWS: u32 = 16_384;

/// Estimate plans kept per padded image size before the cache is cleared.
const MAX_CACHED_PLANS: usize = 4;

/// The neural material network on a wgpu device: weights uploaded once, pipelines built
/// lazily, per-size execution plans cached.
///
/// Conventions (docs/FORMAT.md): the estimator input is CHW `[in_channels, H, W]` (log RGB +
/// half-vector z); params come back HWC `[H, W, 64]`; render queries are rows of 64 params and
/// 9 direction values `[ωi, ωo, ωh]` (unit vectors, surface frame, z up); radiance is
/// `R = π f_r cosθi` per RGB channel (linear, unit light, no falloff).
#[derive(Debug)]
pub struct GpuNetwork {
    ctx: GpuContext,
    precision: Precision,
    /// The architecture: the multiply-add counts derive from it.
    config: ModelConfig,
    unet: UnetWeights,
    render: RenderWeights,
    estimate_plans: HashMap<(u32, u32), EstimatePlan>,
    render_plans: HashMap<(u32, RenderKind), RenderPlan>,
}

/// Which part of `M_render` a render plan runs per row.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
enum RenderKind {
    /// Positional encoding, ND_enc and the render MLP, directions per row.
    General,
    /// The render MLP only: ND_enc features computed once and written into every row
    /// (ωi, ωo the same for all rows: directional light, orthographic view; DESIGN §9).
    ConstantDirections,
}

/// The directions of a render submission's rows.
#[derive(Debug, Clone, Copy)]
enum RowDirections<'a> {
    /// `[N, 9]` rows `[ωi, ωo, ωh]`.
    Each(&'a [f32]),
    /// The ND_enc output `[nd_out]` shared by every row.
    ConstantFeatures(&'a [f32]),
}

#[derive(Debug)]
struct EstimatePlan {
    /// Holds the network input at element `input_at` (after the decoder output the head
    /// reads with it, when the model has an input skip).
    input: DeviceBuffer,
    input_at: u64,
    output: DeviceBuffer,
    dispatches: Vec<Dispatch>,
}

#[derive(Debug)]
struct RenderPlan {
    /// `[rows, 9]` directions; `None` for [`RenderKind::ConstantDirections`].
    dirs: Option<DeviceBuffer>,
    /// `[rows, param_channels + nd_out]`: params uploaded, ND_enc output written in place.
    cat: Cat,
    out: DeviceBuffer,
    dispatches: Vec<Dispatch>,
}

/// Where a render plan keeps `[params | nd_enc]` rows: a buffer, or a texture for the
/// [`MatmulVariant::Texture`] plan (every MLP operand is a texture there).
#[derive(Debug)]
enum Cat {
    Buffer(DeviceBuffer),
    Texture(DeviceTexture),
}

/// Scratch buffers shared by all blocks of one estimate plan (each `scratch` elements).
struct Scratch {
    elems: u64,
    a: DeviceBuffer,
    b: DeviceBuffer,
    c: DeviceBuffer,
    t: DeviceBuffer,
    y: DeviceBuffer,
    d: DeviceBuffer,
    norm: DeviceBuffer,
}

struct UnetBuilder<'a> {
    ctx: &'a GpuContext,
    precision: Precision,
    eps: f32,
    slope: f32,
    s: Scratch,
    out: Vec<Dispatch>,
}

fn to_u32(v: u64, what: &'static str) -> Result<u32> {
    u32::try_from(v).map_err(|_| GpuError::Size {
        what,
        reason: format!("{v} does not fit in 32 bits"),
    })
}

impl UnetBuilder<'_> {
    fn fits(&self, elems: u64, what: &'static str) -> Result<()> {
        if elems > self.s.elems {
            return Err(GpuError::Size {
                what,
                reason: format!("{elems} elements exceed the scratch size {}", self.s.elems),
            });
        }
        Ok(())
    }

    /// HA-Conv + folded BN + tail into `dst` ([cout, h/s, w/s]).
    #[allow(clippy::too_many_arguments)]
    fn ha(
        &mut self,
        w: &HaWeights,
        bn: &DeviceBuffer,
        x: View<'_>,
        (cin, h, wd): (u32, u32, u32),
        cout: u32,
        stride: u32,
        tail: GateTail<'_>,
        dst: View<'_>,
    ) -> Result<()> {
        let (ctx, p) = (self.ctx, self.precision);
        let shape = ConvShape {
            cin,
            h,
            w: wd,
            cout,
            k: 3,
            stride,
            pad: 1,
        };
        let (ho, wo) = shape.out_hw();
        let plane = u64::from(ho) * u64::from(wo);
        self.fits(u64::from(cout) * u64::from(h) * u64::from(wd), "HA scratch")?;
        let half = cout / 2;
        let s = &self.s;
        let mut d = vec![
            ops::instance_norm_stats(ctx, p, x, cin, h * wd, self.eps, &s.norm.buffer)?,
            ops::conv2d(
                ctx,
                p,
                x,
                &w.gate.buffer,
                None,
                None,
                View::new(&s.a.buffer, 0)?,
                shape,
                Act::None,
            )?,
            ops::conv2d(
                ctx,
                p,
                x,
                &w.feat.buffer,
                None,
                Some(&s.norm.buffer),
                View::new(&s.b.buffer, 0)?,
                shape,
                Act::None,
            )?,
            ops::conv2d(
                ctx,
                p,
                x,
                &w.inc1a.buffer,
                None,
                None,
                View::new(&s.t.buffer, 0)?,
                ConvShape { stride: 1, ..shape },
                Act::None,
            )?,
            ops::conv2d(
                ctx,
                p,
                View::new(&s.t.buffer, 0)?,
                &w.inc1b.buffer,
                None,
                None,
                View::new(&s.c.buffer, 0)?,
                ConvShape {
                    cin: cout,
                    cout: half,
                    ..shape
                },
                Act::None,
            )?,
            ops::conv2d(
                ctx,
                p,
                x,
                &w.inc2.buffer,
                None,
                None,
                View::new(&s.c.buffer, u64::from(half) * plane)?,
                ConvShape {
                    cout: cout - half,
                    ..shape
                },
                Act::None,
            )?,
            ops::ha_gate(
                ctx,
                p,
                &s.a.buffer,
                &s.b.buffer,
                &s.c.buffer,
                &bn.buffer,
                tail,
                dst,
                cout,
                to_u32(plane, "plane")?,
                self.slope,
            )?,
        ];
        self.out.append(&mut d);
        Ok(())
    }

    /// BasicBlock: `relu(bn2(ha2(relu(bn1(ha1(x))))) + id)` into `dst`.
    fn basic(
        &mut self,
        b: &BasicWeights,
        x: View<'_>,
        h: u32,
        w: u32,
        dst: View<'_>,
    ) -> Result<()> {
        let (ho, wo) = (h / b.stride, w / b.stride);
        let y = self.s.y.buffer.clone();
        let d = self.s.d.buffer.clone();
        self.ha(
            &b.ha1,
            &b.bn1,
            x,
            (b.cin, h, w),
            b.cout,
            b.stride,
            GateTail::Relu,
            View::new(&y, 0)?,
        )?;
        let res = match &b.down {
            Some((dw, db)) => {
                let shape = ConvShape {
                    cin: b.cin,
                    h,
                    w,
                    cout: b.cout,
                    k: 1,
                    stride: b.stride,
                    pad: 0,
                };
                let op = ops::conv2d(
                    self.ctx,
                    self.precision,
                    x,
                    &dw.buffer,
                    Some(&db.buffer),
                    None,
                    View::new(&d, 0)?,
                    shape,
                    Act::None,
                )?;
                self.out.push(op);
                View::new(&d, 0)?
            }
            None => x,
        };
        self.ha(
            &b.ha2,
            &b.bn2,
            View::new(&y, 0)?,
            (b.cout, ho, wo),
            b.cout,
            1,
            GateTail::Residual(res),
            dst,
        )
    }

    /// ReverseBlock: `relu(conv(relu(up4(x))) + up2(x))` into `dst` ([cout, 2h, 2w]).
    fn reverse(
        &mut self,
        r: &ReverseWeights,
        x: View<'_>,
        h: u32,
        w: u32,
        dst: View<'_>,
    ) -> Result<()> {
        let (ctx, p) = (self.ctx, self.precision);
        let n = u64::from(r.cout) * u64::from(4 * h * w);
        self.fits(n, "ReverseBlock scratch")?;
        let s = &self.s;
        let up4 = ConvShape {
            cin: r.cin,
            h,
            w,
            cout: r.cout,
            k: 4,
            stride: 2,
            pad: 1,
        };
        let up2 = ConvShape {
            k: 2,
            pad: 0,
            ..up4
        };
        let conv = ConvShape {
            cin: r.cout,
            h: 2 * h,
            w: 2 * w,
            cout: r.cout,
            k: 3,
            stride: 1,
            pad: 1,
        };
        let mut d = vec![
            ops::conv_transpose2d(
                ctx,
                p,
                x,
                &r.up4.0.buffer,
                Some(&r.up4.1.buffer),
                View::new(&s.a.buffer, 0)?,
                up4,
                true,
            )?,
            ops::conv2d(
                ctx,
                p,
                View::new(&s.a.buffer, 0)?,
                &r.conv.0.buffer,
                Some(&r.conv.1.buffer),
                None,
                View::new(&s.b.buffer, 0)?,
                conv,
                Act::None,
            )?,
            ops::conv_transpose2d(
                ctx,
                p,
                x,
                &r.up2.0.buffer,
                Some(&r.up2.1.buffer),
                View::new(&s.c.buffer, 0)?,
                up2,
                false,
            )?,
            ops::elementwise(
                ctx,
                p,
                Elementwise::AddRelu(View::new(&s.c.buffer, 0)?),
                View::new(&s.b.buffer, 0)?,
                dst,
                to_u32(n, "elements")?,
            )?,
        ];
        self.out.append(&mut d);
        Ok(())
    }
}

/// LeakyReLU with `slope` after a layer, or nothing.
fn act(slope: Option<f32>) -> Act {
    slope.map_or(Act::None, Act::Leaky)
}

/// Records one product per layer, each feeding the next: layer `i` writes `last` when it is
/// the final layer and `hidden(i)` (ping-pong scratch) otherwise.
fn chain<T: Copy>(
    layers: &[Linear],
    input: T,
    hidden: impl Fn(usize) -> Result<T>,
    last: T,
    op: impl Fn(&Linear, T, T) -> Result<Dispatch>,
) -> Result<Vec<Dispatch>> {
    let mut x = input;
    let mut out = Vec::with_capacity(layers.len());
    for (i, l) in layers.iter().enumerate() {
        let y = if i + 1 == layers.len() {
            last
        } else {
            hidden(i)?
        };
        out.push(op(l, x, y)?);
        x = y;
    }
    Ok(out)
}

fn v(buf: &DeviceBuffer, base: u64) -> Result<View<'_>> {
    View::new(&buf.buffer, base)
}

impl GpuNetwork {
    /// Uploads `weights` to the caller's device. `Precision::F16` needs `SHADER_F16`.
    /// `adapter_type` (from `Adapter::get_info().device_type`) selects kernel variants.
    pub fn new(
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        adapter_type: wgpu::DeviceType,
        weights: &Weights,
        precision: Precision,
    ) -> Result<Self> {
        let ctx = GpuContext::new(device, queue, adapter_type)?;
        ctx.check_precision(precision)?;
        let unet = weights::upload_unet(&ctx, weights, precision)?;
        let render = weights::upload_render(&ctx, weights, precision)?;
        Ok(Self {
            ctx,
            precision,
            config: weights.config().clone(),
            unet,
            render,
            estimate_plans: HashMap::new(),
            render_plans: HashMap::new(),
        })
    }

    /// The device context (pipelines, queue).
    pub fn context(&self) -> &GpuContext {
        &self.ctx
    }

    /// Switches the render MLP's matmul variant (for comparisons and tests; all compute the
    /// same product). `Texture` needs the layer textures, uploaded by [`GpuNetwork::new`] only
    /// when the context chose that variant.
    pub fn set_matmul_variant(&mut self, variant: MatmulVariant) -> Result<()> {
        let r = &self.render;
        if variant == MatmulVariant::Texture && r.nd.iter().chain(&r.mlp).any(|l| l.tex.is_none()) {
            return Err(GpuError::Unsupported(
                "texture matmul: this network was built without layer textures".into(),
            ));
        }
        self.ctx.set_matmul_variant(variant);
        self.render_plans.clear();
        Ok(())
    }

    /// Multiply-adds of one `estimate` on an `h x w` image (after padding to multiples of
    /// [`UNET_MULTIPLE`]), counting every convolution tap as the CPU and torch do
    /// ([`ModelConfig::estimate_macs`]).
    pub fn estimate_macs(&self, h: usize, w: usize) -> u64 {
        self.config.estimate_macs(h, w)
    }

    /// Multiply-adds of `M_render` per query as stored in the file (l0 and l1 unfolded),
    /// the convention of DESIGN §4 (634,470 for the standard widths).
    pub fn render_macs_per_query(&self) -> u64 {
        self.config.render_macs(RenderWork {
            folded: false,
            prepared: false,
            directions: DirectionWork::PerOutput,
        })
    }

    /// Storage precision of this network.
    pub fn precision(&self) -> Precision {
        self.precision
    }

    fn build_estimate_plan(&self, h: u32, w: u32) -> Result<EstimatePlan> {
        let (ctx, p) = (&self.ctx, self.precision);
        let u = &self.unet;
        let c = u.width;
        let hw = u64::from(h) * u64::from(w);
        let c64 = u64::from(c);
        let scratch = 2 * c64 * hw;
        let mk = |label: &str, n: u64| ctx.storage(label, n, p);
        let s = Scratch {
            elems: scratch,
            a: mk("scratch a", scratch)?,
            b: mk("scratch b", scratch)?,
            c: mk("scratch c", scratch)?,
            t: mk("scratch t", scratch)?,
            y: mk("scratch y", scratch)?,
            d: mk("scratch d", scratch)?,
            norm: ctx.storage("instance norm", 2 * 12 * c64, Precision::F32)?,
        };
        // With an input skip the head reads cat([decoder output, input]) from one buffer:
        // the input sits after the decoder's C channels and dec4 writes in front of it.
        let cin = u64::from(u.in_channels);
        let input_at = if u.input_skip { c64 * hw } else { 0 };
        let input = mk("input", input_at + cin * hw)?;
        let output = mk("params", u64::from(u.param_channels) * hw)?;
        let stem_out = mk("stem", c64 * hw)?;
        let mid = mk("mid", 2 * c64 * hw)?;
        // dec4's output: the head's own buffer, or in front of the input (input skip).
        let mid2 = if u.input_skip {
            None
        } else {
            Some(mk("mid2", c64 * hw)?)
        };
        // Decoder inputs cat([x, skip]) live in one buffer each; encoders write skips in place.
        let cat4 = mk("cat4", 3 * c64 * hw)?; // [2C x | C e1] at H
        let cat3 = mk("cat3", 6 * c64 * hw / 4)?; // [4C x | 2C e2] at H/2
        let cat2 = mk("cat2", 12 * c64 * hw / 16)?; // [8C x | 4C e3] at H/4
        let e4 = mk("e4", 8 * c64 * hw / 64)?;
        let bott = mk("bottleneck", 8 * c64 * hw / 64)?;
        let mut b = UnetBuilder {
            ctx,
            precision: p,
            eps: u.eps,
            slope: u.ha_slope,
            s,
            out: Vec::new(),
        };
        b.out.push(ops::conv2d(
            ctx,
            p,
            v(&input, input_at)?,
            &u.stem.buffer,
            None,
            None,
            v(&stem_out, 0)?,
            ConvShape {
                cin: u.in_channels,
                h,
                w,
                cout: c,
                k: 7,
                stride: 1,
                pad: 3,
            },
            Act::None,
        )?);
        // Encoder: stage k writes its output where the decoder concatenation needs it.
        let skips = [
            v(&cat4, 2 * c64 * hw)?,
            v(&cat3, 4 * c64 * hw / 4)?,
            v(&cat2, 8 * c64 * hw / 16)?,
            v(&e4, 0)?,
        ];
        let mut x = v(&stem_out, 0)?;
        let (mut ch, mut cw) = (h, w);
        for (stage, skip) in u.enc.iter().zip(skips) {
            b.basic(&stage[0], x, ch, cw, v(&mid, 0)?)?;
            ch /= stage[0].stride;
            cw /= stage[0].stride;
            b.basic(&stage[1], v(&mid, 0)?, ch, cw, skip)?;
            x = skip;
        }
        let n4 = to_u32(8 * c64 * hw / 64, "elements")?;
        b.out.push(ops::elementwise(
            ctx,
            p,
            Elementwise::Atan,
            v(&e4, 0)?,
            v(&bott, 0)?,
            n4,
        )?);
        // Decoder stages 1..3: ReverseBlock (x2) then BasicBlock into the next concat buffer.
        let mut x = v(&bott, 0)?;
        for ((r, bb), dst) in u
            .dec_reverse
            .iter()
            .zip(&u.dec_basic)
            .zip([&cat2, &cat3, &cat4])
        {
            b.reverse(r, x, ch, cw, v(&mid, 0)?)?;
            ch *= 2;
            cw *= 2;
            b.basic(bb, v(&mid, 0)?, ch, cw, v(dst, 0)?)?;
            x = v(dst, 0)?;
        }
        b.basic(&u.dec4[0], v(&cat4, 0)?, h, w, v(&mid, 0)?)?;
        let head_in = mid2.as_ref().unwrap_or(&input);
        b.basic(&u.dec4[1], v(&mid, 0)?, h, w, v(head_in, 0)?)?;
        b.out.push(ops::conv2d(
            ctx,
            p,
            v(head_in, 0)?,
            &u.head.buffer,
            None,
            None,
            v(&output, 0)?,
            ConvShape {
                cin: u.head_in_channels(),
                h,
                w,
                cout: u.param_channels,
                k: 7,
                stride: 1,
                pad: 3,
            },
            Act::None,
        )?);
        Ok(EstimatePlan {
            input,
            input_at,
            output,
            dispatches: b.out,
        })
    }

    /// Runs `M_est` on one image.
    ///
    /// `input`: CHW `[in_channels, h, w]` network input (docs/FORMAT.md "Network input").
    /// Returns the param map HWC `[h, w, param_channels]`. Any size ≥ 1: the image is
    /// replicate-padded at the bottom/right to multiples of 8 and cropped back, like torch.
    pub fn estimate(&mut self, input: &[f32], h: usize, w: usize) -> Result<Vec<f32>> {
        let cin = self.unet.in_channels as usize;
        let pc = self.unet.param_channels as usize;
        if h == 0 || w == 0 {
            return Err(GpuError::Size {
                what: "image",
                reason: format!("{h}x{w} is empty"),
            });
        }
        let expected = cin
            .checked_mul(h)
            .and_then(|v| v.checked_mul(w))
            .ok_or_else(|| GpuError::Size {
                what: "image",
                reason: format!("{h}x{w} overflows"),
            })?;
        if input.len() != expected {
            return Err(GpuError::InputLength {
                what: "estimate input [C, H, W]",
                expected,
                got: input.len(),
            });
        }
        let hp = h.next_multiple_of(UNET_MULTIPLE);
        let wp = w.next_multiple_of(UNET_MULTIPLE);
        let key = (to_u32(hp as u64, "height")?, to_u32(wp as u64, "width")?);
        if !self.estimate_plans.contains_key(&key) {
            if self.estimate_plans.len() >= MAX_CACHED_PLANS {
                self.estimate_plans.clear();
            }
            let plan = self.build_estimate_plan(key.0, key.1)?;
            self.estimate_plans.insert(key, plan);
        }
        let plan = self
            .estimate_plans
            .get(&key)
            .ok_or_else(|| GpuError::Size {
                what: "plan",
                reason: "estimate plan missing after build".into(),
            })?;
        let mut padded = vec![0.0f32; cin * hp * wp];
        for c in 0..cin {
            for y in 0..hp {
                let sy = y.min(h - 1);
                let src = &input[(c * h + sy) * w..(c * h + sy + 1) * w];
                let dst = &mut padded[(c * hp + y) * wp..(c * hp + y + 1) * wp];
                dst[..w].copy_from_slice(src);
                dst[w..].fill(src[w - 1]);
            }
        }
        self.ctx.write(&plan.input, plan.input_at, &padded)?;
        self.ctx.run(&plan.dispatches)?;
        let chw = self.ctx.read(&plan.output, (pc * hp * wp) as u64)?;
        let mut hwc = vec![0.0f32; h * w * pc];
        for (c, plane) in chw.chunks_exact(hp * wp).enumerate() {
            for y in 0..h {
                for x in 0..w {
                    hwc[(y * w + x) * pc + c] = plane[y * wp + x];
                }
            }
        }
        Ok(hwc)
    }

    /// Whether render plans use textures: the context's matmul is [`MatmulVariant::Texture`],
    /// every layer has its texture and the params fill whole texels.
    fn texture_render(&self) -> bool {
        let r = &self.render;
        self.ctx.matmul_variant() == MatmulVariant::Texture
            && r.param_channels.is_multiple_of(4)
            && r.nd.iter().chain(&r.mlp).all(|l| l.tex.is_some())
    }

    /// Most rows of one render submission.
    fn render_chunk(&self) -> u32 {
        if self.texture_render() {
            MAX_RENDER_ROWS.min(self.ctx.device().limits().max_texture_dimension_2d)
        } else {
            MAX_RENDER_ROWS
        }
    }

    fn build_render_plan(&self, rows: u32, kind: RenderKind) -> Result<RenderPlan> {
        if self.texture_render() {
            self.build_render_plan_tex(rows, kind)
        } else {
            self.build_render_plan_buf(rows, kind)
        }
    }

    /// The render chain on textures: pos_enc_tex, then one `matmul_tex` per layer (only the
    /// render MLP's for [`RenderKind::ConstantDirections`]); the last layer writes the
    /// `[rows, 3]` output buffer.
    fn build_render_plan_tex(&self, rows: u32, kind: RenderKind) -> Result<RenderPlan> {
        let (ctx, p) = (&self.ctx, self.precision);
        let r = &self.render;
        let nd_out = r.nd.last().map_or(0, |l| l.out);
        let widest = r.nd.iter().chain(&r.mlp).map(|l| l.out).max().unwrap_or(1);
        let cat = ctx.texture(
            "params|nd",
            (r.param_channels + nd_out).div_ceil(4),
            rows,
            p,
        )?;
        let ping = [
            ctx.texture("mlp ping", widest.div_ceil(4), rows, p)?,
            ctx.texture("mlp pong", widest.div_ceil(4), rows, p)?,
        ];
        let out_w = r.mlp.last().map_or(0, |l| l.out);
        let out = ctx.storage("radiance log", u64::from(out_w) * u64::from(rows), p)?;
        let missing = || GpuError::Unsupported("render layer without texture".into());
        let op = |l: &Linear, x: TexOut<'_>, y: TexOut<'_>| {
            let TexOut::Texture { tex: xt, .. } = x else {
                return Err(GpuError::Unsupported("buffer input to matmul_tex".into()));
            };
            let w = l.tex.as_ref().ok_or_else(missing)?;
            ops::matmul_tex(ctx, xt, w, y, rows, l.out, l.inp, act(l.slope))
        };
        let tex = |tex, texel_base| TexOut::Texture { tex, texel_base };
        let general = kind == RenderKind::General;
        let dirs = general
            .then(|| ctx.storage("dirs", 9 * u64::from(rows), Precision::F32))
            .transpose()?;
        let enc = general
            .then(|| ctx.texture("encoding", r.encoding.div_ceil(4), rows, p))
            .transpose()?;
        let mut d = Vec::new();
        if let (Some(dir), Some(enc)) = (&dirs, &enc) {
            d.push(ops::pos_enc_tex(ctx, &dir.buffer, rows, r.octaves, enc)?);
            d.extend(chain(
                &r.nd,
                tex(enc, 0),
                |i| Ok(tex(&ping[i % 2], 0)),
                tex(&cat, r.param_channels / 4),
                op,
            )?);
        }
        let to_out = TexOut::Buffer {
            buf: &out.buffer,
            stride: out_w,
        };
        d.extend(chain(
            &r.mlp,
            tex(&cat, 0),
            |i| Ok(tex(&ping[i % 2], 0)),
            to_out,
            op,
        )?);
        Ok(RenderPlan {
            dirs,
            cat: Cat::Texture(cat),
            out,
            dispatches: d,
        })
    }

    fn build_render_plan_buf(&self, rows: u32, kind: RenderKind) -> Result<RenderPlan> {
        let (ctx, p) = (&self.ctx, self.precision);
        let r = &self.render;
        let n = u64::from(rows);
        let nd_out = r.nd.last().map_or(0, |l| l.out);
        let cat_w = r.param_channels + nd_out;
        let widest =
            r.nd.iter()
                .chain(&r.mlp)
                .map(|l| l.out.max(l.inp))
                .max()
                .unwrap_or(1);
        let cat = ctx.storage("params|nd", u64::from(cat_w) * n, p)?;
        let ping = [
            ctx.storage("mlp ping", u64::from(widest) * n, p)?,
            ctx.storage("mlp pong", u64::from(widest) * n, p)?,
        ];
        let out_w = r.mlp.last().map_or(0, |l| l.out);
        let out = ctx.storage("radiance log", u64::from(out_w) * n, p)?;
        let op = |l: &Linear, x, y| {
            ops::matmul(
                ctx,
                p,
                x,
                &l.weight.buffer,
                y,
                rows,
                l.out,
                l.inp,
                act(l.slope),
            )
        };
        // Hidden activations are packed at the layer's width (its consumer reads the same).
        let hidden = |i: usize, width: u32| -> Result<Rows<'_>> {
            Ok(Rows {
                view: View::new(&ping[i % 2].buffer, 0)?,
                stride: width,
            })
        };
        let nd_last = Rows {
            view: View::new(&cat.buffer, u64::from(r.param_channels))?,
            stride: cat_w,
        };
        let general = kind == RenderKind::General;
        let dirs = general
            .then(|| ctx.storage("dirs", 9 * n, Precision::F32))
            .transpose()?;
        let enc = general
            .then(|| ctx.storage("encoding", u64::from(r.encoding) * n, p))
            .transpose()?;
        let mut d = Vec::new();
        if let (Some(dir), Some(enc)) = (&dirs, &enc) {
            d.push(ops::pos_enc(
                ctx,
                p,
                &dir.buffer,
                rows,
                r.octaves,
                View::new(&enc.buffer, 0)?,
                r.encoding,
            )?);
            let enc_rows = Rows {
                view: View::new(&enc.buffer, 0)?,
                stride: r.encoding,
            };
            d.extend(chain(
                &r.nd,
                enc_rows,
                |i| hidden(i, r.nd[i].out),
                nd_last,
                op,
            )?);
        }
        let cat_rows = Rows {
            view: View::new(&cat.buffer, 0)?,
            stride: cat_w,
        };
        let out_rows = Rows {
            view: View::new(&out.buffer, 0)?,
            stride: out_w,
        };
        d.extend(chain(
            &r.mlp,
            cat_rows,
            |i| hidden(i, r.mlp[i].out),
            out_rows,
            op,
        )?);
        Ok(RenderPlan {
            dirs,
            cat: Cat::Buffer(cat),
            out,
            dispatches: d,
        })
    }

    /// Runs `M_render` in chunks; returns (log-space output `[n, 3]`, ND_enc output `[n, 32]`
    /// when `want_nd` and the directions are per row).
    fn run_render(
        &mut self,
        params: &[f32],
        dirs: RowDirections<'_>,
        want_nd: bool,
    ) -> Result<(Vec<f32>, Vec<f32>)> {
        let pc = self.render.param_channels as usize;
        let nd_out = self.render.nd.last().map_or(0, |l| l.out) as usize;
        if !params.len().is_multiple_of(pc) {
            return Err(GpuError::InputLength {
                what: "params [N, param_channels]",
                expected: params.len().next_multiple_of(pc),
                got: params.len(),
            });
        }
        let n = params.len() / pc;
        let kind = match dirs {
            RowDirections::Each(d) => {
                if d.len() != n * 9 {
                    return Err(GpuError::InputLength {
                        what: "directions [N, 9]",
                        expected: n * 9,
                        got: d.len(),
                    });
                }
                RenderKind::General
            }
            RowDirections::ConstantFeatures(f) => {
                if f.len() != nd_out {
                    return Err(GpuError::InputLength {
                        what: "ND_enc features [nd_out]",
                        expected: nd_out,
                        got: f.len(),
                    });
                }
                RenderKind::ConstantDirections
            }
        };
        let want_nd = want_nd && kind == RenderKind::General;
        let out_w = self.render.mlp.last().map_or(0, |l| l.out) as usize;
        let cat_w = pc + nd_out;
        let mut log = Vec::with_capacity(n * out_w);
        let mut nd = Vec::with_capacity(if want_nd { n * nd_out } else { 0 });
        let max_rows = self.render_chunk() as usize;
        let mut start = 0;
        while start < n {
            let rows = (n - start).min(max_rows);
            let key = (to_u32(rows as u64, "rows")?, kind);
            if !self.render_plans.contains_key(&key) {
                if self.render_plans.len() >= MAX_CACHED_PLANS {
                    self.render_plans.clear();
                }
                let plan = self.build_render_plan(key.0, kind)?;
                self.render_plans.insert(key, plan);
            }
            let plan = self.render_plans.get(&key).ok_or_else(|| GpuError::Size {
                what: "plan",
                reason: "render plan missing after build".into(),
            })?;
            let chunk = &params[start * pc..(start + rows) * pc];
            match (&plan.cat, dirs) {
                (Cat::Texture(tex), RowDirections::Each(_)) => {
                    self.ctx.write_texture(tex, 0, chunk, pc)?;
                }
                (cat, _) => {
                    // Rows `[params | ND_enc]`, padded to whole texels for a texture; the
                    // ND_enc part is the shared features or zeros the plan overwrites.
                    let width = match cat {
                        Cat::Buffer(_) => cat_w,
                        Cat::Texture(tex) => 4 * tex.texels as usize,
                    };
                    let mut rows_cat = vec![0.0f32; rows * width];
                    for (dst, src) in rows_cat.chunks_exact_mut(width).zip(chunk.chunks_exact(pc)) {
                        dst[..pc].copy_from_slice(src);
                        if let RowDirections::ConstantFeatures(f) = dirs {
                            dst[pc..cat_w].copy_from_slice(f);
                        }
                    }
                    match cat {
                        Cat::Buffer(buf) => self.ctx.write(buf, 0, &rows_cat)?,
                        Cat::Texture(tex) => self.ctx.write_texture(tex, 0, &rows_cat, width)?,
                    }
                }
            }
            if let (Some(buf), RowDirections::Each(d)) = (&plan.dirs, dirs) {
                self.ctx.write(buf, 0, &d[start * 9..(start + rows) * 9])?;
            }
            self.ctx.run(&plan.dispatches)?;
            log.extend(self.ctx.read(&plan.out, (rows * out_w) as u64)?);
            if want_nd {
                let (c, width) = match &plan.cat {
                    Cat::Buffer(buf) => (self.ctx.read(buf, (rows * cat_w) as u64)?, cat_w),
                    Cat::Texture(tex) => {
                        (self.ctx.read_texture(tex, key.0)?, 4 * tex.texels as usize)
                    }
                };
                for row in c.chunks_exact(width) {
                    nd.extend_from_slice(&row[pc..cat_w]);
                }
            }
            start += rows;
        }
        Ok((log, nd))
    }

    /// Evaluates `M_render` for `N` queries and returns radiance `[N, 3]`,
    /// `max(expm1(y), 0)` of the network's log-space output.
    ///
    /// `params`: `[N, param_channels]` rows; `dirs`: `[N, 9]` rows `[ωi, ωo, ωh]`.
    pub fn render(&mut self, params: &[f32], dirs: &[f32]) -> Result<Vec<f32>> {
        let (log, _) = self.run_render(params, RowDirections::Each(dirs), false)?;
        Ok(log.into_iter().map(radiance_from_log).collect())
    }

    /// As [`GpuNetwork::render`] but returns the log-space output `y` `[N, 3]`.
    pub fn render_log(&mut self, params: &[f32], dirs: &[f32]) -> Result<Vec<f32>> {
        Ok(self.run_render(params, RowDirections::Each(dirs), false)?.0)
    }

    /// Log-space output `[N, 3]` and the ND_enc output `[N, 32]` (for parity checks).
    pub fn render_log_with_nd(
        &mut self,
        params: &[f32],
        dirs: &[f32],
    ) -> Result<(Vec<f32>, Vec<f32>)> {
        self.run_render(params, RowDirections::Each(dirs), true)
    }

    /// Radiance `[N, 3]` of `N` param rows all seen with the same directions `dirs` =
    /// `[ωi, ωo, ωh]` (a directional light and an orthographic view, DESIGN §9): the
    /// positional encoding and ND_enc run once, on one row, and every row runs only the
    /// render MLP (about 13% of [`GpuNetwork::render`]'s multiply-adds per row). Equals
    /// `render` with `dirs` repeated per row up to f32 summation order.
    pub fn render_directional(&mut self, params: &[f32], dirs: &[f32; 9]) -> Result<Vec<f32>> {
        Ok(self
            .render_log_directional(params, dirs)?
            .into_iter()
            .map(radiance_from_log)
            .collect())
    }

    /// As [`GpuNetwork::render_directional`] but returns the log-space output `y` `[N, 3]`.
    pub fn render_log_directional(&mut self, params: &[f32], dirs: &[f32; 9]) -> Result<Vec<f32>> {
        let pc = self.render.param_channels as usize;
        let Some(first) = params.get(..pc) else {
            if params.is_empty() {
                return Ok(Vec::new());
            }
            return Err(GpuError::InputLength {
                what: "params [N, param_channels]",
                expected: pc,
                got: params.len(),
            });
        };
        let (_, nd) = self.run_render(first, RowDirections::Each(dirs), true)?;
        Ok(self
            .run_render(params, RowDirections::ConstantFeatures(&nd), false)?
            .0)
    }

    /// Multiply-adds per row of [`GpuNetwork::render_directional`]: the render MLP as
    /// uploaded (l0·l1 folded), the shared ND_enc features still multiplied per row, the
    /// one-off ND_enc row not counted.
    pub fn render_directional_macs_per_query(&self) -> u64 {
        self.config.render_macs(RenderWork {
            folded: true,
            prepared: false,
            directions: DirectionWork::FeaturesShared,
        })
    }
}
