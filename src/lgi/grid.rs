//! A uniform grid over one marker's tetrahedra (Cong et al. 2019 §4: "this process can be
//! accelerated by precomputing a uniform grid spatial acceleration structure", after
//! Fujimoto et al. 1986).
//!
//! Each cell lists the tetrahedra whose bounding box overlaps it. The resolution is chosen
//! from the tetrahedron count (about `TARGET_PER_CELL` boxes per cell when they are small)
//! and lowered until the lists fit `max_entries`, since the tetrahedra of a non-manifold
//! tetrahedralization overlap heavily and large ones would otherwise be listed in every
//! cell of a fine grid.

use nalgebra::{Point3, Vector3};

/// Tetrahedra per cell aimed at when choosing the resolution.
const TARGET_PER_CELL: f64 = 16.0;
/// Largest resolution per axis.
const MAX_RES: usize = 24;

/// Uniform grid of tetrahedron lists.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct TetGrid {
    /// Lower corner of the grid box, mm.
    pub min: Point3<f64>,
    /// Cell size per axis, mm.
    pub cell: Vector3<f64>,
    /// Cells per axis.
    pub res: [u32; 3],
    /// Start of each cell's list in `items` (cells + 1).
    pub offsets: Vec<u32>,
    /// Tetrahedron indices.
    pub items: Vec<u32>,
}

impl TetGrid {
    /// Builds the grid over the tetrahedra `tets` of `points`, with at most about
    /// `max_entries` list entries (never less than one cell).
    pub fn build(points: &[Point3<f64>], tets: &[[u16; 4]], max_entries: usize) -> Self {
        let mut min = points.first().copied().unwrap_or_else(Point3::origin);
        let mut max = min;
        for p in points {
            min = min.inf(p);
            max = max.sup(p);
        }
        let pad = ((max - min).max() * 1e-9).max(1e-9);
        min -= Vector3::repeat(pad);
        max += Vector3::repeat(pad);
        let ext = max - min;
        let boxes: Vec<(Point3<f64>, Point3<f64>)> = tets
            .iter()
            .map(|t| {
                let mut lo = points[t[0] as usize];
                let mut hi = lo;
                for &c in &t[1..] {
                    lo = lo.inf(&points[c as usize]);
                    hi = hi.sup(&points[c as usize]);
                }
                (lo, hi)
            })
            .collect();
        let mut r =
            ((tets.len() as f64 / TARGET_PER_CELL).cbrt().ceil() as usize).clamp(1, MAX_RES);
        loop {
            let grid = Self::with_res(min, ext, r, &boxes, max_entries);
            match grid {
                Some(g) => return g,
                None if r > 1 => r = (r * 3 / 4).max(1),
                None => {
                    // One cell always fits: every tetrahedron listed once.
                    return Self::with_res(min, ext, 1, &boxes, usize::MAX)
                        .unwrap_or_else(|| Self::empty(min));
                }
            }
        }
    }

    fn empty(min: Point3<f64>) -> Self {
        Self {
            min,
            cell: Vector3::repeat(1.0),
            res: [1, 1, 1],
            offsets: vec![0, 0],
            items: Vec::new(),
        }
    }

    fn with_res(
        min: Point3<f64>,
        ext: Vector3<f64>,
        r: usize,
        boxes: &[(Point3<f64>, Point3<f64>)],
        max_entries: usize,
    ) -> Option<Self> {
        let res = [r as u32; 3];
        let cell = ext / r as f64;
        let mut g = Self {
            min,
            cell,
            res,
            offsets: Vec::new(),
            items: Vec::new(),
        };
        let ranges: Vec<([u32; 3], [u32; 3])> = boxes
            .iter()
            .map(|(lo, hi)| (g.cell_of(lo), g.cell_of(hi)))
            .collect();
        let total: usize = ranges
            .iter()
            .map(|(a, b)| {
                (0..3)
                    .map(|k| (b[k] - a[k] + 1) as usize)
                    .product::<usize>()
            })
            .sum();
        if total > max_entries {
            return None;
        }
        let cells = r * r * r;
        let mut count = vec![0u32; cells + 1];
        for (a, b) in &ranges {
            for z in a[2]..=b[2] {
                for y in a[1]..=b[1] {
                    for x in a[0]..=b[0] {
                        count[g.index([x, y, z]) + 1] += 1;
                    }
                }
            }
        }
        for c in 0..cells {
            count[c + 1] += count[c];
        }
        let mut fill = count.clone();
        let mut items = vec![0u32; total];
        for (t, (a, b)) in ranges.iter().enumerate() {
            for z in a[2]..=b[2] {
                for y in a[1]..=b[1] {
                    for x in a[0]..=b[0] {
                        let c = g.index([x, y, z]);
                        items[fill[c] as usize] = t as u32;
                        fill[c] += 1;
                    }
                }
            }
        }
        g.offsets = count;
        g.items = items;
        Some(g)
    }

    /// Cell coordinates of `p`, clamped into the grid.
    pub fn cell_of(&self, p: &Point3<f64>) -> [u32; 3] {
        let mut c = [0u32; 3];
        for k in 0..3 {
            let f = ((p[k] - self.min[k]) / self.cell[k]).floor();
            c[k] = f.clamp(0.0, (self.res[k] - 1) as f64) as u32;
        }
        c
    }

    fn index(&self, c: [u32; 3]) -> usize {
        c[0] as usize
            + self.res[0] as usize * (c[1] as usize + self.res[1] as usize * c[2] as usize)
    }

    /// Whether `p` lies in the grid box.
    pub fn contains(&self, p: &Point3<f64>) -> bool {
        (0..3)
            .all(|k| p[k] >= self.min[k] && p[k] <= self.min[k] + self.cell[k] * self.res[k] as f64)
    }

    /// The tetrahedra listed in the cell holding `p` (empty outside the grid box).
    pub fn candidates(&self, p: &Point3<f64>) -> &[u32] {
        if !self.contains(p) {
            return &[];
        }
        let c = self.index(self.cell_of(p));
        &self.items[self.offsets[c] as usize..self.offsets[c + 1] as usize]
    }

    /// Calls `visit` with each cell's list, nearest cells to `p` first by Chebyshev shells,
    /// while `visit` returns a squared distance bound that a further shell could still
    /// beat (`visit` gets the shell's squared lower distance bound and the list).
    pub fn visit_shells(&self, p: &Point3<f64>, mut visit: impl FnMut(f64, &[u32]) -> f64) {
        let c = self.cell_of(p);
        // Distance from p to its clamped cell's box: every cell is at least this far.
        let outside = {
            let mut d2 = 0.0;
            for k in 0..3 {
                let lo = self.min[k] + self.cell[k] * c[k] as f64;
                let hi = lo + self.cell[k];
                let d = if p[k] < lo {
                    lo - p[k]
                } else if p[k] > hi {
                    p[k] - hi
                } else {
                    0.0
                };
                d2 += d * d;
            }
            d2.sqrt()
        };
        let min_cell = self.cell.min();
        let max_r = self.res.iter().copied().max().unwrap_or(1) as i64;
        let mut bound = f64::INFINITY;
        for r in 0..max_r {
            let lower = outside.max(((r - 1).max(0) as f64) * min_cell);
            if lower * lower > bound {
                break;
            }
            for dz in -r..=r {
                for dy in -r..=r {
                    for dx in -r..=r {
                        if dx.abs().max(dy.abs()).max(dz.abs()) != r {
                            continue;
                        }
                        let q = [c[0] as i64 + dx, c[1] as i64 + dy, c[2] as i64 + dz];
                        if (0..3).any(|k| q[k] < 0 || q[k] >= self.res[k] as i64) {
                            continue;
                        }
                        let ci = self.index([q[0] as u32, q[1] as u32, q[2] as u32]);
                        let list =
                            &self.items[self.offsets[ci] as usize..self.offsets[ci + 1] as usize];
                        if !list.is_empty() {
                            bound = visit(lower * lower, list);
                        }
                    }
                }
            }
        }
    }

    /// Number of list entries (memory use is 4 bytes each).
    pub fn entries(&self) -> usize {
        self.items.len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_tet_is_found_from_its_centroid() {
        let mut pts = Vec::new();
        for i in 0..6 {
            for j in 0..6 {
                pts.push(Point3::new(i as f64, j as f64, ((i * j) % 5) as f64));
            }
        }
        let tets: Vec<[u16; 4]> = (0..30)
            .map(|t| [t as u16, t as u16 + 1, t as u16 + 6, (t as u16 + 3) % 36])
            .collect();
        let g = TetGrid::build(&pts, &tets, 1_000_000);
        for (i, t) in tets.iter().enumerate() {
            let c = Point3::from(
                t.iter()
                    .map(|&k| pts[k as usize].coords)
                    .sum::<Vector3<f64>>()
                    / 4.0,
            );
            assert!(g.candidates(&c).contains(&(i as u32)));
        }
        assert!(g.candidates(&Point3::new(100.0, 0.0, 0.0)).is_empty());
        let small = TetGrid::build(&pts, &tets, 40);
        assert!(small.entries() <= 40 || small.res == [1, 1, 1]);
        let mut seen = 0;
        small.visit_shells(&Point3::new(-3.0, 0.0, 0.0), |_, l| {
            seen += l.len();
            f64::INFINITY
        });
        assert!(seen >= tets.len());
    }
}
