//! Statistics of repeated measurements, shared by the pipeline's stages, the report and the bench
//! examples: the median of a set of runs and its relative spread.

/// Median; the mean of the two middle values for an even count, 0 for no values. NaN sorts last
/// (`total_cmp`).
pub fn median(v: &[f64]) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    let mut s = v.to_vec();
    s.sort_by(|a, b| a.total_cmp(b));
    let n = s.len();
    if n % 2 == 1 {
        s[n / 2]
    } else {
        0.5 * (s[n / 2 - 1] + s[n / 2])
    }
}

/// Smallest and largest value, ignoring NaN; (inf, -inf) for no values.
pub fn min_max(v: impl IntoIterator<Item = f64>) -> (f64, f64) {
    v.into_iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), x| (a.min(x), b.max(x)))
}

/// Relative spread of repeated timings: (max - min) / median. None with fewer than two runs (no
/// noise measured), a non-finite run or a median <= 0. `<name>_spread` in result rows.
pub fn spread(v: &[f64]) -> Option<f64> {
    if v.len() < 2 || v.iter().any(|x| !x.is_finite()) {
        return None;
    }
    let m = median(v);
    if m <= 0.0 {
        return None;
    }
    let (lo, hi) = min_max(v.iter().copied());
    Some((hi - lo) / m)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn medians() {
        assert_eq!(median(&[3.0, 1.0, 2.0]), 2.0);
        assert_eq!(median(&[4.0, 1.0, 2.0, 3.0]), 2.5);
        assert_eq!(median(&[]), 0.0);
    }

    #[test]
    fn spreads() {
        assert_eq!(spread(&[1.0, 2.0, 3.0]), Some(1.0));
        assert_eq!(spread(&[0.1, 0.1, 0.1, 0.1]), Some(0.0));
        // One run: no noise measured (not zero noise).
        assert_eq!(spread(&[0.5]), None);
        assert_eq!(spread(&[]), None);
        assert_eq!(spread(&[0.0, 0.0]), None);
        assert_eq!(spread(&[1.0, f64::NAN]), None);
        assert_eq!(min_max([2.0, f64::NAN, -1.0]), (-1.0, 2.0));
    }
}
