//! The capture front end on sessions rendered by `helmcap synth`: the recording format, the
//! replay checks, marker detection and stereo pairing against ground truth, and clear
//! errors for bad input.

#![allow(clippy::unwrap_used)]

use std::collections::HashMap;
use std::path::Path;

use helmcap::capture::{Replay, ReplayParams};
use helmcap::stereo::{PairParams, pair_detections};
use helmcap::track::{DetectParams, detect_markers};
use nalgebra::{Point2, Point3, Quaternion, UnitQuaternion, Vector3};

mod common;
use common::helmcap;

fn synth(dir: &Path, frames: usize, extra: &[&str]) {
    let n = frames.to_string();
    let mut args = vec!["synth", "--out", dir.to_str().unwrap(), "-n", &n];
    args.extend_from_slice(extra);
    let out = helmcap(&args);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// `gt/projections.csv`: (frame, camera) → marker → (pixel, visible).
type Projections = HashMap<(usize, usize), HashMap<String, (Point2<f64>, bool)>>;

fn read_projections(dir: &Path) -> Projections {
    let text = std::fs::read_to_string(dir.join("gt/projections.csv")).unwrap();
    let mut out: Projections = HashMap::new();
    for line in text.lines().skip(1) {
        let f: Vec<&str> = line.split(',').collect();
        let cam = usize::from(f[1] == "cam1");
        out.entry((f[0].parse().unwrap(), cam)).or_default().insert(
            f[2].to_string(),
            (
                Point2::new(f[3].parse().unwrap(), f[4].parse().unwrap()),
                f[5] == "1",
            ),
        );
    }
    out
}

/// Ground-truth marker positions in cam0 per frame, from `gt/bundles.csv` (head frame)
/// and `gt/head_pose.csv` (head → cam0).
fn read_truth_in_cam0(dir: &Path) -> HashMap<(usize, String), Point3<f64>> {
    let poses = std::fs::read_to_string(dir.join("gt/head_pose.csv")).unwrap();
    let mut pose = HashMap::new();
    for line in poses.lines().skip(1) {
        let v: Vec<f64> = line.split(',').map(|s| s.parse().unwrap()).collect();
        let q = UnitQuaternion::from_quaternion(Quaternion::new(v[1], v[2], v[3], v[4]));
        pose.insert(v[0] as usize, (q, Vector3::new(v[5], v[6], v[7])));
    }
    let bundles = std::fs::read_to_string(dir.join("gt/bundles.csv")).unwrap();
    let mut out = HashMap::new();
    for line in bundles.lines().skip(1) {
        let f: Vec<&str> = line.split(',').collect();
        let frame: usize = f[0].parse().unwrap();
        let p = Point3::new(
            f[2].parse().unwrap(),
            f[3].parse().unwrap(),
            f[4].parse().unwrap(),
        );
        let (q, t) = pose[&frame];
        out.insert((frame, f[1].to_string()), q * p + t);
    }
    out
}

/// The visible marker whose true projection is nearest `px`, within `tol` pixels.
fn nearest_marker<'a>(
    truth: &'a HashMap<String, (Point2<f64>, bool)>,
    px: &Point2<f64>,
    tol: f64,
) -> Option<(&'a str, f64)> {
    truth
        .iter()
        .filter(|(_, (_, vis))| *vis)
        .map(|(name, (p, _))| (name.as_str(), (p - px).norm()))
        .filter(|(_, d)| *d < tol)
        .min_by(|a, b| a.1.total_cmp(&b.1))
}

#[test]
fn synth_session_detect_and_triangulate_against_ground_truth() {
    let dir = tempfile::tempdir().unwrap();
    let s = dir.path();
    synth(s, 4, &["--slip-mm", "1.5", "--slip-deg", "1"]);
    for f in [
        "session.toml",
        "frames.csv",
        "calibration.yaml",
        "cam0/000003.png",
        "cam1/000000.png",
        "gt/bundles.csv",
        "gt/head_pose.csv",
        "gt/projections.csv",
        "gt/weights.csv",
    ] {
        assert!(s.join(f).is_file(), "{f}");
    }
    let frames_csv = std::fs::read_to_string(s.join("frames.csv")).unwrap();
    assert_eq!(frames_csv.lines().count(), 5);
    // 60 fps cameras on 30 fps timecode: two sub-frames per timecode frame.
    assert!(frames_csv.contains("1,16666667,01:00:00:00.1"));
    assert!(frames_csv.contains("2,33333333,01:00:00:01.0"));

    let projections = read_projections(s);
    let truth = read_truth_in_cam0(s);
    let replay = Replay::open(s, ReplayParams::default()).unwrap();
    let rig = replay.rig().unwrap().clone();
    let params = DetectParams::default();
    let (mut visible, mut found, mut spurious, mut sq_err) = (0usize, 0usize, 0usize, 0.0);
    let (mut pairs, mut wrong_pairs, mut spurious_pairs, mut sq_err_mm) =
        (0usize, 0usize, 0usize, 0.0);
    for frame in replay {
        let frame = frame.unwrap();
        let mut names: [Vec<Option<String>>; 2] = [Vec::new(), Vec::new()];
        let mut centres: [Vec<Point2<f64>>; 2] = [Vec::new(), Vec::new()];
        for c in 0..2 {
            let det = detect_markers(&frame.images[c], &params);
            let gt = &projections[&(frame.index.as_usize(), c)];
            visible += gt.values().filter(|(_, v)| *v).count();
            let mut matched = std::collections::HashSet::new();
            for d in &det {
                match nearest_marker(gt, &d.centre_px, 1.5) {
                    Some((name, e)) => {
                        if matched.insert(name) {
                            found += 1;
                            sq_err += e * e;
                        }
                        names[c].push(Some(name.to_string()));
                    }
                    None => {
                        spurious += 1;
                        names[c].push(None);
                    }
                }
                centres[c].push(d.centre_px);
            }
        }
        for m in pair_detections(&rig, &centres[0], &centres[1], &PairParams::default()) {
            pairs += 1;
            match (&names[0][m.index0], &names[1][m.index1]) {
                (Some(a), Some(b)) if a == b => {
                    let t = truth[&(frame.index.as_usize(), a.clone())];
                    sq_err_mm += (m.bundle.point_in_cam0 - t).norm_squared();
                }
                (Some(_), Some(_)) => {
                    wrong_pairs += 1;
                }
                // A blob that is no marker (nostril, lid crease) seen in both images is a
                // consistent 3D point: labeling, not pairing, must reject it.
                _ => spurious_pairs += 1,
            }
        }
    }
    let recall = found as f64 / visible as f64;
    let rms_px = (sq_err / found as f64).sqrt();
    let rms_mm = (sq_err_mm / (pairs - wrong_pairs - spurious_pairs) as f64).sqrt();
    eprintln!(
        "detection: {found}/{visible} visible found ({:.1} %), {spurious} spurious, centre RMS {rms_px:.3} px; \
         stereo: {pairs} pairs, {wrong_pairs} wrong, {spurious_pairs} with a spurious blob, bundle RMS {rms_mm:.3} mm",
        100.0 * recall
    );
    // Measured on this session: recall 97.2 % (88.5 % before dots touching a crease or
    // the shading at the face's edge were split out of their component), 92 spurious blobs
    // over 8 images (irises, nostrils, the mouth line: round dark blobs that are no marker;
    // labeling rejects them, tests/labeling.rs asserts zero wrong labels), centre RMS
    // 0.24 px, 224 pairs of which none wrong, bundle RMS 0.20 mm. On 2026-12-06: recall
    // 97.4 %, 123 spurious blobs, centre RMS 0.195 px, 210 pairs of which none wrong and 6
    // with a spurious blob, bundle RMS 0.138 mm (before the large window ran at half
    // resolution: 120 spurious blobs, 208 pairs, 4 with a spurious blob, the rest the
    // same). On 2026-12-07: 134 spurious blobs and 206 pairs (5 with a spurious blob)
    // once two blobs either side of a band of light were also reported whole (blobs that
    // are no marker pair so too: 11 more), 141 once a thin blob's core without a hair
    // across its end was taken (7 more); recall, centre RMS and bundle RMS the same. The
    // bound on spurious blobs leaves a tenth. Pairing by the epipolar
    // constraint alone cannot reject a pair of two markers on a shared epipolar line whose
    // true partners were both missed: labeling against the layout must.
    assert!(recall > 0.95, "recall {recall}");
    assert!(rms_px < 0.3, "centre RMS {rms_px} px");
    assert!(spurious <= 155, "{spurious} spurious blobs");
    assert!(
        wrong_pairs * 50 <= pairs,
        "{wrong_pairs} wrong of {pairs} pairs"
    );
    assert!(pairs as f64 > 0.4 * found as f64 / 2.0, "{pairs} pairs");
    assert!(rms_mm < 0.3, "bundle RMS {rms_mm} mm");
}

#[test]
fn bad_input_is_a_clear_error() {
    let dir = tempfile::tempdir().unwrap();
    let s = dir.path().join("s");
    synth(&s, 2, &["--noise", "0"]);
    // A corrupt PNG.
    std::fs::write(s.join("cam1/000001.png"), b"\x89PNG garbage").unwrap();
    let mut replay = Replay::open(&s, ReplayParams::default()).unwrap();
    assert!(replay.next_frame().unwrap().is_ok());
    let e = replay.next_frame().unwrap().unwrap_err().to_string();
    assert!(
        e.contains("frame 1") && e.contains("cam1/000001.png"),
        "{e}"
    );
    // Images of another size than the calibration.
    let calib = std::fs::read_to_string(s.join("calibration.yaml")).unwrap();
    std::fs::write(
        s.join("calibration.yaml"),
        calib.replace("image_width: 1280", "image_width: 1920"),
    )
    .unwrap();
    let mut replay = Replay::open(&s, ReplayParams::default()).unwrap();
    let e = replay.next_frame().unwrap().unwrap_err().to_string();
    assert!(e.contains("1280×1024") && e.contains("1920×1024"), "{e}");
    // A calibration with a wrong key: the replay and the CLI name it.
    let bad = dir.path().join("bad.yaml");
    std::fs::write(&bad, calib.replace("K1:", "K_1:")).unwrap();
    let params = ReplayParams {
        calibration: Some(bad.clone()),
        ..Default::default()
    };
    let e = Replay::open(&s, params).unwrap_err().to_string();
    assert!(e.contains("missing key `K1`"), "{e}");
    let out = helmcap(&[
        "synth",
        "--out",
        dir.path().join("x").to_str().unwrap(),
        "-n",
        "1",
        "--calib",
        bad.to_str().unwrap(),
    ]);
    assert!(!out.status.success());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("K1") && !stderr.contains("panicked"),
        "{stderr}"
    );
    // A wrong matrix size.
    std::fs::write(
        &bad,
        calib.replace("rows: 3\n   cols: 1", "rows: 4\n   cols: 1"),
    )
    .unwrap();
    let e = helmcap::camera::read_rig(&bad).unwrap_err().to_string();
    assert!(e.contains("key `T`"), "{e}");
    // A missing camera folder.
    std::fs::remove_dir_all(s.join("cam0")).unwrap();
    let e = Replay::open(&s, ReplayParams::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("cam0") && e.contains("missing"), "{e}");
}

/// Throughput of detection (both images, in parallel) + stereo pairing and triangulation
/// at 1280×1024, median of 5 passes over a 60-frame session; prints the figures. Heavy:
/// run in release with `--ignored --nocapture`.
#[test]
#[ignore = "a throughput figure, run in release: cargo test --release --test capture_front_end -- --ignored --nocapture"]
fn capture_throughput() {
    let dir = tempfile::tempdir().unwrap();
    let s = dir.path();
    let start = std::time::Instant::now();
    synth(s, 60, &["--slip-mm", "1.5", "--slip-deg", "1"]);
    eprintln!(
        "render: 60 stereo frames in {:.2} s",
        start.elapsed().as_secs_f64()
    );
    let replay = Replay::open(s, ReplayParams::default()).unwrap();
    let rig = replay.rig().unwrap().clone();
    let frames: Vec<_> = replay.map(Result::unwrap).collect();
    let params = DetectParams::default();
    let mut rates = Vec::new();
    let (mut detect_secs, mut pair_secs) = (Vec::new(), Vec::new());
    for _ in 0..5 {
        let t = std::time::Instant::now();
        let mut bundles = 0;
        let (mut td, mut tp) = (0.0, 0.0);
        for f in &frames {
            let t0 = std::time::Instant::now();
            let (a, b) = rayon::join(
                || detect_markers(&f.images[0], &params),
                || detect_markers(&f.images[1], &params),
            );
            let t1 = std::time::Instant::now();
            let pa: Vec<_> = a.iter().map(|d| d.centre_px).collect();
            let pb: Vec<_> = b.iter().map(|d| d.centre_px).collect();
            bundles += pair_detections(&rig, &pa, &pb, &PairParams::default()).len();
            td += (t1 - t0).as_secs_f64();
            tp += t1.elapsed().as_secs_f64();
        }
        assert!(bundles > 0);
        rates.push(frames.len() as f64 / t.elapsed().as_secs_f64());
        detect_secs.push(td / frames.len() as f64);
        pair_secs.push(tp / frames.len() as f64);
    }
    detect_secs.sort_by(f64::total_cmp);
    pair_secs.sort_by(f64::total_cmp);
    eprintln!(
        "per stereo frame (median): detection {:.2} ms, pairing + triangulation {:.2} ms",
        detect_secs[2] * 1e3,
        pair_secs[2] * 1e3
    );
    rates.sort_by(f64::total_cmp);
    eprintln!(
        "detect + pair + triangulate: median {:.0} stereo frames/s (min {:.0}, max {:.0})",
        rates[2], rates[0], rates[4]
    );
}

/// A replay that labels nothing says so, and what to check, even on a take too short for
/// the warning logged while running and under `--quiet`; one that labels does not.
#[test]
fn a_replay_that_labels_nothing_says_what_to_check() {
    let dir = tempfile::tempdir().unwrap();
    let session = dir.path().join("s");
    synth(&session, 4, &[]);
    // Bright dots looked for on dark ones: nothing is detected, nothing labeled.
    let profile = dir.path().join("bright.toml");
    std::fs::write(&profile, "dot_diameter_mm = 2.4\npolarity = \"bright\"\n").unwrap();
    let replay = |name: &str, extra: &[&str]| {
        let out = dir.path().join(name);
        let mut args = vec![
            "replay",
            session.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--no-solve",
            "--quiet",
        ];
        args.extend_from_slice(extra);
        let o = helmcap(&args);
        assert!(o.status.success(), "{o:?}");
        String::from_utf8_lossy(&o.stdout).into_owned()
    };
    let stdout = replay("wrong", &["--profile", profile.to_str().unwrap()]);
    assert!(
        stdout.contains("warning: no marker labeled in 4 frames")
            && stdout.contains("capture profile")
            && stdout.contains("helmcap detect"),
        "{stdout}"
    );
    let stdout = replay("right", &[]);
    assert!(!stdout.contains("no marker labeled"), "{stdout}");
}

/// `helmcap detect` takes the acquisition's whole search in its one frame: on cluttered skin,
/// a profile whose per-frame shares of the search (one triple, one hypothesis) cannot
/// decide in one frame labels the frame as the session's own profile does (a replay goes
/// on with the search over the next frames; `detect` has none).
#[test]
fn detect_takes_the_acquisitions_whole_search_in_its_one_frame() {
    let dir = tempfile::tempdir().unwrap();
    let session = dir.path().join("session");
    synth(&session, 2, &["--preset", "cluttered"]);
    let profile = std::fs::read_to_string(session.join("profile.toml")).unwrap();
    assert!(!profile.contains("[label]"), "{profile}");
    let tight_profile = dir.path().join("tight.toml");
    std::fs::write(
        &tight_profile,
        format!(
            "{profile}\n[label]\nacquire_iterations_per_frame = 1\nacquire_hypotheses_per_frame = 1\n"
        ),
    )
    .unwrap();
    let labels = |extra: &[&str], out: &str| -> String {
        let out_dir = dir.path().join(out);
        let mut args = vec![
            "detect",
            session.to_str().unwrap(),
            "--frame",
            "1",
            "--out",
            out_dir.to_str().unwrap(),
        ];
        args.extend_from_slice(extra);
        common::ok(&helmcap(&args));
        std::fs::read_to_string(out_dir.join("detections.csv")).unwrap()
    };
    // The labeled rows (a marker's name in the last column).
    let labeled = |csv: String| -> Vec<String> {
        csv.lines()
            .skip(1)
            .filter(|l| !l.ends_with(','))
            .map(str::to_string)
            .collect()
    };
    let own = labeled(labels(&[], "own"));
    assert!(
        own.len() >= 100,
        "{} detections labeled with the session's profile",
        own.len()
    );
    let tight = labeled(labels(
        &["--profile", tight_profile.to_str().unwrap()],
        "tight",
    ));
    assert!(
        tight == own,
        "{} detections labeled with the least per-frame shares of the search, {} with the \
         session's profile",
        tight.len(),
        own.len()
    );
}

/// `helmcap detect` on a frame of a session: both annotated images and a CSV whose labeled
/// detections lie on their own markers' dots, at least 95 % of the markers detectable in
/// both cameras labeled in both; `--print-profile` with the session prints the profile the
/// session names.
#[test]
fn detect_labels_a_session_frame_and_prints_its_profile() {
    let dir = tempfile::tempdir().unwrap();
    let session = dir.path().join("session");
    synth(&session, 2, &["--preset", "wide-mixed"]);
    let out_dir = dir.path().join("detect");
    let out = helmcap(&[
        "detect",
        session.to_str().unwrap(),
        "--frame",
        "1",
        "--out",
        out_dir.to_str().unwrap(),
    ]);
    common::ok(&out);
    for name in ["detect_cam0.png", "detect_cam1.png"] {
        let bytes = std::fs::read(out_dir.join(name)).unwrap();
        assert_eq!(&bytes[1..4], b"PNG", "{name}");
    }
    // Ground truth of frame 1: (camera, marker) → (pixel, detectable).
    let gt = std::fs::read_to_string(session.join("gt/projections.csv")).unwrap();
    let mut truth: HashMap<(String, String), (Point2<f64>, bool)> = HashMap::new();
    for line in gt.lines().skip(1) {
        let f: Vec<&str> = line.split(',').collect();
        if f[0] == "1" {
            let at = Point2::new(f[3].parse().unwrap(), f[4].parse().unwrap());
            truth.insert((f[1].to_string(), f[2].to_string()), (at, f[9] == "1"));
        }
    }
    let csv = std::fs::read_to_string(out_dir.join("detections.csv")).unwrap();
    let mut lines = csv.lines();
    assert_eq!(
        lines.next().unwrap(),
        "camera,u,v,diameter_px,area_px,roundness,contrast_dn,quality,status,marker"
    );
    let mut labeled: HashMap<String, usize> = HashMap::new();
    let mut wrong = Vec::new();
    for line in lines {
        let f: Vec<&str> = line.split(',').collect();
        if f[9].is_empty() {
            continue;
        }
        // On its own dot: the nearest true projection is its own, within 5 px (a dot
        // partly hidden by a lip has its blob's centre a few pixels off, as in the preset
        // matrix).
        let at: Point2<f64> = Point2::new(f[1].parse().unwrap(), f[2].parse().unwrap());
        let nearest = truth
            .iter()
            .filter(|((cam, _), _)| cam == f[0])
            .map(|((_, m), (p, _))| (m, (p - at).norm()))
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .unwrap();
        if nearest.0 != f[9] || nearest.1 > 5.0 {
            wrong.push(line.to_string());
        }
        *labeled.entry(f[9].to_string()).or_default() += 1;
    }
    assert!(wrong.is_empty(), "labels off their dots: {wrong:?}");
    let detectable: Vec<&String> = truth
        .iter()
        .filter(|((cam, _), (_, d))| cam == "cam0" && *d)
        .map(|((_, m), _)| m)
        .filter(|m| truth[&("cam1".to_string(), m.to_string())].1)
        .collect();
    let found = detectable
        .iter()
        .filter(|m| labeled.get(m.as_str()) == Some(&2))
        .count();
    assert!(
        found as f64 >= 0.95 * detectable.len() as f64,
        "{found} of {} markers detectable in both cameras labeled in both",
        detectable.len()
    );
    // The profile in use is the session's (3.5 mm dots), not the defaults (2.4 mm).
    let out = helmcap(&["detect", session.to_str().unwrap(), "--print-profile"]);
    common::ok(&out);
    let printed = String::from_utf8_lossy(&out.stdout);
    assert!(printed.contains("dot_diameter_mm = 3.5"), "{printed}");
    let out = helmcap(&["detect", "--print-profile"]);
    common::ok(&out);
    assert!(String::from_utf8_lossy(&out.stdout).contains("dot_diameter_mm = 2.4"));
}
