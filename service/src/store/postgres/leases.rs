//! Leases: the claim, renewals, results, reported failures, releases, and the extension of
//! every lease after a pause.
//!
//! The hot path (claim, renewal, result) is one statement each, in autocommit, and none of
//! them notifies: `NOTIFY` takes a lock for the whole database at commit, which would put
//! every claim and result of every replica in one line.

use sqlx::Row;
use tessera_protocol::Claim;
use tessera_tracer::Rect;

use super::notify::{ENDED, WORK, channel, notify_sql};
use super::{PgStore, Result, job_state, tile_state};
use crate::store::state::{job_sql, tile_sql};
use crate::store::types::{Completion, KeepAway, TileInfo};

/// The first active job with a tile that the worker (placeholder `$w`) may take at `$now`
/// (with fewer than `$max` failures), by priority, then submission: the claim's choice of
/// job, with the placeholders of the statement it goes into.
macro_rules! claimable_job {
    ($w:literal, $now:literal, $max:literal) => {
        concat!(
            "SELECT j.id FROM jobs j
             WHERE j.state IN ",
            job_sql!(active),
            "
               AND NOT EXISTS (SELECT 1 FROM keep_away k
                               WHERE k.job_id = j.id AND k.worker = ",
            $w,
            " AND k.until > ",
            $now,
            ")
               AND EXISTS (SELECT 1 FROM tiles q
                           WHERE q.job_id = j.id AND q.state = ",
            tile_sql!(Queued),
            " AND q.failures < ",
            $max,
            ")
             ORDER BY j.priority DESC, j.seq LIMIT 1"
        )
    };
}

/// The claim: the first queued tile (by index) of the first active job (by priority, then
/// submission) that has one the worker may take, locked with `SKIP LOCKED` so that
/// concurrent claimers on any replica pass over each other's tiles instead of waiting for
/// them; the job becomes `running` (dated by the claim's `now`) in the same statement.
/// The outer `UPDATE` re-checks the state: a row changed between the snapshot and the lock
/// is taken only if it is still queued.
const CLAIM_SQL: &str = concat!(
    "WITH claimed AS (
        UPDATE tiles SET state = ",
    tile_sql!(Leased),
    ", attempt = attempt + 1, lease = $2, worker = $1,
                         lease_expires = $3, rendering = FALSE, claimed_at = $4
        WHERE (job_id, idx) = (
            SELECT t.job_id, t.idx FROM tiles t
            WHERE t.job_id = (",
    claimable_job!("$1", "$4", "$5"),
    ")
              AND t.state = ",
    tile_sql!(Queued),
    " AND t.failures < $5
            ORDER BY t.idx LIMIT 1
            FOR UPDATE SKIP LOCKED)
          AND state = ",
    tile_sql!(Queued),
    "
        RETURNING job_id, idx, x, y, w, h
    ), started AS (
        UPDATE jobs SET state = ",
    job_sql!(Running),
    ", started_at = $4
        WHERE id = (SELECT job_id FROM claimed) AND state = ",
    job_sql!(Queued),
    "
    )
    SELECT job_id, idx, x, y, w, h FROM claimed"
);

/// Whether the claim has a job to take a tile from (the same choice, without the lease):
/// asked when a claim found none, which happens too when every queued tile of that job
/// was locked by other claimers at that instant.
const CLAIMABLE_SQL: &str = concat!("SELECT EXISTS (", claimable_job!("$1", "$2", "$3"), ")");

/// How many times a claim tries again when it found no tile but claimable tiles exist:
/// each time the tiles it passed over were being taken by other claimers, which then hold
/// them, so the next try starts past them.
const CLAIM_TRIES: usize = 8;

impl PgStore {
    /// Hands the first queued tile of the first active job (the highest priority, then the
    /// oldest) to `worker` under a new lease, unless the worker is kept away from that job.
    pub(crate) async fn claim(
        &self,
        worker: &str,
        now: i64,
        lease_ms: u64,
        max_attempts: u32,
    ) -> Result<Option<Claim>> {
        let lease = uuid::Uuid::new_v4().simple().to_string();
        for _ in 0..CLAIM_TRIES {
            let row = sqlx::query(CLAIM_SQL)
                .bind(worker)
                .bind(&lease)
                .bind(now.saturating_add(lease_ms as i64))
                .bind(now)
                .bind(i64::from(max_attempts))
                .fetch_optional(&self.pool)
                .await?;
            if let Some(row) = row {
                return Ok(Some(Claim {
                    job: row.try_get(0)?,
                    idx: row.try_get::<i64, _>(1)? as u32,
                    x: row.try_get::<i64, _>(2)? as u32,
                    y: row.try_get::<i64, _>(3)? as u32,
                    w: row.try_get::<i64, _>(4)? as u32,
                    h: row.try_get::<i64, _>(5)? as u32,
                    lease,
                    lease_ms,
                }));
            }
            let claimable: bool = sqlx::query_scalar(CLAIMABLE_SQL)
                .bind(worker)
                .bind(now)
                .bind(i64::from(max_attempts))
                .fetch_one(&self.pool)
                .await?;
            if !claimable {
                return Ok(None);
            }
            tokio::task::yield_now().await;
        }
        Ok(None)
    }

    /// Extends a lease that is still current; returns its worker's name, `None` if stale.
    /// `rendering`: the worker says it is rendering the tile, not holding it ahead (kept
    /// until the tile is handed out again; see [`PgStore::reap`]).
    pub(crate) async fn renew(
        &self,
        job: &str,
        idx: u32,
        lease: &str,
        now: i64,
        lease_ms: u64,
        rendering: bool,
    ) -> Result<Option<String>> {
        let worker: Option<Option<String>> = sqlx::query_scalar(concat!(
            "UPDATE tiles SET lease_expires = $4, rendering = rendering OR $5
             WHERE job_id = $1 AND idx = $2 AND lease = $3 AND state = ",
            tile_sql!(Leased),
            "
               AND EXISTS (SELECT 1 FROM jobs WHERE id = $1 AND state IN ",
            job_sql!(active),
            ")
             RETURNING worker"
        ))
        .bind(job)
        .bind(i64::from(idx))
        .bind(lease)
        .bind(now.saturating_add(lease_ms as i64))
        .bind(rendering)
        .fetch_optional(&self.pool)
        .await?;
        Ok(worker.map(Option::unwrap_or_default))
    }

    /// A tile's rectangle, state and lease, with its job's state.
    pub(crate) async fn tile(&self, job: &str, idx: u32) -> Result<Option<TileInfo>> {
        let row = sqlx::query(
            "SELECT t.x, t.y, t.w, t.h, t.state, t.lease, j.state, t.worker FROM tiles t
             JOIN jobs j ON j.id = t.job_id WHERE t.job_id = $1 AND t.idx = $2",
        )
        .bind(job)
        .bind(i64::from(idx))
        .fetch_optional(&self.pool)
        .await?;
        let Some(row) = row else { return Ok(None) };
        let u = |i: usize| row.try_get::<i64, _>(i).map(|v| v as u32);
        Ok(Some(TileInfo {
            rect: Rect::new(u(0)?, u(1)?, u(2)?, u(3)?),
            state: tile_state(row.try_get(4)?)?,
            lease: row.try_get(5)?,
            job_state: job_state(row.try_get(6)?)?,
            worker: row.try_get(7)?,
        }))
    }

    /// Stores a tile's pixels if `lease` is its current lease, its job is active and `rect`
    /// (what the blob says it holds; `rgb` has been checked against it) is the tile's.
    ///
    /// One statement: the guarded `UPDATE` marks the tile done (its row lock makes a second
    /// post under the same lease wait, then find the tile done and change nothing), the
    /// pixels are inserted from its row, and the job counts the tile, `RETURNING` the count
    /// after: the job's row lock orders the results of one job, so exactly one sees every
    /// tile in (`last`). The count is not guarded by the job's state: a job that ended
    /// (cancelled, failed) between the tile's check and its count keeps the tile, as it
    /// keeps every stored tile for a retry, and counts it. Only when nothing was stored does
    /// a second query find out why. `now` is not needed: the pixels go into the database,
    /// whose failures are errors.
    #[allow(clippy::too_many_arguments)]
    pub(crate) async fn complete(
        &self,
        job: &str,
        idx: u32,
        lease: &str,
        rect: Rect,
        rgb: &[u8],
        now: i64,
    ) -> Result<Completion> {
        let _ = now;
        let stored: Option<(Option<String>, Option<i64>, Option<i64>)> = sqlx::query_as(concat!(
            "WITH t AS (
                UPDATE tiles SET state = ",
            tile_sql!(Done),
            ", lease_expires = NULL
                WHERE job_id = $1 AND idx = $2 AND lease = $3 AND state = ",
            tile_sql!(Leased),
            "
                  AND x = $5 AND y = $6 AND w = $7 AND h = $8
                  AND EXISTS (SELECT 1 FROM jobs WHERE id = $1 AND state IN ",
            job_sql!(active),
            ")
                RETURNING job_id, idx, worker
            ), p AS (
                INSERT INTO tile_pixels (job_id, idx, rgb) SELECT job_id, idx, $4 FROM t
            ), j AS (
                UPDATE jobs SET tiles_done = tiles_done + 1
                WHERE id = (SELECT job_id FROM t)
                RETURNING tiles_done, tiles_total
            )
            SELECT t.worker, j.tiles_done, j.tiles_total FROM t LEFT JOIN j ON TRUE"
        ))
        .bind(job)
        .bind(i64::from(idx))
        .bind(lease)
        .bind(rgb)
        .bind(i64::from(rect.x))
        .bind(i64::from(rect.y))
        .bind(i64::from(rect.width))
        .bind(i64::from(rect.height))
        .fetch_optional(&self.pool)
        .await?;
        if let Some((worker, Some(done), Some(total))) = stored {
            return Ok(Completion::Stored {
                last: done == total,
                worker,
            });
        }
        // A tile done under this lease is a repeat of a post before.
        Ok(Completion::refused(
            self.tile(job, idx).await?,
            lease,
            stored.is_none(),
        ))
    }

    /// A worker reports that it cannot render a tile: requeue it with one more failure,
    /// count the failure against the worker (keeping it away from the job past the policy's
    /// limit) and fail the job if the tile is out of attempts. False when the lease is stale.
    #[allow(clippy::too_many_arguments)]
    pub(crate) async fn fail_tile(
        &self,
        job: &str,
        idx: u32,
        lease: &str,
        worker: &str,
        reason: &str,
        now: i64,
        max_attempts: u32,
        keep: KeepAway,
    ) -> Result<bool> {
        let mut tx = self.pool.begin().await?;
        let r = sqlx::query(concat!(
            "UPDATE tiles SET state = ",
            tile_sql!(Queued),
            ", lease = NULL, worker = NULL, lease_expires = NULL,
                              failures = failures + 1, last_error = $4
             WHERE job_id = $1 AND idx = $2 AND lease = $3 AND state = ",
            tile_sql!(Leased),
            "
               AND EXISTS (SELECT 1 FROM jobs WHERE id = $1 AND state IN ",
            job_sql!(active),
            ")"
        ))
        .bind(job)
        .bind(i64::from(idx))
        .bind(lease)
        .bind(format!("worker {worker}: {reason}"))
        .execute(&mut *tx)
        .await?;
        if r.rows_affected() == 0 {
            tx.rollback().await?;
            return Ok(false);
        }
        sqlx::query(
            "INSERT INTO keep_away (job_id, worker, failures, until) VALUES ($1, $2, 1, 0)
             ON CONFLICT (job_id, worker) DO UPDATE SET failures = keep_away.failures + 1",
        )
        .bind(job)
        .bind(worker)
        .execute(&mut *tx)
        .await?;
        let (jobs, workers) = (vec![job.to_string()], vec![worker.to_string()]);
        Self::apply_keep_away(&mut tx, &jobs, &workers, now, keep).await?;
        let failed = Self::fail_exhausted(&mut tx, Some(&jobs), now, max_attempts).await?;
        sqlx::query(notify_sql(WORK)).execute(&mut *tx).await?;
        if failed > 0 {
            sqlx::query(notify_sql(ENDED)).execute(&mut *tx).await?;
        }
        tx.commit().await?;
        Ok(true)
    }

    /// Gives a tile back unrendered (a worker shutting down): no failure is counted.
    pub(crate) async fn release(&self, job: &str, idx: u32, lease: &str) -> Result<bool> {
        let released = sqlx::query(concat!(
            "WITH r AS (
                UPDATE tiles SET state = ",
            tile_sql!(Queued),
            ", lease = NULL, worker = NULL, lease_expires = NULL
                WHERE job_id = $1 AND idx = $2 AND lease = $3 AND state = ",
            tile_sql!(Leased),
            "
                  AND EXISTS (SELECT 1 FROM jobs WHERE id = $1 AND state IN ",
            job_sql!(active),
            ")
                RETURNING 1
            )
            SELECT pg_notify(",
            channel!(WORK),
            ", '') FROM r"
        ))
        .bind(job)
        .bind(i64::from(idx))
        .bind(lease)
        .fetch_all(&self.pool)
        .await?;
        Ok(released.len() == 1)
    }

    /// After a pause of the service: every live lease gets a fresh `lease_ms`, so workers
    /// that rode through it can still post what they rendered. Harmless twice.
    pub(crate) async fn extend_leases(&self, now: i64, lease_ms: u64) -> Result<u64> {
        let r = sqlx::query(concat!(
            "UPDATE tiles SET lease_expires = $1 WHERE state = ",
            tile_sql!(Leased)
        ))
        .bind(now.saturating_add(lease_ms as i64))
        .execute(&self.pool)
        .await?;
        Ok(r.rows_affected())
    }

    /// When a replica starts: no live lease runs longer than `grace_ms` from `now`. Holders
    /// that live renew within it (every third of a lease, to any replica); the leases of
    /// those that died while the service was down are reaped at its end. Never lengthens a
    /// lease, so replicas starting again and again keep no dead worker's tile.
    pub(crate) async fn cap_leases(&self, now: i64, grace_ms: u64) -> Result<u64> {
        let r = sqlx::query(concat!(
            "UPDATE tiles SET lease_expires = $1 WHERE lease_expires > $1 AND state = ",
            tile_sql!(Leased)
        ))
        .bind(now.saturating_add(grace_ms as i64))
        .execute(&self.pool)
        .await?;
        Ok(r.rows_affected())
    }
}
