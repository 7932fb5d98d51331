//! The roster of workers seen, in the `workers` table (migration 0012).
//!
//! A worker is heard from on every claim, renewal and result: writing the roster each time
//! would add a write to each of those on the one writer. So what this process hears is
//! added up in memory and written in one transaction whenever the roster is read (the
//! `/workers` route, and the reaper's every pass, which asks for the live workers), and a
//! read adds what could not be written yet. Another process on the same database sees it
//! once written: within one reaper pass.

use std::collections::HashMap;
use std::sync::PoisonError;

use sqlx::Connection;

use super::{Result, SqliteStore};
use crate::store::types::WorkerSeen;

impl SqliteStore {
    /// Notes that `worker` was heard from at `now`; `f` adds to what is noted of it (its
    /// counts start at zero in each batch not yet written, so `f` adds, never sets).
    pub(crate) fn seen(&self, worker: &str, now: i64, f: impl FnOnce(&mut WorkerSeen)) {
        let mut seen = self.seen.lock().unwrap_or_else(PoisonError::into_inner);
        let entry = seen
            .entry(worker.to_string())
            .or_insert_with(|| WorkerSeen {
                name: worker.to_string(),
                ..WorkerSeen::default()
            });
        entry.last_seen = entry.last_seen.max(now);
        f(entry);
    }

    /// Workers heard from at or after `since`, by name, with what this process heard and
    /// has not written yet.
    pub(crate) async fn workers(&self, since: i64) -> Result<Vec<WorkerSeen>> {
        // One read or write of the roster at a time: a read while another's batch is on
        // its way to the table would find it in neither place.
        let _roster = self.roster.lock().await;
        self.write_seen().await;
        let rows: Vec<(String, i64, i64, i64, i64)> = sqlx::query_as(
            "SELECT name, last_seen, claims, claims_with_results, tiles_done FROM workers
             WHERE last_seen >= ?1",
        )
        .bind(since)
        .fetch_all(&mut *self.reader().await?)
        .await?;
        let mut all: HashMap<String, WorkerSeen> = rows
            .into_iter()
            .map(|(name, last_seen, claims, with_results, tiles_done)| {
                let w = WorkerSeen {
                    name: name.clone(),
                    last_seen,
                    claims: u64::try_from(claims).unwrap_or(0),
                    claims_with_results: u64::try_from(with_results).unwrap_or(0),
                    tiles_done: u64::try_from(tiles_done).unwrap_or(0),
                };
                (name, w)
            })
            .collect();
        let pending = self.seen.lock().unwrap_or_else(PoisonError::into_inner);
        for p in pending.values().filter(|p| p.last_seen >= since) {
            add(all.entry(p.name.clone()).or_default(), p);
        }
        drop(pending);
        let mut list: Vec<WorkerSeen> = all.into_values().collect();
        list.sort_by(|a, b| a.name.cmp(&b.name));
        Ok(list)
    }

    /// Writes what was heard since the last write. On failure (a full disk) it is kept for
    /// the next, and reads add it meanwhile: the roster is informational, and its write
    /// must not fail the request that reads it.
    async fn write_seen(&self) {
        let pending =
            std::mem::take(&mut *self.seen.lock().unwrap_or_else(PoisonError::into_inner));
        if pending.is_empty() {
            return;
        }
        if let Err(e) = self.write_roster(&pending).await {
            tracing::warn!("writing the roster of workers: {e}");
            let mut seen = self.seen.lock().unwrap_or_else(PoisonError::into_inner);
            for p in pending.into_values() {
                add(seen.entry(p.name.clone()).or_default(), &p);
            }
        }
    }

    async fn write_roster(&self, pending: &HashMap<String, WorkerSeen>) -> Result<()> {
        let mut conn = self.writer.lock().await?;
        let mut tx = conn.begin_with("BEGIN IMMEDIATE").await?;
        for w in pending.values() {
            sqlx::query(
                "INSERT INTO workers (name, last_seen, claims, claims_with_results, tiles_done)
                 VALUES (?1, ?2, ?3, ?4, ?5)
                 ON CONFLICT (name) DO UPDATE SET
                     last_seen = MAX(last_seen, excluded.last_seen),
                     claims = claims + excluded.claims,
                     claims_with_results = claims_with_results + excluded.claims_with_results,
                     tiles_done = tiles_done + excluded.tiles_done",
            )
            .bind(&w.name)
            .bind(w.last_seen)
            .bind(i64::try_from(w.claims).unwrap_or(i64::MAX))
            .bind(i64::try_from(w.claims_with_results).unwrap_or(i64::MAX))
            .bind(i64::try_from(w.tiles_done).unwrap_or(i64::MAX))
            .execute(&mut *tx)
            .await?;
        }
        tx.commit().await?;
        Ok(())
    }
}

/// Adds `p`'s counts to `to`, keeping the later `last_seen` (`to` takes `p`'s name if it
/// has none).
fn add(to: &mut WorkerSeen, p: &WorkerSeen) {
    if to.name.is_empty() {
        to.name = p.name.clone();
    }
    to.last_seen = to.last_seen.max(p.last_seen);
    to.claims += p.claims;
    to.claims_with_results += p.claims_with_results;
    to.tiles_done += p.tiles_done;
}
