//! The CSV outputs of a take (DESIGN.md §4 "Pipeline outputs"):
//!
//! - `bundles.csv`: `frame,marker,x,y,z,confidence,status,timecode`: millimetres, head
//!   frame. `status` is `observed`, `gap-filled` (position from the solved surface at the
//!   marker's vertex) or `dropped` (labeled but rejected; coordinates `nan`, which readers
//!   count as missing). A marker with nothing in a frame has no row. `timecode` is the
//!   frame's timecode with its rate (`01:00:00:12.1@30`), empty without one.
//! - `head_pose.csv`: `frame,qw,qx,qy,qz,tx,ty,tz,source,timecode`: head frame → cam0,
//!   mm; `source` is `estimated` or `held`; frames without a pose have no row.
//! - `tracks.csv`: `frame,camera,marker,u,v`: the labeled 2D detections, pixels.
//!
//! Each file is written as frames arrive and published atomically at the end. A frame is
//! complete when all three files hold it; when a write fails (disk full), the files are cut
//! back to the last complete frame and published that way (see [`StagedFile`]).

use std::io::{Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};
use std::sync::Arc;

use super::staged_file::StagedFile;
use crate::align::PoseSource;
use crate::dataset::MarkerLayout;
use crate::pipeline::{BundleStatus, FrameResult, Metrics, SessionMeta, Sink, SinkError};

/// Writes `bundles.csv`, `head_pose.csv` and `tracks.csv` into a folder.
#[derive(Debug)]
pub struct CsvSink {
    dir: PathBuf,
    layout: Option<Arc<MarkerLayout>>,
    files: Option<[StagedFile; 3]>,
}

impl CsvSink {
    /// A sink writing into `dir` (created at begin).
    pub fn new(dir: &Path) -> Self {
        Self {
            dir: dir.to_path_buf(),
            layout: None,
            files: None,
        }
    }
}

impl Sink for CsvSink {
    fn name(&self) -> &str {
        "csv"
    }

    fn begin(&mut self, session: &SessionMeta) -> Result<(), SinkError> {
        std::fs::create_dir_all(&self.dir).map_err(|e| SinkError::io(&self.dir, e))?;
        let mut bundles = StagedFile::create(&self.dir.join("bundles.csv"))?;
        bundles.write_with(|w| writeln!(w, "frame,marker,x,y,z,confidence,status,timecode"))?;
        let mut pose = StagedFile::create(&self.dir.join("head_pose.csv"))?;
        pose.write_with(|w| writeln!(w, "frame,qw,qx,qy,qz,tx,ty,tz,source,timecode"))?;
        let mut tracks = StagedFile::create(&self.dir.join("tracks.csv"))?;
        tracks.write_with(|w| writeln!(w, "frame,camera,marker,u,v"))?;
        for f in [&mut bundles, &mut pose, &mut tracks] {
            f.mark_complete()?;
        }
        self.files = Some([bundles, pose, tracks]);
        self.layout = Some(session.layout.clone());
        Ok(())
    }

    fn write(&mut self, f: &FrameResult) -> Result<(), SinkError> {
        let result = self.write_frame(f);
        if let Some(files) = &mut self.files {
            if result.is_ok() {
                // Flush all three, then mark all three: a frame counts only when every
                // file holds it.
                let flushed = files.iter_mut().try_for_each(StagedFile::flush);
                if flushed.is_ok() {
                    for file in files.iter_mut() {
                        file.mark_complete()?;
                    }
                    return Ok(());
                }
                for file in files.iter_mut() {
                    file.roll_back()?;
                }
                return flushed;
            }
            for file in files.iter_mut() {
                file.roll_back()?;
            }
        }
        result
    }

    fn finish(&mut self, _metrics: &Metrics) -> Result<(), SinkError> {
        let mut first_error = None;
        if let Some(files) = self.files.take() {
            for f in files {
                // Every file is published even when another one failed.
                if let Err(e) = f.commit() {
                    first_error.get_or_insert(e);
                }
            }
        }
        first_error.map_or(Ok(()), Err)
    }
}

impl CsvSink {
    /// Writes one frame's rows (buffered; [`Sink::write`] makes them complete).
    fn write_frame(&mut self, f: &FrameResult) -> Result<(), SinkError> {
        let (Some([bundles, pose, tracks]), Some(layout)) = (&mut self.files, &self.layout) else {
            return Err(SinkError::Other("csv sink written before begin".into()));
        };
        let tc = f
            .timecode
            .map(|t| t.to_string_with_rate())
            .unwrap_or_default();
        bundles.write_with(|w| {
            for (r, m) in f.markers.iter().zip(&layout.markers) {
                match (r.status, r.point_in_head) {
                    (BundleStatus::Observed | BundleStatus::GapFilled, Some(p)) => writeln!(
                        w,
                        "{},{},{},{},{},{:.4},{},{tc}",
                        f.index,
                        m.name,
                        p.x,
                        p.y,
                        p.z,
                        r.confidence,
                        r.status.name()
                    )?,
                    (BundleStatus::Dropped, _) => writeln!(
                        w,
                        "{},{},nan,nan,nan,0,{},{tc}",
                        f.index,
                        m.name,
                        r.status.name()
                    )?,
                    _ => {}
                }
            }
            Ok(())
        })?;
        if let Some(p) = &f.cam0_from_head {
            // q and −q are the same rotation: keep qw ≥ 0 so the columns do not flip sign
            // from frame to frame.
            let q = p.rotation.into_inner();
            let q = if q.w < 0.0 { -q } else { q };
            let t = p.translation.vector;
            let source = match f.pose_source {
                PoseSource::Held => "held",
                _ => "estimated",
            };
            pose.write_with(|w| {
                writeln!(
                    w,
                    "{},{},{},{},{},{},{},{},{source},{tc}",
                    f.index, q.w, q.i, q.j, q.k, t.x, t.y, t.z
                )
            })?;
        }
        tracks.write_with(|w| {
            for c in 0..2 {
                for (m, px) in f.tracks(c) {
                    writeln!(
                        w,
                        "{},{c},{},{},{}",
                        f.index, layout.markers[m].name, px.x, px.y
                    )?;
                }
            }
            Ok(())
        })
    }
}

/// Writes `metrics.json` atomically at the end of the take. Its room on disk is taken at
/// the start ([`METRICS_RESERVE_BYTES`] blanks in the temporary file), so a take that
/// fails because the disk is full still gets its metrics.
#[derive(Debug)]
pub struct MetricsSink {
    path: PathBuf,
    file: Option<StagedFile>,
}

/// Bytes reserved for `metrics.json` at the start of a take (a take's metrics are a few KB).
pub const METRICS_RESERVE_BYTES: usize = 16 * 1024;

impl MetricsSink {
    /// A sink writing `path` (usually `<out>/metrics.json`).
    pub fn new(path: &Path) -> Self {
        Self {
            path: path.to_path_buf(),
            file: None,
        }
    }
}

impl Sink for MetricsSink {
    fn name(&self) -> &str {
        "metrics.json"
    }

    fn begin(&mut self, _session: &SessionMeta) -> Result<(), SinkError> {
        if let Some(dir) = self.path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).map_err(|e| SinkError::io(dir, e))?;
        }
        let mut file = StagedFile::create(&self.path)?;
        file.write_with(|w| w.write_all(&[b' '; METRICS_RESERVE_BYTES]))?;
        file.mark_complete()?;
        self.file = Some(file);
        Ok(())
    }

    fn write(&mut self, _frame: &FrameResult) -> Result<(), SinkError> {
        Ok(())
    }

    fn finish(&mut self, metrics: &Metrics) -> Result<(), SinkError> {
        let text = serde_json::to_string_pretty(metrics)
            .map_err(|e| SinkError::Other(format!("metrics: {e}")))?;
        let Some(mut file) = self.file.take() else {
            return crate::atomic_file::write_atomically(&self.path, |w| {
                w.write_all(text.as_bytes())?;
                w.write_all(b"\n")
            })
            .map_err(|e| SinkError::io(&self.path, e));
        };
        // Into the reserved room, then cut to the JSON's length.
        file.write_with(|w| {
            w.seek(SeekFrom::Start(0))?;
            w.write_all(text.as_bytes())?;
            w.write_all(b"\n")?;
            w.flush()?;
            let len = w.get_mut().stream_position()?;
            w.get_mut().set_len(len)
        })?;
        file.commit()
    }
}
