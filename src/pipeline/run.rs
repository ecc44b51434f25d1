//! [`run`]: builds the stage threads and channels, runs a take, returns its metrics.

use std::sync::atomic::{AtomicBool, AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::Instant;

use crossbeam_channel::{Receiver, Sender, TrySendError, bounded};
use nalgebra::Point3;

use super::PipelineError;
use super::config::{
    ChannelConfig, GAP_FILL_MEMORY_HALF_LIVES, PipelineConfig, SolveConfig, TakeInfo, TrackConfig,
};
use super::frame::{BundleStatus, FrameResult, LabelCounts, MarkerResult, Stage};
use super::metrics::{Metrics, MetricsCollector};
use super::priority::{lower_this_thread, replay_nice_step};
use super::sink::{SessionMeta, Sink};
use super::truth::GroundTruth;
use crate::align::{PoseSource, Stabilizer};
use crate::bundles::FrameBundles;
use crate::capture::{CaptureError, FrameSource};
use crate::dataset::MarkerLayout;
use crate::frame_index::FrameIndex;
use crate::solve::Solver;
use crate::track::{Labeler, StereoTracker, TrackedFrame};

/// Counters the source thread shares with the sink thread.
#[derive(Debug, Default)]
struct SourceCounters {
    frames_in: AtomicU64,
    dropped: AtomicU64,
    gaps: AtomicUsize,
}

/// The first error of the take, shared so the sink thread can record why it stopped.
type ErrorSlot = Arc<Mutex<Option<PipelineError>>>;

fn record(slot: &ErrorSlot, e: PipelineError) -> PipelineError {
    if let Ok(mut s) = slot.lock()
        && s.is_none()
    {
        *s = Some(e.clone());
    }
    e
}

fn stage_err(stage: Stage, frame: Option<FrameIndex>, message: impl Into<String>) -> PipelineError {
    PipelineError::Stage {
        stage,
        frame,
        message: message.into(),
    }
}

/// Starts the thread of `stage`, `nice_step` nice levels below the process's priority
/// (see [`super::priority`]).
fn spawn<T: Send + 'static>(
    stage: Stage,
    nice_step: i32,
    f: impl FnOnce() -> Result<T, PipelineError> + Send + 'static,
) -> Result<JoinHandle<Result<T, PipelineError>>, PipelineError> {
    std::thread::Builder::new()
        .name(format!("helmcap:{}", stage.name()))
        .spawn(move || {
            if let Err(e) = lower_this_thread(nice_step) {
                tracing::debug!("helmcap:{} keeps its priority: {e}", stage.name());
            }
            f()
        })
        .map_err(|e| {
            PipelineError::Thread(format!("helmcap:{} could not start: {e}", stage.name()))
        })
}

/// Starts the thread of a middle stage: the one loop every stage between the source and
/// the sinks runs (receive a frame, time the work, record a failure, send the frame on).
///
/// `work` does the stage's job on one frame and says whether it ran (a stage with nothing
/// to do on a frame, such as the solve without a solver, leaves its time unset). A
/// failure is recorded as the take's error (the first one wins, see [`record`]) and ends
/// the stage, which closes its output and so lets the later stages drain and stop. The
/// stage also ends when its input closes (the source is done) or the next stage is gone.
///
/// # Errors
/// [`PipelineError::Thread`] when the thread cannot start.
fn spawn_stage(
    stage: Stage,
    nice_step: i32,
    input: Receiver<Box<FrameResult>>,
    output: Sender<Box<FrameResult>>,
    errors: &ErrorSlot,
    mut work: impl FnMut(&mut FrameResult) -> Result<bool, PipelineError> + Send + 'static,
) -> Result<(Stage, JoinHandle<Result<(), PipelineError>>), PipelineError> {
    let errors = errors.clone();
    let handle = spawn(stage, nice_step, move || {
        for mut f in input {
            let t = Instant::now();
            if work(&mut f).map_err(|e| record(&errors, e))? {
                f.timings.set(stage, ms_since(t));
            }
            if output.send(f).is_err() {
                break;
            }
        }
        Ok(())
    })?;
    Ok((stage, handle))
}

fn ms_since(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}

/// The frame a capture error names, if any.
fn capture_error_frame(e: &CaptureError) -> Option<FrameIndex> {
    match e {
        CaptureError::Decode { frame, .. }
        | CaptureError::Size { frame, .. }
        | CaptureError::MissingImage { frame, .. } => Some(*frame),
        _ => None,
    }
}

/// Runs a take: frames from `source` through every stage into `sinks`, until the source
/// ends, `stop` is set (Ctrl-C), or a stage fails (see the module docs for ordering and
/// shutdown). Sinks get [`Sink::finish`] in every case.
///
/// # Errors
/// [`PipelineError::Config`] before anything runs (the layout and neutral positions
/// disagree, a stage cannot be built, a sink's `begin` fails); otherwise the first stage
/// or sink error, naming the stage and frame (the metrics of the frames that went through
/// are still passed to every sink's `finish`).
pub fn run(
    mut source: Box<dyn FrameSource>,
    config: PipelineConfig,
    mut sinks: Vec<Box<dyn Sink>>,
    stop: Arc<AtomicBool>,
) -> Result<Metrics, PipelineError> {
    let PipelineConfig {
        layout,
        neutral_markers_head,
        rig,
        track:
            TrackConfig {
                detect,
                label,
                expression_templates,
                marker_normals,
                label_restarts,
            },
        stabilize,
        solve:
            SolveConfig {
                solver,
                neutral,
                face_vertices,
                keyframe_interval: solve_keyframe_interval,
                gap_fill_half_life_frames,
            },
        enhancer,
        rig_solver,
        ground_truth,
        channels:
            ChannelConfig {
                capacity: channel_capacity,
                live_entry_capacity,
                replay_entry_capacity,
            },
        take:
            TakeInfo {
                name,
                timecode_rate,
                first_frame,
                frame_count,
                write_from,
            },
    } = config;
    let config_err = PipelineError::Config;
    detect
        .validate()
        .map_err(|e| config_err(format!("detection: {e}")))?;
    if neutral_markers_head.len() != layout.len() {
        return Err(config_err(format!(
            "{} neutral marker positions for {} layout markers",
            neutral_markers_head.len(),
            layout.len()
        )));
    }
    if let (Some(mesh), Some(_)) = (&neutral, &solver)
        && let Some(m) = layout
            .markers
            .iter()
            .find(|m| m.vertex as usize >= mesh.vertex_count())
    {
        return Err(config_err(format!(
            "marker {} is on vertex {}, the neutral mesh has {}",
            m.name,
            m.vertex,
            mesh.vertex_count()
        )));
    }
    let mut labeler = Labeler::new(rig.clone(), &layout, neutral_markers_head.to_vec(), label)
        .map_err(|e| config_err(e.to_string()))?;
    if !marker_normals.is_empty() && !labeler.set_marker_normals(marker_normals.to_vec()) {
        tracing::warn!("the marker normals do not fit the layout: no roundness check");
    }
    let left_out = labeler.set_expression_templates(expression_templates.to_vec());
    if left_out > 0 {
        tracing::warn!("{left_out} expression templates do not fit the layout: left out");
    }
    let stabilizer = Stabilizer::new(&layout, neutral_markers_head.to_vec(), stabilize)
        .map_err(|e| config_err(e.to_string()))?;
    if channel_capacity > crate::limits::MAX_QUEUE_FRAMES {
        return Err(config_err(format!(
            "a channel capacity of {channel_capacity} frames is above the limit of {}",
            crate::limits::MAX_QUEUE_FRAMES
        )));
    }
    let capacity = channel_capacity.max(1);
    let fps = source.fps();
    let live = source.is_live();
    // A replay runs its stages behind the track stage; a live take all alike.
    let nice_step = |stage: Stage| if live { 0 } else { replay_nice_step(stage) };
    // The shared thread pool, which detects in the track stage's place, starts here if
    // it has not yet: its workers take the nice level of the thread that starts them,
    // which must not be a stage running behind the track stage.
    rayon::current_num_threads();
    let meta = SessionMeta {
        name,
        fps,
        timecode_rate,
        first_frame,
        frame_count,
        layout: layout.clone(),
        neutral_markers_head: neutral_markers_head.clone(),
        neutral: if solver.is_some() {
            neutral.clone()
        } else {
            None
        },
        face_vertices: face_vertices.clone(),
        rig: Some(rig.clone()),
        image_size: Some((rig.cam0.width_px, rig.cam0.height_px)),
    };
    let solves = solver.is_some();
    let errors: ErrorSlot = Arc::new(Mutex::new(None));
    let counters = Arc::new(SourceCounters::default());

    // Sinks begin before any thread starts: a sink that cannot start stops the take.
    for s in &mut sinks {
        s.begin(&meta).map_err(|e| PipelineError::Sink {
            sink: s.name().to_string(),
            frame: None,
            message: e.to_string(),
        })?;
    }
    let started = Instant::now();

    let entry_capacity = if live {
        live_entry_capacity.clamp(1, capacity)
    } else {
        replay_entry_capacity.clamp(capacity, crate::limits::MAX_QUEUE_FRAMES.max(capacity))
    };
    let (to_track, track_in) = bounded::<Box<FrameResult>>(entry_capacity);
    let (to_stabilize, stabilize_in) = bounded::<Box<FrameResult>>(capacity);
    let (to_solve, solve_in) = bounded::<Box<FrameResult>>(capacity);
    let marker_count = layout.len();

    let mut handles: Vec<(Stage, JoinHandle<Result<(), PipelineError>>)> = Vec::new();
    // Starts every stage before the sinks; the channel into the sinks when all started.
    let spawned = (|| -> Result<Receiver<Box<FrameResult>>, PipelineError> {
        // Source.
        {
            let stop = stop.clone();
            let counters = counters.clone();
            let errors = errors.clone();
            handles.push((
                Stage::Source,
                spawn(Stage::Source, nice_step(Stage::Source), move || {
                    source_stage(
                        source.as_mut(),
                        live,
                        marker_count,
                        &to_track,
                        &stop,
                        &counters,
                    )
                    .map_err(|e| record(&errors, e))
                })?,
            ));
        }
        // Track.
        let fresh = label_restarts.map(|_| labeler.clone());
        let mut tracker = StereoTracker::new(labeler, detect);
        handles.push(spawn_stage(
            Stage::Track,
            nice_step(Stage::Track),
            track_in,
            to_stabilize,
            &errors,
            move |f| {
                if let (Some(r), Some(fresh)) = (label_restarts, &fresh)
                    && r.restarts_at(f.index)
                {
                    tracker.restart(fresh.clone());
                }
                track_frame(f, &mut tracker);
                Ok(true)
            },
        )?);
        // Stabilize.
        let truth = ground_truth.clone();
        let mut stabilizer = stabilizer;
        handles.push(spawn_stage(
            Stage::Stabilize,
            nice_step(Stage::Stabilize),
            stabilize_in,
            to_solve,
            &errors,
            move |f| {
                stabilize_frame(f, &mut stabilizer, truth.as_deref());
                Ok(true)
            },
        )?);
        // Solve (also gap-fills markers from the solved surface).
        let truth = if enhancer.is_none() {
            ground_truth.clone()
        } else {
            None
        };
        let solve_layout = layout.clone();
        let mut solver = solver;
        let mut last_seen: Vec<Option<FrameIndex>> = vec![None; layout.len()];
        let (solve_out, mut tail) = bounded::<Box<FrameResult>>(capacity);
        handles.push(spawn_stage(
            Stage::Solve,
            nice_step(Stage::Solve),
            solve_in,
            solve_out,
            &errors,
            move |f| {
                let Some(s) = solver.as_mut() else {
                    return Ok(false);
                };
                if solve_keyframe_interval > 0
                    && f.index.get().is_multiple_of(solve_keyframe_interval as u64)
                {
                    s.reset();
                }
                solve_frame(
                    f,
                    s,
                    &solve_layout,
                    &mut last_seen,
                    gap_fill_half_life_frames,
                    truth.as_deref(),
                )?;
                Ok(true)
            },
        )?);
        // Enhance.
        if let Some(enhancer) = enhancer {
            let truth = ground_truth.clone();
            let (enhance_out, next) = bounded::<Box<FrameResult>>(capacity);
            handles.push(spawn_stage(
                Stage::Enhance,
                nice_step(Stage::Enhance),
                std::mem::replace(&mut tail, next),
                enhance_out,
                &errors,
                move |f| {
                    if let Some(mesh) = &f.mesh {
                        let detailed = enhancer
                            .enhance(mesh)
                            .map_err(|e| stage_err(Stage::Enhance, Some(f.index), e.to_string()))?;
                        if let Some(truth) = &truth {
                            f.mesh_error_mm = truth.mesh_error_mm(f.index, &detailed).map(Arc::new);
                        }
                        f.mesh = Some(Arc::new(detailed));
                        f.enhanced = true;
                    }
                    Ok(true)
                },
            )?);
        }
        // Rig weights.
        if let Some(mut rig_solver) = rig_solver {
            let (rig_out, next) = bounded::<Box<FrameResult>>(capacity);
            handles.push(spawn_stage(
                Stage::Rig,
                nice_step(Stage::Rig),
                std::mem::replace(&mut tail, next),
                rig_out,
                &errors,
                move |f| {
                    let Some(mesh) = &f.mesh else {
                        return Ok(false);
                    };
                    let fit = rig_solver
                        .solve(mesh)
                        .map_err(|e| stage_err(Stage::Rig, Some(f.index), e.to_string()))?;
                    f.rig_fit = Some(Arc::new(fit));
                    Ok(true)
                },
            )?);
        }
        Ok(tail)
    })();

    // Sinks run on their own thread too, so a slow sink shows as its own latency.
    let sink_result = match spawned {
        Err(e) => {
            stop.store(true, Ordering::SeqCst);
            Err(e)
        }
        Ok(sinks_in) => {
            let errors = errors.clone();
            let counters = counters.clone();
            let stop = stop.clone();
            let handle = spawn(Stage::Sinks, nice_step(Stage::Sinks), move || {
                let r = sink_stage(
                    &mut sinks,
                    &sinks_in,
                    &counters,
                    &errors,
                    &stop,
                    started,
                    marker_count,
                    fps,
                    solves,
                    face_vertices.as_ref(),
                    write_from,
                );
                drop(sinks_in);
                r
            });
            match handle {
                Ok(h) => h.join().unwrap_or_else(|_| {
                    Err(PipelineError::Thread("helmcap:sinks panicked".into()))
                }),
                Err(e) => Err(e),
            }
        }
    };
    // Join the stages in order; the first error in pipeline order wins, else the sinks'.
    let mut first_error = None;
    for (stage, h) in handles {
        let r = h
            .join()
            .unwrap_or_else(|_| Err(PipelineError::Thread(format!("helmcap:{stage} panicked"))));
        if let Err(e) = r
            && first_error.is_none()
        {
            first_error = Some(e);
        }
    }
    let recorded = errors.lock().ok().and_then(|s| s.clone());
    match (recorded.or(first_error), sink_result) {
        (Some(e), _) => Err(e),
        (None, r) => r,
    }
}

/// The source stage: frames from the source into the first channel.
fn source_stage(
    source: &mut dyn FrameSource,
    live: bool,
    marker_count: usize,
    out: &Sender<Box<FrameResult>>,
    stop: &AtomicBool,
    counters: &SourceCounters,
) -> Result<(), PipelineError> {
    let mut next_index = FrameIndex::new(0);
    loop {
        if stop.load(Ordering::SeqCst) {
            return Ok(());
        }
        let t = Instant::now();
        let Some(item) = source.next_frame() else {
            counters.gaps.store(source.gaps(), Ordering::SeqCst);
            return Ok(());
        };
        counters.gaps.store(source.gaps(), Ordering::SeqCst);
        let frame = item.map_err(|e| {
            stage_err(
                Stage::Source,
                capture_error_frame(&e).or(Some(next_index)),
                e.to_string(),
            )
        })?;
        next_index = frame.index.after(1);
        counters.frames_in.fetch_add(1, Ordering::SeqCst);
        let mut f = Box::new(FrameResult::new(
            frame.index,
            frame.timestamp_ns,
            frame.timecode,
            frame.images,
            marker_count,
        ));
        f.timings.set(Stage::Source, ms_since(t));
        if live {
            match out.try_send(f) {
                Ok(()) => {}
                Err(TrySendError::Full(f)) => {
                    counters.dropped.fetch_add(1, Ordering::SeqCst);
                    tracing::trace!("frame {} dropped at the source: pipeline full", f.index);
                }
                Err(TrySendError::Disconnected(_)) => return Ok(()),
            }
        } else if out.send(f).is_err() {
            return Ok(());
        }
    }
}

/// Detection in both cameras (in parallel, where the labeler expects its markers) and
/// labeling.
fn track_frame(f: &mut FrameResult, tracker: &mut StereoTracker) {
    let images = f.images.clone();
    let TrackedFrame {
        labeled,
        detections,
    } = tracker.track(f.index, &images);
    for (r, m) in f.markers.iter_mut().zip(&labeled.markers) {
        if let Some(m) = m {
            *r = MarkerResult {
                status: BundleStatus::Observed,
                point_in_cam0: Some(m.bundle.point_in_cam0),
                point_in_head: None,
                pixels: Some(m.pixels),
                confidence: m.bundle.confidence,
                reprojection_px: m.bundle.reprojection_px,
                reacquired: m.reacquired,
            };
        }
    }
    let s = &labeled.stats;
    f.label_counts = LabelCounts {
        detections: s.detections,
        labeled: s.labeled,
        reacquired: s.reacquired,
        rejected: s.rejected,
        acquiring: s.acquiring,
    };
    f.detections = detections;
}

/// Head pose and head-frame bundles; bundle accuracy against ground truth.
fn stabilize_frame(f: &mut FrameResult, stabilizer: &mut Stabilizer, truth: Option<&GroundTruth>) {
    let observed: Vec<Option<(Point3<f64>, f64)>> = f
        .markers
        .iter()
        .map(|m| match (m.status, m.point_in_cam0) {
            (BundleStatus::Observed, Some(p)) => Some((p, m.confidence)),
            _ => None,
        })
        .collect();
    let s = stabilizer.process(&observed);
    f.cam0_from_head = s.cam0_from_head;
    f.pose_source = s.pose_source;
    for (i, m) in f.markers.iter_mut().enumerate() {
        if m.status != BundleStatus::Observed {
            continue;
        }
        match s.bundles_in_head.get(i).copied().flatten() {
            Some(h) => m.point_in_head = Some(h),
            None => {
                // Observed but implausible, or no pose to carry it into the head frame.
                m.status = BundleStatus::Dropped;
                m.confidence = 0.0;
            }
        }
    }
    if f.pose_source == PoseSource::Missing {
        tracing::trace!("frame {}: no head pose", f.index);
    }
    if let Some(truth) = truth {
        f.bundle_error_rms_mm = truth.bundle_rms_mm(f.index, &s.bundles_in_head);
    }
}

/// Dense solve from the observed head-frame bundles, gap filling of the other markers
/// from the solved surface, and mesh accuracy against ground truth.
fn solve_frame(
    f: &mut FrameResult,
    solver: &mut Solver,
    layout: &MarkerLayout,
    last_seen: &mut [Option<FrameIndex>],
    half_life_frames: f64,
    truth: Option<&GroundTruth>,
) -> Result<(), PipelineError> {
    let positions: Vec<Option<Point3<f64>>> = f
        .markers
        .iter()
        .map(|m| match m.status {
            BundleStatus::Observed => m.point_in_head,
            _ => None,
        })
        .collect();
    for (seen, p) in last_seen.iter_mut().zip(&positions) {
        if p.is_some() {
            *seen = Some(f.index);
        }
    }
    if positions.iter().all(Option::is_none) {
        tracing::trace!("frame {}: no bundle to solve", f.index);
        return Ok(());
    }
    let bundles = FrameBundles {
        frame: f.index,
        positions,
    };
    let mesh = solver
        .solve(&bundles)
        .map_err(|e| stage_err(Stage::Solve, Some(f.index), e.to_string()))?;
    for ((m, marker), seen) in f
        .markers
        .iter_mut()
        .zip(&layout.markers)
        .zip(last_seen.iter())
    {
        if m.status == BundleStatus::Missing
            && let Some(p) = mesh.get(marker.vertex as usize)
        {
            m.status = BundleStatus::GapFilled;
            m.point_in_head = Some(*p);
            // Beyond GAP_FILL_MEMORY_HALF_LIVES half-lives a fill carries no confidence:
            // the confidence then depends on a bounded stretch of the take, so a chunk
            // warmed up that long writes the single pass's values.
            m.confidence = match seen {
                Some(s)
                    if f.index.since(*s).unwrap_or(0) as f64
                        <= GAP_FILL_MEMORY_HALF_LIVES * half_life_frames =>
                {
                    0.5f64.powf(f.index.since(*s).unwrap_or(0) as f64 / half_life_frames)
                }
                _ => 0.0,
            };
        }
    }
    if let Some(truth) = truth {
        f.mesh_error_mm = truth.mesh_error_mm(f.index, &mesh).map(Arc::new);
    }
    f.mesh = Some(Arc::new(mesh));
    Ok(())
}

/// The sink stage: every finished frame to every sink, metrics, and `finish` at the end.
#[allow(clippy::too_many_arguments)]
fn sink_stage(
    sinks: &mut [Box<dyn Sink>],
    input: &Receiver<Box<FrameResult>>,
    counters: &SourceCounters,
    errors: &ErrorSlot,
    stop: &AtomicBool,
    started: Instant,
    marker_count: usize,
    fps: f64,
    solves: bool,
    face_vertices: Option<&std::ops::RangeInclusive<u32>>,
    write_from: FrameIndex,
) -> Result<Metrics, PipelineError> {
    let mut collector = MetricsCollector::new(marker_count, fps, solves);
    let mut failure: Option<PipelineError> = None;
    let mut warm_up = 0u64;
    for mut f in input.iter() {
        if f.index < write_from {
            warm_up += 1;
            continue;
        }
        let t = Instant::now();
        for s in sinks.iter_mut() {
            if let Err(e) = s.write(&f) {
                failure = Some(PipelineError::Sink {
                    sink: s.name().to_string(),
                    frame: Some(f.index),
                    message: e.to_string(),
                });
                break;
            }
        }
        if let Some(e) = &failure {
            record(errors, e.clone());
            stop.store(true, Ordering::SeqCst);
            break;
        }
        f.timings.set(Stage::Sinks, ms_since(t));
        collector.frame_out(&f, ms_since(f.received_at), face_vertices);
    }
    collector.set_source_counts(
        counters
            .frames_in
            .load(Ordering::SeqCst)
            .saturating_sub(warm_up),
        counters.dropped.load(Ordering::SeqCst),
        counters.gaps.load(Ordering::SeqCst),
    );
    collector.set_warm_up_frames(warm_up);
    // An upstream error is recorded before that stage's channel disconnects.
    let upstream = errors.lock().ok().and_then(|s| s.clone());
    if let Some(e) = upstream.as_ref().or(failure.as_ref()) {
        collector.stopped(e.to_string());
    } else if stop.load(Ordering::SeqCst) {
        collector.stopped("interrupted".into());
    }
    let metrics = collector.snapshot(started.elapsed().as_secs_f64());
    let mut finish_error = None;
    for s in sinks.iter_mut() {
        if let Err(e) = s.finish(&metrics) {
            tracing::error!("sink {}: {e}", s.name());
            finish_error.get_or_insert(PipelineError::Sink {
                sink: s.name().to_string(),
                frame: None,
                message: e.to_string(),
            });
        }
    }
    match failure.or(finish_error) {
        Some(e) => Err(e),
        None => Ok(metrics),
    }
}
