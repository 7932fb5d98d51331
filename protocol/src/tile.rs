//! The tile blob: the binary body in which a worker posts a rendered tile's pixels.
//!
//! Encoding and checking only; where the service stores the pixels, and how it checks that
//! the rectangle is the leased tile's, are its own business.

use tessera_tracer::Rect;

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

/// Why a posted blob is refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum BlobError {
    /// Shorter than the header, or not starting with [`TILE_MAGIC`].
    #[error("tile blob does not start with the TSR1 header")]
    BadMagic,
    /// The header names another rectangle than the leased tile's.
    #[error("tile blob is for the tile {got}, but this lease is for the tile {expected}")]
    WrongTile {
        /// The leased tile's rectangle.
        expected: Rect,
        /// The rectangle the header names.
        got: Rect,
    },
    /// The pixel bytes do not fill the rectangle the header names, exactly.
    #[error("tile blob holds {got} pixel bytes; a {w}×{h} tile needs {expected}")]
    WrongLength {
        /// The header's width.
        w: u32,
        /// The header's height.
        h: u32,
        /// The pixel bytes that width and height need.
        expected: u64,
        /// The pixel bytes the blob holds.
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
