//! Example-based facial rigging (Li, Weise & Pauly 2010, §3), the entry type
//! [`RigBuilder`].
//!
//! # The method
//! A template rig `𝒜 = {A₀, A₁ … Aₙ}` (rest pose plus additive displacements), the actor's
//! rest pose `B₀` and training poses `S₁ … S_m` in the template's topology, each with rough
//! user weights `α*_ij`. Unknown: actor blendshapes `Bᵢ` and weights `α_ij` such that
//! `S_j ≈ B₀ + Σᵢ α_ij Bᵢ`. The paper numbers no equations; its energies are cited by name:
//!
//! - **Step A** (blendshapes, weights fixed), per triangle, in the space of triangle frames
//!   `M = [v₂ − v₁, v₃ − v₁]` (the normal column ignored, after Botsch et al. 2006):
//!   - `E_fit = Σ_j ‖M_j^S − (M₀^B + Σᵢ α_ij Mᵢ^B)‖²_F`,
//!   - `E_reg = Σᵢ wᵢ ‖Mᵢ^B − Mᵢ^{A*}‖²_F` with `Mᵢ^{A*} = G_{A₀→A₀+Aᵢ} M₀^B − M₀^B` (the
//!     template's deformation gradient applied to the actor's rest frame) and
//!     `wᵢ = ((1 + ‖Mᵢ^A‖_F)/(κ + ‖Mᵢ^A‖_F))^θ`, `Mᵢ^A` the template blendshape's frame
//!     (the frame change it causes), so that triangles the template keeps still stay still,
//!   - `E_A = E_fit + β E_reg`, a linear least-squares problem per triangle whose normal
//!     equations `(α αᵀ + β W) X = α R + β W P` (`n × n`, rank-`m` update of a diagonal) are
//!     solved by the Woodbury identity in `O(n m²)` per triangle;
//!
//!   then each blendshape's vertices are reconstructed from its frames by least squares
//!   (Sumner & Popović 2004 §4, in the area-weighted gradient form, i.e. a cotangent
//!   Poisson system, factored once per blendshape), with every vertex the template
//!   blendshape leaves in place held fixed ("to prevent undesirable drifting").
//! - **Step B** (weights, blendshapes fixed), per example:
//!   `E_B = Σ_k ‖v_k^{S_j} − (v_k^{B₀} + Σᵢ α_ij v_k^{Bᵢ})‖² + γ Σᵢ (α_ij − α*_ij)²`,
//!   subject to `0 ≤ α ≤ 1`, plus the penalty `μ (α_ij α_kj)²` for every mutually exclusive
//!   pair `(i, k)`. The paper solves this non-linear least-squares problem with bound
//!   constraints by a trust-region method (Coleman & Li 1996); we take Gauss-Newton steps,
//!   each an exact bounded QP ([`box_qp`]), with a backtracking line search on `E_B`.
//! - **Schedule** (§4): 10 alternations A, B; β falls from 0.5 to 0.1 and γ from 1000 to
//!   100, geometrically (the paper says only "gradually").
//! - **Inexpressible examples** (§4, Limitations): an example whose frame residual
//!   `E_fit` stays above a threshold after the last alternation is reported.
//!
//! # Deviations and choices
//! - Frames: the deformation gradients `G` use Sumner & Popović's normal
//!   `n/√‖n‖` (see [`triangle_frame`]) rather than the paper's unnormalized cross product,
//!   so that a uniform scale maps normals like edges.
//! - The reconstruction minimizes `Σ_t area_t ‖∇_t d − D_t‖²` (Botsch et al. 2006) rather
//!   than Sumner & Popović's unweighted sum, so that dense and coarse regions count by
//!   area; a tiny pull (`1e-6` relative) toward the template displacement fixes the
//!   translation of a component without any still vertex.
//! - `wᵢ` and the frames are in millimetres (the paper gives no unit): `κ = 0.1` means a
//!   triangle whose edges change by 0.1 mm counts as moving.

use std::time::Instant;

use nalgebra::{DMatrix, DVector, Matrix3, Matrix3x2, Point3, Vector2, Vector3};
use nalgebra_sparse::{CooMatrix, CsrMatrix};
use rayon::prelude::*;

use super::RigError;
use crate::dataset::{Dataset, Shape};
use crate::enhance::{PoissonParams, rest_frame_inverses, triangle_frame};
use crate::numeric::SpdFactor;
use crate::numeric::box_qp;

/// Tuning of [`RigBuilder`]; defaults are the paper's values (Li et al. 2010 §3-4).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RigParams {
    /// Number of alternations of step A (blendshapes) and step B (weights). Default 10.
    pub alternations: usize,
    /// β of `E_A = E_fit + β E_reg` in the first alternation: larger stays closer to
    /// deformation transfer. Default 0.5.
    pub beta_start: f64,
    /// β in the last alternation (geometric interpolation in between). Below about 0.05 the
    /// paper sees over-fitting. Default 0.1.
    pub beta_end: f64,
    /// γ of the weight prior `γ Σ (α − α*)²` in step B, first alternation (mm², since the
    /// fitting term is a sum of squared millimetres over all vertices). Default 1000.
    pub gamma_start: f64,
    /// γ in the last alternation. Default 100.
    pub gamma_end: f64,
    /// κ of the regularization weights `wᵢ = ((1 + ‖Mᵢ^A‖)/(κ + ‖Mᵢ^A‖))^θ`, mm. Default 0.1.
    pub kappa: f64,
    /// θ of the regularization weights (the paper: θ ≥ 1). Default 2.
    pub theta: f64,
    /// A vertex whose template displacement is below this (mm) "stays put" in that
    /// blendshape and is held fixed in the actor's blendshape. Default 0.01 mm.
    pub stationary_mm: f64,
    /// Weight μ of the penalty `μ (αᵢ α_k)²` of a mutually exclusive pair, relative to the
    /// mean squared norm of the actor blendshapes (the diagonal of the step-B Gram matrix).
    /// Default 10.
    pub exclusive_weight: f64,
    /// Gauss-Newton steps of step B per example and alternation (each one bounded QP);
    /// without exclusive pairs one step is exact. Default 8.
    pub weight_steps: usize,
    /// An example whose relative frame residual `√(E_fit / Σ_t ‖M_j^S − M₀^B‖²)` exceeds
    /// this after the last alternation cannot be expressed by the template's blendshapes
    /// (Li §4, Limitations) and is reported. Default 0.5 (half the example's deformation
    /// left unexplained).
    pub inexpressible_residual: f64,
}

impl Default for RigParams {
    fn default() -> Self {
        Self {
            alternations: 10,
            beta_start: 0.5,
            beta_end: 0.1,
            gamma_start: 1000.0,
            gamma_end: 100.0,
            kappa: 0.1,
            theta: 2.0,
            stationary_mm: 0.01,
            exclusive_weight: 10.0,
            weight_steps: 8,
            inexpressible_residual: 0.5,
        }
    }
}

impl RigParams {
    /// Checks every field.
    ///
    /// # Errors
    /// [`RigError::InvalidParam`] naming the first bad field.
    pub fn validate(&self) -> Result<(), RigError> {
        let pos = |x: f64| x.is_finite() && x > 0.0;
        let nonneg = |x: f64| x.is_finite() && x >= 0.0;
        if self.alternations == 0 {
            return Err(RigError::invalid("alternations", 0.0, "must be at least 1"));
        }
        for (field, v) in [
            ("beta_start", self.beta_start),
            ("beta_end", self.beta_end),
            ("kappa", self.kappa),
            ("theta", self.theta),
            ("inexpressible_residual", self.inexpressible_residual),
        ] {
            if !pos(v) {
                return Err(RigError::invalid(field, v, "must be finite and > 0"));
            }
        }
        for (field, v) in [
            ("gamma_start", self.gamma_start),
            ("gamma_end", self.gamma_end),
            ("stationary_mm", self.stationary_mm),
            ("exclusive_weight", self.exclusive_weight),
        ] {
            if !nonneg(v) {
                return Err(RigError::invalid(field, v, "must be finite and >= 0"));
            }
        }
        if self.weight_steps == 0 {
            return Err(RigError::invalid("weight_steps", 0.0, "must be at least 1"));
        }
        Ok(())
    }

    /// (β, γ) of alternation `k` of `self.alternations`: geometric from the start to the
    /// end values.
    pub fn schedule(&self, k: usize) -> (f64, f64) {
        let t = if self.alternations > 1 {
            k as f64 / (self.alternations - 1) as f64
        } else {
            0.0
        };
        let geo = |a: f64, b: f64| {
            if a > 0.0 && b > 0.0 {
                a * (b / a).powf(t)
            } else {
                a + (b - a) * t
            }
        };
        (
            geo(self.beta_start, self.beta_end),
            geo(self.gamma_start, self.gamma_end),
        )
    }
}

/// One training pose `S_j` with the user's rough weights `α*_j`.
#[derive(Debug, Clone, PartialEq)]
pub struct Example {
    /// Name, for reports.
    pub name: String,
    /// Vertex positions (#V, mm, the template's topology and the actor's head frame).
    pub positions: Vec<Point3<f64>>,
    /// Initial weight of every template blendshape (#n, in template order; 0 to 1).
    pub initial_weights: Vec<f64>,
}

/// How well the rig reproduces one example.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ExampleFit {
    /// RMS vertex distance between the example and `B₀ + Σ αᵢ Bᵢ`, mm.
    pub vertex_rms_mm: f64,
    /// Largest vertex distance, mm.
    pub vertex_max_mm: f64,
    /// Relative frame residual `√(E_fit / Σ_t ‖M_j^S − M₀^B‖²)` of the reconstructed rig
    /// (0 = perfect, 1 = nothing of the example's deformation explained).
    pub frame_residual: f64,
}

/// Progress of one alternation.
#[derive(Debug, Clone, PartialEq)]
pub struct IterationReport {
    /// 0-based alternation.
    pub iteration: usize,
    /// Total alternations.
    pub of: usize,
    /// β used in step A.
    pub beta: f64,
    /// γ used in step B.
    pub gamma: f64,
    /// Fit of every example after step B.
    pub fits: Vec<ExampleFit>,
    /// Wall time of the alternation (steps A and B and the report), seconds.
    pub seconds: f64,
    /// Wall time of its parts, seconds: step A frames, step A vertex reconstruction,
    /// step B weights.
    pub step_seconds: [f64; 3],
}

/// The actor rig.
#[derive(Debug, Clone, PartialEq)]
pub struct Rig {
    /// Blendshape names (the template's shape names).
    pub names: Vec<String>,
    /// The actor's rest pose `B₀` (#V, mm).
    pub neutral: Vec<Point3<f64>>,
    /// The actor blendshapes `Bᵢ` as displacements from `B₀` (n × #V, mm).
    pub displacements: Vec<Vec<Vector3<f64>>>,
    /// Optimized weights `α_j` of every example (m × n).
    pub weights: Vec<Vec<f64>>,
    /// Final fit of every example.
    pub fits: Vec<ExampleFit>,
    /// Examples (indices) the template cannot express: frame residual above
    /// [`RigParams::inexpressible_residual`].
    pub inexpressible: Vec<usize>,
}

impl Rig {
    /// Absolute positions `B₀ + Bᵢ` of blendshape `i`; `None` when out of range.
    pub fn shape(&self, i: usize) -> Option<Vec<Point3<f64>>> {
        let d = self.displacements.get(i)?;
        Some(self.neutral.iter().zip(d).map(|(p, d)| p + d).collect())
    }

    /// `B₀ + Σᵢ wᵢ Bᵢ`.
    pub fn evaluate(&self, weights: &[f64]) -> Vec<Point3<f64>> {
        let mut out = self.neutral.clone();
        for (d, &w) in self.displacements.iter().zip(weights) {
            if w != 0.0 {
                for (p, d) in out.iter_mut().zip(d) {
                    *p += d * w;
                }
            }
        }
        out
    }

    /// The rig as a dataset named `name`: `B₀` with the template's topology, UVs and face
    /// vertices, one shape per blendshape. The template's jaw rig is not carried over (its
    /// pivot belongs to the template's head).
    ///
    /// # Errors
    /// [`RigError::Mesh`] when `B₀` does not fit the template mesh (cannot happen for a rig
    /// built from that template).
    pub fn to_dataset(&self, template: &Dataset, name: &str) -> Result<Dataset, RigError> {
        let neutral = template.neutral.with_positions(self.neutral.clone())?;
        let shapes = (0..self.displacements.len())
            .filter_map(|i| {
                Some(Shape {
                    name: self.names.get(i)?.clone(),
                    positions: self.shape(i)?,
                    jaw: None,
                })
            })
            .collect();
        Ok(Dataset {
            name: name.to_string(),
            neutral,
            shapes,
            face_vertices: template.face_vertices.clone(),
            jaw: None,
        })
    }
}

/// Reconstruction of one blendshape's displacement from its triangle frames: the
/// prefactored Poisson system on the vertices the template blendshape moves.
struct ShapeSystem {
    /// Global index of every free vertex.
    free: Vec<u32>,
    /// Local index of every vertex (`u32::MAX` when fixed).
    local: Vec<u32>,
    /// Anchor weight of every free vertex (tiny; fixes translation).
    anchor: Vec<f64>,
    /// `None` when no vertex moves (the blendshape is zero).
    factor: Option<SpdFactor>,
}

/// Everything of example-based rigging that does not depend on the examples: template and
/// actor frames, the regularization targets and weights, and one factored reconstruction
/// system per blendshape. Build once, then call [`RigBuilder::build`] with any examples.
pub struct RigBuilder {
    params: RigParams,
    names: Vec<String>,
    triangles: Vec<[u32; 3]>,
    /// `B₀` (#V).
    neutral: Vec<Point3<f64>>,
    /// Template displacements `Aᵢ` (n × #V).
    template_displacements: Vec<Vec<Vector3<f64>>>,
    /// `M₀^B` of every triangle.
    rest_frames: Vec<Matrix3x2<f64>>,
    /// `Mᵢ^{A*}`, triangle-major (`t·n + i`).
    targets: Vec<Matrix3x2<f64>>,
    /// `wᵢ`, triangle-major.
    reg_weights: Vec<f64>,
    /// Per triangle and corner: `area · E⁺ ∇φ_k` (E the rest frame), so that a displacement
    /// frame `C` contributes `C q_k` to the Poisson right-hand side of corner k.
    corner_coefficients: Vec<[Vector2<f64>; 3]>,
    systems: Vec<ShapeSystem>,
}

impl std::fmt::Debug for RigBuilder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RigBuilder")
            .field("vertices", &self.neutral.len())
            .field("triangles", &self.triangles.len())
            .field("blendshapes", &self.names.len())
            .finish_non_exhaustive()
    }
}

/// Frame `[b − a, c − a]` of triangle `t` (the linear columns of Li's local frame).
fn frame2(t: &[u32; 3], p: &[Point3<f64>]) -> Matrix3x2<f64> {
    let [a, b, c] = t.map(|v| p[v as usize]);
    Matrix3x2::from_columns(&[b - a, c - a])
}

/// Frame of a displacement field on triangle `t`.
fn dframe2(t: &[u32; 3], d: &[Vector3<f64>]) -> Matrix3x2<f64> {
    let [a, b, c] = t.map(|v| d[v as usize]);
    Matrix3x2::from_columns(&[b - a, c - a])
}

/// Gradients of the three hat functions of triangle `t` at `p` (1/mm) and its area.
fn hat_gradients(t: &[u32; 3], p: &[Point3<f64>]) -> ([Vector3<f64>; 3], f64) {
    let [a, b, c] = t.map(|v| p[v as usize]);
    let n = (b - a).cross(&(c - a));
    let nn = n.norm_squared();
    if nn <= 0.0 {
        return ([Vector3::zeros(); 3], 0.0);
    }
    (
        [c - b, a - c, b - a].map(|e| n.cross(&e) / nn),
        0.5 * nn.sqrt(),
    )
}

impl RigBuilder {
    /// Prepares rigging from `template` (its neutral is `A₀`, its shapes are `A₀ + Aᵢ`) to
    /// the actor whose rest pose is `neutral` (#V, mm, same topology, same head frame).
    ///
    /// # Errors
    /// [`RigError::InvalidParam`] for bad params, [`RigError::Input`] when `neutral` does
    /// not fit the template or the template has no shapes, [`RigError::Factor`] when a
    /// reconstruction system cannot be factored.
    pub fn new(
        template: &Dataset,
        neutral: &[Point3<f64>],
        params: &RigParams,
    ) -> Result<Self, RigError> {
        params.validate()?;
        let nv = template.vertex_count();
        if neutral.len() != nv {
            return Err(RigError::Input(format!(
                "the actor neutral has {} vertices, the template {nv}",
                neutral.len()
            )));
        }
        if template.shapes.is_empty() {
            return Err(RigError::Input("the template has no blendshapes".into()));
        }
        if let Some(v) = neutral
            .iter()
            .position(|p| !p.iter().all(|c| c.is_finite()))
        {
            return Err(RigError::Input(format!(
                "the actor neutral's vertex {v} is not finite"
            )));
        }
        let triangles = template.neutral.triangles.clone();
        let a0 = &template.neutral.positions;
        let n = template.shapes.len();
        let names: Vec<String> = template.shapes.iter().map(|s| s.name.clone()).collect();
        let template_displacements: Vec<Vec<Vector3<f64>>> = template
            .shapes
            .par_iter()
            .map(|s| s.positions.iter().zip(a0).map(|(p, q)| p - q).collect())
            .collect();
        let rest_frames: Vec<Matrix3x2<f64>> =
            triangles.iter().map(|t| frame2(t, neutral)).collect();
        let template_inverses = rest_frame_inverses(&triangles, a0);
        // Regularization targets and weights, triangle-major.
        let (kappa, theta) = (params.kappa, params.theta);
        let per_triangle: Vec<(Vec<Matrix3x2<f64>>, Vec<f64>)> = triangles
            .par_iter()
            .enumerate()
            .map(|(ti, t)| {
                let [a, b, c] = t.map(|v| a0[v as usize]);
                let rest_a = Matrix3x2::from_columns(&[b - a, c - a]);
                let mut targets = Vec::with_capacity(n);
                let mut weights = Vec::with_capacity(n);
                for s in &template.shapes {
                    let [pa, pb, pc] = t.map(|v| s.positions[v as usize]);
                    // G_{A₀→A₀+Aᵢ} (Sumner & Popović Eq. 3) applied to the actor's frame.
                    let g: Matrix3<f64> = triangle_frame(&pa, &pb, &pc) * template_inverses[ti];
                    targets.push((g - Matrix3::identity()) * rest_frames[ti]);
                    let ma = Matrix3x2::from_columns(&[pb - pa, pc - pa]) - rest_a;
                    let norm = ma.norm();
                    weights.push(((1.0 + norm) / (kappa + norm)).powf(theta));
                }
                (targets, weights)
            })
            .collect();
        let mut targets = Vec::with_capacity(triangles.len() * n);
        let mut reg_weights = Vec::with_capacity(triangles.len() * n);
        for (t, w) in per_triangle {
            targets.extend(t);
            reg_weights.extend(w);
        }
        // Poisson stiffness K_jk = Σ_t area_t ∇φ_j·∇φ_k on B₀, and the corner coefficients.
        let mut corner_coefficients = Vec::with_capacity(triangles.len());
        let mut coo = CooMatrix::new(nv, nv);
        let mut lumped = vec![0.0; nv];
        for (t, frame) in triangles.iter().zip(&rest_frames) {
            let (grads, area) = hat_gradients(t, neutral);
            let pinv = (frame.transpose() * frame)
                .try_inverse()
                .map(|inv| inv * frame.transpose());
            let q = match pinv {
                Some(p) if area > 0.0 => grads.map(|g| p * g * area),
                _ => [Vector2::zeros(); 3],
            };
            corner_coefficients.push(q);
            for j in 0..3 {
                lumped[t[j] as usize] += area / 3.0;
                for k in 0..3 {
                    coo.push(t[j] as usize, t[k] as usize, area * grads[j].dot(&grads[k]));
                }
            }
        }
        let stiffness = CsrMatrix::from(&coo);
        let mean_area = lumped.iter().sum::<f64>() / nv.max(1) as f64;
        let mean_area = if mean_area > 0.0 { mean_area } else { 1.0 };
        let anchor_weight = PoissonParams::default().anchor_weight;
        let stationary = params.stationary_mm;
        let systems = template_displacements
            .par_iter()
            .map(|d| {
                let mut local = vec![u32::MAX; nv];
                let mut free = Vec::new();
                for (v, dv) in d.iter().enumerate() {
                    if dv.norm() >= stationary {
                        local[v] = free.len() as u32;
                        free.push(v as u32);
                    }
                }
                let anchor: Vec<f64> = free
                    .iter()
                    .map(|&v| anchor_weight * (lumped[v as usize] / mean_area).max(1e-3))
                    .collect();
                let factor = if free.is_empty() {
                    None
                } else {
                    let mut sub = CooMatrix::new(free.len(), free.len());
                    for (a, &v) in free.iter().enumerate() {
                        let row = stiffness.row(v as usize);
                        for (&c, &val) in row.col_indices().iter().zip(row.values()) {
                            let b = local[c];
                            if b != u32::MAX {
                                sub.push(a, b as usize, val);
                            }
                        }
                        sub.push(a, a, anchor[a]);
                    }
                    Some(SpdFactor::new(
                        &CsrMatrix::from(&sub),
                        "blendshape reconstruction",
                    )?)
                };
                Ok(ShapeSystem {
                    free,
                    local,
                    anchor,
                    factor,
                })
            })
            .collect::<Result<Vec<_>, RigError>>()?;
        Ok(Self {
            params: *params,
            names,
            triangles,
            neutral: neutral.to_vec(),
            template_displacements,
            rest_frames,
            targets,
            reg_weights,
            corner_coefficients,
            systems,
        })
    }

    /// Number of blendshapes `n`.
    pub fn blendshape_count(&self) -> usize {
        self.names.len()
    }

    /// Blendshape names, in template order.
    pub fn names(&self) -> &[String] {
        &self.names
    }

    /// The parameters.
    pub fn params(&self) -> &RigParams {
        &self.params
    }

    /// Runs the alternation (Li §3-4) on `examples`, with `exclusive` pairs of blendshape
    /// indices that must not be active together. `on_iteration` sees every alternation's
    /// fit. With no examples the result is deformation transfer of the template.
    ///
    /// # Errors
    /// [`RigError::Input`] when an example does not fit the template (vertex or weight
    /// count, non-finite values) or a pair names a blendshape out of range or twice.
    pub fn build(
        &self,
        examples: &[Example],
        exclusive: &[(usize, usize)],
        on_iteration: &mut dyn FnMut(&IterationReport),
    ) -> Result<Rig, RigError> {
        let n = self.names.len();
        let nv = self.neutral.len();
        let m = examples.len();
        for e in examples {
            if e.positions.len() != nv {
                return Err(RigError::Input(format!(
                    "example {}: {} vertices, the template has {nv}",
                    e.name,
                    e.positions.len()
                )));
            }
            if e.initial_weights.len() != n {
                return Err(RigError::Input(format!(
                    "example {}: {} initial weights for {n} blendshapes",
                    e.name,
                    e.initial_weights.len()
                )));
            }
            if !e.initial_weights.iter().all(|w| w.is_finite())
                || !e.positions.iter().all(|p| p.iter().all(|c| c.is_finite()))
            {
                return Err(RigError::Input(format!(
                    "example {}: non-finite weight or position",
                    e.name
                )));
            }
        }
        for &(a, b) in exclusive {
            if a >= n || b >= n || a == b {
                return Err(RigError::Input(format!(
                    "exclusive pair ({a}, {b}) is not two different blendshapes of {n}"
                )));
            }
        }
        if m == 0 {
            // Step A with E_fit empty: M_i^B = M_i^{A*}, i.e. deformation transfer.
            let displacements = self.reconstruct(&self.targets);
            return Ok(Rig {
                names: self.names.clone(),
                neutral: self.neutral.clone(),
                displacements,
                weights: Vec::new(),
                fits: Vec::new(),
                inexpressible: Vec::new(),
            });
        }
        let nt = self.triangles.len();
        // R_j = M_j^S − M₀^B, triangle-major (t·m + j).
        let residual_frames: Vec<Matrix3x2<f64>> = (0..nt)
            .into_par_iter()
            .flat_map_iter(|ti| {
                let t = &self.triangles[ti];
                let rest = self.rest_frames[ti];
                examples.iter().map(move |e| frame2(t, &e.positions) - rest)
            })
            .collect();
        let example_energy: Vec<f64> = (0..m)
            .map(|j| {
                (0..nt)
                    .map(|ti| residual_frames[ti * m + j].norm_squared())
                    .sum()
            })
            .collect();
        let prior: Vec<DVector<f64>> = examples
            .iter()
            .map(|e| DVector::from_iterator(n, e.initial_weights.iter().map(|w| w.clamp(0.0, 1.0))))
            .collect();
        let offsets: Vec<Vec<Vector3<f64>>> = examples
            .iter()
            .map(|e| {
                e.positions
                    .iter()
                    .zip(&self.neutral)
                    .map(|(s, b)| s - b)
                    .collect()
            })
            .collect();
        let mut alpha = prior.clone();
        let mut frames = vec![Matrix3x2::zeros(); nt * n];
        let mut displacements = Vec::new();
        let mut fits = Vec::new();
        for k in 0..self.params.alternations {
            let start = Instant::now();
            let (beta, gamma) = self.params.schedule(k);
            self.step_a(&alpha, &residual_frames, beta, &mut frames);
            let t_frames = start.elapsed().as_secs_f64();
            displacements = self.reconstruct(&frames);
            let t_reconstruct = start.elapsed().as_secs_f64();
            alpha = self.step_b(&displacements, &offsets, &prior, &alpha, gamma, exclusive);
            let t_weights = start.elapsed().as_secs_f64();
            fits = self.fits(&displacements, &offsets, &alpha, &example_energy);
            on_iteration(&IterationReport {
                iteration: k,
                of: self.params.alternations,
                beta,
                gamma,
                fits: fits.clone(),
                seconds: start.elapsed().as_secs_f64(),
                step_seconds: [
                    t_frames,
                    t_reconstruct - t_frames,
                    t_weights - t_reconstruct,
                ],
            });
        }
        let inexpressible: Vec<usize> = fits
            .iter()
            .enumerate()
            .filter(|(_, f)| f.frame_residual > self.params.inexpressible_residual)
            .map(|(j, _)| j)
            .collect();
        for &j in &inexpressible {
            tracing::warn!(
                "example {} cannot be expressed by the template's blendshapes: {:.0} % of its \
                 deformation is left unexplained (RMS {:.2} mm); add a blendshape for it",
                examples[j].name,
                fits[j].frame_residual * 100.0,
                fits[j].vertex_rms_mm
            );
        }
        Ok(Rig {
            names: self.names.clone(),
            neutral: self.neutral.clone(),
            displacements,
            weights: alpha.iter().map(|a| a.iter().copied().collect()).collect(),
            fits,
            inexpressible,
        })
    }

    /// Step A: the frames `Mᵢ^B` minimizing `E_fit + β E_reg` per triangle, written to
    /// `frames` (triangle-major). Solved by Woodbury over the blendshapes some example
    /// uses; the others get `Mᵢ^{A*}` exactly.
    fn step_a(
        &self,
        alpha: &[DVector<f64>],
        residual_frames: &[Matrix3x2<f64>],
        beta: f64,
        frames: &mut [Matrix3x2<f64>],
    ) {
        let n = self.names.len();
        let m = alpha.len();
        // Per active blendshape, the examples using it: (j, α_ij), α_ij ≠ 0.
        let active: Vec<(usize, Vec<(usize, f64)>)> = (0..n)
            .filter_map(|i| {
                let uses: Vec<(usize, f64)> = alpha
                    .iter()
                    .enumerate()
                    .filter(|(_, a)| a[i] != 0.0)
                    .map(|(j, a)| (j, a[i]))
                    .collect();
                (!uses.is_empty()).then_some((i, uses))
            })
            .collect();
        frames.par_chunks_mut(n).enumerate().for_each_init(
            || {
                (
                    DMatrix::<f64>::zeros(m, m),
                    DMatrix::<f64>::zeros(m, 6),
                    Vec::with_capacity(active.len()),
                )
            },
            |(s, y, z), (ti, out)| {
                let p = &self.targets[ti * n..(ti + 1) * n];
                let w = &self.reg_weights[ti * n..(ti + 1) * n];
                let r = &residual_frames[ti * m..(ti + 1) * m];
                out.copy_from_slice(p);
                if active.is_empty() {
                    return;
                }
                // z_i = (Σ_j α_ij R_j)/d_i + P_i, S = I + Σ_i α_i α_iᵀ/d_i, y = Σ_i α_i z_iᵀ,
                // with d_i = β w_i; then X_i = z_i − (Σ_j α_ij U_j)/d_i for U = S⁻¹ y.
                s.fill(0.0);
                s.fill_diagonal(1.0);
                y.fill(0.0);
                z.clear();
                for (i, uses) in &active {
                    let inv_d = 1.0 / (beta * w[*i]);
                    let mut zi = p[*i];
                    for &(j, a) in uses {
                        zi += r[j] * (a * inv_d);
                    }
                    for &(j, aj) in uses {
                        for &(l, al) in uses {
                            s[(j, l)] += aj * al * inv_d;
                        }
                        for c in 0..6 {
                            y[(j, c)] += aj * zi[c];
                        }
                    }
                    z.push((zi, inv_d));
                }
                let Some(chol) = s.clone().cholesky() else {
                    return;
                };
                let u = chol.solve(y);
                for ((i, uses), (zi, inv_d)) in active.iter().zip(z.iter()) {
                    let mut x = *zi;
                    for &(j, aj) in uses {
                        for c in 0..6 {
                            x[c] -= aj * u[(j, c)] * inv_d;
                        }
                    }
                    out[*i] = x;
                }
            },
        );
    }

    /// Reconstructs every blendshape's displacement from its frames (triangle-major).
    fn reconstruct(&self, frames: &[Matrix3x2<f64>]) -> Vec<Vec<Vector3<f64>>> {
        let n = self.names.len();
        let nv = self.neutral.len();
        (0..n)
            .into_par_iter()
            .map(|i| {
                let sys = &self.systems[i];
                let mut out = vec![Vector3::zeros(); nv];
                let Some(factor) = &sys.factor else {
                    return out;
                };
                let template = &self.template_displacements[i];
                let mut rhs: Vec<Vector3<f64>> = sys
                    .free
                    .iter()
                    .zip(&sys.anchor)
                    .map(|(&v, &e)| template[v as usize] * e)
                    .collect();
                for (ti, (t, q)) in self
                    .triangles
                    .iter()
                    .zip(&self.corner_coefficients)
                    .enumerate()
                {
                    let c = frames[ti * n + i];
                    for k in 0..3 {
                        let l = sys.local[t[k] as usize];
                        if l != u32::MAX {
                            rhs[l as usize] += c * q[k];
                        }
                    }
                }
                factor.solve3(&mut rhs);
                for (&v, d) in sys.free.iter().zip(rhs) {
                    out[v as usize] = d;
                }
                out
            })
            .collect()
    }

    /// Step B: the weights of every example minimizing `E_B` plus the exclusive-pair
    /// penalties, within `[0, 1]`.
    fn step_b(
        &self,
        displacements: &[Vec<Vector3<f64>>],
        offsets: &[Vec<Vector3<f64>>],
        prior: &[DVector<f64>],
        current: &[DVector<f64>],
        gamma: f64,
        exclusive: &[(usize, usize)],
    ) -> Vec<DVector<f64>> {
        let n = displacements.len();
        let dot = |a: &[Vector3<f64>], b: &[Vector3<f64>]| -> f64 {
            a.iter().zip(b).map(|(x, y)| x.dot(y)).sum()
        };
        // Gram matrix H = DᵀD.
        let rows: Vec<Vec<f64>> = (0..n)
            .into_par_iter()
            .map(|i| {
                (0..n)
                    .map(|k| {
                        if k < i {
                            0.0
                        } else {
                            dot(&displacements[i], &displacements[k])
                        }
                    })
                    .collect()
            })
            .collect();
        let gram = DMatrix::from_fn(n, n, |i, k| if k >= i { rows[i][k] } else { rows[k][i] });
        let mean_diag = (0..n).map(|i| gram[(i, i)]).sum::<f64>() / n.max(1) as f64;
        let mu = self.params.exclusive_weight * mean_diag.max(f64::MIN_POSITIVE);
        offsets
            .par_iter()
            .zip(prior)
            .zip(current)
            .map(|((off, a_star), a_now)| {
                let c = DVector::from_iterator(n, displacements.iter().map(|d| dot(d, off)));
                let h0 = &gram + DMatrix::identity(n, n) * gamma;
                let g0 = &c + a_star * gamma;
                // ½ E_B up to a constant, with the exact penalties.
                let energy = |a: &DVector<f64>| {
                    let mut e = 0.5 * a.dot(&(&h0 * a)) - g0.dot(a);
                    for &(p, q) in exclusive {
                        e += 0.5 * mu * (a[p] * a[q]).powi(2);
                    }
                    e
                };
                let mut a = a_now.map(|x| x.clamp(0.0, 1.0));
                let steps = if exclusive.is_empty() {
                    1
                } else {
                    self.params.weight_steps
                };
                for _ in 0..steps {
                    // Gauss-Newton: r = √μ α_p α_q linearized at a.
                    let mut h = h0.clone();
                    let mut g = g0.clone();
                    for &(p, q) in exclusive {
                        let (ap, aq) = (a[p], a[q]);
                        let mut jac = DVector::zeros(n);
                        jac[p] += aq;
                        jac[q] += ap;
                        h += &jac * jac.transpose() * mu;
                        g += &jac * (mu * ap * aq);
                    }
                    let target = box_qp(&h, &g, &a, 10 * n + 20);
                    let e0 = energy(&a);
                    let mut t = 1.0;
                    let mut next = a.clone();
                    while t > 1e-4 {
                        let trial = &a + (&target - &a) * t;
                        if energy(&trial) <= e0 {
                            next = trial;
                            break;
                        }
                        t *= 0.5;
                    }
                    let moved = (&next - &a).amax();
                    a = next;
                    if moved < 1e-9 {
                        break;
                    }
                }
                a
            })
            .collect()
    }

    /// Fit of every example for the reconstructed blendshapes and weights.
    fn fits(
        &self,
        displacements: &[Vec<Vector3<f64>>],
        offsets: &[Vec<Vector3<f64>>],
        alpha: &[DVector<f64>],
        example_energy: &[f64],
    ) -> Vec<ExampleFit> {
        let nv = self.neutral.len();
        offsets
            .par_iter()
            .zip(alpha)
            .zip(example_energy)
            .map(|((off, a), &energy)| {
                let mut res: Vec<Vector3<f64>> = off.clone();
                for (d, &w) in displacements.iter().zip(a.iter()) {
                    if w != 0.0 {
                        for (r, d) in res.iter_mut().zip(d) {
                            *r -= d * w;
                        }
                    }
                }
                let sq: f64 = res.iter().map(|r| r.norm_squared()).sum();
                let max = res.iter().map(|r| r.norm()).fold(0.0, f64::max);
                let e_fit: f64 = self
                    .triangles
                    .iter()
                    .map(|t| dframe2(t, &res).norm_squared())
                    .sum();
                ExampleFit {
                    vertex_rms_mm: (sq / nv.max(1) as f64).sqrt(),
                    vertex_max_mm: max,
                    frame_residual: if energy > 0.0 {
                        (e_fit / energy).sqrt()
                    } else {
                        0.0
                    },
                }
            })
            .collect()
    }
}

/// Deformation transfer of every template blendshape to the actor in Sumner & Popović's
/// original form (2004 §3-4), independent of [`RigBuilder`]'s gradient-space solver: for
/// every blendshape, the actor positions `x` (with one fourth vertex per triangle as extra
/// unknowns, Eq. 1) minimize `Σ_t ‖T_t(x) − G_t‖²_F` (Eq. 5 with identity correspondence),
/// `T_t(x) = [x₂ − x₁, x₃ − x₁, x₄ − x₁] V_t⁻¹` the deformation gradient from the actor's
/// rest triangle and `G_t = G_{A₀→A₀+Aᵢ}` the template's (Eq. 3), with the vertices that the
/// template blendshape moves less than `stationary_mm` held at `B₀` (Li et al. 2010 §3).
/// Returns the absolute actor shapes (n × #V).
///
/// # Errors
/// [`RigError::Input`] when `neutral` does not fit the template; [`RigError::Factor`]
/// when a system cannot be factored.
pub fn deformation_transfer(
    template: &Dataset,
    neutral: &[Point3<f64>],
    stationary_mm: f64,
) -> Result<Vec<Vec<Point3<f64>>>, RigError> {
    let nv = template.vertex_count();
    if neutral.len() != nv {
        return Err(RigError::Input(format!(
            "the actor neutral has {} vertices, the template {nv}",
            neutral.len()
        )));
    }
    let tris = &template.neutral.triangles;
    let a0 = &template.neutral.positions;
    let template_inverses = rest_frame_inverses(tris, a0);
    let actor_inverses = rest_frame_inverses(tris, neutral);
    // Q_t = D V_t⁻¹ (4 × 3): T_t(x) row r = Σ_k Q_t[k] x_{k,r} over the corners 1-3 and
    // the fourth vertex.
    let q: Vec<nalgebra::Matrix4x3<f64>> = actor_inverses
        .iter()
        .map(|inv| {
            let d = nalgebra::Matrix4x3::new(
                -1.0, -1.0, -1.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0,
            );
            d * inv
        })
        .collect();
    let fourth: Vec<Point3<f64>> = tris
        .iter()
        .map(|t| {
            let f = triangle_frame(
                &neutral[t[0] as usize],
                &neutral[t[1] as usize],
                &neutral[t[2] as usize],
            );
            neutral[t[0] as usize] + f.column(2)
        })
        .collect();
    template
        .shapes
        .par_iter()
        .map(|s| {
            let gradients =
                crate::enhance::deformation_gradients(tris, &template_inverses, &s.positions);
            // Unknown numbering: free vertices, then one fourth vertex per triangle.
            let mut local = vec![u32::MAX; nv];
            let mut count = 0usize;
            for v in 0..nv {
                if (s.positions[v] - a0[v]).norm() >= stationary_mm {
                    local[v] = count as u32;
                    count += 1;
                }
            }
            let first_fourth = count;
            let total = count + tris.len();
            let index = |t: usize, k: usize| -> Option<usize> {
                if k == 3 {
                    Some(first_fourth + t)
                } else {
                    let l = local[tris[t][k] as usize];
                    (l != u32::MAX).then_some(l as usize)
                }
            };
            let mut coo = CooMatrix::new(total, total);
            let mut rhs = vec![Vector3::zeros(); total];
            for (ti, (qt, g)) in q.iter().zip(&gradients).enumerate() {
                let pos = |k: usize| {
                    if k == 3 {
                        fourth[ti]
                    } else {
                        neutral[tris[ti][k] as usize]
                    }
                };
                for a in 0..4 {
                    let Some(ia) = index(ti, a) else { continue };
                    let qa = qt.row(a);
                    // ∂/∂x_a: Σ_b (q_a·q_b) x_b = G q_aᵀ (row-wise), fixed corners to the rhs.
                    rhs[ia] += g * qa.transpose();
                    for b in 0..4 {
                        let w = qa.dot(&qt.row(b));
                        match index(ti, b) {
                            Some(ib) => coo.push(ia, ib, w),
                            None => rhs[ia] -= pos(b).coords * w,
                        }
                    }
                }
            }
            let factor = SpdFactor::new(&CsrMatrix::from(&coo), "deformation transfer")?;
            factor.solve3(&mut rhs);
            Ok(neutral
                .iter()
                .zip(&local)
                .map(|(p, &l)| {
                    if l == u32::MAX {
                        *p
                    } else {
                        Point3::from(rhs[l as usize])
                    }
                })
                .collect())
        })
        .collect()
}
