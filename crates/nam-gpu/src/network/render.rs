//! The render plans of [`GpuNetwork::render`] and [`GpuNetwork::render_directional`]:
//! per row count and [`RenderKind`], the positional encoding, ND_enc and render MLP as
//! buffer or texture products, tiled into submissions of at most [`MAX_RENDER_ROWS`] rows.

use nam_weights::radiance_from_log;

use super::{GpuNetwork, MAX_CACHED_PLANS, MAX_RENDER_ROWS, to_u32};
use crate::context::{DeviceBuffer, DeviceTexture, Dispatch, MatmulVariant};
use crate::error::{GpuError, Result};
use crate::ops::{self, Act, Rows, TexOut, View};
use crate::shaders::Precision;
use crate::weights::Linear;

/// Which part of `M_render` a render plan runs per row.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub(super) enum RenderKind {
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
pub(super) struct RenderPlan {
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

impl GpuNetwork {
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
}
