//! Reaping: expired leases requeued and charged (one stall, one tile charged), keep-away, jobs
//! failed when a tile is out of attempts or no live worker may take them, and the leases of
//! a previous run's local workers given back.

use std::collections::HashSet;
use std::time::Duration;

use sqlx::Connection;

use super::{Result, SqliteStore};
use crate::store::stall::{Lapse, charge};
use crate::store::state::{job_sql, tile_sql};
use crate::store::types::KeepAway;

/// A leased tile whose lease ran out, as [`SqliteStore::reap`] reads it.
#[derive(Debug, sqlx::FromRow)]
struct Expired {
    job_id: String,
    idx: i64,
    worker: Option<String>,
    lease_expires: i64,
    /// Its holder said it was rendering it (see [`SqliteStore::renew`]).
    rendering: bool,
}

impl SqliteStore {
    /// Requeues tiles whose lease expired and fails jobs with a tile out of attempts.
    /// Returns the number of tiles requeued. Tiles of a job that has ended (cancelled,
    /// failed) are left as they are: nothing will hand them out, and their workers did
    /// nothing wrong.
    ///
    /// A worker's leases on one job that run out within `keep.stall_ms` of each other are
    /// one stall, in this pass or across passes, counted apart from its reported failures
    /// (`keep_away.stalls`): a worker that vanished, or was restarted under its name, says
    /// nothing against itself, so stalls never keep it away; its tiles' failures end a job
    /// whose tile keeps losing its workers.
    /// A failure is charged to each tile it said it was rendering (a renewal with
    /// `rendering`), one per thread of a worker of many; the tiles it held ahead go back to
    /// the queue uncharged. A worker that stalled before renewing anything said nothing:
    /// then the tile whose lease ran out first is charged (its held-ahead tiles were claimed
    /// later). Counted once a tile, one pause or crash of a lone worker would be two
    /// stalls, and tiles never begun would run out of attempts.
    pub(crate) async fn reap(&self, now: i64, max_attempts: u32, keep: KeepAway) -> Result<u64> {
        let mut conn = self.writer.lock().await?;
        let mut tx = conn.begin_with("BEGIN IMMEDIATE").await?;
        let expired: Vec<Expired> = sqlx::query_as(concat!(
            "SELECT job_id, idx, worker, lease_expires, rendering FROM tiles
             WHERE state = ",
            tile_sql!(Leased),
            " AND lease_expires < ?1
               AND EXISTS (SELECT 1 FROM jobs
                           WHERE id = tiles.job_id AND state IN ",
            job_sql!(active),
            ")
             ORDER BY job_id, worker, lease_expires, idx"
        ))
        .bind(now)
        .fetch_all(&mut *tx)
        .await?;
        // One worker's expired leases on one job, in the order they ran out.
        for tiles in expired.chunk_by(|a, b| a.job_id == b.job_id && a.worker == b.worker) {
            let (job, worker) = (&tiles[0].job_id, &tiles[0].worker);
            let stall_until: i64 = match worker {
                Some(w) => sqlx::query_scalar(
                    "SELECT stall_until FROM keep_away WHERE job_id = ?1 AND worker = ?2",
                )
                .bind(job)
                .bind(w)
                .fetch_optional(&mut *tx)
                .await?
                .unwrap_or(0),
                None => 0,
            };
            let lapses: Vec<Lapse> = tiles
                .iter()
                .map(|t| Lapse {
                    expires: t.lease_expires,
                    rendering: t.rendering,
                })
                .collect();
            let c = charge(&lapses, stall_until, keep.stall_ms, worker.is_some());
            let (strikes, stall_until) = (c.strikes, c.stall_until);
            for (t, &charged) in tiles.iter().zip(&c.charged) {
                sqlx::query(concat!(
                    "UPDATE tiles SET state = ",
                    tile_sql!(Queued),
                    ", failures = failures + ?3,
                             last_error = CASE WHEN ?3 = 1
                                 THEN 'lease lost: worker ' || COALESCE(worker, '?')
                                      || ' stopped answering'
                                 ELSE last_error END,
                             lease = NULL, worker = NULL, lease_expires = NULL
                         WHERE job_id = ?1 AND idx = ?2"
                ))
                .bind(job)
                .bind(t.idx)
                .bind(i64::from(charged))
                .execute(&mut *tx)
                .await?;
            }
            if let Some(w) = worker {
                sqlx::query(
                    "INSERT INTO keep_away (job_id, worker, stalls, until, stall_until)
                     VALUES (?1, ?2, ?3, 0, ?4)
                     ON CONFLICT (job_id, worker) DO UPDATE
                     SET stalls = stalls + ?3, stall_until = ?4",
                )
                .bind(job)
                .bind(w)
                .bind(strikes)
                .bind(stall_until)
                .execute(&mut *tx)
                .await?;
            }
        }
        if !expired.is_empty() {
            Self::fail_exhausted(&mut tx, now, max_attempts).await?;
        }
        tx.commit().await?;
        Ok(expired.len() as u64)
    }

    pub(super) async fn apply_keep_away(
        tx: &mut sqlx::Transaction<'_, sqlx::Sqlite>,
        now: i64,
        keep: KeepAway,
    ) -> Result<()> {
        sqlx::query("UPDATE keep_away SET until = ?1, failures = 0 WHERE failures >= ?2")
            .bind(now.saturating_add(keep.for_ms))
            .bind(i64::from(keep.after.max(1)))
            .execute(&mut **tx)
            .await?;
        Ok(())
    }

    pub(super) async fn fail_exhausted(
        tx: &mut sqlx::Transaction<'_, sqlx::Sqlite>,
        now: i64,
        max_attempts: u32,
    ) -> Result<()> {
        sqlx::query(
            concat!("UPDATE jobs SET state = ", job_sql!(Failed), ", finished_at = ?1,
                 error = (SELECT 'tile ' || t.idx || ' (' || t.w || '×' || t.h || ' at ' || t.x || ','
                                 || t.y || ') failed ' || t.failures || ' times; last: '
                                 || COALESCE(t.last_error, 'unknown')
                          FROM tiles t WHERE t.job_id = jobs.id AND t.state = ", tile_sql!(Queued), "
                            AND t.failures >= ?2 LIMIT 1)
             WHERE state IN ", job_sql!(active), " AND EXISTS (
                 SELECT 1 FROM tiles t WHERE t.job_id = jobs.id AND t.state = ", tile_sql!(Queued), "
                   AND t.failures >= ?2)"),
        )
        .bind(now)
        .bind(i64::from(max_attempts))
        .execute(&mut **tx)
        .await?;
        Ok(())
    }

    /// Active jobs with queued work from which every one of `live` workers is kept away:
    /// failed, since nothing would ever render them (Flamenco's rule). Returns how many.
    pub(crate) async fn fail_unservable(&self, live: &[String], now: i64) -> Result<u64> {
        if live.is_empty() {
            return Ok(0);
        }
        let rows: Vec<(String, String)> = sqlx::query_as(concat!(
            "SELECT k.job_id, k.worker FROM keep_away k JOIN jobs j ON j.id = k.job_id
             WHERE k.until > ?1 AND j.state IN ",
            job_sql!(active)
        ))
        .bind(now)
        .fetch_all(&mut *self.reader().await?)
        .await?;
        let mut jobs: Vec<&str> = rows.iter().map(|(j, _)| j.as_str()).collect();
        jobs.sort_unstable();
        jobs.dedup();
        let mut failed = 0;
        for job in jobs {
            let all_away = live
                .iter()
                .all(|w| rows.iter().any(|(j, k)| j == job && k == w));
            if !all_away {
                continue;
            }
            let r = sqlx::query(concat!(
                "UPDATE jobs SET state = ",
                job_sql!(Failed),
                ", finished_at = ?2,
                     error = 'every available worker failed this job; last: ' || COALESCE(
                         (SELECT last_error FROM tiles WHERE job_id = ?1 AND last_error IS NOT NULL
                          ORDER BY failures DESC LIMIT 1), 'unknown')
                 WHERE id = ?1 AND state IN ",
                job_sql!(active),
                "
                   AND EXISTS (SELECT 1 FROM tiles WHERE job_id = ?1 AND state = ",
                tile_sql!(Queued),
                ")"
            ))
            .bind(job)
            .bind(now)
            .execute(&mut *self.writer.lock().await?)
            .await?;
            failed += r.rows_affected();
        }
        Ok(failed)
    }

    /// At start: the tiles held by the local workers of the service process that last
    /// started on this database (their names begin with a prefix it stored) are requeued
    /// without a failure counted, since those workers ended with that process; `prefix`, the
    /// name prefix of this process's local workers (none without any), is stored instead.
    /// Tiles of jobs that have ended are left as they are, as the reaper leaves them.
    /// Returns the number of tiles requeued.
    pub(crate) async fn forget_local_workers(&self, prefix: Option<&str>) -> Result<u64> {
        let mut conn = self.writer.lock().await?;
        let mut tx = conn.begin_with("BEGIN IMMEDIATE").await?;
        let requeued = sqlx::query(concat!(
            "UPDATE tiles SET state = ",
            tile_sql!(Queued),
            ", lease = NULL, worker = NULL, lease_expires = NULL
             WHERE state = ",
            tile_sql!(Leased),
            "
               AND job_id IN (SELECT id FROM jobs WHERE state IN ",
            job_sql!(active),
            ")
               AND EXISTS (SELECT 1 FROM local_workers p
                           WHERE substr(tiles.worker, 1, length(p.prefix)) = p.prefix)"
        ))
        .execute(&mut *tx)
        .await?
        .rows_affected();
        sqlx::query("DELETE FROM local_workers")
            .execute(&mut *tx)
            .await?;
        if let Some(prefix) = prefix {
            sqlx::query("INSERT INTO local_workers (prefix) VALUES (?1)")
                .bind(prefix)
                .execute(&mut *tx)
                .await?;
        }
        tx.commit().await?;
        Ok(requeued)
    }

    /// The reaper's pass while the storage fails ([`SqliteStore::storage_failed_within`]): the
    /// leases heard from within `within` ([`SqliteStore::heard_refused`]: their workers asked to
    /// renew them or to store their results, and were refused) get a fresh `lease_ms`; the
    /// others are reaped as ever, since a worker that died meanwhile asks nothing, and one
    /// whose renewals went through holds a lease that has not run out. Extending every
    /// lease instead would keep a dead worker's tiles for as long as failures kept coming,
    /// which on a nearly full disk, failing now and then, could be for ever. Returns how
    /// many leases were extended and how many reaped.
    pub(crate) async fn reap_unheard(
        &self,
        now: i64,
        lease_ms: u64,
        within: Duration,
        max_attempts: u32,
        keep: KeepAway,
    ) -> Result<(u64, u64)> {
        let heard: HashSet<String> = self.heard_within(now, within).into_iter().collect();
        let mut extended = 0;
        if !heard.is_empty() {
            let mut conn = self.writer.lock().await?;
            let mut tx = conn.begin_with("BEGIN IMMEDIATE").await?;
            let leased: Vec<(String, i64, String)> = sqlx::query_as(concat!(
                "SELECT job_id, idx, lease FROM tiles WHERE state = ",
                tile_sql!(Leased),
                " AND lease IS NOT NULL"
            ))
            .fetch_all(&mut *tx)
            .await?;
            for (job, idx, lease) in leased.iter().filter(|(_, _, l)| heard.contains(l)) {
                extended += sqlx::query(concat!(
                    "UPDATE tiles SET lease_expires = ?1
                     WHERE job_id = ?2 AND idx = ?3 AND lease = ?4 AND state = ",
                    tile_sql!(Leased)
                ))
                .bind(now.saturating_add(lease_ms as i64))
                .bind(job)
                .bind(idx)
                .bind(lease)
                .execute(&mut *tx)
                .await?
                .rows_affected();
            }
            tx.commit().await?;
        }
        let reaped = self.reap(now, max_attempts, keep).await?;
        Ok((extended, reaped))
    }
}
