//! The recorder: writes stereo frames into a recording session folder (DESIGN.md §4) that
//! [`super::Replay`] reads back.
//!
//! # Layout written
//! - `session.toml`: `fps`, `cameras`, `calibration = "calibration.yaml"` when a rig is
//!   given, `[timecode] rate` and (after the first frame) `start`;
//! - `calibration.yaml` (the rig, OpenCV FileStorage), when given;
//! - `cam0/NNNNNN.png`, `cam1/NNNNNN.png`: 8-bit grayscale, numbered by frame index;
//! - `frames.csv`: `frame,timestamp_ns,timecode`, one row per frame written, in order;
//! - `sync.csv`: `frame,trigger,clock`: the sync box's trigger pulse of each frame (empty
//!   on the local clock) and the clock that stamped it (`syncbox` or `local`);
//! - `record_report.json` at the end ([`RecordReport`]).
//!
//! # Threads, queue and drops
//! [`Recorder::push`] never blocks: it puts the frame into a bounded queue
//! ([`RecorderParams::queue_frames`]) that [`RecorderParams::writers`] threads
//! (`helmcap:rec-writer-N`) empty, encoding the PNGs (on the writer side) and writing them.
//! When the disk cannot keep up and the queue is full, the frame is dropped, counted and
//! reported at ERROR level (the first drop at once, then at most once a second with the
//! running count); the report lists every dropped frame. A frame whose PNGs cannot be
//! written (disk full, I/O error) is counted and listed the same way.
//!
//! # Valid at every moment
//! A collector thread (`helmcap:rec-index`) appends a frame's rows to `frames.csv` and
//! `sync.csv` only once both of its PNGs are complete (each PNG is written to a temporary
//! file and renamed), in frame order, each batch of whole rows with one write; the files are
//! synced to disk every [`RecorderParams::sync_every`] and at the end. `session.toml` is
//! replaced atomically. So after a crash (or a Ctrl-C) the folder is a readable session up
//! to the last complete frame. (A power cut can lose the last unsynced second.)

use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use crossbeam_channel::{Receiver, Sender, TrySendError};

use super::live::{LiveStats, StampClock};
use super::{GrayImage, StereoFrame};
use crate::camera::StereoRig;
use crate::timecode::{Timecode, TimecodeRate};

/// Recorder settings.
#[derive(Debug, Clone, PartialEq)]
pub struct RecorderParams {
    /// Frames the queue to the writers holds; a frame pushed when it is full is dropped and
    /// counted. Default 120 (two seconds at 60 fps).
    pub queue_frames: usize,
    /// PNG writer threads. Default 2.
    pub writers: usize,
    /// `frames.csv` and `sync.csv` are synced to disk at least this often. Default 1 s.
    pub sync_every: Duration,
    /// Extra time each frame's write takes: simulates a slow disk (tests, drills).
    /// Default zero.
    pub simulated_write_delay: Duration,
}

impl Default for RecorderParams {
    fn default() -> Self {
        Self {
            queue_frames: 120,
            writers: 2,
            sync_every: Duration::from_secs(1),
            simulated_write_delay: Duration::ZERO,
        }
    }
}

/// What the session says about itself.
#[derive(Debug, Clone, PartialEq)]
pub struct SessionHeader {
    /// Camera frames per second.
    pub fps: f64,
    /// Camera folder names, cam0 first.
    pub cameras: [String; 2],
    /// Timecode rate of the frames' timecodes.
    pub timecode_rate: Option<TimecodeRate>,
    /// The stereo calibration, written as `calibration.yaml`.
    pub calibration: Option<StereoRig>,
}

/// How a frame was stamped (written to `sync.csv`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct FrameStamp {
    /// The sync box's trigger pulse, when stamped from it.
    pub trigger: Option<u64>,
    /// The clock that stamped the timecode (None: not a live frame).
    pub clock: Option<StampClock>,
}

/// What [`Recorder::push`] did with a frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PushOutcome {
    /// Queued for writing.
    Queued,
    /// Dropped: the queue was full (counted and logged).
    Dropped,
}

/// Errors of the recorder.
#[derive(Debug, thiserror::Error)]
pub enum RecordError {
    /// The folder already holds a recording.
    #[error("{0}: already holds a recording (session.toml); choose another folder")]
    Exists(PathBuf),
    /// A file or folder cannot be written.
    #[error("{path}: {message}")]
    Io {
        /// The file or folder.
        path: PathBuf,
        /// What went wrong.
        message: String,
    },
    /// A thread cannot be started or died.
    #[error("recorder thread: {0}")]
    Thread(String),
    /// A setting is invalid.
    #[error("recorder: {0}")]
    Params(String),
}

/// The summary written to `record_report.json`.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct RecordReport {
    /// The session folder.
    pub folder: PathBuf,
    /// Frames pushed.
    pub frames_received: u64,
    /// Frames written (both PNGs, listed in `frames.csv`).
    pub frames_written: u64,
    /// Frames dropped because the queue was full (the disk did not keep up).
    pub frames_dropped_queue_full: u64,
    /// Frames whose PNGs could not be written.
    pub frames_failed_write: u64,
    /// Indices of the dropped and failed frames (the first 10 000).
    pub lost_frames: Vec<usize>,
    /// First frame index pushed.
    pub first_frame: Option<usize>,
    /// Last frame index pushed.
    pub last_frame: Option<usize>,
    /// Frame indices the source skipped (from its counters; frames a camera failed to
    /// deliver).
    pub source_gaps: u64,
    /// Indices from the first to the last frame neither written nor counted as lost or as
    /// a source gap: 0 when every frame is accounted for.
    pub frames_unaccounted: i64,
    /// Queue capacity, frames.
    pub queue_frames: usize,
    /// Most frames ever waiting in the queue.
    pub queue_high_water: usize,
    /// Writer threads.
    pub writers: usize,
    /// Time from the first push to the end, s.
    pub elapsed_s: f64,
    /// Frames written per second over that time.
    pub written_fps: f64,
    /// The live source's counters (cameras, sync box), when recording a live source.
    pub source: Option<LiveStats>,
}

struct Job {
    index: usize,
    images: [GrayImage; 2],
}

struct RowMeta {
    index: usize,
    timestamp_ns: u64,
    timecode: Option<Timecode>,
    stamp: FrameStamp,
}

enum CollectorMsg {
    Accepted(RowMeta),
    Dropped(usize),
    Done(usize, Result<(), String>),
}

#[derive(Debug, Default)]
struct Counters {
    written: AtomicU64,
    failed: AtomicU64,
}

struct CollectorResult {
    lost: Vec<usize>,
}

/// Writes a recording session; see the module docs.
pub struct Recorder {
    root: PathBuf,
    params: RecorderParams,
    jobs: Option<Sender<Job>>,
    collector_tx: Option<Sender<CollectorMsg>>,
    writers: Vec<JoinHandle<()>>,
    collector: Option<JoinHandle<Result<CollectorResult, RecordError>>>,
    counters: Arc<Counters>,
    received: u64,
    dropped: u64,
    first_frame: Option<usize>,
    last_frame: Option<usize>,
    high_water: usize,
    started: Option<Instant>,
    last_drop_log: Option<Instant>,
}

impl std::fmt::Debug for Recorder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Recorder")
            .field("root", &self.root)
            .field("received", &self.received)
            .field("dropped", &self.dropped)
            .finish_non_exhaustive()
    }
}

fn io_err(path: &Path, e: impl std::fmt::Display) -> RecordError {
    RecordError::Io {
        path: path.to_path_buf(),
        message: e.to_string(),
    }
}

/// `session.toml`'s text.
fn session_toml(header: &SessionHeader, start: Option<&Timecode>) -> String {
    let mut s = format!(
        "# Recorded by helmcap record.\nfps = {:?}\ncameras = [\"{}\", \"{}\"]\n",
        header.fps, header.cameras[0], header.cameras[1]
    );
    if header.calibration.is_some() {
        s.push_str("calibration = \"calibration.yaml\"\n");
    }
    if let Some(rate) = header.timecode_rate {
        s.push_str(&format!("\n[timecode]\nrate = \"{rate}\"\n"));
        if let Some(start) = start {
            s.push_str(&format!("start = \"{start}\"\n"));
        }
    }
    s
}

fn write_text_atomically(path: &Path, text: &str) -> Result<(), RecordError> {
    crate::atomic_file::write_atomically(path, |w| w.write_all(text.as_bytes()))
        .map_err(|e| io_err(path, e))
}

impl Recorder {
    /// Creates the session folder (it may exist, but must not hold a `session.toml`) with
    /// `session.toml`, the calibration, the camera folders and the CSV headers, and starts
    /// the writer and collector threads.
    ///
    /// # Errors
    /// [`RecordError`] naming the folder or file.
    pub fn create(
        root: &Path,
        header: SessionHeader,
        params: RecorderParams,
    ) -> Result<Self, RecordError> {
        if !(1..=crate::limits::MAX_QUEUE_FRAMES).contains(&params.queue_frames)
            || !(1..=64).contains(&params.writers)
        {
            return Err(RecordError::Params(format!(
                "queue_frames must be 1 to {} and writers 1 to 64",
                crate::limits::MAX_QUEUE_FRAMES
            )));
        }
        if !(header.fps > 0.0 && header.fps.is_finite()) {
            return Err(RecordError::Params(format!(
                "fps {} must be positive",
                header.fps
            )));
        }
        if root.join("session.toml").exists() {
            return Err(RecordError::Exists(root.to_path_buf()));
        }
        for cam in &header.cameras {
            let dir = root.join(cam);
            std::fs::create_dir_all(&dir).map_err(|e| io_err(&dir, e))?;
        }
        if let Some(rig) = &header.calibration {
            let path = root.join("calibration.yaml");
            crate::camera::write_rig(&path, rig).map_err(|e| io_err(&path, e))?;
        }
        let frames_path = root.join("frames.csv");
        write_text_atomically(&frames_path, "frame,timestamp_ns,timecode\n")?;
        let sync_path = root.join("sync.csv");
        write_text_atomically(&sync_path, "frame,trigger,clock\n")?;
        write_text_atomically(&root.join("session.toml"), &session_toml(&header, None))?;

        let counters = Arc::new(Counters::default());
        let (jobs_tx, jobs_rx) = crossbeam_channel::bounded::<Job>(params.queue_frames);
        let (col_tx, col_rx) = crossbeam_channel::unbounded::<CollectorMsg>();
        let mut writers = Vec::new();
        for w in 0..params.writers {
            let (rx, tx) = (jobs_rx.clone(), col_tx.clone());
            let root = root.to_path_buf();
            let cameras = header.cameras.clone();
            let delay = params.simulated_write_delay;
            let handle = std::thread::Builder::new()
                .name(format!("helmcap:rec-writer-{w}"))
                .spawn(move || writer_loop(&root, &cameras, &rx, &tx, delay))
                .map_err(|e| RecordError::Thread(e.to_string()))?;
            writers.push(handle);
        }
        drop(jobs_rx);
        let collector = {
            let root = root.to_path_buf();
            let counters = counters.clone();
            let sync_every = params.sync_every;
            std::thread::Builder::new()
                .name("helmcap:rec-index".into())
                .spawn(move || collector_loop(&root, &header, &col_rx, &counters, sync_every))
                .map_err(|e| RecordError::Thread(e.to_string()))?
        };
        tracing::info!("recording into {}", root.display());
        Ok(Self {
            root: root.to_path_buf(),
            params,
            jobs: Some(jobs_tx),
            collector_tx: Some(col_tx),
            writers,
            collector: Some(collector),
            counters,
            received: 0,
            dropped: 0,
            first_frame: None,
            last_frame: None,
            high_water: 0,
            started: None,
            last_drop_log: None,
        })
    }

    /// The session folder.
    pub fn root(&self) -> &Path {
        &self.root
    }

    /// Frames pushed, written, dropped (queue full) and failed so far.
    pub fn counts(&self) -> (u64, u64, u64, u64) {
        (
            self.received,
            self.counters.written.load(Ordering::Relaxed),
            self.dropped,
            self.counters.failed.load(Ordering::Relaxed),
        )
    }

    /// Queues a frame for writing without blocking; when the queue is full the frame is
    /// dropped, counted and logged (ERROR). Frame indices must increase.
    pub fn push(&mut self, frame: StereoFrame, stamp: FrameStamp) -> PushOutcome {
        let (Some(jobs), Some(col)) = (&self.jobs, &self.collector_tx) else {
            return PushOutcome::Dropped;
        };
        self.started.get_or_insert_with(Instant::now);
        self.received += 1;
        // The recorder numbers its files and rows by the frame index as an array index.
        let index = frame.index.as_usize();
        self.first_frame.get_or_insert(index);
        self.last_frame = Some(index);
        // The collector is unbounded and only ends after `finish`: a failed send cannot
        // happen while `self` is alive, and would only lose the row, which is then counted.
        let _ = col.send(CollectorMsg::Accepted(RowMeta {
            index,
            timestamp_ns: frame.timestamp_ns,
            timecode: frame.timecode,
            stamp,
        }));
        let outcome = match jobs.try_send(Job {
            index,
            images: frame.images,
        }) {
            Ok(()) => PushOutcome::Queued,
            Err(TrySendError::Full(_) | TrySendError::Disconnected(_)) => {
                let _ = col.send(CollectorMsg::Dropped(index));
                self.dropped += 1;
                let now = Instant::now();
                if self
                    .last_drop_log
                    .is_none_or(|t| now.duration_since(t) >= Duration::from_secs(1))
                {
                    self.last_drop_log = Some(now);
                    tracing::error!(
                        "recorder: the disk is not keeping up: frame {index} dropped, the queue of {} frames is full ({} dropped so far)",
                        self.params.queue_frames,
                        self.dropped
                    );
                }
                PushOutcome::Dropped
            }
        };
        self.high_water = self.high_water.max(jobs.len());
        outcome
    }

    /// Writes every queued frame, closes the files and writes `record_report.json`.
    /// `source` adds the live source's counters (and its gaps) to the report.
    ///
    /// # Errors
    /// [`RecordError`] when the index files or the report cannot be written.
    pub fn finish(mut self, source: Option<LiveStats>) -> Result<RecordReport, RecordError> {
        self.jobs = None;
        for w in self.writers.drain(..) {
            w.join()
                .map_err(|_| RecordError::Thread("a writer thread panicked".into()))?;
        }
        self.collector_tx = None;
        let result = self
            .collector
            .take()
            .ok_or_else(|| RecordError::Thread("collector already joined".into()))?
            .join()
            .map_err(|_| RecordError::Thread("the collector thread panicked".into()))??;
        let written = self.counters.written.load(Ordering::Relaxed);
        let failed = self.counters.failed.load(Ordering::Relaxed);
        let elapsed_s = self.started.map_or(0.0, |t| t.elapsed().as_secs_f64());
        let source_gaps = source.as_ref().map_or(0, |s| s.gaps);
        let span = match (self.first_frame, self.last_frame) {
            (Some(a), Some(b)) => (b - a + 1) as i64,
            _ => 0,
        };
        let mut lost = result.lost;
        lost.truncate(10_000);
        let report = RecordReport {
            folder: self.root.clone(),
            frames_received: self.received,
            frames_written: written,
            frames_dropped_queue_full: self.dropped,
            frames_failed_write: failed,
            lost_frames: lost,
            first_frame: self.first_frame,
            last_frame: self.last_frame,
            source_gaps,
            frames_unaccounted: span - (written + self.dropped + failed + source_gaps) as i64,
            queue_frames: self.params.queue_frames,
            queue_high_water: self.high_water,
            writers: self.params.writers,
            elapsed_s,
            written_fps: if elapsed_s > 0.0 {
                written as f64 / elapsed_s
            } else {
                0.0
            },
            source,
        };
        let path = self.root.join("record_report.json");
        let json = serde_json::to_string_pretty(&report).map_err(|e| io_err(&path, e))?;
        write_text_atomically(&path, &(json + "\n"))?;
        if self.dropped + failed > 0 {
            tracing::error!(
                "recorder: {} frames lost ({} dropped with the queue full, {} failed to write); see {}",
                self.dropped + failed,
                self.dropped,
                failed,
                path.display()
            );
        }
        Ok(report)
    }
}

impl Drop for Recorder {
    fn drop(&mut self) {
        // Without `finish` (an early return): still let the writers and the collector
        // complete what was queued, so the folder stays a valid session.
        self.jobs = None;
        for w in self.writers.drain(..) {
            let _ = w.join();
        }
        self.collector_tx = None;
        if let Some(c) = self.collector.take() {
            let _ = c.join();
        }
    }
}

/// Encodes an 8-bit grayscale PNG into memory (fast compression).
fn encode_png(image: &GrayImage) -> Result<Vec<u8>, String> {
    let mut out = Vec::with_capacity(image.data.len() / 2);
    let mut enc = png::Encoder::new(&mut out, image.width, image.height);
    enc.set_color(png::ColorType::Grayscale);
    enc.set_depth(png::BitDepth::Eight);
    enc.set_compression(png::Compression::Fast);
    // The "up" filter for every row: replay decodes it several times faster than the
    // adaptive choice (mostly Paeth on camera noise), for files a few percent larger.
    enc.set_filter(png::Filter::Up);
    let mut w = enc.write_header().map_err(|e| e.to_string())?;
    w.write_image_data(&image.data).map_err(|e| e.to_string())?;
    w.finish().map_err(|e| e.to_string())?;
    Ok(out)
}

/// Writes `bytes` to a temporary sibling and renames it to `path` (no sync: see the
/// module docs).
fn write_file_renamed(path: &Path, bytes: &[u8]) -> Result<(), String> {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let tmp = path.with_file_name(format!(".{name}.tmp"));
    std::fs::write(&tmp, bytes)
        .and_then(|()| std::fs::rename(&tmp, path))
        .map_err(|e| {
            let _ = std::fs::remove_file(&tmp);
            format!("{}: {e}", path.display())
        })
}

fn writer_loop(
    root: &Path,
    cameras: &[String; 2],
    jobs: &Receiver<Job>,
    collector: &Sender<CollectorMsg>,
    delay: Duration,
) {
    for job in jobs {
        if !delay.is_zero() {
            std::thread::sleep(delay);
        }
        let mut result = Ok(());
        for (cam, image) in cameras.iter().zip(&job.images) {
            let path = root.join(cam).join(format!("{:06}.png", job.index));
            if let Err(e) = encode_png(image).and_then(|bytes| write_file_renamed(&path, &bytes)) {
                result = Err(e);
                break;
            }
        }
        if collector
            .send(CollectorMsg::Done(job.index, result))
            .is_err()
        {
            return;
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum RowState {
    Pending,
    Written,
    Lost,
}

/// Appends `text` to `file` with one write (whole rows only).
fn append(file: &mut std::fs::File, path: &Path, text: &str) -> Result<(), RecordError> {
    file.write_all(text.as_bytes()).map_err(|e| io_err(path, e))
}

fn collector_loop(
    root: &Path,
    header: &SessionHeader,
    rx: &Receiver<CollectorMsg>,
    counters: &Counters,
    sync_every: Duration,
) -> Result<CollectorResult, RecordError> {
    let frames_path = root.join("frames.csv");
    let sync_path = root.join("sync.csv");
    let open = |p: &Path| {
        std::fs::OpenOptions::new()
            .append(true)
            .open(p)
            .map_err(|e| io_err(p, e))
    };
    let mut frames_file = open(&frames_path)?;
    let mut sync_file = open(&sync_path)?;
    let mut pending: std::collections::VecDeque<(RowMeta, RowState)> = Default::default();
    let mut early: std::collections::HashMap<usize, RowState> = Default::default();
    let mut lost = Vec::new();
    let mut start_written = false;
    let mut last_sync = Instant::now();
    let mut unsynced = false;
    let mut logged_failures = 0u32;
    let mut disconnected = false;
    while !disconnected {
        let first = match rx.recv_timeout(Duration::from_millis(200)) {
            Ok(m) => Some(m),
            Err(crossbeam_channel::RecvTimeoutError::Timeout) => None,
            Err(crossbeam_channel::RecvTimeoutError::Disconnected) => {
                disconnected = true;
                None
            }
        };
        let mut batch: Vec<CollectorMsg> = first.into_iter().collect();
        batch.extend(rx.try_iter());
        for msg in batch {
            match msg {
                CollectorMsg::Accepted(meta) => {
                    let state = early.remove(&meta.index).unwrap_or(RowState::Pending);
                    pending.push_back((meta, state));
                }
                CollectorMsg::Dropped(index) => {
                    mark(&mut pending, &mut early, index, RowState::Lost)
                }
                CollectorMsg::Done(index, Ok(())) => {
                    mark(&mut pending, &mut early, index, RowState::Written);
                }
                CollectorMsg::Done(index, Err(e)) => {
                    counters.failed.fetch_add(1, Ordering::Relaxed);
                    logged_failures += 1;
                    if logged_failures <= 10 || logged_failures.is_multiple_of(100) {
                        tracing::error!(
                            "recorder: frame {index} not written: {e} ({} failed so far)",
                            counters.failed.load(Ordering::Relaxed)
                        );
                    }
                    // Remove a half-written pair so the folder holds only complete frames.
                    for cam in &header.cameras {
                        let _ =
                            std::fs::remove_file(root.join(cam).join(format!("{index:06}.png")));
                    }
                    mark(&mut pending, &mut early, index, RowState::Lost);
                }
            }
        }
        let mut frames_rows = String::new();
        let mut sync_rows = String::new();
        let mut first_timecode = None;
        while let Some((_, state)) = pending.front() {
            if *state == RowState::Pending {
                break;
            }
            let Some((meta, state)) = pending.pop_front() else {
                break;
            };
            if state == RowState::Lost {
                lost.push(meta.index);
                continue;
            }
            counters.written.fetch_add(1, Ordering::Relaxed);
            let tc = meta.timecode.map(|t| t.to_string()).unwrap_or_default();
            frames_rows.push_str(&format!("{},{},{tc}\n", meta.index, meta.timestamp_ns));
            let trigger = meta
                .stamp
                .trigger
                .map(|t| t.to_string())
                .unwrap_or_default();
            let clock = meta.stamp.clock.map(|c| c.to_string()).unwrap_or_default();
            sync_rows.push_str(&format!("{},{trigger},{clock}\n", meta.index));
            if !start_written && first_timecode.is_none() {
                first_timecode = Some(meta.timecode);
            }
        }
        if !frames_rows.is_empty() {
            append(&mut frames_file, &frames_path, &frames_rows)?;
            append(&mut sync_file, &sync_path, &sync_rows)?;
            unsynced = true;
        }
        if let Some(tc) = first_timecode {
            start_written = true;
            let toml = session_toml(header, tc.as_ref());
            write_text_atomically(&root.join("session.toml"), &toml)?;
        }
        if unsynced && (disconnected || last_sync.elapsed() >= sync_every) {
            frames_file
                .sync_data()
                .map_err(|e| io_err(&frames_path, e))?;
            sync_file.sync_data().map_err(|e| io_err(&sync_path, e))?;
            last_sync = Instant::now();
            unsynced = false;
        }
    }
    Ok(CollectorResult { lost })
}

fn mark(
    pending: &mut std::collections::VecDeque<(RowMeta, RowState)>,
    early: &mut std::collections::HashMap<usize, RowState>,
    index: usize,
    state: RowState,
) {
    match pending.iter_mut().rev().find(|(m, _)| m.index == index) {
        Some((_, s)) => *s = state,
        None => {
            early.insert(index, state);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::capture::live::{
        CameraDevice, LiveParams, LiveSource, LiveTimecode, TestCamera, TestFaults, TestImages,
        test_pattern,
    };
    use crate::capture::{Replay, ReplayParams};

    fn live_source(frames: usize, fps: f64, faults: TestFaults) -> LiveSource {
        let start = Instant::now() + Duration::from_millis(20);
        let mk = |i: u8, f: TestFaults| -> Box<dyn CameraDevice> {
            Box::new(TestCamera::new(
                &format!("test cam{i}"),
                TestImages::Pattern {
                    width: 32,
                    height: 24,
                    frames,
                    camera: i,
                },
                fps,
                start,
                f,
            ))
        };
        LiveSource::new(
            [mk(0, TestFaults::default()), mk(1, faults)],
            fps,
            LiveParams {
                camera_queue: 1000,
                ..Default::default()
            },
            None,
            None,
            LiveTimecode {
                rate: TimecodeRate::FPS_30,
                frame_delay: Duration::ZERO,
            },
        )
        .unwrap()
    }

    fn header(rig: Option<StereoRig>) -> SessionHeader {
        SessionHeader {
            fps: 60.0,
            cameras: ["cam0".into(), "cam1".into()],
            timecode_rate: Some(TimecodeRate::FPS_30),
            calibration: rig,
        }
    }

    fn record(src: &mut LiveSource, rec: &mut Recorder) {
        while let Some(f) = src.next_stamped() {
            let f = f.unwrap();
            rec.push(
                f.frame,
                FrameStamp {
                    trigger: f.trigger,
                    clock: Some(f.clock),
                },
            );
        }
    }

    #[test]
    fn records_a_session_that_replays_frame_for_frame() {
        let dir = tempfile::tempdir().unwrap();
        let root = dir.path().join("take1");
        let faults = TestFaults {
            corrupt: vec![4],
            ..Default::default()
        };
        let mut src = live_source(24, 60.0, faults);
        let mut rec = Recorder::create(&root, header(None), RecorderParams::default()).unwrap();
        let mut stamps = Vec::new();
        while let Some(f) = src.next_stamped() {
            let f = f.unwrap();
            stamps.push((
                f.frame.index.as_usize(),
                f.frame.timestamp_ns,
                f.frame.timecode,
            ));
            rec.push(
                f.frame,
                FrameStamp {
                    trigger: f.trigger,
                    clock: Some(f.clock),
                },
            );
        }
        let report = rec.finish(Some(src.stats())).unwrap();
        assert_eq!(report.frames_written, 23);
        assert_eq!(report.source_gaps, 1);
        assert_eq!(report.frames_unaccounted, 0);
        assert!(report.lost_frames.is_empty());

        let replay = Replay::open(&root, ReplayParams::default()).unwrap();
        assert_eq!(replay.info().fps, 60.0);
        assert_eq!(replay.info().timecode_rate, Some(TimecodeRate::FPS_30));
        let frames: Vec<_> = replay.map(Result::unwrap).collect();
        assert_eq!(frames.len(), 23);
        for (f, (index, ts, tc)) in frames.iter().zip(&stamps) {
            assert_eq!((f.index.as_usize(), f.timestamp_ns), (*index, *ts));
            assert_eq!(f.timecode.map(|t| t.to_string()), tc.map(|t| t.to_string()));
            assert_eq!(f.images[0], test_pattern(32, 24, *index, 0));
            assert_eq!(f.images[1], test_pattern(32, 24, *index, 1));
        }
        assert!(!frames.iter().any(|f| f.index.get() == 4));
        let toml = std::fs::read_to_string(root.join("session.toml")).unwrap();
        let start = stamps[0].2.unwrap().to_string();
        assert!(toml.contains(&format!("start = \"{start}\"")), "{toml}");
        let sync = std::fs::read_to_string(root.join("sync.csv")).unwrap();
        assert_eq!(sync.lines().count(), 24);
        assert!(sync.lines().nth(1).unwrap().ends_with(",,local"));
        let json: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(root.join("record_report.json")).unwrap(),
        )
        .unwrap();
        assert_eq!(json["frames_written"], 23);
        assert_eq!(json["source"]["cameras"][1]["bad_frames"], 1);
        // A second recording into the same folder is refused.
        let e = Recorder::create(&root, header(None), RecorderParams::default()).unwrap_err();
        assert!(e.to_string().contains("already holds a recording"), "{e}");
    }

    #[test]
    fn a_slow_disk_drops_counted_frames_and_the_session_stays_valid() {
        let dir = tempfile::tempdir().unwrap();
        let root = dir.path().join("slow");
        let params = RecorderParams {
            queue_frames: 4,
            writers: 1,
            simulated_write_delay: Duration::from_millis(30),
            ..Default::default()
        };
        let mut src = live_source(60, 120.0, TestFaults::default());
        let mut rec = Recorder::create(&root, header(None), params).unwrap();
        // While recording, the session is readable at every moment: every listed frame
        // has both images.
        let done = Arc::new(std::sync::atomic::AtomicBool::new(false));
        let checker = {
            let (root, done) = (root.clone(), done.clone());
            std::thread::spawn(move || {
                let mut checks = 0;
                while !done.load(Ordering::Relaxed) {
                    match Replay::open(&root, ReplayParams::default()) {
                        Ok(r) => {
                            for f in r {
                                f.unwrap();
                            }
                            checks += 1;
                        }
                        Err(e) => assert!(e.to_string().contains("no frames"), "{e}"),
                    }
                }
                checks
            })
        };
        record(&mut src, &mut rec);
        let report = rec.finish(Some(src.stats())).unwrap();
        done.store(true, Ordering::Relaxed);
        assert!(checker.join().unwrap() > 0);
        assert!(report.frames_dropped_queue_full > 0, "{report:?}");
        assert_eq!(
            report.frames_written + report.frames_dropped_queue_full,
            60,
            "every frame written or counted"
        );
        assert_eq!(
            report.lost_frames.len() as u64,
            report.frames_dropped_queue_full
        );
        assert_eq!(report.frames_unaccounted, 0);
        assert!(report.queue_high_water <= 4);
        let replay = Replay::open(&root, ReplayParams::default()).unwrap();
        let written: Vec<usize> = replay
            .info()
            .frames
            .iter()
            .map(|f| f.0.as_usize())
            .collect();
        assert_eq!(written.len() as u64, report.frames_written);
        assert!(written.iter().all(|i| !report.lost_frames.contains(i)));
        for f in Replay::open(&root, ReplayParams::default()).unwrap() {
            let f = f.unwrap();
            assert_eq!(f.images[1], test_pattern(32, 24, f.index.as_usize(), 1));
        }
        // No stray temporary files.
        let stray = std::fs::read_dir(root.join("cam0"))
            .unwrap()
            .filter(|e| {
                e.as_ref()
                    .unwrap()
                    .file_name()
                    .to_string_lossy()
                    .starts_with('.')
            })
            .count();
        assert_eq!(stray, 0);
    }

    #[test]
    fn write_failures_are_counted_and_leave_no_half_frames() {
        let dir = tempfile::tempdir().unwrap();
        let root = dir.path().join("fail");
        let rig = crate::camera::default_helmet_rig().unwrap();
        let mut rec =
            Recorder::create(&root, header(Some(rig.clone())), RecorderParams::default()).unwrap();
        let frame = |index: usize| StereoFrame {
            index: index.into(),
            timestamp_ns: index as u64 * 16_666_667,
            timecode: None,
            images: [test_pattern(8, 4, index, 0), test_pattern(8, 4, index, 1)],
        };
        rec.push(frame(0), FrameStamp::default());
        // Wait for frame 0, then make cam1's folder unwritable by replacing it with a file.
        let end = Instant::now() + Duration::from_secs(10);
        while rec.counts().1 < 1 && Instant::now() < end {
            std::thread::sleep(Duration::from_millis(5));
        }
        std::fs::rename(root.join("cam1"), root.join("cam1.bak")).unwrap();
        std::fs::write(root.join("cam1"), b"not a folder").unwrap();
        rec.push(frame(1), FrameStamp::default());
        rec.push(frame(2), FrameStamp::default());
        let report = rec.finish(None).unwrap();
        assert_eq!((report.frames_written, report.frames_failed_write), (1, 2));
        assert_eq!(report.lost_frames, vec![1, 2]);
        assert!(!root.join("cam0/000001.png").exists());
        let csv = std::fs::read_to_string(root.join("frames.csv")).unwrap();
        assert_eq!(csv, "frame,timestamp_ns,timecode\n0,0,\n");
        // The calibration is copied and named by the session.
        let copy = crate::camera::read_rig(&root.join("calibration.yaml")).unwrap();
        assert_eq!(copy.cam0.width_px, rig.cam0.width_px);
        let toml = std::fs::read_to_string(root.join("session.toml")).unwrap();
        assert!(
            toml.contains("calibration = \"calibration.yaml\""),
            "{toml}"
        );
    }
}
