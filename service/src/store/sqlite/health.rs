//! What this process knows of its storage failing: when a database write last failed for
//! the storage's sake, the leases whose requests were refused meanwhile, and the spool's
//! last failed write.
//!
//! Kept in the process's memory, by design: the record is written exactly while the
//! database refuses writes (a full disk under it), so a table would lose precisely the
//! entries it exists for. It is this process's view: with several processes on one
//! database, each would extend only the leases whose requests it refused itself (the
//! PostgreSQL backend shares the record through its database). The record itself is
//! [`crate::store::memo`]'s, as both backends keep it. Times are
//! milliseconds since the epoch, passed in; windows are measured against the `now` of the
//! call that asks.

use std::time::Duration;

use super::SqliteStore;
use crate::store::error::StoreError;

impl SqliteStore {
    /// Passes `e` through, noting at `now` when it is the database's storage failing (a
    /// full disk under it): renewals may be refused then, so the reaper gives the leases of
    /// workers it hears from a fresh term instead of reaping them
    /// ([`SqliteStore::storage_failed_within`], [`SqliteStore::reap_unheard`]). The spool's
    /// own failures refuse no renewal (and their tiles are queued again at once), so they
    /// do not count.
    pub(crate) fn noted(&self, e: StoreError, now: i64) -> StoreError {
        self.failures.noted(e, now)
    }

    /// Whether a database write failed for the storage's sake less than `within` before
    /// `now` (as [`SqliteStore::noted`]): renewals may have been refused meanwhile, so the
    /// leases of workers that asked and were refused ran out through no fault of theirs.
    pub(crate) fn storage_failed_within(&self, now: i64, within: Duration) -> bool {
        self.failures.failed_within(now, within)
    }

    /// Why tile pixels cannot be stored now, if the spool failed to write a tile's pixels
    /// less than `within` before `now` and has written none since
    /// ([`super::spool::Spool::trouble`]); `None` for an in-memory database, which keeps
    /// them in SQLite.
    pub(crate) fn storage_trouble(&self, now: i64, within: Duration) -> Option<String> {
        self.spool.as_ref().and_then(|s| s.trouble(now, within))
    }

    /// Renews the record of a lack of room while the spool's folder still has none (see
    /// `Spool::recheck`).
    pub(crate) fn recheck_storage(&self, now: i64, within: Duration) {
        if let Some(s) = &self.spool {
            s.recheck(now, within);
        }
    }

    /// [`SqliteStore::noted`], for a renewal or a result under `lease` that failed: its
    /// worker is alive and asked in time, so while the storage fails the reaper gives the
    /// lease a fresh term rather than reap it ([`SqliteStore::reap_unheard`]). Only refusals
    /// are noted (a renewal that went through has moved the lease on by itself), only what
    /// could be a lease, and at most [`crate::store::HEARD_LEASES`] at once: requests under
    /// made-up leases cannot grow the record past that.
    pub(crate) fn heard_refused(&self, lease: &str, e: StoreError, now: i64) -> StoreError {
        self.heard(lease, now);
        self.noted(e, now)
    }

    /// Notes a refused request under `lease` at `now` (see [`SqliteStore::heard_refused`]).
    pub(crate) fn heard(&self, lease: &str, now: i64) {
        self.failures.heard(lease, now);
    }

    /// Forgets the leases not heard from within `within` before `now` (the reaper's every
    /// pass, so that the record holds only the leases of workers still asking).
    pub(crate) fn forget_unheard(&self, now: i64, within: Duration) {
        self.failures.forget_unheard(now, within);
    }

    /// The leases heard from within `within` before `now`, after forgetting the others.
    pub(super) fn heard_within(&self, now: i64, within: Duration) -> Vec<String> {
        self.failures.heard_within(now, within)
    }
}
