//! Bad inputs give errors, never panics; degenerate-but-valid inputs give
//! finite outputs (DESIGN §7).

mod common;

use common::{pattern, pattern_map};
use nam_model::reference::{self, Accumulate};
use nam_model::{ModelError, ParamMap, RenderNet, UNet};
use nam_weights::{ModelConfig, Weights};

fn weights() -> Weights {
    Weights::random(ModelConfig::standard(2), 3).unwrap()
}

#[test]
fn estimate_rejects_wrong_lengths_zero_sizes_and_non_finite_input() {
    let w = weights();
    let u = UNet::new(&w).unwrap();
    assert!(matches!(
        u.estimate(&[0.0; 10], 2, 2),
        Err(ModelError::Size { .. })
    ));
    assert!(matches!(
        u.estimate(&[], 0, 5),
        Err(ModelError::ImageSize { .. })
    ));
    assert!(matches!(
        u.estimate(&[], 1 << 20, 0),
        Err(ModelError::ImageSize { .. })
    ));
    let mut input = vec![0.5; 4 * 3 * 3];
    input[7] = f32::NAN;
    assert!(matches!(
        u.estimate(&input, 3, 3),
        Err(ModelError::NonFinite { index: 7, .. })
    ));
    assert!(matches!(
        reference::estimate(&w, &input, 3, 3, Accumulate::F32),
        Err(ModelError::NonFinite { .. })
    ));
}

#[test]
fn constant_and_one_pixel_inputs_give_finite_params() {
    // A constant image has zero variance in every InstanceNorm: eps must keep it finite.
    let u = UNet::new(&weights()).unwrap();
    for (h, w, v) in [(1usize, 1usize, 0.0f32), (9, 17, 0.0), (8, 8, 14.0)] {
        let out = u.estimate(&vec![v; 4 * h * w], h, w).unwrap();
        assert_eq!(out.data.len(), h * w * 64);
        assert!(out.data.iter().all(|x| x.is_finite()), "{h}x{w} value {v}");
    }
}

#[test]
fn render_rejects_mismatched_lengths_and_non_finite_queries() {
    let net = RenderNet::new(&weights()).unwrap();
    let mut out = vec![0.0; 6];
    let wi = [[0.0, 0.0, 1.0]; 2];
    assert!(net.render_batch(&[0.0; 64], &wi, &wi, &mut out).is_err());
    assert!(
        net.render_batch(&[0.0; 128], &wi, &wi[..1], &mut out)
            .is_err()
    );
    assert!(
        net.render_batch(&[0.0; 128], &wi, &wi, &mut out[..3])
            .is_err()
    );
    let bad = [[0.0, f32::INFINITY, 1.0], [0.0, 0.0, 1.0]];
    assert!(matches!(
        net.render_batch(&[0.0; 128], &bad, &wi, &mut out),
        Err(ModelError::NonFinite {
            what: "wi",
            index: 1
        })
    ));
    net.render_batch(&[0.0; 128], &wi, &wi, &mut out).unwrap();
    assert!(out.iter().all(|v| v.is_finite() && *v >= 0.0));
}

#[test]
fn relight_rejects_bad_maps_and_positions_and_handles_degenerate_geometry() {
    let net = RenderNet::new(&weights()).unwrap();
    let map = ParamMap {
        height: 2,
        width: 3,
        channels: 64,
        data: vec![0.1; 2 * 3 * 64],
    };
    let short = ParamMap {
        data: vec![0.1; 10],
        ..map.clone()
    };
    assert!(matches!(
        net.relight(&short, [0.0, 0.0, 1.0], [0.0, 0.0, 1.0]),
        Err(ModelError::Size { .. })
    ));
    let wrong_c = ParamMap {
        channels: 32,
        ..map.clone()
    };
    assert!(
        net.relight(&wrong_c, [0.0, 0.0, 1.0], [0.0, 0.0, 1.0])
            .is_err()
    );
    assert!(matches!(
        net.relight(&map, [0.0, 0.0, -1.0], [0.0, 0.0, 1.0]),
        Err(ModelError::BelowSurface)
    ));
    assert!(
        net.relight(&map, [f32::NAN, 0.0, 1.0], [0.0, 0.0, 1.0])
            .is_err()
    );
    // Grazing light (tiny z), opposite to the view: ωi + ωo ≈ 0 for some pixels.
    let img = net
        .relight(&map, [1e9, 0.0, 1e-30], [-1e9, 0.0, 1e-30])
        .unwrap();
    assert!(img.data.iter().all(|v| v.is_finite() && *v >= 0.0));
}

/// Directional relight (ND_enc once) vs the general path with the same
/// directions at every pixel: identical math, different GEMM row counts.
const DIRECTIONAL_TOL: f32 = 1e-5;

#[test]
fn directional_relight_matches_per_pixel_path_with_constant_directions() {
    let net = RenderNet::new(&weights()).unwrap().with_tile(5);
    let (h, w) = (3, 7);
    let map = pattern_map(h, w, 31, 89, 44.0);
    let wi = [0.3, -0.2, 0.932_738];
    let wo = [0.0, 0.6, 0.8];
    let fast = net.relight_directional(&map, wi, wo).unwrap();
    let general = net
        .relight_with_directions(&map, &vec![wi; h * w], &vec![wo; h * w])
        .unwrap();
    for (a, b) in fast.data.iter().zip(&general.data) {
        assert!(
            (a - b).abs() <= DIRECTIONAL_TOL * (1.0 + b.abs()),
            "{a} vs {b}"
        );
    }
    assert!(
        fast.data.iter().any(|&v| v > 0.0),
        "test must compare non-trivial output"
    );
}

#[test]
fn param_map_with_the_wrong_number_of_values_is_not_written() {
    let map = ParamMap {
        height: 2,
        width: 3,
        channels: 64,
        data: vec![0.5; 2 * 3 * 64 - 1],
    };
    let err = map.to_nam_bytes("abc123").unwrap_err();
    assert!(
        matches!(
            err,
            ModelError::Size {
                expected: 384,
                found: 383,
                ..
            }
        ),
        "{err}"
    );
}

#[test]
fn param_map_roundtrips_through_nam_bytes_and_rejects_mismatches() {
    let map = ParamMap {
        height: 2,
        width: 3,
        channels: 64,
        data: (0..384).map(|i| i as f32 / 7.0).collect(),
    };
    // Default: F16, each value within f16's relative rounding (2^-11) and half the bytes.
    let bytes = map.to_nam_bytes("abc123").unwrap();
    let (back, sha) = ParamMap::from_nam_bytes(&bytes, "m.nam").unwrap();
    assert_eq!((back.height, back.width, back.channels), (2, 3, 64));
    assert!(
        back.data
            .iter()
            .zip(&map.data)
            .all(|(a, b)| (a - b).abs() <= b.abs() * 4.9e-4)
    );
    assert_eq!(sha, "abc123");
    let exact = map
        .to_nam_bytes_as("abc123", nam_weights::StoreAs::F32)
        .unwrap();
    assert_eq!(ParamMap::from_nam_bytes(&exact, "m.nam").unwrap().0, map);
    assert!(bytes.len() * 2 < exact.len() + 1024);
    // A value beyond f16's range: stored as F32 by default, an error when F16 is demanded.
    let mut wide = map.clone();
    wide.data[5] = 1e5;
    let auto = wide.to_nam_bytes("abc123").unwrap();
    assert_eq!(ParamMap::from_nam_bytes(&auto, "w.nam").unwrap().0, wide);
    let err = wide
        .to_nam_bytes_as("abc123", nam_weights::StoreAs::F16)
        .unwrap_err();
    assert!(
        err.to_string().contains("flat index 5 does not fit F16"),
        "{err}"
    );
    // A model file is not a param map.
    let model = weights().to_safetensors_bytes().unwrap();
    assert!(matches!(
        ParamMap::from_nam_bytes(&model, "w"),
        Err(ModelError::ParamFile { .. })
    ));
    // Config size disagreeing with the tensor.
    let cfg = r#"{"format":"nam-params","version":1,"height":4,"width":3,"model_sha256":""}"#;
    let meta = std::collections::BTreeMap::from([("config".to_string(), cfg.to_string())]);
    let t = nam_weights::Tensor::new(vec![2, 3, 64], map.data.clone()).unwrap();
    let tensors = std::collections::BTreeMap::from([("params".to_string(), t)]);
    let bytes = nam_weights::write_safetensors(&tensors, &meta).unwrap();
    assert!(matches!(
        ParamMap::from_nam_bytes(&bytes, "t"),
        Err(ModelError::ParamFile { .. })
    ));
}

#[test]
fn separate_pieces_compose_to_the_fused_pipeline_across_tiles() {
    let net = RenderNet::new(&weights()).unwrap().with_tile(7);
    let n = 20; // three tiles, the last one ragged
    let params = pattern(n * 64, 13, 41, 20.0);
    let wi: Vec<[f32; 3]> = (0..n)
        .map(|q| nam_model::geometry::unit_direction([q as f32 * 0.1, 0.3, 1.0]))
        .collect();
    let wo: Vec<[f32; 3]> = (0..n)
        .map(|q| nam_model::geometry::unit_direction([-0.2, q as f32 * 0.05, 1.0]))
        .collect();
    let mut enc = vec![0.0; n * net.encoded_len()];
    net.encode(&wi, &wo, &mut enc).unwrap();
    let mut nd = vec![0.0; n * net.nd_len()];
    net.nd_enc(&enc, &mut nd).unwrap();
    let mut pieces = vec![0.0; n * 3];
    net.render_from_features(&params, &nd, &mut pieces).unwrap();
    let mut fused = vec![0.0; n * 3];
    net.render_log_batch(&params, &wi, &wo, &mut fused).unwrap();
    // Same operations on the same tiles: bitwise equal is expected, allow 1 ulp-ish.
    for (a, b) in pieces.iter().zip(&fused) {
        assert!((a - b).abs() <= 1e-6 * (1.0 + b.abs()), "{a} vs {b}");
    }
}

/// bf16 products (8-bit mantissa, relative rounding 2^-9 per operand) with f32
/// sums: errors average over 100–600-term dot products through 9 layers.
/// Bound on |Δ log| / (1 + |log|) against the f32 path (measured 1.7e-3).
const BF16_LOG_TOL: f32 = 1e-2;

#[test]
fn bf16_relight_is_close_to_f32_and_not_identical() {
    if !nam_model::bf16_supported() {
        println!("skipping: this CPU has no AVX-512 BF16");
        assert!(RenderNet::new(&weights()).unwrap().with_bf16().is_err());
        return;
    }
    let w = Weights::random(ModelConfig::standard(2), 8).unwrap();
    let f32net = RenderNet::new(&w).unwrap().with_tile(13);
    let bf = f32net.clone().with_bf16().unwrap();
    assert!(bf.is_bf16());
    let (h, wd) = (9, 11); // ragged tiles and row blocks
    let map = pattern_map(h, wd, 29, 83, 41.0);
    let (light, view) = (
        [1.5, 1.0, 3.5],
        [0.0, 0.0, nam_model::geometry::CAPTURE_DISTANCE as f32],
    );
    let a = f32net.relight(&map, light, view).unwrap();
    let b = bf.relight(&map, light, view).unwrap();
    let mut worst = 0.0f32;
    for (x, y) in a.data.iter().zip(&b.data) {
        let (lx, ly) = (x.ln_1p(), y.ln_1p());
        worst = worst.max((lx - ly).abs() / (1.0 + lx.abs()));
    }
    println!("bf16 vs f32 relight: max rel log err {worst:e}");
    assert!(worst < BF16_LOG_TOL, "{worst:e}");
    assert!(worst > 0.0, "bf16 path must actually run");
}
