//! Mesh connectivity: edges, vertex adjacency, boundaries and connected components.
//!
//! Everything here is over the **polygon edges as given**: a quad contributes its four
//! sides, never the diagonal its triangulated view ([`Mesh::triangles`]) adds. Operators
//! built on the triangulated view (the cotangent Laplacian) see those diagonals too.

use super::Mesh;

/// Marks "no entry" in index arrays.
const NONE: u32 = u32::MAX;

/// Connectivity of a mesh's polygons, computed once by [`Topology::new`].
///
/// Vertex indices are the mesh's; edge indices are positions in [`Topology::edges`].
/// The structure describes the mesh it was built from; it does not follow later edits.
#[derive(Debug, Clone, PartialEq)]
pub struct Topology {
    /// Undirected polygon edges `[a, b]` with `a < b`, sorted ascending, each once (#E).
    pub edges: Vec<[u32; 2]>,
    /// Number of polygons using each edge (#E): 1 on the boundary, 2 inside a manifold
    /// surface, 3 or more at a non-manifold edge.
    pub edge_polygon_count: Vec<u32>,
    /// Indices (into [`Topology::edges`]) of the boundary edges, those used by exactly
    /// one polygon, ascending.
    pub boundary_edges: Vec<u32>,
    /// Closed boundary loops, each an ordered vertex cycle (the last vertex joins the
    /// first). Where the polygons are consistently oriented, a loop runs in the
    /// direction of its polygons' corners (counter-clockwise polygons give loops with the
    /// surface on their left).
    ///
    /// Robustness: at a non-manifold vertex where several boundary loops touch (a
    /// "bowtie" vertex) the loops are split there, so every loop is simple (no vertex
    /// twice) and the vertex appears once in each loop through it. Inconsistently oriented
    /// polygons are tolerated (the walk then follows the edges regardless of direction).
    /// Every boundary edge belongs to exactly one loop or one
    /// [open chain](Topology::open_boundary_chains).
    pub boundary_loops: Vec<Vec<u32>>,
    /// Boundary paths that cannot close: next to non-manifold edges an odd number of
    /// boundary edges can meet at a vertex, and the walk stops there. Each chain is an
    /// ordered vertex path (its ends are not joined). Empty when every edge is used by at
    /// most two polygons.
    pub open_boundary_chains: Vec<Vec<u32>>,
    /// Number of non-manifold edges (used by three or more polygons).
    pub non_manifold_edge_count: usize,
    /// Connected component of each vertex (#V), numbered `0..component_count` in order of
    /// each component's smallest vertex. A vertex used by no polygon is a component of its
    /// own.
    pub component_of: Vec<u32>,
    /// Number of connected components (counting unused vertices, see `component_of`).
    pub component_count: usize,
    /// CSR adjacency: neighbours of `v` are `neighbor_list[neighbor_offsets[v]..[v + 1]]`.
    neighbor_offsets: Vec<u32>,
    neighbor_list: Vec<u32>,
}

/// Edge table of a mesh: sorted unique edges, their polygon counts, and for each edge the
/// vertex it starts from in a polygon that uses it (the only one, for a boundary edge).
struct EdgeTable {
    edges: Vec<[u32; 2]>,
    counts: Vec<u32>,
    from: Vec<u32>,
}

impl EdgeTable {
    fn new(mesh: &Mesh) -> Self {
        // (undirected key, start vertex of the directed polygon side)
        let mut sides: Vec<(u64, u32)> = Vec::with_capacity(mesh.face_vertices.len());
        for face in mesh.faces() {
            for (i, &a) in face.iter().enumerate() {
                let b = face[(i + 1) % face.len()];
                let (lo, hi) = if a < b { (a, b) } else { (b, a) };
                sides.push(((u64::from(lo) << 32) | u64::from(hi), a));
            }
        }
        sides.sort_unstable();
        let mut table = EdgeTable {
            edges: Vec::with_capacity(sides.len() / 2 + 1),
            counts: Vec::with_capacity(sides.len() / 2 + 1),
            from: Vec::with_capacity(sides.len() / 2 + 1),
        };
        let mut last_key = None;
        for (key, from) in sides {
            if last_key == Some(key) {
                if let Some(c) = table.counts.last_mut() {
                    *c += 1;
                }
                continue;
            }
            last_key = Some(key);
            table.edges.push([(key >> 32) as u32, key as u32]);
            table.counts.push(1);
            table.from.push(from);
        }
        table
    }
}

impl Topology {
    /// Builds the connectivity of `mesh`'s polygons. O(C log C) for C polygon corners.
    pub fn new(mesh: &Mesh) -> Self {
        let nv = mesh.vertex_count();
        let EdgeTable {
            edges,
            counts,
            from,
        } = EdgeTable::new(mesh);

        let (neighbor_offsets, neighbor_list) = csr_adjacency(nv, &edges);

        let boundary_edges: Vec<u32> = (0..edges.len() as u32)
            .filter(|&e| counts[e as usize] == 1)
            .collect();
        let (boundary_loops, open_boundary_chains) =
            trace_boundaries(nv, &edges, &from, &boundary_edges);

        let non_manifold_edge_count = counts.iter().filter(|&&c| c > 2).count();

        let mut component_of = vec![NONE; nv];
        let mut component_count = 0usize;
        let mut stack = Vec::new();
        for seed in 0..nv {
            if component_of[seed] != NONE {
                continue;
            }
            let id = component_count as u32;
            component_count += 1;
            component_of[seed] = id;
            stack.push(seed as u32);
            while let Some(v) = stack.pop() {
                let (a, b) = (
                    neighbor_offsets[v as usize] as usize,
                    neighbor_offsets[v as usize + 1] as usize,
                );
                for &w in &neighbor_list[a..b] {
                    if component_of[w as usize] == NONE {
                        component_of[w as usize] = id;
                        stack.push(w);
                    }
                }
            }
        }

        Topology {
            edges,
            edge_polygon_count: counts,
            boundary_edges,
            boundary_loops,
            open_boundary_chains,
            non_manifold_edge_count,
            component_of,
            component_count,
            neighbor_offsets,
            neighbor_list,
        }
    }

    /// Number of vertices of the mesh this was built from.
    pub fn vertex_count(&self) -> usize {
        self.neighbor_offsets.len() - 1
    }

    /// Neighbours of vertex `v` along polygon edges, ascending; empty for a vertex used by
    /// no polygon or for `v` out of range.
    pub fn neighbors(&self, v: u32) -> &[u32] {
        let v = v as usize;
        match (
            self.neighbor_offsets.get(v),
            self.neighbor_offsets.get(v + 1),
        ) {
            (Some(&a), Some(&b)) => &self.neighbor_list[a as usize..b as usize],
            _ => &[],
        }
    }

    /// Number of polygon-edge neighbours of `v` (0 when out of range).
    pub fn degree(&self, v: u32) -> usize {
        self.neighbors(v).len()
    }

    /// Index in [`Topology::edges`] of the edge joining `a` and `b` (either order).
    pub fn edge_index(&self, a: u32, b: u32) -> Option<usize> {
        let key = if a < b { [a, b] } else { [b, a] };
        self.edges.binary_search(&key).ok()
    }

    /// Whether the mesh is closed: no boundary edge.
    pub fn is_closed(&self) -> bool {
        self.boundary_edges.is_empty()
    }

    /// Per-vertex flag: whether the vertex lies on a boundary edge (#V).
    pub fn boundary_vertex_mask(&self) -> Vec<bool> {
        let mut mask = vec![false; self.vertex_count()];
        for &e in &self.boundary_edges {
            for v in self.edges[e as usize] {
                mask[v as usize] = true;
            }
        }
        mask
    }
}

/// Sorted CSR adjacency from sorted unique edges: pushing both ends while walking the
/// edges in order leaves every neighbour list ascending (smaller neighbours come from
/// earlier edges `[a, v]`, larger ones from the edges `[v, b]` that follow).
fn csr_adjacency(nv: usize, edges: &[[u32; 2]]) -> (Vec<u32>, Vec<u32>) {
    let mut offsets = vec![0u32; nv + 1];
    for &[a, b] in edges {
        offsets[a as usize + 1] += 1;
        offsets[b as usize + 1] += 1;
    }
    for v in 0..nv {
        offsets[v + 1] += offsets[v];
    }
    let mut fill: Vec<u32> = offsets[..nv].to_vec();
    let mut list = vec![0u32; 2 * edges.len()];
    for &[a, b] in edges {
        list[fill[a as usize] as usize] = b;
        fill[a as usize] += 1;
        list[fill[b as usize] as usize] = a;
        fill[b as usize] += 1;
    }
    (offsets, list)
}

/// Walks the boundary edges into closed loops and open chains (see
/// [`Topology::boundary_loops`]).
///
/// The walk takes, at each vertex, an unused boundary edge leaving it in polygon
/// orientation if there is one, else any unused one (lowest edge index first). When it
/// reaches a vertex already on the current path, the cycle from there is cut off as a
/// loop, which keeps loops simple at bowtie vertices. Walks start first at vertices where
/// an odd number of boundary edges meet (only possible next to non-manifold edges), so
/// an open chain is found whole, from one of its ends.
fn trace_boundaries(
    nv: usize,
    edges: &[[u32; 2]],
    from: &[u32],
    boundary: &[u32],
) -> (Vec<Vec<u32>>, Vec<Vec<u32>>) {
    // Boundary edges at each vertex, as positions in `boundary` (CSR).
    let mut offsets = vec![0u32; nv + 1];
    for &e in boundary {
        let [a, b] = edges[e as usize];
        offsets[a as usize + 1] += 1;
        offsets[b as usize + 1] += 1;
    }
    for v in 0..nv {
        offsets[v + 1] += offsets[v];
    }
    let mut fill: Vec<u32> = offsets[..nv].to_vec();
    let mut incident = vec![0u32; 2 * boundary.len()];
    for (i, &e) in boundary.iter().enumerate() {
        for v in edges[e as usize] {
            incident[fill[v as usize] as usize] = i as u32;
            fill[v as usize] += 1;
        }
    }
    let incident_at =
        |v: u32| &incident[offsets[v as usize] as usize..offsets[v as usize + 1] as usize];

    let mut used = vec![false; boundary.len()];
    let mut position = vec![NONE; nv];
    let mut loops = Vec::new();
    let mut chains = Vec::new();
    let mut path: Vec<u32> = Vec::new();

    let pick = |v: u32, used: &[bool]| -> Option<u32> {
        let unused = incident_at(v)
            .iter()
            .copied()
            .filter(|&i| !used[i as usize]);
        let mut fallback = None;
        for i in unused {
            if from[boundary[i as usize] as usize] == v {
                return Some(i);
            }
            fallback = fallback.or(Some(i));
        }
        fallback
    };

    let odd_starts = (0..nv as u32).filter(|&v| incident_at(v).len() % 2 == 1);
    let starts = odd_starts
        .map(|v| (v, None))
        .chain((0..boundary.len() as u32).map(|i| (from[boundary[i as usize] as usize], Some(i))));
    for (start, edge) in starts {
        let first = match edge {
            Some(i) if !used[i as usize] => i,
            Some(_) => continue,
            None => match pick(start, &used) {
                Some(i) => i,
                None => continue,
            },
        };
        path.clear();
        path.push(start);
        position[start as usize] = 0;
        let mut next = Some(first);
        while let Some(i) = next {
            used[i as usize] = true;
            let current = path.last().copied().unwrap_or(start);
            let [a, b] = edges[boundary[i as usize] as usize];
            let w = if a == current { b } else { a };
            let k = position[w as usize];
            if k == NONE {
                position[w as usize] = path.len() as u32;
                path.push(w);
            } else {
                // Back at a vertex of the path: cut the cycle off as a loop.
                let k = k as usize;
                loops.push(path[k..].to_vec());
                for &v in &path[k + 1..] {
                    position[v as usize] = NONE;
                }
                path.truncate(k + 1);
            }
            next = path.last().and_then(|&v| pick(v, &used));
        }
        if path.len() > 1 {
            chains.push(path.clone());
        }
        for &v in &path {
            position[v as usize] = NONE;
        }
    }
    (loops, chains)
}

/// Sorted unique undirected polygon edges `[a, b]`, `a < b` (see [`Topology::edges`]).
pub fn edges(mesh: &Mesh) -> Vec<[u32; 2]> {
    EdgeTable::new(mesh).edges
}

/// Neighbours of every vertex along polygon edges, each list ascending (#V lists).
pub fn vertex_adjacency(mesh: &Mesh) -> Vec<Vec<u32>> {
    let (offsets, list) = csr_adjacency(mesh.vertex_count(), &edges(mesh));
    offsets
        .windows(2)
        .map(|w| list[w[0] as usize..w[1] as usize].to_vec())
        .collect()
}

/// Closed boundary loops of the mesh (see [`Topology::boundary_loops`]).
pub fn boundary_loops(mesh: &Mesh) -> Vec<Vec<u32>> {
    Topology::new(mesh).boundary_loops
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::test_meshes::{grid, tetrahedron};
    use nalgebra::Point3;

    /// Checks that `lp` is a closed cycle of boundary edges without repeated vertices.
    fn assert_closed_boundary_loop(t: &Topology, lp: &[u32]) {
        let mut seen = lp.to_vec();
        seen.sort_unstable();
        seen.dedup();
        assert_eq!(seen.len(), lp.len(), "loop repeats a vertex: {lp:?}");
        for i in 0..lp.len() {
            let (a, b) = (lp[i], lp[(i + 1) % lp.len()]);
            let e = t
                .edge_index(a, b)
                .unwrap_or_else(|| panic!("{a}-{b} is no edge"));
            assert_eq!(t.edge_polygon_count[e], 1, "{a}-{b} is not a boundary edge");
        }
    }

    /// A grid with quad `(hole_i, hole_j)` removed.
    fn grid_with_hole(n: usize, hole: (usize, usize)) -> Mesh {
        let g = grid(n, 1.0);
        let polys: Vec<Vec<u32>> = g
            .faces()
            .enumerate()
            .filter(|&(f, _)| f != hole.1 * n + hole.0)
            .map(|(_, p)| p.to_vec())
            .collect();
        Mesh::new(g.positions, &polys, Vec::new(), None).unwrap()
    }

    #[test]
    fn grid_edges_and_adjacency() {
        let g = grid(2, 1.0);
        let t = Topology::new(&g);
        // 2 × 3 horizontal + 3 × 2 vertical sides, no triangle diagonals.
        assert_eq!(t.edges.len(), 12);
        assert_eq!(edges(&g), t.edges);
        assert!(t.edges.windows(2).all(|w| w[0] < w[1]));
        assert!(t.edges.iter().all(|e| e[0] < e[1]));
        assert_eq!(t.neighbors(4), &[1, 3, 5, 7]);
        assert_eq!(t.neighbors(0), &[1, 3]);
        assert_eq!(t.neighbors(99), &[] as &[u32]);
        assert_eq!(t.edge_index(4, 0), None);
        assert_eq!(t.edge_polygon_count[t.edge_index(4, 1).unwrap()], 2);
        let adj = vertex_adjacency(&g);
        for v in 0..9u32 {
            assert_eq!(adj[v as usize], t.neighbors(v));
        }
        assert_eq!(t.boundary_edges.len(), 8);
        assert_eq!(t.component_count, 1);
        assert_eq!(t.non_manifold_edge_count, 0);
    }

    #[test]
    fn grid_boundary_is_one_ccw_loop() {
        let n = 4;
        let g = grid(n, 1.0);
        let t = Topology::new(&g);
        assert_eq!(t.boundary_loops.len(), 1);
        assert!(t.open_boundary_chains.is_empty());
        let lp = &t.boundary_loops[0];
        assert_eq!(lp.len(), 4 * n);
        assert_closed_boundary_loop(&t, lp);
        // The grid's quads are counter-clockwise seen from +z, and so is the loop.
        let area2: f64 = (0..lp.len())
            .map(|i| {
                let p = g.positions[lp[i] as usize];
                let q = g.positions[lp[(i + 1) % lp.len()] as usize];
                p.x * q.y - q.x * p.y
            })
            .sum();
        assert!((area2 - 2.0 * 16.0).abs() < 1e-12, "{area2}");
        assert_eq!(boundary_loops(&g), t.boundary_loops);
    }

    #[test]
    fn closed_tetrahedron_has_no_boundary() {
        let t = Topology::new(&tetrahedron());
        assert_eq!(t.edges.len(), 6);
        assert!(t.is_closed());
        assert!(t.boundary_loops.is_empty() && t.open_boundary_chains.is_empty());
        assert!(t.edge_polygon_count.iter().all(|&c| c == 2));
        assert_eq!(t.component_count, 1);
    }

    #[test]
    fn hole_gives_two_loops() {
        let m = grid_with_hole(3, (1, 1));
        let t = Topology::new(&m);
        let mut lens: Vec<usize> = t.boundary_loops.iter().map(Vec::len).collect();
        lens.sort_unstable();
        assert_eq!(lens, vec![4, 12]);
        for lp in &t.boundary_loops {
            assert_closed_boundary_loop(&t, lp);
        }
        let hole = t.boundary_loops.iter().find(|l| l.len() == 4).unwrap();
        let mut hole = hole.clone();
        hole.sort_unstable();
        assert_eq!(hole, vec![5, 6, 9, 10]);
    }

    #[test]
    fn bowtie_vertex_splits_loops() {
        // Two triangles sharing only vertex 0.
        let p = vec![
            Point3::new(0.0, 0.0, 0.0),
            Point3::new(1.0, 0.0, 0.0),
            Point3::new(1.0, 1.0, 0.0),
            Point3::new(-1.0, 0.0, 0.0),
            Point3::new(-1.0, -1.0, 0.0),
        ];
        let m = Mesh::new(p, &[vec![0, 1, 2], vec![0, 3, 4]], Vec::new(), None).unwrap();
        let t = Topology::new(&m);
        assert_eq!(t.boundary_loops.len(), 2);
        for lp in &t.boundary_loops {
            assert_eq!(lp.len(), 3);
            assert!(lp.contains(&0));
            assert_closed_boundary_loop(&t, lp);
        }

        // Two diagonal quads of a 2 × 2 grid, touching only at the centre vertex 4.
        let g = grid(2, 1.0);
        let polys: Vec<Vec<u32>> = vec![g.face(1).to_vec(), g.face(2).to_vec()];
        let m = Mesh::new(g.positions.clone(), &polys, Vec::new(), None).unwrap();
        let t = Topology::new(&m);
        assert_eq!(t.boundary_loops.len(), 2);
        for lp in &t.boundary_loops {
            assert_eq!(lp.len(), 4);
            assert!(lp.contains(&4), "centre vertex in each loop: {lp:?}");
            assert_closed_boundary_loop(&t, lp);
        }
    }

    #[test]
    fn flipped_face_still_closes_the_loop() {
        let g = grid(2, 1.0);
        let mut polys: Vec<Vec<u32>> = g.faces().map(<[u32]>::to_vec).collect();
        polys[3].reverse();
        let m = Mesh::new(g.positions.clone(), &polys, Vec::new(), None).unwrap();
        let t = Topology::new(&m);
        assert_eq!(t.boundary_loops.len(), 1);
        assert_eq!(t.boundary_loops[0].len(), 8);
        assert_closed_boundary_loop(&t, &t.boundary_loops[0]);
    }

    #[test]
    fn non_manifold_edge_gives_open_chain() {
        // Three triangles on edge 0-1.
        let p = vec![
            Point3::new(0.0, 0.0, 0.0),
            Point3::new(1.0, 0.0, 0.0),
            Point3::new(0.5, 1.0, 0.0),
            Point3::new(0.5, -1.0, 0.0),
            Point3::new(0.5, 0.0, 1.0),
        ];
        let faces = vec![vec![0, 1, 2], vec![1, 0, 3], vec![0, 1, 4]];
        let m = Mesh::new(p, &faces, Vec::new(), None).unwrap();
        let t = Topology::new(&m);
        assert_eq!(t.non_manifold_edge_count, 1);
        assert_eq!(t.boundary_edges.len(), 6);
        assert_eq!(t.boundary_loops.len(), 1);
        assert_closed_boundary_loop(&t, &t.boundary_loops[0]);
        assert_eq!(t.open_boundary_chains.len(), 1);
        let chain = &t.open_boundary_chains[0];
        assert_eq!(chain.len(), 3);
        // Every boundary edge is used exactly once by the loop and the chain.
        let mut covered: Vec<usize> = chain
            .windows(2)
            .map(|w| t.edge_index(w[0], w[1]).unwrap())
            .collect();
        let lp = &t.boundary_loops[0];
        covered.extend((0..lp.len()).map(|i| t.edge_index(lp[i], lp[(i + 1) % lp.len()]).unwrap()));
        covered.sort_unstable();
        let expected: Vec<usize> = t.boundary_edges.iter().map(|&e| e as usize).collect();
        assert_eq!(covered, expected);
    }

    #[test]
    fn disjoint_triangles_are_two_components() {
        let p = vec![
            Point3::new(0.0, 0.0, 0.0),
            Point3::new(1.0, 0.0, 0.0),
            Point3::new(0.0, 1.0, 0.0),
            Point3::new(5.0, 0.0, 0.0),
            Point3::new(6.0, 0.0, 0.0),
            Point3::new(5.0, 1.0, 0.0),
            Point3::new(9.0, 9.0, 9.0),
        ];
        let m = Mesh::new(p, &[vec![3, 4, 5], vec![0, 1, 2]], Vec::new(), None).unwrap();
        let t = Topology::new(&m);
        // Vertex 6 is used by no polygon: a component of its own.
        assert_eq!(t.component_count, 3);
        assert_eq!(t.component_of, vec![0, 0, 0, 1, 1, 1, 2]);
        assert_eq!(t.boundary_loops.len(), 2);
        assert_eq!(t.degree(6), 0);
    }

    #[test]
    fn ict_neutral_boundaries_cover_every_boundary_edge() {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../shared/data/ict-facekit/generic_neutral_mesh.obj");
        if !path.exists() {
            eprintln!(
                "skipping: ICT-FaceKit neutral not found at {}",
                path.display()
            );
            return;
        }
        let m = crate::mesh::read_obj(&path).unwrap();
        let t = Topology::new(&m);
        let mut covered = Vec::new();
        for lp in &t.boundary_loops {
            assert_closed_boundary_loop(&t, lp);
            covered.extend((0..lp.len()).map(|i| t.edge_index(lp[i], lp[(i + 1) % lp.len()])));
        }
        for chain in &t.open_boundary_chains {
            covered.extend(chain.windows(2).map(|w| t.edge_index(w[0], w[1])));
        }
        let mut covered: Vec<u32> = covered.into_iter().map(|e| e.unwrap() as u32).collect();
        covered.sort_unstable();
        assert_eq!(covered, t.boundary_edges);
        // Every edge is manifold, so every boundary walk closes.
        if t.non_manifold_edge_count == 0 {
            assert!(t.open_boundary_chains.is_empty());
        }
        eprintln!(
            "ICT neutral: {} edges, {} boundary edges in {} loops + {} open chains, \
             {} non-manifold edges, {} components",
            t.edges.len(),
            t.boundary_edges.len(),
            t.boundary_loops.len(),
            t.open_boundary_chains.len(),
            t.non_manifold_edge_count,
            t.component_count
        );
    }
}
