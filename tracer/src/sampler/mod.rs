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

mod adaptive;
mod jitter;

use crate::math::Color;
use crate::tile::Rect;
use adaptive::adaptive;
#[cfg(feature = "bench")]
pub use jitter::reference_pixel;
use jitter::{SEED_JITTER, stratified};

/// The sampling strategy of a render.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Sampler {
    /// One ray through the pixel centre (`antialias = off`).
    Center,
    /// The thesis's five rays: the centre and the four points `(±¼, ±¼)` from it
    /// (`antialias = on`).
    Thesis,
    /// `n × n` rays on a regular grid.
    Grid {
        /// Rays per axis.
        n: u32,
    },
    /// `n × n` stratified rays, one placed by hash in each cell of the grid.
    Jitter {
        /// Rays per axis.
        n: u32,
    },
    /// One ray (the *probe*), and no more where the renderer's smoothness test shows that
    /// nothing but smooth shading changes in the pixel and no neighbour's probe on the same
    /// surface differs from it by more than `threshold` (see
    /// [`Sampler::render_rect_probed`]). Elsewhere a first pass of one jittered ray per
    /// pixel quadrant (for odd `max`, four cells of the `max × max` grid drawn at random;
    /// the probe among them), then more where the image needs them, reusing every ray
    /// already traced (for even `max` in stages), up to `max × max` stratified rays, the
    /// very rays of `Jitter { n: max }` (`max = 1` is that one ray): where the first pass varies by
    /// more than `threshold` or meets two objects, where the scene's geometry says a solid
    /// the first pass did not see may show in the pixel (`PixelGeometry::may_hide`), or
    /// where a neighbour's first pass saw an edge, another object or another mean. For even
    /// `max ≥ 6`, a pixel only a neighbour asked for takes one more ray per quadrant first
    /// and stops there unless they disagree (or the step between them went unseen by both:
    /// then both take every ray), and a pixel at 16 rays (or, for `max/2` a power of two,
    /// 32, 64, …) stops there once the standard error of its mean is at most `threshold` ·
    /// √(rays/16) (see `refine` and `se_bound` in `sampler/adaptive/refine.rs`), unless a thin
    /// solid may hide in it unseen: then it stops only once its rays meet two objects.
    /// Where the geometry names the quarters of the square a thin solid may show in
    /// (`PixelGeometry::fitted_quadrants`), a pixel that goes on because of one refines
    /// only those. Where it knows the share of the square a plain solid covers against the
    /// background (`PixelGeometry::coverage`), the pixel weighs its rays on the solid by
    /// that share, and takes rays only until they bound the solid's shading (see `covered`
    /// in `sampler/adaptive/refine.rs`).
    Adaptive {
        /// Most rays per axis: a pixel takes at most `max × max`.
        max: u32,
        /// Largest difference between rays (and standard error) taken as smooth.
        threshold: f64,
    },
}

impl Sampler {
    /// `max` of `sampler = adaptive` when the scene gives no `samples`.
    pub const DEFAULT_ADAPTIVE_MAX: u32 = 4;
    /// `threshold` of `sampler = adaptive` when the scene gives none.
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
            Sampler::Grid { n } | Sampler::Jitter { n } | Sampler::Adaptive { max: n, .. } => n * n,
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
    /// (see `PixelGeometry`): the adaptive sampler ends pixels it calls smooth after one
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
        if let Sampler::Adaptive { max, threshold } = *self
            && max >= 2
        {
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
            // A cap of one ray leaves nothing to adapt: the pixel is `jitter`'s one ray.
            Sampler::Adaptive { max: 1, .. } => stratified(x, y, 1, Some(SEED_JITTER), trace),
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
    /// The object id of a sample that hit nothing.
    pub const BACKGROUND: u32 = u32::MAX;
}

/// The four quarters of a pixel's square as bits, bit `k` for the quarter in column
/// `k & 1`, row `k >> 1` (see [`PixelGeometry::fitted_quadrants`]).
pub(crate) const ALL_QUADRANTS: u8 = 0b1111;

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

    /// The quarters of pixel `(px, py)`'s square (bit `k` for column `k & 1`, row `k >> 1`)
    /// in which a solid that [`PixelGeometry::may_hide`] asks about may show, where the rest
    /// of the square shows one backdrop of smooth shading alone; `None` where it does not
    /// know. A quarter without its bit then holds nothing its one first-pass ray can miss but
    /// smooth shading, and the sampler refines only the others. May set bits where none is
    /// true, never leave one out.
    fn fitted_quadrants(&self, _px: i64, _py: i64) -> Option<u8> {
        None
    }

    /// The sample every primary ray through pixel `(px, py)`'s square returns, where the
    /// geometry knows it without tracing one: nothing but the background can show there.
    /// `None` where it does not know. Never a sample that a ray through the square would
    /// not return, bit for bit: the sampler takes it in place of tracing that ray.
    fn blank(&self, _px: i64, _py: i64) -> Option<Sample> {
        None
    }

    /// Where pixel `(px, py)`'s square shows one solid's smooth shading (no edge, texture,
    /// reflection or shadow edge on it) and the background around it, and nothing else:
    /// the solid, the share of the square in which rays meet it, and the background's
    /// sample. `None` where it does not know. The share must be exact to rounding: the
    /// sampler weighs the solid's rays by it ([`Coverage::value`]).
    fn coverage(&self, _px: i64, _py: i64) -> Option<Coverage> {
        None
    }

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

    /// What a checkered plane's cells give pixel `(px, py)`, where the primary ray through
    /// `at` saw `seen` and that plane alone shows in the square: the mean over the square of
    /// [`PixelGeometry::direct`], within `threshold`, and, where nothing but the cells and
    /// smooth shading changes in the square, the pixel's value; summing at most `max_cells`
    /// cells. `None` where it does not know.
    fn cells(
        &self,
        _px: i64,
        _py: i64,
        _at: (f64, f64),
        _seen: &Sample,
        _threshold: f64,
        _max_cells: u32,
    ) -> Option<CellSums> {
        None
    }

    /// The plane's own light at image position `at`, for the [`CellSums`] of `object`: the
    /// function whose mean `CellSums::direct` is.
    fn direct(&self, _object: u32, _at: (f64, f64)) -> Color {
        Color::ZERO
    }
}

/// What a checkered plane's cells give a pixel (see [`PixelGeometry::cells`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CellSums {
    /// The plane.
    pub object: u32,
    /// The mean over the pixel's square of the plane's own unshadowed light,
    /// [`PixelGeometry::direct`]: a control variate. A ray's colour less its `direct`, plus
    /// this mean, estimates the pixel as the ray does, with the cells' edges taken out of
    /// its spread; only shadows and reflections remain.
    pub direct: Color,
    /// The pixel's value, where nothing but the cells and smooth shading change in it.
    pub exact: Option<Color>,
}

/// A pixel's square that shows one solid of smooth shading against the background (see
/// `PixelGeometry::coverage`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Coverage {
    /// The solid.
    pub object: u32,
    /// The share of the square in which primary rays meet it, in `[0, 1]`.
    pub share: f64,
    /// What every other ray returns: the background's colour, clamped as a sample is.
    pub backdrop: Color,
}

impl Coverage {
    /// The pixel's value, given `inner`, the mean of some of its rays that met the solid:
    /// its share of `inner` and the rest of the backdrop. The square's silhouette is then
    /// exact, and only the solid's shading is estimated (post-stratification: each part of
    /// the square weighed by its known area rather than by the rays that fell in it).
    pub fn value(&self, inner: Color) -> Color {
        inner * self.share + self.backdrop * (1.0 - self.share)
    }
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

#[cfg(test)]
mod tests;
