//! The report: which configurations run ([`entries`]), the Markdown tables
//! ([`markdown`]) and the error-versus-time plot ([`plot_points`]), written by [`write`].

use crate::error::{EvalError, Result};
use crate::methods::{Backend, MethodSpec, NeuralConfig, Precision, Specialisation};
use crate::plot::{self, Labels, Point};
use crate::runner::{Entry, EntryResult, PairCounts, RunResults};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// File name of the Markdown report inside the output folder.
pub const REPORT_FILE: &str = "report.md";
/// File name of the plot inside the output folder.
pub const PLOT_FILE: &str = "error_vs_time.png";

/// What the report covers.
#[derive(Debug, Clone, PartialEq)]
pub struct ReportOptions {
    /// Model files, one block of neural rows each.
    pub models: Vec<PathBuf>,
    /// Materials of the full rows.
    pub materials: usize,
    /// Pairs per material of the full rows.
    pub pairs: PairCounts,
    /// Materials of the slow rows (CPU reference, GPU).
    pub subset_materials: usize,
    /// Pairs per material of the slow rows (a prefix of the full rows' pairs).
    pub subset_pairs: PairCounts,
    /// Include GPU rows (skipped with a reason when no adapter exists).
    pub gpu: bool,
}

/// Bounds of the interpolated-ND_enc rows (millidegrees that ωi and ωo may turn between grid
/// nodes): at the report's 64² and the protocols' light heights, grid steps of 1–9 pixels.
const INTERPOLATION_BOUNDS_MILLIDEG: [u32; 4] = [1000, 2000, 4000, 8000];

fn stem(p: &Path) -> String {
    p.file_stem()
        .and_then(|s| s.to_str())
        .unwrap_or("model")
        .to_string()
}

/// The report's rows: the three baselines, then per model the CPU fast path (f32, bf16, int8),
/// the directional specialisation, interpolated ND_enc at several bounds, the CPU reference and the GPU (f32, f16, f32 directional)
/// — the last two kinds on the subset.
pub fn entries(o: &ReportOptions) -> Vec<Entry> {
    let full = |spec: MethodSpec, label: &str| Entry {
        spec,
        label: label.to_string(),
        materials: o.materials,
        pairs: o.pairs,
    };
    let subset = |spec: MethodSpec, label: String| Entry {
        spec,
        label,
        materials: o.subset_materials.min(o.materials),
        pairs: o.subset_pairs.min(o.pairs),
    };
    let mut v = vec![
        full(MethodSpec::Printout, "printout"),
        full(MethodSpec::DiffuseFit, "diffuse fit"),
        full(MethodSpec::GgxTruth, "GGX ground truth (analytic render)"),
    ];
    for m in &o.models {
        let name = stem(m);
        let neural = |backend, precision, specialisation| {
            MethodSpec::Neural(NeuralConfig {
                model: m.clone(),
                backend,
                precision,
                specialisation,
            })
        };
        use Backend::*;
        use Precision::*;
        use Specialisation::*;
        v.push(full(
            neural(CpuFast, F32, General),
            &format!("{name} · CPU fast · f32"),
        ));
        v.push(full(
            neural(CpuFast, Bf16, General),
            &format!("{name} · CPU fast · bf16"),
        ));
        v.push(full(
            neural(CpuFast, Int8, General),
            &format!("{name} · CPU fast · int8"),
        ));
        v.push(full(
            neural(CpuFast, F32, Directional),
            &format!("{name} · CPU fast · f32 · directional"),
        ));
        // The error-vs-time curve of interpolated ND_enc (grid steps of 1–9 pixels at 64²
        // for the protocol's light heights).
        for md in INTERPOLATION_BOUNDS_MILLIDEG {
            v.push(full(
                neural(CpuFast, F32, Interpolated(md)),
                &format!("{name} · CPU fast · f32 · ≤ {}°", f64::from(md) / 1000.0),
            ));
        }
        v.push(subset(
            neural(CpuReference, F32, General),
            format!("{name} · CPU reference · f32"),
        ));
        if o.gpu {
            v.push(subset(
                neural(Gpu, F32, General),
                format!("{name} · GPU · f32"),
            ));
            v.push(subset(
                neural(Gpu, F16, General),
                format!("{name} · GPU · f16"),
            ));
            v.push(subset(
                neural(Gpu, F32, Directional),
                format!("{name} · GPU · f32 · directional"),
            ));
        }
    }
    v
}

/// Where the report is written and what it says about its run.
#[derive(Debug, Clone, PartialEq)]
pub struct ReportMeta {
    /// The command that produced it.
    pub command: String,
    /// CPU threads used (rayon).
    pub threads: usize,
    /// GPU adapter description, if one was found.
    pub gpu: Option<String>,
    /// Where the held-out set came from.
    pub heldout: String,
}

fn f4(v: f64) -> String {
    if v.is_finite() {
        format!("{v:.4}")
    } else {
        "—".into()
    }
}

fn ms(v: f64) -> String {
    if !v.is_finite() {
        "—".into()
    } else if v >= 100.0 {
        format!("{v:.0}")
    } else if v >= 1.0 {
        format!("{v:.2}")
    } else {
        format!("{v:.4}")
    }
}

fn images(r: &EntryResult, full: &RunResults) -> String {
    let e = &r.entry;
    let pairs = format!(
        "{}×({}+{}+{})",
        e.materials.min(full.materials),
        e.pairs.reflect,
        e.pairs.identity,
        e.pairs.hemisphere
    );
    if e.materials < full.materials || e.pairs != full.pairs {
        format!("{pairs} subset")
    } else {
        pairs
    }
}

fn width(r: &EntryResult) -> String {
    if r.width > 0 {
        r.width.to_string()
    } else {
        "—".into()
    }
}

fn backend(r: &EntryResult, meta: &ReportMeta) -> String {
    let b = r.entry.spec.backend_name();
    match (&r.entry.spec, &meta.gpu) {
        // The adapter is named in the header; flag CPU emulation where the times are read.
        (MethodSpec::Neural(c), Some(g))
            if c.backend == Backend::Gpu && g.contains("CPU-emulated") =>
        {
            format!("{b} (lavapipe, CPU-emulated)")
        }
        _ => b.to_string(),
    }
}

/// The Markdown report.
pub fn markdown(res: &RunResults, meta: &ReportMeta) -> String {
    let mut s = String::new();
    let side = res.side;
    let p = res.pairs;
    let _ = writeln!(s, "# Error against run time\n");
    let _ = writeln!(
        s,
        "{} held-out procedural SVBRDFs ({}) at {side}², LDR 8-bit flash photo as input; \
         Reflect {}, Identity {}, Hemisphere {} light/view pairs per material (rows marked \
         *subset* use the first materials and pairs). Ground truth: nam-ggx. Command: `{}` \
         ({:.0} s, {} CPU threads{}).\n",
        res.materials,
        meta.heldout,
        p.reflect,
        p.identity,
        p.hemisphere,
        meta.command,
        res.seconds,
        meta.threads,
        meta.gpu
            .as_ref()
            .map(|g| format!(", GPU adapter {g}"))
            .unwrap_or_else(|| ", no GPU adapter".into()),
    );
    let _ = writeln!(
        s,
        "![error vs time]({PLOT_FILE})\n\n## Hemisphere protocol: error and time\n"
    );
    let _ = writeln!(
        s,
        "| # | method | C | backend | precision | specialisation | images | log-L1 ↓ | log-RMSE ↓ | FLIP ↓ | SSIM ↑ | ms / estimate | ms / relit MP |"
    );
    let _ = writeln!(
        s,
        "|---:|---|---:|---|---|---|---|---:|---:|---:|---:|---:|---:|"
    );
    for (k, r) in res.results.iter().enumerate() {
        let h = &r.scores[2];
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} |",
            k + 1,
            r.entry.label,
            width(r),
            backend(r, meta),
            r.entry.spec.precision_name(),
            r.entry.spec.specialisation_name(),
            images(r, res),
            f4(h.log_l1),
            f4(h.log_rmse),
            f4(h.flip),
            f4(h.ssim),
            r.ms_per_estimate.map(ms).unwrap_or_else(|| "—".into()),
            ms(r.ms_per_megapixel),
        );
    }
    let _ = writeln!(s, "\n## All protocols\n");
    let names = ["reflect", "identity", "hemisphere"];
    let mut head = String::from("| # | method |");
    let mut rule = String::from("|---:|---|");
    for n in names {
        let _ = write!(head, " {n} log-L1 | {n} log-RMSE | {n} FLIP | {n} SSIM |");
        rule.push_str("---:|---:|---:|---:|");
    }
    let _ = writeln!(s, "{head}\n{rule}");
    for (k, r) in res.results.iter().enumerate() {
        let _ = write!(s, "| {} | {} |", k + 1, r.entry.label);
        for sc in &r.scores {
            let _ = write!(
                s,
                " {} | {} | {} | {} |",
                f4(sc.log_l1),
                f4(sc.log_rmse),
                f4(sc.flip),
                f4(sc.ssim)
            );
        }
        s.push('\n');
    }
    if !res.skipped.is_empty() {
        let _ = writeln!(s, "\n## Not available on this machine\n");
        for sk in &res.skipped {
            let _ = writeln!(s, "- {}: {}", sk.entry.label, sk.reason);
        }
    }
    let _ = writeln!(
        s,
        "\n## Definitions\n\n\
         - **Metrics** (`nam_eval::metrics`, the definitions of `train_py/evaluate.py`): log-L1 and \
         log-RMSE of `ln(1+R)` over pixels and channels; SSIM per colour channel on \
         `clamp(R,0,1)^(1/2.2)`, 11×11 Gaussian window σ = 1.5, valid windows; FLIP: our Rust port \
         of LDR-FLIP (`nam_eval::flip`, 67 pixels per degree) on `clamp(R,0,1)`. Means over all \
         images of a row.\n\
         - **Baselines**: *printout* reuses the LDR photo for every light and view; *diffuse fit* \
         divides the photo by the capture cos θ (n = +z) and multiplies by the new `max(ωi.z, 0)`; \
         the *GGX ground truth* row is the analytic render itself (error 0 by construction; its \
         time is the cost of rendering from the true maps, which a photo-only method never has).\n\
         - **Precision** (CPU fast): *bf16* estimates and relights with bf16 products and f32 sums \
         (`set_cpu_precision`), so its error is the two approximations together; *int8* relights \
         with int8 products and exact i32 sums after an f32 estimate (the U-Net has no int8 \
         path).\n\
         - **Times**: wall clock, median over calls, after one untimed warm-up (except the CPU \
         reference). *ms / estimate*: one `M_est` run (or the baseline's preparation) on a \
         {side}² photo; *ms / relit MP*: one relight of the {side}² image divided by its \
         megapixels (at this size per-call overheads weigh more than at 1 MP). CPU threads are \
         shared with other processes on this machine, so times carry noise of tens of percent.\n\
         - **Specialisation** *directional*: the facade's `relight` with a directional light and \
         an orthographic view (ND_enc once per image, DESIGN §9; on the CPU, or on the GPU where \
         the backend says so; bf16 and int8 rows in their precision) with the \
         protocol's point light and viewer replaced by their directions from the material \
         centre; its error includes that approximation. *Interpolated ND_enc (≤ x°)*: the \
         protocol's point light and viewer, ND_enc evaluated only on a grid of pixels whose \
         spacing keeps ωi and ωo within x° between neighbouring nodes (spacing = \
         x·min(light, view height) surface units; below 2 pixels the general path runs), its 32 \
         features bilinearly interpolated per pixel, the render MLP per pixel \
         (`RenderNet::relight_interpolated`).\n\
         - **Pairs** come from nam-ggx's seeded sampler (SplitMix64, seed \
         `4242 + seed mod 100000 + 17·protocol`), which `train_py.evaluate` repeats draw for \
         draw on the same files: the two tables agree to 1e-5 in log-L1 \
         (`crates/nam-eval/tests/eval_agreement.rs`)."
    );
    s
}

/// The plot's points: hemisphere log-L1 against ms per relit megapixel, one per row.
pub fn plot_points(res: &RunResults) -> Vec<Point> {
    res.results
        .iter()
        .map(|r| Point {
            label: r.entry.label.clone(),
            x: r.ms_per_megapixel,
            y: r.scores[2].log_l1,
        })
        .collect()
}

/// Writes `report.md` and `error_vs_time.png` into `dir` (created if missing); returns both
/// paths.
pub fn write(dir: &Path, res: &RunResults, meta: &ReportMeta) -> Result<(PathBuf, PathBuf)> {
    std::fs::create_dir_all(dir).map_err(|error| EvalError::Io {
        path: dir.to_path_buf(),
        error,
    })?;
    let md = dir.join(REPORT_FILE);
    std::fs::write(&md, markdown(res, meta)).map_err(|error| EvalError::Io {
        path: md.clone(),
        error,
    })?;
    let img = plot::scatter(
        &plot_points(res),
        &Labels {
            title: format!(
                "hemisphere log-L1 vs time, {} materials at {}x{}",
                res.materials, res.side, res.side
            ),
            x: "ms per relit megapixel (log scale)".into(),
            y: "hemisphere log-L1 (lower is better)".into(),
        },
    )?;
    let png = dir.join(PLOT_FILE);
    plot::save_png(&img, &png)?;
    Ok((md, png))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn entries_cover_baselines_and_every_backend_per_model() {
        let o = ReportOptions {
            models: vec!["a.safetensors".into(), "b.safetensors".into()],
            materials: 8,
            pairs: PairCounts::PAPER,
            subset_materials: 2,
            subset_pairs: PairCounts {
                reflect: 2,
                identity: 1,
                hemisphere: 300,
            },
            gpu: true,
        };
        let e = entries(&o);
        let interp = INTERPOLATION_BOUNDS_MILLIDEG.len();
        assert_eq!(e.len(), 3 + 2 * (8 + interp));
        assert!(e.iter().any(|x| x.label == "b · CPU fast · int8"));
        assert!(e.iter().any(|x| x.label == "a · CPU fast · f32 · ≤ 2°"
            && x.spec.specialisation_name() == "interpolated ND_enc (≤ 2° per node)"));
        let reference = e
            .iter()
            .find(|x| x.label == "b · CPU reference · f32")
            .unwrap_or_else(|| panic!("missing row"));
        // The subset never asks for more pairs than the full rows.
        assert_eq!(reference.pairs.hemisphere, 128);
        assert_eq!(reference.materials, 2);
        let no_gpu = entries(&ReportOptions { gpu: false, ..o });
        assert_eq!(no_gpu.len(), 3 + 2 * (5 + interp));
    }

    #[test]
    fn number_formats() {
        assert_eq!(ms(1234.4), "1234");
        assert_eq!(ms(12.345), "12.35");
        assert_eq!(ms(0.01234), "0.0123");
        assert_eq!(f4(f64::NAN), "—");
    }
}
