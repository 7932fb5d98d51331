//! Jobs: storing one with its tiles and assets, listing, cancelling, deleting, and what a
//! worker reads of one (scene, assets).

use tessera_protocol::JobSpec;
use tessera_tracer::Rect;

use super::{PgStore, Result};
use crate::store::state::JobState;
use crate::store::types::{Cancel, JobRow, NewJob};

impl PgStore {
    pub(crate) async fn insert_job(
        &self,
        job: &NewJob,
        tiles: &[Rect],
        assets: &[(String, Vec<u8>)],
    ) -> Result<JobRow> {
        todo!("{job:?} {tiles:?} {assets:?}")
    }

    pub(crate) async fn jobs(
        &self,
        limit: u32,
        before: Option<&str>,
    ) -> Result<Option<Vec<JobRow>>> {
        todo!("{limit} {before:?}")
    }

    pub(crate) async fn job(&self, id: &str) -> Result<Option<JobRow>> {
        todo!("{id}")
    }

    pub(crate) async fn cancel(&self, id: &str, now: i64) -> Result<Cancel> {
        todo!("{id} {now}")
    }

    pub(crate) async fn delete(&self, id: &str) -> Result<bool> {
        todo!("{id}")
    }

    pub(crate) async fn active_jobs(&self) -> Result<Vec<String>> {
        todo!()
    }

    pub(crate) async fn unassembled(&self) -> Result<Vec<String>> {
        todo!()
    }

    pub(crate) async fn job_scene(&self, id: &str) -> Result<Option<(JobState, JobSpec)>> {
        todo!("{id}")
    }

    pub(crate) async fn asset(&self, id: &str, name: &str) -> Result<Option<Vec<u8>>> {
        todo!("{id} {name}")
    }

    pub(crate) async fn fail_job(&self, id: &str, reason: &str, now: i64) -> Result<()> {
        todo!("{id} {reason} {now}")
    }
}
