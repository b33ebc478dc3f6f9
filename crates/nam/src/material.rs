//! [`NeuralMaterial`]: a latent parameter map and its `.nam` file (docs/FORMAT.md).

use crate::error::{NamError, Result};
use nam_model::ParamMap;
use std::io::Write;
use std::path::Path;

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

    /// Serialises to `.nam` bytes (safetensors, one tensor `params` [H, W, 64], F16: half the
    /// bytes of F32, relights within a log-L1 of ~1e-5; F32 if a value exceeds f16's range).
    pub fn to_bytes(&self) -> Result<Vec<u8>> {
        Ok(self.params.to_nam_bytes(&self.model_fingerprint)?)
    }

    /// [`Self::to_bytes`] with the params stored exactly (F32, twice the bytes): relighting
    /// the loaded material is then bit-identical to relighting this one.
    pub fn to_bytes_exact(&self) -> Result<Vec<u8>> {
        Ok(self
            .params
            .to_nam_bytes_as(&self.model_fingerprint, nam_weights::StoreAs::F32)?)
    }

    /// Parses `.nam` bytes; `label` names the source in errors.
    pub fn from_bytes(bytes: &[u8], label: &str) -> Result<Self> {
        let (map, fingerprint) = ParamMap::from_nam_bytes(bytes, label)?;
        Self::new(map, fingerprint)
    }

    /// Reads a `.nam` file.
    pub fn load(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        let bytes = crate::io::read(path, crate::io::MAX_MATERIAL_FILE_BYTES, "a .nam material")?;
        Self::from_bytes(&bytes, &path.display().to_string())
    }

    /// Writes a `.nam` file atomically (a temporary file in the same folder, then rename), so
    /// an interrupted write never leaves a half-written file under `path`.
    /// The params are streamed to the file: saving needs no copy of them, only their stored
    /// bytes (half the params' memory).
    pub fn save(&self, path: impl AsRef<Path>) -> Result<()> {
        self.write(path.as_ref(), self.params.nam_dtype())
    }

    /// [`Self::save`] with exact F32 params ([`Self::to_bytes_exact`]).
    pub fn save_exact(&self, path: impl AsRef<Path>) -> Result<()> {
        self.write(path.as_ref(), nam_weights::StoreAs::F32)
    }

    fn write(&self, path: &Path, dtype: nam_weights::StoreAs) -> Result<()> {
        crate::io::Staged::write_with(path, |file| {
            let mut out = std::io::BufWriter::new(file);
            self.params
                .write_nam(&mut out, &self.model_fingerprint, dtype)?;
            out.flush().map_err(|error| NamError::Io {
                path: path.to_path_buf(),
                error,
            })
        })?
        .commit()
    }
}
