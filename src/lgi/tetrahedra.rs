//! The non-manifold tetrahedralization of a marker's point cloud (Cong et al. 2019 §4.1):
//! every combination of four points, minus the degenerate and badly shaped ones, capped in
//! number.
//!
//! Tetrahedra overlap on purpose: "different expressions can map to the same bundle
//! position with different local curvature", and the choice among them is made per frame
//! (§5.1). A space-filling Delaunay tetrahedralization would force one answer per position.
//!
//! # Pruning (every limit is a field of [`super::LgiParams`])
//! - degenerate or too thin: shape quality `q = 6√2·V / l_rms³` (1 for the regular
//!   tetrahedron, 0 when flat) under `min_tet_quality`;
//! - too large: an edge longer than `max_tet_edge_mm` (such a tetrahedron mixes expressions
//!   far apart in the marker's range of motion);
//! - too many: past `max_tets_per_marker`, the best-shaped are kept (and every point keeps
//!   its best few, so each dataset shape stays reproducible). On ICT with a cap of
//!   3000 per marker, keeping the best-shaped gave 0.13 mm mean error, the largest 0.13,
//!   a random choice 0.13, those holding the neutral 0.17 and the smallest 0.33: small
//!   tetrahedra only interpolate between similar shapes, and held-out combinations of
//!   expressions lie between dissimilar ones.
//!
//! When no tetrahedron survives (a marker moved along a plane or a line only, or by fewer
//! than three shapes), the marker falls back to triangles, then segments, then its single
//! point: the bundle is then always projected (§4, outside every tetrahedron).

use nalgebra::Point3;

/// The simplices of one marker: corners index the marker's point cloud.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Simplices {
    /// Dimension: 3 (tetrahedra), 2, 1 or 0. Corners past `dim` repeat corner 0.
    pub dim: u8,
    /// Corner point indices.
    pub corners: Vec<[u16; 4]>,
}

/// Counts of what the pruning did, summed over markers.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct TetStats {
    /// Four-point combinations considered.
    pub combinations: u64,
    /// Dropped for an edge over `max_tet_edge_mm`.
    pub too_large: u64,
    /// Dropped as degenerate or under `min_tet_quality`.
    pub too_thin: u64,
    /// Dropped by the per-marker cap.
    pub capped: u64,
    /// Kept.
    pub kept: u64,
}

impl TetStats {
    /// Adds another marker's counts.
    pub fn add(&mut self, o: &TetStats) {
        self.combinations += o.combinations;
        self.too_large += o.too_large;
        self.too_thin += o.too_thin;
        self.capped += o.capped;
        self.kept += o.kept;
    }
}

/// A tetrahedron with its sort key (negated quality: lower is better).
type Keyed = (f32, [u16; 4]);

/// Tetrahedra each point keeps past the cap.
const PER_POINT: usize = 8;

/// Shape quality `6√2·V / l_rms³` of a tetrahedron and its `l_rms`.
pub fn tet_quality(p: &[Point3<f64>; 4]) -> (f64, f64) {
    let e1 = p[1] - p[0];
    let e2 = p[2] - p[0];
    let e3 = p[3] - p[0];
    let vol = e1.dot(&e2.cross(&e3)).abs() / 6.0;
    let l2 = e1.norm_squared()
        + e2.norm_squared()
        + e3.norm_squared()
        + (p[2] - p[1]).norm_squared()
        + (p[3] - p[1]).norm_squared()
        + (p[3] - p[2]).norm_squared();
    let lrms = (l2 / 6.0).sqrt();
    if lrms <= 0.0 {
        return (0.0, 0.0);
    }
    (
        6.0 * std::f64::consts::SQRT_2 * vol / (lrms * lrms * lrms),
        lrms,
    )
}

/// Triangle quality `4√3·A / Σ l²` (1 equilateral, 0 flat) and its `l_rms`.
fn tri_quality(a: &Point3<f64>, b: &Point3<f64>, c: &Point3<f64>) -> (f64, f64) {
    let area = (b - a).cross(&(c - a)).norm() / 2.0;
    let l2 = (b - a).norm_squared() + (c - a).norm_squared() + (c - b).norm_squared();
    if l2 <= 0.0 {
        return (0.0, 0.0);
    }
    (4.0 * 3f64.sqrt() * area / l2, (l2 / 3.0).sqrt())
}

/// The best-shaped `max_count` of `kept` (keys: negated quality), plus for every one of the
/// `n` points its best [`PER_POINT`] tetrahedra, so a bundle at a dataset shape's own point
/// can always be reproduced.
fn cap(mut kept: Vec<Keyed>, n: usize, max_count: usize) -> Vec<Keyed> {
    cap_with_bar(&mut kept, n, max_count).0
}

/// [`cap`], also returning the key of the last of the best-shaped (the bar a later
/// tetrahedron must beat) and which points have their full reserve.
fn cap_with_bar(kept: &mut Vec<Keyed>, n: usize, max_count: usize) -> (Vec<Keyed>, f32, Vec<bool>) {
    if kept.len() <= max_count {
        return (std::mem::take(kept), f32::INFINITY, vec![false; n]);
    }
    kept.sort_unstable_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    let bar = kept[max_count - 1].0;
    let mut cover = vec![0usize; n];
    let mut out = Vec::with_capacity(max_count + n * PER_POINT);
    for (k, t) in std::mem::take(kept).into_iter().enumerate() {
        let needed = t.1.iter().any(|&c| cover[c as usize] < PER_POINT);
        if k < max_count || needed {
            for &c in &t.1 {
                cover[c as usize] += 1;
            }
            out.push(t);
        }
    }
    let full = cover.iter().map(|&c| c >= PER_POINT).collect();
    (out, bar, full)
}

/// Tetrahedralizes `points` (at most 65 536) with the pruning of the module docs.
pub fn tetrahedralize(
    points: &[Point3<f64>],
    min_quality: f64,
    max_edge_mm: f64,
    max_count: usize,
) -> (Simplices, TetStats) {
    let n = points.len().min(u16::MAX as usize + 1);
    let mut stats = TetStats::default();
    let max_e2 = max_edge_mm * max_edge_mm;
    // Squared edge lengths, and per triangle its normal (times twice its area), so each
    // fourth point costs one dot product: V = |n · (p_l − p_i)| / 6.
    let d2: Vec<f64> = (0..n * n)
        .map(|ij| (points[ij / n] - points[ij % n]).norm_squared())
        .collect();
    let near = |a: usize, b: usize| d2[a * n + b] <= max_e2;
    let mut kept: Vec<(f32, [u16; 4])> = Vec::new();
    // Past the cap, the buffer is trimmed as it fills (memory stays bounded for large
    // clouds): the global quality bar only rises, so an early trim drops none of the final
    // best-shaped; the per-point reserve is drawn again at each trim.
    let mut trimmed = 0u64;
    let mut bar = f32::INFINITY;
    let mut full = vec![false; n];
    for i in 0..n {
        for j in i + 1..n {
            for k in j + 1..n {
                let tri_near = near(i, j) && near(i, k) && near(j, k);
                let nrm = (points[j] - points[i]).cross(&(points[k] - points[i]));
                let s3 = d2[i * n + j] + d2[i * n + k] + d2[j * n + k];
                for l in k + 1..n {
                    stats.combinations += 1;
                    if !(tri_near && near(i, l) && near(j, l) && near(k, l)) {
                        stats.too_large += 1;
                        continue;
                    }
                    let v6 = nrm.dot(&(points[l] - points[i])).abs();
                    let l2 = (s3 + d2[i * n + l] + d2[j * n + l] + d2[k * n + l]) / 6.0;
                    // 6√2·V / l_rms³ with V = v6 / 6.
                    let q = if l2 > 0.0 {
                        std::f64::consts::SQRT_2 * v6 / (l2 * l2.sqrt())
                    } else {
                        0.0
                    };
                    if !(q >= min_quality && q > 0.0) {
                        stats.too_thin += 1;
                        continue;
                    }
                    let key = -q as f32;
                    if key > bar && full[i] && full[j] && full[k] && full[l] {
                        // Worse than the best-shaped kept so far, and its points have
                        // their reserve (approximately: a later reserve may be worse).
                        trimmed += 1;
                        continue;
                    }
                    kept.push((key, [i as u16, j as u16, k as u16, l as u16]));
                    if kept.len() >= 4 * max_count + n * PER_POINT + 1024 {
                        let before = kept.len();
                        let (out, b, f) = cap_with_bar(&mut kept, n, max_count);
                        kept = out;
                        bar = b;
                        full = f;
                        trimmed += (before - kept.len()) as u64;
                    }
                }
            }
        }
    }
    if !kept.is_empty() {
        let before = kept.len();
        kept = cap(kept, n, max_count);
        stats.capped = trimmed + (before - kept.len()) as u64;
        kept.sort_by_key(|a| a.1);
        stats.kept = kept.len() as u64;
        return (
            Simplices {
                dim: 3,
                corners: kept.into_iter().map(|t| t.1).collect(),
            },
            stats,
        );
    }
    // Lower-dimensional fallbacks.
    let mut tris = Vec::new();
    for i in 0..n {
        for j in i + 1..n {
            for k in j + 1..n {
                if near(i, j) && near(i, k) && near(j, k) {
                    let (q, _) = tri_quality(&points[i], &points[j], &points[k]);
                    if q >= min_quality && q > 0.0 {
                        tris.push([i as u16, j as u16, k as u16, i as u16]);
                    }
                }
            }
        }
    }
    if !tris.is_empty() {
        tris.truncate(max_count);
        return (
            Simplices {
                dim: 2,
                corners: tris,
            },
            stats,
        );
    }
    let mut segs = Vec::new();
    for i in 0..n {
        for j in i + 1..n {
            if near(i, j) && (points[i] - points[j]).norm() > 0.0 {
                segs.push([i as u16, j as u16, i as u16, i as u16]);
            }
        }
    }
    if !segs.is_empty() {
        segs.truncate(max_count);
        return (
            Simplices {
                dim: 1,
                corners: segs,
            },
            stats,
        );
    }
    (
        Simplices {
            dim: 0,
            corners: vec![[0; 4]],
        },
        stats,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn all_good_combinations_are_kept_and_bad_ones_dropped() {
        let pts = vec![
            Point3::new(0.0, 0.0, 0.0),
            Point3::new(1.0, 0.0, 0.0),
            Point3::new(0.0, 1.0, 0.0),
            Point3::new(0.0, 0.0, 1.0),
            Point3::new(1.0, 1.0, 1.0),
            Point3::new(0.5, 0.5, 0.0), // on the base plane: some flat combinations
            Point3::new(50.0, 0.0, 0.0), // far away: too large
        ];
        let (s, st) = tetrahedralize(&pts, 0.05, 10.0, 1000);
        assert_eq!(s.dim, 3);
        assert_eq!(st.combinations, 35);
        assert_eq!(st.too_large, 20);
        assert!(st.too_thin >= 1);
        assert_eq!(st.kept as usize, s.corners.len());
        for t in &s.corners {
            assert!(!t.contains(&6));
            assert!(!(t.contains(&0) && t.contains(&1) && t.contains(&2) && t.contains(&5)));
        }
        let (capped, st) = tetrahedralize(&pts, 0.05, 10.0, 3);
        assert!(capped.corners.len() >= 3 && capped.corners.len() <= s.corners.len());
        assert_eq!(st.capped as usize, s.corners.len() - capped.corners.len());
        for p in 0..6u16 {
            assert!(
                capped.corners.iter().any(|t| t.contains(&p)),
                "point {p} kept"
            );
        }
    }

    #[test]
    fn degenerate_clouds_fall_back() {
        let line = vec![
            Point3::origin(),
            Point3::new(1.0, 0.0, 0.0),
            Point3::new(2.0, 0.0, 0.0),
        ];
        let (s, _) = tetrahedralize(&line, 0.05, 10.0, 100);
        assert_eq!(s.dim, 1);
        assert_eq!(s.corners.len(), 3);
        let plane = vec![
            Point3::origin(),
            Point3::new(1.0, 0.0, 0.0),
            Point3::new(0.0, 1.0, 0.0),
            Point3::new(1.0, 1.0, 0.0),
        ];
        assert_eq!(tetrahedralize(&plane, 0.05, 10.0, 100).0.dim, 2);
        assert_eq!(
            tetrahedralize(&[Point3::origin()], 0.05, 10.0, 100).0.dim,
            0
        );
    }
}
