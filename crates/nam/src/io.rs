//! File I/O shared by the model, material and CLI: whole-file reads with the path in the
//! error, and atomic writes.

use crate::error::{NamError, Result};
use std::io::Write;
use std::path::Path;

/// Reads the whole file at `path`; an error names the path.
pub(crate) fn read(path: &Path) -> Result<Vec<u8>> {
    std::fs::read(path).map_err(|error| NamError::Io {
        path: path.to_path_buf(),
        error,
    })
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
