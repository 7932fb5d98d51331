//! Assembling a finished job's PNG from its stored tiles, one band of tile rows at a time.
//!
//! Memory stays bounded whatever the image size: one band of RGB rows (image width × tile
//! height × 3 bytes), the encoder's state, and at most one pending chunk of compressed output
//! ([`CHUNK`]) are held at once. The PNG goes into the database in chunks as it is encoded,
//! so a finished image survives a restart and a download streams it back chunk by chunk.
//! The encoder is the tracer's, so the PNG is byte-identical to `tessera-render`'s.

use tessera_tracer::{PngWriter, SharedBuffer};

use crate::now_ms;
use crate::queue::{Queue, QueueError};

/// Size at which encoded output is flushed to the database.
pub const CHUNK: usize = 1 << 20;

#[derive(Debug, thiserror::Error)]
pub enum AssembleError {
    #[error(transparent)]
    Queue(#[from] QueueError),
    #[error("PNG encoding: {0}")]
    Png(#[from] tessera_tracer::PngError),
    #[error("tiles of rows {y}.. do not cover the image width ({covered} of {width} pixels)")]
    Gap { y: u32, covered: u64, width: u32 },
    #[error("job vanished while its image was assembled")]
    Vanished,
}

/// Encodes the job's PNG from its tiles, stores it, and marks the job done. Idempotent: run
/// again after a crash, it starts over.
pub async fn assemble(queue: &Queue, id: &str) -> Result<(), AssembleError> {
    let job = queue.job(id).await?.ok_or(AssembleError::Vanished)?;
    let (width, height) = (job.width as u32, job.height as u32);
    let tile = job.tile as u32;
    queue.clear_image(id).await?;
    let sink = SharedBuffer::new();
    let mut png = PngWriter::new(sink.clone(), width, height)?;
    let row_bytes = width as usize * 3;
    let mut pending: Vec<u8> = Vec::with_capacity(CHUNK + CHUNK / 4);
    let mut seq = 0u32;
    let mut total = 0u64;
    let mut y = 0u32;
    while y < height {
        let band = queue.band(id, y).await?;
        let bh = band.first().map_or(tile.min(height - y), |t| t.2);
        let mut rows = vec![0u8; row_bytes * bh as usize];
        let mut covered = 0u64;
        for (x, w, h, rgb) in &band {
            if *h != bh || rgb.len() != *w as usize * *h as usize * 3 {
                return Err(AssembleError::Gap { y, covered, width });
            }
            let tile_row = *w as usize * 3;
            for (r, src) in rgb.chunks_exact(tile_row).enumerate() {
                let start = r * row_bytes + *x as usize * 3;
                rows[start..start + tile_row].copy_from_slice(src);
            }
            covered += u64::from(*w);
        }
        if covered != u64::from(width) {
            return Err(AssembleError::Gap { y, covered, width });
        }
        // One band with `Fast` compression is about a millisecond of encoding: short enough
        // to run on the async thread between two database round trips.
        png.write_rows(&rows)?;
        pending.extend_from_slice(&sink.take());
        if pending.len() >= CHUNK {
            queue.put_image_chunk(id, seq, &pending).await?;
            total += pending.len() as u64;
            seq += 1;
            pending.clear();
        }
        y += bh;
    }
    png.finish()?;
    pending.extend_from_slice(&sink.take());
    if !pending.is_empty() {
        queue.put_image_chunk(id, seq, &pending).await?;
        total += pending.len() as u64;
    }
    if queue.finish_image(id, total, now_ms()).await? {
        tracing::info!(job = %id, bytes = total, "image assembled");
    }
    Ok(())
}
