//! Prints the adapter, its FMA peak, the rate of every matmul variant the device can run and
//! the CPU sgemm rate measured in the same run:
//! `cargo run --release -p nam-gpu --example probe [rows]` (default 4096 rows x 594 x 594).

fn main() {
    let Some(gpu) = nam_gpu::request_device(false) else {
        return;
    };
    let rows: u32 = std::env::args()
        .nth(1)
        .and_then(|v| v.parse().ok())
        .unwrap_or(4096);
    println!("adapter: {} ({:?})", gpu.info.name, gpu.info.device_type);
    let mut ctx = match nam_gpu::GpuContext::new(&gpu.device, &gpu.queue, gpu.info.device_type) {
        Ok(c) => c,
        Err(e) => return eprintln!("{e}"),
    };
    match nam_gpu::probe::fma_peak_gflops(&ctx, 512, 4096, 3) {
        Ok(g) => println!("fma peak: {g:.1} GFLOP/s"),
        Err(e) => eprintln!("fma peak: {e}"),
    }
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
}
