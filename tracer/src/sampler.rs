//! Pixel samplers: where in a pixel rays go, how many, and how they are averaged.
//!
//! Each sampler estimates the exact pixel value of SCENE.md, the average of the clamped
//! radiance over the pixel's square. Sample positions come from a hash of the pixel's
//! coordinates and the sample's index, never from a running random generator, so a pixel's
//! value depends only on the scene and the pixel: not on the tile, the thread or the machine.
//!
//! The adaptive sampler also looks at the first samples of the four neighbouring pixels; a
//! tile computes those for a border around itself (two pixels for the probes, one for the
//! first passes), which keeps it tile-independent.
//! This module positions and combines samples; tracing them is the caller's closure.

use crate::math::Color;
use crate::tile::Rect;

/// The sampling strategy of a render.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Sampler {
    /// One ray through the pixel centre (`antialias = off`).
    Center,
    /// The thesis's five rays: the centre and the four points `(±¼, ±¼)` from it
    /// (`antialias = on`).
    Thesis,
    /// `n × n` rays on a regular grid.
    Grid { n: u32 },
    /// `n × n` stratified rays, one placed by hash in each cell of the grid.
    Jitter { n: u32 },
    /// One ray (the *probe*), and no more where the renderer's smoothness test shows that
    /// nothing but smooth shading changes in the pixel and no neighbour's probe on the same
    /// surface differs from it by more than `threshold` (see
    /// [`Sampler::render_rect_probed`]). Elsewhere a first pass of one jittered ray per
    /// pixel quadrant (the probe among them), then more where the image needs them, in
    /// stages that reuse every ray already traced, up to `max × max` stratified rays (for
    /// even `max`, the very rays of `Jitter { n: max }`): where the first pass varies by
    /// more than `threshold` or meets two objects, where the scene's geometry says a solid
    /// the first pass did not see may show in the pixel ([`PixelGeometry::may_hide`]), or
    /// where a neighbour's first pass saw an edge, another object or another mean. For even
    /// `max ≥ 6`, a pixel only a neighbour asked for takes one more ray per quadrant first
    /// and stops there unless they disagree (or the step between them went unseen by both:
    /// then both take every ray), and a pixel at 16 rays (or, for `max/2` a power of two,
    /// 32, 64, …) stops there once the standard error of its mean is at most `threshold` ·
    /// √(rays/16) (see `refine` and `se_bound` in this module).
    Adaptive { max: u32, threshold: f64 },
}

impl Sampler {
    pub const DEFAULT_ADAPTIVE_MAX: u32 = 4;
    pub const DEFAULT_THRESHOLD: f64 = 0.02;

    /// The scene-file name of the sampler (`sampler = ...`).
    pub fn name(&self) -> &'static str {
        match self {
            Sampler::Center => "center",
            Sampler::Thesis => "thesis",
            Sampler::Grid { .. } => "grid",
            Sampler::Jitter { .. } => "jitter",
            Sampler::Adaptive { .. } => "adaptive",
        }
    }

    /// This sampler with a user's overrides applied (from a CLI flag or a job's query
    /// string): another sampler by name, another sample count per axis, another threshold.
    /// Values the override leaves out keep the scene's choice where it applies.
    pub fn with_overrides(
        self,
        name: Option<&str>,
        samples: Option<u32>,
        threshold: Option<f64>,
        max_samples: u32,
    ) -> Result<Sampler, String> {
        if let Some(n) = samples
            && !(1..=max_samples).contains(&n)
        {
            return Err(format!("samples must be from 1 to {max_samples}"));
        }
        if let Some(t) = threshold
            && !(t > 0.0 && t.is_finite())
        {
            return Err("threshold must be a number above 0".into());
        }
        let (own_n, own_threshold) = match self {
            Sampler::Grid { n } | Sampler::Jitter { n } => (Some(n), None),
            Sampler::Adaptive { max, threshold } => (Some(max), Some(threshold)),
            _ => (None, None),
        };
        let (samples_named, threshold_named) = (samples.is_some(), threshold.is_some());
        let n = samples.or(own_n).unwrap_or(4);
        let threshold = threshold
            .or(own_threshold)
            .unwrap_or(Self::DEFAULT_THRESHOLD);
        // Case-insensitive, as the scene's own `sampler = Jitter` is.
        let name = name.map(str::to_ascii_lowercase);
        let out = match name.as_deref().unwrap_or(self.name()) {
            "center" => Sampler::Center,
            "thesis" => Sampler::Thesis,
            "grid" => Sampler::Grid { n },
            "jitter" => Sampler::Jitter { n },
            "adaptive" => Sampler::Adaptive { max: n, threshold },
            other => {
                return Err(format!(
                    "unknown sampler `{other}`: expected center, thesis, grid, jitter or adaptive"
                ));
            }
        };
        // As in a scene file, a setting the sampler does not use is an error, not ignored.
        if samples_named && matches!(out, Sampler::Center | Sampler::Thesis) {
            return Err(format!(
                "samples applies to the grid, jitter and adaptive samplers, not to {}",
                out.name()
            ));
        }
        if threshold_named && !matches!(out, Sampler::Adaptive { .. }) {
            return Err(format!(
                "threshold applies to the adaptive sampler only, not to {}",
                out.name()
            ));
        }
        Ok(out)
    }

    /// The most primary rays one pixel can take.
    pub fn max_samples_per_pixel(&self) -> u32 {
        match *self {
            Sampler::Center => 1,
            Sampler::Thesis => 5,
            Sampler::Grid { n } | Sampler::Jitter { n } => n * n,
            Sampler::Adaptive { max, .. } if max.is_multiple_of(2) => max * max,
            Sampler::Adaptive { max, .. } => 4 + max * max,
        }
    }

    /// Renders `rect` into `out` (row-major, `rect.pixel_count()` long). `trace(x, y)` returns
    /// the clamped radiance of the primary ray through image-plane position `(x, y)` and the
    /// identity of what it hit first.
    ///
    /// Without a probe, the adaptive sampler takes at least its first pass of four rays in
    /// every pixel; [`Sampler::render_rect_probed`] lets it end smooth pixels after one.
    pub fn render_rect<F>(&self, rect: Rect, trace: F, out: &mut [Color])
    where
        F: Fn(f64, f64) -> Sample,
    {
        self.render_rect_inner(rect, &trace, None::<&NoGeometry>, out);
    }

    /// [`Sampler::render_rect`] with what the scene's geometry knows of each pixel's square
    /// (see [`PixelGeometry`]): the adaptive sampler ends pixels it calls smooth after one
    /// ray, and refines pixels where a solid their first pass did not see may show. Other
    /// samplers never ask it.
    pub fn render_rect_probed<F, G>(&self, rect: Rect, trace: F, geometry: &G, out: &mut [Color])
    where
        F: Fn(f64, f64) -> Sample,
        G: PixelGeometry,
    {
        self.render_rect_inner(rect, &trace, Some(geometry), out);
    }

    fn render_rect_inner<F, G>(
        &self,
        rect: Rect,
        trace: &F,
        geometry: Option<&G>,
        out: &mut [Color],
    ) where
        F: Fn(f64, f64) -> Sample,
        G: PixelGeometry,
    {
        debug_assert_eq!(out.len(), rect.pixel_count());
        if let Sampler::Adaptive { max, threshold } = *self {
            adaptive(rect, max, threshold, trace, geometry, out);
            return;
        }
        let mut i = 0;
        for y in rect.y..rect.y + rect.height {
            for x in rect.x..rect.x + rect.width {
                out[i] = self.pixel(x, y, trace);
                i += 1;
            }
        }
    }

    fn pixel<F: Fn(f64, f64) -> Sample>(&self, x: u32, y: u32, trace: &F) -> Color {
        let (fx, fy) = (f64::from(x), f64::from(y));
        match *self {
            Sampler::Center => trace(fx + 0.5, fy + 0.5).color,
            Sampler::Thesis => {
                let mut sum = trace(fx + 0.5, fy + 0.5).color;
                for (dx, dy) in [(0.25, 0.25), (0.75, 0.25), (0.25, 0.75), (0.75, 0.75)] {
                    sum += trace(fx + dx, fy + dy).color;
                }
                sum / 5.0
            }
            Sampler::Grid { n } => stratified(x, y, n, None, trace),
            Sampler::Jitter { n } => stratified(x, y, n, Some(SEED_JITTER), trace),
            Sampler::Adaptive { max, threshold } => {
                let mut one = [Color::ZERO];
                adaptive(
                    Rect::new(x, y, 1, 1),
                    max,
                    threshold,
                    trace,
                    None::<&NoGeometry>,
                    &mut one,
                );
                one[0]
            }
        }
    }
}

/// What one primary sample saw.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sample {
    /// Radiance, already clamped to `[0, 1]` per channel.
    pub color: Color,
    /// The object the primary ray hit first ([`Sample::BACKGROUND`] for none).
    pub object: u32,
}

impl Sample {
    pub const BACKGROUND: u32 = u32::MAX;
}

/// How far around a rect the adaptive sampler traces probes (its smoothness test is asked
/// about the pixels within one less).
pub const PROBE_BORDER: usize = 2;

/// What the scene's geometry knows about one pixel's square, for the adaptive sampler:
/// the tracer's [`crate::footprint::Footprints`] answers from the solids' projections. The
/// sampler itself knows no geometry. Both answers must err one way only, or a pixel loses
/// detail: `is_smooth` may say no where yes is true, `may_hide` yes where no is true.
pub trait PixelGeometry {
    /// Whether pixel `(px, py)`, where the primary ray through its point `(x, y)` saw
    /// `seen`, is known to hold no edge, texture, reflection or shadow edge, so that its
    /// exact value differs from that one ray's only by smooth shading. Such a pixel may end
    /// after that ray.
    fn is_smooth(&self, px: i64, py: i64, x: f64, y: f64, seen: &Sample) -> bool;

    /// Whether a solid other than `object` ([`Sample::BACKGROUND`] for none) may show in
    /// pixel `(px, py)`'s square: a feature that every ray of a pixel's first pass saw
    /// `object` may have slipped between. Such a pixel is refined as if its own rays
    /// disagreed.
    fn may_hide(&self, px: i64, py: i64, object: u32) -> bool;

    /// What an edge of `object`'s own pattern (a checker's cell boundary) can hide in pixel
    /// `(px, py)`'s square on a side that none of the first pass's rays, through image
    /// positions `seen`, all of which saw `object`, fell on; `None` where there is no such
    /// side. Rays that agree there, or differ by smooth shading alone, bound nothing about
    /// the part of the square they all missed: the pixel is refined until a stratified set
    /// of its rays bounds it ([`UnseenPattern::error_bound`]). May overstate, never
    /// understate.
    fn unseen_pattern(
        &self,
        px: i64,
        py: i64,
        object: u32,
        seen: &[(f64, f64)],
    ) -> Option<UnseenPattern>;

    /// Whether pixel `(px, py)`, where the primary ray through `(x, y)` saw `object`, is
    /// known to hold nothing that changes but smooth shading and its object's pattern:
    /// a step between it and a neighbour that neither saw is then a pattern edge, and
    /// [`PixelGeometry::unseen_pattern`] bounds what this pixel can hide. May say no where
    /// yes is true, never the reverse.
    fn pattern_alone(&self, px: i64, py: i64, x: f64, y: f64, object: u32) -> bool;
}

/// A pattern's edges in a pixel's square that its first rays may have missed (see
/// [`PixelGeometry::unseen_pattern`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct UnseenPattern {
    /// The largest step in colour across an edge, in any channel.
    pub step: f64,
    /// How many straight edges may cross the square; `None`: unknown (any number).
    pub edges: Option<u32>,
}

impl UnseenPattern {
    /// The largest error the pattern's edges can leave in the mean of an `m × m` stratified
    /// set of rays over the square (one ray in each cell of the grid, anywhere in it): a
    /// straight edge passes through at most `2m − 1` cells, each ray on the wrong side of
    /// one errs by at most the step over `m²` of the pixel, and a cell no edge crosses shows
    /// one colour to its ray. Where the edges are unknown, the step itself.
    pub fn error_bound(&self, m: u32) -> f64 {
        let Some(edges) = self.edges else {
            return self.step;
        };
        let m = f64::from(m);
        self.step * (f64::from(edges) * (2.0 * m - 1.0) / (m * m)).min(1.0)
    }
}

/// The geometry of renders without a footprint: nothing is known smooth, nothing hidden.
struct NoGeometry;

impl PixelGeometry for NoGeometry {
    fn is_smooth(&self, _: i64, _: i64, _: f64, _: f64, _: &Sample) -> bool {
        false
    }

    fn may_hide(&self, _: i64, _: i64, _: u32) -> bool {
        false
    }

    fn unseen_pattern(&self, _: i64, _: i64, _: u32, _: &[(f64, f64)]) -> Option<UnseenPattern> {
        None
    }

    fn pattern_alone(&self, _: i64, _: i64, _: f64, _: f64, _: u32) -> bool {
        false
    }
}

const SEED_JITTER: u64 = 0x9e37_79b9_7f4a_7c15;
const SEED_FIRST: u64 = 0xc2b2_ae3d_27d4_eb4f;
const SEED_REFERENCE: u64 = 0x27d4_eb2f_1656_67c5;

/// A high-rate stratified estimate of one pixel's exact value (`n × n` jittered samples with a
/// seed of its own, so it is statistically independent of every user-facing sampler). This
/// is the yardstick the samplers are measured against (see `tessera-bench`).
pub fn reference_pixel<F: Fn(f64, f64) -> Sample>(x: u32, y: u32, n: u32, trace: &F) -> Color {
    stratified(x, y, n, Some(SEED_REFERENCE), trace)
}

/// `n × n` samples, one per cell of a regular grid: at the cell centre (`seed = None`) or at
/// a hashed position inside the cell.
fn stratified<F: Fn(f64, f64) -> Sample>(
    x: u32,
    y: u32,
    n: u32,
    seed: Option<u64>,
    trace: &F,
) -> Color {
    let mut sum = Color::ZERO;
    let inv = 1.0 / f64::from(n);
    let hash = seed.map(|s| PixelHash::new(x, y, s));
    for j in 0..n {
        for i in 0..n {
            let (ox, oy) = match hash {
                None => (0.5, 0.5),
                Some(h) => h.pair(j * n + i),
            };
            let sx = f64::from(x) + (f64::from(i) + ox) * inv;
            let sy = f64::from(y) + (f64::from(j) + oy) * inv;
            sum += trace(sx, sy).color;
        }
    }
    sum / f64::from(n * n)
}

/// Two numbers in `[0, 1)` from the pixel, the sample index and a seed.
#[inline]
pub fn unit_pair(x: u32, y: u32, index: u32, seed: u64) -> (f64, f64) {
    PixelHash::new(x, y, seed).pair(index)
}

/// [`unit_pair`] for one pixel and seed, with the pixel's part of the hash mixed once rather
/// than once per sample (the values are the same).
#[derive(Clone, Copy)]
struct PixelHash(u64);

impl PixelHash {
    #[inline]
    fn new(x: u32, y: u32, seed: u64) -> PixelHash {
        PixelHash(mix(seed ^ (u64::from(x) << 32 | u64::from(y))))
    }

    #[inline]
    fn pair(self, index: u32) -> (f64, f64) {
        let h = mix(self.0 ^ u64::from(index));
        let a = (h >> 11) as f64 * (1.0 / (1u64 << 53) as f64);
        let h2 = mix(h);
        let b = (h2 >> 11) as f64 * (1.0 / (1u64 << 53) as f64);
        (a, b)
    }
}

/// SplitMix64's finaliser: a bijective 64-bit mix with full avalanche.
#[inline]
fn mix(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// The samples an adaptive pixel has taken so far: their sum, sum of squares, range and
/// whether they met more than one object.
#[derive(Clone, Copy)]
struct Tally {
    sum: Color,
    sum_sq: Color,
    min: Color,
    max: Color,
    count: u32,
    object: u32,
    mixed: bool,
}

impl Tally {
    fn new() -> Tally {
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

    fn add(&mut self, s: Sample) {
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
    fn of(s: Sample) -> Tally {
        let mut t = Tally::new();
        t.add(s);
        t
    }

    fn mean(&self) -> Color {
        self.sum / f64::from(self.count)
    }

    /// Whether a step between these samples' pixel and `other`'s went unseen by both: in
    /// some channel the two means differ by more than `threshold`, and the two ranges of
    /// samples stay apart by more than `threshold` and by more than [`UNSEEN_GAP`] of that
    /// difference. An unseen step leaves a gap as high as the step itself (each pixel's
    /// samples all on its own side); a smooth gradient leaves a third of the difference on
    /// average (each pixel's samples reach towards the other's), and is no step at all.
    fn unseen_step(&self, other: &Tally, threshold: f64) -> bool {
        let (a, b) = (self.mean(), other.mean());
        (0..3).any(|i| {
            let difference = (a[i] - b[i]).abs();
            let gap = (self.min[i] - other.max[i]).max(other.min[i] - self.max[i]);
            difference > threshold && gap > threshold && gap > UNSEEN_GAP * difference
        })
    }

    /// Whether the samples disagree: more than `threshold` apart in a channel, or on
    /// different objects.
    fn contrast(&self, threshold: f64) -> bool {
        self.mixed || (self.max - self.min).max_element() > threshold
    }

    /// The standard error of the mean, largest over the channels, as if the samples were
    /// independent (stratification makes the true error smaller, so this errs on the side
    /// of more samples).
    fn standard_error(&self) -> f64 {
        let n = f64::from(self.count);
        let var = (self.sum_sq - self.sum * self.sum / n) / (n - 1.0);
        (var.max_element().max(0.0) / n).sqrt()
    }
}

/// First-pass result of one pixel for the adaptive sampler: the tally of its four samples,
/// where they were taken, and, for even `n`, the cell offset each quadrant drew (see
/// [`QuadrantOrder`]).
#[derive(Clone, Copy)]
struct FirstPass {
    tally: Tally,
    positions: [(f64, f64); 4],
    offsets: [(u32, u32); 4],
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
struct QuadrantOrder {
    h: u32,
    cells: Vec<(u32, u32)>,
}

impl QuadrantOrder {
    fn new(h: u32) -> QuadrantOrder {
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
        QuadrantOrder { h, cells }
    }

    /// The cell of the `n × n` grid that quadrant `k` takes as its sample number `rank`,
    /// given the quadrant's offset `(a, b)` in `[0, h)²`.
    #[inline]
    fn cell(&self, k: u32, rank: u32, (a, b): (u32, u32)) -> u32 {
        let h = self.h;
        let (di, dj) = self.cells[rank as usize];
        // a + di < 2h, so one subtraction is the remainder.
        let wrap = |v: u32| if v >= h { v - h } else { v };
        let ci = (k & 1) * h + wrap(a + di);
        let cj = (k >> 1) * h + wrap(b + dj);
        cj * 2 * h + ci
    }
}

/// The sample of cell `cell` of pixel `(x, y)`'s `n × n` grid, at the cell's hashed position.
#[inline]
fn cell_sample<F: Fn(f64, f64) -> Sample>(
    x: i64,
    y: i64,
    hash: PixelHash,
    n: u32,
    inv: f64,
    cell: u32,
    trace: &F,
) -> Sample {
    let (ox, oy) = hash.pair(cell);
    let (ci, cj) = (cell % n, cell / n);
    trace(
        x as f64 + (f64::from(ci) + ox) * inv,
        y as f64 + (f64::from(cj) + oy) * inv,
    )
}

/// Where pixel `(x, y)`'s first-pass sample in quadrant `k` lies and, for even `n`, the
/// quadrant's offset (see [`QuadrantOrder`]).
///
/// For even `n` it is rank 0 of the quadrant, so every later stage reuses it. For odd `n`
/// the quadrants do not align with the grid, and the first pass is an independent 2 × 2
/// jittered set.
fn first_position(
    x: i64,
    y: i64,
    n: u32,
    order: Option<&QuadrantOrder>,
    k: u32,
    hashes: &FirstHashes,
) -> ((f64, f64), (u32, u32)) {
    let FirstHashes { first, cells } = *hashes;
    let Some(order) = order else {
        let (ox, oy) = first.pair(k);
        let (qx, qy) = (f64::from(k % 2), f64::from(k / 2));
        return (
            (x as f64 + (qx + ox) * 0.5, y as f64 + (qy + oy) * 0.5),
            (0, 0),
        );
    };
    let h = order.h;
    // Each half of one 64-bit hash picks a coordinate: ⌊u · h / 2³²⌋ for u uniform on 32
    // bits takes each value in [0, h) with probability within 2⁻³² of 1/h.
    let r = mix(first.0 ^ u64::from(k));
    let a = (((r >> 32) * u64::from(h)) >> 32) as u32;
    let b = (((r & 0xffff_ffff) * u64::from(h)) >> 32) as u32;
    let cell = order.cell(k, 0, (a, b));
    // The cells' positions are jitter's: a pixel refined to the full grid takes exactly the
    // rays of `jitter` with the same `n` (the same arithmetic as `cell_sample`).
    let (ox, oy) = cells.pair(cell);
    let (ci, cj) = (cell % n, cell / n);
    let inv = 1.0 / f64::from(n);
    (
        (
            x as f64 + (f64::from(ci) + ox) * inv,
            y as f64 + (f64::from(cj) + oy) * inv,
        ),
        (a, b),
    )
}

/// A pixel's hashes for its first pass: the quadrants' offsets and the cells' positions.
#[derive(Clone, Copy)]
struct FirstHashes {
    first: PixelHash,
    cells: PixelHash,
}

impl FirstHashes {
    fn new(x: i64, y: i64) -> FirstHashes {
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
/// first of them `probed` when the pixel's probe already traced it.
fn first_pass<F: Fn(f64, f64) -> Sample>(
    x: i64,
    y: i64,
    n: u32,
    order: Option<&QuadrantOrder>,
    trace: &F,
    probed: Option<Sample>,
) -> FirstPass {
    let mut fp = FirstPass {
        tally: Tally::new(),
        positions: [(0.0, 0.0); 4],
        offsets: [(0, 0); 4],
    };
    let hashes = FirstHashes::new(x, y);
    for k in 0..4u32 {
        let ((sx, sy), offset) = first_position(x, y, n, order, k, &hashes);
        fp.offsets[k as usize] = offset;
        fp.positions[k as usize] = (sx, sy);
        fp.tally.add(match probed {
            Some(s) if k == 0 => s,
            _ => trace(sx, sy),
        });
    }
    fp
}

/// The part of the difference between two neighbours' means that must lie between their
/// ranges of samples for a step between them to count as unseen ([`Ask::Unseen`]). A step
/// that neither saw leaves all of it (less the shading's spread); a linear gradient leaves
/// a third on average, more only where both pixels' first rays fell near their centres.
const UNSEEN_GAP: f64 = 0.75;

/// Why a pixel takes more samples than its first pass (see [`refine`]).
#[derive(Debug, Clone, Copy, PartialEq)]
enum Ask {
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
/// Odd `n`: `n × n` stratified samples besides the first pass, count-weighted with it.
#[allow(clippy::too_many_arguments)]
fn refine<F: Fn(f64, f64) -> Sample>(
    x: u32,
    y: u32,
    n: u32,
    threshold: f64,
    ask: Ask,
    fp: &FirstPass,
    order: Option<&QuadrantOrder>,
    trace: &F,
) -> Color {
    let Some(order) = order else {
        // Both sets are unbiased estimates of the pixel, so their count-weighted mean is too.
        let n2 = f64::from(n * n);
        let t = &fp.tally;
        return (t.sum + stratified(x, y, n, Some(SEED_JITTER), trace) * n2) / (4.0 + n2);
    };
    let h = order.h;
    let hash = PixelHash::new(x, y, SEED_JITTER);
    let inv = 1.0 / f64::from(n);
    let (xi, yi) = (i64::from(x), i64::from(y));
    let mut tally = fp.tally;
    // Takes ranks `from..upto` of every quadrant.
    let take = |tally: &mut Tally, from: u32, upto: u32| {
        for rank in from..upto {
            for k in 0..4 {
                let cell = order.cell(k, rank, fp.offsets[k as usize]);
                tally.add(cell_sample(xi, yi, hash, n, inv, cell, trace));
            }
        }
    };
    let all = h * h;
    let mut ranks = 1;
    if h >= 3 && ask == Ask::Neighbour {
        take(&mut tally, ranks, 2);
        ranks = 2;
        if !tally.contrast(threshold) {
            return tally.mean();
        }
    }
    if let Ask::Pattern(pattern) = ask {
        if h.is_power_of_two() {
            let (mut stage, mut m) = (4, 4);
            while stage < all {
                take(&mut tally, ranks, stage);
                ranks = stage;
                if pattern.error_bound(m) <= threshold
                    && tally.standard_error() <= se_bound(threshold, 4 * stage)
                {
                    return tally.mean();
                }
                (stage, m) = (stage * 4, m * 2);
            }
        }
    } else if h >= 3 && ask != Ask::Unseen {
        let mut stage = 4;
        while stage < all {
            take(&mut tally, ranks, stage);
            ranks = stage;
            if tally.standard_error() <= se_bound(threshold, 4 * stage) {
                return tally.mean();
            }
            if !h.is_power_of_two() {
                break;
            }
            stage *= 2;
        }
    }
    take(&mut tally, ranks, all);
    tally.mean()
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
fn se_bound(threshold: f64, rays: u32) -> f64 {
    threshold * (f64::from(rays) / 16.0).sqrt()
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
fn adaptive<F, G>(
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
    let mut ends = vec![false; pw * ph];
    let mut probes: Vec<Option<((f64, f64), Sample)>> = vec![None; pw * ph];
    if let Some(geometry) = geometry {
        let probe = |probes: &mut Vec<Option<((f64, f64), Sample)>>, bx: usize, by: usize| {
            let i = at(bx, by);
            if let Some(p) = probes[i] {
                return p;
            }
            let (x, y) = pixel(bx, by);
            let hashes = FirstHashes::new(x, y);
            let ((sx, sy), _) = first_position(x, y, max, order, 0, &hashes);
            let p = ((sx, sy), trace(sx, sy));
            probes[i] = Some(p);
            p
        };
        let decide = |probes: &mut Vec<Option<((f64, f64), Sample)>>, bx: usize, by: usize| {
            let ((sx, sy), p) = probe(probes, bx, by);
            let (x, y) = pixel(bx, by);
            let gentle = |q: &Sample| {
                q.object != p.object || (q.color - p.color).abs().max_element() <= threshold
            };
            // The neighbours already traced first, then the test, then the rest: each step
            // is only taken if the ones before allow the pixel to end.
            neighbours(bx, by)
                .into_iter()
                .all(|(nx, ny)| probes[at(nx, ny)].is_none_or(|(_, q)| gentle(&q)))
                && geometry.is_smooth(x, y, sx, sy, &p)
                && neighbours(bx, by)
                    .into_iter()
                    .all(|(nx, ny)| gentle(&probe(probes, nx, ny).1))
        };
        let mut decided = vec![false; pw * ph];
        for by in 2..h + 2 {
            for bx in 2..w + 2 {
                ends[at(bx, by)] = decide(&mut probes, bx, by);
                decided[at(bx, by)] = true;
            }
        }
        for by in 2..h + 2 {
            for bx in 2..w + 2 {
                if ends[at(bx, by)] {
                    continue;
                }
                for (nx, ny) in neighbours(bx, by) {
                    if !decided[at(nx, ny)] {
                        ends[at(nx, ny)] = decide(&mut probes, nx, ny);
                        decided[at(nx, ny)] = true;
                    }
                }
            }
        }
    }

    // First passes where the rect's decisions need them: its pixels that go on, and their
    // neighbours that go on (`slot` indexes `passes`, NONE where a pixel has none).
    const NONE: u32 = u32::MAX;
    let mut slot = vec![NONE; pw * ph];
    let mut passes: Vec<FirstPass> = Vec::new();
    for by in 2..h + 2 {
        for bx in 2..w + 2 {
            if ends[at(bx, by)] {
                continue;
            }
            for (qx, qy) in std::iter::once((bx, by)).chain(neighbours(bx, by)) {
                let i = at(qx, qy);
                if slot[i] == NONE && !ends[i] {
                    let (x, y) = pixel(qx, qy);
                    let probed = probes[i].map(|(_, p)| p);
                    // At most one pass per pixel of the grown rect, whose size is bounded
                    // by the image's (`Limits`) and far below u32::MAX.
                    slot[i] = passes.len() as u32;
                    passes.push(first_pass(x, y, max, order, trace, probed));
                }
            }
        }
    }
    // What a pixel's neighbours compare with: its first pass's tally (whether it met two
    // objects, its first object, its mean and the range of its samples); for a pixel that
    // ended, its probe's.
    let seen = |i: usize| -> Tally {
        match (slot[i], probes[i]) {
            (NONE, Some((_, p))) => Tally::of(p),
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
            out[i] = match (ends[here], probes[here], slot[here]) {
                (true, Some((_, p)), _) => p.color,
                // Unreachable: a pixel that does not end has its first pass.
                (_, _, NONE) => Color::ZERO,
                (_, _, k) => {
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
                    let own = c.contrast(threshold)
                        || geometry
                            .is_some_and(|g| g.may_hide(i64::from(x), i64::from(y), c.object));
                    let (mut near, mut unseen) = (false, false);
                    for (nx, ny) in neighbours(bx, by) {
                        let nb = seen(at(nx, ny));
                        let nb_mean = nb.mean();
                        let other_object = nb.object != c.object;
                        let other_mean = (nb_mean - mean).abs().max_element() > threshold;
                        near |= nb.mixed || other_object || other_mean;
                        unseen |= c.unseen_step(&nb, threshold);
                    }
                    // Where nothing but smooth shading and a checker's cells can change in
                    // the pixel, an unseen step beside it is a cell edge: the pattern's own
                    // bound below decides how far this pixel is searched, and an edge that
                    // lies in the neighbour costs this pixel nothing.
                    let (px, py) = (i64::from(x), i64::from(y));
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
                    // The first pass is itself a stratified set over the 2 × 2 quadrants:
                    // where that already bounds the edges' error, nothing changes.
                    let pattern = (!unseen && !c.mixed)
                        .then(|| geometry?.unseen_pattern(px, py, c.object, &fp.positions))
                        .flatten()
                        .filter(|p| p.error_bound(2) > threshold);
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
                        refine(x, y, max, threshold, ask, fp, order, trace)
                    } else {
                        mean
                    }
                }
            };
            i += 1;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn flat(color: f64) -> impl Fn(f64, f64) -> Sample {
        move |_, _| Sample {
            color: Color::splat(color),
            object: 0,
        }
    }

    /// A [`PixelGeometry`] from three closures: `smooth(px, py)`, `hides(px, py, object)` and
    /// `step(px, py, object, seen)`.
    struct Geo<S, H, C>(S, H, C);

    impl<S, H, C> PixelGeometry for Geo<S, H, C>
    where
        S: Fn(i64, i64) -> bool,
        H: Fn(i64, i64, u32) -> bool,
        C: Fn(i64, i64, u32, &[(f64, f64)]) -> Option<UnseenPattern>,
    {
        fn is_smooth(&self, px: i64, py: i64, _: f64, _: f64, _: &Sample) -> bool {
            (self.0)(px, py)
        }

        fn may_hide(&self, px: i64, py: i64, object: u32) -> bool {
            (self.1)(px, py, object)
        }

        fn unseen_pattern(
            &self,
            px: i64,
            py: i64,
            object: u32,
            seen: &[(f64, f64)],
        ) -> Option<UnseenPattern> {
            (self.2)(px, py, object, seen)
        }

        fn pattern_alone(&self, _: i64, _: i64, _: f64, _: f64, _: u32) -> bool {
            false
        }
    }

    /// No pattern edge known anywhere.
    fn no_crossing(_: i64, _: i64, _: u32, _: &[(f64, f64)]) -> Option<UnseenPattern> {
        None
    }

    /// A geometry that knows nothing hidden, and smooth pixels by `smooth`.
    fn smooth_where(smooth: impl Fn(i64, i64) -> bool) -> impl PixelGeometry {
        Geo(smooth, |_, _, _| false, no_crossing)
    }

    /// A vertical edge at x = 10.3: white to its left.
    fn edge(x: f64, _y: f64) -> Sample {
        let white = x < 10.3;
        Sample {
            color: Color::splat(if white { 1.0 } else { 0.0 }),
            object: u32::from(white),
        }
    }

    const ALL: [Sampler; 9] = [
        Sampler::Center,
        Sampler::Thesis,
        Sampler::Grid { n: 3 },
        Sampler::Jitter { n: 4 },
        Sampler::Adaptive {
            max: 4,
            threshold: 0.02,
        },
        Sampler::Adaptive {
            max: 6,
            threshold: 0.02,
        },
        Sampler::Adaptive {
            max: 8,
            threshold: 0.02,
        },
        Sampler::Adaptive {
            max: 3,
            threshold: 0.02,
        },
        Sampler::Jitter { n: 1 },
    ];

    #[test]
    fn overrides_keep_what_they_do_not_name() {
        let s = Sampler::Adaptive {
            max: 6,
            threshold: 0.1,
        };
        assert_eq!(
            s.with_overrides(None, Some(3), None, 32),
            Ok(Sampler::Adaptive {
                max: 3,
                threshold: 0.1
            })
        );
        assert_eq!(
            s.with_overrides(Some("jitter"), None, None, 32),
            Ok(Sampler::Jitter { n: 6 })
        );
        // Any case, as in a scene.
        assert_eq!(
            s.with_overrides(Some("JITTER"), None, None, 32),
            Ok(Sampler::Jitter { n: 6 })
        );
        assert_eq!(
            Sampler::Center.with_overrides(Some("grid"), None, None, 32),
            Ok(Sampler::Grid { n: 4 })
        );
        assert!(s.with_overrides(None, Some(33), None, 32).is_err());
        assert!(s.with_overrides(None, None, Some(f64::NAN), 32).is_err());
        assert!(s.with_overrides(Some("random"), None, None, 32).is_err());
        // A setting the resulting sampler does not use is refused, whichever side named the
        // sampler; a scene's own unused setting is not the user's doing and is dropped.
        let unused = |r: Result<Sampler, String>, what: &str| {
            let e = r.expect_err("an unused setting");
            assert!(e.starts_with(what), "{e}");
        };
        unused(
            Sampler::Center.with_overrides(None, Some(4), None, 32),
            "samples",
        );
        unused(
            s.with_overrides(Some("thesis"), Some(4), None, 32),
            "samples",
        );
        unused(
            Sampler::Jitter { n: 2 }.with_overrides(None, None, Some(0.1), 32),
            "threshold",
        );
        unused(
            s.with_overrides(Some("grid"), None, Some(0.1), 32),
            "threshold",
        );
        assert_eq!(
            s.with_overrides(Some("center"), None, None, 32),
            Ok(Sampler::Center)
        );
    }

    #[test]
    fn a_flat_image_is_flat_for_every_sampler() {
        for s in ALL {
            let rect = Rect::new(3, 4, 5, 6);
            let mut out = vec![Color::ZERO; rect.pixel_count()];
            s.render_rect(rect, flat(0.25), &mut out);
            assert!(
                out.iter()
                    .all(|c| (*c - Color::splat(0.25)).length() < 1e-15),
                "{s:?}"
            );
        }
    }

    #[test]
    fn an_edge_is_estimated_by_its_covered_fraction() {
        // Pixel 10 is 30 % white; the grid of 10 × 10 puts 3 columns of samples left of 10.3.
        let mut out = vec![Color::ZERO; 1];
        Sampler::Grid { n: 10 }.render_rect(Rect::new(10, 0, 1, 1), edge, &mut out);
        assert!((out[0].x - 0.3).abs() < 1e-12);
        Sampler::Jitter { n: 16 }.render_rect(Rect::new(10, 0, 1, 1), edge, &mut out);
        assert!((out[0].x - 0.3).abs() <= 1.0 / 16.0, "{}", out[0].x);
    }

    #[test]
    fn pixel_values_do_not_depend_on_the_tile() {
        for s in ALL {
            let whole = Rect::new(0, 0, 20, 5);
            let mut a = vec![Color::ZERO; whole.pixel_count()];
            s.render_rect(whole, edge, &mut a);
            for x in 0..20 {
                for y in 0..5 {
                    let mut one = vec![Color::ZERO; 1];
                    s.render_rect(Rect::new(x, y, 1, 1), edge, &mut one);
                    assert_eq!(one[0], a[(y * 20 + x) as usize], "{s:?} at ({x}, {y})");
                }
            }
        }
    }

    #[test]
    fn jittered_positions_stay_in_their_cells_and_vary() {
        let mut seen = Vec::new();
        for k in 0..64 {
            let (a, b) = unit_pair(7, 9, k, SEED_JITTER);
            assert!((0.0..1.0).contains(&a) && (0.0..1.0).contains(&b));
            seen.push(a);
        }
        let mean = seen.iter().sum::<f64>() / seen.len() as f64;
        assert!((mean - 0.5).abs() < 0.15, "mean {mean}");
        assert_ne!(
            unit_pair(7, 9, 0, SEED_JITTER),
            unit_pair(9, 7, 0, SEED_JITTER)
        );
    }

    #[test]
    fn adaptive_refines_at_edges_only() {
        use std::cell::RefCell;
        let per_pixel = RefCell::new(vec![0u32; 22]);
        let counting = |x: f64, y: f64| {
            per_pixel.borrow_mut()[(x.floor() + 1.0) as usize] += 1;
            edge(x, y)
        };
        let s = Sampler::Adaptive {
            max: 4,
            threshold: 0.02,
        };
        let mut out = vec![Color::ZERO; 20];
        s.render_rect(Rect::new(0, 0, 20, 1), counting, &mut out);
        // Each column inside the image holds three first passes (rows -1, 0, 1) of 4 samples;
        // the border columns -1 and 20 only row 0's (the border's corners are never looked
        // at). A refined pixel adds the 12 cells of its 4 × 4 grid that the first pass did
        // not take. Only pixels at the edge (x = 10.3) and next to it may refine, and the two
        // that the edge's first pass separates (9 is white, 10 is mixed or black) must.
        let counts = per_pixel.into_inner();
        for (i, &c) in counts.iter().enumerate() {
            let x = i as i64 - 1;
            if x == -1 || x == 20 {
                assert_eq!(c, 4, "border column {x}");
                continue;
            }
            let refined = c == 12 + 12;
            assert!(c == 12 || refined, "column {x}: {c} samples");
            assert!(!refined || (9..=11).contains(&x), "column {x} refined");
            if x == 9 || x == 10 {
                assert!(refined, "column {x} not refined");
            }
        }
        assert!((out[10].x - 0.3).abs() <= 0.25);
        assert_eq!(out[0].x, 1.0);
        assert_eq!(out[19].x, 0.0);
    }

    /// Renders `rect` with `s`, tracing `f`: the estimates and every ray traced, in order.
    fn traced(
        s: Sampler,
        rect: Rect,
        f: impl Fn(f64, f64) -> Sample,
    ) -> (Vec<Color>, Vec<(f64, f64)>) {
        let rays = std::cell::RefCell::new(Vec::new());
        let trace = |x: f64, y: f64| {
            rays.borrow_mut().push((x, y));
            f(x, y)
        };
        let mut out = vec![Color::ZERO; rect.pixel_count()];
        s.render_rect(rect, trace, &mut out);
        (out, rays.into_inner())
    }

    /// Rays traced inside pixel `(px, py)` (border first passes of other pixels excluded).
    fn rays_in(rays: &[(f64, f64)], px: u32, py: u32) -> Vec<(f64, f64)> {
        rays.iter()
            .copied()
            .filter(|(x, y)| x.floor() == f64::from(px) && y.floor() == f64::from(py))
            .collect()
    }

    #[test]
    fn a_fully_refined_pixel_is_the_stratified_set_with_every_ray_reused() {
        use std::cell::RefCell;
        // Fine, high-contrast texture and two objects: every stage asks for more.
        let busy = |x: f64, y: f64| {
            let v = (x * 13.7 + y * 5.3).fract();
            Sample {
                color: Color::splat(v),
                object: u32::from(v < 0.5),
            }
        };
        for n in [2, 4, 6, 8] {
            let rays = RefCell::new(Vec::new());
            let trace = |x: f64, y: f64| {
                rays.borrow_mut().push((x, y));
                busy(x, y)
            };
            let s = Sampler::Adaptive {
                max: n,
                threshold: 0.01,
            };
            let mut out = [Color::ZERO];
            s.render_rect(Rect::new(5, 7, 1, 1), trace, &mut out);
            let mine = rays_in(&rays.into_inner(), 5, 7);
            // Exactly one ray per cell of the n × n grid, at the cell's jittered position: no
            // ray traced twice, none wasted.
            assert_eq!(mine.len() as u32, n * n, "n = {n}");
            let inv = 1.0 / f64::from(n);
            let mut expected: Vec<(f64, f64)> = (0..n * n)
                .map(|cell| {
                    let (ox, oy) = unit_pair(5, 7, cell, SEED_JITTER);
                    (
                        5.0 + (f64::from(cell % n) + ox) * inv,
                        7.0 + (f64::from(cell / n) + oy) * inv,
                    )
                })
                .collect();
            let mut got = mine.clone();
            got.sort_by(|a, b| a.partial_cmp(b).expect("positions are finite"));
            expected.sort_by(|a, b| a.partial_cmp(b).expect("positions are finite"));
            assert_eq!(got, expected, "n = {n}");
            // The estimate is their plain mean.
            let mean =
                mine.iter().map(|&(x, y)| busy(x, y).color.x).sum::<f64>() / mine.len() as f64;
            assert!((out[0].x - mean).abs() < 1e-12, "n = {n}");
        }
    }

    #[test]
    fn a_pixel_only_a_neighbour_flags_takes_one_more_ray_per_quadrant_first() {
        // An edge through the middle of pixel 10: its first pass has two samples on each side,
        // so it is refined in full; 9 and 11 are flat but next to it; 8 and 12 are further.
        let half = |x: f64, _y: f64| {
            let white = x < 10.5;
            Sample {
                color: Color::splat(if white { 1.0 } else { 0.0 }),
                object: u32::from(white),
            }
        };
        let s = Sampler::Adaptive {
            max: 6,
            threshold: 0.02,
        };
        let (out, rays) = traced(s, Rect::new(0, 0, 20, 1), half);
        let count = |x: u32| rays_in(&rays, x, 0).len();
        assert_eq!(count(8), 4);
        assert_eq!(count(9), 8);
        assert_eq!(count(10), 36);
        assert_eq!(count(11), 8);
        assert_eq!(count(12), 4);
        // The 6 × 6 grid puts exactly 3 columns of cells left of x = 10.5.
        assert!((out[10].x - 0.5).abs() < 1e-12, "{}", out[10].x);
        assert_eq!((out[9].x, out[11].x), (1.0, 0.0));
    }

    /// An edge that neither pixel beside it saw: pixel 10 is white but for a black sliver
    /// along its right side that its four first rays miss, and pixel 11 is black. Each
    /// pixel's first pass agrees with itself, and only the neighbour's mean says a step
    /// lies between them, in one of the two: both take every ray of the 6 × 6 grid, and
    /// end with exactly `jitter`'s estimate. (They stopped at eight agreeing rays, which
    /// missed the sliver too: `adaptive` 8×8 to 32×32 rendered checker edges worse than
    /// `jitter` 4×4.)
    #[test]
    fn a_step_neither_neighbour_saw_is_searched_with_every_ray() {
        let edge = 10.96;
        let step = |x: f64, _y: f64| Sample {
            color: Color::splat(if x < edge { 1.0 } else { 0.0 }),
            object: 0,
        };
        let s = Sampler::Adaptive {
            max: 6,
            threshold: 0.02,
        };
        let (out, rays) = traced(s, Rect::new(0, 0, 20, 1), step);
        let first: Vec<_> = rays_in(&rays, 10, 0).into_iter().take(4).collect();
        assert!(
            first.iter().all(|&(x, _)| x < edge),
            "the test needs a sliver the first pass misses: {first:?}"
        );
        assert_eq!(rays_in(&rays, 10, 0).len(), 36);
        assert_eq!(rays_in(&rays, 11, 0).len(), 36);
        assert_eq!(rays_in(&rays, 9, 0).len(), 4, "no step beside it");
        let mut jitter = vec![Color::ZERO; 20];
        Sampler::Jitter { n: 6 }.render_rect(Rect::new(0, 0, 20, 1), step, &mut jitter);
        assert_eq!((out[10], out[11]), (jitter[10], jitter[11]));
    }

    /// A corner of a pattern cut off inside one pixel, missed by its first rays, under shading
    /// that varies across the pixel by more than the threshold: the pixel asks for itself,
    /// and sixteen rays whose spread is the shading's end it there, on their side of the
    /// edge. Only the geometry can say that the pixel holds edges its rays all fell on one
    /// side of. Where it does, the pixel goes on until a stratified stage of its rays bounds
    /// what the edges can hide (`UnseenPattern::error_bound`): at a strict threshold, every
    /// ray, estimating the corner as jitter's set does; at a loose one with one edge, 256 of
    /// a cap of 32's 1,024; with the edges unknown, every ray. A step the first pass already
    /// bounds changes nothing. The geometry is told where the first rays went.
    #[test]
    fn a_pattern_edge_the_first_rays_all_missed_is_searched_until_bounded() {
        // Black where x + y > 11.65 inside pixel (5, 5) only: a triangle of legs 0.35, area
        // 0.061, in the corner towards (6, 6), which the pixel's first 16 rays all miss.
        // Elsewhere one object, shaded 0.9 + 0.01 x.
        let corner = |x: f64, y: f64| {
            let black = x.floor() == 5.0 && y.floor() == 5.0 && x + y > 11.65;
            Sample {
                color: Color::splat(if black { 0.0 } else { 0.9 + 0.01 * x }),
                object: 0,
            }
        };
        let rect = Rect::new(2, 2, 8, 8);
        let asked = std::cell::RefCell::new(Vec::new());
        let render = |max: u32, threshold: f64, pattern: Option<UnseenPattern>| {
            let rays = std::cell::RefCell::new(Vec::new());
            let trace = |x: f64, y: f64| {
                rays.borrow_mut().push((x, y));
                corner(x, y)
            };
            let geometry = |px, py, object, seen: &[(f64, f64)]| {
                if (px, py, object) != (5, 5, 0) {
                    return None;
                }
                asked.borrow_mut().push(seen.to_vec());
                pattern
            };
            let mut out = vec![Color::ZERO; rect.pixel_count()];
            let s = Sampler::Adaptive { max, threshold };
            let geometry = Geo(|_, _| false, |_, _, _| false, geometry);
            s.render_rect_probed(rect, trace, &geometry, &mut out);
            (out, rays.into_inner())
        };
        let pattern = |step: f64, edges: Option<u32>| Some(UnseenPattern { step, edges });
        let at = |px: u32, py: u32| ((py - rect.y) * rect.width + (px - rect.x)) as usize;

        let (blind, rays) = render(8, 0.001, None);
        let first = rays_in(&rays, 5, 5)[..4].to_vec();
        assert!(
            first.iter().all(|&(x, y)| x + y <= 11.65),
            "the test needs a corner the first pass misses: {first:?}"
        );
        assert_eq!(
            asked.borrow().last(),
            Some(&first),
            "told where the first rays went"
        );
        assert_eq!(
            rays_in(&rays, 5, 5).len(),
            16,
            "stops early without the geometry"
        );
        assert!(blind[at(5, 5)].x > 0.9, "unseen: {:?}", blind[at(5, 5)]);

        // 0.0005 · 2 edges · 3/4 ≤ 0.001: the quadrants bound it.
        let (small, _) = render(8, 0.001, pattern(0.0005, Some(2)));
        assert_eq!(small, blind, "a step the first pass bounds changes nothing");

        let (seen, rays) = render(8, 0.001, pattern(0.5, Some(2)));
        assert_eq!(rays_in(&rays, 5, 5).len(), 64);
        let mut grid = vec![Color::ZERO; rect.pixel_count()];
        Sampler::Jitter { n: 8 }.render_rect(rect, corner, &mut grid);
        // The same rays as jitter's, summed in another order.
        let (a, b) = (seen[at(5, 5)], grid[at(5, 5)]);
        assert!((a - b).abs().max_element() < 1e-12, "{a:?} against {b:?}");
        assert!(a.x < blind[at(5, 5)].x - 0.02, "the corner is seen: {a:?}");
        for (i, (a, b)) in seen.iter().zip(&blind).enumerate() {
            if i != at(5, 5) {
                assert_eq!(a, b, "pixel {i} changed");
            }
        }

        // 0.5 · (2m − 1)/m² at m = 4, 8, 16: 0.22, 0.12, 0.06, first within 0.1 at 256 rays.
        let (_, rays) = render(32, 0.1, pattern(0.5, Some(1)));
        assert_eq!(rays_in(&rays, 5, 5).len(), 256);
        let (_, rays) = render(32, 0.1, pattern(0.5, None));
        assert_eq!(rays_in(&rays, 5, 5).len(), 1024);
        let (_, rays) = render(32, 0.1, None);
        assert_eq!(
            rays_in(&rays, 5, 5).len(),
            4,
            "nothing asks without the geometry"
        );
    }

    /// A smooth ramp is no unseen step: neighbours' means differ by several thresholds, but
    /// their first passes reach towards each other. Each pixel asks for itself (its four
    /// rays span more than the threshold) and stops at 16 rays, whose standard error on a
    /// ramp of slope `s` is about `s/√12/4`, under the threshold up to a slope of 13
    /// thresholds a pixel. (Taken for unseen steps, ramps steeper than about three
    /// thresholds a pixel took every ray: 53 to 62 a pixel at a cap of 8, 200 and more at 16.)
    #[test]
    fn a_smooth_ramp_is_not_an_unseen_step() {
        let threshold = 0.02;
        for max in [8, 16] {
            for slope in [3.0, 5.0, 10.0] {
                let ramp = |x: f64, _y: f64| Sample {
                    color: Color::splat(slope * threshold * x),
                    object: 0,
                };
                let s = Sampler::Adaptive { max, threshold };
                let (_, rays) = traced(s, Rect::new(2, 0, 30, 1), ramp);
                for x in 2..32 {
                    let n = rays_in(&rays, x, 0).len();
                    assert!(n <= 16, "cap {max}, slope {slope}: pixel {x} took {n} rays");
                }
            }
        }
    }

    #[test]
    fn sixteen_rays_are_enough_once_their_standard_error_is_below_the_threshold() {
        // Low-contrast fine texture (values within 0.45..0.55): its first pass disagrees by
        // more than either threshold, and the standard error of 16 samples of it cannot
        // exceed 0.05 · √(16/15) / 4 < 0.013.
        let texture = |x: f64, _y: f64| Sample {
            color: Color::splat(0.5 + 0.05 * (97.0 * x).sin()),
            object: 0,
        };
        let exact = 0.5 + 0.05 * ((97.0 * 5.0f64).cos() - (97.0 * 6.0f64).cos()) / 97.0;
        for (threshold, rays_expected) in [(0.02, 16), (0.0005, 64)] {
            let s = Sampler::Adaptive { max: 8, threshold };
            let (out, rays) = traced(s, Rect::new(5, 0, 1, 1), texture);
            assert_eq!(rays_in(&rays, 5, 0).len(), rays_expected);
            // Within three of those standard errors of the pixel's exact mean.
            assert!((out[0].x - exact).abs() < 0.04, "{} vs {exact}", out[0].x);
        }
    }

    #[test]
    fn a_fully_refined_pixel_equals_jitter_with_the_same_count() {
        // Jitter is the second method: it places one ray per cell of its n × n grid, and an
        // adaptive pixel refined to its cap must take those very rays, whatever their order.
        let busy = |x: f64, y: f64| {
            let v = (x * 13.7 + y * 5.3).fract();
            Sample {
                color: Color::new(v, 1.0 - v, v * v),
                object: u32::from(v < 0.5),
            }
        };
        for n in [2, 3, 4, 6, 8, 16] {
            let rect = Rect::new(3, 2, 4, 3);
            let mut jit = vec![Color::ZERO; rect.pixel_count()];
            Sampler::Jitter { n }.render_rect(rect, busy, &mut jit);
            let mut ada = vec![Color::ZERO; rect.pixel_count()];
            let s = Sampler::Adaptive {
                max: n,
                threshold: 1e-9,
            };
            s.render_rect(rect, busy, &mut ada);
            for (a, j) in ada.iter().zip(&jit) {
                if n % 2 == 0 {
                    // Only the order of the sum differs.
                    assert!((*a - *j).abs().max_element() < 1e-12, "n = {n}: {a} vs {j}");
                } else {
                    // Odd n adds its independent 2 × 2 first pass, weighted by count.
                    let n2 = f64::from(n * n);
                    assert!(
                        (*a - *j).abs().max_element() <= 4.0 / (4.0 + n2) + 1e-12,
                        "n = {n}"
                    );
                }
            }
        }
    }

    #[test]
    fn each_stage_of_the_quadrant_order_is_stratified() {
        // For h a power of two, the first 4^k ranks of a quadrant hold one cell in each block
        // of h/2^k cells a side, and the first 2·4^k one in each row and each column of
        // those blocks, whatever the offset: checked by counting, for every offset.
        for h in [2u32, 4, 8, 16] {
            let order = QuadrantOrder::new(h);
            let mut sorted = order.cells.clone();
            sorted.sort_unstable();
            sorted.dedup();
            assert_eq!(sorted.len() as u32, h * h, "h = {h}: every cell once");
            for (a, b) in [(0, 0), (1, h - 1), (h / 2, 1), (h - 1, h - 1)] {
                let mut blocks = 1;
                while blocks <= h {
                    let size = h / blocks;
                    let cell_of = |rank: u32| {
                        let c = order.cell(0, rank, (a, b));
                        (c % (2 * h), c / (2 * h))
                    };
                    let mut per_block = vec![0; (blocks * blocks) as usize];
                    for rank in 0..blocks * blocks {
                        let (ci, cj) = cell_of(rank);
                        per_block[((cj / size) * blocks + ci / size) as usize] += 1;
                    }
                    assert!(per_block.iter().all(|&c| c == 1), "h = {h}, {blocks}²");
                    if blocks < h {
                        let m = 2 * blocks * blocks;
                        let (mut cols, mut rows) =
                            (vec![0; 2 * blocks as usize], vec![0; 2 * blocks as usize]);
                        for rank in 0..m {
                            let (ci, cj) = cell_of(rank);
                            cols[(2 * ci / size) as usize] += 1;
                            rows[(2 * cj / size) as usize] += 1;
                        }
                        let each = (m / (2 * blocks)) as i32;
                        assert!(cols.iter().chain(&rows).all(|&c| c == each), "h = {h}, {m}");
                    }
                    blocks *= 2;
                }
            }
        }
    }

    #[test]
    fn a_stage_may_end_a_pixel_once_its_standard_error_is_below_the_growing_bound() {
        use std::cell::RefCell;
        // The texture of the test above: per-sample spread about 0.05/√2 ≈ 0.035, so 16 rays
        // have a standard error near 0.0088 and 32 rays near 0.0063. With threshold 0.0064,
        // 16 rays are not enough (their bound is 0.0064) but 32 are (bound 0.0064·√2 ≈
        // 0.0091): the measured spread would have to be off by 27 % or more to change the
        // count.
        let texture = |x: f64, _y: f64| Sample {
            color: Color::splat(0.5 + 0.05 * (97.0 * x).sin()),
            object: 0,
        };
        let exact = 0.5 + 0.05 * ((97.0 * 5.0f64).cos() - (97.0 * 6.0f64).cos()) / 97.0;
        let rays = RefCell::new(Vec::new());
        let trace = |x: f64, y: f64| {
            rays.borrow_mut().push((x, y));
            texture(x, y)
        };
        let s = Sampler::Adaptive {
            max: 8,
            threshold: 0.0064,
        };
        let mut out = [Color::ZERO];
        s.render_rect(Rect::new(5, 0, 1, 1), trace, &mut out);
        assert_eq!(rays_in(&rays.into_inner(), 5, 0).len(), 32);
        // Within three standard errors of 32 rays of the pixel's exact mean.
        assert!((out[0].x - exact).abs() < 0.02, "{} vs {exact}", out[0].x);
        assert_eq!(se_bound(0.01, 16), 0.01);
        assert!((se_bound(0.01, 64) - 0.02).abs() < 1e-15);
    }

    /// A smoothness test that never vouches for a pixel leaves the adaptive sampler as it is
    /// without one: the same rays (each probe is the first pass's first ray) and values.
    #[test]
    fn a_test_that_finds_nothing_smooth_changes_nothing() {
        use std::cell::Cell;
        for max in [3, 4, 8] {
            let s = Sampler::Adaptive {
                max,
                threshold: 0.02,
            };
            let rect = Rect::new(7, 3, 9, 5);
            let plain_rays = Cell::new(0);
            let mut plain = vec![Color::ZERO; rect.pixel_count()];
            let trace = |x: f64, y: f64| {
                plain_rays.set(plain_rays.get() + 1);
                edge(x, y)
            };
            s.render_rect(rect, trace, &mut plain);
            let probed_rays = Cell::new(0);
            let mut probed = vec![Color::ZERO; rect.pixel_count()];
            let trace = |x: f64, y: f64| {
                probed_rays.set(probed_rays.get() + 1);
                edge(x, y)
            };
            s.render_rect_probed(rect, trace, &smooth_where(|_, _| false), &mut probed);
            assert_eq!(probed, plain, "max {max}");
            // Not one ray more: a probe is traced only where its first pass would be, and is
            // its first ray; the second border ring is probed only around smooth pixels.
            assert_eq!(probed_rays.get(), plain_rays.get(), "max {max}");
        }
    }

    /// Pixels the test vouches for end after their probe, with the probe's value; where a
    /// neighbour on the same object differs by more than the threshold (a steep gradient),
    /// they do not.
    #[test]
    fn smooth_pixels_end_after_one_ray_unless_the_shading_is_steep() {
        use std::cell::RefCell;
        let s = Sampler::Adaptive {
            max: 8,
            threshold: 0.05,
        };
        let rect = Rect::new(0, 0, 12, 1);
        // Columns 0–5 shade gently (0.01 per pixel), 6–11 steeply (0.1 per pixel).
        let ramp = |x: f64, _y: f64| {
            let v = if x < 6.0 {
                0.01 * x
            } else {
                0.06 + 0.1 * (x - 6.0)
            };
            Sample {
                color: Color::splat(v.min(1.0)),
                object: 0,
            }
        };
        let rays = RefCell::new(vec![0u32; 16]);
        let trace = |x: f64, y: f64| {
            rays.borrow_mut()[(x.floor() + 2.0) as usize] += 1;
            ramp(x, y)
        };
        let mut out = vec![Color::ZERO; 12];
        s.render_rect_probed(rect, trace, &smooth_where(|_, _| true), &mut out);
        let rays = rays.into_inner();
        for x in 0..12usize {
            // A pixel that ends took its probe and compared it with its neighbours' (rows −1
            // and 1): three rays in its column. One that goes on takes three more, and so do
            // the neighbours it compares its first pass with unless they end.
            let c = rays[x + 2];
            if x <= 4 {
                assert_eq!(c, 3, "column {x} should end after its probe");
                let order = QuadrantOrder::new(4);
                let hashes = FirstHashes::new(x as i64, 0);
                let ((sx, sy), _) = first_position(x as i64, 0, 8, Some(&order), 0, &hashes);
                assert_eq!(out[x], ramp(sx, sy).color);
            } else if x >= 7 {
                assert!(c > 3, "column {x} should go on: {c} rays");
            }
        }
    }

    /// With a geometry that vouches for some pixels, and says others may hide a solid, a
    /// pixel's value still does not depend on the tile it is rendered in.
    #[test]
    fn probed_pixels_do_not_depend_on_the_tile() {
        let geometry = Geo(
            |px: i64, py: i64| (px * 7 + py * 3) % 5 != 0,
            |px: i64, py: i64, _| (px * 5 + py) % 4 == 0,
            |px: i64, py: i64, _, _: &[(f64, f64)]| {
                ((px + 2 * py) % 3 == 0).then_some(UnseenPattern {
                    step: 1.0,
                    edges: Some(1 + (px % 2) as u32),
                })
            },
        );
        let disc = |x: f64, y: f64| {
            let inside = (x - 8.3).powi(2) + (y - 5.1).powi(2) < 9.0;
            Sample {
                color: Color::splat(if inside { 0.9 } else { 0.1 }),
                object: u32::from(inside),
            }
        };
        for s in [
            Sampler::Adaptive {
                max: 4,
                threshold: 0.02,
            },
            Sampler::Adaptive {
                max: 8,
                threshold: 0.05,
            },
            Sampler::Adaptive {
                max: 3,
                threshold: 0.02,
            },
        ] {
            let whole_rect = Rect::new(0, 0, 17, 11);
            let mut whole = vec![Color::ZERO; whole_rect.pixel_count()];
            s.render_rect_probed(whole_rect, disc, &geometry, &mut whole);
            for tile in [1u32, 2, 5] {
                for r in crate::tile::tiles(17, 11, tile) {
                    let mut part = vec![Color::ZERO; r.pixel_count()];
                    s.render_rect_probed(r, disc, &geometry, &mut part);
                    for (i, c) in part.iter().enumerate() {
                        let (x, y) = (r.x + i as u32 % r.width, r.y + i as u32 / r.width);
                        assert_eq!(*c, whole[(y * 17 + x) as usize], "{s:?} tile {tile}");
                    }
                }
            }
        }
    }

    /// Where the geometry says a solid may hide, a pixel whose first rays all agree is
    /// refined as if they had not: to jitter's rays for caps up to 4 (a cap of 3 adds its
    /// 3 × 3 to its first four), and to the 16 of its first complete stage above that; the
    /// pixel beside it, which the geometry does not flag, stops at its first four.
    #[test]
    fn a_pixel_that_may_hide_a_solid_is_refined_though_its_rays_agree() {
        use std::cell::RefCell;
        // A flat image: no contrast anywhere, so only the geometry can ask for more rays.
        for (max, flagged) in [(2, 4), (3, 13), (4, 16), (6, 16), (8, 16), (16, 16)] {
            let s = Sampler::Adaptive {
                max,
                threshold: 0.02,
            };
            let rays = RefCell::new(Vec::new());
            let trace = |x: f64, y: f64| {
                rays.borrow_mut().push((x, y));
                Sample {
                    color: Color::splat(0.5),
                    object: Sample::BACKGROUND,
                }
            };
            // Pixel (4, 2) may hide a solid other than the background; nothing is smooth.
            let hides =
                |px: i64, py: i64, object: u32| (px, py) == (4, 2) && object == Sample::BACKGROUND;
            let mut out = vec![Color::ZERO; 2];
            s.render_rect_probed(
                Rect::new(4, 2, 2, 1),
                trace,
                &Geo(|_, _| false, hides, no_crossing),
                &mut out,
            );
            let rays = rays.into_inner();
            assert_eq!(rays_in(&rays, 4, 2).len(), flagged, "max {max}");
            assert_eq!(rays_in(&rays, 5, 2).len(), 4, "max {max}");
            assert_eq!(out, vec![Color::splat(0.5); 2], "max {max}");
        }
    }

    /// A line a twentieth of a pixel wide, which four rays mostly miss: where the geometry
    /// flags the pixels it crosses, adaptive with cap 4 gives jitter 4 × 4's value in every
    /// one of them (the second method), however its first rays fell; without the geometry,
    /// some of those pixels stop at four rays that all missed it.
    #[test]
    fn flagged_thin_features_get_jitters_estimate() {
        // A diagonal line of width 0.05 px (measured across x), object 1, on a flat ground.
        let line = |x: f64, y: f64| {
            let on = (x - 0.37 * y - 2.0).abs() < 0.025;
            Sample {
                color: Color::splat(if on { 1.0 } else { 0.2 }),
                object: if on { 1 } else { Sample::BACKGROUND },
            }
        };
        // The pixels the line crosses (each row y covers x in 2 + 0.37·[y, y + 1] ± 0.025).
        let crosses = |px: i64, py: i64| {
            let (lo, hi) = (
                2.0 + 0.37 * py as f64 - 0.025,
                2.0 + 0.37 * (py + 1) as f64 + 0.025,
            );
            (px as f64) < hi && (px + 1) as f64 > lo
        };
        let rect = Rect::new(0, 0, 12, 24);
        let mut jit = vec![Color::ZERO; rect.pixel_count()];
        Sampler::Jitter { n: 4 }.render_rect(rect, line, &mut jit);
        let s = Sampler::Adaptive {
            max: 4,
            threshold: 0.02,
        };
        let geometry = Geo(
            |_, _| false,
            |px, py, object| crosses(px, py) && object != 1,
            no_crossing,
        );
        let mut flagged = vec![Color::ZERO; rect.pixel_count()];
        s.render_rect_probed(rect, line, &geometry, &mut flagged);
        let mut plain = vec![Color::ZERO; rect.pixel_count()];
        s.render_rect(rect, line, &mut plain);
        let mut missed = 0;
        for (i, ((f, p), j)) in flagged.iter().zip(&plain).zip(&jit).enumerate() {
            let (px, py) = ((i % 12) as i64, (i / 12) as i64);
            if crosses(px, py) {
                assert!((*f - *j).abs().max_element() < 1e-12, "pixel ({px}, {py})");
                missed += usize::from(*p == Color::splat(0.2) && *j != Color::splat(0.2));
            }
        }
        // The failure the geometry is there for: without it, some crossed pixels kept
        // none of the line that jitter found.
        assert!(missed > 0, "no pixel lost the line without the geometry");
    }
}
