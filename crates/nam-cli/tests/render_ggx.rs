//! End-to-end tests of `nam-cli render-ggx`: run the real binary on good and bad inputs.

use nam_ggx::color::srgb_encode;
use nam_ggx::imageio::read_rgb;
use nam_ggx::{DVec3, GgxPoint, Light, RenderSettings, SvbrdfMaps, Vec3, View, render};
mod common;

use common::{expect_failure, ok, run, s, stderr, tmp};
use std::path::{Path, PathBuf};

/// One 8-bit code: the PNG output is quantised after sRGB encoding.
const PNG_CODE_TOL: f32 = 1.0 / 255.0 + 1e-6;

fn example_maps() -> PathBuf {
    common::root().join("assets/example_maps.png")
}

/// `render-ggx MAPS --light LIGHT --view VIEW EXTRA… -o OUT`.
fn ggx_args<'a>(
    maps: &'a Path,
    light: &'a str,
    view: &'a str,
    out: &'a Path,
    extra: &[&'a str],
) -> Vec<&'a str> {
    let mut args = vec!["render-ggx", s(maps), "--light", light, "--view", view];
    args.extend_from_slice(extra);
    args.extend(["-o", s(out)]);
    args
}

/// A small glossy test material (16×16, 4-panel PNG).
fn small_maps(dir: &Path) -> (PathBuf, SvbrdfMaps) {
    let path = dir.join("maps.png");
    let p = GgxPoint {
        diffuse: [0.3, 0.2, 0.1],
        specular: [0.04; 3],
        roughness: 0.3,
        normal: Vec3::up(),
    };
    let maps = SvbrdfMaps::uniform(16, 16, &p).unwrap_or_else(|e| panic!("{e}"));
    maps.save(&path).unwrap_or_else(|e| panic!("{e}"));
    // Reload so the comparison sees the same quantised values as the CLI.
    let maps = SvbrdfMaps::load(&path).unwrap_or_else(|e| panic!("{e}"));
    (path, maps)
}

#[test]
fn renders_bundled_example_to_a_256_square_png() {
    let d = tmp();
    let out = d.path().join("out.png");
    ok(&ggx_args(&example_maps(), "1,1,4", "0,0,4", &out, &[]));
    let (img, _) = read_rgb(&out).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!((img.width(), img.height()), (256, 256));
    let mean: f32 = img.data().iter().sum::<f32>() / img.data().len() as f32;
    assert!(
        mean > 0.2 && mean < 0.9,
        "a lit material, not black or white: {mean}"
    );
}

#[test]
fn exr_output_is_the_linear_f32_library_render() {
    let d = tmp();
    let (maps_path, maps) = small_maps(d.path());
    let out = d.path().join("out.exr");
    ok(&ggx_args(&maps_path, "-1.5,0.5,3", "0.2,0,4", &out, &[]));
    let (img, _) = read_rgb(&out).unwrap_or_else(|e| panic!("{e}"));
    let settings = RenderSettings::new(
        Light::Point(DVec3::new(-1.5, 0.5, 3.0)),
        View::Point(DVec3::new(0.2, 0.0, 4.0)),
    );
    let want = render::<f32>(&maps, &settings).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(
        img.data(),
        want.data(),
        "EXR must hold the exact f32 radiance"
    );
}

#[test]
fn png_output_is_srgb_encoded_clamped_radiance() {
    let d = tmp();
    let (maps_path, maps) = small_maps(d.path());
    let out = d.path().join("out.png");
    let (pos, extra) = ("0,0,4.0108", ["--intensity", "3"]);
    ok(&ggx_args(&maps_path, pos, pos, &out, &extra));
    let (img, _) = read_rgb(&out).unwrap_or_else(|e| panic!("{e}"));
    let cam = DVec3::new(0.0, 0.0, 4.0108);
    let settings = RenderSettings {
        intensity: 3.0,
        ..RenderSettings::new(Light::Point(cam), View::Point(cam))
    };
    let want = render::<f32>(&maps, &settings).unwrap_or_else(|e| panic!("{e}"));
    let mut saw_clamp = false;
    for (got, lin) in img.data().iter().zip(want.data()) {
        saw_clamp |= *lin > 1.0;
        let enc = srgb_encode(*lin);
        assert!(
            (got - enc).abs() <= PNG_CODE_TOL,
            "{got} vs sRGB({lin}) = {enc}"
        );
    }
    assert!(saw_clamp, "intensity 3 should saturate the highlight");
}

#[test]
fn intensity_and_falloff_scale_the_exr() {
    let d = tmp();
    let (maps_path, _) = small_maps(d.path());
    let a = d.path().join("a.exr");
    let b = d.path().join("b.exr");
    let (light, view) = ("0,0,8.0216", "0,0,4");
    ok(&ggx_args(&maps_path, light, view, &a, &[]));
    let extra = ["--intensity", "2", "--falloff"];
    ok(&ggx_args(&maps_path, light, view, &b, &extra));
    let (ia, _) = read_rgb(&a).unwrap_or_else(|e| panic!("{e}"));
    let (ib, _) = read_rgb(&b).unwrap_or_else(|e| panic!("{e}"));
    // Light at 2d above the centre: falloff ≈ 1/4 near the centre, times intensity 2.
    let (x, y) = (ia.pixel(8, 8)[0], ib.pixel(8, 8)[0]);
    assert!((y / x - 0.5).abs() < 0.01, "{y} / {x}");
}

#[test]
fn malformed_vectors_fail_with_expected_xyz() {
    let d = tmp();
    let (maps_path, _) = small_maps(d.path());
    let out = d.path().join("out.png");
    for bad in ["1,2", "1,2,3,4", "a,b,c", "nan,0,4", "0,inf,4"] {
        let args = ggx_args(&maps_path, bad, "0,0,4", &out, &[]);
        expect_failure(&args, &out, "expected x,y,z");
    }
}

#[test]
fn light_or_view_below_the_surface_is_an_error() {
    let d = tmp();
    let (maps_path, _) = small_maps(d.path());
    let out = d.path().join("out.png");
    let args = ggx_args(&maps_path, "1,1,-4", "0,0,4", &out, &[]);
    expect_failure(&args, &out, "--light must be above the surface (z > 0)");
    let args = ggx_args(&maps_path, "1,1,4", "0,0,0", &out, &[]);
    expect_failure(&args, &out, "--view must be above the surface (z > 0)");
}

#[test]
fn negative_intensity_and_unknown_output_format_are_rejected() {
    let d = tmp();
    let (maps_path, _) = small_maps(d.path());
    let out = d.path().join("out.png");
    let args = ggx_args(&maps_path, "1,1,4", "0,0,4", &out, &["--intensity", "-1"]);
    expect_failure(&args, &out, "expected a finite number");
    let jpg = d.path().join("out.jpg");
    let args = ggx_args(&maps_path, "1,1,4", "0,0,4", &jpg, &[]);
    expect_failure(&args, &jpg, "output must end in .png");
}

#[test]
fn bad_map_files_fail_cleanly_without_output() {
    let d = tmp();
    let out = d.path().join("out.png");
    let missing = d.path().join("missing.png");
    let args = ggx_args(&missing, "1,1,4", "0,0,4", &out, &[]);
    expect_failure(&args, &out, "missing.png");
    let (good, _) = small_maps(d.path());
    let bytes = std::fs::read(&good).unwrap_or_else(|e| panic!("{e}"));
    let cut = d.path().join("cut.png");
    std::fs::write(&cut, &bytes[..bytes.len() / 3]).unwrap_or_else(|e| panic!("{e}"));
    let args = ggx_args(&cut, "1,1,4", "0,0,4", &out, &[]);
    expect_failure(&args, &out, "cannot decode image");
    // A plain 16×16 image is not a 4-panel file.
    let square = d.path().join("square.exr");
    let img = nam_ggx::RgbImage::<f32>::zeros(16, 16).unwrap_or_else(|e| panic!("{e}"));
    nam_ggx::imageio::write_rgb(&square, &img, nam_ggx::imageio::PngDepth::Eight)
        .unwrap_or_else(|e| panic!("{e}"));
    let args = ggx_args(&square, "1,1,4", "0,0,4", &out, &[]);
    expect_failure(&args, &out, "must be 4·H wide");
}

#[test]
fn failed_run_leaves_an_existing_output_untouched() {
    let d = tmp();
    let (maps_path, _) = small_maps(d.path());
    let out = d.path().join("keep.png");
    ok(&ggx_args(&maps_path, "1,1,4", "0,0,4", &out, &[]));
    let before = std::fs::read(&out).unwrap_or_else(|e| panic!("{e}"));
    let bad = d.path().join("bad.png");
    std::fs::write(&bad, b"\x89PNG\r\n\x1a\n garbage").unwrap_or_else(|e| panic!("{e}"));
    let o = run(&ggx_args(&bad, "1,1,4", "0,0,4", &out, &[]));
    assert!(!o.status.success());
    let after = std::fs::read(&out).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(before, after);
}

#[test]
fn output_into_missing_directory_fails_before_rendering() {
    let d = tmp();
    let (maps_path, _) = small_maps(d.path());
    let out = d.path().join("no/such/dir/out.png");
    let args = ggx_args(&maps_path, "1,1,4", "0,0,4", &out, &[]);
    expect_failure(&args, &out, "does not exist");
}

#[test]
fn help_lists_examples_and_conventions() {
    let o = run(&["render-ggx", "--help"]);
    assert!(o.status.success());
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(
        text.contains("Examples:") && text.contains("--light 1,1,4"),
        "{text}"
    );
    assert!(text.contains("4·H wide"), "{text}");
}

#[test]
fn directional_light_and_orthographic_view_give_a_uniform_image_on_uniform_maps() {
    let d = tmp();
    let (maps_path, _) = small_maps(d.path());
    let out = d.path().join("ortho.exr");
    let o = run(&[
        "render-ggx",
        s(&maps_path),
        "--light",
        "1,0,1",
        "--directional-light",
        "--view",
        "0,0,1",
        "--orthographic",
        "-o",
        s(&out),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let (img, _) = read_rgb(&out).unwrap_or_else(|e| panic!("{e}"));
    let first = img.pixel(0, 0);
    assert!(first[0] > 0.0);
    for i in 0..img.height() {
        for j in 0..img.width() {
            assert_eq!(img.pixel(i, j), first, "same directions at every pixel");
        }
    }
}

/// Issue 19 class 1: EXR maps can hold any f32; roughness 1e5 gave NaN and albedo 3e38 gave
/// Inf in an f32 render with exit 0. Values outside [0, 1] are now load errors that name the
/// map and the texel; nothing is written.
#[test]
fn exr_maps_outside_0_to_1_are_refused_instead_of_rendering_nan_or_inf() {
    let d = tmp();
    let out = d.path().join("out.exr");
    // 4-panel EXR: diffuse | specular | roughness | normal, 4×4 each.
    let panel = |rough: f32, diffuse: f32| {
        let mut img = nam_ggx::RgbImage::<f32>::zeros(4, 16).unwrap_or_else(|e| panic!("{e}"));
        for i in 0..4 {
            for j in 0..4 {
                img.set_pixel(i, j, [diffuse; 3]);
                img.set_pixel(i, 4 + j, [0.04; 3]);
                img.set_pixel(i, 8 + j, [0.3; 3]);
                img.set_pixel(i, 12 + j, [0.5, 0.5, 1.0]);
            }
        }
        img.set_pixel(2, 8 + 1, [rough; 3]);
        img
    };
    for (name, rough, diffuse, needle) in [
        (
            "rough1e5.exr",
            1e5,
            0.5,
            "roughness map has the value 1e5 at row 2, col 1, above 1",
        ),
        ("rough1e10.exr", 1e10, 0.5, "above 1"),
        (
            "albedo.exr",
            0.3,
            3e38,
            "diffuse map has the value 3e38 at row 0, col 0, above 1",
        ),
    ] {
        let maps = d.path().join(name);
        nam_ggx::imageio::write_rgb(
            &maps,
            &panel(rough, diffuse),
            nam_ggx::imageio::PngDepth::Eight,
        )
        .unwrap_or_else(|e| panic!("{e}"));
        for precision in ["f32", "f64"] {
            let args = ggx_args(&maps, "1,1,4", "0,0,4", &out, &["--precision", precision]);
            expect_failure(&args, &out, needle);
        }
    }
    // At the edge of the range every pixel is finite.
    let maps = d.path().join("edge.exr");
    nam_ggx::imageio::write_rgb(&maps, &panel(1.0, 1.0), nam_ggx::imageio::PngDepth::Eight)
        .unwrap_or_else(|e| panic!("{e}"));
    ok(&ggx_args(
        &maps,
        "0.01,0,1e-3",
        "0,0,4",
        &out,
        &["--intensity", "1e6", "--falloff"],
    ));
    let (img, _) = read_rgb(&out).unwrap_or_else(|e| panic!("{e}"));
    assert!(
        img.data().iter().all(|v| v.is_finite()),
        "non-finite pixels"
    );
}
