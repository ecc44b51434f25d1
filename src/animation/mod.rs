//! Animation deliverables: the per-frame weights of a blendshape rig that reproduce the
//! solved dense mesh ([`RigSolver`]), name maps from a rig's shape names to a target
//! convention such as Apple's 52 ARKit blendshapes ([`NameMap`], [`ARKIT_NAMES`]), and
//! Unreal's Live Link Face CSV layout ([`livelink`]).
//!
//! Depends on [`crate::mesh`], [`crate::dataset`] (the rig is a dataset: neutral plus
//! named shapes) and [`crate::baseline`] (the box-constrained QP).

pub mod livelink;
mod name_map;
mod rig_solve;

pub use name_map::{ARKIT_NAMES, NameMap, NameMapError, ResolvedMap};
pub use rig_solve::{RigFit, RigSolveError, RigSolveParams, RigSolver};
