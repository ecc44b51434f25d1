//! Rig solve: per frame, the weights of a blendshape rig that best reproduce a dense
//! mesh in the rig's topology, by bounded least squares over the face vertices (Lewis et
//! al. 2014, "Practice and Theory of Blendshape Facial Models" §5; Kazlauskaite 2015 §3,
//! here on the dense mesh instead of the markers):
//!
//! min_w ‖B w − (y − x₀)‖² + μ ‖w‖² + λ ‖w − w_prev‖²   subject to 0 ≤ w_n ≤ 1,
//!
//! `B`: the shapes' displacements from the neutral `x₀` at the face vertices (3 rows per
//! vertex), `y` the frame's mesh, `w_prev` the previous frame's weights. `BᵀB` is formed
//! once; per frame only `Bᵀ(y − x₀)` (one pass over the face vertices) and the box QP on
//! the normal equations ([`crate::numeric::box_qp`], ~50 unknowns) remain.
//!
//! # Jaw
//! The jaw is part of the rig's shapes (`jawOpen`, `jawLeft`, ... are shapes like the
//! others), so its rotation is reproduced linearly: for the built-in actor's 0.3 rad
//! jaw the chord of a half-open jaw is within 0.3 mm of the arc.
//!
//! # Deviations
//! The smoothing term is causal (previous frame only) so the same solver serves live
//! runs with no added latency; `λ = 0` (the default) gives independent frames.

use nalgebra::{DMatrix, DVector, Point3};

use crate::dataset::Dataset;
use crate::numeric::box_qp;

/// Rig solve parameters.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RigSolveParams {
    /// Ridge μ, relative to the mean diagonal of `BᵀB`. Default 1e-6 (a performance in the
    /// rig's span is reproduced exactly; raise it for noisy meshes).
    pub regularization: f64,
    /// Temporal smoothing λ toward the previous frame's weights, relative to the mean
    /// diagonal of `BᵀB`. Default 0 (off). Large shapes (the jaw) have diagonals ~30×
    /// the mean, so λ = 1 barely slows them while it halves small shapes' steps; 30
    /// halves a full jaw step.
    pub smoothing: f64,
    /// Most active-set iterations per frame. Default 500.
    pub max_iterations: usize,
}

impl Default for RigSolveParams {
    fn default() -> Self {
        Self {
            regularization: 1e-6,
            smoothing: 0.0,
            max_iterations: 500,
        }
    }
}

impl RigSolveParams {
    /// Checks the parameters.
    ///
    /// # Errors
    /// [`RigSolveError::Param`] naming the field that is negative or not finite.
    pub fn validate(&self) -> Result<(), RigSolveError> {
        for (name, v) in [
            ("regularization", self.regularization),
            ("smoothing", self.smoothing),
        ] {
            if !v.is_finite() || v < 0.0 {
                return Err(RigSolveError::Param(format!(
                    "{name} = {v}: must be a finite number ≥ 0"
                )));
            }
        }
        if self.max_iterations == 0 {
            return Err(RigSolveError::Param("max_iterations must be ≥ 1".into()));
        }
        Ok(())
    }
}

/// Errors of the rig solve.
#[derive(Debug, thiserror::Error)]
pub enum RigSolveError {
    /// The rig cannot be solved for (no shapes, no face vertices).
    #[error("rig {rig}: {message}")]
    Rig {
        /// The rig's name.
        rig: String,
        /// What is wrong.
        message: String,
    },
    /// A parameter is out of range.
    #[error("rig solve parameters: {0}")]
    Param(String),
    /// A frame's mesh does not fit the rig.
    #[error("{0}")]
    Frame(String),
}

/// One frame's fit.
#[derive(Debug, Clone, PartialEq)]
pub struct RigFit {
    /// Weight of each rig shape (rig order), in [0, 1].
    pub weights: Vec<f64>,
    /// RMS distance between the rig evaluated at the weights and the frame's mesh over
    /// the face vertices, mm.
    pub residual_mm: f64,
}

/// Solves rig weights frame after frame (see the module docs).
#[derive(Debug, Clone)]
pub struct RigSolver {
    params: RigSolveParams,
    names: Vec<String>,
    neutral: Vec<Point3<f64>>,
    /// Face vertex indices the fit runs over.
    face: Vec<usize>,
    /// Per shape, every vertex's displacement (flattened xyz, #V·3).
    shapes: Vec<Vec<f64>>,
    /// `BᵀB + μ·d̄·I` over the face vertices.
    normal: DMatrix<f64>,
    /// `λ·d̄`: the smoothing weight in the normal equations' units.
    smoothing: f64,
    previous: Option<DVector<f64>>,
}

impl RigSolver {
    /// Precomputes the normal matrix of `rig` (a dataset: neutral plus named shapes).
    ///
    /// # Errors
    /// [`RigSolveError::Rig`] when the rig has no shapes or no face vertices;
    /// [`RigSolveError::Param`] for invalid parameters.
    pub fn new(rig: &Dataset, params: &RigSolveParams) -> Result<Self, RigSolveError> {
        params.validate()?;
        let err = |message: &str| RigSolveError::Rig {
            rig: rig.name.clone(),
            message: message.into(),
        };
        if rig.shapes.is_empty() {
            return Err(err("no shapes to solve for"));
        }
        let face: Vec<usize> = rig.face_vertex_indices().collect();
        if face.is_empty() {
            return Err(err("no face vertices"));
        }
        let neutral = rig.neutral.positions.clone();
        let shapes: Vec<Vec<f64>> = rig
            .shapes
            .iter()
            .map(|s| {
                s.positions
                    .iter()
                    .zip(&neutral)
                    .flat_map(|(p, q)| {
                        let d = p - q;
                        [d.x, d.y, d.z]
                    })
                    .collect()
            })
            .collect();
        let ns = shapes.len();
        let mut normal = DMatrix::zeros(ns, ns);
        for a in 0..ns {
            for b in a..ns {
                let (sa, sb) = (&shapes[a], &shapes[b]);
                let mut dot = 0.0;
                for &v in &face {
                    let i = 3 * v;
                    dot += sa[i] * sb[i] + sa[i + 1] * sb[i + 1] + sa[i + 2] * sb[i + 2];
                }
                normal[(a, b)] = dot;
                normal[(b, a)] = dot;
            }
        }
        let mean_diag = ((0..ns).map(|i| normal[(i, i)]).sum::<f64>() / ns as f64).max(1e-12);
        for i in 0..ns {
            normal[(i, i)] += params.regularization * mean_diag;
        }
        Ok(Self {
            params: *params,
            names: rig.shapes.iter().map(|s| s.name.clone()).collect(),
            neutral,
            face,
            shapes,
            normal,
            smoothing: params.smoothing * mean_diag,
            previous: None,
        })
    }

    /// The rig's shape names, in weight order.
    pub fn names(&self) -> &[String] {
        &self.names
    }

    /// Vertices of the rig's meshes.
    pub fn vertex_count(&self) -> usize {
        self.neutral.len()
    }

    /// Forgets the previous frame (a new take, or a gap in the frames).
    pub fn reset(&mut self) {
        self.previous = None;
    }

    /// Fits one frame's mesh (#V positions, mm, head frame, the rig's topology).
    ///
    /// # Errors
    /// [`RigSolveError::Frame`] when the vertex count differs from the rig's or a face
    /// vertex is not finite.
    pub fn solve(&mut self, mesh: &[Point3<f64>]) -> Result<RigFit, RigSolveError> {
        if mesh.len() != self.neutral.len() {
            return Err(RigSolveError::Frame(format!(
                "the mesh has {} vertices but the rig has {}: solve the take with the \
                 rig's dataset, or give the dataset the take was solved with as --rig",
                mesh.len(),
                self.neutral.len()
            )));
        }
        let ns = self.shapes.len();
        let mut g = DVector::zeros(ns);
        for &v in &self.face {
            let d = mesh[v] - self.neutral[v];
            if !d.iter().all(|c| c.is_finite()) {
                return Err(RigSolveError::Frame(format!("vertex {v} is not finite")));
            }
            let i = 3 * v;
            for (s, shape) in self.shapes.iter().enumerate() {
                g[s] += shape[i] * d.x + shape[i + 1] * d.y + shape[i + 2] * d.z;
            }
        }
        let start = self.previous.clone().unwrap_or_else(|| DVector::zeros(ns));
        let w = match (&self.previous, self.smoothing > 0.0) {
            (Some(prev), true) => {
                let mut h = self.normal.clone();
                for i in 0..ns {
                    h[(i, i)] += self.smoothing;
                }
                let g = g + prev * self.smoothing;
                box_qp(&h, &g, &start, self.params.max_iterations)
            }
            _ => box_qp(&self.normal, &g, &start, self.params.max_iterations),
        };
        let fitted = self.evaluate(w.as_slice());
        let sq: f64 = self
            .face
            .iter()
            .map(|&v| (fitted[v] - mesh[v]).norm_squared())
            .sum();
        let residual_mm = (sq / self.face.len() as f64).sqrt();
        self.previous = Some(w.clone());
        Ok(RigFit {
            weights: w.iter().copied().collect(),
            residual_mm,
        })
    }

    /// The rig at `weights` (rig order; missing trailing weights count as 0): every
    /// vertex, `x₀ + Σ w_n d_n`.
    pub fn evaluate(&self, weights: &[f64]) -> Vec<Point3<f64>> {
        let mut out = self.neutral.clone();
        for (shape, &w) in self.shapes.iter().zip(weights) {
            if w == 0.0 {
                continue;
            }
            for (p, d) in out.iter_mut().zip(shape.chunks_exact(3)) {
                p.x += w * d[0];
                p.y += w * d[1];
                p.z += w * d[2];
            }
        }
        out
    }

    /// Every shape's displacement from the neutral (#V per shape), e.g. for blend-shape
    /// targets of an export.
    pub fn offsets(&self, shape: usize) -> Option<&[f64]> {
        self.shapes.get(shape).map(Vec::as_slice)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dataset::actor::{Actor, ActorParams};

    /// A performance in the rig's linear span is recovered exactly, with bounds.
    #[test]
    fn recovers_weights_in_the_span() {
        let actor = Actor::new(&ActorParams::default()).unwrap();
        let ds = actor.to_dataset();
        let mut solver = RigSolver::new(&ds, &RigSolveParams::default()).unwrap();
        let n = ds.shapes.len();
        let mut truth = vec![0.0; n];
        truth[0] = 0.4;
        truth[4] = 1.0;
        truth[25] = 0.7;
        let mesh = solver.evaluate(&truth);
        let fit = solver.solve(&mesh).unwrap();
        for (a, b) in fit.weights.iter().zip(&truth) {
            assert!((a - b).abs() < 1e-3, "{a} vs {b}");
        }
        assert!(fit.residual_mm < 1e-3, "{}", fit.residual_mm);
        // Out of the box: weights stay in [0, 1].
        let over = solver.evaluate(&truth.iter().map(|w| w * 1.5).collect::<Vec<_>>());
        let fit = solver.solve(&over).unwrap();
        assert!(fit.weights.iter().all(|w| (0.0..=1.0).contains(w)));
        assert!(fit.residual_mm > 0.01);
        // A wrong vertex count is an error.
        assert!(solver.solve(&mesh[1..]).is_err());
    }

    /// Smoothing pulls a frame toward the previous one.
    #[test]
    fn smoothing_lags_a_step() {
        let actor = Actor::new(&ActorParams::default()).unwrap();
        let ds = actor.to_dataset();
        let params = RigSolveParams {
            smoothing: 30.0,
            ..RigSolveParams::default()
        };
        let mut solver = RigSolver::new(&ds, &params).unwrap();
        let n = ds.shapes.len();
        let zero = solver.evaluate(&vec![0.0; n]);
        let mut w = vec![0.0; n];
        w[0] = 1.0;
        let open = solver.evaluate(&w);
        solver.solve(&zero).unwrap();
        let fit = solver.solve(&open).unwrap();
        assert!(
            fit.weights[0] > 0.2 && fit.weights[0] < 0.9,
            "{}",
            fit.weights[0]
        );
        assert!(
            RigSolveParams {
                smoothing: -1.0,
                ..params
            }
            .validate()
            .is_err()
        );
    }
}
