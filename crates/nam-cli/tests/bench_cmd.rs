//! End-to-end test of `nam-cli bench`: the real binary prints a well-formed
//! Markdown table with one measured row per path, and rejects bad options.

use std::process::{Command, Output};

fn run(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_nam-cli"))
        .args(args)
        .env("RAYON_NUM_THREADS", "2")
        .output()
        .unwrap_or_else(|e| panic!("cannot run nam-cli: {e}"))
}

/// Rows the table must have, in order (prefixes of the first column).
/// (The bf16 and int8 rows, present only on CPUs with AVX-512 BF16 / VNNI, are checked apart.)
const ROWS: [&str; 15] = [
    "sgemm 1024³",
    "estimate 32²",
    "general point relight 32²",
    "point relight 32², interpolated ND_enc ≤ 0.5°",
    "point relight 32², interpolated ND_enc ≤ 1°",
    "point relight 32², interpolated ND_enc ≤ 2°",
    "general point relight 32², l0·l1 unfolded",
    "directional + orthographic 32²",
    "directional + orthographic 32², l0·l1 unfolded",
    "prepare material 32²",
    "prepared point relight 32²",
    "prepared directional + orthographic 32²",
    "prepared point relight, ROI 32²",
    "prepared query batch",
    "estimate 32², direct convs only (no Winograd)",
];

/// The cells of the Markdown table rows in `text` (header and separator left out).
fn table_rows(text: &str) -> Vec<Vec<&str>> {
    text.lines()
        .filter(|l| l.starts_with("| ") && !l.starts_with("| path"))
        .map(|l| l.trim_matches('|').split('|').map(str::trim).collect())
        .collect()
}

#[test]
fn bench_prints_one_measured_row_per_path() {
    let o = run(&["bench", "--size", "32", "--repeat", "1"]);
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(
        o.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(stdout.contains("2 threads"), "{stdout}");
    // The bf16 and int8 rows name their kernels (AMX tiles, AVX-512 BF16, AVX-512 VNNI) and
    // exist only where the CPU has the instructions, in that order (the bf16 estimate first).
    let (reduced, rows): (Vec<_>, Vec<_>) = table_rows(&stdout)
        .into_iter()
        .partition(|r| r[0].contains(", bf16 (") || r[0].contains(", int8 ("));
    assert!(reduced.len() <= 3, "{stdout}");
    assert_eq!(rows.len(), ROWS.len(), "{stdout}");
    let mut kinds: Vec<String> = vec![];
    if nam_model::bf16_supported() {
        // The bf16 estimate names its kernel (AMX tiles where the CPU has them) and gives its
        // params' distance from f32's.
        let kernel = nam_model::bf16_kernel();
        kinds.push(format!("estimate 32², bf16 ({kernel}; params within "));
        kinds.push(format!("general point relight 32², bf16 ({kernel})"));
    }
    if nam_model::int8_supported() {
        kinds.push("general point relight 32², int8 (AVX-512 VNNI)".into());
    }
    assert_eq!(reduced.len(), kinds.len(), "{stdout}");
    let wanted = ROWS.iter().copied().chain(kinds.iter().map(String::as_str));
    for (row, want) in rows.iter().chain(&reduced).zip(wanted) {
        assert_eq!(row.len(), 6, "{row:?}");
        assert!(row[0].starts_with(want), "{} vs {want}", row[0]);
        let ms: f64 = row[2].parse().unwrap_or_else(|_| panic!("ms of {row:?}"));
        let gflops: f64 = row[3]
            .parse()
            .unwrap_or_else(|_| panic!("GFLOP/s of {row:?}"));
        assert!(ms > 0.0 && ms.is_finite(), "{row:?}");
        assert!(gflops > 0.0 && gflops.is_finite(), "{row:?}");
        assert!(row[5].ends_with('%'), "{row:?}");
    }
    // Speedups are per item against the general point relight (row 2).
    assert_eq!(rows[2][4], "1.00");
    assert_eq!(rows[0][4], "—");
    for row in rows[3..]
        .iter()
        .chain(&reduced)
        .filter(|r| !r[0].starts_with("estimate"))
    {
        let x: f64 = row[4]
            .parse()
            .unwrap_or_else(|_| panic!("speedup of {row:?}"));
        assert!(x > 0.0 && x.is_finite(), "{row:?}");
    }
    // Item counts: 32² pixels, the whole image as ROI (64 clamped to 32), 4096 queries.
    assert_eq!(rows[2][1], "1024");
    assert_eq!(rows[12][1], "1024");
    assert_eq!(rows[13][1], "4096");
}

#[test]
fn bench_rejects_bad_options_and_missing_models() {
    for args in [
        &["bench", "--size", "0"][..],
        &["bench", "--size", "4"][..],
        &["bench", "--repeat", "0"][..],
        &["bench", "--size", "x"][..],
    ] {
        let o = run(args);
        assert!(!o.status.success(), "{args:?} must fail");
        assert!(!o.stderr.is_empty(), "{args:?} must say why");
    }
    let o = run(&[
        "bench",
        "--size",
        "8",
        "--model",
        "/nonexistent/model.safetensors",
    ]);
    assert!(!o.status.success());
    assert!(
        String::from_utf8_lossy(&o.stderr).contains("nonexistent"),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
}

/// Rows of the `--gpu` table, in order.
const GPU_ROWS: [&str; 6] = [
    "GPU general point relight 16²",
    "GPU directional + orthographic 16²",
    "CPU general point relight 16²",
    "CPU directional + orthographic 16²",
    "GPU estimate (M_est) 16²",
    "CPU estimate (M_est) 16²",
];

#[test]
fn bench_gpu_times_both_plans_on_the_adapter_and_the_cpu() {
    let o = run(&["bench", "--size", "16", "--repeat", "1", "--gpu-only"]);
    let (stdout, stderr) = (
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr),
    );
    if !o.status.success() && stderr.contains("no wgpu adapter") {
        nam::nam_gpu::skip_without_adapter(&format!("no wgpu adapter\n{stderr}"));
        return;
    }
    assert!(o.status.success(), "{stdout}\n{stderr}");
    let gpu_table = stdout
        .split("\nGPU: ")
        .nth(1)
        .unwrap_or_else(|| panic!("no GPU table:\n{stdout}"));
    assert!(
        !stdout.contains("sgemm"),
        "--gpu-only printed the CPU table:\n{stdout}"
    );
    let peak: f64 = gpu_table
        .split("FMA peak (shaders/fma_peak.wgsl) ")
        .nth(1)
        .and_then(|t| t.split(' ').next())
        .and_then(|v| v.parse().ok())
        .unwrap_or_else(|| panic!("no FMA peak in {gpu_table}"));
    assert!(peak > 0.0 && peak.is_finite(), "{gpu_table}");
    let rows = table_rows(gpu_table);
    assert_eq!(rows.len(), GPU_ROWS.len(), "{gpu_table}");
    for (k, (row, want)) in rows.iter().zip(GPU_ROWS).enumerate() {
        assert_eq!(row[0], want, "{row:?}");
        assert_eq!(row[1], "256", "{row:?}");
        let cols: &[usize] = if k < 4 { &[2, 3, 4] } else { &[2, 3] };
        for &col in cols {
            let v: f64 = row[col]
                .parse()
                .unwrap_or_else(|_| panic!("column {col} of {row:?}"));
            assert!(v > 0.0 && v.is_finite(), "{row:?}");
        }
    }
    assert_eq!(rows[0][4], "1.00");
    assert_eq!(rows[2][4], "1.00");
    assert!(
        rows[0][5].parse::<f64>().is_ok_and(|x| x > 0.0),
        "{:?}",
        rows[0]
    );
    assert_eq!(rows[2][5], "—");
    assert_eq!(rows[4][4], "—");
    assert!(
        rows[4][5].parse::<f64>().is_ok_and(|x| x > 0.0),
        "{:?}",
        rows[4]
    );
    assert_eq!(rows[5][5], "—");
}
