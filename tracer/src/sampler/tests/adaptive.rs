//! The adaptive sampler's tests: where it refines, where it stops, which rays it takes, and
//! that its pixels do not depend on the tile.

use super::*;

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
fn traced(s: Sampler, rect: Rect, f: impl Fn(f64, f64) -> Sample) -> (Vec<Color>, Vec<(f64, f64)>) {
    let rays = std::cell::RefCell::new(Vec::new());
    let trace = |x: f64, y: f64| {
        rays.borrow_mut().push((x, y));
        f(x, y)
    };
    let mut out = vec![Color::ZERO; rect.pixel_count()];
    s.render_rect(rect, trace, &mut out);
    (out, rays.into_inner())
}

/// [`traced`], with `geometry`.
fn traced_probed(
    s: Sampler,
    rect: Rect,
    f: impl Fn(f64, f64) -> Sample,
    geometry: &impl PixelGeometry,
) -> (Vec<Color>, Vec<(f64, f64)>) {
    let rays = std::cell::RefCell::new(Vec::new());
    let trace = |x: f64, y: f64| {
        rays.borrow_mut().push((x, y));
        f(x, y)
    };
    let mut out = vec![Color::ZERO; rect.pixel_count()];
    s.render_rect_probed(rect, trace, geometry, &mut out);
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
        let mean = mine.iter().map(|&(x, y)| busy(x, y).color.x).sum::<f64>() / mine.len() as f64;
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
    for n in [1, 2, 3, 4, 5, 6, 8, 9, 16] {
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
                // Odd n sums its cells in jitter's order.
                assert_eq!(a, j, "n = {n}");
            }
        }
    }
}

/// An odd cap's first pass takes four distinct cells of its `n × n` grid, each at its own
/// jittered position, drawn as a uniformly random set of four: over many pixels every cell
/// is among them with chance 4/n² (so their mean is unbiased) and every pair of cells with
/// chance 4·3/(n²(n² − 1)), as sampling without replacement gives.
#[test]
fn an_odd_cap_s_first_pass_is_four_cells_drawn_without_replacement() {
    for n in [3u32, 5, 7] {
        let cells = (n * n) as usize;
        let mut once = vec![0u32; cells];
        let mut pairs = vec![0u32; cells * cells];
        let pixels = 40_000;
        for p in 0..pixels {
            let (x, y) = (i64::from(p % 200), i64::from(p / 200));
            let hashes = FirstHashes::new(x, y);
            let mut taken = Vec::new();
            for k in 0..4 {
                let ((sx, sy), (ci, cj)) = first_position(x, y, n, None, k, &hashes);
                // The position lies in the cell named, where jitter puts that cell's ray.
                let (ox, oy) = unit_pair(x as u32, y as u32, cj * n + ci, SEED_JITTER);
                let inv = 1.0 / f64::from(n);
                assert_eq!(sx, x as f64 + (f64::from(ci) + ox) * inv, "n = {n}");
                assert_eq!(sy, y as f64 + (f64::from(cj) + oy) * inv, "n = {n}");
                taken.push((cj * n + ci) as usize);
            }
            let mut distinct = taken.clone();
            distinct.sort_unstable();
            distinct.dedup();
            assert_eq!(distinct.len(), 4, "n = {n}: {taken:?}");
            for &a in &taken {
                once[a] += 1;
                for &b in &taken {
                    if a < b {
                        pairs[a * cells + b] += 1;
                    }
                }
            }
        }
        // Binomial counts within five of their standard deviations.
        let within = |count: u32, p: f64, what: &str| {
            let (mean, sd) = (pixels as f64 * p, (pixels as f64 * p * (1.0 - p)).sqrt());
            assert!(
                (f64::from(count) - mean).abs() < 5.0 * sd,
                "n = {n}, {what}: {count} vs {mean}"
            );
        };
        let m = cells as f64;
        for (a, &c) in once.iter().enumerate() {
            within(c, 4.0 / m, &format!("cell {a}"));
            for b in a + 1..cells {
                within(
                    pairs[a * cells + b],
                    12.0 / (m * (m - 1.0)),
                    &format!("cells {a}, {b}"),
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
/// refined as if they had not: to jitter's rays for caps up to 4 (a cap of 3 takes the
/// five cells of its 3 × 3 that its first four left), and above that to every ray of its cap while its rays all meet
/// one object (agreeing rays bound nothing about a solid they all missed); the pixel beside
/// it, which the geometry does not flag, stops at its first four.
#[test]
fn a_pixel_that_may_hide_a_solid_is_refined_though_its_rays_agree() {
    // A flat image: no contrast anywhere, so only the geometry can ask for more rays.
    let flat = |_: f64, _: f64| Sample {
        color: Color::splat(0.5),
        object: Sample::BACKGROUND,
    };
    // Pixel (4, 2) may hide a solid other than the background; nothing is smooth.
    let hides = |px: i64, py: i64, object: u32| (px, py) == (4, 2) && object == Sample::BACKGROUND;
    let geometry = Geo(|_, _| false, hides, no_crossing);
    for (max, flagged) in [(2, 4), (3, 9), (4, 16), (6, 36), (8, 64), (16, 256)] {
        let s = Sampler::Adaptive {
            max,
            threshold: 0.02,
        };
        let (out, rays) = traced_probed(s, Rect::new(4, 2, 2, 1), flat, &geometry);
        assert_eq!(rays_in(&rays, 4, 2).len(), flagged, "max {max}");
        assert_eq!(rays_in(&rays, 5, 2).len(), 4, "max {max}");
        assert_eq!(out, vec![Color::splat(0.5); 2], "max {max}");
    }
}

/// A flagged pixel whose rays have met the solid (a second object, here of the same
/// colour, so that only the objects differ) stops at its first complete stage of 16 rays
/// when their spread allows, as any pixel with two objects does: the rule that takes every
/// ray holds only while the solid is unseen.
#[test]
fn a_flagged_pixel_stops_early_once_its_rays_meet_the_solid() {
    // The left half of every pixel is object 1, the right the background, one colour.
    let halves = |x: f64, _: f64| Sample {
        color: Color::splat(0.5),
        object: if x.fract() < 0.5 {
            1
        } else {
            Sample::BACKGROUND
        },
    };
    let hides = |px: i64, py: i64, _: u32| (px, py) == (4, 2);
    let geometry = Geo(|_, _| false, hides, no_crossing);
    for max in [6, 8, 16] {
        let s = Sampler::Adaptive {
            max,
            threshold: 0.02,
        };
        let (_, rays) = traced_probed(s, Rect::new(4, 2, 1, 1), halves, &geometry);
        assert_eq!(rays_in(&rays, 4, 2).len(), 16, "max {max}");
    }
}

/// [`PixelGeometry`] `G` that is also told the quarters of each pixel a thin solid may show
/// in, by `quadrants(px, py)`, the pixels that are blank, by `blank(px, py)`, and what a
/// solid covers of a pixel, by `coverage(px, py)`.
struct Told<'g, G, Q, B, C = fn(i64, i64) -> Option<Coverage>>(&'g G, Q, B, C);

/// No pixel known blank, for [`Told`].
fn none_blank(_: i64, _: i64) -> Option<Sample> {
    None
}

/// No pixel's coverage known, for [`Told`].
fn none_covered(_: i64, _: i64) -> Option<Coverage> {
    None
}

impl<G, Q, B, C> PixelGeometry for Told<'_, G, Q, B, C>
where
    G: PixelGeometry,
    Q: Fn(i64, i64) -> Option<u8>,
    B: Fn(i64, i64) -> Option<Sample>,
    C: Fn(i64, i64) -> Option<Coverage>,
{
    fn coverage(&self, px: i64, py: i64) -> Option<Coverage> {
        (self.3)(px, py)
    }

    fn is_smooth(&self, px: i64, py: i64, x: f64, y: f64, seen: &Sample) -> bool {
        self.0.is_smooth(px, py, x, y, seen)
    }

    fn may_hide(&self, px: i64, py: i64, object: u32) -> bool {
        self.0.may_hide(px, py, object)
    }

    fn fitted_quadrants(&self, px: i64, py: i64) -> Option<u8> {
        (self.1)(px, py)
    }

    fn blank(&self, px: i64, py: i64) -> Option<Sample> {
        (self.2)(px, py)
    }

    fn unseen_pattern(
        &self,
        px: i64,
        py: i64,
        object: u32,
        seen: &[(f64, f64)],
    ) -> Option<UnseenPattern> {
        self.0.unseen_pattern(px, py, object, seen)
    }

    fn pattern_alone(&self, px: i64, py: i64, x: f64, y: f64, object: u32) -> bool {
        self.0.pattern_alone(px, py, x, y, object)
    }
}

/// Where the geometry names the quarters a hidden solid may show in, only those take more
/// rays: the others keep their one first-pass ray. The refined quarters take what the whole
/// pixel would (jitter's cells at cap 4; every cell at cap 8 while nothing else is seen), and
/// none at all where no quarter is named.
#[test]
fn only_the_quarters_a_solid_may_show_in_are_refined() {
    let flat = |_: f64, _: f64| Sample {
        color: Color::splat(0.5),
        object: Sample::BACKGROUND,
    };
    let hides = |px: i64, py: i64, _: u32| (px, py) == (4, 2);
    let flags = Geo(|_, _| false, hides, no_crossing);
    for (max, named, expected) in [
        (4, 0b0110, 4 + 2 * 3),
        (4, 0b1000, 4 + 3),
        (8, 0b0110, 4 + 2 * 15),
        (8, 0b0000, 4),
    ] {
        let s = Sampler::Adaptive {
            max,
            threshold: 0.02,
        };
        let geometry = Told(&flags, |_, _| Some(named), none_blank, none_covered);
        let (out, rays) = traced_probed(s, Rect::new(4, 2, 1, 1), flat, &geometry);
        let rays = rays_in(&rays, 4, 2);
        assert_eq!(rays.len(), expected, "max {max}, quarters {named:04b}");
        // One first-pass ray in each unnamed quarter, and the rest in the named ones.
        for k in 0..4u8 {
            let inside = |&(x, y): &(f64, f64)| {
                let (qx, qy) = (f64::from(k & 1), f64::from(k >> 1));
                (x - 4.0 - 0.5 * qx) * 2.0 < 1.0
                    && (x - 4.0 - 0.5 * qx) >= 0.0
                    && (y - 2.0 - 0.5 * qy) * 2.0 < 1.0
                    && (y - 2.0 - 0.5 * qy) >= 0.0
            };
            let n = rays.iter().filter(|r| inside(r)).count();
            let want = if named & (1 << k) != 0 {
                (max * max / 4) as usize
            } else {
                1
            };
            assert_eq!(n, want, "max {max}, quarters {named:04b}, quarter {k}");
        }
        assert_eq!(out[0], Color::splat(0.5));
    }
}

/// A pixel whose rays all met one thin solid, beside a neighbour that saw another object,
/// may hold a sliver of what lies behind the solid: where the geometry says only thin solids
/// and a backdrop show there, it takes every ray until a second object is met; where the
/// geometry does not know, it stops at 8 agreeing rays as any pixel a neighbour asked about.
#[test]
fn a_thin_solid_s_silhouette_beside_a_neighbour_is_searched_to_the_cap() {
    // Object 1 left of x = 5, the background right of it, in one colour.
    let split = |x: f64, _: f64| Sample {
        color: Color::splat(0.5),
        object: if x < 5.0 { 1 } else { Sample::BACKGROUND },
    };
    let flags = Geo(|_, _| false, |_, _, _| false, no_crossing);
    let s = Sampler::Adaptive {
        max: 8,
        threshold: 0.02,
    };
    for (quarters, expected) in [(Some(0b1111), 64), (None, 8)] {
        let geometry = Told(&flags, |_, _| quarters, none_blank, none_covered);
        let (_, rays) = traced_probed(s, Rect::new(4, 2, 2, 1), split, &geometry);
        assert_eq!(
            rays_in(&rays, 4, 2).len(),
            expected,
            "quarters {quarters:?}"
        );
    }
}

/// A pixel whose first rays met two objects, in different quarters, with the edge between
/// them in the quarters named: the rays there may all fall on one side of it, so they do
/// not stop on agreeing until they meet both objects, and the pixel ends within the
/// threshold of jitter's value at the same cap (on agreeing rays it would lose the
/// sliver: 0.55 against 0.59 to 0.60 at caps 8 and 12).
#[test]
fn quarters_refined_alone_stop_only_once_they_meet_both_sides() {
    // Object 1 (dark) left of x = 4.45, the background (bright) right of it: the left
    // quarters hold the edge, a sliver a tenth of their width.
    let trace = |x: f64, _y: f64| {
        let dark = x < 4.45;
        Sample {
            color: Color::splat(if dark { 0.2 } else { 0.9 }),
            object: if dark { 1 } else { Sample::BACKGROUND },
        }
    };
    let rect = Rect::new(4, 2, 1, 1);
    let flags = Geo(|_, _| false, |_, _, _| false, no_crossing);
    let left = Told(&flags, |_, _| Some(0b0101), none_blank, none_covered);
    let exact = 0.45 * 0.2 + 0.55 * 0.9;
    for max in [6, 8, 12, 16] {
        let s = Sampler::Adaptive {
            max,
            threshold: 0.01,
        };
        let mut quartered = vec![Color::ZERO; 1];
        s.render_rect_probed(rect, trace, &left, &mut quartered);
        let mut jit = vec![Color::ZERO; 1];
        Sampler::Jitter { n: max }.render_rect(rect, trace, &mut jit);
        assert!(
            (quartered[0].x - jit[0].x).abs() <= 0.01,
            "max {max}: {} against jitter's {} (exact {exact})",
            quartered[0].x,
            jit[0].x
        );
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

    // Naming the quarters the line crosses (the same band test on each half-pixel
    // square) gives the same values with fewer rays: the others hold the ground alone.
    let crosses_quarter = |px: i64, py: i64, k: u8| {
        let (x0, y0) = (
            px as f64 + 0.5 * f64::from(k & 1),
            py as f64 + 0.5 * f64::from(k >> 1),
        );
        let (lo, hi) = (2.0 + 0.37 * y0 - 0.025, 2.0 + 0.37 * (y0 + 0.5) + 0.025);
        x0 < hi && x0 + 0.5 > lo
    };
    let quarters = |px: i64, py: i64| {
        Some((0..4u8).fold(0, |bits, k| {
            bits | (u8::from(crosses_quarter(px, py, k)) << k)
        }))
    };
    let count = std::cell::Cell::new(0usize);
    let counted = |x: f64, y: f64| {
        count.set(count.get() + 1);
        line(x, y)
    };
    let mut quartered = vec![Color::ZERO; rect.pixel_count()];
    s.render_rect_probed(
        rect,
        counted,
        &Told(&geometry, quarters, none_blank, none_covered),
        &mut quartered,
    );
    let with_quarters = count.replace(0);
    s.render_rect_probed(rect, counted, &geometry, &mut flagged);
    let without = count.get();
    for (i, (q, j)) in quartered.iter().zip(&jit).enumerate() {
        let (px, py) = ((i % 12) as i64, (i / 12) as i64);
        if crosses(px, py) {
            assert!((*q - *j).abs().max_element() < 1e-12, "pixel ({px}, {py})");
        }
    }
    // A crossed pixel's quarters the line misses (about one and a half of four) save
    // three rays each.
    let crossed = (0..rect.pixel_count())
        .filter(|&i| crosses((i % 12) as i64, (i / 12) as i64))
        .count();
    assert!(
        with_quarters + 3 * crossed <= without,
        "{with_quarters} rays with quarters named, {without} without, {crossed} pixels crossed"
    );
}

/// A pixel the geometry knows to be blank takes its sample for every ray it would trace
/// (its probe, its first pass and any refinement a neighbour asks of it): it traces none,
/// and every pixel's value is the one tracing would give, whatever the cap and the tile.
#[test]
fn a_blank_pixel_traces_nothing_and_changes_nothing() {
    // A disc on a background: a pixel whose square lies wholly outside is blank.
    let (cx, cy, r) = (8.3, 5.1, 3.0);
    let background = Sample {
        color: Color::new(0.1, 0.2, 0.3),
        object: Sample::BACKGROUND,
    };
    let disc = |x: f64, y: f64| {
        if (x - cx).powi(2) + (y - cy).powi(2) < r * r {
            Sample {
                color: Color::splat(0.9),
                object: 1,
            }
        } else {
            background
        }
    };
    let outside = |px: i64, py: i64| {
        let nx = (px as f64).max(cx.min(px as f64 + 1.0));
        let ny = (py as f64).max(cy.min(py as f64 + 1.0));
        (nx - cx).powi(2) + (ny - cy).powi(2) > r * r
    };
    // Nothing ends after its probe, so blank pixels take first passes, and those beside the
    // disc are refined as its neighbours.
    let geometry = smooth_where(|_, _| false);
    let blanked = Told(
        &geometry,
        |_, _| None,
        |px: i64, py: i64| outside(px, py).then_some(background),
        none_covered,
    );
    for max in [2, 3, 4, 6, 8] {
        let s = Sampler::Adaptive {
            max,
            threshold: 0.02,
        };
        let mut saved = 0;
        for tile in [3u32, 17] {
            for rect in crate::tile::tiles(17, 11, tile) {
                let (traced, all) = traced_probed(s, rect, disc, &geometry);
                let (known, fewer) = traced_probed(s, rect, disc, &blanked);
                assert_eq!(known, traced, "cap {max}, tile {rect:?}");
                let blank_rays = |rays: &[(f64, f64)]| {
                    rays.iter()
                        .filter(|(x, y)| outside(x.floor() as i64, y.floor() as i64))
                        .count()
                };
                assert_eq!(blank_rays(&fewer), 0, "cap {max}, tile {rect:?}");
                saved += blank_rays(&all);
                // The other pixels' rays are the same rays.
                let kept: Vec<_> = all
                    .iter()
                    .filter(|(x, y)| !outside(x.floor() as i64, y.floor() as i64))
                    .collect();
                assert_eq!(fewer.iter().collect::<Vec<_>>(), kept, "cap {max}");
            }
        }
        assert!(saved > 0, "cap {max}");
    }
}

/// A pixel whose square shows one solid's smooth shading on the background weighs its rays
/// that met the solid by the solid's exact share: on a flat disc every pixel is then exact
/// (the share from `exact::disc_coverage`, a closed form), whatever the cap and the tile;
/// with shading, the pixel is the share of its solid's rays' mean and the background's
/// colour for the rest, the same whole or tiled, and takes no more rays than without.
#[test]
fn a_covered_pixel_weighs_its_solid_s_rays_by_its_share() {
    use crate::exact::disc_coverage;
    use glam::DVec2;
    let (c, r) = (DVec2::new(8.3, 5.1), 3.2);
    let backdrop = Color::new(0.1, 0.2, 0.3);
    let share = |px: i64, py: i64| {
        let lo = DVec2::new(px as f64, py as f64);
        disc_coverage(c, r, lo, lo + DVec2::ONE)
    };
    let cover = |px: i64, py: i64| {
        Some(Coverage {
            object: 1,
            share: share(px, py),
            backdrop,
        })
    };
    for slope in [0.0, 0.004, 0.3] {
        let disc = |x: f64, y: f64| {
            if (x - c.x).powi(2) + (y - c.y).powi(2) < r * r {
                Sample {
                    color: Color::new(0.9, 0.5 + slope * (x - c.x), 0.7),
                    object: 1,
                }
            } else {
                Sample {
                    color: backdrop,
                    object: Sample::BACKGROUND,
                }
            }
        };
        let geometry = smooth_where(|_, _| false);
        let covered = Told(&geometry, |_, _| None, none_blank, cover);
        for max in [2, 3, 4, 6, 8] {
            let s = Sampler::Adaptive {
                max,
                threshold: 0.02,
            };
            let whole = Rect::new(0, 0, 17, 11);
            let (plain, plain_rays) = traced_probed(s, whole, disc, &geometry);
            let (out, rays) = traced_probed(s, whole, disc, &covered);
            assert!(rays.len() <= plain_rays.len(), "cap {max}, slope {slope}");
            for tile in [3u32, 5] {
                for rect in crate::tile::tiles(17, 11, tile) {
                    let (part, _) = traced_probed(s, rect, disc, &covered);
                    for (k, v) in part.iter().enumerate() {
                        let (x, y) = (
                            rect.x + k as u32 % rect.width,
                            rect.y + k as u32 / rect.width,
                        );
                        assert_eq!(*v, out[(y * 17 + x) as usize], "cap {max}, tile {rect:?}");
                    }
                }
            }
            let (mut exact_pixels, mut plain_err) = (0, 0.0);
            for (k, v) in out.iter().enumerate() {
                let (px, py) = (k as u32 % 17, k as u32 / 17);
                let a = share(i64::from(px), i64::from(py));
                let inner: Vec<Color> = rays_in(&rays, px, py)
                    .into_iter()
                    .map(|(x, y)| disc(x, y))
                    .filter(|s| s.object == 1)
                    .map(|s| s.color)
                    .collect();
                let expected = if inner.is_empty() {
                    backdrop
                } else {
                    let mean = inner.iter().fold(Color::ZERO, |m, &c| m + c) / inner.len() as f64;
                    mean * a + backdrop * (1.0 - a)
                };
                assert!(
                    (*v - expected).abs().max_element() < 1e-12,
                    "cap {max}, pixel {px},{py}"
                );
                // On the flat disc a pixel that found its solid is exact.
                let exact = Color::new(0.9, 0.5, 0.7) * a + backdrop * (1.0 - a);
                if slope == 0.0 && !inner.is_empty() {
                    assert!(
                        (*v - exact).abs().max_element() < 1e-12,
                        "cap {max}, pixel {px},{py}"
                    );
                    exact_pixels += usize::from(a > 0.0 && a < 1.0);
                    plain_err += (plain[k] - exact).length_squared();
                }
            }
            if slope == 0.0 {
                assert!(exact_pixels > 12, "cap {max}: {exact_pixels}");
                // Without its coverage the same pixels are off.
                assert!(plain_err > 1e-3, "cap {max}: {plain_err}");
            }
        }
    }
}

/// A solid a pixel wide, whose shading spans its whole range within the pixel, never ends
/// a pixel at its probe, even where the probe met it and its share is known: no neighbour's
/// probe on the solid vouches that its shading is smooth at the pixel's scale.
#[test]
fn a_solid_a_pixel_wide_is_not_ended_by_its_probe() {
    use crate::exact::disc_coverage;
    use glam::DVec2;
    let r = 0.45;
    let centre = |px: i64, py: i64| DVec2::new(px as f64 + 0.5, py as f64 + 0.5);
    // One disc in every third pixel, lit across its width.
    let holds = |px: i64, py: i64| px.rem_euclid(3) == 1 && py.rem_euclid(3) == 1;
    let backdrop = Color::splat(0.05);
    let disc = |x: f64, y: f64| {
        let (px, py) = (x.floor() as i64, y.floor() as i64);
        let c = centre(px, py);
        if holds(px, py) && (x - c.x).powi(2) + (y - c.y).powi(2) < r * r {
            Sample {
                color: Color::splat(0.5 + (x - c.x)),
                object: 1,
            }
        } else {
            Sample {
                color: backdrop,
                object: Sample::BACKGROUND,
            }
        }
    };
    let cover = |px: i64, py: i64| {
        let lo = DVec2::new(px as f64, py as f64);
        let share = if holds(px, py) {
            disc_coverage(centre(px, py), r, lo, lo + DVec2::ONE)
        } else {
            0.0
        };
        Some(Coverage {
            object: 1,
            share,
            backdrop,
        })
    };
    let geometry = smooth_where(|_, _| false);
    let covered = Told(&geometry, |_, _| None, none_blank, cover);
    let s = Sampler::Adaptive {
        max: 4,
        threshold: 0.02,
    };
    let (_, rays) = traced_probed(s, Rect::new(0, 0, 15, 12), disc, &covered);
    let mut met = 0;
    for py in 0..12u32 {
        for px in 0..15u32 {
            let mine = rays_in(&rays, px, py);
            if holds(px.into(), py.into()) && disc(mine[0].0, mine[0].1).object == 1 {
                met += 1;
                assert!(mine.len() >= 4, "pixel ({px}, {py}): {} rays", mine.len());
            }
        }
    }
    assert!(met >= 5, "{met} probes met a disc");
}
