//! `helmcap retime`: keyframe interpolation with the actor's timing (Bermano et al. 2014 §6).

use std::path::PathBuf;

use anyhow::{Context, bail};
use helmcap::dataset::actor::Actor;
use helmcap::dataset::builtin_params;
use helmcap::enhance::{Retimer, Sequence, build_enhancer, builtin_sequences, read_params};
use helmcap::mesh::{read_obj_positions, write_obj_positions};

use super::enhance::obj_files;

/// Frames per built-in actor sequence.
const BUILTIN_SEQUENCE_FRAMES: usize = 24;

/// Arguments of `helmcap retime`.
#[derive(Debug, clap::Args)]
pub struct RetimeArgs {
    /// Database: a dataset manifest or `builtin[:SEED]`.
    #[arg(long, value_name = "MANIFEST")]
    pub database: String,
    /// Database sequences: a folder with one sub-folder of OBJ frames (ordered by file
    /// name, uniform in time) per sequence. Default for `builtin`: the actor's own
    /// animated sequences.
    #[arg(long, value_name = "DIR")]
    pub sequences: Option<PathBuf>,
    /// First keyframe (OBJ in the database topology).
    #[arg(long, value_name = "OBJ")]
    pub from: PathBuf,
    /// Last keyframe (OBJ in the database topology).
    #[arg(long, value_name = "OBJ")]
    pub to: PathBuf,
    /// Number of frames to produce, keyframes included (at least 2).
    #[arg(long)]
    pub frames: usize,
    /// Output folder (frame_0000.obj, ...).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    /// Take the timing of the matched sequence's whole motion, not only the matched part.
    #[arg(long)]
    pub extend: bool,
    /// Enhancement parameters (TOML), as for `helmcap enhance`.
    #[arg(long, value_name = "TOML")]
    pub params: Option<PathBuf>,
    /// Unit of the keyframe meshes; both are checked against the database's size.
    #[arg(long, value_enum, default_value_t = super::MeshUnits::Mm)]
    pub units: super::MeshUnits,
}

/// Runs `helmcap retime`.
pub fn run(args: RetimeArgs) -> anyhow::Result<()> {
    if args.frames < 2 {
        bail!("--frames must be at least 2, got {}", args.frames);
    }
    let params = read_params(args.params.as_deref())?;
    let first = read_obj_positions(&args.from)
        .with_context(|| format!("reading {}", args.from.display()))?;
    let last =
        read_obj_positions(&args.to).with_context(|| format!("reading {}", args.to.display()))?;
    let (dataset, enhancer) = build_enhancer(&args.database, &params, false)?;
    let reference = &dataset.neutral.positions;
    let first = if first.len() == reference.len() {
        args.units
            .to_mm_checked(&first, reference, &args.from.display().to_string())?
    } else {
        first
    };
    let last = if last.len() == reference.len() {
        args.units
            .to_mm_checked(&last, reference, &args.to.display().to_string())?
    } else {
        last
    };
    let sequences: Vec<Sequence> = match (&args.sequences, builtin_params(&args.database)?) {
        (Some(dir), _) => {
            let mut subdirs: Vec<PathBuf> = std::fs::read_dir(dir)
                .with_context(|| format!("reading folder {}", dir.display()))?
                .filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|p| p.is_dir())
                .collect();
            subdirs.sort();
            if subdirs.is_empty() {
                bail!("no sequence sub-folders in {}", dir.display());
            }
            subdirs
                .iter()
                .map(|d| {
                    obj_files(d)?
                        .iter()
                        .map(|f| {
                            read_obj_positions(f)
                                .with_context(|| format!("reading {}", f.display()))
                        })
                        .collect::<anyhow::Result<Sequence>>()
                })
                .collect::<anyhow::Result<_>>()?
        }
        (None, Some(p)) => {
            let actor = Actor::new(&p).context("building the built-in actor")?;
            builtin_sequences(&actor, BUILTIN_SEQUENCE_FRAMES).0
        }
        (None, None) => bail!("--sequences is required for a manifest database"),
    };
    let retimer = Retimer::new(&enhancer, &sequences).context("encoding the sequences")?;
    let out = retimer
        .retime(&enhancer, &first, &last, args.frames, args.extend)
        .context("retiming")?;
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;
    for (k, frame) in out.frames.iter().enumerate() {
        let path = args.out.join(format!("frame_{k:04}.obj"));
        write_obj_positions(&path, &dataset.neutral, frame)
            .with_context(|| format!("writing {}", path.display()))?;
    }
    println!(
        "retimed {} frames with the timing of sequence {} into {}",
        out.frames.len(),
        out.sequence,
        args.out.display()
    );
    Ok(())
}
