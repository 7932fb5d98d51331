//! Whether a pixel can hold an edge: the geometric tests that let the adaptive sampler end a
//! pixel after its first ray, and make it refine a pixel where a thin solid may hide between
//! its first rays.
//!
//! **What it is for.** A pixel's exact value differs from the radiance of one ray through it
//! only through what changes inside the pixel's square: a solid's silhouette, a plane's
//! horizon, a texture or checker edge, a reflection, a shadow's edge, or the smooth variation
//! of Lambertian shading. [`Footprints::is_smooth`] says "smooth" only when it can rule out
//! all but the last:
//!
//! - the ray saw the background, or a sphere placed by a similarity, or a plane, outside any
//!   CSG tree, with a plain material (no texture, checker or mirror) and no shadow ray to
//!   trace (`shadow = 0`, no diffuse light, or every light known clear of the object by
//!   [`crate::shadow`]);
//! - a sphere it hit fills the whole pixel, a plane it hit has no horizon in it;
//! - no other solid shows in the pixel's square.
//!
//! The last is decided per tile, once, by projecting the solids onto the image
//! ([`Footprints::new`]): a bounded solid's BVH boxes (a long cylinder's slices, see
//! [`Object::pieces`]) are projected by their corners, and every pixel whose square meets
//! the rectangle around them counts the solid; a similarity sphere, a long object's slice
//! and a torus's ring piece (as capsules, [`Object::outline`]) count only in those pixels
//! whose cone around the centre ray (below) meets them; a box reaching behind the eye's plane
//! counts everywhere. Planes are tested per pixel.
//!
//! **Thin solids.** The same projection answers the opposite question,
//! [`Footprints::may_hide`]: may a solid other than the one a pixel's first rays all saw show
//! in its square? A sphere or rod thinner than the first rays' spacing can fall between them
//! and leave them agreeing; the sampler then refines the pixel as if they had disagreed. Only
//! the solids tested pixel by pixel (similarity spheres, long objects' slices and tori's
//! ring pieces as capsules, [`Object::outline`]) are asked about, alone or inside a CSG tree
//! (a tree counts by its rectangle, and its spheres, rods and tori also pixel by pixel under
//! their own numbers, within the tree's box): a box's rectangle is far larger than what it
//! holds, and would send every pixel around a cube to the cap. Sub-pixel features come from
//! small spheres, thin rods and thin tori; other thin solids keep the sampler's colour and
//! neighbour rules alone.
//!
//! **Cones.** Every ray through a pixel's square lies within [`crate::camera::Camera::pixel_angle`]
//! of any other, so within the cone of that half-angle around any one of them, and within
//! [`crate::camera::Camera::pixel_angle_from_centre`] of the ray through its centre. A sphere of
//! radius `r` at distance `d` fills the directions within `α = asin(r/d)` of its centre: the
//! cone meets it when `θ ≤ α + φ` and lies inside it when `θ + φ ≤ α` (`θ` the angle from the
//! cone's axis to the centre, `φ` the half-angle). These are compared as sines (`sin θ` from a
//! cross product, exact to a few ulps even for the tiny angles of a pixel, where `acos` of a
//! dot product would lose half the digits); a plane is compared by the angle of the cone's
//! axis to its normal. The half-angle is widened by 1e-6 of itself and every comparison
//! keeps a margin of [`ANGLE_MARGIN`], and boxes are the BVH's padded ones, which dwarfs the
//! rounding of these tests and of the renderer's own intersections.
//!
//! **What it is not.** It ignores occlusion (a solid hidden behind another still counts),
//! and a non-spherical solid's rectangle is not its silhouette: it errs towards "may hold an
//! edge", which only costs rays. It says nothing about how many rays a pixel with an edge
//! needs; the sampler decides that.

use std::ops::Range;

use glam::DVec3;

use crate::bvh;
use crate::csg::Prim;
use crate::math::Aabb;
use crate::sampler::{Sample, UnseenPattern};
use crate::shape::Shape;
use crate::world::{Object, Scene};

/// Radians every angular comparison keeps to spare (see the module comment). A pixel of a
/// 7680-pixel-wide image at a 1° field of view still spans 2e-6 radians, 2,000 times this.
pub const ANGLE_MARGIN: f64 = 1e-9;

/// A cone's half-angle with what its tests need of it, computed once per tile.
#[derive(Debug, Clone, Copy)]
pub struct Aperture {
    /// The half-angle, widened as the module comment says.
    half_angle: f64,
    sin: f64,
    cos: f64,
}

impl Aperture {
    /// The aperture of half-angle `half_angle`, widened as the module comment says.
    pub fn new(half_angle: f64) -> Aperture {
        let half_angle = half_angle * (1.0 + 1e-6) + ANGLE_MARGIN;
        Aperture {
            half_angle,
            sin: half_angle.sin(),
            cos: half_angle.cos(),
        }
    }
}

/// The cone from `origin` around the unit direction `axis`.
#[derive(Debug, Clone, Copy)]
pub struct Cone {
    origin: DVec3,
    axis: DVec3,
    aperture: Aperture,
}

/// How a cone meets a plane.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PlaneView {
    /// No direction of the cone reaches the plane.
    Misses,
    /// Some do, some do not: the horizon is inside the cone.
    Horizon,
    /// Every direction reaches it.
    Covers,
}

impl Cone {
    /// The cone of `aperture` from `origin` around the unit direction `axis`.
    pub fn new(origin: DVec3, axis: DVec3, aperture: Aperture) -> Cone {
        Cone {
            origin,
            axis,
            aperture,
        }
    }

    /// Whether some direction of the cone meets the ball of centre `c` and radius `r`.
    pub fn meets_sphere(&self, c: DVec3, r: f64) -> bool {
        // From inside (or on) the ball every direction meets it; NaN lands here too.
        let Some(seen) = self.sphere_seen(c, r) else {
            return true;
        };
        let ap = &self.aperture;
        // β = α + φ + margin; as sines only while β stays well below 90°.
        let sin_b0 = seen.sin_a * ap.cos + seen.cos_a * ap.sin;
        let cos_b0 = seen.cos_a * ap.cos - seen.sin_a * ap.sin;
        let sin_b = sin_b0 * MARGIN_COS + cos_b0 * MARGIN_SIN;
        if !(sin_b < 0.9) {
            let alpha = seen.sin_a.asin();
            return angle_between(self.axis, seen.v) <= alpha + ap.half_angle + ANGLE_MARGIN;
        }
        seen.within(self.axis, sin_b)
    }

    /// Whether every direction of the cone meets the ball of centre `c` and radius `r`, the
    /// origin being outside it.
    pub fn inside_sphere(&self, c: DVec3, r: f64) -> bool {
        let Some(seen) = self.sphere_seen(c, r) else {
            return false;
        };
        let ap = &self.aperture;
        // γ = α − φ − margin, which must be positive; below 90° since α is.
        let sin_g0 = seen.sin_a * ap.cos - seen.cos_a * ap.sin;
        let cos_g0 = seen.cos_a * ap.cos + seen.sin_a * ap.sin;
        let sin_g = sin_g0 * MARGIN_COS - cos_g0 * MARGIN_SIN;
        sin_g > 0.0 && seen.within(self.axis, sin_g)
    }

    /// The ball of centre `c` and radius `r` as seen from the origin: `None` from inside it
    /// (or for NaN).
    fn sphere_seen(&self, c: DVec3, r: f64) -> Option<SphereSeen> {
        let v = c - self.origin;
        let d2 = v.length_squared();
        if !(d2 > r * r) {
            return None;
        }
        let d = d2.sqrt();
        let sin_a = r / d;
        Some(SphereSeen {
            v,
            d,
            sin_a,
            cos_a: (1.0 - sin_a * sin_a).max(0.0).sqrt(),
        })
    }

    /// Whether the cone may meet the capsule of radius `r` around the segment from `a` to
    /// `b`: unless the segment's distance from the axis exceeds `r` by more than the cone's
    /// radius at the capsule's farthest point (a point of the capsule in the cone would be
    /// within that radius of the axis, and it is within `r` of the segment). The distance is
    /// that of the closest points of the segment and the axis up to that farthest distance,
    /// which holds the axis points nearest to every point of the capsule (Ericson, *Real-Time
    /// Collision Detection*, 5.1.9); the comparison keeps 1e-9 of that distance to spare.
    pub fn may_meet_capsule(&self, a: DVec3, b: DVec3, r: f64) -> bool {
        let far = (a - self.origin).length().max((b - self.origin).length()) + r;
        let d1 = self.axis * far;
        let d2 = b - a;
        let w = self.origin - a;
        let (aa, ee, ff) = (d1.dot(d1), d2.dot(d2), d2.dot(w));
        let c = d1.dot(w);
        let (s, t) = if ee <= f64::MIN_POSITIVE {
            ((-c / aa).clamp(0.0, 1.0), 0.0)
        } else {
            let bb = d1.dot(d2);
            let denom = aa * ee - bb * bb;
            let mut s = if denom > 0.0 {
                ((bb * ff - c * ee) / denom).clamp(0.0, 1.0)
            } else {
                0.0
            };
            let mut t = (bb * s + ff) / ee;
            if t < 0.0 {
                t = 0.0;
                s = (-c / aa).clamp(0.0, 1.0);
            } else if t > 1.0 {
                t = 1.0;
                s = ((bb - c) / aa).clamp(0.0, 1.0);
            }
            (s, t)
        };
        let gap = ((self.origin + d1 * s) - (a + d2 * t)).length();
        let width = self.aperture.half_angle.tan() * far;
        // NaN anywhere: "may".
        !(gap - r > width + 1e-9 * far)
    }

    /// How the cone meets the plane through `p0` with normal `n` (any length).
    pub fn view_of_plane(&self, p0: DVec3, n: DVec3) -> PlaneView {
        let h = (self.origin - p0).dot(n);
        if !(h != 0.0) || !n.is_finite() {
            return PlaneView::Horizon;
        }
        // The direction straight towards the plane, and the cone axis's angle from it: a
        // direction reaches the plane exactly when that angle is below 90°.
        let towards = if h > 0.0 { -n } else { n };
        let beta = angle_between(self.axis, towards);
        let right = std::f64::consts::FRAC_PI_2;
        let phi = self.aperture.half_angle;
        if beta + phi <= right - ANGLE_MARGIN {
            PlaneView::Covers
        } else if beta - phi >= right + ANGLE_MARGIN {
            PlaneView::Misses
        } else {
            PlaneView::Horizon
        }
    }
}

/// A ball seen from a cone's origin: the direction `v` and distance `d` to its centre, and
/// the sine and cosine of the angle `α` it fills around that direction.
struct SphereSeen {
    v: DVec3,
    d: f64,
    sin_a: f64,
    cos_a: f64,
}

impl SphereSeen {
    /// Whether the angle from unit `axis` to the centre is below 90° and has sine at most
    /// `sin` (`|axis × v| = d·sin θ`, exact to a few ulps even for tiny angles).
    fn within(&self, axis: DVec3, sin: f64) -> bool {
        axis.dot(self.v) > 0.0 && axis.cross(self.v).length() <= sin * self.d
    }
}

/// `sin` and `cos` of [`ANGLE_MARGIN`] (its sine is itself to 17 digits, its cosine 1).
const MARGIN_SIN: f64 = ANGLE_MARGIN;
const MARGIN_COS: f64 = 1.0;

/// The angle between two non-zero vectors, to a few ulps at any size (`atan2` of the cross
/// and dot products).
fn angle_between(a: DVec3, b: DVec3) -> f64 {
    a.cross(b).length().atan2(a.dot(b))
}

/// A rectangle of pixels (it may reach outside the image: the adaptive sampler looks at a
/// border around each tile).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PixelRegion {
    pub x: i64,
    pub y: i64,
    pub width: usize,
    pub height: usize,
}

/// Which solids may show in each pixel of a region, for [`Footprints::is_smooth`] and
/// [`Footprints::may_hide`].
#[derive(Debug, Clone)]
pub struct Footprints<'s> {
    scene: &'s Scene,
    region: PixelRegion,
    /// Around any ray through a pixel, and around the ray through its centre.
    aperture: Aperture,
    centre_aperture: Aperture,
    /// Per pixel, row-major: [`NOTHING`], the one solid that may show in it, or
    /// [`SEVERAL`].
    shown: Vec<u32>,
    /// Per pixel, as `shown`, but only the solids whose footprint is tested pixel by pixel
    /// (spheres, and long rods and tori piece by piece, in a CSG tree or not): what
    /// [`Footprints::may_hide`] answers from.
    fitted: Vec<u32>,
    /// The planes (world point, normal, object), tested per pixel.
    planes: Vec<(DVec3, DVec3, u32)>,
}

/// A pixel no solid may show in.
const NOTHING: u32 = u32::MAX;
/// A pixel more than one solid may show in.
const SEVERAL: u32 = u32::MAX - 1;
/// The object number a CSG tree counts under: never a hit's object (those are the tree's
/// children, and a child is never plain anyway). Object numbers stay below all three: a
/// scene holds at most `Limits::max_objects` objects (a million by default), and the
/// renderer numbers them in `u32` with `u32::MAX` meaning the background.
const CSG: u32 = u32::MAX - 2;

/// Counts solid `id` in a pixel's record: [`NOTHING`] → `id` → [`SEVERAL`].
#[inline]
fn count(record: &mut u32, id: u32) {
    if *record == NOTHING {
        *record = id;
    } else if *record != id {
        *record = SEVERAL;
    }
}

/// Where a box's projection lies.
enum Projection {
    /// Wholly behind the eye's plane: no primary ray reaches it.
    Behind,
    /// Within `[x0, y0, x1, y1]` (image positions, pixels).
    Within([f64; 4]),
    /// Reaching across the eye's plane (or not finite): anywhere.
    Anywhere,
}

impl<'s> Footprints<'s> {
    /// Which solids may show in each pixel of `region` (see the module comment).
    pub fn new(scene: &'s Scene, region: PixelRegion) -> Footprints<'s> {
        let n = region.width * region.height;
        let mut fp = Footprints {
            scene,
            region,
            aperture: Aperture::new(scene.camera.pixel_angle()),
            centre_aperture: Aperture::new(scene.camera.pixel_angle_from_centre()),
            shown: vec![NOTHING; n],
            fitted: vec![NOTHING; n],
            planes: Vec::new(),
        };
        // The prims that may show in the region: every prim, or those the BVH finds whose
        // boxes' projections meet it, with the ones it leaves out.
        let prims: Vec<u32> = match scene.bvh_and_unbounded() {
            None => (0..scene.prims.len() as u32).collect(),
            Some((tree, unbounded)) => {
                let mut found = unbounded.to_vec();
                tree.any_item(
                    |b| match fp.project_box(b) {
                        Projection::Behind => false,
                        Projection::Within(r) => fp.rect_meets_region(r),
                        Projection::Anywhere => true,
                    },
                    |pi| {
                        found.push(pi);
                        false
                    },
                );
                found.sort_unstable();
                found.dedup();
                found
            }
        };
        for pi in prims {
            fp.add_prim(pi);
        }
        fp
    }

    /// Counts prim `pi` in the pixels it may show in.
    fn add_prim(&mut self, pi: u32) {
        let scene = self.scene;
        let (id, boxes) = match &scene.prims[pi as usize] {
            Prim::Object(o) => {
                let obj = &scene.objects[*o as usize];
                if matches!(obj.shape, Shape::Plane) {
                    let (p0, n) = plane_of(obj);
                    self.planes.push((p0, n, *o));
                    return;
                }
                if self.add_fitted(*o, None) {
                    return;
                }
                (*o, obj.bounds.into_iter().collect::<Vec<Aabb>>())
            }
            Prim::Csg(c) => {
                // The tree counts in its rectangle; its spheres, rods and tori also count
                // pixel by pixel under their own numbers, so that `may_hide` knows of them
                // (a child can only show within the tree's box, when it has one).
                self.add_leaves(c, c.bounds.as_ref());
                (CSG, c.bounds.into_iter().collect())
            }
        };
        if boxes.is_empty() {
            // Unbounded: anywhere.
            self.mark_all(id);
        }
        for b in boxes {
            match bvh::padded(&b).map(|p| self.project_box(&p)) {
                Some(Projection::Behind) => {}
                Some(Projection::Within(r)) => self.mark_rect(id, r),
                _ => self.mark_all(id),
            }
        }
    }

    /// Where the box's projection lies: the bounds of its corners' projections, widened by
    /// 1e-9 of their size and a millionth of a pixel against the projection's rounding.
    fn project_box(&self, b: &Aabb) -> Projection {
        let cam = &self.scene.camera;
        let mut r = [
            f64::INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NEG_INFINITY,
        ];
        let mut behind = 0;
        for i in 0..8 {
            let corner = DVec3::new(
                if i & 1 == 0 { b.min.x } else { b.max.x },
                if i & 2 == 0 { b.min.y } else { b.max.y },
                if i & 4 == 0 { b.min.z } else { b.max.z },
            );
            match cam.project(corner) {
                Some((x, y)) if x.is_finite() && y.is_finite() => {
                    r = [r[0].min(x), r[1].min(y), r[2].max(x), r[3].max(y)];
                }
                Some(_) => return Projection::Anywhere,
                None => behind += 1,
            }
        }
        match behind {
            // Every corner at depth ≤ 0 puts the whole (convex) box there.
            8 => Projection::Behind,
            0 => {
                let pad = |v: f64| 1e-6 + 1e-9 * v.abs();
                Projection::Within([
                    r[0] - pad(r[0]),
                    r[1] - pad(r[1]),
                    r[2] + pad(r[2]),
                    r[3] + pad(r[3]),
                ])
            }
            _ => Projection::Anywhere,
        }
    }

    /// The region's pixels (columns, rows) whose squares meet the rectangle: pixel `p`'s
    /// square `[p, p + 1]` meets `[lo, hi]` when `p ≤ hi` and `p + 1 ≥ lo`.
    fn pixels_of(&self, [x0, y0, x1, y1]: [f64; 4]) -> (Range<usize>, Range<usize>) {
        let span = |lo: f64, hi: f64, start: i64, len: usize| {
            // Clamped in f64 first, so that huge or infinite bounds convert exactly.
            let end = (start + len as i64) as f64;
            let first = (lo - 1.0).ceil().clamp(start as f64, end);
            let last = (hi.floor() + 1.0).clamp(start as f64, end);
            if !(first < last) {
                return 0..0;
            }
            (first as i64 - start) as usize..(last as i64 - start) as usize
        };
        let reg = self.region;
        (
            span(x0, x1, reg.x, reg.width),
            span(y0, y1, reg.y, reg.height),
        )
    }

    fn rect_meets_region(&self, r: [f64; 4]) -> bool {
        let (xs, ys) = self.pixels_of(r);
        !xs.is_empty() && !ys.is_empty()
    }

    /// Counts `id` in every pixel of the region whose square meets the rectangle.
    fn mark_rect(&mut self, id: u32, r: [f64; 4]) {
        let (xs, ys) = self.pixels_of(r);
        for row in ys {
            for col in xs.clone() {
                self.mark(row * self.region.width + col, id);
            }
        }
    }

    fn mark_all(&mut self, id: u32) {
        for i in 0..self.shown.len() {
            self.mark(i, id);
        }
    }

    /// Counts object `o` pixel by pixel if it is a similarity sphere, or has capsules that
    /// hold it (a long rod's slices, a torus's ring, see [`Object::outline`]); `clip`, when
    /// given, is a box outside which it cannot show (its CSG tree's). Returns false for
    /// other shapes, which count by their rectangles.
    fn add_fitted(&mut self, o: u32, clip: Option<&Aabb>) -> bool {
        let obj = &self.scene.objects[o as usize];
        // Boxes clipped to `clip`; an empty one (nothing of the object can show) is skipped,
        // since `add_where` takes a box it cannot pad for "anywhere".
        let clipped = |b: Aabb| match clip {
            None => Some(b),
            Some(c) => {
                let b = Aabb::new(b.min.max(c.min), b.max.min(c.max));
                (!b.is_empty()).then_some(b)
            }
        };
        if let Some((c, r2)) = obj.similarity_sphere() {
            let r = r2.sqrt();
            let b = Aabb::new(c - DVec3::splat(r), c + DVec3::splat(r));
            if let Some(b) = clipped(b) {
                self.add_where(o, &b, |cone| cone.meets_sphere(c, r));
            }
            return true;
        }
        let pieces = obj.outline();
        if pieces.is_empty() {
            return false;
        }
        for p in pieces {
            let (a, e) = p.axis;
            if let Some(b) = clipped(p.bounds) {
                self.add_where(o, &b, |cone| cone.may_meet_capsule(a, e, p.radius));
            }
        }
        true
    }

    /// Counts the fitted leaves of a CSG tree ([`Self::add_fitted`]) within its box `clip`
    /// (none for an unbounded tree), visiting only the children whose boxes may project
    /// into the region (through the tree's index, when it has one: a union of thousands of
    /// spheres is not projected child by child for every tile).
    fn add_leaves(&mut self, c: &crate::csg::Csg, clip: Option<&Aabb>) {
        let mut found: Vec<&Prim> = Vec::new();
        c.children_near(
            |b| match self.project_box(b) {
                Projection::Behind => false,
                Projection::Within(r) => self.rect_meets_region(r),
                Projection::Anywhere => true,
            },
            |child| found.push(child),
        );
        for child in found {
            match child {
                Prim::Object(o) => {
                    self.add_fitted(*o, clip);
                }
                Prim::Csg(inner) => self.add_leaves(inner, clip),
            }
        }
    }

    /// Counts `id` in the pixels of the rectangle of box `b` where `meets` holds for the
    /// cone around the ray through the pixel's centre.
    fn add_where(&mut self, id: u32, b: &Aabb, meets: impl Fn(&Cone) -> bool) {
        let rect = match bvh::padded(b).map(|p| self.project_box(&p)) {
            Some(Projection::Behind) => return,
            Some(Projection::Within(rect)) => rect,
            _ => [
                f64::NEG_INFINITY,
                f64::NEG_INFINITY,
                f64::INFINITY,
                f64::INFINITY,
            ],
        };
        let (xs, ys) = self.pixels_of(rect);
        let reg = self.region;
        for row in ys {
            for col in xs.clone() {
                let (px, py) = (reg.x + col as i64, reg.y + row as i64);
                let ray = self.scene.camera.ray(px as f64 + 0.5, py as f64 + 0.5);
                if meets(&Cone::new(ray.origin, ray.dir, self.centre_aperture)) {
                    let i = row * reg.width + col;
                    self.mark(i, id);
                    count(&mut self.fitted[i], id);
                }
            }
        }
    }

    #[inline]
    fn mark(&mut self, i: usize, id: u32) {
        count(&mut self.shown[i], id);
    }

    /// Whether a similarity sphere, a long object's slice or a torus's ring piece other than
    /// `object` (a hit's object, or [`Sample::BACKGROUND`]) may show in pixel `(px, py)`'s
    /// square: its cone
    /// around the centre ray meets one. Pixels outside the region: no.
    pub fn may_hide(&self, px: i64, py: i64, object: u32) -> bool {
        self.index(px, py)
            .is_some_and(|i| self.fitted[i] != NOTHING && self.fitted[i] != object)
    }

    /// What an edge of `object`'s checker can hide in pixel `(px, py)`'s square on a side
    /// that none of the rays through image positions `seen` (rays that all saw `object`) fell
    /// on: the step between the two colours there ([`Scene::checker_step`]'s bound) and how
    /// many cell edges may cross the square (see `cell_edges`; unknown where a corner's ray
    /// misses the plane). `None` where the square lies in one cell, where those rays met
    /// cells of both colours, or for anything but a checkered plane without a texture. A ray
    /// within rounding of a cell's edge tells no side. Asked of any pixel, inside the region
    /// or not (the answer depends on the pixel alone). Never below the truth.
    pub fn unseen_pattern(
        &self,
        px: i64,
        py: i64,
        object: u32,
        seen: &[(f64, f64)],
    ) -> Option<UnseenPattern> {
        let obj = self.scene.objects.get(object as usize)?;
        if obj.material.texture.is_some() || !matches!(obj.shape, Shape::Plane) {
            return None;
        }
        let step = self.scene.checker_step(obj);
        if step == 0.0 {
            return None;
        }
        let edges = cell_edges(self.scene, obj, px, py);
        if edges == Some(0) {
            return None;
        }
        let mut parity = None;
        for &(x, y) in seen {
            if let Some(p) = cell_parity(self.scene, obj, x, y) {
                if parity.is_some_and(|q| q != p) {
                    return None;
                }
                parity = Some(p);
            }
        }
        Some(UnseenPattern { step, edges })
    }

    /// Pixel `(px, py)`'s place in the per-pixel records; `None` outside the region.
    fn index(&self, px: i64, py: i64) -> Option<usize> {
        let reg = self.region;
        let (cx, cy) = (px - reg.x, py - reg.y);
        let inside = cx >= 0 && cy >= 0 && cx < reg.width as i64 && cy < reg.height as i64;
        inside.then(|| cy as usize * reg.width + cx as usize)
    }

    /// Whether pixel `(px, py)`, where the primary ray through image position `(x, y)` (a
    /// point of that pixel) saw `seen`, is known to hold no edge, texture, reflection or
    /// shadow edge: its exact value then differs from that ray's only by smooth shading.
    /// Pixels outside the region are never known smooth.
    pub fn is_smooth(&self, px: i64, py: i64, x: f64, y: f64, seen: &Sample) -> bool {
        self.shows_alone(px, py, x, y, seen.object, true)
    }

    /// [`Footprints::is_smooth`] but for a checker's cells: whether pixel `(px, py)`, where
    /// the primary ray through `(x, y)` saw `object`, holds no edge, texture, reflection or
    /// shadow edge other than the edges between a checkered plane's cells, which
    /// [`Footprints::unseen_pattern`] bounds. A step between it and a neighbour that neither
    /// saw is then a cell edge, in the neighbour unless the pattern puts one here.
    pub fn pattern_alone(&self, px: i64, py: i64, x: f64, y: f64, object: u32) -> bool {
        self.shows_alone(px, py, x, y, object, false)
    }

    /// [`Footprints::is_smooth`], with a checker's cell edges allowed unless `one_cell`.
    fn shows_alone(
        &self,
        px: i64,
        py: i64,
        x: f64,
        y: f64,
        object: u32,
        one_cell_too: bool,
    ) -> bool {
        let Some(i) = self.index(px, py) else {
            return false;
        };
        let hit = (object != Sample::BACKGROUND).then_some(object);
        let alone = match self.shown[i] {
            NOTHING => true,
            SEVERAL => false,
            one => Some(one) == hit,
        };
        if !alone || hit.is_some_and(|o| !self.scene.plain(o)) {
            return false;
        }
        let ray = self.scene.camera.ray(x, y);
        let cone = Cone::new(ray.origin, ray.dir, self.aperture);
        if let Some(o) = hit {
            let obj = &self.scene.objects[o as usize];
            if !covers(obj, &cone)
                || (one_cell_too
                    && obj.material.color2.is_some()
                    && !one_cell(self.scene, obj, px, py))
            {
                return false;
            }
        }
        self.planes
            .iter()
            .all(|&(p0, n, o)| Some(o) == hit || cone.view_of_plane(p0, n) == PlaneView::Misses)
    }
}

impl Scene {
    /// An upper bound on how far apart a checkered plane's two colours can shade at any
    /// point a primary ray meets it, in the channel where they are farthest apart, after
    /// clamping: `|c1 − c2| · (1 − mirror) · (ambient + diffuse · Σ colour)` over the lights
    /// on the eye's side of the plane, at most 1. Every point of a whole plane that any ray
    /// from the eye reaches, by mirrors or not, faces the eye's side (a ray cannot cross the
    /// plane without meeting it), and a light on the other side lights none of them
    /// (`n · l ≤ 0`); shadows only lower the sum. The mirrored part is the same for both
    /// colours unless the mirrored ray can come back to the plane by another mirror: then the
    /// difference `D` along any ray obeys `D ≤ (1 − m) S + m D`, so `D ≤ S`, and the factor
    /// `1 − mirror` is dropped; and for a plane in a CSG tree, whose gaps let a returning ray
    /// meet it from the other side, every light counts. 0 for an object without a checker,
    /// or whose colours are the same.
    pub fn checker_step(&self, obj: &Object) -> f64 {
        let m = &obj.material;
        let Some(c2) = m.color2 else {
            return 0.0;
        };
        // Whether a ray the plane mirrors can come back to it (by another mirror).
        let returns = m.mirror > 0.0 && self.mirrors > 1;
        let (p0, n) = plane_of(obj);
        let eye = self.camera.ray(0.0, 0.0).origin;
        let side = n.dot(eye - p0);
        let mut light = self.ambient;
        for l in &self.lights {
            let d = l.position - p0;
            // Lights on the plane, within rounding, or an eye on it: counted.
            let margin = 1e-9 * (1.0 + d.length() + (eye - p0).length());
            let eye_side = side.abs() <= margin || n.dot(d) * side.signum() > -margin;
            if eye_side || (returns && obj.in_csg) {
                light += l.color * m.diffuse;
            }
        }
        let kept = if returns { 1.0 } else { 1.0 - m.mirror };
        let step = (m.color1 - c2).abs() * light * kept;
        step.max_element().min(1.0)
    }

    /// Whether object `o` shades smoothly: a sphere placed by a similarity or a plane,
    /// outside any CSG tree, plain (no texture or mirror, a checker only on a plane), with
    /// no shadow ray to trace.
    fn plain(&self, o: u32) -> bool {
        let obj = &self.objects[o as usize];
        let m = &obj.material;
        let shape_ok = match obj.shape {
            Shape::Sphere => obj.similarity_sphere().is_some(),
            Shape::Plane => true,
            _ => false,
        };
        // A checker only on a plane, where `one_cell` can tell whether a pixel crosses it.
        let checker_ok = m.color2.is_none() || matches!(obj.shape, Shape::Plane);
        if !shape_ok || !checker_ok || obj.in_csg || m.texture.is_some() || m.mirror > 0.0 {
            return false;
        }
        // A sphere seen from outside (`covers` requires it) and a plane are left without
        // re-hitting themselves, so their shadow rays skip them, as `crate::shadow` assumes.
        let n = self.lights.len();
        let all_clear = n <= 64 && self.clear_lights(o) == u64::MAX >> (64 - n.max(1));
        let traces_shadows = self.shadow > 0.0 && m.diffuse > 0.0 && self.anything_else(Some(o));
        n == 0 || !traces_shadows || all_clear
    }
}

impl crate::sampler::PixelGeometry for Footprints<'_> {
    fn is_smooth(&self, px: i64, py: i64, x: f64, y: f64, seen: &Sample) -> bool {
        Footprints::is_smooth(self, px, py, x, y, seen)
    }

    fn may_hide(&self, px: i64, py: i64, object: u32) -> bool {
        Footprints::may_hide(self, px, py, object)
    }

    fn pattern_alone(&self, px: i64, py: i64, x: f64, y: f64, object: u32) -> bool {
        Footprints::pattern_alone(self, px, py, x, y, object)
    }

    fn unseen_pattern(
        &self,
        px: i64,
        py: i64,
        object: u32,
        seen: &[(f64, f64)],
    ) -> Option<UnseenPattern> {
        Footprints::unseen_pattern(self, px, py, object, seen)
    }
}

/// Whether every direction of the cone meets `obj` (a similarity sphere or a plane).
fn covers(obj: &Object, cone: &Cone) -> bool {
    match (obj.shape, obj.similarity_sphere()) {
        (Shape::Sphere, Some((c, r2))) => cone.inside_sphere(c, r2.sqrt()),
        (Shape::Plane, _) => {
            let (p0, n) = plane_of(obj);
            cone.view_of_plane(p0, n) == PlaneView::Covers
        }
        _ => false,
    }
}

/// Whether pixel `(px, py)`'s square, on checkered plane `obj` (which its every ray meets:
/// `covers`), lies in one checker cell.
///
/// The rays through the square's corners meet the plane at the corners of the square's
/// image, a convex quadrilateral (a projective map takes the square to the convex hull of
/// its corners' images while no ray of it is parallel to the plane). The cells are the unit
/// squares of the plane's own `x`, `z` (its `y` is 0 on every hit), so the pixel sees one
/// cell when the corners' bounds, widened by 1e-9 of their magnitude (against the rounding
/// of these intersections and of the renderer's), fit between the same integers.
fn one_cell(scene: &Scene, obj: &Object, px: i64, py: i64) -> bool {
    cell_edges(scene, obj, px, py) == Some(0)
}

/// How many lines between cells (`x` or `z` an integer) may cross pixel `(px, py)`'s square
/// on checkered plane `obj`: those between the bounds of its corners' images, widened as in
/// [`one_cell`]; `None` where a corner's ray misses the plane (the square may then hold the
/// horizon, and any number). Each such line is straight in the image too (a projective map
/// keeps lines), so it passes through at most `2m − 1` cells of an `m × m` grid over the
/// square.
fn cell_edges(scene: &Scene, obj: &Object, px: i64, py: i64) -> Option<u32> {
    let (mut lo, mut hi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
    for (dx, dy) in [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0)] {
        let p = plane_point(scene, obj, px as f64 + dx, py as f64 + dy)?;
        lo = lo.min(p);
        hi = hi.max(p);
    }
    let pad = 1e-9 * (1.0 + lo.abs().max(hi.abs()).max_element());
    // Floors of huge coordinates saturate; so does the count.
    let lines = |a: f64, b: f64| ((b + pad).floor() - (a - pad).floor()).clamp(0.0, 1e9) as u32;
    Some(lines(lo.x, hi.x).saturating_add(lines(lo.z, hi.z)))
}

/// Which colour of checkered plane `obj` the primary ray through image position `(x, y)`
/// meets (`false`: `color1`), as the shader picks it from the hit's own coordinates; `None`
/// where the ray misses the plane or meets it within 1e-9 of a cell's edge (relative to the
/// coordinates' magnitude: the shader's own hit may round to the other side there).
fn cell_parity(scene: &Scene, obj: &Object, x: f64, y: f64) -> Option<bool> {
    let p = plane_point(scene, obj, x, y)?;
    let pad = 1e-9 * (1.0 + p.x.abs().max(p.z.abs()));
    let clear = |v: f64| v - v.floor() > pad && v.ceil() - v > pad;
    (clear(p.x) && clear(p.z))
        .then(|| (p.x.floor() as i64).wrapping_add(p.z.floor() as i64) & 1 != 0)
}

/// Where the primary ray through image position `(x, y)` meets plane `obj`, in the plane's
/// own coordinates scaled to its checker's unit cells (`y` is 0); `None` where it misses.
fn plane_point(scene: &Scene, obj: &Object, x: f64, y: f64) -> Option<DVec3> {
    let ray = obj.transform.ray_to_object(&scene.camera.ray(x, y));
    let t = -ray.origin.y / ray.dir.y;
    (t > 0.0 && t.is_finite()).then(|| ray.at(t) * obj.own_scale)
}

/// A plane object's world point and normal.
fn plane_of(obj: &Object) -> (DVec3, DVec3) {
    let (p0, _) = obj.transform.point_to_world(DVec3::ZERO, DVec3::ZERO);
    (p0, obj.transform.normal_to_world(DVec3::Y))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scene(src: &str) -> Scene {
        Scene::from_source(
            src,
            &crate::Limits::default(),
            &crate::texture::MemoryAssets::new(),
            &crate::texture::TextureLimits::default(),
        )
        .unwrap_or_else(|e| panic!("test scene does not build: {e}"))
    }

    /// A checker plane at y = 0, white and `color2`, ambient 0.2, one light of colour 1.5
    /// above it at y = 5, seen from `eye`, with `extra` material keys.
    fn lit_checker(eye: &str, color2: f64, extra: &str) -> Scene {
        scene(&format!(
            "[GLOBALS]\nwidth = 32\nheight = 24\nambient = 0.2\n[/GLOBALS]\n\
             [CAMERA]\neye = {eye}\nlook_at = <0, 0, 0>\n[/CAMERA]\n\
             [LIGHT]\nposition = <1, 5, 2>\ncolor = 1.5\n[/LIGHT]\n\
             [OBJECT]\ntype = plane\ncolor1 = 1\ncolor2 = {color2}\n{extra}[/OBJECT]\n"
        ))
    }

    /// The step between the two colours, worked out by hand from the shading formula: the
    /// light counts only on the eye's side (from below, the points seen face away from it),
    /// a mirror keeps its share of the difference, equal colours make none, and clamping
    /// caps it at 1.
    #[test]
    fn a_checker_s_step_counts_the_lights_on_the_eye_s_side_only() {
        let step = |eye: &str, extra: &str| {
            let s = lit_checker(eye, 0.25, extra);
            s.checker_step(&s.objects[0])
        };
        let close = |a: f64, b: f64| (a - b).abs() < 1e-12;
        assert!(close(step("<0, 3, 6>", ""), 1.0), "0.75 · 1.7, clamped");
        assert!(close(step("<0, -3, 6>", ""), 0.75 * 0.2));
        assert!(close(
            step("<0, 3, 6>", "diffuse = 0.2\n"),
            0.75 * (0.2 + 0.3)
        ));
        assert!(close(
            step("<0, 3, 6>", "diffuse = 0.2\nmirror = 0.5\n"),
            0.75 * 0.5 * 0.5
        ));
        let same = lit_checker("<0, 3, 6>", 1.0, "");
        assert_eq!(same.checker_step(&same.objects[0]), 0.0);
        // A plane turned upside down (its normal −y): the eye's side is still the one lit.
        assert!(close(
            step("<0, 3, 6>", "diffuse = 0.2\nrotate = <180, 0, 0>\n"),
            0.75 * 0.5
        ));
    }

    /// Rays that met cells of both colours leave no side unseen; rays all in one colour
    /// leave the other, where the square crosses an edge; a square inside one cell has none.
    #[test]
    fn the_unseen_step_is_the_side_no_first_ray_met() {
        // Seen straight down, 20 units of the plane over the image's 24 rows, so a cell (2
        // units) is 2.4 pixels wide, with the eye above a cell's corner at the image's
        // centre (16, 12): cells meet at x = 13.6 and 16, y = 9.6 and 12. Pixel (13, 10)
        // crosses the edge x = 13.6 alone, pixel (14, 10) lies inside one cell.
        let s = scene(
            "[GLOBALS]\nwidth = 32\nheight = 24\nambient = 1\n[/GLOBALS]\n\
             [CAMERA]\neye = <0, 10, 0>\nlook_at = <0, 0, 0>\nup = <0, 0, -1>\nfov = 90\n[/CAMERA]\n\
             [OBJECT]\ntype = plane\ncolor1 = 1\ncolor2 = 0\nscale = 2\n[/OBJECT]\n",
        );
        let fp = Footprints::new(
            &s,
            PixelRegion {
                x: 0,
                y: 0,
                width: 32,
                height: 24,
            },
        );
        let (a, b) = ((13.9, 10.5), (13.1, 10.5));
        let parity = |(x, y): (f64, f64)| cell_parity(&s, &s.objects[0], x, y);
        assert!(parity(a).is_some() && parity(b).is_some() && parity(a) != parity(b));
        let one_edge = Some(UnseenPattern {
            step: 1.0,
            edges: Some(1),
        });
        assert_eq!(fp.unseen_pattern(13, 10, 0, &[b, b, b, b]), one_edge);
        assert_eq!(fp.unseen_pattern(13, 10, 0, &[a, a, a, a]), one_edge);
        assert_eq!(fp.unseen_pattern(13, 10, 0, &[b, b, a, b]), None);
        assert_eq!(fp.unseen_pattern(14, 10, 0, &[(14.5, 10.5); 4]), None);
        // Pixel (13, 9) holds a corner: the edges x = 13.6 and y = 9.6.
        let corner = fp.unseen_pattern(13, 9, 0, &[(13.1, 9.1); 4]);
        assert_eq!(corner.and_then(|p| p.edges), Some(2));
        // A ray on the edge tells no side: the others decide.
        assert_eq!(parity((13.6, 10.5)), None);
        assert_eq!(
            fp.unseen_pattern(13, 10, 0, &[b, (13.6, 10.5), b, b]),
            one_edge
        );
        assert_eq!(fp.unseen_pattern(13, 10, Sample::BACKGROUND, &[b; 4]), None);
    }

    fn cone(axis: DVec3, half_angle: f64) -> Cone {
        // Aperture::new widens by 1e-6 relative and the margin; the tests below keep 1e-7
        // radians from every boundary, far more than either.
        Cone::new(DVec3::ZERO, axis, Aperture::new(half_angle))
    }

    #[test]
    fn sphere_tests_are_exact_up_to_the_margin() {
        // A sphere of radius 1 at distance 10 fills α = asin(0.1) around its centre.
        let alpha = 0.1f64.asin();
        let c = DVec3::new(0.0, 0.0, -10.0);
        let phi = 1e-3;
        for (theta, meets, inside) in [
            (alpha + phi - 1e-7, true, false),
            (alpha + phi + 1e-7, false, false),
            (alpha - phi - 1e-7, true, true),
            (alpha - phi + 1e-7, true, false),
        ] {
            let axis = DVec3::new(theta.sin(), 0.0, -theta.cos());
            let k = cone(axis, phi);
            assert_eq!(k.meets_sphere(c, 1.0), meets, "θ = {theta}");
            assert_eq!(k.inside_sphere(c, 1.0), inside, "θ = {theta}");
        }
        // From inside the ball: meets, never "inside" (the far wall is not a silhouette,
        // but the probe saw the wall from inside, which a convex test cannot vouch for).
        let k = cone(DVec3::Z, phi);
        assert!(k.meets_sphere(DVec3::ZERO, 1.0));
        assert!(!k.inside_sphere(DVec3::ZERO, 1.0));
    }

    /// A point with every coordinate in `[−0.5, 0.5)`.
    fn half_cube(rng: &mut crate::shape::test_support::Rng) -> DVec3 {
        DVec3::new(
            rng.range(-0.5, 0.5),
            rng.range(-0.5, 0.5),
            rng.range(-0.5, 0.5),
        )
    }

    /// Against brute force: whenever some point of a capsule lies in the cone, the capsule
    /// test says "may meet"; and it says "no" for most capsules clear of the cone.
    #[test]
    fn capsule_test_never_misses_a_point_in_the_cone() {
        let mut rng = crate::shape::test_support::Rng::new(0x1234_5678);
        let (mut met, mut cleared) = (0, 0);
        for _ in 0..4000 {
            let axis = (DVec3::new(0.0, 0.0, -1.0) + half_cube(&mut rng) * 0.3).normalize();
            let k = cone(axis, 0.02 * rng.unit() + 1e-4);
            let centre = axis * (2.0 + 20.0 * rng.unit()) + half_cube(&mut rng) * 2.0;
            let a = centre + half_cube(&mut rng) * 3.0 * rng.unit();
            let b = centre + half_cube(&mut rng) * 3.0 * rng.unit();
            let r = 0.2 * rng.unit() + 1e-3;
            let says = k.may_meet_capsule(a, b, r);
            // Points of the capsule: on the segment, then moved up to r in a direction.
            let mut inside = false;
            for _ in 0..400 {
                let along = a + (b - a) * rng.unit();
                let q = along + half_cube(&mut rng).normalize_or_zero() * r * rng.unit().sqrt();
                if angle_between(axis, q) <= k.aperture.half_angle {
                    inside = true;
                    break;
                }
            }
            assert!(
                !inside || says,
                "a capsule point in the cone, but the test said no"
            );
            met += u32::from(inside);
            cleared += u32::from(!says);
        }
        assert!(met > 100 && cleared > 1000, "met {met}, cleared {cleared}");
    }

    #[test]
    fn pixel_sized_angles_keep_their_digits() {
        // acos of the dot product would give 0 or 1.5e-8 here; atan2 gives the angle.
        let a = DVec3::new(0.0, 0.0, 1.0);
        let b = DVec3::new(1e-10, 0.0, 1.0);
        assert!((angle_between(a, b) - 1e-10).abs() < 1e-24);
    }

    #[test]
    fn a_plane_s_horizon_is_seen_only_when_the_cone_straddles_it() {
        // The plane y = 0 seen from y = 1: directions below the horizontal reach it.
        let phi = 1e-3;
        let view = |elevation: f64| {
            let axis = DVec3::new(0.0, elevation.sin(), -elevation.cos());
            let mut k = cone(axis, phi);
            k.origin = DVec3::Y;
            k.view_of_plane(DVec3::ZERO, DVec3::Y)
        };
        assert_eq!(view(-2e-3), PlaneView::Covers);
        assert_eq!(view(-0.5e-3), PlaneView::Horizon);
        assert_eq!(view(0.5e-3), PlaneView::Horizon);
        assert_eq!(view(2e-3), PlaneView::Misses);
    }
}
