//! One take folder, loaded and aggregated for its report page: `metrics.json` (required),
//! `take.json`, `bundles.csv`, `head_pose.csv` and `rig_weights.csv` (each optional: a
//! missing or malformed one becomes a note on the page).
//!
//! Files are read as streams, and what is kept is per frame or per time bin, so a long
//! take costs little memory; the contact sheet's images are read separately
//! ([`super::sheet`]).

use std::collections::{BTreeMap, HashMap};
use std::io::BufRead;
use std::path::{Path, PathBuf};

use super::{ReportError, ReportParams};
use crate::align::PoseSource;
use crate::pipeline::{AccuracyMetrics, Metrics};

/// Every marker's coverage over time: the share of the frames of each time bin in which
/// the marker was observed (labeled and triangulated).
#[derive(Debug, Clone, PartialEq)]
pub struct Coverage {
    /// Marker names, in the order of the rows.
    pub markers: Vec<String>,
    /// Each bin's first and last frame (inclusive), in order, covering the take.
    pub bins: Vec<(usize, usize)>,
    /// `share[marker][bin]`, 0..1.
    pub share: Vec<Vec<f32>>,
}

/// Bins the observations `(frame, marker index)` of a take whose frames run from
/// `first` to `last` (inclusive) into at most `max_bins` time bins of (nearly) equal
/// length, for `markers` markers; observations outside the range or of unknown markers
/// are ignored, and a repeated observation counts once per bin frame at most.
pub fn bin_coverage(
    first: usize,
    last: usize,
    markers: &[String],
    observations: &[(usize, usize)],
    max_bins: usize,
) -> Coverage {
    let frames = last.saturating_sub(first) + 1;
    let n = max_bins.clamp(1, frames);
    // Bin b holds frames first + ⌊b·frames/n⌋ .. first + ⌊(b+1)·frames/n⌋ − 1.
    let edge = |b: usize| first + b * frames / n;
    let bins: Vec<(usize, usize)> = (0..n).map(|b| (edge(b), edge(b + 1) - 1)).collect();
    let mut count = vec![vec![0u32; n]; markers.len()];
    let mut seen = std::collections::HashSet::new();
    for &(frame, marker) in observations {
        if frame < first || frame > last || marker >= markers.len() || !seen.insert((frame, marker))
        {
            continue;
        }
        // The last bin starting at or before `frame`: edge(b) ≤ frame ⟺
        // b·frames < (offset + 1)·n.
        let b = (((frame - first + 1) * n - 1) / frames).min(n - 1);
        count[marker][b] += 1;
    }
    let share = count
        .iter()
        .map(|row| {
            row.iter()
                .zip(&bins)
                .map(|(&c, &(a, z))| c as f32 / (z - a + 1) as f32)
                .collect()
        })
        .collect();
    Coverage {
        markers: markers.to_vec(),
        bins,
        share,
    }
}

/// A run of consecutive frames with the same head-pose source.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoseRun {
    /// First frame.
    pub first: usize,
    /// Last frame (inclusive).
    pub last: usize,
    /// Where the pose of these frames came from (`Missing`: `head_pose.csv` has no row).
    pub source: PoseSource,
}

/// What the page can say about the solve's residual.
#[derive(Debug, Clone, PartialEq)]
pub enum Residual {
    /// `rig_weights.csv`'s `residual_mm` per frame (frame, mm).
    PerFrame(Vec<(usize, f64)>),
    /// No per-frame residual, but accuracy against the session's ground truth.
    Accuracy(AccuracyMetrics),
    /// Neither.
    NotRecorded,
}

/// A take folder, loaded for its page.
#[derive(Debug, Clone)]
pub struct TakeSummary {
    /// Take name (`take.json`'s `take`, else the folder's name).
    pub name: String,
    /// The take folder.
    pub dir: PathBuf,
    /// The session folder `take.json` names (resolved; it may not exist).
    pub session: Option<PathBuf>,
    /// `metrics.json`.
    pub metrics: Metrics,
    /// First and last frame (`metrics.json`'s `frame_range`, else the CSV files').
    pub frame_range: Option<(usize, usize)>,
    /// Marker coverage over time (needs `bundles.csv`).
    pub coverage: Option<Coverage>,
    /// Mean confidence of the observed and gap-filled bundles per frame (frame, 0..1).
    pub confidence: Vec<(usize, f64)>,
    /// Each frame's timecode as `bundles.csv` has it.
    pub timecodes: BTreeMap<usize, String>,
    /// Frames that have a row in `bundles.csv` or `head_pose.csv`.
    pub frames_seen: std::collections::BTreeSet<usize>,
    /// Head-pose source over the frame range, in runs (needs `head_pose.csv`).
    pub pose: Option<Vec<PoseRun>>,
    /// The solve residual.
    pub residual: Residual,
    /// What is missing or unreadable in the folder, and what the page lacks for it.
    pub notes: Vec<String>,
}

/// `take.json`'s two keys; anything else in it is ignored.
struct TakeJson {
    take: Option<String>,
    session: Option<String>,
}

impl TakeSummary {
    /// Loads the take in `dir`.
    ///
    /// # Errors
    /// [`ReportError::NotATake`] without `metrics.json`; [`ReportError::Io`] when it
    /// cannot be read, [`ReportError::Format`] when it is not the metrics JSON. Other
    /// files only add notes.
    pub fn load(dir: &Path, params: &ReportParams) -> Result<Self, ReportError> {
        let metrics = read_metrics(dir)?;
        let mut notes = Vec::new();
        let take_json = read_take_json(dir, &mut notes);
        let name = take_json
            .as_ref()
            .and_then(|t| t.take.clone())
            .filter(|t| !t.trim().is_empty())
            .or_else(|| {
                dir.canonicalize()
                    .ok()
                    .as_deref()
                    .unwrap_or(dir)
                    .file_name()
                    .map(|n| n.to_string_lossy().into_owned())
            })
            .unwrap_or_else(|| dir.display().to_string());
        let session = take_json.and_then(|t| t.session).map(|s| {
            let p = PathBuf::from(s);
            if p.is_relative() && dir.join(&p).is_dir() {
                dir.join(p)
            } else {
                p
            }
        });

        let bundles = read_bundles(&dir.join("bundles.csv"), &mut notes);
        let poses = read_poses(&dir.join("head_pose.csv"), &mut notes);
        let mut frames_seen = std::collections::BTreeSet::new();
        if let Some(b) = &bundles {
            frames_seen.extend(b.frames.iter().copied());
        }
        if let Some(p) = &poses {
            frames_seen.extend(p.keys().copied());
        }
        let frame_range = metrics
            .frame_range
            .map(|(a, b)| (a.as_usize(), b.as_usize()))
            .or_else(|| Some((*frames_seen.first()?, *frames_seen.last()?)));

        let coverage = match (&bundles, frame_range) {
            (Some(b), Some((first, last))) if !b.markers.is_empty() => Some(bin_coverage(
                first,
                last,
                &b.markers,
                &b.observed,
                params.coverage_bins,
            )),
            _ => None,
        };
        let pose = match (&poses, frame_range) {
            (Some(p), Some((first, last))) => Some(pose_runs(first, last, p)),
            _ => None,
        };
        let residual = match read_residual(&dir.join("rig_weights.csv"), &mut notes) {
            Some(per_frame) => Residual::PerFrame(per_frame),
            None => match metrics.accuracy {
                Some(a) => Residual::Accuracy(a),
                None => Residual::NotRecorded,
            },
        };
        let (confidence, timecodes) = match bundles {
            Some(b) => (
                b.confidence
                    .into_iter()
                    .filter(|(_, (_, n))| *n > 0)
                    .map(|(f, (sum, n))| (f, sum / f64::from(n)))
                    .collect(),
                b.timecodes,
            ),
            None => (Vec::new(), BTreeMap::new()),
        };
        Ok(Self {
            name,
            dir: dir.to_path_buf(),
            session,
            metrics,
            frame_range,
            coverage,
            confidence,
            timecodes,
            frames_seen,
            pose,
            residual,
            notes,
        })
    }

    /// The number of frames in each pose state (estimated, held, none) over the frame
    /// range, from `head_pose.csv`.
    pub fn pose_counts(&self) -> Option<[usize; 3]> {
        let runs = self.pose.as_ref()?;
        let mut counts = [0; 3];
        for r in runs {
            let k = match r.source {
                PoseSource::Estimated => 0,
                PoseSource::Held => 1,
                PoseSource::Missing => 2,
            };
            counts[k] += r.last - r.first + 1;
        }
        Some(counts)
    }
}

/// Reads and parses `metrics.json` leniently: keys it does not know are ignored, a
/// latency entry without samples (its numbers written as `null`: JSON has no NaN) is
/// dropped, and any other `null` where [`Metrics`] has a number (a mean over no samples,
/// such as `accuracy.mesh_rms_mm` without ground-truth meshes) is read as 0; the page
/// shows such numbers only beside a non-zero count.
fn read_metrics(dir: &Path) -> Result<Metrics, ReportError> {
    let path = dir.join("metrics.json");
    let text = match std::fs::read_to_string(&path) {
        Ok(t) => t,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            return Err(ReportError::NotATake(dir.to_path_buf()));
        }
        Err(e) => return Err(ReportError::io(&path, e)),
    };
    let format = |message: String| ReportError::Format {
        path: path.clone(),
        message,
    };
    let mut value: serde_json::Value =
        serde_json::from_str(&text).map_err(|e| format(format!("not JSON: {e}")))?;
    if let Some(latency) = value.get_mut("latency_ms").and_then(|l| l.as_object_mut()) {
        latency.retain(|_, stats| {
            stats
                .as_object()
                .is_some_and(|s| s.values().all(|v| !v.is_null()))
        });
    }
    // Top-level keys whose default is a number (the others are options, or unknown).
    let template = serde_json::to_value(Metrics::default()).unwrap_or_default();
    if let Some(top) = value.as_object_mut() {
        for (key, v) in top.iter_mut() {
            if v.is_null() && template.get(key).is_some_and(|t| t.is_number()) {
                *v = serde_json::Value::from(0.0);
            } else if let Some(inner) = v.as_object_mut() {
                // Nested structs have no optional fields.
                for x in inner.values_mut().filter(|x| x.is_null()) {
                    *x = serde_json::Value::from(0.0);
                }
            }
        }
    }
    serde_json::from_value(value).map_err(|e| format(format!("not a helmcap metrics file: {e}")))
}

/// Reads `take.json`; a missing or malformed one adds a note (malformed) or nothing
/// (missing: the contact sheet says what it lacks).
fn read_take_json(dir: &Path, notes: &mut Vec<String>) -> Option<TakeJson> {
    let path = dir.join("take.json");
    let text = match std::fs::read_to_string(&path) {
        Ok(t) => t,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return None,
        Err(e) => {
            notes.push(format!("take.json: unreadable ({e})"));
            return None;
        }
    };
    match serde_json::from_str::<serde_json::Value>(&text) {
        Ok(v) => {
            let key = |k: &str| v.get(k).and_then(|s| s.as_str()).map(str::to_string);
            Some(TakeJson {
                take: key("take"),
                session: key("session"),
            })
        }
        Err(e) => {
            notes.push(format!(
                "take.json: not JSON ({e}); take name and session unknown"
            ));
            None
        }
    }
}

/// What `bundles.csv` contributes.
struct BundleData {
    markers: Vec<String>,
    /// (frame, marker index) of every observed bundle.
    observed: Vec<(usize, usize)>,
    /// Per frame: sum and count of the observed and gap-filled bundles' confidence.
    confidence: BTreeMap<usize, (f64, u32)>,
    /// Frames that have any row.
    frames: std::collections::BTreeSet<usize>,
    timecodes: BTreeMap<usize, String>,
}

/// Reads `bundles.csv`; `None` (with a note) when it is missing or malformed.
fn read_bundles(path: &Path, notes: &mut Vec<String>) -> Option<BundleData> {
    let mut data = BundleData {
        markers: Vec::new(),
        observed: Vec::new(),
        confidence: BTreeMap::new(),
        frames: std::collections::BTreeSet::new(),
        timecodes: BTreeMap::new(),
    };
    let mut index: HashMap<String, usize> = HashMap::new();
    let result = read_table(
        path,
        &[
            ("frame", true),
            ("marker", true),
            ("confidence", false),
            ("status", false),
            ("timecode", false),
        ],
        |row| {
            let frame = row.frame(0)?;
            let marker = row.get(1).unwrap_or_default();
            let m = match index.get(marker) {
                Some(&m) => m,
                None => {
                    data.markers.push(marker.to_string());
                    index.insert(marker.to_string(), data.markers.len() - 1);
                    data.markers.len() - 1
                }
            };
            data.frames.insert(frame);
            // Without a status column every row is an observed bundle (the plain
            // bundles format).
            let status = row.get(3).unwrap_or("observed");
            if status == "observed" {
                data.observed.push((frame, m));
            }
            if matches!(status, "observed" | "gap-filled") {
                let c = match row.get(2) {
                    Some(c) => c
                        .parse::<f64>()
                        .map_err(|_| format!("confidence {c:?} is not a number"))?,
                    None => 1.0,
                };
                if c.is_finite() {
                    let e = data.confidence.entry(frame).or_insert((0.0, 0));
                    e.0 += c;
                    e.1 += 1;
                }
            }
            if let Some(tc) = row.get(4).filter(|t| !t.is_empty()) {
                data.timecodes
                    .entry(frame)
                    .or_insert_with(|| tc.to_string());
            }
            Ok(())
        },
    );
    match result {
        Ok(()) => Some(data),
        Err(e) => {
            notes.push(e.note(
                "bundles.csv",
                "marker coverage and bundle confidence not shown",
            ));
            None
        }
    }
}

/// Reads `head_pose.csv`: the pose source of every frame with a row (`estimated` unless
/// the `source` column says `held`).
fn read_poses(path: &Path, notes: &mut Vec<String>) -> Option<BTreeMap<usize, PoseSource>> {
    let mut poses = BTreeMap::new();
    let result = read_table(path, &[("frame", true), ("source", false)], |row| {
        let source = match row.get(1) {
            Some("held") => PoseSource::Held,
            _ => PoseSource::Estimated,
        };
        poses.insert(row.frame(0)?, source);
        Ok(())
    });
    match result {
        Ok(()) => Some(poses),
        Err(e) => {
            notes.push(e.note("head_pose.csv", "head-pose source over time not shown"));
            None
        }
    }
}

/// Reads `rig_weights.csv`'s `residual_mm` per frame; `None` when the file is missing
/// (no note: it is written only on request) or has no such column; a malformed file adds
/// a note.
fn read_residual(path: &Path, notes: &mut Vec<String>) -> Option<Vec<(usize, f64)>> {
    let mut residual = Vec::new();
    let result = read_table(path, &[("frame", true), ("residual_mm", true)], |row| {
        let frame = row.frame(0)?;
        let text = row.get(1).unwrap_or_default();
        let mm: f64 = text
            .parse()
            .map_err(|_| format!("residual_mm {text:?} is not a number"))?;
        if mm.is_finite() {
            residual.push((frame, mm));
        }
        Ok(())
    });
    match result {
        Ok(()) => Some(residual),
        Err(TableError::Missing) | Err(TableError::NoColumn(_)) => None,
        Err(e) => {
            notes.push(e.note("rig_weights.csv", "solve residual per frame not shown"));
            None
        }
    }
}

/// Run-length pose sources over `first..=last`; frames without a row are `Missing`.
fn pose_runs(first: usize, last: usize, poses: &BTreeMap<usize, PoseSource>) -> Vec<PoseRun> {
    let mut runs: Vec<PoseRun> = Vec::new();
    for frame in first..=last {
        let source = poses.get(&frame).copied().unwrap_or(PoseSource::Missing);
        match runs.last_mut() {
            Some(r) if r.source == source && r.last + 1 == frame => r.last = frame,
            _ => runs.push(PoseRun {
                first: frame,
                last: frame,
                source,
            }),
        }
    }
    runs
}

/// Up to `count` frames spread evenly over `first..=last` (the centres of `count` equal
/// parts), each moved to the nearest frame of `present` when that set is not empty;
/// ascending, without repeats.
pub fn pick_frames(
    first: usize,
    last: usize,
    present: &std::collections::BTreeSet<usize>,
    count: usize,
) -> Vec<usize> {
    let len = last.saturating_sub(first) + 1;
    let mut picked: Vec<usize> = (0..count.min(len))
        .map(|i| first + (2 * i + 1) * len / (2 * count.min(len)))
        .filter_map(|target| {
            if present.is_empty() {
                return Some(target);
            }
            let after = present.range(target..).next();
            let before = present.range(..target).next_back();
            match (before, after) {
                (Some(&b), Some(&a)) => Some(if target - b < a - target { b } else { a }),
                (Some(&b), None) => Some(b),
                (None, Some(&a)) => Some(a),
                (None, None) => None,
            }
        })
        .collect();
    picked.dedup();
    picked
}

/// Why a CSV file could not be used.
#[derive(Debug)]
enum TableError {
    /// The file does not exist.
    Missing,
    /// The file could not be read.
    Io(std::io::Error),
    /// The header lacks a required column.
    NoColumn(String),
    /// A row is malformed (1-based line, message).
    Row(usize, String),
}

impl TableError {
    /// The page's note for file `name`; `lost` says what the page lacks for it.
    fn note(&self, name: &str, lost: &str) -> String {
        match self {
            TableError::Missing => format!("{name}: missing ({lost})"),
            TableError::Io(e) => format!("{name}: unreadable: {e} ({lost})"),
            TableError::NoColumn(c) => format!("{name}: no `{c}` column ({lost})"),
            TableError::Row(line, m) => format!("{name}:{line}: {m} ({lost})"),
        }
    }
}

/// One data row of a CSV file, seen through the columns asked for.
struct Row<'a> {
    fields: Vec<&'a str>,
    columns: &'a [Option<usize>],
}

impl Row<'_> {
    /// The field of the `i`-th column asked for; `None` when the file has no such column
    /// or the row is short.
    fn get(&self, i: usize) -> Option<&str> {
        self.columns
            .get(i)
            .copied()
            .flatten()
            .and_then(|c| self.fields.get(c).copied())
    }

    /// The `i`-th column asked for, as a frame number.
    fn frame(&self, i: usize) -> Result<usize, String> {
        let text = self.get(i).unwrap_or_default();
        text.parse()
            .map_err(|_| format!("frame {text:?} is not a whole number"))
    }
}

/// Streams the comma-separated file `path` (header line first, blank lines skipped) row
/// by row through `row`, which sees the columns `wanted` (name, required) in that order.
fn read_table(
    path: &Path,
    wanted: &[(&str, bool)],
    mut row: impl FnMut(&Row) -> Result<(), String>,
) -> Result<(), TableError> {
    let file = match std::fs::File::open(path) {
        Ok(f) => f,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Err(TableError::Missing),
        Err(e) => return Err(TableError::Io(e)),
    };
    let mut lines = std::io::BufReader::new(file).lines().enumerate();
    let header = match lines.next() {
        Some((_, Ok(h))) => h,
        Some((_, Err(e))) => return Err(TableError::Io(e)),
        None => return Err(TableError::Row(1, "empty file (no header)".into())),
    };
    let names: Vec<&str> = header
        .trim_end_matches('\r')
        .split(',')
        .map(str::trim)
        .collect();
    let mut columns = Vec::with_capacity(wanted.len());
    for &(name, required) in wanted {
        let c = names.iter().position(|n| *n == name);
        if c.is_none() && required {
            return Err(TableError::NoColumn(name.to_string()));
        }
        columns.push(c);
    }
    for (i, line) in lines {
        let line = line.map_err(TableError::Io)?;
        let line = line.trim_end_matches('\r');
        if line.trim().is_empty() {
            continue;
        }
        let r = Row {
            fields: line.split(',').collect(),
            columns: &columns,
        };
        row(&r).map_err(|m| TableError::Row(i + 1, m))?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame_index::FrameIndex;
    use std::collections::BTreeSet;

    fn names(n: usize) -> Vec<String> {
        (0..n).map(|i| format!("m{i}")).collect()
    }

    #[test]
    fn coverage_bins_cover_the_take_and_count_shares() {
        // Frames 10..=19 in 4 bins: 10-11, 12-14, 15-16, 17-19.
        let obs: Vec<(usize, usize)> = (10..=19)
            .map(|f| (f, 0))
            .chain([(12, 1), (13, 1), (13, 1), (30, 1), (15, 7)])
            .collect();
        let c = bin_coverage(10, 19, &names(2), &obs, 4);
        assert_eq!(c.bins, vec![(10, 11), (12, 14), (15, 16), (17, 19)]);
        assert_eq!(c.share[0], vec![1.0; 4]);
        let expected = [0.0, 2.0 / 3.0, 0.0, 0.0];
        for (s, e) in c.share[1].iter().zip(expected) {
            assert!((s - e).abs() < 1e-6, "{:?}", c.share[1]);
        }
        // More bins than frames: one frame per bin; every frame lands in its own bin.
        let c = bin_coverage(0, 2, &names(1), &[(0, 0), (1, 0), (2, 0)], 60);
        assert_eq!(c.bins, vec![(0, 0), (1, 1), (2, 2)]);
        assert_eq!(c.share[0], vec![1.0; 3]);
        // Every frame of a long take lands in the bin whose range holds it.
        let obs: Vec<_> = (0..1000).map(|f| (f, 0)).collect();
        let c = bin_coverage(0, 999, &names(1), &obs, 7);
        assert!(
            c.share[0].iter().all(|&s| (s - 1.0).abs() < 1e-6),
            "{:?}",
            c.share[0]
        );
        assert_eq!(c.bins.first().map(|b| b.0), Some(0));
        assert_eq!(c.bins.last().map(|b| b.1), Some(999));
    }

    #[test]
    fn sheet_frames_are_spread_and_snapped_to_present_frames() {
        let none = BTreeSet::new();
        assert_eq!(pick_frames(0, 29, &none, 4), vec![3, 11, 18, 26]);
        assert_eq!(pick_frames(5, 6, &none, 4), vec![5, 6]);
        let present: BTreeSet<usize> = [0, 1, 2, 20, 29].into_iter().collect();
        assert_eq!(pick_frames(0, 29, &present, 4), vec![2, 20, 29]);
    }

    #[test]
    fn pose_runs_mark_frames_without_a_row_missing() {
        let poses: BTreeMap<usize, PoseSource> = [
            (1, PoseSource::Estimated),
            (2, PoseSource::Estimated),
            (3, PoseSource::Held),
            (5, PoseSource::Estimated),
        ]
        .into_iter()
        .collect();
        let runs = pose_runs(0, 5, &poses);
        let kinds: Vec<_> = runs.iter().map(|r| (r.first, r.last, r.source)).collect();
        assert_eq!(
            kinds,
            vec![
                (0, 0, PoseSource::Missing),
                (1, 2, PoseSource::Estimated),
                (3, 3, PoseSource::Held),
                (4, 4, PoseSource::Missing),
                (5, 5, PoseSource::Estimated),
            ]
        );
    }

    #[test]
    fn a_take_with_only_metrics_loads_with_notes() {
        let dir = tempfile::tempdir().unwrap();
        let metrics = Metrics {
            frames_in: 3,
            frames_out: 3,
            frame_range: Some((FrameIndex::new(0), FrameIndex::new(2))),
            ..Metrics::default()
        };
        let mut value = serde_json::to_value(&metrics).unwrap();
        // Keys a newer writer may add are ignored; means over no samples (NaN, written as
        // null) are read.
        value["something_new"] = serde_json::json!({"a": 1});
        value["throughput_fps"] = serde_json::Value::Null;
        value["accuracy"] = serde_json::json!({"bundle_frames": 3, "bundle_rms_mm": 0.2,
            "mesh_frames": 0, "mesh_rms_mm": null, "mesh_mean_mm": null, "mesh_max_mm": 0.0});
        value["latency_ms"] = serde_json::json!({
            "enhance": {"mean": null, "p50": null, "p99": null, "max": null, "count": 0},
            "end_to_end": {"mean": 1.0, "p50": 1.0, "p99": 2.0, "max": 3.0, "count": 3}});
        std::fs::write(dir.path().join("metrics.json"), value.to_string()).unwrap();
        std::fs::write(dir.path().join("head_pose.csv"), "frame,qw\nx,1\n").unwrap();
        let take = TakeSummary::load(dir.path(), &ReportParams::default()).unwrap();
        assert_eq!(take.frame_range, Some((0, 2)));
        assert!(take.coverage.is_none() && take.pose.is_none());
        assert!(matches!(take.residual, Residual::Accuracy(a) if a.bundle_frames == 3));
        assert_eq!(
            take.metrics.latency_ms.keys().collect::<Vec<_>>(),
            ["end_to_end"]
        );
        assert_eq!(take.metrics.timecode, None);
        let notes = take.notes.join("\n");
        assert!(notes.contains("bundles.csv: missing"), "{notes}");
        assert!(notes.contains("head_pose.csv:2: frame \"x\""), "{notes}");
        std::fs::write(dir.path().join("metrics.json"), "{\"frames_in\": \"many\"}").unwrap();
        let err = TakeSummary::load(dir.path(), &ReportParams::default()).unwrap_err();
        assert!(err.to_string().contains("metrics.json"), "{err}");
    }
}
