//! The four voluntary regions with soft geodesic weights (Bermano et al. 2014 §4.3, §5.3),
//! and the seed-and-grow patches of the compressed shape space (§4.2).

use nalgebra::Point3;
use rand::RngCore;

use super::EnhanceError;
use crate::dataset::Dataset;
use crate::dataset::actor::{Actor, Region};
use crate::dataset::markers::vertex_motion;
use crate::mesh::{Mesh, Topology, edge_graph_distances};
use crate::numeric::SplitMix64;

/// Names of the four voluntary regions, in the order used everywhere in this module.
pub const REGION_NAMES: [&str; 4] = ["mouth_l", "mouth_r", "brow_l", "brow_r"];

/// Core vertices of the four voluntary regions (left/right mouth, left/right brow; `_l` is
/// the actor's left, +x), from which [`RegionWeights`] decay with geodesic distance.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct VoluntaryRegions {
    /// Core vertex indices of each region, in [`REGION_NAMES`] order.
    pub cores: [Vec<u32>; 4],
}

impl VoluntaryRegions {
    /// The built-in actor's regions from its anatomical labels: mouth = upper and lower lip
    /// split at the face's midplane x = mean x of the face vertices, brow = each brow plus
    /// its half of the forehead.
    pub fn from_actor(actor: &Actor) -> Self {
        let labels = actor.regions();
        let pos = &actor.neutral().positions;
        let face = actor.face_vertex_count().min(pos.len());
        let mid = pos[..face].iter().map(|p| p.x).sum::<f64>() / face.max(1) as f64;
        let mut cores: [Vec<u32>; 4] = Default::default();
        for (v, (&r, p)) in labels.iter().zip(pos).enumerate() {
            let left = p.x >= mid;
            let slot = match r {
                Region::UpperLip | Region::LowerLip => Some(if left { 0 } else { 1 }),
                Region::BrowL => Some(2),
                Region::BrowR => Some(3),
                Region::Forehead => Some(if left { 2 } else { 3 }),
                _ => None,
            };
            if let Some(s) = slot {
                cores[s].push(v as u32);
            }
        }
        Self { cores }
    }

    /// Regions derived from any dataset without labels, from how its vertices move: among
    /// the face vertices, those in the lower half of the face's height (y up) whose motion
    /// over the shapes is in the top `1 − quantile` of the lower half form the mouth, the
    /// same in the upper half form the brows; each is split at the face's midplane (mean x).
    ///
    /// Assumes the head frame of DESIGN.md (x to the actor's left, y up). With no shapes,
    /// the cores are the lower and upper quarter of the face by height.
    pub fn from_motion(dataset: &Dataset, quantile: f64) -> Self {
        let motion = vertex_motion(dataset);
        let pos = &dataset.neutral.positions;
        let face: Vec<usize> = dataset.face_vertex_indices().collect();
        if face.is_empty() {
            return Self::default();
        }
        let (mut ymin, mut ymax) = (f64::INFINITY, f64::NEG_INFINITY);
        let mut mid = 0.0;
        for &v in &face {
            ymin = ymin.min(pos[v].y);
            ymax = ymax.max(pos[v].y);
            mid += pos[v].x;
        }
        mid /= face.len() as f64;
        let ymid = 0.5 * (ymin + ymax);
        let mut cores: [Vec<u32>; 4] = Default::default();
        for upper in [false, true] {
            let half: Vec<usize> = face
                .iter()
                .copied()
                .filter(|&v| (pos[v].y >= ymid) == upper)
                .collect();
            let mut m: Vec<f64> = half.iter().map(|&v| motion[v]).collect();
            m.sort_by(f64::total_cmp);
            let threshold = if m.iter().all(|&x| x == 0.0) {
                None
            } else {
                m.get(((m.len() as f64 * quantile) as usize).min(m.len().saturating_sub(1)))
                    .copied()
            };
            for &v in &half {
                let keep = match threshold {
                    Some(t) => motion[v] >= t && motion[v] > 0.0,
                    None => {
                        let h = (pos[v].y - ymin) / (ymax - ymin).max(f64::MIN_POSITIVE);
                        if upper { h > 0.75 } else { h < 0.25 }
                    }
                };
                if keep {
                    let side = usize::from(pos[v].x < mid);
                    cores[usize::from(upper) * 2 + side].push(v as u32);
                }
            }
        }
        Self { cores }
    }
}

/// Soft per-triangle region weights ω_r (Bermano et al. 2014 §5.3): 1 on triangles whose
/// vertices are all in the region's core, decaying as `exp(−d²/(2σ²))` with the geodesic
/// (edge-graph) distance d of the triangle (mean of its vertices') from the core; and the
/// normalized blend weights ω_r,t / Σ_ρ ω_ρ,t of Eq. (4), computed from the distances in
/// log space so that triangles far from every region still get a well-defined blend
/// (the nearest region's).
#[derive(Debug, Clone, PartialEq)]
pub struct RegionWeights {
    /// ω_r per triangle (#T) for each region.
    pub omega: [Vec<f64>; 4],
    /// Normalized blend weights per triangle (#T), summing to 1.
    pub blend: Vec<[f64; 4]>,
}

impl RegionWeights {
    /// Weights on `mesh` at `rest` (#V, mm) for `regions`, with Gaussian width `sigma_mm`.
    ///
    /// # Errors
    /// [`EnhanceError::Regions`] when a region has no core vertex in range.
    pub fn new(
        mesh: &Mesh,
        rest: &[Point3<f64>],
        regions: &VoluntaryRegions,
        sigma_mm: f64,
    ) -> Result<Self, EnhanceError> {
        let n = mesh.vertex_count();
        let rest_mesh = mesh
            .with_positions(rest.to_vec())
            .map_err(EnhanceError::Mesh)?;
        let topology = Topology::new(&rest_mesh);
        let mut dist: [Vec<f64>; 4] = Default::default();
        for (r, core) in regions.cores.iter().enumerate() {
            let core: Vec<u32> = core.iter().copied().filter(|&v| (v as usize) < n).collect();
            if core.is_empty() {
                return Err(EnhanceError::Regions(format!(
                    "region {} has no core vertex",
                    REGION_NAMES[r]
                )));
            }
            let d = edge_graph_distances(&rest_mesh, &topology, &core, f64::INFINITY);
            dist[r] = mesh
                .triangles
                .iter()
                .map(|t| t.iter().map(|&v| d[v as usize]).sum::<f64>() / 3.0)
                .collect();
        }
        let two_s2 = 2.0 * sigma_mm * sigma_mm;
        let t_count = mesh.triangles.len();
        let mut omega: [Vec<f64>; 4] = Default::default();
        for r in 0..4 {
            omega[r] = dist[r]
                .iter()
                .map(|&d| {
                    if d.is_finite() {
                        (-d * d / two_s2).exp()
                    } else {
                        0.0
                    }
                })
                .collect();
        }
        let blend = (0..t_count)
            .map(|t| {
                let d: [f64; 4] = std::array::from_fn(|r| dist[r][t]);
                let dmin = d.iter().copied().fold(f64::INFINITY, f64::min);
                if !dmin.is_finite() {
                    return [0.25; 4];
                }
                let e: [f64; 4] = std::array::from_fn(|r| {
                    if d[r].is_finite() {
                        (-(d[r] * d[r] - dmin * dmin) / two_s2).exp()
                    } else {
                        0.0
                    }
                });
                let s: f64 = e.iter().sum();
                e.map(|x| x / s)
            })
            .collect();
        Ok(Self { omega, blend })
    }
}

/// Random seed-and-grow patches of about `patch_vertices` vertices (Bermano et al. 2014
/// §4.2, Fig. 3): `⌈#V / patch_vertices⌉` seeds drawn at random (seeded [`SplitMix64`]), grown
/// together breadth-first over the edge graph, one ring per round, each vertex joining the
/// first patch to reach it. Returns the patch of every triangle (that of its first vertex)
/// and the number of patches. Vertices unreachable from any seed (other connected pieces)
/// get patches of their own by further seeding.
pub fn seed_and_grow_patches(mesh: &Mesh, patch_vertices: usize, seed: u64) -> (Vec<u32>, usize) {
    let n = mesh.vertex_count();
    let topology = Topology::new(mesh);
    let mut label = vec![u32::MAX; n];
    let mut rng = SplitMix64::new(seed);
    let mut next = || rng.next_u64();
    let want = n.div_ceil(patch_vertices.max(1)).max(1);
    let mut frontier: Vec<u32> = Vec::new();
    let mut count = 0u32;
    while frontier.len() < want && n > 0 {
        let v = (next() % n as u64) as usize;
        if label[v] == u32::MAX {
            label[v] = count;
            count += 1;
            frontier.push(v as u32);
        }
        if count as usize >= n {
            break;
        }
    }
    loop {
        while !frontier.is_empty() {
            let mut grown = Vec::new();
            for &v in &frontier {
                for &u in topology.neighbors(v) {
                    if label[u as usize] == u32::MAX {
                        label[u as usize] = label[v as usize];
                        grown.push(u);
                    }
                }
            }
            frontier = grown;
        }
        match label.iter().position(|&l| l == u32::MAX) {
            Some(v) => {
                label[v] = count;
                count += 1;
                frontier.push(v as u32);
            }
            None => break,
        }
    }
    let tri = mesh
        .triangles
        .iter()
        .map(|t| label[t[0] as usize])
        .collect();
    (tri, count as usize)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn patches_cover_the_mesh_with_about_the_requested_size() {
        let mesh = crate::mesh::test_meshes::grid(40, 1.0);
        let (tri, count) = seed_and_grow_patches(&mesh, 100, 7);
        assert_eq!(tri.len(), mesh.triangles.len());
        assert_eq!(count, mesh.vertex_count().div_ceil(100));
        assert!(tri.iter().all(|&p| (p as usize) < count));
    }

    #[test]
    fn weights_decay_with_distance_and_blend_sums_to_one() {
        let mesh = crate::mesh::test_meshes::grid(30, 1.0);
        let corner = |i: u32, j: u32| j * 31 + i;
        let regions = VoluntaryRegions {
            cores: [
                vec![corner(0, 0)],
                vec![corner(30, 0)],
                vec![corner(0, 30)],
                vec![corner(30, 30)],
            ],
        };
        let w = RegionWeights::new(&mesh, &mesh.positions, &regions, 5.0).unwrap();
        for b in &w.blend {
            assert!((b.iter().sum::<f64>() - 1.0).abs() < 1e-12);
        }
        assert!(w.omega[0].iter().all(|&x| (0.0..=1.0).contains(&x)));
        let mut bad = regions.clone();
        bad.cores[2].clear();
        assert!(RegionWeights::new(&mesh, &mesh.positions, &bad, 5.0).is_err());
    }
}
