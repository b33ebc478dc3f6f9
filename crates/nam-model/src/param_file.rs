//! The `.nam` param-map file (docs/FORMAT.md): safetensors with one tensor
//! `params` `[H, W, C]` F32 and a `config` JSON in `__metadata__`.

use std::collections::BTreeMap;

use nam_weights::{Tensor, TensorFile, write_safetensors};

use crate::error::{ModelError, Result};
use crate::maps::ParamMap;

impl ParamMap {
    /// Serialises as a `.nam` file; `model_sha256` identifies the weights that made it.
    /// A map whose `data` is not `height · width · channels` values is an error.
    pub fn to_nam_bytes(&self, model_sha256: &str) -> Result<Vec<u8>> {
        let config = serde_json::json!({
            "format": "nam-params", "version": 1,
            "height": self.height, "width": self.width, "model_sha256": model_sha256,
        });
        let meta = BTreeMap::from([("config".to_string(), config.to_string())]);
        let shape = vec![self.height, self.width, self.channels];
        let params = Tensor::new(shape, self.data.clone()).ok_or(ModelError::Size {
            what: "ParamMap data (height · width · channels)",
            expected: self
                .height
                .saturating_mul(self.width)
                .saturating_mul(self.channels),
            found: self.data.len(),
        })?;
        let tensors = BTreeMap::from([("params".to_string(), params)]);
        Ok(write_safetensors(&tensors, &meta)?)
    }

    /// Parses a `.nam` file; `label` names it in errors. Returns the map and the
    /// recorded `model_sha256`.
    pub fn from_nam_bytes(bytes: &[u8], label: &str) -> Result<(Self, String)> {
        Self::from_tensor_file(TensorFile::from_bytes(bytes, label)?)
    }

    fn from_tensor_file(f: TensorFile) -> Result<(Self, String)> {
        let bad = |reason: String| ModelError::ParamFile {
            file: f.label().to_string(),
            reason,
        };
        let cfg: serde_json::Value = f
            .metadata()
            .get("config")
            .ok_or_else(|| bad("__metadata__ has no \"config\"".into()))
            .and_then(|s| {
                serde_json::from_str(s).map_err(|e| bad(format!("config is not JSON: {e}")))
            })?;
        if cfg["format"] != "nam-params" || cfg["version"] != 1 {
            return Err(bad(format!("not a nam-params v1 file: {}", cfg["format"])));
        }
        let dim = |k: &str| {
            cfg[k]
                .as_u64()
                .and_then(|v| usize::try_from(v).ok())
                .ok_or_else(|| bad(format!("config.{k} is not a size")))
        };
        let (h, w) = (dim("height")?, dim("width")?);
        let t = f
            .tensors()
            .get("params")
            .ok_or_else(|| bad("no tensor `params`".into()))?;
        let shape = t.shape();
        if shape.len() != 3 || shape[0] != h || shape[1] != w || h == 0 || w == 0 {
            return Err(bad(format!(
                "`params` has shape {shape:?}, config says {h}×{w}×C"
            )));
        }
        if f.tensors().len() != 1 {
            return Err(bad("extra tensors besides `params`".into()));
        }
        if let Some(i) = t.data().iter().position(|v| !v.is_finite()) {
            return Err(ModelError::NonFinite {
                what: "params",
                index: i,
            });
        }
        let sha = cfg["model_sha256"].as_str().unwrap_or_default().to_string();
        Ok((
            Self {
                height: h,
                width: w,
                channels: shape[2],
                data: t.data().to_vec(),
            },
            sha,
        ))
    }
}
