//! Summaries of measured samples (timings, errors): the median and quantiles the benchmarks,
//! the training runs and the CLI report.

/// The median of `values` (the mean of the two middle ones for an even count; NaN when
/// there are none, so an empty measurement never reads as a time of 0).
pub fn median(values: &[f64]) -> f64 {
    let mut sorted = values.to_vec();
    sorted.sort_by(f64::total_cmp);
    let n = sorted.len();
    match n {
        0 => f64::NAN,
        _ if n % 2 == 1 => sorted[n / 2],
        _ => 0.5 * (sorted[n / 2 - 1] + sorted[n / 2]),
    }
}

/// The `p`-quantile of `values` (nearest rank; `values` need not be sorted, must not be
/// empty).
pub fn percentile(values: &[f64], p: f64) -> f64 {
    let mut sorted = values.to_vec();
    sorted.sort_by(f64::total_cmp);
    sorted[((sorted.len() - 1) as f64 * p).round() as usize]
}

#[cfg(test)]
mod tests {
    use super::{median, percentile};

    #[test]
    fn median_takes_the_middle_or_the_mean_of_the_two_and_is_nan_for_nothing() {
        assert_eq!(median(&[3.0, 1.0, 2.0]), 2.0);
        assert_eq!(median(&[4.0, 1.0, 3.0, 2.0]), 2.5);
        assert!(median(&[]).is_nan());
        assert_eq!(percentile(&[4.0, 1.0, 3.0, 2.0, 5.0], 0.5), 3.0);
    }
}
