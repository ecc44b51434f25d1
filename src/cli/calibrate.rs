//! `helmcap calibrate`: stereo calibration from image pairs of a calibration target.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, bail};
use helmcap::camera::calibrate::{CalibrateParams, CameraModel, ImagePair, calibrate_stereo};
use helmcap::camera::target::CalibrationTarget;
use indicatif::{ProgressBar, ProgressStyle};

/// Arguments of `helmcap calibrate`.
#[derive(Debug, clap::Args)]
pub struct CalibrateArgs {
    /// Calibration target: `aprilgrid:COLSxROWS:TAG_MM:SPACING_RATIO` (tag36h11 tags in
    /// Kalibr's layout) or `chessboard:COLSxROWS:SQUARE_MM` (inner corners).
    #[arg(long, value_name = "SPEC")]
    target: String,
    /// Lens model of both cameras: `fisheye` or `pinhole`.
    #[arg(long, default_value = "fisheye", value_name = "MODEL")]
    model: String,
    /// cam0's images: a glob pattern (quote it), e.g. 'dir/cam0/*.png'. Pairs are matched
    /// by sorted file order.
    #[arg(long, value_name = "GLOB")]
    cam0: String,
    /// cam1's images: a glob pattern (quote it), e.g. 'dir/cam1/*.png'.
    #[arg(long, value_name = "GLOB")]
    cam1: String,
    /// Output calibration YAML (OpenCV FileStorage).
    #[arg(long, short)]
    out: PathBuf,
    /// Fewest image pairs usable in both cameras.
    #[arg(long, default_value_t = CalibrateParams::default().min_pairs)]
    min_pairs: usize,
    /// Fewest target points in a usable view.
    #[arg(long, default_value_t = CalibrateParams::default().min_points_per_view)]
    min_points: usize,
}

/// The files a glob pattern matches, sorted; an error when it matches none.
fn expand(flag: &str, pattern: &str) -> anyhow::Result<Vec<PathBuf>> {
    let mut files = Vec::new();
    for entry in glob::glob(pattern).with_context(|| format!("{flag} {pattern:?}"))? {
        let path = entry.with_context(|| format!("{flag} {pattern:?}"))?;
        if path.is_file() {
            files.push(path);
        }
    }
    if files.is_empty() {
        bail!("{flag} {pattern:?} matches no image files");
    }
    files.sort();
    Ok(files)
}

pub fn run(args: CalibrateArgs) -> anyhow::Result<()> {
    let target = CalibrationTarget::parse(&args.target)?;
    let model: CameraModel = args.model.parse()?;
    let cam0 = expand("--cam0", &args.cam0)?;
    let cam1 = expand("--cam1", &args.cam1)?;
    if cam0.len() != cam1.len() {
        bail!(
            "--cam0 matches {} images but --cam1 matches {}: pairs are matched by sorted file \
             order, so both must match the same number",
            cam0.len(),
            cam1.len()
        );
    }
    let pairs: Vec<ImagePair> = cam0
        .into_iter()
        .zip(cam1)
        .map(|(cam0, cam1)| ImagePair { cam0, cam1 })
        .collect();
    let params = CalibrateParams {
        model,
        min_pairs: args.min_pairs,
        min_points_per_view: args.min_points,
        ..CalibrateParams::default()
    };
    let bar = ProgressBar::new(pairs.len() as u64);
    bar.set_style(
        ProgressStyle::with_template("detecting {bar:40} {pos}/{len} pairs {eta}")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    let load = |path: &std::path::Path| {
        // PNG, JPEG or TIFF by content; colour as Rec. 601 luma.
        helmcap::capture::read_gray(path, helmcap::capture::GrayConversion::Luma)
            .map_err(|e| e.message)
    };
    let start = Instant::now();
    let result = calibrate_stereo(&pairs, &target, &params, &load, &|| bar.inc(1));
    bar.finish_and_clear();
    let report = result.context("calibration failed")?;
    let name = |p: &std::path::Path| {
        p.file_name().map_or_else(
            || p.display().to_string(),
            |n| n.to_string_lossy().into_owned(),
        )
    };
    for (v, view) in report.views.iter().enumerate() {
        println!(
            "pair {v:3} ({} | {}): cam0 {}; cam1 {}; stereo {}",
            name(&view.pair.cam0),
            name(&view.pair.cam1),
            view.cam0,
            view.cam1,
            view.stereo
        );
    }
    let rig = &report.rig;
    for (c, cam) in [&rig.cam0, &rig.cam1].into_iter().enumerate() {
        println!(
            "cam{c} ({}): fx {:.2} fy {:.2} cx {:.2} cy {:.2} px, D {:?}",
            cam.distortion.model_name(),
            cam.fx(),
            cam.fy(),
            cam.k[(0, 2)],
            cam.k[(1, 2)],
            cam.distortion
                .coefficients()
                .iter()
                .map(|d| (d * 1e6).round() / 1e6)
                .collect::<Vec<_>>()
        );
    }
    let t = rig.cam1_from_cam0.translation.vector;
    println!(
        "baseline {:.3} mm, T = [{:.3}, {:.3}, {:.3}] mm, R angle {:.3}°",
        rig.baseline_mm(),
        t.x,
        t.y,
        t.z,
        rig.cam1_from_cam0.rotation.angle().to_degrees()
    );
    println!(
        "RMS reprojection error: cam0 {:.4} px, cam1 {:.4} px, stereo {:.4} px ({} of {} pairs, {:.1} s)",
        report.rms_cam0_px,
        report.rms_cam1_px,
        report.rms_stereo_px,
        report.stereo_pairs_used(),
        report.views.len(),
        start.elapsed().as_secs_f64()
    );
    helmcap::camera::write_rig(&args.out, rig)?;
    println!("wrote {}", args.out.display());
    Ok(())
}
