//! `M_render`, fast path: positional encoding → ND_enc → render MLP, fused per
//! cache-sized tile of pixels/queries, GEMMs through [`crate::sgemm`], rayon
//! over tiles. Peak extra memory is `threads × tile scratch`, independent of
//! the image size.
//!
//! Every path goes through one tile kernel ([`RenderNet::run_tile`]) that
//! splits the first render layer `W·[p, f]` into a material part `W_p·p` and a
//! direction part `W_d·f` (DESIGN §9):
//!
//! * the material part comes from the param map (a GEMM with k = 64) or from a
//!   [`PreparedMaterial`](crate::PreparedMaterial) (precomputed once, copied);
//! * the direction part is the per-query ND_enc output (a GEMM with k = 32,
//!   accumulated), caller-given features, or one constant vector when ωi, ωo
//!   are the same at every pixel (directional light, orthographic view).
//!
//! This file holds [`RenderNet`] (construction, sizes, multiply-add counts) and its public
//! entry points; `tile.rs` the tile kernel they all run.

use nam_weights::{
    DirectionWork, LinearLayer, ModelConfig, RenderWork, Weights, radiance_from_log,
};

use crate::Source;
use crate::bf16::{Bf16Dense, bf16_supported};
use crate::dense::{Dense, Reduced};
use crate::encoding::{direction_triple, encode_into, encoded_len};
use crate::error::{ModelError, Result, check_finite, check_len};
use crate::geometry::{Directions, pixel_position};
use crate::int8::{Int8Dense, int8_supported};
use crate::maps::{ParamMap, Rgb};

mod choose;
mod interpolated;
mod tile;

pub use choose::ProbeTime;
pub use interpolated::interpolation_step;

pub(crate) use tile::{Base, Dirs, NoDirs};

/// Pixels per fused tile. 256 keeps a tile's activations (256×594 f32 ≈ 600 KB
/// for the two widest) near the per-core L2 while giving GEMMs enough rows.
pub const DEFAULT_TILE: usize = 256;

/// `M_render` ready to run: ND_enc layers and the render MLP with `render.l0`
/// and `render.l1` folded into one matrix (no activation between them).
///
/// Linear-layer folding (DESIGN §4, §9): the only other pair of consecutive
/// layers without an activation between them is ND_enc's last layer
/// (594→32) feeding the direction columns of the first render layer (32→128).
/// It is deliberately **not** folded: the folded 594→128 matrix costs 76,032
/// multiply-adds per query against 594·32 + 32·128 = 23,104 unfolded (3.3×
/// more), and in the directional path both run once per image anyway.
/// Folding `render.l0·l1` (96·128 + 128·128 = 28,672 → 96·128 = 12,288 per
/// pixel) lowers the cost and is applied; [`RenderNet::new_unfolded`] keeps
/// them apart to measure and test it.
#[derive(Debug, Clone)]
pub struct RenderNet {
    pub(crate) octaves: usize,
    pub(crate) params: usize,
    pub(crate) nd: Vec<Dense>,
    /// `render[0]` is the first render layer `[params, nd] → hidden`.
    pub(crate) render: Vec<Dense>,
    pub(crate) tile: usize,
    /// Reduced-precision twins of `nd` and of `render[1..]` after [`RenderNet::with_bf16`] or
    /// [`RenderNet::with_int8`] (the first render layer always stays f32).
    reduced: Option<ReducedLayers>,
    /// Hash of the first render layer: ties a prepared material to this net.
    pub(crate) first_id: u64,
    /// The architecture: the multiply-add counts derive from it.
    config: ModelConfig,
    /// `render.l0·l1` folded into `render[0]`.
    folded: bool,
}

impl RenderNet {
    /// Builds the network from validated weights (folding `render.l0·l1`, in f64).
    pub fn new(weights: &Weights) -> Result<Self> {
        Self::build(weights, true)
    }

    /// Like [`Self::new`] but keeps `render.l0` and `render.l1` as two layers,
    /// as stored: the same function with 16,384 more multiply-adds per pixel.
    /// For measuring and testing the fold; use [`Self::new`] otherwise.
    pub fn new_unfolded(weights: &Weights) -> Result<Self> {
        Self::build(weights, false)
    }

    fn build(weights: &Weights, fold: bool) -> Result<Self> {
        let cfg = weights.config();
        let layers = weights.render_layers(fold)?;
        let dense = |l: &LinearLayer| Dense::from_w(&l.weight, l.out, l.inp, l.slope);
        let nd = layers.nd_enc.iter().map(dense).collect();
        let render: Vec<Dense> = layers.mlp.iter().map(dense).collect();
        // FNV-1a over the first layer's bits and shape.
        let first_id = render[0]
            .wt
            .iter()
            .map(|v| u64::from(v.to_bits()))
            .chain([render[0].inp as u64, render[0].out as u64])
            .fold(0xcbf2_9ce4_8422_2325u64, |h, v| {
                (h ^ v).wrapping_mul(0x0100_0000_01b3)
            });
        Ok(Self {
            octaves: cfg.pe_octaves,
            params: cfg.param_channels,
            nd,
            render,
            tile: DEFAULT_TILE,
            reduced: None,
            first_id,
            config: cfg.clone(),
            folded: fold,
        })
    }

    /// Sets the number of pixels per fused tile (≥ 1).
    pub fn with_tile(mut self, tile: usize) -> Self {
        self.tile = tile.max(1);
        self
    }

    /// Switches the fused paths ([`Self::relight`], [`Self::render_batch`], …) to
    /// bf16 products with f32 accumulation (AVX-512 BF16 or AMX tiles; ~2× faster, log-space
    /// differences of order 1e-3) for ND_enc and the render layers after the
    /// first (which stays f32). Errors when the CPU lacks the instructions.
    pub fn with_bf16(self) -> Result<Self> {
        if !bf16_supported() {
            return Err(ModelError::Unsupported(
                "bf16 needs AVX-512 BF16 (avx512bf16)",
            ));
        }
        Ok(self.with_reduced(Precision::Bf16, |w, l| {
            Reduced::Bf16(Bf16Dense::new(w, l.out, l.inp, l.slope))
        }))
    }

    /// Like [`Self::with_bf16`] with int8 products (AVX-512 VNNI `vpdpbusd`, i32 sums): weights
    /// quantised per output channel, activations per row at run time (see `int8.rs`). Errors
    /// when the CPU lacks the instructions.
    pub fn with_int8(self) -> Result<Self> {
        if !int8_supported() {
            return Err(ModelError::Unsupported(
                "int8 needs AVX-512 VNNI (avx512vnni)",
            ));
        }
        Ok(self.with_reduced(Precision::Int8, |w, l| {
            Reduced::Int8(Int8Dense::new(w, l.out, l.inp, l.slope))
        }))
    }

    /// Twins of `nd` and `render[1..]` built by `twin(W [out, inp], layer)`.
    fn with_reduced(
        mut self,
        precision: Precision,
        twin: impl Fn(&[f32], &Dense) -> Reduced,
    ) -> Self {
        let twins = |layers: &[Dense]| -> Vec<Reduced> {
            layers
                .iter()
                .map(|l| {
                    // Back to [out, inp] for packing.
                    let mut w = vec![0.0f32; l.out * l.inp];
                    for i in 0..l.inp {
                        for o in 0..l.out {
                            w[o * l.inp + i] = l.wt[i * l.out + o];
                        }
                    }
                    twin(&w, l)
                })
                .collect()
        };
        self.reduced = Some(ReducedLayers {
            precision,
            nd: twins(&self.nd),
            tail: twins(&self.render[1..]),
        });
        self
    }

    /// The products the fused paths compute in.
    pub fn precision(&self) -> Precision {
        self.reduced
            .as_ref()
            .map_or(Precision::F32, |r| r.precision)
    }

    /// Whether the bf16 path is active.
    pub fn is_bf16(&self) -> bool {
        self.precision() == Precision::Bf16
    }

    /// Parameter channels per pixel (64).
    pub fn param_channels(&self) -> usize {
        self.params
    }

    /// Length of the positional encoding (297).
    pub fn encoded_len(&self) -> usize {
        encoded_len(self.octaves)
    }

    /// Output width of ND_enc (32).
    pub fn nd_len(&self) -> usize {
        self.nd.last().map_or(0, |l| l.out)
    }

    /// Width of the first render layer's output (128): the values per texel
    /// of a [`PreparedMaterial`](crate::PreparedMaterial).
    pub fn hidden_len(&self) -> usize {
        self.render[0].out
    }

    /// Multiply-adds per output pixel/query of a render path
    /// ([`ModelConfig::render_macs`] with this net's folding): everything
    /// (`prepared = false, constant_directions = false`: the general path)
    /// minus `W_p·p` when the material is prepared, minus the encoding's
    /// ND_enc and `W_d·f` when ωi, ωo are the same for every output.
    pub fn macs_per_output(&self, prepared: bool, constant_directions: bool) -> usize {
        let directions = if constant_directions {
            DirectionWork::Shared
        } else {
            DirectionWork::PerOutput
        };
        let macs = self.config.render_macs(RenderWork {
            folded: self.folded,
            prepared,
            directions,
        });
        usize::try_from(macs).unwrap_or(usize::MAX)
    }

    /// Positional encoding of `n` queries into `out` (`n × encoded_len`), ωh computed.
    pub fn encode(&self, wi: &[[f32; 3]], wo: &[[f32; 3]], out: &mut [f32]) -> Result<()> {
        check_len("wo", wi.len(), wo.len())?;
        let e = self.encoded_len();
        check_len("encoded", wi.len() * e, out.len())?;
        for (q, o) in out.chunks_exact_mut(e).enumerate() {
            encode_into(&direction_triple(wi[q], wo[q]), self.octaves, o);
        }
        Ok(())
    }

    /// Positional encoding of `n` precomputed direction triples `[ωi, ωo, ωh]`
    /// (`dirs`: `n × 9`) into `out` (`n × encoded_len`).
    pub fn encode_triples(&self, dirs: &[f32], out: &mut [f32]) -> Result<()> {
        let n = dirs.len() / 9;
        check_len("dirs", n * 9, dirs.len())?;
        let e = self.encoded_len();
        check_len("encoded", n * e, out.len())?;
        for (d, o) in dirs.chunks_exact(9).zip(out.chunks_exact_mut(e)) {
            encode_into(&triple(d), self.octaves, o);
        }
        Ok(())
    }

    /// Render MLP on precomputed features: `params` (`n × 64`) and `nd` (`n × 32`)
    /// → log-space output `n × 3` (`ln(R + 1)`). Tiled like the fused path.
    pub fn render_from_features(
        &self,
        params: &[f32],
        nd: &[f32],
        out_log: &mut [f32],
    ) -> Result<()> {
        let (p, d) = (self.params, self.nd_len());
        let n = params.len() / p;
        check_len("params", n * p, params.len())?;
        check_len("nd", n * d, nd.len())?;
        check_len("log out", n * 3, out_log.len())?;
        let dirs = Dirs::<NoDirs>::Features(nd);
        self.run(out_log, false, &|g| g, Base::Params(params), &dirs);
        Ok(())
    }

    /// Log-space output (`n × 3`) for `n` queries: `params` `n × 64`, directions
    /// ωi, ωo in the surface frame (unit vectors, z up).
    pub fn render_log_batch(
        &self,
        params: &[f32],
        wi: &[[f32; 3]],
        wo: &[[f32; 3]],
        out_log: &mut [f32],
    ) -> Result<()> {
        let n = wi.len();
        check_len("params", n * self.params, params.len())?;
        check_len("wo", n, wo.len())?;
        check_len("log out", n * 3, out_log.len())?;
        check_finite("params", params)?;
        check_finite("wi", wi.as_flattened())?;
        check_finite("wo", wo.as_flattened())?;
        let dirs = Dirs::Each(|g: usize| direction_triple(wi[g], wo[g]));
        self.run(out_log, false, &|g| g, Base::Params(params), &dirs);
        Ok(())
    }

    /// Like [`Self::render_log_batch`] with precomputed triples `[ωi, ωo, ωh]`
    /// (`dirs`: `n × 9`), e.g. to reproduce another implementation's ωh bit for bit.
    pub fn render_log_triples(
        &self,
        params: &[f32],
        dirs: &[f32],
        out_log: &mut [f32],
    ) -> Result<()> {
        let n = dirs.len() / 9;
        check_len("dirs", n * 9, dirs.len())?;
        check_len("params", n * self.params, params.len())?;
        check_len("log out", n * 3, out_log.len())?;
        check_finite("params", params)?;
        check_finite("dirs", dirs)?;
        let each = Dirs::Each(|g: usize| triple(&dirs[g * 9..(g + 1) * 9]));
        self.run(out_log, false, &|g| g, Base::Params(params), &each);
        Ok(())
    }

    /// Radiance `R = max(expm1(y), 0)` (`n × 3`) for `n` queries; see [`Self::render_log_batch`].
    pub fn render_batch(
        &self,
        params: &[f32],
        wi: &[[f32; 3]],
        wo: &[[f32; 3]],
        out: &mut [f32],
    ) -> Result<()> {
        self.render_log_batch(params, wi, wo, out)?;
        for v in out.iter_mut() {
            *v = radiance_from_log(*v);
        }
        Ok(())
    }

    /// Validates a param map for this network; returns its pixel count.
    pub(crate) fn check_map(&self, map: &ParamMap) -> Result<usize> {
        check_len("param map channels", self.params, map.channels)?;
        let n = map.height * map.width;
        check_len("param map", n * self.params, map.data.len())?;
        check_finite("param map", &map.data)?;
        Ok(n)
    }

    /// Relights a whole param map for a point light at `light` and a viewer at
    /// `view` (surface-frame units, DESIGN §3): the general per-pixel path.
    /// Directions are computed per tile, so memory beyond the output is bounded
    /// by the tile scratch.
    pub fn relight(&self, map: &ParamMap, light: [f32; 3], view: [f32; 3]) -> Result<Rgb> {
        let n = self.check_map(map)?;
        check_finite("light", &light)?;
        check_finite("view", &view)?;
        if light[2] <= 0.0 || view[2] <= 0.0 {
            return Err(ModelError::BelowSurface);
        }
        let (h, w) = (map.height, map.width);
        let (light, view) = (Source::Point(light), Source::Point(view));
        let dirs = Dirs::Each(|g: usize| {
            Directions::at(&light, &view, pixel_position(g / w, g % w, h, w)).to_array9()
        });
        let mut data = vec![0.0f32; n * 3];
        self.run(&mut data, true, &|g| g, Base::Params(&map.data), &dirs);
        Ok(Rgb {
            height: h,
            width: w,
            data,
        })
    }

    /// Relights with the same (ωi, ωo) at every pixel — a directional light and
    /// an orthographic view (DESIGN §9): the encoding, ND_enc and the direction
    /// part of the first render layer run once, and per pixel only `W_p·p` and
    /// the remaining render layers (~9× fewer FLOPs than [`Self::relight`]).
    /// For repeated relights of one material see
    /// [`Self::relight_prepared`](crate::RenderNet::relight_prepared).
    pub fn relight_directional(&self, map: &ParamMap, wi: [f32; 3], wo: [f32; 3]) -> Result<Rgb> {
        let n = self.check_map(map)?;
        check_finite("wi", &wi)?;
        check_finite("wo", &wo)?;
        let c = self.constant_direction_part(wi, wo);
        let mut data = vec![0.0f32; n * 3];
        let dirs = Dirs::<NoDirs>::Constant(&c);
        self.run(&mut data, true, &|g| g, Base::Params(&map.data), &dirs);
        Ok(Rgb {
            height: map.height,
            width: map.width,
            data,
        })
    }

    /// Relights with caller-given per-pixel directions (row-major, `height·width` each).
    pub fn relight_with_directions(
        &self,
        map: &ParamMap,
        wi: &[[f32; 3]],
        wo: &[[f32; 3]],
    ) -> Result<Rgb> {
        check_len("param map channels", self.params, map.channels)?;
        let n = map.height * map.width;
        check_len("wi", n, wi.len())?;
        let mut data = vec![0.0f32; n * 3];
        self.render_batch(&map.data, wi, wo, &mut data)?;
        Ok(Rgb {
            height: map.height,
            width: map.width,
            data,
        })
    }
}

/// The products of ND_enc and of the render layers after the first (sums are f32 or exact i32).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Precision {
    /// f32 products (the default).
    F32,
    /// bf16 products, f32 sums ([`RenderNet::with_bf16`]).
    Bf16,
    /// int8 products, i32 sums, f32 scales ([`RenderNet::with_int8`]).
    Int8,
}

impl Precision {
    /// Short name (`f32`, `bf16`, `int8`).
    pub fn name(self) -> &'static str {
        match self {
            Self::F32 => "f32",
            Self::Bf16 => "bf16",
            Self::Int8 => "int8",
        }
    }
}

/// The reduced-precision twins of a [`RenderNet`]'s layers.
#[derive(Debug, Clone)]
pub(crate) struct ReducedLayers {
    precision: Precision,
    /// ND_enc.
    pub(crate) nd: Vec<Reduced>,
    /// `render[1..]`.
    pub(crate) tail: Vec<Reduced>,
}

/// The 9 values of a `[ωi, ωo, ωh]` row.
fn triple(d: &[f32]) -> [f32; 9] {
    let mut c = [0.0f32; 9];
    c.copy_from_slice(d);
    c
}
