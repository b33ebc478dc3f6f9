//! `nam-cli bench`: the CPU paths of DESIGN §9 timed in one run against the
//! general per-pixel relight and this machine's sgemm rate.

use anyhow::{Result, bail};
use nam::NeuralModel;
use nam_model::geometry::{CAPTURE_DISTANCE, unit_direction};
use nam_model::{RenderNet, Roi, Source};
use std::fmt::Write as _;
use std::path::PathBuf;

use super::timing::{Case, Row, measure};

/// Time the CPU paths (estimate, general relight, directional + orthographic,
/// prepared material, ROI, query batch) against each other and the sgemm
/// roofline, and print a Markdown table.
///
/// Example: `nam-cli bench --size 256 --repeat 3`
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Image side in pixels (param map and photo are size × size).
    #[arg(long, default_value_t = 256, value_parser = clap::value_parser!(u16).range(8..=2048))]
    pub size: u16,
    /// Timed runs per row after one warm-up run; the best is reported.
    #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u16).range(1..))]
    pub repeat: u16,
    /// Model file (default: the embedded model).
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// Also time the image relights on the first wgpu adapter (lavapipe included): the
    /// general and the directional plan and the estimate, each against the same path on the
    /// CPU.
    #[arg(long)]
    pub gpu: bool,
    /// Only the GPU table (implies `--gpu`; its CPU rows, the same paths on the CPU, stay).
    #[arg(long)]
    pub gpu_only: bool,
}

/// Side of the sgemm roofline product (n × n × n).
const SGEMM_N: usize = 1024;
/// Side of the region-of-interest row (clamped to the image).
const ROI_SIDE: usize = 64;
/// Bounds (degrees that ωi and ωo may turn between grid nodes) of the interpolated-ND_enc rows.
const INTERPOLATION_BOUNDS_DEG: [f32; 3] = [0.5, 1.0, 2.0];
/// Queries in the query-batch row.
const QUERIES: usize = 4096;

/// Runs the subcommand.
pub fn run(args: &Args) -> Result<()> {
    let model = match &args.model {
        Some(p) => NeuralModel::from_file(p)?,
        None => NeuralModel::embedded()?,
    };
    let (s, rep) = (usize::from(args.size), usize::from(args.repeat));
    let n = s * s;
    let cpu = model.cpu();
    let net = &cpu.render;
    let unfolded = RenderNet::new_unfolded(model.weights())?;

    // A smooth synthetic photo in the network's input layout, its param map
    // and prepared material.
    let input: Vec<f32> = (0..4 * n)
        .map(|i| {
            let (c, p) = (i / n, i % n);
            let (y, x) = ((p / s) as f32 / s as f32, (p % s) as f32 / s as f32);
            0.3 + 0.2 * ((7.0 * x + 3.0 * y + c as f32).sin())
        })
        .collect();
    let map = cpu.unet.estimate(&input, s, s)?;
    if args.gpu_only {
        return gpu_rows(&model, map, &input, rep);
    }
    let prep = net.prepare(&map)?;

    let sn = SGEMM_N;
    let a: Vec<f32> = (0..sn * sn).map(|i| (i % 7) as f32 * 0.1).collect();
    let b: Vec<f32> = (0..sn * sn).map(|i| (i % 5) as f32 * 0.1).collect();
    let mut c = vec![0.0f32; sn * sn];

    let light = [1.5, 1.0, 3.5];
    let view = [0.0, 0.0, CAPTURE_DISTANCE as f32];
    let wi = unit_direction(light);
    let wo = [0.0, 0.0, 1.0];
    let full = Roi::full(s, s);
    let (pl, pv) = (Source::Point(light), Source::Point(view));
    let (dl, dv) = (Source::Distant(wi), Source::Distant(wo));
    let side = ROI_SIDE.min(s);
    let roi = Roi {
        row: (s - side) / 2,
        col: (s - side) / 2,
        height: side,
        width: side,
    };
    let texels: Vec<usize> = (0..QUERIES).map(|q| (q * 7919) % n).collect();
    let qwi: Vec<[f32; 3]> = (0..QUERIES)
        .map(|q| unit_direction([(q % 61) as f32 / 30.0 - 1.0, 0.4, 1.0]))
        .collect();
    let qwo: Vec<[f32; 3]> = (0..QUERIES)
        .map(|q| unit_direction([0.2, (q % 53) as f32 / 26.0 - 1.0, 1.0]))
        .collect();
    let mut out = vec![0.0f32; QUERIES * 3];
    // The opt-in bf16 and int8 products (`--precision bf16|int8`) where the CPU has them.
    let bf16 = if nam_model::bf16_supported() {
        Some(net.clone().with_bf16()?)
    } else {
        None
    };
    let int8 = if nam_model::int8_supported() {
        Some(net.clone().with_int8()?)
    } else {
        None
    };

    // The U-Net with every conv direct (no Winograd), timed in the same rounds.
    let unet_direct = cpu.unet.clone().without_winograd();

    // The U-Net with bf16 products (`UNet::with_bf16`), and how far its param map lies from
    // the f32 one: the largest |a − b| / (1 + |b|).
    let unet_bf16 = if nam_model::bf16_supported() {
        let u = cpu.unet.clone().with_bf16()?;
        let got = u.estimate(&input, s, s)?;
        let err = got
            .data
            .iter()
            .zip(&map.data)
            .map(|(a, b)| (a - b).abs() / (1.0 + b.abs()))
            .fold(0.0f32, f32::max);
        Some((u, err))
    } else {
        None
    };

    // 2 flops per multiply-add, per run.
    let fl = |macs_per_item: usize, items: usize| 2.0 * macs_per_item as f64 * items as f64;
    let m = |prepared, constant| net.macs_per_output(prepared, constant);
    let mut cases: Vec<Case<'_>> = vec![
        (
            format!("sgemm {sn}³ (roofline)"),
            0,
            2.0 * (sn as f64).powi(3),
            Box::new(|| Ok(nam_model::matmul(sn, sn, sn, &a, &b, &mut c)?)),
        ),
        (
            format!("estimate {s}² (M_est; direct-conv FLOPs, Winograd runs fewer)"),
            0,
            2.0 * model.config().estimate_macs(s, s) as f64,
            Box::new(|| {
                cpu.unet.estimate(&input, s, s)?;
                Ok(())
            }),
        ),
        (
            general_row(s),
            n,
            fl(m(false, false), n),
            Box::new(|| {
                net.relight(&map, light, view)?;
                Ok(())
            }),
        ),
        (
            format!("general point relight {s}², l0·l1 unfolded"),
            n,
            fl(unfolded.macs_per_output(false, false), n),
            Box::new(|| {
                unfolded.relight(&map, light, view)?;
                Ok(())
            }),
        ),
        (
            format!("directional + orthographic {s}²"),
            n,
            fl(m(false, true), n),
            Box::new(|| {
                net.relight_directional(&map, wi, wo)?;
                Ok(())
            }),
        ),
        (
            format!("directional + orthographic {s}², l0·l1 unfolded"),
            n,
            fl(unfolded.macs_per_output(false, true), n),
            Box::new(|| {
                unfolded.relight_directional(&map, wi, wo)?;
                Ok(())
            }),
        ),
        (
            format!("prepare material {s}² (W_p·p once)"),
            n,
            fl(net.param_channels() * net.hidden_len(), n),
            Box::new(|| {
                net.prepare(&map)?;
                Ok(())
            }),
        ),
        (
            format!("prepared point relight {s}²"),
            n,
            fl(m(true, false), n),
            Box::new(|| {
                net.relight_prepared(&prep, pl, pv, full)?;
                Ok(())
            }),
        ),
        (
            format!("prepared directional + orthographic {s}²"),
            n,
            fl(m(true, true), n),
            Box::new(|| {
                net.relight_prepared(&prep, dl, dv, full)?;
                Ok(())
            }),
        ),
        (
            format!("prepared point relight, ROI {side}²"),
            side * side,
            fl(m(true, false), side * side),
            Box::new(|| {
                net.relight_prepared(&prep, pl, pv, roi)?;
                Ok(())
            }),
        ),
        (
            format!("prepared query batch ({QUERIES} texel, ωi, ωo)"),
            QUERIES,
            fl(m(true, false), QUERIES),
            Box::new(|| {
                net.render_log_prepared(&prep, &texels, &qwi, &qwo, &mut out)?;
                Ok(())
            }),
        ),
    ];
    // Interpolated ND_enc: grid steps of 3, 7 and 15 pixels for this light at 256².
    for (k, deg) in INTERPOLATION_BOUNDS_DEG.into_iter().enumerate() {
        let step = nam_model::interpolation_step(light[2], view[2], s, s, deg.to_radians());
        // Per pixel: the directional count plus W_d·f; ND_enc (the rest) per grid node.
        let per_pixel = m(false, true) + net.nd_len() * net.hidden_len();
        let lines = (s - 1).div_ceil(step) + 1;
        let macs = per_pixel * n + (m(false, false) - per_pixel) * lines * lines;
        let (map, net) = (&map, net);
        cases.insert(
            3 + k,
            (
                format!("point relight {s}², interpolated ND_enc ≤ {deg}° (grid step {step} px)"),
                n,
                fl(macs, 1),
                Box::new(move || {
                    net.relight_interpolated(map, light, view, deg.to_radians())?;
                    Ok(())
                }),
            ),
        );
    }
    if let Some(bf) = &bf16 {
        cases.insert(
            3,
            (
                format!(
                    "general point relight {s}², bf16 ({})",
                    nam_model::bf16_kernel()
                ),
                n,
                fl(m(false, false), n),
                Box::new(|| {
                    bf.relight(&map, light, view)?;
                    Ok(())
                }),
            ),
        );
    }
    if let Some(q) = &int8 {
        cases.insert(
            3 + usize::from(bf16.is_some()),
            (
                format!("general point relight {s}², int8 (AVX-512 VNNI)"),
                n,
                fl(m(false, false), n),
                Box::new(|| {
                    q.relight(&map, light, view)?;
                    Ok(())
                }),
            ),
        );
    }
    if let Some((u, err)) = &unet_bf16 {
        cases.insert(
            2,
            (
                format!(
                    "estimate {s}², bf16 ({}; params within {err:.1e} of f32)",
                    nam_model::bf16_kernel()
                ),
                0,
                2.0 * model.config().estimate_macs(s, s) as f64,
                Box::new(|| {
                    u.estimate(&input, s, s)?;
                    Ok(())
                }),
            ),
        );
    }
    cases.push((
        format!("estimate {s}², direct convs only (no Winograd)"),
        0,
        2.0 * model.config().estimate_macs(s, s) as f64,
        Box::new(|| {
            unet_direct.estimate(&input, s, s)?;
            Ok(())
        }),
    ));
    let rows = measure(cases, rep)?;
    if !out.iter().all(|v| v.is_finite()) {
        bail!("query batch gave non-finite output");
    }
    let sg_gflops = rows[0].flops / rows[0].ms / 1e6;
    print!("{}", table(&rows, sg_gflops, threads(), s, rep));
    if args.gpu {
        gpu_rows(&model, map, &input, rep)?;
    }
    Ok(())
}

#[cfg(feature = "gpu")]
fn gpu_rows(
    model: &NeuralModel,
    map: nam_model::ParamMap,
    input: &[f32],
    rep: usize,
) -> Result<()> {
    println!();
    print!("{}", super::bench_gpu::run(model, map, input, rep)?);
    Ok(())
}

#[cfg(not(feature = "gpu"))]
fn gpu_rows(_: &NeuralModel, _: nam_model::ParamMap, _: &[f32], _: usize) -> Result<()> {
    bail!("--gpu: this nam-cli was built without the `gpu` feature")
}

/// Worker threads of rayon's global pool (what the networks run on).
fn threads() -> usize {
    std::env::var("RAYON_NUM_THREADS")
        .ok()
        .and_then(|v| v.parse().ok())
        .filter(|&t: &usize| t > 0)
        .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, usize::from))
}

/// Name of the general point relight row, which speedups are relative to.
fn general_row(s: usize) -> String {
    format!("general point relight {s}²")
}

/// The Markdown report; speedups are per pixel/query, relative to [`general_row`].
fn table(rows: &[Row], sg_gflops: f64, threads: usize, s: usize, rep: usize) -> String {
    let mut t = String::new();
    let _ = writeln!(
        t,
        "CPU, {threads} threads, size {s}², best of {rep} interleaved rounds after a warm-up round; sgemm roofline {sg_gflops:.1} GFLOP/s\n"
    );
    let _ = writeln!(
        t,
        "| path | pixels/queries | ms | GFLOP/s | × general (per item) | % of sgemm roofline |"
    );
    let _ = writeln!(t, "|---|---:|---:|---:|---:|---:|");
    let general = rows
        .iter()
        .find(|r| r.name == general_row(s))
        .map(|g| g.ms / g.items.max(1) as f64);
    for r in rows {
        let gf = r.flops / r.ms / 1e6;
        let items = if r.items == 0 {
            "—".to_string()
        } else {
            r.items.to_string()
        };
        let speedup = match (general, r.items) {
            (Some(g), i) if i > 0 => format!("{:.2}", g / (r.ms / i as f64)),
            _ => "—".to_string(),
        };
        let _ = writeln!(
            t,
            "| {} | {items} | {:.2} | {gf:.1} | {speedup} | {:.0}% |",
            r.name,
            r.ms,
            100.0 * gf / sg_gflops
        );
    }
    t
}
