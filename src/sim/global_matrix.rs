//! The Projective Dynamics global matrix and its sparse Cholesky factor.
//!
//! `L = Σₑ wₑVₑ·GₑGₑᵀ + diag(kₐ)` (n×n, one row per vertex). It depends on neither the
//! actuations nor the positions, so it is factored once per mesh; x, y and z share it, and
//! every solve reuses the symbolic and numeric factor and one preallocated scratch buffer.

use faer::dyn_stack::{MemBuffer, MemStack};
use faer::sparse::linalg::SupernodalThreshold;
use faer::sparse::linalg::cholesky::{
    CholeskySymbolicParams, LltRef, SymbolicCholesky, SymmetricOrdering,
    factorize_symbolic_cholesky,
};
use faer::sparse::{SparseColMat, Triplet};
use faer::{Conj, Mat, Par, Side};

use super::deformation::ElementOperator;

#[derive(Debug, thiserror::Error)]
pub enum FactorError {
    #[error("could not build the sparse matrix: {0}")]
    Build(String),
    #[error(
        "the global matrix is not positive definite ({0}); is every connected part of the mesh attached to a bone?"
    )]
    NotPositiveDefinite(String),
}

/// The factored global matrix.
pub struct GlobalMatrix {
    n: usize,
    symbolic: SymbolicCholesky<usize>,
    l_values: Vec<f64>,
    /// The diagonal of `L`: per-vertex stiffness scale.
    diagonal: Vec<f64>,
    /// `L`'s lower triangle (duplicates summed), for contact steps that refactor `L + K`.
    lower: Vec<Triplet<usize, usize, f64>>,
}

/// Scratch for one solve with 3 right-hand sides: allocate once, reuse every iteration.
pub struct SolveScratch {
    rhs: Mat<f64>,
    stack: MemBuffer,
}

impl GlobalMatrix {
    /// Assembles and factors `L` for elements with weights `w·V` (`element_weights`) and
    /// per-vertex attachment stiffness `k` (zero where a vertex is free).
    pub fn factor(
        tets: &[[u32; 4]],
        ops: &[ElementOperator],
        element_weights: &[f64],
        attachment_stiffness: &[f64],
    ) -> Result<Self, FactorError> {
        let n = attachment_stiffness.len();
        let mut triplets = Vec::with_capacity(tets.len() * 10 + n);
        let mut diagonal = attachment_stiffness.to_vec();
        for ((tet, op), &wv) in tets.iter().zip(ops).zip(element_weights) {
            for i in 0..4 {
                for j in 0..4 {
                    let (a, b) = (tet[i] as usize, tet[j] as usize);
                    let value = wv * op.grads[i].dot(&op.grads[j]);
                    if a == b {
                        diagonal[a] += value;
                    }
                    // Lower triangle only; duplicates are summed on assembly.
                    if a >= b {
                        triplets.push(Triplet::new(a, b, value));
                    }
                }
            }
        }
        for (v, &k) in attachment_stiffness.iter().enumerate() {
            if k != 0.0 {
                triplets.push(Triplet::new(v, v, k));
            }
        }
        let matrix = SparseColMat::<usize, f64>::try_new_from_triplets(n, n, &triplets)
            .map_err(|e| FactorError::Build(format!("{e:?}")))?;
        let symbolic = factorize_symbolic_cholesky(
            matrix.symbolic(),
            Side::Lower,
            SymmetricOrdering::Amd,
            CholeskySymbolicParams {
                supernodal_flop_ratio_threshold: SupernodalThreshold::AUTO,
                ..Default::default()
            },
        )
        .map_err(|e| FactorError::Build(format!("{e:?}")))?;
        let lower: Vec<Triplet<usize, usize, f64>> = matrix
            .as_ref()
            .triplet_iter()
            .map(|t| Triplet::new(t.row, t.col, *t.val))
            .collect();
        let mut l_values = vec![0.0; symbolic.len_val()];
        let par = Par::Seq;
        let mut stack =
            MemBuffer::new(symbolic.factorize_numeric_llt_scratch::<f64>(par, Default::default()));
        symbolic
            .factorize_numeric_llt(
                &mut l_values,
                matrix.as_ref(),
                Side::Lower,
                Default::default(),
                par,
                MemStack::new(&mut stack),
                Default::default(),
            )
            .map_err(|e| FactorError::NotPositiveDefinite(format!("{e:?}")))?;
        Ok(Self {
            n,
            symbolic,
            l_values,
            diagonal,
            lower,
        })
    }

    pub fn dimension(&self) -> usize {
        self.n
    }

    /// Nonzeros in the Cholesky factor (what a solve streams through).
    pub fn factor_nonzeros(&self) -> usize {
        self.l_values.len()
    }

    /// `L`'s lower-triangle entries (row ≥ column).
    pub fn lower_entries(&self) -> &[Triplet<usize, usize, f64>] {
        &self.lower
    }

    pub fn diagonal(&self) -> &[f64] {
        &self.diagonal
    }

    pub fn scratch(&self) -> SolveScratch {
        SolveScratch {
            rhs: Mat::zeros(self.n, 3),
            stack: MemBuffer::new(self.symbolic.solve_in_place_scratch::<f64>(3, Par::Seq)),
        }
    }

    /// Solves `L·X = B` in place for the three coordinate columns of an interleaved
    /// `[x0, y0, z0, x1, …]` vector.
    pub fn solve_in_place(&self, b: &mut [f64], scratch: &mut SolveScratch) {
        debug_assert_eq!(b.len(), 3 * self.n);
        for (v, p) in b.chunks_exact(3).enumerate() {
            for (c, &value) in p.iter().enumerate() {
                scratch.rhs[(v, c)] = value;
            }
        }
        let llt = LltRef::new(&self.symbolic, &self.l_values);
        llt.solve_in_place_with_conj(
            Conj::No,
            scratch.rhs.as_mut(),
            Par::Seq,
            MemStack::new(&mut scratch.stack),
        );
        for (v, p) in b.chunks_exact_mut(3).enumerate() {
            for (c, value) in p.iter_mut().enumerate() {
                *value = scratch.rhs[(v, c)];
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::generate::box_mesh;
    use nalgebra::{DMatrix, DVector, Vector3};

    #[test]
    fn solve_matches_a_dense_solve_of_the_assembled_matrix() {
        let mesh = box_mesh([2, 3, 2], Vector3::new(1.0, 1.5, 1.0), 0.2, 11).unwrap();
        let ops = ElementOperator::for_mesh(&mesh);
        let n = mesh.vertex_count();
        let weights: Vec<f64> = ops.iter().map(|o| 2.0 * o.rest_volume).collect();
        let mut stiffness = vec![0.0; n];
        stiffness[0] = 5.0;
        stiffness[n - 1] = 3.0;
        let global = GlobalMatrix::factor(&mesh.tets, &ops, &weights, &stiffness).unwrap();

        let mut dense = DMatrix::<f64>::zeros(n, n);
        for ((tet, op), wv) in mesh.tets.iter().zip(&ops).zip(&weights) {
            for i in 0..4 {
                for j in 0..4 {
                    dense[(tet[i] as usize, tet[j] as usize)] += wv * op.grads[i].dot(&op.grads[j]);
                }
            }
        }
        for v in 0..n {
            dense[(v, v)] += stiffness[v];
            assert!((dense[(v, v)] - global.diagonal()[v]).abs() < 1e-12);
        }
        let b: Vec<f64> = (0..3 * n).map(|i| ((i * 37 % 11) as f64) - 5.0).collect();
        let mut x = b.clone();
        global.solve_in_place(&mut x, &mut global.scratch());
        let lu = dense.lu();
        for c in 0..3 {
            let bc = DVector::from_iterator(n, (0..n).map(|v| b[3 * v + c]));
            let xc = lu.solve(&bc).unwrap();
            for v in 0..n {
                assert!((xc[v] - x[3 * v + c]).abs() < 1e-9 * (1.0 + xc[v].abs()));
            }
        }
    }
}
