//! Discrete Laplace–Beltrami operators and lumped mass matrices.
//!
//! # Conventions
//! The cotangent Laplacian `L` is the weak ("stiffness") form used by libigl's
//! `cotmatrix`: **negative semi-definite**, rows summing to zero, symmetric. It integrates
//! the Laplacian over each vertex's area, so the pointwise Laplacian of a function `f`
//! sampled at the vertices is `Δf ≈ M⁻¹ L f` with `M` a [`mass_matrix`]. The Dirichlet
//! energy is `½ ∫ ‖∇f‖² = −½ fᵀ L f`.
//!
//! Both are built over the triangulated view ([`Mesh::triangles`]), so a quad's
//! diagonal carries a weight; the [`uniform_laplacian`] is built over the polygon edges.

use nalgebra::Point3;
use nalgebra_sparse::{CooMatrix, CsrMatrix};

use super::Mesh;
use super::topology::Topology;

/// Which lumped (diagonal) mass matrix [`mass_matrix`] builds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum MassKind {
    /// A third of the area of every incident triangle.
    Barycentric,
    /// The mixed Voronoi area of Meyer et al. 2003 §3.3 (Fig. 4): each vertex's share of
    /// a triangle is its Voronoi region, ⅛ (‖e_ij‖² cot γ_k + ‖e_ik‖² cot γ_j), for a
    /// non-obtuse triangle; for an obtuse one, half the area goes to the obtuse corner
    /// and a quarter to each other corner. libigl's default.
    #[default]
    Voronoi,
}

/// The cotangent Laplacian of `mesh` at its own positions (#V × #V), see
/// [`cotangent_laplacian_of`].
pub fn cotangent_laplacian(mesh: &Mesh) -> CsrMatrix<f64> {
    cotangent_laplacian_of(mesh, &mesh.positions)
}

/// The cotangent Laplacian (Pinkall & Polthier 1993; Meyer et al. 2003 Eq. 8) of `mesh`'s
/// triangles placed at `positions` (#V), as a #V × #V sparse matrix:
///
/// L_ij = ½ (cot α_ij + cot β_ij) for i ≠ j sharing a triangle edge, where α_ij and β_ij
/// are the angles opposite the edge in its (one or two) triangles; L_ii = −Σ_{j≠i} L_ij.
///
/// Negative semi-definite, symmetric, rows sum to zero (see the [module docs](self)).
/// Weights are dimensionless: scaling the mesh leaves `L` unchanged. Weights can be
/// negative next to obtuse angles (the matrix is then no M-matrix, but still negative
/// semi-definite).
///
/// A degenerate triangle (zero area up to rounding: 2·area ≤ ε (ℓ₀² + ℓ₁² + ℓ₂²), ε the
/// machine epsilon) contributes nothing, since its cotangents are undefined; its entries
/// are still stored as explicit zeros, so the sparsity pattern (every triangle edge plus
/// the diagonal) depends only on the triangles, never on the positions, which lets a
/// caller reuse a symbolic factorization across poses.
///
/// # Panics
/// If `positions` has fewer entries than a triangle index needs (a caller bug).
pub fn cotangent_laplacian_of(mesh: &Mesh, positions: &[Point3<f64>]) -> CsrMatrix<f64> {
    let n = mesh.vertex_count();
    let mut coo = CooMatrix::new(n, n);
    coo.reserve(12 * mesh.triangles.len());
    for t in &mesh.triangles {
        let cots = triangle_cotangents(positions, t).unwrap_or([0.0; 3]);
        // cots[c] is the angle at corner c, opposite the edge of the other two corners.
        for c in 0..3 {
            let (i, j) = (t[(c + 1) % 3] as usize, t[(c + 2) % 3] as usize);
            let w = 0.5 * cots[c];
            coo.push(i, j, w);
            coo.push(j, i, w);
            coo.push(i, i, -w);
            coo.push(j, j, -w);
        }
    }
    CsrMatrix::from(&coo)
}

/// Cotangents of a triangle's three angles, or `None` when it is degenerate (see
/// [`cotangent_laplacian_of`]). cot θ_a = (b − a)·(c − a) / ‖(b − a) × (c − a)‖, and the
/// cross product's norm (twice the area) is the same at every corner.
fn triangle_cotangents(positions: &[Point3<f64>], t: &[u32; 3]) -> Option<[f64; 3]> {
    let p = [
        positions[t[0] as usize],
        positions[t[1] as usize],
        positions[t[2] as usize],
    ];
    let e = [p[2] - p[1], p[0] - p[2], p[1] - p[0]]; // e[c] is opposite corner c
    let double_area = e[1].cross(&e[2]).norm();
    let scale = e.iter().map(|v| v.norm_squared()).sum::<f64>();
    // Also rejects a non-finite area (coordinates so large that squares overflow).
    let well_shaped = double_area.is_finite() && double_area > f64::EPSILON * scale;
    // At corner c the two sides leaving it are −e[c+1] and e[c+2].
    well_shaped.then(|| std::array::from_fn(|c| -e[(c + 1) % 3].dot(&e[(c + 2) % 3]) / double_area))
}

/// The lumped mass matrix of `mesh` at its own positions, see [`mass_matrix_of`].
pub fn mass_matrix(mesh: &Mesh, kind: MassKind) -> CsrMatrix<f64> {
    mass_matrix_of(mesh, &mesh.positions, kind)
}

/// The diagonal (lumped) mass matrix of `mesh`'s triangles placed at `positions` (#V):
/// M_ii is the area of vertex i's region, in squared mesh units, split as `kind` says.
///
/// The diagonal sums to the total triangle area for both kinds. Degenerate triangles (as
/// in [`cotangent_laplacian_of`]) contribute nothing; a vertex used by no triangle gets
/// a zero (the matrix is then singular). Every diagonal entry is stored, zero or not.
///
/// # Panics
/// If `positions` has fewer entries than a triangle index needs (a caller bug).
pub fn mass_matrix_of(mesh: &Mesh, positions: &[Point3<f64>], kind: MassKind) -> CsrMatrix<f64> {
    let n = mesh.vertex_count();
    let mut area = vec![0.0; n];
    for t in &mesh.triangles {
        let Some(cots) = triangle_cotangents(positions, t) else {
            continue;
        };
        let p = t.map(|v| positions[v as usize]);
        let sq = |a: usize, b: usize| (p[a] - p[b]).norm_squared();
        let tri_area = 0.5 * (p[1] - p[0]).cross(&(p[2] - p[0])).norm();
        match kind {
            MassKind::Barycentric => {
                for &v in t {
                    area[v as usize] += tri_area / 3.0;
                }
            }
            MassKind::Voronoi => {
                // An angle is obtuse exactly when its cotangent is negative.
                let obtuse = cots.iter().position(|&c| c < 0.0);
                for c in 0..3 {
                    let (j, k) = ((c + 1) % 3, (c + 2) % 3);
                    let share = match obtuse {
                        None => (sq(c, j) * cots[k] + sq(c, k) * cots[j]) / 8.0,
                        Some(o) if o == c => tri_area / 2.0,
                        Some(_) => tri_area / 4.0,
                    };
                    area[t[c] as usize] += share;
                }
            }
        }
    }
    diagonal(area)
}

/// A diagonal sparse matrix with every diagonal entry stored.
fn diagonal(values: Vec<f64>) -> CsrMatrix<f64> {
    let n = values.len();
    let mut coo = CooMatrix::new(n, n);
    coo.reserve(n);
    for (i, v) in values.into_iter().enumerate() {
        coo.push(i, i, v);
    }
    CsrMatrix::from(&coo)
}

/// The uniform ("umbrella", graph) Laplacian over the polygon edges (#V × #V):
/// L_ij = 1 / deg(i) for each polygon-edge neighbour j of i, L_ii = −1, so that
/// (L x)_i = mean of the neighbours' x − x_i (Taubin 1995).
///
/// Rows sum to zero; the matrix is not symmetric (rows are normalized by their own
/// degree). Quads contribute their four sides, not the triangulation's diagonals. A
/// vertex used by no polygon has an empty row (no diagonal either). Depends on
/// connectivity only, not on positions.
pub fn uniform_laplacian(mesh: &Mesh) -> CsrMatrix<f64> {
    let topology = Topology::new(mesh);
    let n = mesh.vertex_count();
    let mut coo = CooMatrix::new(n, n);
    coo.reserve(n + 2 * topology.edges.len());
    for v in 0..n as u32 {
        let neighbors = topology.neighbors(v);
        if neighbors.is_empty() {
            continue;
        }
        let w = 1.0 / neighbors.len() as f64;
        coo.push(v as usize, v as usize, -1.0);
        for &u in neighbors {
            coo.push(v as usize, u as usize, w);
        }
    }
    CsrMatrix::from(&coo)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::test_meshes::{grid, tetrahedron};
    use crate::mesh::triangle_areas;
    use nalgebra::{DMatrix, DVector};

    /// Uniform numbers in [-1, 1).
    struct Rng(rand::rngs::StdRng);

    impl Rng {
        fn next(&mut self) -> f64 {
            rand::Rng::random_range(&mut self.0, -1.0..1.0)
        }
    }

    /// A grid with jittered, non-planar vertices: obtuse and uneven triangles.
    fn bumpy_grid(n: usize) -> Mesh {
        let mut g = grid(n, 1.0);
        let mut rng = Rng(rand::SeedableRng::seed_from_u64(7));
        for p in &mut g.positions {
            p.x += 0.35 * rng.next();
            p.y += 0.35 * rng.next();
            p.z = 0.5 * rng.next();
        }
        g.triangulate();
        g
    }

    fn dense(m: &CsrMatrix<f64>) -> DMatrix<f64> {
        DMatrix::from(m)
    }

    fn assert_laplacian_properties(l: &CsrMatrix<f64>, symmetric: bool) {
        let d = dense(l);
        for i in 0..d.nrows() {
            let row = d.row(i);
            let scale: f64 = row.iter().map(|x| x.abs()).sum();
            assert!(
                row.sum().abs() <= 1e-12 * scale.max(1e-300),
                "row {i} sums to {}",
                row.sum()
            );
            assert!(row.iter().all(|x| x.is_finite()));
        }
        if symmetric {
            assert!((&d - d.transpose()).amax() <= 1e-14 * d.amax());
        }
    }

    #[test]
    fn cotangent_laplacian_is_symmetric_zero_row_sum_nsd() {
        let meshes = [bumpy_grid(6), tetrahedron(), grid(3, 0.1)];
        let mut rng = Rng(rand::SeedableRng::seed_from_u64(8));
        for m in &meshes {
            let l = cotangent_laplacian(m);
            assert_eq!((l.nrows(), l.ncols()), (m.vertex_count(), m.vertex_count()));
            assert_laplacian_properties(&l, true);
            let d = dense(&l);
            let ones = DVector::from_element(m.vertex_count(), 1.0);
            assert!((&d * &ones).amax() <= 1e-12 * d.amax());
            for _ in 0..50 {
                let x = DVector::from_fn(m.vertex_count(), |_, _| rng.next());
                let energy = x.dot(&(&d * &x));
                assert!(
                    energy <= 1e-12 * d.amax() * x.norm_squared(),
                    "xᵀLx = {energy}"
                );
            }
            // Strictly negative on something non-constant.
            let x = DVector::from_fn(m.vertex_count(), |i, _| m.positions[i].x);
            assert!(x.dot(&(&d * &x)) < 0.0);
        }
        // The bumpy grid really has obtuse angles, hence some negative weights.
        let l = cotangent_laplacian(&meshes[0]);
        assert!(l.triplet_iter().any(|(i, j, &v)| i != j && v < 0.0));
    }

    #[test]
    fn regular_grid_gives_five_point_stencil() {
        let (n, h) = (4, 0.3);
        let g = grid(n, h);
        // Ties split quads along corners 0-2: the diagonal (i, j)-(i + 1, j + 1).
        assert_eq!(g.triangles[0], [0, 1, 6]);
        let d = dense(&cotangent_laplacian(&g));
        let id = |i: usize, j: usize| j * (n + 1) + i;
        for j in 1..n {
            for i in 1..n {
                let v = id(i, j);
                let mut expected = vec![0.0; g.vertex_count()];
                expected[v] = -4.0;
                for u in [id(i - 1, j), id(i + 1, j), id(i, j - 1), id(i, j + 1)] {
                    expected[u] = 1.0;
                }
                for (u, &e) in expected.iter().enumerate() {
                    assert!((d[(v, u)] - e).abs() < 1e-12, "L[{v},{u}] = {}", d[(v, u)]);
                }
            }
        }
        // Explicit zeros on the split diagonals keep the pattern position-independent.
        let l = cotangent_laplacian(&g);
        assert_eq!(
            l.get_entry(id(1, 1), id(2, 2)).map(|e| e.into_value()),
            Some(0.0)
        );
        assert_eq!(l.nnz(), g.vertex_count() + 2 * (2 * n * (n + 1) + n * n));
    }

    #[test]
    fn scale_invariant_weights_and_mass_scaling() {
        let m = bumpy_grid(5);
        let mut big = m.clone();
        big.scale(1e3);
        let (l, lb) = (
            dense(&cotangent_laplacian(&m)),
            dense(&cotangent_laplacian(&big)),
        );
        assert!((&l - &lb).amax() <= 1e-12 * l.amax());
        for kind in [MassKind::Barycentric, MassKind::Voronoi] {
            let (a, b) = (
                dense(&mass_matrix(&m, kind)),
                dense(&mass_matrix(&big, kind)),
            );
            assert!((&a * 1e6 - &b).amax() <= 1e-12 * b.amax());
        }
    }

    #[test]
    fn mass_matrix_sums_to_total_area() {
        for m in [bumpy_grid(6), tetrahedron(), grid(3, 2.0)] {
            let total: f64 = triangle_areas(&m).iter().sum();
            for kind in [MassKind::Barycentric, MassKind::Voronoi] {
                let mm = mass_matrix(&m, kind);
                assert_eq!(mm.nnz(), m.vertex_count());
                let sum: f64 = mm
                    .triplet_iter()
                    .map(|(i, j, &v)| {
                        assert_eq!(i, j);
                        assert!(v > 0.0);
                        v
                    })
                    .sum();
                assert!(
                    (sum - total).abs() <= 1e-12 * total,
                    "{kind:?}: {sum} vs {total}"
                );
            }
        }
        // On a regular grid an interior vertex's Voronoi cell is an h × h square.
        let g = grid(3, 2.0);
        let v = dense(&mass_matrix(&g, MassKind::Voronoi));
        assert!((v[(5, 5)] - 4.0).abs() < 1e-12);
    }

    #[test]
    fn voronoi_mass_of_obtuse_and_acute_triangles() {
        // Obtuse at corner 2: half the area there, a quarter at the others.
        let p = vec![
            Point3::new(0.0, 0.0, 0.0),
            Point3::new(4.0, 0.0, 0.0),
            Point3::new(1.0, 0.5, 0.0),
        ];
        let m = Mesh::new(p, &[vec![0, 1, 2]], Vec::new(), None).unwrap();
        let v = dense(&mass_matrix(&m, MassKind::Voronoi));
        let area = 1.0;
        assert!((v[(2, 2)] - area / 2.0).abs() < 1e-15);
        assert!((v[(0, 0)] - area / 4.0).abs() < 1e-15);
        let b = dense(&mass_matrix(&m, MassKind::Barycentric));
        assert!((b[(2, 2)] - area / 3.0).abs() < 1e-15);
        // Equilateral: the Voronoi regions are equal thirds.
        let s = 3f64.sqrt();
        let p = vec![
            Point3::new(0.0, 0.0, 0.0),
            Point3::new(2.0, 0.0, 0.0),
            Point3::new(1.0, s, 0.0),
        ];
        let m = Mesh::new(p, &[vec![0, 1, 2]], Vec::new(), None).unwrap();
        let v = dense(&mass_matrix(&m, MassKind::Voronoi));
        for i in 0..3 {
            assert!((v[(i, i)] - s / 3.0).abs() < 1e-14, "{}", v[(i, i)]);
        }
        assert_eq!(MassKind::default(), MassKind::Voronoi);
    }

    #[test]
    fn degenerate_triangles_contribute_nothing() {
        // Triangle 1 is collinear (zero area); triangle 0 is a unit right triangle.
        let p = vec![
            Point3::new(0.0, 0.0, 0.0),
            Point3::new(1.0, 0.0, 0.0),
            Point3::new(0.0, 1.0, 0.0),
            Point3::new(2.0, 0.0, 0.0),
        ];
        let m = Mesh::new(p, &[vec![0, 1, 2], vec![0, 3, 1]], Vec::new(), None).unwrap();
        let l = cotangent_laplacian(&m);
        assert_laplacian_properties(&l, true);
        let d = dense(&l);
        assert_eq!(d[(0, 3)], 0.0);
        assert_eq!(d[(3, 3)], 0.0);
        assert!(
            l.get_entry(0, 3).is_some(),
            "pattern keeps the degenerate edge"
        );
        // The right triangle alone: cot 45° = 1 opposite the legs, cot 90° = 0.
        assert!((d[(0, 1)] - 0.5).abs() < 1e-15 && (d[(1, 2)] - 0.0).abs() < 1e-15);
        let mass = dense(&mass_matrix(&m, MassKind::Voronoi));
        assert_eq!(mass[(3, 3)], 0.0);
        assert!((mass.trace() - 0.5).abs() < 1e-15);
    }

    #[test]
    fn laplacian_of_other_positions() {
        let m = grid(3, 1.0);
        let moved: Vec<_> = m
            .positions
            .iter()
            .map(|p| Point3::new(p.x * 2.0, p.y, p.z))
            .collect();
        let l = dense(&cotangent_laplacian_of(&m, &moved));
        // Stretched 2:1, the horizontal edges get weight ½·(½ + ½) = ½ and the vertical
        // ones 2 at an interior vertex.
        assert!((l[(5, 6)] - 0.5).abs() < 1e-12, "{}", l[(5, 6)]);
        assert!((l[(5, 9)] - 2.0).abs() < 1e-12, "{}", l[(5, 9)]);
        assert!((l[(5, 5)] + 5.0).abs() < 1e-12);
    }

    #[test]
    fn uniform_laplacian_over_polygon_edges() {
        let mut m = grid(3, 1.0);
        // An unused vertex gets an empty row.
        m = Mesh::new(
            m.positions
                .iter()
                .copied()
                .chain([Point3::new(9.0, 9.0, 9.0)])
                .collect(),
            &m.faces().map(<[u32]>::to_vec).collect::<Vec<_>>(),
            Vec::new(),
            None,
        )
        .unwrap();
        let l = uniform_laplacian(&m);
        assert_laplacian_properties(&l, false);
        let d = dense(&l);
        assert_eq!(d[(5, 5)], -1.0);
        for u in [1, 4, 6, 9] {
            assert_eq!(d[(5, u)], 0.25);
        }
        assert_eq!(d[(5, 10)], 0.0, "no diagonal neighbours");
        assert_eq!(d[(0, 1)], 0.5);
        assert_eq!(d[(0, 4)], 0.5);
        assert_eq!(d[(1, 0)], 1.0 / 3.0);
        assert_eq!(l.row(16).nnz(), 0);
    }
}
