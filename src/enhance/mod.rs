//! Detail enhancement of low-resolution facial animation from a high-resolution
//! performance database (Bermano et al. 2014, "Facial Performance Enhancement Using
//! Dynamic Shape Space Analysis", ACM TOG 33(2)).
//!
//! The database is a [`Dataset`](crate::dataset::Dataset): its neutral and shapes play the
//! role of the captured performance frames. [`Enhancer::new`] precomputes everything once
//! (frequency separation §4.2, shape-space encoding §4.2, regions §4.3, per-region Gram
//! matrices §5.3, the factored Poisson system §5.5); [`Enhancer::enhance`] then runs the
//! five per-frame steps of §5 on a mesh in the database topology.
//!
//! Kernels, one file each: [`deformation_gradient`] (Sumner & Popović gradients, polar
//! encoding), [`frequency`] (low-pass filter, Eq. 1), [`poisson`] (reconstruction),
//! [`regions`] (voluntary regions, patches); the convex weights of Eq. 2-3 are
//! [`crate::numeric::convex_weights`],
//! [`retime`] (sequence projection and retiming, §6); [`database`]: the enhancer of a named
//! dataset and the parameters file.
//!
//! Depends on [`crate::mesh`], [`crate::dataset`] and [`crate::align`].

pub mod database;
pub mod deformation_gradient;
pub mod enhancer;
pub mod frequency;
pub mod poisson;
pub mod regions;
pub mod retime;

pub use crate::numeric::convex_weights;
pub use database::{BUILTIN_ONSETS, EnhanceSetupError, build_enhancer, read_params};
pub use deformation_gradient::{
    PolarCode, decode_polar, deformation_gradients, encode_polar, polar_decomposition,
    rest_frame_inverses, triangle_frame,
};
pub use enhancer::{EnhanceParams, EnhanceTimings, Enhanced, Enhancer};
pub use frequency::{LowPass, LowPassParams};
pub use poisson::{PoissonParams, PoissonSolver};
pub use regions::{REGION_NAMES, RegionWeights, VoluntaryRegions, seed_and_grow_patches};
pub use retime::{
    Retimed, Retimer, Sequence, SequenceProjection, builtin_sequences, project_on_segment,
    sequence_projection,
};

use crate::align::HornError;
use crate::mesh::MeshError;

/// Why an enhancement step failed.
#[derive(Debug, thiserror::Error)]
pub enum EnhanceError {
    /// A parameter is out of range. Fix: use a value in the range its docs give.
    #[error("invalid enhancement parameter {field} = {value}")]
    InvalidParam {
        /// The parameter's path, e.g. `low_pass.lambda_dt_mm2`.
        field: &'static str,
        /// The rejected value.
        value: f64,
    },
    /// An array has the wrong length (positions not in the database topology, ...).
    /// Fix: give meshes with the database neutral's vertex count.
    #[error("{what}: expected {expected} entries, got {got}")]
    Shape {
        /// What was measured.
        what: &'static str,
        /// The expected length.
        expected: usize,
        /// The length given.
        got: usize,
    },
    /// The database mesh is unusable.
    #[error("database mesh: {0}")]
    Mesh(#[from] MeshError),
    /// A sparse Cholesky factorization failed (degenerate neutral mesh).
    #[error("factoring the {what} failed: {reason}")]
    Factorization {
        /// Which system.
        what: &'static str,
        /// The solver's message.
        reason: String,
    },
    /// The voluntary regions are unusable (a region without vertices).
    #[error("regions: {0}")]
    Regions(String),
    /// Rigid alignment failed (non-finite positions).
    #[error("rigid alignment: {0}")]
    Alignment(#[from] HornError),
    /// Non-finite numbers in an input frame or a database shape.
    #[error("non-finite values in {0}")]
    NonFinite(String),
}

impl EnhanceError {
    pub(crate) fn invalid(field: &'static str, value: f64) -> Self {
        Self::InvalidParam { field, value }
    }
}

/// Areas of `mesh`'s triangles at the rest positions `rest` (#V, mm), after checking that
/// `rest` fits the mesh and is finite.
///
/// # Errors
/// [`EnhanceError::Shape`] for a wrong length, [`EnhanceError::Mesh`] for a non-finite
/// coordinate.
fn rest_triangle_areas(
    mesh: &crate::mesh::Mesh,
    rest: &[nalgebra::Point3<f64>],
) -> Result<Vec<f64>, EnhanceError> {
    let n = mesh.vertex_count();
    if rest.len() != n {
        return Err(EnhanceError::Shape {
            what: "rest positions",
            expected: n,
            got: rest.len(),
        });
    }
    if let Some(v) = rest
        .iter()
        .position(|p| !p.coords.iter().all(|c| c.is_finite()))
    {
        return Err(EnhanceError::Mesh(MeshError::Invalid(format!(
            "rest vertex {v} has a non-finite coordinate"
        ))));
    }
    Ok(crate::mesh::triangle_areas_of(mesh, rest))
}

impl From<crate::numeric::FactorError> for EnhanceError {
    fn from(e: crate::numeric::FactorError) -> Self {
        Self::Factorization {
            what: e.what,
            reason: e.reason,
        }
    }
}
