//! Jobs: storing one with its tiles and assets, listing, cancelling, deleting, and what a
//! worker reads of one (scene, assets).

use sqlx::Connection;
use tessera_protocol::JobSpec;
use tessera_tracer::Rect;

use super::{Result, SqliteStore, job_state};
use crate::store::error::StoreError;
use crate::store::state::{JobState, job_sql, tile_sql};
use crate::store::types::{Cancel, JobRow, NewJob, Retried};

const JOB_COLUMNS: &str = "id, state, name, width, height, tile, sampler, samples, threshold, \
     tiles_total, tiles_done, error, created_at, started_at, finished_at, png_bytes, priority";

/// Tiles stored by one `INSERT` when a job is stored.
///
/// One statement per tile would be one round trip to SQLite's thread per tile, inside the
/// transaction that holds the only writer: a job of half a million tiles would keep every
/// claim and result of every other job waiting for seconds.
const TILES_PER_INSERT: usize = 1000;

/// `INSERT INTO tiles … VALUES (?1, idx, x, y, w, h, 'queued'), …` for `rows`, numbered
/// from `first`, with the job id as the only parameter. The numbers are written into the
/// statement's text: they are integers this process computed (`Rect`'s `u32`s and the
/// index), never text from a request, so the text cannot carry anything else; binding them
/// instead would take six parameters a row, and SQLite allows 32,766 in all.
fn tile_insert(first: usize, rows: &[Rect]) -> String {
    use std::fmt::Write;
    let mut sql = String::with_capacity(64 + rows.len() * 48);
    sql.push_str("INSERT INTO tiles (job_id, idx, x, y, w, h, state) VALUES ");
    for (i, r) in rows.iter().enumerate() {
        if i > 0 {
            sql.push_str(", ");
        }
        // Writing to a `String` cannot fail.
        let _ = write!(
            sql,
            concat!("(?1, {}, {}, {}, {}, {}, ", tile_sql!(Queued), ")"),
            first + i,
            r.x,
            r.y,
            r.width,
            r.height
        );
    }
    sql
}

impl SqliteStore {
    /// Stores a job, its tiles and its assets in one transaction.
    pub(crate) async fn insert_job(
        &self,
        job: &NewJob,
        tiles: &[Rect],
        assets: &[(String, Vec<u8>)],
    ) -> Result<JobRow> {
        let mut conn = self.writer.lock().await?;
        let mut tx = conn.begin_with("BEGIN IMMEDIATE").await?;
        sqlx::query(concat!(
            "INSERT INTO jobs (id, seq, state, name, width, height, tile, sampler, samples,
                               threshold, tiles_total, created_at, priority)
             VALUES (?1, (SELECT COALESCE(MAX(seq), 0) + 1 FROM jobs), ",
            job_sql!(Queued),
            ", ?2, ?3, ?4,
                     ?5, ?6, ?7, ?8, ?9, ?10, ?11)"
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
        .execute(&mut *tx)
        .await?;
        sqlx::query("INSERT INTO job_scenes (job_id, scene) VALUES (?1, ?2)")
            .bind(&job.id)
            .bind(&job.scene)
            .execute(&mut *tx)
            .await?;
        for (chunk, rows) in tiles.chunks(TILES_PER_INSERT).enumerate() {
            sqlx::query(sqlx::AssertSqlSafe(tile_insert(
                chunk * TILES_PER_INSERT,
                rows,
            )))
            // Text of its own for every job: kept out of the writer's cache of prepared
            // statements (a hundred), where it pushed out the claim's and the result's.
            .persistent(false)
            .bind(&job.id)
            .execute(&mut *tx)
            .await?;
        }
        for (name, bytes) in assets {
            sqlx::query("INSERT INTO assets (job_id, name, bytes) VALUES (?1, ?2, ?3)")
                .bind(&job.id)
                .bind(name)
                .bind(bytes)
                .execute(&mut *tx)
                .await?;
        }
        tx.commit().await?;
        // The reading below may be on the writer's connection (an in-memory database).
        drop(conn);
        // The scene and textures go into the WAL too, so they count towards the next
        // checkpoint as pixels do; else large submissions would let the WAL grow unchecked.
        self.wrote(job.scene.len() + assets.iter().map(|(_, b)| b.len()).sum::<usize>());
        self.job(&job.id).await?.ok_or_else(|| {
            StoreError::Db(sqlx::Error::Protocol("job vanished after insert".into()))
        })
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
                let seq: Option<i64> = sqlx::query_scalar("SELECT seq FROM jobs WHERE id = ?1")
                    .bind(id)
                    .fetch_optional(&mut *self.reader().await?)
                    .await?;
                let Some(seq) = seq else { return Ok(None) };
                seq
            }
        };
        let sql =
            format!("SELECT {JOB_COLUMNS} FROM jobs WHERE seq < ?2 ORDER BY seq DESC LIMIT ?1");
        Ok(Some(
            sqlx::query_as(sqlx::AssertSqlSafe(sql))
                .bind(i64::from(limit))
                .bind(below)
                .fetch_all(&mut *self.reader().await?)
                .await?,
        ))
    }

    pub(crate) async fn job(&self, id: &str) -> Result<Option<JobRow>> {
        let sql = format!("SELECT {JOB_COLUMNS} FROM jobs WHERE id = ?1");
        Ok(sqlx::query_as(sqlx::AssertSqlSafe(sql))
            .bind(id)
            .fetch_optional(&mut *self.reader().await?)
            .await?)
    }

    /// Cancels a queued or running job (its tiles are no longer handed out and results for
    /// it are refused) and drops the chunks of its image encoded so far (by the migrations'
    /// trigger; its stored tiles stay for a retry), unless every tile is already in: then the job is as good as done (its image is being
    /// written), and throwing the pixels away would lose a finished render that a worker was
    /// told was stored.
    pub(crate) async fn cancel(&self, id: &str, now: i64) -> Result<Cancel> {
        let mut conn = self.writer.lock().await?;
        let mut tx = conn.begin_with("BEGIN IMMEDIATE").await?;
        let before: Option<(String, i64, i64)> =
            sqlx::query_as("SELECT state, tiles_done, tiles_total FROM jobs WHERE id = ?1")
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
                // The `job_ended_without_image` trigger drops its image chunks.
                sqlx::query(concat!(
                    "UPDATE jobs SET state = ",
                    job_sql!(Cancelled),
                    ", finished_at = ?2 WHERE id = ?1"
                ))
                .bind(id)
                .bind(now)
                .execute(&mut *tx)
                .await?;
                Cancel::Cancelled { from }
            }
            Some((state, _, _)) => Cancel::Ended { state },
        };
        tx.commit().await?;
        drop(conn);
        if let Cancel::Cancelled { .. } = outcome {
            self.close_job(id);
        }
        Ok(outcome)
    }

    /// Makes a failed or cancelled job active again: its stored tiles stay, every other tile
    /// is queued with its failures forgotten, and no worker is kept away from it any more.
    /// Its time so far is kept (its start moves by the time it spent ended), so that its
    /// elapsed time and time left go on from where they were.
    pub(crate) async fn retry(&self, id: &str, now: i64) -> Result<Retried> {
        let mut conn = self.writer.lock().await?;
        let mut tx = conn.begin_with("BEGIN IMMEDIATE").await?;
        let state: Option<String> = sqlx::query_scalar("SELECT state FROM jobs WHERE id = ?1")
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
            ", lease = NULL, worker = NULL, lease_expires = NULL, rendering = 0,
                   failures = 0, last_error = NULL
             WHERE job_id = ?1 AND (state <> ",
            tile_sql!(Done),
            " OR NOT EXISTS (SELECT 1 FROM tile_pixels p
                             WHERE p.job_id = tiles.job_id AND p.idx = tiles.idx))"
        ))
        .bind(id)
        .execute(&mut *tx)
        .await?;
        sqlx::query("DELETE FROM keep_away WHERE job_id = ?1")
            .bind(id)
            .execute(&mut *tx)
            .await?;
        // `running` once started, so that the first claim (the `job_started` trigger) does
        // not date its start again.
        let (done, total): (i64, i64) = sqlx::query_as(concat!(
            "UPDATE jobs SET
                 state = CASE WHEN started_at IS NULL THEN ",
            job_sql!(Queued),
            " ELSE ",
            job_sql!(Running),
            " END,
                 started_at = ?2 - (COALESCE(finished_at, ?2) - started_at),
                 finished_at = NULL, error = NULL, png_bytes = NULL,
                 tiles_done = (SELECT COUNT(*) FROM tile_pixels WHERE job_id = ?1)
             WHERE id = ?1
             RETURNING tiles_done, tiles_total"
        ))
        .bind(id)
        .bind(now)
        .fetch_one(&mut *tx)
        .await?;
        tx.commit().await?;
        drop(conn);
        self.close_job(id);
        Ok(Retried::Retried {
            complete: done >= total,
        })
    }

    /// Removes a finished job and everything stored for it.
    pub(crate) async fn delete(&self, id: &str) -> Result<bool> {
        let r = sqlx::query("DELETE FROM jobs WHERE id = ?1")
            .bind(id)
            .execute(&mut *self.writer.lock().await?)
            .await?;
        self.forget_job(id);
        Ok(r.rows_affected() > 0)
    }

    /// The ids of queued and running jobs.
    pub(crate) async fn active_jobs(&self) -> Result<Vec<String>> {
        Ok(sqlx::query_scalar(concat!(
            "SELECT id FROM jobs WHERE state IN ",
            job_sql!(active)
        ))
        .fetch_all(&mut *self.reader().await?)
        .await?)
    }

    /// Jobs whose tiles are all in but whose image is not yet assembled (after a restart).
    pub(crate) async fn unassembled(&self) -> Result<Vec<String>> {
        Ok(sqlx::query_scalar(concat!(
            "SELECT id FROM jobs WHERE state IN ",
            job_sql!(active),
            " AND tiles_done = tiles_total
             ORDER BY seq"
        ))
        .fetch_all(&mut *self.reader().await?)
        .await?)
    }

    /// A job's state, and what a worker needs of it: scene, sampler settings, asset names.
    pub(crate) async fn job_scene(&self, id: &str) -> Result<Option<(JobState, JobSpec)>> {
        type SceneRow = (String, String, Option<String>, Option<i64>, Option<f64>);
        let row: Option<SceneRow> = sqlx::query_as(
            "SELECT state, scene, sampler, samples, threshold
             FROM jobs JOIN job_scenes ON job_scenes.job_id = jobs.id WHERE id = ?1",
        )
        .bind(id)
        .fetch_optional(&mut *self.reader().await?)
        .await?;
        let Some((state, scene, sampler, samples, threshold)) = row else {
            return Ok(None);
        };
        let assets = sqlx::query_scalar("SELECT name FROM assets WHERE job_id = ?1 ORDER BY name")
            .bind(id)
            .fetch_all(&mut *self.reader().await?)
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
            sqlx::query_scalar("SELECT bytes FROM assets WHERE job_id = ?1 AND name = ?2")
                .bind(id)
                .bind(name)
                .fetch_optional(&mut *self.reader().await?)
                .await?,
        )
    }

    /// Fails a job whose image could not be assembled.
    pub(crate) async fn fail_job(&self, id: &str, reason: &str, now: i64) -> Result<()> {
        sqlx::query(concat!(
            "UPDATE jobs SET state = ",
            job_sql!(Failed),
            ", error = ?2, finished_at = ?3
             WHERE id = ?1 AND state IN ",
            job_sql!(active)
        ))
        .bind(id)
        .bind(reason)
        .bind(now)
        .execute(&mut *self.writer.lock().await?)
        .await?;
        Ok(())
    }
}
