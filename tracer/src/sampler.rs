//! Pixel samplers: where in a pixel rays go, how many, and how they are averaged.
//!
//! Each sampler estimates the exact pixel value of SCENE.md, the average of the clamped
//! radiance over the pixel's square. Sample positions come from a hash of the pixel's
//! coordinates and the sample's index, never from a running random generator, so a pixel's
//! value depends only on the scene and the pixel: not on the tile, the thread or the machine.
//!
//! The adaptive sampler also looks at the first samples of the four neighbouring pixels; a
//! tile computes those for a one-pixel border around itself, which keeps it tile-independent.
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
    /// A first pass of one jittered ray per pixel quadrant; where it varies by more than
    /// `threshold`, or it or a neighbour's first pass meets more than one object, `max × max`
    /// stratified rays (the first pass's included when `max` is even).
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
        let n = samples.or(own_n).unwrap_or(4);
        let threshold = threshold
            .or(own_threshold)
            .unwrap_or(Self::DEFAULT_THRESHOLD);
        Ok(match name.unwrap_or(self.name()) {
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
        })
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
    pub fn render_rect<F>(&self, rect: Rect, trace: F, out: &mut [Color])
    where
        F: Fn(f64, f64) -> Sample,
    {
        debug_assert_eq!(out.len(), rect.pixel_count());
        if let Sampler::Adaptive { max, threshold } = *self {
            adaptive(rect, max, threshold, &trace, out);
            return;
        }
        let mut i = 0;
        for y in rect.y..rect.y + rect.height {
            for x in rect.x..rect.x + rect.width {
                out[i] = self.pixel(x, y, &trace);
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
                adaptive(Rect::new(x, y, 1, 1), max, threshold, trace, &mut one);
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

const SEED_JITTER: u64 = 0x9e37_79b9_7f4a_7c15;
const SEED_FIRST: u64 = 0xc2b2_ae3d_27d4_eb4f;
const SEED_REFINE: u64 = 0x1656_67b1_9e37_79f9;
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
    for j in 0..n {
        for i in 0..n {
            let (ox, oy) = match seed {
                None => (0.5, 0.5),
                Some(s) => unit_pair(x, y, j * n + i, s),
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
    let h = mix(seed ^ (u64::from(x) << 32 | u64::from(y)));
    let h = mix(h ^ u64::from(index));
    let a = (h >> 11) as f64 * (1.0 / (1u64 << 53) as f64);
    let h2 = mix(h);
    let b = (h2 >> 11) as f64 * (1.0 / (1u64 << 53) as f64);
    (a, b)
}

/// SplitMix64's finaliser: a bijective 64-bit mix with full avalanche.
#[inline]
fn mix(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// First-pass result of one pixel for the adaptive sampler.
#[derive(Clone, Copy)]
struct FirstPass {
    sum: Color,
    min: Color,
    max: Color,
    object: u32,
    mixed: bool,
    /// For even `n`, the cells of the `n × n` grid the four samples took (see
    /// [`first_position`]), so refinement does not trace them again.
    cells: [u32; 4],
}

/// Where first-pass sample `k` (quadrant `k`) of pixel `(x, y)` goes, as an offset inside the
/// pixel, and the cell of the final `n × n` grid it stands for.
///
/// For even `n`, each quadrant of the pixel is `n/2 × n/2` cells of the final grid; the sample
/// picks one of them by hash and sits at that cell's own jittered position. It is then exactly
/// the sample refinement would trace in that cell, so a refined pixel is a plain `n × n`
/// stratified estimate that reuses the first pass, and the first pass alone is still one
/// uniform sample per quadrant. For odd `n` the quadrants do not align with the grid, and the
/// first pass is an independent 2 × 2 jittered set.
fn first_position(x: i64, y: i64, k: u32, n: u32) -> (f64, f64, u32) {
    let (qx, qy) = (k % 2, k / 2);
    // Border pixels left of or above the image have negative coordinates; their hash input
    // wraps, which is as good a seed as any and the same in every tile.
    let (hx, hy) = (x as u32, y as u32);
    if n.is_multiple_of(2) {
        let h = n / 2;
        let (a, b) = unit_pair(hx, hy, k, SEED_FIRST);
        let ci = qx * h + ((a * f64::from(h)) as u32).min(h - 1);
        let cj = qy * h + ((b * f64::from(h)) as u32).min(h - 1);
        let cell = cj * n + ci;
        let (ox, oy) = unit_pair(hx, hy, cell, SEED_REFINE);
        let inv = 1.0 / f64::from(n);
        ((f64::from(ci) + ox) * inv, (f64::from(cj) + oy) * inv, cell)
    } else {
        let (ox, oy) = unit_pair(hx, hy, k, SEED_FIRST);
        (
            (f64::from(qx) + ox) * 0.5,
            (f64::from(qy) + oy) * 0.5,
            u32::MAX,
        )
    }
}

fn first_pass<F: Fn(f64, f64) -> Sample>(x: i64, y: i64, n: u32, trace: &F) -> FirstPass {
    let mut fp = FirstPass {
        sum: Color::ZERO,
        min: Color::splat(f64::INFINITY),
        max: Color::splat(f64::NEG_INFINITY),
        object: 0,
        mixed: false,
        cells: [u32::MAX; 4],
    };
    for k in 0..4u32 {
        let (ox, oy, cell) = first_position(x, y, k, n);
        let s = trace(x as f64 + ox, y as f64 + oy);
        fp.sum += s.color;
        fp.min = fp.min.min(s.color);
        fp.max = fp.max.max(s.color);
        fp.cells[k as usize] = cell;
        if k == 0 {
            fp.object = s.object;
        } else if s.object != fp.object {
            fp.mixed = true;
        }
    }
    fp
}

/// The `n × n` estimate of a pixel whose first pass asked for refinement.
fn refine<F: Fn(f64, f64) -> Sample>(x: u32, y: u32, n: u32, fp: &FirstPass, trace: &F) -> Color {
    if n.is_multiple_of(2) {
        let inv = 1.0 / f64::from(n);
        let mut sum = fp.sum;
        for cell in 0..n * n {
            if fp.cells.contains(&cell) {
                continue;
            }
            let (ci, cj) = (cell % n, cell / n);
            let (ox, oy) = unit_pair(x, y, cell, SEED_REFINE);
            let sx = f64::from(x) + (f64::from(ci) + ox) * inv;
            let sy = f64::from(y) + (f64::from(cj) + oy) * inv;
            sum += trace(sx, sy).color;
        }
        sum / f64::from(n * n)
    } else {
        // Both sets are unbiased estimates of the pixel, so their count-weighted mean is too.
        let n2 = f64::from(n * n);
        (fp.sum + stratified(x, y, n, Some(SEED_REFINE), trace) * n2) / (4.0 + n2)
    }
}

fn adaptive<F: Fn(f64, f64) -> Sample>(
    rect: Rect,
    max: u32,
    threshold: f64,
    trace: &F,
    out: &mut [Color],
) {
    // First pass over the rect plus a one-pixel border. Border pixels outside the image are
    // traced like any others (the camera extends past the image), so a pixel at the image's
    // edge is treated exactly like one inside.
    let bw = rect.width as usize + 2;
    let bh = rect.height as usize + 2;
    let mut border = Vec::with_capacity(bw * bh);
    for by in 0..bh {
        for bx in 0..bw {
            let px = i64::from(rect.x) - 1 + bx as i64;
            let py = i64::from(rect.y) - 1 + by as i64;
            border.push(first_pass(px, py, max, trace));
        }
    }
    let mut i = 0;
    for ry in 0..rect.height as usize {
        for rx in 0..rect.width as usize {
            let (bx, by) = (rx + 1, ry + 1);
            let centre = border[by * bw + bx];
            // Refine where the pixel's own samples disagree (contrast or a second object), or
            // where a neighbour saw an edge, a different object or a different mean: an edge or
            // a thin feature there may reach into this pixel between its own samples, and four
            // samples that happen to agree inside fine texture (a checker near the horizon)
            // still disagree with their neighbours'.
            let mut refine_here =
                centre.mixed || (centre.max - centre.min).max_element() > threshold;
            for (nx, ny) in [(bx - 1, by), (bx + 1, by), (bx, by - 1), (bx, by + 1)] {
                let n = &border[ny * bw + nx];
                refine_here |= n.mixed
                    || n.object != centre.object
                    || ((n.sum - centre.sum) * 0.25).abs().max_element() > threshold;
            }
            let (x, y) = (rect.x + rx as u32, rect.y + ry as u32);
            out[i] = if refine_here {
                refine(x, y, max, &centre, trace)
            } else {
                centre.sum * 0.25
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

    /// A vertical edge at x = 10.3: white to its left.
    fn edge(x: f64, _y: f64) -> Sample {
        let white = x < 10.3;
        Sample {
            color: Color::splat(if white { 1.0 } else { 0.0 }),
            object: u32::from(white),
        }
    }

    const ALL: [Sampler; 6] = [
        Sampler::Center,
        Sampler::Thesis,
        Sampler::Grid { n: 3 },
        Sampler::Jitter { n: 4 },
        Sampler::Adaptive {
            max: 4,
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
        assert_eq!(
            Sampler::Center.with_overrides(Some("grid"), None, None, 32),
            Ok(Sampler::Grid { n: 4 })
        );
        assert!(s.with_overrides(None, Some(33), None, 32).is_err());
        assert!(s.with_overrides(None, None, Some(f64::NAN), 32).is_err());
        assert!(s.with_overrides(Some("random"), None, None, 32).is_err());
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
        // Each column holds three first passes (rows -1, 0, 1) of 4 samples; a refined pixel
        // adds the 12 cells of its 4 × 4 grid that the first pass did not take. Only pixels
        // at the edge (x = 10.3) and next to it may refine, and the two that the edge's first
        // pass separates (9 is white, 10 is mixed or black) must.
        let counts = per_pixel.into_inner();
        for (i, &c) in counts.iter().enumerate() {
            let x = i as i64 - 1;
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
}
