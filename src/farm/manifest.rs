//! `take.json`: what a take folder holds and how it was made. Every `replay` writes it
//! last, after every other output is published, so its presence says the run finished;
//! `farm merge` reads the chunks' manifests to check that they belong together (the same
//! session, the same settings, ranges that tile the take) and to join their metrics
//! exactly ([`MetricsCollector::merge`]); `report` reads it to find the session's camera
//! images.

use std::path::{Path, PathBuf};

use crate::pipeline::MetricsCollector;

/// The manifest's format name (`format` key); a reader refuses any other.
pub const MANIFEST_FORMAT: &str = "helmcap-take-1";

/// The manifest's file name inside a take folder.
pub const MANIFEST_FILE: &str = "take.json";

/// Errors reading or writing a manifest.
#[derive(Debug, thiserror::Error)]
pub enum ManifestError {
    /// The file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// The file is not a take manifest of this format.
    #[error("{path}: not a helmcap take manifest ({message})")]
    Parse {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
}

/// One output file of the take and its size (a later change of size means the file is
/// not the one the run wrote).
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct OutputFile {
    /// Path relative to the take folder (`bundles.csv`, `mesh/frame_000012.obj`).
    pub path: String,
    /// Bytes.
    pub bytes: u64,
}

/// Everything `take.json` holds (see the module docs).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TakeManifest {
    /// [`MANIFEST_FORMAT`].
    pub format: String,
    /// helmcap version that wrote the take.
    pub helmcap: String,
    /// The take's name (the session folder's name).
    pub take: String,
    /// The session folder, as the run saw it.
    pub session: PathBuf,
    /// Fingerprint of the session's own files ([`session_fingerprint`]): the same take
    /// seen from another machine (another mount point) has the same one.
    pub session_fingerprint: String,
    /// Fingerprint of the settings that shape the outputs (dataset, layout, calibration,
    /// profile, solve settings, exports: files by content, not by path).
    pub settings_fingerprint: String,
    /// The session's first and last frame index.
    pub take_frames: (usize, usize),
    /// The frames this run was asked to write (inclusive; a chunk's range, or the whole
    /// take).
    pub frames: (usize, usize),
    /// First frame run as warm-up before `frames` (none without warm-up).
    pub warm_up_from: Option<usize>,
    /// Camera frame rate, frames per second.
    pub fps: f64,
    /// Markers of the layout, in order.
    pub markers: Vec<String>,
    /// Wall time of the run, seconds.
    pub wall_secs: f64,
    /// The output files, with their sizes.
    pub files: Vec<OutputFile>,
    /// The run's metrics collector, for merging chunks.
    pub metrics: MetricsCollector,
}

impl TakeManifest {
    /// Reads `dir/take.json`.
    ///
    /// # Errors
    /// A missing or unreadable file, JSON that is not a manifest, another format.
    pub fn read(dir: &Path) -> Result<Self, ManifestError> {
        let path = dir.join(MANIFEST_FILE);
        let text = std::fs::read_to_string(&path).map_err(|source| ManifestError::Io {
            path: path.clone(),
            source,
        })?;
        let m: TakeManifest = serde_json::from_str(&text).map_err(|e| ManifestError::Parse {
            path: path.clone(),
            message: e.to_string(),
        })?;
        if m.format != MANIFEST_FORMAT {
            return Err(ManifestError::Parse {
                path,
                message: format!("format {:?}, expected {MANIFEST_FORMAT:?}", m.format),
            });
        }
        Ok(m)
    }

    /// Writes `dir/take.json` atomically.
    ///
    /// # Errors
    /// The file cannot be written.
    pub fn write(&self, dir: &Path) -> Result<(), ManifestError> {
        let path = dir.join(MANIFEST_FILE);
        let io = |source| ManifestError::Io {
            path: path.clone(),
            source,
        };
        let text = serde_json::to_string_pretty(self).map_err(|e| io(std::io::Error::other(e)))?;
        crate::atomic_file::write_atomically(&path, |w| {
            use std::io::Write;
            w.write_all(text.as_bytes())?;
            w.write_all(b"\n")
        })
        .map_err(io)
    }

    /// Checks that every output file is there with the size the run wrote.
    ///
    /// # Errors
    /// A message naming the first missing or changed file.
    pub fn check_files(&self, dir: &Path) -> Result<(), String> {
        for f in &self.files {
            let path = dir.join(&f.path);
            match std::fs::metadata(&path) {
                Ok(m) if m.len() == f.bytes => {}
                Ok(m) => {
                    return Err(format!(
                        "{} has {} bytes, the run wrote {}",
                        path.display(),
                        m.len(),
                        f.bytes
                    ));
                }
                Err(e) => return Err(format!("{}: {e}", path.display())),
            }
        }
        Ok(())
    }
}

/// The output files in a take folder (top level, and `mesh/`), with their sizes, sorted;
/// the lock and hidden temporaries are left out, and so is the manifest itself.
///
/// # Errors
/// A folder that cannot be listed.
pub fn list_outputs(dir: &Path) -> std::io::Result<Vec<OutputFile>> {
    let mut out = Vec::new();
    for sub in ["", "mesh"] {
        let folder = dir.join(sub);
        if !folder.is_dir() {
            continue;
        }
        for entry in std::fs::read_dir(&folder)? {
            let entry = entry?;
            let name = entry.file_name().to_string_lossy().into_owned();
            let meta = entry.metadata()?;
            if !meta.is_file() || name.starts_with('.') || name == MANIFEST_FILE {
                continue;
            }
            let path = if sub.is_empty() {
                name
            } else {
                format!("{sub}/{name}")
            };
            out.push(OutputFile {
                path,
                bytes: meta.len(),
            });
        }
    }
    out.sort_by(|a, b| a.path.cmp(&b.path));
    Ok(out)
}

/// 64-bit FNV-1a: a stable fingerprint (unlike the standard library's hasher, the same on
/// every machine and compiler version), enough to tell takes and settings apart.
#[derive(Debug, Clone, Copy)]
pub struct Fingerprint(u64);

impl Default for Fingerprint {
    fn default() -> Self {
        Self(0xcbf2_9ce4_8422_2325)
    }
}

impl Fingerprint {
    /// Adds bytes, then a separator (so `("ab", "c")` and `("a", "bc")` differ).
    pub fn add(&mut self, bytes: &[u8]) -> &mut Self {
        for &b in bytes.iter().chain(&[0xff]) {
            self.0 ^= u64::from(b);
            self.0 = self.0.wrapping_mul(0x0000_0100_0000_01b3);
        }
        self
    }

    /// Adds a file's bytes (its name is not part of it).
    ///
    /// # Errors
    /// The file cannot be read.
    pub fn add_file(&mut self, path: &Path) -> std::io::Result<&mut Self> {
        let bytes = std::fs::read(path)?;
        Ok(self.add(&bytes))
    }

    /// The fingerprint as 16 hex digits.
    pub fn hex(&self) -> String {
        format!("{:016x}", self.0)
    }
}

/// Fingerprint of a session: its folder name, `session.toml` and `frames.csv` (the frame
/// list with timestamps and timecode), whichever exist. Image files are not read (a take
/// is gigabytes), so two sessions differ when their names or frame lists do.
///
/// # Errors
/// A file that exists but cannot be read.
pub fn session_fingerprint(session: &Path) -> std::io::Result<String> {
    let mut fp = Fingerprint::default();
    let name = session
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    fp.add(name.as_bytes());
    for file in ["session.toml", "frames.csv"] {
        let path = session.join(file);
        if path.is_file() {
            fp.add(file.as_bytes()).add_file(&path)?;
        }
    }
    Ok(fp.hex())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fingerprint_is_stable_and_separates_fields() {
        // FNV-1a of "" plus the separator byte, computed by hand from the definition.
        let mut a = Fingerprint::default();
        a.add(b"ab").add(b"c");
        let mut b = Fingerprint::default();
        b.add(b"a").add(b"bc");
        assert_ne!(a.hex(), b.hex());
        let mut c = Fingerprint::default();
        c.add(b"ab").add(b"c");
        assert_eq!(a.hex(), c.hex());
        // Known value: FNV-1a 64 of the single byte 0xff.
        let mut d = Fingerprint::default();
        d.add(b"");
        assert_eq!(
            d.hex(),
            format!(
                "{:016x}",
                (0xcbf2_9ce4_8422_2325u64 ^ 0xff).wrapping_mul(0x100_0000_01b3)
            )
        );
    }

    #[test]
    fn manifest_round_trips_and_refuses_other_formats() {
        let dir = std::env::temp_dir().join(format!("helmcap-manifest-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(dir.join("bundles.csv"), "frame\n").unwrap();
        let m = TakeManifest {
            format: MANIFEST_FORMAT.into(),
            helmcap: "0".into(),
            take: "t".into(),
            session: "s".into(),
            session_fingerprint: "1".into(),
            settings_fingerprint: "2".into(),
            take_frames: (0, 9),
            frames: (0, 4),
            warm_up_from: None,
            fps: 60.0,
            markers: vec!["a".into()],
            wall_secs: 1.0,
            files: list_outputs(&dir).unwrap(),
            metrics: MetricsCollector::new(1, 60.0, true),
        };
        m.write(&dir).unwrap();
        assert_eq!(TakeManifest::read(&dir).unwrap(), m);
        assert!(m.check_files(&dir).is_ok());
        std::fs::write(dir.join("bundles.csv"), "frame,marker\n").unwrap();
        assert!(m.check_files(&dir).unwrap_err().contains("bundles.csv"));
        let text = std::fs::read_to_string(dir.join(MANIFEST_FILE)).unwrap();
        std::fs::write(
            dir.join(MANIFEST_FILE),
            text.replace(MANIFEST_FORMAT, "other-1"),
        )
        .unwrap();
        assert!(TakeManifest::read(&dir).is_err());
        std::fs::remove_dir_all(&dir).ok();
    }
}
