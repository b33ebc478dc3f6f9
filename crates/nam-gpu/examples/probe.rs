//! Prints the adapter, its FMA peak and the tiled matmul rate:
//! `cargo run --release -p nam-gpu --example probe`.

fn main() {
    let Some(gpu) = nam_gpu::request_device(false) else {
        return;
    };
    println!("adapter: {} ({:?})", gpu.info.name, gpu.info.device_type);
    let mut ctx = match nam_gpu::GpuContext::new(&gpu.device, &gpu.queue, gpu.info.device_type) {
        Ok(c) => c,
        Err(e) => return eprintln!("{e}"),
    };
    match nam_gpu::probe::fma_peak_gflops(&ctx, 512, 4096, 3) {
        Ok(g) => println!("fma peak: {g:.1} GFLOP/s"),
        Err(e) => eprintln!("fma peak: {e}"),
    }
    for v in [
        nam_gpu::MatmulVariant::Tiled,
        nam_gpu::MatmulVariant::Direct,
    ] {
        ctx.set_matmul_variant(v);
        match nam_gpu::probe::matmul_gflops(&ctx, 16_384, 594, 594, 3) {
            Ok(g) => println!("matmul {v:?} 16384x594x594: {g:.1} GFLOP/s"),
            Err(e) => eprintln!("matmul: {e}"),
        }
    }
}
