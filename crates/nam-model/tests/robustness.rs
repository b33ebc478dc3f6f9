//! Bad inputs give errors, never panics; degenerate-but-valid inputs give
//! finite outputs (DESIGN §7).

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
