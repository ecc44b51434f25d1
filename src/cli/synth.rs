//! `helmcap synth`: render a synthetic helmet recording, or calibration target images.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;
use helmcap::dataset::MarkerLayout;
use helmcap::dataset::actor;
use helmcap::synth::target::{CalibrationTarget, TargetParams, render_targets};
use helmcap::synth::{
    AnimationParams, Performer, SynthParams, animation, default_rig, render_session,
};
use indicatif::{ProgressBar, ProgressStyle};

use super::{DatasetArgs, builtin_params};

/// Arguments of `helmcap synth`.
#[derive(Debug, clap::Args)]
pub struct SynthArgs {
    /// Output folder (a recording session, or target images with `--target`).
    #[arg(long, short)]
    out: PathBuf,
    /// Dataset manifest, or `builtin[:SEED]` for the built-in actor.
    #[arg(long, short = 'd', default_value = "builtin")]
    dataset: String,
    /// Marker layout CSV (default for the built-in actor: its shipped layout).
    #[arg(long)]
    markers: Option<PathBuf>,
    /// Calibration YAML of the rig (default: the built-in helmet fisheye rig).
    #[arg(long)]
    calib: Option<PathBuf>,
    /// Number of frames (ignored with --weights).
    #[arg(long, short = 'n', default_value_t = 300)]
    frames: usize,
    /// Expression weights per frame (CSV: frame,<expression>,...) instead of random curves.
    #[arg(long)]
    weights: Option<PathBuf>,
    /// Seed of the random expression curves.
    #[arg(long, default_value_t = AnimationParams::default().seed)]
    seed: u64,
    /// Frames per second.
    #[arg(long, default_value_t = SynthParams::default().fps)]
    fps: f64,
    /// Sensor noise standard deviation, 8-bit levels.
    #[arg(long, default_value_t = SynthParams::default().noise_dn)]
    noise: f64,
    /// Gaussian blur sigma, pixels.
    #[arg(long, default_value_t = SynthParams::default().blur_px)]
    blur: f64,
    /// Motion blur: sub-frame samples averaged over the shutter (1: none).
    #[arg(long, default_value_t = SynthParams::default().motion_blur_samples)]
    motion_blur: usize,
    /// Mean time between lip presses (lips squeezed together), seconds (0: none).
    #[arg(long, default_value_t = AnimationParams::default().lip_press_interval_secs)]
    lip_press_interval: f64,
    /// Helmet slip translation amplitude, mm (0: none).
    #[arg(long, default_value_t = 0.0)]
    slip_mm: f64,
    /// Helmet slip rotation amplitude, degrees (0: none).
    #[arg(long, default_value_t = 0.0)]
    slip_deg: f64,
    /// Distance from the cameras to the face centre, mm.
    #[arg(long, default_value_t = SynthParams::default().face_distance_mm)]
    distance: f64,
    /// Radius of the painted dots, mm.
    #[arg(long, default_value_t = SynthParams::default().marker_radius_mm)]
    marker_radius: f64,
    /// Ground truth: smallest projected minor axis of a dot counted as detectable
    /// (`detectable` column of gt/projections.csv), pixels.
    #[arg(long, default_value_t = SynthParams::default().detectable_min_minor_axis_px)]
    detectable_min_minor_axis: f64,
    /// Also write the ground-truth mesh of every frame (gt/mesh/frame_NNNNNN.obj).
    #[arg(long)]
    meshes: bool,
    /// Timecode rate of the session: 23.976, 24, 25, 29.97, 29.97df, 30, 50, 59.94, 60, ...
    #[arg(long, default_value = "30")]
    timecode_rate: helmcap::timecode::TimecodeRate,
    /// Timecode of frame 0 (`HH:MM:SS:FF`; `HH:MM:SS;FF` for drop-frame rates).
    #[arg(long, default_value = "01:00:00:00")]
    timecode_start: String,
    /// Render calibration target images instead: `chessboard:COLSxROWS:SQUARE_MM` or
    /// `aprilgrid:COLSxROWS:TAG_MM:SPACING_RATIO` (tag36h11, Kalibr layout).
    #[arg(long, value_name = "SPEC")]
    target: Option<String>,
    /// Number of target views (with --target).
    #[arg(long, default_value_t = TargetParams::default().views)]
    views: usize,
}

pub fn run(args: SynthArgs) -> anyhow::Result<()> {
    let rig = match &args.calib {
        Some(p) => helmcap::camera::read_rig(p)?,
        None => default_rig().context("the built-in rig")?,
    };
    if let Some(spec) = &args.target {
        let target = CalibrationTarget::parse(spec)?;
        let params = TargetParams {
            views: args.views,
            noise_dn: args.noise,
            seed: args.seed,
            ..TargetParams::default()
        };
        let start = Instant::now();
        render_targets(&rig, &target, &params, &args.out)
            .with_context(|| format!("rendering targets into {}", args.out.display()))?;
        println!(
            "wrote {} target image pairs to {} in {:.1} s",
            args.views,
            args.out.display(),
            start.elapsed().as_secs_f64()
        );
        return Ok(());
    }
    let performer = match builtin_params(&args.dataset)? {
        Some(p) => Performer::Actor(Box::new(
            actor::Actor::new(&p).context("building the built-in actor")?,
        )),
        None => Performer::Dataset(Box::new(
            DatasetArgs {
                dataset: args.dataset.clone(),
                no_cache: false,
                cache_dir: None,
            }
            .load()?,
        )),
    };
    let layout = match (&args.markers, &performer) {
        (Some(p), _) => MarkerLayout::read_csv(p)?,
        (None, Performer::Actor(_)) => MarkerLayout::parse_csv(
            include_str!("../../configs/markers/builtin-actor.csv"),
            "builtin-actor.csv",
        )?,
        (None, Performer::Dataset(_)) => {
            anyhow::bail!("--markers is required with a dataset manifest")
        }
    };
    let names = performer.expression_names();
    let weights = match &args.weights {
        Some(p) => animation::read_weights_csv(p, &names)?,
        None => {
            if args.frames == 0 {
                anyhow::bail!("--frames must be at least 1");
            }
            let a = AnimationParams {
                seed: args.seed,
                lip_press_interval_secs: args.lip_press_interval,
                ..AnimationParams::default()
            };
            a.validate()?;
            animation::random_curves(&names, args.frames, args.fps, &a)
        }
    };
    let params = SynthParams {
        fps: args.fps,
        noise_dn: args.noise,
        blur_px: args.blur,
        motion_blur_samples: args.motion_blur,
        slip_mm: args.slip_mm,
        slip_deg: args.slip_deg,
        face_distance_mm: args.distance,
        marker_radius_mm: args.marker_radius,
        detectable_min_minor_axis_px: args.detectable_min_minor_axis,
        timecode_rate: args.timecode_rate,
        timecode_start: args.timecode_start.clone(),
        seed: args.seed.wrapping_add(7),
        ..SynthParams::default()
    };
    let bar = ProgressBar::new(weights.len() as u64);
    bar.set_style(
        ProgressStyle::with_template("rendering {bar:40} {pos}/{len} frames {eta}")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    let start = Instant::now();
    let summary = render_session(
        &performer,
        &layout,
        &rig,
        &weights,
        &params,
        &args.out,
        args.meshes,
        &|| bar.inc(1),
    )
    .with_context(|| format!("rendering session into {}", args.out.display()))?;
    bar.finish_and_clear();
    let secs = start.elapsed().as_secs_f64();
    println!(
        "wrote {} frames ({} markers; visible in cam0 {:.1} %, cam1 {:.1} %, both {:.1} %, detectable in both {:.1} %) to {} in {:.1} s ({:.1} frames/s)",
        summary.frames,
        summary.markers,
        100.0 * summary.visible_cam0 as f64 / (summary.frames * summary.markers) as f64,
        100.0 * summary.visible_cam1 as f64 / (summary.frames * summary.markers) as f64,
        100.0 * summary.visible_both as f64 / (summary.frames * summary.markers) as f64,
        100.0 * summary.detectable_both as f64 / (summary.frames * summary.markers) as f64,
        args.out.display(),
        secs,
        summary.frames as f64 / secs
    );
    Ok(())
}
