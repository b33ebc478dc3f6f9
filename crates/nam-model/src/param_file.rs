//! The `.nam` param-map file (docs/FORMAT.md): safetensors with one tensor
//! `params` `[H, W, C]` (F16 by default, F32 on request or when a value exceeds f16's range)
//! and a `config` JSON in `__metadata__`.

use std::collections::BTreeMap;

use nam_weights::{
    StoreAs, Tensor, TensorFile, TensorView, write_safetensors_as, write_safetensors_to,
};

use crate::error::{ModelError, Result};
use crate::maps::ParamMap;

/// The name of the one tensor in a `.nam` file.
const PARAMS_TENSOR: &str = "params";

impl ParamMap {
    /// Serialises as a `.nam` file with F16 params (half the size of F32; relighting from
    /// them differs by a log-L1 of ~1e-5, see docs/FORMAT.md), or F32 when a value lies beyond
    /// f16's ±65504 ([`Self::nam_dtype`]); `model_sha256` identifies the weights that made it.
    pub fn to_nam_bytes(&self, model_sha256: &str) -> Result<Vec<u8>> {
        self.to_nam_bytes_as(model_sha256, self.nam_dtype())
    }

    /// The dtype [`Self::to_nam_bytes`] stores: F16 when every value fits it, else F32.
    pub fn nam_dtype(&self) -> StoreAs {
        let fits_f16 = self.data.iter().all(|v| v.abs() <= StoreAs::F16.largest());
        if fits_f16 { StoreAs::F16 } else { StoreAs::F32 }
    }

    /// [`Self::to_nam_bytes`] with the params stored as `dtype` (F16 only when every value
    /// fits: an out-of-range value is an error rather than ±Inf). A map whose `data` is not
    /// `height · width · channels` values is an error.
    pub fn to_nam_bytes_as(&self, model_sha256: &str, dtype: StoreAs) -> Result<Vec<u8>> {
        let (meta, shape) = self.nam_header(model_sha256, dtype)?;
        let params = Tensor::new(shape, self.data.clone()).expect("checked by nam_header");
        let tensors = BTreeMap::from([(PARAMS_TENSOR.to_string(), params)]);
        Ok(write_safetensors_as(&tensors, &meta, dtype)?)
    }

    /// [`Self::to_nam_bytes_as`] streamed into `out` (the same bytes): no copy of the params
    /// and no buffer of the file.
    pub fn write_nam(
        &self,
        out: &mut impl std::io::Write,
        model_sha256: &str,
        dtype: StoreAs,
    ) -> Result<()> {
        let (meta, shape) = self.nam_header(model_sha256, dtype)?;
        let params = TensorView::new(&shape, &self.data).expect("checked by nam_header");
        let tensors = BTreeMap::from([(PARAMS_TENSOR.to_string(), params)]);
        Ok(write_safetensors_to(out, &tensors, &meta, dtype)?)
    }

    /// The `.nam` metadata and the params' shape, after checking that `data` has that shape
    /// and that every value fits `dtype`.
    fn nam_header(
        &self,
        model_sha256: &str,
        dtype: StoreAs,
    ) -> Result<(BTreeMap<String, String>, Vec<usize>)> {
        let shape = vec![self.height, self.width, self.channels];
        if TensorView::new(&shape, &self.data).is_none() {
            return Err(ModelError::Size {
                what: "ParamMap data (height · width · channels)",
                expected: self
                    .height
                    .saturating_mul(self.width)
                    .saturating_mul(self.channels),
                found: self.data.len(),
            });
        }
        if let Some(i) = self.data.iter().position(|v| v.abs() > dtype.largest()) {
            return Err(ModelError::ParamFile {
                file: "(new .nam)".into(),
                reason: format!(
                    "param {} at flat index {i} does not fit {dtype:?} (±{})",
                    self.data[i],
                    dtype.largest()
                ),
            });
        }
        let config = serde_json::json!({
            "format": "nam-params", "version": 1,
            "height": self.height, "width": self.width, "model_sha256": model_sha256,
        });
        let meta = BTreeMap::from([("config".to_string(), config.to_string())]);
        Ok((meta, shape))
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
            .get(PARAMS_TENSOR)
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
