//! The sinks of a take: the files every take writes (CSV, metrics), the exports
//! ([`Export`]), and the rerun recording and viewer ([`ViewerSpec`]).

use std::path::{Path, PathBuf};

use super::TakeError;
use crate::pipeline::Sink;
use crate::sink::{
    C3dSink, CsvSink, MeshFormat, MeshSequenceSink, MetricsSink, RerunParams, RerunSink,
    RerunTarget, UsdSink,
};

/// The sinks of a take and the files they write (for a summary).
pub type TakeSinks = (Vec<Box<dyn Sink>>, Vec<PathBuf>);

/// An export format besides the CSV files and metrics (which are always written).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, clap::ValueEnum)]
pub enum Export {
    /// One OBJ per frame: `mesh/frame_NNNNNN.obj` (neutral topology and UVs, mm).
    Obj,
    /// One binary PLY per frame: `mesh/frame_NNNNNN.ply`.
    Ply,
    /// One USD file with time-sampled points: `mesh.usda`.
    Usd,
    /// The labeled bundles as C3D: `bundles.c3d`.
    C3d,
    /// Unreal's Live Link Face CSV of the rig weights: `livelink.csv` (rig: `--rig`, else
    /// the dataset).
    LivelinkCsv,
    /// UsdSkel blend-shape animation of the rig weights: `face_skel.usda` (rig: `--rig`,
    /// else the dataset).
    UsdSkel,
}

/// The file sinks every take writes into `out` (CSV and metrics), plus one per distinct
/// export among `exports`, and the paths they write (for a summary). The animation
/// exports are written by the rig stage's sink ([`super::RigSpec::install`]).
pub fn file_sinks(out: &Path, exports: &[Export]) -> TakeSinks {
    let mut outputs = vec![
        out.join("bundles.csv"),
        out.join("head_pose.csv"),
        out.join("tracks.csv"),
        out.join("metrics.json"),
    ];
    let mut sinks: Vec<Box<dyn Sink>> = vec![
        Box::new(CsvSink::new(out)),
        Box::new(MetricsSink::new(&out.join("metrics.json"))),
    ];
    let mut seen: Vec<Export> = Vec::new();
    for &e in exports {
        if seen.contains(&e) {
            continue;
        }
        seen.push(e);
        let (sink, path): (Box<dyn Sink>, PathBuf) = match e {
            Export::Obj => (
                Box::new(MeshSequenceSink::new(&out.join("mesh"), MeshFormat::Obj)),
                out.join("mesh/frame_NNNNNN.obj"),
            ),
            Export::Ply => (
                Box::new(MeshSequenceSink::new(&out.join("mesh"), MeshFormat::Ply)),
                out.join("mesh/frame_NNNNNN.ply"),
            ),
            Export::Usd => (
                Box::new(UsdSink::new(&out.join("mesh.usda"))),
                out.join("mesh.usda"),
            ),
            Export::C3d => (
                Box::new(C3dSink::new(&out.join("bundles.c3d"))),
                out.join("bundles.c3d"),
            ),
            // Written by the animation sink (`RigSpec::install`).
            Export::LivelinkCsv | Export::UsdSkel => continue,
        };
        sinks.push(sink);
        outputs.push(path);
    }
    (sinks, outputs)
}

/// The rerun sinks of a take: a recording, a viewer, or both. Default neither.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ViewerSpec {
    /// Also save a rerun recording (`.rrd`) of the take here. Default `None`.
    pub rrd: Option<PathBuf>,
    /// Stream the take to a viewer: [`RerunTarget::Spawn`] or [`RerunTarget::Connect`]
    /// (a [`RerunTarget::File`] here is one more recording). Default `None`.
    pub viewer: Option<RerunTarget>,
    /// What is logged, and how (image rate and size). Default [`RerunParams::default`].
    pub rerun: RerunParams,
}

impl ViewerSpec {
    /// Adds the recording `rrd` (and its path to `outputs`) and the viewer to `sinks`.
    ///
    /// # Errors
    /// Bad parameters, a recording that cannot be created, a viewer that cannot be started
    /// or reached.
    pub fn sinks(
        &self,
        sinks: &mut Vec<Box<dyn Sink>>,
        outputs: &mut Vec<PathBuf>,
    ) -> Result<(), TakeError> {
        if let Some(rrd) = &self.rrd {
            let sink = RerunSink::new(RerunTarget::File(rrd.clone()), self.rerun.clone()).map_err(
                |source| TakeError::Recording {
                    path: rrd.display().to_string(),
                    source,
                },
            )?;
            sinks.push(Box::new(sink));
            outputs.push(rrd.clone());
        }
        if let Some(target) = &self.viewer {
            let sink =
                RerunSink::new(target.clone(), self.rerun.clone()).map_err(TakeError::Viewer)?;
            sinks.push(Box::new(sink));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn file_sinks_write_each_export_once() {
        let out = Path::new("/take");
        let (sinks, outputs) = file_sinks(
            out,
            &[Export::Obj, Export::C3d, Export::Obj, Export::LivelinkCsv],
        );
        assert_eq!(sinks.len(), 4);
        assert_eq!(
            outputs,
            [
                "bundles.csv",
                "head_pose.csv",
                "tracks.csv",
                "metrics.json",
                "mesh/frame_NNNNNN.obj",
                "bundles.c3d"
            ]
            .map(|f| out.join(f))
        );
    }

    #[test]
    fn no_rerun_sinks_by_default() {
        let (mut sinks, mut outputs) = (Vec::new(), Vec::new());
        ViewerSpec::default()
            .sinks(&mut sinks, &mut outputs)
            .unwrap();
        assert!(sinks.is_empty() && outputs.is_empty());
    }
}
