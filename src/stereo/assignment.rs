//! Optimal assignment (Hungarian method, Kuhn 1955 / Munkres 1957), in the O(n²·m)
//! shortest-augmenting-path form with potentials.

/// Minimum-cost assignment of rows to columns for a `rows × cols` cost matrix (row-major,
/// `rows ≤ cols` not required). Entries that are not finite are forbidden. Returns for each
/// row its column, or `None` when the row is unassigned (more rows than columns, or only
/// forbidden entries).
pub fn hungarian(cost: &[f64], rows: usize, cols: usize) -> Vec<Option<usize>> {
    if rows == 0 || cols == 0 || cost.len() != rows * cols {
        return vec![None; rows];
    }
    let transpose = rows > cols;
    let (n, m) = if transpose {
        (cols, rows)
    } else {
        (rows, cols)
    };
    // Forbidden entries get a large finite cost and are removed afterwards.
    let finite_max = cost
        .iter()
        .copied()
        .filter(|c| c.is_finite())
        .fold(0.0f64, |a, c| a.max(c.abs()));
    let big = (finite_max + 1.0) * (n as f64 + 1.0) * 4.0;
    let at = |i: usize, j: usize| -> f64 {
        let c = if transpose {
            cost[j * cols + i]
        } else {
            cost[i * cols + j]
        };
        if c.is_finite() { c } else { big }
    };
    // 1-based arrays as in the classic formulation; column 0 is the virtual start.
    let mut u = vec![0.0; n + 1];
    let mut v = vec![0.0; m + 1];
    let mut p = vec![0usize; m + 1];
    let mut way = vec![0usize; m + 1];
    for i in 1..=n {
        p[0] = i;
        let mut j0 = 0;
        let mut minv = vec![f64::INFINITY; m + 1];
        let mut used = vec![false; m + 1];
        loop {
            used[j0] = true;
            let i0 = p[j0];
            let mut delta = f64::INFINITY;
            let mut j1 = 0;
            for j in 1..=m {
                if !used[j] {
                    let cur = at(i0 - 1, j - 1) - u[i0] - v[j];
                    if cur < minv[j] {
                        minv[j] = cur;
                        way[j] = j0;
                    }
                    if minv[j] < delta {
                        delta = minv[j];
                        j1 = j;
                    }
                }
            }
            for j in 0..=m {
                if used[j] {
                    u[p[j]] += delta;
                    v[j] -= delta;
                } else {
                    minv[j] -= delta;
                }
            }
            j0 = j1;
            if p[j0] == 0 {
                break;
            }
        }
        loop {
            let j1 = way[j0];
            p[j0] = p[j1];
            j0 = j1;
            if j0 == 0 {
                break;
            }
        }
    }
    let mut out = vec![None; rows];
    for (j, &pj) in p.iter().enumerate().skip(1) {
        if pj == 0 {
            continue;
        }
        let (r, c) = if transpose {
            (j - 1, pj - 1)
        } else {
            (pj - 1, j - 1)
        };
        if cost[r * cols + c].is_finite() {
            out[r] = Some(c);
        }
    }
    out
}

/// Minimum-cost assignment on a sparse cost graph: `candidates[row]` lists the allowed
/// `(column, cost)` pairs of each row (columns `0..cols`). The graph is split into its
/// connected components (union-find) and [`hungarian`] runs on each, so that a few
/// hundred rows and columns with a handful of candidates each cost little more than their
/// candidates. Returns the assigned `(row, column)` pairs.
pub fn assign_sparse(candidates: &[Vec<(usize, f64)>], cols: usize) -> Vec<(usize, usize)> {
    let m = candidates.len();
    let dets = cols;
    // Union-find over rows 0..m and columns m..m+cols.
    let mut parent: Vec<usize> = (0..m + dets).collect();
    fn find(parent: &mut [usize], mut x: usize) -> usize {
        while parent[x] != x {
            parent[x] = parent[parent[x]];
            x = parent[x];
        }
        x
    }
    for (i, cands) in candidates.iter().enumerate() {
        for &(a, _) in cands {
            if a >= dets {
                continue;
            }
            let (r1, r2) = (find(&mut parent, i), find(&mut parent, m + a));
            if r1 != r2 {
                parent[r1] = r2;
            }
        }
    }
    let mut groups: std::collections::HashMap<usize, (Vec<usize>, Vec<usize>)> =
        std::collections::HashMap::new();
    for (i, cands) in candidates.iter().enumerate() {
        if cands.is_empty() {
            continue;
        }
        let r = find(&mut parent, i);
        groups.entry(r).or_default().0.push(i);
    }
    for a in 0..dets {
        let r = find(&mut parent, m + a);
        if let Some(g) = groups.get_mut(&r) {
            g.1.push(a);
        }
    }
    let mut out = Vec::new();
    let mut keys: Vec<usize> = groups.keys().copied().collect();
    keys.sort_unstable();
    for key in keys {
        let Some((rows, cols)) = groups.get(&key) else {
            continue;
        };
        if rows.len() == 1 && cols.len() == 1 {
            out.push((rows[0], cols[0]));
            continue;
        }
        let mut cost = vec![f64::INFINITY; rows.len() * cols.len()];
        for (r, &i) in rows.iter().enumerate() {
            for &(a, e) in &candidates[i] {
                if let Some(c) = cols.iter().position(|&x| x == a) {
                    cost[r * cols.len() + c] = e;
                }
            }
        }
        for (r, c) in hungarian(&cost, rows.len(), cols.len()).iter().enumerate() {
            if let Some(c) = c {
                out.push((rows[r], cols[*c]));
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Brute force over all permutations for small square matrices.
    fn brute(cost: &[f64], n: usize) -> f64 {
        fn rec(cost: &[f64], n: usize, i: usize, used: &mut Vec<bool>) -> f64 {
            if i == n {
                return 0.0;
            }
            let mut best = f64::INFINITY;
            for j in 0..n {
                if !used[j] {
                    used[j] = true;
                    best = best.min(cost[i * n + j] + rec(cost, n, i + 1, used));
                    used[j] = false;
                }
            }
            best
        }
        rec(cost, n, 0, &mut vec![false; n])
    }

    #[test]
    fn optimal_on_random_matrices() {
        let mut rng = crate::numeric::SplitMix64::new(12345);
        let mut rnd = || rng.next_f64();
        for n in 1..=6 {
            for _ in 0..20 {
                let cost: Vec<f64> = (0..n * n).map(|_| rnd()).collect();
                let a = hungarian(&cost, n, n);
                let total: f64 = a
                    .iter()
                    .enumerate()
                    .map(|(i, j)| cost[i * n + j.unwrap()])
                    .sum();
                assert!((total - brute(&cost, n)).abs() < 1e-12);
            }
        }
    }

    #[test]
    fn rectangular_and_forbidden() {
        let inf = f64::INFINITY;
        // 3 rows, 2 columns: the cheapest two rows get the columns.
        let cost = [1.0, 9.0, 9.0, 1.0, 0.5, 0.6];
        let a = hungarian(&cost, 3, 2);
        assert_eq!(a.iter().filter(|x| x.is_some()).count(), 2);
        let a = hungarian(&[inf, 1.0, inf, inf], 2, 2);
        assert_eq!(a, vec![Some(1), None]);
    }
}
