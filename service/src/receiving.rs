//! How much submitted body the service holds at once: one budget shared by every
//! `POST /jobs`.
//!
//! A submission is read whole, then parsed and checked (its textures decoded) before anything
//! is stored, and costs some four to five times its body while that lasts. `--max-body-bytes`
//! bounds one submission; nothing bounded how many were taken in at once (sixteen 64 MiB
//! uploads held 1.6 GB). Each submission now reserves its declared length (`Content-Length`,
//! or the whole body limit when it declares none) before any of its body is read, and keeps
//! it until it is answered. One that does not fit waits its turn (first come, first served),
//! at most [`Receiving::wait_limit`], and is then answered `503` with `Retry-After`.
//!
//! **What it is not.** It does not limit connections, nor other routes' bodies (a tile's is
//! bounded by its size), nor what a submission costs once stored.

use std::sync::Arc;
use std::time::Duration;

use tokio::sync::{OwnedSemaphorePermit, Semaphore};

/// Bytes are reserved in whole KiB: tokio's semaphore counts permits in `u32` per request.
const UNIT: usize = 1024;

/// The submission budget (see the module comment).
#[derive(Debug, Clone)]
pub struct Receiving {
    permits: Arc<Semaphore>,
    units: usize,
}

/// A submission's share of the budget, given back when dropped.
#[derive(Debug)]
pub struct Reservation {
    _room: OwnedSemaphorePermit,
}

/// The budget stayed full for as long as a submission may wait.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Full;

impl Receiving {
    /// A budget of `bytes` (rounded up to whole KiB, at least one).
    pub fn new(bytes: usize) -> Receiving {
        let units = bytes.div_ceil(UNIT).clamp(1, Semaphore::MAX_PERMITS);
        Receiving {
            permits: Arc::new(Semaphore::new(units)),
            units,
        }
    }

    /// The longest a submission waits for room: at most 30 s, and no longer than its
    /// connection may stay silent (`silence`, [`crate::Config::longest_silence`]): nothing
    /// is read from it meanwhile, and the idle timeout would close it unanswered.
    pub fn wait_limit(silence: Duration) -> Duration {
        silence.min(Duration::from_secs(30))
    }

    /// Reserves room for `bytes` (at most the whole budget, so that a request larger than
    /// the budget waits for it to be free rather than for ever), waiting up to `within`.
    pub async fn reserve(&self, bytes: usize, within: Duration) -> Result<Reservation, Full> {
        // At most the whole budget; past `u32::MAX` KiB (4 TiB, so the budget is larger
        // still) `u32::MAX` units, which the budget also holds.
        let units = u32::try_from(bytes.div_ceil(UNIT).clamp(1, self.units)).unwrap_or(u32::MAX);
        match tokio::time::timeout(within, self.permits.clone().acquire_many_owned(units)).await {
            Ok(Ok(room)) => Ok(Reservation { _room: room }),
            // The semaphore is never closed; a closed one admits no one.
            Ok(Err(_)) | Err(_) => Err(Full),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const LONG: Duration = Duration::from_secs(600);

    /// Room is given first come, first served, waited for, and given back when a reservation
    /// is dropped.
    #[tokio::test]
    async fn a_submission_waits_for_room_and_gets_it_when_another_ends() {
        let budget = Receiving::new(1000 * UNIT);
        let first = budget.reserve(600 * UNIT, LONG).await.expect("room");
        assert_eq!(
            budget
                .reserve(600 * UNIT, Duration::from_millis(1))
                .await
                .err(),
            Some(Full)
        );
        // Two small ones still fit beside the first.
        let a = budget.reserve(200 * UNIT, LONG).await.expect("room");
        let b = budget.reserve(200 * UNIT - 7, LONG).await.expect("room");
        let waiting = tokio::spawn({
            let budget = budget.clone();
            async move { budget.reserve(600 * UNIT, LONG).await.is_ok() }
        });
        drop((a, b));
        // A current-thread runtime: the task runs only when this one yields.
        for _ in 0..10 {
            tokio::task::yield_now().await;
        }
        assert!(
            !waiting.is_finished(),
            "600 + 600 KiB fit in a budget of 1000"
        );
        drop(first);
        assert!(
            waiting.await.expect("task"),
            "the waiting submission got its room"
        );
        assert_eq!(
            budget.permits.available_permits(),
            1000,
            "all room given back"
        );
    }

    /// A request larger than the whole budget takes the whole budget once it is free, instead
    /// of waiting for more room than there is.
    #[tokio::test]
    async fn a_request_past_the_budget_takes_all_of_it() {
        let budget = Receiving::new(10 * UNIT);
        let all = budget.reserve(usize::MAX, LONG).await.expect("room");
        assert_eq!(budget.permits.available_permits(), 0);
        assert_eq!(
            budget.reserve(1, Duration::from_millis(1)).await.err(),
            Some(Full)
        );
        drop(all);
        budget.reserve(1, LONG).await.expect("room again");
    }
}
