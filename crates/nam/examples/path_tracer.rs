//! A small CPU path tracer that puts a neural material on a sphere (the idea of the paper's
//! Fig. 6): the material is estimated from one flash photo, then evaluated and importance-sampled
//! through [`nam::NeuralBrdf`] like any analytic BRDF.
//!
//! Scene (world frame: y up, metres are arbitrary units): a unit-radius sphere at the origin
//! wearing the material (tiled 2× around, once pole to pole), on a grey floor at y = −1, lit by
//! a point light and a constant environment colour. Per sample: direct light from the point
//! light (shadowed by the sphere on the floor) plus one bounce towards the environment or the
//! floor, picked by the BRDF's cosine sampling.
//!
//! ```text
//! cargo run --release -p nam --example path_tracer -- [--photo P.png] [--size 256] [--spp 16] [-o out.png]
//! ```

use glam::{Vec2, Vec3};
use nam::{BrdfQuery, NeuralBrdf, NeuralModel, Photo, RgbImage, ShadingFrame};
use std::time::Instant;

/// Point-light position (world) and intensity (radiance scale at distance 1).
const LIGHT_POS: Vec3 = Vec3::new(3.0, 4.0, 4.0);
const LIGHT_POWER: f32 = 40.0;
/// Constant environment radiance (a pale sky).
const ENVIRONMENT: Vec3 = Vec3::new(0.20, 0.24, 0.30);
/// Floor height and diffuse albedo.
const FLOOR_Y: f32 = -1.0;
const FLOOR_ALBEDO: f32 = 0.45;
/// Camera position, look-at point and vertical field of view (degrees).
const CAMERA: Vec3 = Vec3::new(0.0, 0.6, 4.2);
const LOOK_AT: Vec3 = Vec3::new(0.0, -0.15, 0.0);
const FOV_DEG: f32 = 38.0;
/// Offset along the normal for rays leaving a surface (avoids self-hits).
const EPS: f32 = 1e-4;

struct Options {
    photo: String,
    size: usize,
    spp: usize,
    output: String,
}

fn parse_options() -> Result<Options, String> {
    let mut o = Options {
        photo: concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../assets/example_photo.png"
        )
        .into(),
        size: 256,
        spp: 16,
        output: "path_traced.png".into(),
    };
    let mut args = std::env::args().skip(1);
    while let Some(flag) = args.next() {
        let mut value = || args.next().ok_or(format!("{flag} needs a value"));
        match flag.as_str() {
            "--photo" => o.photo = value()?,
            "--size" => o.size = value()?.parse().map_err(|e| format!("--size: {e}"))?,
            "--spp" => o.spp = value()?.parse().map_err(|e| format!("--spp: {e}"))?,
            "-o" | "--output" => o.output = value()?,
            _ => return Err(format!("unknown argument {flag}")),
        }
    }
    if !(8..=4096).contains(&o.size) || !(1..=4096).contains(&o.spp) {
        return Err("--size must be in 8..=4096 and --spp in 1..=4096".into());
    }
    Ok(o)
}

/// Distance along a unit ray to the unit sphere at the origin, if hit in front.
fn hit_sphere(origin: Vec3, dir: Vec3) -> Option<f32> {
    let b = origin.dot(dir);
    let c = origin.length_squared() - 1.0;
    let disc = b * b - c;
    if disc < 0.0 {
        return None;
    }
    let s = disc.sqrt();
    [-b - s, -b + s].into_iter().find(|&t| t > EPS)
}

/// Distance along a unit ray to the floor, if hit in front.
fn hit_floor(origin: Vec3, dir: Vec3) -> Option<f32> {
    (dir.y < 0.0)
        .then(|| (FLOOR_Y - origin.y) / dir.y)
        .filter(|&t| t > EPS)
}

/// Radiance leaving the floor at `p` towards anything (Lambertian): shadowed direct light
/// plus the environment (a constant-ambient approximation for the floor only).
fn floor_radiance(p: Vec3) -> Vec3 {
    let to_light = LIGHT_POS - p;
    let d2 = to_light.length_squared();
    let l = to_light / d2.sqrt();
    let shadow = hit_sphere(p, l).is_some();
    let checker = if ((p.x.floor() + p.z.floor()) as i32).rem_euclid(2) == 0 {
        1.0
    } else {
        0.7
    };
    let albedo = FLOOR_ALBEDO * checker;
    let direct = if shadow { 0.0 } else { l.y * LIGHT_POWER / d2 };
    Vec3::splat(albedo / std::f32::consts::PI * direct) + ENVIRONMENT * albedo * 0.8
}

/// Texture coordinate of a point on the unit sphere (longitude tiled twice).
fn sphere_uv(n: Vec3) -> Vec2 {
    let u = (n.z.atan2(n.x) / std::f32::consts::TAU + 0.5) * 2.0;
    let v = n.y.clamp(-1.0, 1.0).acos() / std::f32::consts::PI;
    Vec2::new(u, v)
}

/// Radiance arriving along a ray that left the sphere (the sphere is convex, so it never
/// sees itself): the floor or the environment.
fn incoming(origin: Vec3, dir: Vec3) -> Vec3 {
    match hit_floor(origin, dir) {
        Some(t) => floor_radiance(origin + dir * t),
        None => ENVIRONMENT,
    }
}

/// A tiny deterministic generator (PCG-style hash), so runs are reproducible.
fn rand2(pixel: usize, sample: usize, dim: u32) -> Vec2 {
    let h = |x: u64| {
        let mut z = x.wrapping_add(0x9e37_79b9_7f4a_7c15);
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        ((z ^ (z >> 31)) >> 40) as f32 / (1u64 << 24) as f32
    };
    let key = ((pixel as u64) << 24) ^ ((sample as u64) << 4) ^ u64::from(dim);
    Vec2::new(h(key), h(key ^ 0x5555_5555_5555))
}

/// A sphere hit waiting for its batched BRDF evaluations.
struct SphereHit {
    pixel: usize,
    point: Vec3,
    frame: ShadingFrame,
    uv: Vec2,
    wo: Vec3,
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let opt = parse_options()?;
    let started = Instant::now();
    let model = NeuralModel::embedded()?;
    let photo = Photo::load(&opt.photo)?;
    let material = model.estimate(&photo)?;
    let brdf = NeuralBrdf::new(&model, &material)?;
    let n = opt.size;
    let mut sum = vec![Vec3::ZERO; n * n];

    let forward = (LOOK_AT - CAMERA).normalize();
    let right = forward.cross(Vec3::Y).normalize();
    let up = right.cross(forward);
    let half = (FOV_DEG.to_radians() / 2.0).tan();

    for s in 0..opt.spp {
        // 1. Camera rays; floor and sky are shaded directly, sphere hits are batched.
        let mut hits = Vec::new();
        for (pixel, acc) in sum.iter_mut().enumerate() {
            let j = rand2(pixel, s, 0);
            let x = ((pixel % n) as f32 + j.x) / n as f32 * 2.0 - 1.0;
            let y = 1.0 - ((pixel / n) as f32 + j.y) / n as f32 * 2.0;
            let dir = (forward + right * (x * half) + up * (y * half)).normalize();
            match hit_sphere(CAMERA, dir) {
                Some(t) => {
                    let point = CAMERA + dir * t;
                    let frame = ShadingFrame::from_normal(point).ok_or("degenerate normal")?;
                    hits.push(SphereHit {
                        pixel,
                        point,
                        frame,
                        uv: sphere_uv(point),
                        wo: frame.to_local(-dir),
                    });
                }
                None => *acc += incoming(CAMERA, dir),
            }
        }
        // 2. Direct light: one batched evaluation of f_r·cos θi.
        let queries: Vec<BrdfQuery> = hits
            .iter()
            .map(|h| BrdfQuery {
                uv: h.uv,
                wi: h.frame.to_local((LIGHT_POS - h.point).normalize()),
                wo: h.wo,
            })
            .collect();
        let direct = brdf.eval(&queries)?;
        // 3. One bounce: cosine-sampled directions, weight = f_r·cos θi / pdf.
        let requests: Vec<_> = hits
            .iter()
            .map(|h| (h.uv, h.wo, rand2(h.pixel, s, 1)))
            .collect();
        let bounces = brdf.sample(&requests)?;
        for ((h, f), b) in hits.iter().zip(direct).zip(bounces) {
            let d2 = (LIGHT_POS - h.point).length_squared();
            let mut l = f * LIGHT_POWER / d2;
            if let Some(b) = b {
                let origin = h.point + h.frame.n * EPS;
                l += b.weight * incoming(origin, h.frame.to_world(b.wi));
            }
            sum[h.pixel] += l;
        }
    }

    let rgb: Vec<f32> = sum
        .iter()
        .flat_map(|v| (*v / opt.spp as f32).to_array())
        .collect();
    let img = RgbImage::from_vec(n, n, rgb)?.map(nam_ggx::color::srgb_encode);
    let png = nam_ggx::imageio::encode_png(&img, nam_ggx::imageio::PngDepth::Eight)?;
    nam::write_atomic(opt.output.as_ref(), &png)?;
    println!(
        "{n}×{n}, {} spp in {:.1} s → {}",
        opt.spp,
        started.elapsed().as_secs_f64(),
        opt.output
    );
    Ok(())
}
