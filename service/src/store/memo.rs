//! What a store keeps in its process's memory, whatever the backend: the record of the
//! storage failing ([`FailureRecord`]) and the batch of the roster not yet written
//! ([`RosterBatch`]).
//!
//! The failure record is kept in memory by design: it is written exactly while the
//! database refuses writes (a full disk under it, a server gone), so a table would lose
//! precisely the entries it exists for. It is this process's view; a backend that several
//! processes share copies it into the database once it writes again (PostgreSQL's
//! `share`). The roster's batch is kept in memory so that claims, renewals and results do
//! not each add a write; every read of the roster writes it first.
//!
//! What this is not: the statements that write either to a database. Those are the
//! backends'. Times are milliseconds since the epoch, passed in; windows are measured
//! against the `now` of the call that asks.

use std::collections::HashMap;
use std::future::Future;
use std::sync::{Mutex, PoisonError};
use std::time::Duration;

use super::error::StoreError;
use super::types::WorkerSeen;

/// The most leases [`FailureRecord::heard`] keeps at once (a worker holds two per render
/// thread): a few MB at most. Past it, a lease not yet heard from is not noted, and so is
/// reaped as it would be without the record if the storage fails while its lease runs out.
pub(crate) const HEARD_LEASES: usize = 1 << 16;

/// `d` in milliseconds, saturating.
pub(crate) fn millis(d: Duration) -> i64 {
    i64::try_from(d.as_millis()).unwrap_or(i64::MAX)
}

/// Whether `at` is less than `within` before `now` (a clock set back counts as within).
pub(crate) fn is_within(at: i64, now: i64, within: Duration) -> bool {
    now.saturating_sub(at) < millis(within)
}

/// Whether `lease` could be a lease token this service handed out (32 lowercase hex
/// digits): only those are noted, so requests under made-up text cannot fill the record.
fn plausible(lease: &str) -> bool {
    lease.len() == 32
        && lease
            .bytes()
            .all(|b| matches!(b, b'0'..=b'9' | b'a'..=b'f'))
}

/// When a database write of this process last failed for the storage's sake, and the
/// leases whose renewals or results it refused lately.
#[derive(Debug, Default)]
pub(crate) struct FailureRecord {
    /// When (ms since the epoch) a database write last failed for the storage's sake.
    failed_at: Mutex<Option<i64>>,
    /// Leases whose renewal or result was refused lately, and when.
    heard: Mutex<HashMap<String, i64>>,
}

impl FailureRecord {
    /// Passes `e` through, noting at `now` when it is the database's storage failing
    /// ([`StoreError::is_storage`]). The spool's own failures refuse no renewal (and their
    /// tiles are queued again at once), so they do not count.
    pub(crate) fn noted(&self, e: StoreError, now: i64) -> StoreError {
        if matches!(e, StoreError::Db(_)) && e.is_storage() {
            *self
                .failed_at
                .lock()
                .unwrap_or_else(PoisonError::into_inner) = Some(now);
        }
        e
    }

    /// When a database write last failed for the storage's sake, if ever.
    pub(crate) fn failed_at(&self) -> Option<i64> {
        *self
            .failed_at
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
    }

    /// Whether a database write failed for the storage's sake less than `within` before
    /// `now`.
    pub(crate) fn failed_within(&self, now: i64, within: Duration) -> bool {
        self.failed_at()
            .is_some_and(|at| is_within(at, now, within))
    }

    /// Notes a refused request under `lease` at `now`: only what could be a lease, and at
    /// most [`HEARD_LEASES`] at once (a lease already noted is always dated anew).
    pub(crate) fn heard(&self, lease: &str, now: i64) {
        if !plausible(lease) {
            return;
        }
        let mut heard = self.heard.lock().unwrap_or_else(PoisonError::into_inner);
        let room = heard.len() < HEARD_LEASES;
        match heard.get_mut(lease) {
            Some(at) => *at = now,
            None if room => {
                heard.insert(lease.to_string(), now);
            }
            None => {}
        }
    }

    /// Forgets the leases not heard from within `within` before `now`.
    pub(crate) fn forget_unheard(&self, now: i64, within: Duration) {
        let mut heard = self.heard.lock().unwrap_or_else(PoisonError::into_inner);
        heard.retain(|_, at| is_within(*at, now, within));
    }

    /// The leases heard from within `within` before `now`, after forgetting the others.
    pub(crate) fn heard_within(&self, now: i64, within: Duration) -> Vec<String> {
        self.forget_unheard(now, within);
        let heard = self.heard.lock().unwrap_or_else(PoisonError::into_inner);
        heard.keys().cloned().collect()
    }

    /// Every lease noted, with when it was last heard from.
    pub(crate) fn heard_all(&self) -> Vec<(String, i64)> {
        let heard = self.heard.lock().unwrap_or_else(PoisonError::into_inner);
        heard.iter().map(|(l, at)| (l.clone(), *at)).collect()
    }
}

/// What this process heard of workers since it last wrote the roster, added up by name.
#[derive(Debug, Default)]
pub(crate) struct RosterBatch {
    pending: Mutex<HashMap<String, WorkerSeen>>,
    /// Held while the roster is written and read: a read while another's batch is on its
    /// way to the table would find it in neither place.
    turn: tokio::sync::Mutex<()>,
}

impl RosterBatch {
    /// Notes that `worker` was heard from at `now`; `f` adds to what is noted of it (its
    /// counts start at zero in each batch not yet written, so `f` adds, never sets).
    pub(crate) fn seen(&self, worker: &str, now: i64, f: impl FnOnce(&mut WorkerSeen)) {
        let mut pending = self.pending.lock().unwrap_or_else(PoisonError::into_inner);
        let entry = pending
            .entry(worker.to_string())
            .or_insert_with(|| WorkerSeen {
                name: worker.to_string(),
                ..WorkerSeen::default()
            });
        entry.last_seen = entry.last_seen.max(now);
        f(entry);
    }

    /// The right to write and read the roster, one holder at a time.
    pub(crate) async fn turn(&self) -> tokio::sync::MutexGuard<'_, ()> {
        self.turn.lock().await
    }

    /// Writes the batch with `write` (called only when something is pending). On failure
    /// (a full disk) the batch is kept for the next write, and reads add it meanwhile: the
    /// roster is informational, and its write must not fail the request that reads it.
    /// Call it holding [`RosterBatch::turn`].
    pub(crate) async fn flush<F, Fut>(&self, write: F)
    where
        F: FnOnce(Vec<WorkerSeen>) -> Fut,
        Fut: Future<Output = Result<(), StoreError>>,
    {
        let taken =
            std::mem::take(&mut *self.pending.lock().unwrap_or_else(PoisonError::into_inner));
        if taken.is_empty() {
            return;
        }
        let batch: Vec<WorkerSeen> = taken.values().cloned().collect();
        if let Err(e) = write(batch).await {
            tracing::warn!("writing the roster of workers: {e}");
            let mut pending = self.pending.lock().unwrap_or_else(PoisonError::into_inner);
            for p in taken.into_values() {
                add(pending.entry(p.name.clone()).or_default(), &p);
            }
        }
    }

    /// The roster as read from the database (`rows`, those heard from at or after
    /// `since`) with what is pending added, by name.
    pub(crate) fn merged(&self, rows: Vec<WorkerSeen>, since: i64) -> Vec<WorkerSeen> {
        let mut all: HashMap<String, WorkerSeen> =
            rows.into_iter().map(|w| (w.name.clone(), w)).collect();
        let pending = self.pending.lock().unwrap_or_else(PoisonError::into_inner);
        for p in pending.values().filter(|p| p.last_seen >= since) {
            add(all.entry(p.name.clone()).or_default(), p);
        }
        drop(pending);
        let mut list: Vec<WorkerSeen> = all.into_values().collect();
        list.sort_by(|a, b| a.name.cmp(&b.name));
        list
    }
}

/// The columns of a roster row as both backends read them, in [`RosterRow`]'s order.
pub(crate) const ROSTER_COLUMNS: &str =
    "name, last_seen, claims, claims_with_results, tiles_done, threads, rays_per_second, left_at";

/// A roster row as both backends read it ([`ROSTER_COLUMNS`]).
pub(crate) type RosterRow = (String, i64, i64, i64, i64, Option<i64>, Option<f64>, i64);

/// The [`WorkerSeen`] of a roster row (a negative count, which no write makes, reads 0).
pub(crate) fn roster_row(
    (name, last_seen, claims, with_results, tiles_done, threads, rays, left_at): RosterRow,
) -> WorkerSeen {
    WorkerSeen {
        name,
        last_seen,
        claims: u64::try_from(claims).unwrap_or(0),
        claims_with_results: u64::try_from(with_results).unwrap_or(0),
        tiles_done: u64::try_from(tiles_done).unwrap_or(0),
        threads: threads.and_then(|t| u32::try_from(t).ok()),
        rays_per_second: rays,
        left_at,
    }
}

/// A count as the database stores it (saturating).
pub(crate) fn count(n: u64) -> i64 {
    i64::try_from(n).unwrap_or(i64::MAX)
}

/// Adds `p`'s counts to `to`, keeping the later `last_seen` and goodbye; what `p` says of
/// the worker (threads, rays per second) replaces `to`'s, as `p` is the later news (`to`
/// takes `p`'s name if it has none).
fn add(to: &mut WorkerSeen, p: &WorkerSeen) {
    if to.name.is_empty() {
        to.name = p.name.clone();
    }
    to.last_seen = to.last_seen.max(p.last_seen);
    to.claims += p.claims;
    to.claims_with_results += p.claims_with_results;
    to.tiles_done += p.tiles_done;
    to.threads = p.threads.or(to.threads);
    to.rays_per_second = p.rays_per_second.or(to.rays_per_second);
    to.left_at = to.left_at.max(p.left_at);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_plausible_leases_are_heard_and_old_ones_are_forgotten() {
        let r = FailureRecord::default();
        r.heard("not a lease", 0);
        let lease = "0123456789abcdef0123456789abcdef";
        r.heard(lease, 1_000);
        assert_eq!(r.heard_all(), [(lease.to_string(), 1_000)]);
        assert_eq!(r.heard_within(1_500, Duration::from_secs(1)), [lease]);
        assert!(r.heard_within(2_000, Duration::from_secs(1)).is_empty());
    }

    #[tokio::test]
    async fn a_batch_that_could_not_be_written_is_kept_for_the_next() {
        let b = RosterBatch::default();
        b.seen("w", 5, |w| w.claims += 1);
        b.flush(|_| async { Err(StoreError::WriteTimeout(Duration::ZERO)) })
            .await;
        b.seen("w", 7, |w| w.claims += 1);
        let listed = b.merged(Vec::new(), 0);
        assert_eq!((listed[0].last_seen, listed[0].claims), (7, 2));
        let mut written = Vec::new();
        b.flush(|batch| {
            written = batch;
            async { Ok(()) }
        })
        .await;
        assert_eq!(written.len(), 1);
        assert!(b.merged(Vec::new(), 0).is_empty());
    }

    #[test]
    fn a_pending_report_replaces_the_stored_one_and_a_goodbye_lasts_until_heard_again() {
        let b = RosterBatch::default();
        let stored = WorkerSeen {
            name: "w".into(),
            last_seen: 10,
            tiles_done: 3,
            threads: Some(4),
            rays_per_second: Some(1e6),
            ..WorkerSeen::default()
        };
        // Heard again without a report: what it said before stands.
        b.seen("w", 20, |w| w.tiles_done += 1);
        let w = &b.merged(vec![stored.clone()], 0)[0];
        assert_eq!(
            (w.tiles_done, w.threads, w.rays_per_second),
            (4, Some(4), Some(1e6))
        );
        assert!(!w.has_left());
        // A new report wins over the stored one; a goodbye marks it gone.
        b.seen("w", 30, |w| {
            w.threads = Some(2);
            w.rays_per_second = Some(5e5);
            w.left_at = 30;
        });
        let w = &b.merged(vec![stored.clone()], 0)[0];
        assert_eq!((w.threads, w.rays_per_second), (Some(2), Some(5e5)));
        assert!(w.has_left());
        // A claim after the goodbye: back.
        b.seen("w", 31, |_| {});
        assert!(!b.merged(vec![stored], 0)[0].has_left());
    }
}
