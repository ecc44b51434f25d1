//! `helmcap record`: records the live cameras (and the sync box's timecode) into a session
//! folder.

use std::path::{Path, PathBuf};
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

use anyhow::Context;
use helmcap::capture::recorder::{FrameStamp, SessionHeader};
use helmcap::capture::{LiveConfig, LiveSource, Recorder, RecorderParams};

/// Arguments of `helmcap record`.
#[derive(Debug, clap::Args)]
pub struct RecordArgs {
    /// Live config: cameras, sync box, queues (see configs/live.toml).
    #[arg(long, short, default_value = "configs/live.toml")]
    pub config: PathBuf,
    /// Output session folder (created; must not hold a recording already).
    #[arg(long, short)]
    pub out: PathBuf,
    /// Stop after this many stereo frames.
    #[arg(long, conflicts_with = "seconds")]
    pub frames: Option<usize>,
    /// Stop after this many seconds.
    #[arg(long)]
    pub seconds: Option<f64>,
    /// Use test cameras replaying this recording session at real-time pace instead of the
    /// configured cameras (no hardware needed).
    #[arg(long, value_name = "SESSION")]
    pub test_source: Option<PathBuf>,
    /// Serial port of the sync box, overriding the config's `[syncbox] port`.
    #[arg(long, value_name = "PORT")]
    pub sync_port: Option<String>,
    /// Recorder queue, frames (overrides `[record] queue_frames`).
    #[arg(long)]
    pub queue_frames: Option<usize>,
    /// Simulate a slow disk: every frame's write takes this much longer, ms (drills, tests).
    #[arg(long, value_name = "MS", default_value_t = 0)]
    pub simulate_write_delay_ms: u64,
}

/// Loads the live config and applies the command-line overrides shared by `record` and
/// `live`.
pub fn load_config(path: &Path, sync_port: Option<&str>) -> anyhow::Result<LiveConfig> {
    let mut config = LiveConfig::load(path)?;
    if let Some(port) = sync_port {
        config.syncbox.get_or_insert_with(Default::default).port = port.to_string();
    }
    Ok(config)
}

/// Runs `helmcap record`.
pub fn run(args: RecordArgs) -> anyhow::Result<()> {
    if let Some(s) = args.seconds
        && !(s > 0.0 && s <= helmcap::limits::MAX_TAKE_SECONDS)
    {
        anyhow::bail!(
            "--seconds {s} must be above 0 and at most {} (a week)",
            helmcap::limits::MAX_TAKE_SECONDS
        );
    }
    let mut config = load_config(&args.config, args.sync_port.as_deref())?;
    if let Some(q) = args.queue_frames {
        anyhow::ensure!(
            (1..=helmcap::limits::MAX_QUEUE_FRAMES).contains(&q),
            "--queue-frames {q} must be 1 to {}",
            helmcap::limits::MAX_QUEUE_FRAMES
        );
        config.record.queue_frames = q;
    }
    let stop = super::take::stop_flag();
    let mut source: LiveSource = config
        .open_source(args.test_source.as_deref())
        .context("opening the live source")?;
    source.set_stop_flag(stop.clone());
    let header = SessionHeader {
        fps: helmcap::capture::FrameSource::fps(&source),
        cameras: ["cam0".into(), "cam1".into()],
        timecode_rate: Some(source.timecode_rate()),
        calibration: helmcap::capture::FrameSource::rig(&source).cloned(),
    };
    let params = RecorderParams {
        queue_frames: config.record.queue_frames,
        writers: config.record.writers,
        simulated_write_delay: Duration::from_millis(args.simulate_write_delay_ms),
        ..RecorderParams::default()
    };
    let mut recorder = Recorder::create(&args.out, header, params)
        .with_context(|| format!("creating the recording {}", args.out.display()))?;
    let deadline = args
        .seconds
        .map(|s| Instant::now() + Duration::from_secs_f64(s));
    let mut frames = 0usize;
    let mut last_status = Instant::now();
    let mut source_error = None;
    loop {
        if stop.load(Ordering::Relaxed)
            || args.frames.is_some_and(|n| frames >= n)
            || deadline.is_some_and(|d| Instant::now() >= d)
        {
            break;
        }
        match source.next_stamped() {
            None => break,
            Some(Err(e)) => {
                source_error = Some(e);
                break;
            }
            Some(Ok(f)) => {
                frames += 1;
                recorder.push(
                    f.frame,
                    FrameStamp {
                        trigger: f.trigger,
                        clock: Some(f.clock),
                    },
                );
            }
        }
        if last_status.elapsed() >= Duration::from_secs(2) {
            last_status = Instant::now();
            let (received, written, dropped, failed) = recorder.counts();
            let stats = source.stats();
            tracing::info!(
                "recording: {received} frames, {written} written, {dropped} dropped, {failed} failed, {} gaps; timecode: {} from the sync box, {} local",
                stats.gaps,
                stats.stamped_syncbox,
                stats.stamped_local
            );
        }
    }
    let stats = source.stats();
    drop(source);
    let report = recorder.finish(Some(stats.clone()))?;
    println!(
        "recorded {} frames to {} ({} dropped by the recorder, {} failed writes, {} camera gaps; timecode {} frames from the sync box, {} from the local clock)",
        report.frames_written,
        args.out.display(),
        report.frames_dropped_queue_full,
        report.frames_failed_write,
        report.source_gaps,
        stats.stamped_syncbox,
        stats.stamped_local
    );
    if let Some(sync) = &stats.syncbox {
        let p = &sync.parser;
        println!(
            "sync box: {} valid lines; rejected {} (bad checksum {}, malformed {}, partial {}, overlong {}, not UTF-8 {}); {} garbage bytes; {} read errors, {} opens, {} losses",
            p.lines_ok,
            p.bad_lines(),
            p.bad_checksums,
            p.malformed_lines,
            p.partial_lines,
            p.overlong_lines,
            p.non_utf8_lines,
            p.garbage_bytes,
            sync.read_errors,
            sync.opens,
            sync.losses
        );
    }
    match source_error {
        Some(e) => Err(anyhow::Error::new(e).context(format!(
            "recording stopped after {} frames (everything up to there is in {})",
            report.frames_written,
            args.out.display()
        ))),
        None => Ok(()),
    }
}
