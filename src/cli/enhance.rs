//! `helmcap enhance`: adds the database's actor-specific details to a mesh sequence
//! (Bermano et al. 2014 §5).

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use helmcap::dataset::Dataset;
use helmcap::dataset::actor::Actor;
use helmcap::enhance::{EnhanceParams, Enhancer, VoluntaryRegions};
use helmcap::mesh::{read_obj_positions, write_obj_positions};

use super::{DatasetArgs, builtin_params};

/// Arguments of `helmcap enhance`.
#[derive(Debug, clap::Args)]
pub struct EnhanceArgs {
    /// Database: a dataset manifest (its neutral and shapes are the performance frames), or
    /// `builtin[:SEED]` for the built-in actor.
    #[arg(long, value_name = "MANIFEST")]
    pub database: String,
    /// Folder of OBJ frames in the database topology (e.g. the output of `helmcap solve`),
    /// processed in file-name order.
    #[arg(long, value_name = "DIR")]
    pub input: PathBuf,
    /// Output folder; each frame is written under its input file name.
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    /// Enhancement parameters (TOML, fields of `EnhanceParams`; missing fields keep their
    /// defaults).
    #[arg(long, value_name = "TOML")]
    pub params: Option<PathBuf>,
}

/// Loads the database and precomputes the enhancer; the built-in actor uses its labelled
/// regions, other datasets regions derived from their motion.
pub fn build_enhancer(
    database: &str,
    params: &EnhanceParams,
) -> anyhow::Result<(Dataset, Enhancer)> {
    let args = DatasetArgs {
        dataset: database.to_string(),
        no_cache: false,
        cache_dir: None,
    };
    if let Some(actor_params) = builtin_params(database)? {
        let actor = Actor::new(&actor_params).context("building the built-in actor")?;
        let dataset = actor.to_dataset();
        let regions = VoluntaryRegions::from_actor(&actor);
        let enhancer = Enhancer::with_regions(&dataset, params, &regions)
            .context("precomputing the enhancement database")?;
        return Ok((dataset, enhancer));
    }
    let dataset = args.load()?;
    let manifest = helmcap::dataset::Manifest::read(Path::new(database))
        .with_context(|| format!("reading {database}"))?;
    let enhancer = match manifest.regions {
        Some(cores) => {
            tracing::info!("voluntary regions from the manifest's [regions]");
            Enhancer::with_regions(&dataset, params, &VoluntaryRegions { cores })
        }
        None => Enhancer::new(&dataset, params),
    }
    .context("precomputing the enhancement database")?;
    Ok((dataset, enhancer))
}

/// Reads an [`EnhanceParams`] TOML file, or the defaults.
pub fn read_params(path: Option<&Path>) -> anyhow::Result<EnhanceParams> {
    let params: EnhanceParams = match path {
        Some(p) => {
            let text =
                std::fs::read_to_string(p).with_context(|| format!("reading {}", p.display()))?;
            toml::from_str(&text).with_context(|| format!("parsing {}", p.display()))?
        }
        None => EnhanceParams::default(),
    };
    params.validate()?;
    Ok(params)
}

/// The OBJ files of `dir`, sorted by name.
pub fn obj_files(dir: &Path) -> anyhow::Result<Vec<PathBuf>> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .with_context(|| format!("reading folder {}", dir.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e.eq_ignore_ascii_case("obj")))
        .collect();
    files.sort();
    if files.is_empty() {
        bail!("no .obj files in {}", dir.display());
    }
    Ok(files)
}

/// Runs `helmcap enhance`.
pub fn run(args: EnhanceArgs) -> anyhow::Result<()> {
    let params = read_params(args.params.as_deref())?;
    let files = obj_files(&args.input)?;
    let (dataset, enhancer) = build_enhancer(&args.database, &params)?;
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;
    let bar = indicatif::ProgressBar::new(files.len() as u64);
    for file in &files {
        let positions =
            read_obj_positions(file).with_context(|| format!("reading {}", file.display()))?;
        let enhanced = enhancer
            .enhance(&positions)
            .with_context(|| format!("enhancing {}", file.display()))?;
        let name = file.file_name().context("input file without a name")?;
        let out = args.out.join(name);
        write_obj_positions(&out, &dataset.neutral, &enhanced)
            .with_context(|| format!("writing {}", out.display()))?;
        bar.inc(1);
    }
    bar.finish_and_clear();
    println!(
        "enhanced {} frames against {} ({} database frames) into {}",
        files.len(),
        dataset.name,
        enhancer.frame_count(),
        args.out.display()
    );
    Ok(())
}

/// Arguments of `helmcap bench enhance`.
#[derive(Debug, clap::Args)]
pub struct EnhanceBenchArgs {
    /// Database (manifest or `builtin[:SEED]`), e.g. configs/datasets/ict-facekit.toml for
    /// the 26,719-vertex ICT resolution.
    #[arg(long, value_name = "MANIFEST", default_value = "builtin")]
    pub database: String,
    /// Number of timed frames (the database shapes, in turn).
    #[arg(long, default_value_t = 20)]
    pub frames: usize,
    /// Catmull-Clark subdivision levels applied to the whole database first (2 on ICT
    /// gives about 430k vertices): the per-frame cost at film resolution.
    #[arg(long, default_value_t = 0)]
    pub subdivide: usize,
}

/// Runs `helmcap bench enhance`: precomputation time, memory, median per-frame time.
pub fn run_bench(args: EnhanceBenchArgs) -> anyhow::Result<()> {
    let params = EnhanceParams::default();
    let rss_before = resident_kib();
    let t = std::time::Instant::now();
    let (dataset, enhancer) = if args.subdivide == 0 {
        build_enhancer(&args.database, &params)?
    } else {
        let coarse = match builtin_params(&args.database)? {
            Some(p) => Actor::new(&p)
                .context("building the built-in actor")?
                .to_dataset(),
            None => DatasetArgs {
                dataset: args.database.clone(),
                no_cache: false,
                cache_dir: None,
            }
            .load()?,
        };
        let fine = coarse
            .subdivided(
                args.subdivide,
                helmcap::mesh::SubdivisionScheme::CatmullClark,
            )
            .context("subdividing the database")?;
        let enhancer =
            Enhancer::new(&fine, &params).context("precomputing the enhancement database")?;
        (fine, enhancer)
    };
    let load_and_precompute = t.elapsed().as_secs_f64();
    let rss_after = resident_kib();
    let inputs: Vec<_> = std::iter::once(&dataset.neutral.positions)
        .chain(dataset.shapes.iter().map(|s| &s.positions))
        .collect();
    let mut times = Vec::with_capacity(args.frames.max(1));
    for i in 0..args.frames.max(1) {
        let input = inputs[i % inputs.len()];
        let t = std::time::Instant::now();
        let out = enhancer.enhance(input)?;
        times.push(t.elapsed().as_secs_f64());
        std::hint::black_box(out);
    }
    times.sort_by(f64::total_cmp);
    let median = times[times.len() / 2];
    println!(
        "enhance {}: {} vertices, {} triangles, {} database frames, {} patches",
        dataset.name,
        dataset.vertex_count(),
        dataset.neutral.triangles.len(),
        enhancer.frame_count(),
        enhancer.patch_count()
    );
    println!("  load + precompute   {:8.2} s", load_and_precompute);
    println!(
        "  precomputed data    {:8.1} MB (estimate){}",
        enhancer.memory_bytes() as f64 / 1e6,
        match (rss_before, rss_after) {
            (Some(a), Some(b)) => format!(
                ", resident set grew {:.1} MB",
                (b as f64 - a as f64) / 1024.0
            ),
            _ => String::new(),
        }
    );
    println!(
        "  per frame (median of {}) {:8.1} ms = {:.1} frames/s",
        times.len(),
        median * 1e3,
        1.0 / median
    );
    Ok(())
}

/// The process's resident set size in KiB, where the platform reports it.
fn resident_kib() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmRSS:"))?;
    line.split_whitespace().nth(1)?.parse().ok()
}
