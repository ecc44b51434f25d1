//! `helmcap bench pipeline`: replay throughput, live-paced latency and a memory soak of
//! the streaming pipeline on a synthetic 1280×1024, 60 fps session of the built-in actor
//! (detection → labeling → stabilization → LGI, no enhancement; CSV and metrics sinks),
//! the take assembled by the library's `TakeSpec` with the capture defaults.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::AtomicBool;
use std::time::Instant;

use anyhow::Context;
use helmcap::capture::{FrameSource, Replay, ReplayParams};
use helmcap::dataset::{DatasetSpec, MarkerLayout};
use helmcap::numeric::upper_median;
use helmcap::pipeline::sources::{LoopSource, PacedSource};
use helmcap::pipeline::{FrameResult, Metrics, PipelineConfig, SessionMeta, Sink, SinkError};
use helmcap::synth::{
    AnimationParams, Performer, SynthParams, animation, default_rig, render_session,
};
use helmcap::take::{TakeSpec, file_sinks};

/// Arguments of `helmcap bench pipeline`.
#[derive(Debug, clap::Args)]
pub struct PipelineBenchArgs {
    /// Frames of the synthetic session (600 = 10 s: the first second's start-up, face
    /// acquisition included, is 10 % of the latency run, as in a short take).
    #[arg(long, default_value_t = 600)]
    pub frames: usize,
    /// Timed runs of the throughput and latency measurements (the median is reported).
    #[arg(long, default_value_t = 3)]
    pub runs: usize,
    /// Frames of the memory soak (the session's first frames looped from memory; 0: no
    /// soak).
    #[arg(long, default_value_t = 10_000)]
    pub soak_frames: usize,
    /// Frames kept in memory and looped by the soak.
    #[arg(long, default_value_t = 20)]
    pub soak_loop: usize,
    /// Working folder (default: a temporary folder, removed at the end).
    #[arg(long, value_name = "DIR")]
    pub work: Option<PathBuf>,
}

/// Records each frame's latency as it reaches the sinks (ms since the source delivered it)
/// and its stage times, to show where the slowest frames spent their time.
struct LatencyProbe {
    frames: Arc<std::sync::Mutex<Vec<(usize, f64, helmcap::pipeline::StageTimings)>>>,
}

impl Sink for LatencyProbe {
    fn name(&self) -> &str {
        "latency-probe"
    }
    fn begin(&mut self, _session: &SessionMeta) -> Result<(), SinkError> {
        Ok(())
    }
    fn write(&mut self, frame: &FrameResult) -> Result<(), SinkError> {
        let ms = frame.received_at.elapsed().as_secs_f64() * 1e3;
        if let Ok(mut f) = self.frames.lock() {
            f.push((frame.index.as_usize(), ms, frame.timings));
        }
        Ok(())
    }
    fn finish(&mut self, _metrics: &Metrics) -> Result<(), SinkError> {
        Ok(())
    }
}

/// The `k` slowest frames of a probe: index, latency at the sinks and stage times.
fn slowest_frames(
    frames: &[(usize, f64, helmcap::pipeline::StageTimings)],
    k: usize,
) -> Vec<String> {
    let mut by_latency: Vec<_> = frames.iter().collect();
    by_latency.sort_by(|a, b| b.1.total_cmp(&a.1));
    by_latency
        .iter()
        .take(k)
        .map(|(index, ms, t)| {
            let stages: Vec<String> = helmcap::pipeline::Stage::ALL
                .iter()
                .filter(|s| t.get(**s).is_finite())
                .map(|s| format!("{} {:.1}", s.name(), t.get(*s)))
                .collect();
            format!("#{index} {ms:.1} ms ({})", stages.join(", "))
        })
        .collect()
}

/// Samples the process's resident memory every `every` frames.
struct RssSink {
    every: usize,
    samples: Arc<std::sync::Mutex<Vec<(usize, u64)>>>,
    seen: usize,
}

impl Sink for RssSink {
    fn name(&self) -> &str {
        "rss"
    }
    fn begin(&mut self, _session: &SessionMeta) -> Result<(), SinkError> {
        Ok(())
    }
    fn write(&mut self, _frame: &FrameResult) -> Result<(), SinkError> {
        if self.seen.is_multiple_of(self.every)
            && let (Some(kb), Ok(mut s)) =
                (helmcap::bench::host::resident_kib(), self.samples.lock())
        {
            s.push((self.seen, kb));
        }
        self.seen += 1;
        Ok(())
    }
    fn finish(&mut self, _metrics: &Metrics) -> Result<(), SinkError> {
        Ok(())
    }
}

/// The pipeline configuration of the built-in actor with LGI (the pipeline's default
/// parameters; no index cache) and the capture defaults.
fn actor_config(rig: helmcap::camera::StereoRig) -> anyhow::Result<PipelineConfig> {
    let spec = TakeSpec {
        dataset: DatasetSpec {
            no_cache: true,
            ..DatasetSpec::default()
        },
        ..TakeSpec::default()
    };
    let take = spec.load()?;
    let mut config = take.pipeline_config(rig);
    if let Some(stages) = spec.dense_stages(&take)? {
        stages.install(&mut config, &take.dataset);
    }
    Ok(config)
}

fn run_once(
    source: Box<dyn FrameSource>,
    rig: &helmcap::camera::StereoRig,
    out: &Path,
    extra: Vec<Box<dyn Sink>>,
) -> anyhow::Result<Metrics> {
    let config = actor_config(rig.clone())?;
    let (mut sinks, _) = file_sinks(out, &[]);
    sinks.extend(extra);
    Ok(helmcap::pipeline::run(
        source,
        config,
        sinks,
        Arc::new(AtomicBool::new(false)),
    )?)
}

pub fn run(args: PipelineBenchArgs) -> anyhow::Result<()> {
    let (work, temporary) = match &args.work {
        Some(w) => (w.clone(), false),
        None => (
            std::env::temp_dir().join(format!("helmcap-bench-pipeline-{}", std::process::id())),
            true,
        ),
    };
    let session = work.join("session");
    let rig = default_rig().context("the built-in rig")?;
    if !session.join("frames.csv").is_file() {
        let layout = MarkerLayout::builtin_actor()?;
        let actor = helmcap::dataset::actor::Actor::new(&Default::default())?;
        let performer = Performer::Actor(Box::new(actor));
        let synth = SynthParams {
            slip_mm: 1.5,
            slip_deg: 1.0,
            ..SynthParams::default()
        };
        let names = performer.expression_names();
        let weights =
            animation::random_curves(&names, args.frames, synth.fps, &AnimationParams::default());
        let t = Instant::now();
        render_session(
            &performer,
            &layout,
            &rig,
            &weights,
            &synth,
            &session,
            false,
            &|| {},
        )?;
        println!(
            "rendered {} frames (1280×1024, 60 fps) in {:.1} s",
            args.frames,
            t.elapsed().as_secs_f64()
        );
    }
    let open = || -> anyhow::Result<Box<dyn FrameSource>> {
        Ok(Box::new(Replay::open(&session, ReplayParams::default())?))
    };
    let out = work.join("out");
    let runs = args.runs.max(1);

    // Throughput: as fast as the pipeline goes (replay: backpressure, no drops).
    let mut fps = Vec::new();
    let mut stage_p50: std::collections::BTreeMap<String, Vec<f64>> = Default::default();
    for _ in 0..runs {
        let m = run_once(open()?, &rig, &out, Vec::new())?;
        fps.push(m.throughput_fps);
        for (k, s) in &m.latency_ms {
            stage_p50.entry(k.clone()).or_default().push(s.mean);
        }
    }
    let source_fps = 60.0;
    let thr = upper_median(&fps).unwrap_or(f64::NAN);
    println!(
        "replay throughput, median of {runs}: {thr:.1} frames/s = {:.2}× real time (runs: {})",
        thr / source_fps,
        fps.iter()
            .map(|f| format!("{f:.1}"))
            .collect::<Vec<_>>()
            .join(", ")
    );
    let per_stage: Vec<String> = stage_p50
        .into_iter()
        .map(|(k, v)| format!("{k} {:.2}", upper_median(&v).unwrap_or(f64::NAN)))
        .collect();
    println!("  mean ms per frame and stage: {}", per_stage.join(", "));

    // Latency: frames delivered on a 60 fps clock, dropped when the pipeline is full.
    let (mut p50, mut p99, mut dropped) = (Vec::new(), Vec::new(), Vec::new());
    let (mut steady_p50, mut steady_p99) = (Vec::new(), Vec::new());
    let mut slowest = Vec::new();
    for _ in 0..runs {
        let probe = LatencyProbe {
            frames: Default::default(),
        };
        let frames = probe.frames.clone();
        let m = run_once(
            Box::new(PacedSource::new(open()?, source_fps)),
            &rig,
            &out,
            vec![Box::new(probe)],
        )?;
        if let Ok(f) = frames.lock() {
            let first: Vec<String> = f
                .iter()
                .take(4)
                .map(|(i, ms, t)| {
                    format!(
                        "#{i} {ms:.1} ms (track {:.1}, solve {:.1})",
                        t.get(helmcap::pipeline::Stage::Track),
                        t.get(helmcap::pipeline::Stage::Solve)
                    )
                })
                .collect();
            slowest.push(format!(
                "slowest {}\n    first {}",
                slowest_frames(&f, 4).join("; "),
                first.join("; ")
            ));
        }
        let e = m.latency_ms.get("end_to_end").copied();
        p50.push(e.map_or(f64::NAN, |s| s.p50));
        p99.push(e.map_or(f64::NAN, |s| s.p99));
        dropped.push(m.frames_dropped as f64);
        if let Ok(f) = frames.lock() {
            // After the first second: the face acquired, the caches warm (at the sinks,
            // so without the sinks' own time, which is ~0.3 ms).
            let mut steady: Vec<f64> = f
                .iter()
                .filter(|(i, _, _)| *i as f64 >= source_fps)
                .map(|x| x.1)
                .collect();
            steady.sort_by(f64::total_cmp);
            let at = |q: f64| {
                steady
                    .get(((steady.len() as f64 - 1.0) * q).round() as usize)
                    .copied()
                    .unwrap_or(f64::NAN)
            };
            steady_p50.push(at(0.5));
            steady_p99.push(at(0.99));
        }
    }
    println!(
        "live-paced 60 fps end-to-end latency, median of {runs}: p50 {:.1} ms, p99 {:.1} ms (goal p99 < 33.3 ms); frames dropped {}",
        upper_median(&p50).unwrap_or(f64::NAN),
        upper_median(&p99).unwrap_or(f64::NAN),
        upper_median(&dropped).unwrap_or(f64::NAN)
    );
    println!(
        "  after the first second (face acquired, caches warm), median of {runs}: p50 {:.1} ms, \
         p99 {:.1} ms",
        upper_median(&steady_p50).unwrap_or(f64::NAN),
        upper_median(&steady_p99).unwrap_or(f64::NAN)
    );
    for (run, line) in slowest.iter().enumerate() {
        println!("  run {}, frames at the sinks: {line}", run + 1);
    }

    // Memory soak.
    if args.soak_frames > 0 {
        let samples = Arc::new(std::sync::Mutex::new(Vec::new()));
        let rss = RssSink {
            every: (args.soak_frames / 20).max(1),
            samples: samples.clone(),
            seen: 0,
        };
        let limited = Replay::open(&session, ReplayParams::default())?;
        let mut frames = Vec::new();
        let mut limited = limited;
        while frames.len() < args.soak_loop {
            match limited.next_frame() {
                Some(f) => frames.push(f?),
                None => break,
            }
        }
        let looped =
            LoopSource::from_frames(frames, source_fps, args.soak_frames, Some(rig.clone()));
        let t = Instant::now();
        let m = run_once(Box::new(looped), &rig, &out, vec![Box::new(rss)])?;
        let s = samples.lock().map(|s| s.clone()).unwrap_or_default();
        let line: Vec<String> = s
            .iter()
            .map(|(f, kb)| format!("{f}:{:.0}", *kb as f64 / 1024.0))
            .collect();
        let after_warmup: Vec<u64> = s.iter().skip(s.len() / 5).map(|x| x.1).collect();
        let (lo, hi) = (
            after_warmup.iter().min().copied().unwrap_or(0),
            after_warmup.iter().max().copied().unwrap_or(0),
        );
        println!(
            "soak: {} frames in {:.1} s ({:.1} frames/s); RSS MB by frame: {}",
            m.frames_out,
            t.elapsed().as_secs_f64(),
            m.throughput_fps,
            line.join(" ")
        );
        println!(
            "  after warm-up (from frame {}): RSS {:.1}–{:.1} MB, spread {:.1} MB",
            s.get(s.len() / 5).map_or(0, |x| x.0),
            lo as f64 / 1024.0,
            hi as f64 / 1024.0,
            (hi - lo) as f64 / 1024.0
        );
    }
    if temporary {
        let _ = std::fs::remove_dir_all(&work);
    }
    Ok(())
}
