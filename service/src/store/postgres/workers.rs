//! The roster of workers seen, in the `workers` table, written in batches by each replica.
//!
//! A worker is heard from on every claim, renewal and result; what this replica hears is
//! added up in memory ([`crate::store::memo::RosterBatch`]) and written in one statement
//! whenever the roster is read (the `/workers` route, the reaper's live workers) and on
//! every [`PgStore::share`], so another replica sees it within one reaper pass.

use super::{PgStore, Result};
use crate::store::memo::{RosterRow, count, roster_row};
use crate::store::types::WorkerSeen;

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
        let rows: Vec<RosterRow> = sqlx::query_as(
            "SELECT name, last_seen, claims, claims_with_results, tiles_done FROM workers
             WHERE last_seen >= $1",
        )
        .bind(since)
        .fetch_all(&self.pool)
        .await?;
        Ok(self
            .roster
            .merged(rows.into_iter().map(roster_row).collect(), since))
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
            "INSERT INTO workers (name, last_seen, claims, claims_with_results, tiles_done)
             SELECT * FROM UNNEST($1::TEXT[], $2::BIGINT[], $3::BIGINT[], $4::BIGINT[],
                                  $5::BIGINT[])
             ON CONFLICT (name) DO UPDATE SET
                 last_seen = GREATEST(workers.last_seen, excluded.last_seen),
                 claims = workers.claims + excluded.claims,
                 claims_with_results = workers.claims_with_results
                                       + excluded.claims_with_results,
                 tiles_done = workers.tiles_done + excluded.tiles_done",
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
        .execute(&self.pool)
        .await?;
        Ok(())
    }
}
