//! `helmcap solve`: bundles CSV to one mesh per frame, by local geometric indexing or a
//! baseline.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use anyhow::{Context, bail};
use helmcap::bundles::{FrameBundles, LabelMap, read_bundles_with};
use helmcap::dataset::{Dataset, MarkerLayout};
use helmcap::frame_index::FrameIndex;
use helmcap::lgi::{LgiIndex, LgiParams, LgiSolver, TemporalParams, WeightSmoother};
use helmcap::mesh::{write_obj_positions, write_ply};
use helmcap::solve::{Method, SolveParams, Solver};
use nalgebra::Point3;

use super::DatasetArgs;

/// Mesh file format of the output frames.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Format {
    /// Wavefront OBJ (text).
    Obj,
    /// Binary PLY.
    Ply,
}

/// Reconstruction method (`lgi` is the paper's; the others are baselines).
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum MethodArg {
    /// Local geometric indexing (Cong et al. 2019).
    Lgi,
    /// Thin-plate RBF interpolation of the bundle displacements.
    Rbf,
    /// Blendshape fit with weights bounded to [0, 1].
    Blendshape,
}

/// Arguments of `helmcap solve`.
#[derive(Debug, clap::Args)]
pub struct SolveArgs {
    #[command(flatten)]
    dataset: DatasetArgs,
    /// Marker layout CSV (name,vertex,stabilize_weight).
    #[arg(long, short = 'k', value_name = "CSV")]
    markers: PathBuf,
    /// Bundles: a CSV (frame,marker,x,y,z in mm, head frame) or a C3D marker file
    /// (recognised by content; POINT:UNITS mm, cm or m).
    #[arg(long, short = 'b', value_name = "CSV|C3D")]
    bundles: PathBuf,
    /// Marker names of the bundles file mapped to the layout's: CSV `c3d_label,marker`.
    #[arg(long, value_name = "CSV")]
    label_map: Option<PathBuf>,
    /// Output folder: one frame_NNNNNN.obj (or .ply) per frame.
    #[arg(long, short)]
    out: PathBuf,
    /// Reconstruction method.
    #[arg(long, value_enum, default_value_t = MethodArg::Lgi)]
    method: MethodArg,
    /// Output mesh format.
    #[arg(long, value_enum, default_value_t = Format::Obj)]
    format: Format,
    /// LGI: temporal smoothing of the barycentric weights, frames on each side (0: off).
    #[arg(long, default_value_t = 0)]
    smooth: usize,
    /// LGI: frames after each frame in the smoothing window, i.e. the output lag of a live
    /// run (default: the same as --smooth, a centred window).
    #[arg(long, value_name = "FRAMES")]
    lag: Option<usize>,
    /// LGI: settings for noisy bundles (tetrahedra within 0.5 mm compete; the surface is
    /// not forced through each bundle; cloud points within 0.5 mm merge, see LgiParams::noisy).
    #[arg(long)]
    noisy: bool,
    /// LGI parameters file (TOML with the fields of LgiParams; the flags above override).
    #[arg(long, value_name = "TOML")]
    lgi_params: Option<PathBuf>,
    /// Do not read or write the LGI index cache.
    #[arg(long)]
    no_index_cache: bool,
}

pub fn run(args: SolveArgs) -> anyhow::Result<()> {
    let ds = args.dataset.load()?;
    let layout = MarkerLayout::read_csv(&args.markers)
        .with_context(|| format!("reading markers {}", args.markers.display()))?;
    layout
        .validate_for(&ds)
        .with_context(|| format!("markers {} do not fit {}", args.markers.display(), ds.name))?;
    let label_map = match &args.label_map {
        Some(p) => Some(LabelMap::read_csv(p).context("reading the label map")?),
        None => None,
    };
    let (frames, report) = read_bundles_with(&args.bundles, &layout, label_map.as_ref())
        .with_context(|| format!("reading bundles {}", args.bundles.display()))?;
    if let Some(c3d) = &report.c3d {
        tracing::info!(
            "{}: C3D, {} points at {} Hz in {}, first frame {}",
            args.bundles.display(),
            c3d.points,
            c3d.rate_hz,
            c3d.units,
            c3d.first_frame
        );
    }
    if report.non_finite_rows > 0 {
        tracing::warn!(
            "{}: {} rows with non-finite coordinates count as missing markers",
            args.bundles.display(),
            report.non_finite_rows
        );
    }
    if report.implausible_rows > 0 {
        tracing::warn!(
            "{}: {} rows with a coordinate beyond {} mm (wrong units?) count as missing markers",
            args.bundles.display(),
            report.implausible_rows,
            helmcap::bundles::MAX_PLAUSIBLE_MM
        );
    }
    if !report.unknown_markers.is_empty() {
        let names: Vec<String> = report
            .unknown_markers
            .iter()
            .map(|(n, c)| format!("{n} ({c} rows)"))
            .collect();
        tracing::warn!(
            "{}: markers not in the layout were skipped: {}",
            args.bundles.display(),
            names.join(", ")
        );
    }
    if frames.is_empty() {
        bail!("{}: no frames", args.bundles.display());
    }
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;

    let mut lgi = match &args.lgi_params {
        Some(p) => {
            let text =
                std::fs::read_to_string(p).with_context(|| format!("reading {}", p.display()))?;
            toml::from_str::<LgiParams>(&text)
                .with_context(|| format!("{}: not LGI parameters", p.display()))?
        }
        None if args.noisy => LgiParams::noisy(),
        None => LgiParams::default(),
    };
    if args.noisy {
        let n = LgiParams::noisy();
        lgi.bundle_tolerance_mm = n.bundle_tolerance_mm;
        lgi.merge_tolerance_mm = n.merge_tolerance_mm;
        lgi.snap_to_bundles = n.snap_to_bundles;
    }
    if args.smooth > 0 || args.lag.is_some_and(|l| l > 0) {
        lgi.smoothing = TemporalParams {
            past_frames: args.smooth,
            future_frames: args.lag.unwrap_or(args.smooth),
            ..TemporalParams::default()
        };
    }
    lgi.validate()?;
    let params = SolveParams {
        lgi,
        ..SolveParams::default()
    };

    let t0 = Instant::now();
    let method = match args.method {
        MethodArg::Lgi => Method::Lgi,
        MethodArg::Rbf => Method::Rbf,
        MethodArg::Blendshape => Method::Blendshape,
    };
    let bar = indicatif::ProgressBar::new(frames.len() as u64);
    bar.set_style(
        indicatif::ProgressStyle::with_template("solving [{bar:30}] {pos}/{len} frames {msg}")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    let writer = FrameWriter {
        neutral: &ds,
        out: &args.out,
        format: args.format,
    };
    let mut written = 0usize;
    let mut skipped = Vec::new();
    match method {
        Method::Lgi => {
            let index = lgi_index(&ds, &layout, &params.lgi, &args)?;
            let mut solver = LgiSolver::from_index(index, &params.lgi)?;
            let mut smoother = WeightSmoother::new(params.lgi.smoothing);
            let mut queue: std::collections::VecDeque<&FrameBundles> = Default::default();
            let solve_t = Instant::now();
            for f in &frames {
                let w = match solver.index_frame(f, None) {
                    Ok(w) => w,
                    Err(e) => {
                        skipped.push(format!("{e}"));
                        bar.inc(1);
                        continue;
                    }
                };
                queue.push_back(f);
                for s in smoother.push(w) {
                    let b = queue.pop_front().context("smoother out of step")?;
                    writer.write(b.frame, &solver.reconstruct(&s, b)?)?;
                    written += 1;
                    bar.inc(1);
                }
            }
            for s in smoother.finish() {
                let b = queue.pop_front().context("smoother out of step")?;
                writer.write(b.frame, &solver.reconstruct(&s, b)?)?;
                written += 1;
                bar.inc(1);
            }
            bar.set_message(format!(
                "{:.2} ms/frame",
                solve_t.elapsed().as_secs_f64() * 1e3 / frames.len() as f64
            ));
        }
        _ => {
            let mut solver = Solver::new(method, &ds, &layout, &params)?;
            for f in &frames {
                match solver.solve(f) {
                    Ok(p) => {
                        writer.write(f.frame, &p)?;
                        written += 1;
                    }
                    Err(e) => skipped.push(format!("{e}")),
                }
                bar.inc(1);
            }
        }
    }
    bar.finish_and_clear();
    for s in skipped.iter().take(5) {
        tracing::warn!("skipped {s}");
    }
    if skipped.len() > 5 {
        tracing::warn!("... and {} more frames skipped", skipped.len() - 5);
    }
    println!(
        "wrote {written} frames to {} ({}, {:.2} s){}",
        args.out.display(),
        method.name(),
        t0.elapsed().as_secs_f64(),
        if skipped.is_empty() {
            String::new()
        } else {
            format!("; {} frames without any marker skipped", skipped.len())
        }
    );
    Ok(())
}

/// Writes solved frames into the output folder.
struct FrameWriter<'a> {
    neutral: &'a Dataset,
    out: &'a Path,
    format: Format,
}

impl FrameWriter<'_> {
    fn write(&self, frame: FrameIndex, positions: &[Point3<f64>]) -> anyhow::Result<()> {
        let mesh = &self.neutral.neutral;
        let (path, r) = match self.format {
            Format::Obj => {
                let p = self.out.join(format!("frame_{frame:06}.obj"));
                let r = write_obj_positions(&p, mesh, positions);
                (p, r)
            }
            Format::Ply => {
                let p = self.out.join(format!("frame_{frame:06}.ply"));
                let r = write_ply(&p, mesh, Some(positions));
                (p, r)
            }
        };
        r.with_context(|| format!("writing {}", path.display()))
    }
}

/// The LGI index of `ds` for `layout`: from the cache when one was built with the same
/// dataset, layout and parameters, else built (and cached).
fn lgi_index(
    ds: &Dataset,
    layout: &MarkerLayout,
    params: &LgiParams,
    args: &SolveArgs,
) -> anyhow::Result<Arc<LgiIndex>> {
    let cache = if args.no_index_cache {
        None
    } else {
        args.dataset.spec().cache_folder()
    };
    let (index, _) = helmcap::lgi::cache::load_or_build(ds, layout, params, cache.as_deref())?;
    Ok(index)
}
