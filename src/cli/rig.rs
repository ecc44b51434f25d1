//! `helmcap rig ...`: actor-specific blendshape rigs (Li et al. 2010; Cong et al. 2019 §7).
//!
//! # EXAMPLES.toml (`rig build --examples`)
//! ```toml
//! units = "mm"                                  # optional: unit of the example meshes
//!                                               # ("mm", "cm" or "m"); default: --units
//! exclusive = [["mouthLeft", "mouthRight"]]     # optional: pairs never active together
//!
//! [[example]]                                   # repeatable (zero examples is allowed:
//! name = "smile"                                #   the rig is then deformation transfer)
//! file = "examples/smile.obj"                   # relative to this file; template topology
//! weights = { mouthSmile_L = 0.8, mouthSmile_R = 0.8 }   # rough initial weights α* by
//!                                               # template shape name; others are 0
//! ```
//! `name` is optional (default: the file stem). Unknown shape names are an error.

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use clap::Subcommand;
use helmcap::dataset::markers::{LayoutParams, generate_layout};
use helmcap::dataset::{Dataset, MarkerLayout, Units, write_dataset};
use helmcap::mesh::read_obj_positions;
use helmcap::rig::{
    Combination, Example, FromLgiParams, IterationReport, RigBuilder, RigParams, rig_from_lgi,
};
use nalgebra::Point3;

use super::DatasetArgs;

#[derive(Debug, Subcommand)]
pub enum RigCommand {
    /// Example-based rigging (Li et al. 2010): actor blendshapes from a template rig, the
    /// actor's neutral and a few example poses with rough weights.
    Build(BuildArgs),
    /// Rig generation with local geometric indexing (Cong et al. 2019 §7): the template's
    /// blendshapes (and combinations) transferred to the actor, sampled at the markers and
    /// reconstructed from the actor's own dataset.
    FromLgi(FromLgiArgs),
}

/// Arguments of `helmcap rig from-lgi`.
#[derive(Debug, clap::Args)]
pub struct FromLgiArgs {
    /// Template rig in the actor's topology (dataset manifest or `builtin[:SEED]`), e.g.
    /// registered to the actor's neutral with `helmcap register`.
    #[arg(long, value_name = "MANIFEST")]
    pub template: String,
    /// The actor's dataset (its captured shapes are the LGI database; its neutral is B₀).
    #[command(flatten)]
    pub dataset: DatasetArgs,
    /// Marker layout CSV on the actor's neutral (default: one generated for the dataset
    /// with the default layout parameters, as `helmcap markers generate` does).
    #[arg(long, value_name = "CSV")]
    pub layout: Option<PathBuf>,
    /// Combinations to reconstruct as corrective shapes: `none`, `all` (every pair of
    /// template shapes), or a comma-separated list like `mouthSmile_L+mouthSmile_R,jawOpen+mouthFunnel`
    /// (a term may carry a weight: `jawOpen*0.5+mouthFunnel`).
    #[arg(long, default_value = "none")]
    pub combinations: String,
    /// Output folder: the rig as a dataset (manifest.toml, neutral.obj, shapes/*.obj).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
}

/// Arguments of `helmcap rig build`.
#[derive(Debug, clap::Args)]
pub struct BuildArgs {
    /// Template rig: a dataset manifest (its neutral is A₀, its shapes A₀ + Aᵢ), or
    /// `builtin[:SEED]` for the built-in actor.
    #[arg(long, value_name = "MANIFEST")]
    pub template: String,
    /// The actor's neutral B₀ (OBJ in the template's topology, aligned with the template's
    /// head frame; e.g. from `helmcap register`).
    #[arg(long, value_name = "OBJ")]
    pub neutral: PathBuf,
    /// Example poses with initial weights (TOML; format in the README, section "Actor
    /// rigs"). Without it the rig is deformation transfer of the template.
    #[arg(long, value_name = "TOML")]
    pub examples: Option<PathBuf>,
    /// Output folder: manifest.toml, neutral.obj, shapes/*.obj, example_weights.csv.
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    /// Unit of the neutral (and of the examples unless EXAMPLES.toml says): mm, cm or m.
    #[arg(long, default_value = "mm")]
    pub units: String,
    /// Rig parameters (TOML, fields of `RigParams`; missing fields keep their defaults).
    #[arg(long, value_name = "TOML")]
    pub params: Option<PathBuf>,
    /// Number of alternations (overrides the parameter file; default 10).
    #[arg(long)]
    pub alternations: Option<usize>,
    /// Read and write no dataset cache for the template.
    #[arg(long)]
    pub no_cache: bool,
}

/// The examples file.
#[derive(Debug, serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct ExamplesFile {
    units: Option<String>,
    #[serde(default)]
    exclusive: Vec<[String; 2]>,
    #[serde(default, rename = "example")]
    examples: Vec<ExampleEntry>,
}

#[derive(Debug, serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct ExampleEntry {
    name: Option<String>,
    file: PathBuf,
    #[serde(default)]
    weights: std::collections::BTreeMap<String, f64>,
}

pub fn run(cmd: RigCommand) -> anyhow::Result<()> {
    match cmd {
        RigCommand::Build(a) => build(a),
        RigCommand::FromLgi(a) => from_lgi(a),
    }
}

fn parse_units(s: &str) -> anyhow::Result<f64> {
    Units::parse(s)
        .map(Units::to_mm)
        .with_context(|| format!("unknown unit {s:?} (use mm, cm or m)"))
}

/// Reads an OBJ's positions in millimetres, checking the vertex count.
fn read_mesh_mm(path: &Path, scale: f64, vertices: usize) -> anyhow::Result<Vec<Point3<f64>>> {
    let mut p = read_obj_positions(path).with_context(|| format!("reading {}", path.display()))?;
    if p.len() != vertices {
        bail!(
            "{}: {} vertices, the template has {vertices}",
            path.display(),
            p.len()
        );
    }
    for x in &mut p {
        x.coords *= scale;
    }
    Ok(p)
}

/// The examples and the exclusive pairs (shape indices) of an EXAMPLES.toml.
type ExamplesAndPairs = (Vec<Example>, Vec<(usize, usize)>);

/// Reads EXAMPLES.toml: the examples and the exclusive pairs as shape indices.
fn read_examples(
    path: &Path,
    template: &Dataset,
    default_scale: f64,
) -> anyhow::Result<ExamplesAndPairs> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let file: ExamplesFile =
        toml::from_str(&text).with_context(|| format!("parsing {}", path.display()))?;
    let scale = match &file.units {
        Some(u) => parse_units(u).with_context(|| format!("{}: units", path.display()))?,
        None => default_scale,
    };
    let dir = path.parent().unwrap_or(Path::new("."));
    let index = |name: &str| {
        template
            .shape_index(name)
            .with_context(|| format!("{}: the template has no shape {name:?}", path.display()))
    };
    let mut examples = Vec::new();
    for e in &file.examples {
        let file_path = dir.join(&e.file);
        let positions = read_mesh_mm(&file_path, scale, template.vertex_count())?;
        let mut initial_weights = vec![0.0; template.shapes.len()];
        for (name, &w) in &e.weights {
            if !w.is_finite() {
                bail!("{}: weight of {name} is not finite", path.display());
            }
            initial_weights[index(name)?] = w;
        }
        let name = match &e.name {
            Some(n) => n.clone(),
            None => e
                .file
                .file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_else(|| format!("example{}", examples.len())),
        };
        examples.push(Example {
            name,
            positions,
            initial_weights,
        });
    }
    let exclusive = file
        .exclusive
        .iter()
        .map(|[a, b]| Ok((index(a)?, index(b)?)))
        .collect::<anyhow::Result<Vec<_>>>()?;
    Ok((examples, exclusive))
}

fn read_params(path: Option<&Path>) -> anyhow::Result<RigParams> {
    let params: RigParams = match path {
        Some(p) => {
            let text =
                std::fs::read_to_string(p).with_context(|| format!("reading {}", p.display()))?;
            toml::from_str(&text).with_context(|| format!("parsing {}", p.display()))?
        }
        None => RigParams::default(),
    };
    params.validate()?;
    Ok(params)
}

fn build(args: BuildArgs) -> anyhow::Result<()> {
    let mut params = read_params(args.params.as_deref())?;
    if let Some(k) = args.alternations {
        params.alternations = k;
    }
    params.validate()?;
    let template = DatasetArgs {
        dataset: args.template.clone(),
        no_cache: args.no_cache,
        cache_dir: None,
    }
    .load()?;
    let scale = parse_units(&args.units)?;
    let neutral = read_mesh_mm(&args.neutral, scale, template.vertex_count())?;
    let (examples, exclusive) = match &args.examples {
        Some(p) => read_examples(p, &template, scale)?,
        None => (Vec::new(), Vec::new()),
    };
    let builder = RigBuilder::new(&template, &neutral, &params)
        .context("preparing the rig (frames, reconstruction systems)")?;
    let bar = if examples.is_empty() {
        indicatif::ProgressBar::hidden()
    } else {
        indicatif::ProgressBar::new(params.alternations as u64)
    };
    let mut on_iteration = |r: &IterationReport| {
        // Printed through the bar (suspended), so it also reaches a pipe.
        bar.suspend(|| {
            println!(
                "alternation {}/{} (β {:.3}, γ {:.0}, {:.2} s):",
                r.iteration + 1,
                r.of,
                r.beta,
                r.gamma,
                r.seconds
            );
            for (e, f) in examples.iter().zip(&r.fits) {
                println!(
                    "  {:<24} rms {:7.3} mm  max {:7.3} mm  residual {:5.1} %",
                    e.name,
                    f.vertex_rms_mm,
                    f.vertex_max_mm,
                    f.frame_residual * 100.0
                );
            }
        });
        bar.inc(1);
    };
    let rig = builder
        .build(&examples, &exclusive, &mut on_iteration)
        .context("building the rig")?;
    bar.finish_and_clear();
    let name = args
        .out
        .file_name()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "rig".into());
    let dataset = rig.to_dataset(&template, &name)?;
    let manifest = write_dataset(&dataset, &args.out)
        .with_context(|| format!("writing the rig to {}", args.out.display()))?;
    if !examples.is_empty() {
        let csv = args.out.join("example_weights.csv");
        helmcap::atomic_file::write_atomically(&csv, |w| {
            use std::io::Write as _;
            write!(w, "example")?;
            for n in &rig.names {
                write!(w, ",{n}")?;
            }
            writeln!(w)?;
            for (e, a) in examples.iter().zip(&rig.weights) {
                write!(w, "{}", e.name)?;
                for x in a {
                    write!(w, ",{x:.6}")?;
                }
                writeln!(w)?;
            }
            Ok(())
        })
        .with_context(|| format!("writing {}", csv.display()))?;
    }
    for &j in &rig.inexpressible {
        println!(
            "warning: example {} cannot be expressed by the template ({:.0} % unexplained)",
            examples[j].name,
            rig.fits[j].frame_residual * 100.0
        );
    }
    println!(
        "rig of {} blendshapes from {} examples written to {}",
        rig.names.len(),
        examples.len(),
        manifest.display()
    );
    Ok(())
}

/// Parses `--combinations`.
fn parse_combinations(spec: &str, template: &Dataset) -> anyhow::Result<Vec<Combination>> {
    let n = template.shapes.len();
    match spec.trim() {
        "none" | "" => Ok(Vec::new()),
        "all" => Ok((0..n)
            .flat_map(|a| ((a + 1)..n).map(move |b| vec![(a, 1.0), (b, 1.0)]))
            .collect()),
        list => list
            .split(',')
            .map(|combo| {
                combo
                    .split('+')
                    .map(|term| {
                        let (name, w) = match term.split_once('*') {
                            Some((name, w)) => (
                                name.trim(),
                                w.trim()
                                    .parse::<f64>()
                                    .with_context(|| format!("bad weight in {term:?}"))?,
                            ),
                            None => (term.trim(), 1.0),
                        };
                        let i = template
                            .shape_index(name)
                            .with_context(|| format!("the template has no shape {name:?}"))?;
                        Ok((i, w))
                    })
                    .collect::<anyhow::Result<Combination>>()
            })
            .collect(),
    }
}

fn from_lgi(args: FromLgiArgs) -> anyhow::Result<()> {
    let template = args.dataset.for_dataset(args.template.clone()).load()?;
    let dataset = args.dataset.load()?;
    let layout = match &args.layout {
        Some(p) => MarkerLayout::read_csv(p).with_context(|| format!("reading {}", p.display()))?,
        None => generate_layout(&dataset, &LayoutParams::default())
            .context("generating a marker layout for the dataset")?,
    };
    let combinations = parse_combinations(&args.combinations, &template)?;
    let total = (template.shapes.len() + combinations.len()) as u64;
    let bar = indicatif::ProgressBar::new(total);
    let rig = rig_from_lgi(
        &template,
        &dataset,
        &layout,
        &combinations,
        &FromLgiParams::default(),
        &|done, _| bar.set_position(done as u64),
    )
    .context("building the rig through LGI")?;
    bar.finish_and_clear();
    let manifest = write_dataset(&rig.dataset, &args.out)
        .with_context(|| format!("writing the rig to {}", args.out.display()))?;
    println!(
        "rig of {} blendshapes and {} combinations from {} markers written to {}",
        template.shapes.len(),
        combinations.len(),
        layout.len(),
        manifest.display()
    );
    Ok(())
}
