//! Nearest-point queries over a fixed set of 3D points: a k-d tree (`kiddo`).

use kiddo::SquaredEuclidean;
use kiddo::immutable::float::kdtree::ImmutableKdTree;
use nalgebra::Point3;

/// A fixed set of points indexed for nearest-point queries. Points with a non-finite
/// coordinate are never found.
pub struct NearestPoints {
    tree: Option<ImmutableKdTree<f64, u64, 3, 32>>,
}

impl std::fmt::Debug for NearestPoints {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("NearestPoints")
            .field("points", &self.tree.as_ref().map_or(0, |t| t.size()))
            .finish()
    }
}

/// Where a point with a non-finite coordinate is kept: farther from any finite query than
/// any finite point can be, and finite, so the tree's arithmetic stays finite.
const NOWHERE: [f64; 3] = [f64::MAX / 4.0; 3];

impl NearestPoints {
    /// Indexes `points`; a query returns a position in this sequence.
    pub fn new(points: impl IntoIterator<Item = Point3<f64>>) -> Self {
        let coords: Vec<[f64; 3]> = points
            .into_iter()
            .map(|p| {
                if p.coords.iter().all(|v| v.is_finite()) {
                    [p.x, p.y, p.z]
                } else {
                    NOWHERE
                }
            })
            .collect();
        Self {
            tree: (!coords.is_empty()).then(|| ImmutableKdTree::new_from_slice(&coords)),
        }
    }

    /// Index and squared distance of the point nearest to `q`; None when there is no
    /// finite point or `q` is not finite.
    pub fn nearest(&self, q: &Point3<f64>) -> Option<(usize, f64)> {
        let tree = self.tree.as_ref()?;
        if !q.coords.iter().all(|v| v.is_finite()) {
            return None;
        }
        let nn = tree.nearest_one::<SquaredEuclidean>(&[q.x, q.y, q.z]);
        // A non-finite point is far away: found only when every point is non-finite.
        (nn.distance < 1e300).then_some((nn.item as usize, nn.distance))
    }

    /// [`NearestPoints::nearest`], and of several points equally near the first in the
    /// sequence, so that the answer does not depend on the tree's order (coincident
    /// vertices are common in meshes: the two sides of a UV seam).
    pub fn nearest_first(&self, q: &Point3<f64>) -> Option<(usize, f64)> {
        let (i, d2) = self.nearest(q)?;
        let tree = self.tree.as_ref()?;
        let first = tree
            .within_unsorted::<SquaredEuclidean>(&[q.x, q.y, q.z], d2)
            .into_iter()
            .filter(|n| n.distance == d2)
            .map(|n| n.item as usize)
            .min()
            .unwrap_or(i);
        Some((first, d2))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::rngs::StdRng;
    use rand::{Rng, SeedableRng};

    #[test]
    fn nearest_equals_brute_force() {
        let mut rng = StdRng::seed_from_u64(7);
        let mut pick = || Point3::new(rng.random(), rng.random(), rng.random::<f64>()) * 100.0;
        let mut points: Vec<Point3<f64>> = (0..500).map(|_| pick()).collect();
        points[17] = Point3::new(f64::NAN, 0.0, 0.0);
        let index = NearestPoints::new(points.iter().copied());
        for _ in 0..200 {
            let q = pick();
            let (i, d2) = index.nearest(&q).unwrap();
            let best = points
                .iter()
                .filter(|p| p.x.is_finite())
                .map(|p| (p - q).norm_squared())
                .fold(f64::INFINITY, f64::min);
            assert!(i != 17);
            assert!((d2 - best).abs() <= 1e-9 * best.max(1.0), "{d2} vs {best}");
            assert!(((points[i] - q).norm_squared() - best).abs() <= 1e-9 * best.max(1.0));
        }
        assert!(index.nearest(&Point3::new(f64::NAN, 0.0, 0.0)).is_none());
        // Coincident points: the first of them.
        let twins = NearestPoints::new([
            Point3::new(5.0, 0.0, 0.0),
            Point3::new(1.0, 1.0, 1.0),
            Point3::new(2.0, 0.0, 0.0),
            Point3::new(1.0, 1.0, 1.0),
            Point3::new(1.0, 1.0, 1.0),
        ]);
        for q in [Point3::new(1.2, 0.9, 1.0), Point3::new(1.0, 1.0, 1.0)] {
            assert_eq!(twins.nearest_first(&q).map(|n| n.0), Some(1));
        }
        assert!(NearestPoints::new([]).nearest(&Point3::origin()).is_none());
        let nowhere = NearestPoints::new([Point3::new(f64::INFINITY, 0.0, 0.0)]);
        assert!(nowhere.nearest(&Point3::origin()).is_none());
    }
}
