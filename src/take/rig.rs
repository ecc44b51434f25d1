//! The rig stage of a take: the weights of a blendshape rig solved for every frame, and
//! the animation sink that writes them (`rig_weights.csv`, `livelink.csv`,
//! `face_skel.usda`) or streams them to Unreal's Live Link.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use super::TakeError;
use crate::animation::{NameMap, RigSolveParams, RigSolver};
use crate::dataset::{Dataset, DatasetSpec};
use crate::pipeline::{PipelineConfig, Sink};
use crate::sink::{AnimationOutputs, AnimationSink};

/// The animation sink of a take and the files it writes.
pub type AnimationStage = (Box<dyn Sink>, Vec<PathBuf>);

/// Settings of the rig stage. Default: off (unless an animation export asks for it).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RigSpec {
    /// Solve the weights of this rig for every frame (`rig_weights.csv`): a dataset
    /// manifest or `builtin[:SEED]` in the take's topology; `None`: the take's dataset
    /// when an animation export or `livelink` asks for a rig, else no rig stage.
    pub rig: Option<String>,
    /// Name map CSV (`shape,target`) from the rig's shapes to ARKit's; `None`: chosen from
    /// the shipped maps by the rig's shape names ([`NameMap::default_for`]).
    pub name_map: Option<PathBuf>,
    /// Temporal smoothing of the rig weights toward the previous frame (relative λ).
    /// Default 0.
    pub smoothing: f64,
    /// Stream the weights to Unreal's Live Link as the Live Link Face app does (UDP to
    /// `HOST:PORT`), paced at the camera rate. Default `None`.
    pub livelink: Option<String>,
}

impl RigSpec {
    /// When a rig, an animation export (`livelink_csv`, `usd_skel`) or Live Link is asked
    /// for: switches the pipeline's rig stage on in `config` and returns the animation
    /// sink that writes its weights into `out`, and the files it writes. The rig is
    /// loaded with the cache options of `cache`; the take's dataset `take_dataset` is used
    /// as it is when the rig names it (or none is named).
    ///
    /// # Errors
    /// When the rig cannot be loaded or solved for, or the name map cannot be read.
    pub fn install(
        &self,
        config: &mut PipelineConfig,
        take_dataset: &Dataset,
        cache: &DatasetSpec,
        livelink_csv: bool,
        usd_skel: bool,
        out: &Path,
    ) -> Result<Option<AnimationStage>, TakeError> {
        if self.rig.is_none() && !livelink_csv && !usd_skel && self.livelink.is_none() {
            return Ok(None);
        }
        let rig = match &self.rig {
            Some(name) if *name != cache.name => cache.for_dataset(name.clone()).load()?,
            _ => take_dataset.clone(),
        };
        let params = RigSolveParams {
            smoothing: self.smoothing,
            ..RigSolveParams::default()
        };
        let solver = RigSolver::new(&rig, &params)?;
        let map = match &self.name_map {
            Some(p) => NameMap::read_csv(p)?,
            None => NameMap::default_for(&rig),
        };
        let mut files = vec![out.join("rig_weights.csv")];
        if livelink_csv {
            files.push(out.join("livelink.csv"));
        }
        if usd_skel {
            files.push(out.join("face_skel.usda"));
        }
        config.rig_solver = Some(solver.clone());
        let sink = AnimationSink::new(
            solver,
            AnimationOutputs {
                dir: out.to_path_buf(),
                livelink: livelink_csv.then(|| map.clone()),
                usd_skel: usd_skel.then(|| Arc::new(rig.neutral.clone())),
                livelink_udp: self.livelink.clone().map(|t| (t, map)),
            },
        );
        Ok(Some((Box::new(sink), files)))
    }
}
