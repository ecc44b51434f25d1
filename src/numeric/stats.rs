//! Order statistics.

/// The upper median of `values` (the element at index `n / 2` once sorted; for an odd
/// count the median itself), or None for an empty slice. NaN sorts above every number
/// (`f64::total_cmp`). The slice is copied, not reordered.
pub fn upper_median(values: &[f64]) -> Option<f64> {
    if values.is_empty() {
        return None;
    }
    let mut v = values.to_vec();
    let mid = v.len() / 2;
    let (_, m, _) = v.select_nth_unstable_by(mid, f64::total_cmp);
    Some(*m)
}

#[cfg(test)]
mod tests {
    use super::upper_median;

    #[test]
    fn upper_median_of_odd_even_and_empty() {
        assert_eq!(upper_median(&[3.0, 1.0, 2.0]), Some(2.0));
        assert_eq!(upper_median(&[4.0, 1.0, 3.0, 2.0]), Some(3.0));
        assert_eq!(upper_median(&[]), None);
        assert_eq!(upper_median(&[f64::NAN, 1.0, 2.0]), Some(2.0));
    }
}
