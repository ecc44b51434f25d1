//! Dense face reconstruction from bundles by local geometric indexing (Cong, Lan and
//! Fedkiw 2019, "Local Geometric Indexing of High Resolution Data for Facial Reconstruction
//! from Sparse Markers").
//!
//! Each marker indexes the dataset on its own: its point cloud (the marker's position on
//! every shape, §4) is tetrahedralized with all four-point combinations (§4.1); a bundle
//! inside a tetrahedron gives convex barycentric weights over four shapes, Eq. (1); when
//! several tetrahedra contain it, the one whose local geometry best fits the neighbouring
//! bundles wins, with a preference for the previous frame's shapes (§5.1); outside every
//! tetrahedron the bundle is projected onto the tetrahedral volume (§4). The markers' local
//! geometries are sewn together with natural-neighbour weights computed in UV space (§5),
//! optionally smoothed in time (§7), with the jaw unskinned and reskinned when the dataset
//! has a jaw rig (§6, Eq. 2).
//!
//! Everything that does not depend on the frame is built once in [`LgiIndex`]; per frame
//! only grid lookups, a few candidate scores per marker and a sparse blend over the face
//! vertices remain.
//!
//! # Deviations and choices the paper leaves open
//! - **Variants of coincident points** ([`point_cloud`]): shapes that put a marker at the
//!   same place (within `merge_tolerance_mm`) share one point of the tetrahedralization but
//!   keep their own local geometry; the neighbour criterion of §5.1 picks among them. The
//!   paper prunes such redundancies; keeping them as variants loses no local geometry.
//! - **Projection onto the convex hull** (§4 says "convex hull of the associated point
//!   cloud"): the union of all four-point tetrahedra is that hull; the tetrahedra on the
//!   closest hull triangle compete on the neighbour criterion.
//! - **Containment by an orientation table** ([`barycentric::TripleTable`]): the paper's
//!   uniform grid is built ([`grid`]) but all-combination tetrahedra overlap so much that a
//!   cell lists most of them; one orientation per triangle of the cloud per frame makes each
//!   tetrahedron's test four look-ups.
//! - **Per-frame jaw pose** (§6 assumes a jaw tracker): when none is given it is estimated
//!   from the jaw markers by kernel ridge regression on the dataset's shapes ([`jaw`]).
//! - **Noisy bundles** ([`LgiParams::noisy`]): an optional tolerance lets tetrahedra near a
//!   bundle compete, and the surface is then not forced through it.
//! - **Passing through projected bundles** ([`LgiParams::snap_to_bundles`], on by default):
//!   when a bundle lies outside every tetrahedron, the paper keeps the projection and the
//!   surface misses the bundle. We add the residual (bundle minus projection) to the
//!   marker's local geometry, so the natural-neighbour blend still interpolates every
//!   bundle, as the paper does for its RBF variant ("smoothly interpolating the remaining
//!   displacements needed to properly interpolate the bundles", §7). Bundles are what was
//!   measured; a surface that misses them looks wrong against the plates.
//!
//! Depends on [`crate::mesh`], [`crate::dataset`] and [`crate::bundles`].

pub mod barycentric;
pub mod cache;
pub mod grid;
pub mod hull;
pub mod index;
pub mod jaw;
pub mod natural_neighbor;
pub mod point_cloud;
pub mod select;
pub mod temporal;
pub mod tetrahedra;

use std::sync::Arc;

use nalgebra::{Point3, Vector3};

pub use index::{IndexStats, LgiIndex, MarkerIndex};
pub use natural_neighbor::{NaturalNeighborError, NaturalNeighborWeights};
pub use temporal::{Kernel, TemporalParams, WeightSmoother};

use crate::bundles::FrameBundles;
use crate::dataset::{Dataset, JawPose, MarkerLayout};
use crate::frame_index::FrameIndex;

/// Errors of local geometric indexing.
#[derive(Debug, thiserror::Error)]
pub enum LgiError {
    /// A parameter is out of range.
    #[error("invalid LGI parameter {field} = {value}: {reason}")]
    Param {
        /// Field name.
        field: &'static str,
        /// Its value.
        value: String,
        /// The valid range.
        reason: &'static str,
    },
    /// The marker layout does not fit the dataset.
    #[error("marker layout: {0}")]
    Layout(String),
    /// The dataset cannot be indexed.
    #[error("dataset: {0}")]
    Dataset(String),
    /// The blending weights could not be built.
    #[error(transparent)]
    Blend(#[from] NaturalNeighborError),
    /// A frame does not fit the layout or has no bundle at all.
    #[error("frame {frame}: {message}")]
    Frame {
        /// Frame number.
        frame: FrameIndex,
        /// What was wrong.
        message: String,
    },
}

/// Parameters of local geometric indexing. Every limit of §4.1 is a field here.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LgiParams {
    /// A shape whose displacement at a marker is under this does not involve the marker and
    /// is left out of its point cloud (§4.1), mm. Default 0.01.
    pub min_motion_mm: f64,
    /// Points of one cloud closer than this are merged into one point of the
    /// tetrahedralization (the least-deforming shape represents it), mm. Default 0.01.
    pub merge_tolerance_mm: f64,
    /// A merged or still shape stays as a variant of its point when its displacement of
    /// the marker's patch differs from every other variant's by at least this (RMS), mm;
    /// otherwise it is redundant and dropped. Default 0.0001.
    pub variant_tolerance_mm: f64,
    /// Tetrahedra with shape quality `6√2·V / l_rms³` under this are too thin (§4.1).
    /// Default 0.001 (only near-flat ones go: a thin tetrahedron still interpolates
    /// correctly, and keeping many tetrahedra is what makes LGI accurate).
    pub min_tet_quality: f64,
    /// Tetrahedra with an edge longer than this are too large (§4.1), mm. Default 1000
    /// (no limit: every combination of a face's shapes is a plausible in-between).
    pub max_tet_edge_mm: f64,
    /// Most tetrahedra kept per marker (the best-shaped win, see [`tetrahedra`]).
    /// Default 10 000: on ICT (53 shapes, 120 markers) about 0.8 M tetrahedra; keeping all
    /// (1.5 to 2 M) was about 10 % more accurate on held-out frames and twice as slow.
    pub max_tets_per_marker: usize,
    /// Most grid list entries (4 bytes each) per tetrahedron of a marker, on average; the
    /// grid gets coarser to fit. Heavily overlapping tetrahedra make fine grids list the
    /// same tetrahedra in many cells. Default 8.
    pub grid_entries_per_tet: f64,
    /// Cost added to a candidate per fraction of its corners not shared with the previous
    /// frame's choice (§5.1 temporal coherence), mm. 0 turns the preference off.
    /// Default 0.05.
    pub temporal_weight_mm: f64,
    /// Tetrahedra within this distance of a bundle compete with those containing it, their
    /// distance counting in the neighbour criterion (§5.1), mm. For noisy bundles: a
    /// bundle pushed by noise into (or out of) a tetrahedron is then not bound to it, and
    /// the neighbours pick the shapes. 0 (default) is the paper's exact containment.
    pub bundle_tolerance_mm: f64,
    /// Add the residual of a projected bundle to its marker's geometry so the surface
    /// still passes through it (see the module's Deviations). Default true.
    pub snap_to_bundles: bool,
    /// Work in unskinned space when the dataset has a jaw rig and a jaw pose per shape
    /// (§6). Default true.
    pub use_jaw: bool,
    /// Temporal smoothing of the barycentric weights (§7). Default off.
    pub smoothing: TemporalParams,
}

impl Default for LgiParams {
    fn default() -> Self {
        Self {
            min_motion_mm: 0.01,
            merge_tolerance_mm: 0.01,
            variant_tolerance_mm: 0.0001,
            min_tet_quality: 0.001,
            max_tet_edge_mm: 1000.0,
            max_tets_per_marker: 10_000,
            grid_entries_per_tet: 8.0,
            temporal_weight_mm: 0.05,
            bundle_tolerance_mm: 0.0,
            snap_to_bundles: true,
            use_jaw: true,
            smoothing: TemporalParams::default(),
        }
    }
}

impl LgiParams {
    /// Preset for noisy bundles (triangulation noise of a few tenths of a millimetre):
    /// - tetrahedra within 0.5 mm of a bundle compete on the neighbour criterion;
    /// - the surface is not forced through each bundle (which would copy the noise into it);
    /// - points of a marker's cloud within 0.5 mm merge into one point, their shapes kept as
    ///   its variants and told apart by the neighbours. A bundle's own position cannot tell
    ///   such points apart under noise, and their patches may differ a lot: an eye blink
    ///   moves a marker under the brow by 0.05 mm and the eyelid by 8 mm, so barycentric
    ///   weights between the blink and the neutral would follow the noise (on the demo
    ///   session: a half-closed eyelid, mesh error RMS 0.258 mm against 0.136 mm merged).
    ///
    /// It needs its own index (the merge shapes the point clouds).
    pub fn noisy() -> Self {
        Self {
            bundle_tolerance_mm: 0.5,
            merge_tolerance_mm: 0.5,
            snap_to_bundles: false,
            ..Self::default()
        }
    }

    /// These parameters with every per-frame setting at its default: two parameter sets
    /// build the same index exactly when their `index_params` are equal.
    pub fn index_params(&self) -> Self {
        Self {
            temporal_weight_mm: 0.0,
            bundle_tolerance_mm: 0.0,
            snap_to_bundles: true,
            smoothing: TemporalParams::default(),
            ..*self
        }
    }

    /// Checks every field's range.
    ///
    /// # Errors
    /// [`LgiError::Param`] naming the first bad field.
    pub fn validate(&self) -> Result<(), LgiError> {
        let nonneg = |field: &'static str, v: f64| {
            if v.is_finite() && v >= 0.0 {
                Ok(())
            } else {
                Err(LgiError::Param {
                    field,
                    value: v.to_string(),
                    reason: "must be a finite number ≥ 0",
                })
            }
        };
        nonneg("min_motion_mm", self.min_motion_mm)?;
        nonneg("merge_tolerance_mm", self.merge_tolerance_mm)?;
        nonneg("variant_tolerance_mm", self.variant_tolerance_mm)?;
        nonneg("temporal_weight_mm", self.temporal_weight_mm)?;
        nonneg("bundle_tolerance_mm", self.bundle_tolerance_mm)?;
        if !(0.0..1.0).contains(&self.min_tet_quality) {
            return Err(LgiError::Param {
                field: "min_tet_quality",
                value: self.min_tet_quality.to_string(),
                reason: "must be in [0, 1)",
            });
        }
        if self.max_tet_edge_mm.is_nan() || self.max_tet_edge_mm <= 0.0 {
            return Err(LgiError::Param {
                field: "max_tet_edge_mm",
                value: self.max_tet_edge_mm.to_string(),
                reason: "must be > 0",
            });
        }
        if self.max_tets_per_marker == 0 {
            return Err(LgiError::Param {
                field: "max_tets_per_marker",
                value: "0".into(),
                reason: "must be ≥ 1",
            });
        }
        if self.grid_entries_per_tet.is_nan() || self.grid_entries_per_tet < 1.0 {
            return Err(LgiError::Param {
                field: "grid_entries_per_tet",
                value: self.grid_entries_per_tet.to_string(),
                reason: "must be ≥ 1",
            });
        }
        Ok(())
    }
}

/// One marker's result for a frame: convex weights over its point cloud.
#[derive(Debug, Clone, PartialEq)]
pub struct MarkerWeights {
    /// Whether the marker has a bundle in this frame.
    pub present: bool,
    /// Whether the bundle lay inside a tetrahedron (else it was projected).
    pub inside: bool,
    /// `(variant index, weight)`, weights summing to 1 (4 entries at most before
    /// smoothing).
    pub points: Vec<(u16, f64)>,
}

/// The indexing result of one frame, before blending.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameWeights {
    /// Frame number.
    pub frame: FrameIndex,
    /// Per marker, in layout order.
    pub markers: Vec<MarkerWeights>,
    /// Jaw pose θ of the frame (when the index works in unskinned space).
    pub jaw: Option<JawPose>,
}

/// Local geometric indexing solver: the index plus the per-take state (previous frame's
/// choices for temporal coherence, cached blending weights for missing-marker sets).
///
/// # Example
/// ```no_run
/// # use helmcap::lgi::{LgiParams, LgiSolver};
/// # fn f(dataset: &helmcap::dataset::Dataset, layout: &helmcap::dataset::MarkerLayout,
/// #      frame: &helmcap::bundles::FrameBundles) -> Result<(), helmcap::lgi::LgiError> {
/// let mut solver = LgiSolver::new(dataset, layout, &LgiParams::default())?;
/// let positions = solver.solve(frame)?; // every vertex of the neutral mesh, mm
/// # Ok(()) }
/// ```
#[derive(Debug)]
pub struct LgiSolver {
    index: Arc<LgiIndex>,
    params: LgiParams,
    previous: Vec<Option<[u16; 4]>>,
    scratch: select::Scratch,
    /// Recomputed weights of recent clusters of missing markers (see
    /// [`NaturalNeighborWeights::missing_clusters`]), with the frame each was last used.
    cluster_cache: std::collections::HashMap<Vec<u32>, (u64, Arc<ClusterWeights>)>,
    /// Frames solved (the clock of `cluster_cache`).
    solved: u64,
    /// Kept between frames by the jaw pose estimate.
    rig_fit: jaw::RigFitCache,
}

/// Blending weights of the vertices affected by one cluster of missing markers (the
/// cluster's markers left out of the diagram).
#[derive(Debug)]
struct ClusterWeights {
    /// Every vertex with weight on a marker of the cluster.
    vertices: Vec<u32>,
    /// Their weights, in the same order.
    weights: natural_neighbor::SharedWeights,
}

/// Blending weights of the vertices affected by a frame's missing markers.
#[derive(Debug)]
struct MissingWeights {
    /// Whether each vertex is affected.
    affected: Vec<bool>,
    /// The clusters of missing markers; every affected vertex is in exactly one.
    clusters: Vec<Arc<ClusterWeights>>,
}

/// Number of missing-marker clusters whose weights are kept. An entry holds the weights
/// of the vertices its markers influence: a few hundred for a marker inside the face, up
/// to ~10,000 (~200 kB) for a group on the face border, whose weights the back of the
/// head copies. Every single marker of a 120-marker layout fits, with room for the
/// recurring groups (an eyelid, the lips, the chin line); at most ~50 MB.
const CLUSTER_CACHE: usize = 256;

impl LgiSolver {
    /// Builds the index of `dataset` for `layout` and a solver over it.
    ///
    /// # Errors
    /// As [`LgiIndex::build`].
    pub fn new(
        dataset: &Dataset,
        layout: &MarkerLayout,
        params: &LgiParams,
    ) -> Result<Self, LgiError> {
        let index = LgiIndex::build(dataset, layout, params)?;
        Self::from_index(Arc::new(index), params)
    }

    /// A solver over a prebuilt (possibly shared or cached) index. Only the per-frame
    /// parameters of `params` are used; the index keeps those it was built with.
    ///
    /// # Errors
    /// [`LgiError::Param`] when `params` is invalid.
    pub fn from_index(index: Arc<LgiIndex>, params: &LgiParams) -> Result<Self, LgiError> {
        params.validate()?;
        let n = index.markers.len();
        Ok(Self {
            index,
            params: *params,
            previous: vec![None; n],
            scratch: select::Scratch::default(),
            cluster_cache: Default::default(),
            solved: 0,
            rig_fit: Default::default(),
        })
    }

    /// The index.
    pub fn index(&self) -> &Arc<LgiIndex> {
        &self.index
    }

    /// The parameters.
    pub fn params(&self) -> &LgiParams {
        &self.params
    }

    /// Forgets the previous frame (call between unrelated takes or frames).
    pub fn reset(&mut self) {
        self.previous.iter_mut().for_each(|p| *p = None);
    }

    /// Solves one frame: indexing (§4, §5.1) then blending (§5). No temporal smoothing
    /// (that needs future frames: see [`LgiSolver::solve_sequence`]); the temporal
    /// preference of §5.1 does apply, so call [`LgiSolver::reset`] between unrelated frames.
    ///
    /// Returns every vertex of the neutral mesh, mm, head frame.
    ///
    /// # Errors
    /// [`LgiError::Frame`] when the frame's marker count differs from the layout or no
    /// marker is present.
    pub fn solve(&mut self, bundles: &FrameBundles) -> Result<Vec<Point3<f64>>, LgiError> {
        let w = self.index_frame(bundles, None)?;
        self.reconstruct(&w, bundles)
    }

    /// Solves a whole take in order, with the temporal smoothing of `params.smoothing`.
    ///
    /// # Errors
    /// As [`LgiSolver::solve`], for the first bad frame.
    pub fn solve_sequence(
        &mut self,
        frames: &[FrameBundles],
    ) -> Result<Vec<Vec<Point3<f64>>>, LgiError> {
        let mut smoother = WeightSmoother::new(self.params.smoothing);
        let mut out = Vec::with_capacity(frames.len());
        let mut emitted = 0usize;
        for f in frames {
            let w = self.index_frame(f, None)?;
            for s in smoother.push(w) {
                out.push(self.reconstruct(&s, &frames[emitted])?);
                emitted += 1;
            }
        }
        for s in smoother.finish() {
            out.push(self.reconstruct(&s, &frames[emitted])?);
            emitted += 1;
        }
        Ok(out)
    }

    fn check_frame(&self, bundles: &FrameBundles) -> Result<(), LgiError> {
        if bundles.positions.len() != self.index.markers.len() {
            return Err(LgiError::Frame {
                frame: bundles.frame,
                message: format!(
                    "{} bundles for a layout of {} markers",
                    bundles.positions.len(),
                    self.index.markers.len()
                ),
            });
        }
        if !bundles.positions.iter().any(is_usable) {
            return Err(LgiError::Frame {
                frame: bundles.frame,
                message: "no marker present".into(),
            });
        }
        Ok(())
    }

    /// The frame's bundles in the index's space (unskinned by `jaw` when the index uses
    /// the jaw); `None` for missing or non-finite bundles.
    fn index_space_bundles(
        &self,
        bundles: &FrameBundles,
        jaw: Option<&JawPose>,
    ) -> Vec<Option<Point3<f64>>> {
        let unskin = self.index.jaw.as_ref().zip(jaw).map(|(j, pose)| {
            let t = j.rig.jaw_transform(pose);
            (j, t)
        });
        bundles
            .positions
            .iter()
            .zip(&self.index.markers)
            .map(|(p, mi)| {
                let p = p.filter(|p| is_usable(&Some(*p)))?;
                Some(match &unskin {
                    Some((j, t)) => j.rig.unskin_point(t, j.rig.weights[mi.vertex as usize], &p),
                    None => p,
                })
            })
            .collect()
    }

    /// Indexes one frame (§4, §5.1): per marker, the chosen tetrahedron and weights.
    /// `jaw` is the frame's jaw pose θ; `None` estimates it from the bundles when the index
    /// works in unskinned space.
    ///
    /// # Errors
    /// As [`LgiSolver::solve`].
    pub fn index_frame(
        &mut self,
        bundles: &FrameBundles,
        jaw: Option<JawPose>,
    ) -> Result<FrameWeights, LgiError> {
        self.check_frame(bundles)?;
        let jaw = match (&self.index.jaw, jaw) {
            (None, _) => None,
            (Some(_), Some(j)) => Some(j),
            (Some(_), None) => Some(jaw::estimate_pose(&self.index, bundles, &mut self.rig_fit)),
        };
        let xs = self.index_space_bundles(bundles, jaw.as_ref());
        let sp = select::SelectParams {
            temporal_weight_mm: self.params.temporal_weight_mm,
            bundle_tolerance_mm: self.params.bundle_tolerance_mm,
        };
        let use_prev = self.params.temporal_weight_mm > 0.0;
        let mut markers = Vec::with_capacity(xs.len());
        let mut nbr = Vec::new();
        for (m, x) in xs.iter().enumerate() {
            let mi = &self.index.markers[m];
            let Some(x) = x else {
                markers.push(MarkerWeights {
                    present: false,
                    inside: false,
                    points: Vec::new(),
                });
                continue;
            };
            nbr.clear();
            nbr.extend(mi.neighbors.iter().map(|&k| xs[k as usize]));
            let prev = if use_prev {
                self.previous[m].as_ref()
            } else {
                None
            };
            let c = select::choose(mi, x, &nbr, prev, &sp, &mut self.scratch);
            self.previous[m] = Some(c.corners);
            let dim = mi.simplices.dim as usize;
            let mut points: Vec<(u16, f64)> = Vec::with_capacity(4);
            for k in 0..=dim {
                if c.weights[k] > 0.0 {
                    let var = c.variants[k] as u16;
                    match points.iter_mut().find(|e| e.0 == var) {
                        Some(e) => e.1 += c.weights[k],
                        None => points.push((var, c.weights[k])),
                    }
                }
            }
            if points.is_empty() {
                points.push((c.variants[0] as u16, 1.0));
            }
            markers.push(MarkerWeights {
                present: true,
                inside: c.inside,
                points,
            });
        }
        Ok(FrameWeights {
            frame: bundles.frame,
            markers,
            jaw,
        })
    }

    /// Blends the markers' local geometries across the face (§5) and reskins the jaw
    /// (§6, Eq. 2). `bundles` are the frame's bundles, used for the residual that makes the
    /// surface pass through each present bundle (see [`LgiParams::snap_to_bundles`]).
    ///
    /// Returns every vertex of the neutral mesh, mm, head frame.
    ///
    /// # Errors
    /// As [`LgiSolver::solve`].
    pub fn reconstruct(
        &mut self,
        weights: &FrameWeights,
        bundles: &FrameBundles,
    ) -> Result<Vec<Point3<f64>>, LgiError> {
        self.check_frame(bundles)?;
        let index = Arc::clone(&self.index);
        let xs = self.index_space_bundles(bundles, weights.jaw.as_ref());
        let present: Vec<bool> = weights
            .markers
            .iter()
            .zip(&xs)
            .map(|(m, x)| m.present && x.is_some())
            .collect();
        // Residual per marker: bundle minus the candidate's marker position.
        let residual: Vec<Vector3<f64>> = index
            .markers
            .iter()
            .zip(&weights.markers)
            .zip(&xs)
            .map(|((mi, mw), x)| match x {
                Some(x) if self.params.snap_to_bundles && mw.present => {
                    let at: Vector3<f64> = mw
                        .points
                        .iter()
                        .map(|&(j, w)| mi.variant_position[j as usize].coords * w)
                        .sum();
                    x.coords - at
                }
                _ => Vector3::zeros(),
            })
            .collect();
        let missing = if present.iter().all(|&p| p) {
            None
        } else {
            Some(self.missing_weights(&present)?)
        };
        // The neutral plus every marker's blended displacement, accumulated in place.
        let mut out: Vec<Point3<f64>> = index.neutral.clone();
        for (m, mi) in index.markers.iter().enumerate() {
            if !present[m] {
                continue;
            }
            let ns = mi.moving;
            let pts = &weights.markers[m].points;
            let r = residual[m];
            let affected = missing.as_ref().map(|mw| &mw.affected);
            for (s, &(v, lam)) in mi.blend[..ns].iter().enumerate() {
                if affected.is_some_and(|a| a[v as usize]) {
                    continue;
                }
                let mut d = r;
                for &(j, w) in pts {
                    d += index::widen(mi.patch[j as usize * ns + s]) * w;
                }
                out[v as usize] += d * lam;
            }
            // Vertices no variant displaces: only the residual (their patch terms are 0).
            for &(v, lam) in &mi.blend[ns..] {
                if affected.is_some_and(|a| a[v as usize]) {
                    continue;
                }
                out[v as usize] += r * lam;
            }
        }
        for (v, ws) in missing.iter().flat_map(|mw| {
            mw.clusters.iter().flat_map(|c| {
                c.vertices
                    .iter()
                    .enumerate()
                    .map(|(k, &v)| (v, c.weights.of(k)))
            })
        }) {
            let v = v as usize;
            let mut a = Vector3::zeros();
            for &(m, lam) in ws {
                let m = m as usize;
                let mi = &index.markers[m];
                let mut d = residual[m];
                for &(j, w) in &weights.markers[m].points {
                    if let Some(s) = mi.shapes[j as usize] {
                        // Rounded as the patches are (see `MarkerIndex::patch`).
                        d += index::widen(index::narrow(index.displacements[s as usize][v])) * w;
                    }
                }
                a += d * lam;
            }
            out[v] = index.neutral[v] + a;
        }
        if let (Some(j), Some(pose)) = (&index.jaw, &weights.jaw) {
            let t = j.rig.jaw_transform(pose);
            for (p, &w) in out.iter_mut().zip(&j.rig.weights) {
                *p = j.rig.skin_point(&t, w, p);
            }
        }
        Ok(out)
    }

    /// Blending weights of the vertices affected by the missing markers, put together
    /// from the independent clusters of missing markers, each computed once and cached.
    fn missing_weights(&mut self, present: &[bool]) -> Result<MissingWeights, LgiError> {
        self.solved += 1;
        let index = Arc::clone(&self.index);
        let supports: Vec<&[(u32, f64)]> = index.markers.iter().map(|mi| &mi.support[..]).collect();
        let clusters = index.weights.missing_clusters(present, &supports);
        let mut affected = vec![false; index.neutral.len()];
        let mut out = Vec::with_capacity(clusters.len());
        for cluster in clusters {
            for &m in &cluster {
                for &(v, _) in supports[m as usize] {
                    affected[v as usize] = true;
                }
            }
            if let Some((used, w)) = self.cluster_cache.get_mut(&cluster) {
                *used = self.solved;
                out.push(Arc::clone(w));
                continue;
            }
            // The vertices with weight on the cluster's markers, ascending: marked, then
            // listed (sorting the supports' tens of thousands of entries cost more).
            let mut marked = vec![false; index.neutral.len()];
            for &m in &cluster {
                for &(v, _) in supports[m as usize] {
                    if let Some(k) = marked.get_mut(v as usize) {
                        *k = true;
                    }
                }
            }
            let vertices: Vec<u32> = (0..marked.len() as u32)
                .filter(|&v| marked[v as usize])
                .collect();
            let mut present_c = vec![true; present.len()];
            for &m in &cluster {
                present_c[m as usize] = false;
            }
            // From the cached cluster nearest to this one, when it shares most of it (a
            // hidden marker shown again, another hidden): only the vertices whose natural
            // neighbours changed are queried again.
            let nearest = self
                .cluster_cache
                .iter()
                .map(|(k, (_, w))| (sorted_difference(k, &cluster), k, w))
                .filter(|(d, ..)| d.0.len() + d.1.len() <= cluster.len() / 2)
                .min_by(|(da, ka, _), (db, kb, _)| {
                    // Ties go to the smaller cluster list: the cache's order is a hash's.
                    (da.0.len() + da.1.len(), ka).cmp(&(db.0.len() + db.1.len(), kb))
                });
            let weights = match nearest {
                Some(((added, removed), _, base)) => index.weights.update_shared(
                    &present_c,
                    &vertices,
                    natural_neighbor::WeightsBefore {
                        vertices: &base.vertices,
                        weights: &base.weights,
                        added: &added,
                        removed: &removed,
                    },
                )?,
                None => index.weights.recompute_shared(&present_c, &vertices)?,
            };
            let w = Arc::new(ClusterWeights { vertices, weights });
            if self.cluster_cache.len() >= CLUSTER_CACHE {
                // Forget the least recently used cluster.
                if let Some(oldest) = self
                    .cluster_cache
                    .iter()
                    .min_by_key(|(_, (used, _))| *used)
                    .map(|(k, _)| k.clone())
                {
                    self.cluster_cache.remove(&oldest);
                }
            }
            self.cluster_cache
                .insert(cluster, (self.solved, Arc::clone(&w)));
            out.push(w);
        }
        Ok(MissingWeights {
            affected,
            clusters: out,
        })
    }
}

/// The markers of `old` not in `new`, and of `new` not in `old` (both ascending).
fn sorted_difference(old: &[u32], new: &[u32]) -> (Vec<u32>, Vec<u32>) {
    let (mut only_old, mut only_new) = (Vec::new(), Vec::new());
    let (mut i, mut j) = (0, 0);
    while i < old.len() || j < new.len() {
        match (old.get(i), new.get(j)) {
            (Some(a), Some(b)) if a == b => {
                i += 1;
                j += 1;
            }
            (Some(a), Some(b)) if a < b => {
                only_old.push(*a);
                i += 1;
            }
            (Some(a), None) => {
                only_old.push(*a);
                i += 1;
            }
            (_, Some(b)) => {
                only_new.push(*b);
                j += 1;
            }
            (None, None) => break,
        }
    }
    (only_old, only_new)
}

/// Whether a bundle is present and finite.
fn is_usable(p: &Option<Point3<f64>>) -> bool {
    p.is_some_and(|p| p.coords.iter().all(|c| c.is_finite()))
}
