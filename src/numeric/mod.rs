//! Numerical kernels the stages share, at the bottom of the layers: they use no other
//! module of the crate.
//!
//! - [`SpdFactor`]: a sparse symmetric positive-definite matrix factored once by sparse
//!   Cholesky (`faer`) and solved many times (Poisson reconstruction and curvature flow in
//!   `enhance`, non-rigid ICP and deformation transfer in `rig`).
//! - [`upper_median`]: the median the robust estimators and the benchmarks report.
//! - [`box_qp`] and [`convex_weights`]: small dense quadratic programs over the box and
//!   the simplex (blendshape and rig weights, the jaw, the enhancer's combinations).
//! - [`SplitMix64`] and [`standard_normal`]: seeded random numbers (the built-in actor,
//!   the benchmarks' noise).
//! - [`NearestPoints`]: nearest-point queries over a fixed set of 3D points (a `kiddo`
//!   k-d tree), for acquisition's registration and LGI's vertices off the UV map.
//! - [`find_root`] and [`join_sets`]: disjoint sets in a parent array (the detector's
//!   blobs from runs of pixels, LGI's clusters of missing markers).

mod points;
mod qp;
mod random;
mod spd;
mod stats;
mod union_find;

pub use points::NearestPoints;
pub use qp::{box_qp, convex_weights};
pub use random::{SplitMix64, standard_normal};
pub use spd::{FactorError, SpdFactor};
pub use stats::upper_median;
pub use union_find::{find_root, join_sets};
