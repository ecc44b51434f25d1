//! `helmcap synth --preset`: every preset renders a complete session that replay opens and
//! reads, with a capture profile that parses; explicit options override a preset; a
//! capture profile sets the dots.

#![allow(clippy::unwrap_used)]

use std::path::Path;

use helmcap::capture::{Replay, ReplayParams};
use helmcap::track::profile::{CaptureProfile, Polarity};

mod common;
use common::helmcap;

fn synth_ok(args: &[&str]) -> String {
    let out = helmcap(args);
    assert!(
        out.status.success(),
        "{args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

const PRESETS: [&str; 9] = [
    "clean-far",
    "near-face",
    "wide-mixed",
    "cluttered",
    "wiped-moles",
    "bright-dots",
    "color-dots",
    "mono16",
    "vga",
];

/// PNG header facts: (width, height, colour type byte, bit depth).
fn png_header(path: &Path) -> (u32, u32, u8, u8) {
    let bytes = std::fs::read(path).unwrap();
    assert_eq!(&bytes[1..4], b"PNG", "{}", path.display());
    let be = |i: usize| u32::from_be_bytes([bytes[i], bytes[i + 1], bytes[i + 2], bytes[i + 3]]);
    (be(16), be(20), bytes[25], bytes[24])
}

#[test]
fn list_presets_names_them_all() {
    let listing = synth_ok(&["synth", "--list-presets"]);
    for name in PRESETS {
        assert!(
            listing.lines().any(|l| l.starts_with(name)),
            "{name} missing from:\n{listing}"
        );
    }
}

#[test]
fn every_preset_renders_a_complete_readable_session() {
    let tmp = tempfile::tempdir().unwrap();
    for name in PRESETS {
        let dir = tmp.path().join(name);
        synth_ok(&[
            "synth",
            "--preset",
            name,
            "--out",
            dir.to_str().unwrap(),
            "-n",
            "2",
        ]);
        for file in [
            "session.toml",
            "calibration.yaml",
            "profile.toml",
            "frames.csv",
            "gt/bundles.csv",
            "gt/head_pose.csv",
            "gt/projections.csv",
            "gt/weights.csv",
            "gt/markers.csv",
        ] {
            assert!(dir.join(file).is_file(), "{name}: {file} missing");
        }
        let session = std::fs::read_to_string(dir.join("session.toml")).unwrap();
        assert!(session.contains("profile = \"profile.toml\""), "{name}");
        let profile = CaptureProfile::load(&dir.join("profile.toml")).unwrap();
        let mut replay = Replay::open(&dir, ReplayParams::default()).unwrap();
        let rig = replay.rig().unwrap().clone();
        let (w, h) = (rig.cam0.width_px, rig.cam0.height_px);
        let mut frames = 0;
        while let Some(frame) = replay.next_frame() {
            let frame = frame.unwrap();
            assert_eq!((frame.images[0].width, frame.images[0].height), (w, h));
            frames += 1;
        }
        assert_eq!(frames, 2, "{name}");
        let (pw, ph, color, depth) = png_header(&dir.join("cam1/000001.png"));
        assert_eq!((pw, ph), (w, h), "{name}");
        // Projections: two cameras × markers × frames, and some detectable dots.
        let proj = std::fs::read_to_string(dir.join("gt/projections.csv")).unwrap();
        let detectable = proj.lines().skip(1).filter(|l| l.ends_with(",1")).count();
        assert!(detectable > 50, "{name}: {detectable} detectable dots");
        match name {
            "color-dots" => {
                assert_eq!((color, depth), (2, 8), "RGB 8-bit");
                assert!(profile.color.is_some());
            }
            "mono16" => {
                assert_eq!((color, depth), (0, 16), "grey 16-bit");
                assert_eq!((w, h), (2448, 2048));
            }
            "vga" => assert_eq!((w, h), (640, 480)),
            "bright-dots" => assert_eq!(profile.polarity, Polarity::Bright),
            "cluttered" | "wiped-moles" => {
                let d = std::fs::read_to_string(dir.join("gt/distractors.csv")).unwrap();
                let kinds: &[&str] = if name == "cluttered" {
                    &["freckle", "mole", "hair", "smudged_dot", "wiped_dot"]
                } else {
                    &["freckle", "mole", "wiped_dot"]
                };
                for kind in kinds {
                    assert!(
                        d.contains(&format!(",{kind},")),
                        "{name}: no {kind} in distractors"
                    );
                }
            }
            _ => assert_eq!((color, depth), (0, 8), "{name}"),
        }
        if !["cluttered", "wiped-moles"].contains(&name) {
            assert!(!dir.join("gt/distractors.csv").exists(), "{name}");
        }
    }
}

#[test]
fn explicit_options_override_the_preset_and_a_profile_sets_the_dots() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("s");
    synth_ok(&[
        "synth",
        "--preset",
        "vga",
        "--marker-radius",
        "1.0",
        "--out",
        dir.to_str().unwrap(),
        "-n",
        "1",
    ]);
    let profile = CaptureProfile::load(&dir.join("profile.toml")).unwrap();
    assert_eq!(profile.dot_diameter_mm, 2.0);
    let (w, _, _, _) = png_header(&dir.join("cam0/000000.png"));
    assert_eq!(w, 640);

    let given = tmp.path().join("rig.toml");
    let text = "dot_diameter_mm = 3.2\npolarity = \"bright\"\ncamera_distance_mm = [150, 300]\n";
    std::fs::write(&given, text).unwrap();
    let dir = tmp.path().join("p");
    synth_ok(&[
        "synth",
        "--profile",
        given.to_str().unwrap(),
        "--out",
        dir.to_str().unwrap(),
        "-n",
        "1",
    ]);
    assert_eq!(
        std::fs::read_to_string(dir.join("profile.toml")).unwrap(),
        text
    );
    // Bright 3.2 mm dots: the dots' pixels are brighter than the skin around them.
    let mut replay = Replay::open(&dir, ReplayParams::default()).unwrap();
    let frame = replay.next_frame().unwrap().unwrap();
    let proj = std::fs::read_to_string(dir.join("gt/projections.csv")).unwrap();
    let mut brighter = 0;
    let mut total = 0;
    for line in proj.lines().skip(1) {
        let f: Vec<&str> = line.split(',').collect();
        if f[1] != "cam0" || f[9] != "1" || f[7].parse::<f64>().unwrap() < 6.0 {
            continue;
        }
        let (u, v): (f64, f64) = (f[3].parse().unwrap(), f[4].parse().unwrap());
        let img = &frame.images[0];
        let at = |x: f64, y: f64| f64::from(img.get(x.round() as u32, y.round() as u32).unwrap());
        let skin = (at(u + 9.0, v) + at(u - 9.0, v) + at(u, v + 9.0) + at(u, v - 9.0)) / 4.0;
        total += 1;
        brighter += usize::from(at(u, v) > skin + 30.0);
    }
    assert!(
        total > 20 && brighter as f64 > 0.9 * total as f64,
        "{brighter}/{total}"
    );

    let out = helmcap(&["synth", "--preset", "nope", "--out", "/nonexistent/x"]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("unknown preset") && err.contains("clean-far"),
        "{err}"
    );
}
