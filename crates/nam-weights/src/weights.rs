//! Validated model weights with shape-checked, prefix-scoped access.

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

use crate::config::ModelConfig;
use crate::error::{Result, WeightsError};
use crate::layout::expected_tensors;
use crate::tensor_file::{Tensor, TensorFile, get_checked, write_safetensors};

/// A model's config and its tensors, validated against each other: every tensor
/// the architecture needs is present with the right shape, there are no extra
/// tensors, and every value is finite. Values are `f32` whatever the storage dtype.
#[derive(Debug, Clone)]
pub struct Weights {
    label: String,
    config: ModelConfig,
    tensors: BTreeMap<String, Tensor>,
}

impl Weights {
    /// Reads a model file from disk.
    pub fn from_file(path: impl AsRef<Path>) -> Result<Self> {
        Self::from_tensor_file(TensorFile::from_file(path)?)
    }

    /// Parses an in-memory model file (e.g. `include_bytes!`); `label` names it in errors.
    pub fn from_bytes(bytes: &[u8], label: &str) -> Result<Self> {
        Self::from_tensor_file(TensorFile::from_bytes(bytes, label)?)
    }

    /// Validates an already parsed file (config from `__metadata__["config"]`).
    pub fn from_tensor_file(file: TensorFile) -> Result<Self> {
        let label = file.label().to_string();
        let (metadata, tensors) = file.into_parts();
        let json = metadata.get("config").ok_or_else(|| WeightsError::Config {
            file: label.clone(),
            reason: "__metadata__ has no \"config\" entry".into(),
        })?;
        let config = ModelConfig::from_json(json).map_err(|reason| WeightsError::Config {
            file: label.clone(),
            reason,
        })?;
        Self::from_tensors(config, tensors, &label)
    }

    /// Validates tensors built in memory against `config`.
    pub fn from_tensors(
        config: ModelConfig,
        tensors: BTreeMap<String, Tensor>,
        label: &str,
    ) -> Result<Self> {
        config.check().map_err(|reason| WeightsError::Config {
            file: label.to_string(),
            reason,
        })?;
        let expected = expected_tensors(&config);
        let names: BTreeSet<&str> = expected.iter().map(|(n, _)| n.as_str()).collect();
        for (name, shape) in &expected {
            let t = tensors
                .get(name)
                .ok_or_else(|| WeightsError::MissingTensor {
                    file: label.to_string(),
                    tensor: name.clone(),
                    expected: shape.clone(),
                })?;
            if t.shape() != shape.as_slice() {
                return Err(WeightsError::ShapeMismatch {
                    file: label.to_string(),
                    tensor: name.clone(),
                    expected: shape.clone(),
                    found: t.shape().to_vec(),
                });
            }
            if let Some(index) = t.data().iter().position(|v| !v.is_finite()) {
                return Err(WeightsError::NonFinite {
                    file: label.to_string(),
                    tensor: name.clone(),
                    index,
                });
            }
        }
        if let Some((name, t)) = tensors.iter().find(|(n, _)| !names.contains(n.as_str())) {
            return Err(WeightsError::UnexpectedTensor {
                file: label.to_string(),
                tensor: name.clone(),
                found: t.shape().to_vec(),
            });
        }
        Ok(Self {
            label: label.to_string(),
            config,
            tensors,
        })
    }

    /// Deterministic random weights for `config` (benchmarks, tests), seeded.
    ///
    /// Weights are uniform with variance `1/fan_in` (activations keep their scale
    /// through the layers); folded-BN scales are `1 ± 0.1`, shifts/biases `± 0.1`.
    pub fn random(config: ModelConfig, seed: u64) -> Result<Self> {
        config.check().map_err(|reason| WeightsError::Config {
            file: "<random>".into(),
            reason,
        })?;
        let mut rng = SplitMix64(seed);
        let mut tensors = BTreeMap::new();
        for (name, shape) in expected_tensors(&config) {
            let n: usize = shape.iter().product();
            let (centre, half_range) = if name.ends_with(".scale") {
                (1.0, 0.1)
            } else if name.ends_with(".shift") || name.ends_with(".bias") {
                (0.0, 0.1)
            } else {
                let fan_in = match shape.as_slice() {
                    [_, i] => *i,
                    // Transposed conv, stride 2: each output sees in·(k/2)² taps.
                    [i, _, kh, kw] if name.contains(".up") => i * kh * kw / 4,
                    [_, i, kh, kw] => i * kh * kw,
                    _ => 1,
                };
                (0.0, (3.0 / fan_in.max(1) as f64).sqrt())
            };
            let data = (0..n)
                .map(|_| (centre + half_range * rng.uniform_pm1()) as f32)
                .collect();
            if let Some(t) = Tensor::new(shape, data) {
                tensors.insert(name, t);
            }
        }
        Self::from_tensors(config, tensors, "<random>")
    }

    /// The source label (path or caller-given name).
    pub fn label(&self) -> &str {
        &self.label
    }

    /// The validated architecture.
    pub fn config(&self) -> &ModelConfig {
        &self.config
    }

    /// All tensors by full name.
    pub fn tensors(&self) -> &BTreeMap<String, Tensor> {
        &self.tensors
    }

    /// Row-major `f32` data of `name`, checking the shape is exactly `shape`.
    pub fn get(&self, name: &str, shape: &[usize]) -> Result<&[f32]> {
        get_checked(&self.tensors, &self.label, name, shape)
    }

    /// A view that prefixes names with `prefix.` (e.g. `w.scope("est.enc1.0")`).
    pub fn scope(&self, prefix: &str) -> Scope<'_> {
        Scope {
            weights: self,
            prefix: prefix.to_string(),
        }
    }

    /// Serialises as an F32 model file with the config in `__metadata__`.
    pub fn to_safetensors_bytes(&self) -> Result<Vec<u8>> {
        let mut meta = BTreeMap::new();
        meta.insert("config".to_string(), self.config.to_json());
        write_safetensors(&self.tensors, &meta)
    }
}

/// A prefix-scoped view of [`Weights`]: `scope.get("ha1.gate.weight", shape)`
/// looks up `"{prefix}.ha1.gate.weight"`.
#[derive(Debug, Clone)]
pub struct Scope<'a> {
    weights: &'a Weights,
    prefix: String,
}

impl<'a> Scope<'a> {
    /// Shape-checked data of `{prefix}.{name}`.
    pub fn get(&self, name: &str, shape: &[usize]) -> Result<&'a [f32]> {
        self.weights.get(&self.full_name(name), shape)
    }

    /// A nested scope `{prefix}.{sub}`.
    pub fn scope(&self, sub: &str) -> Scope<'a> {
        Scope {
            weights: self.weights,
            prefix: self.full_name(sub),
        }
    }

    /// The prefix of this scope (no trailing dot).
    pub fn prefix(&self) -> &str {
        &self.prefix
    }

    /// The config of the underlying weights.
    pub fn config(&self) -> &'a ModelConfig {
        &self.weights.config
    }

    fn full_name(&self, name: &str) -> String {
        if self.prefix.is_empty() {
            name.to_string()
        } else {
            format!("{}.{name}", self.prefix)
        }
    }
}

/// SplitMix64 (Steele, Lea & Flood 2014): a tiny, seedable stream for test weights, the fuzz
/// corpora of the workspace's tests and the evaluation's light/view pairs (nam-ggx's
/// `ProtocolSampler`, which `train_py/protocols.py` repeats bit for bit); not for
/// cryptography. The field is the state; seed it directly. Written out rather than taken from
/// `rand`, whose value conversions are not stable across versions.
#[derive(Debug, Clone)]
pub struct SplitMix64(pub u64);

impl SplitMix64 {
    /// The next 64 random bits.
    #[allow(clippy::should_implement_trait)] // not an iterator: the stream never ends
    pub fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// An index below `n` (0 when `n` is 0), by modulo (its bias does not matter here).
    pub fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }

    /// A uniformly chosen element of a non-empty slice.
    pub fn pick<'a, T>(&mut self, xs: &'a [T]) -> &'a T {
        &xs[self.below(xs.len())]
    }

    /// Uniform on [0, 1): the top 53 bits times 2⁻⁵³.
    pub fn uniform(&mut self) -> f64 {
        (self.next() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }

    /// Uniform in [-1, 1).
    fn uniform_pm1(&mut self) -> f64 {
        (self.next() >> 11) as f64 * (2.0 / (1u64 << 53) as f64) - 1.0
    }
}
