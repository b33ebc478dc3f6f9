//! The tile kernel of [`RenderNet`]: per-thread scratch, the material part (params or
//! prepared rows) and the direction part (per query, given features or one constant vector)
//! of the first render layer, then the render MLP, over rayon-parallel tiles.

use nam_weights::radiance_from_log;
use rayon::prelude::*;

use super::RenderNet;
use super::interpolated::FeatureGrid;
use crate::dense::chain;
use crate::encoding::{direction_triple, encode_into};
use crate::error::{Result, check_len};
use crate::sgemm::{Mat, sgemm};
use crate::simd::Line;

/// Where a tile's material part `W_p·p` of the first render layer comes from.
#[derive(Clone, Copy)]
pub(crate) enum Base<'a> {
    /// Param rows (`texels × param_channels`): one GEMM per tile.
    Params(&'a [f32]),
    /// Precomputed `W_p·p` rows (`texels × hidden`): copied.
    Prepared(&'a [f32]),
}

/// Where the direction features of output `g` come from.
pub(crate) enum Dirs<'a, F> {
    /// The direction triple `[ωi, ωo, ωh]` of output `g`: encoding and ND_enc per query.
    Each(F),
    /// ND_enc output rows given by the caller (`outputs × nd_len`).
    Features(&'a [f32]),
    /// One precomputed `W_d·ND_enc(…)` vector (`hidden`) for every output.
    Constant(&'a [f32]),
    /// ND_enc rows interpolated from a grid of nodes (outputs are the image's pixels).
    Grid(&'a FeatureGrid),
}

/// The `F` of a [`Dirs`] that is not [`Dirs::Each`].
pub(crate) type NoDirs = fn(usize) -> [f32; 9];

/// Per-thread scratch of one tile.
pub(crate) struct Scratch {
    enc: Vec<f32>,
    a: Vec<f32>,
    b: Vec<f32>,
    /// Gathered param rows (`n × params`).
    x: Vec<f32>,
    /// First render layer output (`n × hidden`).
    h: Vec<f32>,
    /// ND_enc output (`n × nd_len`).
    pub(super) nd: Vec<f32>,
    log: Vec<f32>,
    packed: Vec<Line>,
}

impl RenderNet {
    fn max_hidden(&self) -> usize {
        self.nd
            .iter()
            .chain(&self.render)
            .map(|l| l.out)
            .max()
            .unwrap_or(1)
    }

    pub(crate) fn scratch(&self, n: usize) -> Scratch {
        Scratch {
            enc: vec![0.0; n * self.encoded_len()],
            a: vec![0.0; n * self.max_hidden()],
            b: vec![0.0; n * self.max_hidden()],
            x: vec![0.0; n * self.params],
            h: vec![0.0; n * self.hidden_len()],
            nd: vec![0.0; n * self.nd_len()],
            log: vec![0.0; n * 3],
            packed: Vec::new(),
        }
    }

    /// Runs `f(scratch, first index, output chunk)` over tiles of `out`
    /// (`width` values per item) in parallel, one scratch per worker.
    pub(crate) fn tiles(
        &self,
        out: &mut [f32],
        width: usize,
        f: impl Fn(&mut Scratch, usize, &mut [f32]) + Sync + Send,
    ) {
        let n = out.len() / width;
        let t = self.tile.min(n.max(1));
        out.par_chunks_mut(t * width)
            .enumerate()
            .for_each_init(|| self.scratch(t), |s, (ti, dst)| f(s, ti * t, dst));
    }

    /// ND_enc of `n` encoded queries (`n × 297` → `n × 32`), f32.
    pub fn nd_enc(&self, encoded: &[f32], out: &mut [f32]) -> Result<()> {
        let e = self.encoded_len();
        let d = self.nd_len();
        let n = encoded.len() / e;
        check_len("encoded", n * e, encoded.len())?;
        check_len("nd out", n * d, out.len())?;
        self.tiles(out, d, |s, q0, dst| {
            let m = dst.len() / d;
            let src = &encoded[q0 * e..(q0 + m) * e];
            chain(
                &self.nd,
                m,
                src,
                e,
                &mut s.a,
                &mut s.b,
                dst,
                d,
                &mut s.packed,
            );
        });
        Ok(())
    }

    /// ND_enc features of `n` direction triples into `s.nd` (reduced precision when active).
    pub(super) fn features_into(&self, s: &mut Scratch, n: usize, dir: impl Fn(usize) -> [f32; 9]) {
        let e = self.encoded_len();
        let d = self.nd_len();
        for q in 0..n {
            encode_into(&dir(q), self.octaves, &mut s.enc[q * e..(q + 1) * e]);
        }
        let Scratch {
            enc,
            a,
            b,
            nd,
            packed,
            ..
        } = s;
        match &self.reduced {
            Some(r) => chain(&r.nd, n, enc, e, a, b, nd, d, packed),
            None => chain(&self.nd, n, enc, e, a, b, nd, d, packed),
        }
    }

    /// The direction part `W_d · ND_enc(enc(ωi, ωo, ωh))` of the first render
    /// layer for one direction pair (`hidden_len` values): what every pixel
    /// shares under a directional light and an orthographic view.
    pub(crate) fn constant_direction_part(&self, wi: [f32; 3], wo: [f32; 3]) -> Vec<f32> {
        let mut s = self.scratch(1);
        self.features_into(&mut s, 1, |_| direction_triple(wi, wo));
        let h1 = self.hidden_len();
        let mut c = vec![0.0f32; h1];
        sgemm(
            1,
            h1,
            self.nd_len(),
            Mat {
                data: &s.nd,
                ld: self.nd_len(),
            },
            self.render[0].rows_from(self.params),
            &mut c,
            h1,
            false,
            1,
        );
        c
    }

    /// The fused pipeline on outputs `q0..q0 + n`: `texel(g)` is the material
    /// row of output `g`; log-space results land in `s.log[..n·3]`.
    pub(crate) fn run_tile<F: Fn(usize) -> [f32; 9]>(
        &self,
        s: &mut Scratch,
        (q0, n): (usize, usize),
        texel: &dyn Fn(usize) -> usize,
        base: Base<'_>,
        dirs: &Dirs<'_, F>,
    ) {
        let first = &self.render[0];
        let (p, d, h1) = (self.params, self.nd_len(), first.out);
        // Direction features first: ND_enc uses the a/b scratch.
        let feats: Option<&[f32]> = match dirs {
            Dirs::Each(dir) => {
                self.features_into(s, n, |q| dir(q0 + q));
                None
            }
            Dirs::Features(f) => Some(&f[q0 * d..(q0 + n) * d]),
            Dirs::Grid(g) => {
                g.fill(q0, n, &mut s.nd);
                None
            }
            Dirs::Constant(_) => None,
        };
        let Scratch {
            a,
            b,
            x,
            h,
            nd,
            log,
            packed,
            ..
        } = s;
        let h = &mut h[..n * h1];
        // Material part W_p · p.
        match base {
            Base::Params(map) => {
                for q in 0..n {
                    let t = texel(q0 + q);
                    x[q * p..(q + 1) * p].copy_from_slice(&map[t * p..(t + 1) * p]);
                }
                sgemm(
                    n,
                    h1,
                    p,
                    Mat { data: x, ld: p },
                    first.rows_from(0),
                    h,
                    h1,
                    false,
                    1,
                );
            }
            Base::Prepared(rows) => {
                for q in 0..n {
                    let t = texel(q0 + q);
                    h[q * h1..(q + 1) * h1].copy_from_slice(&rows[t * h1..(t + 1) * h1]);
                }
            }
        }
        // Direction part W_d · f.
        match dirs {
            Dirs::Constant(c) => {
                for row in h.chunks_exact_mut(h1) {
                    for (v, c) in row.iter_mut().zip(c.iter()) {
                        *v += c;
                    }
                }
            }
            Dirs::Each(_) | Dirs::Features(_) | Dirs::Grid(_) => {
                let f = feats.unwrap_or(&nd[..n * d]);
                sgemm(
                    n,
                    h1,
                    d,
                    Mat { data: f, ld: d },
                    first.rows_from(p),
                    h,
                    h1,
                    true,
                    1,
                );
            }
        }
        first.activate(n, h, h1);
        match &self.reduced {
            Some(r) => chain(&r.tail, n, h, h1, a, b, log, 3, packed),
            None => chain(&self.render[1..], n, h, h1, a, b, log, 3, packed),
        }
    }

    /// Runs the fused pipeline for every output of `out` (`n × 3`, log space
    /// or, with `radiance`, `max(expm1(y), 0)`), in parallel tiles.
    pub(crate) fn run<F: Fn(usize) -> [f32; 9] + Sync>(
        &self,
        out: &mut [f32],
        radiance: bool,
        texel: &(dyn Fn(usize) -> usize + Sync),
        base: Base<'_>,
        dirs: &Dirs<'_, F>,
    ) {
        self.tiles(out, 3, |s, q0, dst| {
            let m = dst.len() / 3;
            self.run_tile(s, (q0, m), texel, base, dirs);
            dst.copy_from_slice(&s.log[..m * 3]);
            if radiance {
                dst.iter_mut().for_each(|v| *v = radiance_from_log(*v));
            }
        });
    }
}
