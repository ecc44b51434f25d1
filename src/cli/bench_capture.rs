//! `helmcap bench capture`: detection + tracking + triangulation throughput, and labeling
//! accuracy at centroid noise levels, on a synthetic session.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use helmcap::capture::{Replay, ReplayParams, StereoFrame};
use helmcap::dataset::MarkerLayout;
use helmcap::dataset::actor::{Actor, ActorParams};
use helmcap::synth::{AnimationParams, Performer, SynthParams, animation, default_rig};
use helmcap::track::{
    DetectParams, Detection, Labeler, SearchWindows, StereoTracker, detect_markers,
};
use nalgebra::{Point2, Point3, Quaternion, UnitQuaternion, Vector3};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

/// Arguments of `helmcap bench capture`.
#[derive(Debug, clap::Args)]
pub struct CaptureBenchArgs {
    /// A session rendered by `helmcap synth` with the built-in actor (default: render one
    /// into a temporary folder).
    #[arg(long)]
    session: Option<PathBuf>,
    /// Frames to render when no session is given.
    #[arg(long, default_value_t = 300)]
    frames: usize,
    /// Number of timed passes over the session.
    #[arg(long, default_value_t = 5)]
    runs: usize,
    /// Extra Gaussian centroid noise levels (pixels, comma-separated) for the accuracy
    /// table.
    #[arg(long, value_delimiter = ',', default_value = "0,0.25,0.5,1")]
    noise_px: Vec<f64>,
    /// Capture profile (default: the one the session names, else the built-in defaults).
    #[arg(long, value_name = "TOML")]
    profile: Option<PathBuf>,
    /// Acquisition benchmark: blobs of a dot's size added at random places to each image
    /// of 20 frames, each frame acquired from scratch (0: skip).
    #[arg(long, default_value_t = 500)]
    clutter: usize,
}

/// Runs the capture benchmark and prints the figures.
pub fn run(args: CaptureBenchArgs) -> anyhow::Result<()> {
    let actor = Actor::new(&ActorParams::default()).context("building the built-in actor")?;
    let layout = MarkerLayout::builtin_actor()?;
    let tmp;
    let session = match &args.session {
        Some(s) => s.clone(),
        None => {
            tmp = super::bench_work_dir()?;
            let rig = default_rig().context("the built-in rig")?;
            let performer = Performer::Actor(Box::new(actor.clone()));
            let names = performer.expression_names();
            let anim = AnimationParams {
                lip_press_interval_secs: 1.5,
                ..AnimationParams::default()
            };
            let weights = animation::random_curves(&names, args.frames.max(1), 60.0, &anim);
            let params = SynthParams {
                slip_mm: 1.5,
                slip_deg: 1.0,
                ..SynthParams::default()
            };
            eprintln!("rendering {} frames...", weights.len());
            helmcap::synth::render_session(
                &performer,
                &layout,
                &rig,
                &weights,
                &params,
                &tmp,
                false,
                &|| {},
            )?;
            tmp.clone()
        }
    };
    let mut replay = Replay::open(&session, ReplayParams::default())?;
    let rig = replay
        .rig()
        .context("the session has no calibration")?
        .clone();
    let profile =
        helmcap::take::load_profile(args.profile.as_deref().or(replay.info().profile.as_deref()))?;
    // Colour footage is read as `replay` reads it: the profile's conversion to grey.
    replay.set_gray_conversion(profile.gray_conversion());
    let detect_params = profile.detect_params(Some(&rig));
    let label_params = profile.label_params();
    let frames: Vec<StereoFrame> = replay.collect::<Result<_, _>>()?;
    anyhow::ensure!(!frames.is_empty(), "the session has no frames");
    let neutral: Vec<Point3<f64>> = layout
        .markers
        .iter()
        .map(|m| actor.neutral().positions[m.vertex as usize])
        .collect();
    // The skin's normal at each marker, as `replay` gives the labeler.
    let vertex_normals = helmcap::mesh::vertex_normals(actor.neutral());
    let normals: Vec<Vector3<f64>> = layout
        .markers
        .iter()
        .map(|m| vertex_normals[m.vertex as usize])
        .collect();
    let new_labeler = || {
        Labeler::new(rig.clone(), &layout, neutral.clone(), label_params.clone()).map(|mut l| {
            if !l.set_marker_normals(normals.clone()) {
                tracing::warn!("the marker normals do not fit the layout: no roundness check");
            }
            l
        })
    };

    // Throughput: detection in predicted ROIs (both cameras in parallel) + labeling and
    // triangulation.
    let mut rates = Vec::new();
    let mut cpu_ms = Vec::new();
    // Per run: each frame's time, and whether it was an acquiring frame.
    let mut frame_ms: Vec<Vec<(f64, bool)>> = Vec::new();
    let mut acquiring_ms: Vec<f64> = Vec::new();
    let mut labeled = 0;
    // Per camera and frame searched in windows: the share of the image searched.
    let mut searched: Vec<f64> = Vec::new();
    let load_before = helmcap::bench::host::load_average();
    for _ in 0..args.runs.max(1) {
        let mut tracker = StereoTracker::new(new_labeler()?, detect_params.clone());
        let cpu = helmcap::bench::host::process_cpu_seconds();
        let t = Instant::now();
        labeled = 0;
        let mut times = Vec::with_capacity(frames.len());
        for f in &frames {
            let windows = tracker.labeler().predicted_windows();
            if !windows[0].is_empty() {
                for (c, w) in windows.iter().enumerate() {
                    let (iw, ih) = (f.images[c].width as usize, f.images[c].height as usize);
                    let area = SearchWindows::new(w, (0, 0, iw, ih)).area();
                    searched.push(area as f64 / (iw * ih) as f64);
                }
            }
            let tf = Instant::now();
            let out = tracker.track(f.index, &f.images).labeled;
            labeled += out.stats.labeled;
            let ms = 1e3 * tf.elapsed().as_secs_f64();
            if out.stats.acquiring {
                acquiring_ms.push(ms);
            }
            times.push((ms, out.stats.acquiring));
        }
        frame_ms.push(times);
        rates.push(frames.len() as f64 / t.elapsed().as_secs_f64());
        if let (Some(a), Some(b)) = (cpu, helmcap::bench::host::process_cpu_seconds()) {
            cpu_ms.push(1e3 * (b - a) / frames.len() as f64);
        }
    }
    let load_after = helmcap::bench::host::load_average();
    rates.sort_by(f64::total_cmp);
    cpu_ms.sort_by(f64::total_cmp);
    let (w, h) = (rig.cam0.width_px, rig.cam0.height_px);
    println!(
        "capture {w}×{h}, {} stereo frames, median of {} runs: {:.0} stereo frames/s \
         (min {:.0}, max {:.0}); {:.1} markers labeled per frame",
        frames.len(),
        rates.len(),
        rates[rates.len() / 2],
        rates[0],
        rates[rates.len() - 1],
        labeled as f64 / frames.len() as f64
    );
    // Per-frame time of the run with the median rate.
    let mut run_means: Vec<(f64, usize)> = frame_ms
        .iter()
        .enumerate()
        .map(|(k, t)| {
            (
                t.iter().map(|f| f.0).sum::<f64>() / t.len().max(1) as f64,
                k,
            )
        })
        .collect();
    run_means.sort_by(|a, b| a.0.total_cmp(&b.0));
    if let Some(&(mean, k)) = run_means.get(run_means.len() / 2) {
        let mut t: Vec<f64> = frame_ms[k].iter().map(|f| f.0).collect();
        t.sort_by(f64::total_cmp);
        // The frames labeled by tracking alone (the stream's steady state).
        let mut tracking: Vec<f64> = frame_ms[k].iter().filter(|f| !f.1).map(|f| f.0).collect();
        tracking.sort_by(f64::total_cmp);
        let tracking_mean = tracking.iter().sum::<f64>() / tracking.len().max(1) as f64;
        acquiring_ms.sort_by(f64::total_cmp);
        println!(
            "track stage per stereo frame (detect both cameras + label): mean {mean:.2} ms, \
             p99 {:.2} ms, max {:.2} ms; tracking frames only: mean {tracking_mean:.2} ms, \
             p99 {:.2} ms; acquiring frames {} (median {:.1} ms)",
            percentile_99(&t),
            t.last().copied().unwrap_or(f64::NAN),
            percentile_99(&tracking),
            acquiring_ms.len() / args.runs.max(1),
            acquiring_ms
                .get(acquiring_ms.len() / 2)
                .copied()
                .unwrap_or(f64::NAN)
        );
    }
    if !searched.is_empty() {
        println!(
            "search windows: {:.0} % of the frames searched in windows, covering {:.1} % of the \
             image on average",
            100.0 * searched.len() as f64 / (2 * frames.len() * args.runs.max(1)) as f64,
            100.0 * searched.iter().sum::<f64>() / searched.len() as f64
        );
    }
    if let Some(m) = cpu_ms.get(cpu_ms.len() / 2) {
        println!(
            "CPU time (all threads) per stereo frame: median {m:.2} ms; 1-minute load average \
             {} before, {} after",
            load_before.as_deref().unwrap_or("?"),
            load_after.as_deref().unwrap_or("?")
        );
    }

    // Accuracy against ground truth at added centroid noise.
    let projections = read_projections(&session, &layout)?;
    let truth = read_truth_in_cam0(&session, &layout)?;
    let detections: Vec<[Vec<Detection>; 2]> = frames
        .iter()
        .map(|f| [0, 1].map(|c| detect_markers(&f.images[c], &detect_params)))
        .collect();
    if args.clutter > 0 {
        acquisition_with_clutter(
            &frames,
            &detections,
            &detect_params,
            args.clutter,
            &new_labeler,
        )?;
    }
    let f_px = rig.cam0.fx().min(rig.cam1.fx());
    let b_mm = rig.baseline_mm();
    let has_detectable = projections
        .values()
        .flatten()
        .all(|t| t.detectable.is_some());
    println!(
        "added σ px | visible | labeled right (% of visible) | detectable | labeled right (% of detectable) | swaps | off-dot | gate px (ŝ px) | bundle RMS mm | σz bound mm | RMS / bound"
    );
    let base_sigma = 0.24; // Centroid RMS error of the detector on these images (tests).
    for &sigma in &args.noise_px {
        let mut labeler = new_labeler()?;
        let mut rng = Jitter(StdRng::seed_from_u64(0x006e_6f69_7365 ^ sigma.to_bits()));
        let (mut visible, mut right, mut wrong, mut sq, mut z_sum) = (0, 0, 0, 0.0, 0.0);
        let (mut right_visible, mut detectable, mut right_detectable) = (0, 0, 0);
        let mut off_dot = 0;
        for (f, dets) in frames.iter().zip(&detections) {
            let noisy: Vec<Vec<Detection>> = dets
                .iter()
                .map(|d| {
                    d.iter()
                        .map(|x| Detection {
                            centre_px: Point2::new(
                                x.centre_px.x + sigma * rng.normal(),
                                x.centre_px.y + sigma * rng.normal(),
                            ),
                            ..*x
                        })
                        .collect()
                })
                .collect();
            let out = labeler.process(f.index, [&noisy[0], &noisy[1]]);
            let gt = [
                projections.get(&(f.index.as_usize(), 0)),
                projections.get(&(f.index.as_usize(), 1)),
            ];
            let (Some(g0), Some(g1)) = (gt[0], gt[1]) else {
                continue;
            };
            let gt = [g0, g1];
            let is_visible = |k: usize| g0[k].visible && g1[k].visible;
            let is_detectable =
                |k: usize| g0[k].detectable == Some(true) && g1[k].detectable == Some(true);
            visible += (0..layout.len()).filter(|&k| is_visible(k)).count();
            detectable += (0..layout.len()).filter(|&k| is_detectable(k)).count();
            for (k, m) in out.markers.iter().enumerate() {
                let Some(m) = m else { continue };
                let ok =
                    (0..2).all(|c| owner(gt[c], &dets[c][m.detections[c]].centre_px) == Some(k));
                if ok {
                    right += 1;
                    right_visible += usize::from(is_visible(k));
                    right_detectable += usize::from(is_detectable(k));
                    if let Some(t) = truth.get(&f.index.as_usize()) {
                        sq += (m.bundle.point_in_cam0 - t[k]).norm_squared();
                        z_sum += t[k].z;
                    }
                } else {
                    // A swap when a detection used is another marker's dot; otherwise a
                    // blob more than 4 px from any dot (a displaced or spurious blob).
                    let swap = (0..2).any(|c| {
                        owner(gt[c], &dets[c][m.detections[c]].centre_px).is_some_and(|j| j != k)
                    });
                    if swap {
                        wrong += 1;
                    } else {
                        off_dot += 1;
                    }
                }
            }
        }
        let rms = (sq / right.max(1) as f64).sqrt();
        let z = z_sum / right.max(1) as f64;
        let s_px = (base_sigma * base_sigma + sigma * sigma).sqrt();
        let bound = z * z * s_px / (f_px * b_mm);
        let (gate, gate_sigma) = labeler.epipolar_gate();
        let detectable_cols = if has_detectable {
            format!(
                "{detectable:10} | {right_detectable:7} ({:6.2} %)               ",
                100.0 * right_detectable as f64 / detectable.max(1) as f64
            )
        } else {
            format!("{:>10} | {:>33}", "-", "-")
        };
        println!(
            "{sigma:10.2} | {visible:7} | {right_visible:7} ({:5.2} %)             | {detectable_cols} | {wrong:5} | {off_dot:7} | {gate:5.2} ({}) | {rms:13.3} | {bound:11.3} | {:.2}",
            100.0 * right_visible as f64 / visible.max(1) as f64,
            gate_sigma.map_or("-".to_string(), |s| format!("{s:.3}")),
            rms / bound
        );
    }
    println!(
        "(σz = z²·σpx/(f·b) with z the mean marker depth, f = {f_px:.1} px, b = {b_mm:.1} mm, \
         σpx = √({base_sigma}² + added²) per coordinate; RMS is the full 3D error over every \
         right label; swaps: a detection used is another marker's dot; off-dot: a detection used \
         is more than 4 px from every dot (a partly hidden dot's displaced blob); detectable: ground truth's `detectable` column, \
         visible and unoccluded over the whole dot with a projected minor axis of at least \
         2 px; gate: the epipolar gate at the end, with ŝ the robust scale of the residuals)"
    );
    if args.session.is_none() {
        let _ = std::fs::remove_dir_all(&session);
    }
    Ok(())
}

/// Acquisition with `clutter` blobs of a dot's size added at random places to each image:
/// (1) from scratch on 20 frames, the time of each attempt and how many markers it labels;
/// (2) on consecutive frames from the first, each with fresh clutter, as a take that starts
/// on a cluttered face: the frames until the search acquires, and the slowest frame of the
/// search (the search runs on a budget of samples per frame and never holds the stream).
fn acquisition_with_clutter(
    frames: &[StereoFrame],
    detections: &[[Vec<Detection>; 2]],
    params: &DetectParams,
    clutter: usize,
    new_labeler: &dyn Fn() -> Result<Labeler, helmcap::track::LabelError>,
) -> anyhow::Result<()> {
    let mut rng = StdRng::seed_from_u64(0x00c1_0773);
    let mut cluttered = |f: &StereoFrame, dets: &[Vec<Detection>; 2]| -> Vec<Vec<Detection>> {
        (0..2)
            .map(|c| {
                let (w, h) = (f.images[c].width as f64, f.images[c].height as f64);
                let mut d = dets[c].clone();
                for _ in 0..clutter {
                    let diameter = rng
                        .random_range(params.min_dot_px..=params.max_dot_px.max(params.min_dot_px));
                    d.push(Detection {
                        centre_px: Point2::new(rng.random_range(0.0..w), rng.random_range(0.0..h)),
                        area_px: (0.785 * diameter * diameter) as usize,
                        roundness: rng.random_range(0.5..1.0),
                        contrast_dn: rng.random_range(20.0..120.0),
                        quality: rng.random_range(0.2..0.8),
                        diameter_px: diameter,
                        axis_rad: rng.random_range(-1.5..1.5),
                        streak: false,
                    });
                }
                d
            })
            .collect()
    };
    let step = (frames.len() / 20).max(1);
    let mut times = Vec::new();
    let mut labeled = Vec::new();
    for (f, dets) in frames.iter().zip(detections).step_by(step).take(20) {
        let noisy = cluttered(f, dets);
        let mut labeler = new_labeler()?;
        let t = Instant::now();
        let out = labeler.process(f.index, [&noisy[0], &noisy[1]]);
        times.push(1e3 * t.elapsed().as_secs_f64());
        labeled.push(out.stats.labeled);
    }
    times.sort_by(f64::total_cmp);
    let acquired = labeled.iter().filter(|&&n| n > 0).count();
    println!(
        "acquisition with {clutter} clutter blobs per image added ({} frames, each from scratch): \
         median {:.1} ms, max {:.1} ms per attempt; {acquired} acquired on the first attempt, \
         {:.1} markers labeled on average",
        times.len(),
        times.get(times.len() / 2).copied().unwrap_or(f64::NAN),
        times.last().copied().unwrap_or(f64::NAN),
        labeled.iter().sum::<usize>() as f64 / labeled.len().max(1) as f64
    );
    // A take that starts on the cluttered face.
    let mut labeler = new_labeler()?;
    let mut search_ms: Vec<f64> = Vec::new();
    let mut acquired_at = None;
    for (k, (f, dets)) in frames.iter().zip(detections).enumerate() {
        let noisy = cluttered(f, dets);
        let t = Instant::now();
        let out = labeler.process(f.index, [&noisy[0], &noisy[1]]);
        search_ms.push(1e3 * t.elapsed().as_secs_f64());
        if out.stats.labeled > 0 {
            acquired_at = Some((k, out.stats.labeled));
            break;
        }
    }
    search_ms.sort_by(f64::total_cmp);
    let median = search_ms[search_ms.len() / 2];
    let slowest = search_ms[search_ms.len() - 1];
    match acquired_at {
        Some((k, n)) => println!(
            "acquisition with {clutter} clutter blobs per image on consecutive frames: acquired on \
             frame {} of the take ({n} markers labeled); per frame of the search median \
             {median:.1} ms, max {slowest:.1} ms",
            k + 1
        ),
        None => println!(
            "acquisition with {clutter} clutter blobs per image on consecutive frames: not acquired \
             in {} frames; per frame of the search median {median:.1} ms, max {slowest:.1} ms",
            search_ms.len()
        ),
    }
    Ok(())
}

/// The marker whose true projection is nearest `px`, within 4 px.
fn owner(gt: &[Truth2d], px: &Point2<f64>) -> Option<usize> {
    gt.iter()
        .enumerate()
        .map(|(k, t)| (k, (t.px - px).norm()))
        .filter(|(_, d)| *d < 4.0)
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .map(|(k, _)| k)
}

/// Ground truth of one marker in one camera: true pixel, visible (geometric), and
/// detectable (None for sessions written before the `detectable` column).
#[derive(Debug, Clone, Copy)]
struct Truth2d {
    px: Point2<f64>,
    visible: bool,
    detectable: Option<bool>,
}

type Projections = HashMap<(usize, usize), Vec<Truth2d>>;

fn read_projections(dir: &Path, layout: &MarkerLayout) -> anyhow::Result<Projections> {
    let path = dir.join("gt/projections.csv");
    let text =
        std::fs::read_to_string(&path).with_context(|| format!("reading {}", path.display()))?;
    let mut out: Projections = HashMap::new();
    for (n, line) in text.lines().enumerate().skip(1) {
        let bad = || anyhow::anyhow!("{}:{}: malformed row", path.display(), n + 1);
        let f: Vec<&str> = line.split(',').collect();
        if f.len() < 6 {
            return Err(bad());
        }
        let cam = usize::from(f[1] == "cam1");
        let frame: usize = f[0].parse().map_err(|_| bad())?;
        let k = layout.index_of(f[2]).ok_or_else(bad)?;
        let entry = out.entry((frame, cam)).or_insert_with(|| {
            vec![
                Truth2d {
                    px: Point2::origin(),
                    visible: false,
                    detectable: Some(false),
                };
                layout.len()
            ]
        });
        entry[k] = Truth2d {
            px: Point2::new(
                f[3].parse().map_err(|_| bad())?,
                f[4].parse().map_err(|_| bad())?,
            ),
            visible: f[5] == "1",
            detectable: f.get(9).map(|v| *v == "1"),
        };
    }
    Ok(out)
}

fn read_truth_in_cam0(
    dir: &Path,
    layout: &MarkerLayout,
) -> anyhow::Result<HashMap<usize, Vec<Point3<f64>>>> {
    let path = dir.join("gt/head_pose.csv");
    let poses =
        std::fs::read_to_string(&path).with_context(|| format!("reading {}", path.display()))?;
    let mut pose = HashMap::new();
    for (n, line) in poses.lines().enumerate().skip(1) {
        let v: Vec<f64> = line
            .split(',')
            .map(str::parse)
            .collect::<Result<_, _>>()
            .with_context(|| format!("{}:{}", path.display(), n + 1))?;
        anyhow::ensure!(v.len() >= 8, "{}:{}: malformed row", path.display(), n + 1);
        let q = UnitQuaternion::from_quaternion(Quaternion::new(v[1], v[2], v[3], v[4]));
        pose.insert(v[0] as usize, (q, Vector3::new(v[5], v[6], v[7])));
    }
    let path = dir.join("gt/bundles.csv");
    let bundles =
        std::fs::read_to_string(&path).with_context(|| format!("reading {}", path.display()))?;
    let mut out: HashMap<usize, Vec<Point3<f64>>> = HashMap::new();
    for (n, line) in bundles.lines().enumerate().skip(1) {
        let bad = || anyhow::anyhow!("{}:{}: malformed row", path.display(), n + 1);
        let f: Vec<&str> = line.split(',').collect();
        if f.len() < 5 {
            return Err(bad());
        }
        let frame: usize = f[0].parse().map_err(|_| bad())?;
        let k = layout.index_of(f[1]).ok_or_else(bad)?;
        let p = Point3::new(
            f[2].parse().map_err(|_| bad())?,
            f[3].parse().map_err(|_| bad())?,
            f[4].parse().map_err(|_| bad())?,
        );
        let (q, t) = pose.get(&frame).ok_or_else(bad)?;
        out.entry(frame)
            .or_insert_with(|| vec![Point3::origin(); layout.len()])[k] = q * p + t;
    }
    Ok(out)
}

/// Seeded Gaussian jitter (Box-Muller).
struct Jitter(StdRng);

impl Jitter {
    fn normal(&mut self) -> f64 {
        helmcap::numeric::standard_normal(&mut self.0)
    }
}

/// The 99th percentile of sorted values (the value at rank ⌈0.99·n⌉), NaN when empty.
fn percentile_99(sorted: &[f64]) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    let rank = ((sorted.len() as f64 * 0.99).ceil() as usize).clamp(1, sorted.len());
    sorted[rank - 1]
}
