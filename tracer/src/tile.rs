//! Rectangles of the image (tiles) and how an image is cut into them.
//!
//! A tile is only a unit of work: every pixel's value depends on the scene and the pixel's
//! coordinates alone, never on the tile it was rendered in (see [`crate::sampler`]).

/// A rectangle of pixels: columns `x..x + width`, rows `y..y + height` (row 0 at the top).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Rect {
    /// First column.
    pub x: u32,
    /// First row (row 0 at the top).
    pub y: u32,
    /// Columns.
    pub width: u32,
    /// Rows.
    pub height: u32,
}

/// `64×32 at (128, 0)`: the size, and the top-left pixel (column, row), as messages show it.
impl std::fmt::Display for Rect {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{}×{} at ({}, {})",
            self.width, self.height, self.x, self.y
        )
    }
}

impl Rect {
    /// The rectangle of `width × height` pixels whose top-left pixel is (`x`, `y`).
    pub const fn new(x: u32, y: u32, width: u32, height: u32) -> Rect {
        Rect {
            x,
            y,
            width,
            height,
        }
    }

    /// The whole image.
    pub const fn full(width: u32, height: u32) -> Rect {
        Rect::new(0, 0, width, height)
    }

    /// `width × height`.
    pub fn pixel_count(&self) -> usize {
        self.width as usize * self.height as usize
    }

    /// Whether the rectangle is non-empty and lies inside a `width × height` image.
    pub fn fits_in(&self, width: u32, height: u32) -> bool {
        self.width > 0
            && self.height > 0
            && u64::from(self.x) + u64::from(self.width) <= u64::from(width)
            && u64::from(self.y) + u64::from(self.height) <= u64::from(height)
    }
}

/// Cuts a `width × height` image into tiles of at most `tile × tile` pixels, row by row from
/// the top left; the last column and row of tiles take what is left.
pub fn tiles(width: u32, height: u32, tile: u32) -> Vec<Rect> {
    let tile = tile.max(1);
    let mut out = Vec::new();
    let mut y = 0;
    while y < height {
        let h = tile.min(height - y);
        let mut x = 0;
        while x < width {
            let w = tile.min(width - x);
            out.push(Rect::new(x, y, w, h));
            x += w;
        }
        y += h;
    }
    out
}

/// How many tiles [`tiles`] cuts a `width × height` image into, without making them.
pub fn tile_count(width: u32, height: u32, tile: u32) -> u64 {
    let tile = tile.max(1);
    u64::from(width.div_ceil(tile)) * u64::from(height.div_ceil(tile))
}

/// The tile edges [`local_tile`] picks from, largest first.
const LOCAL_TILE_RANGE: (u32, u32) = (32, 128);

/// Tiles per thread [`local_tile`] keeps at least: with several each, a thread that drew
/// slow tiles (a mirror's, an edge's) is helped by the others with theirs.
const LOCAL_TILES_PER_THREAD: u64 = 4;

/// The tile edge for rendering a whole `width × height` image on `threads` threads of one
/// machine, as `tessera-render` does: 128 px, halved while the image would have fewer than
/// four tiles per thread, down to 32 px.
///
/// Any edge gives the same pixels (see the module comment); the choice is speed alone. A
/// larger tile costs less per pixel: the adaptive sampler probes a border two pixels wide
/// around each tile and projects the scene's solids onto it once per tile (at 32 px the
/// border alone is a quarter more pixels, at 128 px a sixteenth). A smaller one shares the
/// image more evenly between the threads.
pub fn local_tile(width: u32, height: u32, threads: usize) -> u32 {
    let (lo, hi) = LOCAL_TILE_RANGE;
    let wanted = LOCAL_TILES_PER_THREAD.saturating_mul(threads.max(1) as u64);
    let mut edge = hi;
    while edge > lo && tile_count(width, height, edge) < wanted {
        edge /= 2;
    }
    edge
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The largest edge in the range that leaves four tiles per thread, or the smallest
    /// edge where none does; checked against every edge of the range.
    #[test]
    fn local_tiles_are_the_largest_that_leave_four_per_thread() {
        let edges = [128, 64, 32];
        for (w, h) in [(160, 120), (640, 480), (1920, 1080), (1, 1), (4000, 10)] {
            for threads in [0, 1, 2, 3, 16, 1024] {
                let wanted = 4 * threads.max(1) as u64;
                let expected = edges
                    .into_iter()
                    .find(|&e| tile_count(w, h, e) >= wanted)
                    .unwrap_or(32);
                assert_eq!(
                    local_tile(w, h, threads),
                    expected,
                    "{w}×{h} on {threads} threads"
                );
            }
        }
        // The chart's and the tests' images on one thread, and a 1080p frame on sixteen.
        assert_eq!(local_tile(160, 120, 1), 64);
        assert_eq!(local_tile(160, 120, 2), 32);
        assert_eq!(local_tile(1920, 1080, 16), 128);
    }

    #[test]
    fn tile_count_is_the_number_of_tiles_made() {
        for (w, h, t) in [
            (10, 7, 3),
            (64, 64, 64),
            (1, 1, 16),
            (100, 3, 7),
            (0, 5, 2),
            (9, 9, 0),
        ] {
            assert_eq!(
                tile_count(w, h, t),
                tiles(w, h, t).len() as u64,
                "{w}×{h} by {t}"
            );
        }
    }

    #[test]
    fn tiles_cover_the_image_exactly_once() {
        for (w, h, t) in [(10, 7, 3), (64, 64, 64), (1, 1, 16), (100, 3, 7)] {
            let mut seen = vec![0u8; (w * h) as usize];
            for r in tiles(w, h, t) {
                assert!(r.fits_in(w, h));
                assert!(r.width <= t && r.height <= t);
                for y in r.y..r.y + r.height {
                    for x in r.x..r.x + r.width {
                        seen[(y * w + x) as usize] += 1;
                    }
                }
            }
            assert!(seen.iter().all(|&c| c == 1), "{w}×{h} by {t}");
        }
    }

    #[test]
    fn fits_in_refuses_empty_and_overhanging_rects() {
        assert!(!Rect::new(0, 0, 0, 5).fits_in(10, 10));
        assert!(!Rect::new(8, 0, 3, 5).fits_in(10, 10));
        assert!(!Rect::new(u32::MAX, 0, 2, 1).fits_in(10, 10));
        assert!(Rect::new(7, 5, 3, 5).fits_in(10, 10));
    }
}
