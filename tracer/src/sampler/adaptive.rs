//! The adaptive sampler: a probe ray or a four-ray first pass per pixel, compared with the
//! neighbours' to decide which pixels end early and which are refined, up to the sampler's
//! maximum, with the decision made the same way in every tile.

use crate::math::Color;
use crate::tile::Rect;

use super::jitter::{PixelHash, SEED_FIRST, SEED_JITTER, mix};
use super::{ALL_QUADRANTS, CellSums, PixelGeometry, Sample, UnseenPattern};

/// The samples an adaptive pixel has taken so far: their sum, sum of squares, range and
/// whether they met more than one object.
#[derive(Clone, Copy)]
pub(super) struct Tally {
    pub(super) sum: Color,
    pub(super) sum_sq: Color,
    pub(super) min: Color,
    pub(super) max: Color,
    pub(super) count: u32,
    pub(super) object: u32,
    pub(super) mixed: bool,
}

impl Tally {
    pub(super) fn new() -> Tally {
        Tally {
            sum: Color::ZERO,
            sum_sq: Color::ZERO,
            min: Color::splat(f64::INFINITY),
            max: Color::splat(f64::NEG_INFINITY),
            count: 0,
            object: 0,
            mixed: false,
        }
    }

    pub(super) fn add(&mut self, s: Sample) {
        if self.count == 0 {
            self.object = s.object;
        } else if s.object != self.object {
            self.mixed = true;
        }
        self.sum += s.color;
        self.sum_sq += s.color * s.color;
        self.min = self.min.min(s.color);
        self.max = self.max.max(s.color);
        self.count += 1;
    }

    /// The tally of one sample.
    pub(super) fn of(s: Sample) -> Tally {
        let mut t = Tally::new();
        t.add(s);
        t
    }

    pub(super) fn mean(&self) -> Color {
        self.sum / f64::from(self.count)
    }

    /// Whether a step between these samples' pixel and `other`'s went unseen by both: in
    /// some channel the two means differ by more than `threshold`, and the two ranges of
    /// samples stay apart by more than `threshold` and by more than [`UNSEEN_GAP`] of that
    /// difference. An unseen step leaves a gap as high as the step itself (each pixel's
    /// samples all on its own side); a smooth gradient leaves a third of the difference on
    /// average (each pixel's samples reach towards the other's), and is no step at all.
    pub(super) fn unseen_step(&self, other: &Tally, threshold: f64) -> bool {
        let (a, b) = (self.mean(), other.mean());
        (0..3).any(|i| {
            let difference = (a[i] - b[i]).abs();
            let gap = (self.min[i] - other.max[i]).max(other.min[i] - self.max[i]);
            difference > threshold && gap > threshold && gap > UNSEEN_GAP * difference
        })
    }

    /// The same samples, each `by` more.
    pub(super) fn shifted(&self, by: Color) -> Tally {
        let n = f64::from(self.count);
        Tally {
            sum: self.sum + by * n,
            sum_sq: self.sum_sq + self.sum * by * 2.0 + by * by * n,
            min: self.min + by,
            max: self.max + by,
            ..*self
        }
    }

    /// Whether the samples disagree: more than `threshold` apart in a channel, or on
    /// different objects.
    pub(super) fn contrast(&self, threshold: f64) -> bool {
        self.mixed || (self.max - self.min).max_element() > threshold
    }

    /// The standard error of the mean, largest over the channels, as if the samples were
    /// independent (stratification makes the true error smaller, so this errs on the side
    /// of more samples).
    pub(super) fn standard_error(&self) -> f64 {
        let n = f64::from(self.count);
        let var = (self.sum_sq - self.sum * self.sum / n) / (n - 1.0);
        (var.max_element().max(0.0) / n).sqrt()
    }
}

/// First-pass result of one pixel for the adaptive sampler: its four samples and their
/// tally, where they were taken, and, for even `n`, the cell offset each quadrant drew (see
/// [`QuadrantOrder`]).
#[derive(Clone, Copy)]
pub(super) struct FirstPass {
    pub(super) tally: Tally,
    /// Quadrant `k`'s sample.
    pub(super) samples: [Sample; 4],
    pub(super) positions: [(f64, f64); 4],
    pub(super) offsets: [(u32, u32); 4],
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
pub(super) struct QuadrantOrder {
    pub(super) h: u32,
    pub(super) cells: Vec<(u32, u32)>,
    /// `1/n` for the grid's `n = 2h` cells a side.
    inv: f64,
}

impl QuadrantOrder {
    pub(super) fn new(h: u32) -> QuadrantOrder {
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
    pub(super) fn cell(&self, k: u32, rank: u32, offset: (u32, u32)) -> u32 {
        let (ci, cj) = self.column_row(k, rank, offset);
        cj * 2 * self.h + ci
    }

    /// [`Self::cell`] as the cell's column and row: what a sample's position needs, with no
    /// division to get them back from the cell's number.
    #[inline]
    pub(super) fn column_row(&self, k: u32, rank: u32, (a, b): (u32, u32)) -> (u32, u32) {
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
pub(super) fn cell_sample<F: Fn(f64, f64) -> Sample>(
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
/// distinct cells of the `n × n` grid drawn at random (see `odd_first_cell`), at the
/// cells' own hashed positions, and the offset returned is the cell's column and row. A
/// pixel refined takes the other cells, its `n × n` rays being exactly `jitter`'s.
pub(super) fn first_position(
    x: i64,
    y: i64,
    n: u32,
    order: Option<&QuadrantOrder>,
    k: u32,
    hashes: &FirstHashes,
) -> ((f64, f64), (u32, u32)) {
    let FirstHashes { first, cells } = *hashes;
    let Some(order) = order else {
        let (ci, cj) = odd_first_cell(first, k, n);
        let (ox, oy) = cells.pair(cj * n + ci);
        let inv = 1.0 / f64::from(n);
        return (
            (
                x as f64 + (f64::from(ci) + ox) * inv,
                y as f64 + (f64::from(cj) + oy) * inv,
            ),
            (ci, cj),
        );
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

/// The column and row of the cell of the `n × n` grid (odd `n ≥ 3`) that first-pass sample
/// `k` of a pixel with first-pass hash `first` takes (see [`first_position`]).
///
/// The four cells are a uniformly random set of four distinct cells, drawn without
/// replacement: sample `k` takes the `r`-th of the `n² − k` cells the samples before it
/// left, `r` uniform. So each cell is among them with chance `4/n²` (the mean of the four is
/// unbiased), and whether each cell is among them is negatively associated, which keeps the
/// bound that four rays in four quadrants give on missing a feature (STABILITY.md).
#[inline]
fn odd_first_cell(first: PixelHash, k: u32, n: u32) -> (u32, u32) {
    let mut taken = [0u32; 4];
    for j in 0..=k {
        // ⌊u · m / 2³²⌋ for u uniform on 32 bits takes each value in [0, m) with probability
        // within 2⁻³² of 1/m (as in `quadrant_offset`).
        let u = mix(first.0 ^ u64::from(j)) >> 32;
        let mut r = ((u * u64::from(n * n - j)) >> 32) as u32;
        // The r-th cell not yet taken: step past each taken cell at or below it, in
        // ascending order.
        let mut earlier = [u32::MAX; 4];
        earlier[..j as usize].copy_from_slice(&taken[..j as usize]);
        earlier.sort_unstable();
        for c in earlier {
            if c <= r {
                r += 1;
            }
        }
        taken[j as usize] = r;
    }
    let c = taken[k as usize];
    (c % n, c / n)
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
pub(super) struct FirstHashes {
    pub(super) first: PixelHash,
    pub(super) cells: PixelHash,
}

impl FirstHashes {
    pub(super) fn new(x: i64, y: i64) -> FirstHashes {
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
pub(super) fn first_pass<F: Fn(f64, f64) -> Sample>(
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
    for k in 0..4u32 {
        let ((sx, sy), offset, sample) = match probed {
            // The probe is this very ray: only the quadrant's offset is left to draw.
            Some((at, s)) if k == 0 => {
                let offset = match order {
                    Some(o) => quadrant_offset(hashes.first, 0, o.h),
                    None => odd_first_cell(hashes.first, 0, n),
                };
                (at, offset, s)
            }
            _ => {
                let ((sx, sy), offset) = first_position(x, y, n, order, k, &hashes);
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

/// The part of the difference between two neighbours' means that must lie between their
/// ranges of samples for a step between them to count as unseen ([`Ask::Unseen`]). A step
/// that neither saw leaves all of it (less the shading's spread); a linear gradient leaves
/// a third on average, more only where both pixels' first rays fell near their centres.
pub(super) const UNSEEN_GAP: f64 = 0.75;

/// Why a pixel takes more samples than its first pass (see [`refine`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) enum Ask {
    /// Only a neighbour asked: it saw an edge, or differs from this pixel with the edge
    /// seen inside one of the two.
    Neighbour,
    /// The pixel itself asked: its first pass disagreed, or the geometry says a solid it did
    /// not see may show in it.
    Own,
    /// A neighbour's colour differs from this pixel's and neither saw the step between
    /// them: a sliver that agreeing rays say nothing about lies in one of the two.
    Unseen,
    /// The geometry says the pixel's square crosses edges of the pattern its first rays
    /// all met on one side of: the pixel stops only where a stratified set of its rays
    /// bounds what those edges can hide to the threshold (and its standard error allows).
    Pattern(UnseenPattern),
}

/// The estimate of a pixel whose first pass, or a neighbour's, asked for more samples
/// (`ask`: why).
///
/// Even `n`, in stages of ranks per quadrant (see [`QuadrantOrder`]), each stage reusing the
/// ones before:
/// - 2 (8 rays in all), when only a neighbour asked ([`Ask::Neighbour`]) and `n ≥ 6`: the
///   pixel stops there unless these samples disagree (contrast above `threshold`, or two
///   objects);
/// - 4 (16 rays), when `n ≥ 6`, then every doubling below `n²/4` when `n/2` is a power of
///   two (32, 64, … rays): the pixel stops at such a stage if the standard error of its mean
///   is at most the stage's bound (see [`se_bound`]), unless the edge is unseen
///   ([`Ask::Unseen`]: rays that agree bound nothing about a sliver they all missed);
/// - for [`Ask::Pattern`], with `n/2` a power of two: the stages of `4^k` ranks per
///   quadrant (16, 64, 256 rays), whose rays are a stratified set over a grid of `m × m`
///   cells (`m = 2^(k+1)`, see [`QuadrantOrder`]): the pixel stops at such a stage if the
///   pattern's error bound for that grid is at most `threshold` and the standard error at
///   most the stage's bound;
/// - `n²/4` (all `n × n` cells).
///
/// Odd `n`: the `n × n` cells the first pass did not take, so that the pixel is `jitter`'s
/// `n × n` set; no stage stops it.
///
/// With `hidden` (a thin solid may show in the pixel that its rays have not met), no stage
/// stops it while its rays all meet one object: agreeing rays bound nothing about what they
/// all missed, and the pixel takes jitter's rays until one meets a second object. The same
/// holds for the quadrants refined alone (below) of a pixel whose first pass met two
/// objects.
///
/// Even `n` with `quadrants` short of [`ALL_QUADRANTS`]: the stages above run over the
/// quadrants named alone (their rays' tally decides each stop), and every other quadrant
/// keeps its one first-pass sample. The pixel is the mean of its four quadrants' means, each
/// an unbiased estimate of its quarter. The geometry names the quadrants where anything but
/// one backdrop's smooth shading may show ([`super::PixelGeometry::fitted_quadrants`]);
/// a feature there is found by exactly the rays that find it with every quadrant refined.
#[allow(clippy::too_many_arguments)]
pub(super) fn refine<F: Fn(f64, f64) -> Sample>(
    x: u32,
    y: u32,
    n: u32,
    threshold: f64,
    ask: Ask,
    hidden: bool,
    fp: &FirstPass,
    order: Option<&QuadrantOrder>,
    quadrants: u8,
    trace: &F,
) -> Color {
    let Some(order) = order else {
        // Summed in `stratified`'s order, the first pass's samples in their cells' places:
        // where no cells correct the rays, the very bits of `jitter`'s pixel.
        let hash = PixelHash::new(x, y, SEED_JITTER);
        let inv = 1.0 / f64::from(n);
        let mut sum = Color::ZERO;
        for cj in 0..n {
            for ci in 0..n {
                sum += match fp.offsets.iter().position(|&o| o == (ci, cj)) {
                    Some(k) => fp.samples[k].color,
                    None => {
                        cell_sample(i64::from(x), i64::from(y), hash, n, inv, (ci, cj), trace).color
                    }
                };
            }
        }
        return sum / f64::from(n * n);
    };
    let h = order.h;
    let hash = PixelHash::new(x, y, SEED_JITTER);
    let inv = 1.0 / f64::from(n);
    let (xi, yi) = (i64::from(x), i64::from(y));
    // The quadrants refined, in order, and the first-pass samples of the others.
    let full = quadrants & ALL_QUADRANTS == ALL_QUADRANTS;
    // Where the first pass met two objects, the edge between them lies in the quadrants
    // refined (the others hold the backdrop alone): their rays may all fall on one side
    // of it, so they too stop only once they meet two objects.
    let hidden = hidden || (!full && fp.tally.mixed);
    let mut ks = [0u32; 4];
    let mut kn = 0;
    let (mut tally, mut rest) = if full {
        (fp.tally, Color::ZERO)
    } else {
        (Tally::new(), Color::ZERO)
    };
    for k in 0..4u32 {
        if quadrants & (1 << k) != 0 {
            ks[kn] = k;
            kn += 1;
            if !full {
                tally.add(fp.samples[k as usize]);
            }
        } else {
            rest += fp.samples[k as usize].color;
        }
    }
    let ks = &ks[..kn];
    if ks.is_empty() {
        return rest / 4.0;
    }
    // The pixel's value with `ranks` ranks taken in each refined quadrant, their sum `sum`.
    let value = |sum: Color, ranks: u32| {
        if full {
            sum / f64::from(4 * ranks)
        } else {
            (sum / f64::from(ranks) + rest) / 4.0
        }
    };
    let sample = |k: u32, rank: u32| {
        let cell = order.column_row(k, rank, fp.offsets[k as usize]);
        cell_sample(xi, yi, hash, n, inv, cell, trace)
    };
    // Takes ranks `from..upto` of every refined quadrant.
    let take = |tally: &mut Tally, from: u32, upto: u32| {
        for rank in from..upto {
            for &k in ks {
                tally.add(sample(k, rank));
            }
        }
    };
    let all = h * h;
    let mut ranks = 1;
    if h >= 3 && ask == Ask::Neighbour {
        take(&mut tally, ranks, 2);
        ranks = 2;
        if !tally.contrast(threshold) {
            return value(tally.sum, ranks);
        }
    }
    if let Ask::Pattern(pattern) = ask {
        if h.is_power_of_two() {
            let (mut stage, mut m) = (4, 4);
            while stage < all {
                take(&mut tally, ranks, stage);
                ranks = stage;
                if pattern.error_bound(m) <= threshold
                    && (!hidden || tally.mixed)
                    && tally.standard_error() <= se_bound(threshold, 4 * stage)
                {
                    return value(tally.sum, stage);
                }
                (stage, m) = (stage * 4, m * 2);
            }
        }
    } else if h >= 3 && ask != Ask::Unseen {
        let mut stage = 4;
        while stage < all {
            take(&mut tally, ranks, stage);
            ranks = stage;
            if (!hidden || tally.mixed) && tally.standard_error() <= se_bound(threshold, 4 * stage)
            {
                return value(tally.sum, stage);
            }
            if !h.is_power_of_two() {
                break;
            }
            stage *= 2;
        }
    }
    // The last ranks decide nothing more: only their sum is kept, added in the same order
    // as `Tally::add` would add it.
    let mut sum = tally.sum;
    for rank in ranks..all {
        for &k in ks {
            sum += sample(k, rank).color;
        }
    }
    value(sum, all)
}

/// Traces the probe of pixel `(x, y)` (the first ray of its first pass, see
/// [`first_position`]) into `slot`, and returns it. Kept out of line: its callers mostly find
/// the probe already traced, and should not pay for this body's registers.
#[inline(never)]
fn trace_probe<F: Fn(f64, f64) -> Sample>(
    (x, y): (i64, i64),
    max: u32,
    order: Option<&QuadrantOrder>,
    trace: &F,
    slot: &mut Option<((f64, f64), Sample)>,
) -> ((f64, f64), Sample) {
    let hashes = FirstHashes::new(x, y);
    let ((sx, sy), _) = first_position(x, y, max, order, 0, &hashes);
    let p = ((sx, sy), trace(sx, sy));
    *slot = Some(p);
    p
}

/// The standard error at or below which a pixel of `rays` rays (16 or more) takes no more:
/// `threshold` at 16 rays, growing as √(rays/16).
///
/// The growth spreads rays the way that minimises the image's summed squared error: a
/// pixel whose samples have spread σ errs by about σ²/m with m rays, so its next m rays
/// (doubling) save σ²/2m, and they are worth their cost where σ²/m² is above a constant
/// common to all pixels, that is where σ/m, the standard error over √m, is. Pixels then end
/// with rays in proportion to σ (Neyman's allocation), rather than to σ² as a fixed bound
/// on the standard error would give, which spends most of the rays on the few noisiest
/// pixels. At 16 rays the bound is the threshold itself, as documented.
pub(super) fn se_bound(threshold: f64, rays: u32) -> f64 {
    threshold * (f64::from(rays) / 16.0).sqrt()
}

/// The most checker cells [`PixelGeometry::cells`] sums for a pixel of cap `max`: one per
/// ray the pixel could take at most (a cell's clipping costs less than a ray), and 16 at
/// least.
fn exact_cells(max: u32) -> u32 {
    (max * max).max(16)
}

/// `v` as `n` copies of `value`, in the allocation it has.
fn refill<T: Clone>(v: &mut Vec<T>, n: usize, value: T) {
    v.clear();
    v.resize(n, value);
}

/// The adaptive sampler over `rect`.
///
/// With a smoothness test, every pixel of the rect first traces its first ray alone (its
/// *probe*); a pixel ends there, with that one ray, when no neighbour whose probe saw the
/// same object differs from it by more than `threshold` (a steep shading gradient) and the
/// test says it is smooth. Every other pixel takes its four-ray first pass, the probe's ray
/// being the first of them, and goes on as without a test. A pixel that goes on compares its
/// first pass with its neighbours', and whether a neighbour has one depends on that
/// neighbour's own neighbours' probes: so the decision is made, the same way, for the
/// border pixels next to a pixel that goes on, with probes up to two pixels beyond the
/// rect ([`PROBE_BORDER`]). Every pixel's rays are thus what they would be in any other
/// tile.
///
/// Where a checkered plane alone shows in a pixel ([`PixelGeometry::cells`]), the pixel ends
/// after its probe with the cells' exact sum when nothing else changes in it. Otherwise
/// each of its rays is corrected by the cells' control variate, so that its spread, and its
/// difference from a neighbour's on the same plane, is what shadows and reflections make.
pub(super) fn adaptive<F, G>(
    rect: Rect,
    max: u32,
    threshold: f64,
    trace: &F,
    geometry: Option<&G>,
    out: &mut [Color],
) where
    F: Fn(f64, f64) -> Sample,
    G: PixelGeometry,
{
    SCRATCH.with(|cell| {
        // A rect traced from inside another's rays (no caller does that) would find the
        // thread's arrays in use, and gets arrays of its own rather than a panic.
        let mut own = Scratch::default();
        let mut kept = cell.try_borrow_mut();
        let scratch = match kept {
            Ok(ref mut s) => &mut **s,
            Err(_) => &mut own,
        };
        adaptive_in(rect, max, threshold, trace, geometry, out, scratch);
        if scratch.bytes() > SCRATCH_KEPT {
            *scratch = Scratch::default();
        }
    });
}

/// The adaptive sampler's working arrays for one rect (indexed by the pixels of the rect
/// grown by two on every side), kept by each thread and reused from rect to rect: a tile's
/// arrays are some hundred kilobytes, and allocated afresh for every tile, the allocator
/// hands their pages back to the system in between and every tile faults them in again,
/// which costs more than the rays on a scene of small objects. Only the allocations are
/// reused; every array is refilled for each rect, so no value carries over.
#[derive(Default)]
struct Scratch {
    ends: Vec<Option<Color>>,
    probes: Vec<Option<((f64, f64), Sample)>>,
    sums: Vec<Option<CellSums>>,
    decided: Vec<bool>,
    slot: Vec<u32>,
    passes: Vec<FirstPass>,
}

impl Scratch {
    /// The memory the arrays hold.
    fn bytes(&self) -> usize {
        use std::mem::size_of;
        self.ends.capacity() * size_of::<Option<Color>>()
            + self.probes.capacity() * size_of::<Option<((f64, f64), Sample)>>()
            + self.sums.capacity() * size_of::<Option<CellSums>>()
            + self.decided.capacity()
            + self.slot.capacity() * size_of::<u32>()
            + self.passes.capacity() * size_of::<FirstPass>()
    }
}

/// What a thread keeps between rects at most: the arrays of a 128-pixel tile and more; a
/// larger rect's are freed after it, so one big rect leaves no lasting memory behind.
const SCRATCH_KEPT: usize = 16 << 20;

thread_local! {
    static SCRATCH: std::cell::RefCell<Scratch> = std::cell::RefCell::new(Scratch::default());
}

/// [`adaptive`] with its working arrays in `scratch`.
fn adaptive_in<F, G>(
    rect: Rect,
    max: u32,
    threshold: f64,
    trace: &F,
    geometry: Option<&G>,
    out: &mut [Color],
    scratch: &mut Scratch,
) where
    F: Fn(f64, f64) -> Sample,
    G: PixelGeometry,
{
    let Scratch {
        ends,
        probes,
        sums,
        decided,
        slot,
        passes,
    } = scratch;
    let order = max.is_multiple_of(2).then(|| QuadrantOrder::new(max / 2));
    let order = order.as_ref();
    // Pixels are indexed in the rect grown by two on every side; `(bx, by)` is the rect's
    // `(bx - 2, by - 2)`. Border pixels outside the image are traced like any others (the
    // camera extends past the image), so a pixel at the image's edge is treated exactly like
    // one inside.
    let (w, h) = (rect.width as usize, rect.height as usize);
    let (pw, ph) = (w + 4, h + 4);
    let at = |bx: usize, by: usize| by * pw + bx;
    let pixel = |bx: usize, by: usize| {
        (
            i64::from(rect.x) + bx as i64 - 2,
            i64::from(rect.y) + by as i64 - 2,
        )
    };
    let neighbours =
        |bx: usize, by: usize| [(bx - 1, by), (bx + 1, by), (bx, by - 1), (bx, by + 1)];

    // Which inner pixels end after their probe, decided where needed: for every pixel of
    // the rect, and for a border pixel next to one that goes on (its first pass is compared
    // with). A pixel's probe is traced when first needed, and its neighbours' only once its
    // own is smooth, so a region nothing can end in (a mirror) traces no probes beyond the
    // first passes' first rays.
    // `Some(value)`: the pixel ends with that value (its probe's, or the geometry's).
    refill(ends, pw * ph, None);
    refill(probes, pw * ph, None);
    // What a checkered plane's cells give each decided pixel (see `PixelGeometry::cells`).
    refill(sums, pw * ph, None);
    if let Some(geometry) = geometry {
        // The probe of the pixel at `i`, traced if it is not yet. The check is inlined at
        // every call and the tracing is not: most calls find the probe traced.
        let probe = |probes: &mut Vec<Option<((f64, f64), Sample)>>, bx: usize, by: usize| {
            let i = at(bx, by);
            match probes[i] {
                Some(p) => p,
                None => trace_probe(pixel(bx, by), max, order, trace, &mut probes[i]),
            }
        };
        let decide = |probes: &mut Vec<Option<((f64, f64), Sample)>>,
                      sums: &mut Vec<Option<CellSums>>,
                      bx: usize,
                      by: usize| {
            let ((sx, sy), p) = probe(probes, bx, by);
            let (x, y) = pixel(bx, by);
            let gentle = |q: &Sample| {
                q.object != p.object || (q.color - p.color).abs().max_element() <= threshold
            };
            // The neighbours already traced first, then the test, then the rest: each step
            // is only taken if the ones before allow the pixel to end. A neighbour checked
            // in the first step is not checked again.
            let around = neighbours(bx, by);
            let mut traced = [false; 4];
            let mut gentle_so_far = true;
            for (k, &(nx, ny)) in around.iter().enumerate() {
                if let Some((_, q)) = &probes[at(nx, ny)] {
                    traced[k] = true;
                    if !gentle(q) {
                        gentle_so_far = false;
                        break;
                    }
                }
            }
            let smooth = gentle_so_far
                && geometry.is_smooth(x, y, sx, sy, &p)
                && around
                    .iter()
                    .zip(traced)
                    .all(|(&(nx, ny), done)| done || gentle(&probe(probes, nx, ny).1));
            if smooth {
                return Some(p.color);
            }
            // A checkered plane alone in the square: its cells' exact areas, where they are
            // few enough to cost less than the rays they replace; the pixel's value where
            // nothing else changes in it, and otherwise the control variate its rays are
            // corrected by (see `corrected`).
            let cells = geometry.cells(x, y, (sx, sy), &p, threshold, exact_cells(max));
            sums[at(bx, by)] = cells;
            cells.and_then(|c| c.exact)
        };
        refill(decided, pw * ph, false);
        for by in 2..h + 2 {
            for bx in 2..w + 2 {
                ends[at(bx, by)] = decide(probes, sums, bx, by);
                decided[at(bx, by)] = true;
            }
        }
        for by in 2..h + 2 {
            for bx in 2..w + 2 {
                if ends[at(bx, by)].is_some() {
                    continue;
                }
                for (nx, ny) in neighbours(bx, by) {
                    if !decided[at(nx, ny)] {
                        ends[at(nx, ny)] = decide(probes, sums, nx, ny);
                        decided[at(nx, ny)] = true;
                    }
                }
            }
        }
    }

    // A pixel's rays, each corrected by the control variate of its checkered plane's cells
    // where it has one: `f − direct + mean(direct)` has the same mean over the square as
    // `f` (to within the cells' sums' bound), and none of the cells' edges in its spread.
    let correct = |cells: Option<CellSums>, s: Sample, at: (f64, f64)| match (cells, geometry) {
        (Some(c), Some(g)) => Sample {
            color: s.color - g.direct(c.object, at) + c.direct,
            object: s.object,
        },
        _ => s,
    };
    let corrected =
        |cells: Option<CellSums>| move |sx: f64, sy: f64| correct(cells, trace(sx, sy), (sx, sy));

    // First passes where the rect's decisions need them: its pixels that go on, and their
    // neighbours that go on (`slot` indexes `passes`, NONE where a pixel has none).
    const NONE: u32 = u32::MAX;
    refill(slot, pw * ph, NONE);
    passes.clear();
    for by in 2..h + 2 {
        for bx in 2..w + 2 {
            if ends[at(bx, by)].is_some() {
                continue;
            }
            for (qx, qy) in std::iter::once((bx, by)).chain(neighbours(bx, by)) {
                let i = at(qx, qy);
                if slot[i] == NONE && ends[i].is_none() {
                    let (x, y) = pixel(qx, qy);
                    let probed = probes[i].map(|(at, p)| (at, correct(sums[i], p, at)));
                    // At most one pass per pixel of the grown rect, whose size is bounded
                    // by the image's (`Limits`) and far below u32::MAX.
                    slot[i] = passes.len() as u32;
                    passes.push(first_pass(x, y, max, order, &corrected(sums[i]), probed));
                }
            }
        }
    }
    // What a pixel's neighbours compare with: its first pass's tally (whether it met two
    // objects, its first object, its mean and the range of its samples); for a pixel that
    // ended, its probe's (corrected, where the pixel has cells' sums).
    let seen = |i: usize| -> Tally {
        match (slot[i], probes[i]) {
            (NONE, Some((at, p))) => Tally::of(correct(sums[i], p, at)),
            (NONE, None) => Tally::of(Sample {
                color: Color::ZERO,
                object: Sample::BACKGROUND,
            }),
            (k, _) => passes[k as usize].tally,
        }
    };

    let mut i = 0;
    for by in 2..h + 2 {
        for bx in 2..w + 2 {
            let here = at(bx, by);
            let (x, y) = (rect.x + (bx - 2) as u32, rect.y + (by - 2) as u32);
            out[i] = match (ends[here], slot[here]) {
                (Some(value), _) => value,
                // Unreachable: a pixel that does not end has its first pass.
                (_, NONE) => Color::ZERO,
                (_, k) => {
                    let fp = &passes[k as usize];
                    let c = &fp.tally;
                    // More samples where the pixel's own samples disagree (contrast or a
                    // second object) or the geometry says a solid they did not see may show
                    // in it (one thinner than their spacing, slipped between them: refined
                    // as if they had seen it), or where a neighbour saw an edge, a different
                    // object or a different mean: an edge or a thin feature there may reach
                    // into this pixel between its own samples, and four samples that happen
                    // to agree inside fine texture (a checker near the horizon) still
                    // disagree with their neighbours'.
                    //
                    // A neighbour whose mean differs by more than `threshold` while the
                    // ranges of the two first passes stay apart by most of that difference
                    // (see `Tally::unseen_step`) has a step between them that neither saw,
                    // in one of the two: a sliver of one pixel that four rays, and eight, can all
                    // miss. Both take every ray (`Ask::Unseen`): stopping at eight agreeing
                    // rays there made `adaptive` 8×8 to 32×32 worse than `jitter` 4×4 along
                    // checker edges (a sixth of a pixel lost, 56 to 73 steps off). A step
                    // between two objects of like colours costs less than the threshold if
                    // missed, so only colours count here.
                    let mean = c.mean();
                    let (px, py) = (i64::from(x), i64::from(y));
                    let flagged =
                        !c.mixed && geometry.is_some_and(|g| g.may_hide(px, py, c.object));
                    // Two pixels on one checkered plane whose rays are corrected by its cells
                    // (`corrected`) compare what is left: shadows and reflections. Their
                    // cells differ, and the cells are summed exactly in both.
                    let mine = sums[here];
                    let (mut near, mut unseen, mut beside_other) = (false, false, false);
                    for (nx, ny) in neighbours(bx, by) {
                        let there = at(nx, ny);
                        let (mut c, mut nb) = (*c, seen(there));
                        if let (Some(a), Some(b)) = (mine, sums[there])
                            && a.object == b.object
                        {
                            (c, nb) = (c.shifted(-a.direct), nb.shifted(-b.direct));
                        }
                        let other_object = nb.object != c.object;
                        let other_mean = (nb.mean() - c.mean()).abs().max_element() > threshold;
                        near |= nb.mixed || other_object || other_mean;
                        beside_other |= nb.mixed || other_object;
                        unseen |= c.unseen_step(&nb, threshold);
                    }
                    // Where nothing but smooth shading and a checker's cells can change in
                    // the pixel, an unseen step beside it is a cell edge: the pattern's own
                    // bound below decides how far this pixel is searched, and an edge that
                    // lies in the neighbour costs this pixel nothing.
                    // The quarters a thin solid may show in, asked once and only where
                    // needed (see `refine`).
                    let quarters = std::cell::OnceCell::new();
                    let quarters = || {
                        *quarters.get_or_init(|| match (order, geometry) {
                            (Some(_), Some(g)) => g.fitted_quadrants(px, py),
                            _ => None,
                        })
                    };
                    // A solid the first pass did not see may show in the pixel (the
                    // geometry flags one), or the pixel's one object is a thin solid whose
                    // silhouette may cross it (a neighbour saw another object, and nothing
                    // but thin solids shows here besides the backdrop): agreeing rays bound
                    // nothing about what they all missed.
                    let hidden =
                        flagged || (!c.mixed && beside_other && quarters().is_some_and(|q| q != 0));
                    let own = c.contrast(threshold) || hidden;
                    if unseen && !c.mixed {
                        let (sx, sy) = fp.positions[0];
                        unseen =
                            !geometry.is_some_and(|g| g.pattern_alone(px, py, sx, sy, c.object));
                    }
                    // Rays that all saw one object may have fallen on one side of an edge of
                    // its pattern (a checker's corner in the pixel, a diagonal edge past
                    // them, cells finer than their spacing): agreeing, or differing only by
                    // shading, they bound nothing about the other side, and the early stops
                    // would end the pixel on theirs. The geometry knows where a checker
                    // plane's cells meet and which cells the rays met.
                    //
                    // For even `max` the first pass is itself a stratified set over the
                    // 2 × 2 quadrants: where that already bounds the edges' error, nothing
                    // changes. An odd cap's four cells are no stratified set, and bound only
                    // what one ray would.
                    //
                    // Rays corrected by the cells' control variate have no such edges left.
                    let first_grid = if order.is_some() { 2 } else { 1 };
                    let pattern = (!unseen && !c.mixed && mine.is_none())
                        .then(|| geometry?.unseen_pattern(px, py, c.object, &fp.positions))
                        .flatten()
                        .filter(|p| p.error_bound(first_grid) > threshold);
                    let ask = if unseen {
                        Ask::Unseen
                    } else if let Some(p) = pattern {
                        Ask::Pattern(p)
                    } else if own {
                        Ask::Own
                    } else {
                        Ask::Neighbour
                    };
                    if own || near || pattern.is_some() {
                        // Where a thin solid is why the pixel goes on (the geometry flags
                        // one, or the first pass met two objects), the geometry knows which
                        // quarters it may show in and the rest holds one smooth backdrop:
                        // only those quarters are refined.
                        let quadrants = if hidden || c.mixed {
                            quarters().unwrap_or(ALL_QUADRANTS)
                        } else {
                            ALL_QUADRANTS
                        };
                        refine(
                            x,
                            y,
                            max,
                            threshold,
                            ask,
                            hidden,
                            fp,
                            order,
                            quadrants,
                            &corrected(mine),
                        )
                    } else {
                        mean
                    }
                }
            };
            i += 1;
        }
    }
}
