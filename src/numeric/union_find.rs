//! Disjoint sets of indices in a parent array (`parent[i] == i` at a root), with the root
//! of every set its smallest index: a set's root is its first member in index order, so
//! that callers numbering sets by their roots number them in that order too.

/// The root of `i`'s set, halving the path on the way.
pub fn find_root(parent: &mut [u32], mut i: u32) -> u32 {
    while parent[i as usize] != i {
        let grand = parent[parent[i as usize] as usize];
        parent[i as usize] = grand;
        i = grand;
    }
    i
}

/// Joins the sets of `a` and `b` under the smaller of their roots.
pub fn join_sets(parent: &mut [u32], a: u32, b: u32) {
    let (ra, rb) = (find_root(parent, a), find_root(parent, b));
    if ra != rb {
        parent[ra.max(rb) as usize] = ra.min(rb);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sets_join_under_their_smallest_index() {
        let mut parent: Vec<u32> = (0..8).collect();
        join_sets(&mut parent, 5, 3);
        join_sets(&mut parent, 7, 5);
        join_sets(&mut parent, 6, 1);
        let roots: Vec<u32> = (0..8).map(|i| find_root(&mut parent, i)).collect();
        assert_eq!(roots, [0, 1, 2, 3, 4, 3, 1, 3]);
        join_sets(&mut parent, 7, 6);
        assert_eq!(find_root(&mut parent, 5), 1);
        assert_eq!(find_root(&mut parent, 0), 0);
    }
}
