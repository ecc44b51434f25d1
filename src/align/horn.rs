//! Closed-form absolute orientation by unit quaternions (Horn 1987).

use nalgebra::{Isometry3, Matrix3, Matrix4, Point3, Quaternion, Translation3, UnitQuaternion};

/// Why [`horn_alignment`] could not align two point sets.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum HornError {
    /// The two point sets (or the weights) have different lengths.
    #[error(
        "point sets differ in length: {source_len} source, {target_len} target, {weight_len} weights"
    )]
    Length {
        /// Number of source points.
        source_len: usize,
        /// Number of target points.
        target_len: usize,
        /// Number of weights (0 when none were given).
        weight_len: usize,
    },
    /// The weights sum to zero or less, or a weight or point is not finite.
    #[error("weights must be finite, non-negative and sum to a positive value")]
    Weights,
}

/// The rigid transform `target_from_source` minimizing Σᵢ wᵢ ‖R·sᵢ + t − tᵢ‖² (Horn 1987,
/// "Closed-form solution of absolute orientation using unit quaternions", §4: the
/// rotation is the eigenvector of the largest eigenvalue of the symmetric 4×4 matrix
/// built from the cross-covariance; the translation maps the weighted centroids).
///
/// `source`, `target`: #P points in any consistent unit. `weights`: #P non-negative
/// weights, or empty for all ones. With fewer than three non-collinear points the
/// rotation is not unique; one minimizer is returned.
///
/// # Errors
/// [`HornError::Length`] when the lengths differ; [`HornError::Weights`] when the weights
/// sum to zero or anything is non-finite.
pub fn horn_alignment(
    source: &[Point3<f64>],
    target: &[Point3<f64>],
    weights: &[f64],
) -> Result<Isometry3<f64>, HornError> {
    if source.len() != target.len() || (!weights.is_empty() && weights.len() != source.len()) {
        return Err(HornError::Length {
            source_len: source.len(),
            target_len: target.len(),
            weight_len: weights.len(),
        });
    }
    let w = |i: usize| if weights.is_empty() { 1.0 } else { weights[i] };
    let mut total = 0.0;
    let mut cs = nalgebra::Vector3::zeros();
    let mut ct = nalgebra::Vector3::zeros();
    for i in 0..source.len() {
        let wi = w(i);
        if !(wi.is_finite() && wi >= 0.0) {
            return Err(HornError::Weights);
        }
        total += wi;
        cs += source[i].coords * wi;
        ct += target[i].coords * wi;
    }
    if total <= 0.0 || total.is_nan() || !cs.iter().chain(ct.iter()).all(|v| v.is_finite()) {
        return Err(HornError::Weights);
    }
    cs /= total;
    ct /= total;
    // Cross-covariance M = Σ w (s − s̄)(t − t̄)ᵀ.
    let mut m = Matrix3::zeros();
    for i in 0..source.len() {
        m += (source[i].coords - cs) * (target[i].coords - ct).transpose() * w(i);
    }
    let (sxx, sxy, sxz) = (m[(0, 0)], m[(0, 1)], m[(0, 2)]);
    let (syx, syy, syz) = (m[(1, 0)], m[(1, 1)], m[(1, 2)]);
    let (szx, szy, szz) = (m[(2, 0)], m[(2, 1)], m[(2, 2)]);
    // Horn 1987 Eq. (N): the symmetric matrix whose top eigenvector is the rotation.
    let n = Matrix4::new(
        sxx + syy + szz,
        syz - szy,
        szx - sxz,
        sxy - syx,
        syz - szy,
        sxx - syy - szz,
        sxy + syx,
        szx + sxz,
        szx - sxz,
        sxy + syx,
        -sxx + syy - szz,
        syz + szy,
        sxy - syx,
        szx + sxz,
        syz + szy,
        -sxx - syy + szz,
    );
    let eig = n.symmetric_eigen();
    let best = eig.eigenvalues.imax();
    let q = eig.eigenvectors.column(best);
    let rotation = UnitQuaternion::from_quaternion(Quaternion::new(q[0], q[1], q[2], q[3]));
    let translation = ct - rotation * cs;
    Ok(Isometry3::from_parts(
        Translation3::from(translation),
        rotation,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    #[test]
    fn recovers_a_random_rigid_transform() {
        let pts: Vec<Point3<f64>> = (0..20)
            .map(|i| {
                let f = i as f64;
                Point3::new(
                    (f * 1.3).sin() * 40.0,
                    (f * 0.7).cos() * 30.0,
                    f * 2.0 - 15.0,
                )
            })
            .collect();
        let truth = Isometry3::new(Vector3::new(3.0, -7.0, 12.0), Vector3::new(0.4, -1.1, 0.7));
        let moved: Vec<_> = pts.iter().map(|p| truth * p).collect();
        let est = horn_alignment(&pts, &moved, &[]).unwrap();
        for (p, q) in pts.iter().zip(&moved) {
            assert!((est * p - q).norm() < 1e-9);
        }
    }

    #[test]
    fn rejects_bad_input() {
        let p = [Point3::origin(); 3];
        assert!(matches!(
            horn_alignment(&p, &p[..2], &[]),
            Err(HornError::Length { .. })
        ));
        assert_eq!(horn_alignment(&p, &p, &[0.0; 3]), Err(HornError::Weights));
    }
}
