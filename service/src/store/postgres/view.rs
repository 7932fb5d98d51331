//! What users see of a job while it renders: its tiles with their states and holders, the
//! pixels stored so far (for the live preview), and a change of its priority.
//!
//! Reads only, but for the priority: a preview that meets pixels of the wrong size leaves
//! them out rather than requeue them (the image's assembly does that, see
//! [`super::images`]).

use sqlx::Row;

use super::{PgStore, Result, job_state, tile_state};
use crate::store::state::{job_sql, tile_sql};
use crate::store::types::{BandTile, FarmCounts, Reprioritized, TileView};

impl PgStore {
    /// Every tile of job `id` in index order; `None` when there is no such job.
    pub(crate) async fn tiles(&self, id: &str) -> Result<Option<Vec<TileView>>> {
        let exists: Option<i32> = sqlx::query_scalar("SELECT 1 FROM jobs WHERE id = $1")
            .bind(id)
            .fetch_optional(&self.pool)
            .await?;
        if exists.is_none() {
            return Ok(None);
        }
        let rows = sqlx::query(
            "SELECT idx, x, y, w, h, state, worker, attempt, failures, last_error
             FROM tiles WHERE job_id = $1 ORDER BY idx",
        )
        .bind(id)
        .fetch_all(&self.pool)
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

    /// The stored tiles of the band of rows starting at `y`, left to right, their bytes
    /// appended to `buf` (cleared first). A row whose bytes are not its tile's size is left
    /// out.
    pub(crate) async fn stored_band(
        &self,
        id: &str,
        _size: (u32, u32),
        y: u32,
        buf: &mut Vec<u8>,
    ) -> Result<Vec<BandTile>> {
        buf.clear();
        let rows = sqlx::query(
            "SELECT t.x, t.w, t.h, p.rgb FROM tiles t
             JOIN tile_pixels p ON p.job_id = t.job_id AND p.idx = t.idx
             WHERE t.job_id = $1 AND t.y = $2 ORDER BY t.idx",
        )
        .bind(id)
        .bind(i64::from(y))
        .fetch_all(&self.pool)
        .await?;
        let mut tiles = Vec::with_capacity(rows.len());
        for row in &rows {
            let (x, w, h): (i64, i64, i64) = (row.try_get(0)?, row.try_get(1)?, row.try_get(2)?);
            let rgb: &[u8] = row.try_get(3)?;
            if rgb.len() as i64 != w * h * 3 {
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
        Ok(tiles)
    }

    /// The top rows of job `id`'s bands of tiles, top to bottom.
    pub(crate) async fn bands(&self, id: &str) -> Result<Vec<u32>> {
        let ys: Vec<i64> =
            sqlx::query_scalar("SELECT DISTINCT y FROM tiles WHERE job_id = $1 ORDER BY y")
                .bind(id)
                .fetch_all(&self.pool)
                .await?;
        Ok(ys.into_iter().map(|y| y as u32).collect())
    }

    /// Sets a queued or running job's priority.
    pub(crate) async fn set_priority(&self, id: &str, priority: i64) -> Result<Reprioritized> {
        let changed = sqlx::query(concat!(
            "UPDATE jobs SET priority = $2 WHERE id = $1 AND state IN ",
            job_sql!(active)
        ))
        .bind(id)
        .bind(priority)
        .execute(&self.pool)
        .await?
        .rows_affected();
        if changed > 0 {
            return Ok(Reprioritized::Changed);
        }
        let state: Option<String> = sqlx::query_scalar("SELECT state FROM jobs WHERE id = $1")
            .bind(id)
            .fetch_optional(&self.pool)
            .await?;
        Ok(match state {
            None => Reprioritized::Unknown,
            Some(s) => Reprioritized::Ended(job_state(s)?),
        })
    }
}

impl PgStore {
    /// Jobs by state, and the tiles of active jobs waiting and leased: the metrics' gauges.
    pub(crate) async fn counts(&self) -> Result<FarmCounts> {
        let by_state: Vec<(String, i64)> =
            sqlx::query_as("SELECT state, COUNT(*) FROM jobs GROUP BY state ORDER BY state")
                .fetch_all(&self.pool)
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
        .fetch_one(&self.pool)
        .await?;
        Ok(FarmCounts {
            jobs,
            tiles_queued: u64::try_from(queued.unwrap_or(0)).unwrap_or(0),
            tiles_leased: u64::try_from(leased.unwrap_or(0)).unwrap_or(0),
        })
    }
}
