//! PNG encoding of 8-bit sRGB RGB images, row by row.
//!
//! The local renderer and the farm's service both write PNGs through [`PngWriter`], with the
//! same settings and the same row-at-a-time path, so the same pixels always give the same PNG
//! bytes. Feeding rows as they become available (the service assembles tile rows one band
//! at a time) keeps memory at one band, not one image.

use std::io::Write;
use std::sync::{Arc, Mutex, PoisonError};

/// Why a PNG could not be written.
#[derive(Debug, thiserror::Error)]
pub enum PngError {
    /// The output took no more bytes (a full disk, a closed pipe). Its cause is the message,
    /// not a source as well: `anyhow`'s `{:#}` would print the OS error twice.
    #[error("{0}")]
    Write(std::io::Error),
    /// The encoder refused (an image of zero size, an internal limit).
    #[error("PNG encoding failed: {0}")]
    Encode(png::EncodingError),
    /// The rows given add up to more or fewer bytes than the image holds.
    #[error("expected {expected} bytes of rows in all, got {got}")]
    Length {
        /// `width × height × 3`.
        expected: u64,
        /// The bytes given.
        got: u64,
    },
    /// A tile's bytes do not match its size (`width × height × 3`).
    #[error("a tile {width} pixels wide and {height} rows high holds {len} bytes")]
    Piece {
        /// The tile's width in pixels.
        width: u32,
        /// Its height in rows.
        height: u32,
        /// The bytes given for it.
        len: usize,
    },
}

impl From<png::EncodingError> for PngError {
    fn from(e: png::EncodingError) -> PngError {
        match e {
            png::EncodingError::IoError(io) => PngError::Write(io),
            other => PngError::Encode(other),
        }
    }
}

/// Streams the rows of a `width × height` RGB8 image into a PNG. The output is owned by the
/// writer (the encoder's streaming mode requires it); write into a [`SharedBuffer`] to get
/// the bytes back in memory.
pub struct PngWriter<W: Write + 'static> {
    stream: png::StreamWriter<'static, W>,
    row_bytes: usize,
    expected: u64,
    written: u64,
}

impl<W: Write + 'static> PngWriter<W> {
    /// Writes the PNG header of a `width × height` sRGB image to `out`.
    pub fn new(out: W, width: u32, height: u32) -> Result<Self, PngError> {
        let mut enc = png::Encoder::new(out, width, height);
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Eight);
        enc.set_source_srgb(png::SrgbRenderingIntent::Perceptual);
        // `Fast` keeps encoding a small share of a render; `Balanced` costs many times more
        // for files barely smaller.
        enc.set_compression(png::Compression::Fast);
        let writer = enc.write_header()?;
        let stream = writer.into_stream_writer()?;
        Ok(PngWriter {
            stream,
            row_bytes: width as usize * 3,
            expected: u64::from(width) * u64::from(height) * 3,
            written: 0,
        })
    }

    /// Appends whole rows (any number of them, `3 · width` bytes each). Rows reach the
    /// encoder one at a time whatever the caller's grouping, so the output never depends on
    /// how the image was banded.
    pub fn write_rows(&mut self, rows: &[u8]) -> Result<(), PngError> {
        let got = self.written + rows.len() as u64;
        if got > self.expected || !rows.len().is_multiple_of(self.row_bytes) {
            return Err(PngError::Length {
                expected: self.expected,
                got,
            });
        }
        for row in rows.chunks_exact(self.row_bytes) {
            self.stream
                .write_all(row)
                .map_err(png::EncodingError::from)?;
        }
        self.written = got;
        Ok(())
    }

    /// Appends a band of `height` whole rows held tile by tile, as a farm stores it: `tiles`
    /// lists, left to right, each tile's width in pixels and its `width × height × 3` bytes
    /// (its own rows, top to bottom). Each row is fed to the encoder in pieces, tile by tile,
    /// without first copying the band into image rows; the encoder keeps one row and
    /// encodes it once whole, so the output is the same as [`Self::write_rows`] on the
    /// assembled rows. The widths must add up to the image's, and each tile hold exactly its
    /// bytes; otherwise nothing is written.
    pub fn write_band(&mut self, height: u32, tiles: &[(u32, &[u8])]) -> Result<(), PngError> {
        let band = self.row_bytes as u64 * u64::from(height);
        let got = self.written + band;
        if let Some(&(width, bytes)) = tiles
            .iter()
            .find(|&&(w, bytes)| bytes.len() as u64 != u64::from(w) * 3 * u64::from(height))
        {
            return Err(PngError::Piece {
                width,
                height,
                len: bytes.len(),
            });
        }
        let widths: u64 = tiles.iter().map(|&(w, _)| u64::from(w) * 3).sum();
        if got > self.expected || widths != self.row_bytes as u64 {
            return Err(PngError::Length {
                expected: self.expected,
                got,
            });
        }
        for r in 0..height as usize {
            for &(w, bytes) in tiles {
                let piece = w as usize * 3;
                self.stream
                    .write_all(&bytes[r * piece..(r + 1) * piece])
                    .map_err(png::EncodingError::from)?;
            }
        }
        self.written = got;
        Ok(())
    }

    /// Completes the file; every row must have been written.
    pub fn finish(self) -> Result<(), PngError> {
        if self.written != self.expected {
            return Err(PngError::Length {
                expected: self.expected,
                got: self.written,
            });
        }
        self.stream.finish()?;
        Ok(())
    }
}

/// An in-memory byte sink that can be handed to a [`PngWriter`] and read after it finishes.
#[derive(Debug, Clone, Default)]
pub struct SharedBuffer(Arc<Mutex<Vec<u8>>>);

impl SharedBuffer {
    /// An empty buffer.
    pub fn new() -> Self {
        Self::default()
    }

    /// Takes the bytes written so far, leaving the buffer empty.
    pub fn take(&self) -> Vec<u8> {
        // A panic while holding this lock cannot leave the Vec half-written in a way that
        // matters here, so a poisoned lock is simply recovered.
        std::mem::take(&mut *self.0.lock().unwrap_or_else(PoisonError::into_inner))
    }
}

impl Write for SharedBuffer {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.0
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .extend_from_slice(buf);
        Ok(buf.len())
    }

    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

/// Encodes a whole RGB8 image held in memory.
pub fn encode_png(width: u32, height: u32, rgb: &[u8]) -> Result<Vec<u8>, PngError> {
    let buf = SharedBuffer::new();
    let mut w = PngWriter::new(buf.clone(), width, height)?;
    w.write_rows(rgb)?;
    w.finish()?;
    Ok(buf.take())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn decode(bytes: &[u8]) -> (u32, u32, Vec<u8>) {
        let img = image::load_from_memory_with_format(bytes, image::ImageFormat::Png)
            .expect("our own PNG decodes")
            .into_rgb8();
        (img.width(), img.height(), img.into_raw())
    }

    #[test]
    fn round_trips_pixels() {
        let (w, h) = (7u32, 5u32);
        let rgb: Vec<u8> = (0..w * h * 3).map(|i| (i * 37 % 251) as u8).collect();
        let png = encode_png(w, h, &rgb).expect("encode");
        assert_eq!(decode(&png), (w, h, rgb));
    }

    #[test]
    fn row_by_row_equals_all_at_once() {
        let (w, h) = (300u32, 40u32);
        let rgb: Vec<u8> = (0..w * h * 3).map(|i| (i % 253) as u8).collect();
        let whole = encode_png(w, h, &rgb).expect("encode");
        let banded = SharedBuffer::new();
        let mut pw = PngWriter::new(banded.clone(), w, h).expect("header");
        for band in rgb.chunks(w as usize * 3 * 7) {
            pw.write_rows(band).expect("rows");
        }
        pw.finish().expect("finish");
        assert_eq!(whole, banded.take());
    }

    /// A band given tile by tile (uneven widths, the last narrower) encodes to the same
    /// bytes as its rows assembled first, checked against the whole image encoded at once.
    #[test]
    fn bands_given_tile_by_tile_equal_rows() {
        let (w, h) = (300u32, 40u32);
        let rgb: Vec<u8> = (0..w * h * 3).map(|i| (i * 7 % 251) as u8).collect();
        let whole = encode_png(w, h, &rgb).expect("encode");
        let tiled = SharedBuffer::new();
        let mut pw = PngWriter::new(tiled.clone(), w, h).expect("header");
        let widths = [128u32, 128, 44];
        for y in (0..h).step_by(16) {
            let bh = 16.min(h - y);
            let mut x = 0;
            let tiles: Vec<(u32, Vec<u8>)> = widths
                .iter()
                .map(|&tw| {
                    let mut t = Vec::new();
                    for r in y..y + bh {
                        let start = ((r * w + x) * 3) as usize;
                        t.extend_from_slice(&rgb[start..start + tw as usize * 3]);
                    }
                    x += tw;
                    (tw, t)
                })
                .collect();
            let refs: Vec<(u32, &[u8])> = tiles.iter().map(|(tw, t)| (*tw, &t[..])).collect();
            pw.write_band(bh, &refs).expect("band");
        }
        pw.finish().expect("finish");
        assert_eq!(whole, tiled.take());
    }

    #[test]
    fn bands_that_do_not_fit_are_refused() {
        let mut pw = PngWriter::new(SharedBuffer::new(), 4, 2).expect("header");
        // Widths short of the image's, a tile with a byte too many, and one band too many.
        assert!(pw.write_band(1, &[(3, &[0; 9])]).is_err());
        assert!(matches!(
            pw.write_band(1, &[(3, &[0; 9]), (1, &[0; 4])]),
            Err(PngError::Piece {
                width: 1,
                height: 1,
                len: 4
            })
        ));
        pw.write_band(2, &[(3, &[0; 18]), (1, &[0; 6])])
            .expect("the whole image");
        assert!(pw.write_band(1, &[(4, &[0; 12])]).is_err());
        pw.finish().expect("complete");
    }

    #[test]
    fn wrong_lengths_are_refused() {
        let mut pw = PngWriter::new(SharedBuffer::new(), 2, 2).expect("header");
        pw.write_rows(&[0; 6]).expect("one row");
        assert!(matches!(pw.finish(), Err(PngError::Length { .. })));
        let mut pw = PngWriter::new(SharedBuffer::new(), 2, 2).expect("header");
        assert!(pw.write_rows(&[0; 13]).is_err());
    }
}
