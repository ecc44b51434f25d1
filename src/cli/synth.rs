//! `helmcap synth`: render a synthetic helmet recording, or calibration target images.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;
use helmcap::dataset::actor;
use helmcap::dataset::{MarkerLayout, builtin_params};
use helmcap::synth::target::{CalibrationTarget, TargetParams, render_targets};
use helmcap::synth::{
    AnimationParams, ColorParams, Performer, Polarity, ProfileOutput, SynthParams, animation,
    default_rig, preset, presets, render_session,
};
use indicatif::{ProgressBar, ProgressStyle};

use super::DatasetArgs;

/// Arguments of `helmcap synth`.
#[derive(Debug, clap::Args)]
pub struct SynthArgs {
    /// Output folder (a recording session, or target images with `--target`).
    #[arg(long, short, required_unless_present = "list_presets")]
    out: Option<PathBuf>,
    /// A named set-up of rig, dots, skin and lighting (see --list-presets); options given
    /// explicitly override it.
    #[arg(long, value_name = "NAME")]
    preset: Option<String>,
    /// List the presets and exit.
    #[arg(long)]
    list_presets: bool,
    /// Capture profile (TOML): dot diameter, polarity and colour are rendered from it, and
    /// it is copied into the session as profile.toml.
    #[arg(long, value_name = "FILE")]
    profile: Option<PathBuf>,
    /// Dataset manifest, or `builtin[:SEED]` for the built-in actor.
    #[arg(long, short = 'd', default_value = "builtin")]
    dataset: String,
    /// Marker layout CSV (default for the built-in actor: its shipped layout).
    #[arg(long)]
    markers: Option<PathBuf>,
    /// Calibration YAML of the rig (default: the preset's, else the built-in helmet
    /// fisheye rig).
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
    /// Frames per second [default: 60].
    #[arg(long)]
    fps: Option<f64>,
    /// Sensor noise standard deviation, 8-bit levels [default: 1.5].
    #[arg(long)]
    noise: Option<f64>,
    /// Gaussian blur sigma, pixels [default: 0, or the preset's].
    #[arg(long)]
    blur: Option<f64>,
    /// Motion blur: sub-frame samples averaged over the shutter (1: none) [default: 1, or
    /// the preset's].
    #[arg(long)]
    motion_blur: Option<usize>,
    /// Mean time between lip presses (lips squeezed together), seconds (0: none)
    /// [default: 0, or the preset's].
    #[arg(long)]
    lip_press_interval: Option<f64>,
    /// Helmet slip translation amplitude, mm (0: none) [default: 0, or the preset's].
    #[arg(long)]
    slip_mm: Option<f64>,
    /// Helmet slip rotation amplitude, degrees (0: none) [default: 0, or the preset's].
    #[arg(long)]
    slip_deg: Option<f64>,
    /// Distance from the cameras to the face centre, mm [default: 225, or the preset's].
    #[arg(long)]
    distance: Option<f64>,
    /// Radius of the painted dots, mm [default: 1.2, or the preset's or profile's].
    #[arg(long)]
    marker_radius: Option<f64>,
    /// Ground truth: smallest projected minor axis of a dot counted as detectable
    /// (`detectable` column of gt/projections.csv), pixels [default: 2].
    #[arg(long)]
    detectable_min_minor_axis: Option<f64>,
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
    if args.list_presets {
        for p in presets() {
            println!("{:<12} {}", p.name, p.summary);
        }
        return Ok(());
    }
    let out = args.out.clone().context("--out is required")?;
    let chosen = match &args.preset {
        Some(name) => Some(preset(name).with_context(|| {
            format!(
                "unknown preset {name:?} (one of: {})",
                helmcap::synth::PRESET_NAMES.join(", ")
            )
        })?),
        None => None,
    };
    let rig = match (&args.calib, chosen.as_ref().and_then(|p| p.rig.clone())) {
        (Some(p), _) => helmcap::camera::read_rig(p)?,
        (None, Some(mut r)) => {
            // The cameras converge on the face wherever --distance puts it.
            if let Some(d) = args.distance {
                r.convergence_mm = d;
            }
            r.build().context("the preset's rig")?
        }
        (None, None) => default_rig().context("the built-in rig")?,
    };
    if let Some(spec) = &args.target {
        let target = CalibrationTarget::parse(spec)?;
        let params = TargetParams {
            views: args.views,
            noise_dn: args.noise.unwrap_or(SynthParams::default().noise_dn),
            seed: args.seed,
            ..TargetParams::default()
        };
        let start = Instant::now();
        render_targets(&rig, &target, &params, &out)
            .with_context(|| format!("rendering targets into {}", out.display()))?;
        println!(
            "wrote {} target image pairs to {} in {:.1} s",
            args.views,
            out.display(),
            start.elapsed().as_secs_f64()
        );
        return Ok(());
    }
    let performer = match builtin_params(&args.dataset)? {
        Some(p) => Performer::Actor(Box::new(
            actor::Actor::new(&p).context("building the built-in actor")?,
        )),
        None => Performer::Dataset(Box::new(DatasetArgs::new(args.dataset.clone()).load()?)),
    };
    let layout = match (&args.markers, &performer) {
        (Some(p), _) => MarkerLayout::read_csv(p)?,
        (None, Performer::Actor(_)) => MarkerLayout::builtin_actor()?,
        (None, Performer::Dataset(_)) => {
            anyhow::bail!("--markers is required with a dataset manifest")
        }
    };
    let names = performer.expression_names();
    let lip_presses = chosen
        .as_ref()
        .map_or(AnimationParams::default().lip_press_interval_secs, |p| {
            p.lip_press_interval_secs
        });
    let mut params = chosen.map_or_else(SynthParams::default, |p| p.params);
    if let Some(path) = &args.profile {
        apply_profile(&mut params, path)?;
    }
    let fps = args.fps.unwrap_or(params.fps);
    let weights = match &args.weights {
        Some(p) => animation::read_weights_csv(p, &names)?,
        None => {
            if args.frames == 0 {
                anyhow::bail!("--frames must be at least 1");
            }
            let a = AnimationParams {
                seed: args.seed,
                lip_press_interval_secs: args.lip_press_interval.unwrap_or(lip_presses),
                ..AnimationParams::default()
            };
            a.validate()?;
            animation::random_curves(&names, args.frames, fps, &a)
        }
    };
    let params = SynthParams {
        fps,
        noise_dn: args.noise.unwrap_or(params.noise_dn),
        blur_px: args.blur.unwrap_or(params.blur_px),
        motion_blur_samples: args.motion_blur.unwrap_or(params.motion_blur_samples),
        slip_mm: args.slip_mm.unwrap_or(params.slip_mm),
        slip_deg: args.slip_deg.unwrap_or(params.slip_deg),
        face_distance_mm: args.distance.unwrap_or(params.face_distance_mm),
        marker_radius_mm: args.marker_radius.unwrap_or(params.marker_radius_mm),
        detectable_min_minor_axis_px: args
            .detectable_min_minor_axis
            .unwrap_or(params.detectable_min_minor_axis_px),
        timecode_rate: args.timecode_rate,
        timecode_start: args.timecode_start.clone(),
        seed: args.seed.wrapping_add(7),
        ..params
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
        &out,
        args.meshes,
        &|| bar.inc(1),
    )
    .with_context(|| format!("rendering session into {}", out.display()))?;
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
        out.display(),
        secs,
        summary.frames as f64 / secs
    );
    Ok(())
}

/// Dot diameter, polarity and colour from a capture profile; the profile's text goes into
/// the session as its profile.
fn apply_profile(params: &mut SynthParams, path: &std::path::Path) -> anyhow::Result<()> {
    let profile = helmcap::track::profile::CaptureProfile::load(path)?;
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    params.marker_radius_mm = 0.5 * profile.dot_diameter_mm;
    params.polarity = profile.polarity;
    match profile.color {
        Some(c) => {
            let dot_rgb = c.map(|v| v / 255.0);
            params.color = Some(ColorParams {
                dot_rgb,
                ..params.color.unwrap_or_default()
            });
            // A colour profile reads dots by colour: paint them.
            params.polarity = Polarity::Dark;
        }
        // A colour camera read by one channel keeps its colours.
        None if profile.channel.is_some() => {
            params.color = Some(params.color.unwrap_or_default());
        }
        None => params.color = None,
    }
    params.profile = ProfileOutput::Text(text);
    Ok(())
}
