//! Every kernel against a plain CPU loop, on odd sizes, in f32 and (when the adapter has
//! SHADER_F16) f16. Without an adapter tests print a reason and pass, except under `CI=true`
//! ([`crate::skip_without_adapter`]).
//!
//! Over 600 lines on purpose: one test per kernel family, each next to the plain CPU loop it is
//! checked against, sharing one device and one set of helpers; it is test code only.

use std::sync::OnceLock;

use crate::context::{DeviceBuffer, GpuContext, MatmulVariant};
use crate::ops::{self, Act, ConvShape, Elementwise, GateTail, Rows, TexOut, View};
use crate::shaders::Precision;

/// f32 kernels vs f64 CPU loops: sums of up to ~600 products of O(1) values; f32 rounding
/// of such sums stays below 1e-5 relative to the sum of magnitudes.
const F32_TOL: f32 = 2e-5;
/// f16 storage: inputs, weights and outputs are rounded to 11 significant bits (~5e-4).
const F16_TOL: f32 = 4e-3;

fn ctx() -> Option<&'static GpuContext> {
    static CTX: OnceLock<Result<GpuContext, String>> = OnceLock::new();
    let c = CTX.get_or_init(|| {
        let h = crate::request_device(true).ok_or("no GPU adapter available")?;
        eprintln!(
            "nam-gpu kernel tests on {:?} ({:?})",
            h.info.name, h.info.backend
        );
        GpuContext::new(&h.device, &h.queue, h.info.device_type)
            .map_err(|e| format!("context creation failed: {e}"))
    });
    match c {
        Ok(c) => Some(c),
        Err(reason) => {
            crate::skip_without_adapter(reason);
            None
        }
    }
}

fn precisions(ctx: &GpuContext) -> Vec<(Precision, f32)> {
    let mut v = vec![(Precision::F32, F32_TOL)];
    if ctx.check_precision(Precision::F16).is_ok() {
        v.push((Precision::F16, F16_TOL));
    } else {
        eprintln!("note: adapter lacks SHADER_F16; f16 kernel variants not run");
    }
    v
}

/// Deterministic values in [-1, 1).
fn rand_vec(n: usize, seed: u64) -> Vec<f32> {
    let mut s = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15).wrapping_add(1);
    (0..n)
        .map(|_| {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            ((s >> 40) as f32 / (1u64 << 23) as f32) - 1.0
        })
        .collect()
}

/// Rounds through the storage precision, so the CPU reference sees the same inputs.
fn q(v: &[f32], p: Precision) -> Vec<f32> {
    match p {
        Precision::F32 => v.to_vec(),
        Precision::F16 => v.iter().map(|&x| half::f16::from_f32(x).to_f32()).collect(),
    }
}

fn assert_close(got: &[f32], want: &[f32], tol: f32, what: &str) {
    assert_eq!(got.len(), want.len(), "{what}: length");
    let scale = want.iter().fold(1.0f32, |m, v| m.max(v.abs()));
    for (i, (g, w)) in got.iter().zip(want).enumerate() {
        let err = (g - w).abs();
        assert!(
            err <= tol * scale.max(w.abs()),
            "{what}: element {i}: got {g}, want {w} (|err| {err}, tol {tol} x {scale})"
        );
    }
}

fn run(
    ctx: &GpuContext,
    d: Vec<crate::context::Dispatch>,
    out: &DeviceBuffer,
    n: usize,
) -> Vec<f32> {
    ctx.run(&d).unwrap_or_else(|e| panic!("run: {e}"));
    ctx.read(out, n as u64)
        .unwrap_or_else(|e| panic!("read: {e}"))
}

fn up(ctx: &GpuContext, data: &[f32], p: Precision) -> DeviceBuffer {
    ctx.upload("test", data, p)
        .unwrap_or_else(|e| panic!("upload: {e}"))
}

fn zeros(ctx: &GpuContext, n: usize, p: Precision) -> DeviceBuffer {
    ctx.storage("test out", n as u64, p)
        .unwrap_or_else(|e| panic!("alloc: {e}"))
}

fn act_ref(v: f64, act: Act) -> f64 {
    match act {
        Act::None => v,
        Act::Leaky(s) => {
            if v >= 0.0 {
                v
            } else {
                v * f64::from(s)
            }
        }
    }
}

#[allow(clippy::too_many_arguments)]
fn conv_ref(
    x: &[f32],
    w: &[f32],
    bias: Option<&[f32]>,
    norm: Option<&[f32]>,
    s: ConvShape,
    act: Act,
) -> Vec<f32> {
    let (ho, wo) = s.out_hw();
    let (cin, h, wd, k) = (s.cin as usize, s.h as i64, s.w as i64, s.k as i64);
    let mut out = vec![0.0; s.cout as usize * (ho * wo) as usize];
    for co in 0..s.cout as usize {
        for oy in 0..ho as i64 {
            for ox in 0..wo as i64 {
                let mut acc = bias.map_or(0.0, |b| f64::from(b[co]));
                for ci in 0..cin {
                    let (sc, sh) = norm.map_or((1.0, 0.0), |n| {
                        (f64::from(n[2 * ci]), f64::from(n[2 * ci + 1]))
                    });
                    for ky in 0..k {
                        for kx in 0..k {
                            let iy =
                                (oy * i64::from(s.stride) + ky - i64::from(s.pad)).clamp(0, h - 1);
                            let ix =
                                (ox * i64::from(s.stride) + kx - i64::from(s.pad)).clamp(0, wd - 1);
                            let xv = f64::from(x[ci * (h * wd) as usize + (iy * wd + ix) as usize])
                                * sc
                                + sh;
                            let wv = f64::from(
                                w[((co * cin + ci) * k as usize + ky as usize) * k as usize
                                    + kx as usize],
                            );
                            acc += xv * wv;
                        }
                    }
                }
                out[co * (ho * wo) as usize + (oy * i64::from(wo) + ox) as usize] =
                    act_ref(acc, act) as f32;
            }
        }
    }
    out
}

/// ConvTranspose2d (stride 2, weight `[cin, cout, k, k]`) + bias + optional ReLU, in the
/// scatter form of the definition: every input tap adds to one output pixel.
fn conv_t_ref(x: &[f32], wt: &[f32], b: &[f32], s: ConvShape, relu: bool) -> Vec<f32> {
    let (cin, cout, h, w, k) = (
        s.cin as usize,
        s.cout as usize,
        i64::from(s.h),
        i64::from(s.w),
        i64::from(s.k),
    );
    let (ho, wo) = (
        (h - 1) * 2 + k - 2 * i64::from(s.pad),
        (w - 1) * 2 + k - 2 * i64::from(s.pad),
    );
    let mut want = vec![0.0f64; cout * (ho * wo) as usize];
    for ci in 0..cin {
        for iy in 0..h {
            for ix in 0..w {
                for co in 0..cout {
                    for ky in 0..k {
                        for kx in 0..k {
                            let oy = iy * 2 - i64::from(s.pad) + ky;
                            let ox = ix * 2 - i64::from(s.pad) + kx;
                            if (0..ho).contains(&oy) && (0..wo).contains(&ox) {
                                want[co * (ho * wo) as usize + (oy * wo + ox) as usize] +=
                                    f64::from(x[ci * (h * w) as usize + (iy * w + ix) as usize])
                                        * f64::from(
                                            wt[((ci * cout + co) * k as usize + ky as usize)
                                                * k as usize
                                                + kx as usize],
                                        );
                            }
                        }
                    }
                }
            }
        }
    }
    want.iter()
        .enumerate()
        .map(|(j, v)| {
            let y = v + f64::from(b[j / (ho * wo) as usize]);
            (if relu { y.max(0.0) } else { y }) as f32
        })
        .collect()
}

#[test]
fn smoke_kernel_round_trips_through_the_device() {
    let Some(ctx) = ctx() else { return };
    let data: Vec<f32> = (0..100).map(|i| i as f32 * 0.5).collect();
    let got = crate::probe::smoke(ctx, &data).unwrap_or_else(|e| panic!("{e}"));
    let want: Vec<f32> = data.iter().map(|v| 2.0 * v + 1.0).collect();
    assert_eq!(got, want);
}

#[test]
fn conv2d_matches_cpu_reference_on_odd_sizes() {
    let Some(ctx) = ctx() else { return };
    for (p, tol) in precisions(ctx) {
        // (cin, h, w, cout, k, stride, pad, bias, norm, act)
        let cases = [
            (
                3u32,
                9u32,
                11u32,
                5u32,
                3u32,
                1u32,
                1u32,
                false,
                false,
                Act::None,
            ),
            (3, 9, 11, 6, 3, 2, 1, true, true, Act::Leaky(0.1)),
            (4, 13, 10, 7, 7, 1, 3, false, false, Act::Leaky(0.01)),
            (5, 7, 9, 3, 1, 2, 0, true, false, Act::None),
            (2, 5, 3, 9, 7, 2, 3, true, true, Act::None),
        ];
        for (i, &(cin, h, w, cout, k, stride, pad, use_bias, use_norm, act)) in
            cases.iter().enumerate()
        {
            let s = ConvShape {
                cin,
                h,
                w,
                cout,
                k,
                stride,
                pad,
            };
            let (ho, wo) = s.out_hw();
            let x = q(&rand_vec((cin * h * w) as usize + 5, 10 + i as u64), p);
            let wt = q(&rand_vec((cout * cin * k * k) as usize, 20 + i as u64), p);
            let b = q(&rand_vec(cout as usize, 30 + i as u64), p);
            let norm: Vec<f32> = rand_vec(2 * cin as usize, 40 + i as u64)
                .iter()
                .map(|v| v + 1.5)
                .collect();
            let xb = up(ctx, &x, p);
            let wb = up(ctx, &wt, p);
            let bb = up(ctx, &b, p);
            let nb = up(ctx, &norm, Precision::F32);
            // Input view at element offset 5 and output at offset 3 exercise the bases.
            let out = zeros(ctx, (3 + cout * ho * wo) as usize, p);
            let d = ops::conv2d(
                ctx,
                p,
                View {
                    buf: &xb.buffer,
                    base: 5,
                },
                &wb.buffer,
                use_bias.then_some(&bb.buffer),
                use_norm.then_some(&nb.buffer),
                View {
                    buf: &out.buffer,
                    base: 3,
                },
                s,
                act,
            )
            .unwrap_or_else(|e| panic!("{e}"));
            let got = run(ctx, vec![d], &out, out.elems as usize);
            let want = conv_ref(
                &x[5..],
                &wt,
                use_bias.then_some(&b[..]),
                use_norm.then_some(&norm[..]),
                s,
                act,
            );
            assert_close(&got[3..], &want, tol, &format!("conv2d case {i} {p:?}"));
        }
    }
}

#[test]
fn conv_transpose_matches_cpu_reference_on_odd_sizes() {
    let Some(ctx) = ctx() else { return };
    for (p, tol) in precisions(ctx) {
        for (i, &(cin, h, w, cout, k, pad, relu)) in [
            (3u32, 5u32, 7u32, 4u32, 4u32, 1u32, true),
            (5, 3, 5, 3, 2, 0, false),
        ]
        .iter()
        .enumerate()
        {
            let s = ConvShape {
                cin,
                h,
                w,
                cout,
                k,
                stride: 2,
                pad,
            };
            let (ho, wo) = ((h - 1) * 2 + k - 2 * pad, (w - 1) * 2 + k - 2 * pad);
            let x = q(&rand_vec((cin * h * w) as usize, 50 + i as u64), p);
            let wt = q(&rand_vec((cin * cout * k * k) as usize, 60 + i as u64), p);
            let b = q(&rand_vec(cout as usize, 70 + i as u64), p);
            let (xb, wb, bb) = (up(ctx, &x, p), up(ctx, &wt, p), up(ctx, &b, p));
            let out = zeros(ctx, (cout * ho * wo) as usize, p);
            let d = ops::conv_transpose2d(
                ctx,
                p,
                View {
                    buf: &xb.buffer,
                    base: 0,
                },
                &wb.buffer,
                Some(&bb.buffer),
                View {
                    buf: &out.buffer,
                    base: 0,
                },
                s,
                relu,
            )
            .unwrap_or_else(|e| panic!("{e}"));
            let got = run(ctx, vec![d], &out, out.elems as usize);
            let want = conv_t_ref(&x, &wt, &b, s, relu);
            assert_close(&got, &want, tol, &format!("conv_transpose case {i} {p:?}"));
        }
    }
}

#[test]
fn instance_norm_statistics_match_cpu_reference_on_odd_sizes() {
    let Some(ctx) = ctx() else { return };
    for (p, _) in precisions(ctx) {
        for &(c, h, w) in &[(3usize, 5usize, 7usize), (2, 37, 29)] {
            let hw = h * w;
            // Offset mean and scale so the two-pass variance matters.
            let x: Vec<f32> = q(
                &rand_vec(c * hw, 80 + hw as u64)
                    .iter()
                    .enumerate()
                    .map(|(i, v)| 3.0 + v * (1 + i / hw) as f32)
                    .collect::<Vec<_>>(),
                p,
            );
            let xb = up(ctx, &x, p);
            let norm = zeros(ctx, 2 * c, Precision::F32);
            let eps = 1e-5;
            let d = ops::instance_norm_stats(
                ctx,
                p,
                View {
                    buf: &xb.buffer,
                    base: 0,
                },
                c as u32,
                hw as u32,
                eps,
                &norm.buffer,
            )
            .unwrap_or_else(|e| panic!("{e}"));
            let got = run(ctx, vec![d], &norm, 2 * c);
            let mut want = Vec::with_capacity(2 * c);
            for ch in x.chunks_exact(hw) {
                let mean = ch.iter().map(|&v| f64::from(v)).sum::<f64>() / hw as f64;
                let var = ch
                    .iter()
                    .map(|&v| (f64::from(v) - mean).powi(2))
                    .sum::<f64>()
                    / hw as f64;
                let r = 1.0 / (var + f64::from(eps)).sqrt();
                want.extend([r as f32, (-mean * r) as f32]);
            }
            // The statistics are computed in f32 whatever the storage precision; the scale is
            // O(1) and the shift O(mean · scale), so the tolerance applies to them directly.
            assert_close(
                &got,
                &want,
                F32_TOL * 4.0,
                &format!("instance norm statistics {c}x{h}x{w} {p:?}"),
            );
        }
    }
}

#[test]
fn ha_gate_matches_cpu_reference_for_every_tail() {
    let Some(ctx) = ctx() else { return };
    // (hw, residual offset, output offset): element by element, then the vec4 path.
    for (p, tol) in precisions(ctx) {
        for (hw, rb, ob) in [(35usize, 1usize, 2usize), (36, 4, 8)] {
            let c = 3usize;
            let n = c * hw;
            let [a, b, cc, res] = [1, 2, 3, 4].map(|s| {
                q(
                    &rand_vec(n + rb, 90 + s)
                        .iter()
                        .map(|v| 3.0 * v)
                        .collect::<Vec<_>>(),
                    p,
                )
            });
            let ab = q(&rand_vec(2 * c, 95), p);
            let bufs = [&a, &b, &cc, &res, &ab].map(|v| up(ctx, v, p));
            for mode in 1..3 {
                let out = zeros(ctx, n + ob, p);
                let tail = match mode {
                    1 => GateTail::Relu,
                    _ => GateTail::Residual(View {
                        buf: &bufs[3].buffer,
                        base: rb as u32,
                    }),
                };
                let d = ops::ha_gate(
                    ctx,
                    p,
                    &bufs[0].buffer,
                    &bufs[1].buffer,
                    &bufs[2].buffer,
                    &bufs[4].buffer,
                    tail,
                    View {
                        buf: &out.buffer,
                        base: ob as u32,
                    },
                    c as u32,
                    hw as u32,
                    0.1,
                )
                .unwrap_or_else(|e| panic!("{e}"));
                let got = run(ctx, vec![d], &out, n + ob);
                let want: Vec<f32> = (0..n)
                    .map(|i| {
                        let ch = i / hw;
                        let g = 1.0 / (1.0 + (-f64::from(a[i])).exp());
                        let bv = f64::from(b[i]);
                        let f = if bv >= 0.0 { bv } else { 0.1 * bv };
                        let y = (g * f + f64::from(cc[i])) * f64::from(ab[2 * ch])
                            + f64::from(ab[2 * ch + 1]);
                        (match mode {
                            1 => y.max(0.0),
                            _ => (y + f64::from(res[rb + i])).max(0.0),
                        }) as f32
                    })
                    .collect();
                assert!(
                    got[..ob].iter().all(|&v| v == 0.0),
                    "ha_gate wrote before its output"
                );
                assert_close(
                    &got[ob..],
                    &want,
                    tol,
                    &format!("ha_gate mode {mode} hw {hw} {p:?}"),
                );
            }
        }
    }
}

#[test]
fn elementwise_kernels_match_cpu_reference() {
    let Some(ctx) = ctx() else { return };
    for (p, tol) in precisions(ctx) {
        let (c, hw) = (3usize, 101usize);
        let n = c * hw;
        let x = q(
            &rand_vec(n + 1, 100)
                .iter()
                .map(|v| 4.0 * v)
                .collect::<Vec<_>>(),
            p,
        );
        let y = q(&rand_vec(n, 101), p);
        let (xb, yb) = (up(ctx, &x, p), up(ctx, &y, p));
        let xs = &x[1..];
        let cases: Vec<(&str, Elementwise<'_>, Vec<f64>)> = vec![
            (
                "add_relu",
                Elementwise::AddRelu(View {
                    buf: &yb.buffer,
                    base: 0,
                }),
                (0..n)
                    .map(|i| (f64::from(xs[i]) + f64::from(y[i])).max(0.0))
                    .collect(),
            ),
            (
                "atan",
                Elementwise::Atan,
                xs.iter().map(|&v| f64::from(v).atan()).collect(),
            ),
        ];
        for (name, op, want) in cases {
            let out = zeros(ctx, n, p);
            let d = ops::elementwise(
                ctx,
                p,
                op,
                View {
                    buf: &xb.buffer,
                    base: 1,
                },
                View {
                    buf: &out.buffer,
                    base: 0,
                },
                n as u32,
            )
            .unwrap_or_else(|e| panic!("{e}"));
            let got = run(ctx, vec![d], &out, n);
            let want: Vec<f32> = want.iter().map(|&v| v as f32).collect();
            assert_close(&got, &want, tol, &format!("{name} {p:?}"));
        }
    }
}

/// The encoding's sin/cos come from a polynomial after exact reduction: absolute error
/// ~1e-7 for every octave, including 2^15·π·c where plain f32 sin would be off by ~1e-2.
const PE_ABS_TOL_F32: f32 = 1e-6;

#[test]
fn positional_encoding_matches_f64_reference_at_every_octave() {
    let Some(ctx) = ctx() else { return };
    for (p, tol) in precisions(ctx) {
        let abs_tol = if p == Precision::F32 {
            PE_ABS_TOL_F32
        } else {
            tol
        };
        let rows = 37usize;
        let mut dirs = rand_vec(rows * 9, 110);
        // Values whose multiples land near the reduction's branch points.
        dirs[..9].copy_from_slice(&[
            0.5,
            -0.5,
            1.0,
            -1.0,
            0.25,
            0.0,
            0.999_999,
            -0.999_999,
            1.0 / 3.0,
        ]);
        let db = up(ctx, &dirs, Precision::F32);
        let width = 9 + 18 * 16;
        let stride = width + 3;
        let out = zeros(ctx, rows * stride + 2, p);
        let d = ops::pos_enc(
            ctx,
            p,
            &db.buffer,
            rows as u32,
            16,
            View {
                buf: &out.buffer,
                base: 2,
            },
            stride as u32,
        )
        .unwrap_or_else(|e| panic!("{e}"));
        let got = run(ctx, vec![d], &out, rows * stride + 2);
        for r in 0..rows {
            let row = &got[2 + r * stride..2 + r * stride + width];
            for j in 0..9 {
                let c = f64::from(dirs[r * 9 + j]);
                assert!(
                    (row[j] - c as f32).abs() <= abs_tol,
                    "identity part row {r} j {j}"
                );
                for k in 0..16 {
                    let arg = (1u64 << k) as f64 * std::f64::consts::PI * c;
                    let (s, co) = (arg.sin() as f32, arg.cos() as f32);
                    let (gs, gc) = (row[9 + 18 * k + 2 * j], row[9 + 18 * k + 2 * j + 1]);
                    assert!(
                        (gs - s).abs() <= abs_tol && (gc - co).abs() <= abs_tol,
                        "row {r} j {j} octave {k} c={c}: got ({gs}, {gc}) want ({s}, {co}) {p:?}"
                    );
                }
            }
        }
    }
}

#[test]
fn tiled_matmul_matches_cpu_reference_on_odd_sizes() {
    let Some(ctx) = ctx() else { return };
    for ((p, tol), variant) in precisions(ctx)
        .into_iter()
        .flat_map(|pt| [(pt, MatmulVariant::Tiled), (pt, MatmulVariant::Direct)])
    {
        for &(rows, cols, inner, act) in &[
            (70usize, 37usize, 45usize, Act::Leaky(0.01)),
            (3, 130, 17, Act::None),
            (129, 3, 594, Act::Leaky(0.001)),
        ] {
            // x rows have stride inner + 5 starting at column 2; y rows stride cols + 4 at column 1.
            let (xs, ys) = (inner + 5, cols + 4);
            let x = q(&rand_vec(rows * xs + 7, rows as u64), p);
            let w = q(&rand_vec(cols * inner, cols as u64), p);
            let (xb, wb) = (up(ctx, &x, p), up(ctx, &w, p));
            let out = zeros(ctx, rows * ys, p);
            let d = ops::matmul_as(
                ctx,
                variant,
                p,
                Rows {
                    view: View {
                        buf: &xb.buffer,
                        base: 2,
                    },
                    stride: xs as u32,
                },
                &wb.buffer,
                Rows {
                    view: View {
                        buf: &out.buffer,
                        base: 1,
                    },
                    stride: ys as u32,
                },
                rows as u32,
                cols as u32,
                inner as u32,
                act,
            )
            .unwrap_or_else(|e| panic!("{e}"));
            let got = run(ctx, vec![d], &out, rows * ys);
            let mut g = Vec::new();
            let mut want = Vec::new();
            for m in 0..rows {
                for n in 0..cols {
                    let s: f64 = (0..inner)
                        .map(|k| f64::from(x[m * xs + 2 + k]) * f64::from(w[n * inner + k]))
                        .sum();
                    want.push(act_ref(s, act) as f32);
                    g.push(got[m * ys + 1 + n]);
                }
            }
            assert_close(
                &g,
                &want,
                tol,
                &format!("matmul {variant:?} {rows}x{cols}x{inner} {p:?}"),
            );
        }
    }
}

/// The texture matmul needs `Features::SUBGROUP`; `None` (with a printed reason) without it.
fn texture_ctx() -> Option<&'static GpuContext> {
    let ctx = ctx()?;
    if !ctx.device().features().contains(wgpu::Features::SUBGROUP)
        || ctx.device().adapter_info().subgroup_min_size < 8
    {
        eprintln!("SKIP: adapter lacks subgroups of >= 8 invocations; texture matmul not run");
        return None;
    }
    Some(ctx)
}

#[test]
fn texture_matmul_matches_cpu_reference_on_odd_sizes() {
    let Some(ctx) = texture_ctx() else { return };
    for (p, tol) in precisions(ctx) {
        for &(rows, cols, inner, act) in &[
            (70usize, 37usize, 45usize, Act::Leaky(0.01)),
            (3, 130, 17, Act::None),
            (129, 3, 594, Act::Leaky(0.001)),
            (33, 594, 297, Act::Leaky(0.01)),
        ] {
            let x = q(&rand_vec(rows * inner, rows as u64 + 3), p);
            let w = q(&rand_vec(cols * inner, cols as u64 + 5), p);
            let xt = ctx
                .upload_matrix("x", &x, rows as u32, inner as u32, p)
                .unwrap_or_else(|e| panic!("{e}"));
            let wt = ctx
                .upload_matrix("w", &w, cols as u32, inner as u32, p)
                .unwrap_or_else(|e| panic!("{e}"));
            let mut want = Vec::with_capacity(rows * cols);
            for m in 0..rows {
                for n in 0..cols {
                    let s: f64 = (0..inner)
                        .map(|k| f64::from(x[m * inner + k]) * f64::from(w[n * inner + k]))
                        .sum();
                    want.push(act_ref(s, act) as f32);
                }
            }
            let what = format!("matmul_tex {rows}x{cols}x{inner} {p:?}");
            // Texture output one texel in, with a texel to spare: the texel before the
            // output keeps its sentinel, channels past `cols` come back as 0.
            let texels = cols.div_ceil(4) + 2;
            let yt = ctx
                .upload_matrix(
                    "y",
                    &vec![7.0; rows * 4 * texels],
                    rows as u32,
                    4 * texels as u32,
                    p,
                )
                .unwrap_or_else(|e| panic!("{e}"));
            let to_tex = TexOut::Texture {
                tex: &yt,
                texel_base: 1,
            };
            let d = ops::matmul_tex(
                ctx,
                &xt,
                &wt,
                to_tex,
                rows as u32,
                cols as u32,
                inner as u32,
                act,
            )
            .unwrap_or_else(|e| panic!("{e}"));
            ctx.run(&[d]).unwrap_or_else(|e| panic!("{e}"));
            let got = ctx
                .read_texture(&yt, rows as u32)
                .unwrap_or_else(|e| panic!("{e}"));
            let mut g = Vec::with_capacity(rows * cols);
            for row in got.chunks_exact(4 * texels) {
                assert!(
                    row[..4].iter().all(|&v| v == 7.0),
                    "{what}: texel 0 overwritten"
                );
                let pad = &row[4 + cols..4 + 4 * cols.div_ceil(4)];
                assert!(pad.iter().all(|&v| v == 0.0), "{what}: pad {pad:?}");
                g.extend_from_slice(&row[4..4 + cols]);
            }
            assert_close(&g, &want, tol, &format!("{what} -> texture"));
            // Buffer output with a row stride wider than `cols`.
            let ys = cols + 4;
            let out = zeros(ctx, rows * ys, p);
            let d = ops::matmul_tex(
                ctx,
                &xt,
                &wt,
                TexOut::Buffer {
                    buf: &out.buffer,
                    stride: ys as u32,
                },
                rows as u32,
                cols as u32,
                inner as u32,
                act,
            )
            .unwrap_or_else(|e| panic!("{e}"));
            let got = run(ctx, vec![d], &out, rows * ys);
            let g: Vec<f32> = got
                .chunks_exact(ys)
                .flat_map(|r| r[..cols].to_vec())
                .collect();
            assert_close(&g, &want, tol, &format!("{what} -> buffer"));
        }
    }
}

#[test]
fn texture_positional_encoding_matches_buffer_kernel_and_pads_with_zeros() {
    let Some(ctx) = texture_ctx() else { return };
    for (p, _) in precisions(ctx) {
        let rows = 29usize;
        let width = 9 + 18 * 16;
        let dirs = rand_vec(rows * 9, 111);
        let db = up(ctx, &dirs, Precision::F32);
        let out = zeros(ctx, rows * width, p);
        let d = ops::pos_enc(
            ctx,
            p,
            &db.buffer,
            rows as u32,
            16,
            View {
                buf: &out.buffer,
                base: 0,
            },
            width as u32,
        )
        .unwrap_or_else(|e| panic!("{e}"));
        let want = run(ctx, vec![d], &out, rows * width);
        // One spare texel beyond the encoding's 75: it must come back as zeros too.
        let texels = width.div_ceil(4) + 1;
        let tex = ctx
            .texture("enc", texels as u32, rows as u32, p)
            .unwrap_or_else(|e| panic!("{e}"));
        let d = ops::pos_enc_tex(ctx, &db.buffer, rows as u32, 16, &tex)
            .unwrap_or_else(|e| panic!("{e}"));
        ctx.run(&[d]).unwrap_or_else(|e| panic!("{e}"));
        let got = ctx
            .read_texture(&tex, rows as u32)
            .unwrap_or_else(|e| panic!("{e}"));
        // Same formula and range reduction, and the texture kernel rounds to the storage type
        // before its store: equal up to a couple of f32 ulps of values <= 1.
        let tol = 2.0 * f32::EPSILON;
        for (r, row) in got.chunks_exact(4 * texels).enumerate() {
            for (c, (&g, &w)) in row[..width].iter().zip(&want[r * width..]).enumerate() {
                assert!(
                    (g - w).abs() <= tol,
                    "row {r} channel {c}: {g} vs {w} {p:?}"
                );
            }
            assert!(row[width..].iter().all(|&v| v == 0.0), "row {r} padding");
        }
    }
}

/// The texture convolutions (`tex_pack.wgsl` + `conv_tex.wgsl`) against the CPU loops, on
/// sizes that leave partial pixel blocks, partial 16-channel blocks and partial texels, with
/// the input packed from an offset view (and normalised on the way) and the output written at
/// an offset; the packed texture's padding channels must be zero.
#[test]
fn texture_convolutions_match_cpu_reference_on_odd_sizes() {
    let Some(ctx) = texture_ctx() else { return };
    for (p, tol) in precisions(ctx) {
        // (cin, h, w, cout, k, stride, pad, bias, norm, act)
        let direct = [
            (
                3u32,
                9u32,
                11u32,
                5u32,
                3u32,
                1u32,
                1u32,
                false,
                false,
                Act::None,
            ),
            (9, 13, 19, 21, 3, 2, 1, true, true, Act::Leaky(0.1)),
            (4, 13, 10, 7, 7, 1, 3, false, false, Act::Leaky(0.01)),
            (5, 7, 9, 33, 1, 2, 0, true, false, Act::None),
            (12, 16, 8, 64, 7, 1, 3, false, true, Act::None),
            (2, 5, 3, 9, 7, 2, 3, true, true, Act::Leaky(0.0)),
        ];
        for (i, &(cin, h, w, cout, k, stride, pad, use_bias, use_norm, act)) in
            direct.iter().enumerate()
        {
            let s = ConvShape {
                cin,
                h,
                w,
                cout,
                k,
                stride,
                pad,
            };
            let (ho, wo) = s.out_hw();
            // Even cases start at element 4 (with w a multiple of 4: the vec4 pack), odd at 5.
            let off = 4 + i % 2;
            let x = q(&rand_vec((cin * h * w) as usize + off, 80 + i as u64), p);
            let wt = q(&rand_vec((cout * cin * k * k) as usize, 90 + i as u64), p);
            let b = q(&rand_vec(cout as usize, 100 + i as u64), p);
            let norm: Vec<f32> = rand_vec(2 * cin as usize, 110 + i as u64)
                .iter()
                .map(|v| v + 1.5)
                .collect();
            // The reference sees the normalised input as the texture stores it.
            let xn: Vec<f32> = if use_norm {
                let hw = (h * w) as usize;
                let v: Vec<f32> = (0..cin as usize * hw)
                    .map(|e| x[off + e] * norm[2 * (e / hw)] + norm[2 * (e / hw) + 1])
                    .collect();
                q(&v, p)
            } else {
                x[off..].to_vec()
            };
            let got = run_conv_tex(
                ctx,
                p,
                ops::ConvKind::Direct,
                &x,
                off,
                use_norm.then_some(&norm[..]),
                &wt,
                use_bias.then_some(&b[..]),
                s,
                act,
            );
            let want = conv_ref(&xn, &wt, use_bias.then_some(&b[..]), None, s, act);
            assert_eq!(got.len(), 3 + (cout * ho * wo) as usize);
            assert!(
                got[..3].iter().all(|&v| v == 0.0),
                "conv_tex case {i}: wrote before its output"
            );
            assert_close(&got[3..], &want, tol, &format!("conv_tex case {i} {p:?}"));
        }
        // (cin, h, w, cout, k, pad, relu)
        let transposed = [
            (3u32, 5u32, 7u32, 4u32, 4u32, 1u32, true),
            (5, 3, 5, 3, 2, 0, false),
            (17, 4, 6, 20, 4, 1, false),
            (8, 9, 4, 16, 2, 0, true),
        ];
        for (i, &(cin, h, w, cout, k, pad, relu)) in transposed.iter().enumerate() {
            let s = ConvShape {
                cin,
                h,
                w,
                cout,
                k,
                stride: 2,
                pad,
            };
            let off = 4 + i % 2;
            let x = q(&rand_vec((cin * h * w) as usize + off, 120 + i as u64), p);
            let wt = q(&rand_vec((cin * cout * k * k) as usize, 130 + i as u64), p);
            let b = q(&rand_vec(cout as usize, 140 + i as u64), p);
            let act = if relu { Act::Leaky(0.0) } else { Act::None };
            let got = run_conv_tex(
                ctx,
                p,
                ops::ConvKind::Transposed,
                &x,
                off,
                None,
                &wt,
                Some(&b),
                s,
                act,
            );
            let want = conv_t_ref(&x[off..], &wt, &b, s, relu);
            assert_close(&got[3..], &want, tol, &format!("conv_t_tex case {i} {p:?}"));
        }
    }
}

/// Packs `x[off..]` (normalised by `norm` when given) into a texture one band taller than
/// needed, checks its padding channels, runs [`ops::conv_tex`] into a buffer at element 3 and
/// returns the whole buffer.
#[allow(clippy::too_many_arguments)]
fn run_conv_tex(
    ctx: &GpuContext,
    p: Precision,
    kind: ops::ConvKind,
    x: &[f32],
    off: usize,
    norm: Option<&[f32]>,
    wt: &[f32],
    bias: Option<&[f32]>,
    s: ConvShape,
    act: Act,
) -> Vec<f32> {
    let rows = ops::channel_block_rows(s.cin, s.h);
    let xt = ctx
        .texture("x", s.w + 1, rows + s.h, p)
        .unwrap_or_else(|e| panic!("{e}"));
    let xb = up(ctx, x, p);
    let nb = norm.map(|n| up(ctx, n, Precision::F32));
    let pack = ops::pack_tex(
        ctx,
        View {
            buf: &xb.buffer,
            base: off as u32,
        },
        (s.cin, s.h, s.w),
        nb.as_ref().map(|n| &n.buffer),
        &xt,
    )
    .unwrap_or_else(|e| panic!("{e}"));
    ctx.run(&[pack]).unwrap_or_else(|e| panic!("{e}"));
    let texels = ctx
        .read_texture(&xt, rows)
        .unwrap_or_else(|e| panic!("{e}"));
    let row_len = 4 * (s.w + 1) as usize;
    for (r, row) in texels.chunks_exact(row_len).enumerate() {
        for (xx, t) in row[..4 * s.w as usize].chunks_exact(4).enumerate() {
            for (j, &v) in t.iter().enumerate() {
                let c = 4 * (r / s.h as usize) + j;
                if c >= s.cin as usize {
                    assert_eq!(v, 0.0, "pack: padding channel {c} at x {xx}, row {r}");
                } else if norm.is_none() {
                    let e = off + c * (s.h * s.w) as usize + (r % s.h as usize) * s.w as usize + xx;
                    assert_eq!(
                        v, x[e],
                        "pack: channel {c} at x {xx}, row {r}, {s:?}, offset {off}"
                    );
                }
            }
        }
    }
    let (cout, cin) = (s.cout as usize, s.cin as usize);
    let (m, cols) = crate::weights::conv_weight_matrix(
        wt,
        cout,
        cin,
        s.k as usize,
        kind == ops::ConvKind::Transposed,
    );
    let wtex = ctx
        .upload_matrix("w", &m, s.cout, cols as u32, p)
        .unwrap_or_else(|e| panic!("{e}"));
    let bb = bias.map(|b| up(ctx, b, p));
    let plane = match kind {
        ops::ConvKind::Direct => {
            let (ho, wo) = s.out_hw();
            ho * wo
        }
        ops::ConvKind::Transposed => 4 * s.h * s.w,
    };
    let out = zeros(ctx, 3 + (s.cout * plane) as usize, p);
    let d = ops::conv_tex(
        ctx,
        kind,
        &xt,
        &wtex,
        bb.as_ref().map(|b| &b.buffer),
        View {
            buf: &out.buffer,
            base: 3,
        },
        s,
        act,
    )
    .unwrap_or_else(|e| panic!("{e}"));
    run(ctx, vec![d], &out, out.elems as usize)
}
