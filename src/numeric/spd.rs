//! Sparse Cholesky factorization of a symmetric positive-definite matrix.

use faer::linalg::solvers::Solve;
use faer::sparse::{SparseColMat, Triplet};
use faer::{Mat, Side};
use nalgebra::Vector3;
use nalgebra_sparse::CsrMatrix;

/// A sparse Cholesky factorization that failed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("factoring the {what} failed: {reason}")]
pub struct FactorError {
    /// Which system.
    pub what: &'static str,
    /// The solver's message.
    pub reason: String,
}

/// A sparse symmetric positive-definite matrix factored once by sparse Cholesky (`faer`),
/// solved by back-substitution afterwards.
pub struct SpdFactor {
    llt: faer::sparse::linalg::solvers::Llt<usize, f64>,
    n: usize,
}

impl SpdFactor {
    /// Factors `a` (#N × #N, symmetric positive definite; both triangles stored); `what`
    /// names the system in the error.
    ///
    /// # Errors
    /// [`FactorError`] when `a` is not square, holds an index out of range, or is not
    /// positive definite (a degenerate mesh).
    pub fn new(a: &CsrMatrix<f64>, what: &'static str) -> Result<Self, FactorError> {
        let n = a.nrows();
        let triplets: Vec<Triplet<usize, usize, f64>> = a
            .triplet_iter()
            .map(|(i, j, &v)| Triplet::new(i, j, v))
            .collect();
        let mat =
            SparseColMat::<usize, f64>::try_new_from_triplets(n, n, &triplets).map_err(|e| {
                FactorError {
                    what,
                    reason: format!("{e:?}"),
                }
            })?;
        let llt = mat.sp_cholesky(Side::Lower).map_err(|e| FactorError {
            what,
            reason: format!("{e:?}"),
        })?;
        Ok(Self { llt, n })
    }

    /// Solves `A X = B` for the three coordinate columns of `rhs` (#N), in place.
    pub fn solve3(&self, rhs: &mut [Vector3<f64>]) {
        debug_assert_eq!(rhs.len(), self.n);
        let mut b = Mat::<f64>::from_fn(self.n, 3, |i, c| rhs[i][c]);
        self.llt.solve_in_place(b.as_mut());
        for (i, r) in rhs.iter_mut().enumerate() {
            *r = Vector3::new(b[(i, 0)], b[(i, 1)], b[(i, 2)]);
        }
    }
}
