//! Summary statistics of per-frame numbers.

/// mean / median / p90 of a list (0s when empty); the quantiles by nearest rank ([`quantile`]).
pub fn stats(v: &[f64]) -> (f64, f64, f64) {
    if v.is_empty() {
        return (0.0, 0.0, 0.0);
    }
    let mut s = v.to_vec();
    s.sort_by(|a, b| a.total_cmp(b));
    let mean = s.iter().sum::<f64>() / s.len() as f64;
    (mean, quantile(&s, 0.5), quantile(&s, 0.9))
}

/// The value at quantile `q` (0..1, nearest rank) of sorted values; 0 when there are none.
pub fn quantile(sorted: &[f64], q: f64) -> f64 {
    let last = sorted.len().saturating_sub(1);
    sorted
        .get((last as f64 * q).round() as usize)
        .copied()
        .unwrap_or(0.0)
}

/// The mean, summed in the given order; 0 when empty.
pub fn mean(v: &[f64]) -> f64 {
    if v.is_empty() {
        0.0
    } else {
        v.iter().sum::<f64>() / v.len() as f64
    }
}

/// The median (the upper one of an even count, as [`quantile`] 0.5); 0 when empty.
pub fn median(v: &[f64]) -> f64 {
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    quantile(&s, 0.5)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn empty_lists_give_zeros() {
        assert_eq!(stats(&[]), (0.0, 0.0, 0.0));
        assert_eq!(quantile(&[], 0.9), 0.0);
        assert_eq!(mean(&[]), 0.0);
        assert_eq!(median(&[]), 0.0);
    }

    #[test]
    fn quantiles_take_the_nearest_rank() {
        let sorted: Vec<f64> = (0..20).map(f64::from).collect();
        // rank round(19 * q)
        assert_eq!(quantile(&sorted, 0.0), 0.0);
        assert_eq!(quantile(&sorted, 0.5), 10.0);
        assert_eq!(quantile(&sorted, 0.9), 17.0);
        assert_eq!(quantile(&sorted, 0.95), 18.0);
        assert_eq!(quantile(&sorted, 1.0), 19.0);
    }

    #[test]
    fn median_is_the_upper_middle_of_an_even_count() {
        assert_eq!(median(&[4.0, 1.0, 3.0, 2.0]), 3.0);
        assert_eq!(median(&[5.0, 1.0, 3.0]), 3.0);
        // the same element for every length
        for n in 1..30 {
            let v: Vec<f64> = (0..n).rev().map(f64::from).collect();
            assert_eq!(median(&v), f64::from(n / 2), "n = {n}");
        }
    }

    #[test]
    fn stats_sort_before_ranking() {
        let (mean, median, p90) = stats(&[9.0, 0.0, 1.0, 8.0, 2.0, 7.0, 3.0, 6.0, 4.0, 5.0]);
        assert_eq!((mean, median, p90), (4.5, 5.0, 8.0));
    }
}
