//! The tiling policy: the tile edges a job may ask for, the edge the service picks when it
//! asks for none ([`auto_tile`]), the cap on a job's tile count, and the largest tile blob a
//! worker may post. Tile bounds themselves are the tracer's (`tessera_tracer::tiles`).

use tessera_tracer::{Sampler, tile_count};

use crate::error::ApiError;

/// Smallest tile edge a job may ask for.
pub const MIN_TILE: u32 = 8;
/// Largest tile edge a job may ask for.
pub const MAX_TILE: u32 = 1024;

/// Primary rays a tile should carry when the service picks its size: enough tracing that
/// the fixed cost the service and the worker spend per tile (claim, post, store) is a small
/// share of it (docs/PERFORMANCE.md, "The farm", has the figures).
pub const TILE_RAYS: u64 = 262_144;

/// Tiles a job should have at least when the service picks their size, so that a handful of
/// workers can share even a small image and finish together. Twelve lets a 1080p frame at
/// one ray per pixel have 512 px tiles (4 × 3), whose per-tile cost is the smallest share
/// (docs/PERFORMANCE.md, "The farm", compares the tile sizes).
pub const MIN_AUTO_TILES: u64 = 12;

/// The tile edges the service picks from.
pub const AUTO_TILE_RANGE: (u32, u32) = (32, 512);

/// The tile edge for a `width × height` job whose pixels are counted as `rays_per_pixel`
/// primary rays each, when neither the job nor `--tile` sets one: the smallest power of two whose
/// tile carries [`TILE_RAYS`], then halved while the job would have fewer than
/// [`MIN_AUTO_TILES`] tiles, always within [`AUTO_TILE_RANGE`]. A 1080p frame gets 512 px
/// tiles at one ray per pixel (12 tiles) and 128 px tiles at 16 (135 tiles).
pub fn auto_tile(width: u32, height: u32, rays_per_pixel: u32) -> u32 {
    let (lo, hi) = AUTO_TILE_RANGE;
    let rays = u64::from(rays_per_pixel.max(1));
    let mut edge = lo;
    while edge < hi && u64::from(edge) * u64::from(edge) * rays < TILE_RAYS {
        edge *= 2;
    }
    while edge > lo && tessera_tracer::tile_count(width, height, edge) < MIN_AUTO_TILES {
        edge /= 2;
    }
    edge
}

/// Primary rays per pixel as the automatic tile size counts a job's cost: what a fixed
/// pattern traces, and for the adaptive sampler its first pass of four (a pixel that the
/// scene's geometry shows smooth ends after one ray; one at an edge takes more).
pub fn tile_rays_per_pixel(sampler: &Sampler) -> u32 {
    match sampler {
        Sampler::Adaptive { .. } => 4,
        other => other.max_samples_per_pixel(),
    }
}

/// The tile edge of a `width × height` job whose pixels cost `rays_per_pixel` primary rays
/// each: `asked` (the job's `?tile=` or `--tile`) or, without it, the service's pick, and
/// either refused when it makes more than `max_tiles` tiles ([`check_tile_count`]).
///
/// The service's own pick grows to the smallest edge that `max_tiles` allows, so that a job
/// that asked for no size is not refused for the service's choice; where no edge does, the
/// refusal counts the largest edge's tiles. An edge that was asked for is refused instead,
/// naming the smallest that fits.
pub fn job_tile(
    width: u32,
    height: u32,
    rays_per_pixel: u32,
    asked: Option<u32>,
    max_tiles: u64,
) -> Result<u32, ApiError> {
    let tile = asked.unwrap_or_else(|| {
        let auto = auto_tile(width, height, rays_per_pixel);
        smallest_fitting_tile(width, height, auto, max_tiles).unwrap_or(MAX_TILE)
    });
    check_tile_count(width, height, tile, max_tiles)?;
    Ok(tile)
}

/// The smallest tile edge from `from` up to [`MAX_TILE`] that cuts a `width × height` image
/// into at most `max_tiles` tiles, if any does. The count only falls as the edge grows, so
/// the first edge that fits is the smallest.
fn smallest_fitting_tile(width: u32, height: u32, from: u32, max_tiles: u64) -> Option<u32> {
    (from..=MAX_TILE).find(|&e| tile_count(width, height, e) <= max_tiles)
}

/// Refuses a job of more than `max_tiles` tiles (`--max-tiles`), naming the smallest tile
/// edge that would do, if any does.
fn check_tile_count(width: u32, height: u32, tile: u32, max_tiles: u64) -> Result<(), ApiError> {
    let count = tile_count(width, height, tile);
    if count <= max_tiles {
        return Ok(());
    }
    let fits = smallest_fitting_tile(width, height, tile, max_tiles);
    let hint = match fits {
        Some(edge) => format!("; ask for tile={edge} or more"),
        None => format!("; no tile edge up to {MAX_TILE} makes so few"),
    };
    let err = ApiError::bad_request(format!(
        "tiles of {tile} px make {count} tiles of this {width}×{height} image; a job may have \
         at most {max_tiles} (--max-tiles){hint}"
    ))
    .with("tiles", count)
    .with("max_tiles", max_tiles);
    Err(match fits {
        Some(edge) => err.with("min_tile", edge),
        None => err,
    })
}

/// Largest accepted tile blob.
pub const fn protocol_limit() -> usize {
    tessera_protocol::TILE_HEADER_LEN + MAX_TILE as usize * MAX_TILE as usize * 3
}

#[cfg(test)]
mod tests {
    use super::*;

    fn count(w: u32, h: u32, e: u32) -> u64 {
        u64::from(w.div_ceil(e)) * u64::from(h.div_ceil(e))
    }

    /// The rule's two promises, checked over many sizes and costs: a tile carries
    /// `TILE_RAYS` unless that would leave fewer than `MIN_AUTO_TILES` tiles (or the range
    /// ends), and a job has `MIN_AUTO_TILES` tiles unless tiles are already the smallest.
    #[test]
    fn auto_tiles_carry_enough_rays_and_are_enough_in_number() {
        let (lo, hi) = AUTO_TILE_RANGE;
        for &(w, h) in &[
            (1, 1),
            (64, 64),
            (320, 180),
            (640, 480),
            (1280, 720),
            (1920, 1080),
            (7680, 4320),
        ] {
            let mut last = u32::MAX;
            for rays in [1, 4, 5, 9, 16, 64, 256, 4096] {
                let e = auto_tile(w, h, rays);
                assert!(
                    (lo..=hi).contains(&e) && e.is_power_of_two(),
                    "{w}×{h} {rays}: {e}"
                );
                assert!(e <= last, "more rays per pixel never gives larger tiles");
                last = e;
                let carried = u64::from(e) * u64::from(e) * u64::from(rays);
                let doubled = 2 * e;
                // Either the tile carries enough rays, or a larger one would be too few tiles.
                assert!(
                    carried >= TILE_RAYS || e == hi || count(w, h, doubled) < MIN_AUTO_TILES,
                    "{w}×{h} {rays}: {e}"
                );
                assert!(
                    count(w, h, e) >= MIN_AUTO_TILES || e == lo,
                    "{w}×{h} {rays}: {e} gives {} tiles",
                    count(w, h, e)
                );
                // And no smaller tile would already carry enough.
                if e > lo && count(w, h, e) >= MIN_AUTO_TILES {
                    let half = u64::from(e / 2);
                    assert!(
                        half * half * u64::from(rays) < TILE_RAYS,
                        "{w}×{h} {rays}: {e}"
                    );
                }
            }
        }
    }

    #[test]
    fn a_1080p_frame_gets_large_tiles_at_one_ray_and_small_ones_at_sixteen() {
        // 512² = 262,144 rays at one ray per pixel, in 4 × 3 = 12 tiles; 128² × 16 =
        // 262,144 at 16.
        assert_eq!(auto_tile(1920, 1080, 1), 512);
        assert_eq!(auto_tile(1920, 1080, 16), 128);
        // 1280×720 at one ray: 512 px would be 3 × 2 = 6 tiles, 256 px is 5 × 3 = 15.
        assert_eq!(auto_tile(1280, 720, 1), 256);
        // 640×480 at one ray: 512 px would be 2 tiles, 256 px 6, 128 px is 20.
        assert_eq!(auto_tile(640, 480, 1), 128);
    }

    /// Over many sizes and caps: a job is refused exactly when the tiler would make more
    /// tiles than the cap (counted by the tiler itself), and the edge it suggests is the
    /// smallest that the tiler keeps under the cap.
    #[test]
    fn jobs_of_too_many_tiles_are_refused_with_the_smallest_edge_that_fits() {
        let count = |w: u32, h: u32, e: u32| tessera_tracer::tiles(w, h, e).len() as u64;
        for (w, h) in [(1, 1), (100, 100), (333, 7), (1920, 1080), (7680, 4320)] {
            for max in [1, 2, 10, 169, 1000, 65_536] {
                for tile in [MIN_TILE, 9, 31, 256, MAX_TILE] {
                    let n = count(w, h, tile);
                    match check_tile_count(w, h, tile, max) {
                        Ok(()) => assert!(n <= max, "{w}×{h} tile {tile} max {max}"),
                        Err(e) => {
                            assert!(n > max, "{w}×{h} tile {tile} max {max}");
                            assert_eq!(e.status, 400);
                            assert_eq!(e.body["tiles"], n);
                            match e.body.get("min_tile").and_then(|v| v.as_u64()) {
                                Some(m) => {
                                    let m = m as u32;
                                    assert!(m > tile && m <= MAX_TILE && count(w, h, m) <= max);
                                    assert!(count(w, h, m - 1) > max, "{w}×{h} max {max}: {m}");
                                    let msg = e.body.get("error").and_then(|v| v.as_str());
                                    let msg = msg.unwrap_or_default();
                                    assert!(msg.contains(&format!("tile={m}")), "{msg}");
                                }
                                None => assert!(count(w, h, MAX_TILE) > max),
                            }
                        }
                    }
                }
            }
        }
    }
}
