//! Throwaway timer (not committed).
use nam_model::UNet;
use nam_weights::Weights;
use std::time::Instant;
fn main() {
    let a: Vec<String> = std::env::args().collect();
    let path = &a[1];
    let reps: usize = a.get(2).map(|s| s.parse().unwrap()).unwrap_or(10);
    let w = Weights::from_file(path).unwrap();
    let u = UNet::new(&w).unwrap().with_bf16().unwrap();
    let n = 256usize;
    let c = w.config().in_channels;
    let x: Vec<f32> = (0..n * n * c)
        .map(|i| ((i * 7919 % 1000) as f32) / 1000.0)
        .collect();
    let mut best = f64::MAX;
    for _ in 0..reps {
        let t = Instant::now();
        let p = u.estimate(&x, n, n).unwrap();
        std::hint::black_box(p);
        best = best.min(t.elapsed().as_secs_f64() * 1e3);
    }
    println!("best {best:.1} ms");
}
