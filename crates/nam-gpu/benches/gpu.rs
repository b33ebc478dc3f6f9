//! GPU benchmarks: `render`, `render_directional` (ND_enc once) and `estimate` at 256² on
//! the default adapter, with GFLOP/s and the ratio to the CPU fast path (nam-model) measured
//! in the same run, plus the FMA-peak probe, the tiled matmul kernel and the CPU sgemm rate
//! it is compared with.
//!
//! `cargo bench -p nam-gpu --bench gpu` (set `XDG_RUNTIME_DIR` on Mesa). The U-Net width is
//! `NAM_BENCH_WIDTH` (default 8); `NAM_BENCH_SIDE` changes the 256 image side;
//! `NAM_BENCH_REPS` (default 2) the timed runs behind the printed ratios. Criterion's own
//! groups can be filtered as usual (`-- render`).

use std::time::Instant;

use criterion::{Criterion, Throughput};
use nam_gpu::{GpuNetwork, Precision};
use nam_weights::{ModelConfig, Weights};

fn env_usize(name: &str, default: usize) -> usize {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

/// Best wall time of `reps` runs of `f` after one warm-up, in seconds.
fn best_of<T>(reps: usize, mut f: impl FnMut() -> T) -> f64 {
    std::hint::black_box(f());
    (0..reps.max(1))
        .map(|_| {
            let t = Instant::now();
            std::hint::black_box(f());
            t.elapsed().as_secs_f64()
        })
        .fold(f64::INFINITY, f64::min)
}

/// Deterministic unit directions [ωi, ωo, ωh] for `n` queries.
fn directions(n: usize) -> (Vec<f32>, Vec<[f32; 3]>, Vec<[f32; 3]>) {
    let norm = |v: [f32; 3]| {
        let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        [v[0] / l, v[1] / l, v[2] / l]
    };
    let (mut dirs, mut wi, mut wo) = (
        Vec::with_capacity(9 * n),
        Vec::with_capacity(n),
        Vec::with_capacity(n),
    );
    for q in 0..n {
        let t = q as f32 * 0.001;
        let i = norm([t.sin() * 0.5, t.cos() * 0.3, 1.0]);
        let o = norm([-(t * 1.3).cos() * 0.4, (t * 0.7).sin() * 0.6, 1.0]);
        let h = norm([i[0] + o[0], i[1] + o[1], i[2] + o[2]]);
        dirs.extend(i.iter().chain(&o).chain(&h));
        wi.push(i);
        wo.push(o);
    }
    (dirs, wi, wo)
}

fn main() {
    let Some(gpu) = nam_gpu::request_device(true) else {
        eprintln!("nam-gpu bench: no GPU adapter; nothing to measure");
        return;
    };
    println!(
        "adapter: {} ({:?}, {:?})",
        gpu.info.name, gpu.info.backend, gpu.info.device_type
    );
    let width = env_usize("NAM_BENCH_WIDTH", 8);
    let side = env_usize("NAM_BENCH_SIDE", 256);
    let weights = match Weights::random(ModelConfig::standard(width), 7) {
        Ok(w) => w,
        Err(e) => return eprintln!("weights: {e}"),
    };
    let cpu = match nam_model::Model::new(&weights) {
        Ok(m) => m,
        Err(e) => return eprintln!("nam-model: {e}"),
    };
    let mut net = match GpuNetwork::new(
        &gpu.device,
        &gpu.queue,
        gpu.info.device_type,
        &weights,
        Precision::F32,
    ) {
        Ok(n) => n,
        Err(e) => return eprintln!("nam-gpu: {e}"),
    };
    let n = side * side;
    let params: Vec<f32> = (0..n * 64)
        .map(|i| ((i * 37 % 101) as f32 / 101.0) - 0.5)
        .collect();
    let input: Vec<f32> = (0..4 * n).map(|i| (i * 13 % 97) as f32 / 97.0).collect();
    let (dirs, wi, wo) = directions(n);

    // Rates measured in this run: FMA peak, GPU matmul kernel, CPU sgemm.
    let ctx = net.context();
    let peak = nam_gpu::probe::fma_peak_gflops(ctx, 512, 4096, 3).unwrap_or(f64::NAN);
    // 8192 rows: the texture variant keeps rows along a texture side (WebGPU's default
    // max_texture_dimension_2d is 8192).
    let mm = match nam_gpu::probe::matmul_gflops(ctx, 8192, 594, 594, 3) {
        Ok(g) => g,
        Err(e) => {
            eprintln!("matmul probe: {e}");
            f64::NAN
        }
    };
    let sgemm = nam_model::sgemm_gflops(512, 3);
    println!(
        "fma peak: {peak:.1} GFLOP/s; matmul ({:?}) 8192x594x594: {mm:.2} GFLOP/s",
        ctx.matmul_variant()
    );
    println!(
        "cpu sgemm 512³: {sgemm:.1} GFLOP/s; gpu matmul / cpu sgemm = {:.3} (target ≥ 0.10); matmul / fma peak = {:.2}",
        mm / sgemm,
        mm / peak
    );

    let render_flops = 2.0 * net.render_macs_per_query() as f64 * n as f64;
    let estimate_flops = 2.0 * net.estimate_macs(side, side) as f64;
    let reps = env_usize("NAM_BENCH_REPS", 2);
    let t_gpu_r = best_of(reps, || net.render(&params, &dirs).map(|v| v.len()));
    let mut out = vec![0.0f32; n * 3];
    let t_cpu_r = best_of(reps, || {
        cpu.render.render_batch(&params, &wi, &wo, &mut out).is_ok()
    });
    // Directional light + orthographic view: one triple for every row (DESIGN §9).
    let triple: [f32; 9] = dirs[..9]
        .try_into()
        .unwrap_or([0.0, 0.0, 1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0]);
    let map = nam_model::ParamMap {
        height: side,
        width: side,
        channels: 64,
        data: params.clone(),
    };
    let t_gpu_d = best_of(reps, || {
        net.render_directional(&params, &triple).map(|v| v.len())
    });
    let t_cpu_d = best_of(reps, || {
        cpu.render
            .relight_directional(&map, wi[0], wo[0])
            .map(|r| r.data.len())
    });
    let directional_flops = 2.0 * net.render_directional_macs_per_query() as f64 * n as f64;
    let t_gpu_e = best_of(reps, || net.estimate(&input, side, side).map(|v| v.len()));
    let t_cpu_e = best_of(reps, || {
        cpu.unet.estimate(&input, side, side).map(|m| m.data.len())
    });
    for (what, flops, tg, tc) in [
        ("render", render_flops, t_gpu_r, t_cpu_r),
        ("render directional", directional_flops, t_gpu_d, t_cpu_d),
        ("estimate", estimate_flops, t_gpu_e, t_cpu_e),
    ] {
        println!(
            "{what} {side}² (C={width}): gpu {:.1} ms {:.1} GFLOP/s | cpu fast path {:.1} ms {:.1} GFLOP/s | gpu/cpu speed {:.2}",
            tg * 1e3,
            flops / tg / 1e9,
            tc * 1e3,
            flops / tc / 1e9,
            tc / tg
        );
    }

    println!(
        "directional plan / general plan speed: gpu {:.2} | cpu {:.2}",
        t_gpu_r / t_gpu_d,
        t_cpu_r / t_cpu_d
    );

    let mut c = Criterion::default().sample_size(10).configure_from_args();
    let mut g = c.benchmark_group("nam-gpu");
    g.throughput(Throughput::Elements(n as u64));
    g.bench_function(format!("render_{side}"), |b| {
        b.iter(|| net.render(&params, &dirs).map(|v| v.len()))
    });
    g.bench_function(format!("render_directional_{side}"), |b| {
        b.iter(|| net.render_directional(&params, &triple).map(|v| v.len()))
    });
    g.bench_function(format!("estimate_{side}_c{width}"), |b| {
        b.iter(|| net.estimate(&input, side, side).map(|v| v.len()))
    });
    g.finish();
    c.final_summary();
}
