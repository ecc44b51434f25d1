//! The options `replay` and `live` share (one flattened clap struct, [`TakeArgs`]), read
//! into the library's [`TakeSpec`] that assembles the take; the stop flag and the
//! end-of-take summary.

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, OnceLock};

use helmcap::dataset::DatasetSpec;
use helmcap::pipeline::Metrics;
use helmcap::take::{DEFAULT_SOLVE_KEYFRAMES, Export, SolveSpec, TakeSpec};

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
    /// Frames each stage channel holds (a replay's source decodes up to four times as many
    /// ahead of the detection).
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

impl TakeArgs {
    /// The take these options describe.
    pub fn spec(&self) -> TakeSpec {
        TakeSpec {
            dataset: DatasetSpec {
                name: self.dataset.clone(),
                no_cache: self.no_cache,
                cache_dir: self.cache_dir.clone(),
            },
            markers: self.markers.clone(),
            profile: self.profile.clone(),
            no_solve: self.no_solve,
            enhance: self.enhance,
            exports: self.export.clone(),
            solve: self.solve_stage.spec(),
            rig: self.rig_stage.spec(),
            queue: self.queue,
            viewer: self.view.spec(self.rrd.clone()),
        }
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
    if m.frames_out > 0 && m.labeling.markers > 0 && m.labeling.observed == 0 {
        // Said at the end even of a take too short for the warning logged while running
        // (`NO_LABEL_WARNING_SECS`), and under `--quiet`.
        println!(
            "warning: no marker labeled in {} frames: are the cameras swapped or not the \
             calibration's, or the marker layout (--markers) or the capture profile (dot size, \
             polarity, colour) not the footage's? `helmcap detect` on one frame shows what is \
             found",
            m.frames_out
        );
    }
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
    /// The solve settings these options ask for.
    pub fn spec(&self) -> SolveSpec {
        SolveSpec {
            exact_bundles: self.exact_bundles,
            lgi_params: self.lgi_params.clone(),
            keyframes: self.solve_keyframes,
        }
    }
}
