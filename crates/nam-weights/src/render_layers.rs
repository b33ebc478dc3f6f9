//! `M_render`'s bias-free linear layers as every backend runs them: ND_enc, then the render
//! MLP, each with the leaky-ReLU slope that follows it (DESIGN §4). The one home of which
//! layer has which activation and of the `render.l1 · render.l0` fold (DESIGN §9), shared by
//! the CPU path (`nam-model`), the GPU path (`nam-gpu`) and the browser viewer (`nam-cli
//! view`, which ships these layers to WebGPU).

use crate::error::Result;
use crate::weights::Weights;

/// One bias-free linear layer `y = act(W x)`.
#[derive(Debug, Clone, PartialEq)]
pub struct LinearLayer {
    /// Tensor name(s) it comes from (`"nd_enc.l0"`, `"render.l0l1"` when folded).
    pub name: String,
    /// Output width.
    pub out: usize,
    /// Input width.
    pub inp: usize,
    /// `[out, inp]`, row-major (PyTorch `Linear` layout).
    pub weight: Vec<f32>,
    /// Negative slope of the leaky ReLU after the layer; `None`: no activation.
    pub slope: Option<f32>,
}

/// ND_enc (positional encoding → direction features) and the render MLP
/// (`[params | features]` → log radiance).
#[derive(Debug, Clone, PartialEq)]
pub struct RenderLayers {
    /// ND_enc, input first; the last layer has no activation.
    pub nd_enc: Vec<LinearLayer>,
    /// The render MLP, input first: `render.l0` has no activation; hidden layers use
    /// `slopes.render_hidden`, the output layer `slopes.render_out`.
    pub mlp: Vec<LinearLayer>,
}

impl Weights {
    /// The layers of `M_render`. With `fold`, `render.l1 · render.l0` (no activation between
    /// them) becomes one `[r2, r0]` matrix, summed in f64: 96·128 instead of 96·128 + 128·128
    /// multiply-adds per pixel for the standard widths, the same function up to rounding.
    pub fn render_layers(&self, fold: bool) -> Result<RenderLayers> {
        let cfg = self.config();
        let slopes = cfg.slopes;
        let n_nd = cfg.nd_enc.len() - 1;
        let mut nd_enc = Vec::with_capacity(n_nd);
        for i in 0..n_nd {
            let (inp, out) = (cfg.nd_enc[i], cfg.nd_enc[i + 1]);
            let name = format!("nd_enc.l{i}");
            nd_enc.push(LinearLayer {
                weight: self.get(&format!("{name}.weight"), &[out, inp])?.to_vec(),
                name,
                out,
                inp,
                slope: (i + 1 < n_nd).then_some(slopes.nd_enc),
            });
        }
        let r = &cfg.render;
        let n_r = r.len() - 1; // ≥ 2: ModelConfig::check
        let slope_of = |i: usize| match i {
            0 => None,
            _ if i + 1 == n_r => Some(slopes.render_out),
            _ => Some(slopes.render_hidden),
        };
        let layer = |i: usize| -> Result<LinearLayer> {
            let name = format!("render.l{i}");
            Ok(LinearLayer {
                weight: self
                    .get(&format!("{name}.weight"), &[r[i + 1], r[i]])?
                    .to_vec(),
                name,
                out: r[i + 1],
                inp: r[i],
                slope: slope_of(i),
            })
        };
        let mut mlp = Vec::with_capacity(n_r);
        if fold {
            let (w0, w1) = (layer(0)?, layer(1)?);
            let mut weight = vec![0.0f32; r[2] * r[0]];
            for (o, row) in weight.chunks_exact_mut(r[0]).enumerate() {
                for (k, v) in row.iter_mut().enumerate() {
                    let s: f64 = (0..r[1])
                        .map(|m| {
                            f64::from(w1.weight[o * r[1] + m]) * f64::from(w0.weight[m * r[0] + k])
                        })
                        .sum();
                    *v = s as f32;
                }
            }
            mlp.push(LinearLayer {
                name: "render.l0l1".into(),
                out: r[2],
                inp: r[0],
                weight,
                slope: w1.slope,
            });
        } else {
            mlp.push(layer(0)?);
            mlp.push(layer(1)?);
        }
        for i in 2..n_r {
            mlp.push(layer(i)?);
        }
        Ok(RenderLayers { nd_enc, mlp })
    }
}

#[cfg(test)]
mod tests {
    use crate::{ModelConfig, Weights};

    #[test]
    fn layers_chain_widths_and_slopes_and_the_fold_is_the_product() {
        let w = Weights::random(ModelConfig::standard(4), 7).expect("weights");
        let cfg = w.config().clone();
        let plain = w.render_layers(false).expect("layers");
        let folded = w.render_layers(true).expect("layers");
        for layers in [&plain.nd_enc, &plain.mlp, &folded.mlp] {
            for pair in layers.windows(2) {
                assert_eq!(
                    pair[0].out, pair[1].inp,
                    "{} → {}",
                    pair[0].name, pair[1].name
                );
            }
            for l in layers.iter() {
                assert_eq!(l.weight.len(), l.out * l.inp, "{}", l.name);
            }
        }
        assert_eq!(plain.nd_enc[0].inp, cfg.encoding_len());
        assert_eq!(plain.nd_enc.last().map(|l| l.slope), Some(None));
        assert_eq!(plain.nd_enc[0].slope, Some(cfg.slopes.nd_enc));
        assert_eq!(plain.mlp[0].slope, None);
        assert_eq!(plain.mlp[1].slope, Some(cfg.slopes.render_hidden));
        assert_eq!(
            plain.mlp.last().and_then(|l| l.slope),
            Some(cfg.slopes.render_out)
        );
        assert_eq!(folded.mlp.len() + 1, plain.mlp.len());
        assert_eq!(folded.mlp[0].slope, plain.mlp[1].slope);
        // The folded matrix applied to a vector equals the two layers applied in turn.
        let (l0, l1, f) = (&plain.mlp[0], &plain.mlp[1], &folded.mlp[0]);
        let x: Vec<f32> = (0..l0.inp).map(|k| (k as f32 * 0.37).sin()).collect();
        let apply = |l: &crate::LinearLayer, x: &[f32]| -> Vec<f64> {
            (0..l.out)
                .map(|o| {
                    (0..l.inp)
                        .map(|k| f64::from(l.weight[o * l.inp + k]) * f64::from(x[k]))
                        .sum()
                })
                .collect()
        };
        let h: Vec<f32> = apply(l0, &x).into_iter().map(|v| v as f32).collect();
        for (a, b) in apply(l1, &h).into_iter().zip(apply(f, &x)) {
            assert!((a - b).abs() <= 1e-4 * (1.0 + a.abs()), "{a} vs {b}");
        }
    }
}
