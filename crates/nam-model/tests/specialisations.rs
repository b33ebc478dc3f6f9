//! Each DESIGN §9 specialisation of `M_render` against the general path (or
//! the f64 reference) within a named tolerance: prepared material (`W_p·p`
//! once), directional light + orthographic view (ND_enc once), ROI and query
//! batches (only what is asked for), and the `render.l0·l1` fold.

use nam_model::geometry::{CAPTURE_DISTANCE, pixel_directions, unit_direction};
use nam_model::reference::{self, Accumulate};
use nam_model::{ModelError, ParamMap, RenderNet, Roi, Source};
use nam_weights::{ModelConfig, Weights};

/// Prepared vs unprepared: the same f32 products, the `W_p·p` GEMM run at
/// prepare time (other tile rows) instead of per relight. Bound on
/// |a − b| / (1 + |b|) of radiance.
const PREPARED_TOL: f32 = 1e-5;
/// Constant directions through the shared-direction path vs the per-pixel
/// path given the same direction at every pixel (ND_enc on 1 row vs a tile).
const DIRECTIONAL_TOL: f32 = 1e-5;
/// A region of interest vs the same pixels of the whole image: identical
/// per-pixel arithmetic, only the grouping of rows into tiles differs.
const ROI_TOL: f32 = 1e-6;
/// Query batches from a prepared material vs `render_log_batch` on the
/// gathered params: log space, |a − b| / (1 + |b|).
const QUERY_TOL: f32 = 1e-5;
/// The folded `render.l0·l1` (f64 product rounded to f32) vs the two layers:
/// log space, |a − b| / (1 + |b|).
const FOLD_TOL: f32 = 1e-4;
/// Fast f32 path vs the f64 reference (same bound as tests/parity.rs).
const FAST_VS_REFERENCE_TOL: f32 = 1e-4;

const LIGHT: [f32; 3] = [1.5, 1.0, 3.5];
const VIEW: [f32; 3] = [0.0, 0.0, CAPTURE_DISTANCE as f32];

fn weights(seed: u64) -> Weights {
    Weights::random(ModelConfig::standard(2), seed).unwrap()
}

fn map(h: usize, w: usize, salt: usize) -> ParamMap {
    let data = (0..h * w * 64)
        .map(|i| (((i + salt) * 53 % 97) as f32) / 48.0 - 1.0)
        .collect();
    ParamMap {
        height: h,
        width: w,
        channels: 64,
        data,
    }
}

fn assert_close(what: &str, got: &[f32], want: &[f32], tol: f32) {
    assert_eq!(got.len(), want.len(), "{what}: lengths");
    let mut worst = 0.0f32;
    for (i, (a, b)) in got.iter().zip(want).enumerate() {
        let e = (a - b).abs() / (1.0 + b.abs());
        assert!(e <= tol, "{what}: value {i}: {a} vs {b} ({e:e} > {tol:e})");
        worst = worst.max(e);
    }
    println!("{what}: worst {worst:e} (tolerance {tol:e})");
    assert!(
        want.iter().filter(|&&v| v > 0.0).count() > want.len() / 4,
        "{what}: the comparison must cover non-trivial output"
    );
}

#[test]
fn prepared_point_relight_matches_general_relight() {
    // Odd tile: ragged last tile, and tiles straddle image rows.
    let net = RenderNet::new(&weights(11)).unwrap().with_tile(7);
    let m = map(9, 11, 0);
    let prep = net.prepare(&m).unwrap();
    assert_eq!((prep.height(), prep.width(), prep.texels()), (9, 11, 99));
    assert_eq!(prep.rows().len(), 99 * net.hidden_len());
    let general = net.relight(&m, LIGHT, VIEW).unwrap();
    let fast = net
        .relight_prepared(
            &prep,
            Source::Point(LIGHT),
            Source::Point(VIEW),
            Roi::full(9, 11),
        )
        .unwrap();
    assert_eq!((fast.height, fast.width), (9, 11));
    assert_close("prepared point", &fast.data, &general.data, PREPARED_TOL);
}

#[test]
fn prepared_directional_matches_per_pixel_path_and_one_shot_directional() {
    let net = RenderNet::new(&weights(12)).unwrap().with_tile(5);
    let (h, w) = (6, 7);
    let m = map(h, w, 3);
    // Not unit length: Source::Distant normalises.
    let (l, v) = ([0.6, -0.4, 1.8], [0.0, 1.2, 1.6]);
    let (wi, wo) = (unit_direction(l), unit_direction(v));
    let general = net
        .relight_with_directions(&m, &vec![wi; h * w], &vec![wo; h * w])
        .unwrap();
    let prep = net.prepare(&m).unwrap();
    let fast = net
        .relight_prepared(
            &prep,
            Source::Distant(l),
            Source::Distant(v),
            Roi::full(h, w),
        )
        .unwrap();
    assert_close(
        "prepared directional",
        &fast.data,
        &general.data,
        DIRECTIONAL_TOL,
    );
    let one_shot = net.relight_directional(&m, wi, wo).unwrap();
    assert_close(
        "one-shot directional",
        &one_shot.data,
        &general.data,
        DIRECTIONAL_TOL,
    );
}

#[test]
fn mixed_point_light_and_orthographic_view_match_per_pixel_directions() {
    let net = RenderNet::new(&weights(13)).unwrap().with_tile(4);
    let (h, w) = (5, 6);
    let m = map(h, w, 5);
    let v = [0.3, 0.0, 1.0];
    let (wi, _) = pixel_directions(h, w, LIGHT, VIEW);
    let wo = vec![unit_direction(v); h * w];
    let general = net.relight_with_directions(&m, &wi, &wo).unwrap();
    let prep = net.prepare(&m).unwrap();
    let fast = net
        .relight_prepared(
            &prep,
            Source::Point(LIGHT),
            Source::Distant(v),
            Roi::full(h, w),
        )
        .unwrap();
    assert_close(
        "point light, orthographic view",
        &fast.data,
        &general.data,
        PREPARED_TOL,
    );
}

#[test]
fn roi_equals_the_same_pixels_of_the_full_relight() {
    let net = RenderNet::new(&weights(14)).unwrap().with_tile(6);
    let (h, w) = (10, 13);
    let m = map(h, w, 7);
    let prep = net.prepare(&m).unwrap();
    let roi = Roi {
        row: 2,
        col: 3,
        height: 5,
        width: 7,
    };
    for (light, view) in [
        (Source::Point(LIGHT), Source::Point(VIEW)),
        (
            Source::Distant([0.2, 0.5, 1.0]),
            Source::Distant([0.0, 0.0, 1.0]),
        ),
    ] {
        let full = net
            .relight_prepared(&prep, light, view, Roi::full(h, w))
            .unwrap();
        let part = net.relight_prepared(&prep, light, view, roi).unwrap();
        assert_eq!((part.height, part.width), (5, 7));
        let mut want = Vec::new();
        for r in roi.row..roi.row + roi.height {
            let s = (r * w + roi.col) * 3;
            want.extend_from_slice(&full.data[s..s + roi.width * 3]);
        }
        assert_close(&format!("roi {light:?}"), &part.data, &want, ROI_TOL);
    }
    // And against the unprepared general relight.
    let general = net.relight(&m, LIGHT, VIEW).unwrap();
    let part = net
        .relight_prepared(&prep, Source::Point(LIGHT), Source::Point(VIEW), roi)
        .unwrap();
    let mut want = Vec::new();
    for r in roi.row..roi.row + roi.height {
        let s = (r * w + roi.col) * 3;
        want.extend_from_slice(&general.data[s..s + roi.width * 3]);
    }
    assert_close("roi vs general", &part.data, &want, PREPARED_TOL);
}

#[test]
fn query_batch_matches_render_log_batch_and_the_reference() {
    let w = weights(15);
    let net = RenderNet::new(&w).unwrap().with_tile(9);
    let m = map(8, 8, 11);
    let prep = net.prepare(&m).unwrap();
    let n = 40; // five tiles, ragged; repeated and out-of-order texels
    let texels: Vec<usize> = (0..n).map(|q| (q * 37 + 5) % 64).collect();
    let wi: Vec<[f32; 3]> = (0..n)
        .map(|q| unit_direction([q as f32 * 0.07 - 1.0, 0.3, 1.0]))
        .collect();
    let wo: Vec<[f32; 3]> = (0..n)
        .map(|q| unit_direction([-0.2, 0.8 - q as f32 * 0.04, 1.0]))
        .collect();
    let mut got = vec![0.0f32; n * 3];
    net.render_log_prepared(&prep, &texels, &wi, &wo, &mut got)
        .unwrap();
    let params: Vec<f32> = texels
        .iter()
        .flat_map(|&t| m.data[t * 64..(t + 1) * 64].iter().copied())
        .collect();
    let mut want = vec![0.0f32; n * 3];
    net.render_log_batch(&params, &wi, &wo, &mut want).unwrap();
    assert_close("query batch", &got, &want, QUERY_TOL);
    for q in 0..n {
        let t = reference::render(
            &w,
            &params[q * 64..(q + 1) * 64],
            wi[q],
            wo[q],
            Accumulate::F64,
        )
        .unwrap();
        for k in 0..3 {
            let e = (got[q * 3 + k] - t.log[k]).abs() / (1.0 + t.log[k].abs());
            assert!(e < FAST_VS_REFERENCE_TOL, "query {q} ch {k}: {e:e}");
        }
    }
}

#[test]
fn unfolded_first_layers_give_the_same_output_with_more_work() {
    let w = weights(16);
    let folded = RenderNet::new(&w).unwrap().with_tile(8);
    let unfolded = RenderNet::new_unfolded(&w).unwrap().with_tile(8);
    // DESIGN §4: 634,470 multiply-adds unfolded; the fold saves 128·128.
    assert_eq!(unfolded.macs_per_output(false, false), 634_470);
    assert_eq!(folded.macs_per_output(false, false), 634_470 - 128 * 128);
    // Prepared + constant directions leave the layers after the first.
    assert_eq!(
        folded.macs_per_output(true, true),
        3 * 128 * 128 + 128 * 64 + 64 * 3
    );
    let m = map(4, 9, 13);
    let to_log = |v: &[f32]| v.iter().map(|r| r.ln_1p()).collect::<Vec<_>>();
    let a = folded.relight(&m, LIGHT, VIEW).unwrap();
    let b = unfolded.relight(&m, LIGHT, VIEW).unwrap();
    assert_close("fold, point", &to_log(&a.data), &to_log(&b.data), FOLD_TOL);
    let (wi, wo) = ([0.3, -0.2, 0.932_738], [0.0, 0.6, 0.8]);
    let a = folded.relight_directional(&m, wi, wo).unwrap();
    let b = unfolded.relight_directional(&m, wi, wo).unwrap();
    assert_close(
        "fold, directional",
        &to_log(&a.data),
        &to_log(&b.data),
        FOLD_TOL,
    );
    // The unfolded net's prepared material holds W_l0p·p (before l1).
    let pa = folded.prepare(&m).unwrap();
    let pb = unfolded.prepare(&m).unwrap();
    let roi = Roi::full(4, 9);
    let a = folded
        .relight_prepared(&pa, Source::Point(LIGHT), Source::Point(VIEW), roi)
        .unwrap();
    let b = unfolded
        .relight_prepared(&pb, Source::Point(LIGHT), Source::Point(VIEW), roi)
        .unwrap();
    assert_close(
        "fold, prepared",
        &to_log(&a.data),
        &to_log(&b.data),
        FOLD_TOL,
    );
    // A prepared material only works with the network (weights) that made it.
    let other = RenderNet::new(&weights(17)).unwrap();
    for net in [&unfolded, &other] {
        assert!(matches!(
            net.relight_prepared(&pa, Source::Point(LIGHT), Source::Point(VIEW), roi),
            Err(ModelError::ParamFile { .. })
        ));
    }
}

#[test]
fn specialised_paths_reject_bad_regions_queries_and_sources() {
    let net = RenderNet::new(&weights(18)).unwrap();
    let m = map(4, 5, 1);
    let prep = net.prepare(&m).unwrap();
    let (l, v) = (Source::Point(LIGHT), Source::Point(VIEW));
    for roi in [
        Roi {
            row: 0,
            col: 0,
            height: 0,
            width: 2,
        },
        Roi {
            row: 3,
            col: 0,
            height: 2,
            width: 2,
        },
        Roi {
            row: 0,
            col: 4,
            height: 1,
            width: 2,
        },
        Roi {
            row: usize::MAX,
            col: 0,
            height: 1,
            width: 1,
        },
    ] {
        assert!(
            matches!(
                net.relight_prepared(&prep, l, v, roi),
                Err(ModelError::ImageSize { .. })
            ),
            "{roi:?}"
        );
    }
    let full = Roi::full(4, 5);
    for (light, view) in [
        (Source::Distant([0.0, 1.0, 0.0]), v),
        (l, Source::Distant([0.0, 0.0, -1.0])),
        (Source::Point([0.0, 0.0, 0.0]), v),
    ] {
        assert!(matches!(
            net.relight_prepared(&prep, light, view, full),
            Err(ModelError::BelowSurface)
        ));
    }
    assert!(matches!(
        net.relight_prepared(&prep, Source::Point([f32::NAN, 0.0, 1.0]), v, full),
        Err(ModelError::NonFinite { .. })
    ));
    let up = [[0.0, 0.0, 1.0f32]];
    let mut out = [0.0f32; 3];
    assert!(matches!(
        net.render_log_prepared(&prep, &[20], &up, &up, &mut out),
        Err(ModelError::Size { found: 20, .. })
    ));
    assert!(matches!(
        net.render_log_prepared(&prep, &[0, 1], &up, &up, &mut out),
        Err(ModelError::Size { .. })
    ));
    assert!(matches!(
        net.render_log_prepared(&prep, &[0], &[[f32::INFINITY, 0.0, 1.0]], &up, &mut out),
        Err(ModelError::NonFinite { .. })
    ));
    net.render_log_prepared(&prep, &[19], &up, &up, &mut out)
        .unwrap();
    assert!(out.iter().all(|v| v.is_finite()));
    // Empty batches are fine.
    net.render_log_prepared(&prep, &[], &[], &[], &mut [])
        .unwrap();
}

#[test]
fn streamed_region_relight_matches_the_prepared_one_for_every_source_pair() {
    let net = RenderNet::new(&weights(19)).unwrap().with_tile(6);
    let (h, w) = (7, 9);
    let m = map(h, w, 17);
    let prep = net.prepare(&m).unwrap();
    let roi = Roi {
        row: 1,
        col: 2,
        height: 4,
        width: 6,
    };
    let (pl, pv) = (Source::Point(LIGHT), Source::Point(VIEW));
    let (dl, dv) = (
        Source::Distant([0.4, -0.3, 1.0]),
        Source::Distant([0.0, 0.2, 1.0]),
    );
    for (light, view) in [(pl, pv), (dl, dv), (pl, dv), (dl, pv)] {
        for r in [roi, Roi::full(h, w)] {
            let streamed = net.relight_sources(&m, light, view, r).unwrap();
            let prepared = net.relight_prepared(&prep, light, view, r).unwrap();
            assert_eq!((streamed.height, streamed.width), (r.height, r.width));
            assert_close(
                &format!("streamed {light:?} {view:?} {r:?}"),
                &streamed.data,
                &prepared.data,
                PREPARED_TOL,
            );
        }
    }
    // The full point/point region is the general relight.
    let general = net.relight(&m, LIGHT, VIEW).unwrap();
    let streamed = net.relight_sources(&m, pl, pv, Roi::full(h, w)).unwrap();
    assert_close(
        "streamed vs general",
        &streamed.data,
        &general.data,
        PREPARED_TOL,
    );
}

/// Interpolated ND_enc at the grid nodes (pixels on a node row and column) vs the
/// general path: the same features, other tile groupings. Radiance, |a − b| / (1 + |b|).
const INTERPOLATED_NODE_TOL: f32 = 1e-5;
/// Interpolated ND_enc vs the general path everywhere, with the shipped model on a
/// capture-like scene at 64² and a 1° bound (grid step 2): log space,
/// mean |Δ ln(1 + R)| over pixels and channels (measured 3.3e-3; the model's own Hemisphere
/// log-L1 is ~0.03).
const INTERPOLATED_MEAN_LOG_TOL: f32 = 5e-3;

#[test]
fn interpolated_nd_enc_is_exact_at_the_nodes_and_the_general_path_below_two_pixels() {
    let net = RenderNet::new(&weights(17)).unwrap().with_tile(7);
    let (h, w) = (13, 10);
    let m = map(h, w, 5);
    let general = net.relight(&m, LIGHT, VIEW).unwrap();
    // 13 rows of 2/10 units at step 4: light height 1.0 → 0.8 rad·1.0 = 4 pixels.
    let (light, angle) = ([0.4, -0.3, 1.0], 0.8);
    let step = nam_model::interpolation_step(light[2], VIEW[2], h, w, angle);
    assert_eq!(step, 4);
    let exact = net.relight(&m, light, VIEW).unwrap();
    let interp = net.relight_interpolated(&m, light, VIEW, angle).unwrap();
    let node_rows: Vec<usize> = (0..h).filter(|r| r % step == 0 || *r == h - 1).collect();
    let node_cols: Vec<usize> = (0..w).filter(|c| c % step == 0 || *c == w - 1).collect();
    let (mut got, mut want) = (Vec::new(), Vec::new());
    for &r in &node_rows {
        for &c in &node_cols {
            let k = (r * w + c) * 3;
            got.extend_from_slice(&interp.data[k..k + 3]);
            want.extend_from_slice(&exact.data[k..k + 3]);
        }
    }
    assert_close("interpolated at nodes", &got, &want, INTERPOLATED_NODE_TOL);
    assert_ne!(
        interp.data, exact.data,
        "between nodes the features are interpolated"
    );
    // A bound below two pixels runs the general path itself.
    let tiny = net.relight_interpolated(&m, LIGHT, VIEW, 1e-4).unwrap();
    assert_eq!(tiny.data, general.data);
    for bad in [0.0, -1.0, f32::NAN, f32::INFINITY] {
        assert!(
            net.relight_interpolated(&m, LIGHT, VIEW, bad).is_err(),
            "{bad}"
        );
    }
    assert!(matches!(
        net.relight_interpolated(&m, [0.0, 0.0, -1.0], VIEW, 0.5),
        Err(ModelError::BelowSurface)
    ));
}

#[test]
fn interpolated_nd_enc_stays_close_to_the_general_path_with_the_shipped_model() {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../models/default.safetensors"
    );
    let net = RenderNet::new(&Weights::from_file(path).unwrap()).unwrap();
    let m = map(64, 64, 3);
    let light = [1.2, 0.5, 3.8];
    let angle = 1f32.to_radians();
    assert_eq!(
        nam_model::interpolation_step(light[2], VIEW[2], 64, 64, angle),
        2
    );
    let general = net.relight(&m, light, VIEW).unwrap();
    let interp = net.relight_interpolated(&m, light, VIEW, angle).unwrap();
    let mean = general
        .data
        .iter()
        .zip(&interp.data)
        .map(|(a, b)| (a.ln_1p() - b.ln_1p()).abs())
        .sum::<f32>()
        / general.data.len() as f32;
    println!("interpolated (1°, step 2) vs general: mean |Δ log| {mean:e}");
    assert!(mean < INTERPOLATED_MEAN_LOG_TOL, "{mean:e}");
    assert!(mean > 0.0);
}
