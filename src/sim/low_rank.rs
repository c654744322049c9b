//! Curvature the prefactored PD matrix `L` lacks, brought into every step as a low-rank
//! update, so `L` is never refactored.
//!
//! Two terms of the energy are stiff where `L` knows nothing about them: the contact barrier
//! (on the few simulation vertices under active pairs) and the volume barrier (on the few
//! elements close to folding). Both are written as `K = U·C·Uᵀ` with sparse columns `U` (a
//! column touches a handful of vertices) and a small PSD `C`, and the step's initial inverse
//! Hessian is, by Woodbury,
//!
//! `(L + U·C·Uᵀ)⁻¹ = L⁻¹ − L⁻¹U·S⁻¹·C·UᵀL⁻¹`,  `S = I + C·(UᵀL⁻¹U)`,
//!
//! a form that needs no inverse of `C` (the contact block is often singular). `UᵀL⁻¹U` is read
//! from single columns of `L⁻¹` ([`InverseColumns`]), computed once per vertex and kept for
//! the simulator's life, since `L` never changes. Each step then costs two solves with `L`
//! and a dense LU of the `r × r` matrix `S` (`r` = columns).

use std::collections::HashMap;
use std::sync::{Arc, Mutex};

use faer::dyn_stack::{MemBuffer, MemStack};
use faer::sparse::linalg::cholesky::{
    CholeskySymbolicParams, LltRef, SymbolicCholesky, SymmetricOrdering,
    factorize_symbolic_cholesky,
};
use faer::sparse::{SparseColMat, Triplet};
use faer::{Conj, Mat, Par, Side};
use nalgebra::{DMatrix, DVector, Vector3};

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

/// `K = U·C·Uᵀ`: the extra curvature of one step.
#[derive(Clone, Debug, Default)]
pub(crate) struct Curvature {
    pub(crate) columns: Vec<SparseColumn>,
    /// `r × r`, symmetric positive semidefinite.
    pub(crate) c: DMatrix<f64>,
}

impl Curvature {
    pub(crate) fn is_empty(&self) -> bool {
        self.columns.is_empty()
    }

    /// A dense PSD block `k` (`3a × 3a`) over `vertices`: one unit column per coordinate.
    pub(crate) fn from_vertex_block(vertices: &[u32], k: DMatrix<f64>) -> Self {
        let columns = vertices
            .iter()
            .flat_map(|&v| (0..3).map(move |c| vec![(v, Vector3::ith(c, 1.0))]))
            .collect();
        Self { columns, c: k }
    }

    /// Rank-one terms `cᵢ·uᵢ·uᵢᵀ` (`cᵢ ≥ 0`).
    pub(crate) fn from_rank_one(terms: Vec<(f64, SparseColumn)>) -> Self {
        let c = DMatrix::from_diagonal(&DVector::from_iterator(
            terms.len(),
            terms.iter().map(|t| t.0),
        ));
        Self {
            columns: terms.into_iter().map(|t| t.1).collect(),
            c,
        }
    }

    /// `K₁ + K₂`: the columns side by side, `C` block-diagonal.
    pub(crate) fn plus(self, other: Curvature) -> Curvature {
        if self.is_empty() {
            return other;
        }
        if other.is_empty() {
            return self;
        }
        let (r1, r2) = (self.columns.len(), other.columns.len());
        let mut c = DMatrix::zeros(r1 + r2, r1 + r2);
        c.view_mut((0, 0), (r1, r1)).copy_from(&self.c);
        c.view_mut((r1, r1), (r2, r2)).copy_from(&other.c);
        let mut columns = self.columns;
        columns.extend(other.columns);
        Curvature { columns, c }
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
        let r = self.columns.len();
        let mut out = Vec::new();
        for p in 0..r {
            for q in 0..r {
                let cpq = self.c[(p, q)];
                if cpq == 0.0 {
                    continue;
                }
                for &(v, a) in &self.columns[p] {
                    for &(w, b) in &self.columns[q] {
                        for i in 0..3 {
                            for j in 0..3 {
                                let (gi, gj) = (3 * v as usize + i, 3 * w as usize + j);
                                let value = cpq * a[i] * b[j];
                                if gi >= gj && value != 0.0 {
                                    out.push((gi, gj, value));
                                }
                            }
                        }
                    }
                }
            }
        }
        out
    }

    /// `Uᵀ·z` for a full-length `z`.
    fn project(&self, z: &[f64]) -> DVector<f64> {
        DVector::from_iterator(
            self.columns.len(),
            self.columns.iter().map(|col| {
                col.iter()
                    .map(|&(v, a)| {
                        let i = 3 * v as usize;
                        a.x * z[i] + a.y * z[i + 1] + a.z * z[i + 2]
                    })
                    .sum::<f64>()
            }),
        )
    }
}

/// `(L + K)⁻¹` applied by Woodbury (module doc).
pub(crate) struct LowRankInverse {
    curvature: Curvature,
    /// LU of `S = I + C·(UᵀL⁻¹U)`.
    s: nalgebra::LU<f64, nalgebra::Dyn, nalgebra::Dyn>,
}

impl LowRankInverse {
    pub(crate) fn new(
        global: &GlobalMatrix,
        columns: &InverseColumns,
        curvature: Curvature,
    ) -> Self {
        let vertices = curvature.vertices();
        let inverse = columns.get(global, &vertices);
        let slot: HashMap<u32, usize> = vertices.iter().enumerate().map(|(i, &v)| (v, i)).collect();
        // Each column's entries paired with their vertex's column of L⁻¹, looked up once:
        // (UᵀL⁻¹U)ₚq = Σ over entries (v, a) of p and (w, b) of q of (L⁻¹)ᵥw·⟨a, b⟩.
        let cols: Vec<Vec<(&[f64], Vector3<f64>)>> = curvature
            .columns
            .iter()
            .map(|col| col.iter().map(|&(v, a)| (&*inverse[slot[&v]], a)).collect())
            .collect();
        let r = cols.len();
        let mut m = DMatrix::<f64>::zeros(r, r);
        for p in 0..r {
            for q in 0..=p {
                let mut sum = 0.0;
                for &(column, a) in &cols[p] {
                    for &(w, b) in &curvature.columns[q] {
                        sum += column[w as usize] * a.dot(&b);
                    }
                }
                m[(p, q)] = sum;
                m[(q, p)] = sum;
            }
        }
        let mut s = DMatrix::<f64>::identity(r, r);
        s.gemm(1.0, &curvature.c, &m, 1.0);
        Self {
            curvature,
            s: s.lu(),
        }
    }

    /// `d ← (L + K)⁻¹·d`.
    pub(crate) fn apply(&self, global: &GlobalMatrix, d: &mut [f64], scratch: &mut SolveScratch) {
        global.solve_in_place(d, scratch);
        let t = &self.curvature.c * self.curvature.project(d);
        let w = self
            .s
            .solve(&t)
            .expect("S = I + C·UᵀL⁻¹U is invertible for PSD C and SPD L");
        let mut back = vec![0.0; d.len()];
        for (col, &wp) in self.curvature.columns.iter().zip(w.iter()) {
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

/// The initial inverse Hessian `H₀` of one step.
pub(crate) enum StepInverse {
    /// No extra curvature: `L⁻¹`.
    Plain,
    /// `(L + K)⁻¹` by Woodbury.
    LowRank(LowRankInverse),
    /// `L⊗I₃ + K` assembled and factored from scratch: the reference the low-rank update is
    /// measured against (`facesim bench contact`).
    Refactored {
        symbolic: SymbolicCholesky<usize>,
        values: Vec<f64>,
    },
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
                Self::LowRank(LowRankInverse::new(global, columns, curvature))
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
                Self::Refactored { symbolic, values }
            }
        })
    }

    /// `d ← H₀·d`.
    pub(crate) fn apply(&self, global: &GlobalMatrix, d: &mut [f64], scratch: &mut SolveScratch) {
        match self {
            Self::Plain => global.solve_in_place(d, scratch),
            Self::LowRank(inverse) => inverse.apply(global, d, scratch),
            Self::Refactored { symbolic, values } => {
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

    /// `(L + K)·((L + K)⁻¹·b) = b` for a contact-like dense block plus rank-one terms that
    /// share vertices with it, on a real mesh's `L`.
    #[test]
    fn the_low_rank_inverse_solves_l_plus_k() {
        let sim = crate::sim::tests::small_simulator();
        let global: &GlobalMatrix = &sim.global;
        let n = global.dimension();
        let block_vertices = [3u32, 7, 8];
        let b = DMatrix::<f64>::from_fn(9, 9, |i, j| ((i * 7 + j * 3) % 5) as f64 - 2.0);
        let k = &b * b.transpose() * 10.0;
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
        let curvature = Curvature::from_vertex_block(&block_vertices, k)
            .plus(Curvature::from_rank_one(rank_one));
        let columns = InverseColumns::default();
        let inverse = LowRankInverse::new(global, &columns, curvature.clone());
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
