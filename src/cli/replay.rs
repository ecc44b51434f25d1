//! `helmcap replay SESSION`: a recorded session through the whole pipeline (detection,
//! labeling, triangulation, stabilization, dense solve, optional enhancement) into an
//! output folder, with a progress bar and a summary.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, OnceLock};

use anyhow::{Context, bail};
use helmcap::capture::{FrameSource, Replay, ReplayParams};
use helmcap::dataset::{Dataset, MarkerLayout};
use helmcap::enhance::Enhancer;
use helmcap::farm::{Fingerprint, TakeManifest, list_outputs, session_fingerprint};
use helmcap::lgi::LgiParams;
use helmcap::pipeline::{
    FrameResult, GroundTruth, LabelRestarts, Metrics, PipelineConfig, SessionMeta, Sink, SinkError,
};
use helmcap::sink::TakeDir;
use helmcap::sink::{C3dSink, CsvSink, MeshFormat, MeshSequenceSink, MetricsSink, UsdSink};
use helmcap::solve::Solver;
use helmcap::track::CaptureProfile;
use nalgebra::Point3;

use super::{DatasetArgs, builtin_params};

/// An export format besides the CSV files and metrics (which are always written).
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Export {
    /// One OBJ per frame: `mesh/frame_NNNNNN.obj` (neutral topology and UVs, mm).
    Obj,
    /// One binary PLY per frame: `mesh/frame_NNNNNN.ply`.
    Ply,
    /// One USD file with time-sampled points: `mesh.usda`.
    Usd,
    /// The labeled bundles as C3D: `bundles.c3d`.
    C3d,
    /// Unreal's Live Link Face CSV of the rig weights: `livelink.csv` (rig: `--rig`, else
    /// the dataset).
    LivelinkCsv,
    /// UsdSkel blend-shape animation of the rig weights: `face_skel.usda` (rig: `--rig`,
    /// else the dataset).
    UsdSkel,
}

/// Arguments of `helmcap replay`.
#[derive(Debug, clap::Args)]
pub struct ReplayArgs {
    /// Recording session folder (session.toml, frames.csv, cam0/, cam1/).
    pub session: PathBuf,
    /// Calibration YAML (default: the one session.toml names).
    #[arg(long, value_name = "YAML")]
    pub calib: Option<PathBuf>,
    /// Capture profile: dot size, polarity, colour, detection and labeling settings
    /// (default: the one session.toml names, else the built-in defaults).
    #[arg(long, value_name = "TOML")]
    pub profile: Option<PathBuf>,
    /// Dataset manifest, or `builtin[:SEED]` for the built-in actor.
    #[arg(long, short = 'd', default_value = "builtin")]
    pub dataset: String,
    /// Marker layout CSV (default for the built-in actor: its shipped layout).
    #[arg(long, short = 'k', value_name = "CSV")]
    pub markers: Option<PathBuf>,
    /// Output folder (bundles.csv, head_pose.csv, tracks.csv, metrics.json, exports). It
    /// holds one take: a folder with files is refused unless --overwrite.
    #[arg(long, short, default_value = "out/replay")]
    pub out: PathBuf,
    /// Replace the take in --out: its files are removed before the run.
    #[arg(long)]
    pub overwrite: bool,
    /// Also save a rerun recording (.rrd) of the take (view it with `rerun FILE`).
    #[arg(long, value_name = "FILE")]
    pub rrd: Option<PathBuf>,
    /// Rerun viewer and logging options.
    #[command(flatten)]
    pub view: super::view::ViewerArgs,
    /// Export format (repeatable): obj, ply, usd, c3d, livelink-csv, usd-skel.
    #[arg(long, value_enum)]
    pub export: Vec<Export>,
    /// Rig solve per frame (`--rig`, `--name-map`, `--rig-smoothing`).
    #[command(flatten)]
    pub rig_stage: super::animate::RigStageArgs,
    /// Add the actor's fine detail to every solved mesh (Bermano et al. 2014).
    #[arg(long)]
    pub enhance: bool,
    /// Settings of the dense solve.
    #[command(flatten)]
    pub solve_stage: SolveStageArgs,
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
    /// Stop after labeling and stabilization (no dense solve, no meshes).
    #[arg(long)]
    pub no_solve: bool,
    /// Skip unreadable frames (counted as gaps) instead of stopping at the first one.
    #[arg(long)]
    pub skip_bad_frames: bool,
    /// Frames each stage channel holds.
    #[arg(long, default_value_t = 4)]
    pub queue: usize,
    /// Do not read or write the dataset and LGI index caches.
    #[arg(long)]
    pub no_cache: bool,
    /// Cache folder (default: $HELMCAP_CACHE_DIR, else ~/.cache/helmcap).
    #[arg(long, value_name = "DIR")]
    pub cache_dir: Option<PathBuf>,
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

/// The layout for `dataset` (a path, or the built-in actor's shipped layout).
pub fn load_layout(dataset: &str, markers: Option<&Path>) -> anyhow::Result<MarkerLayout> {
    match markers {
        Some(p) => {
            MarkerLayout::read_csv(p).with_context(|| format!("reading markers {}", p.display()))
        }
        None if builtin_params(dataset)?.is_some() => Ok(MarkerLayout::parse_csv(
            include_str!("../../configs/markers/builtin-actor.csv"),
            "builtin-actor.csv",
        )?),
        None => bail!("--markers is required with a dataset manifest"),
    }
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
        if f.index.is_multiple_of(10) {
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

/// Installs the Ctrl-C handler once per process; returns the stop flag it sets.
pub fn stop_flag() -> Arc<AtomicBool> {
    static FLAG: OnceLock<Arc<AtomicBool>> = OnceLock::new();
    FLAG.get_or_init(|| {
        let flag = Arc::new(AtomicBool::new(false));
        let f = flag.clone();
        if let Err(e) = ctrlc::set_handler(move || {
            if f.swap(true, Ordering::SeqCst) {
                // Second Ctrl-C: the user really wants out.
                std::process::exit(130);
            }
            eprintln!("\nstopping after the frames in flight (Ctrl-C again to abort)");
        }) {
            tracing::warn!("no Ctrl-C handler: {e}");
        }
        flag
    })
    .clone()
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
        (Some(a), Some(b)) => (a.0, b.0),
        _ => bail!("session {} has no frames", args.session.display()),
    };
    let mut written = take_frames;
    let mut warm_up_from = None;
    if let Some(r) = &args.frames {
        let range = parse_frame_range(r)?;
        let in_range = |i: usize| range.contains(&i);
        let frames = &source.info().frames;
        let (Some(first), Some(last)) = (
            frames.iter().map(|f| f.0).find(|&i| in_range(i)),
            frames.iter().map(|f| f.0).rfind(|&i| in_range(i)),
        ) else {
            bail!(
                "--frames {r}: the session has no frame in {}..={}",
                range.start(),
                range.end()
            );
        };
        written = (*range.start(), (*range.end()).min(take_frames.1));
        let run_from = range.start().saturating_sub(args.warm_up);
        source.select_frames(run_from..=last);
        if args.warm_up > 0 {
            warm_up_from = source
                .info()
                .frames
                .first()
                .map(|f| f.0)
                .filter(|&f| f < first);
        }
    }
    let rig = source
        .rig()
        .cloned()
        .context("the session names no calibration; pass --calib")?;
    let info = source.info().clone();
    // One take per folder, one run per folder (held until the take is written).
    let _take = TakeDir::claim(&args.out, args.overwrite)?;
    let dataset_args = DatasetArgs {
        dataset: args.dataset.clone(),
        no_cache: args.no_cache,
        cache_dir: args.cache_dir.clone(),
    };
    let (ds, layout, neutral_markers) =
        load_dataset_and_layout(&dataset_args, args.markers.as_deref())?;
    let profile = load_profile(args.profile.as_deref().or(info.profile.as_deref()))?;
    source.set_gray_conversion(profile.gray_conversion());
    let mut config = PipelineConfig::new(layout.clone(), Arc::new(neutral_markers), rig);
    config.detect = profile.detect_params(Some(&config.rig));
    config.label = profile.label_params();
    config.expression_templates = Arc::new(layout.expression_templates(&ds));
    config.channel_capacity = args.queue;
    let take_name = args
        .session
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "take".into());
    config.name = take_name.clone();
    config.timecode_rate = info.timecode_rate;
    config.write_from = written.0;
    config.frame_count = Some(
        info.frames
            .iter()
            .filter(|f| f.0 >= written.0 && f.0 <= written.1)
            .count(),
    );
    config.first_frame = written.0;
    config.label_restarts = match args.relabel_every {
        Some(0) => bail!("--relabel-every must be at least 1 frame"),
        Some(n) => LabelRestarts::of_chunks(take_frames.0, n, args.relabel_lead),
        None => None,
    };
    let settings = settings_fingerprint(args, &config, &ds, &profile)?;
    let markers: Vec<String> = layout.markers.iter().map(|m| m.name.clone()).collect();
    if let Some(stages) = dense_stages(
        &ds,
        &layout,
        &dataset_args,
        args.no_solve,
        args.enhance,
        &args.export,
        &args.solve_stage,
    )? {
        stages.install(&mut config, &ds);
    }
    config.ground_truth = GroundTruth::load(&args.session, &layout)
        .with_context(|| format!("reading ground truth of {}", args.session.display()))?
        .map(Arc::new);

    let out = &args.out;
    let (mut sinks, mut outputs) = file_sinks(out, &args.export);
    if let Some((sink, files)) = args.rig_stage.install(
        &mut config,
        &ds,
        &dataset_args,
        args.export.contains(&Export::LivelinkCsv),
        args.export.contains(&Export::UsdSkel),
        out,
    )? {
        if args.no_solve {
            bail!("--no-solve writes no meshes to solve a rig from: drop --rig and livelink-csv");
        }
        sinks.push(sink);
        outputs.extend(files);
    }
    args.view
        .sinks(args.rrd.as_deref(), &mut sinks, &mut outputs)?;
    if !args.quiet {
        let bar = indicatif::ProgressBar::new(config.frame_count.unwrap_or(0) as u64);
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
    let manifest = Path::new(&args.dataset);
    if manifest.is_file() {
        fp.add_file(manifest)
            .with_context(|| format!("reading {}", manifest.display()))?;
    } else {
        fp.add(args.dataset.as_bytes());
    }
    let mut exports = args.export.clone();
    exports.sort_by_key(|e| format!("{e:?}"));
    exports.dedup();
    let lgi = if args.no_solve {
        None
    } else {
        Some(args.solve_stage.lgi_params()?)
    };
    fp.add(
        format!(
            "{exports:?} {lgi:?} keyframes={} relabel={:?}/{} enhance={} no_solve={} \
             skip_bad_frames={} rig={:?}",
            args.solve_stage.solve_keyframes,
            args.relabel_every,
            args.relabel_lead,
            args.enhance,
            args.no_solve,
            args.skip_bad_frames,
            args.rig_stage
        )
        .as_bytes(),
    );
    Ok(fp.hex())
}

/// The capture profile at `path`, or the built-in defaults.
///
/// # Errors
/// An unreadable or invalid profile (the message names the file and key).
pub fn load_profile(path: Option<&Path>) -> anyhow::Result<CaptureProfile> {
    Ok(match path {
        Some(p) => CaptureProfile::load(p)?,
        None => CaptureProfile::default(),
    })
}

/// Prints the end-of-take summary.
pub fn print_summary(m: &Metrics, outputs: &[PathBuf]) {
    let e2e = m.latency_ms.get("end_to_end");
    println!(
        "frames: {} in, {} out, {} dropped, {} gaps (source {}, pose held {}, no pose {}, no mesh {})",
        m.frames_in,
        m.frames_out,
        m.frames_dropped,
        m.gaps.source as u64 + m.gaps.pose_held + m.gaps.pose_missing + m.gaps.mesh_missing,
        m.gaps.source,
        m.gaps.pose_held,
        m.gaps.pose_missing,
        m.gaps.mesh_missing
    );
    println!(
        "markers: {:.1} % labeled ({} observed, {} gap-filled, {} dropped marker-frames; {} reacquired)",
        m.labeling.labeled_fraction * 100.0,
        m.labeling.observed,
        m.labeling.gap_filled,
        m.labeling.dropped,
        m.labeling.reacquired
    );
    let realtime = if m.source_fps > 0.0 {
        format!(
            " ({:.2}× real time at {} fps)",
            m.throughput_fps / m.source_fps,
            m.source_fps
        )
    } else {
        String::new()
    };
    println!(
        "throughput: {:.1} frames/s{realtime}; latency end to end p50 {:.1} ms, p99 {:.1} ms",
        m.throughput_fps,
        e2e.map_or(f64::NAN, |s| s.p50),
        e2e.map_or(f64::NAN, |s| s.p99)
    );
    let stages: Vec<String> = m
        .latency_ms
        .iter()
        .filter(|(k, _)| *k != "end_to_end")
        .map(|(k, s)| format!("{k} {:.1}/{:.1}", s.p50, s.p99))
        .collect();
    println!("per stage p50/p99 ms: {}", stages.join(", "));
    if let Some(tc) = &m.timecode {
        println!("timecode: {} – {}", tc.first, tc.last);
    }
    if let Some(a) = &m.accuracy {
        let mesh = if a.mesh_frames > 0 {
            format!(
                "; mesh error RMS {:.3} mm, mean {:.3} mm, max {:.2} mm over {} frames",
                a.mesh_rms_mm, a.mesh_mean_mm, a.mesh_max_mm, a.mesh_frames
            )
        } else {
            String::new()
        };
        println!(
            "accuracy vs ground truth: bundles RMS {:.3} mm over {} frames{mesh}",
            a.bundle_rms_mm, a.bundle_frames
        );
    }
    let files: Vec<String> = outputs.iter().map(|p| p.display().to_string()).collect();
    println!("wrote {}", files.join(", "));
}

pub fn run(args: ReplayArgs) -> anyhow::Result<()> {
    let outcome = replay(&args)?;
    print_summary(&outcome.metrics, &outcome.outputs);
    if let Some(reason) = &outcome.metrics.stopped {
        eprintln!("stopped early: {reason}");
    }
    Ok(())
}

/// The dataset and its marker layout (checked against each other), and the markers'
/// positions on the neutral: what every pipeline run starts from.
///
/// # Errors
/// Unreadable dataset or layout, or a layout that does not fit the dataset.
pub fn load_dataset_and_layout(
    dataset: &DatasetArgs,
    markers: Option<&Path>,
) -> anyhow::Result<(Dataset, Arc<MarkerLayout>, Vec<Point3<f64>>)> {
    let layout = load_layout(&dataset.dataset, markers)?;
    let ds = dataset.load()?;
    layout
        .validate_for(&ds)
        .with_context(|| format!("the marker layout does not fit {}", ds.name))?;
    let neutral_markers = layout
        .markers
        .iter()
        .map(|m| ds.neutral.positions[m.vertex as usize])
        .collect();
    Ok((ds, Arc::new(layout), neutral_markers))
}

/// The dense stages of a run: LGI and, optionally, detail enhancement.
pub struct DenseStages {
    solver: Solver,
    enhancer: Option<Arc<Enhancer>>,
    keyframes: usize,
}

impl DenseStages {
    /// Switches the stages on in `config` (with the dataset's neutral and face vertices).
    pub fn install(self, config: &mut PipelineConfig, ds: &Dataset) {
        config.solver = Some(self.solver);
        config.solve_keyframe_interval = self.keyframes;
        config.neutral = Some(Arc::new(ds.neutral.clone()));
        config.face_vertices = Some(ds.face_vertices.clone());
        config.enhancer = self.enhancer;
    }
}

/// Settings of the pipeline's dense solve (`replay`, `live`).
#[derive(Debug, Clone, clap::Args)]
pub struct SolveStageArgs {
    /// Force the mesh through every bundle (LGI's exact settings, as `helmcap solve` uses by
    /// default) instead of the pipeline's default for triangulated bundles (LGI's noisy
    /// preset), which lets nearby tetrahedra compete, merges nearly coincident shapes per
    /// marker and does not copy each bundle's noise into the surface.
    #[arg(long)]
    pub exact_bundles: bool,
    /// LGI parameters of the solve stage (TOML with the fields of LgiParams); fields it
    /// leaves out keep the pipeline's defaults (see --exact-bundles).
    #[arg(long, value_name = "TOML")]
    pub lgi_params: Option<PathBuf>,
    /// The solve forgets the previous frame's shape choices (LGI's temporal preference) on
    /// frame numbers that are multiples of N (0: never), so that a chunk of a take warmed
    /// up past such a frame solves exactly as one pass over the whole take does.
    #[arg(long, value_name = "N", default_value_t = DEFAULT_SOLVE_KEYFRAMES)]
    pub solve_keyframes: usize,
}

/// Default of `--solve-keyframes`: half a second at 60 fps.
pub const DEFAULT_SOLVE_KEYFRAMES: usize = 30;

impl Default for SolveStageArgs {
    fn default() -> Self {
        Self {
            exact_bundles: false,
            lgi_params: None,
            solve_keyframes: DEFAULT_SOLVE_KEYFRAMES,
        }
    }
}

impl SolveStageArgs {
    /// The LGI parameters of the solve stage.
    ///
    /// The default is [`LgiParams::noisy`]: bundles triangulated from the helmet cameras
    /// carry a few tenths of a millimetre of noise, and forcing the surface through each one
    /// (LGI's exact setting, §5 of the paper) spreads that noise over the face. On the demo
    /// session (bundles 0.244 mm RMS against ground truth) the mesh error drops from
    /// 0.383 mm RMS (mean 0.239 mm) to 0.136 mm (mean 0.054 mm).
    ///
    /// # Errors
    /// An unreadable file, TOML that is not LGI parameters, or a value out of range.
    pub fn lgi_params(&self) -> anyhow::Result<LgiParams> {
        let base = if self.exact_bundles {
            LgiParams::default()
        } else {
            LgiParams::noisy()
        };
        let params = match &self.lgi_params {
            None => base,
            Some(path) => {
                let text = std::fs::read_to_string(path)
                    .with_context(|| format!("reading {}", path.display()))?;
                let file: toml::Table = toml::from_str(&text)
                    .with_context(|| format!("{}: not a TOML table", path.display()))?;
                let mut merged = toml::Table::try_from(base)
                    .context("writing the default LGI parameters as TOML")?;
                merged.extend(file);
                merged
                    .try_into::<LgiParams>()
                    .with_context(|| format!("{}: not LGI parameters", path.display()))?
            }
        };
        params.validate()?;
        Ok(params)
    }
}

/// Builds the dense stages a run asks for: the LGI solver (its index from the cache unless
/// the dataset options say not to) and, with `enhance`, the enhancer. `None` with
/// `no_solve`, which writes no meshes.
///
/// # Errors
/// `--no-solve` with `--enhance` or a mesh export; an index or enhancer that cannot be
/// built.
pub fn dense_stages(
    ds: &Dataset,
    layout: &MarkerLayout,
    dataset: &DatasetArgs,
    no_solve: bool,
    enhance: bool,
    exports: &[Export],
    solve_stage: &SolveStageArgs,
) -> anyhow::Result<Option<DenseStages>> {
    if no_solve {
        if enhance || !exports.iter().all(|e| *e == Export::C3d) {
            bail!("--no-solve writes no meshes: drop --enhance and mesh exports");
        }
        return Ok(None);
    }
    let params = solve_stage.lgi_params()?;
    let index = super::solve::lgi_index_cached(
        ds,
        layout,
        &params,
        (!dataset.no_cache).then(|| {
            dataset
                .cache_dir
                .clone()
                .unwrap_or_else(helmcap::dataset::cache::default_cache_dir)
        }),
    )?;
    let solver = Solver::lgi(index, &params)?;
    let enhancer = if enhance {
        let params = super::enhance::read_params(None)?;
        let (_, enhancer) = super::enhance::build_enhancer(&dataset.dataset, &params, true)?;
        Some(Arc::new(enhancer))
    } else {
        None
    };
    Ok(Some(DenseStages {
        solver,
        enhancer,
        keyframes: solve_stage.solve_keyframes,
    }))
}

/// The file sinks every pipeline run writes into `out` (CSV and metrics), plus one per
/// distinct `--export`, and the paths they write (for the summary).
pub fn file_sinks(out: &Path, exports: &[Export]) -> (Vec<Box<dyn Sink>>, Vec<PathBuf>) {
    let mut outputs = vec![
        out.join("bundles.csv"),
        out.join("head_pose.csv"),
        out.join("tracks.csv"),
        out.join("metrics.json"),
    ];
    let mut sinks: Vec<Box<dyn Sink>> = vec![
        Box::new(CsvSink::new(out)),
        Box::new(MetricsSink::new(&out.join("metrics.json"))),
    ];
    let mut seen: Vec<Export> = Vec::new();
    for &e in exports {
        if seen.contains(&e) {
            continue;
        }
        seen.push(e);
        let (sink, path): (Box<dyn Sink>, PathBuf) = match e {
            Export::Obj => (
                Box::new(MeshSequenceSink::new(&out.join("mesh"), MeshFormat::Obj)),
                out.join("mesh/frame_NNNNNN.obj"),
            ),
            Export::Ply => (
                Box::new(MeshSequenceSink::new(&out.join("mesh"), MeshFormat::Ply)),
                out.join("mesh/frame_NNNNNN.ply"),
            ),
            Export::Usd => (
                Box::new(UsdSink::new(&out.join("mesh.usda"))),
                out.join("mesh.usda"),
            ),
            Export::C3d => (
                Box::new(C3dSink::new(&out.join("bundles.c3d"))),
                out.join("bundles.c3d"),
            ),
            // Written by the animation sink (`RigStageArgs::sink`).
            Export::LivelinkCsv | Export::UsdSkel => continue,
        };
        sinks.push(sink);
        outputs.push(path);
    }
    (sinks, outputs)
}
