//! `helmcap live`: the pipeline on the live cameras (or test cameras), with the same outputs
//! as `helmcap replay`; frames the pipeline cannot take in time are dropped at the source
//! and counted.

use std::path::PathBuf;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::Context;
use helmcap::camera::StereoRig;
use helmcap::capture::{CaptureError, FrameSource, LiveSource, LiveStats, StereoFrame};
use helmcap::frame_index::FrameIndex;
use helmcap::pipeline::GroundTruth;

use super::take::{TakeArgs, print_summary, stop_flag};

/// Arguments of `helmcap live`.
#[derive(Debug, clap::Args)]
pub struct LiveArgs {
    /// Live config: cameras, sync box, queues (see configs/live.toml).
    #[arg(long, short, default_value = "configs/live.toml")]
    pub config: PathBuf,
    /// Use test cameras replaying this recording session at real-time pace instead of the
    /// configured cameras (its ground truth, if any, is used for accuracy figures).
    #[arg(long, value_name = "SESSION")]
    pub test_source: Option<PathBuf>,
    /// Serial port of the sync box, overriding the config's `[syncbox] port`.
    #[arg(long, value_name = "PORT")]
    pub sync_port: Option<String>,
    /// Output folder (bundles.csv, head_pose.csv, tracks.csv, metrics.json,
    /// live_stats.json, exports).
    #[arg(long, short, default_value = "out/live")]
    pub out: PathBuf,
    /// The options every take has (profile, dataset, exports, stages, caches).
    #[command(flatten)]
    pub take: TakeArgs,
    /// Stop after this many stereo frames from the cameras.
    #[arg(long, conflicts_with = "seconds")]
    pub frames: Option<usize>,
    /// Stop after this many seconds.
    #[arg(long)]
    pub seconds: Option<f64>,
}

/// The live source, stopped after a frame count or a duration, publishing its counters.
struct LimitedLive {
    source: LiveSource,
    max_frames: Option<usize>,
    deadline: Option<Instant>,
    frames: usize,
    stats: Arc<Mutex<LiveStats>>,
}

impl LimitedLive {
    fn publish(&self) {
        if let Ok(mut s) = self.stats.lock() {
            *s = self.source.stats();
        }
    }
}

impl FrameSource for LimitedLive {
    fn next_frame(&mut self) -> Option<Result<StereoFrame, CaptureError>> {
        if self.max_frames.is_some_and(|n| self.frames >= n)
            || self.deadline.is_some_and(|d| Instant::now() >= d)
        {
            self.publish();
            return None;
        }
        let next = self.source.next_frame();
        self.frames += 1;
        if next.as_ref().is_none_or(Result::is_err) || self.frames.is_multiple_of(30) {
            self.publish();
        }
        next
    }

    fn fps(&self) -> f64 {
        self.source.fps()
    }

    fn is_live(&self) -> bool {
        true
    }

    fn rig(&self) -> Option<&StereoRig> {
        self.source.rig()
    }

    fn gaps(&self) -> usize {
        self.source.gaps()
    }
}

/// Runs `helmcap live`.
pub fn run(args: LiveArgs) -> anyhow::Result<()> {
    if let Some(s) = args.seconds
        && !(s > 0.0 && s <= helmcap::limits::MAX_TAKE_SECONDS)
    {
        anyhow::bail!(
            "--seconds {s} must be above 0 and at most {} (a week)",
            helmcap::limits::MAX_TAKE_SECONDS
        );
    }
    let live_config = super::record::load_config(&args.config, args.sync_port.as_deref())?;
    // A bad profile is an error before anything slow starts.
    let spec = args.take.spec();
    let profile = spec.load_profile(None)?;
    let take = spec.load()?;
    let ground_truth = match &args.test_source {
        Some(session) => GroundTruth::load(session, &take.layout)
            .with_context(|| format!("reading ground truth of {}", session.display()))?
            .map(Arc::new),
        None => None,
    };
    let dense = spec.dense_stages(&take)?;

    // One take per folder, one run per folder (held until the take is written).
    let _take_dir = helmcap::sink::TakeDir::claim(&args.out, args.take.overwrite)?;

    // The cameras start last, once everything slow is built.
    let stop = stop_flag();
    let mut source = live_config
        .open_source(args.test_source.as_deref())
        .context("opening the live source")?;
    source.set_stop_flag(stop.clone());
    let rig = source
        .rig()
        .cloned()
        .context("the live config names no calibration (`calibration = ...`)")?;
    let mut config = spec.pipeline_config(&take, rig, &profile);
    config.take.name = "live".into();
    config.take.timecode_rate = Some(source.timecode_rate());
    config.take.frame_count = args.frames;
    config.take.first_frame = FrameIndex::new(0);
    config.ground_truth = ground_truth;
    if let Some(stages) = dense {
        stages.install(&mut config, &take.dataset);
    }

    let out = &args.out;
    let (sinks, mut outputs) = spec.sinks(&mut config, &take, out)?;
    outputs.push(out.join("live_stats.json"));
    let stats = Arc::new(Mutex::new(source.stats()));
    let limited = LimitedLive {
        source,
        max_frames: args.frames,
        deadline: args
            .seconds
            .map(|s| Instant::now() + Duration::from_secs_f64(s)),
        frames: 0,
        stats: stats.clone(),
    };
    let result = helmcap::pipeline::run(Box::new(limited), config, sinks, stop);
    let stats = stats.lock().map(|s| s.clone()).unwrap_or_default();
    let stats_path = out.join("live_stats.json");
    let json = serde_json::to_string_pretty(&stats)?;
    helmcap::atomic_file::write_atomically(&stats_path, |w| {
        std::io::Write::write_all(w, (json + "\n").as_bytes())
    })
    .with_context(|| format!("writing {}", stats_path.display()))?;
    let metrics = result.map_err(|e| {
        anyhow::Error::new(e).context(format!(
            "live run stopped; outputs so far are in {}",
            out.display()
        ))
    })?;
    print_summary(&metrics, &outputs);
    println!(
        "cameras: {} stereo frames, {} gaps; timecode: {} frames from the sync box, {} from the local clock, {} switches",
        stats.frames_out,
        stats.gaps,
        stats.stamped_syncbox,
        stats.stamped_local,
        stats.clock_switches
    );
    if let Some(reason) = &metrics.stopped {
        eprintln!("stopped early: {reason}");
    }
    Ok(())
}
