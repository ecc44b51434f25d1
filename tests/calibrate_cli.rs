//! `helmcap calibrate` on target images rendered by `helmcap synth --target`: it recovers
//! the rig the images were rendered with (issue 4: focal lengths within 0.5 %, baseline
//! within 0.5 mm, RMS under 0.3 px at the default noise), drops views it cannot use, and
//! reports bad input with one clear error.

#![allow(clippy::unwrap_used)]

use std::path::Path;
use std::process::{Command, Output};

use helmcap::camera::{StereoRig, read_rig};

mod common;
use common::helmcap;

fn synth_targets(dir: &Path, spec: &str, calib: Option<&str>, views: usize) {
    let views = views.to_string();
    let mut args = vec![
        "synth",
        "--target",
        spec,
        "--views",
        &views,
        "--out",
        dir.to_str().unwrap(),
    ];
    if let Some(c) = calib {
        args.extend_from_slice(&["--calib", c]);
    }
    let out = helmcap(&args);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

fn calibrate(dir: &Path, spec: &str, model: &str) -> Output {
    let cam0 = format!("{}/cam0/*.png", dir.display());
    let cam1 = format!("{}/cam1/*.png", dir.display());
    let out = dir.join("rig.yaml");
    helmcap(&[
        "calibrate",
        "--target",
        spec,
        "--model",
        model,
        "--cam0",
        &cam0,
        "--cam1",
        &cam1,
        "--out",
        out.to_str().unwrap(),
    ])
}

/// The three RMS figures printed by `helmcap calibrate`: cam0, cam1, stereo.
fn printed_rms(stdout: &str) -> [f64; 3] {
    let line = stdout
        .lines()
        .find(|l| l.starts_with("RMS reprojection error:"))
        .unwrap();
    let nums: Vec<f64> = line
        .split_whitespace()
        .filter_map(|w| w.parse().ok())
        .collect();
    [nums[0], nums[1], nums[2]]
}

/// Compares the calibrated rig with the rendered one against the tolerances, and
/// prints the figures.
fn check_recovery(name: &str, truth: &StereoRig, got: &StereoRig, stdout: &str) {
    for (c, (t, g)) in [(&truth.cam0, &got.cam0), (&truth.cam1, &got.cam1)]
        .into_iter()
        .enumerate()
    {
        assert_eq!(t.distortion.model_name(), g.distortion.model_name());
        let efx = (g.fx() - t.fx()) / t.fx();
        let efy = (g.fy() - t.fy()) / t.fy();
        let ecx = g.k[(0, 2)] - t.k[(0, 2)];
        let ecy = g.k[(1, 2)] - t.k[(1, 2)];
        eprintln!(
            "{name} cam{c}: fx {:.2} (true {:.2}, {:+.3} %), fy {:.2} (true {:.2}, {:+.3} %), \
             cx {ecx:+.2} px, cy {ecy:+.2} px",
            g.fx(),
            t.fx(),
            100.0 * efx,
            g.fy(),
            t.fy(),
            100.0 * efy
        );
        assert!(
            efx.abs() < 0.005 && efy.abs() < 0.005,
            "{name} cam{c} focal"
        );
        assert!(
            ecx.abs() < 3.0 && ecy.abs() < 3.0,
            "{name} cam{c} principal point"
        );
    }
    let db = got.baseline_mm() - truth.baseline_mm();
    let dr = (got.cam1_from_cam0.rotation.inverse() * truth.cam1_from_cam0.rotation)
        .angle()
        .to_degrees();
    let rms = printed_rms(stdout);
    eprintln!(
        "{name}: baseline {:.3} mm (true {:.3}, {db:+.3} mm), rotation error {dr:.4}°, \
         RMS cam0 {:.4} cam1 {:.4} stereo {:.4} px",
        got.baseline_mm(),
        truth.baseline_mm(),
        rms[0],
        rms[1],
        rms[2]
    );
    assert!(db.abs() < 0.5, "{name} baseline");
    assert!(dr < 0.1, "{name} rotation");
    assert!(rms.iter().all(|&r| r < 0.3), "{name} RMS {rms:?}");
    assert!((got.rms_px - rms[2]).abs() < 1e-3, "file rms = stereo RMS");
}

fn run_case(spec: &str, calib: Option<&str>, model: &str, views: usize) {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    synth_targets(dir, spec, calib, views);
    let out = calibrate(dir, spec, model);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{}\n{stdout}",
        String::from_utf8_lossy(&out.stderr)
    );
    let truth = read_rig(&dir.join("calibration.yaml")).unwrap();
    let got = read_rig(&dir.join("rig.yaml")).unwrap();
    check_recovery(&format!("{spec} {model}"), &truth, &got, &stdout);
}

#[test]
fn aprilgrid_recovers_the_default_fisheye_rig_and_drops_unusable_views() {
    let spec = "aprilgrid:6x6:30:0.3";
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    synth_targets(dir, spec, None, 12);
    // A blank cam1 image: that pair is dropped from cam1 and from the stereo step.
    let truth = read_rig(&dir.join("calibration.yaml")).unwrap();
    let (w, h) = (truth.cam1.width_px, truth.cam1.height_px);
    let blank = vec![128u8; (w * h) as usize];
    helmcap::synth::write_png_gray(&dir.join("cam1/000003.png"), w, h, &blank).unwrap();
    let out = calibrate(dir, spec, "fisheye");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{}\n{stdout}",
        String::from_utf8_lossy(&out.stderr)
    );
    let pair3 = stdout.lines().find(|l| l.starts_with("pair   3")).unwrap();
    assert!(
        pair3.contains("cam1 dropped: target not found")
            && pair3.contains("stereo dropped: cam1 image unusable"),
        "{pair3}"
    );
    assert!(stdout.contains("(11 of 12 pairs"), "{stdout}");
    let got = read_rig(&dir.join("rig.yaml")).unwrap();
    check_recovery("aprilgrid fisheye", &truth, &got, &stdout);
}

#[test]
fn chessboard_recovers_the_pinhole_rig() {
    run_case(
        "chessboard:9x6:20",
        Some("calib/helmet-pinhole.yaml"),
        "pinhole",
        12,
    );
}

#[test]
fn chessboard_recovers_the_default_fisheye_rig() {
    run_case("chessboard:9x6:20", None, "fisheye", 12);
}

#[test]
fn aprilgrid_recovers_the_pinhole_rig() {
    run_case(
        "aprilgrid:5x4:30:0.3",
        Some("calib/helmet-pinhole.yaml"),
        "pinhole",
        10,
    );
}

/// Small blank images (no target) for `n` pairs.
fn blank_pairs(dir: &Path, n: usize) {
    for cam in ["cam0", "cam1"] {
        std::fs::create_dir_all(dir.join(cam)).unwrap();
        for i in 0..n {
            helmcap::synth::write_png_gray(
                &dir.join(format!("{cam}/{i:06}.png")),
                160,
                120,
                &vec![100u8; 160 * 120],
            )
            .unwrap();
        }
    }
}

fn assert_error(out: &Output, needles: &[&str]) {
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    let line = stderr
        .lines()
        .find(|l| l.starts_with("error:"))
        .unwrap_or_else(|| panic!("no error line in {stderr}"));
    for n in needles {
        assert!(line.contains(n), "{n:?} not in {line:?}");
    }
}

#[test]
fn bad_input_gets_one_clear_error() {
    let help = helmcap(&["calibrate", "--help"]);
    assert!(help.status.success());
    let text = String::from_utf8_lossy(&help.stdout);
    assert!(
        text.contains("aprilgrid:COLSxROWS:TAG_MM:SPACING_RATIO") && text.contains("--min-pairs")
    );
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    blank_pairs(dir, 6);
    // The target is never found.
    let out = calibrate(dir, "aprilgrid:6x6:30:0.3", "fisheye");
    assert_error(
        &out,
        &["0 usable views", "need at least 6", "6 target not found"],
    );
    let out = calibrate(dir, "chessboard:9x6:20", "pinhole");
    assert_error(&out, &["6 target not found"]);
    // Bad target spec, model, chessboard symmetric under a half turn.
    assert_error(
        &calibrate(dir, "aprilgrid:6x6:30", "fisheye"),
        &["aprilgrid:6x6:30", "TAG_MM:SPACING_RATIO"],
    );
    assert_error(&calibrate(dir, "chessboard:9x6:20", "kb"), &["\"kb\""]);
    assert_error(
        &calibrate(dir, "chessboard:8x6:20", "fisheye"),
        &["half turn"],
    );
    // Missing images: a pattern that matches nothing.
    let out = helmcap(&[
        "calibrate",
        "--target",
        "chessboard:9x6:20",
        "--cam0",
        &format!("{}/cam0/*.png", dir.display()),
        "--cam1",
        &format!("{}/nocam/*.png", dir.display()),
        "--out",
        dir.join("rig.yaml").to_str().unwrap(),
    ]);
    assert_error(&out, &["--cam1", "nocam", "matches no image files"]);
    // Mismatched counts.
    std::fs::remove_file(dir.join("cam1/000005.png")).unwrap();
    assert_error(
        &calibrate(dir, "chessboard:9x6:20", "fisheye"),
        &["--cam0 matches 6 images but --cam1 matches 5"],
    );
    // An unreadable image, named.
    std::fs::write(dir.join("cam1/000005.png"), b"not a png").unwrap();
    assert_error(
        &calibrate(dir, "chessboard:9x6:20", "fisheye"),
        &["cam1/000005.png"],
    );
    // An image of another size, named.
    helmcap::synth::write_png_gray(&dir.join("cam1/000005.png"), 80, 60, &[0u8; 80 * 60]).unwrap();
    assert_error(
        &calibrate(dir, "chessboard:9x6:20", "fisheye"),
        &["cam1/000005.png", "80×60", "160×120"],
    );
    assert!(!dir.join("rig.yaml").exists(), "no output on error");
}

/// The folder holding OpenCV's stereo sample images (Debian's `opencv-doc`), if installed.
fn opencv_stereo_samples() -> Option<std::path::PathBuf> {
    let listed = Command::new("dpkg")
        .args(["-L", "opencv-doc"])
        .output()
        .ok()
        .and_then(|o| {
            String::from_utf8_lossy(&o.stdout)
                .lines()
                .find(|l| l.ends_with("/left01.jpg"))
                .map(|l| Path::new(l).parent().unwrap().to_path_buf())
        });
    listed
        .or_else(|| Some("/usr/share/doc/opencv-doc/examples/data".into()))
        .filter(|d: &std::path::PathBuf| d.join("left01.jpg").is_file())
}

/// OpenCV's own stereo samples (JPEG, 640×480, 9×6 inner corners), as they ship: the
/// pinhole calibration's stereo RMS is at or below the 0.447 px OpenCV's stereo_calib
/// sample reports on them.
#[test]
fn opencv_jpeg_stereo_samples_calibrate_as_shipped() {
    let Some(data) = opencv_stereo_samples() else {
        println!("skipped: opencv-doc is not installed (scripts/setup.sh installs it)");
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("rig.yaml");
    let run = helmcap(&[
        "calibrate",
        "--target",
        "chessboard:9x6:25",
        "--model",
        "pinhole",
        "--cam0",
        &format!("{}/left[0-9]*.jpg", data.display()),
        "--cam1",
        &format!("{}/right[0-9]*.jpg", data.display()),
        "--out",
        out.to_str().unwrap(),
    ]);
    let stdout = String::from_utf8_lossy(&run.stdout);
    assert!(
        run.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&run.stderr)
    );
    println!("{stdout}");
    let [rms0, rms1, stereo] = printed_rms(&stdout);
    assert!(
        stereo <= 0.447,
        "stereo RMS {stereo} px (cam0 {rms0}, cam1 {rms1})"
    );
    let rig = read_rig(&out).unwrap();
    assert_eq!((rig.cam0.width_px, rig.cam0.height_px), (640, 480));
    // The square size is arbitrary (25 mm here); the cameras are about 3.3 squares apart.
    let baseline_squares = rig.baseline_mm() / 25.0;
    assert!(
        (2.5..4.5).contains(&baseline_squares),
        "baseline {baseline_squares} squares"
    );
}
