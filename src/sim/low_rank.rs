//! Curvature the prefactored PD matrix `L` lacks, brought into every step as a low-rank
//! update, so `L` is not refactored (unless the update has so many columns that a sparse
//! factorization of `L + K` is cheaper: the solver's `REFACTOR_COLUMNS_PER_VERTEX`).
//!
//! Two terms of the energy are stiff where `L` knows nothing about them: the contact barrier
//! (on the few simulation vertices under active pairs) and the volume barrier (on the few
//! elements close to folding). Both are written as `K = U·Uᵀ` with sparse factor columns `U` (a
//! column touches a handful of vertices: one per kept eigenvalue of a contact stencil's
//! Hessian, one per element near folding), and the step's initial inverse
//! Hessian is, by Woodbury,
//!
//! `(L + U·Uᵀ)⁻¹ = L⁻¹ − L⁻¹U·S⁻¹·UᵀL⁻¹`,  `S = I + UᵀL⁻¹U`,
//!
//! with `S` symmetric positive definite (a Cholesky factor, no pivoting). `UᵀL⁻¹U` is read
//! from single columns of `L⁻¹` ([`InverseColumns`]), computed once per vertex and kept for
//! the simulator's life, since `L` never changes. Each step then costs two solves with `L`
//! and the Cholesky factor of the `r × r` matrix `S` (`r` = columns), rebuilt with `K`.

use std::collections::HashMap;
use std::sync::{Arc, Mutex};

use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::solvers::{Llt, Solve};
use faer::sparse::linalg::cholesky::{
    CholeskySymbolicParams, LltRef, SymbolicCholesky, SymmetricOrdering,
    factorize_symbolic_cholesky,
};
use faer::sparse::{SparseColMat, Triplet};
use faer::{Conj, Mat, Par, Side};
use nalgebra::Vector3;
use rayon::prelude::*;

use super::contact::ContactStep;
use super::global_matrix::{GlobalMatrix, SolveScratch};

/// Cache budget for columns of `L⁻¹` (bytes). A coarse face's whole inverse fits many
/// times over; on a fine face the cache is cleared when full (columns are recomputed on
/// demand, so this bounds memory, not correctness).
const COLUMN_CACHE_BYTES: usize = 256 << 20;

/// Columns of `L⁻¹` for single vertices (`L` acts on each coordinate alike, so one scalar
/// column serves all three), computed on demand.
#[derive(Default)]
pub(crate) struct InverseColumns {
    columns: Mutex<HashMap<u32, Arc<[f64]>>>,
}

impl InverseColumns {
    /// The columns of `vertices`, computing the missing ones three per solve (one per
    /// coordinate of one right-hand side).
    pub(crate) fn get(&self, global: &GlobalMatrix, vertices: &[u32]) -> Vec<Arc<[f64]>> {
        let n = global.dimension();
        let mut cache = self.columns.lock().unwrap_or_else(|e| e.into_inner());
        let mut missing: Vec<u32> = vertices
            .iter()
            .copied()
            .filter(|v| !cache.contains_key(v))
            .collect();
        missing.sort_unstable();
        missing.dedup();
        if (cache.len() + missing.len()) * n * 8 > COLUMN_CACHE_BYTES {
            cache.retain(|v, _| vertices.contains(v));
        }
        let mut scratch = global.scratch();
        let mut rhs = vec![0.0; 3 * n];
        for chunk in missing.chunks(3) {
            rhs.fill(0.0);
            for (k, &v) in chunk.iter().enumerate() {
                rhs[3 * v as usize + k] = 1.0;
            }
            global.solve_in_place(&mut rhs, &mut scratch);
            for (k, &v) in chunk.iter().enumerate() {
                let column: Arc<[f64]> = (0..n).map(|w| rhs[3 * w + k]).collect();
                cache.insert(v, column);
            }
        }
        vertices.iter().map(|v| cache[v].clone()).collect()
    }

    /// How many columns are cached.
    #[cfg(test)]
    pub(crate) fn len(&self) -> usize {
        self.columns.lock().unwrap_or_else(|e| e.into_inner()).len()
    }
}

/// A sparse column of `U`: a 3-vector at each of a few vertices.
pub(crate) type SparseColumn = Vec<(u32, Vector3<f64>)>;

/// `K = U·Uᵀ = Σₚ uₚuₚᵀ`: the extra curvature of one step, as sparse factor columns.
#[derive(Clone, Debug, Default)]
pub(crate) struct Curvature {
    pub(crate) columns: Vec<SparseColumn>,
}

impl Curvature {
    pub(crate) fn is_empty(&self) -> bool {
        self.columns.is_empty()
    }

    /// Factor columns `uₚ` as they are (`K = Σ uₚuₚᵀ`).
    pub(crate) fn from_columns(columns: Vec<SparseColumn>) -> Self {
        Self { columns }
    }

    /// Rank-one terms `cᵢ·uᵢ·uᵢᵀ` (`cᵢ ≥ 0`), stored as `√cᵢ·uᵢ`.
    pub(crate) fn from_rank_one(terms: Vec<(f64, SparseColumn)>) -> Self {
        let columns = terms
            .into_iter()
            .filter(|(c, _)| *c > 0.0)
            .map(|(c, col)| col.into_iter().map(|(v, a)| (v, c.sqrt() * a)).collect())
            .collect();
        Self { columns }
    }

    /// `K₁ + K₂`: the columns side by side.
    pub(crate) fn plus(mut self, other: Curvature) -> Curvature {
        self.columns.extend(other.columns);
        self
    }

    /// Every simulation vertex a column touches, sorted, once each.
    pub(crate) fn vertices(&self) -> Vec<u32> {
        let mut v: Vec<u32> = self.columns.iter().flatten().map(|e| e.0).collect();
        v.sort_unstable();
        v.dedup();
        v
    }

    /// `K`'s entries over the whole `3n` system, lower triangle (`row ≥ col`), duplicates
    /// left to be summed: for assembling `L⊗I₃ + K` directly.
    pub(crate) fn lower_triplets(&self) -> Vec<(usize, usize, f64)> {
        let mut out = Vec::new();
        for col in &self.columns {
            for &(v, a) in col {
                for &(w, b) in col {
                    for i in 0..3 {
                        for j in 0..3 {
                            let (gi, gj) = (3 * v as usize + i, 3 * w as usize + j);
                            let value = a[i] * b[j];
                            if gi >= gj && value != 0.0 {
                                out.push((gi, gj, value));
                            }
                        }
                    }
                }
            }
        }
        out
    }

    /// `Uᵀ·z` for a full-length `z`.
    fn project(&self, z: &[f64]) -> Mat<f64> {
        Mat::from_fn(self.columns.len(), 1, |p, _| {
            self.columns[p]
                .iter()
                .map(|&(v, a)| {
                    let i = 3 * v as usize;
                    a.x * z[i] + a.y * z[i + 1] + a.z * z[i + 2]
                })
                .sum::<f64>()
        })
    }
}

/// `(L + K)⁻¹` applied by Woodbury (module doc).
pub(crate) struct LowRankInverse {
    curvature: Curvature,
    /// Cholesky factor of `S = I + UᵀL⁻¹U` (symmetric positive definite).
    s: Llt<f64>,
}

impl LowRankInverse {
    pub(crate) fn new(
        global: &GlobalMatrix,
        columns: &InverseColumns,
        curvature: Curvature,
    ) -> Result<Self, String> {
        let vertices = curvature.vertices();
        let inverse = columns.get(global, &vertices);
        let mut slot = vec![u32::MAX; global.dimension()];
        for (i, &v) in vertices.iter().enumerate() {
            slot[v as usize] = i as u32;
        }
        // The columns with their entries' slots among the touched vertices.
        let slotted: Vec<Vec<(usize, Vector3<f64>)>> = curvature
            .columns
            .iter()
            .map(|col| {
                col.iter()
                    .map(|&(v, a)| (slot[v as usize] as usize, a))
                    .collect()
            })
            .collect();
        // zₚ = (L⁻¹uₚ) at the touched vertices, one 3-vector each: zₚ[w] = Σ over entries
        // (v, a) of uₚ of (L⁻¹)ᵥw·a (L acts on each coordinate alike). Then
        // (UᵀL⁻¹U)ₚq = Σ over entries (w, b) of u_q of ⟨zₚ[w], b⟩: r·(entries·3a + r·entries)
        // operations, not r²·entries².
        let a = vertices.len();
        let z: Vec<Vec<Vector3<f64>>> = slotted
            .par_iter()
            .map(|col| {
                let mut zp = vec![Vector3::zeros(); a];
                for &(sv, av) in col {
                    let column = &inverse[sv];
                    for (zw, &w) in zp.iter_mut().zip(&vertices) {
                        *zw += column[w as usize] * av;
                    }
                }
                zp
            })
            .collect();
        let r = slotted.len();
        let mut s = Mat::<f64>::identity(r, r);
        for p in 0..r {
            for q in 0..=p {
                let m: f64 = slotted[q].iter().map(|&(sw, b)| z[p][sw].dot(&b)).sum();
                s[(p, q)] += m;
            }
        }
        let s = s
            .llt(Side::Lower)
            .map_err(|e| format!("I + UᵀL⁻¹U is not positive definite: {e:?}"))?;
        Ok(Self { curvature, s })
    }

    /// `d ← (L + K)⁻¹·d`.
    pub(crate) fn apply(&self, global: &GlobalMatrix, d: &mut [f64], scratch: &mut SolveScratch) {
        global.solve_in_place(d, scratch);
        let mut w = self.curvature.project(d);
        self.s.solve_in_place(w.as_mut());
        let mut back = vec![0.0; d.len()];
        for (p, col) in self.curvature.columns.iter().enumerate() {
            let wp = w[(p, 0)];
            for &(v, a) in col {
                let i = 3 * v as usize;
                back[i] += wp * a.x;
                back[i + 1] += wp * a.y;
                back[i + 2] += wp * a.z;
            }
        }
        global.solve_in_place(&mut back, scratch);
        for (di, bi) in d.iter_mut().zip(&back) {
            *di -= bi;
        }
    }
}

/// `L⊗I₃ + K`'s sparse Cholesky factor.
pub(crate) struct Refactored {
    symbolic: SymbolicCholesky<usize>,
    values: Vec<f64>,
}

/// The initial inverse Hessian `H₀` of one step.
pub(crate) enum StepInverse {
    /// No extra curvature: `L⁻¹`.
    Plain,
    /// `(L + K)⁻¹` by Woodbury.
    LowRank(LowRankInverse),
    /// `L⊗I₃ + K` assembled and factored from scratch: the reference the low-rank update is
    /// measured against (`facesim bench contact`).
    Refactored(Box<Refactored>),
}

impl StepInverse {
    pub(crate) fn new(
        global: &GlobalMatrix,
        columns: &InverseColumns,
        curvature: Curvature,
        mode: ContactStep,
    ) -> Result<Self, String> {
        if curvature.is_empty() {
            return Ok(Self::Plain);
        }
        Ok(match mode {
            ContactStep::LowRankUpdate => {
                Self::LowRank(LowRankInverse::new(global, columns, curvature)?)
            }
            ContactStep::Refactor => {
                let lower = global.lower_entries();
                let mut triplets: Vec<Triplet<usize, usize, f64>> = lower
                    .iter()
                    .flat_map(|e| {
                        (0..3).map(move |c| Triplet::new(3 * e.row + c, 3 * e.col + c, e.val))
                    })
                    .collect();
                triplets.extend(
                    curvature
                        .lower_triplets()
                        .into_iter()
                        .map(|(i, j, v)| Triplet::new(i, j, v)),
                );
                let (symbolic, values) = factor_triplets(3 * global.dimension(), &triplets)
                    .map_err(|e| format!("factoring L + K failed: {e}"))?;
                Self::Refactored(Box::new(Refactored { symbolic, values }))
            }
        })
    }

    /// `d ← H₀·d`.
    pub(crate) fn apply(&self, global: &GlobalMatrix, d: &mut [f64], scratch: &mut SolveScratch) {
        match self {
            Self::Plain => global.solve_in_place(d, scratch),
            Self::LowRank(inverse) => inverse.apply(global, d, scratch),
            Self::Refactored(factor) => {
                let Refactored { symbolic, values } = factor.as_ref();
                let mut rhs = Mat::<f64>::zeros(d.len(), 1);
                for (i, &v) in d.iter().enumerate() {
                    rhs[(i, 0)] = v;
                }
                let mut stack = MemBuffer::new(symbolic.solve_in_place_scratch::<f64>(1, Par::Seq));
                LltRef::new(symbolic, values).solve_in_place_with_conj(
                    Conj::No,
                    rhs.as_mut(),
                    Par::Seq,
                    MemStack::new(&mut stack),
                );
                for (i, v) in d.iter_mut().enumerate() {
                    *v = rhs[(i, 0)];
                }
            }
        }
    }
}

/// Factors a lower-triangle `dim × dim` matrix given as triplets (symbolic and numeric).
pub(crate) fn factor_triplets(
    dim: usize,
    triplets: &[Triplet<usize, usize, f64>],
) -> Result<
    (
        faer::sparse::linalg::cholesky::SymbolicCholesky<usize>,
        Vec<f64>,
    ),
    String,
> {
    let matrix = SparseColMat::<usize, f64>::try_new_from_triplets(dim, dim, triplets)
        .map_err(|e| format!("{e:?}"))?;
    let symbolic = factorize_symbolic_cholesky(
        matrix.symbolic(),
        Side::Lower,
        SymmetricOrdering::Amd,
        CholeskySymbolicParams::default(),
    )
    .map_err(|e| format!("{e:?}"))?;
    let mut values = vec![0.0; symbolic.len_val()];
    let mut stack =
        MemBuffer::new(symbolic.factorize_numeric_llt_scratch::<f64>(Par::Seq, Default::default()));
    symbolic
        .factorize_numeric_llt(
            &mut values,
            matrix.as_ref(),
            Side::Lower,
            Default::default(),
            Par::Seq,
            MemStack::new(&mut stack),
            Default::default(),
        )
        .map_err(|e| format!("{e:?}"))?;
    Ok((symbolic, values))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::global_matrix::GlobalMatrix;

    /// `(L + K)·((L + K)⁻¹·b) = b` for contact-like factor columns (a stencil's columns
    /// spread over the vertices of two tetrahedra) plus rank-one terms that share vertices
    /// with them, on a real mesh's `L`.
    #[test]
    fn the_low_rank_inverse_solves_l_plus_k() {
        let sim = crate::sim::tests::small_simulator();
        let global: &GlobalMatrix = &sim.global;
        let n = global.dimension();
        let stencil_columns: Vec<SparseColumn> = (0..3)
            .map(|k| {
                [3u32, 7, 8, 7]
                    .iter()
                    .enumerate()
                    .map(|(i, &v)| {
                        let f = |j: usize| (((i + 2 * k) * 7 + j * 3) % 5) as f64 - 2.0;
                        (v, 3.0 * Vector3::new(f(0), f(1), f(2)))
                    })
                    .collect()
            })
            .collect();
        let rank_one = vec![
            (
                50.0,
                vec![
                    (7u32, Vector3::new(1.0, -2.0, 0.5)),
                    (11, Vector3::new(0.0, 1.0, 1.0)),
                ],
            ),
            (0.0, vec![(2u32, Vector3::new(1.0, 1.0, 1.0))]),
            (3e4, vec![(n as u32 - 1, Vector3::new(0.3, 0.0, -1.0))]),
        ];
        let curvature =
            Curvature::from_columns(stencil_columns).plus(Curvature::from_rank_one(rank_one));
        assert_eq!(
            curvature.columns.len(),
            5,
            "the zero-weight term adds no column"
        );
        let columns = InverseColumns::default();
        let inverse = LowRankInverse::new(global, &columns, curvature.clone()).unwrap();
        assert_eq!(columns.len(), curvature.vertices().len());
        let rhs: Vec<f64> = (0..3 * n).map(|i| ((i * 13) % 7) as f64 - 3.0).collect();
        let mut x = rhs.clone();
        let mut scratch = global.scratch();
        inverse.apply(global, &mut x, &mut scratch);
        // (L⊗I₃ + K)·x, with L from its lower triangle and K from its triplets.
        let mut lx = vec![0.0; 3 * n];
        let mut add = |i: usize, j: usize, v: f64| {
            lx[i] += v * x[j];
            if i != j {
                lx[j] += v * x[i];
            }
        };
        for e in global.lower_entries() {
            for c in 0..3 {
                add(3 * e.row + c, 3 * e.col + c, e.val);
            }
        }
        for (i, j, v) in curvature.lower_triplets() {
            add(i, j, v);
        }
        let err = lx
            .iter()
            .zip(&rhs)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        assert!(err < 1e-8, "residual {err}");
    }
}
