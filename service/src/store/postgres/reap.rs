//! Reaping: expired leases requeued and charged (one stall, one tile charged), keep-away, jobs
//! failed when a tile is out of attempts or no live worker may take them.
//!
//! The maintenance lock makes one replica at a time reap; each statement is guarded as
//! well (the expired tiles are locked `SKIP LOCKED` and requeued only while still leased
//! under the same, expired lease), so a second reaper at once changes nothing twice.

use std::time::Duration;

use sqlx::{Postgres, Transaction};

use super::notify::{ENDED, WORK, notify_sql};
use super::{PgStore, Result};
use crate::store::memo::millis;
use crate::store::stall::{Lapse, charge};
use crate::store::state::{job_sql, tile_sql};
use crate::store::types::KeepAway;

/// A leased tile whose lease ran out, as [`PgStore::reap`] reads it.
#[derive(Debug, sqlx::FromRow)]
struct Expired {
    job_id: String,
    idx: i64,
    lease: Option<String>,
    worker: Option<String>,
    lease_expires: i64,
    /// Its holder said it was rendering it (see [`PgStore::renew`]).
    rendering: bool,
}

impl PgStore {
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
    /// later). The SQLite backend's rule, in the same steps.
    pub(crate) async fn reap(&self, now: i64, max_attempts: u32, keep: KeepAway) -> Result<u64> {
        let mut tx = self.pool.begin().await?;
        let expired: Vec<Expired> = sqlx::query_as(concat!(
            "SELECT job_id, idx, lease, worker, lease_expires, rendering FROM tiles
             WHERE state = ",
            tile_sql!(Leased),
            " AND lease_expires < $1
               AND EXISTS (SELECT 1 FROM jobs
                           WHERE id = tiles.job_id AND state IN ",
            job_sql!(active),
            ")
             ORDER BY job_id, worker, lease_expires, idx
             FOR UPDATE SKIP LOCKED"
        ))
        .bind(now)
        .fetch_all(&mut *tx)
        .await?;
        if expired.is_empty() {
            tx.commit().await?;
            return Ok(0);
        }
        // The stalls already counted of each worker on each job, locked: a second reaper
        // waits here for the first's, and then counts on from it.
        let named: Vec<(&str, &str)> = {
            let mut v: Vec<(&str, &str)> = expired
                .iter()
                .filter_map(|t| t.worker.as_deref().map(|w| (t.job_id.as_str(), w)))
                .collect();
            v.dedup();
            v
        };
        let (jobs, workers): (Vec<String>, Vec<String>) = named
            .iter()
            .map(|(j, w)| (j.to_string(), w.to_string()))
            .unzip();
        let stalls: Vec<(String, String, i64)> = sqlx::query_as(
            "SELECT job_id, worker, stall_until FROM keep_away
             WHERE (job_id, worker) IN (SELECT * FROM UNNEST($1::TEXT[], $2::TEXT[]))
             ORDER BY job_id, worker
             FOR UPDATE",
        )
        .bind(&jobs)
        .bind(&workers)
        .fetch_all(&mut *tx)
        .await?;
        let stall_of = |job: &str, worker: &str| {
            stalls
                .iter()
                .find(|(j, w, _)| j == job && w == worker)
                .map_or(0, |(_, _, s)| *s)
        };
        // What each tile is charged, and each worker's strikes and stall's end.
        let mut charges: Vec<i64> = Vec::with_capacity(expired.len());
        let mut strikes_of: Vec<(String, String, i64, i64)> = Vec::new();
        // One worker's expired leases on one job, in the order they ran out.
        for tiles in expired.chunk_by(|a, b| a.job_id == b.job_id && a.worker == b.worker) {
            let (job, worker) = (&tiles[0].job_id, &tiles[0].worker);
            let lapses: Vec<Lapse> = tiles
                .iter()
                .map(|t| Lapse {
                    expires: t.lease_expires,
                    rendering: t.rendering,
                })
                .collect();
            let stored = worker.as_deref().map_or(0, |w| stall_of(job, w));
            let c = charge(&lapses, stored, keep.stall_ms, worker.is_some());
            charges.extend(c.charged.iter().map(|&b| i64::from(b)));
            if let Some(w) = worker {
                strikes_of.push((job.clone(), w.clone(), c.strikes, c.stall_until));
            }
        }
        let requeued = sqlx::query(concat!(
            "UPDATE tiles SET state = ",
            tile_sql!(Queued),
            ", failures = failures + c.charge,
                 last_error = CASE WHEN c.charge = 1
                     THEN 'lease lost: worker ' || COALESCE(tiles.worker, '?')
                          || ' stopped answering'
                     ELSE last_error END,
                 lease = NULL, worker = NULL, lease_expires = NULL
             FROM UNNEST($1::TEXT[], $2::BIGINT[], $3::TEXT[], $4::BIGINT[])
                  AS c(job_id, idx, lease, charge)
             WHERE tiles.job_id = c.job_id AND tiles.idx = c.idx
               AND tiles.lease IS NOT DISTINCT FROM c.lease AND tiles.state = ",
            tile_sql!(Leased),
            " AND tiles.lease_expires < $5"
        ))
        .bind(expired.iter().map(|t| t.job_id.clone()).collect::<Vec<_>>())
        .bind(expired.iter().map(|t| t.idx).collect::<Vec<_>>())
        .bind(expired.iter().map(|t| t.lease.clone()).collect::<Vec<_>>())
        .bind(&charges)
        .bind(now)
        .execute(&mut *tx)
        .await?
        .rows_affected();
        if !strikes_of.is_empty() {
            let col = |f: fn(&(String, String, i64, i64)) -> String| {
                strikes_of.iter().map(f).collect::<Vec<_>>()
            };
            sqlx::query(
                "INSERT INTO keep_away (job_id, worker, stalls, until, stall_until)
                 SELECT job_id, worker, strikes, 0, stall_until
                 FROM UNNEST($1::TEXT[], $2::TEXT[], $3::BIGINT[], $4::BIGINT[])
                      AS s(job_id, worker, strikes, stall_until)
                 ON CONFLICT (job_id, worker) DO UPDATE
                 SET stalls = keep_away.stalls + excluded.stalls,
                     stall_until = excluded.stall_until",
            )
            .bind(col(|s| s.0.clone()))
            .bind(col(|s| s.1.clone()))
            .bind(strikes_of.iter().map(|s| s.2).collect::<Vec<_>>())
            .bind(strikes_of.iter().map(|s| s.3).collect::<Vec<_>>())
            .execute(&mut *tx)
            .await?;
        }
        let failed = Self::fail_exhausted(&mut tx, None, now, max_attempts).await?;
        if requeued > 0 {
            sqlx::query(notify_sql(WORK)).execute(&mut *tx).await?;
        }
        if failed > 0 {
            sqlx::query(notify_sql(ENDED)).execute(&mut *tx).await?;
        }
        tx.commit().await?;
        Ok(requeued)
    }

    /// Keeps away from their jobs, for `keep.for_ms` from `now`, the workers among
    /// `(jobs[i], workers[i])` whose failures reached `keep.after` (their count starting
    /// again). Only the rows given: those whose failures this transaction counted, the only
    /// ones that can have reached it, and the only rows it locks, so that two transactions
    /// counting failures of different workers never wait for each other.
    pub(super) async fn apply_keep_away(
        tx: &mut Transaction<'_, Postgres>,
        jobs: &[String],
        workers: &[String],
        now: i64,
        keep: KeepAway,
    ) -> Result<()> {
        sqlx::query(
            "UPDATE keep_away SET until = $1, failures = 0
             WHERE failures >= $2
               AND (job_id, worker) IN (SELECT * FROM UNNEST($3::TEXT[], $4::TEXT[]))",
        )
        .bind(now.saturating_add(keep.for_ms))
        .bind(i64::from(keep.after.max(1)))
        .bind(jobs)
        .bind(workers)
        .execute(&mut **tx)
        .await?;
        Ok(())
    }

    /// Fails the active jobs (of `jobs`, or all) with a queued tile that failed
    /// `max_attempts` times, saying which tile and why. Returns how many jobs failed.
    pub(super) async fn fail_exhausted(
        tx: &mut Transaction<'_, Postgres>,
        jobs: Option<&[String]>,
        now: i64,
        max_attempts: u32,
    ) -> Result<u64> {
        let r = sqlx::query(concat!(
            "UPDATE jobs SET state = ",
            job_sql!(Failed),
            ", finished_at = $1,
                 error = (SELECT 'tile ' || t.idx || ' (' || t.w || '×' || t.h || ' at '
                                 || t.x || ',' || t.y || ') failed ' || t.failures
                                 || ' times; last: ' || COALESCE(t.last_error, 'unknown')
                          FROM tiles t WHERE t.job_id = jobs.id AND t.state = ",
            tile_sql!(Queued),
            "
                            AND t.failures >= $2 ORDER BY t.idx LIMIT 1)
             WHERE state IN ",
            job_sql!(active),
            " AND ($3::TEXT[] IS NULL OR id = ANY($3))
               AND EXISTS (SELECT 1 FROM tiles t WHERE t.job_id = jobs.id AND t.state = ",
            tile_sql!(Queued),
            " AND t.failures >= $2)"
        ))
        .bind(now)
        .bind(i64::from(max_attempts))
        .bind(jobs)
        .execute(&mut **tx)
        .await?;
        Ok(r.rows_affected())
    }

    /// Active jobs with queued work from which every one of `live` workers is kept away:
    /// failed, since nothing would ever render them (Flamenco's rule). Returns how many.
    pub(crate) async fn fail_unservable(&self, live: &[String], now: i64) -> Result<u64> {
        if live.is_empty() {
            return Ok(0);
        }
        let rows: Vec<(String, String)> = sqlx::query_as(concat!(
            "SELECT k.job_id, k.worker FROM keep_away k JOIN jobs j ON j.id = k.job_id
             WHERE k.until > $1 AND j.state IN ",
            job_sql!(active)
        ))
        .bind(now)
        .fetch_all(&self.pool)
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
            let notified = sqlx::query(concat!(
                "WITH f AS (
                    UPDATE jobs SET state = ",
                job_sql!(Failed),
                ", finished_at = $2,
                         error = 'every available worker failed this job; last: ' || COALESCE(
                             (SELECT last_error FROM tiles
                              WHERE job_id = $1 AND last_error IS NOT NULL
                              ORDER BY failures DESC, idx LIMIT 1), 'unknown')
                    WHERE id = $1 AND state IN ",
                job_sql!(active),
                "
                      AND EXISTS (SELECT 1 FROM tiles WHERE job_id = $1 AND state = ",
                tile_sql!(Queued),
                ")
                    RETURNING 1
                )
                SELECT pg_notify(",
                super::notify::channel!(ENDED),
                ", '') FROM f"
            ))
            .bind(job)
            .bind(now)
            .fetch_all(&self.pool)
            .await?;
            failed += notified.len() as u64;
        }
        Ok(failed)
    }

    /// The reaper's pass while the storage fails: the leases heard from within `within`,
    /// by this replica or by any other (the `heard_leases` table, which
    /// [`PgStore::share`] writes), get a fresh `lease_ms`; the others are reaped as ever,
    /// since a worker that died meanwhile asks nothing, and one whose renewals went through
    /// holds a lease that has not run out. Returns how many leases were extended and how
    /// many reaped.
    pub(crate) async fn reap_unheard(
        &self,
        now: i64,
        lease_ms: u64,
        within: Duration,
        max_attempts: u32,
        keep: KeepAway,
    ) -> Result<(u64, u64)> {
        let heard = self.failures.heard_within(now, within);
        let extended = sqlx::query(concat!(
            "UPDATE tiles SET lease_expires = $1
             WHERE state = ",
            tile_sql!(Leased),
            "
               AND (lease = ANY($2)
                    OR lease IN (SELECT lease FROM heard_leases WHERE heard_at > $3))"
        ))
        .bind(now.saturating_add(lease_ms as i64))
        .bind(&heard)
        .bind(now.saturating_sub(millis(within)))
        .execute(&self.pool)
        .await?
        .rows_affected();
        let reaped = self.reap(now, max_attempts, keep).await?;
        Ok((extended, reaped))
    }
}
