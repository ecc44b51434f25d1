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
    /// Load a dataset and write its binary cache (later loads are fast); with --markers,
    /// also build and cache its LGI index for that layout, printing the index statistics.
    Build {
        #[command(flatten)]
        dataset: DatasetArgs,
        /// Marker layout CSV: build (or load) the LGI index for it and cache it, as
        /// `helmcap solve` would.
        #[arg(long, short = 'k', value_name = "CSV")]
        markers: Option<PathBuf>,
        /// LGI parameters file (TOML with the fields of LgiParams; only the index-building
        /// ones matter here).
        #[arg(long, value_name = "TOML", requires = "markers")]
        lgi_params: Option<PathBuf>,
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
        DatasetCommand::Build {
            dataset,
            markers,
            lgi_params,
        } => {
            let t = Instant::now();
            let ds = dataset.load()?;
            println!(
                "dataset {}: {} shapes of {} vertices ready ({:.2} s)",
                ds.name,
                ds.shapes.len(),
                ds.vertex_count(),
                t.elapsed().as_secs_f64()
            );
            if let Some(markers) = markers {
                build_index(&dataset, &ds, &markers, lgi_params.as_deref())?;
            }
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

/// Builds (or loads) the LGI index of `ds` for the layout `markers` and caches it.
fn build_index(
    args: &DatasetArgs,
    ds: &helmcap::dataset::Dataset,
    markers: &std::path::Path,
    lgi_params: Option<&std::path::Path>,
) -> anyhow::Result<()> {
    use helmcap::lgi::cache::{IndexSource, cache_path, load_or_build};
    let layout = helmcap::dataset::MarkerLayout::read_csv(markers)
        .with_context(|| format!("reading markers {}", markers.display()))?;
    layout
        .validate_for(ds)
        .with_context(|| format!("markers {} do not fit {}", markers.display(), ds.name))?;
    let params = match lgi_params {
        Some(p) => {
            let text =
                std::fs::read_to_string(p).with_context(|| format!("reading {}", p.display()))?;
            toml::from_str::<helmcap::lgi::LgiParams>(&text)
                .with_context(|| format!("{}: not LGI parameters", p.display()))?
        }
        None => helmcap::lgi::LgiParams::default(),
    };
    params.validate()?;
    let dir = (!args.no_cache).then(|| {
        args.cache_dir
            .clone()
            .unwrap_or_else(helmcap::dataset::cache::default_cache_dir)
    });
    let t = Instant::now();
    let (index, source) = load_or_build(ds, &layout, &params, dir.as_deref())?;
    println!("{}", index.stats);
    match (&dir, source) {
        (Some(d), src) => {
            let path = cache_path(d, ds, &layout, &params);
            let size = std::fs::metadata(&path).map(|m| m.len()).unwrap_or(0);
            println!(
                "LGI index {} {} ({:.1} MB, {:.2} s)",
                if src == IndexSource::Cache {
                    "read from"
                } else {
                    "written to"
                },
                path.display(),
                size as f64 / 1e6,
                t.elapsed().as_secs_f64()
            );
        }
        (None, _) => println!("LGI index built, not cached (--no-cache)"),
    }
    Ok(())
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
