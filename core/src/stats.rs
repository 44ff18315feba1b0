//! Summary statistics of measurements: the one median every timing in biscale reports (the
//! CPU stages, the GPU passes, the viewer's frame times), so that CPU and GPU figures are
//! comparable, and the one relative L2 error every comparison reports (`L*`, images).

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

/// `sqrt(err_sq / ref_sq)`, the relative L2 error from its two sums of squares: 0 when both
/// are 0, infinite when only the reference is 0.
pub fn relative_l2(err_sq: f64, ref_sq: f64) -> f64 {
    match (err_sq == 0.0, ref_sq == 0.0) {
        (true, _) => 0.0,
        (false, true) => f64::INFINITY,
        (false, false) => (err_sq / ref_sq).sqrt(),
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

    #[test]
    fn relative_l2_of_zero_references() {
        assert_eq!(relative_l2(0.0, 0.0), 0.0);
        assert_eq!(relative_l2(1.0, 0.0), f64::INFINITY);
        assert_eq!(relative_l2(0.0, 4.0), 0.0);
        assert_eq!(relative_l2(1.0, 4.0), 0.5);
    }
}
