//! Rerun options of the commands that run the pipeline (`--viewer`, image rate and size;
//! `--rrd` is the replay's own), read into the library's `ViewerSpec`, and `helmcap bench
//! rerun`.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;
use helmcap::capture::GrayImage;
use helmcap::numeric::{SplitMix64, upper_median};
use helmcap::sink::rerun::{
    BundlePoint, MarkerPixel, MeshTopology, RerunFrame, RerunParams, RerunSession, RerunSink,
    RerunTarget,
};
use helmcap::take::ViewerSpec;
use helmcap::timecode::{Timecode, TimecodeRate};
use nalgebra::{Isometry3, Point2, Point3};
use rand::RngCore;

/// How to reach a viewer: `spawn` or `connect[=ADDR]`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ViewerArg {
    /// Start a viewer (`rerun` on PATH).
    Spawn,
    /// Stream to a running viewer at this address (default: the viewer's default port).
    Connect(Option<String>),
}

fn parse_viewer(s: &str) -> Result<ViewerArg, String> {
    match s {
        "spawn" => Ok(ViewerArg::Spawn),
        "connect" => Ok(ViewerArg::Connect(None)),
        _ => match s.strip_prefix("connect=") {
            Some(addr) if !addr.is_empty() => Ok(ViewerArg::Connect(Some(addr.to_string()))),
            _ => Err(format!(
                "expected `spawn`, `connect` or `connect=HOST:PORT`, got {s:?}"
            )),
        },
    }
}

/// Viewer and logging options of a pipeline run.
#[derive(Debug, Clone, clap::Args)]
pub struct ViewerArgs {
    /// Stream the take to a rerun viewer: `spawn` starts one (`rerun` must be on PATH;
    /// `pip install rerun-sdk==0.36.3`), `connect` streams to a running one on the default
    /// port (9876), `connect=HOST:PORT` to another.
    #[arg(long, value_name = "spawn|connect[=ADDR]", value_parser = parse_viewer)]
    pub viewer: Option<ViewerArg>,
    /// Log the camera images to rerun every Nth frame only (0 = never); markers, bundles
    /// and meshes are logged every frame.
    #[arg(long, value_name = "N", default_value_t = RerunParams::default().image_every)]
    pub rerun_image_every: u32,
    /// Shrink the camera images logged to rerun by this integer factor (2 = half width and
    /// height).
    #[arg(long, value_name = "N", default_value_t = RerunParams::default().image_downscale)]
    pub rerun_image_downscale: u32,
}

impl Default for ViewerArgs {
    fn default() -> Self {
        let params = RerunParams::default();
        Self {
            viewer: None,
            rerun_image_every: params.image_every,
            rerun_image_downscale: params.image_downscale,
        }
    }
}

impl ViewerArgs {
    /// The sink parameters these options ask for.
    pub fn params(&self) -> RerunParams {
        RerunParams {
            image_every: self.rerun_image_every,
            image_downscale: self.rerun_image_downscale,
            ..Default::default()
        }
    }

    /// The rerun sinks these options ask for, with the recording `rrd` (`--rrd`).
    pub fn spec(&self, rrd: Option<PathBuf>) -> ViewerSpec {
        ViewerSpec {
            rrd,
            viewer: self.viewer.as_ref().map(|v| match v {
                ViewerArg::Spawn => RerunTarget::Spawn,
                ViewerArg::Connect(addr) => RerunTarget::Connect(
                    addr.clone()
                        .unwrap_or_else(|| helmcap::sink::rerun::DEFAULT_VIEWER_URL.to_string()),
                ),
            }),
            rerun: self.params(),
        }
    }
}

/// Options of `helmcap bench rerun`.
#[derive(Debug, Clone, clap::Args)]
pub struct RerunBenchArgs {
    /// Frames logged per run.
    #[arg(long, default_value_t = 120)]
    frames: usize,
    /// Number of timed runs.
    #[arg(long, default_value_t = 5)]
    runs: usize,
    /// Image width, pixels.
    #[arg(long, default_value_t = 1280)]
    width: u32,
    /// Image height, pixels.
    #[arg(long, default_value_t = 1024)]
    height: u32,
    /// Mesh vertices per side of the square grid mesh (135 → 18 225 vertices).
    #[arg(long, default_value_t = 135)]
    grid: u32,
    /// Markers per frame.
    #[arg(long, default_value_t = 120)]
    markers: usize,
    /// Log images every Nth frame.
    #[arg(long, default_value_t = 1)]
    image_every: u32,
    /// Image downscale factor.
    #[arg(long, default_value_t = 1)]
    image_downscale: u32,
    /// Do not log vertex normals.
    #[arg(long)]
    no_normals: bool,
}

/// Cost of logging frames to an `.rrd` file: per-frame time on the calling thread, wall
/// time per frame including the final flush, process CPU time per frame (all of the SDK's
/// threads), file size per frame. Median of the runs.
pub fn run_bench(a: RerunBenchArgs) -> anyhow::Result<()> {
    let n = a.grid.max(2);
    let vertex_count = (n * n) as usize;
    let mut triangles = Vec::new();
    for y in 0..n - 1 {
        for x in 0..n - 1 {
            let v = y * n + x;
            triangles.push([v, v + 1, v + n]);
            triangles.push([v + 1, v + n + 1, v + n]);
        }
    }
    let uvs = (0..vertex_count as u32)
        .map(|i| Point2::new(f64::from(i % n), f64::from(i / n)) / f64::from(n - 1))
        .collect();
    let session = RerunSession {
        name: "bench".into(),
        marker_names: (0..a.markers).map(|i| format!("m{i:03}")).collect(),
        rig: None,
        mesh: Some(MeshTopology {
            vertex_count,
            triangles,
            vertex_uvs: Some(uvs),
        }),
    };
    // Camera-like images: a smooth gradient plus a little sensor noise.
    let mut rng = SplitMix64::new(0x2545_f491);
    let mut image = || {
        let data = (0..a.width * a.height)
            .map(|i| {
                let (x, y) = (i % a.width, i / a.width);
                (40 + (x + y) * 100 / (a.width + a.height)) as u8 + (rng.next_u64() % 6) as u8
            })
            .collect();
        GrayImage {
            width: a.width,
            height: a.height,
            data,
        }
    };
    let images = [image(), image()];
    let params = RerunParams {
        image_every: a.image_every,
        image_downscale: a.image_downscale,
        mesh_normals: !a.no_normals,
        ..Default::default()
    };
    let dir = std::env::temp_dir().join(format!("helmcap-bench-rerun-{}", std::process::id()));
    std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    let path = dir.join("bench.rrd");
    let timings = [("detect", 3.0), ("triangulate", 0.4), ("solve", 2.0)];
    let (mut log_ms, mut wall_ms, mut cpu_ms, mut mb) = (vec![], vec![], vec![], vec![]);
    for _ in 0..a.runs.max(1) {
        let cpu0 = helmcap::bench::host::process_cpu_seconds();
        let t0 = Instant::now();
        let mut sink = RerunSink::new(RerunTarget::File(path.clone()), params.clone())?;
        sink.begin_session(&session)?;
        let mut in_log = 0.0;
        for i in 0..a.frames {
            let s = i as f64 * 0.01;
            let markers: Vec<MarkerPixel> = (0..a.markers)
                .map(|m| MarkerPixel {
                    marker: m,
                    pixel: Point2::new(100.0 + m as f64 * 8.0 + s, 500.0),
                })
                .collect();
            let bundles: Vec<BundlePoint> = (0..a.markers)
                .map(|m| BundlePoint {
                    marker: m,
                    position_mm: Point3::new(m as f64, s, 300.0),
                    confidence: 0.9,
                })
                .collect();
            let mesh: Vec<Point3<f64>> = (0..vertex_count as u32)
                .map(|v| Point3::new(f64::from(v % n), f64::from(v / n), s))
                .collect();
            let errors: Vec<f32> = (0..vertex_count).map(|v| (v % 7) as f32 * 0.2).collect();
            let timecode = Timecode::from_frame_count(TimecodeRate::FPS_60, i as u64);
            let frame = RerunFrame {
                frame: i.into(),
                timestamp_ns: i as u64 * 16_666_667,
                timecode: Some(&timecode),
                images: [Some(&images[0]), Some(&images[1])],
                markers: [&markers, &markers],
                bundles_in_cam0: &bundles,
                bundles_in_head: &bundles,
                cam0_from_head: Some(Isometry3::identity()),
                mesh_in_head: Some(&mesh),
                vertex_error_mm: Some(&errors),
                bundle_error_rms_mm: None,
                stage_ms: &timings,
            };
            let t = Instant::now();
            sink.log_frame(&frame)?;
            in_log += t.elapsed().as_secs_f64();
        }
        sink.finish()?;
        let frames = a.frames.max(1) as f64;
        wall_ms.push(t0.elapsed().as_secs_f64() * 1e3 / frames);
        log_ms.push(in_log * 1e3 / frames);
        if let (Some(c0), Some(c1)) = (cpu0, helmcap::bench::host::process_cpu_seconds()) {
            cpu_ms.push((c1 - c0) * 1e3 / frames);
        }
        let size = std::fs::metadata(&path).map(|m| m.len()).unwrap_or(0);
        mb.push(size as f64 / 1e6 / frames);
    }
    let _ = std::fs::remove_dir_all(&dir);
    println!(
        "rerun logging to .rrd: {} frames of 2 × {}×{} images (every {}, downscale {}), \
         {vertex_count}-vertex mesh{}, {} markers; median of {} runs, per frame:",
        a.frames,
        a.width,
        a.height,
        a.image_every,
        a.image_downscale,
        if a.no_normals { "" } else { " with normals" },
        a.markers,
        a.runs.max(1)
    );
    println!(
        "  log_frame (calling thread)  {:8.2} ms",
        upper_median(&log_ms).unwrap_or(f64::NAN)
    );
    println!(
        "  wall incl. final flush      {:8.2} ms",
        upper_median(&wall_ms).unwrap_or(f64::NAN)
    );
    if !cpu_ms.is_empty() {
        println!(
            "  CPU, all threads            {:8.2} ms",
            upper_median(&cpu_ms).unwrap_or(f64::NAN)
        );
    }
    println!(
        "  file size                   {:8.2} MB",
        upper_median(&mb).unwrap_or(f64::NAN)
    );
    Ok(())
}
