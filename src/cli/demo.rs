//! `helmcap demo`: the first thing a new user runs.
//!
//! Builds the built-in synthetic actor, writes it as a dataset, generates its marker layout
//! and prints a summary of each step.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;
use helmcap::dataset::markers::{LayoutParams, generate_layout};
use helmcap::dataset::{actor, write_dataset};

#[derive(Debug, clap::Args)]
pub struct DemoArgs {
    /// Output folder.
    #[arg(long, short, default_value = "out/demo")]
    out: PathBuf,
    /// Identity seed of the built-in actor (default: the standard actor).
    #[arg(long)]
    seed: Option<u64>,
}

pub fn run(args: DemoArgs) -> anyhow::Result<()> {
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;
    let t = Instant::now();
    let params = match args.seed {
        Some(s) => actor::ActorParams::from_seed(s),
        None => actor::ActorParams::default(),
    };
    let actor = actor::Actor::new(&params).context("building the built-in actor")?;
    let ds = actor.to_dataset();
    println!(
        "[1/3] built-in actor: {} vertices, {} polygons, {} expressions ({:.0} ms)",
        ds.vertex_count(),
        ds.neutral.face_count(),
        ds.shapes.len(),
        t.elapsed().as_secs_f64() * 1e3
    );
    let dataset_dir = args.out.join("dataset");
    let manifest = write_dataset(&ds, &dataset_dir)
        .with_context(|| format!("writing {}", dataset_dir.display()))?;
    println!("[2/3] dataset written: {}", manifest.display());
    let layout = generate_layout(&ds, &LayoutParams::default()).context("generating markers")?;
    let markers = args.out.join("markers.csv");
    layout
        .write_csv(&markers)
        .with_context(|| format!("writing {}", markers.display()))?;
    let stable = layout.stabilizing_count();
    println!(
        "[3/3] marker layout: {} markers, {} stabilizing, written to {}",
        layout.len(),
        stable,
        markers.display()
    );
    println!(
        "done. Inspect with: helmcap dataset info --dataset {}",
        manifest.display()
    );
    Ok(())
}
