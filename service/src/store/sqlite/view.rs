//! What users see of a job while it renders: its tiles with their states and holders, the
//! pixels stored so far (for the live preview), and a change of its priority.
//!
//! Everything here reads on the reading connections and changes nothing about leases: a
//! preview that meets pixels it cannot read leaves them out rather than requeue them (the
//! image's assembly does that, see [`super::images`]).

use sqlx::Row;
use tessera_tracer::Rect;

use super::{Result, SqliteStore, job_state, tile_state};
use crate::store::state::{job_sql, tile_sql};
use crate::store::types::{BandTile, FarmCounts, Reprioritized, TileView};

impl SqliteStore {
    /// Every tile of job `id` in index order; `None` when there is no such job.
    pub(crate) async fn tiles(&self, id: &str) -> Result<Option<Vec<TileView>>> {
        let mut conn = self.reader().await?;
        let exists: Option<i64> = sqlx::query_scalar("SELECT 1 FROM jobs WHERE id = ?1")
            .bind(id)
            .fetch_optional(&mut *conn)
            .await?;
        if exists.is_none() {
            return Ok(None);
        }
        let rows = sqlx::query(
            "SELECT idx, x, y, w, h, state, worker, attempt, failures, last_error
             FROM tiles WHERE job_id = ?1 ORDER BY idx",
        )
        .bind(id)
        .fetch_all(&mut *conn)
        .await?;
        let mut tiles = Vec::with_capacity(rows.len());
        for row in &rows {
            tiles.push(TileView {
                idx: row.try_get::<i64, _>(0)? as u32,
                x: row.try_get::<i64, _>(1)? as u32,
                y: row.try_get::<i64, _>(2)? as u32,
                w: row.try_get::<i64, _>(3)? as u32,
                h: row.try_get::<i64, _>(4)? as u32,
                state: tile_state(row.try_get(5)?)?,
                worker: row.try_get(6)?,
                attempts: row.try_get(7)?,
                failures: row.try_get(8)?,
                error: row.try_get(9)?,
            });
        }
        Ok(Some(tiles))
    }

    /// The stored tiles of the band of rows starting at `y` of a `width × height` job, left
    /// to right, their bytes appended to `buf` (cleared first). A tile whose pixels cannot be
    /// read or do not match their checksum is left out.
    pub(crate) async fn stored_band(
        &self,
        id: &str,
        (width, height): (u32, u32),
        y: u32,
        buf: &mut Vec<u8>,
    ) -> Result<Vec<BandTile>> {
        buf.clear();
        let rows = sqlx::query(super::images::BAND_SQL)
            .bind(id)
            .bind(i64::from(y))
            .fetch_all(&mut *self.reader().await?)
            .await?;
        let mut tiles = Vec::with_capacity(rows.len());
        for row in &rows {
            let (x, w, h): (i64, i64, i64) = (row.try_get(0)?, row.try_get(1)?, row.try_get(2)?);
            let (x, w, h) = (x as u32, w as u32, h as u32);
            let crc: Option<i64> = row.try_get(4)?;
            let start = buf.len();
            let read = match (crc, &self.spool) {
                (Some(crc), Some(spool)) => {
                    spool.read(id, width, height, Rect::new(x, y, w, h), crc as u32, buf)
                }
                (Some(_), None) => false,
                (None, _) => {
                    let rgb: &[u8] = row.try_get(3)?;
                    let fits = rgb.len() as u64 == 3 * u64::from(w) * u64::from(h);
                    if fits {
                        buf.extend_from_slice(rgb);
                    }
                    fits
                }
            };
            if read {
                tiles.push(BandTile {
                    x,
                    w,
                    h,
                    bytes: start..buf.len(),
                });
            }
        }
        Ok(tiles)
    }

    /// The top rows of job `id`'s bands of tiles, top to bottom.
    pub(crate) async fn bands(&self, id: &str) -> Result<Vec<u32>> {
        let ys: Vec<i64> =
            sqlx::query_scalar("SELECT DISTINCT y FROM tiles WHERE job_id = ?1 ORDER BY y")
                .bind(id)
                .fetch_all(&mut *self.reader().await?)
                .await?;
        Ok(ys.into_iter().map(|y| y as u32).collect())
    }

    /// Sets a queued or running job's priority.
    pub(crate) async fn set_priority(&self, id: &str, priority: i64) -> Result<Reprioritized> {
        let changed = sqlx::query(concat!(
            "UPDATE jobs SET priority = ?2 WHERE id = ?1 AND state IN ",
            job_sql!(active)
        ))
        .bind(id)
        .bind(priority)
        .execute(&mut *self.writer.lock().await?)
        .await?
        .rows_affected();
        if changed > 0 {
            return Ok(Reprioritized::Changed);
        }
        let state: Option<String> = sqlx::query_scalar("SELECT state FROM jobs WHERE id = ?1")
            .bind(id)
            .fetch_optional(&mut *self.reader().await?)
            .await?;
        Ok(match state {
            None => Reprioritized::Unknown,
            Some(s) => Reprioritized::Ended(job_state(s)?),
        })
    }
}

impl SqliteStore {
    /// Jobs by state, and the tiles of active jobs waiting and leased: the metrics' gauges.
    pub(crate) async fn counts(&self) -> Result<FarmCounts> {
        let mut conn = self.reader().await?;
        let by_state: Vec<(String, i64)> =
            sqlx::query_as("SELECT state, COUNT(*) FROM jobs GROUP BY state ORDER BY state")
                .fetch_all(&mut *conn)
                .await?;
        let mut jobs = Vec::with_capacity(by_state.len());
        for (state, n) in by_state {
            jobs.push((job_state(state)?, u64::try_from(n).unwrap_or(0)));
        }
        let (queued, leased): (Option<i64>, Option<i64>) = sqlx::query_as(concat!(
            "SELECT SUM(CASE WHEN t.state = ",
            tile_sql!(Queued),
            " THEN 1 ELSE 0 END), SUM(CASE WHEN t.state = ",
            tile_sql!(Leased),
            " THEN 1 ELSE 0 END)
             FROM tiles t JOIN jobs j ON j.id = t.job_id
             WHERE j.state IN ",
            job_sql!(active),
            " AND t.state <> ",
            tile_sql!(Done)
        ))
        .fetch_one(&mut *conn)
        .await?;
        Ok(FarmCounts {
            jobs,
            tiles_queued: u64::try_from(queued.unwrap_or(0)).unwrap_or(0),
            tiles_leased: u64::try_from(leased.unwrap_or(0)).unwrap_or(0),
        })
    }
}
