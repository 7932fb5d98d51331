//! What a worker says of itself to the service (`GET /workers` shows it): its threads and
//! the rays it traced per second lately ([`Meter`]), and what one tile cost ([`Cost`]).
//!
//! Not the tracing: the render threads count into these, and nothing here changes a pixel.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Mutex, PoisonError};
use std::time::{Duration, Instant};

/// The shortest span a rate is measured over: shorter, one tile's arrival would swing it.
pub(crate) const WINDOW: Duration = Duration::from_secs(2);

/// The rays one tile took and the render-thread time it took them in, added up over its
/// strips (on whichever threads rendered them).
#[derive(Debug, Default)]
pub(crate) struct Cost {
    rays: AtomicU64,
    nanos: AtomicU64,
}

impl Cost {
    /// Adds a strip's rays and time.
    pub(crate) fn add(&self, rays: u64, took: Duration) {
        self.rays.fetch_add(rays, Ordering::Relaxed);
        let nanos = u64::try_from(took.as_nanos()).unwrap_or(u64::MAX);
        self.nanos.fetch_add(nanos, Ordering::Relaxed);
    }

    /// The rays so far.
    pub(crate) fn rays(&self) -> u64 {
        self.rays.load(Ordering::Relaxed)
    }

    /// The render-thread time so far, in whole milliseconds.
    pub(crate) fn millis(&self) -> u64 {
        self.nanos.load(Ordering::Relaxed) / 1_000_000
    }
}

/// A worker's rays traced, all threads together, and its rate over the last window.
#[derive(Debug)]
pub(crate) struct Meter {
    total: AtomicU64,
    /// The last reading a rate was measured from, and the rate then (none before the first
    /// window has passed).
    last: Mutex<(Instant, u64, Option<f64>)>,
}

impl Meter {
    /// A meter at zero, starting its first window `now`.
    pub(crate) fn new(now: Instant) -> Meter {
        Meter {
            total: AtomicU64::new(0),
            last: Mutex::new((now, 0, None)),
        }
    }

    /// Counts rays traced.
    pub(crate) fn add(&self, rays: u64) {
        self.total.fetch_add(rays, Ordering::Relaxed);
    }

    /// Rays per second over the span since the last reading, once that span is at least
    /// [`WINDOW`] (a new reading starts then); until then the rate measured last, or none
    /// before the first window has passed. An idle worker's rate falls to 0.
    pub(crate) fn rate(&self, now: Instant) -> Option<f64> {
        let total = self.total.load(Ordering::Relaxed);
        let mut last = self.last.lock().unwrap_or_else(PoisonError::into_inner);
        let span = now.saturating_duration_since(last.0);
        if span >= WINDOW {
            let rays = total.saturating_sub(last.1);
            *last = (now, total, Some(rays as f64 / span.as_secs_f64()));
        }
        last.2
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_rate_is_rays_over_a_whole_window_and_falls_to_zero_when_idle() {
        let t0 = Instant::now();
        let m = Meter::new(t0);
        m.add(1_000);
        // Before a window has passed: nothing measured yet.
        assert_eq!(m.rate(t0 + WINDOW / 2), None);
        m.add(3_000);
        // 4,000 rays over 4 s.
        assert_eq!(m.rate(t0 + WINDOW * 2), Some(1_000.0));
        // Within the next window: the last rate stands.
        m.add(500);
        assert_eq!(m.rate(t0 + WINDOW * 2 + WINDOW / 2), Some(1_000.0));
        // 500 rays over the 2 s after it, then none.
        assert_eq!(m.rate(t0 + WINDOW * 3), Some(250.0));
        assert_eq!(m.rate(t0 + WINDOW * 4), Some(0.0));
    }

    #[test]
    fn a_cost_adds_up_its_strips() {
        let c = Cost::default();
        c.add(10, Duration::from_micros(1_500));
        c.add(5, Duration::from_micros(2_600));
        assert_eq!((c.rays(), c.millis()), (15, 4));
    }
}
