//! Benchmarks run by `facesim bench`.
pub mod contact;
pub mod contact_sweep;
pub mod editor;
pub mod extremes;
pub mod sequence;
pub mod shapes;
pub mod solver;
pub mod tradeoff;

/// The `p`-quantile of `values` (nearest rank; `values` need not be sorted, must not be
/// empty).
pub(crate) fn percentile(values: &[f64], p: f64) -> f64 {
    let mut sorted = values.to_vec();
    sorted.sort_by(f64::total_cmp);
    sorted[((sorted.len() - 1) as f64 * p).round() as usize]
}
