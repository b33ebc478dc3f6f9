//! The Rust report and `train_py/evaluate.py` score the same images with the same numbers
//! (issue 18 item 8): tests/fixtures/eval_agreement.safetensors, written by
//! `python -m train_py.eval_agreement`, holds evaluate.py's light/view pairs and per-protocol
//! log-L1 and SSIM for the printout, the diffuse fit and a model on the first held-out
//! materials of `assets/heldout`; the runner must draw the same pairs and reproduce the scores.

use nam_eval::heldout::{self, PROTOCOLS};
use nam_eval::runner::{self, Entry, PairCounts};
use nam_eval::{Backend, MethodSpec, NeuralConfig, Precision, Specialisation};
use safetensors::{Dtype, SafeTensors};
use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// Light/view coordinates: both sides draw the same f64 stream; only `sqrt`/`ln`/`cos` may
/// differ in the last bits between Rust's and Python's libm.
const PAIR_TOLERANCE: f64 = 1e-12;
/// Per-protocol mean log-L1, every method: the same formulas on the same f32 renders, and for
/// the model nam's CPU fast path against torch. Seen: ≤ 1.1e-6 (the LDR photo's 8-bit
/// rounding of values on a code boundary), the model ≤ 6.4e-7.
const LOG_L1_TOLERANCE: f64 = 1e-5;
/// Per-protocol mean SSIM (evaluate.py filters in f32, nam-eval in f64). Seen: ≤ 1.4e-5.
const SSIM_TOLERANCE: f64 = 1e-4;

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn f64s(st: &SafeTensors<'_>, name: &str) -> (Vec<usize>, Vec<f64>) {
    let t = st.tensor(name).unwrap_or_else(|e| panic!("{name}: {e}"));
    assert_eq!(t.dtype(), Dtype::F64, "{name}");
    let v = t
        .data()
        .chunks_exact(8)
        .map(|b| f64::from_le_bytes(b.try_into().unwrap_or([0; 8])))
        .collect();
    (t.shape().to_vec(), v)
}

#[test]
fn report_runner_draws_evaluate_pys_pairs_and_reproduces_its_scores() {
    let bytes = std::fs::read(repo().join("tests/fixtures/eval_agreement.safetensors"))
        .unwrap_or_else(|e| panic!("{e}"));
    let (_, header) = SafeTensors::read_metadata(&bytes).unwrap_or_else(|e| panic!("{e}"));
    let meta: HashMap<String, String> = header.metadata().clone().unwrap_or_default();
    let num = |k: &str| -> usize {
        meta.get(k)
            .and_then(|v| v.parse().ok())
            .unwrap_or_else(|| panic!("metadata {k}"))
    };
    let st = SafeTensors::deserialize(&bytes).unwrap_or_else(|e| panic!("{e}"));
    let counts = PairCounts {
        reflect: num("count.reflect"),
        identity: num("count.identity"),
        hemisphere: num("count.hemisphere"),
    };
    let names: Vec<&str> = PROTOCOLS.iter().map(|p| p.name()).collect();
    assert_eq!(meta["protocols"], names.join(","), "protocol order");
    assert_eq!(meta["methods"], "printout,diffuse fit,model");
    assert_eq!(meta["metrics"], "log_l1,ssim");

    let materials = heldout::load(
        &repo().join("assets/heldout"),
        num("materials"),
        num("size"),
    )
    .unwrap_or_else(|e| panic!("{e}"));
    for (i, m) in materials.iter().enumerate() {
        for &p in &PROTOCOLS {
            let (shape, want) = f64s(&st, &format!("pairs.{}.{i}", p.name()));
            let got = m.pairs(p, counts.get(p));
            assert_eq!(shape, [got.len(), 6], "{} {i}", p.name());
            for (k, lv) in got.iter().enumerate() {
                let ours = [lv.light, lv.view].map(|v| v.to_array()).concat();
                for (a, b) in ours.iter().zip(&want[6 * k..6 * k + 6]) {
                    assert!(
                        (a - b).abs() <= PAIR_TOLERANCE,
                        "{} pair {k} of material {i}: {ours:?} vs {:?}",
                        p.name(),
                        &want[6 * k..6 * k + 6]
                    );
                }
            }
        }
    }

    let model = repo().join(&meta["model"]);
    let neural = MethodSpec::Neural(NeuralConfig {
        model,
        backend: Backend::CpuFast,
        precision: Precision::F32,
        specialisation: Specialisation::General,
    });
    let entries: Vec<Entry> = [MethodSpec::Printout, MethodSpec::DiffuseFit, neural]
        .into_iter()
        .map(|spec| Entry {
            label: spec.backend_name().into(),
            spec,
            materials: materials.len(),
            pairs: counts,
        })
        .collect();
    let run = runner::run(
        &materials,
        &entries,
        None,
        nam_eval::flip::DEFAULT_PIXELS_PER_DEGREE,
        &mut |_| {},
    )
    .unwrap_or_else(|e| panic!("{e}"));
    assert!(run.skipped.is_empty(), "{:?}", run.skipped);
    let (shape, want) = f64s(&st, "scores");
    assert_eq!(shape, [3, 3, 2]);
    let mut failures = Vec::new();
    for (mi, r) in run.results.iter().enumerate() {
        for (pi, p) in PROTOCOLS.iter().enumerate() {
            let s = &r.scores[pi];
            let (want_l1, want_ssim) = (want[(pi * 3 + mi) * 2], want[(pi * 3 + mi) * 2 + 1]);
            println!(
                "{:>10} {:<12} log-L1 {:.6} vs {:.6} ({:.1e})  SSIM {:.6} vs {:.6} ({:.1e})",
                p.name(),
                meta["methods"].split(',').nth(mi).unwrap_or("?"),
                s.log_l1,
                want_l1,
                (s.log_l1 - want_l1).abs(),
                s.ssim,
                want_ssim,
                (s.ssim - want_ssim).abs()
            );
            if (s.log_l1 - want_l1).abs() > LOG_L1_TOLERANCE
                || (s.ssim - want_ssim).abs() > SSIM_TOLERANCE
            {
                failures.push(format!("{} method {mi}", p.name()));
            }
        }
    }
    assert!(failures.is_empty(), "disagree: {failures:?}");
}
