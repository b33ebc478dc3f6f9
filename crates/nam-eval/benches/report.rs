//! One report configuration timed with criterion: the default model on the CPU fast path,
//! estimate and relight of one held-out material at 64², next to the GGX analytic render of
//! the same pair (the ratio is the cost of the neural relight over the analytic one).

use criterion::{Criterion, criterion_group, criterion_main};
use nam_eval::heldout;
use nam_eval::methods::{Backend, MethodSpec, NeuralConfig, Precision, Prepared, Specialisation};
use nam_ggx::Protocol;
use std::hint::black_box;
use std::path::Path;

fn bench(c: &mut Criterion) {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let materials = match heldout::load(&root.join("assets/heldout"), 1, 64) {
        Ok(m) => m,
        Err(e) => {
            eprintln!("skipping the report bench: {e}");
            return;
        }
    };
    let m = &materials[0];
    let neural = MethodSpec::Neural(NeuralConfig {
        model: root.join("models/default.safetensors"),
        backend: Backend::CpuFast,
        precision: Precision::F32,
        specialisation: Specialisation::General,
    });
    let run = |spec: &MethodSpec| Prepared::new(spec, None).unwrap_or_else(|e| panic!("{e}"));
    let (net, ggx) = (run(&neural), run(&MethodSpec::GgxTruth));
    let lv = m.pairs(Protocol::Hemisphere, 1)[0];
    let est = net.estimate(m).unwrap_or_else(|e| panic!("{e}"));
    let truth = ggx.estimate(m).unwrap_or_else(|e| panic!("{e}"));
    let mut g = c.benchmark_group("report");
    g.sample_size(10);
    g.bench_function("default_cpu_fast_f32/estimate_64", |b| {
        b.iter(|| black_box(net.estimate(m).unwrap_or_else(|e| panic!("{e}"))))
    });
    g.bench_function("default_cpu_fast_f32/relight_64", |b| {
        b.iter(|| black_box(net.relight(&est, 64, &lv).unwrap_or_else(|e| panic!("{e}"))))
    });
    g.bench_function("ggx_truth/relight_64", |b| {
        b.iter(|| {
            black_box(
                ggx.relight(&truth, 64, &lv)
                    .unwrap_or_else(|e| panic!("{e}")),
            )
        })
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
