//! Jaw articulation (Cong et al. 2019 §6): shapes and bundles are unskinned by their jaw
//! pose before indexing, and the reconstruction is reskinned, Eq. (2):
//! `x = T(θ) (x₀ + Σ_n w_n b*_n)` with `b*_n = T(θ_n)⁻¹ (x₀ + b_n) − x₀`.
//!
//! `T(θ)` is the dataset's linear-blend-skinned jaw ([`crate::dataset::JawRig`]).

use nalgebra::{Point3, Vector3};

use super::LgiParams;
use super::index::JawSpace;
use crate::dataset::{Dataset, JawPose, JawRig};

/// The jaw space of `dataset` when `params.use_jaw` is set, the dataset has a jaw rig and
/// every shape has a jaw pose; `None` otherwise (the index then works on the shapes as
/// they are).
pub fn jaw_space(
    dataset: &Dataset,
    params: &LgiParams,
    marker_vertices: &[u32],
) -> Option<JawSpace> {
    if !params.use_jaw {
        return None;
    }
    let rig = dataset.jaw.clone()?;
    let poses: Option<Vec<JawPose>> = dataset.shapes.iter().map(|s| s.jaw).collect();
    let poses = poses?;
    if rig.weights.len() != dataset.vertex_count() {
        return None;
    }
    let regression = train_regression(dataset, &rig, &poses, marker_vertices);
    Some(JawSpace {
        rig,
        poses,
        regression,
    })
}

/// Unskinned displacement `b*_n = T(θ_n)⁻¹ (x₀ + b_n) − x₀` of every vertex of a shape
/// with positions `shape` (= `x₀ + b_n`) and jaw pose `pose`.
pub fn unskinned_displacement(
    rig: &JawRig,
    pose: &JawPose,
    neutral: &[Point3<f64>],
    shape: &[Point3<f64>],
) -> Vec<Vector3<f64>> {
    let j = rig.jaw_transform(pose);
    shape
        .iter()
        .zip(neutral)
        .zip(&rig.weights)
        .map(|((p, x0), &w)| rig.unskin_point(&j, w, p) - x0)
        .collect()
}

/// Markers whose skinning weight is at least this drive the jaw estimate.
const JAW_MARKER_WEIGHT: f64 = 0.5;
/// Ridge regularization of the jaw estimate, relative to the mean squared feature.
const RIDGE: f64 = 1e-3;

/// Training data of the per-frame jaw estimate: the jaw-driven markers' displacements on
/// every shape (and the neutral) with the shapes' jaw poses.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct JawRegression {
    /// Marker indices whose bundles are the features.
    pub markers: Vec<u32>,
    /// Neutral position of each feature marker, mm.
    pub rest: Vec<Point3<f64>>,
    /// One row per training shape: the feature markers' displacements (3 per marker).
    pub rows: Vec<Vec<f64>>,
    /// Jaw pose of each row as `[open_rad, lateral_rad, forward_mm]`.
    pub targets: Vec<[f64; 3]>,
}

/// Builds the jaw estimate's training data from the dataset's (skinned) shapes.
pub fn train_regression(
    dataset: &Dataset,
    rig: &JawRig,
    poses: &[JawPose],
    marker_vertices: &[u32],
) -> JawRegression {
    let markers: Vec<u32> = (0..marker_vertices.len() as u32)
        .filter(|&m| rig.weights[marker_vertices[m as usize] as usize] >= JAW_MARKER_WEIGHT)
        .collect();
    let rest: Vec<Point3<f64>> = markers
        .iter()
        .map(|&m| dataset.neutral.positions[marker_vertices[m as usize] as usize])
        .collect();
    let mut rows = vec![vec![0.0; 3 * markers.len()]];
    let mut targets = vec![[0.0; 3]];
    for (s, pose) in dataset.shapes.iter().zip(poses) {
        let mut row = Vec::with_capacity(3 * markers.len());
        for (&m, x0) in markers.iter().zip(&rest) {
            let d = s.positions[marker_vertices[m as usize] as usize] - x0;
            row.extend_from_slice(&[d.x, d.y, d.z]);
        }
        rows.push(row);
        targets.push([pose.open_rad, pose.lateral_rad, pose.forward_mm]);
    }
    JawRegression {
        markers,
        rest,
        rows,
        targets,
    }
}

impl JawRegression {
    /// Estimates the frame's jaw pose from the present feature markers by kernel ridge
    /// regression (linear kernel) over the training shapes: `θ = f·Fᵀ (F Fᵀ + λI)⁻¹ Θ`,
    /// with `F` restricted to the present markers. The neutral pose when no feature
    /// marker is present.
    pub fn estimate(&self, bundles: &[Option<Point3<f64>>]) -> JawPose {
        let mut cols = Vec::new();
        let mut f = Vec::new();
        for (i, (&m, x0)) in self.markers.iter().zip(&self.rest).enumerate() {
            if let Some(Some(y)) = bundles.get(m as usize) {
                let d = y - x0;
                cols.extend_from_slice(&[3 * i, 3 * i + 1, 3 * i + 2]);
                f.extend_from_slice(&[d.x, d.y, d.z]);
            }
        }
        if cols.is_empty() {
            return JawPose::default();
        }
        let n = self.rows.len();
        let k = nalgebra::DMatrix::from_fn(n, n, |a, b| {
            cols.iter()
                .map(|&c| self.rows[a][c] * self.rows[b][c])
                .sum::<f64>()
        });
        let scale = (0..n).map(|a| k[(a, a)]).sum::<f64>() / n as f64;
        let lambda = RIDGE * scale.max(1e-12);
        let k = k + nalgebra::DMatrix::identity(n, n) * lambda;
        let kf = nalgebra::DVector::from_fn(n, |a, _| {
            cols.iter()
                .zip(&f)
                .map(|(&c, x)| self.rows[a][c] * x)
                .sum::<f64>()
        });
        let Some(chol) = k.cholesky() else {
            return JawPose::default();
        };
        let alpha = chol.solve(&kf);
        let mut theta = [0.0; 3];
        for (a, t) in self.targets.iter().enumerate() {
            for q in 0..3 {
                theta[q] += alpha[a] * t[q];
            }
        }
        JawPose {
            open_rad: theta[0],
            lateral_rad: theta[1],
            forward_mm: theta[2],
        }
    }
}

/// The frame's jaw pose estimated from its bundles (see [`JawRegression::estimate`]).
pub fn estimate_pose(index: &super::LgiIndex, bundles: &crate::bundles::FrameBundles) -> JawPose {
    match &index.jaw {
        Some(j) => j.regression.estimate(&bundles.positions),
        None => JawPose::default(),
    }
}
