//! Numerical kernels the stages share, at the bottom of the layers: they use no other
//! module of the crate.
//!
//! - [`SpdFactor`]: a sparse symmetric positive-definite matrix factored once by sparse
//!   Cholesky (`faer`) and solved many times (Poisson reconstruction and curvature flow in
//!   `enhance`, non-rigid ICP and deformation transfer in `rig`).
//! - [`upper_median`]: the median the robust estimators and the benchmarks report.

mod spd;
mod stats;

pub use spd::{FactorError, SpdFactor};
pub use stats::upper_median;
