//! Images: the stored tiles of a band read back for the PNG, lost tiles handed out again,
//! the PNG's chunks, and the end of an assembled job.

use sqlx::Row;

use super::notify::{ENDED, WORK, notify_sql};
use super::{PgStore, Result};
use crate::store::error::StoreError;
use crate::store::state::{job_sql, tile_sql};
use crate::store::types::BandTile;

/// PNG chunks stored by one statement (as arrays bound as parameters).
const CHUNKS_PER_INSERT: usize = 100;

impl PgStore {
    /// The stored tiles of one band of rows starting at `y`, left to right: each tile's
    /// bytes (`tile_pixels.rgb`) are appended to `buf` (cleared first, its capacity kept
    /// from band to band), and the tiles are returned in order with where their bytes are
    /// in it. The rows come in `idx` order, which within a band is left to right.
    ///
    /// A row whose bytes are not its tile's size (which no result stores) is lost: its tile
    /// is queued again ([`PgStore::requeue_lost`]) and the call fails with
    /// [`StoreError::Lost`].
    pub(crate) async fn band(
        &self,
        id: &str,
        y: u32,
        now: i64,
        buf: &mut Vec<u8>,
    ) -> Result<Vec<BandTile>> {
        buf.clear();
        let rows = sqlx::query(
            "SELECT t.x, t.w, t.h, p.rgb, t.idx FROM tiles t
             JOIN tile_pixels p ON p.job_id = t.job_id AND p.idx = t.idx
             WHERE t.job_id = $1 AND t.y = $2 ORDER BY t.idx",
        )
        .bind(id)
        .bind(i64::from(y))
        .fetch_all(&self.pool)
        .await?;
        let mut tiles = Vec::with_capacity(rows.len());
        let mut lost = Vec::new();
        for row in &rows {
            let (x, w, h): (i64, i64, i64) = (row.try_get(0)?, row.try_get(1)?, row.try_get(2)?);
            let rgb: &[u8] = row.try_get(3)?;
            if rgb.len() as i64 != w * h * 3 {
                lost.push(row.try_get::<i64, _>(4)?);
                continue;
            }
            let start = buf.len();
            buf.extend_from_slice(rgb);
            tiles.push(BandTile {
                x: x as u32,
                w: w as u32,
                h: h as u32,
                bytes: start..buf.len(),
            });
        }
        if !lost.is_empty() {
            let tiles = self.requeue_lost(id, &lost, now).await?;
            tracing::warn!(job = %id, y, tiles, "stored tile pixels unreadable: rendering them again");
            return Err(StoreError::Lost {
                job: id.to_string(),
                tiles: lost.len(),
            });
        }
        Ok(tiles)
    }

    /// Hands out again the done tiles `idxs` of an active job whose pixels were lost: their
    /// rows go, the tiles are queued and the job counts them as not done. Each loss counts
    /// a failure against its tile, not against any worker, so that a tile whose pixels
    /// keep being lost fails its job after `max_attempts` losses with the reason. Returns
    /// how many tiles were requeued.
    ///
    /// The job's row is locked first: a cancellation meanwhile (which locks it, then drops
    /// the pixels) waits for this or this for it, never each for the other.
    pub(crate) async fn requeue_lost(&self, id: &str, idxs: &[i64], now: i64) -> Result<u64> {
        let mut tx = self.pool.begin().await?;
        let active: Option<i64> = sqlx::query_scalar(concat!(
            "SELECT 1::BIGINT FROM jobs WHERE id = $1 AND state IN ",
            job_sql!(active),
            " FOR UPDATE"
        ))
        .bind(id)
        .fetch_optional(&mut *tx)
        .await?;
        if active.is_none() {
            tx.commit().await?;
            return Ok(0);
        }
        let requeued: Vec<i64> = sqlx::query_scalar(concat!(
            "UPDATE tiles SET state = ",
            tile_sql!(Queued),
            ", lease = NULL, worker = NULL,
                    lease_expires = NULL, rendering = FALSE, failures = failures + 1,
                    last_error = 'its stored pixels were lost'
             WHERE job_id = $1 AND idx = ANY($2) AND state = ",
            tile_sql!(Done),
            "
             RETURNING idx"
        ))
        .bind(id)
        .bind(idxs)
        .fetch_all(&mut *tx)
        .await?;
        if requeued.is_empty() {
            tx.commit().await?;
            return Ok(0);
        }
        sqlx::query("DELETE FROM tile_pixels WHERE job_id = $1 AND idx = ANY($2)")
            .bind(id)
            .bind(&requeued)
            .execute(&mut *tx)
            .await?;
        sqlx::query("UPDATE jobs SET tiles_done = tiles_done - $2 WHERE id = $1")
            .bind(id)
            .bind(requeued.len() as i64)
            .execute(&mut *tx)
            .await?;
        let jobs = [id.to_string()];
        let failed = Self::fail_exhausted(&mut tx, Some(&jobs), now, self.max_attempts).await?;
        sqlx::query(notify_sql(WORK)).execute(&mut *tx).await?;
        if failed > 0 {
            sqlx::query(notify_sql(ENDED)).execute(&mut *tx).await?;
        }
        tx.commit().await?;
        Ok(requeued.len() as u64)
    }

    pub(crate) async fn clear_image(&self, id: &str) -> Result<()> {
        sqlx::query("DELETE FROM image_chunks WHERE job_id = $1")
            .bind(id)
            .execute(&self.pool)
            .await?;
        Ok(())
    }

    /// Stores `pieces` as the job's PNG chunks `first_seq`, `first_seq + 1`, …, a hundred to
    /// a statement, unless the job has ended meanwhile (a cancelled job's chunks are
    /// dropped with it and must not come back). The job's row is share-locked while they
    /// are written: a cancellation waits for them, and then drops them too.
    pub(crate) async fn put_image_chunks(
        &self,
        id: &str,
        first_seq: u32,
        pieces: &[&[u8]],
    ) -> Result<()> {
        for (n, group) in pieces.chunks(CHUNKS_PER_INSERT).enumerate() {
            let first = i64::from(first_seq) + (n * CHUNKS_PER_INSERT) as i64;
            let seqs: Vec<i64> = (first..first + group.len() as i64).collect();
            sqlx::query(concat!(
                "INSERT INTO image_chunks (job_id, seq, bytes)
                 SELECT $1, seq, bytes FROM UNNEST($2::BIGINT[], $3::BYTEA[]) AS c(seq, bytes)
                 WHERE EXISTS (SELECT 1 FROM jobs WHERE id = $1 AND state IN ",
                job_sql!(active),
                " FOR SHARE)"
            ))
            .bind(id)
            .bind(seqs)
            .bind(group)
            .execute(&self.pool)
            .await?;
        }
        Ok(())
    }

    /// Marks an assembled job done and drops its tile pixels. False (and the image dropped)
    /// when the job ended meanwhile; its pixels then stay for a retry.
    pub(crate) async fn finish_image(&self, id: &str, png_bytes: u64, now: i64) -> Result<bool> {
        let mut tx = self.pool.begin().await?;
        let r = sqlx::query(concat!(
            "UPDATE jobs SET state = ",
            job_sql!(Done),
            ", finished_at = $2, png_bytes = $3
             WHERE id = $1 AND state IN ",
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
            sqlx::query("DELETE FROM image_chunks WHERE job_id = $1")
                .bind(id)
                .execute(&mut *tx)
                .await?;
        }
        // The pixels go with a stored image only. A job still active had a tile handed
        // out again meanwhile (its pixels lost), and the others wait for the next
        // assembly; one that ended without an image keeps them for a retry.
        if done {
            sqlx::query("DELETE FROM tile_pixels WHERE job_id = $1")
                .bind(id)
                .execute(&mut *tx)
                .await?;
            sqlx::query(notify_sql(ENDED)).execute(&mut *tx).await?;
        }
        tx.commit().await?;
        Ok(done)
    }

    /// The number of chunks of a job's PNG.
    pub(crate) async fn image_chunks(&self, id: &str) -> Result<u32> {
        let n: i64 = sqlx::query_scalar("SELECT COUNT(*) FROM image_chunks WHERE job_id = $1")
            .bind(id)
            .fetch_one(&self.pool)
            .await?;
        Ok(n as u32)
    }

    pub(crate) async fn image_chunk(&self, id: &str, seq: u32) -> Result<Option<Vec<u8>>> {
        Ok(
            sqlx::query_scalar("SELECT bytes FROM image_chunks WHERE job_id = $1 AND seq = $2")
                .bind(id)
                .bind(i64::from(seq))
                .fetch_optional(&self.pool)
                .await?,
        )
    }
}
