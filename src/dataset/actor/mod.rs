//! The built-in synthetic actor: a procedural head with a nonlinear expression model,
//! the default actor of the demo and of fast tests.
//!
//! # What it is
//! - One connected head skin (face, scalp, back of the head, the top of the neck) whose
//!   only boundary loops are the two eye openings (between the eyelid margins), the
//!   mouth opening (between the lips) and the neck, plus two closed eyeball spheres
//!   behind the eye openings. 18 355 vertices (10 104 of them face skin, 2 × 314
//!   eyeball), 18 350 polygons (quads, with triangles at the opening corners, the crown
//!   and the eyeball poles), edges of about 2 mm on the face (median 2.0, 95 % below
//!   2.7 mm, so wrinkles of 6–10 mm wavelength are resolved) and coarser ones toward the
//!   back of the head, the crown and the neck. Every identity has the same
//!   topology; the face-skin vertices come first (see [`Actor::face_vertex_count`]).
//! - Millimetres, head frame: y up, z forward (out of the face, toward helmet cameras),
//!   x toward the actor's left (so `_L` expressions move +x vertices), origin roughly at
//!   the centre of the head.
//! - Identity from [`ActorParams`] (head, face, nose, jaw, lips, eyes, brow, cheeks,
//!   chin, wrinkles), or a random plausible one from [`ActorParams::from_seed`].
//! - 36 ARKit / FACS style expressions (see [`Actor::expression_names`]) and a
//!   nonlinear ground-truth model [`Actor::evaluate`]:
//!
//!   `x(w) = T(θ(w)) · ( L(w) + Σ_i w_i·d_i + Σ_(a,b) w_a·w_b·c_ab + Σ_k s(a_k(w))·h_k·n )`
//!
//!   - `L(w)`: the skin with the eyelids in the state the weights ask for: the eye
//!     openings are re-warped in parameter space and the lids slide over the eyelid
//!     sphere (a blink closes the opening; lid closure saturates and a closed upper lid
//!     meets the lower lid wherever squint has raised it);
//!   - `d_i`: the soft-tissue field of expression `i` (compact, smooth masks in the
//!     face's parameter space, along the neutral's local frame);
//!   - `c_ab`: correctives for common pairs (smile + jawOpen, funnel + jawOpen,
//!     browDown + browInnerUp, blink + squint, smile_L + smile_R);
//!   - wrinkles: height fields `h_k` along the neutral normal `n` (forehead furrows,
//!     glabella lines, crow's feet, nasolabial folds, bunny lines, chin dimpling), with
//!     depth `s(a) = smoothstep(0, 1, a)` of an activation `a_k = Σ coefficient·w`,
//!     which saturates;
//!   - `T(θ)`: linear-blend-skinned jaw rotation and protrusion ([`JawRig`]) about a
//!     pivot between the jaw joints, applied last (Cong et al. 2019 §6, Eq. 2), with
//!     `θ(w)` from `jawOpen` (0.30 rad), `jawLeft` / `jawRight` (±0.075 rad) and
//!     `jawForward` (6 mm).
//!
//!   So a linear blendshape fit of the expression shapes is not exact by construction.
//! - Region labels ([`Region`]) and named landmark vertices ([`Landmarks`]) that are
//!   the same for every identity.
//!
//! # What it is not
//! Not a photoreal or anatomically exact face: no teeth, tongue or mouth interior (the
//! mouth opening looks into the hollow head), no ears, no hair, eyebrows or lashes, no
//! nostril openings, no eye gaze (the eyeballs are plain spheres that never move), no
//! skin texture or pores, no tissue dynamics or collisions (lips can pass through each
//! other under extreme weights). Expression magnitudes are plausible, not measured.
//!
//! # Example
//! ```
//! use helmcap::dataset::actor::{Actor, ActorParams};
//! let actor = Actor::new(&ActorParams::default())?;
//! let dataset = actor.to_dataset();
//! assert_eq!(dataset.shapes.len(), actor.expression_names().len());
//! # Ok::<(), helmcap::dataset::actor::ActorError>(())
//! ```

mod expressions;
mod openings;
mod params;
mod regions;
mod surface;
mod topology;

#[cfg(test)]
mod tests;

use std::sync::{Arc, OnceLock};

use nalgebra::{Point3, Vector3};

use crate::dataset::{Dataset, JawPose, JawRig, Shape};
use crate::mesh::{Mesh, MeshError, vertex_normals};

pub use params::ActorParams;
pub use regions::{Landmarks, Region};

use expressions::{Frame, Model};
use openings::LidState;
use surface::Surface;
use topology::{GridKind, Topology};

/// Errors from building the synthetic actor.
#[derive(Debug, thiserror::Error)]
pub enum ActorError {
    /// A parameter is not finite, out of range, or inconsistent with another one.
    /// Fix: bring the named field back into the range the message gives (the defaults
    /// of [`ActorParams::default`] are always valid).
    #[error("invalid actor parameter `{field}` = {value}: {reason}")]
    InvalidParam {
        /// The offending field.
        field: &'static str,
        /// Its value.
        value: f64,
        /// What is wrong with it.
        reason: String,
    },
    /// The generated mesh failed validation (a bug in the generator).
    #[error("built-in actor mesh: {0}")]
    Mesh(#[from] MeshError),
    /// The generated geometry is degenerate (a bug, or parameters at an extreme).
    #[error("built-in actor geometry: {0}")]
    Geometry(String),
}

impl ActorError {
    fn invalid(field: &'static str, value: f64, reason: impl Into<String>) -> Self {
        Self::InvalidParam {
            field,
            value,
            reason: reason.into(),
        }
    }
}

/// One evaluated pose of the actor: the ground truth for given expression weights.
#[derive(Debug, Clone, PartialEq)]
pub struct ActorPose {
    /// Vertex positions (#V), mm, head frame.
    pub positions: Vec<Point3<f64>>,
    /// The jaw pose the weights produced.
    pub jaw: JawPose,
}

/// The canonical layout and topology, shared by every identity.
struct Canonical {
    surface: Surface,
    topology: Topology,
}

/// Builds (once per process) the canonical surface and topology.
fn canonical() -> Result<Arc<Canonical>, ActorError> {
    static CANON: OnceLock<Result<Arc<Canonical>, String>> = OnceLock::new();
    let built = CANON.get_or_init(|| {
        let surface = Surface::new(&ActorParams::default(), None).map_err(|e| e.to_string())?;
        let topology = Topology::new(&surface).map_err(|e| e.to_string())?;
        Ok(Arc::new(Canonical { surface, topology }))
    });
    built.clone().map_err(ActorError::Geometry)
}

/// The built-in synthetic actor of one identity. See the [module docs](self).
#[derive(Clone)]
pub struct Actor {
    params: ActorParams,
    canon: Arc<Canonical>,
    surface: Surface,
    neutral: Mesh,
    normals: Vec<Vector3<f64>>,
    regions: Vec<Region>,
    landmarks: Landmarks,
    rig: JawRig,
    model: Model,
    /// Skin vertices inside each eyelid warp's support (left, right).
    lid_support: [Vec<u32>; 2],
}

impl std::fmt::Debug for Actor {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Actor")
            .field("params", &self.params)
            .field("vertices", &self.neutral.vertex_count())
            .field("polygons", &self.neutral.face_count())
            .finish_non_exhaustive()
    }
}

impl Actor {
    /// Builds the actor of identity `params`: neutral mesh, expression model, jaw rig,
    /// regions and landmarks.
    ///
    /// # Errors
    /// [`ActorError::InvalidParam`] when `params` fails [`ActorParams::validate`];
    /// [`ActorError::Geometry`] / [`ActorError::Mesh`] if the generator produced a bad
    /// mesh (a bug).
    pub fn new(params: &ActorParams) -> Result<Self, ActorError> {
        params.validate()?;
        let canon = canonical()?;
        let topo = &canon.topology;
        let cl = canon.surface.layout;
        let surface = Surface::new(params, Some(&cl))?;
        let positions = topo.positions(&surface);
        let neutral = Mesh::new(
            positions,
            &topo.polygons,
            topo.uvs.clone(),
            Some(&topo.polygon_uvs),
        )?;
        let normals = vertex_normals(&neutral);

        // Local frames of the skin vertices: the tangent toward +u is the chord between
        // the polygon neighbours of smallest and largest `u` (seam-aware), made
        // orthogonal to the mesh normal.
        let neutral_lids = [LidState::default(); 2];
        let skin_len = topo.skin.len();
        let mut side_nbrs = vec![(f64::INFINITY, u32::MAX, f64::NEG_INFINITY, u32::MAX); skin_len];
        let wrap = |du: f64| {
            let period = 2.0 * surface::U_SEAM;
            du - period * (du / period).round()
        };
        for f in neutral.faces() {
            for (a, &va) in f.iter().enumerate() {
                let vb = f[(a + 1) % f.len()];
                for (x, y) in [(va, vb), (vb, va)] {
                    let (xi, yi) = (x as usize, y as usize);
                    if xi >= skin_len || yi >= skin_len {
                        continue;
                    }
                    let du = wrap(topo.skin[yi].u - topo.skin[xi].u);
                    let e = &mut side_nbrs[xi];
                    if du < e.0 {
                        (e.0, e.1) = (du, y);
                    }
                    if du > e.2 {
                        (e.2, e.3) = (du, y);
                    }
                }
            }
        }
        let positions = &neutral.positions;
        let frames: Vec<Frame> = topo
            .skin
            .iter()
            .enumerate()
            .map(|(k, sv)| {
                let n = normals[k];
                let (u, v) = topo.skin_param(sv, &neutral_lids);
                let (_, left, _, right) = side_nbrs[k];
                let tu_raw = if sv.kind == GridKind::Pole || left == u32::MAX || right == u32::MAX {
                    Vector3::x()
                } else {
                    positions[right as usize] - positions[left as usize]
                };
                let tu = (tu_raw - n * n.dot(&tu_raw))
                    .try_normalize(1e-12)
                    .unwrap_or_else(Vector3::x);
                let row_sign = regions::lip_row_sign(topo, sv);
                Frame {
                    u,
                    v,
                    n,
                    tu,
                    tv: n.cross(&tu),
                    lower: regions::lower_share(&cl, u, v, row_sign),
                }
            })
            .collect();

        let mut weights = vec![0.0; neutral.vertex_count()];
        for (k, sv) in topo.skin.iter().enumerate() {
            let row_sign = regions::lip_row_sign(topo, sv);
            weights[k] = regions::jaw_weight(&cl, frames[k].u, frames[k].v, row_sign);
        }
        let rig = JawRig {
            pivot: surface.jaw_pivot,
            open_axis: Vector3::x_axis(),
            lateral_axis: Vector3::y_axis(),
            forward: Vector3::z_axis(),
            weights,
        };

        let mut regions_out: Vec<Region> = topo
            .skin
            .iter()
            .map(|sv| regions::skin_region(topo, &cl, sv))
            .collect();
        regions_out.extend(std::iter::repeat_n(Region::EyeballL, topo.eyeball_len));
        regions_out.extend(std::iter::repeat_n(Region::EyeballR, topo.eyeball_len));

        let lid_support = [0, 1].map(|e| {
            let ((u0, u1), (v0, v1)) = topo.openings.eyes[e].support();
            topo.skin
                .iter()
                .enumerate()
                .filter(|(_, sv)| sv.u >= u0 && sv.u <= u1 && sv.v_grid >= v0 && sv.v_grid <= v1)
                .map(|(k, _)| k as u32)
                .collect()
        });

        let model = Model::new(&frames, &cl, params.seed, params.wrinkle_depth_scale);
        let landmarks = regions::landmarks(topo, &cl);
        Ok(Self {
            params: params.clone(),
            canon: canon.clone(),
            surface,
            neutral,
            normals,
            regions: regions_out,
            landmarks,
            rig,
            model,
            lid_support,
        })
    }

    /// The identity parameters this actor was built from.
    pub fn params(&self) -> &ActorParams {
        &self.params
    }

    /// The neutral mesh (positions in mm, head frame, per-corner UVs).
    pub fn neutral(&self) -> &Mesh {
        &self.neutral
    }

    /// Names of the expressions, in the order of weight vectors and dataset shapes.
    pub fn expression_names(&self) -> &'static [&'static str] {
        &expressions::NAMES
    }

    /// Index of the expression called `name`.
    pub fn expression_index(&self, name: &str) -> Option<usize> {
        expressions::NAMES.iter().position(|&n| n == name)
    }

    /// A weight vector with the named expressions set (unknown names are ignored).
    pub fn weights(&self, named: &[(&str, f64)]) -> Vec<f64> {
        let mut w = vec![0.0; expressions::NAMES.len()];
        for (name, value) in named {
            if let Some(i) = self.expression_index(name) {
                w[i] = *value;
            }
        }
        w
    }

    /// Number of face-skin vertices: vertices `0..face_vertex_count()` are the face (the
    /// reconstruction region); the rest of the head, the neck and the eyeballs follow.
    pub fn face_vertex_count(&self) -> usize {
        self.canon.topology.face_count
    }

    /// Index range of the eyeball vertices, left (+x) then right.
    pub fn eyeball_vertices(&self) -> [std::ops::Range<usize>; 2] {
        let t = &self.canon.topology;
        t.eyeball_first.map(|f| f..f + t.eyeball_len)
    }

    /// Centres of the eyeballs (left, right), mm, head frame.
    pub fn eyeball_centres(&self) -> [Point3<f64>; 2] {
        self.surface.eye_centres.map(Point3::from)
    }

    /// Region label of every vertex (#V).
    pub fn regions(&self) -> &[Region] {
        &self.regions
    }

    /// Named landmark vertices.
    pub fn landmarks(&self) -> &Landmarks {
        &self.landmarks
    }

    /// The jaw rig the model skins with.
    pub fn jaw_rig(&self) -> &JawRig {
        &self.rig
    }

    /// Unit vertex normals of the neutral (#V).
    pub fn neutral_normals(&self) -> &[Vector3<f64>] {
        &self.normals
    }

    /// The ground-truth face for expression weights `weights` (indexed like
    /// [`Actor::expression_names`]). Missing weights count as 0, extra ones are ignored,
    /// non-finite ones count as 0 and the rest are clamped to [0, 1]. See the
    /// [module docs](self) for the model.
    pub fn evaluate(&self, weights: &[f64]) -> ActorPose {
        let topo = &self.canon.topology;
        let mut pos = self.neutral.positions.clone();
        // 1. Eyelids.
        let lids = expressions::lid_states(weights);
        for (e, support) in self.lid_support.iter().enumerate() {
            if lids[e] == LidState::default() {
                continue;
            }
            for &k in support {
                let sv = &topo.skin[k as usize];
                let (u, v) = topo.skin_param(sv, &lids);
                pos[k as usize] = self.surface.point(u, v);
            }
        }
        // 2. Soft tissue and correctives.
        for (i, field) in self.model.soft.iter().enumerate() {
            let w = expressions::weight(weights, i);
            if w > 0.0 {
                field.add_to(&mut pos, w);
            }
        }
        for c in &self.model.correctives {
            let w = expressions::weight(weights, c.a) * expressions::weight(weights, c.b);
            if w > 0.0 {
                c.field.add_to(&mut pos, w);
            }
        }
        // 3. Wrinkles.
        for (wr, (_, depth)) in self.model.wrinkles.iter().zip(self.wrinkle_depths(weights)) {
            if depth > 0.0 {
                wr.field.add_to(&mut pos, depth);
            }
        }
        // 4. Jaw.
        let jaw = expressions::jaw_pose(weights);
        if jaw != JawPose::default() {
            pos = self.rig.skin(&jaw, &pos);
        }
        ActorPose {
            positions: pos,
            jaw,
        }
    }

    /// Relative depth (0 to 1) of each wrinkle pattern for `weights`, with the pattern's
    /// name: forehead furrows (centre, left, right), glabella lines, crow's feet,
    /// nasolabial folds, bunny lines (each left and right) and chin dimpling. Depth is
    /// `smoothstep(0, 1, a)` of the pattern's activation `a = Σ coefficient·weight`.
    /// Useful as ground truth for the detail-enhancement stage.
    pub fn wrinkle_depths(&self, weights: &[f64]) -> Vec<(&'static str, f64)> {
        self.model
            .wrinkles
            .iter()
            .map(|wr| {
                let a: f64 = wr
                    .drivers
                    .iter()
                    .map(|&(i, c)| c * expressions::weight(weights, i))
                    .sum();
                (wr.name, expressions::wrinkle_ramp(a))
            })
            .collect()
    }

    /// Expression `i` at weight 1 (all others 0) as a dataset shape with its jaw pose;
    /// `None` when `i` is out of range.
    pub fn expression_shape(&self, i: usize) -> Option<Shape> {
        let name = expressions::NAMES.get(i)?;
        let mut w = vec![0.0; expressions::NAMES.len()];
        w[i] = 1.0;
        let pose = self.evaluate(&w);
        Some(Shape {
            name: (*name).to_string(),
            positions: pose.positions,
            jaw: Some(pose.jaw),
        })
    }

    /// The actor as a dataset named `builtin-actor`: the neutral, one shape per
    /// expression in [`Actor::expression_names`] order, the face vertices
    /// `0..=face_vertex_count() − 1` and the jaw rig.
    pub fn to_dataset(&self) -> Dataset {
        let shapes = (0..expressions::NAMES.len())
            .filter_map(|i| self.expression_shape(i))
            .collect();
        let last_face = self.face_vertex_count().saturating_sub(1) as u32;
        Dataset {
            name: "builtin-actor".to_string(),
            neutral: self.neutral.clone(),
            shapes,
            face_vertices: 0..=last_face,
            jaw: Some(self.rig.clone()),
        }
    }

    /// The actor as a detail-enhancement database in the sense of Bermano et al. 2014
    /// §4.1: performance sequences from the neutral to each extreme, not the extremes
    /// alone. Every expression at each weight of `onsets` joins [`Actor::to_dataset`]'s
    /// neutral and full-weight shapes, named `NAME@WEIGHT`. Wrinkle depths follow
    /// smoothstep of the activation, not the weight, so these frames hold what a convex
    /// mix of the neutral and the full shape cannot: a half-raised brow's half-deep
    /// furrows. Weights outside (0, 1) are skipped.
    pub fn performance_dataset(&self, onsets: &[f64]) -> Dataset {
        let mut dataset = self.to_dataset();
        for (i, name) in expressions::NAMES.iter().enumerate() {
            for &w in onsets.iter().filter(|w| **w > 0.0 && **w < 1.0) {
                let mut weights = vec![0.0; expressions::NAMES.len()];
                weights[i] = w;
                let pose = self.evaluate(&weights);
                dataset.shapes.push(Shape {
                    name: format!("{name}@{w}"),
                    positions: pose.positions,
                    jaw: Some(pose.jaw),
                });
            }
        }
        dataset
    }
}
