//! Natural-neighbour (Sibson) blending weights of every mesh vertex over the markers,
//! computed in UV space (Cong et al. 2019 §5: "constructing the Voronoi diagram and
//! calculating the natural neighbor weights in UV/texture space and subsequently mapping
//! them back onto the 3D mesh yielded smoother natural neighbor weights").
//!
//! A vertex placed at a marker gets weight 1 on that marker and 0 elsewhere, so the blended
//! surface passes through every bundle; the weights are continuous, so the surface is C0
//! (Piper 1993, reference 33 of the paper).
//!
//! # Vertices the UV Voronoi diagram does not cover
//! - **Outside the markers' convex hull** (in UV): Sibson coordinates are undefined there.
//!   The vertex takes the weights of its closest point on the hull, which on a hull edge are
//!   the linear weights of the edge's two markers (Sibson coordinates restricted to the
//!   hull boundary). Projection onto a convex set is continuous, so the weights stay
//!   continuous across the hull and the outer face follows the outermost markers.
//! - **On another UV island** than the one holding most markers (ears and neck in
//!   ICT-FaceKit, the eyes, teeth and mouth socket, any vertex outside the dataset's face
//!   range): UV distances to the markers mean nothing there. The vertex copies the weights
//!   of the nearest (3D, neutral pose) vertex that has UV weights, and so is carried along
//!   with the nearest part of the face. Its own displacement in each chosen shape is still
//!   used. A marker on such an island stands, in UV, at its nearest main-island vertex, so
//!   the surface still passes through its bundle.
//! - **A mesh without UVs**: the frontal projection (x, y) of the neutral stands in for UV.
//!
//! # Missing markers
//! Removing a marker from the diagram changes only the weights of vertices whose inserted
//! cell overlapped its cell, which are exactly the vertices with a non-zero weight on it
//! ([`NaturalNeighborWeights::support`]). [`NaturalNeighborWeights::recompute`] redoes
//! those vertices with the present markers only: the neighbours take the missing marker's
//! area.
//!
//! Several missing markers split into independent clusters
//! ([`NaturalNeighborWeights::missing_clusters`]): two missing markers share a cluster when
//! they are Delaunay neighbours or some vertex has weight on both. Removing a cluster
//! re-triangulates only the hole its markers leave, among their Delaunay neighbours, so a
//! vertex in the support of one cluster only gets the same weights whether the other
//! clusters are removed too or not. Each cluster's weights can then be computed (and
//! cached) on its own: in a stream the set of missing markers changes almost every frame,
//! while its clusters (an occluded eyelid, one edge-on dot) recur.
//!
//! A helmet rig does not see every marker: a third to a half of them may be hidden for a
//! whole take, and they make one large cluster, which every marker shown or hidden beside
//! it changes. A new cluster is then computed from the cached one nearest to it
//! ([`NaturalNeighborWeights::update_shared`]): only the vertices whose natural neighbours
//! changed are queried again (a quarter of the queries on the `cluttered` synth preset).

use nalgebra::{Point2, Point3};
use spade::{DelaunayTriangulation, HasPosition, Triangulation};

use crate::mesh::Mesh;
use crate::numeric::{NearestPoints, find_root, join_sets};

/// A marker site in the UV-space Delaunay triangulation.
#[derive(Debug, Clone, Copy)]
struct Site {
    uv: spade::Point2<f64>,
    marker: u32,
}

impl HasPosition for Site {
    type Scalar = f64;
    fn position(&self) -> spade::Point2<f64> {
        self.uv
    }
}

/// Errors from building the blending weights.
#[derive(Debug, thiserror::Error)]
pub enum NaturalNeighborError {
    /// Two markers have the same UV position (or a UV is not finite).
    #[error("markers {a} and {b} share UV position ({u}, {v}); every marker needs its own UV")]
    SharedUv {
        /// One marker index.
        a: usize,
        /// The other.
        b: usize,
        /// U coordinate.
        u: f64,
        /// V coordinate.
        v: f64,
    },
    /// A marker vertex has no usable UV or is out of range.
    #[error("marker {0} sits on a vertex with no usable texture coordinate")]
    NoUv(usize),
    /// Fewer than one marker to blend.
    #[error("no markers to blend")]
    NoMarkers,
}

/// Sparse blending weights: for every mesh vertex, `(marker, λ)` pairs with `Σ λ = 1`.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct NaturalNeighborWeights {
    /// Start of each vertex's entries in `entries` (#V + 1).
    pub offsets: Vec<u32>,
    /// `(marker index, weight)` pairs.
    pub entries: Vec<(u32, f64)>,
    /// Vertex that each vertex copies its weights from (itself when it has UV weights).
    pub source: Vec<u32>,
    /// 2D coordinate of every vertex used for the diagram (UV or frontal projection);
    /// NaN for vertices that copy.
    pub uv: Vec<Point2<f64>>,
    /// 2D coordinate of each marker.
    pub marker_uv: Vec<Point2<f64>>,
    /// Delaunay neighbours of each marker in UV space (all markers present), ascending.
    pub neighbors: Vec<Vec<u32>>,
}

impl NaturalNeighborWeights {
    /// Weights of vertex `v`.
    pub fn of(&self, v: usize) -> &[(u32, f64)] {
        &self.entries[self.offsets[v] as usize..self.offsets[v + 1] as usize]
    }

    /// For each marker, the vertices with a non-zero weight on it and the weights
    /// (ascending vertex order).
    pub fn support(&self, marker_count: usize) -> Vec<Vec<(u32, f64)>> {
        let mut out = vec![Vec::new(); marker_count];
        for v in 0..self.offsets.len() - 1 {
            for &(m, w) in self.of(v) {
                out[m as usize].push((v as u32, w));
            }
        }
        out
    }

    /// Builds the weights of every vertex of `mesh` over the markers on
    /// `marker_vertices`; only vertices in `face` (and on a UV island holding a marker)
    /// get UV weights, the others copy (see the module docs).
    ///
    /// # Errors
    /// [`NaturalNeighborError`] when a marker has no usable UV or two markers share one.
    pub fn build(
        mesh: &Mesh,
        face: &dyn Fn(usize) -> bool,
        marker_vertices: &[u32],
    ) -> Result<Self, NaturalNeighborError> {
        if marker_vertices.is_empty() {
            return Err(NaturalNeighborError::NoMarkers);
        }
        let n = mesh.vertex_count();
        let (coords, island) = vertex_coords(mesh);
        // The UV domain is the island holding the most markers; only its vertices get UV
        // weights (UV coordinates of different islands are unrelated).
        let mut counts: std::collections::HashMap<u32, usize> = Default::default();
        for (m, &v) in marker_vertices.iter().enumerate() {
            let v = v as usize;
            if v >= n || !coords[v].x.is_finite() || !coords[v].y.is_finite() {
                return Err(NaturalNeighborError::NoUv(m));
            }
            *counts.entry(island[v]).or_default() += 1;
        }
        let main = counts
            .iter()
            .max_by_key(|(i, c)| (**c, std::cmp::Reverse(**i)))
            .map(|(i, _)| *i)
            .ok_or(NaturalNeighborError::NoMarkers)?;
        let uv_vertex: Vec<bool> = (0..n)
            .map(|v| face(v) && coords[v].x.is_finite() && island[v] == main)
            .collect();
        // A marker off the main island stands at its nearest (3D) main-island vertex, so
        // that vertex, and the marker's own vertex that copies it, get weight 1 on it.
        let source = nearest_sources(&mesh.positions, &uv_vertex);
        let mut marker_uv: Vec<Point2<f64>> = marker_vertices
            .iter()
            .map(|&v| coords[v as usize])
            .collect();
        let key = |p: &Point2<f64>| (p.x.to_bits(), p.y.to_bits());
        let mut taken: std::collections::HashSet<(u64, u64)> = marker_vertices
            .iter()
            .filter(|&&v| uv_vertex[v as usize])
            .map(|&v| key(&coords[v as usize]))
            .collect();
        let mut marker_sources = Vec::new();
        for (m, &v) in marker_vertices.iter().enumerate() {
            let v = v as usize;
            if uv_vertex[v] {
                continue;
            }
            // Nearest main-island vertex whose UV no other marker uses.
            let mut cands: Vec<(f64, usize)> = (0..n)
                .filter(|&u| uv_vertex[u])
                .map(|u| ((mesh.positions[u] - mesh.positions[v]).norm_squared(), u))
                .collect();
            cands.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
            let u = cands
                .iter()
                .map(|c| c.1)
                .find(|&u| !taken.contains(&key(&coords[u])))
                .ok_or(NaturalNeighborError::NoUv(m))?;
            taken.insert(key(&coords[u]));
            marker_uv[m] = coords[u];
            marker_sources.push((v, u as u32));
        }
        let mut source = source;
        for (v, u) in marker_sources {
            source[v] = u;
        }
        let all: Vec<bool> = vec![true; marker_vertices.len()];
        let tri = triangulate(&marker_uv, &all)?;
        let neighbors = delaunay_neighbors(&tri, marker_vertices.len());

        // UV weights for the vertices that have them.
        let mut per_vertex: Vec<Vec<(u32, f64)>> = vec![Vec::new(); n];
        let nn = tri.natural_neighbor();
        let mut buf = Vec::new();
        for v in 0..n {
            if uv_vertex[v] {
                per_vertex[v] = weights_at(&tri, &nn, coords[v], &mut buf);
            }
        }
        // Everything else copies its nearest UV-weighted vertex.
        let mut offsets = Vec::with_capacity(n + 1);
        let mut entries = Vec::new();
        offsets.push(0u32);
        for &s in &source {
            entries.extend_from_slice(&per_vertex[s as usize]);
            offsets.push(entries.len() as u32);
        }
        let uv = (0..n)
            .map(|v| {
                if uv_vertex[v] {
                    coords[v]
                } else {
                    Point2::new(f64::NAN, f64::NAN)
                }
            })
            .collect();
        Ok(Self {
            offsets,
            entries,
            source,
            uv,
            marker_uv,
            neighbors,
        })
    }

    /// The missing markers (`present[m]` false) grouped into clusters whose weights are
    /// independent (see the module docs): each cluster ascending, clusters ordered by their
    /// first marker. `supports[m]` lists the vertices with weight on marker `m`
    /// ([`Self::support`]).
    pub fn missing_clusters(&self, present: &[bool], supports: &[&[(u32, f64)]]) -> Vec<Vec<u32>> {
        let count = present.len();
        let is_missing = |m: u32| !present.get(m as usize).copied().unwrap_or(true);
        let mut parent: Vec<u32> = (0..count as u32).collect();
        // The first missing marker met on each (source) vertex; u32::MAX: none yet.
        let mut owner = vec![u32::MAX; self.source.len()];
        for m in (0..count as u32).filter(|&m| is_missing(m)) {
            for &nb in self.neighbors.get(m as usize).map_or(&[][..], |n| n) {
                if is_missing(nb) {
                    join_sets(&mut parent, m, nb);
                }
            }
            // Vertices that copy a source have its weights: the sources decide.
            for &(v, _) in supports.get(m as usize).copied().unwrap_or_default() {
                let v = self.source.get(v as usize).copied().unwrap_or(v) as usize;
                match owner.get(v).copied() {
                    Some(u32::MAX) => owner[v] = m,
                    Some(other) => join_sets(&mut parent, m, other),
                    None => {}
                }
            }
        }
        let mut clusters: std::collections::BTreeMap<u32, Vec<u32>> = Default::default();
        for m in (0..count as u32).filter(|&m| is_missing(m)) {
            let root = find_root(&mut parent, m);
            clusters.entry(root).or_default().push(m);
        }
        clusters.into_values().collect()
    }

    /// Weights of `vertices` with only the markers flagged in `present` (missing markers
    /// left out of the diagram); one list per vertex, in the given order. Vertices that
    /// copy use their source's recomputed weights.
    ///
    /// # Errors
    /// [`NaturalNeighborError::NoMarkers`] when no marker is present.
    pub fn recompute(
        &self,
        present: &[bool],
        vertices: &[u32],
    ) -> Result<Vec<Vec<(u32, f64)>>, NaturalNeighborError> {
        let shared = self.recompute_shared(present, vertices)?;
        Ok((0..vertices.len()).map(|k| shared.of(k).to_vec()).collect())
    }

    /// As [`Self::recompute`], with the weights of vertices that copy the same source
    /// stored once.
    ///
    /// # Errors
    /// [`NaturalNeighborError::NoMarkers`] when no marker is present.
    pub fn recompute_shared(
        &self,
        present: &[bool],
        vertices: &[u32],
    ) -> Result<SharedWeights, NaturalNeighborError> {
        let tri = triangulate(&self.marker_uv, present)?;
        let nn = tri.natural_neighbor();
        let mut buf = Vec::new();
        Ok(self.per_source(vertices, |_, s, out| {
            out.extend(weights_at(&tri, &nn, self.uv[s as usize], &mut buf));
        }))
    }

    /// The weights of `vertices`, computed once per distinct source (many vertices copy
    /// the same one: the non-face parts of the head) by `weigh(vertex, source, entries)`,
    /// which appends them to `entries`; `vertex` is the first of the list with that source.
    fn per_source(
        &self,
        vertices: &[u32],
        mut weigh: impl FnMut(u32, u32, &mut Vec<(u32, f64)>),
    ) -> SharedWeights {
        // The slot of each source done so far, indexed by the source vertex (a dense table:
        // a hash map's hashing was a tenth of a cluttered replay's solve).
        const NOT_DONE: u32 = u32::MAX;
        let mut done = vec![NOT_DONE; self.source.len()];
        let mut out = SharedWeights {
            slot: Vec::with_capacity(vertices.len()),
            offsets: vec![0],
            entries: Vec::new(),
        };
        for &v in vertices {
            let s = self.source[v as usize];
            let slot = match done.get(s as usize) {
                Some(&k) if k != NOT_DONE => k,
                _ => {
                    let k = (out.offsets.len() - 1) as u32;
                    if let Some(d) = done.get_mut(s as usize) {
                        *d = k;
                    }
                    weigh(v, s, &mut out.entries);
                    out.offsets.push(out.entries.len() as u32);
                    k
                }
            };
            out.slot.push(slot);
        }
        out
    }
}

/// The weights of a list of vertices computed for other missing markers
/// ([`NaturalNeighborWeights::update_shared`]): the list (ascending), its weights, and the
/// markers that were missing then and are present now (`added`), or present then and
/// missing now (`removed`).
#[derive(Debug, Clone, Copy)]
pub struct WeightsBefore<'a> {
    /// The vertices, ascending.
    pub vertices: &'a [u32],
    /// Their weights.
    pub weights: &'a SharedWeights,
    /// Markers missing then, present now.
    pub added: &'a [u32],
    /// Markers present then, missing now.
    pub removed: &'a [u32],
}

/// Weights of a list of vertices, those of vertices that copy the same source stored once
/// ([`NaturalNeighborWeights::recompute_shared`]).
#[derive(Debug, Clone, Default)]
pub struct SharedWeights {
    /// Per vertex of the list, its slot.
    slot: Vec<u32>,
    /// Start of each slot's entries in `entries` (#slots + 1).
    offsets: Vec<u32>,
    /// `(marker, λ)` pairs.
    entries: Vec<(u32, f64)>,
}

impl SharedWeights {
    /// Weights of the `k`-th vertex of the list.
    pub fn of(&self, k: usize) -> &[(u32, f64)] {
        let slot = self.slot[k] as usize;
        &self.entries[self.offsets[slot] as usize..self.offsets[slot + 1] as usize]
    }

    /// Number of vertices.
    pub fn len(&self) -> usize {
        self.slot.len()
    }

    /// Whether the list is empty.
    pub fn is_empty(&self) -> bool {
        self.slot.is_empty()
    }
}

impl NaturalNeighborWeights {
    /// [`Self::recompute_shared`] for `present`, from the weights of an earlier set of
    /// missing markers: only the vertices whose natural neighbours changed are queried
    /// again, the others keep their weights.
    ///
    /// Sibson weights at a point depend only on its natural neighbours, the sites of the
    /// Delaunay triangles whose circumcircles hold it (within its inserted cell the
    /// Voronoi diagram is that of those sites). A vertex keeps them unless it had weight on
    /// a marker now removed, or lies in the circumcircle of a triangle of the new diagram
    /// at a marker now added (then it has weight on it). A vertex outside the hull takes
    /// the weights of its closest hull edge instead; the hull only shrinks when markers are
    /// removed (and edges not at a removed marker stay), so only an added marker on the
    /// new hull can move it: then every vertex outside the old hull is queried again,
    /// those with at most two weights (an edge's linear weights, or one at a hull
    /// marker). A vertex inside the old hull and outside the new lies in a Delaunay
    /// triangle at a removed marker (the hull shrank there), so it had weight on it; one
    /// outside the old hull and inside the new lies in a triangle at the added marker,
    /// so in its circumcircle (on cluttered, an added marker on the hull had every vertex
    /// queried again in 42 of the 99 updates of a 120-frame replay, 88 % of the queries).
    /// A stream's missing markers change by a few a frame while most of them stay hidden,
    /// and their cluster (one large one on a helmet rig, which does not see half the face)
    /// changes with them.
    ///
    /// # Errors
    /// [`NaturalNeighborError::NoMarkers`] when no marker is present.
    pub fn update_shared(
        &self,
        present: &[bool],
        vertices: &[u32],
        before: WeightsBefore<'_>,
    ) -> Result<SharedWeights, NaturalNeighborError> {
        let tri = triangulate(&self.marker_uv, present)?;
        let marker_count = self.marker_uv.len();
        let mut is_added = vec![false; marker_count];
        for &m in before.added {
            if let Some(a) = is_added.get_mut(m as usize) {
                *a = true;
            }
        }
        let added = |m: u32| is_added.get(m as usize).copied().unwrap_or(false);
        let degenerate = tri.num_vertices() < 3 || tri.all_vertices_on_line();
        let on_hull = tri.undirected_edges().any(|e| {
            e.is_part_of_convex_hull() && e.vertices().iter().any(|v| added(v.data().marker))
        });
        // Circumcircles at the added markers, a little grown: a vertex on one (within
        // rounding) is queried again.
        let circles: Vec<(Point2<f64>, f64)> = tri
            .inner_faces()
            .filter(|f| f.vertices().iter().any(|v| added(v.data().marker)))
            .map(|f| {
                let (c, r2) = f.circumcircle();
                (Point2::new(c.x, c.y), r2 * (1.0 + 1e-9) + 1e-12)
            })
            .collect();
        let mut is_removed = vec![false; marker_count];
        for &m in before.removed {
            if let Some(r) = is_removed.get_mut(m as usize) {
                *r = true;
            }
        }
        let removed = |m: u32| is_removed.get(m as usize).copied().unwrap_or(false);
        let nn = tri.natural_neighbor();
        let mut buf = Vec::new();
        Ok(self.per_source(vertices, |v, s, out| {
            let uv = self.uv[s as usize];
            let kept = before
                .vertices
                .binary_search(&v)
                .ok()
                .map(|i| before.weights.of(i))
                .filter(|w| {
                    !(degenerate
                        || (on_hull && w.len() <= 2)
                        || w.iter().any(|e| removed(e.0))
                        || circles.iter().any(|(c, r2)| (uv - c).norm_squared() <= *r2))
                });
            match kept {
                Some(w) => out.extend_from_slice(w),
                None => out.extend(weights_at(&tri, &nn, uv, &mut buf)),
            }
        }))
    }
}

/// Delaunay triangulation of the present markers' UVs.
fn triangulate(
    marker_uv: &[Point2<f64>],
    present: &[bool],
) -> Result<DelaunayTriangulation<Site>, NaturalNeighborError> {
    let mut tri: DelaunayTriangulation<Site> = DelaunayTriangulation::new();
    let mut seen: std::collections::HashMap<(u64, u64), usize> = Default::default();
    let mut count = 0;
    for (m, uv) in marker_uv.iter().enumerate() {
        if !present.get(m).copied().unwrap_or(false) {
            continue;
        }
        let site = Site {
            uv: spade::Point2::new(uv.x, uv.y),
            marker: m as u32,
        };
        if let Some(&other) = seen.get(&(uv.x.to_bits(), uv.y.to_bits())) {
            return Err(NaturalNeighborError::SharedUv {
                a: other,
                b: m,
                u: uv.x,
                v: uv.y,
            });
        }
        seen.insert((uv.x.to_bits(), uv.y.to_bits()), m);
        tri.insert(site)
            .map_err(|_| NaturalNeighborError::NoUv(m))?;
        count += 1;
    }
    if count == 0 {
        return Err(NaturalNeighborError::NoMarkers);
    }
    Ok(tri)
}

/// Sibson weights at `p`, or the weights of its closest point on the convex hull when
/// `p` lies outside it.
fn weights_at(
    tri: &DelaunayTriangulation<Site>,
    nn: &spade::NaturalNeighbor<'_, DelaunayTriangulation<Site>>,
    p: Point2<f64>,
    buf: &mut Vec<(spade::handles::FixedVertexHandle, f64)>,
) -> Vec<(u32, f64)> {
    let marker = |h: spade::handles::FixedVertexHandle| tri.vertex(h).data().marker;
    if tri.num_vertices() == 1 {
        return tri.vertices().map(|v| (v.data().marker, 1.0)).collect();
    }
    if tri.num_vertices() >= 3 && tri.all_vertices_on_line() {
        // Degenerate diagram: fall through to the hull (segment) projection below.
    } else if tri.num_vertices() >= 3 {
        let q = spade::Point2::new(p.x, p.y);
        // Located first: a point outside the hull (Sibson weights have none there) goes
        // straight to the hull below, without the natural-neighbour query's own locating.
        let at = tri.locate(q);
        if !matches!(at, spade::PositionInTriangulation::OutsideOfConvexHull(_)) {
            nn.get_weights(q, buf);
        } else {
            buf.clear();
        }
        if !buf.is_empty() && buf.iter().all(|e| e.1.is_finite()) {
            return normalized(buf.iter().map(|&(h, w)| (marker(h), w)).collect());
        }
        // Numerically degenerate insertion cell (a point on a hull edge up to rounding,
        // cocircular sites): the Delaunay triangle's linear weights, which agree with
        // Sibson's on the hull edges.
        if let spade::PositionInTriangulation::OnFace(f) = at {
            let face = tri.face(f);
            let w = face.barycentric_interpolation(q);
            if w.iter().all(|x| x.is_finite()) {
                let vs = face.vertices();
                return normalized(
                    vs.iter()
                        .zip(w)
                        .map(|(v, x)| (v.data().marker, x.max(0.0)))
                        .collect(),
                );
            }
        }
    }
    // Outside the hull (or a line of markers): closest point on the hull's edges (on a
    // line of markers, every edge).
    let mut best: Option<(f64, Vec<(u32, f64)>)> = None;
    let q = Point3::new(p.x, p.y, 0.0);
    let mut consider = |a: spade::handles::VertexHandle<'_, Site>,
                        b: spade::handles::VertexHandle<'_, Site>| {
        let pa = Point3::new(a.position().x, a.position().y, 0.0);
        let pb = Point3::new(b.position().x, b.position().y, 0.0);
        let t = super::barycentric::closest_on_segment(&pa, &pb, &q);
        let d = (pa + (pb - pa) * t - q).norm_squared();
        if best.as_ref().is_none_or(|(bd, _)| d < *bd) {
            best = Some((d, vec![(a.data().marker, 1.0 - t), (b.data().marker, t)]));
        }
    };
    if tri.num_vertices() >= 3 && !tri.all_vertices_on_line() {
        // The hull's own edges, not every edge tested for being one (a tenth as many on a
        // face's markers; a replay queries thousands of vertices outside the hull).
        for e in tri.convex_hull() {
            consider(e.from(), e.to());
        }
    } else {
        for e in tri.undirected_edges() {
            let [a, b] = e.vertices();
            consider(a, b);
        }
    }
    best.map(|(_, w)| normalized(w)).unwrap_or_default()
}

/// Drops zero weights, renormalizes to sum 1, sorts by marker.
fn normalized(mut w: Vec<(u32, f64)>) -> Vec<(u32, f64)> {
    w.retain(|&(_, x)| x > 0.0);
    let s: f64 = w.iter().map(|&(_, x)| x).sum();
    if s > 0.0 {
        for (_, x) in &mut w {
            *x /= s;
        }
    }
    w.sort_by_key(|&(m, _)| m);
    w
}

/// Delaunay neighbours of each marker.
fn delaunay_neighbors(tri: &DelaunayTriangulation<Site>, count: usize) -> Vec<Vec<u32>> {
    let mut out = vec![Vec::new(); count];
    for e in tri.undirected_edges() {
        let [a, b] = e.vertices();
        let (a, b) = (a.data().marker, b.data().marker);
        out[a as usize].push(b);
        out[b as usize].push(a);
    }
    for n in &mut out {
        n.sort_unstable();
        n.dedup();
    }
    out
}

/// 2D coordinate of each vertex (its first corner's UV, or the frontal projection when the
/// mesh has no UVs) and the UV island of that corner (all 0 without UVs).
fn vertex_coords(mesh: &Mesh) -> (Vec<Point2<f64>>, Vec<u32>) {
    let n = mesh.vertex_count();
    if !mesh.has_uvs() {
        return (
            mesh.positions
                .iter()
                .map(|p| Point2::new(p.x, p.y))
                .collect(),
            vec![0; n],
        );
    }
    // Union-find over UV indices joined by polygons.
    let mut parent: Vec<u32> = (0..mesh.uvs.len() as u32).collect();
    for f in 0..mesh.face_count() {
        let t = mesh.face_uv(f);
        for w in t.windows(2) {
            let (a, b) = (find_root(&mut parent, w[0]), find_root(&mut parent, w[1]));
            if a != b {
                parent[a as usize] = b;
            }
        }
    }
    let mut coords = vec![Point2::new(f64::NAN, f64::NAN); n];
    let mut island = vec![u32::MAX; n];
    for (&v, &t) in mesh.face_vertices.iter().zip(&mesh.face_uvs) {
        if island[v as usize] == u32::MAX {
            island[v as usize] = find_root(&mut parent, t);
            coords[v as usize] = mesh.uvs[t as usize];
        }
    }
    (coords, island)
}

/// For each vertex, the nearest vertex (3D) flagged in `has`; itself when flagged.
pub fn nearest_sources(positions: &[Point3<f64>], has: &[bool]) -> Vec<u32> {
    use rayon::prelude::*;
    let targets: Vec<u32> = (0..positions.len() as u32)
        .filter(|&v| has[v as usize])
        .collect();
    if targets.is_empty() {
        return (0..positions.len() as u32).collect();
    }
    let index = NearestPoints::new(targets.iter().map(|&t| positions[t as usize]));
    (0..positions.len())
        .into_par_iter()
        .map(|v| {
            if has[v] {
                v as u32
            } else {
                // Of equally near targets the first (a vertex with a non-finite
                // position takes the first target).
                index
                    .nearest_first(&positions[v])
                    .map_or(targets[0], |(i, _)| targets[i])
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::test_meshes::grid;

    #[test]
    fn weights_interpolate_markers_and_sum_to_one() {
        let mesh = grid(10, 1.0);
        let markers = [12u32, 18, 60, 100, 104, 56];
        let w = NaturalNeighborWeights::build(&mesh, &|_| true, &markers).unwrap();
        for v in 0..mesh.vertex_count() {
            let s: f64 = w.of(v).iter().map(|e| e.1).sum();
            assert!((s - 1.0).abs() < 1e-9, "vertex {v}: {s}");
            assert!(w.of(v).iter().all(|e| e.1 > 0.0));
        }
        for (m, &v) in markers.iter().enumerate() {
            assert_eq!(w.of(v as usize), &[(m as u32, 1.0)]);
        }
        // Linear precision of Sibson coordinates: reproduces the UV of interior vertices.
        for v in 0..mesh.vertex_count() {
            let uv = w.uv[v];
            let rec = w
                .of(v)
                .iter()
                .fold(Point2::origin(), |acc: Point2<f64>, &(m, l)| {
                    acc + w.marker_uv[m as usize].coords * l
                });
            if w.of(v).len() >= 3 {
                assert!((rec - uv).norm() < 1e-9, "vertex {v}");
            }
        }
        // Vertex 0 is outside the hull: it takes the hull edge's weights.
        assert!(w.of(0).len() <= 2);
    }

    #[test]
    fn missing_marker_neighbors_take_its_area() {
        let mesh = grid(10, 1.0);
        let markers = [12u32, 18, 60, 100, 104, 56];
        let w = NaturalNeighborWeights::build(&mesh, &|_| true, &markers).unwrap();
        let present = [true, true, false, true, true, true];
        let support = w.support(markers.len());
        let verts: Vec<u32> = support[2].iter().map(|e| e.0).collect();
        let new = w.recompute(&present, &verts).unwrap();
        for ws in &new {
            assert!(ws.iter().all(|e| e.0 != 2));
            assert!((ws.iter().map(|e| e.1).sum::<f64>() - 1.0).abs() < 1e-9);
        }
        // A vertex without weight on marker 2 keeps its weights.
        let all: Vec<u32> = (0..mesh.vertex_count() as u32).collect();
        let full = w.recompute(&present, &all).unwrap();
        for (v, fv) in full.iter().enumerate() {
            if w.of(v).iter().all(|e| e.0 != 2) {
                let get =
                    |ws: &[(u32, f64)], m: u32| ws.iter().find(|e| e.0 == m).map_or(0.0, |e| e.1);
                for m in 0..markers.len() as u32 {
                    let (a, b) = (get(w.of(v), m), get(fv, m));
                    assert!(
                        (a - b).abs() < 1e-9,
                        "vertex {v} marker {m}: {a} became {b}"
                    );
                }
            }
        }
    }

    /// `count` distinct values below `n` from `next`.
    fn distinct(next: &mut impl FnMut(u32) -> u32, n: u32, count: usize) -> Vec<u32> {
        let mut out: Vec<u32> = Vec::new();
        while out.len() < count {
            let v = next(n);
            if !out.contains(&v) {
                out.push(v);
            }
        }
        out
    }

    /// Weights of the missing markers' supports computed cluster by cluster equal those
    /// computed with every missing marker removed at once, on random layouts and missing
    /// sets (markers on the hull, neighbours missing together, vertices outside the hull).
    #[test]
    fn clusters_of_missing_markers_are_independent() {
        let mesh = grid(30, 1.0);
        let n = mesh.vertex_count() as u32;
        let mut rng: rand::rngs::StdRng = rand::SeedableRng::seed_from_u64(7);
        let mut next = move |below: u32| rand::Rng::random_range(&mut rng, 0..below);
        let mut compared = 0;
        for _ in 0..60 {
            let markers = distinct(&mut next, n, 40);
            let w = NaturalNeighborWeights::build(&mesh, &|_| true, &markers).unwrap();
            let support = w.support(markers.len());
            let supports: Vec<&[(u32, f64)]> = support.iter().map(|s| &s[..]).collect();
            for _ in 0..5 {
                let mut present = vec![true; markers.len()];
                for _ in 0..1 + next(10) {
                    present[next(markers.len() as u32) as usize] = false;
                }
                let clusters = w.missing_clusters(&present, &supports);
                let mut seen = 0;
                for cluster in &clusters {
                    seen += cluster.len();
                    let mut present_c = vec![true; markers.len()];
                    let mut verts: Vec<u32> = Vec::new();
                    for &m in cluster {
                        present_c[m as usize] = false;
                        verts.extend(support[m as usize].iter().map(|e| e.0));
                    }
                    verts.sort_unstable();
                    verts.dedup();
                    let alone = w.recompute(&present_c, &verts).unwrap();
                    let together = w.recompute(&present, &verts).unwrap();
                    // Equal up to rounding (spade may return a 1e-16 weight on a
                    // cocircular site in one diagram and none in the other).
                    let get = |ws: &[(u32, f64)], m: u32| {
                        ws.iter().find(|e| e.0 == m).map_or(0.0, |e| e.1)
                    };
                    for ((v, a), b) in verts.iter().zip(&alone).zip(&together) {
                        for m in 0..markers.len() as u32 {
                            let (x, y) = (get(a, m), get(b, m));
                            assert!((x - y).abs() < 1e-9, "vertex {v}: {a:?} vs {b:?}");
                        }
                        compared += 1;
                    }
                }
                assert_eq!(seen, present.iter().filter(|p| !**p).count());
            }
        }
        assert!(compared > 10_000, "{compared}");
    }

    /// Weights updated from those of another set of missing markers equal weights
    /// computed afresh, on random layouts and changes (markers hidden and shown, on the
    /// hull and inside it, many missing at once), and the update queries fewer vertices.
    #[test]
    fn updated_weights_equal_weights_computed_afresh() {
        let mesh = grid(30, 1.0);
        let n = mesh.vertex_count() as u32;
        let mut rng: rand::rngs::StdRng = rand::SeedableRng::seed_from_u64(11);
        let mut next = move |below: u32| rand::Rng::random_range(&mut rng, 0..below);
        let (mut compared, mut kept) = (0, 0);
        for _ in 0..40 {
            let markers = distinct(&mut next, n, 40);
            let w = NaturalNeighborWeights::build(&mesh, &|_| true, &markers).unwrap();
            let support = w.support(markers.len());
            let verts_of = |present: &[bool]| {
                let mut v: Vec<u32> = (0..markers.len())
                    .filter(|&m| !present[m])
                    .flat_map(|m| support[m].iter().map(|e| e.0))
                    .collect();
                v.sort_unstable();
                v.dedup();
                v
            };
            // A helmet rig's view: a third of the markers hidden, then a few toggled.
            let mut before = vec![true; markers.len()];
            for _ in 0..12 {
                before[next(markers.len() as u32) as usize] = false;
            }
            let before_verts = verts_of(&before);
            let before_w = w.recompute_shared(&before, &before_verts).unwrap();
            for _ in 0..6 {
                let mut now = before.clone();
                for _ in 0..1 + next(3) {
                    let m = next(markers.len() as u32) as usize;
                    now[m] = !now[m];
                }
                if now.iter().all(|p| !p) {
                    continue;
                }
                let added: Vec<u32> = (0..markers.len() as u32)
                    .filter(|&m| !before[m as usize] && now[m as usize])
                    .collect();
                let removed: Vec<u32> = (0..markers.len() as u32)
                    .filter(|&m| before[m as usize] && !now[m as usize])
                    .collect();
                let verts = verts_of(&now);
                let fresh = w.recompute_shared(&now, &verts).unwrap();
                let updated = w
                    .update_shared(
                        &now,
                        &verts,
                        WeightsBefore {
                            vertices: &before_verts,
                            weights: &before_w,
                            added: &added,
                            removed: &removed,
                        },
                    )
                    .unwrap();
                let get =
                    |ws: &[(u32, f64)], m: u32| ws.iter().find(|e| e.0 == m).map_or(0.0, |e| e.1);
                for (k, v) in verts.iter().enumerate() {
                    let (a, b) = (fresh.of(k), updated.of(k));
                    for m in 0..markers.len() as u32 {
                        assert!(
                            (get(a, m) - get(b, m)).abs() < 1e-9,
                            "vertex {v}: {a:?} vs {b:?}"
                        );
                    }
                    compared += 1;
                    if let Ok(i) = before_verts.binary_search(v) {
                        kept += usize::from(before_w.of(i) == b);
                    }
                }
            }
        }
        assert!(compared > 10_000, "{compared}");
        // Most vertices keep their weights (the update is worth its while).
        assert!(kept * 2 > compared, "{kept} of {compared}");
    }

    #[test]
    fn non_face_vertices_copy_their_nearest() {
        let mesh = grid(6, 1.0);
        let markers = [8u32, 12, 36, 40];
        let w = NaturalNeighborWeights::build(&mesh, &|v| v % 7 < 5, &markers).unwrap();
        assert_eq!(w.source[5], 4);
        assert_eq!(w.of(5), w.of(4));
        assert!(
            NaturalNeighborWeights::build(&mesh, &|_| true, &[8, 8]).is_err(),
            "shared UV must be rejected"
        );
    }
}
