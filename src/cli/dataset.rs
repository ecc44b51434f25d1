//! `helmcap dataset info | build | synth`.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;
use clap::Subcommand;
use helmcap::dataset::{actor, write_dataset};

use super::DatasetArgs;

#[derive(Debug, Subcommand)]
pub enum DatasetCommand {
    /// Print a dataset's shapes, vertex counts, units and per-shape displacement statistics.
    Info {
        #[command(flatten)]
        dataset: DatasetArgs,
    },
    /// Load a dataset and write its binary cache (later loads are fast).
    Build {
        #[command(flatten)]
        dataset: DatasetArgs,
    },
    /// Write the built-in synthetic actor as a dataset: manifest.toml, OBJs, jaw weights.
    Synth {
        /// Output folder (created).
        #[arg(long, short)]
        out: PathBuf,
        /// Identity seed: another seed gives another actor with the same topology.
        #[arg(long)]
        seed: Option<u64>,
    },
}

pub fn run(cmd: DatasetCommand) -> anyhow::Result<()> {
    match cmd {
        DatasetCommand::Info { dataset } => info(&dataset),
        DatasetCommand::Build { dataset } => {
            let t = Instant::now();
            let ds = dataset.load()?;
            println!(
                "dataset {}: {} shapes of {} vertices ready ({:.2} s)",
                ds.name,
                ds.shapes.len(),
                ds.vertex_count(),
                t.elapsed().as_secs_f64()
            );
            Ok(())
        }
        DatasetCommand::Synth { out, seed } => {
            let params = match seed {
                Some(s) => actor::ActorParams::from_seed(s),
                None => actor::ActorParams::default(),
            };
            let actor = actor::Actor::new(&params).context("building the built-in actor")?;
            let ds = actor.to_dataset();
            let manifest = write_dataset(&ds, &out)
                .with_context(|| format!("writing dataset to {}", out.display()))?;
            println!(
                "wrote {} ({} shapes, {} vertices, mm)",
                manifest.display(),
                ds.shapes.len(),
                ds.vertex_count()
            );
            Ok(())
        }
    }
}

fn info(args: &DatasetArgs) -> anyhow::Result<()> {
    let t = Instant::now();
    let ds = args.load()?;
    let secs = t.elapsed().as_secs_f64();
    let m = &ds.neutral;
    println!("dataset      {}", ds.name);
    println!("source       {}", args.dataset);
    println!("loaded in    {secs:.2} s");
    println!("units        mm (converted from the manifest's unit)");
    println!(
        "neutral      {} vertices, {} polygons ({} triangles), {} texture coordinates",
        m.vertex_count(),
        m.face_count(),
        m.triangles.len(),
        m.uvs.len()
    );
    println!(
        "face         vertices {}..{} ({} vertices)",
        ds.face_vertices.start(),
        ds.face_vertices.end(),
        ds.face_vertex_indices().count()
    );
    if let Some((lo, hi)) = m.bounding_box() {
        let size = hi - lo;
        println!(
            "extent       {:.1} x {:.1} x {:.1} mm",
            size.x, size.y, size.z
        );
    }
    match &ds.jaw {
        Some(j) => println!(
            "jaw rig      pivot ({:.1}, {:.1}, {:.1}) mm, {} skinned vertices",
            j.pivot.x,
            j.pivot.y,
            j.pivot.z,
            j.weights.iter().filter(|&&w| w > 0.0).count()
        ),
        None => println!("jaw rig      none"),
    }
    println!("shapes       {}", ds.shapes.len());
    println!(
        "\n{:<28} {:>9} {:>9} {:>9} {:>9}  jaw (open rad)",
        "shape", "mean mm", "p95 mm", "max mm", "moving"
    );
    for (i, s) in ds.shapes.iter().enumerate() {
        let st = ds.displacement_stats(i);
        let jaw = s
            .jaw
            .map(|j| format!("{:.3}", j.open_rad))
            .unwrap_or_else(|| "-".into());
        println!(
            "{:<28} {:>9.3} {:>9.3} {:>9.3} {:>9}  {}",
            s.name, st.mean_mm, st.p95_mm, st.max_mm, st.moving, jaw
        );
    }
    Ok(())
}
