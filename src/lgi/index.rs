//! The frame-independent part of local geometric indexing: per marker, the point cloud
//! (§4), its tetrahedra (§4.1), a uniform grid over them (§4), the marker's blending patch
//! with the natural-neighbour weights (§5) and, for each point, the patch's displacement
//! and the neighbouring markers' positions in that point's shape (for the choice of §5.1).

use nalgebra::{Point3, Vector3};
use rayon::prelude::*;

use super::natural_neighbor::NaturalNeighborWeights;
use super::point_cloud::build_point_cloud;
use super::tetrahedra::{Simplices, TetStats, tetrahedralize};
use super::{LgiError, LgiParams, grid::TetGrid};
use crate::dataset::{Dataset, JawPose, MarkerLayout};

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
    pub variant_position: Vec<Point3<f64>>,
    /// Patch deformation of each variant's shape (RMS displacement), mm: the tie-break.
    pub deformation_mm: Vec<f64>,
    /// Tetrahedra (or lower simplices) over the points.
    pub simplices: Simplices,
    /// `1 / det[b − a, c − a, d − a]` of each tetrahedron (see
    /// [`super::barycentric::TripleTable`]).
    pub inv_volume: Vec<f64>,
    /// Face triples of each tetrahedron ([`super::barycentric::TripleTable::faces`]).
    pub faces: Vec<[u32; 4]>,
    /// `1 / (2 · area)` of every triple's triangle (for distances to face planes).
    pub triple_inv_area2: Vec<f64>,
    /// The face triples the tetrahedra use (see [`super::barycentric::used_triples`]).
    pub used_triples: Vec<(u32, [u16; 3])>,
    /// Grid over the tetrahedra (`None` below dimension 3).
    pub grid: Option<TetGrid>,
    /// Convex hull triangles of the points (empty below dimension 3).
    pub hull: Vec<[u16; 3]>,
    /// For each hull triangle, the tetrahedra having it as a face.
    pub hull_tets: Vec<Vec<u32>>,
    /// Neighbouring markers (Delaunay neighbours in UV space).
    pub neighbors: Vec<u32>,
    /// `variants × neighbors` positions of each neighbour's vertex in each variant's shape.
    pub neighbor_positions: Vec<Point3<f64>>,
    /// Vertices this marker blends into, with their weights (all markers present).
    pub support: Vec<(u32, f64)>,
    /// `variants × support` displacement of each support vertex in each variant's shape.
    pub patch: Vec<Vector3<f64>>,
}

impl MarkerIndex {
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
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
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
}

/// The jaw data of an unskinned index (Cong et al. 2019 §6).
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct JawSpace {
    /// The rig (pivot, axes, per-vertex weights).
    pub rig: crate::dataset::JawRig,
    /// Jaw pose of each shape, θ_n.
    pub poses: Vec<JawPose>,
    /// Per-frame jaw pose estimate from the bundles.
    pub regression: super::jaw::JawRegression,
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
                let (inv_volume, grid) = if simplices.dim == 3 {
                    let inv: Vec<f64> = simplices
                        .corners
                        .iter()
                        .map(|c| {
                            let p = [
                                cloud.points[c[0] as usize],
                                cloud.points[c[1] as usize],
                                cloud.points[c[2] as usize],
                                cloud.points[c[3] as usize],
                            ];
                            let o = super::barycentric::orient(&p[0], &p[1], &p[2], &p[3]);
                            if o != 0.0 { 1.0 / o } else { 0.0 }
                        })
                        .collect();
                    let budget =
                        (params.grid_entries_per_tet * simplices.corners.len() as f64) as usize;
                    let g = TetGrid::build(&cloud.points, &simplices.corners, budget);
                    (inv, Some(g))
                } else {
                    (Vec::new(), None)
                };
                let disp_of = |shape: Option<u32>, vertex: u32| -> Vector3<f64> {
                    shape.map_or_else(Vector3::zeros, |s| {
                        displacements[s as usize][vertex as usize]
                    })
                };
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
                let variant_position: Vec<Point3<f64>> = shapes
                    .iter()
                    .map(|&s| neutral[v as usize] + disp_of(s, v))
                    .collect();
                let mut neighbor_positions = Vec::with_capacity(shapes.len() * neighbors.len());
                let mut patch = Vec::with_capacity(shapes.len() * support[m].len());
                for &s in &shapes {
                    for &k in &neighbors {
                        let kv = marker_vertices[k as usize];
                        neighbor_positions.push(neutral[kv as usize] + disp_of(s, kv));
                    }
                    for &(sv, _) in &support[m] {
                        patch.push(disp_of(s, sv));
                    }
                }
                let lower_dim = simplices.dim < 3;
                let faces: Vec<[u32; 4]> = if simplices.dim == 3 {
                    simplices
                        .corners
                        .iter()
                        .map(super::barycentric::TripleTable::faces)
                        .collect()
                } else {
                    Vec::new()
                };
                let used_triples = if simplices.dim == 3 {
                    super::barycentric::used_triples(&simplices.corners)
                } else {
                    Vec::new()
                };
                let hull = if simplices.dim == 3 {
                    super::hull::hull_faces(&cloud.points)
                } else {
                    Vec::new()
                };
                let hull_tets: Vec<Vec<u32>> = {
                    let mut of: std::collections::HashMap<u32, usize> = Default::default();
                    for (h, f) in hull.iter().enumerate() {
                        let idx = super::barycentric::triple_index(
                            f[0] as usize,
                            f[1] as usize,
                            f[2] as usize,
                        ) as u32;
                        of.insert(idx, h);
                    }
                    let mut lists = vec![Vec::new(); hull.len()];
                    for (t, fs) in faces.iter().enumerate() {
                        for f in fs {
                            if let Some(&h) = of.get(f) {
                                lists[h].push(t as u32);
                            }
                        }
                    }
                    lists
                };
                let triple_inv_area2 = if simplices.dim == 3 {
                    super::barycentric::triple_inv_area2(&cloud.points)
                } else {
                    Vec::new()
                };
                let still = cloud.still;
                let merged = cloud.merged;
                let grid_entries = grid.as_ref().map_or(0, TetGrid::entries);
                BuiltMarker {
                    index: MarkerIndex {
                        vertex: v,
                        points: cloud.points,
                        point_variants,
                        shapes,
                        variant_point,
                        variant_position,
                        deformation_mm,
                        simplices,
                        faces,
                        triple_inv_area2,
                        used_triples,
                        inv_volume,
                        hull_tets,
                        hull,
                        grid,
                        neighbors,
                        neighbor_positions,
                        support: support[m].clone(),
                        patch,
                    },
                    tets: tstats,
                    still,
                    merged,
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
        })
    }
}
