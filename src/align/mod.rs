//! Rigid alignment of point sets and head stabilization.
//!
//! - [`horn`]: Horn's closed-form absolute orientation (weighted least squares).
//! - [`robust`]: the same inside iteratively reweighted least squares (Huber, Tukey), with
//!   an optional uniform scale, returning a report (inliers, residuals).
//! - [`stabilize`]: the [`Stabilizer`]: head pose per frame from the stabilizing markers,
//!   bundles in the head frame.
//!
//! Depends on nothing above [`crate::mesh`] and [`crate::dataset`] (marker layouts).

pub mod horn;
pub mod robust;
pub mod stabilize;

pub use horn::{HornError, horn_alignment};
pub use robust::{RobustFit, RobustHornParams, RobustLoss, horn_similarity, robust_horn};
pub use stabilize::{
    PoseSource, StabilizeCounts, StabilizeError, StabilizeParams, StabilizedFrame, Stabilizer,
};
