//! The solve stage: bundles in the head frame to the dense mesh in the dataset's topology,
//! by local geometric indexing ([`crate::lgi`], the default) or one of the baselines
//! ([`crate::baseline`]).
//!
//! [`Solver`] is the one entry type; [`crate::bench::solve`] measures every method on
//! held-out performances.
//!
//! Depends on [`crate::dataset`], [`crate::bundles`], [`crate::lgi`] and
//! [`crate::baseline`].

use std::sync::Arc;

use nalgebra::Point3;

use crate::baseline::{BaselineError, BlendshapeParams, BlendshapeSolver, RbfParams, RbfSolver};
use crate::bundles::FrameBundles;
use crate::dataset::{Dataset, MarkerLayout};
use crate::lgi::{LgiError, LgiIndex, LgiParams, LgiSolver};

/// Reconstruction method.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Method {
    /// Local geometric indexing (Cong et al. 2019).
    Lgi,
    /// Thin-plate RBF interpolation of the bundle displacements.
    Rbf,
    /// Blendshape fit with weights bounded to [0, 1].
    Blendshape,
}

impl Method {
    /// Every method, LGI first.
    pub const ALL: [Method; 3] = [Method::Lgi, Method::Rbf, Method::Blendshape];

    /// Short name (`lgi`, `rbf`, `blendshape`).
    pub fn name(self) -> &'static str {
        match self {
            Method::Lgi => "lgi",
            Method::Rbf => "rbf",
            Method::Blendshape => "blendshape",
        }
    }
}

impl std::str::FromStr for Method {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "lgi" => Ok(Method::Lgi),
            "rbf" => Ok(Method::Rbf),
            "blendshape" => Ok(Method::Blendshape),
            _ => Err(format!("unknown method {s:?} (lgi, rbf or blendshape)")),
        }
    }
}

/// Parameters of every method.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SolveParams {
    /// Local geometric indexing.
    pub lgi: LgiParams,
    /// Thin-plate RBF.
    pub rbf: RbfParams,
    /// Bounded blendshape fit.
    pub blendshape: BlendshapeParams,
}

/// Errors of the solve stage.
#[derive(Debug, thiserror::Error)]
pub enum SolveError {
    /// From local geometric indexing.
    #[error(transparent)]
    Lgi(#[from] LgiError),
    /// From a baseline.
    #[error(transparent)]
    Baseline(#[from] BaselineError),
}

/// A solver of one method, holding its precomputation and per-take state.
#[derive(Debug)]
pub enum Solver {
    /// Local geometric indexing.
    Lgi(Box<LgiSolver>),
    /// Thin-plate RBF.
    Rbf(RbfSolver),
    /// Bounded blendshape fit.
    Blendshape(BlendshapeSolver),
}

impl Solver {
    /// Builds the solver of `method` for `dataset` and `layout`.
    ///
    /// # Errors
    /// [`SolveError`] from the method's precomputation.
    pub fn new(
        method: Method,
        dataset: &Dataset,
        layout: &MarkerLayout,
        params: &SolveParams,
    ) -> Result<Self, SolveError> {
        Ok(match method {
            Method::Lgi => Solver::Lgi(Box::new(LgiSolver::new(dataset, layout, &params.lgi)?)),
            Method::Rbf => Solver::Rbf(RbfSolver::new(dataset, layout, &params.rbf)?),
            Method::Blendshape => {
                Solver::Blendshape(BlendshapeSolver::new(dataset, layout, &params.blendshape)?)
            }
        })
    }

    /// An LGI solver over a prebuilt index.
    ///
    /// # Errors
    /// [`SolveError::Lgi`] when `params` is invalid.
    pub fn lgi(index: Arc<LgiIndex>, params: &LgiParams) -> Result<Self, SolveError> {
        Ok(Solver::Lgi(Box::new(LgiSolver::from_index(index, params)?)))
    }

    /// The method.
    pub fn method(&self) -> Method {
        match self {
            Solver::Lgi(_) => Method::Lgi,
            Solver::Rbf(_) => Method::Rbf,
            Solver::Blendshape(_) => Method::Blendshape,
        }
    }

    /// Forgets the previous frame (temporal preference, warm starts).
    pub fn reset(&mut self) {
        if let Solver::Lgi(s) = self {
            s.reset();
        }
    }

    /// Solves one frame: every vertex of the neutral mesh, mm, head frame.
    ///
    /// # Errors
    /// [`SolveError`] when the frame does not fit the layout or has no bundle.
    pub fn solve(&mut self, bundles: &FrameBundles) -> Result<Vec<Point3<f64>>, SolveError> {
        Ok(match self {
            Solver::Lgi(s) => s.solve(bundles)?,
            Solver::Rbf(s) => s.solve(bundles)?,
            Solver::Blendshape(s) => s.solve(bundles)?,
        })
    }

    /// Solves a take in order (LGI applies its temporal smoothing here).
    ///
    /// # Errors
    /// As [`Solver::solve`], for the first bad frame.
    pub fn solve_sequence(
        &mut self,
        frames: &[FrameBundles],
    ) -> Result<Vec<Vec<Point3<f64>>>, SolveError> {
        match self {
            Solver::Lgi(s) => Ok(s.solve_sequence(frames)?),
            _ => frames.iter().map(|f| self.solve(f)).collect(),
        }
    }
}
