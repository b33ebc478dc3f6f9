//! SVBRDF map files: round trips of every supported encoding and clear errors on bad files.

use nam_ggx::imageio::{PngDepth, RgbImage, encode_exr, encode_png};
use nam_ggx::{GgxError, MapFiles, SvbrdfMaps};
use std::path::Path;

/// 16-bit PNG quantisation after gamma 2.2: half a code (7.6e-6) times the largest slope of
/// v^2.2 on [0, 1] (2.2) ≈ 1.7e-5; 2e-5 leaves rounding headroom.
const PNG16_TOL: f32 = 2e-5;
/// 8-bit PNG: half a code (2e-3) times 2.2 ≈ 4.3e-3.
const PNG8_TOL: f32 = 4.5e-3;
/// Normals: the quantised `(n+1)/2` is renormalised; a half-code error per component moves the
/// unit vector by about √3·(1/255) in 8 bits.
const NORMAL8_TOL: f32 = 8e-3;

fn sample_maps(h: usize, w: usize) -> SvbrdfMaps {
    let n = h * w;
    let f = |k: usize, s: f32| ((k as f32 * 0.37 + s).sin() * 0.5 + 0.5).clamp(0.0, 1.0);
    let diffuse = (0..n).map(|k| [f(k, 0.0), f(k, 1.0), f(k, 2.0)]).collect();
    let specular = (0..n).map(|k| [f(k, 3.0) * 0.3; 3]).collect();
    let roughness = (0..n).map(|k| f(k, 4.0)).collect();
    let normal = (0..n)
        .map(|k| [f(k, 5.0) - 0.5, f(k, 6.0) - 0.5, 1.0])
        .collect();
    SvbrdfMaps::new(h, w, diffuse, specular, roughness, normal).unwrap_or_else(|e| panic!("{e}"))
}

fn max_diff(a: &[[f32; 3]], b: &[[f32; 3]]) -> f32 {
    a.iter()
        .zip(b)
        .flat_map(|(x, y)| (0..3).map(move |c| (x[c] - y[c]).abs()))
        .fold(0.0, f32::max)
}

fn max_diff1(a: &[f32], b: &[f32]) -> f32 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f32::max)
}

fn assert_close(a: &SvbrdfMaps, b: &SvbrdfMaps, tol: f32, ntol: f32) {
    assert_eq!((a.height(), a.width()), (b.height(), b.width()));
    assert!(max_diff(a.diffuse(), b.diffuse()) <= tol, "diffuse");
    assert!(max_diff(a.specular(), b.specular()) <= tol, "specular");
    assert!(max_diff1(a.roughness(), b.roughness()) <= tol, "roughness");
    assert!(max_diff(a.normal(), b.normal()) <= ntol, "normal");
}

fn load_err(path: &Path) -> GgxError {
    match SvbrdfMaps::load(path) {
        Ok(_) => panic!("{} should not load", path.display()),
        Err(e) => e,
    }
}

#[test]
fn four_panel_png16_round_trips_within_quantisation() {
    let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
    let path = dir.path().join("m.png");
    let maps = sample_maps(12, 12);
    maps.save(&path).unwrap_or_else(|e| panic!("{e}"));
    let back = SvbrdfMaps::load(&path).unwrap_or_else(|e| panic!("{e}"));
    assert_close(&maps, &back, PNG16_TOL, PNG16_TOL * 4.0);
}

#[test]
fn four_panel_png8_round_trips_within_quantisation() {
    let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
    let path = dir.path().join("m.png");
    let maps = sample_maps(9, 9);
    maps.save_png(&path, PngDepth::Eight)
        .unwrap_or_else(|e| panic!("{e}"));
    let back = SvbrdfMaps::load(&path).unwrap_or_else(|e| panic!("{e}"));
    assert_close(&maps, &back, PNG8_TOL, NORMAL8_TOL);
}

#[test]
fn four_panel_exr_round_trips_exactly_without_gamma() {
    let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
    let path = dir.path().join("m.exr");
    let maps = sample_maps(8, 8);
    maps.save(&path).unwrap_or_else(|e| panic!("{e}"));
    let back = SvbrdfMaps::load(&path).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(
        maps.diffuse(),
        back.diffuse(),
        "EXR stores linear f32 as is"
    );
    assert_eq!(maps.roughness(), back.roughness());
    // Normals pass through (n+1)/2 and 2v−1 in f32: one or two ulps.
    assert!(max_diff(maps.normal(), back.normal()) < 1e-6);
}

#[test]
fn exr_panel_values_are_linear_while_png_values_are_gamma_encoded() {
    // One diffuse value of 0.5 stored in both formats: the PNG holds 0.5^(1/2.2).
    let maps = sample_maps(4, 4);
    let exr = maps.to_panels(nam_ggx::imageio::FileKind::Exr);
    let png = maps.to_panels(nam_ggx::imageio::FileKind::Ldr);
    let lin = exr.pixel(0, 0)[0];
    let enc = png.pixel(0, 0)[0];
    assert!((enc - lin.powf(1.0 / 2.2)).abs() < 1e-6);
    assert_eq!(
        exr.pixel(0, 8),
        png.pixel(0, 8),
        "roughness panel is linear in both"
    );
}

#[test]
fn separate_map_files_round_trip_with_mixed_formats() {
    let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
    let files = MapFiles {
        diffuse: dir.path().join("d.png"),
        specular: dir.path().join("s.exr"),
        roughness: dir.path().join("r.png"),
        normal: dir.path().join("n.exr"),
    };
    let maps = sample_maps(6, 10);
    maps.save_separate(&files).unwrap_or_else(|e| panic!("{e}"));
    let back = SvbrdfMaps::load_separate(&files).unwrap_or_else(|e| panic!("{e}"));
    assert_close(&maps, &back, PNG16_TOL, 1e-6);
}

#[test]
fn png_normal_128_128_255_decodes_to_a_unit_normal_near_z() {
    let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
    let path = dir.path().join("flat.png");
    let mut img = RgbImage::<f32>::zeros(2, 8).unwrap_or_else(|e| panic!("{e}"));
    for i in 0..2 {
        for j in 6..8 {
            img.set_pixel(i, j, [128.0 / 255.0, 128.0 / 255.0, 1.0]);
        }
    }
    let bytes = encode_png(&img, PngDepth::Eight).unwrap_or_else(|e| panic!("{e}"));
    std::fs::write(&path, bytes).unwrap_or_else(|e| panic!("{e}"));
    let maps = SvbrdfMaps::load(&path).unwrap_or_else(|e| panic!("{e}"));
    for n in maps.normal() {
        let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
        assert!((len - 1.0).abs() < 1e-6 && n[2] > 0.9999, "{n:?}");
    }
}

#[test]
fn wrong_panel_width_is_a_clear_error() {
    let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
    let path = dir.path().join("wide.png");
    let img = RgbImage::<f32>::zeros(8, 30).unwrap_or_else(|e| panic!("{e}"));
    let bytes = encode_png(&img, PngDepth::Eight).unwrap_or_else(|e| panic!("{e}"));
    std::fs::write(&path, bytes).unwrap_or_else(|e| panic!("{e}"));
    let e = load_err(&path);
    let msg = e.to_string();
    assert!(
        msg.contains("4·H") && msg.contains("30×8") && msg.contains("wide.png"),
        "{msg}"
    );
}

#[test]
fn truncated_and_empty_png_are_decode_errors() {
    let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
    let good = dir.path().join("good.png");
    sample_maps(16, 16)
        .save(&good)
        .unwrap_or_else(|e| panic!("{e}"));
    let bytes = std::fs::read(&good).unwrap_or_else(|e| panic!("{e}"));
    let cut = dir.path().join("cut.png");
    std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap_or_else(|e| panic!("{e}"));
    assert!(matches!(load_err(&cut), GgxError::Decode { .. }));
    let empty = dir.path().join("empty.png");
    std::fs::write(&empty, b"").unwrap_or_else(|e| panic!("{e}"));
    let e = load_err(&empty);
    assert!(
        matches!(e, GgxError::Decode { .. }) && e.to_string().contains("empty"),
        "{e}"
    );
    let junk = dir.path().join("junk.exr");
    std::fs::write(&junk, b"not an exr file at all").unwrap_or_else(|e| panic!("{e}"));
    assert!(matches!(load_err(&junk), GgxError::Decode { .. }));
}

#[test]
fn missing_file_and_unknown_extension_are_reported_with_the_path() {
    let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
    let missing = dir.path().join("nope.png");
    let e = load_err(&missing);
    assert!(matches!(e, GgxError::Io { .. }) && e.to_string().contains("nope.png"));
    let tif = dir.path().join("maps.tif");
    assert!(matches!(load_err(&tif), GgxError::UnsupportedFormat { .. }));
}

fn write_exr_panel(path: &Path, h: usize, poke: impl Fn(&mut RgbImage<f32>)) {
    let mut img = RgbImage::<f32>::zeros(h, 4 * h).unwrap_or_else(|e| panic!("{e}"));
    for i in 0..h {
        for j in 0..h {
            img.set_pixel(i, 3 * h + j, [0.5, 0.5, 1.0]);
        }
    }
    poke(&mut img);
    let bytes = encode_exr(&img).unwrap_or_else(|e| panic!("{e}"));
    std::fs::write(path, bytes).unwrap_or_else(|e| panic!("{e}"));
}

#[test]
fn nan_inf_negative_and_zero_normal_in_exr_are_rejected_with_location() {
    let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
    let p = dir.path().join("bad.exr");

    write_exr_panel(&p, 4, |img| img.set_pixel(1, 2, [f32::NAN, 0.0, 0.0]));
    let e = load_err(&p);
    assert!(e.to_string().contains("non-finite") && e.to_string().contains("row 1, col 2"));

    write_exr_panel(&p, 4, |img| img.set_pixel(3, 5, [0.1, f32::INFINITY, 0.0]));
    assert!(load_err(&p).to_string().contains("non-finite"));

    write_exr_panel(&p, 4, |img| img.set_pixel(0, 1, [-0.25, 0.0, 0.0]));
    let e = load_err(&p);
    assert!(
        e.to_string()
            .contains("diffuse map has a negative value -0.25"),
        "{e}"
    );

    write_exr_panel(&p, 4, |img| img.set_pixel(2, 12 + 3, [0.5, 0.5, 0.5]));
    let e = load_err(&p);
    assert!(
        e.to_string().contains("zero-length normal at row 2, col 3"),
        "{e}"
    );
    assert!(e.to_string().contains("bad.exr"), "{e}");
}

#[test]
fn separate_maps_of_different_sizes_are_rejected() {
    let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
    let files = MapFiles {
        diffuse: dir.path().join("d.png"),
        specular: dir.path().join("s.png"),
        roughness: dir.path().join("r.png"),
        normal: dir.path().join("n.png"),
    };
    sample_maps(6, 6)
        .save_separate(&files)
        .unwrap_or_else(|e| panic!("{e}"));
    let small = MapFiles {
        roughness: dir.path().join("r_small.png"),
        ..files.clone()
    };
    let other = sample_maps(5, 6);
    other
        .save_separate(&MapFiles {
            diffuse: dir.path().join("d5.png"),
            specular: dir.path().join("s5.png"),
            roughness: small.roughness.clone(),
            normal: dir.path().join("n5.png"),
        })
        .unwrap_or_else(|e| panic!("{e}"));
    let e = match SvbrdfMaps::load_separate(&small) {
        Ok(_) => panic!("size mismatch should fail"),
        Err(e) => e,
    };
    assert!(e.to_string().contains("roughness map is 5×6"), "{e}");
}

#[test]
fn constructing_maps_rejects_empty_and_mismatched_buffers() {
    assert!(matches!(
        SvbrdfMaps::new(0, 4, vec![], vec![], vec![], vec![]),
        Err(GgxError::Empty { .. })
    ));
    let e = SvbrdfMaps::new(
        2,
        2,
        vec![[0.0; 3]; 4],
        vec![[0.0; 3]; 3],
        vec![0.0; 4],
        vec![[0.0, 0.0, 1.0]; 4],
    );
    assert!(matches!(e, Err(GgxError::SizeMismatch { .. })));
}
