//! Images: the stored tiles of a band read back for the PNG (from the spool or the rows),
//! lost tiles handed out again, the PNG's chunks, and the end of an assembled job.

use sqlx::{Connection, Row};
use tessera_tracer::Rect;

use super::spool::Spool;
use super::{Result, SqliteStore, job_state};
use crate::store::error::StoreError;
use crate::store::state::{job_sql, tile_sql};
use crate::store::types::BandTile;

/// A band's stored tiles, left to right (see [`SqliteStore::band`]).
pub(super) const BAND_SQL: &str = "SELECT t.x, t.w, t.h, p.rgb, p.crc, t.idx FROM tiles t
     JOIN tile_pixels p ON p.job_id = t.job_id AND p.idx = t.idx
     WHERE t.job_id = ?1 AND t.y = ?2 ORDER BY t.idx";

impl SqliteStore {
    /// The stored tiles of one band of rows starting at `y`, left to right: each tile's
    /// bytes are appended to `buf` (cleared first, its capacity kept from band to band), and
    /// the tiles are returned in order with where their bytes are in it.
    ///
    /// The rows come in `idx` order from the `tiles_by_band` index (migration 0003), which
    /// within a band is left to right, so SQLite sorts nothing. A spooled tile's pixels are
    /// read from the job's spool file straight into `buf` and checked against the row's
    /// CRC; pixels kept in the row (an in-memory database, rows from before migration 0011)
    /// are copied from it.
    ///
    /// Tiles whose spooled pixels are missing or do not match are lost: they are queued
    /// again ([`SqliteStore::requeue_lost`]) and the call fails with [`StoreError::Lost`].
    ///
    /// Read on the writing connection, taken in turn with the results and claims: a band
    /// is one short read, and the rows of pixels kept in SQLite are still in its cache.
    pub(crate) async fn band(
        &self,
        id: &str,
        y: u32,
        now: i64,
        buf: &mut Vec<u8>,
    ) -> Result<Vec<BandTile>> {
        buf.clear();
        let rows = sqlx::query(BAND_SQL)
            .bind(id)
            .bind(i64::from(y))
            .fetch_all(&mut *self.writer.lock().await?)
            .await?;
        let mut tiles = Vec::with_capacity(rows.len());
        let mut lost = Vec::new();
        // The job's image size, looked up once a band (and only if a row is spooled).
        let mut size = None;
        for row in &rows {
            let (x, w, h): (i64, i64, i64) = (row.try_get(0)?, row.try_get(1)?, row.try_get(2)?);
            let (x, w, h) = (x as u32, w as u32, h as u32);
            let crc: Option<i64> = row.try_get(4)?;
            let start = buf.len();
            let read = match (crc, &self.spool) {
                (Some(crc), Some(spool)) => {
                    if size.is_none() {
                        size = Some(self.spooled_size(spool, id).await?);
                    }
                    match size.flatten() {
                        Some((width, height)) => {
                            spool.read(id, width, height, Rect::new(x, y, w, h), crc as u32, buf)
                        }
                        None => false,
                    }
                }
                // A spooled row read without a spool (the database moved to memory: cannot
                // happen, an in-memory database is new) is lost like a missing file.
                (Some(_), None) => false,
                (None, _) => {
                    buf.extend_from_slice(row.try_get::<&[u8], _>(3)?);
                    true
                }
            };
            if read {
                tiles.push(BandTile {
                    x,
                    w,
                    h,
                    bytes: start..buf.len(),
                });
            } else {
                lost.push(row.try_get::<i64, _>(5)?);
            }
        }
        if !lost.is_empty() {
            let tiles = self.requeue_lost(id, &lost, now).await?;
            tracing::warn!(job = %id, y, tiles, "tile pixels lost from the spool: rendering them again");
            return Err(StoreError::Lost {
                job: id.to_string(),
                tiles: lost.len(),
            });
        }
        Ok(tiles)
    }

    /// Hands out again the done tiles `idxs` of an active job whose pixels were lost: their
    /// rows go, the tiles are queued and the job counts them as not done. Each loss counts
    /// a failure against its tile, not against any worker (none did anything wrong), so
    /// that a tile whose pixels keep being lost (a failing disk, a folder something else
    /// empties) fails its job after `max_attempts` losses with the reason, instead of being
    /// rendered for ever. Returns how many tiles were requeued.
    pub(crate) async fn requeue_lost(&self, id: &str, idxs: &[i64], now: i64) -> Result<u64> {
        let mut conn = self.writer.lock().await?;
        let mut tx = conn.begin_with("BEGIN IMMEDIATE").await?;
        let mut requeued = 0;
        for &idx in idxs {
            let r = sqlx::query(concat!(
                "UPDATE tiles SET state = ",
                tile_sql!(Queued),
                ", lease = NULL, worker = NULL,
                        lease_expires = NULL, rendering = 0, failures = failures + 1,
                        last_error = 'its pixels were lost from the tile spool'
                 WHERE job_id = ?1 AND idx = ?2 AND state = ",
                tile_sql!(Done),
                "
                   AND EXISTS (SELECT 1 FROM jobs WHERE id = ?1 AND state IN ",
                job_sql!(active),
                ")"
            ))
            .bind(id)
            .bind(idx)
            .execute(&mut *tx)
            .await?;
            if r.rows_affected() == 1 {
                sqlx::query("DELETE FROM tile_pixels WHERE job_id = ?1 AND idx = ?2")
                    .bind(id)
                    .bind(idx)
                    .execute(&mut *tx)
                    .await?;
                requeued += 1;
            }
        }
        sqlx::query("UPDATE jobs SET tiles_done = tiles_done - ?2 WHERE id = ?1")
            .bind(id)
            .bind(requeued as i64)
            .execute(&mut *tx)
            .await?;
        Self::fail_exhausted(&mut tx, now, self.max_attempts).await?;
        tx.commit().await?;
        Ok(requeued)
    }

    pub(crate) async fn clear_image(&self, id: &str) -> Result<()> {
        sqlx::query("DELETE FROM image_chunks WHERE job_id = ?1")
            .bind(id)
            .execute(&mut *self.writer.lock().await?)
            .await?;
        Ok(())
    }

    /// Stores `pieces` as the job's PNG chunks `first_seq`, `first_seq + 1`, …, a hundred to
    /// a statement, unless the job has ended meanwhile (a cancelled job's chunks are dropped with it and
    /// must not come back).
    pub(crate) async fn put_image_chunks(
        &self,
        id: &str,
        first_seq: u32,
        pieces: &[&[u8]],
    ) -> Result<()> {
        const PER_STATEMENT: usize = 100;
        for (n, group) in pieces.chunks(PER_STATEMENT).enumerate() {
            let values = (0..group.len())
                .map(|i| format!("(?{}, ?{})", 2 + 2 * i, 3 + 2 * i))
                .collect::<Vec<_>>()
                .join(", ");
            let sql = format!(
                concat!(
                    "INSERT INTO image_chunks (job_id, seq, bytes)
                 SELECT ?1, column1, column2 FROM (VALUES {})
                 WHERE EXISTS (SELECT 1 FROM jobs WHERE id = ?1 AND state IN ",
                    job_sql!(active),
                    ")"
                ),
                values
            );
            // Only placeholders are formatted in: the values are bound. One text per group
            // size: kept out of the writer's statement cache, as the tiles' insert is.
            let mut q = sqlx::query(sqlx::AssertSqlSafe(sql))
                .persistent(false)
                .bind(id);
            let first = i64::from(first_seq) + (n * PER_STATEMENT) as i64;
            for (i, piece) in group.iter().enumerate() {
                q = q.bind(first + i as i64).bind(*piece);
            }
            q.execute(&mut *self.writer.lock().await?).await?;
            self.wrote(group.iter().map(|p| p.len()).sum());
        }
        Ok(())
    }

    /// Marks an assembled job done and drops its tile pixels. False (and the image dropped)
    /// when the job ended meanwhile; its pixels then stay for a retry.
    pub(crate) async fn finish_image(&self, id: &str, png_bytes: u64, now: i64) -> Result<bool> {
        let mut conn = self.writer.lock().await?;
        let mut tx = conn.begin_with("BEGIN IMMEDIATE").await?;
        let r = sqlx::query(concat!(
            "UPDATE jobs SET state = ",
            job_sql!(Done),
            ", finished_at = ?2, png_bytes = ?3
             WHERE id = ?1 AND state IN ",
            job_sql!(active),
            " AND tiles_done = tiles_total"
        ))
        .bind(id)
        .bind(now)
        .bind(png_bytes as i64)
        .execute(&mut *tx)
        .await?;
        let done = r.rows_affected() == 1;
        if !done {
            sqlx::query("DELETE FROM image_chunks WHERE job_id = ?1")
                .bind(id)
                .execute(&mut *tx)
                .await?;
        }
        // The pixels go with a stored image only. A job still active had a tile handed
        // out again meanwhile (its pixels lost), and the others wait for the next
        // assembly; one that ended without an image keeps them for a retry.
        if done {
            sqlx::query("DELETE FROM tile_pixels WHERE job_id = ?1")
                .bind(id)
                .execute(&mut *tx)
                .await?;
        }
        tx.commit().await?;
        drop(conn);
        if done {
            self.forget_job(id);
        }
        Ok(done)
    }

    /// The number of chunks of a job's PNG.
    pub(crate) async fn image_chunks(&self, id: &str) -> Result<u32> {
        let n: i64 = sqlx::query_scalar("SELECT COUNT(*) FROM image_chunks WHERE job_id = ?1")
            .bind(id)
            .fetch_one(&mut *self.reader().await?)
            .await?;
        Ok(n as u32)
    }

    pub(crate) async fn image_chunk(&self, id: &str, seq: u32) -> Result<Option<Vec<u8>>> {
        Ok(
            sqlx::query_scalar("SELECT bytes FROM image_chunks WHERE job_id = ?1 AND seq = ?2")
                .bind(id)
                .bind(i64::from(seq))
                .fetch_optional(&mut *self.reader().await?)
                .await?,
        )
    }

    /// Deletes the spool files of jobs whose image is stored or that were deleted, and
    /// closes those of jobs that ended without an image (kept for a retry; see
    /// [`Spool::sweep`]); returns how many files went. A finished image's file goes at
    /// once; this catches the rest (deletions, a crash).
    pub(crate) async fn sweep_spool(&self) -> Result<usize> {
        let Some(spool) = &self.spool else {
            return Ok(0);
        };
        let listing = spool.listing()?;
        if listing.is_empty() && self.issued_map().is_empty() {
            return Ok(0);
        }
        let jobs: Vec<(String, String)> = sqlx::query_as(concat!(
            "SELECT id, state FROM jobs WHERE state <> ",
            job_sql!(Done)
        ))
        .fetch_all(&mut *self.reader().await?)
        .await?;
        let mut active = Vec::new();
        let mut kept = Vec::with_capacity(jobs.len());
        for (id, state) in jobs {
            if job_state(state)?.is_active() {
                active.push(id.clone());
            }
            kept.push(id);
        }
        // A job submitted since `active` was read loses its entries here: its results then
        // read their tile's row instead, one query slower.
        self.issued_map()
            .retain(|(job, _), _| active.iter().any(|a| a == job));
        Ok(spool.sweep(&listing, &active, &kept))
    }

    /// The spool's folder; `None` for an in-memory database.
    pub(crate) fn spool_dir(&self) -> Option<&std::path::Path> {
        self.spool.as_deref().map(Spool::dir)
    }
}
