//! Helpers shared by the CLI integration tests: run the real binary, check clean failures.
#![allow(dead_code)] // each test binary uses a different subset

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// The workspace root (bundled assets and fixtures live there).
pub fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// Runs `nam-cli` with `args` (XDG_RUNTIME_DIR set so wgpu stays quiet).
pub fn run(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_nam-cli"))
        .args(args)
        .env("XDG_RUNTIME_DIR", std::env::temp_dir())
        .output()
        .unwrap_or_else(|e| panic!("cannot run nam-cli: {e}"))
}

/// Its stderr as text.
pub fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// Runs a command that must succeed; returns its stdout.
pub fn ok(args: &[&str]) -> String {
    let o = run(args);
    assert!(
        o.status.success(),
        "nam-cli {args:?} failed:\n{}",
        stderr(&o)
    );
    String::from_utf8_lossy(&o.stdout).into_owned()
}

/// A path as `&str` (temp paths are UTF-8 here).
pub fn s(p: &Path) -> &str {
    p.to_str().unwrap_or_else(|| panic!("non-UTF-8 path"))
}

/// A fresh temporary folder.
pub fn tmp() -> tempfile::TempDir {
    tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"))
}

/// Runs a command that must fail: nonzero exit, `needle` in stderr, no panic, `out` not
/// created and no temporary file left in its folder.
pub fn expect_failure(args: &[&str], out: &Path, needle: &str) {
    let o = run(args);
    let err = stderr(&o);
    assert!(!o.status.success(), "should fail: {args:?}");
    assert!(err.contains(needle), "stderr lacks {needle:?}:\n{err}");
    assert!(!err.contains("panicked"), "panic: {err}");
    assert!(!out.exists(), "{} must not exist", out.display());
    let dir = out.parent().unwrap_or_else(|| Path::new("."));
    let leftovers: Vec<_> = std::fs::read_dir(dir)
        .into_iter()
        .flatten()
        .flatten()
        .filter(|e| e.file_name().to_string_lossy().contains(".tmp"))
        .collect();
    assert!(leftovers.is_empty(), "temporary files left: {leftovers:?}");
}

/// A small square photo: the bundled example photo downscaled to `side` pixels (PNG).
pub fn small_photo(dir: &Path, side: u32) -> PathBuf {
    let img = image::open(root().join("assets/example_photo.png"))
        .unwrap_or_else(|e| panic!("{e}"))
        .resize_exact(side, side, image::imageops::FilterType::Triangle);
    let path = dir.join(format!("photo{side}.png"));
    img.save(&path).unwrap_or_else(|e| panic!("{e}"));
    path
}
