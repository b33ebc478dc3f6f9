//! Prints the adapter, its FMA peak, the rate of every matmul variant the device can run and
//! the CPU sgemm rate measured in the same run:
//! `cargo run --release -p nam-gpu --example probe [rows] [pairs]` (default 4096 rows x 594 x
//! 594). On a shared machine a single pair of timings is noisy, so the adapter's own variant
//! is then measured `pairs` (default 5) more times, each right after a CPU sgemm and an FMA
//! peak run, and the median ratios are printed.

fn main() {
    let Some(gpu) = nam_gpu::request_device(false) else {
        return;
    };
    let arg = |i: usize, default: u32| {
        std::env::args()
            .nth(i)
            .and_then(|v| v.parse().ok())
            .unwrap_or(default)
    };
    let (rows, pairs) = (arg(1, 4096), arg(2, 5));
    println!("adapter: {} ({:?})", gpu.info.name, gpu.info.device_type);
    let mut ctx = match nam_gpu::GpuContext::new(&gpu.device, &gpu.queue, gpu.info.device_type) {
        Ok(c) => c,
        Err(e) => return eprintln!("{e}"),
    };
    match nam_gpu::probe::fma_peak_gflops(&ctx, 512, 4096, 3) {
        Ok(g) => println!("fma peak: {g:.1} GFLOP/s"),
        Err(e) => eprintln!("fma peak: {e}"),
    }
    let own = ctx.matmul_variant();
    let mut variants = vec![
        nam_gpu::MatmulVariant::Direct,
        nam_gpu::MatmulVariant::Tiled,
    ];
    if gpu.device.features().contains(wgpu::Features::SUBGROUP) {
        variants.insert(0, nam_gpu::MatmulVariant::Texture);
    }
    for v in variants {
        ctx.set_matmul_variant(v);
        let sgemm = nam_model::sgemm_gflops(512, 3);
        match nam_gpu::probe::matmul_gflops(&ctx, rows, 594, 594, 3) {
            Ok(g) => println!(
                "matmul {v:?} {rows}x594x594: {g:.2} GFLOP/s | cpu sgemm 512³ {sgemm:.1} GFLOP/s | ratio {:.3}",
                g / sgemm
            ),
            Err(e) => eprintln!("matmul: {e}"),
        }
    }
    ctx.set_matmul_variant(own);
    let (mut vs_cpu, mut vs_peak) = (Vec::new(), Vec::new());
    for i in 0..pairs {
        let sgemm = nam_model::sgemm_gflops(512, 3);
        let peak = nam_gpu::probe::fma_peak_gflops(&ctx, 512, 4096, 3);
        let mm = nam_gpu::probe::matmul_gflops(&ctx, rows, 594, 594, 3);
        match (peak, mm) {
            (Ok(peak), Ok(mm)) => {
                println!(
                    "pair {i}: matmul {own:?} {mm:.2} | fma peak {peak:.1} | cpu sgemm {sgemm:.1} GFLOP/s"
                );
                vs_cpu.push(mm / sgemm);
                vs_peak.push(mm / peak);
            }
            (Err(e), _) | (_, Err(e)) => eprintln!("pair {i}: {e}"),
        }
    }
    let median = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v.get(v.len() / 2).copied().unwrap_or(f64::NAN)
    };
    println!(
        "median over {} pairs: matmul {own:?} / cpu sgemm = {:.3}, matmul / fma peak = {:.2}",
        vs_cpu.len(),
        median(&mut vs_cpu),
        median(&mut vs_peak)
    );
}
