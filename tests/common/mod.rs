//! What the integration tests share: running the `helmcap` binary, and finding the
//! Python tools (`scripts/setup.sh` installs them) that cross-check our files.
//!
//! Each test file compiles this module on its own and uses part of it.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// Asserts that a run succeeded; the message holds its standard output and error.
pub fn ok(out: &Output) {
    assert!(
        out.status.success(),
        "stdout:\n{}\nstderr:\n{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}

/// Runs the `helmcap` binary built with the tests.
pub fn helmcap(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_helmcap"))
        .args(args)
        .output()
        .expect("run helmcap")
}

/// Runs the `helmcap` binary with its dataset cache in `cache` (`HELMCAP_CACHE_DIR`), so
/// that tests do not share or pollute the user's cache.
pub fn helmcap_cached(args: &[&str], cache: &Path) -> Output {
    Command::new(env!("CARGO_BIN_EXE_helmcap"))
        .args(args)
        .env("HELMCAP_CACHE_DIR", cache)
        .output()
        .expect("run helmcap")
}

/// The cross-check Python (`HELMCAP_PYTHON_ENV`, else `~/.cache/helmcap-python`) when it
/// imports every module of `modules` (comma-separated, as Python's `import` takes them),
/// or why not, for the test's skip message.
pub fn python_with(modules: &str) -> Result<PathBuf, String> {
    let env = std::env::var_os("HELMCAP_PYTHON_ENV")
        .map(PathBuf::from)
        .or_else(|| std::env::var_os("HOME").map(|h| Path::new(&h).join(".cache/helmcap-python")))
        .ok_or("no HOME")?;
    let py = env.join("bin/python");
    match Command::new(&py)
        .args(["-c", &format!("import {modules}")])
        .output()
    {
        Ok(o) if o.status.success() => Ok(py),
        _ => Err(format!(
            "{} cannot import {modules} (run scripts/setup.sh)",
            py.display()
        )),
    }
}

/// Blender's Python module (`bpy` from PyPI) in its own environment
/// (`HELMCAP_BLENDER_ENV`, else `~/.cache/helmcap-blender`: `bpy` pins an older numpy than
/// the other cross-check tools), or why it is not there.
pub fn blender_python() -> Result<PathBuf, String> {
    let env = std::env::var_os("HELMCAP_BLENDER_ENV")
        .map(PathBuf::from)
        .or_else(|| std::env::var_os("HOME").map(|h| Path::new(&h).join(".cache/helmcap-blender")))
        .ok_or("no HOME")?;
    let py = env.join("bin/python");
    match Command::new(&py).args(["-c", "import bpy"]).output() {
        Ok(o) if o.status.success() => Ok(py),
        _ => Err(format!(
            "{} cannot import bpy (run scripts/setup.sh)",
            py.display()
        )),
    }
}
