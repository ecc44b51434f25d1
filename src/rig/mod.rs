//! Actor-specific blendshape rigs.
//!
//! - [`RigBuilder`]: example-based facial rigging (Li, Weise & Pauly 2010, "Example-Based
//!   Facial Rigging", ACM TOG 29(4)): from a generic template rig (neutral `A₀` and
//!   blendshapes `Aᵢ`), the actor's neutral `B₀` and a few example poses `S_j` with rough
//!   weights `α*_ij`, compute actor blendshapes `Bᵢ` that reproduce the examples and keep
//!   the template's controller semantics. Without examples it is deformation transfer
//!   (Sumner & Popović 2004, in the gradient form of Botsch et al. 2006).
//! - [`register`](mod@register): optimal-step non-rigid ICP (Amberg et al. 2007, as described in
//!   Kazlauskaite 2015 §3.3.2) that brings a scan of any topology into the template's
//!   topology, so it can serve as `B₀` or as an example pose.
//! - [`from_lgi`]: rig generation with local geometric indexing (Cong et al. 2019 §7): the
//!   template's shapes (and pairwise combinations) applied to the actor, sampled at the
//!   marker layout and reconstructed through the actor's LGI index.
//!
//! The rigs are [`Dataset`](crate::dataset::Dataset)s (neutral plus one absolute shape per
//! blendshape, written with [`write_dataset`](crate::dataset::write_dataset)), so they feed
//! LGI and enhancement directly.
//!
//! Depends on [`crate::mesh`], [`crate::dataset`], [`crate::enhance`] (deformation
//! gradients, sparse Cholesky), [`crate::baseline`] (the bounded QP), [`crate::align`]
//! and [`crate::lgi`].

pub mod builder;
pub mod from_lgi;
pub mod register;

pub use builder::{
    Example, ExampleFit, IterationReport, Rig, RigBuilder, RigParams, deformation_transfer,
};
pub use from_lgi::{Combination, FromLgiParams, LgiRig, combination_name, rig_from_lgi};
pub use register::{Registration, RegistrationParams, register};

use crate::dataset::DatasetError;
use crate::lgi::LgiError;
use crate::mesh::MeshError;

/// Why building a rig or registering a scan failed.
#[derive(Debug, thiserror::Error)]
pub enum RigError {
    /// A parameter is out of range. Fix: use a value in the range its docs give.
    #[error("invalid rig parameter {field} = {value}: {reason}")]
    InvalidParam {
        /// The parameter's name.
        field: &'static str,
        /// The rejected value.
        value: f64,
        /// The valid range.
        reason: &'static str,
    },
    /// An input does not fit the template (vertex count, weight count, names...).
    #[error("{0}")]
    Input(String),
    /// A sparse factorization failed (a mesh with a degenerate region).
    #[error(transparent)]
    Factor(#[from] crate::numeric::FactorError),
    /// Reading or writing a mesh failed.
    #[error(transparent)]
    Mesh(#[from] MeshError),
    /// Reading or writing a dataset failed.
    #[error(transparent)]
    Dataset(#[from] DatasetError),
    /// Local geometric indexing failed.
    #[error(transparent)]
    Lgi(#[from] LgiError),
}

impl RigError {
    fn invalid(field: &'static str, value: f64, reason: &'static str) -> Self {
        Self::InvalidParam {
            field,
            value,
            reason,
        }
    }
}

#[cfg(test)]
mod tests;
