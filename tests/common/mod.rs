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

/// The nice level in a `/proc` `stat` file (of a process or a thread).
#[cfg(target_os = "linux")]
fn nice_level(stat: &Path) -> Option<i32> {
    let stat = std::fs::read_to_string(stat).ok()?;
    // Fields after the name's closing parenthesis start at the state (field 3); the nice
    // level is field 19.
    stat.rsplit_once(')')?
        .1
        .split_whitespace()
        .nth(16)?
        .parse()
        .ok()
}

/// The nice level of each thread of process `pid`, by thread name, from `/proc`.
#[cfg(target_os = "linux")]
fn thread_nice_levels(pid: u32) -> Vec<(String, i32)> {
    let Ok(tasks) = std::fs::read_dir(format!("/proc/{pid}/task")) else {
        return Vec::new();
    };
    tasks
        .flatten()
        .filter_map(|task| {
            let name = std::fs::read_to_string(task.path().join("comm")).ok()?;
            Some((
                name.trim().to_string(),
                nice_level(&task.path().join("stat"))?,
            ))
        })
        .collect()
}

/// The nice level of this test process (its main thread).
#[cfg(target_os = "linux")]
pub fn own_nice_level() -> i32 {
    nice_level(Path::new("/proc/self/stat")).expect("the test process's nice level")
}

/// Samples the nice level of every thread of `child` (every millisecond) until it exits:
/// per thread name the lowest priority (highest nice level) seen, since a thread may
/// lower its own priority as it starts; and the child's output.
#[cfg(target_os = "linux")]
pub fn thread_nice_levels_until_exit(
    mut child: std::process::Child,
) -> (std::collections::HashMap<String, i32>, Output) {
    let mut seen = std::collections::HashMap::new();
    while child.try_wait().expect("child status").is_none() {
        for (name, nice) in thread_nice_levels(child.id()) {
            let level = seen.entry(name).or_insert(nice);
            *level = (*level).max(nice);
        }
        std::thread::sleep(std::time::Duration::from_millis(1));
    }
    (seen, child.wait_with_output().expect("child output"))
}
