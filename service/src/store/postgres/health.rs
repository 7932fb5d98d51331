//! What replicas know of the database failing, shared through it once it writes again.
//!
//! Each replica keeps its own record in memory ([`crate::store::memo::FailureRecord`]):
//! it is written exactly while the database refuses writes, so a table would lose the
//! entries it exists for. Once the database writes again, [`PgStore::share`] copies it
//! there (the latest failure into the health row, the leases refused into
//! `heard_leases`), so that whichever replica reaps knows that renewals may have been
//! refused, and by which workers, whichever replica refused them.

use std::sync::atomic::Ordering;
use std::time::Duration;

use super::{PgStore, Result};
use crate::store::error::StoreError;
use crate::store::memo::is_within;

/// How long a lease refused by some replica stays in `heard_leases`: past any window the
/// reaper asks about (a lease period and a few reaper passes), short enough that the table
/// stays small.
const HEARD_SHARED_MS: i64 = 5 * 60_000;

impl PgStore {
    /// Rewrites the health row (dated `now`) within `within`: whether the database takes a
    /// write now. The pixels go into the same database, so this is the check for them too.
    pub(crate) async fn probe_write(&self, now: i64, within: Duration) -> Result<()> {
        let write = sqlx::query(
            "INSERT INTO health (id, checked_at) VALUES (1, $1)
             ON CONFLICT (id) DO UPDATE SET checked_at = excluded.checked_at",
        )
        .bind(now)
        .execute(&self.pool);
        match tokio::time::timeout(within, write).await {
            Ok(done) => done.map(|_| ()).map_err(StoreError::from),
            Err(_) => Err(StoreError::WriteTimeout(within)),
        }
    }

    /// Passes `e` through, noting at `now` when it is the database's storage failing.
    pub(crate) fn noted(&self, e: StoreError, now: i64) -> StoreError {
        self.failures.noted(e, now)
    }

    /// Whether a database write failed for the storage's sake less than `within` before
    /// `now`, on this replica or, as last shared, on any.
    pub(crate) fn storage_failed_within(&self, now: i64, within: Duration) -> bool {
        let shared = self.shared_failed.load(Ordering::Relaxed);
        self.failures.failed_within(now, within)
            || (shared != i64::MIN && is_within(shared, now, within))
    }

    /// [`PgStore::noted`], for a renewal or a result under `lease` that failed (see
    /// [`crate::store::Store::heard_refused`]).
    pub(crate) fn heard_refused(&self, lease: &str, e: StoreError, now: i64) -> StoreError {
        self.heard(lease, now);
        self.noted(e, now)
    }

    /// Notes a refused request under `lease` at `now`.
    pub(crate) fn heard(&self, lease: &str, now: i64) {
        self.failures.heard(lease, now);
    }

    /// Forgets the leases this replica has not heard from within `within` before `now`
    /// (those shared stay in `heard_leases` until [`PgStore::share`] drops them).
    pub(crate) fn forget_unheard(&self, now: i64, within: Duration) {
        self.failures.forget_unheard(now, within);
    }

    /// Writes what this replica noted (the roster's batch, the leases it refused and when
    /// the storage last failed) for the other replicas, and reads what they shared: the
    /// latest failure of any, for [`PgStore::storage_failed_within`]. Leases shared more
    /// than a few minutes before `now` are dropped from the table. Every write keeps the
    /// later time, so replicas sharing at once, or one sharing twice, lose nothing.
    pub(crate) async fn share(&self, now: i64) -> Result<()> {
        {
            let _turn = self.roster.turn().await;
            self.write_seen().await;
        }
        let mut heard = self.failures.heard_all();
        // One order for every replica: two writing the same leases at once wait for each
        // other instead of each holding a row the other needs.
        heard.sort_unstable();
        let (leases, times): (Vec<String>, Vec<i64>) = heard.into_iter().unzip();
        let mut tx = self.pool.begin().await?;
        if !leases.is_empty() {
            sqlx::query(
                "INSERT INTO heard_leases (lease, heard_at)
                 SELECT * FROM UNNEST($1::TEXT[], $2::BIGINT[])
                 ON CONFLICT (lease) DO UPDATE
                 SET heard_at = GREATEST(heard_leases.heard_at, excluded.heard_at)",
            )
            .bind(&leases)
            .bind(&times)
            .execute(&mut *tx)
            .await?;
        }
        if let Some(at) = self.failures.failed_at() {
            sqlx::query(
                "INSERT INTO health (id, checked_at, storage_failed_at) VALUES (1, $1, $2)
                 ON CONFLICT (id) DO UPDATE
                 SET storage_failed_at = GREATEST(health.storage_failed_at,
                                                  excluded.storage_failed_at)",
            )
            .bind(now)
            .bind(at)
            .execute(&mut *tx)
            .await?;
        }
        sqlx::query("DELETE FROM heard_leases WHERE heard_at < $1")
            .bind(now.saturating_sub(HEARD_SHARED_MS))
            .execute(&mut *tx)
            .await?;
        let shared: Option<i64> = sqlx::query_scalar("SELECT MAX(storage_failed_at) FROM health")
            .fetch_one(&mut *tx)
            .await?;
        tx.commit().await?;
        self.shared_failed
            .store(shared.unwrap_or(i64::MIN), Ordering::Relaxed);
        Ok(())
    }
}
