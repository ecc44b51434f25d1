//! `helmcap bench ...`: release-mode measurements, median of several runs.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;
use clap::Subcommand;
use helmcap::dataset::{LoadOptions, actor, load_dataset};

#[derive(Debug, Subcommand)]
pub enum BenchCommand {
    /// Time loading a dataset manifest: cold from the mesh files, and from the cache.
    Dataset {
        /// Dataset manifest (TOML).
        #[arg(long, short = 'd')]
        dataset: PathBuf,
        /// Number of timed runs of each kind.
        #[arg(long, default_value_t = 5)]
        runs: usize,
    },
    /// Time detail enhancement: precomputation, memory and per-frame time.
    Enhance(super::enhance::EnhanceBenchArgs),
    /// Accuracy and speed of the solve methods on held-out performances (ICT-FaceKit
    /// variants and the built-in actor): prints the Markdown table of the README.
    Solve(SolveBenchArgs),
    /// Time example-based rigging (Li et al. 2010): setup, and each alternation of steps A
    /// and B (median over the alternations).
    Rig {
        /// Template dataset manifest, or `builtin[:SEED]`.
        #[arg(long, short = 'd', default_value = "configs/datasets/ict-facekit.toml")]
        dataset: String,
        /// Number of synthetic example poses (each 3 random blendshapes at random weights,
        /// on a smoothly warped copy of the template neutral).
        #[arg(long, default_value_t = 14)]
        examples: usize,
        /// Number of timed alternations.
        #[arg(long, default_value_t = 5)]
        runs: usize,
    },
    /// Replay throughput, live-paced latency and a memory soak of the pipeline.
    Pipeline(super::bench_pipeline::PipelineBenchArgs),
    /// Time logging frames (camera images, markers, mesh) to a rerun recording.
    Rerun(super::view::RerunBenchArgs),
    /// Time building the built-in actor and its dataset.
    Actor {
        /// Number of timed runs.
        #[arg(long, default_value_t = 5)]
        runs: usize,
    },
    /// Time detection + tracking + triangulation on a synthetic session, and measure
    /// labeling accuracy and bundle error at centroid noise levels.
    Capture(super::bench_capture::CaptureBenchArgs),
}

pub fn run(cmd: BenchCommand) -> anyhow::Result<()> {
    if cfg!(debug_assertions) {
        eprintln!("note: this is not a release build; figures are not representative");
    }
    match cmd {
        BenchCommand::Dataset { dataset, runs } => {
            let cache = super::bench_work_dir()?;
            let cold_opts = LoadOptions {
                no_cache: true,
                ..Default::default()
            };
            let cached_opts = LoadOptions {
                cache_dir: Some(cache.clone()),
                ..Default::default()
            };
            let mut shapes = 0;
            let cold = time_runs(runs, || {
                let ds = load_dataset(&dataset, &cold_opts)?;
                shapes = ds.shapes.len();
                Ok::<(), helmcap::dataset::DatasetError>(())
            })
            .with_context(|| format!("loading {}", dataset.display()))?;
            // One load writes the cache; the timed runs read it.
            load_dataset(&dataset, &cached_opts)?;
            let cached = time_runs(runs, || load_dataset(&dataset, &cached_opts).map(|_| ()))?;
            let _ = std::fs::remove_dir_all(&cache);
            println!(
                "dataset {} ({shapes} shapes), median of {runs} runs:",
                dataset.display()
            );
            println!("  from mesh files   {:8.1} ms", cold * 1e3);
            println!("  from cache        {:8.1} ms", cached * 1e3);
        }
        BenchCommand::Enhance(a) => super::enhance::run_bench(a)?,
        BenchCommand::Solve(a) => solve_bench(a)?,
        BenchCommand::Rig {
            dataset,
            examples,
            runs,
        } => bench_rig(&dataset, examples, runs)?,
        BenchCommand::Capture(a) => super::bench_capture::run(a)?,
        BenchCommand::Pipeline(a) => super::bench_pipeline::run(a)?,
        BenchCommand::Rerun(a) => super::view::run_bench(a)?,
        BenchCommand::Actor { runs } => {
            let params = actor::ActorParams::default();
            let t = time_runs(runs, || {
                let a = actor::Actor::new(&params)?;
                let ds = a.to_dataset();
                std::hint::black_box(ds);
                Ok::<(), actor::ActorError>(())
            })?;
            println!(
                "built-in actor + dataset, median of {runs} runs: {:.1} ms",
                t * 1e3
            );
        }
    }
    Ok(())
}

/// Arguments of `helmcap bench solve`.
#[derive(Debug, clap::Args)]
pub struct SolveBenchArgs {
    /// ICT-FaceKit manifest (its rows are skipped when the data is missing).
    #[arg(
        long,
        default_value = "configs/datasets/ict-facekit.toml",
        value_name = "MANIFEST"
    )]
    ict: PathBuf,
    /// Marker layout for ICT (generated when unreadable).
    #[arg(
        long,
        default_value = "configs/markers/ict-facekit.csv",
        value_name = "CSV"
    )]
    ict_markers: PathBuf,
    /// Marker layout for the built-in actor (generated when unreadable).
    #[arg(
        long,
        default_value = "configs/markers/builtin-actor.csv",
        value_name = "CSV"
    )]
    actor_markers: PathBuf,
    /// Datasets to run: comma-separated substrings of their names ("all 53", "in-betweens",
    /// "pairs", "symmetric", "actor"); default every dataset.
    #[arg(long, value_delimiter = ',', value_name = "NAMES")]
    only: Vec<String>,
    /// Conditions to run: comma-separated substrings of their names ("exact", "noise 0.3",
    /// "noise 1", "missing", "animated"); default every condition.
    #[arg(long, value_delimiter = ',', value_name = "NAMES")]
    conditions: Vec<String>,
    /// Methods to run (lgi, rbf, blendshape; comma-separated).
    #[arg(long, value_delimiter = ',', default_value = "lgi,rbf,blendshape")]
    methods: Vec<String>,
    /// Static held-out frames per condition.
    #[arg(long, default_value_t = 60)]
    frames: usize,
    /// Timed runs of every take (the median time per frame is reported).
    #[arg(long, default_value_t = 5)]
    runs: usize,
    /// Half-width of LGI's centred smoothing for the `lgi+smooth` rows (0: no such rows).
    #[arg(long, default_value_t = 2)]
    smooth: usize,
    /// LGI parameters file (TOML with the fields of LgiParams).
    #[arg(long, value_name = "TOML")]
    lgi_params: Option<PathBuf>,
    /// Also write the table to this file (Markdown).
    #[arg(long, value_name = "MD")]
    out: Option<PathBuf>,
}

fn solve_bench(a: SolveBenchArgs) -> anyhow::Result<()> {
    use helmcap::bench::solve::{BenchConfig, format_table, run_benchmark};
    let methods = a
        .methods
        .iter()
        .map(|m| m.trim().parse::<helmcap::solve::Method>())
        .collect::<Result<Vec<_>, _>>()
        .map_err(anyhow::Error::msg)?;
    let mut params = helmcap::solve::SolveParams::default();
    if let Some(p) = &a.lgi_params {
        let text =
            std::fs::read_to_string(p).with_context(|| format!("reading {}", p.display()))?;
        params.lgi = toml::from_str(&text)
            .with_context(|| format!("{}: not LGI parameters", p.display()))?;
        params.lgi.validate()?;
    }
    let config = BenchConfig {
        frames: a.frames,
        smooth: a.smooth,
        runs: a.runs.max(1),
        only: a.only.iter().map(|s| s.trim().to_string()).collect(),
        conditions: a.conditions.iter().map(|s| s.trim().to_string()).collect(),
        methods,
        params,
        ict_manifest: Some(a.ict),
        ict_layout: Some(a.ict_markers),
        actor_layout: Some(a.actor_markers),
    };
    let rows = run_benchmark(&config).map_err(anyhow::Error::msg)?;
    let table = format_table(&rows);
    println!("{table}");
    if let Some(out) = &a.out {
        helmcap::atomic_file::write_atomically(out, |w| {
            std::io::Write::write_all(w, table.as_bytes())
        })
        .with_context(|| format!("writing {}", out.display()))?;
    }
    Ok(())
}

/// Median wall time in seconds of `runs` calls of `f`.
fn time_runs<E: Into<anyhow::Error>>(
    runs: usize,
    mut f: impl FnMut() -> Result<(), E>,
) -> anyhow::Result<f64> {
    let mut times = Vec::with_capacity(runs.max(1));
    for _ in 0..runs.max(1) {
        let t = Instant::now();
        f().map_err(Into::into)?;
        times.push(t.elapsed().as_secs_f64());
    }
    times.sort_by(f64::total_cmp);
    Ok(times[times.len() / 2])
}

/// `helmcap bench rig`.
fn bench_rig(dataset: &str, count: usize, runs: usize) -> anyhow::Result<()> {
    use helmcap::rig::{Example, RigBuilder, RigParams};
    let template = super::DatasetArgs::new(dataset.to_string()).load()?;
    let n = template.shapes.len();
    let a0 = &template.neutral.positions;
    // The "actor": the template neutral under a smooth non-rigid warp (a few mm).
    let neutral: Vec<nalgebra::Point3<f64>> = a0
        .iter()
        .map(|p| {
            nalgebra::Point3::new(
                p.x * 1.03 + 0.5 * (p.y * 0.05).sin(),
                p.y * 0.98 + 0.5 * (p.z * 0.04).cos(),
                p.z * 1.01 + 0.5 * (p.x * 0.06).sin(),
            )
        })
        .collect();
    let mut rng = helmcap::numeric::SplitMix64::new(17);
    let mut next = || rng.next_f64();
    let examples: Vec<Example> = (0..count)
        .map(|j| {
            let mut w = vec![0.0; n];
            for _ in 0..3 {
                let i = ((next() * n as f64) as usize).min(n - 1);
                w[i] = 0.4 + 0.6 * next();
            }
            let mut positions = neutral.clone();
            for (i, &wi) in w.iter().enumerate() {
                if wi > 0.0 {
                    for ((p, s), a) in positions
                        .iter_mut()
                        .zip(&template.shapes[i].positions)
                        .zip(a0)
                    {
                        *p += (s - a) * wi;
                    }
                }
            }
            let initial_weights = w.iter().map(|&x| if x > 0.0 { 0.7 } else { 0.0 }).collect();
            Example {
                name: format!("example{j}"),
                positions,
                initial_weights,
            }
        })
        .collect();
    let params = RigParams {
        alternations: runs.max(1),
        ..RigParams::default()
    };
    let t = Instant::now();
    let builder = RigBuilder::new(&template, &neutral, &params)?;
    let setup = t.elapsed().as_secs_f64();
    let mut times = Vec::new();
    let mut parts = Vec::new();
    let mut cpu = Vec::new();
    let mut cpu_before = helmcap::bench::host::process_cpu_seconds();
    let rig = builder.build(&examples, &[], &mut |r| {
        times.push(r.seconds);
        parts.push(r.step_seconds);
        let now = helmcap::bench::host::process_cpu_seconds();
        if let (Some(a), Some(b)) = (cpu_before, now) {
            cpu.push(b - a);
        }
        cpu_before = now;
    })?;
    times.sort_by(f64::total_cmp);
    cpu.sort_by(f64::total_cmp);
    let median_part = |k: usize| {
        let mut v: Vec<f64> = parts.iter().map(|p| p[k]).collect();
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let worst = rig.fits.iter().map(|f| f.vertex_rms_mm).fold(0.0, f64::max);
    println!(
        "rig: {} vertices, {} triangles, {n} blendshapes, {count} examples",
        template.vertex_count(),
        template.neutral.triangles.len()
    );
    println!("  setup (frames, targets, {n} factorizations) {setup:8.2} s");
    println!(
        "  per alternation, median of {}            {:8.2} s",
        times.len(),
        times[times.len() / 2]
    );
    println!(
        "    step A frames {:.2} s, reconstruction {:.2} s, step B weights {:.2} s",
        median_part(0),
        median_part(1),
        median_part(2)
    );
    if !cpu.is_empty() {
        println!(
            "  CPU time per alternation, median           {:8.2} s (all threads)",
            cpu[cpu.len() / 2]
        );
    }
    println!(
        "  worst example fit after {} alternations   {worst:8.3} mm RMS",
        times.len()
    );
    Ok(())
}
