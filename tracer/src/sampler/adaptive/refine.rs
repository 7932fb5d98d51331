//! How far a pixel that goes on is refined: the stages of an even cap, where each may stop,
//! and an odd cap's rest of its grid. Not whether a pixel goes on (the driver decides).

use crate::math::Color;

use super::{FirstPass, QuadrantOrder, Tally, cell_sample};
use crate::sampler::jitter::{PixelHash, SEED_JITTER};
use crate::sampler::{ALL_QUADRANTS, Coverage, Sample, UnseenPattern};

/// Why a pixel takes more samples than its first pass (see [`refine`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(in crate::sampler) enum Ask {
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
/// one backdrop's smooth shading may show ([`crate::sampler::PixelGeometry::fitted_quadrants`]);
/// a feature there is found by exactly the rays that find it with every quadrant refined.
#[allow(clippy::too_many_arguments)]
pub(in crate::sampler) fn refine<F: Fn(f64, f64) -> Sample>(
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

/// The estimate of a pixel that shows one solid's smooth shading against the background
/// (`cover`, see [`Coverage`]), from its first pass `fp` and as many more of its rays as it
/// needs: its rays that met the solid estimate the solid's shading, and [`Coverage::value`]
/// weighs that by the solid's exact share. The silhouette is then exact whatever rays are
/// taken; rays are taken, in the order [`refine`] takes them (for even `n`, rank by rank in
/// each quadrant named in `quadrants`; for odd `n`, the cells the first pass left), until
/// the solid's rays so far bound the shading's error:
/// - one ray met the solid and its share is at most [`ONE_RAY`] of `threshold` (no ray's
///   colour is more than 1 from another's in a channel, so the pixel errs by at most the
///   share);
/// - or two or more did, and their range times the share is at most [`RANGE`] of
///   `threshold`, or their standard error times the share at most [`SE`] of the stage's
///   bound ([`se_bound`]).
///
/// The solid's shading is smooth, but across a solid a few pixels wide it spans its whole
/// range within one pixel: hence bounds tighter than the threshold. For even `n` the stops
/// are tested after whole ranks, so that every quadrant searched has as many rays. An odd
/// cap's rest of its grid, taken in row order, would meet the solid's top first, so an odd
/// cap stops only after its first pass. A pixel none of whose rays meet the solid is the
/// background's.
#[allow(clippy::too_many_arguments)]
pub(in crate::sampler) fn covered<F: Fn(f64, f64) -> Sample>(
    (x, y): (u32, u32),
    n: u32,
    threshold: f64,
    fp: &FirstPass,
    order: Option<&QuadrantOrder>,
    quadrants: u8,
    cover: Coverage,
    trace: &F,
) -> Color {
    let mut inner = Tally::new();
    let mut rays = 4;
    let add = |inner: &mut Tally, s: Sample| {
        if s.object == cover.object {
            inner.add(s);
        }
    };
    for &s in &fp.samples {
        add(&mut inner, s);
    }
    let enough = |inner: &Tally, rays: u32| match inner.count {
        0 => false,
        1 => cover.share <= ONE_RAY * threshold,
        _ => {
            cover.share * (inner.max - inner.min).max_element() <= RANGE * threshold
                || cover.share * inner.standard_error() <= SE * se_bound(threshold, rays)
        }
    };
    let value = |inner: &Tally| {
        if inner.count == 0 {
            cover.backdrop
        } else {
            cover.value(inner.mean())
        }
    };
    if enough(&inner, rays) || cover.share == 0.0 {
        return value(&inner);
    }
    let hash = PixelHash::new(x, y, SEED_JITTER);
    let inv = 1.0 / f64::from(n);
    let (xi, yi) = (i64::from(x), i64::from(y));
    match order {
        Some(order) => {
            for rank in 1..order.h * order.h {
                for k in (0..4u32).filter(|k| quadrants & (1 << k) != 0) {
                    let cell = order.column_row(k, rank, fp.offsets[k as usize]);
                    add(&mut inner, cell_sample(xi, yi, hash, n, inv, cell, trace));
                    rays += 1;
                }
                if enough(&inner, rays) {
                    break;
                }
            }
        }
        None => {
            for cj in 0..n {
                for ci in 0..n {
                    if fp.offsets.contains(&(ci, cj)) {
                        continue;
                    }
                    add(
                        &mut inner,
                        cell_sample(xi, yi, hash, n, inv, (ci, cj), trace),
                    );
                }
            }
        }
    }
    value(&inner)
}

/// A covered pixel's one ray on its solid stands for the solid's shading where the
/// solid's share is at most this part of the threshold: the ray errs by at most 1 in a
/// channel, so the pixel by at most a quarter of the threshold.
const ONE_RAY: f64 = 0.25;
/// A covered pixel's rays on its solid stand for its shading where their range, weighed by
/// the share, is at most this part of the threshold...
const RANGE: f64 = 0.5;
/// ... or their standard error, weighed by the share, at most this part of the stage's
/// bound.
const SE: f64 = 0.5;

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
pub(in crate::sampler) fn se_bound(threshold: f64, rays: u32) -> f64 {
    threshold * (f64::from(rays) / 16.0).sqrt()
}
