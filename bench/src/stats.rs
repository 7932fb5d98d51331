//! Summaries of repeated measurements, shared by the benchmarks: the median of a set of
//! timings, and the median and range of the ratios of back-to-back pairs (on a machine whose
//! speed drifts from minute to minute, two runs made back to back see the same machine, so
//! their ratio moves less than the ratio of two separate medians).
//!
//! Not a statistics library: no means, no confidence intervals.

/// The median; of an even count, the upper of the two middle values.
pub fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// Median and extremes of a set of ratios (at least one).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Spread {
    pub median: f64,
    pub lo: f64,
    pub hi: f64,
    pub count: usize,
}

impl Spread {
    pub fn of(mut v: Vec<f64>) -> Spread {
        v.sort_by(f64::total_cmp);
        Spread {
            median: v[v.len() / 2],
            lo: v[0],
            hi: v[v.len() - 1],
            count: v.len(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn median_of_odd_and_even_counts() {
        assert_eq!(median(vec![3.0, 1.0, 2.0]), 2.0);
        assert_eq!(median(vec![4.0, 1.0, 3.0, 2.0]), 3.0);
    }

    #[test]
    fn spread_is_median_and_extremes_in_any_order() {
        let s = Spread::of(vec![1.3, 0.9, 1.1, 2.0]);
        assert_eq!((s.median, s.lo, s.hi, s.count), (1.3, 0.9, 2.0, 4));
    }
}
