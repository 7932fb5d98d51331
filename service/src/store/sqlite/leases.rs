//! Leases: the claim, renewals, results (with the spool's guard of leases handed out),
//! reported failures, releases, and the extension of every lease after a restart.

use sqlx::{Connection, Row};
use tessera_protocol::Claim;
use tessera_tracer::Rect;

use super::spool::Spool;
use super::{Issued, Result, SqliteStore, job_state, tile_state};
use crate::store::error::{SpoolError, StoreError};
use crate::store::state::{TileState, job_sql, tile_sql};
use crate::store::types::{Completion, KeepAway, TileInfo};

/// The claim: the first queued tile (by index) of the first active job (by priority, then
/// submission) that has one the worker may take. Its job is found through `jobs_to_claim`
/// (migration 0009), which holds only the active jobs, in that order, so the walk stops at
/// the first job that qualifies. Named, because SQLite's planner would prefer
/// `jobs_by_state` and then sort every active job, checking each for a tile, on every
/// claim. The claim stamps `claimed_at` with the caller's `now`, which the `job_started` trigger (migration
/// 0010) copies into a queued job's `started_at` as it marks the job running, inside this
/// statement.
pub(super) const CLAIM_SQL: &str = concat!(
    "UPDATE tiles SET state = ",
    tile_sql!(Leased),
    ", attempt = attempt + 1, lease = ?2, worker = ?1,
                   lease_expires = ?3, rendering = 0, claimed_at = ?4
  WHERE rowid = (
      SELECT t.rowid FROM tiles t
      WHERE t.job_id = (
          SELECT j.id FROM jobs j INDEXED BY jobs_to_claim
          WHERE j.state IN ",
    job_sql!(active),
    "
            AND NOT EXISTS (SELECT 1 FROM keep_away k
                            WHERE k.job_id = j.id AND k.worker = ?1 AND k.until > ?4)
            AND EXISTS (SELECT 1 FROM tiles q
                        WHERE q.job_id = j.id AND q.state = ",
    tile_sql!(Queued),
    " AND q.failures < ?5)
          ORDER BY j.priority DESC, j.seq LIMIT 1)
        AND t.state = ",
    tile_sql!(Queued),
    " AND t.failures < ?5
      ORDER BY t.idx LIMIT 1)
  RETURNING job_id, idx, x, y, w, h"
);

impl SqliteStore {
    /// Hands the first queued tile of the first active job (the highest priority, then the
    /// oldest) to `worker` under a new lease, unless the worker is kept away from that job. One statement: see the module comment.
    /// The job is chosen first and its tile second, so that both steps walk an index in
    /// order (`jobs_to_claim`, `tiles_by_state`) instead of sorting every queued tile of
    /// every job on each claim.
    pub(crate) async fn claim(
        &self,
        worker: &str,
        now: i64,
        lease_ms: u64,
        max_attempts: u32,
    ) -> Result<Option<Claim>> {
        let lease = uuid::Uuid::new_v4().simple().to_string();
        let row = sqlx::query(CLAIM_SQL)
            .bind(worker)
            .bind(&lease)
            .bind(now.saturating_add(lease_ms as i64))
            .bind(now)
            .bind(i64::from(max_attempts))
            // To the statement's end, not its first row: SQLite commits an autocommit statement
            // when it finishes, and a commit that fails (a full disk) must be this call's error,
            // not lost in a reset after the row was taken (the claim was answered with a lease
            // that was never stored).
            .fetch_all(&mut *self.writer.lock().await?)
            .await?
            .into_iter()
            .next();
        let Some(row) = row else { return Ok(None) };
        let claim = Claim {
            job: row.try_get(0)?,
            idx: row.try_get::<i64, _>(1)? as u32,
            x: row.try_get::<i64, _>(2)? as u32,
            y: row.try_get::<i64, _>(3)? as u32,
            w: row.try_get::<i64, _>(4)? as u32,
            h: row.try_get::<i64, _>(5)? as u32,
            lease,
            lease_ms,
        };
        if self.spool.is_some() {
            self.issued_map().insert(
                (claim.job.clone(), claim.idx),
                (claim.lease.clone(), claim.rect()),
            );
        }
        Ok(Some(claim))
    }

    /// Extends a lease that is still current; returns its worker's name, `None` if stale.
    /// `rendering`: the worker says it is rendering the tile, not holding it ahead (kept
    /// until the tile is handed out again; see [`SqliteStore::reap`]).
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
            "UPDATE tiles SET lease_expires = ?4, rendering = MAX(rendering, ?5)
             WHERE job_id = ?1 AND idx = ?2 AND lease = ?3 AND state = ",
            tile_sql!(Leased),
            "
               AND EXISTS (SELECT 1 FROM jobs WHERE id = ?1 AND state IN ",
            job_sql!(active),
            ")
             RETURNING worker"
        ))
        .bind(job)
        .bind(i64::from(idx))
        .bind(lease)
        .bind(now.saturating_add(lease_ms as i64))
        .bind(i64::from(rendering))
        // To the statement's end, not its first row: SQLite commits an autocommit statement
        // when it finishes, and a commit that fails (a full disk) must be this call's error,
        // not lost in a reset after the row was taken (the claim was answered with a lease
        // that was never stored).
        .fetch_all(&mut *self.writer.lock().await?)
        .await?
        .into_iter()
        .next();
        Ok(worker.map(Option::unwrap_or_default))
    }

    /// A tile's rectangle, state and lease, with its job's state.
    pub(crate) async fn tile(&self, job: &str, idx: u32) -> Result<Option<TileInfo>> {
        let row = sqlx::query(
            "SELECT t.x, t.y, t.w, t.h, t.state, t.lease, j.state, t.worker FROM tiles t
             JOIN jobs j ON j.id = t.job_id WHERE t.job_id = ?1 AND t.idx = ?2",
        )
        .bind(job)
        .bind(i64::from(idx))
        .fetch_optional(&mut *self.reader().await?)
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
    /// One statement, so one round trip to the writing connection: the insert happens only
    /// `WHERE` all of that holds, and the `tile_pixels_stored` trigger (migration 0002) marks
    /// the tile done and counts it in its job within the same statement. Only when nothing
    /// was stored does a second query find out why. `now` dates a failure to store the
    /// pixels (see [`SqliteStore::storage_trouble`]).
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
        // Spooled, the pixels are written first (see `spool.rs`) and the row gets their CRC,
        // but only under the tile's current lease and for its own rectangle: any other post
        // (stale, foreign, for another tile, or for a job that has ended) writes nothing, so
        // that it cannot touch the pixels of tiles already stored.
        let (blob, crc): (&[u8], Option<i64>) = match &self.spool {
            None => (rgb, None),
            Some(spool) => match self.spooled_size(spool, job).await? {
                Some((width, height)) if self.holds(job, idx, lease, rect).await? => {
                    match spool.write(job, width, height, rect, rgb, now) {
                        Ok(crc) => (&[], Some(i64::from(crc))),
                        Err(SpoolError::Outside { .. }) => (&[], None),
                        Err(e) if e.is_capacity() => {
                            // A full disk: the service's trouble, and it passes. The tile
                            // goes back to the queue uncharged, rather than wait for its
                            // lease to run out and count against the worker (whose job
                            // would fail, blaming workers, after `--max-attempts` such
                            // posts). With the database on the same full disk the requeue
                            // may fail too: then the tile stays leased, and the reaper
                            // extends the leases of workers it hears from while it fails.
                            let e = StoreError::from(e);
                            if let Err(requeue) = self.release(job, idx, lease).await {
                                tracing::error!(
                                    job,
                                    tile = idx,
                                    "cannot store the tile's pixels ({e}), nor queue it again: {requeue}"
                                );
                                return Err(self.noted(requeue, now));
                            }
                            tracing::error!(
                                job,
                                tile = idx,
                                "cannot store the tile's pixels, queued again: {e}"
                            );
                            return Ok(Completion::Unstored(e.to_string()));
                        }
                        Err(e) => {
                            // Any other failure (an I/O error, a file that cannot be
                            // written) may not pass: the tile is queued again with a failure
                            // counted against it, not the worker, as a lost tile is, so that
                            // a disk that keeps failing fails the job with the reason after
                            // `--max-attempts` instead of rendering the tile for ever.
                            tracing::error!(
                                job,
                                tile = idx,
                                "cannot store the tile's pixels, queued again with a failure: {e}"
                            );
                            let reason = format!("its pixels could not be stored: {e}");
                            self.requeue_unstored(job, idx, lease, &reason, now).await?;
                            return Ok(Completion::Unstored(e.to_string()));
                        }
                    }
                }
                _ => (&[], None),
            },
        };
        let spooled = self.spool.is_some();
        let stored: Option<(i64, i64, Option<String>)> = if spooled && crc.is_none() {
            None
        } else {
            self.insert_result(job, idx, lease, rect, blob, crc).await?
        };
        if let Some((done_before, total, worker)) = stored {
            if spooled {
                self.forget_lease(job, idx);
            } else {
                self.wrote(rgb.len());
            }
            // `RETURNING` is computed before the trigger counts this tile (see the migration).
            return Ok(Completion::Stored {
                last: done_before + 1 == total,
                worker,
            });
        }
        Ok(Completion::refused(self.tile(job, idx).await?, lease, true))
    }

    pub(super) fn issued_map(&self) -> std::sync::MutexGuard<'_, Issued> {
        self.issued
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    /// Forgets the lease this process handed out for tile `idx` of `job` (stored, given
    /// back, or queued again): a later post under it writes nothing to the spool.
    pub(super) fn forget_lease(&self, job: &str, idx: u32) {
        self.issued_map().remove(&(job.to_string(), idx));
    }

    /// Whether `lease` is tile `idx`'s current lease and `rect` its rectangle: as this
    /// process handed it out, or else (after a restart) as its row says.
    pub(super) async fn holds(&self, job: &str, idx: u32, lease: &str, rect: Rect) -> Result<bool> {
        let issued = self.issued_map().get(&(job.to_string(), idx)).cloned();
        if let Some((current, tile)) = issued {
            return Ok(current == lease && tile == rect);
        }
        Ok(self.tile(job, idx).await?.is_some_and(|t| {
            t.state == TileState::Leased && t.lease.as_deref() == Some(lease) && t.rect == rect
        }))
    }

    /// Drops what this process keeps of a job whose image is stored, or that was deleted:
    /// its spool file and the leases it handed out.
    pub(super) fn forget_job(&self, id: &str) {
        if let Some(spool) = &self.spool {
            spool.remove(id);
            self.issued_map().retain(|(job, _), _| job != id);
        }
    }

    /// Drops the leases this process handed out for job `id` and closes its spool file,
    /// keeping the file: the job ended without an image (its tiles wait for a retry or its
    /// deletion), or it is retried (its tiles are handed out under new leases).
    pub(super) fn close_job(&self, id: &str) {
        if let Some(spool) = &self.spool {
            spool.close(id);
            self.issued_map().retain(|(job, _), _| job != id);
        }
    }

    /// The image size of job `id`, for its spool file: remembered by the spool once the
    /// file is open, read from the job's row the first time. `None`: no such job, or it
    /// has ended (nothing of it is written any more).
    pub(super) async fn spooled_size(&self, spool: &Spool, id: &str) -> Result<Option<(u32, u32)>> {
        if let Some(size) = spool.size_of(id) {
            return Ok(Some(size));
        }
        let row: Option<(i64, i64)> = sqlx::query_as(concat!(
            "SELECT width, height FROM jobs WHERE id = ?1 AND state IN ",
            job_sql!(active)
        ))
        .bind(id)
        .fetch_optional(&mut *self.reader().await?)
        .await?;
        Ok(row.map(|(w, h)| (w as u32, h as u32)))
    }

    /// The result's one statement: see [`SqliteStore::complete`].
    pub(super) async fn insert_result(
        &self,
        job: &str,
        idx: u32,
        lease: &str,
        rect: Rect,
        blob: &[u8],
        crc: Option<i64>,
    ) -> Result<Option<(i64, i64, Option<String>)>> {
        Ok(sqlx::query_as(concat!(
            "INSERT INTO tile_pixels (job_id, idx, rgb, crc)
             SELECT ?1, ?2, ?4, ?9 WHERE EXISTS (
                 SELECT 1 FROM tiles t JOIN jobs j ON j.id = t.job_id
                 WHERE t.job_id = ?1 AND t.idx = ?2 AND t.lease = ?3 AND t.state = ",
            tile_sql!(Leased),
            "
                   AND t.x = ?5 AND t.y = ?6 AND t.w = ?7 AND t.h = ?8
                   AND j.state IN ",
            job_sql!(active),
            ")
             RETURNING (SELECT tiles_done FROM jobs WHERE id = ?1),
                       (SELECT tiles_total FROM jobs WHERE id = ?1),
                       (SELECT worker FROM tiles WHERE job_id = ?1 AND idx = ?2)"
        ))
        .bind(job)
        .bind(i64::from(idx))
        .bind(lease)
        .bind(blob)
        .bind(i64::from(rect.x))
        .bind(i64::from(rect.y))
        .bind(i64::from(rect.width))
        .bind(i64::from(rect.height))
        .bind(crc)
        // To the statement's end, not its first row: SQLite commits an autocommit statement
        // when it finishes, and a commit that fails (a full disk) must be this call's error,
        // not lost in a reset after the row was taken (the claim was answered with a lease
        // that was never stored).
        .fetch_all(&mut *self.writer.lock().await?)
        .await?
        .into_iter()
        .next())
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
        let mut conn = self.writer.lock().await?;
        let mut tx = conn.begin_with("BEGIN IMMEDIATE").await?;
        let r = sqlx::query(concat!(
            "UPDATE tiles SET state = ",
            tile_sql!(Queued),
            ", lease = NULL, worker = NULL, lease_expires = NULL,
                              failures = failures + 1, last_error = ?4
             WHERE job_id = ?1 AND idx = ?2 AND lease = ?3 AND state = ",
            tile_sql!(Leased),
            "
               AND EXISTS (SELECT 1 FROM jobs WHERE id = ?1 AND state IN ",
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
            "INSERT INTO keep_away (job_id, worker, failures, until) VALUES (?1, ?2, 1, 0)
             ON CONFLICT (job_id, worker) DO UPDATE SET failures = failures + 1",
        )
        .bind(job)
        .bind(worker)
        .execute(&mut *tx)
        .await?;
        Self::apply_keep_away(&mut tx, now, keep).await?;
        Self::fail_exhausted(&mut tx, now, max_attempts).await?;
        tx.commit().await?;
        Ok(true)
    }

    /// Gives a tile back unrendered (a worker shutting down): no failure is counted.
    pub(crate) async fn release(&self, job: &str, idx: u32, lease: &str) -> Result<bool> {
        let r = sqlx::query(concat!(
            "UPDATE tiles SET state = ",
            tile_sql!(Queued),
            ", lease = NULL, worker = NULL, lease_expires = NULL
             WHERE job_id = ?1 AND idx = ?2 AND lease = ?3 AND state = ",
            tile_sql!(Leased),
            "
               AND EXISTS (SELECT 1 FROM jobs WHERE id = ?1 AND state IN ",
            job_sql!(active),
            ")"
        ))
        .bind(job)
        .bind(i64::from(idx))
        .bind(lease)
        .execute(&mut *self.writer.lock().await?)
        .await?;
        let released = r.rows_affected() == 1;
        if released {
            // The lease is no longer current: a late post under it writes nothing.
            self.forget_lease(job, idx);
        }
        Ok(released)
    }

    /// Queues tile `idx` again, under `lease`, with a failure counted against the tile
    /// alone (its pixels could not be stored for a reason that may not pass), failing the
    /// job if the tile is out of attempts.
    pub(super) async fn requeue_unstored(
        &self,
        job: &str,
        idx: u32,
        lease: &str,
        reason: &str,
        now: i64,
    ) -> Result<()> {
        let mut conn = self.writer.lock().await?;
        let mut tx = conn.begin_with("BEGIN IMMEDIATE").await?;
        let r = sqlx::query(concat!(
            "UPDATE tiles SET state = ",
            tile_sql!(Queued),
            ", lease = NULL, worker = NULL,
                    lease_expires = NULL, rendering = 0, failures = failures + 1,
                    last_error = ?4
             WHERE job_id = ?1 AND idx = ?2 AND lease = ?3 AND state = ",
            tile_sql!(Leased),
            "
               AND EXISTS (SELECT 1 FROM jobs WHERE id = ?1 AND state IN ",
            job_sql!(active),
            ")"
        ))
        .bind(job)
        .bind(i64::from(idx))
        .bind(lease)
        .bind(reason)
        .execute(&mut *tx)
        .await?;
        if r.rows_affected() == 1 {
            Self::fail_exhausted(&mut tx, now, self.max_attempts).await?;
        }
        tx.commit().await?;
        drop(conn);
        self.forget_lease(job, idx);
        Ok(())
    }

    /// After a restart: every live lease gets a fresh `lease_ms`, so workers that rode
    /// through the outage can still post what they rendered.
    pub(crate) async fn extend_leases(&self, now: i64, lease_ms: u64) -> Result<u64> {
        let r = sqlx::query(concat!(
            "UPDATE tiles SET lease_expires = ?1 WHERE state = ",
            tile_sql!(Leased)
        ))
        .bind(now.saturating_add(lease_ms as i64))
        .execute(&mut *self.writer.lock().await?)
        .await?;
        Ok(r.rows_affected())
    }
}
