//! The roster of workers seen, in the `workers` table, written in batches by each replica.
//!
//! A worker is heard from on every claim, renewal and result; what this replica hears is
//! added up in memory ([`crate::store::memo::RosterBatch`]) and written in one statement
//! whenever the roster is read (the `/workers` route, the reaper's live workers) and on
//! every [`PgStore::share`], so another replica sees it within one reaper pass.

use sqlx::Row;

use super::{PgStore, Result};
use crate::store::memo::{ROSTER_COLUMNS, RosterRow, count, roster_row};
use crate::store::state::tile_sql;
use crate::store::types::{HeldTile, WorkerSeen};

impl PgStore {
    /// Notes that `worker` was heard from at `now`; `f` adds to what is noted of it.
    pub(crate) fn seen(&self, worker: &str, now: i64, f: impl FnOnce(&mut WorkerSeen)) {
        self.roster.seen(worker, now, f);
    }

    /// Workers heard from at or after `since`, by name, with what this replica heard and
    /// has not written yet.
    pub(crate) async fn workers(&self, since: i64) -> Result<Vec<WorkerSeen>> {
        let _turn = self.roster.turn().await;
        self.write_seen().await;
        let sql = format!("SELECT {ROSTER_COLUMNS} FROM workers WHERE last_seen >= $1");
        let rows: Vec<RosterRow> = sqlx::query_as(sqlx::AssertSqlSafe(sql))
            .bind(since)
            .fetch_all(&self.pool)
            .await?;
        Ok(self
            .roster
            .merged(rows.into_iter().map(roster_row).collect(), since))
    }

    /// Writes what this replica heard of workers now, rather than at the next read of the
    /// roster (a goodbye, which the other replicas should see at once).
    pub(crate) async fn write_roster_now(&self) {
        let _turn = self.roster.turn().await;
        self.write_seen().await;
    }

    /// The leases that run past `now`, by worker, job and tile.
    pub(crate) async fn held(&self, now: i64) -> Result<Vec<HeldTile>> {
        let rows = sqlx::query(concat!(
            "SELECT worker, job_id, idx, rendering FROM tiles
             WHERE state = ",
            tile_sql!(Leased),
            " AND lease_expires > $1 AND worker IS NOT NULL
             ORDER BY worker, job_id, idx"
        ))
        .bind(now)
        .fetch_all(&self.pool)
        .await?;
        rows.iter()
            .map(|row| {
                Ok(HeldTile {
                    worker: row.try_get(0)?,
                    job: row.try_get(1)?,
                    idx: row.try_get::<i64, _>(2)? as u32,
                    rendering: row.try_get(3)?,
                })
            })
            .collect()
    }

    /// Writes the roster's pending batch (kept for the next write if it fails). Call it
    /// holding the roster's turn.
    pub(super) async fn write_seen(&self) {
        self.roster
            .flush(|batch| async move { self.write_roster(batch).await })
            .await;
    }

    /// Adds a batch to the roster in one statement, by name: names in one order, so that
    /// two replicas writing the same workers at once wait for each other rather than each
    /// hold a row the other needs.
    async fn write_roster(&self, mut batch: Vec<WorkerSeen>) -> Result<()> {
        batch.sort_by(|a, b| a.name.cmp(&b.name));
        sqlx::query(
            "INSERT INTO workers (name, last_seen, claims, claims_with_results, tiles_done,
                                  threads, rays_per_second, left_at)
             SELECT * FROM UNNEST($1::TEXT[], $2::BIGINT[], $3::BIGINT[], $4::BIGINT[],
                                  $5::BIGINT[], $6::BIGINT[], $7::DOUBLE PRECISION[],
                                  $8::BIGINT[])
             ON CONFLICT (name) DO UPDATE SET
                 last_seen = GREATEST(workers.last_seen, excluded.last_seen),
                 claims = workers.claims + excluded.claims,
                 claims_with_results = workers.claims_with_results
                                       + excluded.claims_with_results,
                 tiles_done = workers.tiles_done + excluded.tiles_done,
                 threads = COALESCE(excluded.threads, workers.threads),
                 rays_per_second = COALESCE(excluded.rays_per_second, workers.rays_per_second),
                 left_at = GREATEST(workers.left_at, excluded.left_at)",
        )
        .bind(batch.iter().map(|w| w.name.clone()).collect::<Vec<_>>())
        .bind(batch.iter().map(|w| w.last_seen).collect::<Vec<_>>())
        .bind(batch.iter().map(|w| count(w.claims)).collect::<Vec<_>>())
        .bind(
            batch
                .iter()
                .map(|w| count(w.claims_with_results))
                .collect::<Vec<_>>(),
        )
        .bind(
            batch
                .iter()
                .map(|w| count(w.tiles_done))
                .collect::<Vec<_>>(),
        )
        .bind(
            batch
                .iter()
                .map(|w| w.threads.map(i64::from))
                .collect::<Vec<_>>(),
        )
        .bind(batch.iter().map(|w| w.rays_per_second).collect::<Vec<_>>())
        .bind(batch.iter().map(|w| w.left_at).collect::<Vec<_>>())
        .execute(&self.pool)
        .await?;
        Ok(())
    }
}
