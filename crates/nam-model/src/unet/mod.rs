//! `M_est`, fast path: HWC activations, convolutions over bands of output rows (rayon) — as
//! Winograd F(4×4, 3×3) or direct register tiles on AVX-512, else im2col + blocked GEMM —,
//! convs that read the same input fused into one (gate, inc1a, inc2 and the 1×1 `down` as a
//! centre tap), transposed convs split into output-parity sub-convolutions.
//!
//! This file holds [`UNet`] (packing and the forward pass) and the image checks;
//! `blocks.rs` the HA-Conv, BasicBlock and ReverseBlock; `conv.rs` the convolution
//! primitives they are built from (`direct.rs`, `winograd.rs`: the AVX-512 kernels;
//! `amx_conv.rs`: the bf16 one on AMX tiles).

use nam_weights::Weights;

use crate::error::{ModelError, Result, check_finite, check_len};
use crate::maps::ParamMap;

mod amx_conv;
mod blocks;
mod conv;
mod direct;
mod winograd;

use blocks::{Basic, Reverse};
use conv::{Hwc, PackedConv, concat};

/// Largest accepted image side, in pixels (guards size arithmetic).
pub const MAX_SIDE: usize = 1 << 15;

/// Largest difference of a [`UNet::with_bf16`] param map from the f32 one (torch's), per value
/// `|a − b| / (1 + |b|)`, on the embedded model's golden photo (`tests/parity.rs`).
pub const BF16_PARAM_TOL: f32 = 2e-2;

pub(crate) fn pad_multiple(n: usize) -> usize {
    n.next_multiple_of(nam_weights::UNET_MULTIPLE)
}

pub(crate) fn check_image(height: usize, width: usize) -> Result<()> {
    let bad = |reason| {
        Err(ModelError::ImageSize {
            height,
            width,
            reason,
        })
    };
    if height == 0 || width == 0 {
        return bad("zero-sized");
    }
    if height > MAX_SIDE || width > MAX_SIDE {
        return bad("side larger than 32768");
    }
    Ok(())
}

/// `M_est` on the CPU, packed for the fast path.
#[derive(Debug, Clone)]
pub struct UNet {
    /// `C`, the width of the first level.
    width: usize,
    in_channels: usize,
    /// The head sees `[decoder output, network input]` (`ModelConfig::input_skip`).
    input_skip: bool,
    params: usize,
    eps: f32,
    slope: f32,
    stem: PackedConv,
    enc: Vec<Basic>,
    dec1: (Reverse, Basic),
    dec2: (Reverse, Basic),
    dec3: (Reverse, Basic),
    dec4: (Basic, Basic),
    head: PackedConv,
}

impl UNet {
    /// Packs the `est.*` tensors of validated weights.
    pub fn new(weights: &Weights) -> Result<Self> {
        let cfg = weights.config();
        let c = cfg.width;
        let est = weights.scope("est");
        let mut enc = Vec::new();
        let mut prev = c;
        for (k, w) in [c, 2 * c, 4 * c, 8 * c].into_iter().enumerate() {
            let s = if k == 0 { 1 } else { 2 };
            enc.push(Basic::new(
                &est.scope(&format!("enc{}.0", k + 1)),
                prev,
                w,
                s,
            )?);
            enc.push(Basic::new(&est.scope(&format!("enc{}.1", k + 1)), w, w, 1)?);
            prev = w;
        }
        Ok(Self {
            width: c,
            in_channels: cfg.in_channels,
            input_skip: cfg.input_skip,
            params: cfg.param_channels,
            eps: cfg.norm_eps,
            slope: cfg.slopes.ha,
            stem: PackedConv::fused(
                &[(est.get("stem.weight", &[c, cfg.in_channels, 7, 7])?, c, 7)],
                cfg.in_channels,
                7,
                1,
            ),
            enc,
            dec1: (
                Reverse::new(&est.scope("dec1.0"), 8 * c, 8 * c)?,
                Basic::new(&est.scope("dec1.1"), 8 * c, 8 * c, 1)?,
            ),
            dec2: (
                Reverse::new(&est.scope("dec2.0"), 12 * c, 4 * c)?,
                Basic::new(&est.scope("dec2.1"), 4 * c, 4 * c, 1)?,
            ),
            dec3: (
                Reverse::new(&est.scope("dec3.0"), 6 * c, 2 * c)?,
                Basic::new(&est.scope("dec3.1"), 2 * c, 2 * c, 1)?,
            ),
            dec4: (
                Basic::new(&est.scope("dec4.0"), 3 * c, c, 1)?,
                Basic::new(&est.scope("dec4.1"), c, c, 1)?,
            ),
            head: PackedConv::fused(
                &[(
                    est.get(
                        "head.weight",
                        &[cfg.param_channels, cfg.head_in_channels(), 7, 7],
                    )?,
                    cfg.param_channels,
                    7,
                )],
                cfg.head_in_channels(),
                7,
                1,
            ),
        })
    }

    /// The same network with bf16 products and f32 sums in its convolutions, where the CPU has
    /// AVX-512 BF16: about twice the products per instruction (`vdpbf16ps`), or on AMX tiles
    /// where the CPU has AMX-BF16 (`amx_conv.rs`, and the ReverseBlocks' GEMMs as bf16 dense
    /// layers; [`crate::bf16_kernel`] names the one used), the param map within
    /// [`BF16_PARAM_TOL`] of f32's. Errors when the CPU lacks the instructions.
    pub fn with_bf16(mut self) -> Result<Self> {
        if !direct::available_bf16() {
            return Err(ModelError::Unsupported(
                "a bf16 estimate needs a CPU with AVX-512 BF16",
            ));
        }
        self.set_bf16(true);
        Ok(self)
    }

    /// The same network with f32 products (undoes [`Self::with_bf16`]).
    pub fn with_f32(mut self) -> Self {
        self.set_bf16(false);
        self
    }

    fn set_bf16(&mut self, on: bool) {
        self.convs_mut().into_iter().for_each(|c| c.bf16 = on);
        for r in [&mut self.dec1.0, &mut self.dec2.0, &mut self.dec3.0] {
            r.set_bf16(on);
        }
    }

    /// The same network with every conv on the direct tiles (or im2col), none as Winograd: the
    /// same values within the Winograd path's rounding, for timing the two in one run
    /// (`nam-cli bench`, the criterion benches).
    pub fn without_winograd(mut self) -> Self {
        self.convs_mut()
            .into_iter()
            .for_each(|c| c.winograd = false);
        self
    }

    /// Every k×k convolution of the network (the ReverseBlocks' transposed ones excluded).
    fn convs_mut(&mut self) -> Vec<&mut PackedConv> {
        let mut convs = vec![&mut self.stem, &mut self.head];
        for b in self
            .enc
            .iter_mut()
            .chain([&mut self.dec1.1, &mut self.dec2.1, &mut self.dec3.1])
            .chain([&mut self.dec4.0, &mut self.dec4.1])
        {
            convs.extend(b.convs_mut());
        }
        convs.extend([
            &mut self.dec1.0.conv,
            &mut self.dec2.0.conv,
            &mut self.dec3.0.conv,
        ]);
        convs
    }

    /// Whether [`Self::with_bf16`] made this network's products bf16.
    pub fn is_bf16(&self) -> bool {
        self.stem.bf16
    }

    /// Heap bytes [`Self::estimate`] holds at its peak for a `height × width` input, the returned
    /// param map (f32) included, the input not. The larger of two full-resolution stages: the
    /// last BasicBlocks of the decoder (per pixel their input, first HA-Conv output, centred
    /// copy, output and the skip `e1`: ≈ 9·C floats; plus one band of an HA-Conv's fused GEMM
    /// and inc1b per rayon thread, ≈ 8·C floats for up to [`blocks::HA_BAND_PIXELS`] pixels)
    /// or the head (its 64 outputs and its input). On top, each rayon thread's conv scratch: its direct band or
    /// Winograd piece, or its im2col band. `tests/memory.rs` checks it against a
    /// counting allocator (docs/perf/unet_memory.md).
    pub fn peak_bytes(&self, height: usize, width: usize) -> u64 {
        let (hp, wp) = (pad_multiple(height), pad_multiple(width));
        let pixels = hp * wp;
        let (c, i) = (self.width, self.in_channels);
        let head_in = c + if self.input_skip { i } else { 0 };
        // One band of an HA-Conv per thread at most (`blocks::Ha::run`: its rows and a halo row
        // either side).
        let threads = rayon::current_num_threads();
        let rows = (blocks::HA_BAND_PIXELS / wp).clamp(1, hp.div_ceil(2 * threads).max(1));
        let bands = threads.min(hp.div_ceil(rows));
        let decoder = pixels * (9 * c + 2 * i) + bands * ((rows + 2) * wp).min(pixels) * 8 * c;
        let head = pixels * (self.params + head_in + i);
        // Per rayon thread, the conv scratch: the direct path's padded input band (the widest
        // input of a level: the 7×7 head or stem, dec4's 3·C at full size, then 2·C, 4·C and
        // 8·C channels at 1/2, 1/4 and 1/8 of the side), else one im2col band, whose widest row
        // is the 7×7 stem's or head's, or a 3×3 conv's over 12·C channels (dec2).
        let scratch = if direct::available() {
            let direct = [(wp, 7, head_in.max(i)), (wp, 3, 3 * c), (wp / 2, 3, 2 * c)]
                .into_iter()
                .chain([(wp / 4, 3, 4 * c), (wp / 8, 3, 8 * c)])
                .map(|(w, k, ch)| direct::scratch_floats(w, k, ch))
                .max()
                .unwrap_or(0);
            // Or (one conv runs at a time) a Winograd conv's transformed weights and one piece
            // per thread, at a full-resolution stage, where the peak is (deeper levels hold a
            // quarter of the activations or less): the 7×7 head, or dec4's fused HA-Conv
            // columns (3·C inputs, 4.5·C outputs).
            let winograd = [(7, head_in, self.params), (3, 3 * c, 9 * c / 2)].map(|(k, ci, co)| {
                winograd::weight_floats(k, ci, co) + threads * winograd::scratch_floats(k, ci, co)
            });
            (threads * direct).max(winograd[0]).max(winograd[1])
        } else {
            threads * conv::BAND_PIXELS.max(wp) * (49 * head_in).max(49 * i).max(9 * 12 * c)
        };
        4 * (decoder.max(head) + scratch) as u64
    }

    /// Runs `M_est` on the network input (CHW, `in_channels × height × width`,
    /// docs/FORMAT.md) and returns the param map (HWC). Any size: the input is
    /// replicate-padded bottom/right to a multiple of 8 and the output cropped.
    pub fn estimate(&self, input: &[f32], height: usize, width: usize) -> Result<ParamMap> {
        // On one of rayon's threads: from any other thread each parallel loop of the network
        // (hundreds of them) would be handed to the pool and waited for on its own.
        rayon::scope(|_| self.estimate_here(input, height, width))
    }

    /// [`Self::estimate`] on the calling thread's rayon pool.
    fn estimate_here(&self, input: &[f32], height: usize, width: usize) -> Result<ParamMap> {
        check_image(height, width)?;
        let ci = self.in_channels;
        check_len("network input", ci * height * width, input.len())?;
        check_finite("network input", input)?;
        let (hp, wp) = (pad_multiple(height), pad_multiple(width));
        let mut d = vec![0.0f32; hp * wp * ci];
        for y in 0..hp {
            for x in 0..wp {
                for c in 0..ci {
                    d[(y * wp + x) * ci + c] =
                        input[(c * height + y.min(height - 1)) * width + x.min(width - 1)];
                }
            }
        }
        let (eps, sl) = (self.eps, self.slope);
        let photo = Hwc {
            h: hp,
            w: wp,
            c: ci,
            d,
        };
        // Every activation is dropped as soon as its last reader has run: the peak is then
        // one level's working set plus the skips and the param map (docs/perf/unet_memory.md).
        let stem = self.stem.run(&photo);
        // Encoder outputs e1..e4; e1..e3 are the decoder's skips.
        let mut skips: Vec<Hwc> = Vec::with_capacity(4);
        for pair in self.enc.chunks_exact(2) {
            let input = skips.last().unwrap_or(&stem);
            let y = pair[1].run(&pair[0].run(input, eps, sl), eps, sl);
            skips.push(y);
        }
        drop(stem);
        let mut x = skips.pop().expect("four encoder levels");
        x.d.iter_mut().for_each(|v| *v = v.atan());
        let x = self.dec1.1.run(&self.dec1.0.run(&x), eps, sl);
        let up = |x: Hwc, skip: Hwc, (rev, basic): &(Reverse, Basic)| {
            let cat = concat(&x, &skip);
            drop((x, skip));
            let r = rev.run(&cat);
            drop(cat);
            basic.run(&r, eps, sl)
        };
        let e3 = skips.pop().expect("e3");
        let x = up(x, e3, &self.dec2);
        let e2 = skips.pop().expect("e2");
        let x = up(x, e2, &self.dec3);
        let e1 = skips.pop().expect("e1");
        let cat = concat(&x, &e1);
        drop((x, e1));
        let y = self.dec4.0.run(&cat, eps, sl);
        drop(cat);
        let x = self.dec4.1.run(&y, eps, sl);
        drop(y);
        let out = if self.input_skip {
            let cat = concat(&x, &photo);
            drop((x, photo));
            self.head.run(&cat)
        } else {
            drop(photo);
            self.head.run(&x)
        };
        let pc = self.params;
        // Crop the padding in place (rows move left; the spare capacity is at most 7 rows and
        // columns of the padded map).
        let mut data = out.d;
        if (height, width) != (hp, wp) {
            for y in 1..height {
                data.copy_within(y * wp * pc..(y * wp + width) * pc, y * width * pc);
            }
            data.truncate(height * width * pc);
        }
        Ok(ParamMap {
            height,
            width,
            channels: pc,
            data,
        })
    }
}
