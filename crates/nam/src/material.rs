//! [`NeuralMaterial`]: a latent parameter map and its `.nam` file (docs/FORMAT.md).

use crate::error::{NamError, Result};
use crate::model::NeuralModel;
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
        self.params.to_nam_bytes(&self.model_fingerprint)
    }

    /// Parses `.nam` bytes; `label` names the source in errors.
    pub fn from_bytes(bytes: &[u8], label: &str) -> Result<Self> {
        let (map, fingerprint) = ParamMap::from_nam_bytes(bytes, label)?;
        Self::new(map, fingerprint)
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

/// Writes `bytes` to `path` atomically: a uniquely named temporary file in the same folder is
/// filled, flushed to disk and renamed over `path`; on any error it is removed, so `path` is
/// either untouched or complete.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    let io = |error| NamError::Io {
        path: path.to_path_buf(),
        error,
    };
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    let mut tmp = tempfile::Builder::new()
        .prefix(".nam-")
        .suffix(".tmp")
        .tempfile_in(dir)
        .map_err(io)?;
    tmp.write_all(bytes)
        .and_then(|()| final_permissions(path, tmp.as_file()))
        .and_then(|perm| tmp.as_file().set_permissions(perm))
        .and_then(|()| tmp.as_file().sync_all())
        .map_err(io)?;
    tmp.persist(path).map_err(|e| io(e.error))?;
    Ok(())
}

/// The permissions a replaced file keeps, or a new file's usual `rw-r--r--` on Unix
/// (temporary files are created owner-only).
fn final_permissions(path: &Path, tmp: &std::fs::File) -> std::io::Result<std::fs::Permissions> {
    if let Ok(meta) = std::fs::metadata(path) {
        return Ok(meta.permissions());
    }
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        let _ = tmp;
        Ok(std::fs::Permissions::from_mode(0o644))
    }
    #[cfg(not(unix))]
    {
        Ok(tmp.metadata()?.permissions())
    }
}

fn short(fp: &str) -> &str {
    &fp[..fp.len().min(12)]
}
