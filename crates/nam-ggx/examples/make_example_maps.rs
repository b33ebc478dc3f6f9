//! Generates the bundled demo material `assets/example_maps.png`: red bricks in running bond
//! with a glossy clear coat, rough recessed mortar, per-brick colour and gloss variation and a
//! normal map from the height field. 4-panel layout, 256×(4·256), 8-bit PNG.
//!
//! ```text
//! cargo run --release -p nam-ggx --example make_example_maps -- assets/example_maps.png
//! ```
//! Deterministic: the same file every run.

use nam_ggx::SvbrdfMaps;
use nam_ggx::imageio::PngDepth;
use std::path::PathBuf;

const SIZE: usize = 256;
/// Brick pitch in pixels (including one mortar joint).
const BRICK_W: f64 = 64.0;
const BRICK_H: f64 = 32.0;
/// Half-width of the mortar joint, pixels.
const MORTAR: f64 = 2.5;
/// Width of the bevelled brick edge, pixels.
const BEVEL: f64 = 4.0;
/// Height-to-slope scale of the normal map (pixels of height per pixel).
const BUMP: f64 = 2.5;

fn hash(x: i64, y: i64, seed: u64) -> f64 {
    let mut h = (x as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
        ^ (y as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F)
        ^ seed.wrapping_mul(0x1656_67B1_9E37_79F9);
    h ^= h >> 33;
    h = h.wrapping_mul(0xFF51_AFD7_ED55_8CCD);
    h ^= h >> 33;
    h = h.wrapping_mul(0xC4CE_B9FE_1A85_EC53);
    h ^= h >> 33;
    (h >> 11) as f64 / (1u64 << 53) as f64
}

/// Smooth value noise in [0, 1] at lattice scale `scale` pixels.
fn noise(x: f64, y: f64, scale: f64, seed: u64) -> f64 {
    let (u, v) = (x / scale, y / scale);
    let (i, j) = (u.floor() as i64, v.floor() as i64);
    let (fu, fv) = (u - u.floor(), v - v.floor());
    let s = |t: f64| t * t * (3.0 - 2.0 * t);
    let (a, b) = (s(fu), s(fv));
    let lerp = |p: f64, q: f64, t: f64| p + (q - p) * t;
    lerp(
        lerp(hash(i, j, seed), hash(i + 1, j, seed), a),
        lerp(hash(i, j + 1, seed), hash(i + 1, j + 1, seed), a),
        b,
    )
}

fn fbm(x: f64, y: f64, scale: f64, seed: u64) -> f64 {
    (0..4)
        .map(|o| {
            let f = f64::from(1u32 << o);
            noise(x, y, scale / f, seed + o as u64) / f
        })
        .sum::<f64>()
        / 1.875
}

struct Sample {
    height: f64,
    brick: Option<(i64, i64)>,
    edge: f64,
}

/// Height (0 in the mortar, ≈1 on bricks) and brick id at pixel (x right, y down).
fn sample(x: f64, y: f64) -> Sample {
    let row = (y / BRICK_H).floor();
    let shift = if (row as i64).rem_euclid(2) == 1 {
        BRICK_W / 2.0
    } else {
        0.0
    };
    let col = ((x + shift) / BRICK_W).floor();
    let lx = x + shift - col * BRICK_W;
    let ly = y - row * BRICK_H;
    // Distance to the nearest joint centre line.
    let dx = lx.min(BRICK_W - lx);
    let dy = ly.min(BRICK_H - ly);
    let edge = dx.min(dy) - MORTAR;
    let s = |t: f64| {
        let t = t.clamp(0.0, 1.0);
        t * t * (3.0 - 2.0 * t)
    };
    if edge <= 0.0 {
        Sample {
            height: 0.15 * fbm(x, y, 6.0, 7),
            brick: None,
            edge,
        }
    } else {
        let id = (col as i64, row as i64);
        let rough_surface = 0.12 * fbm(x, y, 10.0, 3) + 0.05 * fbm(x, y, 3.0, 4);
        Sample {
            height: 0.3 + 0.7 * s(edge / BEVEL) + rough_surface,
            brick: Some(id),
            edge,
        }
    }
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let out = std::env::args()
        .nth(1)
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from("assets/example_maps.png"));
    let n = SIZE * SIZE;
    let mut diffuse = Vec::with_capacity(n);
    let mut specular = Vec::with_capacity(n);
    let mut roughness = Vec::with_capacity(n);
    let mut normal = Vec::with_capacity(n);
    for i in 0..SIZE {
        for j in 0..SIZE {
            let (x, y) = (j as f64 + 0.5, i as f64 + 0.5);
            let c = sample(x, y);
            // Central differences of the height field; image rows grow towards −y.
            let hx = (sample(x + 1.0, y).height - sample(x - 1.0, y).height) / 2.0;
            let hrow = (sample(x, y + 1.0).height - sample(x, y - 1.0).height) / 2.0;
            normal.push([(-BUMP * hx) as f32, (BUMP * hrow) as f32, 1.0]);
            match c.brick {
                Some((bc, br)) => {
                    let v = hash(bc, br, 11);
                    let w = hash(bc, br, 12);
                    let grain = fbm(x, y, 5.0, 21);
                    let base = [0.42 + 0.18 * v, 0.13 + 0.07 * w, 0.08 + 0.04 * v];
                    let k = 0.75 + 0.4 * grain;
                    // Soot darkens the edges slightly.
                    let edge_dark = 0.8 + 0.2 * (c.edge / BEVEL).clamp(0.0, 1.0);
                    diffuse.push(base.map(|b| (b * k * edge_dark) as f32));
                    specular.push([0.05_f32; 3]);
                    // The coat is glossy on most bricks, worn (rougher) on some.
                    let worn = hash(bc, br, 13);
                    let r = 0.18 + 0.25 * worn * worn + 0.08 * fbm(x, y, 12.0, 31);
                    roughness.push(r as f32);
                }
                None => {
                    let g = 0.45 + 0.15 * fbm(x, y, 4.0, 41);
                    diffuse.push([g as f32, (g * 0.97) as f32, (g * 0.92) as f32]);
                    specular.push([0.02_f32; 3]);
                    roughness.push((0.8 + 0.15 * fbm(x, y, 5.0, 42)) as f32);
                }
            }
        }
    }
    let maps = SvbrdfMaps::new(SIZE, SIZE, diffuse, specular, roughness, normal)?;
    maps.save_png(&out, PngDepth::Eight)?;
    println!("wrote {}", out.display());
    Ok(())
}
