//! Jaw articulation (Cong et al. 2019 §6): shapes and bundles are unskinned by their jaw
//! pose before indexing, and the reconstruction is reskinned, Eq. (2):
//! `x = T(θ) (x₀ + Σ_n w_n b*_n)` with `b*_n = T(θ_n)⁻¹ (x₀ + b_n) − x₀`.
//!
//! `T(θ)` is the dataset's linear-blend-skinned jaw ([`crate::dataset::JawRig`]).

use nalgebra::{Point3, Vector3};

use super::LgiParams;
use crate::dataset::{Dataset, JawPose, JawRig};
use crate::numeric::box_qp;

/// The jaw data of an unskinned index (Cong et al. 2019 §6).
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct JawSpace {
    /// The rig (pivot, axes, per-vertex weights).
    pub rig: JawRig,
    /// Jaw pose of each shape, θ_n.
    pub poses: Vec<JawPose>,
    /// Per-frame jaw pose estimate from the bundles.
    pub regression: JawRegression,
}

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

/// The frame's jaw pose estimated from its bundles: the regression's estimate
/// ([`JawRegression::estimate`]), refined by fitting the dataset as a skinned rig to the
/// bundles ([`refine_pose`]).
pub fn estimate_pose(
    index: &super::LgiIndex,
    bundles: &crate::bundles::FrameBundles,
    cache: &mut RigFitCache,
) -> JawPose {
    match &index.jaw {
        Some(j) => {
            let initial = j.regression.estimate(&bundles.positions);
            refine_pose(index, &bundles.positions, initial, cache)
        }
        None => JawPose::default(),
    }
}

/// The Gram matrix of the unskinned shapes over the present markers, kept between
/// frames of [`refine_pose`] while the same markers are present (the usual case).
#[derive(Debug, Clone, Default)]
pub struct RigFitCache {
    present: Vec<bool>,
    /// The unskinned shapes at the present markers, `marker × shape` (row per marker).
    basis: Vec<Vector3<f64>>,
    gram: Option<nalgebra::DMatrix<f64>>,
}

/// Rounds of the rig fit in [`refine_pose`].
const RIG_FIT_ROUNDS: usize = 6;
/// Most active-set iterations of the weights' box QP per round.
const WEIGHT_ITERATIONS: usize = 200;
/// Ridge added to the Gram matrix, relative to its mean diagonal: keeps the box QP's
/// Cholesky factorizations defined when shapes coincide at the markers, far below any
/// weight that matters.
const GRAM_RIDGE: f64 = 1e-9;
/// The rounds stop when the pose moved by less than this (radians; the protrusion counts
/// per 100 mm).
const POSE_CONVERGED_RAD: f64 = 1e-6;

/// Refines the jaw pose `initial` of a frame whose (head-frame) bundles are `bundles`, by
/// fitting the dataset as a jaw-skinned blendshape rig to them: `y_m ≈ T_m(θ) (x₀_m +
/// Σ_n w_n b*_n,m)` over the present markers `m`, with `b*_n` the unskinned shapes of
/// Eq. (2) and `w_n ∈ [0, 1]`. Alternately: the weights given the pose (the bundles
/// unskinned by `θ`, then bounded least squares by the exact box QP), and the pose given
/// the weights (Gauss–Newton on the three jaw parameters).
///
/// §6 leaves the per-frame jaw estimate to "one of the usual methods for head and jaw
/// tracking". A linear regression from marker motion to the pose alone is confounded
/// by the other expressions' motion of the chin and lips, and a hundredth of a radian
/// moves the chin by most of a millimetre, which the unskinned bundles then carry into
/// the indexing. The rig fit explains the expressions and the jaw together. It keeps the
/// initial pose when it does not fit the bundles better.
pub fn refine_pose(
    index: &super::LgiIndex,
    bundles: &[Option<Point3<f64>>],
    initial: JawPose,
    cache: &mut RigFitCache,
) -> JawPose {
    let Some(space) = &index.jaw else {
        return initial;
    };
    let rig = &space.rig;
    // Present markers (finite bundles): vertex, bundle, skinning weight, rest position.
    let usable = |y: &Option<Point3<f64>>| y.filter(|y| y.coords.iter().all(|c| c.is_finite()));
    let mask: Vec<bool> = bundles.iter().map(|y| usable(y).is_some()).collect();
    let present: Vec<(usize, Point3<f64>, f64, Point3<f64>)> = index
        .markers
        .iter()
        .zip(bundles)
        .filter_map(|(mi, y)| {
            let y = usable(y)?;
            let v = mi.vertex as usize;
            Some((v, y, rig.weights[v], index.neutral[v]))
        })
        .collect();
    let n = index.displacements.len();
    if present.is_empty() || n == 0 {
        return initial;
    }
    // The unskinned shapes at the present markers, contiguous, and their Gram matrix.
    if cache.present != mask || cache.gram.as_ref().is_none_or(|g| g.nrows() != n) {
        cache.basis.clear();
        for p in &present {
            cache
                .basis
                .extend(index.displacements.iter().map(|d| d[p.0]));
        }
        let rows = &cache.basis;
        let mut gram = nalgebra::DMatrix::<f64>::zeros(n, n);
        for row in rows.chunks_exact(n) {
            for a in 0..n {
                for b in a..n {
                    gram[(a, b)] += row[a].dot(&row[b]);
                }
            }
        }
        for a in 0..n {
            for b in a + 1..n {
                gram[(b, a)] = gram[(a, b)];
            }
        }
        let ridge = GRAM_RIDGE * gram.diagonal().mean().max(f64::MIN_POSITIVE);
        for a in 0..n {
            gram[(a, a)] += ridge;
        }
        cache.present = mask;
        cache.gram = Some(gram);
    }
    let (Some(gram), basis) = (cache.gram.as_ref(), &cache.basis) else {
        return initial;
    };
    // The rig's unskinned position of present marker `k` for weights `w`.
    let unskinned_at = |k: usize, x0: Point3<f64>, w: &[f64]| -> Point3<f64> {
        let mut p = x0;
        for (d, &ws) in basis[k * n..(k + 1) * n].iter().zip(w) {
            if ws != 0.0 {
                p += d * ws;
            }
        }
        p
    };
    let cost = |pose: &JawPose, w: &[f64]| -> f64 {
        let jaw = rig.jaw_transform(pose);
        present
            .iter()
            .enumerate()
            .map(|(k, &(_, y, sw, x0))| {
                let p = unskinned_at(k, x0, w);
                (rig.skin_point(&jaw, sw, &p) - y).norm_squared()
            })
            .sum()
    };
    // The bounded least squares of the weights given the pose: the project's exact box QP
    // (the blendshape baseline's), warm-started from the previous round's weights.
    let fit_weights = |pose: &JawPose, w: &mut [f64]| {
        let jaw = rig.jaw_transform(pose);
        let mut h = nalgebra::DVector::<f64>::zeros(n);
        for (k, &(_, y, sw, x0)) in present.iter().enumerate() {
            let r = rig.unskin_point(&jaw, sw, &y) - x0;
            for (hs, d) in h.iter_mut().zip(&basis[k * n..(k + 1) * n]) {
                *hs += d.dot(&r);
            }
        }
        let start = nalgebra::DVector::from_column_slice(w);
        let solved = box_qp(gram, &h, &start, WEIGHT_ITERATIONS);
        w.copy_from_slice(solved.as_slice());
    };
    let fit_pose = |pose: JawPose, w: &[f64]| -> JawPose {
        let mut pose = pose;
        let unskinned: Vec<(Point3<f64>, f64, Point3<f64>)> = present
            .iter()
            .enumerate()
            .map(|(k, &(_, y, sw, x0))| (unskinned_at(k, x0, w), sw, y))
            .collect();
        let residuals = |q: &JawPose| -> Vec<Vector3<f64>> {
            let jaw = rig.jaw_transform(q);
            unskinned
                .iter()
                .map(|(p, sw, y)| rig.skin_point(&jaw, *sw, p) - y)
                .collect()
        };
        let as_array = |q: &JawPose| [q.open_rad, q.lateral_rad, q.forward_mm];
        let from_array = |a: [f64; 3]| JawPose {
            open_rad: a[0],
            lateral_rad: a[1],
            forward_mm: a[2],
        };
        const STEPS: [f64; 3] = [1e-5, 1e-5, 1e-4];
        for _ in 0..3 {
            let r0 = residuals(&pose);
            let base = as_array(&pose);
            let cols: [Vec<Vector3<f64>>; 3] = [0, 1, 2].map(|k| {
                let mut a = base;
                a[k] += STEPS[k];
                residuals(&from_array(a))
                    .iter()
                    .zip(&r0)
                    .map(|(a, b)| (a - b) / STEPS[k])
                    .collect()
            });
            let mut jtj = nalgebra::Matrix3::<f64>::zeros();
            let mut jtr = Vector3::<f64>::zeros();
            for a in 0..3 {
                for b in 0..3 {
                    jtj[(a, b)] = cols[a].iter().zip(&cols[b]).map(|(x, y)| x.dot(y)).sum();
                }
                jtr[a] = cols[a].iter().zip(&r0).map(|(x, y)| x.dot(y)).sum();
            }
            let damped = jtj + nalgebra::Matrix3::from_diagonal(&jtj.diagonal()) * 1e-6;
            let Some(step) = damped.try_inverse().map(|inv| inv * jtr) else {
                break;
            };
            let next = from_array([base[0] - step[0], base[1] - step[1], base[2] - step[2]]);
            if !(next.open_rad.is_finite()
                && next.lateral_rad.is_finite()
                && next.forward_mm.is_finite())
            {
                break;
            }
            pose = next;
        }
        pose
    };
    let mut w = vec![0.0; n];
    let mut pose = initial;
    fit_weights(&pose, &mut w);
    let start = cost(&initial, &w);
    for _ in 0..RIG_FIT_ROUNDS {
        let next = fit_pose(pose, &w);
        let moved = (next.open_rad - pose.open_rad)
            .abs()
            .max((next.lateral_rad - pose.lateral_rad).abs())
            .max((next.forward_mm - pose.forward_mm).abs() * 1e-2);
        pose = next;
        fit_weights(&pose, &mut w);
        if moved < POSE_CONVERGED_RAD {
            break;
        }
    }
    if cost(&pose, &w) < start {
        pose
    } else {
        initial
    }
}
