//! `helmcap enhance`: adds the database's actor-specific details to a mesh sequence
//! (Bermano et al. 2014 §5).

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use helmcap::dataset::actor::Actor;
use helmcap::dataset::builtin_params;
use helmcap::enhance::{EnhanceParams, EnhanceTimings, Enhancer, build_enhancer, read_params};
use helmcap::mesh::{read_obj_positions, write_obj_positions};
use helmcap::sink::read_usda_sequence;

use super::DatasetArgs;

/// Arguments of `helmcap enhance`.
#[derive(Debug, clap::Args)]
pub struct EnhanceArgs {
    /// Database: a dataset manifest (its neutral and shapes are the performance frames), or
    /// `builtin[:SEED]` for the built-in actor.
    #[arg(long, value_name = "MANIFEST")]
    pub database: String,
    /// Frames in the database topology: a folder of OBJ files (e.g. the output of
    /// `helmcap solve`), processed in file-name order, or a `mesh.usda` written by
    /// `helmcap replay --export usd` (one mesh, time-sampled points), processed in
    /// time-sample order.
    #[arg(long, value_name = "DIR_OR_USDA")]
    pub input: PathBuf,
    /// Output folder; each frame is written under its input file name (OBJ input) or as
    /// `frame_NNNNNN.obj`, NNNNNN the time code (USD input).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    /// Enhancement parameters (TOML, fields of `EnhanceParams`; missing fields keep their
    /// defaults).
    #[arg(long, value_name = "TOML")]
    pub params: Option<PathBuf>,
    /// Unit of the input meshes (default mm); each frame is checked against the
    /// database's size, so a file in metres read as millimetres is refused.
    #[arg(long, value_enum, default_value_t = super::MeshUnits::Mm)]
    pub units: super::MeshUnits,
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

/// Where `helmcap enhance` takes its frames from.
enum Input {
    /// OBJ files, in name order.
    Objs(Vec<PathBuf>),
    /// The time samples of a `mesh.usda`: output file name and positions.
    Usd(Vec<(String, Vec<nalgebra::Point3<f64>>)>),
}

impl Input {
    /// A folder of OBJ files, or a `.usda` file.
    fn open(path: &Path) -> anyhow::Result<Self> {
        if path.is_dir() {
            return Ok(Self::Objs(obj_files(path)?));
        }
        let ext = path
            .extension()
            .map(|e| e.to_string_lossy().to_ascii_lowercase());
        match ext.as_deref() {
            Some("usda" | "usd") => {
                let seq = read_usda_sequence(path)?;
                let frames = seq
                    .frames
                    .into_iter()
                    .map(|(time, p)| (format!("frame_{:06}.obj", time.round() as i64), p))
                    .collect();
                Ok(Self::Usd(frames))
            }
            _ if !path.exists() => bail!("{}: no such folder or file", path.display()),
            _ => bail!(
                "{}: --input takes a folder of OBJ files or a .usda file",
                path.display()
            ),
        }
    }

    fn len(&self) -> usize {
        match self {
            Self::Objs(f) => f.len(),
            Self::Usd(f) => f.len(),
        }
    }
}

/// Runs `helmcap enhance`.
pub fn run(args: EnhanceArgs) -> anyhow::Result<()> {
    let params = read_params(args.params.as_deref())?;
    let input = Input::open(&args.input)?;
    let (dataset, enhancer) = build_enhancer(&args.database, &params, true)?;
    if let Input::Usd(frames) = &input {
        let expected = dataset.vertex_count();
        if let Some((name, p)) = frames.first()
            && p.len() != expected
        {
            bail!(
                "{}: {} has {} points but the database {} has {expected} vertices",
                args.input.display(),
                name,
                p.len(),
                dataset.name
            );
        }
    }
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;
    let count = input.len();
    let bar = indicatif::ProgressBar::new(count as u64);
    let enhance_one = |label: &str, name: &std::ffi::OsStr, positions: &[nalgebra::Point3<f64>]| {
        let positions = args
            .units
            .to_mm_checked(positions, &dataset.neutral.positions, label)?;
        let positions = &positions[..];
        let enhanced = enhancer
            .enhance(positions)
            .with_context(|| format!("enhancing {label}"))?;
        let out = args.out.join(name);
        write_obj_positions(&out, &dataset.neutral, &enhanced)
            .with_context(|| format!("writing {}", out.display()))?;
        bar.inc(1);
        anyhow::Ok(())
    };
    match &input {
        Input::Objs(files) => {
            for file in files {
                let positions = read_obj_positions(file)
                    .with_context(|| format!("reading {}", file.display()))?;
                let name = file.file_name().context("input file without a name")?;
                enhance_one(&file.display().to_string(), name, &positions)?;
            }
        }
        Input::Usd(frames) => {
            for (name, positions) in frames {
                let label = format!("{} ({name})", args.input.display());
                enhance_one(&label, std::ffi::OsStr::new(name), positions)?;
            }
        }
    }
    bar.finish_and_clear();
    println!(
        "enhanced {} frames against {} ({} database frames) into {}",
        count,
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
    let rss_before = helmcap::bench::host::resident_kib();
    let t = std::time::Instant::now();
    let (dataset, enhancer) = if args.subdivide == 0 {
        build_enhancer(&args.database, &params, true)?
    } else {
        let coarse = match builtin_params(&args.database)? {
            Some(p) => Actor::new(&p)
                .context("building the built-in actor")?
                .to_dataset(),
            None => DatasetArgs::new(args.database.clone()).load()?,
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
    let rss_after = helmcap::bench::host::resident_kib();
    let inputs: Vec<_> = std::iter::once(&dataset.neutral.positions)
        .chain(dataset.shapes.iter().map(|s| &s.positions))
        .collect();
    let cpu_before = helmcap::bench::host::process_cpu_seconds();
    let timed_start = std::time::Instant::now();
    let mut times = Vec::with_capacity(args.frames.max(1));
    let mut steps = Vec::with_capacity(args.frames.max(1));
    let mut selected = Vec::with_capacity(args.frames.max(1));
    for i in 0..args.frames.max(1) {
        let input = inputs[i % inputs.len()];
        let mut step = EnhanceTimings::default();
        let t = std::time::Instant::now();
        let out = enhancer.enhance_timed(input, &mut step)?;
        times.push(t.elapsed().as_secs_f64());
        steps.push(step);
        selected.push(
            (0..enhancer.frame_count())
                .filter(|&k| out.region_weights.iter().any(|w| w[k] > 1e-9))
                .count(),
        );
        std::hint::black_box(out);
    }
    let timed_wall = timed_start.elapsed().as_secs_f64();
    let cpu = match (cpu_before, helmcap::bench::host::process_cpu_seconds()) {
        (Some(a), Some(b)) => Some(b - a),
        _ => None,
    };
    times.sort_by(f64::total_cmp);
    let median = times[times.len() / 2];
    let step_median = |f: fn(&EnhanceTimings) -> f64| {
        let mut v: Vec<f64> = steps.iter().map(f).collect();
        v.sort_by(f64::total_cmp);
        v[v.len() / 2] * 1e3
    };
    println!(
        "enhance {}: {} vertices, {} triangles, {} database frames, {} patches",
        dataset.name,
        dataset.vertex_count(),
        dataset.neutral.triangles.len(),
        enhancer.frame_count(),
        enhancer.patch_count()
    );
    println!(
        "  triangles with details that vary between database frames: {}",
        enhancer.varying_triangle_count()
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
    if let Some(cpu) = cpu {
        let frames = times.len() as f64;
        println!(
            "  CPU per frame (user + system / frames) {:.1} ms, {:.2} cores busy on average",
            cpu / frames * 1e3,
            cpu / timed_wall
        );
    }
    selected.sort_unstable();
    println!(
        "  database frames selected by some region (median) {}",
        selected[selected.len() / 2]
    );
    println!(
        "  steps (median, ms)  low-pass {:.1}, encode {:.1}, matching {:.1}, blend {:.1}, \
         reconstruct {:.1}, finish {:.1}",
        step_median(|s| s.low_pass_input),
        step_median(|s| s.encode),
        step_median(|s| s.matching),
        step_median(|s| s.blend),
        step_median(|s| s.reconstruct),
        step_median(|s| s.finish),
    );
    Ok(())
}
