//! [`NeuralBrdf`]: a neural material as a BRDF for renderers — batched evaluation,
//! importance sampling and pdf.
//!
//! Conventions (pbrt-style, stated once): directions are unit vectors pointing *away* from
//! the surface; `wi` towards the light, `wo` towards the viewer. "Local" means the material's
//! surface frame (z = shading normal); world-space variants take a [`ShadingFrame`].
//! [`NeuralBrdf::eval`] returns `f_r(ωi, ωo) · cos θi` — what a path tracer multiplies by the
//! incident radiance — and [`NeuralBrdf::eval_fr`] returns `f_r` alone. Both are exactly 0
//! when `wi` or `wo` is on or below the horizon.

use crate::error::{NamError, Result};
use crate::frame::ShadingFrame;
use crate::material::NeuralMaterial;
use crate::model::NeuralModel;
use crate::sampling::{cosine_hemisphere_pdf, sample_cosine_hemisphere};
use glam::{Vec2, Vec3};
use std::f32::consts::PI;

/// Smallest cos θi `eval_fr` divides by: below it `f_r` would amplify network noise by >1e6.
const MIN_COS_FOR_FR: f32 = 1e-6;

/// Smallest batch [`NeuralBrdf::eval`] sends to an attached GPU: below it the upload,
/// submission and readback cost more than the CPU's tile-fused evaluation.
pub const GPU_MIN_QUERIES: usize = 4096;

/// One evaluation query in the surface frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BrdfQuery {
    /// Texture coordinate; `[0,1]²` covers the material once (u → columns, v → rows, v = 0
    /// at the top row), outside it the material tiles.
    pub uv: Vec2,
    /// Unit direction towards the light, surface frame.
    pub wi: Vec3,
    /// Unit direction towards the viewer, surface frame.
    pub wo: Vec3,
}

/// A sampled incident direction.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BrdfSample {
    /// Sampled unit direction towards the light, surface frame (z > 0).
    pub wi: Vec3,
    /// `f_r · cos θi / pdf`: the path throughput factor.
    pub weight: Vec3,
    /// Solid-angle pdf of `wi`.
    pub pdf: f32,
}

/// A neural material bound to its model (thread-safe, batched). Batches of at least
/// [`GPU_MIN_QUERIES`] run on the model's GPU when one is attached
/// ([`NeuralModel::attach_gpu`]), smaller ones on the CPU; both give the same values within
/// f32 summation order.
#[derive(Debug, Clone, Copy)]
pub struct NeuralBrdf<'a> {
    model: &'a NeuralModel,
    material: &'a NeuralMaterial,
}

impl<'a> NeuralBrdf<'a> {
    /// Binds a material to the model that estimated it.
    pub fn new(model: &'a NeuralModel, material: &'a NeuralMaterial) -> Result<Self> {
        material.check_model(model)?;
        Ok(Self { model, material })
    }

    /// Pixel index of a texture coordinate (nearest texel, wrapping).
    fn texel(&self, uv: Vec2) -> Result<usize> {
        if !uv.is_finite() {
            return Err(NamError::Query(format!("uv must be finite, got {uv}")));
        }
        let (h, w) = self.material.size();
        let wrap = |t: f32, n: usize| ((t - t.floor()) * n as f32).min(n as f32 - 1.0) as usize;
        Ok(wrap(uv.y, h) * w + wrap(uv.x, w))
    }

    /// `f_r · cos θi` (RGB) for a batch of surface-frame queries; see the module docs.
    /// Non-unit directions are normalised; zero or non-finite ones are errors.
    pub fn eval(&self, queries: &[BrdfQuery]) -> Result<Vec<Vec3>> {
        let c = self.material.params().channels;
        let map = &self.material.params().data;
        let mut params = Vec::with_capacity(queries.len() * c);
        let mut wi = Vec::with_capacity(queries.len());
        let mut wo = Vec::with_capacity(queries.len());
        let mut visible = Vec::with_capacity(queries.len());
        for q in queries {
            let t = self.texel(q.uv)?;
            let (i, o) = match (unit(q.wi), unit(q.wo)) {
                (Some(i), Some(o)) => (i, o),
                _ => {
                    return Err(NamError::Query(format!(
                        "directions must be non-zero and finite, got wi={} wo={}",
                        q.wi, q.wo
                    )));
                }
            };
            visible.push(i.z > 0.0 && o.z > 0.0);
            params.extend_from_slice(&map[t * c..(t + 1) * c]);
            wi.push(i.to_array());
            wo.push(o.to_array());
        }
        let r = match self.eval_gpu(&params, &wi, &wo) {
            Some(gpu) => gpu?,
            None => {
                let mut r = vec![0.0f32; queries.len() * 3];
                self.model
                    .cpu()
                    .render
                    .render_batch(&params, &wi, &wo, &mut r)?;
                r
            }
        };
        // R = π f_r cos θi  ⇒  f_r cos θi = R / π.
        Ok(r.chunks_exact(3)
            .zip(visible)
            .map(|(v, vis)| {
                if vis {
                    Vec3::new(v[0], v[1], v[2]) / PI
                } else {
                    Vec3::ZERO
                }
            })
            .collect())
    }

    /// Radiance `[n, 3]` of a large batch on the attached GPU; `None` for small batches or
    /// without a GPU.
    #[cfg(feature = "gpu")]
    fn eval_gpu(
        &self,
        params: &[f32],
        wi: &[[f32; 3]],
        wo: &[[f32; 3]],
    ) -> Option<Result<Vec<f32>>> {
        if wi.len() < GPU_MIN_QUERIES {
            return None;
        }
        let dirs: Vec<f32> = wi
            .iter()
            .zip(wo)
            .flat_map(|(&i, &o)| nam_model::encoding::direction_triple(i, o))
            .collect();
        self.model.with_gpu(|net| Ok(net.render(params, &dirs)?))
    }

    /// Without the `gpu` feature every batch runs on the CPU.
    #[cfg(not(feature = "gpu"))]
    fn eval_gpu(&self, _: &[f32], _: &[[f32; 3]], _: &[[f32; 3]]) -> Option<Result<Vec<f32>>> {
        None
    }

    /// `f_r` alone (RGB): [`NeuralBrdf::eval`] divided by `cos θi` (guarded).
    pub fn eval_fr(&self, queries: &[BrdfQuery]) -> Result<Vec<Vec3>> {
        let v = self.eval(queries)?;
        Ok(v.into_iter()
            .zip(queries)
            .map(|(f, q)| {
                let cos = q.wi.normalize_or_zero().z;
                if cos > MIN_COS_FOR_FR {
                    f / cos
                } else {
                    Vec3::ZERO
                }
            })
            .collect())
    }

    /// World-space evaluation: rotates `wi`, `wo` into `frame` first (arbitrary surface
    /// orientation, DESIGN §3 / paper §5).
    pub fn eval_world(&self, frame: &ShadingFrame, uv: Vec2, wi: Vec3, wo: Vec3) -> Result<Vec3> {
        let q = BrdfQuery {
            uv,
            wi: frame.to_local(wi),
            wo: frame.to_local(wo),
        };
        Ok(self.eval(&[q])?[0])
    }

    /// Samples `wi` for a batch of `(uv, wo, u)` with cosine-weighted hemisphere sampling (the
    /// paper's diffuse sampling, not adapted to the material). `None` where `wo` is below the
    /// horizon. `u ∈ [0,1)²` are the caller's random numbers.
    pub fn sample(&self, requests: &[(Vec2, Vec3, Vec2)]) -> Result<Vec<Option<BrdfSample>>> {
        let queries: Vec<BrdfQuery> = requests
            .iter()
            .map(|&(uv, wo, u)| BrdfQuery {
                uv,
                wi: sample_cosine_hemisphere(u),
                wo,
            })
            .collect();
        let f = self.eval(&queries)?;
        Ok(queries
            .iter()
            .zip(f)
            .map(|(q, f)| {
                let pdf = cosine_hemisphere_pdf(q.wi);
                (q.wo.z > 0.0 && pdf > 0.0).then(|| BrdfSample {
                    wi: q.wi,
                    weight: f / pdf,
                    pdf,
                })
            })
            .collect())
    }

    /// Solid-angle pdf with which [`NeuralBrdf::sample`] picks `wi` (surface frame); 0 when
    /// `wo` or `wi` is below the horizon.
    pub fn pdf(&self, wo: Vec3, wi: Vec3) -> f32 {
        if wo.z <= 0.0 {
            return 0.0;
        }
        cosine_hemisphere_pdf(wi.normalize_or_zero())
    }
}

/// `v / |v|`, computed in f64 so tiny (|v| < 1e-19) and huge vectors normalise too; `None`
/// for zero or non-finite vectors.
fn unit(v: Vec3) -> Option<Vec3> {
    v.as_dvec3().try_normalize().map(|d| d.as_vec3())
}
