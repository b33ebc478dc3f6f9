//! Tiny probes on a device: the smoke kernel and the FMA throughput probe used by benches.

use std::time::Instant;

use crate::context::{GpuContext, PipelineKey, Res};
use crate::error::Result;
use crate::params::PeakParams;
use crate::shaders::{Family, Precision};

/// Runs `shaders/smoke.wgsl` (`x -> 2x + 1`) on `data` and reads the result back.
pub fn smoke(ctx: &GpuContext, data: &[f32]) -> Result<Vec<f32>> {
    let buf = ctx.upload("smoke", data, Precision::F32)?;
    let key = PipelineKey {
        family: Family::Smoke,
        entry: "smoke",
        precision: Precision::F32,
        constants: vec![],
    };
    let groups = crate::context::groups_1d(u32::try_from(data.len()).unwrap_or(u32::MAX), 64)?;
    let d = ctx.dispatch(&key, None, &[Res::Buf(&buf.buffer)], [groups, 1, 1])?;
    ctx.run(&[d])?;
    ctx.read(&buf, data.len() as u64)
}

/// Measures f32 FMA throughput with `shaders/fma_peak.wgsl`: `groups` workgroups of 256
/// invocations, `iters` iterations of 64 flops each. Returns GFLOP/s of the best of `reps`
/// timed runs (after one warm-up).
pub fn fma_peak_gflops(ctx: &GpuContext, groups: u32, iters: u32, reps: u32) -> Result<f64> {
    let out = ctx.storage("fma out", u64::from(groups) * 256, Precision::F32)?;
    let key = PipelineKey {
        family: Family::FmaPeak,
        entry: "fma_peak",
        precision: Precision::F32,
        constants: vec![],
    };
    let d = ctx.dispatch(
        &key,
        Some(bytemuck::bytes_of(&PeakParams {
            iters,
            seed: 1.0,
            _pad0: 0,
            _pad1: 0,
        })),
        &[Res::Buf(&out.buffer)],
        [groups, 1, 1],
    )?;
    let flops = f64::from(groups) * 256.0 * f64::from(iters) * 64.0;
    let best = time_best(ctx, &d, reps)?;
    // Keep the result observable so the kernel cannot be elided.
    let _ = ctx.read(&out, 1)?;
    Ok(flops / best / 1e9)
}

/// Measures the context's matmul variant (`shaders/matmul.wgsl` or, for
/// [`crate::MatmulVariant::Texture`], `shaders/matmul_tex.wgsl`; f32, LeakyReLU epilogue) on
/// a `rows x inner` by `inner x cols` product. Returns GFLOP/s (2 flops per multiply-add) of
/// the best of `reps` timed runs after one warm-up.
pub fn matmul_gflops(ctx: &GpuContext, rows: u32, cols: u32, inner: u32, reps: u32) -> Result<f64> {
    let p = Precision::F32;
    let x: Vec<f32> = (0..rows as usize * inner as usize)
        .map(|i| (i % 7) as f32 * 0.1)
        .collect();
    let w: Vec<f32> = (0..cols as usize * inner as usize)
        .map(|i| (i % 5) as f32 * 0.1)
        .collect();
    let flops = 2.0 * f64::from(rows) * f64::from(cols) * f64::from(inner);
    if ctx.matmul_variant() == crate::MatmulVariant::Texture {
        let xt = ctx.upload_matrix("matmul x", &x, rows, inner, p)?;
        let wt = ctx.upload_matrix("matmul w", &w, cols, inner, p)?;
        let yt = ctx.texture("matmul y", cols.div_ceil(4), rows, p)?;
        let d = crate::ops::matmul_tex(
            ctx,
            &xt,
            &wt,
            crate::ops::TexOut::Texture {
                tex: &yt,
                texel_base: 0,
            },
            rows,
            cols,
            inner,
            crate::ops::Act::Leaky(0.01),
        )?;
        let best = time_best(ctx, &d, reps)?;
        let _ = ctx.read_texture(&yt, 1)?;
        return Ok(flops / best / 1e9);
    }
    let xb = ctx.upload("matmul x", &x, p)?;
    let wb = ctx.upload("matmul w", &w, p)?;
    let yb = ctx.storage("matmul y", u64::from(rows) * u64::from(cols), p)?;
    let d = crate::ops::matmul(
        ctx,
        p,
        crate::ops::Rows {
            view: crate::ops::View::new(&xb.buffer, 0)?,
            stride: inner,
        },
        &wb.buffer,
        crate::ops::Rows {
            view: crate::ops::View::new(&yb.buffer, 0)?,
            stride: cols,
        },
        rows,
        cols,
        inner,
        crate::ops::Act::Leaky(0.01),
    )?;
    let best = time_best(ctx, &d, reps)?;
    let _ = ctx.read(&yb, 1)?;
    Ok(flops / best / 1e9)
}

/// Best wall time in seconds of `reps` submissions of `d` (each waited for), after one warm-up.
fn time_best(ctx: &GpuContext, d: &crate::context::Dispatch, reps: u32) -> Result<f64> {
    ctx.run(std::slice::from_ref(d))?;
    ctx.wait()?;
    let mut best = f64::INFINITY;
    for _ in 0..reps.max(1) {
        let t = Instant::now();
        ctx.run(std::slice::from_ref(d))?;
        ctx.wait()?;
        best = best.min(t.elapsed().as_secs_f64());
    }
    Ok(best)
}
