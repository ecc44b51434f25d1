//! `helmcap demo`: the first thing a new user runs.
//!
//! Builds the built-in synthetic actor, renders a short helmet session of it (with helmet
//! slip and ground truth), replays it through the whole pipeline and prints what came out
//! and how close it is to the truth; opens the viewer when one is installed.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;
use helmcap::dataset::actor;
use helmcap::synth::{
    AnimationParams, Performer, SynthParams, animation, default_rig, render_session,
};
use helmcap::take::{Export, load_layout};

use super::replay::{ReplayArgs, replay};
use super::take::{TakeArgs, print_summary};

#[derive(Debug, clap::Args)]
pub struct DemoArgs {
    /// Output folder.
    #[arg(long, short, default_value = "out/demo")]
    out: PathBuf,
    /// Identity seed of the built-in actor (default: the standard actor).
    #[arg(long)]
    seed: Option<u64>,
    /// Frames to render and replay.
    #[arg(long, short = 'n', default_value_t = 120)]
    frames: usize,
    /// Also add the actor's fine detail to every frame (slower).
    #[arg(long)]
    enhance: bool,
    /// Do not open the viewer at the end.
    #[arg(long)]
    no_viewer: bool,
}

pub fn run(args: DemoArgs) -> anyhow::Result<()> {
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;
    if args.frames == 0 {
        anyhow::bail!("--frames must be at least 1");
    }
    let dataset = match args.seed {
        Some(s) => format!("builtin:{s}"),
        None => "builtin".to_string(),
    };
    let t = Instant::now();
    let params = match args.seed {
        Some(s) => actor::ActorParams::from_seed(s),
        None => actor::ActorParams::default(),
    };
    let actor = actor::Actor::new(&params).context("building the built-in actor")?;
    println!(
        "[1/3] built-in actor: {} vertices, {} expressions ({:.0} ms)",
        actor.to_dataset().vertex_count(),
        actor.to_dataset().shapes.len(),
        t.elapsed().as_secs_f64() * 1e3
    );

    let t = Instant::now();
    let session = args.out.join("session");
    let layout = load_layout(&dataset, None)?;
    let performer = Performer::Actor(Box::new(actor));
    let names = performer.expression_names();
    let synth = SynthParams {
        slip_mm: 1.5,
        slip_deg: 1.0,
        ..SynthParams::default()
    };
    let weights =
        animation::random_curves(&names, args.frames, synth.fps, &AnimationParams::default());
    let rig = default_rig().context("the built-in rig")?;
    let bar = indicatif::ProgressBar::new(args.frames as u64);
    bar.set_style(
        indicatif::ProgressStyle::with_template("rendering [{bar:30}] {pos}/{len} frames")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    let summary = render_session(
        &performer,
        &layout,
        &rig,
        &weights,
        &synth,
        &session,
        true,
        &|| bar.inc(1),
    )
    .with_context(|| format!("rendering {}", session.display()))?;
    bar.finish_and_clear();
    println!(
        "[2/3] synthetic session: {} frames at {} fps, 1280×1024 stereo, helmet slip on, {} markers ({:.1} s) -> {}",
        summary.frames,
        synth.fps,
        summary.markers,
        t.elapsed().as_secs_f64(),
        session.display()
    );

    // A build without the viewer SDK (cargo feature `rerun`) makes everything but the .rrd.
    let rrd = args.out.join("demo.rrd");
    let with_rerun = cfg!(feature = "rerun");
    let replay_args = ReplayArgs {
        session: session.clone(),
        calib: None,
        out: args.out.join("replay"),
        take: TakeArgs {
            dataset,
            // The demo's own folder: each run replaces the previous one.
            overwrite: true,
            rrd: with_rerun.then(|| rrd.clone()),
            // Half-size images keep the recording near 60 MB for 120 frames (240 MB at
            // full size); the markers are drawn at full precision either way.
            view: super::view::ViewerArgs {
                rerun_image_downscale: 2,
                ..Default::default()
            },
            export: vec![Export::Usd, Export::Obj, Export::C3d],
            enhance: args.enhance,
            ..TakeArgs::default()
        },
        frames: None,
        warm_up: 0,
        relabel_every: None,
        relabel_lead: 0,
        skip_bad_frames: false,
        quiet: false,
    };
    let t = Instant::now();
    let outcome = replay(&replay_args)?;
    println!(
        "[3/3] replayed through the pipeline ({:.1} s):",
        t.elapsed().as_secs_f64()
    );
    print_summary(&outcome.metrics, &outcome.outputs);
    if !with_rerun {
        println!("no rerun recording: this helmcap was built without the `rerun` feature");
    } else if !args.no_viewer {
        // A viewer needs a screen: on a headless machine only say how to open the file.
        let has_display = ["DISPLAY", "WAYLAND_DISPLAY"]
            .iter()
            .any(|v| std::env::var_os(v).is_some_and(|d| !d.is_empty()));
        match which("rerun").or_else(setup_viewer).filter(|_| has_display) {
            Some(viewer) => {
                println!("opening the viewer: {} {}", viewer.display(), rrd.display());
                if let Err(e) = std::process::Command::new(viewer).arg(&rrd).spawn() {
                    eprintln!("could not start the viewer: {e}");
                }
            }
            None => println!(
                "view it with `rerun {}` on a machine with a screen (`scripts/setup.sh` puts \
                 the viewer in ~/.cache/helmcap-python/bin; or `pip install rerun-sdk==0.36.3`)",
                rrd.display()
            ),
        }
    }
    Ok(())
}

/// The viewer `scripts/setup.sh` installs (`~/.cache/helmcap-python/bin/rerun`, or under
/// `$HELMCAP_PYTHON_ENV`), if it is there.
fn setup_viewer() -> Option<PathBuf> {
    let env = std::env::var_os("HELMCAP_PYTHON_ENV")
        .map(PathBuf::from)
        .or_else(|| {
            std::env::var_os("HOME").map(|h| PathBuf::from(h).join(".cache/helmcap-python"))
        })?;
    Some(env.join("bin/rerun")).filter(|p| p.is_file())
}

/// The first `name` on PATH.
fn which(name: &str) -> Option<PathBuf> {
    std::env::var_os("PATH").and_then(|paths| {
        std::env::split_paths(&paths)
            .map(|d| d.join(name))
            .find(|p| p.is_file())
    })
}
