//! Summary statistics of measurements: the one median every timing in biscale reports (the
//! CPU stages, the GPU passes, the viewer's frame times), so that CPU and GPU figures are
//! comparable.

/// The median of `samples`: the middle value, or the mean of the two middle values for an
/// even count; NaN for no samples. NaNs sort last (`f64::total_cmp`).
pub fn median(samples: &[f64]) -> f64 {
    if samples.is_empty() {
        return f64::NAN;
    }
    let mut s = samples.to_vec();
    s.sort_by(f64::total_cmp);
    let n = s.len();
    if n % 2 == 1 {
        s[n / 2]
    } else {
        0.5 * (s[n / 2 - 1] + s[n / 2])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn median_of_odd_even_and_empty() {
        assert_eq!(median(&[3.0, 1.0, 2.0]), 2.0);
        assert_eq!(median(&[4.0, 1.0, 3.0, 2.0]), 2.5);
        assert_eq!(median(&[7.0]), 7.0);
        assert!(median(&[]).is_nan());
        // NaN sorts last: it is the median only when it is in the upper half's middle.
        assert_eq!(median(&[1.0, f64::NAN, 2.0]), 2.0);
    }
}
