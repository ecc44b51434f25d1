//! Binary dataset cache: a loaded [`Dataset`] written once, reloaded in a fraction of the
//! time it takes to parse its OBJ files; [`load_dataset`] loads a manifest through it.
//!
//! # Format (little-endian)
//! `b"HLMCDS02"`, the 64-bit cache key, the length of a bincode header (topology, UVs,
//! names, jaw rig), the header, then the raw `f64` positions of the neutral and of every
//! shape (`3 · #V` each). The key hashes the format version, the crate version and every
//! input file's path, size and modification time, so editing any file rebuilds the cache.

use std::io::Write;
use std::ops::RangeInclusive;
use std::path::{Path, PathBuf};

use nalgebra::{Point2, Point3};
use serde::{Deserialize, Serialize};

use super::manifest::{DatasetError, Manifest};
use super::{Dataset, JawPose, JawRig, Shape};
use crate::atomic_file::write_atomically;
use crate::mesh::Mesh;

const MAGIC: &[u8; 8] = b"HLMCDS02";

/// The folder dataset caches go to: `$HELMCAP_CACHE_DIR`, else `$XDG_CACHE_HOME/helmcap`,
/// else `~/.cache/helmcap`, else the system temporary folder.
pub fn default_cache_dir() -> PathBuf {
    if let Some(d) = std::env::var_os("HELMCAP_CACHE_DIR") {
        return PathBuf::from(d);
    }
    if let Some(d) = std::env::var_os("XDG_CACHE_HOME") {
        return PathBuf::from(d).join("helmcap");
    }
    if let Some(h) = std::env::var_os("HOME") {
        return PathBuf::from(h).join(".cache").join("helmcap");
    }
    std::env::temp_dir().join("helmcap-cache")
}

/// The cache file of `manifest` inside `dir`: named by the manifest's stem and a hash of its
/// absolute path, so two manifests with the same name do not collide.
pub fn cache_path(dir: &Path, manifest: &Manifest) -> PathBuf {
    let canon = manifest
        .path
        .canonicalize()
        .unwrap_or_else(|_| manifest.path.clone());
    let h = fnv1a(canon.to_string_lossy().as_bytes(), FNV_OFFSET);
    dir.join(format!("{}-{h:016x}.dataset.bin", manifest.name()))
}

/// The key of the manifest's current inputs; `None` when a file's metadata is unreadable
/// (then the cache is not used).
pub fn cache_key(manifest: &Manifest) -> Option<u64> {
    let mut h = fnv1a(MAGIC, FNV_OFFSET);
    h = fnv1a(env!("CARGO_PKG_VERSION").as_bytes(), h);
    for f in manifest.input_files() {
        let meta = std::fs::metadata(&f).ok()?;
        let mtime = meta
            .modified()
            .ok()?
            .duration_since(std::time::UNIX_EPOCH)
            .ok()?
            .as_nanos();
        h = fnv1a(f.to_string_lossy().as_bytes(), h);
        h = fnv1a(&meta.len().to_le_bytes(), h);
        h = fnv1a(&mtime.to_le_bytes(), h);
    }
    Some(h)
}

const FNV_OFFSET: u64 = 0xcbf2_9ce4_8422_2325;

fn fnv1a(bytes: &[u8], mut h: u64) -> u64 {
    for &b in bytes {
        h ^= u64::from(b);
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    h
}

#[derive(Serialize, Deserialize)]
struct Header {
    name: String,
    vertex_count: usize,
    uvs: Vec<Point2<f64>>,
    face_offsets: Vec<u32>,
    face_vertices: Vec<u32>,
    face_uvs: Vec<u32>,
    mtllib: Option<String>,
    materials: Vec<(u32, String)>,
    shapes: Vec<(String, Option<JawPose>)>,
    face_range: (u32, u32),
    jaw: Option<JawRig>,
}

fn corrupt(path: &Path, what: &str) -> DatasetError {
    DatasetError::Invalid {
        path: path.display().to_string(),
        message: format!("corrupt dataset cache: {what}"),
    }
}

/// Reads a cached dataset; `Ok(None)` when the file is absent or its key differs.
///
/// # Errors
/// [`DatasetError`] when the file exists with the right key but cannot be decoded.
pub fn read_cache(path: &Path, key: u64) -> Result<Option<Dataset>, DatasetError> {
    let bytes = match std::fs::read(path) {
        Ok(b) => b,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
        Err(source) => {
            return Err(DatasetError::Io {
                path: path.display().to_string(),
                source,
            });
        }
    };
    if bytes.len() < 24 || &bytes[..8] != MAGIC {
        return Ok(None);
    }
    let word = |at: usize| -> u64 {
        let mut b = [0u8; 8];
        b.copy_from_slice(&bytes[at..at + 8]);
        u64::from_le_bytes(b)
    };
    if word(8) != key {
        return Ok(None);
    }
    let header_len = usize::try_from(word(16)).map_err(|_| corrupt(path, "header length"))?;
    let body = 24usize
        .checked_add(header_len)
        .filter(|&e| e <= bytes.len())
        .ok_or_else(|| corrupt(path, "truncated header"))?;
    let header: Header =
        bincode::deserialize(&bytes[24..body]).map_err(|e| corrupt(path, &e.to_string()))?;
    let nv = header.vertex_count;
    let block = nv * 3 * 8;
    let expected = body + block * (header.shapes.len() + 1);
    if bytes.len() != expected {
        return Err(corrupt(path, "wrong size"));
    }
    let positions = |k: usize| -> Vec<Point3<f64>> {
        let start = body + k * block;
        bytes[start..start + block]
            .chunks_exact(24)
            .map(|c| {
                let f = |i: usize| {
                    let mut b = [0u8; 8];
                    b.copy_from_slice(&c[i * 8..i * 8 + 8]);
                    f64::from_le_bytes(b)
                };
                Point3::new(f(0), f(1), f(2))
            })
            .collect()
    };
    let neutral = Mesh::from_flat(
        positions(0),
        header.uvs,
        header.face_offsets,
        header.face_vertices,
        header.face_uvs,
        header.mtllib,
        header.materials,
    )?;
    let shapes = header
        .shapes
        .into_iter()
        .enumerate()
        .map(|(i, (name, jaw))| Shape {
            name,
            positions: positions(i + 1),
            jaw,
        })
        .collect();
    let face_vertices: RangeInclusive<u32> = header.face_range.0..=header.face_range.1;
    Ok(Some(Dataset {
        name: header.name,
        neutral,
        shapes,
        face_vertices,
        jaw: header.jaw,
    }))
}

/// Writes `dataset` to the cache file atomically (creating the folder).
///
/// # Errors
/// [`DatasetError::Io`] when the folder or file cannot be written.
pub fn write_cache(path: &Path, key: u64, dataset: &Dataset) -> Result<(), DatasetError> {
    let io = |source| DatasetError::Io {
        path: path.display().to_string(),
        source,
    };
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir).map_err(io)?;
    }
    let m = &dataset.neutral;
    let header = Header {
        name: dataset.name.clone(),
        vertex_count: m.vertex_count(),
        uvs: m.uvs.clone(),
        face_offsets: m.face_offsets.clone(),
        face_vertices: m.face_vertices.clone(),
        face_uvs: m.face_uvs.clone(),
        mtllib: m.mtllib.clone(),
        materials: m.materials.clone(),
        shapes: dataset
            .shapes
            .iter()
            .map(|s| (s.name.clone(), s.jaw))
            .collect(),
        face_range: (*dataset.face_vertices.start(), *dataset.face_vertices.end()),
        jaw: dataset.jaw.clone(),
    };
    let header_bytes =
        bincode::serialize(&header).map_err(|e| io(std::io::Error::other(e.to_string())))?;
    write_atomically(path, |w| {
        w.write_all(MAGIC)?;
        w.write_all(&key.to_le_bytes())?;
        w.write_all(&(header_bytes.len() as u64).to_le_bytes())?;
        w.write_all(&header_bytes)?;
        let mut buf = Vec::with_capacity(m.vertex_count() * 24);
        for block in
            std::iter::once(&m.positions).chain(dataset.shapes.iter().map(|s| &s.positions))
        {
            buf.clear();
            for p in block {
                for c in p.coords.iter() {
                    buf.extend_from_slice(&c.to_le_bytes());
                }
            }
            w.write_all(&buf)?;
        }
        Ok(())
    })
    .map_err(io)
}

/// Options for [`load_dataset`].
#[derive(Debug, Clone, Default)]
pub struct LoadOptions {
    /// Cache folder; `None` uses [`default_cache_dir`].
    pub cache_dir: Option<PathBuf>,
    /// Skip the cache entirely (neither read nor write it).
    pub no_cache: bool,
    /// Show a progress bar while reading mesh files.
    pub progress: bool,
}

/// Loads the dataset a manifest describes, from the binary cache when it is fresh.
///
/// The cache is keyed by the manifest and every file it names (path, size, modification
/// time); any change rebuilds it. A cache that cannot be read or written costs a warning,
/// never the load.
///
/// # Errors
/// As [`Manifest::read`] and [`Manifest::load`].
pub fn load_dataset(path: &Path, options: &LoadOptions) -> Result<Dataset, DatasetError> {
    let manifest = Manifest::read(path)?;
    let cache_file = (!options.no_cache).then(|| {
        let dir = options.cache_dir.clone().unwrap_or_else(default_cache_dir);
        cache_path(&dir, &manifest)
    });
    let key = cache_key(&manifest);
    if let (Some(file), Some(key)) = (&cache_file, key) {
        match read_cache(file, key) {
            Ok(Some(ds)) => {
                tracing::debug!("dataset {} from cache {}", ds.name, file.display());
                return Ok(ds);
            }
            Ok(None) => tracing::debug!("cache {} is stale or absent", file.display()),
            Err(e) => tracing::warn!("ignoring unreadable dataset cache {}: {e}", file.display()),
        }
    }
    let bar = options.progress.then(|| {
        let bar = indicatif::ProgressBar::new((manifest.shapes.len() + 1) as u64);
        bar.set_style(
            indicatif::ProgressStyle::with_template("loading {msg} [{bar:30}] {pos}/{len} files")
                .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
        );
        bar.set_message(manifest.name());
        bar
    });
    let ds = manifest.load(&|done, _| {
        if let Some(b) = &bar {
            b.set_position(done as u64);
        }
    })?;
    if let Some(b) = bar {
        b.finish_and_clear();
    }
    if let (Some(file), Some(key)) = (&cache_file, key)
        && let Err(e) = write_cache(file, key, &ds)
    {
        tracing::warn!("could not write dataset cache {}: {e}", file.display());
    }
    Ok(ds)
}
