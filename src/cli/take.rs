//! What `replay` and `live` share to assemble a take: the options common to both (one
//! flattened clap struct, [`TakeArgs`]), the dataset and layout, the capture profile, the
//! dense stages, the file sinks and exports, the stop flag and the end-of-take summary.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, OnceLock};

use anyhow::{Context, bail};
use helmcap::dataset::{Dataset, MarkerLayout};
use helmcap::enhance::Enhancer;
use helmcap::lgi::LgiParams;
use helmcap::pipeline::{Metrics, PipelineConfig, Sink};
use helmcap::sink::{C3dSink, CsvSink, MeshFormat, MeshSequenceSink, MetricsSink, UsdSink};
use helmcap::solve::Solver;
use helmcap::track::CaptureProfile;
use nalgebra::Point3;

use super::DatasetArgs;

/// The options of a take that `replay` and `live` share (flattened into both).
#[derive(Debug, Clone, clap::Args)]
pub struct TakeArgs {
    /// Capture profile: dot size, polarity, colour, detection and labeling settings
    /// (default: in a replay, the one session.toml names; else the built-in defaults).
    #[arg(long, value_name = "TOML")]
    pub profile: Option<PathBuf>,
    /// Dataset manifest, or `builtin[:SEED]` for the built-in actor.
    #[arg(long, short = 'd', default_value = "builtin")]
    pub dataset: String,
    /// Marker layout CSV (default for the built-in actor: its shipped layout).
    #[arg(long, short = 'k', value_name = "CSV")]
    pub markers: Option<PathBuf>,
    /// Replace the take in --out: its files are removed before the run (a folder with
    /// files is refused otherwise).
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
    /// Stop after labeling and stabilization (no dense solve, no meshes).
    #[arg(long)]
    pub no_solve: bool,
    /// Frames each stage channel holds.
    #[arg(long, default_value_t = 4)]
    pub queue: usize,
    /// Do not read or write the dataset and LGI index caches.
    #[arg(long)]
    pub no_cache: bool,
    /// Cache folder (default: $HELMCAP_CACHE_DIR, else ~/.cache/helmcap).
    #[arg(long, value_name = "DIR")]
    pub cache_dir: Option<PathBuf>,
}

impl Default for TakeArgs {
    fn default() -> Self {
        Self {
            profile: None,
            dataset: "builtin".into(),
            markers: None,
            overwrite: false,
            rrd: None,
            view: Default::default(),
            export: Vec::new(),
            rig_stage: Default::default(),
            enhance: false,
            solve_stage: SolveStageArgs::default(),
            no_solve: false,
            queue: 4,
            no_cache: false,
            cache_dir: None,
        }
    }
}

/// The sinks of a take and the files they write (for the summary).
pub type TakeSinks = (Vec<Box<dyn Sink>>, Vec<PathBuf>);

/// The dataset a take is solved with, and everything loaded from it.
pub struct TakeDataset {
    /// The dataset.
    pub dataset: Dataset,
    /// Its marker layout (checked against it).
    pub layout: Arc<MarkerLayout>,
    /// Each marker's neutral position, head frame, mm.
    pub neutral_markers: Vec<Point3<f64>>,
}

impl TakeArgs {
    /// The dataset options (`--dataset`, `--no-cache`, `--cache-dir`).
    pub fn dataset_args(&self) -> DatasetArgs {
        DatasetArgs {
            dataset: self.dataset.clone(),
            no_cache: self.no_cache,
            cache_dir: self.cache_dir.clone(),
        }
    }

    /// Loads the dataset and the layout (checked against each other).
    ///
    /// # Errors
    /// Unreadable dataset or layout, or a layout that does not fit the dataset.
    pub fn load_dataset(&self) -> anyhow::Result<TakeDataset> {
        let (dataset, layout, neutral_markers) =
            load_dataset_and_layout(&self.dataset_args(), self.markers.as_deref())?;
        Ok(TakeDataset {
            dataset,
            layout,
            neutral_markers,
        })
    }

    /// The dense stages the options ask for (see [`dense_stages`]).
    ///
    /// # Errors
    /// As [`dense_stages`].
    pub fn dense_stages(&self, take: &TakeDataset) -> anyhow::Result<Option<DenseStages>> {
        dense_stages(
            &take.dataset,
            &take.layout,
            &self.dataset_args(),
            self.no_solve,
            self.enhance,
            &self.export,
            &self.solve_stage,
        )
    }

    /// The pipeline configuration of a take on `rig` with `profile`: the capture settings,
    /// the expression templates for acquisition and the channel size.
    pub fn pipeline_config(
        &self,
        take: &TakeDataset,
        rig: helmcap::camera::StereoRig,
        profile: &CaptureProfile,
    ) -> PipelineConfig {
        let mut config = PipelineConfig::new(
            take.layout.clone(),
            Arc::new(take.neutral_markers.clone()),
            rig,
        );
        config.track.detect = profile.detect_params(Some(&config.rig));
        config.track.label = profile.label_params();
        config.track.expression_templates =
            Arc::new(take.layout.expression_templates(&take.dataset));
        config.channels.capacity = self.queue;
        config
    }

    /// The sinks of a take written into `out`: the file sinks and exports, the rig stage
    /// and its animation sink when asked for (switched on in `config`), the viewer and
    /// recording; and the files they write, for the summary.
    ///
    /// # Errors
    /// A rig that cannot be loaded, a rig with `--no-solve`, a viewer that cannot start.
    pub fn sinks(
        &self,
        config: &mut PipelineConfig,
        take: &TakeDataset,
        out: &Path,
    ) -> anyhow::Result<TakeSinks> {
        let (mut sinks, mut outputs) = file_sinks(out, &self.export);
        if let Some((sink, files)) = self.rig_stage.install(
            config,
            &take.dataset,
            &self.dataset_args(),
            self.export.contains(&Export::LivelinkCsv),
            self.export.contains(&Export::UsdSkel),
            out,
        )? {
            if self.no_solve {
                bail!(
                    "--no-solve writes no meshes to solve a rig from: drop --rig and livelink-csv"
                );
            }
            sinks.push(sink);
            outputs.extend(files);
        }
        self.view
            .sinks(self.rrd.as_deref(), &mut sinks, &mut outputs)?;
        Ok((sinks, outputs))
    }
}

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

/// The layout for `dataset` (a path, or the built-in actor's shipped layout).
pub fn load_layout(dataset: &str, markers: Option<&Path>) -> anyhow::Result<MarkerLayout> {
    match markers {
        Some(p) => {
            MarkerLayout::read_csv(p).with_context(|| format!("reading markers {}", p.display()))
        }
        None if helmcap::dataset::builtin_params(dataset)?.is_some() => {
            Ok(MarkerLayout::builtin_actor()?)
        }
        None => bail!("--markers is required with a dataset manifest"),
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
        config.solve.solver = Some(self.solver);
        config.solve.keyframe_interval = self.keyframes;
        config.solve.neutral = Some(Arc::new(ds.neutral.clone()));
        config.solve.face_vertices = Some(ds.face_vertices.clone());
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
        let params = helmcap::enhance::read_params(None)?;
        let (_, enhancer) = helmcap::enhance::build_enhancer(&dataset.dataset, &params, true)?;
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
pub fn file_sinks(out: &Path, exports: &[Export]) -> TakeSinks {
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
