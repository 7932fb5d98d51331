//! Images: the stored tiles of a band read back for the PNG, lost tiles handed out again,
//! the PNG's chunks, and the end of an assembled job.

use super::{PgStore, Result};
use crate::store::types::BandTile;

impl PgStore {
    pub(crate) async fn band(
        &self,
        id: &str,
        y: u32,
        now: i64,
        buf: &mut Vec<u8>,
    ) -> Result<Vec<BandTile>> {
        todo!("{id} {y} {now} {}", buf.len())
    }

    pub(crate) async fn requeue_lost(&self, id: &str, idxs: &[i64], now: i64) -> Result<u64> {
        todo!("{id} {idxs:?} {now}")
    }

    pub(crate) async fn clear_image(&self, id: &str) -> Result<()> {
        todo!("{id}")
    }

    pub(crate) async fn put_image_chunks(
        &self,
        id: &str,
        first_seq: u32,
        pieces: &[&[u8]],
    ) -> Result<()> {
        todo!("{id} {first_seq} {}", pieces.len())
    }

    pub(crate) async fn finish_image(&self, id: &str, png_bytes: u64, now: i64) -> Result<bool> {
        todo!("{id} {png_bytes} {now}")
    }

    pub(crate) async fn image_chunks(&self, id: &str) -> Result<u32> {
        todo!("{id}")
    }

    pub(crate) async fn image_chunk(&self, id: &str, seq: u32) -> Result<Option<Vec<u8>>> {
        todo!("{id} {seq}")
    }
}
