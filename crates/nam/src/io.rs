//! File I/O shared by the model, material and CLI: whole-file reads with the path in the
//! error, and atomic writes.

use crate::error::{NamError, Result};
use std::io::Write;
use std::path::Path;

/// Largest model file read (bytes): a C = 64 f32 model is ~40 MB, the shipped C = 8 f16 one
/// 4 MB.
pub const MAX_MODEL_FILE_BYTES: u64 = 256 << 20;

/// Largest `.nam` file read (bytes): the f32 params of a [`crate::MAX_PHOTO_SIDE`]² material
/// (64 channels) plus a header.
pub const MAX_MATERIAL_FILE_BYTES: u64 =
    (crate::MAX_PHOTO_SIDE * crate::MAX_PHOTO_SIDE * 64 * 4) as u64 + (1 << 20);

/// Reads the whole file at `path`, refusing non-regular files and files above `max_bytes`
/// before reading ([`nam_ggx::imageio::read_bounded`]); an error names the path.
pub(crate) fn read(path: &Path, max_bytes: u64, what: &str) -> Result<Vec<u8>> {
    nam_ggx::imageio::read_bounded(path, max_bytes, what).map_err(|error| NamError::Io {
        path: path.to_path_buf(),
        error,
    })
}

/// Writes `bytes` to `path` atomically: a uniquely named temporary file in the same folder is
/// filled, flushed to disk and renamed over `path`; on any error it is removed, so `path` is
/// either untouched or complete.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    Staged::write(path, bytes)?.commit()
}

/// A file written in full next to its destination but not yet moved there: [`Staged::commit`]
/// renames it into place; dropped uncommitted, it is removed. Staging every output of a run
/// and committing them together ([`commit_all`]) means a run that fails leaves none of them.
#[derive(Debug)]
pub struct Staged {
    tmp: tempfile::TempPath,
    path: std::path::PathBuf,
}

impl Staged {
    /// Writes `bytes` to a temporary file in `path`'s folder (flushed to disk, with the
    /// permissions `path` will have).
    pub fn write(path: &Path, bytes: &[u8]) -> Result<Self> {
        Self::write_with(path, |file| {
            file.write_all(bytes).map_err(|error| NamError::Io {
                path: path.to_path_buf(),
                error,
            })
        })
    }

    /// Like [`Self::write`], with `fill` writing the whole file into the temporary one (it is
    /// flushed and given its permissions afterwards): for writers that stream.
    pub fn write_with(
        path: &Path,
        fill: impl FnOnce(&mut std::fs::File) -> Result<()>,
    ) -> Result<Self> {
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
        fill(tmp.as_file_mut())?;
        final_permissions(path, tmp.as_file())
            .and_then(|perm| tmp.as_file().set_permissions(perm))
            .and_then(|()| tmp.as_file().sync_all())
            .map_err(io)?;
        Ok(Self {
            tmp: tmp.into_temp_path(),
            path: path.to_path_buf(),
        })
    }

    /// Where it goes.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Renames the file into place.
    pub fn commit(self) -> Result<()> {
        self.tmp.persist(&self.path).map_err(|e| NamError::Io {
            path: self.path.clone(),
            error: e.error,
        })
    }
}

/// Commits every staged file in order; if one fails, the ones already moved are removed
/// again (a file they replaced is not restored) and the rest are dropped, so the outputs of
/// a failed run are all absent.
pub fn commit_all(staged: Vec<Staged>) -> Result<()> {
    let mut done: Vec<std::path::PathBuf> = Vec::with_capacity(staged.len());
    for file in staged {
        let path = file.path().to_path_buf();
        if let Err(e) = file.commit() {
            for p in &done {
                let _ = std::fs::remove_file(p);
            }
            return Err(e);
        }
        done.push(path);
    }
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
