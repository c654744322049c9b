//! A reusable, contiguous column-major matrix buffer and the batched kernels built on it.
//!
//! Batches are stored "points as rows": an `N × w` matrix whose column `j` (feature `j` of
//! every point) is one contiguous slice, so per-feature work (bias, activation) runs over long
//! contiguous slices and dense layers are single matrix products (faer).
//!
//! Determinism: element-wise kernels are independent per element, so any partition gives the
//! same bits; reductions ([`col_sums_into`]) use a fixed summation order that does not depend
//! on the thread count.

use faer::linalg::matmul::matmul;
use faer::{Accum, MatMut, MatRef, Par};
use rayon::prelude::*;

use super::real::Real;

/// A column-major `rows × cols` matrix in one contiguous `Vec`, resized in place so that a
/// buffer reused across iterations allocates only when it grows.
#[derive(Clone, Debug, Default)]
pub(crate) struct Buf<T> {
    data: Vec<T>,
    rows: usize,
    cols: usize,
}

impl<T: Real> Buf<T> {
    /// Sets the shape; existing contents become unspecified (callers overwrite them).
    pub fn reshape(&mut self, rows: usize, cols: usize) {
        self.rows = rows;
        self.cols = cols;
        self.data.resize(rows * cols, T::ZERO);
    }

    /// Sets the shape and fills with zeros.
    pub fn reshape_zeroed(&mut self, rows: usize, cols: usize) {
        self.reshape(rows, cols);
        self.data.fill(T::ZERO);
    }

    pub fn rows(&self) -> usize {
        self.rows
    }

    pub fn cols(&self) -> usize {
        self.cols
    }

    pub fn as_slice(&self) -> &[T] {
        &self.data[..self.rows * self.cols]
    }

    pub fn as_mut_slice(&mut self) -> &mut [T] {
        let n = self.rows * self.cols;
        &mut self.data[..n]
    }

    pub fn col(&self, j: usize) -> &[T] {
        &self.data[j * self.rows..(j + 1) * self.rows]
    }

    pub fn col_mut(&mut self, j: usize) -> &mut [T] {
        let r = self.rows;
        &mut self.data[j * r..(j + 1) * r]
    }

    pub fn view(&self) -> MatRef<'_, T> {
        MatRef::from_column_major_slice(self.as_slice(), self.rows, self.cols)
    }

    pub fn view_mut(&mut self) -> MatMut<'_, T> {
        let (r, c) = (self.rows, self.cols);
        MatMut::from_column_major_slice_mut(self.as_mut_slice(), r, c)
    }

    /// Copies `src` (any strides) into this buffer.
    pub fn copy_from(&mut self, src: MatRef<'_, T>) {
        self.reshape(src.nrows(), src.ncols());
        for j in 0..src.ncols() {
            let col = self.col_mut(j);
            for (i, v) in col.iter_mut().enumerate() {
                *v = src[(i, j)];
            }
        }
    }

    /// Bytes held (capacity), for memory reports.
    pub fn bytes(&self) -> usize {
        self.data.capacity() * std::mem::size_of::<T>()
    }
}

/// `dst (+)= lhs · rhs` with faer.
pub(crate) fn matmul_into<T: Real>(
    dst: MatMut<'_, T>,
    accumulate: bool,
    lhs: MatRef<'_, T>,
    rhs: MatRef<'_, T>,
    par: Par,
) {
    let accum = if accumulate {
        Accum::Add
    } else {
        Accum::Replace
    };
    matmul(dst, accum, lhs, rhs, T::ONE, par);
}

/// Number of worker chunks for element-wise kernels under `par`.
pub(crate) fn n_tasks(par: Par) -> usize {
    match par {
        Par::Seq => 1,
        Par::Rayon(n) => n.get(),
    }
}

/// Runs `f(j, col_j)` over every column of `a`, split into at most `n_tasks(par)` contiguous
/// groups of columns run in parallel.
pub(crate) fn for_cols<T: Real, F>(par: Par, a: &mut Buf<T>, f: F)
where
    F: Fn(usize, &mut [T]) + Sync,
{
    let (rows, cols) = (a.rows, a.cols);
    if rows == 0 || cols == 0 {
        return;
    }
    let tasks = n_tasks(par).min(cols);
    let per = cols.div_ceil(tasks);
    let data = a.as_mut_slice();
    if tasks <= 1 {
        for (j, c) in data.chunks_mut(rows).enumerate() {
            f(j, c);
        }
        return;
    }
    data.par_chunks_mut(rows * per)
        .enumerate()
        .for_each(|(g, group)| {
            for (jj, c) in group.chunks_mut(rows).enumerate() {
                f(g * per + jj, c);
            }
        });
}

/// Like [`for_cols`] over two buffers with the same number of columns (row counts may
/// differ): `f(j, a_j, b_j)`.
pub(crate) fn for_cols2<T: Real, F>(par: Par, a: &mut Buf<T>, b: &mut Buf<T>, f: F)
where
    F: Fn(usize, &mut [T], &mut [T]) + Sync,
{
    assert_eq!(a.cols, b.cols);
    let (ra, rb, cols) = (a.rows, b.rows, a.cols);
    if cols == 0 {
        return;
    }
    let tasks = n_tasks(par).min(cols);
    let per = cols.div_ceil(tasks);
    let run = |g: usize, ga: &mut [T], gb: &mut [T]| {
        let ca = ga.chunks_mut(ra.max(1));
        let cb = gb.chunks_mut(rb.max(1));
        for (jj, (x, y)) in ca.zip(cb).enumerate() {
            f(g * per + jj, x, y);
        }
    };
    if ra == 0 || rb == 0 {
        // Degenerate: pass empty slices column by column.
        for j in 0..cols {
            f(j, &mut [], &mut []);
        }
        return;
    }
    let (da, db) = (a.as_mut_slice(), b.as_mut_slice());
    if tasks <= 1 {
        run(0, da, db);
        return;
    }
    da.par_chunks_mut(ra * per)
        .zip(db.par_chunks_mut(rb * per))
        .enumerate()
        .for_each(|(g, (ga, gb))| run(g, ga, gb));
}

/// Like [`for_cols`] over three buffers with the same number of columns.
pub(crate) fn for_cols3<T: Real, F>(par: Par, a: &mut Buf<T>, b: &mut Buf<T>, c: &mut Buf<T>, f: F)
where
    F: Fn(usize, &mut [T], &mut [T], &mut [T]) + Sync,
{
    assert!(a.cols == b.cols && a.cols == c.cols);
    let (ra, rb, rc, cols) = (a.rows, b.rows, c.rows, a.cols);
    if cols == 0 {
        return;
    }
    if ra == 0 || rb == 0 || rc == 0 {
        for j in 0..cols {
            f(j, &mut [], &mut [], &mut []);
        }
        return;
    }
    let tasks = n_tasks(par).min(cols);
    let per = cols.div_ceil(tasks);
    let run = |g: usize, ga: &mut [T], gb: &mut [T], gc: &mut [T]| {
        let it = ga
            .chunks_mut(ra)
            .zip(gb.chunks_mut(rb))
            .zip(gc.chunks_mut(rc));
        for (jj, ((x, y), z)) in it.enumerate() {
            f(g * per + jj, x, y, z);
        }
    };
    let (da, db, dc) = (a.as_mut_slice(), b.as_mut_slice(), c.as_mut_slice());
    if tasks <= 1 {
        run(0, da, db, dc);
        return;
    }
    da.par_chunks_mut(ra * per)
        .zip(db.par_chunks_mut(rb * per))
        .zip(dc.par_chunks_mut(rc * per))
        .enumerate()
        .for_each(|(g, ((ga, gb), gc))| run(g, ga, gb, gc));
}

/// Σᵢ xᵢ in a fixed order: 8 interleaved partial sums (lane `i mod 8`), then the tail, then
/// the partials pairwise. Vectorizes, and gives the same bits on every call.
#[inline]
pub(crate) fn sum<T: Real>(x: &[T]) -> T {
    let mut acc = [T::ZERO; 8];
    let chunks = x.chunks_exact(8);
    let tail = chunks.remainder();
    for c in chunks {
        for l in 0..8 {
            acc[l] += c[l];
        }
    }
    let mut t = T::ZERO;
    for &v in tail {
        t += v;
    }
    ((acc[0] + acc[4]) + (acc[2] + acc[6])) + ((acc[1] + acc[5]) + (acc[3] + acc[7])) + t
}

/// Column sums of `a` over the row range `rows` into `out[j]` (overwrites).
pub(crate) fn col_sums_into<T: Real>(a: &Buf<T>, rows: std::ops::Range<usize>, out: &mut [T]) {
    debug_assert_eq!(out.len(), a.cols());
    for (j, o) in out.iter_mut().enumerate() {
        *o = sum(&a.col(j)[rows.clone()]);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fixed_order_sum_matches_naive_sum_closely() {
        let x: Vec<f64> = (0..1003)
            .map(|i| ((i * 37 % 101) as f64 - 50.0) * 0.013)
            .collect();
        let naive: f64 = x.iter().sum();
        assert!((sum(&x) - naive).abs() < 1e-12);
    }

    #[test]
    fn for_cols_visits_each_column_once_in_any_partition() {
        for threads in [1usize, 2, 3] {
            let mut b = Buf::<f64>::default();
            b.reshape_zeroed(4, 5);
            let par = if threads == 1 {
                Par::Seq
            } else {
                Par::rayon(threads)
            };
            for_cols(par, &mut b, |j, c| {
                for v in c.iter_mut() {
                    *v += j as f64;
                }
            });
            for j in 0..5 {
                assert!(b.col(j).iter().all(|&v| v == j as f64));
            }
        }
    }
}
