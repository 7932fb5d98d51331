//! What replicas know of the database failing, shared through it once it writes again.

use std::time::Duration;

use super::{PgStore, Result};
use crate::store::error::StoreError;

impl PgStore {
    pub(crate) async fn probe_write(&self, now: i64, within: Duration) -> Result<()> {
        todo!("{now} {within:?}")
    }

    pub(crate) fn noted(&self, e: StoreError, now: i64) -> StoreError {
        let _ = now;
        e
    }

    pub(crate) fn storage_failed_within(&self, now: i64, within: Duration) -> bool {
        todo!("{now} {within:?}")
    }

    pub(crate) fn heard_refused(&self, lease: &str, e: StoreError, now: i64) -> StoreError {
        let _ = lease;
        self.noted(e, now)
    }

    pub(crate) fn heard(&self, lease: &str, now: i64) {
        let _ = (lease, now);
    }

    pub(crate) fn forget_unheard(&self, now: i64, within: Duration) {
        let _ = (now, within);
    }

    /// Writes what this replica noted (the roster's batch, the leases it refused and when
    /// the storage last failed) for the other replicas, and reads what they shared.
    pub(crate) async fn share(&self, now: i64) -> Result<()> {
        todo!("{now}")
    }
}
