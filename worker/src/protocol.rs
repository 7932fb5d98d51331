//! The worker protocol: the JSON bodies and the tile blob format that the service and its
//! workers exchange. Both sides use these types, so they cannot drift apart.
//!
//! This module is data only: no HTTP, no I/O. The routes are documented in `docs/PROTOCOL.md`.

use serde::{Deserialize, Serialize};
use tessera_tracer::Rect;

/// `POST /worker/claim` body.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ClaimRequest {
    /// The worker's self-chosen name (host and process), used for keep-away and `/workers`.
    pub worker: String,
}

/// A tile handed to one worker under a lease (`200` answer to a claim; `204` means no work).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Claim {
    pub job: String,
    pub idx: u32,
    pub x: u32,
    pub y: u32,
    pub w: u32,
    pub h: u32,
    /// The lease token: renewals, results, failures and releases carry it, and are accepted
    /// only while it is the tile's current lease.
    pub lease: String,
    /// How long the lease lasts without renewal.
    pub lease_ms: u64,
}

impl Claim {
    pub fn rect(&self) -> Rect {
        Rect::new(self.x, self.y, self.w, self.h)
    }
}

/// `GET /worker/jobs/{id}`: what a worker needs to build a job's scene.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct JobSpec {
    pub id: String,
    pub scene: String,
    pub sampler: Option<String>,
    pub samples: Option<u32>,
    pub threshold: Option<f64>,
    /// Names of the job's assets, fetched from `GET /worker/jobs/{id}/assets/{name}`.
    pub assets: Vec<String>,
}

/// Answer to a renewal.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Renewed {
    pub lease_ms: u64,
}

/// Answer to a posted tile: `repeat` is true when the tile was already in from this lease
/// (the repeat changed nothing). When the post asked for its worker's next tile
/// (`?next=NAME`), `next` is that claim, as `POST /worker/claim` would have answered it
/// without waiting; absent when there is no work at this moment (or none was asked for).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Accepted {
    pub repeat: bool,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub next: Option<Claim>,
}

/// `POST /worker/jobs/{id}/tiles/{idx}/fail` body.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct FailRequest {
    pub worker: String,
    pub reason: String,
}

/// The first bytes of every tile blob.
pub const TILE_MAGIC: [u8; 4] = *b"TSR1";
/// Magic plus the rectangle as four little-endian `u32`s.
pub const TILE_HEADER_LEN: usize = 4 + 16;

/// A tile's pixels as posted: [`TILE_MAGIC`], the rectangle (`x, y, w, h`, little-endian
/// `u32`), then `w × h × 3` sRGB bytes, row-major. Final 8-bit values, so a blob cannot carry
/// a non-finite or out-of-range pixel; the header lets the service refuse a blob meant for
/// another tile.
pub fn encode_tile(rect: Rect, rgb: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(TILE_HEADER_LEN + rgb.len());
    out.extend_from_slice(&TILE_MAGIC);
    for v in [rect.x, rect.y, rect.width, rect.height] {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out.extend_from_slice(rgb);
    out
}

/// Why a posted blob was refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum BlobError {
    #[error("tile blob does not start with the TSR1 header")]
    BadMagic,
    #[error("tile blob is for the tile {got}, but this lease is for the tile {expected}")]
    WrongTile { expected: Rect, got: Rect },
    #[error("tile blob holds {got} pixel bytes; a {w}×{h} tile needs {expected}")]
    WrongLength {
        w: u32,
        h: u32,
        expected: u64,
        got: usize,
    },
}

/// Checks a blob against the tile it must be for and returns its pixel bytes.
pub fn decode_tile(blob: &[u8], expected: Rect) -> Result<&[u8], BlobError> {
    let (got, pixels) = split_tile(blob)?;
    if got != expected {
        return Err(BlobError::WrongTile { expected, got });
    }
    Ok(pixels)
}

/// Reads a blob's header and checks its length against the rectangle the header names:
/// the rectangle and the pixel bytes. Whether that rectangle is the tile's is for the caller
/// to check ([`decode_tile`], or the service's store statement).
pub fn split_tile(blob: &[u8]) -> Result<(Rect, &[u8]), BlobError> {
    if blob.len() < TILE_HEADER_LEN || blob[..4] != TILE_MAGIC {
        return Err(BlobError::BadMagic);
    }
    let word = |i: usize| {
        let at = 4 + 4 * i;
        u32::from_le_bytes([blob[at], blob[at + 1], blob[at + 2], blob[at + 3]])
    };
    let got = Rect::new(word(0), word(1), word(2), word(3));
    let pixels = &blob[TILE_HEADER_LEN..];
    // In u64: a header naming a huge rectangle must not overflow the product.
    let want = u64::from(got.width) * u64::from(got.height) * 3;
    if pixels.len() as u64 != want {
        return Err(BlobError::WrongLength {
            w: got.width,
            h: got.height,
            expected: want,
            got: pixels.len(),
        });
    }
    Ok((got, pixels))
}

/// The longest worker name, in bytes.
pub const MAX_WORKER_NAME: usize = 200;

/// A worker name as the service takes it: 1 to [`MAX_WORKER_NAME`] bytes, no control
/// characters. `tessera-worker` checks its `--name` by it at start (a name the service would
/// refuse was found only once the service answered, and retried for ever while it did not).
pub fn check_worker_name(name: &str) -> Result<(), String> {
    if name.is_empty() || name.len() > MAX_WORKER_NAME || name.chars().any(char::is_control) {
        return Err(format!(
            "a worker name is 1 to {MAX_WORKER_NAME} bytes of printable characters"
        ));
    }
    Ok(())
}

/// Why a bearer token cannot be sent as it is, if it cannot: white space at either end,
/// which HTTP trims from the header that carries it (a worker's token was refused with 401
/// by the service whose token it was meant to be, and `--token ' '` locked every worker
/// out), or a control character, which no header may hold (every request failed as if the
/// service were unreachable, for ever). Both programs check their tokens by it after clap
/// has parsed them, since clap's own refusal repeats the value; the service also refuses an
/// empty one, which to a worker means none.
pub fn token_problem(token: &str) -> Option<&'static str> {
    if token.trim() != token {
        Some("a token may not start or end with white space")
    } else if token.chars().any(char::is_control) {
        Some("a token may not hold control characters")
    } else {
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn blob_round_trips_and_refuses_mismatches() {
        let r = Rect::new(64, 0, 2, 3);
        let rgb: Vec<u8> = (0..18).collect();
        let blob = encode_tile(r, &rgb);
        assert_eq!(decode_tile(&blob, r), Ok(&rgb[..]));
        assert!(matches!(
            decode_tile(&blob, Rect::new(0, 0, 2, 3)),
            Err(BlobError::WrongTile { .. })
        ));
        assert!(matches!(
            decode_tile(&blob[..blob.len() - 1], r),
            Err(BlobError::WrongLength { got: 17, .. })
        ));
        let mut bad = blob.clone();
        bad[0] = b'X';
        assert_eq!(decode_tile(&bad, r), Err(BlobError::BadMagic));
        assert_eq!(decode_tile(&blob[..3], r), Err(BlobError::BadMagic));
    }
}
