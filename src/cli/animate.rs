//! `helmcap animate`: the solved meshes of a finished take -> the weights of a blendshape
//! rig per frame (`rig_weights.csv`) and animation exports (`livelink.csv`).

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use helmcap::animation::{NameMap, RigSolveParams, RigSolver};
use helmcap::sink::{AnimationOutputs, AnimationWriter, read_usda_sequence};
use helmcap::take::RigSpec;
use helmcap::timecode::{Timecode, TimecodeClock};
use nalgebra::{Isometry3, Point3, Quaternion, Translation3, UnitQuaternion};

use super::{DatasetArgs, MeshUnits};

/// An animation export (besides `rig_weights.csv`, always written).
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum AnimExport {
    /// Unreal's Live Link Face CSV (`livelink.csv`): 52 ARKit curves, head angles.
    LivelinkCsv,
    /// UsdSkel blend-shape animation (`face_skel.usda`): the rig's shapes as blend-shape
    /// targets, the weights time-sampled, the head pose as an animated transform.
    UsdSkel,
}

/// Arguments of `helmcap animate`.
#[derive(Debug, clap::Args)]
pub struct AnimateArgs {
    /// The rig: a dataset manifest (the ICT-FaceKit, a rig from `helmcap rig build`) or
    /// `builtin[:SEED]`; its topology must be the meshes'.
    #[arg(long, value_name = "MANIFEST")]
    pub rig: String,
    /// The take's meshes: a `mesh.usda` (`replay --export usd`) or a folder of OBJ files
    /// (`frame_NNNNNN.obj`, frame numbers from the names).
    #[arg(long, short, value_name = "USDA_OR_DIR")]
    pub input: PathBuf,
    /// Output folder.
    #[arg(long, short, value_name = "DIR")]
    pub out: PathBuf,
    /// Export (repeatable): livelink-csv.
    #[arg(long, value_enum)]
    pub export: Vec<AnimExport>,
    /// Name map CSV (`shape,target`) from the rig's shapes to ARKit's names (default: the
    /// shipped map for the built-in actor or the ICT-FaceKit, chosen by shape names).
    #[arg(long, value_name = "CSV")]
    pub name_map: Option<PathBuf>,
    /// Temporal smoothing of the weights toward the previous frame (relative λ, 0: off).
    #[arg(long, default_value_t = 0.0)]
    pub smoothing: f64,
    /// Unit of the input meshes.
    #[arg(long, value_enum, default_value_t = MeshUnits::Mm)]
    pub units: MeshUnits,
    /// Camera rate when the input does not say (OBJ folders), frames per second.
    #[arg(long, default_value_t = 60.0)]
    pub fps: f64,
    /// Head poses and timecodes (`head_pose.csv` of the take; default: the one beside
    /// the input, when there is one).
    #[arg(long, value_name = "CSV")]
    pub head_pose: Option<PathBuf>,
    /// Read and write no dataset cache.
    #[arg(long)]
    pub no_cache: bool,
    /// Cache folder (default: $HELMCAP_CACHE_DIR, else ~/.cache/helmcap).
    #[arg(long, value_name = "DIR")]
    pub cache_dir: Option<PathBuf>,
}

/// One frame of the input.
struct Frame {
    index: usize,
    positions: Vec<Point3<f64>>,
}

/// A `head_pose.csv`: pose and timecode per frame.
type Poses = std::collections::HashMap<usize, (Isometry3<f64>, Option<Timecode>)>;

/// Reads `head_pose.csv` (`frame,qw,qx,qy,qz,tx,ty,tz[,source,timecode]`).
fn read_head_pose(path: &Path) -> anyhow::Result<Poses> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let mut out = Poses::new();
    let mut lines = text.lines().enumerate();
    let header: Vec<&str> = lines
        .next()
        .map(|(_, h)| h.split(',').collect())
        .unwrap_or_default();
    if header.len() < 8 || header[..8] != ["frame", "qw", "qx", "qy", "qz", "tx", "ty", "tz"] {
        bail!(
            "{}:1: header should start with frame,qw,qx,qy,qz,tx,ty,tz",
            path.display()
        );
    }
    let tc_col = header.iter().position(|h| *h == "timecode");
    for (i, line) in lines {
        if line.trim().is_empty() {
            continue;
        }
        let f: Vec<&str> = line.split(',').collect();
        let bad = || anyhow::anyhow!("{}:{}: malformed row {line:?}", path.display(), i + 1);
        if f.len() < 8 {
            return Err(bad());
        }
        let frame: usize = f[0].parse().map_err(|_| bad())?;
        let mut v = [0.0f64; 7];
        for (k, x) in v.iter_mut().enumerate() {
            *x = f[1 + k].trim().parse().map_err(|_| bad())?;
        }
        let q = UnitQuaternion::from_quaternion(Quaternion::new(v[0], v[1], v[2], v[3]));
        let pose = Isometry3::from_parts(Translation3::new(v[4], v[5], v[6]), q);
        let tc = tc_col
            .and_then(|c| f.get(c))
            .filter(|t| !t.trim().is_empty())
            .map(|t| t.trim().parse::<Timecode>())
            .transpose()
            .map_err(|e| anyhow::anyhow!("{}:{}: {e}", path.display(), i + 1))?;
        out.insert(frame, (pose, tc));
    }
    Ok(out)
}

/// The number in a file name (`frame_000012.obj` → 12).
fn frame_number(path: &Path) -> Option<usize> {
    let stem = path.file_stem()?.to_string_lossy().into_owned();
    let digits: String = stem
        .chars()
        .rev()
        .take_while(char::is_ascii_digit)
        .collect::<Vec<_>>()
        .into_iter()
        .rev()
        .collect();
    digits.parse().ok()
}

/// `timeCodesPerSecond` and the start timecode of a helmcap `mesh.usda`.
fn usd_timing(path: &Path) -> (Option<f64>, Option<Timecode>) {
    let Ok(text) = std::fs::read_to_string(path) else {
        return (None, None);
    };
    let head = &text[..text.len().min(4096)];
    let value = |key: &str| -> Option<String> {
        let at = head.find(key)? + key.len();
        let rest = head[at..].trim_start().strip_prefix('=')?.trim_start();
        Some(rest.lines().next()?.trim().trim_matches('"').to_string())
    };
    let fps = value("timeCodesPerSecond").and_then(|v| v.parse().ok());
    let start = value("string timecodeStart").and_then(|v| v.parse().ok());
    (fps, start)
}

/// Runs `helmcap animate`.
pub fn run(args: AnimateArgs) -> anyhow::Result<()> {
    let rig = DatasetArgs {
        dataset: args.rig.clone(),
        no_cache: args.no_cache,
        cache_dir: args.cache_dir.clone(),
    }
    .load()?;
    let params = RigSolveParams {
        smoothing: args.smoothing,
        ..RigSolveParams::default()
    };
    let solver = RigSolver::new(&rig, &params)?;
    let input = &args.input;
    let (frames, fps, start_tc, take_dir): (Vec<Frame>, f64, Option<Timecode>, PathBuf) =
        if input.is_dir() {
            let files = super::enhance::obj_files(input)?;
            let mut frames = Vec::with_capacity(files.len());
            for (i, f) in files.iter().enumerate() {
                let positions = helmcap::mesh::read_obj_positions(f)
                    .with_context(|| format!("reading {}", f.display()))?;
                frames.push(Frame {
                    index: frame_number(f).unwrap_or(i),
                    positions,
                });
            }
            let take = input.parent().map(Path::to_path_buf).unwrap_or_default();
            (frames, args.fps, None, take)
        } else if input.exists() {
            let seq = read_usda_sequence(input)?;
            let (fps, start) = usd_timing(input);
            let frames = seq
                .frames
                .into_iter()
                .map(|(t, positions)| Frame {
                    index: t.round().max(0.0) as usize,
                    positions,
                })
                .collect();
            let take = input.parent().map(Path::to_path_buf).unwrap_or_default();
            (frames, fps.unwrap_or(args.fps), start, take)
        } else {
            bail!("{}: no such file or folder", input.display());
        };
    if frames.is_empty() {
        bail!("{}: no frames", input.display());
    }
    let pose_file = args
        .head_pose
        .clone()
        .or_else(|| Some(take_dir.join("head_pose.csv")).filter(|p| p.exists()));
    let poses = match &pose_file {
        Some(p) => read_head_pose(p)?,
        None => Poses::new(),
    };
    let map = match &args.name_map {
        Some(p) => NameMap::read_csv(p)?,
        None => NameMap::default_for(&rig),
    };
    let outputs = AnimationOutputs {
        dir: args.out.clone(),
        livelink: args
            .export
            .contains(&AnimExport::LivelinkCsv)
            .then_some(map),
        usd_skel: args
            .export
            .contains(&AnimExport::UsdSkel)
            .then(|| std::sync::Arc::new(rig.neutral.clone())),
        livelink_udp: None,
    };
    let mut writer = AnimationWriter::new(solver, &outputs, fps)?;
    let first = frames[0].index;
    let clock = start_tc.map(|s| TimecodeClock::new(s, fps));
    let bar = indicatif::ProgressBar::new(frames.len() as u64);
    for f in &frames {
        let label = format!("{} (frame {})", input.display(), f.index);
        let mm = args
            .units
            .to_mm_checked(&f.positions, &rig.neutral.positions, &label)?;
        let pose = poses.get(&f.index);
        let tc = pose.and_then(|p| p.1).or_else(|| {
            clock
                .as_ref()
                .map(|c| c.stamp(f.index.saturating_sub(first) as u64))
        });
        writer
            .frame(f.index, tc.as_ref(), &mm, pose.map(|p| &p.0))
            .with_context(|| label.clone())?;
        bar.inc(1);
    }
    bar.finish_and_clear();
    let s = writer.finish()?;
    println!(
        "animated {} frames with rig {} ({} shapes): fit residual mean {:.3} mm, max {:.3} mm; \
         wrote {}",
        s.frames,
        rig.name,
        rig.shapes.len(),
        s.mean_residual_mm,
        s.max_residual_mm,
        args.out.display()
    );
    if !s.unmapped_shapes.is_empty() {
        println!(
            "livelink.csv: shapes without an ARKit name (left out): {}",
            s.unmapped_shapes.join(", ")
        );
    }
    Ok(())
}

/// The rig-solve options of `replay` and `live`.
#[derive(Debug, Clone, Default, clap::Args)]
pub struct RigStageArgs {
    /// Solve the weights of this rig for every frame (`rig_weights.csv`): a dataset
    /// manifest or `builtin[:SEED]` in the take's topology (default with
    /// `--export livelink-csv`: the take's dataset).
    #[arg(long, value_name = "MANIFEST")]
    pub rig: Option<String>,
    /// Name map CSV (`shape,target`) from the rig's shapes to ARKit's (default: chosen
    /// from the shipped maps by the rig's shape names).
    #[arg(long, value_name = "CSV")]
    pub name_map: Option<PathBuf>,
    /// Temporal smoothing of the rig weights toward the previous frame (relative λ).
    #[arg(long, default_value_t = 0.0)]
    pub rig_smoothing: f64,
    /// Stream the weights to Unreal's Live Link as the Live Link Face app does (UDP to
    /// HOST:PORT, usually port 11111), paced at the camera rate (rig: `--rig`, else the
    /// dataset).
    #[arg(long, value_name = "HOST:PORT")]
    pub livelink: Option<String>,
}

impl RigStageArgs {
    /// The rig stage these options ask for.
    pub fn spec(&self) -> RigSpec {
        RigSpec {
            rig: self.rig.clone(),
            name_map: self.name_map.clone(),
            smoothing: self.rig_smoothing,
            livelink: self.livelink.clone(),
        }
    }
}
