//! Baselines that local geometric indexing is compared with (Cong et al. 2019 Figure 4):
//! thin-plate RBF interpolation of the bundle displacements ([`RbfSolver`]) and a
//! blendshape fit of the dataset's shapes with weights bounded to [0, 1]
//! ([`BlendshapeSolver`]).
//!
//! Depends on [`crate::mesh`], [`crate::dataset`], [`crate::bundles`] and the geometric
//! helpers of [`crate::lgi`].

pub mod blendshape;
pub mod rbf;

pub use blendshape::{BlendshapeParams, BlendshapeSolver};
pub use rbf::{RbfKernel, RbfParams, RbfSolver};

use crate::bundles::FrameBundles;
use crate::frame_index::FrameIndex;

/// Errors of the baseline solvers.
#[derive(Debug, thiserror::Error)]
pub enum BaselineError {
    /// The marker layout does not fit the dataset.
    #[error("marker layout: {0}")]
    Layout(String),
    /// A parameter is out of range.
    #[error("invalid parameter: {0}")]
    Param(String),
    /// A frame cannot be solved.
    #[error("frame {frame}: {message}")]
    Frame {
        /// Frame number.
        frame: FrameIndex,
        /// What was wrong.
        message: String,
    },
}

/// Which markers of `bundles` are present and finite.
///
/// # Errors
/// [`BaselineError::Frame`] when the marker count differs from `markers` or none is
/// present.
pub(crate) fn present_mask(
    bundles: &FrameBundles,
    markers: usize,
) -> Result<Vec<bool>, BaselineError> {
    if bundles.positions.len() != markers {
        return Err(BaselineError::Frame {
            frame: bundles.frame,
            message: format!(
                "{} bundles for a layout of {markers} markers",
                bundles.positions.len()
            ),
        });
    }
    let present: Vec<bool> = bundles
        .positions
        .iter()
        .map(|p| p.is_some_and(|p| p.coords.iter().all(|c| c.is_finite())))
        .collect();
    if !present.iter().any(|&p| p) {
        return Err(BaselineError::Frame {
            frame: bundles.frame,
            message: "no marker present".into(),
        });
    }
    Ok(present)
}
