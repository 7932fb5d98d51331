//! Back-off with jitter, and the seed its random numbers start from.
//!
//! Pure arithmetic: when to back off, and for how long at most, is the caller's business.

use std::time::Duration;

/// Exponential back-off from 25 ms up to `max`, with ±50% jitter so that many idle workers
/// do not poll in step.
pub(crate) fn backoff(streak: u32, max: Duration, rng: &mut u64) -> Duration {
    let base = 25u64.saturating_mul(1u64 << streak.min(16));
    let capped = base.min(max.as_millis() as u64).max(1);
    // xorshift64: jitter needs no quality, only spread.
    *rng ^= *rng << 13;
    *rng ^= *rng >> 7;
    *rng ^= *rng << 17;
    let jitter = 0.5 + (*rng % 1000) as f64 / 1000.0;
    Duration::from_millis((capped as f64 * jitter) as u64)
}

/// A seed for [`backoff`]'s generator that differs between processes and moments; odd, so
/// that it is never the generator's fixed point, zero.
pub(crate) fn seed() -> u64 {
    let t = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as u64);
    (t ^ (u64::from(std::process::id()) << 32)) | 1
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn backoff_grows_to_its_cap_with_bounded_jitter() {
        let mut rng = 12345;
        let max = Duration::from_millis(800);
        for streak in 0..40 {
            let d = backoff(streak, max, &mut rng);
            let nominal = (25u64 << streak.min(16)).min(800);
            assert!(d.as_millis() as u64 >= nominal / 2, "{streak}: {d:?}");
            assert!(d.as_millis() as u64 <= nominal * 3 / 2, "{streak}: {d:?}");
        }
    }
}
