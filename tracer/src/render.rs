//! Shading and rendering: the radiance of SCENE.md's "exact image" along a ray, pixels by
//! the scene's sampler, tiles and whole images.
//!
//! Radiance at the nearest hit, with `n` the normal facing the ray:
//!
//! ```text
//! local = c · (ambient + k · Σ_lights color_l · max(0, n·l̂) · V_l)
//! V_l   = 1 if the segment to the light is clear, else 1 − shadow
//! L     = (1 − m) · local + m · L(mirror ray)     (black past max_depth bounces)
//! ```
//!
//! Work a scene does not need is not done: no shadow ray where `n·l ≤ 0`, where `shadow = 0`,
//! where nothing but the (convex) surface itself could block the light (in the whole scene,
//! or between this object and this light, see [`crate::shadow`]), where a scene of few
//! solids shows the line to the light clear of every other solid's ball (see
//! `Scene::shadow_certainly_clear`), or where the surface is a perfect mirror; no mirror ray
//! where `m = 0`; no texture lookup without a texture.
//!
//! Pixels are independent of one another except through the sampler, which is itself
//! tile-independent, so any rectangle can be rendered alone and match the whole image.

use std::cell::Cell;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};

use glam::DVec3;
use rayon::prelude::*;

use crate::footprint::{Footprints, PixelRegion};
use crate::math::{Color, Ray, floor, offset_ray_origin};
use crate::object::Object;
use crate::sampler::{Sample, Sampler};
use crate::shape::LocalHit;
use crate::srgb;
use crate::tile::{Rect, tiles};
use crate::transform::Transform;
use crate::world::{Hit, Scene};

/// A shadow ray stops this far short of its light, as a fraction of its scale
/// (`|origin|/|dir| + 1`, in units of its `t`, which is 1 at the light): a surface that
/// passes through the light itself does not shadow it.
///
/// Without it, a light placed exactly on a surface (a lamp on a wall, a light at a sphere's
/// pole) would be shadowed by that surface on a random quarter of the pixels it lights: the
/// crossing at the light comes out a few ulps before or after `t = 1` from ray to ray. The
/// segment from a point to its light is open at the light (SCENE.md's "clear" segment
/// ends there). 1e-14 of the scale is some 45 ulps of it: the crossing's rounding is a few
/// ulps of the coordinates (of `|origin|` for an object placed by a general matrix, less
/// for one placed by a similarity), and a blocker nearer the light than that is lost,
/// 2e-13 of a unit for a scene 20 units across, 1e-5 of a unit for one placed at 1e9. (At
/// 1e-12, a light 1e-3 under a plane at 1e9 would shine through it.)
pub const SHADOW_END_REL: f64 = 1e-14;

/// The most pixels of a band that a rectangle is rendered in (see `Scene::rect_bytes`):
/// their linear values are 96 KiB, under the allocator's threshold for fresh pages, so one
/// buffer serves every band and stays in the cache.
const BAND_PIXELS: usize = 4096;

/// Counts of rays traced, for benchmarks ("rays per pixel").
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct RayStats {
    /// Rays from the eye.
    pub primary: u64,
    /// Rays towards lights.
    pub shadow: u64,
    /// Mirror reflections.
    pub mirror: u64,
}

impl RayStats {
    /// All rays together.
    pub fn total(&self) -> u64 {
        self.primary + self.shadow + self.mirror
    }

    /// Adds `other`'s counts to these.
    pub fn add(&mut self, other: &RayStats) {
        self.primary += other.primary;
        self.shadow += other.shadow;
        self.mirror += other.mirror;
    }
}

/// Per-render ray counters (interior mutability, so the sampler's `Fn` closure can count).
#[derive(Default)]
struct Counters {
    primary: Cell<u64>,
    shadow: Cell<u64>,
    mirror: Cell<u64>,
}

impl Counters {
    fn bump(c: &Cell<u64>) {
        c.set(c.get() + 1);
    }

    fn stats(&self) -> RayStats {
        RayStats {
            primary: self.primary.get(),
            shadow: self.shadow.get(),
            mirror: self.mirror.get(),
        }
    }
}

/// A hit point ready to spawn secondary rays: its world position, what bounds its error,
/// and the normal facing the ray that arrived. The bound an origin must clear, the world
/// point's own error among it, is worked out only when a secondary ray is spawned
/// ([`SurfacePoint::err`]): most hits on a scene without mirrors, or lit by lights known
/// clear, spawn none.
#[derive(Debug, Clone, Copy)]
pub struct SurfacePoint<'a> {
    /// The hit point in world space.
    pub p: DVec3,
    /// The hit point in the object's space, and its error bound there.
    local: (DVec3, DVec3),
    /// The object's placement, which carries the next intersection test's origin back.
    transform: &'a Transform,
    /// Unit normal facing the incoming ray.
    pub n: DVec3,
    /// Whether the incoming ray arrived from the outside of the solid.
    pub outside: bool,
}

impl<'a> SurfacePoint<'a> {
    /// The world-space surface point of `hit` on `obj`, for a ray arriving along `incoming`.
    pub fn new(obj: &'a Object, hit: &LocalHit, incoming: DVec3) -> SurfacePoint<'a> {
        let p = obj.transform.to_world().transform_point3(hit.p);
        let outward = obj.transform.normal_to_world(hit.n).normalize();
        let outside = outward.dot(incoming) <= 0.0;
        let n = if outside { outward } else { -outward };
        SurfacePoint {
            p,
            local: (hit.p, hit.p_err),
            transform: &obj.transform,
            n,
            outside,
        }
    }

    /// Per-axis bound the offset of a secondary ray's origin must clear: the hit point's own
    /// error plus the rounding of carrying a point near it back into this object's space for
    /// the next intersection test. The factor 2 leaves room for the intersection routine's
    /// own rounding when it classifies the new origin as off the surface (a few ulps of the
    /// unit shape).
    pub fn err(&self) -> DVec3 {
        let (local, local_err) = self.local;
        2.0 * self.transform.origin_error(local, local_err, self.p)
    }

    /// Origin for a secondary ray leaving towards `dir`: off the surface, on `dir`'s side.
    // Used through `crate::internals` (feature `bench`) and by the tests.
    #[cfg_attr(not(feature = "bench"), allow(dead_code))]
    pub fn origin_towards(&self, dir: DVec3) -> DVec3 {
        offset_ray_origin(self.p, self.err(), self.n, dir)
    }

    /// Origin for a secondary ray leaving on the side the incoming ray came from (`n`'s):
    /// every ray the shader spawns does, a shadow ray only towards a light with `n·l > 0`
    /// and a mirror ray by reflection. It is [`Self::origin_towards`] of any such direction,
    /// computed once per hit rather than once per ray.
    pub fn origin_ahead(&self) -> DVec3 {
        offset_ray_origin(self.p, self.err(), self.n, self.n)
    }

    /// How far from `p` the origin of [`Self::origin_ahead`] can lie, at most, without
    /// computing it. The offset along the unit normal is `|n̂|·err ≤ Σ errᵢ ≤ 3·max errᵢ`
    /// (to a few ulps), bounded through [`Transform::origin_error_max`] by the largest
    /// components of the hit's point and error; the rounding of the sum and the step of
    /// one ulp outwards add at most two ulps of the result per axis, under `10⁻¹⁵·|p|∞`
    /// while the offset is small. The factors are generous, and the last term covers a
    /// point at zero, whose step is subnormal. The sums of magnitudes stand for the largest
    /// components (never smaller, and NaN when a component is).
    pub fn reach(&self) -> f64 {
        let (local, local_err) = self.local;
        let sum = |v: DVec3| v.x.abs() + v.y.abs() + v.z.abs();
        let p = sum(self.p);
        let err = 2.0
            * self
                .transform
                .origin_error_max(sum(local), sum(local_err), p);
        1.01 * 3.0 * err + 1e-14 * p + 1e-300
    }
}

impl Scene {
    /// The surface colour `c` at a hit: texture, checker or plain `color1`.
    fn surface_color(&self, obj: &Object, hit: &Hit) -> Color {
        let m = &obj.material;
        if let Some(tex) = &m.texture {
            return m.color1 * tex.sample(obj.shape.uv(hit.local.p, hit.local.face));
        }
        if let Some(c2) = m.color2 {
            let p = hit.local.p * obj.own_scale;
            // `as i64` saturates, so huge coordinates cannot overflow the sum.
            let cell = (floor(p.x) as i64)
                .wrapping_add(floor(p.y) as i64)
                .wrapping_add(floor(p.z) as i64);
            if cell & 1 != 0 {
                return c2;
            }
        }
        m.color1
    }

    /// Radiance along `ray` (not yet clamped). `skip` is an object the ray cannot meet again.
    /// `TABLES`: whether the scene has tables of rays through the eye and the lights (see
    /// `crate::point_index`); compiled twice, so that a scene without them runs the plain
    /// searches with no check for them at all.
    fn radiance<const TABLES: bool>(
        &self,
        ray: &Ray,
        bounces_left: u32,
        skip: Option<u32>,
        c: &Counters,
    ) -> (Color, u32) {
        let Some(hit) = self.intersect_in::<TABLES>(ray, f64::INFINITY, skip) else {
            return (self.background, Sample::BACKGROUND);
        };
        let obj = &self.objects[hit.object as usize];
        let m = &obj.material;
        let sp = SurfacePoint::new(obj, &hit.local, ray.dir);
        let self_skip = self.self_skip(&hit, sp.outside);

        // Every secondary ray leaves on the incoming side: one origin serves them all.
        let mut ahead: Option<DVec3> = None;
        let mut ahead_len: Option<f64> = None;
        let mut color = Color::ZERO;
        if m.mirror < 1.0 {
            let mut light_sum = Color::ZERO;
            if m.diffuse > 0.0 {
                let can_block = self.shadow > 0.0 && self.anything_else(self_skip);
                // The lights nothing else can hide from this object (see `crate::shadow`):
                // known clear where the shadow ray would skip the object itself.
                let mut clear = match self_skip {
                    Some(o) if can_block => self.clear_lights_at(o, hit.local.p.y),
                    _ => 0,
                };
                for (li, light) in self.lights.iter().enumerate() {
                    // Bit 0 is this light's; lights past the 64th find it 0.
                    let known_clear = clear & 1 == 1;
                    clear >>= 1;
                    let to_light = light.position - sp.p;
                    let cos = sp.n.dot(to_light);
                    if !(cos > 0.0) {
                        continue;
                    }
                    let cos = cos / to_light.length();
                    let mut v = 1.0;
                    if can_block && !known_clear {
                        // A shadow ray shown clear of every other solid from wherever its
                        // origin may lie is not traced (see `Scene::shadow_certainly_clear`).
                        let reach = || sp.reach();
                        if !self.shadow_certainly_clear(sp.p, reach, light.position, self_skip) {
                            Counters::bump(&c.shadow);
                            let origin = *ahead.get_or_insert_with(|| sp.origin_ahead());
                            let origin_len = *ahead_len.get_or_insert_with(|| origin.length());
                            if self.shadow_blocked::<TABLES>(li, origin, origin_len, self_skip) {
                                v = 1.0 - self.shadow;
                            }
                        }
                    }
                    light_sum += light.color * (cos * v);
                }
            }
            let local = self.surface_color(obj, &hit) * (self.ambient + light_sum * m.diffuse);
            color += local * (1.0 - m.mirror);
        }
        if m.mirror > 0.0 && bounces_left > 0 {
            Counters::bump(&c.mirror);
            let d = ray.dir.normalize();
            let r = d - sp.n * (2.0 * d.dot(sp.n));
            let origin = *ahead.get_or_insert_with(|| sp.origin_ahead());
            let mirror_ray = Ray::new(origin, r);
            let (reflected, _) =
                self.radiance::<TABLES>(&mirror_ray, bounces_left - 1, self_skip, c);
            color += reflected * m.mirror;
        }
        (color, hit.object)
    }

    /// Whether the shadow ray from `origin` (of length `origin_len`, off a surface of object
    /// `self_skip`) to light `li` is blocked. It stops [`SHADOW_END_REL`] of its scale short
    /// of the light.
    #[inline(always)]
    fn shadow_blocked<const TABLES: bool>(
        &self,
        li: usize,
        origin: DVec3,
        origin_len: f64,
        self_skip: Option<u32>,
    ) -> bool {
        let light = &self.lights[li];
        let shadow_ray = Ray::new(origin, light.position - origin);
        let scale = origin_len / shadow_ray.dir.length() + 1.0;
        let end = 1.0 - SHADOW_END_REL * scale;
        // Objects the light lies on cannot shadow it from their outer side (see
        // `Scene::lights_on`); past four, the rest are traced. Most lights lie on nothing:
        // their search is the plain one.
        let lies_on = self.lights_on(li);
        // Scenes with a table per light look there first (see `crate::point_index`).
        if !lies_on.is_empty() {
            let mut on: arrayvec::ArrayVec<u32, 4> = arrayvec::ArrayVec::new();
            for &(o, n) in lies_on {
                // An object at whose edge or corner the light lies is listed once per face
                // plane there: one outer side is enough.
                if n.dot(origin - light.position) > 0.0
                    && !on.contains(&o)
                    && on.try_push(o).is_err()
                {
                    break;
                }
            }
            if TABLES {
                self.occluded_towards(li, &shadow_ray, end, self_skip, &on)
            } else {
                self.occluded_skipping(&shadow_ray, end, self_skip, &on)
            }
        } else if TABLES {
            self.occluded_towards(li, &shadow_ray, end, self_skip, &[])
        } else {
            self.occluded(&shadow_ray, end, self_skip)
        }
    }

    /// The sample of a primary ray that meets nothing, as [`Self::primary`] returns it: the
    /// background, clamped like every primary sample. What a pixel the footprints know to
    /// be blank takes without tracing (see `Footprints::blank`).
    pub(crate) fn background_sample(&self) -> Sample {
        Sample {
            color: self.background.min(Color::ONE),
            object: Sample::BACKGROUND,
        }
    }

    /// [`Self::primary`], for tests.
    #[cfg(test)]
    pub(crate) fn primary_sample(&self, x: f64, y: f64) -> Sample {
        self.primary::<true>(x, y, &Counters::default())
    }

    /// The clamped radiance of the primary ray through image-plane position `(x, y)`.
    fn primary<const TABLES: bool>(&self, x: f64, y: f64, c: &Counters) -> Sample {
        Counters::bump(&c.primary);
        let ray = self.camera.ray(x, y);
        let (l, object) = self.radiance::<TABLES>(&ray, self.max_depth, None, c);
        Sample {
            color: l.min(Color::ONE),
            object,
        }
    }

    /// Linear pixel values of a rectangle, row-major, with the rays it took.
    pub fn render_rect_linear(&self, rect: Rect) -> (Vec<Color>, RayStats) {
        self.render_rect_linear_with(rect, &self.sampler)
    }

    /// [`Self::render_rect_linear`] with another sampler than the scene's.
    pub fn render_rect_linear_with(&self, rect: Rect, sampler: &Sampler) -> (Vec<Color>, RayStats) {
        self.rect_linear(rect, sampler, || false)
    }

    /// The samples of `rect`, each traced unless `stopped()` says the tile is no longer
    /// wanted, in which case it is the background's black at no cost (the values are then
    /// meaningless, and the caller drops them). `stopped` is a constant `false` for every
    /// render but a worker's, and is then compiled away.
    fn rect_linear(
        &self,
        rect: Rect,
        sampler: &Sampler,
        stopped: impl Fn() -> bool,
    ) -> (Vec<Color>, RayStats) {
        let mut out = Vec::new();
        let stats = self.rect_linear_into(rect, sampler, stopped, &mut out);
        (out, stats)
    }

    /// [`Self::rect_linear`] into `out`, whose allocation is reused (its contents are
    /// replaced).
    fn rect_linear_into(
        &self,
        rect: Rect,
        sampler: &Sampler,
        stopped: impl Fn() -> bool,
        out: &mut Vec<Color>,
    ) -> RayStats {
        self.rect_linear_watched(rect, sampler, stopped, |_, _| {}, out)
    }

    /// [`Self::rect_linear_into`], calling `on_ray` with the image position of every primary
    /// ray traced (a constant no-op for every render but the benchmark's count of rays per
    /// pixel, and then compiled away).
    fn rect_linear_watched(
        &self,
        rect: Rect,
        sampler: &Sampler,
        stopped: impl Fn() -> bool,
        on_ray: impl Fn(f64, f64),
        out: &mut Vec<Color>,
    ) -> RayStats {
        out.clear();
        out.resize(rect.pixel_count(), Color::ZERO);
        // Chosen once per rectangle: the tracing compiled without any look at the eye's and
        // the lights' tables, for scenes that have none, is the plain one (see `radiance`).
        if self.has_point_tables() {
            self.rect_linear_in::<true>(rect, sampler, stopped, on_ray, out)
        } else {
            self.rect_linear_in::<false>(rect, sampler, stopped, on_ray, out)
        }
    }

    /// How many primary rays `sampler` traces in each pixel of `rect`, row-major (the rays
    /// an adaptive render traces around the rect for its decisions are not counted).
    #[cfg(feature = "bench")]
    pub fn primary_rays_per_pixel(&self, rect: Rect, sampler: &Sampler) -> Vec<u32> {
        let counts = vec![std::cell::Cell::new(0u32); rect.pixel_count()];
        let count = |x: f64, y: f64| {
            let (cx, cy) = (x.floor() - f64::from(rect.x), y.floor() - f64::from(rect.y));
            let inside =
                cx >= 0.0 && cy >= 0.0 && cx < f64::from(rect.width) && cy < f64::from(rect.height);
            if inside {
                let c = &counts[cy as usize * rect.width as usize + cx as usize];
                c.set(c.get() + 1);
            }
        };
        self.rect_linear_watched(rect, sampler, || false, count, &mut Vec::new());
        counts
            .into_iter()
            .map(std::cell::Cell::into_inner)
            .collect()
    }

    /// The sRGB bytes of `rect` with the rays they took, unless `stopped()` turns true
    /// meanwhile (then `None`). The rectangle is rendered a band of rows at a time into one
    /// reused buffer of linear values (see [`BAND_PIXELS`]): a pixel's value depends only on
    /// the scene and the pixel, so the bands give the rectangle's very bytes, and a large
    /// rectangle costs 3 bytes a pixel instead of 27. The adaptive sampler renders the
    /// rectangle whole: it looks past each band's edges.
    fn rect_bytes(
        &self,
        rect: Rect,
        sampler: &Sampler,
        stopped: impl Fn() -> bool,
    ) -> Option<(Vec<u8>, RayStats)> {
        let rows = if matches!(sampler, Sampler::Adaptive { .. }) {
            rect.height
        } else {
            (BAND_PIXELS / rect.width.max(1) as usize).clamp(1, rect.height.max(1) as usize) as u32
        };
        let mut bytes = Vec::with_capacity(rect.pixel_count() * 3);
        let mut linear = Vec::new();
        let mut stats = RayStats::default();
        let mut y = rect.y;
        while y < rect.y + rect.height {
            let band = Rect::new(rect.x, y, rect.width, rows.min(rect.y + rect.height - y));
            stats.add(&self.rect_linear_into(band, sampler, &stopped, &mut linear));
            if stopped() {
                return None;
            }
            for &c in &linear {
                bytes.extend_from_slice(&srgb::encode_rgb8(c));
            }
            y += band.height;
        }
        Some((bytes, stats))
    }

    fn rect_linear_in<const TABLES: bool>(
        &self,
        rect: Rect,
        sampler: &Sampler,
        stopped: impl Fn() -> bool,
        on_ray: impl Fn(f64, f64),
        out: &mut [Color],
    ) -> RayStats {
        let counters = Counters::default();
        let trace = |x, y| {
            if stopped() {
                return Sample {
                    color: Color::ZERO,
                    object: Sample::BACKGROUND,
                };
            }
            on_ray(x, y);
            self.primary::<TABLES>(x, y, &counters)
        };
        if matches!(sampler, Sampler::Adaptive { max: 2.., .. }) {
            // The adaptive sampler asks the geometry which pixels may end after one ray and
            // which may hide a solid their first rays missed; which solids may show in each
            // pixel is worked out once for the tile and the border the sampler looks at.
            let border = crate::sampler::PROBE_BORDER;
            let region = PixelRegion {
                x: i64::from(rect.x) - border as i64,
                y: i64::from(rect.y) - border as i64,
                width: rect.width as usize + 2 * border,
                height: rect.height as usize + 2 * border,
            };
            let footprints = Footprints::new(self, region);
            sampler.render_rect_probed(rect, trace, &footprints, out);
        } else {
            sampler.render_rect(rect, trace, out);
        }
        counters.stats()
    }

    /// A high-rate estimate of the exact image over `rect` (`n × n` stratified samples per
    /// pixel, see `crate::sampler::reference_pixel`).
    #[cfg(feature = "bench")]
    pub fn reference_rect(&self, rect: Rect, n: u32) -> (Vec<Color>, RayStats) {
        let counters = Counters::default();
        let trace = |x: f64, y: f64| self.primary::<true>(x, y, &counters);
        let mut out = Vec::with_capacity(rect.pixel_count());
        for y in rect.y..rect.y + rect.height {
            for x in rect.x..rect.x + rect.width {
                out.push(crate::sampler::reference_pixel(x, y, n, &trace));
            }
        }
        (out, counters.stats())
    }

    /// 8-bit sRGB RGB bytes of a rectangle, row-major: what a worker sends for a tile.
    pub fn render_rect(&self, rect: Rect) -> Vec<u8> {
        self.render_rect_stats(rect).0
    }

    /// [`Self::render_rect`] with the rays it took.
    pub fn render_rect_stats(&self, rect: Rect) -> (Vec<u8>, RayStats) {
        self.render_rect_stats_with(rect, &self.sampler)
    }

    /// [`Self::render_rect_stats`] with another sampler than the scene's (a farm job's
    /// override).
    pub fn render_rect_stats_with(&self, rect: Rect, sampler: &Sampler) -> (Vec<u8>, RayStats) {
        // `stopped` is constantly false: there is always a result.
        self.rect_bytes(rect, sampler, || false)
            .unwrap_or_else(|| (Vec::new(), RayStats::default()))
    }

    /// [`Self::render_rect_stats_with`], given up once `stop` is set: the tile's remaining
    /// samples are not traced and `None` is returned. A worker sets it when the tile's lease
    /// is lost (its job cancelled, or the tile handed to another worker), so that its render
    /// thread is free for the next tile within one sample's time rather than the tile's (a
    /// cancelled job's big tile held a worker for a minute).
    pub fn render_rect_stats_until(
        &self,
        rect: Rect,
        sampler: &Sampler,
        stop: &AtomicBool,
    ) -> Option<(Vec<u8>, RayStats)> {
        self.rect_bytes(rect, sampler, || stop.load(Ordering::Relaxed))
    }

    /// Renders the whole image as 8-bit sRGB RGB rows, on the current rayon pool, in tiles of
    /// `tile` pixels. `progress` is called with the number of pixels finished so far.
    pub fn render_image<P>(&self, tile: u32, progress: P) -> (Vec<u8>, RayStats)
    where
        P: Fn(u64) + Sync,
    {
        let (w, h) = (self.width as usize, self.height as usize);
        let done = AtomicU64::new(0);
        let parts: Vec<(Rect, Vec<u8>, RayStats)> = tiles(self.width, self.height, tile)
            .into_par_iter()
            .map(|r| {
                let (bytes, stats) = self.render_rect_stats(r);
                let n = done.fetch_add(r.pixel_count() as u64, Ordering::Relaxed);
                progress(n + r.pixel_count() as u64);
                (r, bytes, stats)
            })
            .collect();
        let mut image = vec![0u8; w * h * 3];
        let mut total = RayStats::default();
        for (r, bytes, stats) in parts {
            total.add(&stats);
            let row_bytes = r.width as usize * 3;
            for (i, row) in bytes.chunks_exact(row_bytes).enumerate() {
                let start = ((r.y as usize + i) * w + r.x as usize) * 3;
                image[start..start + row_bytes].copy_from_slice(row);
            }
        }
        (image, total)
    }
}
