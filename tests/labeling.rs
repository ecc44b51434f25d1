//! Tracking and labeling on a synthetic session of 300 frames with blinks, lip presses
//! (lip contact) and helmet slip: every frame is detected and labeled, and the labels are
//! counted against the ground truth twice: against geometric visibility and against
//! detectability (the `detectable` column of `gt/projections.csv`), in both cameras. The
//! detector's misses are broken down by reason, view angle and projected minor axis. Set
//! `HELMCAP_LABELING_SESSION` to a session folder rendered the same way to skip the
//! rendering while investigating.

#![allow(clippy::unwrap_used)]

use std::collections::HashMap;
use std::path::Path;
use std::process::Command;

use helmcap::capture::{GrayImage, Replay, ReplayParams};
use helmcap::dataset::MarkerLayout;
use helmcap::dataset::actor::{Actor, ActorParams};
use helmcap::track::{DetectParams, Detection, LabelParams, Labeler, detect_markers};
use nalgebra::{Point2, Point3, Quaternion, UnitQuaternion, Vector3};

/// One row of `gt/projections.csv`.
#[derive(Debug, Clone, Copy)]
struct Truth2d {
    px: Point2<f64>,
    visible: bool,
    /// The `detectable` column (the dot is visible, unoccluded over its disc, inside the
    /// image and its projected minor axis is at least 2 px).
    detectable: bool,
    view_angle_deg: f64,
    minor_axis_px: f64,
    unoccluded: f64,
}

/// `gt/projections.csv`: (frame, camera) → marker index → truth.
type Projections = HashMap<(usize, usize), Vec<Truth2d>>;

fn read_projections(dir: &Path, layout: &MarkerLayout) -> Projections {
    let text = std::fs::read_to_string(dir.join("gt/projections.csv")).unwrap();
    let mut out: Projections = HashMap::new();
    let empty = Truth2d {
        px: Point2::origin(),
        visible: false,
        detectable: false,
        view_angle_deg: 90.0,
        minor_axis_px: 0.0,
        unoccluded: 0.0,
    };
    for line in text.lines().skip(1) {
        let f: Vec<&str> = line.split(',').collect();
        let cam = usize::from(f[1] == "cam1");
        let entry = out
            .entry((f[0].parse().unwrap(), cam))
            .or_insert_with(|| vec![empty; layout.len()]);
        let k = layout.index_of(f[2]).unwrap();
        entry[k] = Truth2d {
            px: Point2::new(f[3].parse().unwrap(), f[4].parse().unwrap()),
            visible: f[5] == "1",
            detectable: f[9] == "1",
            view_angle_deg: f[6].parse().unwrap(),
            minor_axis_px: f[7].parse().unwrap(),
            unoccluded: f[8].parse().unwrap(),
        };
    }
    out
}

/// Why the detector missed a dot that ground truth calls visible in one camera.
fn miss_reason(image: &GrayImage, t: &Truth2d, dets: &[Detection], gt: &[Truth2d]) -> &'static str {
    let near = |d: &Detection, tol: f64| (d.centre_px - t.px).norm() < tol;
    if let Some(d) = dets.iter().find(|d| near(d, 4.0)) {
        // A blob within 4 px whose nearest true projection is another marker's: merged.
        let nearest_other = gt
            .iter()
            .filter(|o| (o.px - t.px).norm() > 1e-9)
            .map(|o| (o.px - d.centre_px).norm())
            .fold(f64::MAX, f64::min);
        return if nearest_other < (d.centre_px - t.px).norm() {
            "merged with another dot"
        } else {
            "found, centre 1.5-4 px off"
        };
    }
    let (w, h) = (image.width as f64, image.height as f64);
    let roi = (
        (t.px.x - 16.0).max(0.0) as u32,
        (t.px.y - 16.0).max(0.0) as u32,
        (t.px.x + 17.0).clamp(1.0, w) as u32,
        (t.px.y + 17.0).clamp(1.0, h) as u32,
    );
    let finds = |p: DetectParams| {
        detect_markers(
            image,
            &DetectParams {
                roi: Some(roi),
                ..p
            },
        )
        .iter()
        .any(|d| near(d, 1.5))
    };
    let base = DetectParams::default();
    if finds(base.clone()) {
        return "outside the predicted ROI";
    }
    if finds(DetectParams {
        min_roundness: 0.0,
        ..base.clone()
    }) {
        return "roundness filter";
    }
    if finds(DetectParams {
        min_area_px: 1,
        ..base.clone()
    }) {
        return "size filter";
    }
    if finds(DetectParams {
        min_peak_contrast_dn: 0.0,
        ..base.clone()
    }) {
        return "peak contrast filter";
    }
    if finds(DetectParams {
        min_roundness: 0.0,
        min_area_px: 1,
        min_peak_contrast_dn: 0.0,
        ..base.clone()
    }) {
        return "several filters";
    }
    "below the local-contrast threshold"
}

/// Histogram bin of `v` over the upper `edges`.
fn bin(v: f64, edges: &[f64]) -> usize {
    edges.iter().position(|&e| v < e).unwrap_or(edges.len())
}

/// Ground-truth marker positions in cam0 per frame (index by layout order).
fn read_truth_in_cam0(dir: &Path, layout: &MarkerLayout) -> HashMap<usize, Vec<Point3<f64>>> {
    let poses = std::fs::read_to_string(dir.join("gt/head_pose.csv")).unwrap();
    let mut pose = HashMap::new();
    for line in poses.lines().skip(1) {
        let v: Vec<f64> = line.split(',').map(|s| s.parse().unwrap()).collect();
        let q = UnitQuaternion::from_quaternion(Quaternion::new(v[1], v[2], v[3], v[4]));
        pose.insert(v[0] as usize, (q, Vector3::new(v[5], v[6], v[7])));
    }
    let bundles = std::fs::read_to_string(dir.join("gt/bundles.csv")).unwrap();
    let mut out: HashMap<usize, Vec<Point3<f64>>> = HashMap::new();
    for line in bundles.lines().skip(1) {
        let f: Vec<&str> = line.split(',').collect();
        let frame: usize = f[0].parse().unwrap();
        let p = Point3::new(
            f[2].parse().unwrap(),
            f[3].parse().unwrap(),
            f[4].parse().unwrap(),
        );
        let (q, t) = pose[&frame];
        out.entry(frame)
            .or_insert_with(|| vec![Point3::origin(); layout.len()])
            [layout.index_of(f[1]).unwrap()] = q * p + t;
    }
    out
}

/// Largest value of an expression column in `gt/weights.csv`.
fn max_weight(dir: &Path, name: &str) -> f64 {
    let text = std::fs::read_to_string(dir.join("gt/weights.csv")).unwrap();
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let col = header.iter().position(|h| *h == name).unwrap();
    lines
        .map(|l| l.split(',').nth(col).unwrap().parse::<f64>().unwrap())
        .fold(0.0, f64::max)
}

#[test]
fn labels_a_300_frame_session_without_swaps() {
    let dir = tempfile::tempdir().unwrap();
    let reuse = std::env::var_os("HELMCAP_LABELING_SESSION");
    let s = reuse.as_deref().map_or(dir.path(), Path::new);
    let out = if reuse.is_some() {
        Command::new("true").output().unwrap()
    } else {
        Command::new(env!("CARGO_BIN_EXE_helmcap"))
            .args([
                "synth",
                "--out",
                s.to_str().unwrap(),
                "-n",
                "300",
                "--slip-mm",
                "1.5",
                "--slip-deg",
                "1",
                "--lip-press-interval",
                "1.5",
            ])
            .output()
            .unwrap()
    };
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    // The session has blinks and lip contact.
    assert!(max_weight(s, "eyeBlink_L") > 0.95, "no full blink");
    assert!(max_weight(s, "mouthPress_L") > 0.85, "no lip press");

    let actor = Actor::new(&ActorParams::default()).unwrap();
    let layout = MarkerLayout::read_csv(
        &Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/markers/builtin-actor.csv"),
    )
    .unwrap();
    let neutral: Vec<Point3<f64>> = layout
        .markers
        .iter()
        .map(|m| actor.neutral().positions[m.vertex as usize])
        .collect();
    let projections = read_projections(s, &layout);
    let truth = read_truth_in_cam0(s, &layout);
    let replay = Replay::open(s, ReplayParams::default()).unwrap();
    let rig = replay.rig().unwrap().clone();
    let mut labeler = Labeler::new(rig, &layout, neutral, LabelParams::default()).unwrap();

    let (mut visible, mut detected, mut correct, mut wrong) = (0usize, 0usize, 0usize, 0usize);
    let (mut correct_visible, mut correct_detected) = (0usize, 0usize);
    let (mut sq_err, mut reacquired, mut acquiring_frames) = (0.0, 0usize, 0usize);
    let mut missed: HashMap<(usize, usize), (usize, usize)> = HashMap::new();
    // Per marker: detectable observations not labeled right, and the first frame of them.
    let mut unlabeled: HashMap<usize, (usize, usize)> = HashMap::new();
    // Misses per camera: by detector reason (and whether ground truth calls the dot
    // detectable), by view angle and by projected minor axis.
    const ANGLE_EDGES: [f64; 5] = [60.0, 70.0, 72.5, 75.0, 77.5];
    const MINOR_EDGES: [f64; 5] = [1.5, 2.0, 2.5, 3.0, 4.0];
    let mut reasons: HashMap<(&str, bool), usize> = HashMap::new();
    let (mut miss_angle, mut vis_angle) = ([0usize; 6], [0usize; 6]);
    let (mut miss_minor, mut vis_minor) = ([0usize; 6], [0usize; 6]);
    let (mut miss_occluded, mut miss_border, mut miss_detectable) = (0usize, 0usize, 0usize);
    let mut detectable_misses_shown = 0usize;
    let (mut n_detectable, mut correct_detectable) = (0usize, 0usize);
    let mut spurious = 0usize;
    // Wrong labels whose dot in a camera is another marker's (the rest use a blob that is
    // no dot's).
    let mut swaps = 0usize;
    for frame in replay {
        let frame = frame.unwrap();
        let rois = labeler.predicted_rois();
        let dets: Vec<_> = (0..2)
            .map(|c| {
                let params = DetectParams {
                    roi: rois[c],
                    ..DetectParams::default()
                };
                detect_markers(&frame.images[c], &params)
            })
            .collect();
        let labels = labeler.process(frame.index, [&dets[0], &dets[1]]);
        acquiring_frames += usize::from(labels.stats.acquiring);
        reacquired += labels.stats.reacquired;
        let gt = [
            &projections[&(frame.index.as_usize(), 0)],
            &projections[&(frame.index.as_usize(), 1)],
        ];
        // The marker whose true projection is nearest a detection, within `tol` pixels
        // (visible or not: a dot the ground truth calls hidden, at a grazing angle or at
        // the edge of an eyelid, can still show).
        let owner = |c: usize, px: &Point2<f64>, tol: f64| -> Option<usize> {
            gt[c]
                .iter()
                .enumerate()
                .map(|(k, t)| (k, (t.px - px).norm()))
                .filter(|(_, d)| *d < tol)
                .min_by(|a, b| a.1.total_cmp(&b.1))
                .map(|(k, _)| k)
        };
        // Detection: within 1.5 px of the true projection. Label: the detection's dot is
        // the marker's when its true projection is the nearest within 4 px (markers are
        // 15 px or more apart in the images; a partly hidden dot's centre moves by a few
        // pixels).
        let near: [Vec<Option<usize>>; 2] = [0, 1].map(|c| {
            dets[c]
                .iter()
                .map(|d| owner(c, &d.centre_px, 4.0))
                .collect()
        });
        let found: [Vec<Option<usize>>; 2] = [0, 1].map(|c| {
            dets[c]
                .iter()
                .map(|d| owner(c, &d.centre_px, 1.5))
                .collect()
        });
        // Blobs that are no marker's dot (nothing within 4 px).
        spurious += near.iter().flatten().filter(|o| o.is_none()).count();
        for k in 0..layout.len() {
            let vis = gt[0][k].visible && gt[1][k].visible;
            let detectable = gt[0][k].detectable && gt[1][k].detectable;
            visible += usize::from(vis);
            n_detectable += usize::from(detectable);
            let in_both = found[0].contains(&Some(k)) && found[1].contains(&Some(k));
            detected += usize::from(vis && in_both);
            for c in 0..2 {
                let t = &gt[c][k];
                if t.visible && !found[c].contains(&Some(k)) {
                    let near = dets[c]
                        .iter()
                        .map(|d| (d.centre_px - t.px).norm())
                        .fold(f64::MAX, f64::min);
                    let e = missed.entry((k, c)).or_insert((0usize, 0usize));
                    e.0 += 1;
                    e.1 += usize::from(near < 5.0);
                    let reason = miss_reason(&frame.images[c], t, &dets[c], gt[c]);
                    *reasons.entry((reason, t.detectable)).or_insert(0usize) += 1;
                    miss_angle[bin(t.view_angle_deg, &ANGLE_EDGES)] += 1;
                    miss_minor[bin(t.minor_axis_px, &MINOR_EDGES)] += 1;
                    miss_occluded += usize::from(t.unoccluded < 1.0);
                    miss_detectable += usize::from(t.detectable);
                    let (w, h) = (frame.images[c].width as f64, frame.images[c].height as f64);
                    miss_border += usize::from(
                        t.px.x < 10.0 || t.px.y < 10.0 || t.px.x > w - 11.0 || t.px.y > h - 11.0,
                    );
                    if t.detectable && detectable_misses_shown < 15 {
                        detectable_misses_shown += 1;
                        eprintln!(
                            "detectable miss: frame {} {} cam{c} at ({:.1}, {:.1}): {:.1}°, minor {:.2} px, {reason}",
                            frame.index,
                            layout.markers[k].name,
                            t.px.x,
                            t.px.y,
                            t.view_angle_deg,
                            t.minor_axis_px
                        );
                    }
                }
                if t.visible {
                    vis_angle[bin(t.view_angle_deg, &ANGLE_EDGES)] += 1;
                    vis_minor[bin(t.minor_axis_px, &MINOR_EDGES)] += 1;
                }
            }
            let right = labels.markers[k].as_ref().is_some_and(|m| {
                near[0][m.detections[0]] == Some(k) && near[1][m.detections[1]] == Some(k)
            });
            if detectable && !right {
                unlabeled.entry(k).or_insert((0, frame.index.as_usize())).0 += 1;
            }
            if let Some(m) = &labels.markers[k] {
                let ok = near[0][m.detections[0]] == Some(k) && near[1][m.detections[1]] == Some(k);
                if ok {
                    correct += 1;
                    correct_visible += usize::from(vis);
                    correct_detected += usize::from(vis && in_both);
                    correct_detectable += usize::from(detectable);
                    let t = truth[&frame.index.as_usize()][k];
                    sq_err += (m.bundle.point_in_cam0 - t).norm_squared();
                } else {
                    wrong += 1;
                    swaps += usize::from(
                        (0..2).any(|c| near[c][m.detections[c]].is_some_and(|j| j != k)),
                    );
                    eprintln!(
                        "frame {}: marker {} labeled (reacquired {}, {:?} {:?} {:?}) with the dots of {:?} / {:?}",
                        frame.index,
                        layout.markers[k].name,
                        m.reacquired,
                        m.bundle,
                        dets[0][m.detections[0]],
                        (gt[0][k].px - m.pixels[0]).norm(),
                        near[0][m.detections[0]].map(|j| &layout.markers[j].name),
                        near[1][m.detections[1]].map(|j| &layout.markers[j].name)
                    );
                }
            }
        }
    }
    let mut worst: Vec<_> = missed.iter().collect();
    worst.sort_by_key(|b| std::cmp::Reverse(b.1.0));
    for ((k, c), (n, near)) in worst.iter().take(10) {
        eprintln!(
            "missed {} in cam{c}: {n} frames ({near} with a blob within 5 px)",
            layout.markers[*k].name
        );
    }
    let mut worst: Vec<_> = unlabeled.iter().collect();
    worst.sort_by_key(|b| (std::cmp::Reverse(b.1.0), b.0));
    for (k, (n, first)) in worst.iter().take(10) {
        eprintln!(
            "not labeled right while detectable: {} in {n} frames (from frame {first})",
            layout.markers[**k].name
        );
    }
    let total_missed: usize = miss_angle.iter().sum();
    eprintln!(
        "detector misses of dots visible in one camera: {total_missed} ({miss_detectable} of \
         them detectable; {miss_occluded} partly occluded; {miss_border} within 10 px of the \
         border); {spurious} spurious blobs (no dot within 4 px)"
    );
    let mut reasons: Vec<_> = reasons.into_iter().collect();
    reasons.sort_by_key(|r| std::cmp::Reverse(r.1));
    for ((reason, det), n) in &reasons {
        eprintln!("  {reason}{}: {n}", if *det { " (detectable)" } else { "" });
    }
    let label = |edges: &[f64], i: usize, unit: &str| match i {
        0 => format!("< {}{unit}", edges[0]),
        i if i == edges.len() => format!(">= {}{unit}", edges[i - 1]),
        i => format!("{}-{}{unit}", edges[i - 1], edges[i]),
    };
    for i in 0..6 {
        eprintln!(
            "  view angle {:>10}: missed {:5} of {:6} visible ({:5.1} %)",
            label(&ANGLE_EDGES, i, "°"),
            miss_angle[i],
            vis_angle[i],
            100.0 * miss_angle[i] as f64 / vis_angle[i].max(1) as f64
        );
    }
    for i in 0..6 {
        eprintln!(
            "  minor axis {:>10}: missed {:5} of {:6} visible ({:5.1} %)",
            label(&MINOR_EDGES, i, " px"),
            miss_minor[i],
            vis_minor[i],
            100.0 * miss_minor[i] as f64 / vis_minor[i].max(1) as f64
        );
    }
    let rms_mm = (sq_err / correct.max(1) as f64).sqrt();
    eprintln!(
        "labeling: {correct_visible} of {visible} geometrically visible ({:.2} %) and \
         {correct_detectable} of {n_detectable} detectable ({:.2} %) marker observations \
         labeled right, {wrong} wrong ({swaps} swaps)",
        100.0 * correct_visible as f64 / visible as f64,
        100.0 * correct_detectable as f64 / n_detectable.max(1) as f64,
    );
    eprintln!(
        "labeling: {visible} marker observations visible in both cameras, {detected} of them \
         detected in both images ({:.2} %); {correct} labels right ({correct_visible} of the \
         visible: {:.2} %; {correct_detected} of the detected: {:.2} %), {wrong} wrong; \
         {reacquired} re-identified after a gap; {acquiring_frames} acquiring frames; bundle \
         RMS error {rms_mm:.3} mm",
        100.0 * detected as f64 / visible as f64,
        100.0 * correct_visible as f64 / visible as f64,
        100.0 * correct_detected as f64 / detected as f64,
    );
    assert_eq!(wrong, 0, "wrong labels");
    // The goal, on the detectability definition of the ground truth (visible, unoccluded
    // over the whole dot, inside the image, projected minor axis at least 2 px): 99.5 %.
    assert!(
        correct_detectable as f64 >= 0.995 * n_detectable as f64,
        "{correct_detectable} of {n_detectable} detectable markers labeled"
    );
    // The labeler cannot label a dot the detector did not find: 99.5 % is required of the
    // markers detected in both images.
    assert!(
        correct_detected as f64 >= 0.995 * detected as f64,
        "{correct_detected} of {detected} detected markers labeled"
    );
    // Of all geometrically visible markers (dots up to 80° from facing the camera, which
    // become slivers under 1.5 px wide at the face's edge) about 95.5 % are labeled: the
    // misses are dots whose projected minor axis is under 2 px.
    assert!(
        correct_visible as f64 >= 0.94 * visible as f64,
        "{correct_visible} of {visible} visible markers labeled"
    );
    assert!(acquiring_frames <= 3, "{acquiring_frames} acquiring frames");
    assert!(rms_mm < 0.3, "bundle RMS {rms_mm} mm");
}
