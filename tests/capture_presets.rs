//! The capture front end over every `helmcap synth` preset (near and far rigs, narrow and
//! wide lenses, small and large dots, cluttered skin, bright, coloured and 16-bit images):
//! each preset is rendered, replayed through the binary with the profile the session names,
//! and its labels are checked against the ground truth.
//!
//! The goal per preset: at least 99 % of the marker observations ground truth calls
//! detectable in both cameras are labeled, none wrongly (a label whose 2D detection is not
//! on the marker's dot, or any label of a dot wiped off: `wiped-moles` puts a mole beside
//! each), the labeled bundles' RMS error is within 1.2× the stereo bound,
//! and the head pose is held (too few stabilizing markers) on at most 2 % of frames.
//! Every preset reaches it.
//!
//! The stereo bound is what the detector's own centroid accuracy allows: the true
//! projections of the labeled markers, perturbed by Gaussian noise of the centroid error
//! RMS measured on those labels, triangulated through the calibration (Monte Carlo, fixed
//! seed). Labels on the wrong dot, or a heavy tail of bad centroids, push the pipeline's
//! error above it.
//!
//! Set `HELMCAP_PRESETS` to a comma-separated list to run some presets only.

#![allow(clippy::unwrap_used)]

use std::collections::{HashMap, HashSet};
use std::path::Path;

use helmcap::stereo::{TriangulateParams, triangulate};
use nalgebra::Point2;
use rand::SeedableRng;
use rand_distr_free::normal;

mod common;
use common::helmcap;

fn run_ok(args: &[&str]) -> String {
    let out = helmcap(args);
    assert!(
        out.status.success(),
        "helmcap {}: {}{}",
        args.join(" "),
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// Gaussian samples without another dependency (Box-Muller).
mod rand_distr_free {
    use rand::Rng;

    pub fn normal(rng: &mut impl Rng) -> f64 {
        let u1: f64 = rng.random::<f64>().max(1e-12);
        let u2: f64 = rng.random();
        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
    }
}

/// Ground truth of one marker in one camera and frame.
#[derive(Clone, Copy)]
struct Truth {
    px: Point2<f64>,
    detectable: bool,
}

/// `gt/projections.csv`: (frame, camera, marker) → truth.
fn read_projections(dir: &Path) -> HashMap<(usize, usize, String), Truth> {
    let text = std::fs::read_to_string(dir.join("gt/projections.csv")).unwrap();
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let col = |name: &str| header.iter().position(|h| *h == name).unwrap();
    let (cf, cc, cm, cu, cv, cd) = (
        col("frame"),
        col("camera"),
        col("marker"),
        col("u"),
        col("v"),
        col("detectable"),
    );
    lines
        .map(|line| {
            let f: Vec<&str> = line.split(',').collect();
            let cam = usize::from(f[cc] == "cam1");
            (
                (f[cf].parse().unwrap(), cam, f[cm].to_string()),
                Truth {
                    px: Point2::new(f[cu].parse().unwrap(), f[cv].parse().unwrap()),
                    detectable: f[cd] == "1",
                },
            )
        })
        .collect()
}

/// `gt/distractors.csv`: the (frame, marker) of every dot wiped off (no ink to label).
fn read_wiped(dir: &Path) -> HashSet<(usize, String)> {
    let Ok(text) = std::fs::read_to_string(dir.join("gt/distractors.csv")) else {
        return HashSet::new();
    };
    text.lines()
        .skip(1)
        .filter_map(|line| {
            let f: Vec<&str> = line.split(',').collect();
            (f.len() >= 7 && f[2] == "wiped_dot").then(|| (f[0].parse().unwrap(), f[6].to_string()))
        })
        .collect()
}

/// `tracks.csv` of a replay: (frame, camera, marker) → labeled pixel.
fn read_tracks(dir: &Path) -> HashMap<(usize, usize, String), Point2<f64>> {
    let text = std::fs::read_to_string(dir.join("tracks.csv")).unwrap();
    text.lines()
        .skip(1)
        .map(|line| {
            let f: Vec<&str> = line.split(',').collect();
            let cam = usize::from(f[1] == "cam1" || f[1] == "1");
            (
                (f[0].parse().unwrap(), cam, f[2].to_string()),
                Point2::new(f[3].parse().unwrap(), f[4].parse().unwrap()),
            )
        })
        .collect()
}

/// The true projections of the markers in one image: (marker, pixel).
type ImageTruth<'a> = Vec<(&'a str, Point2<f64>)>;

/// A stereo observation: the pixel in cam0 and in cam1.
type PixelPair = [Point2<f64>; 2];

/// The figures of one preset.
#[derive(Debug)]
struct Figures {
    detectable: usize,
    labeled_detectable: usize,
    labeled: usize,
    wrong: usize,
    /// The marker and frame of each wrong label.
    wrong_markers: Vec<(String, usize)>,
    bundle_rms_mm: f64,
    bound_mm: f64,
    frames: usize,
    pose_held: u64,
}

/// A label is on its own dot when, in both cameras, the nearest true projection of any
/// marker to its pixel is its own, within this distance (a dot partly covered by a lip or a
/// hair has its blob's centre pulled off the dot's centre, up to a few pixels on large
/// dots; the bundle error then counts it), pixels.
const OWN_DOT_PX: f64 = 5.0;

fn evaluate(session: &Path, out: &Path) -> Figures {
    let truth = read_projections(session);
    let wiped = read_wiped(session);
    let tracks = read_tracks(out);
    let rig = helmcap::camera::read_rig(&session.join("calibration.yaml")).unwrap();
    let metrics: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("metrics.json")).unwrap()).unwrap();
    let frames = metrics["frames_out"].as_u64().unwrap() as usize;
    let pose_held = metrics["gaps"]["pose_held"].as_u64().unwrap_or(0);
    let mut markers: Vec<(usize, String)> = truth
        .keys()
        .filter(|k| k.1 == 0)
        .map(|k| (k.0, k.2.clone()))
        .collect();
    markers.sort();
    // True projections per frame and camera, to find the dot a labeled pixel is on.
    let mut by_image: HashMap<(usize, usize), ImageTruth> = HashMap::new();
    for ((frame, cam, name), t) in &truth {
        by_image
            .entry((*frame, *cam))
            .or_default()
            .push((name.as_str(), t.px));
    }
    let on_own_dot = |frame: usize, cam: usize, name: &str, px: &Point2<f64>| {
        by_image.get(&(frame, cam)).is_some_and(|all| {
            all.iter()
                .map(|(n, p)| (*n, (p - px).norm()))
                .min_by(|a, b| a.1.total_cmp(&b.1))
                .is_some_and(|(n, d)| n == name && d <= OWN_DOT_PX)
        })
    };
    let (mut detectable, mut labeled_detectable, mut labeled, mut wrong) = (0, 0, 0, 0);
    let mut wrong_markers = Vec::new();
    // Per labeled-and-right marker: the true and the labeled pixels in both cameras.
    let mut pairs: Vec<(PixelPair, PixelPair)> = Vec::new();
    for (frame, name) in &markers {
        let t = [0, 1].map(|c| truth.get(&(*frame, c, name.clone())).copied());
        let (Some(t0), Some(t1)) = (t[0], t[1]) else {
            continue;
        };
        let both = t0.detectable && t1.detectable;
        detectable += usize::from(both);
        let l = [0, 1].map(|c| tracks.get(&(*frame, c, name.clone())).copied());
        let (Some(l0), Some(l1)) = (l[0], l[1]) else {
            continue;
        };
        labeled += 1;
        // A dot wiped off has no ink: any label of it is on something else.
        let right = !wiped.contains(&(*frame, name.clone()))
            && on_own_dot(*frame, 0, name, &l0)
            && on_own_dot(*frame, 1, name, &l1);
        if !right {
            wrong += 1;
            wrong_markers.push((name.clone(), *frame));
            eprintln!(
                "  wrong: frame {frame} {name}: labeled ({:.1}, {:.1}) / ({:.1}, {:.1}), truth ({:.1}, {:.1}) / ({:.1}, {:.1})",
                l0.x, l0.y, l1.x, l1.y, t0.px.x, t0.px.y, t1.px.x, t1.px.y
            );
            continue;
        }
        labeled_detectable += usize::from(both);
        pairs.push(([t0.px, t1.px], [l0, l1]));
    }
    // The pipeline's error and the stereo bound, both against the triangulated truth.
    let params = TriangulateParams {
        max_reprojection_px: 1e9,
        depth_range_mm: (1.0, 1e5),
        ..TriangulateParams::default()
    };
    let tri = |p: &PixelPair| {
        triangulate(&rig, &p[0], &p[1], &params)
            .ok()
            .map(|b| b.point_in_cam0)
    };
    let (mut sq, mut n, mut centroid_sq) = (0.0, 0usize, 0.0);
    for (t, l) in &pairs {
        centroid_sq += (l[0] - t[0]).norm_squared() + (l[1] - t[1]).norm_squared();
        if let (Some(a), Some(b)) = (tri(t), tri(l)) {
            sq += (a - b).norm_squared();
            n += 1;
        }
    }
    let bundle_rms_mm = (sq / n.max(1) as f64).sqrt();
    // Per axis: the 2D centroid RMS over √2.
    let sigma = (centroid_sq / (2 * pairs.len()).max(1) as f64).sqrt() / 2f64.sqrt();
    let mut rng = rand::rngs::StdRng::seed_from_u64(7);
    let (mut bsq, mut bn) = (0.0, 0usize);
    for _ in 0..4 {
        for (t, _) in &pairs {
            let noisy = [0, 1].map(|c| {
                Point2::new(
                    t[c].x + sigma * normal(&mut rng),
                    t[c].y + sigma * normal(&mut rng),
                )
            });
            if let (Some(a), Some(b)) = (tri(t), tri(&noisy)) {
                bsq += (a - b).norm_squared();
                bn += 1;
            }
        }
    }
    Figures {
        detectable,
        labeled_detectable,
        labeled,
        wrong,
        wrong_markers,
        bundle_rms_mm,
        bound_mm: (bsq / bn.max(1) as f64).sqrt(),
        frames,
        pose_held,
    }
}

/// Least share of detectable marker observations labeled.
const MIN_LABELED: f64 = 0.99;

/// Largest bundle RMS error, in units of the stereo bound.
const MAX_RMS_OVER_BOUND: f64 = 1.2;

/// Largest share of frames with the head pose held.
const MAX_POSE_HELD: f64 = 0.02;

/// The presets of the matrix and the frames rendered of each; each must reach the goal
/// (module docs): at least [`MIN_LABELED`] of detectable labeled, no wrong label, bundle
/// RMS within [`MAX_RMS_OVER_BOUND`] times the stereo bound, head pose held on at most
/// [`MAX_POSE_HELD`] of frames.
const PRESETS: &[(&str, usize)] = &[
    ("clean-far", 60),
    ("near-face", 60),
    ("wide-mixed", 60),
    // Cluttered reached the goal on 2026-12-07 (99.05 % labeled, no wrong label) with dots
    // a dark band touches fitted to their rim and markers the acquisition's frame shows
    // confirmed from there; it was held to a floor before (98.6 % with the pieces of a dot
    // a highlight splits joined and a dot edge-on under a hair found by its core, 97.25 %
    // before thin blobs' contrast floor went from 1.5 to 1.3 times the dots', 94.4 % before
    // dots merged with a mole were labeled at their lobe, 88.5 % before worn dots were
    // taken and frame 0 was acquired).
    ("cluttered", 60),
    ("wiped-moles", 60),
    // Two seconds: the first press comes after the neutral lead, and dots hidden by a
    // press come back from behind the lip only in the second.
    ("lip-press", 120),
    ("bright-dots", 60),
    ("color-dots", 60),
    ("mono16", 60),
    ("vga", 60),
];

/// Renders a session into `dir/name` with `helmcap synth` and `synth_args`, replays it
/// without the solve (the profile the session names) into `dir/name-out`, and checks its
/// labels against the ground truth.
fn render_and_replay(dir: &Path, name: &str, synth_args: &[&str]) -> Figures {
    let session = dir.join(name);
    let out = dir.join(format!("{name}-out"));
    let mut synth = vec!["synth", "--out", session.to_str().unwrap()];
    synth.extend_from_slice(synth_args);
    run_ok(&synth);
    run_ok(&[
        "replay",
        session.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--no-solve",
        "--quiet",
    ]);
    evaluate(&session, &out)
}

/// Writes a line of the matrix straight to the standard error, past the test harness's
/// capture (which `eprintln!` goes through): CI's log shows the table of a passing run.
fn report(line: &str) {
    use std::io::Write;
    let _ = writeln!(std::io::stderr().lock(), "{line}");
}

#[test]
fn every_preset_reaches_its_goal() {
    let listed = run_ok(&["synth", "--list-presets"]);
    let only: Option<Vec<String>> = std::env::var("HELMCAP_PRESETS")
        .ok()
        .map(|s| s.split(',').map(|x| x.trim().to_string()).collect());
    let dir = tempfile::tempdir().unwrap();
    let mut failures = Vec::new();
    report(
        "preset        frames  detectable  labeled %  wrong  bundle RMS  bound    ratio  pose held",
    );
    for &(preset, frames) in PRESETS {
        if only
            .as_ref()
            .is_some_and(|o| !o.iter().any(|x| x == preset))
        {
            continue;
        }
        assert!(listed.contains(preset), "synth has no preset {preset}");
        let frames = frames.to_string();
        let f = render_and_replay(dir.path(), preset, &["--preset", preset, "-n", &frames]);
        let share = f.labeled_detectable as f64 / f.detectable.max(1) as f64;
        let ratio = f.bundle_rms_mm / f.bound_mm.max(1e-9);
        report(&format!(
            "{preset:<13} {:>6}  {:>10}  {:>8.2} %  {:>5}  {:>7.3} mm  {:.3}  {:>5.2}  {:>4} ({} labels)",
            f.frames,
            f.detectable,
            100.0 * share,
            f.wrong,
            f.bundle_rms_mm,
            f.bound_mm,
            ratio,
            f.pose_held,
            f.labeled
        ));
        if f.detectable == 0 {
            failures.push(format!("{preset}: no detectable markers"));
        }
        if share < MIN_LABELED {
            failures.push(format!(
                "{preset}: {:.2} % of detectable labeled",
                100.0 * share
            ));
        }
        if f.wrong > 0 {
            failures.push(format!("{preset}: {} wrong labels", f.wrong));
        }
        if ratio > MAX_RMS_OVER_BOUND {
            failures.push(format!(
                "{preset}: bundle RMS {:.3} mm is {ratio:.2}× the stereo bound",
                f.bundle_rms_mm
            ));
        }
        if f.pose_held as f64 > MAX_POSE_HELD * f.frames as f64 {
            failures.push(format!(
                "{preset}: head pose held on {} of {} frames",
                f.pose_held, f.frames
            ));
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// Set-ups of the `wiped-moles` preset beyond its default seed, each of which once had
/// moles taken for wiped markers: a marker wiped before the take labeled on a mole two
/// thirds of a dot's size (seeds 7 and 203), and markers whose place their neighbours do
/// not follow taken, after a long gap, on a mole that slid where they were predicted
/// (seed 11), and a marker wiped mid-take labeled for four frames on a freckle that lay
/// under its dot, a third of the ink's contrast (seed 912, M096 from frame 23; see
/// `LabelParams::kept_contrast_ratio`), and one wiped mid-take taken four frames later on a
/// mole that had stood 21 px from its dot, where its neighbours put it as the jaw opened
/// (seed 1301, M102 from frame 44; see `Labeler::stayed_while_gone`). Frame counts: up to
/// the frames where that happened, or the whole set-up.
const WIPED_MOLES_SET_UPS: [(u64, usize); 5] =
    [(7, 40), (11, 90), (203, 60), (912, 30), (1301, 60)];

#[test]
fn moles_where_markers_were_wiped_off_are_not_taken_on_more_set_ups() {
    let failures = set_up_failures("wiped-moles", &WIPED_MOLES_SET_UPS, 0.99);
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// Renders and replays set-ups (seed, frames) of `preset` and lists those with a wrong
/// label or under `min_share` of the detectable markers labeled (0: wrong labels only).
fn set_up_failures(preset: &str, set_ups: &[(u64, usize)], min_share: f64) -> Vec<String> {
    let dir = tempfile::tempdir().unwrap();
    let mut failures = Vec::new();
    for &(seed, frames) in set_ups {
        let (seed_arg, frames_arg) = (seed.to_string(), frames.to_string());
        let f = render_and_replay(
            dir.path(),
            &format!("{preset}-{seed}"),
            &["--preset", preset, "--seed", &seed_arg, "-n", &frames_arg],
        );
        let share = f.labeled_detectable as f64 / f.detectable.max(1) as f64;
        report(&format!(
            "{preset} seed {seed}: {frames} frames, {:.2} % of detectable labeled, {} wrong",
            100.0 * share,
            f.wrong
        ));
        if f.wrong > 0 || share < min_share {
            failures.push(format!(
                "{preset} seed {seed}: {:.2} % labeled, {} wrong",
                100.0 * share,
                f.wrong
            ));
        }
    }
    failures
}

/// A `lip-press` set-up beyond its default seed that once had a mole taken for a lip dot:
/// the dot, moved 7 px in a frame together with the mole beside it, was lost for that
/// frame (the mole a rival of it), then taken on the mole from where it was last seen and
/// followed on it for eight frames, 21-29 px off (seed 2, M053; see
/// `Labeler::doubt_told_by_size`). Frames: up to where that happened and after.
const LIP_PRESS_SET_UPS: [(u64, usize); 1] = [(2, 100)];

#[test]
fn a_lip_dot_moved_with_its_mole_is_not_followed_on_the_mole() {
    let failures = set_up_failures("lip-press", &LIP_PRESS_SET_UPS, 0.99);
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// `lip-press` set-ups with dots merged with a mole beside them. Seed 7: a lip dot seen
/// 80° from cam0 once was labeled between itself and the mole for 11 frames, 6.4 px off:
/// its blob touched the mole a frame early, pulling the label and the prediction after it,
/// and then was one 30 px streak only 3.6 px off that prediction (M060; see
/// `Labeler::grew_past_a_dot`); and M008, merged with a mole in cam1 only, was missed
/// throughout. Seed 902: M044, merged with a larger mole in one camera and then in both,
/// was missed throughout; taken at its lobe in one camera and at its dot in the other, it
/// once was followed onto the two blobs' centres, 10 px off, for three frames (frames
/// 12-14; see `Labeler::merged_dot`). Seed 1401 (made after the preset, never tuned on):
/// M085, half hidden by the lip all take long and merged with a mole of its size 12 px away,
/// was labeled at the merged blob's centre, 6-8 px off, in 9 frames: as a first sighting
/// whose blob read as two discs in both cameras, and as a marker tracked at the dot's
/// lobe when the lobes were not read in one camera (see `Labeler::two_discs_in_both` and
/// `Labeler::still_merged`).
const LIP_PRESS_MERGED_SET_UPS: [(u64, usize); 3] = [(7, 30), (902, 20), (1401, 60)];

#[test]
fn a_lip_dot_merged_with_its_mole_is_not_labeled_between_the_two() {
    let failures = set_up_failures("lip-press", &LIP_PRESS_MERGED_SET_UPS, 0.99);
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// A `lip-press` set-up (made after the preset, never tuned on) whose forehead dot, seen
/// 81° from cam1 (not found there), has a 3.8 mm mole beside it that both cameras see,
/// merged with the dot in cam0: it was labeled on the mole from its first sighting on,
/// 6 px from the dot, for 56 frames from frame 4 (seed 901, M009; see
/// `LabelParams::never_seen_max_relative_size`).
const LIP_PRESS_LARGE_MOLE_SET_UPS: [(u64, usize); 1] = [(901, 20)];

#[test]
fn a_mole_larger_than_a_dot_beside_an_edge_on_dot_is_not_taken_for_it() {
    let failures = set_up_failures("lip-press", &LIP_PRESS_LARGE_MOLE_SET_UPS, 0.99);
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// A `lip-press` set-up whose lip dot, seen 81° from cam0, made one blob there with a mole
/// beside it that looked as thin: it was labeled on the two merged, 4.5 px from the dot's
/// place in cam0, for most of the take, and on the mole alone, 8-9 px off, once they parted
/// (seed 3, M076; 11 wrong labels on the set-up). Gone since a dot merged with a mole in
/// one camera is labeled at its lobe (`Labeler::merged_dot`) and a blob that shrank on one
/// side is told as a piece of the last one (`Labeler::a_piece_off_its_blob`). Frames: past
/// the last of those.
const LIP_PRESS_EDGE_ON_SET_UPS: [(u64, usize); 1] = [(3, 72)];

#[test]
fn an_edge_on_lip_dot_parted_from_its_mole_is_not_followed_onto_the_mole() {
    let failures = set_up_failures("lip-press", &LIP_PRESS_EDGE_ON_SET_UPS, 0.99);
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// A `lip-press` set-up below the goal (run with `--ignored`; README, "Capture presets"):
/// seed 4 has no wrong label since dots merged with a mole in one camera are labeled at
/// their lobe (three before), but 98.1 % labeled (M067 and M107 missed in most frames).
const LIP_PRESS_BELOW_GOAL: [(u64, usize); 1] = [(4, 120)];

#[test]
#[ignore = "a lip-press set-up below the labeled share asked (see LIP_PRESS_BELOW_GOAL)"]
fn lip_press_set_ups_below_the_goal_reach_it() {
    let failures = set_up_failures("lip-press", &LIP_PRESS_BELOW_GOAL, 0.99);
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// Lip-press seed 1402 (made after the preset, never tuned on; README, "Not at the centre
/// of a blob still merged"): M076, a dot at the silhouette beside a mole, tracked at its
/// lobe of the blob the two make, was taken at the blob's centre when its lobes were not
/// read and followed onto the mole from frame 88 (11 wrong labels in 100 frames, 31 in
/// 120). Wrong labels only: the set-up labels 96.5 %, its edge-on side-of-face dots missed.
const LIP_PRESS_SILHOUETTE_SET_UPS: [(u64, usize); 1] = [(1402, 100)];

#[test]
fn a_silhouette_dot_tracked_on_a_merged_blob_is_not_followed_onto_the_mole() {
    let failures = set_up_failures("lip-press", &LIP_PRESS_SILHOUETTE_SET_UPS, 0.0);
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// A `lip-press` set-up (made after the preset and every rule, never tuned on) with wrong
/// labels left (run with `--ignored`; README, "A lip dot told from its mole by what stood
/// beside them"): M040, a dot at the silhouette that neither camera sees (edge-on), is
/// labeled in one frame on a mole 3 px from it in cam0 and 6 px in cam1, both images of
/// the mole as thin as the dot's would be (the second of the two in a row that confirm it
/// as a new track; in 14 frames before a marker back after a gap was confirmed again until
/// its track held, `Labeler::confirm_new_tracks`). Its M054 and M102, once taken on moles for 55
/// and 11 frames, are now labeled right (see
/// `lip_dots_back_beside_their_mole_or_merged_with_it_are_not_taken_on_it`).
const LIP_PRESS_KNOWN_WRONG: [(u64, usize); 1] = [(1501, 120)];

/// Lip-press seed 1501 (README, "A lip dot told from its mole by what stood beside
/// them"). M054, a lower-lip dot lost at frame 56 as the press moved it 15 px a frame,
/// comes back at frame 65, after a 9-frame gap, 17 px from where its neighbours put it,
/// with the mole that stood 19 px below it still there; the lip has carried the mole to
/// where the dot was last labeled. It was taken on the mole from frame 65 to the end (55
/// wrong labels): from the neighbours' place the dot sat at the mole's remembered offset,
/// and the pass that looks where the marker was last seen found the mole. Told by the
/// blobs that stood beside the dot (`Labeler::dot_by_its_surroundings`,
/// `Labeler::beside_its_dot_found`). M102, a chin dot merged with a mole in cam0 only and
/// tracked at its lobe, was taken at the merged blob's centre at frame 54, when its lobes
/// were not read, and followed from there onto the mole (11 wrong labels, 8 px off in
/// cam0): a blob still as long as the merged blob it was is not taken as a dot at its
/// centre (`Labeler::still_merged`). Frames: to 15 frames after M054's return.
#[test]
fn lip_dots_back_beside_their_mole_or_merged_with_it_are_not_taken_on_it() {
    let dir = tempfile::tempdir().unwrap();
    let f = render_and_replay(
        dir.path(),
        "lip-press-1501",
        &["--preset", "lip-press", "--seed", "1501", "-n", "80"],
    );
    let of = |marker: &str| f.wrong_markers.iter().filter(|m| m.0 == marker).count();
    let (m054, m102) = (of("M054"), of("M102"));
    report(&format!(
        "lip-press seed 1501: 80 frames, {} wrong labels, {m054} of M054, {m102} of M102",
        f.wrong
    ));
    assert_eq!((m054, m102), (0, 0), "wrong labels of M054 and M102");
}

#[test]
fn an_edge_on_dot_merged_with_a_mole_comes_back_at_its_lobe_not_at_the_blobs_centre() {
    // Lip-press seed 1601's M030, a dot seen edge-on beside a 20 px mole, one blob with it
    // in both cameras, is tracked at its lobe and lost now and then for a few frames where
    // the lobes are not read in cam1. It came back at the blob's centre, 5 px from the dot
    // and 2.5 px from the mole, and was tracked there (35 wrong labels in frames 5-63
    // before the rules of `Labeler::back_at_its_lobe` and
    // `Labeler::back_on_its_merged_blob`). Its first five frames, labeled at the centre by
    // the acquisition, are still wrong (see the README's status).
    let dir = tempfile::tempdir().unwrap();
    let f = render_and_replay(
        dir.path(),
        "lip-press-1601",
        &["--preset", "lip-press", "--seed", "1601", "-n", "64"],
    );
    let after_acquisition = f
        .wrong_markers
        .iter()
        .filter(|(m, frame)| m == "M030" && *frame >= 5)
        .count();
    report(&format!(
        "lip-press seed 1601: 64 frames, {} wrong labels, {after_acquisition} of M030 from frame 5",
        f.wrong
    ));
    assert_eq!(after_acquisition, 0, "wrong labels of M030 from frame 5");
}

#[test]
fn a_smudged_dot_back_after_a_gap_is_not_taken_at_a_lobe() {
    // Cluttered seed 2001 (made after the preset, never tuned on): M049, a dot smudged
    // into a smear wide enough to read as a dot merged with a blob beside it, a hair
    // touching its end, is labeled at its centre as a worn dot, missed in frames 40 and
    // 43-46, and was taken back at the lobe toward its lower end, 5.3-5.8 px off (4 wrong
    // labels in frames 41-47 before `Labeler::back_on_its_smear`).
    let dir = tempfile::tempdir().unwrap();
    let f = render_and_replay(
        dir.path(),
        "cluttered-2001",
        &["--preset", "cluttered", "--seed", "2001", "-n", "48"],
    );
    let m049 = f.wrong_markers.iter().filter(|(m, _)| m == "M049").count();
    report(&format!(
        "cluttered seed 2001: 48 frames, {:.2} % labeled, {} wrong labels, {m049} of M049",
        100.0 * f.labeled_detectable as f64 / f.detectable.max(1) as f64,
        f.wrong
    ));
    assert_eq!(f.wrong, 0, "wrong labels: {:?}", f.wrong_markers);
}

#[test]
#[ignore = "known wrong labels on lip-press seed 1501 (see LIP_PRESS_KNOWN_WRONG)"]
fn a_mole_the_lip_carried_where_its_dot_was_is_not_taken_for_it() {
    let failures = set_up_failures("lip-press", &LIP_PRESS_KNOWN_WRONG, 0.99);
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}
