//! Reaping: expired leases requeued and charged, keep-away, jobs failed when a tile is out
//! of attempts or no live worker may take them.

use std::time::Duration;

use super::{PgStore, Result};
use crate::store::types::KeepAway;

impl PgStore {
    pub(crate) async fn reap(&self, now: i64, max_attempts: u32, keep: KeepAway) -> Result<u64> {
        todo!("{now} {max_attempts} {keep:?}")
    }

    pub(crate) async fn fail_unservable(&self, live: &[String], now: i64) -> Result<u64> {
        todo!("{live:?} {now}")
    }

    pub(crate) async fn reap_unheard(
        &self,
        now: i64,
        lease_ms: u64,
        within: Duration,
        max_attempts: u32,
        keep: KeepAway,
    ) -> Result<(u64, u64)> {
        todo!("{now} {lease_ms} {within:?} {max_attempts} {keep:?}")
    }
}
