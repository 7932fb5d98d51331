//! Leases: the claim, renewals, results, reported failures, releases, and the extension of
//! every lease after a pause.

use tessera_protocol::Claim;
use tessera_tracer::Rect;

use super::{PgStore, Result};
use crate::store::types::{Completion, KeepAway, TileInfo};

impl PgStore {
    pub(crate) async fn claim(
        &self,
        worker: &str,
        now: i64,
        lease_ms: u64,
        max_attempts: u32,
    ) -> Result<Option<Claim>> {
        todo!("{worker} {now} {lease_ms} {max_attempts}")
    }

    pub(crate) async fn renew(
        &self,
        job: &str,
        idx: u32,
        lease: &str,
        now: i64,
        lease_ms: u64,
        rendering: bool,
    ) -> Result<Option<String>> {
        todo!("{job} {idx} {lease} {now} {lease_ms} {rendering}")
    }

    pub(crate) async fn tile(&self, job: &str, idx: u32) -> Result<Option<TileInfo>> {
        todo!("{job} {idx}")
    }

    pub(crate) async fn complete(
        &self,
        job: &str,
        idx: u32,
        lease: &str,
        rect: Rect,
        rgb: &[u8],
        now: i64,
    ) -> Result<Completion> {
        todo!("{job} {idx} {lease} {rect:?} {} {now}", rgb.len())
    }

    #[allow(clippy::too_many_arguments)]
    pub(crate) async fn fail_tile(
        &self,
        job: &str,
        idx: u32,
        lease: &str,
        worker: &str,
        reason: &str,
        now: i64,
        max_attempts: u32,
        keep: KeepAway,
    ) -> Result<bool> {
        todo!("{job} {idx} {lease} {worker} {reason} {now} {max_attempts} {keep:?}")
    }

    pub(crate) async fn release(&self, job: &str, idx: u32, lease: &str) -> Result<bool> {
        todo!("{job} {idx} {lease}")
    }

    pub(crate) async fn extend_leases(&self, now: i64, lease_ms: u64) -> Result<u64> {
        todo!("{now} {lease_ms}")
    }
}
