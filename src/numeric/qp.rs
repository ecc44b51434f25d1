//! Small dense quadratic programs by primal active-set methods (Nocedal & Wright 2006
//! §16.5), exact up to rounding and finite: [`box_qp`] over the box `0 ≤ w ≤ 1` (blendshape
//! weights: the baseline fit, the jaw of LGI, rig weights, rig building) and
//! [`convex_weights`] over the simplex (the enhancer's convex combinations).

use nalgebra::{DMatrix, DVector};

/// Minimizes `½ wᵀ H w − gᵀ w` over `0 ≤ w ≤ 1` (`H` symmetric positive definite) by a
/// primal active-set method, starting from `start` clamped into the box.
pub fn box_qp(
    h: &DMatrix<f64>,
    g: &DVector<f64>,
    start: &DVector<f64>,
    max_iter: usize,
) -> DVector<f64> {
    let n = g.len();
    let mut w = start.map(|x| x.clamp(0.0, 1.0));
    // Working set: weights held at a bound.
    let mut fixed: Vec<bool> = w.iter().map(|&x| x <= 0.0 || x >= 1.0).collect();
    for _ in 0..max_iter.max(1) {
        let free: Vec<usize> = (0..n).filter(|&i| !fixed[i]).collect();
        // Minimizer over the free weights with the others at their bounds.
        let target = if free.is_empty() {
            w.clone()
        } else {
            let hff = DMatrix::from_fn(free.len(), free.len(), |a, b| h[(free[a], free[b])]);
            let mut rhs = DVector::from_fn(free.len(), |a, _| g[free[a]]);
            for (a, &i) in free.iter().enumerate() {
                for j in 0..n {
                    if fixed[j] {
                        rhs[a] -= h[(i, j)] * w[j];
                    }
                }
            }
            let Some(chol) = hff.cholesky() else {
                break;
            };
            let sol = chol.solve(&rhs);
            let mut t = w.clone();
            for (a, &i) in free.iter().enumerate() {
                t[i] = sol[a];
            }
            t
        };
        // Step toward it, stopping at the first bound.
        let mut alpha = 1.0;
        let mut blocking = None;
        for &i in &free {
            let d = target[i] - w[i];
            if d < 0.0 && target[i] < 0.0 {
                let a = w[i] / -d;
                if a < alpha {
                    alpha = a;
                    blocking = Some((i, 0.0));
                }
            } else if d > 0.0 && target[i] > 1.0 {
                let a = (1.0 - w[i]) / d;
                if a < alpha {
                    alpha = a;
                    blocking = Some((i, 1.0));
                }
            }
        }
        for &i in &free {
            w[i] += alpha * (target[i] - w[i]);
        }
        if let Some((i, bound)) = blocking {
            w[i] = bound;
            fixed[i] = true;
            continue;
        }
        // At the subproblem's minimizer: release the bound weight whose gradient points
        // most into the box, or stop (KKT conditions hold).
        let grad = h * &w - g;
        let mut worst = (0.0, None);
        for i in 0..n {
            if !fixed[i] {
                continue;
            }
            let v = if w[i] <= 0.0 { -grad[i] } else { grad[i] };
            if v > worst.0 + 1e-14 {
                worst = (v, Some(i));
            }
        }
        match worst.1 {
            Some(i) => fixed[i] = false,
            None => break,
        }
    }
    w
}

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

    #[test]
    fn box_qp_matches_brute_force_on_small_problems() {
        // Random SPD problems in 3 variables; compare against a fine grid search.
        let mut rng = crate::numeric::SplitMix64::new(7);
        let mut rnd = || rng.uniform(-1.0, 1.0);
        for _ in 0..20 {
            let a = DMatrix::from_fn(5, 3, |_, _| rnd());
            let h = a.transpose() * &a + DMatrix::identity(3, 3) * 0.01;
            let g = DVector::from_fn(3, |_, _| rnd() * 2.0);
            let w = box_qp(&h, &g, &DVector::zeros(3), 100);
            let f = |x: &DVector<f64>| 0.5 * (x.transpose() * &h * x)[0] - g.dot(x);
            let fw = f(&w);
            let n = 40;
            for i in 0..=n {
                for j in 0..=n {
                    for k in 0..=n {
                        let x = DVector::from_vec(vec![
                            i as f64 / n as f64,
                            j as f64 / n as f64,
                            k as f64 / n as f64,
                        ]);
                        assert!(fw <= f(&x) + 1e-12, "{fw} > {}", f(&x));
                    }
                }
            }
            assert!(w.iter().all(|&x| (0.0..=1.0).contains(&x)));
        }
    }
}
