//! `helmcap farm job` (a shooting day as an OpenJD job bundle) and `helmcap farm merge`
//! (the chunks of a take joined into one take folder).

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use helmcap::capture::{Replay, ReplayParams};
use helmcap::farm::{JobSpec, JobTake, ReplayOption, chunk_ranges, find_chunks, merge_chunks};
use helmcap::take::{DEFAULT_SOLVE_KEYFRAMES, Export};

/// `helmcap farm` subcommands.
#[derive(Debug, clap::Subcommand)]
pub enum FarmCommand {
    /// Write an OpenJD job bundle (template.yaml, parameter_values.yaml) that replays each
    /// take in chunks of frames, merges each take, then writes the dailies report.
    Job(Box<JobArgs>),
    /// Join the chunks of a take (replay --frames --warm-up folders) into the take folder a
    /// single replay writes.
    Merge(MergeArgs),
}

/// Arguments of `helmcap farm job`.
#[derive(Debug, clap::Args)]
pub struct JobArgs {
    /// Session folders, one per take; a folder of session folders adds each of them.
    #[arg(long, required = true, num_args = 1.., value_name = "DIR")]
    pub takes: Vec<PathBuf>,
    /// Folder of the job bundle (template.yaml, parameter_values.yaml).
    #[arg(long, short)]
    pub out: PathBuf,
    /// Folder the job writes into (chunks/, one folder per take, report/): the OutDir job
    /// parameter (default: results/ in the bundle folder).
    #[arg(long, value_name = "DIR")]
    pub results: Option<PathBuf>,
    /// Frames per chunk (one farm task each).
    #[arg(long, default_value_t = 600)]
    pub chunk: usize,
    /// Frames each chunk runs before its range to warm up (the WarmUpFrames job
    /// parameter).
    #[arg(long, default_value_t = 60)]
    pub overlap: usize,
    /// The job's name.
    #[arg(long, default_value = "helmcap dailies")]
    pub name: String,
    /// The helmcap executable the workers run (default: this one).
    #[arg(long, value_name = "PATH")]
    pub helmcap: Option<PathBuf>,
    /// Replay: dataset manifest, or `builtin[:SEED]`.
    #[arg(long, short = 'd', default_value = "builtin")]
    pub dataset: String,
    /// Replay: marker layout CSV.
    #[arg(long, short = 'k', value_name = "CSV")]
    pub markers: Option<PathBuf>,
    /// Replay: calibration YAML (default: the one each session names).
    #[arg(long, value_name = "YAML")]
    pub calib: Option<PathBuf>,
    /// Replay: capture profile (default: the one each session names).
    #[arg(long, value_name = "TOML")]
    pub profile: Option<PathBuf>,
    /// Replay: export format (repeatable): obj, ply, usd, c3d.
    #[arg(long, value_enum)]
    pub export: Vec<Export>,
    /// Replay: add the actor's fine detail to every mesh.
    #[arg(long)]
    pub enhance: bool,
    /// Replay: force the mesh through every bundle.
    #[arg(long)]
    pub exact_bundles: bool,
    /// Replay: LGI parameters of the solve stage (TOML).
    #[arg(long, value_name = "TOML")]
    pub lgi_params: Option<PathBuf>,
    /// Replay: skip unreadable frames instead of stopping.
    #[arg(long)]
    pub skip_bad_frames: bool,
    /// Replay: bundles only, no dense solve.
    #[arg(long)]
    pub no_solve: bool,
}

/// Arguments of `helmcap farm merge`.
#[derive(Debug, clap::Args)]
pub struct MergeArgs {
    /// A take's chunk folders, or the folder holding them (chunks/<take>).
    #[arg(required = true, value_name = "CHUNKS")]
    pub chunks: Vec<PathBuf>,
    /// The merged take folder.
    #[arg(long, short)]
    pub out: PathBuf,
    /// Replace an existing take folder (only once the merged take is complete).
    #[arg(long)]
    pub overwrite: bool,
}

pub fn run(command: FarmCommand) -> anyhow::Result<()> {
    match command {
        FarmCommand::Job(a) => job(*a),
        FarmCommand::Merge(a) => merge(a),
    }
}

/// An absolute path (the job runs elsewhere: relative paths mean nothing there).
fn absolute(p: &Path) -> anyhow::Result<PathBuf> {
    std::path::absolute(p).with_context(|| format!("{}: no absolute path", p.display()))
}

/// The session folders `dirs` name: each one, or the session folders inside it.
fn session_folders(dirs: &[PathBuf]) -> anyhow::Result<Vec<PathBuf>> {
    let mut out = Vec::new();
    for d in dirs {
        if d.join("session.toml").is_file() {
            out.push(d.clone());
            continue;
        }
        let mut inner: Vec<PathBuf> = std::fs::read_dir(d)
            .with_context(|| format!("--takes {}: not a session folder", d.display()))?
            .filter_map(Result::ok)
            .map(|e| e.path())
            .filter(|p| p.join("session.toml").is_file())
            .collect();
        if inner.is_empty() {
            bail!(
                "--takes {}: neither a session folder (session.toml) nor a folder of them",
                d.display()
            );
        }
        inner.sort();
        out.extend(inner);
    }
    Ok(out)
}

fn job(args: JobArgs) -> anyhow::Result<()> {
    if let Some(e) = args
        .export
        .iter()
        .find(|e| matches!(e, Export::LivelinkCsv | Export::UsdSkel))
    {
        bail!(
            "--export {e:?}: rig outputs are not merged from chunks; run `helmcap animate` on \
             each merged take"
        );
    }
    // The stages' memory: labeling restarts where each chunk's warm-up starts
    // (--relabel-every), the solve forgets its preference every keyframe interval,
    // gap-fill confidence reaches back 4 half-lives of 15 frames.
    let memory = 60usize.max(DEFAULT_SOLVE_KEYFRAMES);
    if args.overlap < memory {
        bail!(
            "--overlap {}: a chunk needs at least {memory} frames of warm-up to write what a \
             single pass writes (gap-fill confidence looks back {memory} frames, the solve \
             forgets its preference every {} frames)",
            args.overlap,
            DEFAULT_SOLVE_KEYFRAMES
        );
    }
    let mut takes = Vec::new();
    for session in session_folders(&args.takes)? {
        let replay = Replay::open(
            &session,
            ReplayParams {
                calibration: args.calib.clone(),
                ..ReplayParams::default()
            },
        )
        .with_context(|| format!("opening session {}", session.display()))?;
        let frames = &replay.info().frames;
        let (Some(first), Some(last)) = (frames.first(), frames.last()) else {
            bail!("session {} has no frames", session.display());
        };
        let name = session
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        takes.push(JobTake {
            name,
            session: absolute(&session)?,
            chunks: chunk_ranges(
                first.0.as_usize(),
                last.0.as_usize(),
                args.chunk,
                args.overlap,
            )
            .map_err(|e| anyhow::anyhow!("--chunk: {e}"))?,
        });
    }
    let mut options = Vec::new();
    let dataset_file = Path::new(&args.dataset);
    if dataset_file.is_file() {
        options.push(ReplayOption::File {
            option: "--dataset".into(),
            param: "Dataset".into(),
            path: absolute(dataset_file)?,
        });
    } else {
        // Checked here, not on the farm.
        helmcap::dataset::builtin_params(&args.dataset)?.with_context(|| {
            format!(
                "--dataset {}: neither a file nor builtin[:SEED]",
                args.dataset
            )
        })?;
        options.push(ReplayOption::Value(
            "--dataset".into(),
            args.dataset.clone(),
        ));
    }
    for (option, param, path) in [
        ("--markers", "Markers", &args.markers),
        ("--calib", "Calib", &args.calib),
        ("--profile", "Profile", &args.profile),
        ("--lgi-params", "LgiParams", &args.lgi_params),
    ] {
        if let Some(p) = path {
            if !p.is_file() {
                bail!("{option} {}: no such file", p.display());
            }
            options.push(ReplayOption::File {
                option: option.into(),
                param: param.into(),
                path: absolute(p)?,
            });
        }
    }
    let mut exports: Vec<Export> = Vec::new();
    for e in &args.export {
        if !exports.contains(e) {
            exports.push(*e);
        }
    }
    for e in exports {
        let name = clap::ValueEnum::to_possible_value(&e)
            .map(|v| v.get_name().to_string())
            .unwrap_or_default();
        options.push(ReplayOption::Value("--export".into(), name));
    }
    for (on, flag) in [
        (args.enhance, "--enhance"),
        (args.exact_bundles, "--exact-bundles"),
        (args.skip_bad_frames, "--skip-bad-frames"),
        (args.no_solve, "--no-solve"),
    ] {
        if on {
            options.push(ReplayOption::Flag(flag.into()));
        }
    }
    let helmcap = match &args.helmcap {
        Some(p) => absolute(p)?,
        None => std::env::current_exe().context("finding the helmcap executable")?,
    };
    let results = match &args.results {
        Some(r) => absolute(r)?,
        None => absolute(&args.out.join("results"))?,
    };
    let spec = JobSpec {
        name: args.name.clone(),
        helmcap,
        out: results,
        takes,
        overlap: args.overlap,
        chunk: args.chunk,
        replay_options: options,
    };
    spec.validate()?;
    spec.write(&args.out)
        .with_context(|| format!("writing the job bundle into {}", args.out.display()))?;
    let tasks: usize = spec.takes.iter().map(|t| t.chunks.len()).sum();
    let frames: usize = spec
        .takes
        .iter()
        .flat_map(|t| &t.chunks)
        .map(|c| c.end - c.start)
        .sum();
    println!(
        "job bundle {}: {} takes, {frames} frames in {tasks} chunk tasks of up to {} frames \
         (+{} warm-up), {} merge tasks, 1 report task; results into {}",
        args.out.display(),
        spec.takes.len(),
        args.chunk,
        args.overlap,
        spec.takes.len(),
        spec.out.display()
    );
    println!(
        "run it here with: openjd run {}/template.yaml -p NAME=VALUE for each value in \
         parameter_values.yaml",
        args.out.display()
    );
    Ok(())
}

fn merge(args: MergeArgs) -> anyhow::Result<()> {
    let mut chunks = Vec::new();
    for c in &args.chunks {
        chunks.extend(find_chunks(c)?);
    }
    let s = merge_chunks(&chunks, &args.out, args.overwrite)?;
    println!(
        "merged take {}: {} chunks, {} frames, {} files into {} in {:.2} s",
        s.take,
        s.chunks,
        s.frames_out,
        s.files,
        args.out.display(),
        s.secs
    );
    Ok(())
}
