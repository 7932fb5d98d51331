//! Where an adaptive pixel's rays go: its first pass (one ray per quadrant for an even cap,
//! four random cells of the grid for an odd one), and for an even cap the order in which
//! each quadrant takes its cells. Not what the rays decide (`refine`, the driver).

use crate::math::Color;

use super::Tally;
use crate::sampler::Sample;
use crate::sampler::jitter::{PixelHash, SEED_FIRST, SEED_JITTER, mix};

/// First-pass result of one pixel for the adaptive sampler: its four samples and their
/// tally, where they were taken, and, for even `n`, the cell offset each quadrant drew (see
/// [`QuadrantOrder`]).
#[derive(Clone, Copy)]
pub(in crate::sampler) struct FirstPass {
    pub(in crate::sampler) tally: Tally,
    /// Quadrant `k`'s sample.
    pub(in crate::sampler) samples: [Sample; 4],
    pub(in crate::sampler) positions: [(f64, f64); 4],
    pub(in crate::sampler) offsets: [(u32, u32); 4],
}

/// The order in which each quadrant of an adaptive pixel with an even cap `n` (`h = n/2`
/// cells a side per quadrant) takes its cells of the `n × n` grid, and where it may stop.
///
/// The order is a fixed list of cells of an `h × h` quadrant, shifted cyclically by the
/// quadrant's hashed offset `(a, b)`. Since the offset is uniform over the quadrant, the
/// cell of any rank is uniform over it, and its sample (at that cell's own hashed position,
/// whatever the rank) is uniform over the quadrant too: the mean of the same number of ranks
/// in every quadrant is an unbiased estimate of the pixel, and all `h²` ranks are exactly
/// the `n × n` stratified set. The list is built so that its prefixes are well spread:
///
/// - ranks 0–3 are a 2 × 2 lattice: the offset, the cell half the quadrant away diagonally,
///   then the two others (for every `h`);
/// - for `h` a power of two, each later doubling repeats the lattice one level down: ranks
///   `m..2m` put a cell diagonally across each block of the current level from the cell of
///   rank `r − m`, ranks `2m..4m` fill the two other sub-blocks. So every prefix of `4^k`
///   ranks has exactly one cell in each block of `h/2^k` cells a side (16 rays per pixel are
///   one per quarter-pixel square, as 4 × 4 jitter has), and every prefix of `2·4^k` ranks
///   has one in each row and column of those blocks' halves.
pub(in crate::sampler) struct QuadrantOrder {
    pub(in crate::sampler) h: u32,
    pub(in crate::sampler) cells: Vec<(u32, u32)>,
    /// `1/n` for the grid's `n = 2h` cells a side.
    inv: f64,
}

impl QuadrantOrder {
    pub(in crate::sampler) fn new(h: u32) -> QuadrantOrder {
        let mut cells = vec![(0, 0)];
        if h.is_power_of_two() {
            let mut size = h;
            while size > 1 {
                let half = size / 2;
                let level: Vec<(u32, u32)> = cells.clone();
                cells.extend(level.iter().map(|&(i, j)| (i + half, j + half)));
                for &(i, j) in &level {
                    cells.push((i + half, j));
                    cells.push((i, j + half));
                }
                size = half;
            }
        } else {
            let s = h.div_ceil(2);
            cells.extend([(s, s), (s, 0), (0, s)]);
            for j in 0..h {
                for i in 0..h {
                    if !cells.contains(&(i, j)) {
                        cells.push((i, j));
                    }
                }
            }
        }
        debug_assert_eq!(cells.len() as u32, h * h);
        QuadrantOrder {
            h,
            cells,
            inv: 1.0 / f64::from(2 * h),
        }
    }

    /// The cell of the `n × n` grid that quadrant `k` takes as its sample number `rank`,
    /// given the quadrant's offset `(a, b)` in `[0, h)²`.
    #[cfg(test)]
    pub(in crate::sampler) fn cell(&self, k: u32, rank: u32, offset: (u32, u32)) -> u32 {
        let (ci, cj) = self.column_row(k, rank, offset);
        cj * 2 * self.h + ci
    }

    /// [`Self::cell`] as the cell's column and row: what a sample's position needs, with no
    /// division to get them back from the cell's number.
    #[inline]
    pub(in crate::sampler) fn column_row(
        &self,
        k: u32,
        rank: u32,
        (a, b): (u32, u32),
    ) -> (u32, u32) {
        let h = self.h;
        let (di, dj) = self.cells[rank as usize];
        // a + di < 2h, so one subtraction is the remainder.
        let wrap = |v: u32| if v >= h { v - h } else { v };
        ((k & 1) * h + wrap(a + di), (k >> 1) * h + wrap(b + dj))
    }
}

/// The sample of the cell at column `ci`, row `cj` of pixel `(x, y)`'s `n × n` grid, at
/// the cell's hashed position (the hash of its number `cj·n + ci`, as `jitter`'s).
#[inline]
pub(in crate::sampler) fn cell_sample<F: Fn(f64, f64) -> Sample>(
    x: i64,
    y: i64,
    hash: PixelHash,
    n: u32,
    inv: f64,
    (ci, cj): (u32, u32),
    trace: &F,
) -> Sample {
    let (ox, oy) = hash.pair(cj * n + ci);
    trace(
        x as f64 + (f64::from(ci) + ox) * inv,
        y as f64 + (f64::from(cj) + oy) * inv,
    )
}

/// Where pixel `(x, y)`'s first-pass sample in quadrant `k` lies and, for even `n`, the
/// quadrant's offset (see [`QuadrantOrder`]).
///
/// For even `n` it is rank 0 of the quadrant, so every later stage reuses it. For odd `n`
/// (at least 3) the quadrants do not align with the grid: the four samples are four
/// distinct cells of the `n × n` grid drawn at random (see `odd_first_cells`), at the
/// cells' own hashed positions, and the offset returned is the cell's column and row. A
/// pixel refined takes the other cells, its `n × n` rays being exactly `jitter`'s.
pub(in crate::sampler) fn first_position(
    x: i64,
    y: i64,
    n: u32,
    order: Option<&QuadrantOrder>,
    k: u32,
    hashes: &FirstHashes,
) -> ((f64, f64), (u32, u32)) {
    let FirstHashes { first, cells } = *hashes;
    let Some(order) = order else {
        let c = odd_first_cells(first, n, k as usize + 1)[k as usize];
        return odd_position(x, y, n, c, cells);
    };
    let h = order.h;
    let (a, b) = quadrant_offset(first, k, h);
    // Rank 0 is the quadrant's cell `(a, b)` itself (`QuadrantOrder::cell` with the list's
    // first entry `(0, 0)`), so its column and row need no division from its number.
    let (ci, cj) = ((k & 1) * h + a, (k >> 1) * h + b);
    // The cells' positions are jitter's: a pixel refined to the full grid takes exactly the
    // rays of `jitter` with the same `n` (the same arithmetic as `cell_sample`).
    let (ox, oy) = cells.pair(cj * n + ci);
    let inv = order.inv;
    (
        (
            x as f64 + (f64::from(ci) + ox) * inv,
            y as f64 + (f64::from(cj) + oy) * inv,
        ),
        (a, b),
    )
}

/// Where the first-pass sample that takes cell `c` (number `cj·n + ci`) of pixel `(x, y)`'s
/// `n × n` grid lies, at the cell's hashed position (`cells`, as `jitter`'s), with the cell's
/// column and row.
#[inline]
fn odd_position(x: i64, y: i64, n: u32, c: u32, cells: PixelHash) -> ((f64, f64), (u32, u32)) {
    let (ci, cj) = (c % n, c / n);
    let (ox, oy) = cells.pair(cj * n + ci);
    let inv = 1.0 / f64::from(n);
    (
        (
            x as f64 + (f64::from(ci) + ox) * inv,
            y as f64 + (f64::from(cj) + oy) * inv,
        ),
        (ci, cj),
    )
}

/// The cells of the `n × n` grid (odd `n ≥ 3`, numbered `cj·n + ci`) that the first `count`
/// (at most four) first-pass samples of a pixel with first-pass hash `first` take (see
/// [`first_position`]); the entries past `count` are 0.
///
/// The four cells are a uniformly random set of four distinct cells, drawn without
/// replacement: sample `j` takes the `r`-th of the `n² − j` cells the samples before it
/// left, `r` uniform. So each cell is among them with chance `4/n²` (the mean of the four is
/// unbiased), and whether each cell is among them is negatively associated, which keeps the
/// bound that four rays in four quadrants give on missing a feature (STABILITY.md). A pass
/// draws all four at once: each draw depends on the ones before it.
#[inline]
fn odd_first_cells(first: PixelHash, n: u32, count: usize) -> [u32; 4] {
    let mut taken = [0u32; 4];
    // The cells taken so far in ascending order, then `u32::MAX`, above every cell.
    let mut ascending = [u32::MAX; 4];
    for (j, cell) in taken.iter_mut().enumerate().take(count) {
        // ⌊u · m / 2³²⌋ for u uniform on 32 bits takes each value in [0, m) with probability
        // within 2⁻³² of 1/m (as in `quadrant_offset`).
        let u = mix(first.0 ^ j as u64) >> 32;
        let mut r = ((u * u64::from(n * n - j as u32)) >> 32) as u32;
        // The r-th cell not yet taken: step past each taken cell at or below it, in
        // ascending order.
        for c in ascending {
            if c <= r {
                r += 1;
            }
        }
        *cell = r;
        // Insert `r` in order: `j` cells precede the free slot.
        let mut i = j;
        while i > 0 && ascending[i - 1] > r {
            ascending[i] = ascending[i - 1];
            i -= 1;
        }
        ascending[i] = r;
    }
    taken
}

/// The offset `(a, b)` in `[0, h)²` that quadrant `k` of a pixel with first-pass hash
/// `first` draws (see [`QuadrantOrder`]).
#[inline]
fn quadrant_offset(first: PixelHash, k: u32, h: u32) -> (u32, u32) {
    // Each half of one 64-bit hash picks a coordinate: ⌊u · h / 2³²⌋ for u uniform on 32
    // bits takes each value in [0, h) with probability within 2⁻³² of 1/h.
    let r = mix(first.0 ^ u64::from(k));
    let a = (((r >> 32) * u64::from(h)) >> 32) as u32;
    let b = (((r & 0xffff_ffff) * u64::from(h)) >> 32) as u32;
    (a, b)
}

/// A pixel's hashes for its first pass: the quadrants' offsets and the cells' positions.
#[derive(Clone, Copy)]
pub(in crate::sampler) struct FirstHashes {
    pub(in crate::sampler) first: PixelHash,
    pub(in crate::sampler) cells: PixelHash,
}

impl FirstHashes {
    pub(in crate::sampler) fn new(x: i64, y: i64) -> FirstHashes {
        // Border pixels left of or above the image have negative coordinates; their hash
        // input wraps, which is as good a seed as any and the same in every tile.
        let (hx, hy) = (x as u32, y as u32);
        FirstHashes {
            first: PixelHash::new(hx, hy, SEED_FIRST),
            cells: PixelHash::new(hx, hy, SEED_JITTER),
        }
    }
}

/// The first pass of pixel `(x, y)`: one sample per quadrant (see [`first_position`]), the
/// first of them `probed` (its position and sample) when the pixel's probe already traced
/// it.
pub(in crate::sampler) fn first_pass<F: Fn(f64, f64) -> Sample>(
    x: i64,
    y: i64,
    n: u32,
    order: Option<&QuadrantOrder>,
    trace: &F,
    probed: Option<((f64, f64), Sample)>,
) -> FirstPass {
    let mut fp = FirstPass {
        tally: Tally::new(),
        samples: [Sample {
            color: Color::ZERO,
            object: Sample::BACKGROUND,
        }; 4],
        positions: [(0.0, 0.0); 4],
        offsets: [(0, 0); 4],
    };
    let hashes = FirstHashes::new(x, y);
    // An odd cap's four cells, drawn once for the pass.
    let odd = match order {
        None => odd_first_cells(hashes.first, n, 4),
        Some(_) => [0; 4],
    };
    for k in 0..4u32 {
        let ((sx, sy), offset, sample) = match probed {
            // The probe is this very ray: only the quadrant's offset is left to draw.
            Some((at, s)) if k == 0 => {
                let offset = match order {
                    Some(o) => quadrant_offset(hashes.first, 0, o.h),
                    None => (odd[0] % n, odd[0] / n),
                };
                (at, offset, s)
            }
            _ => {
                let ((sx, sy), offset) = match order {
                    Some(_) => first_position(x, y, n, order, k, &hashes),
                    None => odd_position(x, y, n, odd[k as usize], hashes.cells),
                };
                ((sx, sy), offset, trace(sx, sy))
            }
        };
        fp.offsets[k as usize] = offset;
        fp.positions[k as usize] = (sx, sy);
        fp.samples[k as usize] = sample;
        fp.tally.add(sample);
    }
    fp
}
