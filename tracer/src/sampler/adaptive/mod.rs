//! The adaptive sampler: a probe ray or a four-ray first pass per pixel, compared with the
//! neighbours' to decide which pixels end early and which are refined, up to the sampler's
//! maximum, with the decision made the same way in every tile.

use crate::math::Color;
use crate::tile::Rect;

use super::{ALL_QUADRANTS, CellSums, PixelGeometry, Sample};

mod first;
mod refine;
mod tally;

pub(super) use first::{FirstHashes, QuadrantOrder, first_position};
use first::{FirstPass, cell_sample, first_pass};
#[cfg(test)]
pub(super) use refine::se_bound;
use refine::{Ask, covered, refine};
use tally::Tally;

/// A probe: the image position of a pixel's first ray, and its sample.
type Probe = ((f64, f64), Sample);

/// Traces the probe of pixel `(x, y)` (the first ray of its first pass, see
/// [`first_position`]) into `slot`, and returns it; where the geometry knows every ray of
/// the pixel to be blank ([`PixelGeometry::blank`]), takes its sample instead and sets
/// `blank`. Kept out of line: its callers mostly find the probe already traced, and should
/// not pay for this body's registers.
#[inline(never)]
fn trace_probe<F: Fn(f64, f64) -> Sample, G: PixelGeometry>(
    (x, y): (i64, i64),
    max: u32,
    order: Option<&QuadrantOrder>,
    trace: &F,
    geometry: &G,
    (slot, blank): (&mut Option<Probe>, &mut bool),
) -> Probe {
    let hashes = FirstHashes::new(x, y);
    let ((sx, sy), _) = first_position(x, y, max, order, 0, &hashes);
    let sample = match geometry.blank(x, y) {
        Some(s) => {
            *blank = true;
            s
        }
        None => trace(sx, sy),
    };
    let p = ((sx, sy), sample);
    *slot = Some(p);
    p
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
/// rect ([`super::PROBE_BORDER`]). Every pixel's rays are thus what they would be in any other
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
///
/// The per-pixel arrays are kept small (a state byte, indices into `cells` and `passes`)
/// so that a tile's arrays fit in a core's caches: the few pixels that have cells' sums or a
/// first pass keep them in the dense arrays.
#[derive(Default)]
struct Scratch {
    state: Vec<u8>,
    probes: Vec<Option<Probe>>,
    /// Whether the pixel's probe found it blank: its every ray is the probe's sample.
    blank: Vec<bool>,
    cell_slot: Vec<u32>,
    cells: Vec<CellSums>,
    slot: Vec<u32>,
    passes: Vec<FirstPass>,
}

/// A pixel's `Scratch::state`: not yet decided (or, without a geometry, never decided:
/// every pixel then goes on).
const UNDECIDED: u8 = 0;
/// Decided: the pixel takes its first pass.
const GOES_ON: u8 = 1;
/// Decided: the pixel ends with its probe's colour.
const ENDS_PROBE: u8 = 2;
/// Decided: the pixel ends with its cells' exact sum.
const ENDS_EXACT: u8 = 3;
/// Decided: the pixel ends with its probe's colour weighed by its solid's exact share of
/// the square, the background's for the rest ([`PixelGeometry::coverage`]).
const ENDS_COVERED: u8 = 4;
/// Not a state: [`ENDS_COVERED`] once a neighbour's probe is found on the same solid.
const ENDS_COVERING: u8 = 5;

/// No entry in `Scratch::cells` or `Scratch::passes`.
const NONE: u32 = u32::MAX;

impl Scratch {
    /// The memory the arrays hold.
    fn bytes(&self) -> usize {
        use std::mem::size_of;
        self.state.capacity()
            + self.blank.capacity()
            + self.probes.capacity() * size_of::<Option<Probe>>()
            + self.cell_slot.capacity() * size_of::<u32>()
            + self.cells.capacity() * size_of::<CellSums>()
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
        state,
        probes,
        blank,
        cell_slot,
        cells,
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
    refill(state, pw * ph, UNDECIDED);
    refill(probes, pw * ph, None);
    refill(blank, pw * ph, false);
    // What a checkered plane's cells give each decided pixel (see `PixelGeometry::cells`):
    // its index in `cells`, NONE where it has none.
    refill(cell_slot, pw * ph, NONE);
    cells.clear();
    if let Some(geometry) = geometry {
        // The probe of the pixel at `i`, traced if it is not yet. The check is inlined at
        // every call and the tracing is not: most calls find the probe traced.
        let probe =
            |probes: &mut Vec<Option<Probe>>, blank: &mut Vec<bool>, bx: usize, by: usize| {
                let i = at(bx, by);
                match probes[i] {
                    Some(p) => p,
                    None => {
                        let into = (&mut probes[i], &mut blank[i]);
                        trace_probe(pixel(bx, by), max, order, trace, geometry, into)
                    }
                }
            };
        let decide = |probes: &mut Vec<Option<Probe>>,
                      blank: &mut Vec<bool>,
                      cell_slot: &mut Vec<u32>,
                      cells: &mut Vec<CellSums>,
                      bx: usize,
                      by: usize| {
            let ((sx, sy), p) = probe(probes, blank, bx, by);
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
            // Smooth, or one plain solid's silhouette against the background whose probe
            // met the solid (or whose square holds none of it): the solid's share of the
            // square is exact, and the probe stands for its shading where a neighbour's
            // probe on the solid agrees with it (the shading is smooth at the pixel's
            // scale: not a solid a few pixels across, whose shading spans its whole range
            // within one).
            let ends = if !gentle_so_far {
                None
            } else if geometry.is_smooth(x, y, sx, sy, &p) {
                Some(ENDS_PROBE)
            } else {
                match geometry.coverage(x, y) {
                    Some(c) if c.share == 0.0 => Some(ENDS_COVERED),
                    Some(c) if c.object == p.object => Some(ENDS_COVERING),
                    _ => None,
                }
            };
            if let Some(state) = ends
                && around
                    .iter()
                    .zip(traced)
                    .all(|(&(nx, ny), done)| done || gentle(&probe(probes, blank, nx, ny).1))
            {
                if state != ENDS_COVERING {
                    return state;
                }
                // Every neighbour's probe is traced by now.
                let beside = |&(nx, ny): &(usize, usize)| {
                    probes[at(nx, ny)].is_some_and(|(_, q)| q.object == p.object)
                };
                if around.iter().any(beside) {
                    return ENDS_COVERED;
                }
            }
            // A checkered plane alone in the square: its cells' exact areas, where they are
            // few enough to cost less than the rays they replace; the pixel's value where
            // nothing else changes in it, and otherwise the control variate its rays are
            // corrected by (see `corrected`).
            let Some(sums) = geometry.cells(x, y, (sx, sy), &p, threshold, exact_cells(max)) else {
                return GOES_ON;
            };
            // At most one entry per pixel of the grown rect (see `slot` below).
            cell_slot[at(bx, by)] = cells.len() as u32;
            cells.push(sums);
            if sums.exact.is_some() {
                ENDS_EXACT
            } else {
                GOES_ON
            }
        };
        for by in 2..h + 2 {
            for bx in 2..w + 2 {
                state[at(bx, by)] = decide(probes, blank, cell_slot, cells, bx, by);
            }
        }
        for by in 2..h + 2 {
            for bx in 2..w + 2 {
                if state[at(bx, by)] >= ENDS_PROBE {
                    continue;
                }
                for (nx, ny) in neighbours(bx, by) {
                    if state[at(nx, ny)] == UNDECIDED {
                        state[at(nx, ny)] = decide(probes, blank, cell_slot, cells, nx, ny);
                    }
                }
            }
        }
    }
    let (state, probes, blank, cells) = (&*state, &*probes, &*blank, &*cells);
    // The pixel's cells' sums, where it has them.
    let sums = |i: usize| (cell_slot[i] != NONE).then(|| cells[cell_slot[i] as usize]);
    // The value of pixel `(px, py)` at `i` where it ends, `None` where it goes on.
    let ends = |i: usize, px: i64, py: i64| match state[i] {
        ENDS_PROBE => probes[i].map(|(_, p)| p.color),
        ENDS_EXACT => sums(i).and_then(|c| c.exact),
        ENDS_COVERED => {
            let c = geometry?.coverage(px, py)?;
            probes[i].map(|(_, p)| c.value(p.color))
        }
        _ => None,
    };

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
    // Pixel `i`'s rays, corrected: traced, or its probe's sample where the probe found the
    // pixel blank.
    let corrected = |i: usize| {
        let (cells, known) = (sums(i), probes[i].filter(|_| blank[i]));
        move |sx: f64, sy: f64| {
            let s = match known {
                Some((_, s)) => s,
                None => trace(sx, sy),
            };
            correct(cells, s, (sx, sy))
        }
    };

    // First passes where the rect's decisions need them: its pixels that go on, and their
    // neighbours that go on (`slot` indexes `passes`, NONE where a pixel has none).
    refill(slot, pw * ph, NONE);
    passes.clear();
    for by in 2..h + 2 {
        for bx in 2..w + 2 {
            if state[at(bx, by)] >= ENDS_PROBE {
                continue;
            }
            for (qx, qy) in std::iter::once((bx, by)).chain(neighbours(bx, by)) {
                let i = at(qx, qy);
                if slot[i] == NONE && state[i] < ENDS_PROBE {
                    let (x, y) = pixel(qx, qy);
                    let probed = probes[i].map(|(at, p)| (at, correct(sums(i), p, at)));
                    // At most one pass per pixel of the grown rect, whose size is bounded
                    // by the image's (`Limits`) and far below u32::MAX.
                    slot[i] = passes.len() as u32;
                    passes.push(first_pass(x, y, max, order, &corrected(i), probed));
                }
            }
        }
    }
    // What a pixel's neighbours compare with: its first pass's tally (whether it met two
    // objects, its first object, its mean and the range of its samples); for a pixel that
    // ended, its probe's (corrected, where the pixel has cells' sums).
    let seen = |i: usize| -> Tally {
        match (slot[i], probes[i]) {
            (NONE, Some((at, p))) => Tally::of(correct(sums(i), p, at)),
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
            let (px, py) = (i64::from(x), i64::from(y));
            out[i] = match (ends(here, px, py), slot[here]) {
                (Some(value), _) => value,
                // Unreachable: a pixel that does not end has its first pass.
                (_, NONE) => Color::ZERO,
                (_, k) => {
                    let fp = &passes[k as usize];
                    if let Some(g) = geometry
                        && let Some(cover) = g.coverage(px, py)
                    {
                        // A plain solid's silhouette against the background: its rays are
                        // weighed by its exact share, and the pixel takes rays only until
                        // they estimate the solid's shading. A quarter the solid cannot
                        // show in holds the background alone, and takes no more rays.
                        let quadrants = order.and_then(|_| g.fitted_quadrants(px, py));
                        out[i] = covered(
                            (x, y),
                            max,
                            threshold,
                            fp,
                            order,
                            quadrants.unwrap_or(ALL_QUADRANTS),
                            cover,
                            &corrected(here),
                        );
                        i += 1;
                        continue;
                    }
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
                    let flagged =
                        !c.mixed && geometry.is_some_and(|g| g.may_hide(px, py, c.object));
                    // Two pixels on one checkered plane whose rays are corrected by its cells
                    // (`corrected`) compare what is left: shadows and reflections. Their
                    // cells differ, and the cells are summed exactly in both.
                    let mine = sums(here);
                    let (mut near, mut unseen, mut beside_other) = (false, false, false);
                    for (nx, ny) in neighbours(bx, by) {
                        let there = at(nx, ny);
                        let (mut c, mut nb) = (*c, seen(there));
                        if let (Some(a), Some(b)) = (mine, sums(there))
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
                            &corrected(here),
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
