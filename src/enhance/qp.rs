//! Convex-combination weights by a small quadratic program (Bermano et al. 2014 §5.3,
//! Eq. 2-3).

use nalgebra::{DMatrix, DVector};

/// Minimizes `½ wᵀ G w − bᵀ w` subject to `Σ wᵢ = 1`, `wᵢ ≥ 0` (the normal-equation form of
/// Eq. 3: `G = D̃ᵀ diag(ω_r) D̃`, `b = D̃ᵀ diag(ω_r) ã`), by a primal active-set method
/// (Nocedal & Wright 2006 §16.5): start at the best single column, solve the
/// equality-constrained problem on the current support, step back to the boundary when a
/// weight would turn negative, and add the column with the most negative reduced cost
/// until the KKT conditions hold. Exact (up to rounding) and finite, unlike a projected
/// gradient method, which matters for the exact-reproduction property: an input equal to
/// a database column gets weight 1 on it (when no other convex combination matches too).
///
/// `ridge` (relative to the mean diagonal of `G`) is added to the diagonal so that the
/// support systems stay non-singular when database shapes coincide in a region.
///
/// Returns `None` when the sizes disagree or anything is non-finite; the weights otherwise.
pub fn convex_weights(g: &DMatrix<f64>, b: &DVector<f64>, ridge: f64) -> Option<DVector<f64>> {
    let k = b.len();
    if k == 0 || g.nrows() != k || g.ncols() != k {
        return None;
    }
    if !g.iter().chain(b.iter()).all(|x| x.is_finite()) {
        return None;
    }
    let mean_diag = (0..k).map(|i| g[(i, i)]).sum::<f64>() / k as f64;
    let mut g = g.clone();
    let eps = ridge * mean_diag.abs().max(f64::MIN_POSITIVE);
    for i in 0..k {
        g[(i, i)] += eps;
    }
    let objective = |w: &DVector<f64>| 0.5 * w.dot(&(&g * w)) - b.dot(w);
    // Start at the best vertex of the simplex.
    let start = (0..k).min_by(|&i, &j| {
        let fi = 0.5 * g[(i, i)] - b[i];
        let fj = 0.5 * g[(j, j)] - b[j];
        fi.total_cmp(&fj)
    })?;
    let mut w = DVector::zeros(k);
    w[start] = 1.0;
    let mut support = vec![start];
    let tol = 1e-12 * (1.0 + mean_diag.abs() + b.amax());
    for _ in 0..(10 * k + 20) {
        // Equality-constrained minimizer on the support: [G_SS 1; 1ᵀ 0][w; ν] = [b_S; 1].
        let s = support.len();
        let mut kkt = DMatrix::zeros(s + 1, s + 1);
        let mut rhs = DVector::zeros(s + 1);
        for (a, &i) in support.iter().enumerate() {
            for (c, &j) in support.iter().enumerate() {
                kkt[(a, c)] = g[(i, j)];
            }
            kkt[(a, s)] = 1.0;
            kkt[(s, a)] = 1.0;
            rhs[a] = b[i];
        }
        rhs[s] = 1.0;
        let sol = kkt.lu().solve(&rhs)?;
        let candidate: Vec<f64> = (0..s).map(|a| sol[a]).collect();
        if candidate.iter().all(|&x| x > 0.0) {
            for (a, &i) in support.iter().enumerate() {
                w[i] = candidate[a];
            }
            // Reduced costs of the columns outside the support: r_j = (G w − b)_j + ν.
            let grad = &g * &w - b;
            let nu = -grad[support[0]];
            let entering = (0..k)
                .filter(|j| !support.contains(j))
                .map(|j| (j, grad[j] + nu))
                .min_by(|x, y| x.1.total_cmp(&y.1));
            match entering {
                Some((j, r)) if r < -tol => support.push(j),
                _ => return Some(w),
            }
        } else {
            // Step from w toward the candidate until the first weight hits zero.
            let mut alpha = 1.0_f64;
            for (a, &i) in support.iter().enumerate() {
                if candidate[a] <= 0.0 && w[i] > candidate[a] {
                    alpha = alpha.min(w[i] / (w[i] - candidate[a]));
                }
            }
            for (a, &i) in support.iter().enumerate() {
                w[i] += alpha * (candidate[a] - w[i]);
            }
            support.retain(|&i| w[i] > 1e-15);
            for i in 0..k {
                if !support.contains(&i) {
                    w[i] = 0.0;
                }
            }
            if support.is_empty() {
                return None;
            }
            let total: f64 = w.sum();
            w /= total;
        }
        debug_assert!(objective(&w).is_finite());
    }
    Some(w)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Columns: 5 random-ish vectors in R^8.
    fn columns() -> DMatrix<f64> {
        DMatrix::from_fn(8, 5, |i, j| {
            ((i * 7 + j * 13) as f64 * 0.37).sin() + j as f64 * 0.1
        })
    }

    #[test]
    fn weights_are_convex_and_reproduce_a_column() {
        let d = columns();
        let g = d.transpose() * &d;
        for c in 0..5 {
            let a = d.column(c).into_owned();
            let w = convex_weights(&g, &(d.transpose() * &a), 1e-12).unwrap();
            assert!((w.sum() - 1.0).abs() < 1e-12);
            assert!(w.iter().all(|&x| x >= 0.0));
            assert!((w[c] - 1.0).abs() < 1e-6, "column {c}: {w}");
        }
        // A point inside the hull is reproduced, one outside is projected with the KKT
        // conditions holding.
        let inside = d.column(0) * 0.2 + d.column(3) * 0.5 + d.column(4) * 0.3;
        let w = convex_weights(&g, &(d.transpose() * &inside), 1e-12).unwrap();
        assert!((&d * &w - &inside).norm() < 1e-6);
        let outside = d.column(1) * 3.0 - d.column(2);
        let b = d.transpose() * &outside;
        let w = convex_weights(&g, &b, 0.0).unwrap();
        let grad = &g * &w - &b;
        let nu = (0..5)
            .filter(|&i| w[i] > 1e-12)
            .map(|i| -grad[i])
            .next()
            .unwrap();
        for i in 0..5 {
            assert!(grad[i] + nu > -1e-9);
            if w[i] > 1e-9 {
                assert!((grad[i] + nu).abs() < 1e-9);
            }
        }
        assert!(w.iter().all(|&x| x >= 0.0) && (w.sum() - 1.0).abs() < 1e-12);
        assert!(convex_weights(&g, &DVector::zeros(3), 0.0).is_none());
    }
}
