//! `helmcap replay SESSION`: a recorded session through the whole pipeline (detection,
//! labeling, triangulation, stabilization, dense solve, optional enhancement) into an
//! output folder, with a progress bar and a summary.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::{Context, bail};
use helmcap::capture::{FrameSource, Replay, ReplayParams};
use helmcap::dataset::Dataset;
use helmcap::farm::{Fingerprint, TakeManifest, list_outputs, session_fingerprint};
use helmcap::frame_index::FrameIndex;
use helmcap::pipeline::{
    FrameResult, GroundTruth, LabelRestarts, Metrics, PipelineConfig, SessionMeta, Sink, SinkError,
};
use helmcap::sink::TakeDir;
use helmcap::track::CaptureProfile;

use super::take::{TakeArgs, print_summary, stop_flag};

/// Arguments of `helmcap replay`.
#[derive(Debug, clap::Args)]
pub struct ReplayArgs {
    /// Recording session folder (session.toml, frames.csv, cam0/, cam1/).
    pub session: PathBuf,
    /// Calibration YAML (default: the one session.toml names).
    #[arg(long, value_name = "YAML")]
    pub calib: Option<PathBuf>,
    /// Output folder (bundles.csv, head_pose.csv, tracks.csv, metrics.json, exports). It
    /// holds one take: a folder with files is refused unless --overwrite.
    #[arg(long, short, default_value = "out/replay")]
    pub out: PathBuf,
    /// The options every take has (profile, dataset, exports, stages, caches).
    #[command(flatten)]
    pub take: TakeArgs,
    /// Frames to process: `A..B` (B excluded), `A..=B`, `A..` or `..B`, frame numbers of
    /// frames.csv; for splitting long takes.
    #[arg(long, value_name = "RANGE")]
    pub frames: Option<String>,
    /// Frames to run before --frames' first without writing them: they warm up tracking,
    /// stabilization and the solve's temporal preference, so a chunk of a long take
    /// starts as a single pass over the whole take would be at that frame.
    #[arg(long, value_name = "N", default_value_t = 0, requires = "frames")]
    pub warm_up: usize,
    /// Start labeling again from nothing on the frames where the warm-ups of a farm job's
    /// chunks of N frames start (`first + k·N − --relabel-lead`, `first` the take's first
    /// frame). A chunk starts labeling from nothing, so the chunks of `farm job --chunk N
    /// --overlap W` (which pass this with `--relabel-lead W`) merge into exactly what one
    /// replay with these options writes.
    #[arg(long, value_name = "N")]
    pub relabel_every: Option<usize>,
    /// With --relabel-every: frames before each chunk boundary where labeling restarts
    /// (the farm job's warm-up).
    #[arg(
        long,
        value_name = "W",
        default_value_t = 0,
        requires = "relabel_every"
    )]
    pub relabel_lead: usize,
    /// Skip unreadable frames (counted as gaps) instead of stopping at the first one.
    #[arg(long)]
    pub skip_bad_frames: bool,
    /// No progress bar.
    #[arg(long)]
    pub quiet: bool,
}

/// Parses `A..B`, `A..=B`, `A..`, `..B` into an inclusive range.
pub fn parse_frame_range(s: &str) -> anyhow::Result<std::ops::RangeInclusive<usize>> {
    let bad = || anyhow::anyhow!("--frames {s:?}: expected A..B, A..=B, A.. or ..B");
    let (a, b) = s.split_once("..").ok_or_else(bad)?;
    let start = if a.is_empty() {
        0
    } else {
        a.trim().parse().map_err(|_| bad())?
    };
    let end = if let Some(b) = b.strip_prefix('=') {
        b.trim().parse::<usize>().map_err(|_| bad())?
    } else if b.is_empty() {
        usize::MAX
    } else {
        b.trim()
            .parse::<usize>()
            .map_err(|_| bad())?
            .checked_sub(1)
            .ok_or_else(bad)?
    };
    if end < start {
        bail!("--frames {s:?} is empty");
    }
    Ok(start..=end)
}

/// Shows progress on the terminal (a sink like the others).
struct ProgressSink {
    bar: indicatif::ProgressBar,
}

impl Sink for ProgressSink {
    fn name(&self) -> &str {
        "progress"
    }

    fn begin(&mut self, session: &SessionMeta) -> Result<(), SinkError> {
        if let Some(n) = session.frame_count {
            self.bar.set_length(n as u64);
        }
        Ok(())
    }

    fn write(&mut self, f: &FrameResult) -> Result<(), SinkError> {
        self.bar.inc(1);
        if f.index.get().is_multiple_of(10) {
            let labeled = f.count(helmcap::pipeline::BundleStatus::Observed);
            self.bar
                .set_message(format!("frame {} · {labeled} markers", f.index));
        }
        Ok(())
    }

    fn finish(&mut self, _metrics: &Metrics) -> Result<(), SinkError> {
        self.bar.finish_and_clear();
        Ok(())
    }
}

/// Everything a replay run produced, for summaries.
pub struct ReplayOutcome {
    /// The take's metrics.
    pub metrics: Metrics,
    /// Files written.
    pub outputs: Vec<PathBuf>,
}

/// Runs the replay described by `args`; the result holds the metrics (also in
/// `metrics.json`).
pub fn replay(args: &ReplayArgs) -> anyhow::Result<ReplayOutcome> {
    let mut source = Replay::open(
        &args.session,
        ReplayParams {
            skip_bad_frames: args.skip_bad_frames,
            calibration: args.calib.clone(),
            ..ReplayParams::default()
        },
    )
    .with_context(|| format!("opening session {}", args.session.display()))?;
    let take_frames = match (source.info().frames.first(), source.info().frames.last()) {
        (Some(a), Some(b)) => (a.0.as_usize(), b.0.as_usize()),
        _ => bail!("session {} has no frames", args.session.display()),
    };
    let mut written = take_frames;
    let mut warm_up_from = None;
    if let Some(r) = &args.frames {
        let range = parse_frame_range(r)?;
        let in_range = |i: usize| range.contains(&i);
        let frames = &source.info().frames;
        let (Some(first), Some(last)) = (
            frames.iter().map(|f| f.0.as_usize()).find(|&i| in_range(i)),
            frames
                .iter()
                .map(|f| f.0.as_usize())
                .rfind(|&i| in_range(i)),
        ) else {
            bail!(
                "--frames {r}: the session has no frame in {}..={}",
                range.start(),
                range.end()
            );
        };
        written = (*range.start(), (*range.end()).min(take_frames.1));
        let run_from = range.start().saturating_sub(args.warm_up);
        source.select_frames(FrameIndex::from(run_from)..=FrameIndex::from(last));
        if args.warm_up > 0 {
            warm_up_from = source
                .info()
                .frames
                .first()
                .map(|f| f.0.as_usize())
                .filter(|&f| f < first);
        }
    }
    let rig = source
        .rig()
        .cloned()
        .context("the session names no calibration; pass --calib")?;
    let info = source.info().clone();
    // One take per folder, one run per folder (held until the take is written).
    let _take = TakeDir::claim(&args.out, args.take.overwrite)?;
    let spec = args.take.spec();
    let take = spec.load()?;
    let profile = spec.load_profile(info.profile.as_deref())?;
    source.set_gray_conversion(profile.gray_conversion());
    let mut config = spec.pipeline_config(&take, rig, &profile);
    let take_name = args
        .session
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "take".into());
    config.take.name = take_name.clone();
    config.take.timecode_rate = info.timecode_rate;
    config.take.write_from = FrameIndex::from(written.0);
    config.take.frame_count = Some(
        info.frames
            .iter()
            .filter(|f| (written.0..=written.1).contains(&f.0.as_usize()))
            .count(),
    );
    config.take.first_frame = FrameIndex::from(written.0);
    config.track.label_restarts = match args.relabel_every {
        Some(0) => bail!("--relabel-every must be at least 1 frame"),
        Some(n) => LabelRestarts::of_chunks(
            FrameIndex::from(take_frames.0),
            n as u64,
            args.relabel_lead as u64,
        ),
        None => None,
    };
    let settings = settings_fingerprint(args, &config, &take.dataset, &profile)?;
    let markers: Vec<String> = take.layout.markers.iter().map(|m| m.name.clone()).collect();
    if let Some(stages) = spec.dense_stages(&take)? {
        stages.install(&mut config, &take.dataset);
    }
    config.ground_truth = GroundTruth::load(&args.session, &take.layout)
        .with_context(|| format!("reading ground truth of {}", args.session.display()))?
        .map(Arc::new);

    let out = &args.out;
    let (mut sinks, mut outputs) = spec.sinks(&mut config, &take, out)?;
    if !args.quiet {
        let bar = indicatif::ProgressBar::new(config.take.frame_count.unwrap_or(0) as u64);
        bar.set_style(
            indicatif::ProgressStyle::with_template(
                "replay [{bar:30}] {pos}/{len} frames {per_sec} {msg}",
            )
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
        );
        sinks.push(Box::new(ProgressSink { bar }));
    }
    let stop = stop_flag();
    let source: Box<dyn FrameSource> = Box::new(source);
    let fps = source.fps();
    let result = helmcap::pipeline::run(source, config, sinks, stop);
    match result {
        Ok(metrics) => {
            // Written last: its presence says the take is complete (see farm::manifest).
            if metrics.stopped.is_none()
                && let Some(collector) = metrics.collector.as_deref()
            {
                let manifest = TakeManifest {
                    format: helmcap::farm::manifest::MANIFEST_FORMAT.into(),
                    helmcap: env!("CARGO_PKG_VERSION").into(),
                    take: take_name,
                    session: std::path::absolute(&args.session)
                        .unwrap_or_else(|_| args.session.clone()),
                    session_fingerprint: session_fingerprint(&args.session)
                        .with_context(|| format!("reading session {}", args.session.display()))?,
                    settings_fingerprint: settings,
                    take_frames,
                    frames: written,
                    warm_up_from,
                    fps,
                    markers,
                    wall_secs: metrics.wall_secs,
                    files: list_outputs(out)
                        .with_context(|| format!("listing {}", out.display()))?,
                    metrics: collector.clone(),
                };
                manifest.write(out)?;
                outputs.push(out.join(helmcap::farm::MANIFEST_FILE));
            }
            Ok(ReplayOutcome { metrics, outputs })
        }
        Err(e) => Err(anyhow::Error::new(e).context(format!(
            "replay of {} stopped; the outputs in {} hold the frames completed before the error",
            args.session.display(),
            out.display()
        ))),
    }
}

/// Fingerprint of everything that shapes a take's outputs besides its frames: the
/// calibration, capture settings, layout, dataset, solve settings, exports and flags, by
/// value (not by path: the same files mounted elsewhere give the same fingerprint).
fn settings_fingerprint(
    args: &ReplayArgs,
    config: &PipelineConfig,
    ds: &Dataset,
    profile: &CaptureProfile,
) -> anyhow::Result<String> {
    let mut fp = Fingerprint::default();
    fp.add(format!("{:?}", config.rig).as_bytes())
        .add(format!("{profile:?}").as_bytes())
        .add(format!("{:?}", config.layout).as_bytes())
        .add(ds.name.as_bytes())
        .add(&ds.neutral.vertex_count().to_le_bytes());
    let manifest = Path::new(&args.take.dataset);
    if manifest.is_file() {
        fp.add_file(manifest)
            .with_context(|| format!("reading {}", manifest.display()))?;
    } else {
        fp.add(args.take.dataset.as_bytes());
    }
    let mut exports = args.take.export.clone();
    exports.sort_by_key(|e| format!("{e:?}"));
    exports.dedup();
    let lgi = if args.take.no_solve {
        None
    } else {
        Some(args.take.solve_stage.spec().lgi_params()?)
    };
    fp.add(
        format!(
            "{exports:?} {lgi:?} keyframes={} relabel={:?}/{} enhance={} no_solve={} \
             skip_bad_frames={} rig={:?}",
            args.take.solve_stage.solve_keyframes,
            args.relabel_every,
            args.relabel_lead,
            args.take.enhance,
            args.take.no_solve,
            args.skip_bad_frames,
            args.take.rig_stage
        )
        .as_bytes(),
    );
    Ok(fp.hex())
}

pub fn run(args: ReplayArgs) -> anyhow::Result<()> {
    let outcome = replay(&args)?;
    print_summary(&outcome.metrics, &outcome.outputs);
    if let Some(reason) = &outcome.metrics.stopped {
        eprintln!("stopped early: {reason}");
    }
    Ok(())
}
