//! The roster of workers seen, in the `workers` table (migration 0012).
//!
//! A worker is heard from on every claim, renewal and result: writing the roster each time
//! would add a write to each of those on the one writer. So what this process hears is
//! added up in memory and written in one transaction whenever the roster is read (the
//! `/workers` route, and the reaper's every pass, which asks for the live workers), and a
//! read adds what could not be written yet. Another process on the same database sees it
//! once written: within one reaper pass. The batch is [`crate::store::memo`]'s, as both
//! backends keep it.

use sqlx::{Connection, Row};

use super::{Result, SqliteStore};
use crate::store::memo::{ROSTER_COLUMNS, RosterRow, count, roster_row};
use crate::store::state::tile_sql;
use crate::store::types::{HeldTile, WorkerSeen};

impl SqliteStore {
    /// Notes that `worker` was heard from at `now`; `f` adds to what is noted of it (its
    /// counts start at zero in each batch not yet written, so `f` adds, never sets).
    pub(crate) fn seen(&self, worker: &str, now: i64, f: impl FnOnce(&mut WorkerSeen)) {
        self.roster.seen(worker, now, f);
    }

    /// Workers heard from at or after `since`, by name, with what this process heard and
    /// has not written yet.
    pub(crate) async fn workers(&self, since: i64) -> Result<Vec<WorkerSeen>> {
        let _turn = self.roster.turn().await;
        self.roster
            .flush(|batch| async move { self.write_roster(&batch).await })
            .await;
        let sql = format!("SELECT {ROSTER_COLUMNS} FROM workers WHERE last_seen >= ?1");
        let rows: Vec<RosterRow> = sqlx::query_as(sqlx::AssertSqlSafe(sql))
            .bind(since)
            .fetch_all(&mut *self.reader().await?)
            .await?;
        Ok(self
            .roster
            .merged(rows.into_iter().map(roster_row).collect(), since))
    }

    /// Writes what this process heard of workers now, rather than at the next read of the
    /// roster (a goodbye, which another process should see at once).
    pub(crate) async fn write_roster_now(&self) {
        let _turn = self.roster.turn().await;
        self.roster
            .flush(|batch| async move { self.write_roster(&batch).await })
            .await;
    }

    /// The leases that run past `now`, by worker, job and tile.
    pub(crate) async fn held(&self, now: i64) -> Result<Vec<HeldTile>> {
        let rows = sqlx::query(concat!(
            "SELECT worker, job_id, idx, rendering FROM tiles
             WHERE state = ",
            tile_sql!(Leased),
            " AND lease_expires > ?1 AND worker IS NOT NULL
             ORDER BY worker, job_id, idx"
        ))
        .bind(now)
        .fetch_all(&mut *self.reader().await?)
        .await?;
        rows.iter()
            .map(|row| {
                Ok(HeldTile {
                    worker: row.try_get(0)?,
                    job: row.try_get(1)?,
                    idx: row.try_get::<i64, _>(2)? as u32,
                    rendering: row.try_get::<i64, _>(3)? != 0,
                })
            })
            .collect()
    }

    /// Writes a batch of the roster in one transaction.
    async fn write_roster(&self, batch: &[WorkerSeen]) -> Result<()> {
        let mut conn = self.writer.lock().await?;
        let mut tx = conn.begin_with("BEGIN IMMEDIATE").await?;
        for w in batch {
            sqlx::query(
                "INSERT INTO workers (name, last_seen, claims, claims_with_results, tiles_done,
                                      threads, rays_per_second, left_at)
                 VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8)
                 ON CONFLICT (name) DO UPDATE SET
                     last_seen = MAX(last_seen, excluded.last_seen),
                     claims = claims + excluded.claims,
                     claims_with_results = claims_with_results + excluded.claims_with_results,
                     tiles_done = tiles_done + excluded.tiles_done,
                     threads = COALESCE(excluded.threads, threads),
                     rays_per_second = COALESCE(excluded.rays_per_second, rays_per_second),
                     left_at = MAX(left_at, excluded.left_at)",
            )
            .bind(&w.name)
            .bind(w.last_seen)
            .bind(count(w.claims))
            .bind(count(w.claims_with_results))
            .bind(count(w.tiles_done))
            .bind(w.threads.map(i64::from))
            .bind(w.rays_per_second)
            .bind(w.left_at)
            .execute(&mut *tx)
            .await?;
        }
        tx.commit().await?;
        Ok(())
    }
}
