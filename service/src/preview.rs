//! The live preview (`GET /jobs/{id}/preview.png`): a job's image as far as it is rendered,
//! as an RGBA PNG whose stored tiles hold their final pixels and whose other pixels are
//! transparent (alpha 0).
//!
//! **Bounded memory.** The PNG is encoded one band of tiles at a time, as the image's own
//! assembly is (`assemble`): one band's stored tiles as read, one band of RGBA rows, the
//! encoder's state, and the compressed bytes of that band, which go out to the client before
//! the next band is read. The whole PNG is kept only when it is small (see [`Cache`]).
//!
//! **Cheap to fetch again.** A preview is named by its job's state and the set of its
//! stored tiles ([`Version`]), sent as the `ETag`: a page that asks again with
//! `If-None-Match` while nothing new is stored gets `304` for the price of reading the
//! tiles' states, and a preview already encoded for that version is served from the cache
//! to every viewer, not encoded once per viewer.
//!
//! A done job's tile pixels are gone (its PNG holds them); its preview is that PNG decoded
//! and encoded again as RGBA, every alpha 255.
//!
//! What this is not: the image. Its bytes are not the final PNG's (RGBA, other settings);
//! the download is `GET /jobs/{id}/image.png`.

use std::collections::VecDeque;
use std::io::Write;
use std::sync::{Mutex, PoisonError};

use axum::body::Bytes;
use futures_util::Stream;
use tessera_tracer::SharedBuffer;

use crate::store::{JobRow, JobState, Store, StoreError, TileState, TileView};

/// Why a preview could not be made.
#[derive(Debug, thiserror::Error)]
pub enum PreviewError {
    /// The store failed.
    #[error(transparent)]
    Store(#[from] StoreError),
    /// The encoder or the stored image's decoder refused.
    #[error("preview: {0}")]
    Png(String),
}

impl From<png::EncodingError> for PreviewError {
    fn from(e: png::EncodingError) -> PreviewError {
        PreviewError::Png(e.to_string())
    }
}

impl From<png::DecodingError> for PreviewError {
    fn from(e: png::DecodingError) -> PreviewError {
        PreviewError::Png(e.to_string())
    }
}

/// What a preview shows: the job's state and which of its tiles are stored. Two previews of
/// one job with equal versions have the same pixels (a tile's pixels depend on the scene and
/// the tile only), so the version is the preview's `ETag`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Version(String);

impl Version {
    /// The version of `job` with `tiles` (all of its tiles, in index order).
    pub fn of(job: &JobRow, tiles: &[TileView]) -> Version {
        if job.state == JobState::Done {
            return Version(format!("\"{}-done\"", job.id));
        }
        // FNV-1a over the stored tiles' indices: the set, not its count, since a tile whose
        // pixels were lost is stored again later while another is not yet.
        let mut h: u64 = 0xcbf2_9ce4_8422_2325;
        let mut stored = 0u64;
        for t in tiles.iter().filter(|t| t.state == TileState::Done) {
            stored += 1;
            for b in t.idx.to_le_bytes() {
                h = (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3);
            }
        }
        Version(format!("\"{}-{}-{stored}-{h:016x}\"", job.id, job.state))
    }

    /// The `ETag` header's value.
    pub fn etag(&self) -> &str {
        &self.0
    }
}

/// The largest preview the cache keeps: a 1920×1080 preview of noisy tiles is a few MB.
const CACHED_PREVIEW_BYTES: usize = 16 << 20;
/// The most bytes of previews the cache holds at once.
const CACHE_BYTES: usize = 48 << 20;

/// Previews encoded lately, by version, oldest first: every viewer of a job between two
/// stored tiles gets the same bytes without encoding them again. Bounded in bytes; a
/// preview larger than [`CACHED_PREVIEW_BYTES`] is streamed and not kept.
#[derive(Debug, Default)]
pub struct Cache {
    entries: Mutex<VecDeque<(Version, Bytes)>>,
}

impl Cache {
    /// The preview of `version`, if it is kept.
    pub fn get(&self, version: &Version) -> Option<Bytes> {
        let entries = self.entries.lock().unwrap_or_else(PoisonError::into_inner);
        entries
            .iter()
            .find(|(v, _)| v == version)
            .map(|(_, b)| b.clone())
    }

    /// Keeps `png` as the preview of `version`, dropping the oldest previews past the
    /// cache's bound, and any older preview of the same job.
    fn put(&self, job: &str, version: Version, png: Bytes) {
        if png.len() > CACHED_PREVIEW_BYTES {
            return;
        }
        let mut entries = self.entries.lock().unwrap_or_else(PoisonError::into_inner);
        let prefix = format!("\"{job}-");
        entries.retain(|(v, _)| !v.0.starts_with(&prefix));
        entries.push_back((version, png));
        let mut total: usize = entries.iter().map(|(_, b)| b.len()).sum();
        while total > CACHE_BYTES {
            match entries.pop_front() {
                Some((_, b)) => total -= b.len(),
                None => break,
            }
        }
    }

    /// Forgets job `id`'s previews (it was deleted).
    pub fn forget(&self, id: &str) {
        let prefix = format!("\"{id}-");
        self.entries
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .retain(|(v, _)| !v.0.starts_with(&prefix));
    }
}

/// An RGBA8 PNG encoder whose output is taken a band at a time.
struct Rgba {
    stream: png::StreamWriter<'static, SharedBuffer>,
    sink: SharedBuffer,
}

impl Rgba {
    fn new(width: u32, height: u32) -> Result<Rgba, PreviewError> {
        let sink = SharedBuffer::new();
        let mut enc = png::Encoder::new(sink.clone(), width, height);
        enc.set_color(png::ColorType::Rgba);
        enc.set_depth(png::BitDepth::Eight);
        enc.set_source_srgb(png::SrgbRenderingIntent::Perceptual);
        enc.set_compression(png::Compression::Fast);
        let stream = enc.write_header()?.into_stream_writer()?;
        Ok(Rgba { stream, sink })
    }

    /// Encodes whole RGBA rows and returns the compressed bytes produced so far.
    fn rows(&mut self, rows: &[u8]) -> Result<Vec<u8>, PreviewError> {
        self.stream
            .write_all(rows)
            .map_err(|e| PreviewError::Png(e.to_string()))?;
        Ok(self.sink.take())
    }

    /// Ends the PNG and returns its last bytes.
    fn finish(self) -> Result<Vec<u8>, PreviewError> {
        self.stream.finish()?;
        Ok(self.sink.take())
    }
}

/// The preview of `job` (whose tiles, in index order, are `tiles`) at `version`, as a stream
/// of PNG bytes, one band of tiles at a time; kept in `cache` once whole if small enough.
pub fn stream(
    store: Store,
    cache: std::sync::Arc<Cache>,
    job: JobRow,
    tiles: Vec<TileView>,
    version: Version,
) -> impl Stream<Item = Result<Bytes, PreviewError>> {
    let (width, height) = (job.width as u32, job.height as u32);
    // The bands' top rows, top to bottom: the tiler cuts the image into bands that cover it
    // from top to bottom, so each band ends where the next begins.
    let mut ys: Vec<u32> = tiles.iter().map(|t| t.y).collect();
    ys.sort_unstable();
    ys.dedup();
    struct State {
        store: Store,
        cache: std::sync::Arc<Cache>,
        job: JobRow,
        version: Version,
        ys: Vec<u32>,
        next: usize,
        enc: Option<Rgba>,
        tiles: Vec<u8>,
        rows: Vec<u8>,
        kept: Option<Vec<u8>>,
        done: bool,
    }
    let state = State {
        store,
        cache,
        job,
        version,
        ys,
        next: 0,
        enc: None,
        tiles: Vec::new(),
        rows: Vec::new(),
        kept: Some(Vec::new()),
        done: false,
    };
    futures_util::stream::unfold(state, move |mut s| async move {
        if s.done {
            return None;
        }
        let step = async {
            if s.job.state == JobState::Done {
                s.done = true;
                return from_image(&s.store, &s.job).await;
            }
            if s.enc.is_none() {
                s.enc = Some(Rgba::new(width, height)?);
            }
            let Some(&y) = s.ys.get(s.next) else {
                s.done = true;
                let enc = s
                    .enc
                    .take()
                    .ok_or_else(|| PreviewError::Png("no encoder".into()))?;
                return enc.finish();
            };
            let end = s.ys.get(s.next + 1).copied().unwrap_or(height);
            s.next += 1;
            let bh = end.saturating_sub(y);
            let stored = s
                .store
                .stored_band(&s.job.id, (width, height), y, &mut s.tiles)
                .await?;
            let row_bytes = width as usize * 4;
            s.rows.clear();
            s.rows.resize(row_bytes * bh as usize, 0);
            for t in stored.iter().filter(|t| t.h == bh) {
                let bytes = &s.tiles[t.bytes.clone()];
                for (r, src) in bytes.chunks_exact(t.w as usize * 3).enumerate() {
                    let at = r * row_bytes + t.x as usize * 4;
                    let dst = &mut s.rows[at..at + t.w as usize * 4];
                    for (d, p) in dst.chunks_exact_mut(4).zip(src.chunks_exact(3)) {
                        d[..3].copy_from_slice(p);
                        d[3] = 255;
                    }
                }
            }
            let enc = s
                .enc
                .as_mut()
                .ok_or_else(|| PreviewError::Png("no encoder".into()))?;
            enc.rows(&s.rows)
        };
        match step.await {
            Ok(bytes) => {
                if let Some(kept) = &mut s.kept {
                    kept.extend_from_slice(&bytes);
                    if kept.len() > CACHED_PREVIEW_BYTES {
                        s.kept = None;
                    }
                }
                if s.done
                    && let Some(kept) = s.kept.take()
                {
                    s.cache.put(&s.job.id, s.version.clone(), Bytes::from(kept));
                }
                Some((Ok(Bytes::from(bytes)), s))
            }
            Err(e) => {
                s.done = true;
                Some((Err(e), s))
            }
        }
    })
}

/// A done job's PNG, read whole from its chunks, decoded and encoded again as RGBA.
async fn from_image(store: &Store, job: &JobRow) -> Result<Vec<u8>, PreviewError> {
    let chunks = store.image_chunks(&job.id).await?;
    let mut png_bytes = Vec::new();
    for seq in 0..chunks {
        match store.image_chunk(&job.id, seq).await? {
            Some(c) => png_bytes.extend_from_slice(&c),
            None => {
                return Err(PreviewError::Png(
                    "the image's chunks are incomplete".into(),
                ));
            }
        }
    }
    let mut reader = png::Decoder::new(std::io::Cursor::new(png_bytes)).read_info()?;
    let (width, height) = (reader.info().width, reader.info().height);
    let mut enc = Rgba::new(width, height)?;
    let mut out = Vec::new();
    let mut rgba = vec![255u8; width as usize * 4];
    while let Some(row) = reader.next_row()? {
        for (d, p) in rgba.chunks_exact_mut(4).zip(row.data().chunks_exact(3)) {
            d[..3].copy_from_slice(p);
        }
        out.extend_from_slice(&enc.rows(&rgba)?);
    }
    out.extend_from_slice(&enc.finish()?);
    Ok(out)
}
