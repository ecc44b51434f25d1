//! The reproducers of the hardening issue through the real binary: each must end in one
//! clear error line naming the file and the line or key, quickly, with no panic and no
//! memory abort.

#![allow(clippy::unwrap_used)]

use std::path::Path;
use std::process::Output;
use std::time::{Duration, Instant};

mod common;
use common::helmcap;

/// The one error line of a failed run (and checks that there is exactly one, no panic).
fn error_line(o: &Output) -> String {
    let err = String::from_utf8_lossy(&o.stderr).into_owned();
    assert!(!o.status.success(), "should fail: {err}");
    assert_eq!(o.status.code(), Some(1), "a clean exit, not a crash: {err}");
    assert!(!err.contains("panicked"), "{err}");
    let lines: Vec<&str> = err.lines().filter(|l| l.starts_with("error:")).collect();
    assert_eq!(lines.len(), 1, "{err}");
    lines[0].to_string()
}

fn live_toml(dir: &Path, extra: &str) -> String {
    let path = dir.join("live.toml");
    std::fs::write(
        &path,
        format!(
            "fps = 60.0\n[[camera]]\ndevice = 0\nwidth = 64\nheight = 48\n\
             [[camera]]\ndevice = 1\nwidth = 64\nheight = 48\n{extra}"
        ),
    )
    .unwrap();
    path.to_str().unwrap().to_string()
}

#[test]
fn live_and_record_configs_are_range_checked_with_the_key() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("rec");
    for (extra, line, key) in [
        (
            "[syncbox]\nframe_delay_ms = 1e300\n",
            11,
            "[syncbox] frame_delay_ms = 1e300",
        ),
        (
            "[live]\ncamera_queue = 9223372036854775807\n",
            11,
            "[live] camera_queue = 9223372036854775807",
        ),
        (
            "[live]\ncamera_queue = 1000000000000\n",
            11,
            "[live] camera_queue = 1000000000000",
        ),
        (
            "[record]\nqueue_frames = 0\n",
            11,
            "[record] queue_frames = 0",
        ),
    ] {
        let config = live_toml(dir.path(), extra);
        for cmd in ["record", "live"] {
            let t = Instant::now();
            let o = helmcap(&[
                cmd,
                "--config",
                &config,
                "--out",
                out.to_str().unwrap(),
                "--frames",
                "5",
            ]);
            let e = error_line(&o);
            assert!(e.contains(&format!("live.toml:{line}:")), "{e}");
            assert!(e.contains(key) && e.contains("out of range"), "{e}");
            assert!(t.elapsed() < Duration::from_secs(30));
        }
    }
    // --seconds that no clock can hold.
    let config = live_toml(dir.path(), "");
    let o = helmcap(&[
        "record",
        "--config",
        &config,
        "--out",
        "x",
        "--seconds",
        "1e300",
    ]);
    assert!(error_line(&o).contains("--seconds"), "{o:?}");
}

#[test]
fn a_ply_declaring_a_huge_element_fails_at_once() {
    let dir = tempfile::tempdir().unwrap();
    let scan = dir.path().join("scan.ply");
    std::fs::write(
        &scan,
        "ply\nformat ascii 1.0\nelement junk 1000000000000000000\nelement vertex 1\n\
         property float x\nproperty float y\nproperty float z\nend_header\n0 0 0\n",
    )
    .unwrap();
    let template = dir.path().join("t.obj");
    std::fs::write(&template, "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n").unwrap();
    let t = Instant::now();
    let o = helmcap(&[
        "register",
        "--template",
        template.to_str().unwrap(),
        "--scan",
        scan.to_str().unwrap(),
        "--out",
        dir.path().join("r.obj").to_str().unwrap(),
    ]);
    let e = error_line(&o);
    assert!(e.contains("scan.ply:3:") && e.contains("junk"), "{e}");
    assert!(t.elapsed() < Duration::from_secs(10), "{:?}", t.elapsed());
}

/// A session whose frames.csv jumps to frame 16777215 (the C3D reproducer) is
/// refused when opened, naming the line; a frame number past the limit too.
#[test]
fn frames_csv_with_a_huge_frame_number_is_refused_with_the_line() {
    let dir = tempfile::tempdir().unwrap();
    let s = dir.path().join("session");
    for cam in ["cam0", "cam1"] {
        std::fs::create_dir_all(s.join(cam)).unwrap();
    }
    std::fs::write(
        s.join("session.toml"),
        "fps = 60.0\ncameras = [\"cam0\", \"cam1\"]\n",
    )
    .unwrap();
    for (rows, line, what) in [
        (
            "0,0,\n1,16666667,\n16777215,33333334,\n",
            4,
            "a gap of more than 65535 frames",
        ),
        ("0,0,\n16777216,1,\n", 3, "above the largest frame number"),
    ] {
        std::fs::write(
            s.join("frames.csv"),
            format!("frame,timestamp_ns,timecode\n{rows}"),
        )
        .unwrap();
        let o = helmcap(&[
            "replay",
            s.to_str().unwrap(),
            "--out",
            dir.path().join("out").to_str().unwrap(),
            "--export",
            "c3d",
            "--quiet",
        ]);
        let e = error_line(&o);
        assert!(
            e.contains(&format!("frames.csv:{line}:")) && e.contains(what),
            "{e}"
        );
    }
    // One camera twice.
    std::fs::write(
        s.join("session.toml"),
        "fps = 60.0\ncameras = [\"cam0\", \"cam0\"]\n",
    )
    .unwrap();
    let o = helmcap(&["replay", s.to_str().unwrap(), "--out", "x", "--quiet"]);
    assert!(error_line(&o).contains("names \"cam0\" twice"), "{o:?}");
}

/// A megabyte line is quoted in at most ~80 characters, and an OS error is printed once.
#[test]
fn messages_quote_a_short_excerpt_and_each_cause_once() {
    let dir = tempfile::tempdir().unwrap();
    let markers = dir.path().join("markers.csv");
    let long = "x".repeat(1 << 20);
    std::fs::write(
        &markers,
        format!("name,vertex,stabilize_weight\nm1,{long},0\n"),
    )
    .unwrap();
    let bundles = dir.path().join("b.csv");
    std::fs::write(&bundles, "frame,marker,x,y,z\n0,m1,0,0,0\n").unwrap();
    let out = dir.path().join("out");
    let o = helmcap(&[
        "solve",
        "--dataset",
        "builtin",
        "--markers",
        markers.to_str().unwrap(),
        "--bundles",
        bundles.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    let e = error_line(&o);
    assert!(e.contains("markers.csv:2:"), "{e}");
    assert!(e.len() < 400, "{} characters: {}", e.len(), &e[..200]);
    let o = helmcap(&[
        "solve",
        "--dataset",
        "builtin",
        "--markers",
        dir.path().join("missing.csv").to_str().unwrap(),
        "--bundles",
        bundles.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    let e = error_line(&o);
    assert_eq!(e.matches("No such file or directory").count(), 1, "{e}");
    assert_eq!(e.matches("os error 2").count(), 1, "{e}");
}

/// A megabyte line in a calibration file is quoted briefly, with its line.
#[test]
fn calibration_errors_quote_a_short_excerpt() {
    let good = include_str!("../calib/helmet-fisheye.yaml").trim_end();
    let lines = good.lines().count();
    let text = format!("{good}\n{}\n", "z".repeat(1 << 20));
    let e = helmcap::camera::parse_rig(Path::new("rig.yaml"), &text)
        .unwrap_err()
        .to_string();
    assert!(
        e.starts_with(&format!("rig.yaml:{}:", lines + 1)),
        "{}",
        &e[..100]
    );
    assert!(e.len() < 300, "{} characters", e.len());
}
