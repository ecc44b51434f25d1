//! Convex hull faces of a small point cloud, for projecting a bundle that lies outside
//! every tetrahedron (Cong et al. 2019 §4: "we project the bundle position to the convex
//! hull of the associated point cloud").
//!
//! The clouds have tens of points, so the hull is found directly: a triangle of three
//! points is a hull face when no point lies strictly in front of its plane. Coplanar
//! facets come out as several overlapping triangles, which is harmless for closest-point
//! queries.

use nalgebra::Point3;

use super::barycentric::{closest_on_triangle, combine};

/// Hull triangles (point indices) of `points`; empty when the cloud is flat or smaller
/// than a tetrahedron.
pub fn hull_faces(points: &[Point3<f64>]) -> Vec<[u16; 3]> {
    let n = points.len().min(u16::MAX as usize);
    if n < 4 {
        return Vec::new();
    }
    let mut lo = points[0];
    let mut hi = lo;
    for p in points {
        lo = lo.inf(p);
        hi = hi.sup(p);
    }
    let scale = (hi - lo).norm().max(1e-12);
    let eps = 1e-9 * scale;
    let mut faces = Vec::new();
    for i in 0..n {
        for j in i + 1..n {
            for k in j + 1..n {
                let nrm = (points[j] - points[i]).cross(&(points[k] - points[i]));
                let len = nrm.norm();
                if len <= 1e-12 * scale * scale {
                    continue;
                }
                let nrm = nrm / len;
                let (mut front, mut back) = (false, false);
                for (l, p) in points.iter().enumerate().take(n) {
                    if l == i || l == j || l == k {
                        continue;
                    }
                    let d = (p - points[i]).dot(&nrm);
                    front |= d > eps;
                    back |= d < -eps;
                    if front && back {
                        break;
                    }
                }
                if !(front && back) {
                    faces.push([i as u16, j as u16, k as u16]);
                }
            }
        }
    }
    faces
}

/// Closest point to `x` on the hull triangles `faces` of `points`, and the triangle it
/// lies on.
pub fn closest_on_hull(
    points: &[Point3<f64>],
    faces: &[[u16; 3]],
    x: &Point3<f64>,
) -> Option<(Point3<f64>, usize)> {
    let mut best: Option<(f64, Point3<f64>, usize)> = None;
    for (fi, f) in faces.iter().enumerate() {
        let (a, b, c) = (
            &points[f[0] as usize],
            &points[f[1] as usize],
            &points[f[2] as usize],
        );
        let w = closest_on_triangle(a, b, c, x);
        let y = combine(&[*a, *b, *c], &[w[0], w[1], w[2], 0.0]);
        let d = (y - x).norm_squared();
        if best.is_none_or(|(bd, _, _)| d < bd) {
            best = Some((d, y, fi));
        }
    }
    best.map(|b| (b.1, b.2))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cube_hull_and_projection() {
        let mut pts = Vec::new();
        for i in 0..8 {
            pts.push(Point3::new(
                (i & 1) as f64,
                ((i >> 1) & 1) as f64,
                ((i >> 2) & 1) as f64,
            ));
        }
        pts.push(Point3::new(0.5, 0.5, 0.5)); // interior: on no face
        let f = hull_faces(&pts);
        assert!(f.iter().all(|t| !t.contains(&8)));
        // 6 square facets, each of 4 coplanar points: 4 triangles each.
        assert_eq!(f.len(), 24);
        let (y, _) = closest_on_hull(&pts, &f, &Point3::new(2.0, 0.5, 0.25)).unwrap();
        assert!((y - Point3::new(1.0, 0.5, 0.25)).norm() < 1e-12);
        assert!(hull_faces(&pts[..3]).is_empty());
    }
}
