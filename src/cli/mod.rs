//! Subcommands, one file each. Every command validates its input and reports one clear
//! error line; long work shows a progress bar.

mod animate;
mod bench;
mod bench_capture;
mod bench_pipeline;
mod calibrate;
mod dataset;
mod demo;
mod detect;
mod enhance;
mod farm;
mod ingest;
mod live;
mod markers;
mod record;
mod register;
mod replay;
mod report;
mod retime;
mod rig;
mod solve;
mod synth;
mod take;
mod view;

use std::path::PathBuf;

use anyhow::Context;
use clap::{Parser, Subcommand};
use helmcap::dataset::{Dataset, DatasetSpec};

/// helmcap: facial performance capture from helmet-mounted stereo cameras.
#[derive(Debug, Parser)]
#[command(version, about, long_about = None)]
pub struct Cli {
    /// More log output (-v debug, -vv trace). RUST_LOG overrides.
    #[arg(short, long, action = clap::ArgAction::Count, global = true)]
    pub verbose: u8,
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// A synthetic session of the built-in actor through the whole pipeline.
    Demo(demo::DemoArgs),
    /// Inspect, cache or synthesize datasets of face shapes.
    #[command(subcommand)]
    Dataset(dataset::DatasetCommand),
    /// Marker layouts.
    #[command(subcommand)]
    Markers(markers::MarkersCommand),
    /// Add the database's actor-specific details to a mesh sequence (Bermano et al. 2014).
    Enhance(enhance::EnhanceArgs),
    /// Interpolate two keyframes with the actor's timing (Bermano et al. 2014 §6).
    Retime(retime::RetimeArgs),
    /// Solved meshes -> rig weights per frame and animation exports (Live Link Face CSV).
    Animate(animate::AnimateArgs),
    /// Run the pipeline on a recorded session: bundles, head pose, meshes, exports.
    Replay(replay::ReplayArgs),
    /// Reconstruct the dense face of every frame of a bundles CSV.
    Solve(solve::SolveArgs),
    /// Release-mode benchmarks (median of several runs).
    #[command(subcommand)]
    Bench(bench::BenchCommand),
    /// Bring a scan of any topology into a template's topology (non-rigid ICP).
    Register(register::RegisterArgs),
    /// Actor-specific blendshape rigs (example-based rigging, rigs from LGI).
    #[command(subcommand)]
    Rig(rig::RigCommand),
    /// Render a synthetic helmet recording with ground truth, or calibration target images.
    Synth(synth::SynthArgs),
    /// Marker detection (and labeling, with a calibration) on one image, a stereo pair or a
    /// session frame -> annotated PNGs and a CSV. Labels are an acquisition's on that frame
    /// alone, as at the start of a replay (its whole search at once, where a replay spreads
    /// it over a few frames), not those of tracking through the take.
    Detect(detect::DetectArgs),
    /// Stereo calibration from image pairs of a target -> calibration YAML.
    Calibrate(calibrate::CalibrateArgs),
    /// Record the live cameras (and the sync box's timecode) to a session folder.
    Record(record::RecordArgs),
    /// Run the pipeline on the live cameras (or test cameras): the outputs of replay.
    Live(live::LiveArgs),
    /// Turn a pair of camera videos into a session folder of PNG frames.
    Ingest(ingest::IngestArgs),
    /// A dailies report: self-contained HTML pages with plots for one or more takes.
    Report(report::ReportArgs),
    /// Dailies on a render farm: OpenJD job bundles, and joining a take's chunks.
    #[command(subcommand)]
    Farm(farm::FarmCommand),
}

/// Sets up logging to stderr: warnings and progress notes by default, more with `-v`.
pub fn init_logging(verbose: u8) {
    let default = match verbose {
        0 => "helmcap=info,warn",
        1 => "helmcap=debug,info",
        _ => "trace",
    };
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(default));
    let _ = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_target(false)
        .without_time()
        .try_init();
}

/// Runs the parsed command.
pub fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Command::Demo(a) => demo::run(a),
        Command::Dataset(c) => dataset::run(c),
        Command::Markers(c) => markers::run(c),
        Command::Enhance(a) => enhance::run(a),
        Command::Replay(a) => replay::run(a),
        Command::Animate(a) => animate::run(a),
        Command::Retime(a) => retime::run(a),
        Command::Solve(a) => solve::run(a),
        Command::Bench(c) => bench::run(c),
        Command::Synth(a) => synth::run(a),
        Command::Calibrate(a) => calibrate::run(a),
        Command::Detect(a) => detect::run(a),
        Command::Rig(c) => rig::run(c),
        Command::Register(a) => register::run(a),
        Command::Record(a) => record::run(a),
        Command::Live(a) => live::run(a),
        Command::Ingest(a) => ingest::run(a),
        Command::Report(a) => report::run(a),
        Command::Farm(c) => farm::run(c),
    }
}

/// How a command names its dataset: a manifest path, or `builtin` / `builtin:SEED` for the
/// built-in synthetic actor (seed 0 is the default actor).
#[derive(Debug, Clone, clap::Args)]
pub struct DatasetArgs {
    /// Dataset manifest (TOML), or `builtin[:SEED]` for the built-in synthetic actor.
    #[arg(long, short = 'd', value_name = "MANIFEST")]
    pub dataset: String,
    /// Read and write no dataset cache.
    #[arg(long)]
    pub no_cache: bool,
    /// Cache folder (default: $HELMCAP_CACHE_DIR, else ~/.cache/helmcap).
    #[arg(long, value_name = "DIR")]
    pub cache_dir: Option<PathBuf>,
}

impl DatasetArgs {
    /// `dataset` with the default cache (read and written in the default folder).
    pub fn new(dataset: impl Into<String>) -> Self {
        Self {
            dataset: dataset.into(),
            no_cache: false,
            cache_dir: None,
        }
    }

    /// Another dataset with these cache options.
    pub fn for_dataset(&self, dataset: impl Into<String>) -> Self {
        Self {
            dataset: dataset.into(),
            no_cache: self.no_cache,
            cache_dir: self.cache_dir.clone(),
        }
    }

    /// The dataset and cache options these options name.
    pub fn spec(&self) -> DatasetSpec {
        DatasetSpec {
            name: self.dataset.clone(),
            no_cache: self.no_cache,
            cache_dir: self.cache_dir.clone(),
        }
    }

    /// Loads the dataset, with a progress bar for manifests.
    pub fn load(&self) -> anyhow::Result<Dataset> {
        Ok(self.spec().load()?)
    }
}

/// A working folder for a benchmark run (`$TMPDIR/helmcap-bench-<pid>`), created.
///
/// # Errors
/// When the folder cannot be created.
fn bench_work_dir() -> anyhow::Result<PathBuf> {
    let dir = std::env::temp_dir().join(format!("helmcap-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    Ok(dir)
}

/// The unit of mesh files given as input (`--units`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum MeshUnits {
    /// Millimetres (what helmcap writes).
    Mm,
    /// Centimetres.
    Cm,
    /// Metres.
    M,
}

impl MeshUnits {
    /// Factor from this unit to millimetres.
    pub fn to_mm(self) -> f64 {
        match self {
            MeshUnits::Mm => 1.0,
            MeshUnits::Cm => 10.0,
            MeshUnits::M => 1000.0,
        }
    }

    /// `positions` converted to millimetres, after checking their size against the
    /// dataset's neutral (`reference`, mm); `label` names the input in the error.
    pub fn to_mm_checked(
        self,
        positions: &[nalgebra::Point3<f64>],
        reference: &[nalgebra::Point3<f64>],
        label: &str,
    ) -> anyhow::Result<Vec<nalgebra::Point3<f64>>> {
        let k = self.to_mm();
        let mm: Vec<_> = positions.iter().map(|p| p * k).collect();
        helmcap::dataset::check_mesh_scale(&mm, reference)
            .map_err(|e| anyhow::anyhow!("{label}: {e}"))?;
        Ok(mm)
    }
}
