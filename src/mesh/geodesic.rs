//! Approximate geodesic distances: shortest paths along the polygon edges.
//!
//! Edge-graph distances overestimate true surface geodesics (a path must follow edges;
//! on a regular grid it is the Manhattan distance, up to √2 times the straight line), but
//! they are exact for the graph, cheap, and monotone in the true distance, which is what
//! farthest point sampling and neighbourhood cut-offs need.

use std::cmp::Ordering;
use std::collections::BinaryHeap;

use nalgebra::Point3;

use super::Mesh;
use super::topology::Topology;

/// A heap entry ordered so that [`BinaryHeap`] pops the smallest distance first.
#[derive(Clone, Copy, PartialEq)]
struct Entry {
    distance: f64,
    vertex: u32,
}

impl Eq for Entry {}

impl Ord for Entry {
    fn cmp(&self, other: &Self) -> Ordering {
        other
            .distance
            .total_cmp(&self.distance)
            .then_with(|| other.vertex.cmp(&self.vertex))
    }
}

impl PartialOrd for Entry {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}

/// Multi-source shortest-path distances along polygon edges (Dijkstra 1959), with the
/// Euclidean length of each edge as its weight, in mesh units.
///
/// d(v) = min over sources s and edge paths s = v₀, v₁, …, vₖ = v of Σᵢ ‖p(vᵢ₊₁) − p(vᵢ)‖.
///
/// Returns #V distances: 0 at the sources, `f64::INFINITY` for vertices farther than
/// `max_distance` (pass `f64::INFINITY` for no limit) or unreachable from every source.
/// The search stops expanding at `max_distance`, so a small limit keeps it local.
///
/// `topology` must be [`Topology::new`] of `mesh`; if its vertex count differs, every
/// distance is infinite. Sources out of range are ignored.
pub fn edge_graph_distances(
    mesh: &Mesh,
    topology: &Topology,
    sources: &[u32],
    max_distance: f64,
) -> Vec<f64> {
    let n = mesh.vertex_count();
    let mut distances = vec![f64::INFINITY; n];
    if topology.vertex_count() != n {
        return distances;
    }
    let mut heap = BinaryHeap::new();
    for &s in sources {
        if let Some(d) = distances.get_mut(s as usize)
            && max_distance >= 0.0
        {
            *d = 0.0;
            heap.push(Entry {
                distance: 0.0,
                vertex: s,
            });
        }
    }
    relax(
        &mesh.positions,
        topology,
        heap,
        &mut distances,
        max_distance,
    );
    distances
}

/// Lowers `distances` (#V) to account for one more `source`: afterwards `distances[v]` is
/// min(previous `distances[v]`, edge-graph distance from `source` to v).
///
/// The incremental step of farthest point sampling: start from all `f64::INFINITY`, add
/// the sources one at a time, pick the vertex of largest distance as the next source. The
/// search prunes wherever it cannot improve on the stored distance, so each step only
/// touches the region that is now closer to the new source (the Voronoi cell of the
/// source).
///
/// Exactness needs `distances` to be a shortest-path field already, i.e. all infinite
/// or the output of these functions without a finite `max_distance`; otherwise the
/// result is an upper bound. Nothing changes when `source` is out of range, when
/// `distances.len()` differs from the vertex count, or when `topology` does not match
/// the mesh.
pub fn update_edge_graph_distances(
    mesh: &Mesh,
    topology: &Topology,
    source: u32,
    distances: &mut [f64],
) {
    let n = mesh.vertex_count();
    if distances.len() != n || topology.vertex_count() != n || source as usize >= n {
        return;
    }
    distances[source as usize] = 0.0;
    let heap = BinaryHeap::from(vec![Entry {
        distance: 0.0,
        vertex: source,
    }]);
    relax(&mesh.positions, topology, heap, distances, f64::INFINITY);
}

/// Dijkstra's loop: settles vertices in order of distance and lowers their neighbours'
/// distances when a shorter path within `max_distance` is found.
fn relax(
    positions: &[Point3<f64>],
    topology: &Topology,
    mut heap: BinaryHeap<Entry>,
    distances: &mut [f64],
    max_distance: f64,
) {
    while let Some(Entry { distance, vertex }) = heap.pop() {
        if distance > distances[vertex as usize] {
            continue; // stale entry: the vertex was reached more cheaply since
        }
        let p = positions[vertex as usize];
        for &w in topology.neighbors(vertex) {
            let candidate = distance + (positions[w as usize] - p).norm();
            if candidate < distances[w as usize] && candidate <= max_distance {
                distances[w as usize] = candidate;
                heap.push(Entry {
                    distance: candidate,
                    vertex: w,
                });
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::test_meshes::grid;

    fn manhattan(n: usize, spacing: f64, a: u32, b: u32) -> f64 {
        let (ai, aj) = (a as usize % (n + 1), a as usize / (n + 1));
        let (bi, bj) = (b as usize % (n + 1), b as usize / (n + 1));
        (ai.abs_diff(bi) + aj.abs_diff(bj)) as f64 * spacing
    }

    #[test]
    fn grid_distances_are_manhattan() {
        let (n, h) = (6, 0.5);
        let g = grid(n, h);
        let t = Topology::new(&g);
        let sources = [0u32, 30];
        let d = edge_graph_distances(&g, &t, &sources, f64::INFINITY);
        for v in 0..g.vertex_count() as u32 {
            let expected = sources
                .iter()
                .map(|&s| manhattan(n, h, s, v))
                .fold(f64::INFINITY, f64::min);
            assert!(
                (d[v as usize] - expected).abs() < 1e-12,
                "vertex {v}: {}",
                d[v as usize]
            );
        }
        assert_eq!(d[0], 0.0);
        assert_eq!(d[30], 0.0);
    }

    #[test]
    fn max_distance_cuts_off() {
        let (n, h) = (5, 1.0);
        let g = grid(n, h);
        let t = Topology::new(&g);
        let d = edge_graph_distances(&g, &t, &[0], 3.0);
        for v in 0..g.vertex_count() as u32 {
            let m = manhattan(n, h, 0, v);
            if m <= 3.0 {
                assert_eq!(d[v as usize], m);
            } else {
                assert_eq!(d[v as usize], f64::INFINITY);
            }
        }
    }

    #[test]
    fn unreachable_and_bad_sources() {
        let g = grid(2, 1.0);
        let t = Topology::new(&g);
        let d = edge_graph_distances(&g, &t, &[99], f64::INFINITY);
        assert!(d.iter().all(|x| x.is_infinite()));
        let other = Topology::new(&grid(3, 1.0));
        let d = edge_graph_distances(&g, &other, &[0], f64::INFINITY);
        assert!(d.iter().all(|x| x.is_infinite()));
    }

    #[test]
    fn incremental_update_matches_multi_source() {
        // A bumpy grid so that edge lengths differ.
        let mut g = grid(8, 1.0);
        for (k, p) in g.positions.iter_mut().enumerate() {
            p.z = ((k * 7919) % 13) as f64 * 0.1;
        }
        let t = Topology::new(&g);
        let mut d = vec![f64::INFINITY; g.vertex_count()];
        let sources = [40u32, 0, 80, 8];
        for (i, &s) in sources.iter().enumerate() {
            update_edge_graph_distances(&g, &t, s, &mut d);
            let fresh = edge_graph_distances(&g, &t, &sources[..=i], f64::INFINITY);
            for (a, b) in d.iter().zip(&fresh) {
                assert!((a - b).abs() <= 1e-12 * b.max(1.0), "{a} vs {b}");
            }
        }
        // Farthest point sampling on the flat grid picks a corner after the centre.
        let flat = grid(8, 1.0);
        let mut d = vec![f64::INFINITY; flat.vertex_count()];
        update_edge_graph_distances(&flat, &t, 40, &mut d);
        let far = (0..d.len()).max_by(|&a, &b| d[a].total_cmp(&d[b])).unwrap();
        assert!([0, 8, 72, 80].contains(&far), "{far}");
        assert_eq!(d[far], 8.0);
        // A mismatched buffer is left alone.
        let mut short = vec![f64::INFINITY; 3];
        update_edge_graph_distances(&flat, &t, 0, &mut short);
        assert!(short.iter().all(|x| x.is_infinite()));
    }
}
