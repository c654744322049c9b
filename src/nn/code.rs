//! Codes that modulate a network: the activation code z concatenated to the input of every
//! layer with `takes_code` (N_A's modulation by the tanh-bounded z).
//!
//! A batch holds G codes; code g applies to a contiguous run of points. Because a code is the
//! same for all points of its run, its contribution W_z·z_g is folded into the layer bias for
//! that run (no per-point work), and its gradient is W̃_zᵀ Σ_{points of g} ∂L/∂(pre-activation).

use std::ops::Range;

use super::error::NnError;
use super::real::Real;

/// G codes of one dimension, each covering a contiguous run of the batch's points.
#[derive(Clone, Debug, PartialEq)]
pub struct CodeBatch<T> {
    dim: usize,
    /// G × dim, row-major.
    values: Vec<T>,
    /// Points per code, in batch order; `None`: a single code for every point.
    counts: Option<Vec<usize>>,
}

impl<T: Real> CodeBatch<T> {
    /// One code for every point of the batch.
    pub fn shared(code: &[T]) -> Self {
        CodeBatch {
            dim: code.len(),
            values: code.to_vec(),
            counts: None,
        }
    }

    /// `counts.len()` codes (`values` row-major, `counts.len() × dim`); code g applies to the
    /// next `counts[g]` points.
    pub fn segments(dim: usize, values: Vec<T>, counts: Vec<usize>) -> Result<Self, NnError> {
        if dim == 0 {
            return Err(NnError::CodeBatch("code dimension 0".into()));
        }
        if values.len() != dim * counts.len() {
            return Err(NnError::CodeBatch(format!(
                "{} values for {} codes of dimension {dim}",
                values.len(),
                counts.len()
            )));
        }
        Ok(CodeBatch {
            dim,
            values,
            counts: Some(counts),
        })
    }

    pub fn dim(&self) -> usize {
        self.dim
    }

    /// Number of codes G.
    pub fn len(&self) -> usize {
        self.counts.as_ref().map_or(1, Vec::len)
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Code g.
    pub fn code(&self, g: usize) -> &[T] {
        &self.values[g * self.dim..(g + 1) * self.dim]
    }

    /// All codes, row-major G × dim.
    pub fn values(&self) -> &[T] {
        &self.values
    }

    /// The codes of the points `rows` of an `n`-point batch, and the index of the first of
    /// them in this batch (codes g₀.. of the result are codes g₀ + i here).
    pub(crate) fn slice(&self, n: usize, rows: Range<usize>) -> Result<(Self, usize), NnError> {
        if self.counts.is_none() {
            return Ok((self.clone(), 0));
        }
        let ranges = self.ranges(n)?;
        let mut first = None;
        let mut counts = Vec::new();
        let mut values = Vec::new();
        for (g, r) in ranges.iter().enumerate() {
            let (lo, hi) = (r.start.max(rows.start), r.end.min(rows.end));
            // Keep empty runs between kept ones so code indices stay contiguous.
            if lo < hi || (first.is_some() && r.start < rows.end) {
                first.get_or_insert(g);
                counts.push(hi.saturating_sub(lo));
                values.extend_from_slice(self.code(g));
            }
        }
        let first = first.unwrap_or(0);
        Ok((CodeBatch::segments(self.dim, values, counts)?, first))
    }

    /// The point ranges of the codes for a batch of `n` points.
    pub(crate) fn ranges(&self, n: usize) -> Result<Vec<Range<usize>>, NnError> {
        match &self.counts {
            None => Ok(std::iter::once(0..n).collect()),
            Some(counts) => {
                let total: usize = counts.iter().sum();
                if total != n {
                    return Err(NnError::CodeBatch(format!(
                        "code runs cover {total} points, the batch has {n}"
                    )));
                }
                let mut start = 0;
                Ok(counts
                    .iter()
                    .map(|&c| {
                        start += c;
                        start - c..start
                    })
                    .collect())
            }
        }
    }
}
