//! The roster of workers seen, in the `workers` table, written in batches by each replica.

use super::{PgStore, Result};
use crate::store::types::WorkerSeen;

impl PgStore {
    pub(crate) fn seen(&self, worker: &str, now: i64, f: impl FnOnce(&mut WorkerSeen)) {
        let _ = (worker, now, f);
        todo!()
    }

    pub(crate) async fn workers(&self, since: i64) -> Result<Vec<WorkerSeen>> {
        todo!("{since}")
    }
}
