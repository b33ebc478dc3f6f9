//! Python bindings of the `nam` facade: the extension module `nam._nam`, re-exported by the
//! `nam` package (`python/nam/__init__.py`, stubs in `_nam.pyi`).
//!
//! It exposes the facade, it does not re-implement it: [`nam::NeuralModel`],
//! [`nam::NeuralMaterial`], [`nam::relight`] and [`nam::NeuralBrdf`]. Arrays cross as numpy
//! (rust-numpy over ndarray); the GIL is released while Rust computes; bad input is a
//! `ValueError` or `TypeError` (a file that cannot be read an `OSError`), never a panic.

mod arrays;

use std::path::PathBuf;
use std::sync::Arc;

use arrays::{PhotoPixels, out_image, out_rows, out_values, rows, same_rows};
use nam::geometry::{CAPTURE_FOV_DEG, Light, View};
use nam::{BrdfQuery, DVec3, NamError, NeuralBrdf, Photo, Scene, Vec2, Vec3};
use numpy::{PyArray1, PyArray2, PyArray3, PyArrayMethods};
use pyo3::exceptions::{PyOSError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;

/// A facade error as the Python exception a caller can act on.
fn py_err(e: NamError) -> PyErr {
    match e {
        NamError::Io { .. } => PyOSError::new_err(e.to_string()),
        _ => PyValueError::new_err(e.to_string()),
    }
}

/// A neural appearance model: the estimator `M_est` (photo → 64-channel latent map) and the
/// renderer `M_render` (latent, light and view directions → radiance).
#[pyclass(frozen, module = "nam")]
struct Model {
    inner: Arc<nam::NeuralModel>,
}

#[pymethods]
impl Model {
    /// The model built into this package (the project's `models/default.safetensors`).
    #[staticmethod]
    fn embedded() -> PyResult<Self> {
        Ok(Self {
            inner: Arc::new(nam::NeuralModel::embedded().map_err(py_err)?),
        })
    }

    /// Loads a model file (`.safetensors`, docs/FORMAT.md).
    #[staticmethod]
    fn load(py: Python<'_>, path: PathBuf) -> PyResult<Self> {
        let model = py
            .detach(|| nam::NeuralModel::from_file(&path))
            .map_err(py_err)?;
        Ok(Self {
            inner: Arc::new(model),
        })
    }

    /// `{"width", "parameters", "dtype", "sha256", "param_channels", "input_skip"}`.
    fn info<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let m = &self.inner;
        let cfg = m.config();
        let d = PyDict::new(py);
        d.set_item("width", cfg.width)?;
        d.set_item("parameters", m.parameter_count())?;
        d.set_item("dtype", &cfg.dtype)?;
        d.set_item("sha256", m.fingerprint())?;
        d.set_item("param_channels", cfg.param_channels)?;
        d.set_item("input_skip", cfg.input_skip)?;
        Ok(d)
    }

    /// Estimates the neural material of a square flash photo: `photo` is `H×W×3`, `uint8`
    /// (sRGB-encoded, as a PNG or JPEG stores it) or `float32` (linear radiance), taken from
    /// (0, 0, d) with the flash beside the lens, d = 1/tan(fov/2) material half-widths
    /// (`fov` in degrees; 28 is the training geometry). The params of the pixels the photo
    /// clipped are filled from the pixels around them unless `keep_clipped`.
    #[pyo3(signature = (photo, fov = CAPTURE_FOV_DEG, keep_clipped = false))]
    fn estimate(
        &self,
        py: Python<'_>,
        photo: &Bound<'_, PyAny>,
        fov: f64,
        keep_clipped: bool,
    ) -> PyResult<Material> {
        let (h, w, pixels) = arrays::photo(photo)?;
        let model = Arc::clone(&self.inner);
        let material = py
            .detach(|| {
                let photo = match pixels {
                    PhotoPixels::Srgb8(v) => Photo::from_srgb8(h, w, &v),
                    PhotoPixels::Linear(v) => Photo::from_linear_rgb(h, w, v),
                }?
                .with_fov(fov)?;
                model.estimate_with(&photo, !keep_clipped)
            })
            .map_err(py_err)?;
        Ok(Material {
            inner: Arc::new(material),
            model: Arc::clone(&self.inner),
        })
    }

    /// Estimates the material of a photo file as `nam-cli estimate` does: PNG/JPEG (sRGB, EXIF
    /// orientation applied) or EXR (linear); `crop` takes the centred square of a non-square
    /// photo, `resize` resamples it to that side first; `keep_clipped` as in `estimate`.
    #[pyo3(signature = (path, fov = CAPTURE_FOV_DEG, crop = false, resize = None, keep_clipped = false))]
    fn estimate_file(
        &self,
        py: Python<'_>,
        path: PathBuf,
        fov: f64,
        crop: bool,
        resize: Option<usize>,
        keep_clipped: bool,
    ) -> PyResult<Material> {
        let model = Arc::clone(&self.inner);
        let material = py
            .detach(|| {
                let photo = Photo::load_resized(&path, crop, resize)?.with_fov(fov)?;
                model.estimate_with(&photo, !keep_clipped)
            })
            .map_err(py_err)?;
        Ok(Material {
            inner: Arc::new(material),
            model: Arc::clone(&self.inner),
        })
    }

    fn __repr__(&self) -> String {
        let cfg = self.inner.config();
        format!(
            "nam.Model(width={}, parameters={}, sha256={}…)",
            cfg.width,
            self.inner.parameter_count(),
            &self.inner.fingerprint()[..12]
        )
    }
}

/// A neural material: one 64-d latent vector per pixel, bound to the model that estimated
/// it. Directions of the renderer API are unit vectors in the local shading frame (z = the
/// surface normal); `uv` in [0, 1]² covers the material once (u → columns, v → rows, v = 0 at
/// the top row) and tiles beyond.
#[pyclass(frozen, module = "nam")]
struct Material {
    inner: Arc<nam::NeuralMaterial>,
    model: Arc<nam::NeuralModel>,
}

impl Material {
    /// Runs `f` on this material's BRDF with the GIL released.
    fn brdf<T: Send>(
        &self,
        py: Python<'_>,
        f: impl FnOnce(NeuralBrdf<'_>) -> nam::Result<T> + Send,
    ) -> PyResult<T> {
        let (model, material) = (&self.model, &self.inner);
        py.detach(|| f(NeuralBrdf::new(model, material)?))
            .map_err(py_err)
    }
}

/// The `(uv, wi, wo)` arguments of a batch call, as Python passed them.
type BatchArgs<'a, 'py> = (
    &'a Bound<'py, PyAny>,
    &'a Bound<'py, PyAny>,
    &'a Bound<'py, PyAny>,
);

impl Material {
    /// An RGB value per query (`N×3`) from one of the BRDF's batched evaluations.
    fn rgb_per_query<'py>(
        &self,
        py: Python<'py>,
        (uv, wi, wo): BatchArgs<'_, 'py>,
        f: impl Fn(&NeuralBrdf<'_>, &[BrdfQuery]) -> nam::Result<Vec<Vec3>> + Sync,
    ) -> PyResult<Bound<'py, PyArray2<f32>>> {
        let (uv, wi, wo) = batch(uv, wi, wo)?;
        let q = queries(&uv, &wi, &wo);
        let v = self.brdf(py, |b| f(&b, &q))?;
        Ok(out_rows(py, v.iter().map(Vec3::to_array).collect()))
    }
}

/// `N×3` directions and `N×2` texture coordinates as queries.
fn queries(uv: &[[f32; 2]], wi: &[[f32; 3]], wo: &[[f32; 3]]) -> Vec<BrdfQuery> {
    uv.iter()
        .zip(wi)
        .zip(wo)
        .map(|((uv, wi), wo)| BrdfQuery {
            uv: Vec2::from_array(*uv),
            wi: Vec3::from_array(*wi),
            wo: Vec3::from_array(*wo),
        })
        .collect()
}

/// `(uv, wi, wo)` of a batch call, checked.
type Batch = (Vec<[f32; 2]>, Vec<[f32; 3]>, Vec<[f32; 3]>);

fn batch(uv: &Bound<'_, PyAny>, wi: &Bound<'_, PyAny>, wo: &Bound<'_, PyAny>) -> PyResult<Batch> {
    let (uv, wi, wo) = (
        rows::<2>("uv", uv)?,
        rows::<3>("wi", wi)?,
        rows::<3>("wo", wo)?,
    );
    same_rows(&[("uv", uv.len()), ("wi", wi.len()), ("wo", wo.len())])?;
    Ok((uv, wi, wo))
}

#[pymethods]
impl Material {
    /// Reads a `.nam` file (as `nam-cli estimate` writes it); `model` is the model that
    /// estimated it (default: the embedded one) — another model is an error.
    #[staticmethod]
    #[pyo3(signature = (path, model = None))]
    fn load(py: Python<'_>, path: PathBuf, model: Option<&Model>) -> PyResult<Self> {
        let model = match model {
            Some(m) => Arc::clone(&m.inner),
            None => Model::embedded()?.inner,
        };
        let material = py
            .detach(|| {
                let material = nam::NeuralMaterial::load(&path)?;
                material.check_model(&model)?;
                Ok(material)
            })
            .map_err(py_err)?;
        Ok(Self {
            inner: Arc::new(material),
            model,
        })
    }

    /// Writes a `.nam` file: f16 params (half the size; relights within a log-L1 of ~1e-5),
    /// or exact f32 ones with `exact=True`.
    #[pyo3(signature = (path, exact = false))]
    fn save(&self, py: Python<'_>, path: PathBuf, exact: bool) -> PyResult<()> {
        let m = &self.inner;
        py.detach(|| {
            if exact {
                m.save_exact(&path)
            } else {
                m.save(&path)
            }
        })
        .map_err(py_err)
    }

    /// The latent map, `H×W×64` float32: a read-only view of the material's memory.
    #[getter]
    fn params<'py>(slf: &Bound<'py, Self>) -> PyResult<Bound<'py, PyArray3<f32>>> {
        let p = slf.get().inner.params();
        let view = ndarray::ArrayView3::from_shape((p.height, p.width, p.channels), &p.data)
            .map_err(|e| PyValueError::new_err(e.to_string()))?;
        // SAFETY: the map lives in an `Arc` this object owns and never mutates (the class is
        // frozen); the array keeps this object alive as its base.
        let array = unsafe { PyArray3::borrow_from_array(&view, slf.clone().into_any()) };
        array.readwrite().make_nonwriteable();
        Ok(array)
    }

    /// `(height, width)` in pixels.
    #[getter]
    fn shape(&self) -> (usize, usize) {
        self.inner.size()
    }

    /// The model this material belongs to.
    #[getter]
    fn model(&self) -> Model {
        Model {
            inner: Arc::clone(&self.model),
        }
    }

    /// `f_r · cos θi` (RGB, `N×3`) for `N` queries: `uv` `N×2`, `wi` (towards the light) and
    /// `wo` (towards the viewer) `N×3`, local frame; 0 where either is below the horizon.
    fn eval<'py>(
        &self,
        py: Python<'py>,
        uv: &Bound<'py, PyAny>,
        wi: &Bound<'py, PyAny>,
        wo: &Bound<'py, PyAny>,
    ) -> PyResult<Bound<'py, PyArray2<f32>>> {
        self.rgb_per_query(py, (uv, wi, wo), |b, q| b.eval(q))
    }

    /// `f_r` alone (RGB, `N×3`): [`eval`](Self::eval) divided by `cos θi`.
    fn eval_fr<'py>(
        &self,
        py: Python<'py>,
        uv: &Bound<'py, PyAny>,
        wi: &Bound<'py, PyAny>,
        wo: &Bound<'py, PyAny>,
    ) -> PyResult<Bound<'py, PyArray2<f32>>> {
        self.rgb_per_query(py, (uv, wi, wo), |b, q| b.eval_fr(q))
    }

    /// Samples `wi` with cosine-weighted hemisphere sampling for `N` rows of `uv` (`N×2`),
    /// `wo` (`N×3`) and random numbers `u` in [0, 1)² (`N×2`). Returns `(wi N×3,
    /// weight N×3 = f_r·cos θi / pdf, pdf N)`; rows with `wo` below the horizon are all zero.
    #[allow(clippy::type_complexity)]
    fn sample<'py>(
        &self,
        py: Python<'py>,
        uv: &Bound<'py, PyAny>,
        wo: &Bound<'py, PyAny>,
        u: &Bound<'py, PyAny>,
    ) -> PyResult<(
        Bound<'py, PyArray2<f32>>,
        Bound<'py, PyArray2<f32>>,
        Bound<'py, PyArray1<f32>>,
    )> {
        let (uv, wo, u) = (
            rows::<2>("uv", uv)?,
            rows::<3>("wo", wo)?,
            rows::<2>("u", u)?,
        );
        same_rows(&[("uv", uv.len()), ("wo", wo.len()), ("u", u.len())])?;
        let requests: Vec<(Vec2, Vec3, Vec2)> = uv
            .iter()
            .zip(&wo)
            .zip(&u)
            .map(|((uv, wo), u)| {
                (
                    Vec2::from_array(*uv),
                    Vec3::from_array(*wo),
                    Vec2::from_array(*u),
                )
            })
            .collect();
        let samples = self.brdf(py, |b| b.sample(&requests))?;
        let (mut wi, mut weight, mut pdf) = (Vec::new(), Vec::new(), Vec::new());
        for s in samples {
            let s = s.unwrap_or(nam::BrdfSample {
                wi: Vec3::ZERO,
                weight: Vec3::ZERO,
                pdf: 0.0,
            });
            wi.push(s.wi.to_array());
            weight.push(s.weight.to_array());
            pdf.push(s.pdf);
        }
        Ok((out_rows(py, wi), out_rows(py, weight), out_values(py, pdf)))
    }

    /// The solid-angle pdf (`N`) with which [`sample`](Self::sample) picks `wi` given `wo`;
    /// 0 below the horizon. `uv` is accepted for the renderer interface (the sampling does not
    /// depend on the texel).
    fn pdf<'py>(
        &self,
        py: Python<'py>,
        uv: &Bound<'py, PyAny>,
        wi: &Bound<'py, PyAny>,
        wo: &Bound<'py, PyAny>,
    ) -> PyResult<Bound<'py, PyArray1<f32>>> {
        let (_, wi, wo) = batch(uv, wi, wo)?;
        let v = self.brdf(py, |b| {
            Ok(wi
                .iter()
                .zip(&wo)
                .map(|(wi, wo)| b.pdf(Vec3::from_array(*wo), Vec3::from_array(*wi)))
                .collect())
        })?;
        Ok(out_values(py, v))
    }

    fn __repr__(&self) -> String {
        let (h, w) = self.inner.size();
        format!("nam.Material({h}×{w}×{})", self.inner.params().channels)
    }
}

/// Renders `material` under one light and viewer: linear radiance `H×W×3` float32,
/// `R = π·f_r·cos θi` times `intensity` (and the inverse-square falloff `d²/|light − p|²` with
/// `falloff`). Positions are in the surface frame in material half-widths: the material spans
/// [−1, 1]² at z = 0, the capture camera sat at (0, 0, 4.01) for 28°. `directional=True`
/// makes `light` a direction towards the light, `orthographic=True` makes `view` a direction
/// towards the viewer.
#[pyfunction]
#[pyo3(signature = (model, material, light, view, directional = false, orthographic = false, intensity = 1.0, falloff = false))]
#[allow(clippy::too_many_arguments)]
fn relight<'py>(
    py: Python<'py>,
    model: &Model,
    material: &Material,
    light: [f64; 3],
    view: [f64; 3],
    directional: bool,
    orthographic: bool,
    intensity: f64,
    falloff: bool,
) -> PyResult<Bound<'py, PyArray3<f32>>> {
    let (l, v) = (DVec3::from_array(light), DVec3::from_array(view));
    let scene = Scene {
        light: if directional {
            Light::Directional(l)
        } else {
            Light::Point(l)
        },
        view: if orthographic {
            View::Orthographic(v)
        } else {
            View::Point(v)
        },
        intensity,
        falloff,
    };
    let (m, mat) = (&model.inner, &material.inner);
    let img = py.detach(|| nam::relight(m, mat, &scene)).map_err(py_err)?;
    let (h, w) = (img.height(), img.width());
    Ok(out_image(py, h, w, img.into_vec()))
}

/// The extension module.
#[pymodule]
fn _nam(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<Model>()?;
    m.add_class::<Material>()?;
    m.add_function(wrap_pyfunction!(relight, m)?)?;
    m.add("CAPTURE_FOV_DEG", CAPTURE_FOV_DEG)?;
    Ok(())
}
