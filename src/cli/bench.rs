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
}

pub fn run(cmd: BenchCommand) -> anyhow::Result<()> {
    if cfg!(debug_assertions) {
        eprintln!("note: this is not a release build; figures are not representative");
    }
    match cmd {
        BenchCommand::Dataset { dataset, runs } => {
            let cache = tempfile_dir()?;
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

fn tempfile_dir() -> anyhow::Result<PathBuf> {
    let dir = std::env::temp_dir().join(format!("helmcap-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    Ok(dir)
}
