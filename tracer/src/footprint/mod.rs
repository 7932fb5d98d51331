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
//! **Quarters.** Each pixel's record also names the first few pieces (balls, capsules) whose
//! cone met it. [`Footprints::fitted_quadrants`] tests them against the narrower cone of
//! each quarter of the square, where everything else in it is one backdrop of smooth
//! shading; the sampler then refines only the quarters a thin solid may show in.
//!
//! **Blank pixels.** Where no solid counts in a pixel and no plane can show in it,
//! [`Footprints::blank`] gives the background's sample: every ray through the square would
//! return it, so the sampler takes it without tracing.
//!
//! **Silhouettes.** Where a pixel shows one plain similarity sphere, or a plain circular
//! cylinder away from its ends, against the background alone, [`Footprints::coverage`]
//! gives the exact share of its square inside the solid's outline (an ellipse or a band,
//! see `coverage`): the sampler weighs the rays that met the solid by it, and the
//! silhouette costs no rays.
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
use crate::math::{Aabb, Color};
use crate::sampler::{ALL_QUADRANTS, CellSums, Coverage, Sample, UnseenPattern};
use crate::shape::Shape;
use crate::world::Scene;
use cells::{cell_edges, cell_parity, covers, one_cell, plane_of};

mod average;
mod cells;
mod cone;
mod coverage;

pub use cone::{Aperture, Cone, PlaneView};
use cone::{BallTest, CapsuleTest};
use coverage::{Ellipse, Silhouette};

/// A rectangle of pixels (it may reach outside the image: the adaptive sampler looks at a
/// border around each tile).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PixelRegion {
    /// First column (may be negative).
    pub x: i64,
    /// First row (may be negative).
    pub y: i64,
    /// Columns.
    pub width: usize,
    /// Rows.
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
    /// Around the ray through the centre of a quarter of a pixel's square.
    quadrant_aperture: Aperture,
    /// Per pixel, row-major: [`NOTHING`], the one solid that may show in it, or
    /// [`SEVERAL`].
    shown: Vec<u32>,
    /// Per pixel, as `shown`, but only the solids whose footprint is tested pixel by pixel
    /// (spheres, and long rods and tori piece by piece, in a CSG tree or not): what
    /// [`Footprints::may_hide`] answers from.
    fitted: Vec<u32>,
    /// The pieces of the solids counted pixel by pixel, as `near` refers to them.
    outlines: Vec<Outline>,
    /// Per pixel, the first [`NEAR`] pieces whose cone test met it, as their index into
    /// `outlines` plus one; 0 in the slots left (so that the records start as zeroed memory).
    near: Vec<[u32; NEAR]>,
    /// Per pixel: [`ROUGH`] where a solid counted by its rectangle may show, [`MANY`] where
    /// more pieces met it than `near` holds. With `near`, what
    /// [`Footprints::fitted_quadrants`] answers from.
    flags: Vec<u8>,
    /// The planes (world point, normal, object), tested per pixel.
    planes: Vec<(DVec3, DVec3, u32)>,
    /// Where each plane of `planes` can show in the image, for [`Footprints::blank`];
    /// `None` where the eye lies on it (or it is not finite).
    plane_sides: Vec<Option<PlaneSide>>,
    /// The checkered planes without a texture, with their rays' map in image coordinates,
    /// for [`Footprints::direct`].
    checker_planes: Vec<(u32, average::PlaneImage<'s>)>,
    /// The solids that may shadow a checkered plane, found when first asked.
    solids: std::cell::OnceCell<average::Solids>,
}

/// What [`Footprints::shows_alone`] allows in a pixel besides its one object's smooth
/// shading.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Alone {
    /// Nothing: the square lies in one checker cell.
    OneCell,
    /// A checker's cell edges.
    Cells,
    /// A checkered plane's cell edges, shadows and a mirror (the caller accounts for
    /// them).
    Mirrored,
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

/// A pixel's flag: a solid counted by its rectangle may show in it.
const ROUGH: u8 = 1;
/// A pixel's flag: more pieces met it than [`NEAR`].
const MANY: u8 = 2;
/// How many pieces a pixel's record names.
const NEAR: usize = 4;

/// A piece of a solid counted pixel by pixel (a similarity sphere's ball, or a capsule that
/// holds a long object's slice or a torus's ring piece), as the cones from the eye test it:
/// around a pixel's centre ray, and around a quarter's.
#[derive(Debug, Clone, Copy)]
struct Outline {
    centre: PieceTest,
    quadrant: PieceTest,
    /// The solid's outline in the image, for [`Footprints::coverage`]: only for a
    /// similarity sphere, or a circular cylinder's slices but its two ends, outside any CSG
    /// tree and wholly in front of the eye.
    silhouette: Option<Silhouette>,
}

/// One piece's cone test for one aperture (never a false no).
#[derive(Debug, Clone, Copy)]
enum PieceTest {
    Ball(BallTest),
    Capsule(CapsuleTest),
}

impl PieceTest {
    #[inline]
    fn meets(&self, axis: DVec3) -> bool {
        match self {
            PieceTest::Ball(t) => t.meets(axis),
            PieceTest::Capsule(t) => t.meets(axis),
        }
    }
}

/// Counts solid `id` in a pixel's record: [`NOTHING`] → `id` → [`SEVERAL`].
#[inline]
fn count(record: &mut u32, id: u32) {
    if *record == NOTHING {
        *record = id;
    } else if *record != id {
        *record = SEVERAL;
    }
}

/// Where a plane can show in the image. A primary ray through image position `(x, y)`
/// heads for the plane when its direction has a positive component along `towards` (the
/// normal turned to the plane's side away from the eye); that component, of the camera's
/// unnormalised direction `corner + right·x + down·y`, is `c + a·x + b·y`: affine in the
/// image position, so over a pixel's square it is largest at one corner.
#[derive(Debug, Clone, Copy)]
struct PlaneSide {
    a: f64,
    b: f64,
    c: f64,
    /// Per unit of `|c|`, `|x|` and `|y|` below: what the rounding of the direction and of
    /// the sum can move the component by, a billion times over.
    slack: [f64; 3],
}

impl PlaneSide {
    /// `None` where the eye lies on the plane (every pixel may show it) or something is not
    /// finite.
    fn new(camera: &crate::camera::Camera, p0: DVec3, n: DVec3) -> Option<PlaneSide> {
        let h = (camera.eye() - p0).dot(n);
        if !(h != 0.0) || !h.is_finite() || !n.is_finite() {
            return None;
        }
        let towards = if h > 0.0 { -n } else { n };
        let (right, down) = camera.steps();
        let corner = camera.direction(0.0, 0.0);
        let t = towards.length();
        let side = PlaneSide {
            a: towards.dot(right),
            b: towards.dot(down),
            c: towards.dot(corner),
            slack: [
                1e-9 * t * corner.length(),
                1e-9 * t * right.length(),
                1e-9 * t * down.length(),
            ],
        };
        let finite = [side.a, side.b, side.c].iter().all(|v| v.is_finite());
        finite.then_some(side)
    }

    /// Whether no ray through pixel `(px, py)`'s square heads for the plane: the component
    /// at the square's corner where it is largest is below zero by more than the slack.
    fn misses(&self, px: i64, py: i64) -> bool {
        let x = px as f64 + if self.a > 0.0 { 1.0 } else { 0.0 };
        let y = py as f64 + if self.b > 0.0 { 1.0 } else { 0.0 };
        let most = self.c + self.a * x + self.b * y;
        let [sc, sx, sy] = self.slack;
        most < -(sc + sx * x.abs() + sy * y.abs())
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
            quadrant_aperture: Aperture::new(scene.camera.quadrant_angle_from_centre()),
            shown: vec![NOTHING; n],
            fitted: vec![NOTHING; n],
            outlines: Vec::new(),
            near: vec![[0; NEAR]; n],
            flags: vec![0; n],
            planes: Vec::new(),
            plane_sides: Vec::new(),
            checker_planes: Vec::new(),
            solids: std::cell::OnceCell::new(),
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
                    self.plane_sides.push(PlaneSide::new(&scene.camera, p0, n));
                    if obj.material.color2.is_some() && obj.material.texture.is_none() {
                        let image = average::PlaneImage::frame(scene, *o, 0, 0);
                        self.checker_planes.push((*o, image));
                    }
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
                let eye = self.scene.camera.eye();
                let ball = |ap| PieceTest::Ball(BallTest::new(eye, ap, c, r));
                let camera = &self.scene.camera;
                let piece = Outline {
                    centre: ball(self.centre_aperture),
                    quadrant: ball(self.quadrant_aperture),
                    silhouette: clip
                        .is_none()
                        .then(|| Ellipse::new(camera, c, r).map(Silhouette::Ellipse))
                        .flatten(),
                };
                self.add_where(o, &b, piece);
            }
            return true;
        }
        let pieces = obj.outline();
        if pieces.is_empty() {
            return false;
        }
        let band = clip.is_none().then(|| self.cylinder_band(obj)).flatten();
        let k = pieces.len();
        for (j, p) in pieces.into_iter().enumerate() {
            let (a, e) = p.axis;
            if let Some(b) = clipped(p.bounds) {
                let eye = self.scene.camera.eye();
                let capsule = |ap| PieceTest::Capsule(CapsuleTest::new(eye, ap, a, e, p.radius));
                // The end slices hold the caps, whose outline is no band; and a slice a
                // shadow may fall on has no smooth shading.
                let middle = -1.0 + (2 * j + 1) as f64 / k as f64;
                let interior = j > 0
                    && j + 1 < k
                    && band.is_some()
                    && self.scene.casts_no_shadow_on_slice(o, middle);
                let piece = Outline {
                    centre: capsule(self.centre_aperture),
                    quadrant: capsule(self.quadrant_aperture),
                    silhouette: band.filter(|_| interior).map(Silhouette::Band),
                };
                self.add_where(o, &b, piece);
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

    /// Counts `id` in the pixels of the rectangle of box `b` where the cone around the ray
    /// through the pixel's centre meets `piece`, and names the piece in their records.
    fn add_where(&mut self, id: u32, b: &Aabb, piece: Outline) {
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
        // At most one piece per BVH leaf of every solid, far below u32::MAX.
        self.outlines.push(piece);
        let slot_value = self.outlines.len() as u32;
        let (xs, ys) = self.pixels_of(rect);
        let reg = self.region;
        for row in ys {
            for col in xs.clone() {
                let (px, py) = (reg.x + col as i64, reg.y + row as i64);
                let ray = self.scene.camera.ray(px as f64 + 0.5, py as f64 + 0.5);
                if piece.centre.meets(ray.dir) {
                    let i = row * reg.width + col;
                    count(&mut self.shown[i], id);
                    count(&mut self.fitted[i], id);
                    match self.near[i].iter_mut().find(|slot| **slot == 0) {
                        Some(slot) => *slot = slot_value,
                        None => self.flags[i] |= MANY,
                    }
                }
            }
        }
    }

    /// Counts solid `id`, counted by its rectangle, in pixel `i`.
    #[inline]
    fn mark(&mut self, i: usize, id: u32) {
        count(&mut self.shown[i], id);
        self.flags[i] |= ROUGH;
    }

    /// Whether a similarity sphere, a long object's slice or a torus's ring piece other than
    /// `object` (a hit's object, or [`Sample::BACKGROUND`]) may show in pixel `(px, py)`'s
    /// square: its cone
    /// around the centre ray meets one. Pixels outside the region: no.
    pub fn may_hide(&self, px: i64, py: i64, object: u32) -> bool {
        self.index(px, py)
            .is_some_and(|i| self.fitted[i] != NOTHING && self.fitted[i] != object)
    }

    /// The quarters of pixel `(px, py)`'s square in which a similarity sphere, a long
    /// object's slice or a torus's ring piece may show (bit `k` for the quarter in column
    /// `k & 1`, row `k >> 1`), where everything else the square shows is one backdrop of
    /// smooth shading: the background, or one plain plane that every ray of the square meets
    /// in one checker cell. The quarters without a bit then hold that backdrop alone: no
    /// edge, texture, reflection or shadow. `None` where another solid may show (one counted
    /// by its rectangle, a CSG tree), a plane's horizon crosses the square, the plane is not
    /// plain, or the pixel lies outside the region.
    pub fn fitted_quadrants(&self, px: i64, py: i64) -> Option<u8> {
        let i = self.index(px, py)?;
        if self.flags[i] & ROUGH != 0 {
            return None;
        }
        if !self.planes.is_empty() {
            let ray = self.scene.camera.ray(px as f64 + 0.5, py as f64 + 0.5);
            let cone = Cone::new(ray.origin, ray.dir, self.centre_aperture);
            let mut backdrop = false;
            for &(p0, n, o) in &self.planes {
                match cone.view_of_plane(p0, n) {
                    PlaneView::Misses => {}
                    PlaneView::Covers if !backdrop && self.scene.plain(o) => {
                        let obj = &self.scene.objects[o as usize];
                        if obj.material.color2.is_some() && !one_cell(self.scene, obj, px, py) {
                            return None;
                        }
                        backdrop = true;
                    }
                    _ => return None,
                }
            }
        }
        if self.flags[i] & MANY != 0 {
            return Some(ALL_QUADRANTS);
        }
        // Each quarter of the square lies within the cone of the quarter-pixel aperture
        // around the ray through its centre.
        let mut bits = 0;
        for k in 0..4u8 {
            let (qx, qy) = (f64::from(k & 1), f64::from(k >> 1));
            let (cx, cy) = (px as f64 + 0.25 + 0.5 * qx, py as f64 + 0.25 + 0.5 * qy);
            let axis = self.scene.camera.ray(cx, cy).dir;
            let met = self.near[i]
                .iter()
                .take_while(|&&slot| slot != 0)
                .any(|&slot| self.outlines[slot as usize - 1].quadrant.meets(axis));
            if met {
                bits |= 1 << k;
            }
        }
        Some(bits)
    }

    /// What an edge of `object`'s checker can hide in pixel `(px, py)`'s square on a side
    /// that none of the rays through image positions `seen` (rays that all saw `object`) fell
    /// on: the step between the two colours there (`Scene::checker_step`'s bound) and how
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

    /// What a checkered plane's cells give pixel `(px, py)`, where the primary ray through
    /// `(x, y)` saw `seen`: where that plane alone shows in the square (mirrored or not,
    /// shadowed or not, no texture, outside any CSG tree), the mean over the square of its
    /// own unshadowed light ([`Footprints::direct`]), the cells' areas exact and the
    /// shading smooth to within `threshold` (see `average`); and, where nothing else can
    /// change in the square (no mirror, no shadow, no clamp's kink), the pixel's value. At
    /// most `max_cells` cells are summed. `None` elsewhere.
    pub fn cells(
        &self,
        px: i64,
        py: i64,
        (x, y): (f64, f64),
        seen: &Sample,
        threshold: f64,
        max_cells: u32,
    ) -> Option<CellSums> {
        let o = seen.object;
        let obj = self.scene.objects.get(o as usize)?;
        if !self.scene.cell_areas
            || obj.material.color2.is_none()
            || obj.material.mirror >= 1.0
            || !matches!(obj.shape, Shape::Plane)
            || !self.shows_alone(px, py, x, y, o, Alone::Mirrored)
        {
            return None;
        }
        let sums = average::cell_sums(self.scene, o, px, py, threshold, max_cells)?;
        let alone = obj.material.mirror <= 0.0
            && !sums.kink
            && (self.scene.casts_no_shadow_on(o)
                || !average::may_be_shadowed(self.scene, o, &sums, self.solids()));
        Some(CellSums {
            object: o,
            direct: sums.direct,
            exact: alone.then_some(sums.clamped),
        })
    }

    /// The scene's solids as the shadow test of [`Footprints::cells`] takes them.
    fn solids(&self) -> &average::Solids {
        self.solids.get_or_init(|| average::solids(self.scene))
    }

    /// [`Footprints::cells`]' value of the pixel, where it has one: for the tests.
    #[cfg(any(test, feature = "bench"))]
    pub fn exact(
        &self,
        px: i64,
        py: i64,
        at: (f64, f64),
        seen: &Sample,
        threshold: f64,
        max_cells: u32,
    ) -> Option<Color> {
        self.cells(px, py, at, seen, threshold, max_cells)?.exact
    }

    /// Checkered plane `object`'s own light at image position `at`: `(1 − mirror) · c · S`,
    /// its cell's colour times the Lambertian shading with no light shadowed, unclamped;
    /// the function whose mean over a pixel's square `CellSums::direct` is. Zero for any
    /// other object, and where the ray misses the plane.
    pub fn direct(&self, object: u32, at: (f64, f64)) -> Color {
        self.checker_planes
            .iter()
            .find(|(o, _)| *o == object)
            .map_or(Color::ZERO, |(_, image)| image.direct(at))
    }

    /// The background's sample, where nothing else can show in pixel `(px, py)`'s square:
    /// no solid's footprint meets it (the solids counted by their rectangles, the others by
    /// the cone around the centre ray, which holds every ray of the square), and that cone
    /// misses every plane. A ray through the square then meets nothing, and its radiance is
    /// the background's. Pixels outside the region: `None`.
    pub fn blank(&self, px: i64, py: i64) -> Option<Sample> {
        let i = self.index(px, py)?;
        if self.shown[i] != NOTHING {
            return None;
        }
        let misses = |side: &Option<PlaneSide>| side.is_some_and(|s| s.misses(px, py));
        if !self.plane_sides.iter().all(misses) {
            return None;
        }
        Some(self.scene.background_sample())
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
        self.shows_alone(px, py, x, y, seen.object, Alone::OneCell)
    }

    /// [`Footprints::is_smooth`] but for a checker's cells: whether pixel `(px, py)`, where
    /// the primary ray through `(x, y)` saw `object`, holds no edge, texture, reflection or
    /// shadow edge other than the edges between a checkered plane's cells, which
    /// [`Footprints::unseen_pattern`] bounds. A step between it and a neighbour that neither
    /// saw is then a cell edge, in the neighbour unless the pattern puts one here.
    pub fn pattern_alone(&self, px: i64, py: i64, x: f64, y: f64, object: u32) -> bool {
        self.shows_alone(px, py, x, y, object, Alone::Cells)
    }

    /// [`Footprints::is_smooth`], with what `alone` allows besides.
    fn shows_alone(&self, px: i64, py: i64, x: f64, y: f64, object: u32, alone: Alone) -> bool {
        let one_cell_too = alone == Alone::OneCell;
        let Some(i) = self.index(px, py) else {
            return false;
        };
        let hit = (object != Sample::BACKGROUND).then_some(object);
        let shown_alone = match self.shown[i] {
            NOTHING => true,
            SEVERAL => false,
            one => Some(one) == hit,
        };
        let plain = |o: u32| match alone {
            Alone::Mirrored => {
                let obj = &self.scene.objects[o as usize];
                matches!(obj.shape, Shape::Plane) && !obj.in_csg && obj.material.texture.is_none()
            }
            _ => self.scene.plain(o),
        };
        if !shown_alone || hit.is_some_and(|o| !plain(o)) {
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

impl crate::sampler::PixelGeometry for Footprints<'_> {
    fn is_smooth(&self, px: i64, py: i64, x: f64, y: f64, seen: &Sample) -> bool {
        Footprints::is_smooth(self, px, py, x, y, seen)
    }

    fn may_hide(&self, px: i64, py: i64, object: u32) -> bool {
        Footprints::may_hide(self, px, py, object)
    }

    fn fitted_quadrants(&self, px: i64, py: i64) -> Option<u8> {
        Footprints::fitted_quadrants(self, px, py)
    }

    fn blank(&self, px: i64, py: i64) -> Option<Sample> {
        Footprints::blank(self, px, py)
    }

    fn coverage(&self, px: i64, py: i64) -> Option<Coverage> {
        Footprints::coverage(self, px, py)
    }

    fn pattern_alone(&self, px: i64, py: i64, x: f64, y: f64, object: u32) -> bool {
        Footprints::pattern_alone(self, px, py, x, y, object)
    }

    fn cells(
        &self,
        px: i64,
        py: i64,
        at: (f64, f64),
        seen: &Sample,
        threshold: f64,
        max_cells: u32,
    ) -> Option<CellSums> {
        Footprints::cells(self, px, py, at, seen, threshold, max_cells)
    }

    fn direct(&self, object: u32, at: (f64, f64)) -> Color {
        Footprints::direct(self, object, at)
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

#[cfg(test)]
mod tests;
