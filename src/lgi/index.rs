//! The frame-independent part of local geometric indexing: per marker, the point cloud
//! (§4), its tetrahedra (§4.1), a uniform grid over them (§4), the marker's blending patch
//! with the natural-neighbour weights (§5) and, for each point, the patch's displacement
//! and the neighbouring markers' positions in that point's shape (for the choice of §5.1).

use nalgebra::{Point3, Vector3};
use rayon::prelude::*;

pub use super::jaw::JawSpace;
use super::natural_neighbor::NaturalNeighborWeights;
use super::point_cloud::build_point_cloud;
use super::tetrahedra::{Simplices, TetStats, tetrahedralize};
use super::{LgiError, LgiParams, grid::TetGrid};
use crate::dataset::{Dataset, MarkerLayout};

/// Everything one marker needs per frame.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct MarkerIndex {
    /// Vertex of the neutral the marker sits on.
    pub vertex: u32,
    /// Point cloud positions (unskinned when the index uses the jaw), mm.
    pub points: Vec<Point3<f64>>,
    /// Variants of point `j` are `point_variants[j]..point_variants[j + 1]`, the
    /// representative first (see [`super::point_cloud::PointCloud`]).
    pub point_variants: Vec<u32>,
    /// Dataset shape of each variant (`None`: the neutral).
    pub shapes: Vec<Option<u32>>,
    /// Point of each variant.
    pub variant_point: Vec<u16>,
    /// The marker's own position in each variant's shape (within the merge tolerance of
    /// its point), mm: what the candidate surface passes through.
    #[serde(skip)]
    pub variant_position: Vec<Point3<f64>>,
    /// Patch deformation of each variant's shape (RMS displacement), mm: the tie-break.
    pub deformation_mm: Vec<f64>,
    /// Tetrahedra (or lower simplices) over the points.
    pub simplices: Simplices,
    /// `1 / det[b − a, c − a, d − a]` of each tetrahedron (see
    /// [`super::barycentric::TripleTable`]).
    #[serde(skip)]
    pub inv_volume: Vec<f64>,
    /// Face triples of each tetrahedron ([`super::barycentric::TripleTable::faces`]).
    #[serde(skip)]
    pub faces: Vec<[u32; 4]>,
    /// Compact form of the tetrahedra for the containment scan (derived).
    #[serde(skip)]
    pub scan: super::barycentric::TetScan,
    /// `1 / (2 · area)` of every triple's triangle (for distances to face planes).
    #[serde(skip)]
    pub triple_inv_area2: Vec<f64>,
    /// The face triples the tetrahedra use.
    #[serde(skip)]
    pub used_triples: super::barycentric::UsedTriples,
    /// Grid over the tetrahedra (`None` below dimension 3).
    #[serde(skip)]
    pub grid: Option<TetGrid>,
    /// Convex hull triangles of the points (empty below dimension 3).
    pub hull: Vec<[u16; 3]>,
    /// For each hull triangle, the tetrahedra having it as a face.
    #[serde(skip)]
    pub hull_tets: Vec<Vec<u32>>,
    /// Neighbouring markers (Delaunay neighbours in UV space).
    pub neighbors: Vec<u32>,
    /// `variants × neighbors` positions of each neighbour's vertex in each variant's shape.
    #[serde(skip)]
    pub neighbor_positions: Vec<Point3<f64>>,
    /// Vertices this marker blends into, with their weights (all markers present).
    pub support: Vec<(u32, f64)>,
    /// The support entries in blending order (derived): first the `moving` vertices that
    /// some variant's shape displaces, then those none does (they only take the residual).
    #[serde(skip)]
    pub blend: Vec<(u32, f64)>,
    /// Number of leading `blend` entries that some variant displaces (derived).
    #[serde(skip)]
    pub moving: usize,
    /// `variants × moving` displacement of each moving `blend` vertex in each variant's
    /// shape (derived), in single precision: the per-frame blend reads a few megabytes of
    /// them, and halving that keeps more of the index in cache. Single precision is
    /// within 2e-6 mm at 30 mm of motion.
    #[serde(skip)]
    pub patch: Vec<[f32; 3]>,
}

impl MarkerIndex {
    /// Computes the fields derived from the stored ones (everything marked "derived"):
    /// tetrahedron volumes and faces, the grid, the hull's tetrahedra, and the variants'
    /// positions and patches copied out of the dataset's `displacements` for locality.
    /// Used by the build and when an index is read back from its cache.
    fn derive(
        &mut self,
        neutral: &[Point3<f64>],
        displacements: &[Vec<Vector3<f64>>],
        marker_vertices: &[u32],
        grid_entries_per_tet: f64,
    ) {
        let dim3 = self.simplices.dim == 3;
        let points = &self.points;
        let corners = &self.simplices.corners;
        if dim3 {
            self.inv_volume = corners
                .iter()
                .map(|c| {
                    let o = super::barycentric::orient(
                        &points[c[0] as usize],
                        &points[c[1] as usize],
                        &points[c[2] as usize],
                        &points[c[3] as usize],
                    );
                    if o != 0.0 { 1.0 / o } else { 0.0 }
                })
                .collect();
            let budget = (grid_entries_per_tet * corners.len() as f64) as usize;
            self.grid = Some(TetGrid::build(points, corners, budget));
            self.faces = corners
                .iter()
                .map(super::barycentric::TripleTable::faces)
                .collect();
            self.used_triples = super::barycentric::UsedTriples::new(corners);
            self.scan = super::barycentric::TetScan::new(&self.faces, &self.inv_volume);
            self.triple_inv_area2 = super::barycentric::triple_inv_area2(points);
        } else {
            self.inv_volume = Vec::new();
            self.grid = None;
            self.faces = Vec::new();
            self.used_triples = Default::default();
            self.scan = Default::default();
            self.triple_inv_area2 = Vec::new();
        }
        self.hull_tets = {
            let mut of: std::collections::HashMap<u32, usize> = Default::default();
            for (h, f) in self.hull.iter().enumerate() {
                let idx =
                    super::barycentric::triple_index(f[0] as usize, f[1] as usize, f[2] as usize)
                        as u32;
                of.insert(idx, h);
            }
            let mut lists = vec![Vec::new(); self.hull.len()];
            for (t, fs) in self.faces.iter().enumerate() {
                for f in fs {
                    if let Some(&h) = of.get(f) {
                        lists[h].push(t as u32);
                    }
                }
            }
            lists
        };
        let disp_of = |shape: Option<u32>, vertex: u32| -> Vector3<f64> {
            shape.map_or_else(Vector3::zeros, |s| {
                displacements[s as usize][vertex as usize]
            })
        };
        // The marker's position in each variant with the displacement rounded as the
        // patches store it, so the blend still passes exactly through the bundles.
        let v = self.vertex;
        self.variant_position = self
            .shapes
            .iter()
            .map(|&s| neutral[v as usize] + widen(narrow(disp_of(s, v))))
            .collect();
        let mut neighbor_positions = Vec::with_capacity(self.shapes.len() * self.neighbors.len());
        let (mut blend, still): (Vec<_>, Vec<_>) = self.support.iter().partition(|&&(sv, _)| {
            self.shapes
                .iter()
                .any(|&s| disp_of(s, sv) != Vector3::zeros())
        });
        let moving = blend.len();
        blend.extend(still);
        let mut patch = Vec::with_capacity(self.shapes.len() * moving);
        for &s in &self.shapes {
            for &k in &self.neighbors {
                let kv = marker_vertices[k as usize];
                neighbor_positions.push(neutral[kv as usize] + disp_of(s, kv));
            }
            for &(sv, _) in &blend[..moving] {
                patch.push(narrow(disp_of(s, sv)));
            }
        }
        self.blend = blend;
        self.moving = moving;
        self.neighbor_positions = neighbor_positions;
        self.patch = patch;
    }

    /// Positions of the given corner points.
    pub fn corners_of(&self, c: &[u16; 4]) -> [Point3<f64>; 4] {
        [
            self.points[c[0] as usize],
            self.points[c[1] as usize],
            self.points[c[2] as usize],
            self.points[c[3] as usize],
        ]
    }

    /// Corner positions of simplex `s`.
    pub fn corners(&self, s: usize) -> [Point3<f64>; 4] {
        let c = self.simplices.corners[s];
        [
            self.points[c[0] as usize],
            self.points[c[1] as usize],
            self.points[c[2] as usize],
            self.points[c[3] as usize],
        ]
    }
}

/// Build statistics, printed when the index is built.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct IndexStats {
    /// Markers indexed.
    pub markers: usize,
    /// Shapes in the dataset (neutral excluded).
    pub shapes: usize,
    /// Points kept, summed over markers.
    pub points: usize,
    /// Smallest and largest point count of a marker.
    pub points_min_max: (usize, usize),
    /// Shape evaluations left out because they do not move the marker.
    pub still: usize,
    /// Shape evaluations kept as variants of a coincident point.
    pub merged: usize,
    /// Variants (points plus merged shapes), summed over markers.
    pub variants: usize,
    /// Tetrahedron counts.
    pub tets: TetStats,
    /// Markers that fell back to triangles, segments or a single point.
    pub lower_dim_markers: usize,
    /// Grid list entries, summed over markers.
    pub grid_entries: usize,
    /// Build time, seconds.
    pub build_secs: f64,
}

impl std::fmt::Display for IndexStats {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "LGI index: {} markers over {} shapes; {} points ({}..{} per marker; {} still, {} \
             variants of coincident points); {} tetrahedra kept of {} combinations ({} too large, {} too thin, {} \
             over the cap); {} markers without tetrahedra; {} grid entries; built in {:.2} s",
            self.markers,
            self.shapes,
            self.points,
            self.points_min_max.0,
            self.points_min_max.1,
            self.still,
            self.merged,
            self.tets.kept,
            self.tets.combinations,
            self.tets.too_large,
            self.tets.too_thin,
            self.tets.capped,
            self.lower_dim_markers,
            self.grid_entries,
            self.build_secs
        )
    }
}

/// One marker's build output and counts.
struct BuiltMarker {
    index: MarkerIndex,
    tets: TetStats,
    still: usize,
    merged: usize,
    lower_dim: bool,
    grid_entries: usize,
}

/// The precomputed index of a dataset for a marker layout.
///
/// Serialized (the index cache, [`super::cache`]) without what is cheap to recompute: the
/// fields of [`MarkerIndex`] marked "derived" are rebuilt on deserialization, with the
/// same arithmetic as the build, so a cached index solves bit for bit like a fresh one.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
#[serde(from = "StoredIndex")]
pub struct LgiIndex {
    /// Per-marker indices, in layout order.
    pub markers: Vec<MarkerIndex>,
    /// Blending weights of every vertex.
    pub weights: NaturalNeighborWeights,
    /// Neutral positions, mm.
    pub neutral: Vec<Point3<f64>>,
    /// Per-shape displacements of every vertex (unskinned when `jaw` is set), mm.
    pub displacements: Vec<Vec<Vector3<f64>>>,
    /// Jaw skinning, when the index works in unskinned space (§6).
    pub jaw: Option<JawSpace>,
    /// Build statistics.
    pub stats: IndexStats,
    /// The parameters the index was built with (only the build-time fields matter).
    pub params: LgiParams,
}

/// The serialized part of [`LgiIndex`] (same fields, same order).
#[derive(serde::Deserialize)]
struct StoredIndex {
    markers: Vec<MarkerIndex>,
    weights: NaturalNeighborWeights,
    neutral: Vec<Point3<f64>>,
    displacements: Vec<Vec<Vector3<f64>>>,
    jaw: Option<JawSpace>,
    stats: IndexStats,
    params: LgiParams,
}

impl From<StoredIndex> for LgiIndex {
    fn from(s: StoredIndex) -> Self {
        let mut markers = s.markers;
        let marker_vertices: Vec<u32> = markers.iter().map(|m| m.vertex).collect();
        markers.par_iter_mut().for_each(|mi| {
            mi.derive(
                &s.neutral,
                &s.displacements,
                &marker_vertices,
                s.params.grid_entries_per_tet,
            );
        });
        Self {
            markers,
            weights: s.weights,
            neutral: s.neutral,
            displacements: s.displacements,
            jaw: s.jaw,
            stats: s.stats,
            params: s.params,
        }
    }
}

impl LgiIndex {
    /// Builds the index of `dataset` for `layout` (see the module docs).
    ///
    /// # Errors
    /// [`LgiError`] when the parameters are invalid, the layout does not fit the dataset,
    /// a marker has no usable UV, or the dataset has more shapes than a point cloud can
    /// index (65 535).
    pub fn build(
        dataset: &Dataset,
        layout: &MarkerLayout,
        params: &LgiParams,
    ) -> Result<Self, LgiError> {
        let t0 = std::time::Instant::now();
        params.validate()?;
        layout
            .validate_for(dataset)
            .map_err(|e| LgiError::Layout(e.to_string()))?;
        if dataset.shapes.len() >= u16::MAX as usize {
            return Err(LgiError::Dataset(format!(
                "{} shapes: at most {} can be indexed",
                dataset.shapes.len(),
                u16::MAX - 1
            )));
        }
        let neutral = dataset.neutral.positions.clone();
        let marker_vertices: Vec<u32> = layout.markers.iter().map(|m| m.vertex).collect();
        let jaw = super::jaw::jaw_space(dataset, params, &marker_vertices);
        let displacements: Vec<Vec<Vector3<f64>>> = dataset
            .shapes
            .par_iter()
            .enumerate()
            .map(|(n, s)| match &jaw {
                Some(j) => {
                    super::jaw::unskinned_displacement(&j.rig, &j.poses[n], &neutral, &s.positions)
                }
                None => s
                    .positions
                    .iter()
                    .zip(&neutral)
                    .map(|(p, x)| p - x)
                    .collect(),
            })
            .collect();
        let weights = NaturalNeighborWeights::build(
            &dataset.neutral,
            &|v| dataset.is_face_vertex(v as u32),
            &marker_vertices,
        )?;
        let support = weights.support(marker_vertices.len());
        let built: Vec<BuiltMarker> = marker_vertices
            .par_iter()
            .enumerate()
            .map(|(m, &v)| {
                let patch_vertices: Vec<u32> = support[m].iter().map(|e| e.0).collect();
                let cloud = build_point_cloud(
                    v as usize,
                    &patch_vertices,
                    &neutral,
                    &displacements,
                    params.min_motion_mm,
                    params.merge_tolerance_mm,
                    params.variant_tolerance_mm,
                );
                let (simplices, tstats) = tetrahedralize(
                    &cloud.points,
                    params.min_tet_quality,
                    params.max_tet_edge_mm,
                    params.max_tets_per_marker,
                );
                let neighbors = weights.neighbors[m].clone();
                let mut point_variants = vec![0u32];
                let mut shapes = Vec::new();
                let mut variant_point = Vec::new();
                let mut deformation_mm = Vec::new();
                for (j, vs) in cloud.variants.iter().enumerate() {
                    for &(s, d) in vs {
                        shapes.push(s);
                        variant_point.push(j as u16);
                        deformation_mm.push(d);
                    }
                    point_variants.push(shapes.len() as u32);
                }
                let lower_dim = simplices.dim < 3;
                let hull = if simplices.dim == 3 {
                    super::hull::hull_faces(&cloud.points)
                } else {
                    Vec::new()
                };
                let mut index = MarkerIndex {
                    vertex: v,
                    points: cloud.points,
                    point_variants,
                    shapes,
                    variant_point,
                    variant_position: Vec::new(),
                    deformation_mm,
                    simplices,
                    inv_volume: Vec::new(),
                    faces: Vec::new(),
                    scan: Default::default(),
                    triple_inv_area2: Vec::new(),
                    used_triples: Default::default(),
                    grid: None,
                    hull,
                    hull_tets: Vec::new(),
                    neighbors,
                    neighbor_positions: Vec::new(),
                    support: support[m].clone(),
                    blend: Vec::new(),
                    moving: 0,
                    patch: Vec::new(),
                };
                index.derive(
                    &neutral,
                    &displacements,
                    &marker_vertices,
                    params.grid_entries_per_tet,
                );
                let grid_entries = index.grid.as_ref().map_or(0, TetGrid::entries);
                BuiltMarker {
                    index,
                    tets: tstats,
                    still: cloud.still,
                    merged: cloud.merged,
                    lower_dim,
                    grid_entries,
                }
            })
            .collect();
        let mut stats = IndexStats {
            markers: built.len(),
            shapes: dataset.shapes.len(),
            points_min_max: (usize::MAX, 0),
            ..Default::default()
        };
        let mut markers = Vec::with_capacity(built.len());
        for b in built {
            let n = b.index.points.len();
            stats.points += n;
            stats.points_min_max.0 = stats.points_min_max.0.min(n);
            stats.points_min_max.1 = stats.points_min_max.1.max(n);
            stats.still += b.still;
            stats.variants += b.index.shapes.len();
            stats.merged += b.merged;
            stats.lower_dim_markers += usize::from(b.lower_dim);
            stats.tets.add(&b.tets);
            stats.grid_entries += b.grid_entries;
            markers.push(b.index);
        }
        stats.build_secs = t0.elapsed().as_secs_f64();
        tracing::info!("{stats}");
        Ok(Self {
            markers,
            weights,
            neutral,
            displacements,
            jaw,
            stats,
            params: *params,
        })
    }
}

/// A displacement in the patches' single precision.
#[inline]
pub fn narrow(d: Vector3<f64>) -> [f32; 3] {
    [d.x as f32, d.y as f32, d.z as f32]
}

/// A patch displacement back in double precision.
#[inline]
pub fn widen(d: [f32; 3]) -> Vector3<f64> {
    Vector3::new(f64::from(d[0]), f64::from(d[1]), f64::from(d[2]))
}
