//! Assembling a job's PNG from its stored tiles, one band of tile rows at a time: while the
//! job renders, as each band completes ([`Progress`]), and whole once the last tile is in
//! ([`assemble`]) for jobs this process did not follow from the start (after a restart).
//!
//! A PNG is one compressed stream of rows from top to bottom, so bands are encoded strictly
//! in order; a band that completes early waits for those above it. Encoding bands while
//! later tiles still render takes the encoding off the end of the job: when the last tile
//! arrives, only the bands not yet encoded (usually its own) remain.
//!
//! Memory stays bounded whatever the image size: per job being encoded, one band's tiles as
//! read, one after another (image width × tile height × 3 bytes, kept from one band to the
//! next), the encoder's state, and one band's compressed output. The band is never copied
//! into image rows: the encoder takes each row in pieces from the tiles' bytes
//! ([`PngWriter::write_band`]), and a band whose tiles do not lie side by side from the
//! left edge is refused ([`AssembleError::Gap`]). The PNG goes into the database in chunks of
//! [`CHUNK`] bytes as it is encoded, so a finished image survives a restart and a download
//! streams it back chunk by chunk, holding one small chunk at a time per client. The
//! encoder is the tracer's, fed the same rows in the same order, so the PNG is
//! byte-identical to `tessera-render`'s however the rows were grouped.
//!
//! This module does not decide when a job is complete: the store does, and says so with the
//! result that completes it.

use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, PoisonError};

use tessera_tracer::{PngWriter, Rect, SharedBuffer};

use crate::now_ms;
use crate::store::{Store, StoreError};

/// The size of the PNG's chunks in the database (all but the last): what a download holds
/// per client while the client reads, so that clients that stop reading hold the service
/// to a small, fixed amount of memory each (about 1.5 chunks, with the allocator's share).
pub const CHUNK: usize = 64 << 10;

/// Why a job's image could not be assembled (or not yet).
#[derive(Debug, thiserror::Error)]
pub enum AssembleError {
    /// The store failed, or lost tiles' pixels ([`StoreError::Lost`]).
    #[error(transparent)]
    Store(#[from] StoreError),
    /// The encoder refused a row or its output failed.
    #[error("PNG encoding: {0}")]
    Png(#[from] tessera_tracer::PngError),
    /// The stored tiles of a band leave pixels of its rows uncovered: no PNG is written
    /// with a hole in it.
    #[error("tiles of rows {y}.. do not cover the image width ({covered} of {width} pixels)")]
    Gap {
        /// The band's first row.
        y: u32,
        /// The pixels of a row that its tiles cover, side by side from the left edge.
        covered: u64,
        /// The image's width.
        width: u32,
    },
    /// The job was deleted while its image was assembled.
    #[error("job vanished while its image was assembled")]
    Vanished,
    /// Some of the job's tiles are not done (any more): their pixels were lost while its
    /// bands were encoded ahead, and they are being rendered again.
    #[error("tiles of the job are being rendered again")]
    Unfinished,
}

impl AssembleError {
    /// Tiles' pixels were lost and the tiles queued again: the job goes on, and is assembled
    /// when its (new) last tile is in.
    pub fn requeued(&self) -> bool {
        matches!(
            self,
            AssembleError::Store(StoreError::Lost { .. }) | AssembleError::Unfinished
        )
    }

    /// The database failed (gone, restarting, full): the image can be assembled again
    /// once it answers, so the job does not fail for it where another process may assemble
    /// it (see [`Store::is_shared`]).
    pub fn transient(&self) -> bool {
        matches!(self, AssembleError::Store(e) if e.is_storage()
            || matches!(e, StoreError::Db(sqlx::Error::PoolTimedOut)))
    }
}

/// A PNG being written band by band into the job's image chunks.
struct Encoder {
    png: PngWriter<SharedBuffer>,
    sink: SharedBuffer,
    pending: Vec<u8>,
    /// The band's tiles as read, one after another, kept from band to band so that its
    /// pages are not allocated and faulted in again for each (a 1920-pixel band of 256
    /// rows is 1.5 MB). The encoder takes each row from the tiles' bytes directly.
    band: Vec<u8>,
    seq: u32,
    total: u64,
    /// The first row not yet encoded.
    y: u32,
    width: u32,
    height: u32,
}

impl Encoder {
    /// Starts the job's PNG, dropping any chunks of an earlier, unfinished attempt.
    async fn start(
        store: &Store,
        id: &str,
        width: u32,
        height: u32,
    ) -> Result<Self, AssembleError> {
        store.clear_image(id).await?;
        let sink = SharedBuffer::new();
        let png = PngWriter::new(sink.clone(), width, height)?;
        Ok(Encoder {
            png,
            sink,
            pending: Vec::new(),
            band: Vec::new(),
            seq: 0,
            total: 0,
            y: 0,
            width,
            height,
        })
    }

    fn done(&self) -> bool {
        self.y >= self.height
    }

    /// Encodes the band of tiles whose top row is `self.y`; every tile of it must be stored.
    async fn band(&mut self, store: &Store, id: &str) -> Result<(), AssembleError> {
        let (y, width) = (self.y, self.width);
        let tiles = store.band(id, y, now_ms(), &mut self.band).await?;
        // The band's height is its first tile's; the tiles must share it and lie side by
        // side from the left edge to the right one.
        let bh = tiles.first().map_or(0, |t| t.h);
        let mut covered = 0u64;
        let mut pieces = Vec::with_capacity(tiles.len());
        for t in &tiles {
            if t.h != bh || u64::from(t.x) != covered {
                break;
            }
            pieces.push((t.w, &self.band[t.bytes.clone()]));
            covered += u64::from(t.w);
        }
        if bh == 0 || pieces.len() != tiles.len() || covered != u64::from(width) {
            return Err(AssembleError::Gap { y, covered, width });
        }
        // One band with `Fast` compression is about a millisecond of encoding: short enough
        // to run on the async thread between two database round trips.
        let started = std::time::Instant::now();
        self.png.write_band(bh, &pieces)?;
        self.pending.extend_from_slice(&self.sink.take());
        self.flush(store, id, false).await?;
        self.y += bh;
        tracing::debug!(
            job = %id, rows = bh, y, us = started.elapsed().as_micros() as u64,
            "band encoded"
        );
        Ok(())
    }

    /// Stores the pending output's whole chunks (with `all`, the rest too).
    async fn flush(&mut self, store: &Store, id: &str, all: bool) -> Result<(), AssembleError> {
        self.total += store_chunks(store, id, &mut self.pending, &mut self.seq, all).await?;
        Ok(())
    }

    /// Encodes every band left, completes the file and marks the job done.
    async fn finish(mut self, store: &Store, id: &str) -> Result<(), AssembleError> {
        while !self.done() {
            self.band(store, id).await?;
        }
        let Encoder {
            png,
            sink,
            mut pending,
            mut seq,
            mut total,
            ..
        } = self;
        png.finish()?;
        pending.extend_from_slice(&sink.take());
        total += store_chunks(store, id, &mut pending, &mut seq, true).await?;
        if store.finish_image(id, total, now_ms()).await? {
            tracing::info!(job = %id, bytes = total, "image assembled");
        }
        Ok(())
    }
}

/// Stores the whole [`CHUNK`]s at the front of `pending` (with `all`, the rest too) as the
/// job's chunks from `*seq` on, in one statement, and returns how many bytes it stored.
async fn store_chunks(
    store: &Store,
    id: &str,
    pending: &mut Vec<u8>,
    seq: &mut u32,
    all: bool,
) -> Result<u64, AssembleError> {
    let whole = if all {
        pending.len()
    } else {
        pending.len() - pending.len() % CHUNK
    };
    if whole == 0 {
        return Ok(0);
    }
    let pieces: Vec<&[u8]> = pending[..whole].chunks(CHUNK).collect();
    store.put_image_chunks(id, *seq, &pieces).await?;
    *seq += pieces.len() as u32;
    pending.drain(..whole);
    Ok(whole as u64)
}

/// Encodes the job's whole PNG from its stored tiles, stores it, and marks the job done.
/// Idempotent: run again after a crash, it starts over. Under the store's assembly lock,
/// so that two processes on one database never write the same job's chunks at once: when
/// another holds it, this does nothing (the holder finishes the image, or, if it dies, the
/// maintenance pass assembles it again).
pub async fn assemble(store: &Store, id: &str) -> Result<(), AssembleError> {
    let Some(_lock) = store.assembling(id).await? else {
        tracing::debug!(job = %id, "another process assembles the image");
        return Ok(());
    };
    let job = store.job(id).await?.ok_or(AssembleError::Vanished)?;
    // Read under the lock: a holder that finished before it was taken leaves a done job.
    if !job.state.is_active() {
        return Ok(());
    }
    if job.tiles_done < job.tiles_total {
        return Err(AssembleError::Unfinished);
    }
    let enc = Encoder::start(store, id, job.width as u32, job.height as u32).await?;
    enc.finish(store, id).await
}

/// One followed job: how many tiles each band still waits for, and its encoder.
struct Followed {
    width: u32,
    height: u32,
    /// Top rows of the bands, ascending, and their tiles not yet stored.
    bands: Mutex<Vec<(u32, u32)>>,
    /// `None` until the first band is complete; the async lock keeps bands in order.
    encoder: tokio::sync::Mutex<Option<Encoder>>,
    /// Set under the encoder's lock when encoding ahead must stop: it failed (the job is
    /// then assembled whole at the end), or the last tile is in and the job is being
    /// finished. An `advance` that gets the lock afterwards does nothing.
    stopped: AtomicBool,
}

impl Followed {
    /// Whether the band starting at row `y` has all its tiles stored.
    fn complete(&self, y: u32) -> bool {
        let bands = self.bands.lock().unwrap_or_else(PoisonError::into_inner);
        bands
            .binary_search_by_key(&y, |b| b.0)
            .is_ok_and(|i| bands[i].1 == 0)
    }
}

/// Jobs whose PNG is encoded while they render. A job is followed from its submission, so
/// its counts see every stored tile; jobs from before a restart are not followed and are
/// assembled whole. The counts only ever hold a band back, never let an incomplete one
/// through early: a band is read only once all its tiles were stored, and the encoding
/// checks that its tiles cover it.
#[derive(Default)]
pub struct Progress {
    jobs: Mutex<HashMap<String, Arc<Followed>>>,
}

impl Progress {
    fn get(&self, id: &str) -> Option<Arc<Followed>> {
        let jobs = self.jobs.lock().unwrap_or_else(PoisonError::into_inner);
        jobs.get(id).cloned()
    }

    /// Follows a job about to be stored with these tiles.
    pub fn follow(&self, id: &str, width: u32, height: u32, tiles: &[Rect]) {
        let mut bands: Vec<(u32, u32)> = Vec::new();
        let mut ys: Vec<u32> = tiles.iter().map(|t| t.y).collect();
        ys.sort_unstable();
        for y in ys {
            match bands.last_mut() {
                Some(b) if b.0 == y => b.1 += 1,
                _ => bands.push((y, 1)),
            }
        }
        let followed = Followed {
            width,
            height,
            bands: Mutex::new(bands),
            encoder: tokio::sync::Mutex::new(None),
            stopped: AtomicBool::new(false),
        };
        let mut jobs = self.jobs.lock().unwrap_or_else(PoisonError::into_inner);
        jobs.insert(id.to_string(), Arc::new(followed));
    }

    /// Stops following a job (it was not stored, or it ended without an image).
    pub fn forget(&self, id: &str) {
        let mut jobs = self.jobs.lock().unwrap_or_else(PoisonError::into_inner);
        jobs.remove(id);
    }

    /// Ids of the jobs followed.
    pub fn followed(&self) -> Vec<String> {
        let jobs = self.jobs.lock().unwrap_or_else(PoisonError::into_inner);
        jobs.keys().cloned().collect()
    }

    /// How many rows of a followed job's PNG are encoded (`None` if it is not followed).
    pub async fn encoded_rows(&self, id: &str) -> Option<u32> {
        let f = self.get(id)?;
        let encoder = f.encoder.lock().await;
        Some(encoder.as_ref().map_or(0, |e| e.y))
    }

    /// Counts a stored tile (not the job's last); true when that completed its band, so
    /// that [`Progress::advance`] has something to encode.
    pub fn stored(&self, id: &str, tile: Rect) -> bool {
        let Some(f) = self.get(id) else { return false };
        let mut bands = f.bands.lock().unwrap_or_else(PoisonError::into_inner);
        match bands.binary_search_by_key(&tile.y, |b| b.0) {
            Ok(i) if bands[i].1 > 0 => {
                bands[i].1 -= 1;
                bands[i].1 == 0
            }
            _ => false,
        }
    }

    /// Encodes the complete bands that come next in the image, if any. True when a band
    /// found tiles whose pixels were lost and queued them again (workers should be told).
    pub async fn advance(&self, store: &Store, id: &str) -> bool {
        let Some(f) = self.get(id) else { return false };
        let mut encoder = f.encoder.lock().await;
        if f.stopped.load(Ordering::Relaxed) {
            return false;
        }
        let result: Result<(), AssembleError> = async {
            loop {
                let y = encoder.as_ref().map_or(0, |e| e.y);
                if y >= f.height || !f.complete(y) {
                    return Ok(());
                }
                if encoder.is_none() {
                    *encoder = Some(Encoder::start(store, id, f.width, f.height).await?);
                }
                if let Some(enc) = encoder.as_mut() {
                    enc.band(store, id).await?;
                }
            }
        }
        .await;
        match result {
            Ok(()) => false,
            Err(e) => {
                // Not fatal: the job is assembled whole when its last tile is in.
                tracing::warn!(job = %id, "encoding ahead stopped: {e}");
                f.stopped.store(true, Ordering::Relaxed);
                *encoder = None;
                e.requeued()
            }
        }
    }

    /// The job's last tile is in: encodes what is left and marks the job done (the whole
    /// image if the job was not followed or encoding ahead failed).
    pub async fn complete(&self, store: &Store, id: &str) -> Result<(), AssembleError> {
        tracing::debug!(job = %id, "last tile in: finishing the image");
        let Some(f) = self.get(id) else {
            return assemble(store, id).await;
        };
        let enc = {
            let mut encoder = f.encoder.lock().await;
            // A failed encoding ahead has left `None` here.
            f.stopped.store(true, Ordering::Relaxed);
            encoder.take()
        };
        self.forget(id);
        match enc {
            // Every tile is stored now, whatever the counts say (a tile's count may still be
            // on its way): the remaining bands are read regardless of them.
            Some(enc) => enc.finish(store, id).await,
            None => assemble(store, id).await,
        }
    }
}
