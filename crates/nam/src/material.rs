//! [`NeuralMaterial`]: a latent parameter map and its `.nam` file (docs/FORMAT.md).

use crate::error::{NamError, Result};
use crate::model::NeuralModel;
use nam_model::ParamMap;
use nam_weights::{Tensor, TensorFile, write_safetensors};
use std::collections::BTreeMap;
use std::io::Write;
use std::path::Path;

/// Name of the single tensor of a `.nam` file.
const PARAMS_TENSOR: &str = "params";
/// `format` value in a `.nam` file's config.
const PARAMS_FORMAT: &str = "nam-params";

/// A neural material: one latent vector per pixel (`H×W×64`, HWC), estimated by one model.
#[derive(Debug, Clone, PartialEq)]
pub struct NeuralMaterial {
    params: ParamMap,
    model_fingerprint: String,
}

impl NeuralMaterial {
    /// Wraps a param map; every value must be finite.
    pub fn new(params: ParamMap, model_fingerprint: String) -> Result<Self> {
        let n = params.height * params.width * params.channels;
        if n == 0 || params.data.len() != n {
            return Err(NamError::Params(format!(
                "{}×{}×{} map holds {} values",
                params.height,
                params.width,
                params.channels,
                params.data.len()
            )));
        }
        if let Some(k) = params.data.iter().position(|v| !v.is_finite()) {
            return Err(NamError::Params(format!(
                "value {k} is not finite ({})",
                params.data[k]
            )));
        }
        Ok(Self {
            params,
            model_fingerprint,
        })
    }

    /// The latent map (HWC).
    pub fn params(&self) -> &ParamMap {
        &self.params
    }

    /// Side lengths `(height, width)` in pixels.
    pub fn size(&self) -> (usize, usize) {
        (self.params.height, self.params.width)
    }

    /// SHA-256 of the model that estimated this material.
    pub fn model_fingerprint(&self) -> &str {
        &self.model_fingerprint
    }

    /// Errors unless `model` is the model that estimated this material.
    pub fn check_model(&self, model: &NeuralModel) -> Result<()> {
        if self.params.channels != model.config().param_channels {
            return Err(NamError::Params(format!(
                "the material has {} channels per pixel, the model expects {}",
                self.params.channels,
                model.config().param_channels
            )));
        }
        if self.model_fingerprint != model.fingerprint() {
            return Err(NamError::Params(format!(
                "the material was estimated by model {}…, not by this model {}… \
                 (latent parameters only make sense to the model that produced them)",
                short(&self.model_fingerprint),
                short(model.fingerprint())
            )));
        }
        Ok(())
    }

    /// Serialises to `.nam` bytes (safetensors, one F32 tensor `params` [H, W, 64]).
    pub fn to_bytes(&self) -> Vec<u8> {
        let p = &self.params;
        let mut tensors = BTreeMap::new();
        let tensor = Tensor::new(vec![p.height, p.width, p.channels], p.data.clone())
            .expect("shape matches data: checked in NeuralMaterial::new");
        tensors.insert(PARAMS_TENSOR.to_string(), tensor);
        let config = serde_json::json!({
            "format": PARAMS_FORMAT, "version": 1, "height": p.height, "width": p.width,
            "model_sha256": self.model_fingerprint,
        })
        .to_string();
        let metadata = BTreeMap::from([("config".to_string(), config)]);
        write_safetensors(&tensors, &metadata)
    }

    /// Parses `.nam` bytes; `label` names the source in errors.
    pub fn from_bytes(bytes: &[u8], label: &str) -> Result<Self> {
        let file = TensorFile::from_bytes(bytes, label)?;
        let bad = |why: String| NamError::Params(format!("{label}: {why}"));
        let config = file
            .metadata()
            .get("config")
            .ok_or_else(|| bad("no `config` in the metadata: not a .nam file".into()))?;
        let fingerprint = parse_config(config).map_err(bad)?;
        let t = file
            .tensors()
            .get(PARAMS_TENSOR)
            .ok_or_else(|| bad("no `params` tensor".into()))?;
        let &[height, width, channels] = t.shape() else {
            return Err(bad(format!(
                "`params` has shape {:?}, expected [H, W, C]",
                t.shape()
            )));
        };
        let map = ParamMap {
            height,
            width,
            channels,
            data: t.data().to_vec(),
        };
        Self::new(map, fingerprint).map_err(|e| bad(e.to_string()))
    }

    /// Reads a `.nam` file.
    pub fn load(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        let bytes = std::fs::read(path).map_err(|error| NamError::Io {
            path: path.to_path_buf(),
            error,
        })?;
        Self::from_bytes(&bytes, &path.display().to_string())
    }

    /// Writes a `.nam` file atomically (a temporary file in the same folder, then rename), so
    /// an interrupted write never leaves a half-written file under `path`.
    pub fn save(&self, path: impl AsRef<Path>) -> Result<()> {
        write_atomic(path.as_ref(), &self.to_bytes())
    }
}

/// Writes `bytes` to `path` through a temporary sibling file and a rename.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    let io = |error| NamError::Io {
        path: path.to_path_buf(),
        error,
    };
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let tmp = dir.join(format!(".{name}.{}.tmp", std::process::id()));
    let result = (|| {
        let mut f = std::fs::File::create(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all()?;
        std::fs::rename(&tmp, path)
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result.map_err(io)
}

fn parse_config(json: &str) -> std::result::Result<String, String> {
    let v: serde_json::Value =
        serde_json::from_str(json).map_err(|e| format!("config is not JSON: {e}"))?;
    match v.get("format").and_then(|f| f.as_str()) {
        Some(PARAMS_FORMAT) => {}
        other => {
            return Err(format!(
                "config format is {other:?}, expected \"{PARAMS_FORMAT}\""
            ));
        }
    }
    v.get("model_sha256")
        .and_then(|f| f.as_str())
        .map(str::to_string)
        .ok_or_else(|| "config has no model_sha256".into())
}

fn short(fp: &str) -> &str {
    &fp[..fp.len().min(12)]
}
