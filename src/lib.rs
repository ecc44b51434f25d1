//! helmcap: facial performance capture from helmet-mounted stereo cameras.
//!
//! Layers, bottom up (a module uses only those above it in this list; `tests/layers.rs`
//! checks the `crate::` paths of every file against it):
//! - [`file_error`], [`param_error`], [`limits`], [`atomic_file`], [`timecode`], [`frame_index`]:
//!   the one error of a file and its line, the one error of a parameter out of range, the
//!   stated size limits of every input, atomic writes, SMPTE timecode, the frame number
//!   every stage and file shares.
//! - [`gray_image`]: the 8-bit grey image every stage that reads pixels shares (the
//!   capture's frames, the calibration's target images, the detector's input).
//! - [`numeric`]: shared numerical kernels (sparse Cholesky, order statistics, small box-
//!   and simplex-constrained QPs); the two-column name files (label and name maps) are
//!   read by one private parser.
//! - [`mesh`]: polygon meshes, OBJ/PLY I/O, topology, Laplacians.
//! - [`dataset`]: the actor's face shapes, manifests, caching, marker layouts, the
//!   built-in synthetic actor.
//! - [`bundles`]: per-frame 3D marker positions (the bundles CSV).
//! - [`lgi`]: dense reconstruction from bundles by local geometric indexing.
//! - [`baseline`]: thin-plate RBF and bounded blendshape fit, for comparison with LGI.
//! - [`solve`]: the solve stage (bundles to dense mesh by any method).
//! - [`camera`]: camera models (pinhole, fisheye), stereo rigs, calibration files.
//! - [`stereo`]: triangulation of stereo observations into bundles.
//! - [`align`]: rigid alignment (Horn's method, robust variant) and head stabilization.
//! - [`capture`]: frame sources: replay of recorded sessions, video, live cameras.
//! - [`track`]: marker detection in images and labeling.
//! - [`synth`]: synthetic helmet footage and calibration target images with ground truth.
//! - [`enhance`]: detail enhancement and retiming (Bermano et al. 2014).
//! - [`rig`]: actor-specific blendshape rigs (Li et al. 2010), scan registration, rigs
//!   from LGI.
//! - [`animation`]: rig weights per frame from solved meshes, name maps (ARKit), Live
//!   Link Face layouts.
//! - [`pipeline`]: the streaming pipeline (stage threads, frame envelope, metrics, the
//!   sink interface).
//! - [`sink`]: the file sinks (CSV, metrics, OBJ/PLY sequences, USD, C3D) and the rerun
//!   viewer / `.rrd` recordings.
//! - [`take`]: a take assembled from one `TakeSpec` (dataset, profile, stages, sinks).
//! - [`farm`], [`report`]: take manifests, farm job bundles and merging; the dailies
//!   report.
//! - [`bench`](mod@bench): benchmark harnesses (the solve methods' accuracy and speed) and the host's
//!   figures for them (CPU time, resident memory, load average).

pub mod align;
pub mod animation;
pub mod atomic_file;
pub mod baseline;
pub mod bench;
pub mod bundles;
pub mod camera;
pub mod capture;
pub mod dataset;
pub mod enhance;
pub mod farm;
pub mod file_error;
pub mod frame_index;
pub mod gray_image;
pub mod lgi;
pub mod limits;
pub mod mesh;
mod name_pairs;
pub mod numeric;
pub mod param_error;
pub mod pipeline;
pub mod report;
pub mod rig;
pub mod sink;
pub mod solve;
pub mod stereo;
pub mod synth;
pub mod take;
pub mod timecode;
pub mod track;
