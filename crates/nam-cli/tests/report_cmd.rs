//! End-to-end test of `nam-cli report`: a tiny report (2 materials at 16², a few pairs) on
//! the committed held-out set and default model; the table and the plot must exist and the
//! numbers must be finite and ordered as the definitions imply.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap_or_else(|| panic!("non-UTF-8 path"))
}

/// Runs `nam-cli report` at a tiny size; with `gpu` the GPU rows run on the default adapter
/// (lavapipe in CI) when there is one.
fn report(out: &Path, model: &Path, gpu: bool) -> Output {
    let heldout = root().join("assets/heldout");
    Command::new(env!("CARGO_BIN_EXE_nam-cli"))
        .args([
            "report",
            "-o",
            s(out),
            "--heldout",
            s(&heldout),
            "--materials",
            "2",
            "--size",
            "16",
            "--reflect",
            "2",
            "--identity",
            "1",
            "--hemisphere",
            "3",
            "--subset-materials",
            "1",
            "--subset-pairs",
            "1,1,1",
            "--models",
            s(model),
        ])
        .args(if gpu { None } else { Some("--no-gpu") })
        .env("XDG_RUNTIME_DIR", std::env::temp_dir())
        .output()
        .unwrap_or_else(|e| panic!("cannot run nam-cli: {e}"))
}

/// The cells of the rows of the first Markdown table after `heading`.
fn table(md: &str, heading: &str) -> Vec<Vec<String>> {
    let start = md
        .find(heading)
        .unwrap_or_else(|| panic!("no {heading:?} in report"));
    md[start..]
        .lines()
        .skip_while(|l| !l.starts_with('|'))
        .take_while(|l| l.starts_with('|'))
        .skip(2)
        .map(|l| {
            l.trim_matches('|')
                .split('|')
                .map(|c| c.trim().to_string())
                .collect()
        })
        .collect()
}

fn num(cell: &str) -> f64 {
    cell.parse()
        .unwrap_or_else(|_| panic!("not a number: {cell:?}"))
}

#[test]
fn tiny_report_writes_a_table_with_finite_numbers_and_a_plot() {
    let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
    let out = dir.path().join("report");
    let o = report(&out, &root().join("models/default.safetensors"), true);
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "nam-cli report failed: {stderr}");
    let md = std::fs::read_to_string(out.join("report.md")).unwrap_or_else(|e| panic!("{e}"));
    let rows = table(&md, "## Hemisphere protocol");
    let find = |label: &str| {
        rows.iter()
            .find(|r| r[1] == label)
            .unwrap_or_else(|| panic!("no row {label:?} in\n{md}"))
    };
    // Baselines, GGX and, for the model, CPU fast f32, the directional and interpolated
    // specialisations and the CPU reference (bf16 is listed as skipped on CPUs without AVX-512 BF16).
    for label in [
        "printout",
        "diffuse fit",
        "GGX ground truth (analytic render)",
        "default · CPU fast · f32",
        "default · CPU fast · f32 · directional",
        "default · CPU fast · f32 · ≤ 8°",
        "default · CPU reference · f32",
    ] {
        let r = find(label);
        // log-L1, log-RMSE, FLIP, SSIM, ms/relit MP: always numbers.
        for c in [7, 8, 9, 10, 12] {
            let v = num(&r[c]);
            assert!(v.is_finite(), "{label}: column {c} = {v}");
        }
        assert!(num(&r[12]) > 0.0, "{label}: relight time must be positive");
        if label.starts_with("GGX") {
            assert_eq!(r[11], "—", "the GGX truth has no estimate step");
            assert_eq!(num(&r[7]), 0.0);
            assert_eq!(num(&r[10]), 1.0);
        } else {
            assert!(num(&r[11]) >= 0.0);
            assert!(num(&r[7]) > 0.0, "{label}: a method is never exact");
            assert!((0.0..=1.0).contains(&num(&r[9])), "{label}: FLIP in [0, 1]");
        }
    }
    assert_eq!(
        find("default · CPU fast · f32")[2],
        "8",
        "U-Net width C of default"
    );
    assert!(find("default · CPU reference · f32")[6].ends_with("subset"));
    // With an adapter, the GPU rows (general f32 and f16, directional f32) are measured; the
    // general GPU f32 row computes what the CPU reference does on the same subset.
    if md.contains(", GPU adapter ") {
        let reference = find("default · CPU reference · f32");
        for label in [
            "default · GPU · f32",
            "default · GPU · f16",
            "default · GPU · f32 · directional",
        ] {
            let r = find(label);
            for c in [7, 8, 9, 10, 11, 12] {
                assert!(num(&r[c]).is_finite(), "{label}: column {c} = {}", r[c]);
            }
        }
        let gpu = find("default · GPU · f32");
        assert!(
            (num(&gpu[7]) - num(&reference[7])).abs() <= 2e-3,
            "GPU f32 {gpu:?} vs reference {reference:?}"
        );
    } else {
        nam::nam_gpu::skip_without_adapter(&format!("GPU rows: no adapter\n{md}"));
    }
    let all = table(&md, "## All protocols");
    let row = |label: &str| {
        all.iter()
            .find(|r| r[1] == label)
            .unwrap_or_else(|| panic!("no row {label:?}"))
            .clone()
    };
    // The identity protocol is the capture geometry: the printout differs from the truth only
    // by the 8-bit round trip, far less than under new lights.
    let p = row("printout");
    assert!(
        num(&p[6]) < 0.5 * num(&p[10]),
        "printout identity vs hemisphere: {p:?}"
    );
    let png = image::open(out.join("error_vs_time.png")).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!((png.width(), png.height()), (1500, 800));
    assert!(String::from_utf8_lossy(&o.stdout).contains("wrote"));
}

#[test]
fn a_missing_model_is_a_clear_error() {
    let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
    let o = report(
        &dir.path().join("r"),
        &dir.path().join("nope.safetensors"),
        false,
    );
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("nope.safetensors") && err.contains("not found"),
        "{err}"
    );
    assert!(!dir.path().join("r/report.md").exists());
}
