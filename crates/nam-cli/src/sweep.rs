//! Light sweeps: `--light` given several times, or `orbit:N[,elevation°[,distance]]`, rendered
//! as numbered frames plus an optional contact sheet and animated GIF, so the material can be
//! seen moving under the light.

use crate::args::parse_vec3;
use anyhow::{Context, Result, bail};
use nam_ggx::RgbImage;
use nam_ggx::color::srgb_encode;
use std::path::{Path, PathBuf};

/// Most frames one run may render (a typo such as `orbit:100000` should not run for hours).
pub const MAX_FRAMES: usize = 1000;
/// Default orbit elevation above the surface plane (degrees).
const ORBIT_ELEVATION_DEG: f64 = 45.0;
/// Gap between contact-sheet tiles (pixels, black).
const SHEET_GAP: usize = 2;

/// One `--light` value.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum LightSpec {
    /// A single position (or direction with `--directional`) `x,y,z`.
    At([f64; 3]),
    /// `count` positions evenly spaced in azimuth (starting at +x, counter-clockwise seen
    /// from above) at `elevation_deg` above the plane and `distance` from the origin (by
    /// default the capture camera's: [`expand`] takes it).
    Orbit {
        /// Number of frames.
        count: usize,
        /// Elevation above the surface plane, degrees in (0, 90].
        elevation_deg: f64,
        /// Distance from the material's centre (surface-frame units; the material spans
        /// [−1, 1]²); `None`: the capture distance.
        distance: Option<f64>,
    },
}

/// Parses `x,y,z` or `orbit:N[,elevation°[,distance]]` (clap value parser).
pub fn parse_light_spec(s: &str) -> Result<LightSpec, String> {
    let Some(rest) = s.trim().strip_prefix("orbit:") else {
        return parse_vec3(s).map(LightSpec::At);
    };
    let mut parts = rest.split(',').map(str::trim);
    let count: usize = parts
        .next()
        .and_then(|n| n.parse().ok())
        .filter(|n| (1..=MAX_FRAMES).contains(n))
        .ok_or_else(|| format!("orbit:N needs 1 ≤ N ≤ {MAX_FRAMES}, got '{s}'"))?;
    let mut number = |name: &str| -> Result<Option<f64>, String> {
        parts
            .next()
            .map(|v| {
                v.parse::<f64>()
                    .ok()
                    .filter(|x| x.is_finite())
                    .ok_or_else(|| format!("orbit {name} '{v}' is not a finite number"))
            })
            .transpose()
    };
    let elevation_deg = number("elevation")?.unwrap_or(ORBIT_ELEVATION_DEG);
    let distance = number("distance")?;
    if parts.next().is_some() {
        return Err(format!(
            "expected orbit:N[,elevation°[,distance]], got '{s}'"
        ));
    }
    if !(elevation_deg > 0.0 && elevation_deg <= 90.0) {
        return Err(format!(
            "orbit elevation must be in (0, 90] degrees (above the surface), got {elevation_deg}"
        ));
    }
    if let Some(d) = distance.filter(|&d| d <= 0.0) {
        return Err(format!("orbit distance must be > 0, got {d}"));
    }
    Ok(LightSpec::Orbit {
        count,
        elevation_deg,
        distance,
    })
}

/// All light positions of the specs, in order; orbits without a distance circle at
/// `capture_distance`, the photo camera's distance from the material's centre.
pub fn expand(specs: &[LightSpec], capture_distance: f64) -> Result<Vec<[f64; 3]>> {
    let mut out = Vec::new();
    for spec in specs {
        match *spec {
            LightSpec::At(p) => out.push(p),
            LightSpec::Orbit {
                count,
                elevation_deg,
                distance,
            } => {
                let distance = distance.unwrap_or(capture_distance);
                let el = elevation_deg.to_radians();
                out.extend((0..count).map(|k| {
                    let phi = std::f64::consts::TAU * k as f64 / count as f64;
                    [
                        distance * el.cos() * phi.cos(),
                        distance * el.cos() * phi.sin(),
                        distance * el.sin(),
                    ]
                }));
            }
        }
    }
    if out.len() > MAX_FRAMES {
        bail!("{} frames requested; at most {MAX_FRAMES}", out.len());
    }
    Ok(out)
}

/// Where frame `k` of `n` goes: `base` itself for a single frame, else `stem_KKK.ext` next to it.
pub fn frame_path(base: &Path, k: usize, n: usize) -> PathBuf {
    if n == 1 {
        return base.to_path_buf();
    }
    let stem = base
        .file_stem()
        .map(|s| s.to_string_lossy())
        .unwrap_or_default();
    let ext = base
        .extension()
        .map(|s| s.to_string_lossy())
        .unwrap_or_default();
    base.with_file_name(format!("{stem}_{k:03}.{ext}"))
}

/// A grid of the frames (row-major, ⌈√n⌉ columns, 2-pixel black gaps), linear RGB.
pub fn contact_sheet(frames: &[RgbImage<f32>]) -> Result<RgbImage<f32>> {
    let Some(first) = frames.first() else {
        bail!("no frames for a contact sheet");
    };
    let (w, h) = (first.width(), first.height());
    let cols = (frames.len() as f64).sqrt().ceil() as usize;
    let rows = frames.len().div_ceil(cols);
    let mut sheet = RgbImage::zeros(
        rows * h + (rows - 1) * SHEET_GAP,
        cols * w + (cols - 1) * SHEET_GAP,
    )?;
    for (k, frame) in frames.iter().enumerate() {
        let (r0, c0) = ((k / cols) * (h + SHEET_GAP), (k % cols) * (w + SHEET_GAP));
        for i in 0..h {
            for j in 0..w {
                sheet.set_pixel(r0 + i, c0 + j, frame.pixel(i, j));
            }
        }
    }
    Ok(sheet)
}

/// An endlessly looping GIF of the frames (sRGB, clamped; `delay_ms` per frame).
pub fn encode_gif(frames: &[RgbImage<f32>], delay_ms: u32) -> Result<Vec<u8>> {
    use image::codecs::gif::{GifEncoder, Repeat};
    use image::{Delay, Frame, RgbaImage};
    let mut bytes = Vec::new();
    {
        let mut enc = GifEncoder::new_with_speed(&mut bytes, 10);
        enc.set_repeat(Repeat::Infinite)?;
        for f in frames {
            let rgba: Vec<u8> = f
                .data()
                .chunks_exact(3)
                .flat_map(|p| {
                    let q = |v: f32| (srgb_encode(v).clamp(0.0, 1.0) * 255.0).round() as u8;
                    [q(p[0]), q(p[1]), q(p[2]), 255]
                })
                .collect();
            let (w, h) = (u32::try_from(f.width())?, u32::try_from(f.height())?);
            let buf = RgbaImage::from_raw(w, h, rgba).context("frame buffer size")?;
            let delay = Delay::from_numer_denom_ms(delay_ms, 1);
            enc.encode_frame(Frame::from_parts(buf, 0, 0, delay))?;
        }
    }
    Ok(bytes)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn orbit_positions_lie_on_the_requested_circle() {
        let spec = parse_light_spec("orbit:8,30,2").unwrap();
        let ps = expand(&[spec], 4.0).unwrap();
        assert_eq!(ps.len(), 8);
        for p in &ps {
            let r = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
            assert!((r - 2.0).abs() < 1e-12);
            assert!((p[2] / r - 0.5).abs() < 1e-12, "elevation 30°");
        }
        assert!(
            (ps[2][1] - 2.0 * 30f64.to_radians().cos()).abs() < 1e-12,
            "quarter turn → +y"
        );
    }

    #[test]
    fn orbit_without_a_distance_circles_at_the_capture_distance() {
        let spec = parse_light_spec("orbit:3").unwrap();
        use nam_ggx::geometry::{CAPTURE_DISTANCE, capture_distance};
        for d in [CAPTURE_DISTANCE, capture_distance(45.0)] {
            for p in expand(&[spec], d).unwrap() {
                let r = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
                assert!((r - d).abs() < 1e-12, "{r} vs {d}");
            }
        }
    }

    #[test]
    fn light_specs_parse_points_and_reject_bad_orbits() {
        assert_eq!(
            parse_light_spec("1,-2,3").unwrap(),
            LightSpec::At([1.0, -2.0, 3.0])
        );
        assert!(matches!(
            parse_light_spec("orbit:4").unwrap(),
            LightSpec::Orbit { count: 4, .. }
        ));
        for bad in [
            "orbit:0",
            "orbit:x",
            "orbit:5000",
            "orbit:4,0",
            "orbit:4,95",
            "orbit:4,45,-1",
            "orbit:4,45,nan",
            "orbit:4,45,4,1",
        ] {
            assert!(parse_light_spec(bad).is_err(), "{bad} accepted");
        }
    }

    #[test]
    fn frames_are_numbered_only_when_there_are_several() {
        let base = Path::new("out/relit.png");
        assert_eq!(frame_path(base, 0, 1), base);
        assert_eq!(frame_path(base, 7, 12), Path::new("out/relit_007.png"));
    }

    #[test]
    fn contact_sheet_places_each_frame_in_its_cell() {
        let frames: Vec<_> = (0..5)
            .map(|k| RgbImage::from_vec(2, 3, vec![k as f32 + 1.0; 18]).unwrap())
            .collect();
        let sheet = contact_sheet(&frames).unwrap();
        // 3 columns, 2 rows.
        assert_eq!((sheet.width(), sheet.height()), (3 * 3 + 4, 2 * 2 + 2));
        assert_eq!(sheet.pixel(0, 0), [1.0; 3]);
        assert_eq!(sheet.pixel(0, 3), [0.0; 3], "gap");
        assert_eq!(sheet.pixel(1, 5 + 2), [2.0; 3]);
        assert_eq!(sheet.pixel(4, 5), [5.0; 3]);
        assert_eq!(sheet.pixel(4, 10), [0.0; 3], "empty cell stays black");
    }

    #[test]
    fn gif_has_one_frame_per_image() {
        let frames: Vec<_> = (0..3)
            .map(|k| RgbImage::from_vec(4, 4, vec![0.1 * k as f32; 48]).unwrap())
            .collect();
        let bytes = encode_gif(&frames, 100).unwrap();
        assert_eq!(&bytes[..6], b"GIF89a");
        let dec = image::codecs::gif::GifDecoder::new(std::io::Cursor::new(bytes)).unwrap();
        use image::AnimationDecoder;
        assert_eq!(dec.into_frames().count(), 3);
    }
}
