//! One take per output folder: [`TakeDir::claim`] locks the folder against a second
//! concurrent run and refuses a folder that already holds files, unless asked to overwrite,
//! which first removes the previous take's files. Old and new frames can then never sit
//! side by side (a re-run with fewer frames, a killed re-run), and two runs cannot
//! interleave their files.
//!
//! The lock is an advisory exclusive lock ([`std::fs::File::try_lock`], `flock` on Linux)
//! on `.helmcap.lock` in the folder, held for the life of the [`TakeDir`]. The system
//! releases it when the process ends in any way (also SIGKILL), so no stale lock is left;
//! the lock file itself stays and does not count as content.
//!
//! What `--overwrite` removes ([`is_take_file`]): the files a take writes at the top of
//! the folder (`*.csv`, `*.json`, `*.usda`, `*.usd`, `*.c3d`, `*.rrd`, `*.obj`, `*.ply`),
//! the mesh sequence in `mesh/` (`frame_*.obj`, `frame_*.ply`; the folder too once empty),
//! and hidden temporaries of interrupted writes (`.*.partial`, `.*.tmp`). Anything else
//! is left in place and named in a warning.

use std::fs::{File, OpenOptions, TryLockError};
use std::path::{Path, PathBuf};

/// Name of the lock file inside a take folder.
pub const LOCK_FILE: &str = ".helmcap.lock";

/// Errors of [`TakeDir::claim`].
#[derive(Debug, thiserror::Error)]
pub enum TakeDirError {
    /// The folder already holds files and overwriting was not asked for.
    #[error(
        "{dir} already holds a take ({entries}); pass --overwrite to replace it, or choose an empty folder"
    )]
    NotEmpty {
        /// The folder.
        dir: PathBuf,
        /// A few of its entries, for the message.
        entries: String,
    },
    /// Another run holds the folder's lock.
    #[error("{dir} is in use by another helmcap run (its lock {LOCK_FILE} is held)")]
    Locked {
        /// The folder.
        dir: PathBuf,
    },
    /// A file operation failed.
    #[error("{path}: {source}")]
    Io {
        /// The file or folder.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
}

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> TakeDirError + '_ {
    move |source| TakeDirError::Io {
        path: path.to_path_buf(),
        source,
    }
}

/// A claimed output folder (see the module docs); the lock is held until it is dropped.
#[derive(Debug)]
pub struct TakeDir {
    dir: PathBuf,
    /// Holds the lock (released when the file is closed).
    _lock: File,
    removed: usize,
}

impl TakeDir {
    /// Creates `dir` if needed, locks it, and checks that it holds no take: with
    /// `overwrite`, the previous take's files are removed first (see the module docs),
    /// else a non-empty folder is refused.
    ///
    /// # Errors
    /// [`TakeDirError::Locked`] when another run holds the folder,
    /// [`TakeDirError::NotEmpty`] for a folder with files (without `overwrite`),
    /// [`TakeDirError::Io`] when the folder cannot be created, read or cleared.
    pub fn claim(dir: &Path, overwrite: bool) -> Result<Self, TakeDirError> {
        std::fs::create_dir_all(dir).map_err(io(dir))?;
        let lock_path = dir.join(LOCK_FILE);
        let lock = OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(false)
            .open(&lock_path)
            .map_err(io(&lock_path))?;
        match lock.try_lock() {
            Ok(()) => {}
            Err(TryLockError::WouldBlock) => {
                return Err(TakeDirError::Locked {
                    dir: dir.to_path_buf(),
                });
            }
            Err(TryLockError::Error(e)) => return Err(io(&lock_path)(e)),
        }
        let entries = content(dir)?;
        let mut removed = 0;
        if !entries.is_empty() {
            if !overwrite {
                let mut names: Vec<String> = entries
                    .iter()
                    .take(3)
                    .map(|p| {
                        p.file_name()
                            .map(|n| n.to_string_lossy().into_owned())
                            .unwrap_or_default()
                    })
                    .collect();
                if entries.len() > 3 {
                    names.push(format!("and {} more", entries.len() - 3));
                }
                return Err(TakeDirError::NotEmpty {
                    dir: dir.to_path_buf(),
                    entries: names.join(", "),
                });
            }
            removed = clear_take(dir)?;
        }
        Ok(Self {
            dir: dir.to_path_buf(),
            _lock: lock,
            removed,
        })
    }

    /// The folder.
    pub fn path(&self) -> &Path {
        &self.dir
    }

    /// Files of a previous take removed by `overwrite`.
    pub fn removed(&self) -> usize {
        self.removed
    }
}

/// The folder's entries, the lock file left out.
fn content(dir: &Path) -> Result<Vec<PathBuf>, TakeDirError> {
    let mut out = Vec::new();
    for e in std::fs::read_dir(dir).map_err(io(dir))? {
        let e = e.map_err(io(dir))?;
        if e.file_name() != LOCK_FILE {
            out.push(e.path());
        }
    }
    out.sort();
    Ok(out)
}

/// Whether `name` (a file at the top of a take folder) is one a take writes.
pub fn is_take_file(name: &str) -> bool {
    if name.starts_with('.') {
        return name.ends_with(".partial") || name.ends_with(".tmp");
    }
    let ext = Path::new(name)
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default();
    matches!(
        ext.as_str(),
        "csv" | "json" | "usda" | "usd" | "c3d" | "rrd" | "obj" | "ply"
    )
}

/// Removes the previous take's files (see the module docs); returns how many.
fn clear_take(dir: &Path) -> Result<usize, TakeDirError> {
    let mut removed = 0;
    let mut left = Vec::new();
    for path in content(dir)? {
        let name = path
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        let meta = std::fs::symlink_metadata(&path).map_err(io(&path))?;
        if meta.is_dir() && name == "mesh" {
            for f in content(&path)? {
                let n = f
                    .file_name()
                    .map(|n| n.to_string_lossy().into_owned())
                    .unwrap_or_default();
                let frame = n.starts_with("frame_") && (n.ends_with(".obj") || n.ends_with(".ply"));
                if frame || (n.starts_with('.') && is_take_file(&n)) {
                    std::fs::remove_file(&f).map_err(io(&f))?;
                    removed += 1;
                } else {
                    left.push(f);
                }
            }
            // Only when empty: anything else in it stays.
            let _ = std::fs::remove_dir(&path);
        } else if meta.is_file() && is_take_file(&name) {
            std::fs::remove_file(&path).map_err(io(&path))?;
            removed += 1;
        } else {
            left.push(path);
        }
    }
    if !left.is_empty() {
        let names: Vec<String> = left
            .iter()
            .take(5)
            .map(|p| p.display().to_string())
            .collect();
        tracing::warn!(
            "--overwrite left {} entries that a take does not write: {}",
            left.len(),
            names.join(", ")
        );
    }
    tracing::info!(
        "--overwrite: removed {removed} files of the previous take in {}",
        dir.display()
    );
    Ok(removed)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn refuses_a_folder_with_a_take_and_clears_it_on_overwrite() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("take");
        // An empty or new folder is fine.
        drop(TakeDir::claim(&out, false).unwrap());
        std::fs::create_dir_all(out.join("mesh")).unwrap();
        for f in [
            "bundles.csv",
            "metrics.json",
            "mesh.usda",
            ".bundles.csv.7.partial",
        ] {
            std::fs::write(out.join(f), "x").unwrap();
        }
        for k in 0..3 {
            std::fs::write(out.join(format!("mesh/frame_{k:06}.obj")), "x").unwrap();
        }
        std::fs::write(out.join("notes.txt"), "keep me").unwrap();
        let e = TakeDir::claim(&out, false).unwrap_err();
        assert!(matches!(e, TakeDirError::NotEmpty { .. }), "{e}");
        assert!(e.to_string().contains("--overwrite"), "{e}");
        let t = TakeDir::claim(&out, true).unwrap();
        assert_eq!(t.removed(), 7);
        let mut left: Vec<String> = std::fs::read_dir(&out)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        left.sort();
        assert_eq!(left, [LOCK_FILE, "notes.txt"]);
    }

    #[test]
    fn a_second_claim_of_a_locked_folder_fails() {
        let dir = tempfile::tempdir().unwrap();
        let first = TakeDir::claim(dir.path(), false).unwrap();
        let e = TakeDir::claim(dir.path(), true).unwrap_err();
        assert!(matches!(e, TakeDirError::Locked { .. }), "{e}");
        drop(first);
        TakeDir::claim(dir.path(), false).unwrap();
    }
}
