//! A take assembled from one [`TakeSpec`]: the dataset and marker layout, the capture
//! profile, the pipeline configuration, the dense stages (LGI solve, detail enhancement),
//! the rig stage, and the sinks with the files they write. `replay`, `live` and `demo`, the
//! pipeline benchmark and the farm's chunks all start a take from here; the command line
//! only parses its options into a [`TakeSpec`].
//!
//! The steps, in the order a run takes them (a caller may interleave its own, e.g. open
//! its source before the profile):
//! 1. [`TakeSpec::load`]: the dataset and its layout ([`TakeDataset`]);
//! 2. [`TakeSpec::load_profile`]: the capture profile;
//! 3. [`TakeSpec::pipeline_config`]: the configuration on the source's stereo rig;
//! 4. [`TakeSpec::dense_stages`], then [`DenseStages::install`]: the solve and enhance
//!    stages (none with [`TakeSpec::no_solve`]);
//! 5. [`TakeSpec::sinks`]: the file sinks and exports, the rig stage and its animation
//!    sink, the rerun recording and viewer; and the files they write.
//!
//! Files by job: [`dense`] (solve settings, LGI parameters, the dense stages), [`rig`]
//! (the rig stage), [`sinks`] (exports, file sinks, the rerun sinks).
//!
//! Depends on [`crate::dataset`], [`crate::lgi`], [`crate::solve`], [`crate::track`] (the
//! capture profile), [`crate::enhance`], [`crate::animation`], [`crate::pipeline`] and
//! [`crate::sink`].

pub mod dense;
pub mod rig;
pub mod sinks;

pub use dense::{DEFAULT_SOLVE_KEYFRAMES, DenseStages, SolveSpec};
pub use rig::{AnimationStage, RigSpec};
pub use sinks::{Export, TakeSinks, ViewerSpec, file_sinks};

use std::path::{Path, PathBuf};
use std::sync::Arc;

use nalgebra::Point3;

use crate::animation::{NameMapError, RigSolveError};
use crate::camera::StereoRig;
use crate::dataset::markers::MarkerError;
use crate::dataset::{Dataset, DatasetLoadError, DatasetSpec, MarkerLayout};
use crate::enhance::EnhanceSetupError;
use crate::lgi::LgiError;
use crate::pipeline::PipelineConfig;
use crate::sink::RerunSinkError;
use crate::solve::SolveError;
use crate::track::{CaptureProfile, ProfileError};

/// Why a take could not be assembled. The messages name the command-line options of
/// `replay` and `live` (`--markers`, `--no-solve`, `--rrd`, ...), which the fields of
/// [`TakeSpec`] mirror.
#[derive(Debug, thiserror::Error)]
pub enum TakeError {
    /// The dataset could not be loaded.
    #[error(transparent)]
    Dataset(#[from] DatasetLoadError),
    /// The marker layout file could not be read.
    #[error("reading markers {path}")]
    Markers {
        /// The layout file.
        path: String,
        /// What went wrong.
        #[source]
        source: MarkerError,
    },
    /// The built-in actor's shipped layout could not be read.
    #[error(transparent)]
    Layout(#[from] MarkerError),
    /// A dataset manifest without a marker layout.
    #[error("--markers is required with a dataset manifest")]
    MarkersRequired,
    /// The layout does not fit the dataset (a vertex it does not have).
    #[error("the marker layout does not fit {dataset}")]
    LayoutMismatch {
        /// The dataset's name.
        dataset: String,
        /// What does not fit.
        #[source]
        source: MarkerError,
    },
    /// The capture profile could not be read.
    #[error(transparent)]
    Profile(#[from] ProfileError),
    /// `no_solve` with enhancement or a mesh export.
    #[error("--no-solve writes no meshes: drop --enhance and mesh exports")]
    NoSolveMeshes,
    /// `no_solve` with a rig or an animation export.
    #[error("--no-solve writes no meshes to solve a rig from: drop --rig and livelink-csv")]
    NoSolveRig,
    /// The LGI parameters file could not be read.
    #[error("reading {path}")]
    LgiParamsRead {
        /// The file.
        path: String,
        /// The system's error.
        #[source]
        source: std::io::Error,
    },
    /// The LGI parameters file is not TOML.
    #[error("{path}: not a TOML table")]
    LgiParamsToml {
        /// The file.
        path: String,
        /// The parser's error.
        #[source]
        source: toml::de::Error,
    },
    /// The default LGI parameters could not be written as TOML (a bug).
    #[error("writing the default LGI parameters as TOML")]
    LgiParamsDefaults(#[source] toml::ser::Error),
    /// The LGI parameters file has keys or values that are not LGI parameters.
    #[error("{path}: not LGI parameters")]
    LgiParamsFields {
        /// The file.
        path: String,
        /// The parser's error.
        #[source]
        source: toml::de::Error,
    },
    /// An LGI parameter is out of range, or the index could not be built.
    #[error(transparent)]
    Lgi(#[from] LgiError),
    /// The solver could not be set up.
    #[error(transparent)]
    Solve(#[from] SolveError),
    /// The enhancer could not be set up.
    #[error(transparent)]
    Enhance(#[from] EnhanceSetupError),
    /// The rig cannot be solved for.
    #[error(transparent)]
    Rig(#[from] RigSolveError),
    /// The name map could not be read.
    #[error(transparent)]
    NameMap(#[from] NameMapError),
    /// The rerun recording could not be created.
    #[error("--rrd {path}")]
    Recording {
        /// The recording.
        path: String,
        /// What went wrong.
        #[source]
        source: RerunSinkError,
    },
    /// The viewer could not be started or reached.
    #[error("--viewer")]
    Viewer(#[source] RerunSinkError),
}

/// How many times the stage channels' capacity (`--queue`) a replay's source may decode
/// ahead of the track stage ([`crate::pipeline::ChannelConfig::replay_entry_capacity`]):
/// 16 frames at the default queue of 4.
pub const REPLAY_READ_AHEAD: usize = 4;

/// Everything that shapes a take besides its source, its output folder and what the
/// sinks are told of it ([`crate::pipeline::TakeInfo`]). Every field has a default
/// ([`TakeSpec::default`]): the built-in actor, the capture defaults, LGI's noisy preset,
/// CSV and metrics only.
#[derive(Debug, Clone, PartialEq)]
pub struct TakeSpec {
    /// The dataset (manifest or `builtin[:SEED]`) and its cache options; the LGI index is
    /// cached with them. Default: the built-in actor, default cache.
    pub dataset: DatasetSpec,
    /// Marker layout CSV; `None`: the built-in actor's shipped layout (required with a
    /// manifest). Default `None`.
    pub markers: Option<PathBuf>,
    /// Capture profile TOML (dot size, polarity, colour, detection and labeling); `None`:
    /// the one the source names (a recorded session's `session.toml`), else
    /// [`CaptureProfile::default`]. Default `None`.
    pub profile: Option<PathBuf>,
    /// Stop after labeling and stabilization: no dense solve, no meshes (refused with
    /// `enhance`, a mesh export or a rig). Default false.
    pub no_solve: bool,
    /// Add the actor's fine detail to every solved mesh (Bermano et al. 2014), with the
    /// dataset as the database. Default false.
    pub enhance: bool,
    /// Exports besides the CSV files and metrics (always written); repeats are written
    /// once. Default none.
    pub exports: Vec<Export>,
    /// Settings of the dense solve. Default [`SolveSpec::default`].
    pub solve: SolveSpec,
    /// The rig stage (rig weights per frame, Live Link). Default off.
    pub rig: RigSpec,
    /// Frames each stage channel holds; a replay's source may decode
    /// [`REPLAY_READ_AHEAD`] times as many ahead of the track stage. Default 4.
    pub queue: usize,
    /// The rerun recording and viewer. Default neither.
    pub viewer: ViewerSpec,
}

impl Default for TakeSpec {
    fn default() -> Self {
        Self {
            dataset: DatasetSpec::default(),
            markers: None,
            profile: None,
            no_solve: false,
            enhance: false,
            exports: Vec::new(),
            solve: SolveSpec::default(),
            rig: RigSpec::default(),
            queue: 4,
            viewer: ViewerSpec::default(),
        }
    }
}

/// The dataset a take is solved with, and everything loaded from it.
pub struct TakeDataset {
    /// The dataset.
    pub dataset: Dataset,
    /// Its marker layout (checked against it).
    pub layout: Arc<MarkerLayout>,
    /// Each marker's neutral position, head frame, mm.
    pub neutral_markers: Vec<Point3<f64>>,
}

impl TakeDataset {
    /// The dataset and its marker layout (`markers`, else the built-in actor's), checked
    /// against each other, and the markers' positions on the neutral: what every pipeline
    /// run starts from.
    ///
    /// # Errors
    /// Unreadable dataset or layout, or a layout that does not fit the dataset.
    pub fn load(dataset: &DatasetSpec, markers: Option<&Path>) -> Result<Self, TakeError> {
        let layout = load_layout(&dataset.name, markers)?;
        let ds = dataset.load()?;
        layout
            .validate_for(&ds)
            .map_err(|source| TakeError::LayoutMismatch {
                dataset: ds.name.clone(),
                source,
            })?;
        let neutral_markers = layout
            .markers
            .iter()
            .map(|m| ds.neutral.positions[m.vertex as usize])
            .collect();
        Ok(Self {
            dataset: ds,
            layout: Arc::new(layout),
            neutral_markers,
        })
    }

    /// A pipeline configuration on `rig` with the capture defaults: the layout, the
    /// markers' neutral positions and the expression templates for acquisition.
    pub fn pipeline_config(&self, rig: StereoRig) -> PipelineConfig {
        let mut config = PipelineConfig::new(
            self.layout.clone(),
            Arc::new(self.neutral_markers.clone()),
            rig,
        );
        config.track.expression_templates =
            Arc::new(self.layout.expression_templates(&self.dataset));
        config.track.marker_normals = Arc::new(self.layout.neutral_normals(&self.dataset));
        config
    }
}

/// The layout for the dataset `dataset`: the file `markers`, else the built-in actor's
/// shipped layout when `dataset` names the built-in actor.
///
/// # Errors
/// An unreadable layout, a bad `builtin:SEED`, or no `markers` with a manifest.
pub fn load_layout(dataset: &str, markers: Option<&Path>) -> Result<MarkerLayout, TakeError> {
    match markers {
        Some(p) => MarkerLayout::read_csv(p).map_err(|source| TakeError::Markers {
            path: p.display().to_string(),
            source,
        }),
        None if crate::dataset::builtin_params(dataset)?.is_some() => {
            Ok(MarkerLayout::builtin_actor()?)
        }
        None => Err(TakeError::MarkersRequired),
    }
}

/// The capture profile at `path`, or the built-in defaults.
///
/// # Errors
/// An unreadable or invalid profile (the message names the file and key).
pub fn load_profile(path: Option<&Path>) -> Result<CaptureProfile, ProfileError> {
    match path {
        Some(p) => CaptureProfile::load(p),
        None => Ok(CaptureProfile::default()),
    }
}

impl TakeSpec {
    /// Loads the dataset and the layout (checked against each other).
    ///
    /// # Errors
    /// As [`TakeDataset::load`].
    pub fn load(&self) -> Result<TakeDataset, TakeError> {
        TakeDataset::load(&self.dataset, self.markers.as_deref())
    }

    /// The capture profile: [`TakeSpec::profile`], else `source_profile` (the one a
    /// recorded session names), else the built-in defaults.
    ///
    /// # Errors
    /// An unreadable or invalid profile.
    pub fn load_profile(&self, source_profile: Option<&Path>) -> Result<CaptureProfile, TakeError> {
        Ok(load_profile(self.profile.as_deref().or(source_profile))?)
    }

    /// The pipeline configuration of a take on `rig` with `profile`: the capture settings,
    /// the expression templates for acquisition and the channel size.
    pub fn pipeline_config(
        &self,
        take: &TakeDataset,
        rig: StereoRig,
        profile: &CaptureProfile,
    ) -> PipelineConfig {
        let mut config = take.pipeline_config(rig);
        config.track.detect = profile.detect_params(Some(&config.rig));
        config.track.label = profile.label_params();
        config.channels.capacity = self.queue;
        config.channels.replay_entry_capacity = REPLAY_READ_AHEAD.saturating_mul(self.queue);
        config
    }

    /// Builds the dense stages the spec asks for: the LGI solver (its index from the
    /// cache of [`TakeSpec::dataset`] unless it says not to) and, with `enhance`, the
    /// enhancer. `None` with `no_solve`, which writes no meshes.
    ///
    /// # Errors
    /// `no_solve` with `enhance` or a mesh export; bad LGI parameters; an index or
    /// enhancer that cannot be built.
    pub fn dense_stages(&self, take: &TakeDataset) -> Result<Option<DenseStages>, TakeError> {
        if self.no_solve {
            if self.enhance || !self.exports.iter().all(|e| *e == Export::C3d) {
                return Err(TakeError::NoSolveMeshes);
            }
            return Ok(None);
        }
        DenseStages::build(
            &take.dataset,
            &take.layout,
            &self.dataset,
            self.enhance,
            &self.solve,
        )
        .map(Some)
    }

    /// The sinks of a take written into `out`: the file sinks and exports, the rig stage
    /// and its animation sink when asked for (switched on in `config`), the rerun
    /// recording and viewer; and the files they write, for a summary.
    ///
    /// # Errors
    /// A rig that cannot be loaded, a rig with `no_solve`, a recording that cannot be
    /// created, a viewer that cannot start.
    pub fn sinks(
        &self,
        config: &mut PipelineConfig,
        take: &TakeDataset,
        out: &Path,
    ) -> Result<TakeSinks, TakeError> {
        let (mut sinks, mut outputs) = file_sinks(out, &self.exports);
        if let Some((sink, files)) = self.rig.install(
            config,
            &take.dataset,
            &self.dataset,
            self.exports.contains(&Export::LivelinkCsv),
            self.exports.contains(&Export::UsdSkel),
            out,
        )? {
            if self.no_solve {
                return Err(TakeError::NoSolveRig);
            }
            sinks.push(sink);
            outputs.extend(files);
        }
        self.viewer.sinks(&mut sinks, &mut outputs)?;
        Ok((sinks, outputs))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn layout_of_the_builtin_actor_and_of_manifests() {
        let builtin = load_layout("builtin:3", None).unwrap();
        assert_eq!(builtin, MarkerLayout::builtin_actor().unwrap());
        let e = load_layout("actor.toml", None).unwrap_err();
        assert_eq!(
            e.to_string(),
            "--markers is required with a dataset manifest"
        );
        let e = load_layout("builtin", Some(Path::new("/no/such/layout.csv"))).unwrap_err();
        assert!(
            e.to_string()
                .starts_with("reading markers /no/such/layout.csv"),
            "{e}"
        );
    }

    #[test]
    fn no_solve_refuses_meshes() {
        let spec = TakeSpec {
            no_solve: true,
            exports: vec![Export::C3d, Export::Obj],
            ..TakeSpec::default()
        };
        let take = spec.load().unwrap();
        assert!(matches!(
            spec.dense_stages(&take),
            Err(TakeError::NoSolveMeshes)
        ));
        let c3d_only = TakeSpec {
            exports: vec![Export::C3d],
            ..spec
        };
        assert!(c3d_only.dense_stages(&take).unwrap().is_none());
    }
}
