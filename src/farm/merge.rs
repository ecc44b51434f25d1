//! Joins the chunks of a take (each a `replay --frames A..B --warm-up N` folder with its
//! `take.json`) into the take folder a single `replay` writes: the CSV files row for row,
//! `metrics.json` from the chunks' collectors added together (exact counts and latency
//! histograms, not averages of summaries), `bundles.c3d` and `mesh.usda` joined by frame
//! data, the mesh sequence in `mesh/`, and a `take.json` for the whole take.
//!
//! Nothing partial is published: every check runs before anything is written, the take
//! is assembled in a hidden sibling folder, and that folder is renamed into place. A
//! chunk without `take.json` (a run that did not finish), a file of a different size
//! than its run wrote, chunks of another session or other settings, missing frames
//! between chunks, or chunks that overlap are refused with a message naming the chunk.

use std::io::{BufRead, Write};
use std::path::{Path, PathBuf};
use std::time::Instant;

use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion};

use super::manifest::{MANIFEST_FORMAT, ManifestError, TakeManifest, list_outputs};
use crate::pipeline::MetricsCollector;
use crate::sink::{C3dPart, join_c3d, join_layers};

/// Errors of [`merge_chunks`].
#[derive(Debug, thiserror::Error)]
pub enum MergeError {
    /// A chunk cannot be used (unfinished, changed, of another take or settings).
    #[error("chunk {chunk}: {message}")]
    Chunk {
        /// The chunk folder.
        chunk: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// The chunks together do not make the take (frames missing, overlaps).
    #[error("{0}")]
    Tiling(String),
    /// The output exists and overwriting was not asked for.
    #[error("{0} already exists; pass --overwrite to replace it")]
    Exists(PathBuf),
    /// Writing the merged take failed (nothing was published).
    #[error("writing the merged take: {0}")]
    Write(String),
}

/// What a merge did.
#[derive(Debug, Clone, PartialEq)]
pub struct MergeSummary {
    /// The take's name.
    pub take: String,
    /// Chunks joined.
    pub chunks: usize,
    /// Frames written (out of the take's frames).
    pub frames_out: u64,
    /// Files in the merged take.
    pub files: usize,
    /// Wall time of the merge, seconds.
    pub secs: f64,
}

/// The chunk folders under `dir`: its sub-folders (`chunks/<take>/<start>`), or `dir`
/// itself when it is a chunk.
///
/// # Errors
/// A folder that cannot be listed, or one without chunks.
pub fn find_chunks(dir: &Path) -> Result<Vec<PathBuf>, MergeError> {
    if dir.join(super::manifest::MANIFEST_FILE).is_file() {
        return Ok(vec![dir.to_path_buf()]);
    }
    let entries = std::fs::read_dir(dir).map_err(|e| MergeError::Chunk {
        chunk: dir.to_path_buf(),
        message: e.to_string(),
    })?;
    let mut chunks: Vec<PathBuf> = entries
        .filter_map(Result::ok)
        .map(|e| e.path())
        .filter(|p| {
            p.is_dir()
                && !p
                    .file_name()
                    .is_some_and(|n| n.to_string_lossy().starts_with('.'))
        })
        .collect();
    chunks.sort();
    if chunks.is_empty() {
        return Err(MergeError::Tiling(format!(
            "{} holds no chunk folders",
            dir.display()
        )));
    }
    Ok(chunks)
}

/// Joins `chunks` (folders, in any order) into the take folder `out` (see the module
/// docs); with `overwrite` an existing `out` is replaced, else refused.
///
/// # Errors
/// [`MergeError`]; `out` is then untouched.
pub fn merge_chunks(
    chunks: &[PathBuf],
    out: &Path,
    overwrite: bool,
) -> Result<MergeSummary, MergeError> {
    let started = Instant::now();
    if out.exists() && !overwrite {
        return Err(MergeError::Exists(out.to_path_buf()));
    }
    let mut parts = read_chunks(chunks)?;
    parts.sort_by_key(|(_, m)| m.frames.0);
    check_tiling(&parts)?;
    let name = out
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .ok_or_else(|| MergeError::Write(format!("{} names no folder", out.display())))?;
    let parent = match out.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    std::fs::create_dir_all(&parent)
        .map_err(|e| MergeError::Write(format!("{}: {e}", parent.display())))?;
    let staging = parent.join(format!(".{name}.merging-{}", std::process::id()));
    if staging.exists() {
        std::fs::remove_dir_all(&staging)
            .map_err(|e| MergeError::Write(format!("{}: {e}", staging.display())))?;
    }
    let built = std::fs::create_dir(&staging)
        .map_err(|e| MergeError::Write(format!("{}: {e}", staging.display())))
        .and_then(|()| build(&parts, &staging, started));
    let summary = match built {
        Ok(s) => s,
        Err(e) => {
            let _ = std::fs::remove_dir_all(&staging);
            return Err(e);
        }
    };
    publish(&staging, out).inspect_err(|_| {
        let _ = std::fs::remove_dir_all(&staging);
    })?;
    Ok(MergeSummary {
        secs: started.elapsed().as_secs_f64(),
        ..summary
    })
}

/// Each chunk's manifest, checked against its files.
fn read_chunks(chunks: &[PathBuf]) -> Result<Vec<(PathBuf, TakeManifest)>, MergeError> {
    if chunks.is_empty() {
        return Err(MergeError::Tiling("no chunks to merge".into()));
    }
    chunks
        .iter()
        .map(|dir| {
            let err = |message: String| MergeError::Chunk {
                chunk: dir.clone(),
                message,
            };
            let m = TakeManifest::read(dir).map_err(|e| match e {
                ManifestError::Io { source, .. }
                    if source.kind() == std::io::ErrorKind::NotFound =>
                {
                    err(
                        "no take.json: its run did not finish (killed, failed, still running)"
                            .into(),
                    )
                }
                other => err(other.to_string()),
            })?;
            m.check_files(dir).map_err(err)?;
            if m.metrics.frame_range().is_none() {
                return Err(err("its run wrote no frame".into()));
            }
            Ok((dir.clone(), m))
        })
        .collect()
}

/// Checks that the chunks (sorted by first frame) are of one take and settings, and tile
/// its frames without gap or overlap.
fn check_tiling(parts: &[(PathBuf, TakeManifest)]) -> Result<(), MergeError> {
    let (first_dir, first) = &parts[0];
    for (dir, m) in parts {
        let err = |message: String| MergeError::Chunk {
            chunk: dir.clone(),
            message,
        };
        if m.session_fingerprint != first.session_fingerprint || m.take != first.take {
            return Err(err(format!(
                "it is of take {} ({}), {} is of take {} ({}): chunks of another take",
                m.take,
                m.session.display(),
                first_dir.display(),
                first.take,
                first.session.display()
            )));
        }
        if m.settings_fingerprint != first.settings_fingerprint
            || m.markers != first.markers
            || m.fps != first.fps
            || m.take_frames != first.take_frames
        {
            return Err(err(format!(
                "it ran with other settings (dataset, layout, calibration, profile, solve or \
                 exports) than {}",
                first_dir.display()
            )));
        }
        let kinds = |m: &TakeManifest| -> Vec<String> {
            let mut k: Vec<String> = m
                .files
                .iter()
                .map(|f| match f.path.strip_prefix("mesh/") {
                    Some(rest) => format!("mesh/*.{}", rest.rsplit('.').next().unwrap_or("")),
                    None => f.path.clone(),
                })
                .collect();
            k.dedup();
            k
        };
        if kinds(m) != kinds(first) {
            return Err(err(format!(
                "its outputs ({}) are not those of {} ({})",
                kinds(m).join(", "),
                first_dir.display(),
                kinds(first).join(", ")
            )));
        }
    }
    for pair in parts.windows(2) {
        let ((a_dir, a), (b_dir, b)) = (&pair[0], &pair[1]);
        if b.frames.0 <= a.frames.1 {
            return Err(MergeError::Tiling(format!(
                "chunks {} (frames {}..={}) and {} (frames {}..={}) overlap",
                a_dir.display(),
                a.frames.0,
                a.frames.1,
                b_dir.display(),
                b.frames.0,
                b.frames.1
            )));
        }
        if b.frames.0 > a.frames.1 + 1 {
            return Err(MergeError::Tiling(format!(
                "frames {}..={} are in no chunk (between {} and {}): a chunk is missing",
                a.frames.1 + 1,
                b.frames.0 - 1,
                a_dir.display(),
                b_dir.display()
            )));
        }
    }
    let (start, end) = (
        first.frames.0,
        parts.last().map_or(first.frames.1, |(_, m)| m.frames.1),
    );
    let (take_first, take_last) = first.take_frames;
    if start > take_first || end < take_last {
        return Err(MergeError::Tiling(format!(
            "the chunks cover frames {start}..={end} of take {} (frames {take_first}..={take_last}): \
             chunks are missing",
            first.take
        )));
    }
    Ok(())
}

/// Writes the merged take into `staging`.
fn build(
    parts: &[(PathBuf, TakeManifest)],
    staging: &Path,
    started: Instant,
) -> Result<MergeSummary, MergeError> {
    let w = |e: String| MergeError::Write(e);
    let first = &parts[0].1;
    let top_files: Vec<&str> = first
        .files
        .iter()
        .map(|f| f.path.as_str())
        .filter(|p| !p.starts_with("mesh/"))
        .collect();
    // Metrics first: they also say where each chunk's frames are.
    let mut collector: Option<MetricsCollector> = None;
    for (dir, m) in parts {
        match &mut collector {
            None => collector = Some(m.metrics.clone()),
            Some(c) => c.merge(&m.metrics).map_err(|e| MergeError::Chunk {
                chunk: dir.clone(),
                message: e,
            })?,
        }
    }
    let collector = collector.ok_or_else(|| w("no chunks".into()))?;
    let wall_secs: f64 = parts.iter().map(|(_, m)| m.wall_secs).sum();
    let mut metrics = collector.snapshot(wall_secs);
    for file in &top_files {
        let target = staging.join(file);
        match *file {
            "metrics.json" => {
                metrics.collector = None;
                let text = serde_json::to_string_pretty(&metrics).map_err(|e| w(e.to_string()))?;
                crate::atomic_file::write_atomically(&target, |f| {
                    f.write_all(text.as_bytes())?;
                    f.write_all(b"\n")
                })
                .map_err(|e| w(format!("{}: {e}", target.display())))?;
            }
            "bundles.c3d" => {
                let c3d: Vec<C3dPart> = parts
                    .iter()
                    .filter_map(|(dir, m)| {
                        m.metrics.frame_range().map(|(a, b)| C3dPart {
                            path: dir.join(file),
                            first_frame: a.as_usize(),
                            last_frame: b.as_usize(),
                        })
                    })
                    .collect();
                join_c3d(
                    &target,
                    &c3d,
                    first.markers.clone(),
                    first.fps,
                    collector.first_timecode().map(|(i, tc)| (i.as_usize(), tc)),
                )
                .map_err(|e| w(e.to_string()))?;
            }
            "mesh.usda" => {
                let layers: Vec<PathBuf> = parts.iter().map(|(dir, _)| dir.join(file)).collect();
                let mut poses = Vec::new();
                if top_files.contains(&"head_pose.csv") {
                    for (dir, _) in parts {
                        poses.extend(read_head_poses(&dir.join("head_pose.csv")).map_err(w)?);
                    }
                }
                join_layers(&target, &layers, &poses).map_err(|e| w(e.to_string()))?;
            }
            f if f.ends_with(".csv") => join_csv(parts, f, &target)?,
            other => {
                return Err(MergeError::Chunk {
                    chunk: parts[0].0.clone(),
                    message: format!(
                        "{other} cannot be merged (farm merge joins the CSV files, metrics.json, \
                         bundles.c3d, mesh.usda and mesh/; run `helmcap animate` on the merged \
                         take for rig outputs)"
                    ),
                });
            }
        }
    }
    let meshes: Vec<(&PathBuf, &str)> = parts
        .iter()
        .flat_map(|(dir, m)| {
            m.files
                .iter()
                .filter(|f| f.path.starts_with("mesh/"))
                .map(move |f| (dir, f.path.as_str()))
        })
        .collect();
    if !meshes.is_empty() {
        std::fs::create_dir_all(staging.join("mesh")).map_err(|e| w(e.to_string()))?;
    }
    for (dir, path) in meshes {
        let (from, to) = (dir.join(path), staging.join(path));
        if to.exists() {
            return Err(w(format!("{path} is in two chunks")));
        }
        // A hard link costs no space; another file system gets a copy.
        if std::fs::hard_link(&from, &to).is_err() {
            std::fs::copy(&from, &to).map_err(|e| w(format!("{}: {e}", from.display())))?;
        }
    }
    let files = list_outputs(staging).map_err(|e| w(e.to_string()))?;
    let manifest = TakeManifest {
        format: MANIFEST_FORMAT.into(),
        helmcap: env!("CARGO_PKG_VERSION").into(),
        take: first.take.clone(),
        session: first.session.clone(),
        session_fingerprint: first.session_fingerprint.clone(),
        settings_fingerprint: first.settings_fingerprint.clone(),
        take_frames: first.take_frames,
        frames: (
            first.frames.0,
            parts.last().map_or(first.frames.1, |(_, m)| m.frames.1),
        ),
        warm_up_from: None,
        fps: first.fps,
        markers: first.markers.clone(),
        wall_secs,
        files: files.clone(),
        metrics: collector.clone(),
    };
    manifest.write(staging).map_err(|e| w(e.to_string()))?;
    Ok(MergeSummary {
        take: first.take.clone(),
        chunks: parts.len(),
        frames_out: metrics.frames_out,
        files: files.len() + 1,
        secs: started.elapsed().as_secs_f64(),
    })
}

/// Joins one CSV file of every chunk: the header once (the same in every chunk), then
/// each chunk's rows, which must lie in its own frames.
fn join_csv(
    parts: &[(PathBuf, TakeManifest)],
    file: &str,
    target: &Path,
) -> Result<(), MergeError> {
    let mut header: Option<String> = None;
    let mut readers = Vec::with_capacity(parts.len());
    for (dir, m) in parts {
        let path = dir.join(file);
        let chunk_err = |message: String| MergeError::Chunk {
            chunk: dir.clone(),
            message,
        };
        let f = std::fs::File::open(&path).map_err(|e| chunk_err(format!("{file}: {e}")))?;
        readers.push((dir, m, path, std::io::BufReader::new(f)));
    }
    crate::atomic_file::write_atomically(target, |out| {
        for (dir, m, path, reader) in &mut readers {
            let mut lines = reader.lines();
            let head = lines.next().transpose()?.unwrap_or_default();
            match &header {
                None => {
                    writeln!(out, "{head}")?;
                    header = Some(head.clone());
                }
                Some(h) if *h != head => {
                    return Err(std::io::Error::other(format!(
                        "chunk {}: {file} has the header {head:?}, the first chunk {h:?}",
                        dir.display()
                    )));
                }
                Some(_) => {}
            }
            let frame_column = head.split(',').next() == Some("frame");
            for (n, line) in lines.enumerate() {
                let line = line?;
                if frame_column {
                    let frame = line.split(',').next().and_then(|f| f.parse::<usize>().ok());
                    if !frame.is_some_and(|f| f >= m.frames.0 && f <= m.frames.1) {
                        return Err(std::io::Error::other(format!(
                            "{} line {}: frame {:?} is outside the chunk's frames {}..={}",
                            path.display(),
                            n + 2,
                            line.split(',').next().unwrap_or(""),
                            m.frames.0,
                            m.frames.1
                        )));
                    }
                }
                writeln!(out, "{line}")?;
            }
        }
        Ok(())
    })
    .map_err(|e| MergeError::Write(format!("{file}: {e}")))
}

/// The head poses of `head_pose.csv` (`frame,qw,qx,qy,qz,tx,ty,tz,...`), in file order.
fn read_head_poses(path: &Path) -> Result<Vec<(usize, Isometry3<f64>)>, String> {
    let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
    text.lines()
        .enumerate()
        .skip(1)
        .filter(|(_, l)| !l.trim().is_empty())
        .map(|(n, line)| {
            let bad = || format!("{} line {}: not a head pose row", path.display(), n + 1);
            let mut cols = line.split(',');
            let frame = cols
                .next()
                .and_then(|f| f.parse::<usize>().ok())
                .ok_or_else(bad)?;
            let v: Vec<f64> = cols
                .take(7)
                .map(|c| c.parse::<f64>().map_err(|_| bad()))
                .collect::<Result<_, _>>()?;
            if v.len() != 7 {
                return Err(bad());
            }
            // The sink wrote the unit quaternion exactly (shortest round-trip decimals).
            let rotation = UnitQuaternion::new_unchecked(Quaternion::new(v[0], v[1], v[2], v[3]));
            Ok((
                frame,
                Isometry3::from_parts(Translation3::new(v[4], v[5], v[6]), rotation),
            ))
        })
        .collect()
}

/// Renames `staging` to `out`, replacing an existing `out` (moved aside first, removed
/// once the new take is in place).
fn publish(staging: &Path, out: &Path) -> Result<(), MergeError> {
    let w = |e: std::io::Error, p: &Path| MergeError::Write(format!("{}: {e}", p.display()));
    if out.exists() {
        let aside = out.with_file_name(format!(
            ".{}.replaced-{}",
            out.file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_default(),
            std::process::id()
        ));
        std::fs::rename(out, &aside).map_err(|e| w(e, out))?;
        if let Err(e) = std::fs::rename(staging, out) {
            // Put the old take back.
            let _ = std::fs::rename(&aside, out);
            return Err(w(e, out));
        }
        std::fs::remove_dir_all(&aside).map_err(|e| w(e, &aside))?;
    } else {
        std::fs::rename(staging, out).map_err(|e| w(e, out))?;
    }
    Ok(())
}
