//! Jobs: storing one with its tiles and assets, listing, cancelling, deleting, and what a
//! worker reads of one (scene, assets).

use tessera_protocol::JobSpec;
use tessera_tracer::Rect;

use super::notify::{ENDED, WORK, channel, notify_sql};
use super::{PgStore, Result, job_state};
use crate::store::state::{JobState, job_sql, tile_sql};
use crate::store::types::{Cancel, JobRow, NewJob, Retried};

/// The columns of a [`JobRow`], in its order.
macro_rules! job_columns {
    () => {
        "id, state, name, width, height, tile, sampler, samples, threshold, tiles_total, \
         tiles_done, error, created_at, started_at, finished_at, png_bytes, priority"
    };
}

/// Tiles stored by one `INSERT` when a job is stored: each is a row of five arrays bound
/// as parameters, so a job of half a million tiles is a few hundred statements, not one
/// per tile nor one of a hundred megabytes.
const TILES_PER_INSERT: usize = 2000;

impl PgStore {
    /// Stores a job, its tiles and its assets in one transaction, and wakes the claims
    /// waiting on every replica once it commits.
    pub(crate) async fn insert_job(
        &self,
        job: &NewJob,
        tiles: &[Rect],
        assets: &[(String, Vec<u8>)],
    ) -> Result<JobRow> {
        let mut tx = self.pool.begin().await?;
        let row: JobRow = sqlx::query_as(concat!(
            "INSERT INTO jobs (id, state, name, width, height, tile, sampler, samples,
                               threshold, tiles_total, created_at, priority)
             VALUES ($1, ",
            job_sql!(Queued),
            ", $2, $3, $4, $5, $6, $7, $8, $9, $10, $11)
             RETURNING ",
            job_columns!()
        ))
        .bind(&job.id)
        .bind(&job.name)
        .bind(i64::from(job.width))
        .bind(i64::from(job.height))
        .bind(i64::from(job.tile))
        .bind(&job.sampler)
        .bind(job.samples.map(i64::from))
        .bind(job.threshold)
        .bind(tiles.len() as i64)
        .bind(job.created_at)
        .bind(job.priority)
        .fetch_one(&mut *tx)
        .await?;
        sqlx::query("INSERT INTO job_scenes (job_id, scene) VALUES ($1, $2)")
            .bind(&job.id)
            .bind(&job.scene)
            .execute(&mut *tx)
            .await?;
        for (chunk, rows) in tiles.chunks(TILES_PER_INSERT).enumerate() {
            let first = (chunk * TILES_PER_INSERT) as i64;
            let idx: Vec<i64> = (first..first + rows.len() as i64).collect();
            let col = |f: fn(&Rect) -> u32| rows.iter().map(|r| i64::from(f(r))).collect();
            let (x, y, w, h): (Vec<i64>, Vec<i64>, Vec<i64>, Vec<i64>) = (
                col(|r| r.x),
                col(|r| r.y),
                col(|r| r.width),
                col(|r| r.height),
            );
            sqlx::query(concat!(
                "INSERT INTO tiles (job_id, idx, x, y, w, h, state)
                 SELECT $1, idx, x, y, w, h, ",
                tile_sql!(Queued),
                " FROM UNNEST($2::BIGINT[], $3::BIGINT[], $4::BIGINT[], $5::BIGINT[],
                              $6::BIGINT[]) AS t(idx, x, y, w, h)"
            ))
            .bind(&job.id)
            .bind(idx)
            .bind(x)
            .bind(y)
            .bind(w)
            .bind(h)
            .execute(&mut *tx)
            .await?;
        }
        for (name, bytes) in assets {
            sqlx::query("INSERT INTO assets (job_id, name, bytes) VALUES ($1, $2, $3)")
                .bind(&job.id)
                .bind(name)
                .bind(bytes)
                .execute(&mut *tx)
                .await?;
        }
        sqlx::query(notify_sql(WORK)).execute(&mut *tx).await?;
        tx.commit().await?;
        Ok(row)
    }

    /// Jobs, newest first: at most `limit`, and with `before`, only those submitted before
    /// that job (a page after the one that ended with it). `None` when `before` names no job.
    pub(crate) async fn jobs(
        &self,
        limit: u32,
        before: Option<&str>,
    ) -> Result<Option<Vec<JobRow>>> {
        let below = match before {
            None => i64::MAX,
            Some(id) => {
                let seq: Option<i64> = sqlx::query_scalar("SELECT seq FROM jobs WHERE id = $1")
                    .bind(id)
                    .fetch_optional(&self.pool)
                    .await?;
                let Some(seq) = seq else { return Ok(None) };
                seq
            }
        };
        Ok(Some(
            sqlx::query_as(concat!(
                "SELECT ",
                job_columns!(),
                " FROM jobs WHERE seq < $2 ORDER BY seq DESC LIMIT $1"
            ))
            .bind(i64::from(limit))
            .bind(below)
            .fetch_all(&self.pool)
            .await?,
        ))
    }

    pub(crate) async fn job(&self, id: &str) -> Result<Option<JobRow>> {
        Ok(sqlx::query_as(concat!(
            "SELECT ",
            job_columns!(),
            " FROM jobs WHERE id = $1"
        ))
        .bind(id)
        .fetch_optional(&self.pool)
        .await?)
    }

    /// Cancels a queued or running job (its tiles are no longer handed out and results for
    /// it are refused) and drops the chunks of its image encoded so far (by the schema's
    /// trigger; its stored tiles stay for a retry), unless every tile is already in: then
    /// the job is as good as done (its image is being written). The job's row is locked
    /// first, so a result counted meanwhile is either before (and seen here) or after (and
    /// kept with the others).
    pub(crate) async fn cancel(&self, id: &str, now: i64) -> Result<Cancel> {
        let mut tx = self.pool.begin().await?;
        let before: Option<(String, i64, i64)> = sqlx::query_as(
            "SELECT state, tiles_done, tiles_total FROM jobs WHERE id = $1 FOR UPDATE",
        )
        .bind(id)
        .fetch_optional(&mut *tx)
        .await?;
        let before = match before {
            Some((state, done, total)) => Some((job_state(state)?, done, total)),
            None => None,
        };
        let outcome = match before {
            None => Cancel::Unknown,
            Some((_, done, total)) if done >= total => Cancel::Complete,
            Some((from, _, _)) if from.is_active() => {
                sqlx::query(concat!(
                    "UPDATE jobs SET state = ",
                    job_sql!(Cancelled),
                    ", finished_at = $2 WHERE id = $1"
                ))
                .bind(id)
                .bind(now)
                .execute(&mut *tx)
                .await?;
                sqlx::query(notify_sql(ENDED)).execute(&mut *tx).await?;
                Cancel::Cancelled { from }
            }
            Some((state, _, _)) => Cancel::Ended { state },
        };
        tx.commit().await?;
        Ok(outcome)
    }

    /// Makes a failed or cancelled job active again: its stored tiles stay, every other tile
    /// is queued with its failures forgotten, and no worker is kept away from it any more.
    /// Its time so far is kept (its start moves by the time it spent ended). Wakes the
    /// claims waiting on every replica once it commits.
    pub(crate) async fn retry(&self, id: &str, now: i64) -> Result<Retried> {
        let mut tx = self.pool.begin().await?;
        let state: Option<String> =
            sqlx::query_scalar("SELECT state FROM jobs WHERE id = $1 FOR UPDATE")
                .bind(id)
                .fetch_optional(&mut *tx)
                .await?;
        let state = match state {
            None => return Ok(Retried::Unknown),
            Some(s) => job_state(s)?,
        };
        if !matches!(state, JobState::Failed | JobState::Cancelled) {
            return Ok(Retried::NotEnded(state));
        }
        // A tile is kept only with its pixels: a `done` row without them (stored under a
        // schema that dropped an ended job's pixels) is rendered again.
        sqlx::query(concat!(
            "UPDATE tiles SET state = ",
            tile_sql!(Queued),
            ", lease = NULL, worker = NULL, lease_expires = NULL, rendering = FALSE,
                   failures = 0, last_error = NULL
             WHERE job_id = $1 AND (state <> ",
            tile_sql!(Done),
            " OR NOT EXISTS (SELECT 1 FROM tile_pixels p
                             WHERE p.job_id = tiles.job_id AND p.idx = tiles.idx))"
        ))
        .bind(id)
        .execute(&mut *tx)
        .await?;
        sqlx::query("DELETE FROM keep_away WHERE job_id = $1")
            .bind(id)
            .execute(&mut *tx)
            .await?;
        // `running` once started, so that the first claim does not date its start again.
        let (done, total): (i64, i64) = sqlx::query_as(concat!(
            "UPDATE jobs SET
                 state = CASE WHEN started_at IS NULL THEN ",
            job_sql!(Queued),
            " ELSE ",
            job_sql!(Running),
            " END,
                 started_at = $2 - (COALESCE(finished_at, $2) - started_at),
                 finished_at = NULL, error = NULL, png_bytes = NULL,
                 tiles_done = (SELECT COUNT(*) FROM tile_pixels WHERE job_id = $1)
             WHERE id = $1
             RETURNING tiles_done, tiles_total"
        ))
        .bind(id)
        .bind(now)
        .fetch_one(&mut *tx)
        .await?;
        sqlx::query(notify_sql(WORK)).execute(&mut *tx).await?;
        tx.commit().await?;
        Ok(Retried::Retried {
            complete: done >= total,
        })
    }

    /// Removes a job and everything stored for it.
    pub(crate) async fn delete(&self, id: &str) -> Result<bool> {
        let mut tx = self.pool.begin().await?;
        let r = sqlx::query("DELETE FROM jobs WHERE id = $1")
            .bind(id)
            .execute(&mut *tx)
            .await?;
        let deleted = r.rows_affected() > 0;
        if deleted {
            sqlx::query(notify_sql(ENDED)).execute(&mut *tx).await?;
        }
        tx.commit().await?;
        Ok(deleted)
    }

    /// The ids of queued and running jobs.
    pub(crate) async fn active_jobs(&self) -> Result<Vec<String>> {
        Ok(sqlx::query_scalar(concat!(
            "SELECT id FROM jobs WHERE state IN ",
            job_sql!(active),
            " ORDER BY seq"
        ))
        .fetch_all(&self.pool)
        .await?)
    }

    /// Jobs whose tiles are all in but whose image is not yet assembled.
    pub(crate) async fn unassembled(&self) -> Result<Vec<String>> {
        Ok(sqlx::query_scalar(concat!(
            "SELECT id FROM jobs WHERE state IN ",
            job_sql!(active),
            " AND tiles_done = tiles_total ORDER BY seq"
        ))
        .fetch_all(&self.pool)
        .await?)
    }

    /// A job's state, and what a worker needs of it: scene, sampler settings, asset names.
    pub(crate) async fn job_scene(&self, id: &str) -> Result<Option<(JobState, JobSpec)>> {
        type SceneRow = (String, String, Option<String>, Option<i64>, Option<f64>);
        let row: Option<SceneRow> = sqlx::query_as(
            "SELECT state, scene, sampler, samples, threshold
             FROM jobs JOIN job_scenes ON job_scenes.job_id = jobs.id WHERE id = $1",
        )
        .bind(id)
        .fetch_optional(&self.pool)
        .await?;
        let Some((state, scene, sampler, samples, threshold)) = row else {
            return Ok(None);
        };
        let assets = sqlx::query_scalar("SELECT name FROM assets WHERE job_id = $1 ORDER BY name")
            .bind(id)
            .fetch_all(&self.pool)
            .await?;
        let spec = JobSpec {
            id: id.to_string(),
            scene,
            sampler,
            samples: samples.map(|s| s as u32),
            threshold,
            assets,
        };
        Ok(Some((job_state(state)?, spec)))
    }

    pub(crate) async fn asset(&self, id: &str, name: &str) -> Result<Option<Vec<u8>>> {
        Ok(
            sqlx::query_scalar("SELECT bytes FROM assets WHERE job_id = $1 AND name = $2")
                .bind(id)
                .bind(name)
                .fetch_optional(&self.pool)
                .await?,
        )
    }

    /// Fails a job whose image could not be assembled.
    pub(crate) async fn fail_job(&self, id: &str, reason: &str, now: i64) -> Result<()> {
        sqlx::query(concat!(
            "WITH f AS (UPDATE jobs SET state = ",
            job_sql!(Failed),
            ", error = $2, finished_at = $3
                 WHERE id = $1 AND state IN ",
            job_sql!(active),
            " RETURNING 1)
             SELECT pg_notify(",
            channel!(ENDED),
            ", '') FROM f"
        ))
        .bind(id)
        .bind(reason)
        .bind(now)
        .fetch_all(&self.pool)
        .await?;
        Ok(())
    }
}
