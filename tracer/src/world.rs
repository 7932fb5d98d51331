//! The scene ready to render: objects placed in the world with their materials and loaded
//! textures, CSG trees over them, and the queries rays make of them (nearest hit, any hit).
//!
//! This is where a [`SceneDesc`] meets its assets. Every primitive, inside a CSG tree or
//! not, is an [`Object`] with its full object-to-world transform (a CSG child's own
//! transform followed by those of every enclosing `[CSG]`); the solids a ray is tested
//! against are the [`Prim`]s, each a lone object or a CSG tree over objects. What a pixel
//! looks like is [`crate::render`]'s business; this module only answers "what does this ray
//! hit".

use std::collections::HashMap;
use std::ops::ControlFlow;
use std::sync::Arc;

use arrayvec::ArrayVec;
use glam::DVec3;

use crate::bvh::{Bvh, Item};
use crate::camera::Camera;
use crate::csg::{Csg, Prim};
use crate::diag::{Diagnostic, SceneError};
use crate::math::{Aabb, Color, Ray};
use crate::point_index::{self, PointIndex};
use crate::sampler::Sampler;
use crate::scene::{self, Light, Limits, MaterialDesc, Node, SceneDesc};
use crate::shadow::ClearLights;
use crate::shape::{LocalHit, Shape};
use crate::texture::{AssetSource, Texture, TextureError, TextureLimits};
use crate::transform::Transform;

/// Surface properties with textures loaded.
#[derive(Debug, Clone)]
pub struct Material {
    pub color1: Color,
    pub color2: Option<Color>,
    pub texture: Option<Arc<Texture>>,
    pub mirror: f64,
    pub diffuse: f64,
}

/// A primitive placed in the world.
#[derive(Debug, Clone)]
pub struct Object {
    pub shape: Shape,
    pub transform: Transform,
    /// Unit shape to the shape's own space (where checker cells are unit cubes).
    pub own_scale: DVec3,
    pub material: Material,
    /// World bounds; `None` when unbounded.
    pub bounds: Option<Aabb>,
    /// Whether the object is part of a CSG tree (then the ray meets the tree, not the
    /// object, and the object's own convexity says nothing about hitting it again).
    pub in_csg: bool,
    /// For a sphere placed by a similarity (uniform scale and translation): its world centre
    /// and squared radius, for [`Object::certainly_missed_by`].
    sphere: Option<(DVec3, f64)>,
}

impl Object {
    /// An object as placed in the world (see the fields).
    pub fn new(
        shape: Shape,
        transform: Transform,
        own_scale: DVec3,
        material: Material,
        in_csg: bool,
    ) -> Object {
        let sphere = match (shape, transform.similarity()) {
            (Shape::Sphere, Some((s, centre))) => Some((centre, s * s)),
            _ => None,
        };
        Object {
            shape,
            transform,
            own_scale,
            material,
            bounds: shape.bounds().map(|b| transform.bounds_to_world(&b)),
            in_csg,
            sphere,
        }
    }

    /// A world-space test that can only say "certainly missed": for a sphere placed by a
    /// similarity, whether the ray's line passes clearly outside it. It saves the object-space
    /// ray (a division) and the exact root finding (a square root and five divisions) for
    /// most rays that miss, and never changes an answer: it rejects only lines whose
    /// distance from the centre exceeds the radius by far more than any rounding.
    ///
    /// With `f = o − c`, the squared distance of the line from `c` times `|d|²` is
    /// `Q = |f|²|d|² − (f·d)²` (Lagrange's identity, so `Q ≥ 0` exactly). Computed, `Q` is
    /// off by at most `2γ(6)·|f|²|d|²` (each product is within `γ(6)` and `(f·d)² ≤
    /// |f|²|d|²`). The exact intersection ([`Shape::intersect`] on the object-space ray)
    /// computes the same distance in the sphere's units to within a few ulps of `|f|/r`, that
    /// is `Q/|d|² ≤ r² + O(ε)·(|f|² + r²)`, if it finds a hit. The test rejects only when
    /// `Q > |d|²·(r² + 1e-6·(|f|² + r²))`, a margin some 10⁹ times wider than both errors
    /// together; an overflow to ∞ or a NaN fails the comparison and so rejects nothing.
    #[inline]
    pub fn certainly_missed_by(&self, ray: &Ray) -> bool {
        let Some((c, r2)) = self.sphere else {
            return false;
        };
        sphere_certainly_missed(c, r2, ray)
    }

    /// For a sphere placed by a similarity, its world centre and squared radius.
    pub fn similarity_sphere(&self) -> Option<(DVec3, f64)> {
        self.sphere
    }
}

/// Most pieces a long object is cut into for the BVH (see [`Object::pieces`]).
pub const MAX_PIECES: usize = 16;

impl Object {
    /// Boxes that together hold the whole surface, for the BVH: a cylinder or cone cut
    /// across its axis into up to [`MAX_PIECES`] slices, each bounded exactly; empty for
    /// every other shape (the BVH then uses [`Object::bounds`]).
    ///
    /// A long thin solid laid diagonally fills only a sliver of its world box, and in a
    /// scene of many such (a fan of rods) the boxes overlap so much that every ray opens
    /// most of them. A slice of the solid has a box close to its own size, so the slices'
    /// boxes overlap far less. The BVH then holds several items for the object, and offers
    /// it once for each slice whose box the ray enters: the object is tested whole each
    /// time and gives the same answer, so only the speed changes ("early split clipping",
    /// Ernst and Greiner 2007). Slices are halved while that shrinks their total box area by
    /// at least a fifth, which stops once slices are about as long as they are wide.
    ///
    /// **Bounds.** The slice `y ∈ [y0, y1]` of the unit cylinder (radius `ρ(y) = 1`) or cone
    /// (`ρ(y) = (1 − y)/2`) is the convex hull of its two end discs, so its world box is the
    /// union of theirs. The disc at `y` maps to the centre `M·(0, y, 0) + t` and the ellipse
    /// spanned by `ρ·M·x̂` and `ρ·M·ẑ`, whose extent along world axis `i` is exactly
    /// `ρ·√(M_i0² + M_i2²)` (the largest `ρ(M_i0 cos φ + M_i2 sin φ)`). Computed, each is
    /// within a few ulps of its magnitude; the BVH pads every box by 1e-7 of its magnitude
    /// ([`crate::bvh::SLACK`]), a margin nine orders wider, and the slices share their end
    /// discs, so the padded boxes together hold the solid and every computed hit on it.
    pub fn pieces(&self) -> Vec<Aabb> {
        self.slices().into_iter().map(|p| p.bounds).collect()
    }

    /// The same slices as [`Object::pieces`], each with its box and a capsule that holds it
    /// (see [`Piece`]); empty for shapes that are not cut.
    pub fn slices(&self) -> Vec<Piece> {
        let radius: fn(f64) -> f64 = match self.shape {
            Shape::Cylinder => |_| 1.0,
            Shape::Cone => |y| (1.0 - y) / 2.0,
            _ => return Vec::new(),
        };
        let m = self.transform.to_world();
        let (c0, c1, c2) = (m.matrix3.x_axis, m.matrix3.y_axis, m.matrix3.z_axis);
        let spread = DVec3::new(c0.x.hypot(c2.x), c0.y.hypot(c2.y), c0.z.hypot(c2.z));
        let disc = |y: f64| {
            let (c, e) = (m.translation + c1 * y, spread * radius(y));
            Aabb::new(c - e, c + e)
        };
        let end = |j: usize, k: usize| {
            if j == k {
                1.0
            } else {
                -1.0 + 2.0 * j as f64 / k as f64
            }
        };
        let slices = |k: usize| -> Vec<Aabb> {
            (0..k)
                .map(|j| disc(end(j, k)).union(&disc(end(j + 1, k))))
                .collect()
        };
        let area = |b: &[Aabb]| b.iter().map(Aabb::surface_area).sum::<f64>();
        let mut best = slices(1);
        let mut k = 1;
        while 2 * k <= MAX_PIECES {
            let finer = slices(2 * k);
            // Not finite (a degenerate transform) or not a fifth smaller: stop.
            if !(area(&finer) < 0.8 * area(&best)) {
                break;
            }
            best = finer;
            k *= 2;
        }
        // The capsules: a disc of radius ρ spanned by ρ·M·x̂ and ρ·M·ẑ lies within
        // ρ·√(|M·x̂|² + |M·ẑ|²) of its centre (Cauchy–Schwarz).
        let across = (c0.length_squared() + c2.length_squared()).sqrt();
        best.into_iter()
            .enumerate()
            .map(|(j, bounds)| {
                let (y0, y1) = (end(j, k), end(j + 1, k));
                let (a, b) = (m.translation + c1 * y0, m.translation + c1 * y1);
                let r = across * radius(y0).max(radius(y1));
                let size = a.abs().max(b.abs()).max_element() + r;
                Piece {
                    bounds,
                    axis: (a, b),
                    radius: r + size * crate::bvh::SLACK,
                }
            })
            .collect()
    }
}

/// Chords a torus's core circle is cut into for [`Object::outline`]: the arc between two
/// neighbouring chord ends lies within `R·(1 − cos(π/32)) ≈ 0.0048·R` of its chord.
pub const RING_CHORDS: usize = 32;

impl Object {
    /// Capsules that together hold the whole solid, for the adaptive sampler's per-pixel
    /// footprints ([`crate::footprint`]): a long cylinder's or cone's slices
    /// ([`Object::slices`]), and for a torus one capsule per chord of its core circle
    /// ([`RING_CHORDS`]); empty for every other shape.
    ///
    /// **The torus.** In object space the tube is the set of points within `minor` of the
    /// core circle, and every point of an arc lies within the sagitta `s = R·(1 − cos(π/n))`
    /// of its chord, so the tube's piece over an arc lies in the capsule of radius
    /// `minor + s` around the chord. The linear part `M` of the transform maps a ball of
    /// radius `ρ` into one of radius `ρ·‖M‖` (`‖M‖` no larger than its Frobenius norm), so
    /// the world capsule around the transformed chord with radius `(minor + s)·‖M‖_F` holds
    /// the world piece. Padded as [`Object::slices`] pads its capsules.
    pub fn outline(&self) -> Vec<Piece> {
        let Shape::Torus { major, minor } = self.shape else {
            return self.slices();
        };
        let m = self.transform.to_world();
        let frobenius = (m.matrix3.x_axis.length_squared()
            + m.matrix3.y_axis.length_squared()
            + m.matrix3.z_axis.length_squared())
        .sqrt();
        let step = std::f64::consts::TAU / RING_CHORDS as f64;
        let sagitta = major * (1.0 - (step / 2.0).cos());
        let r = (minor + sagitta) * frobenius;
        let at = |j: usize| {
            let a = step * j as f64;
            m.transform_point3(DVec3::new(major * a.cos(), 0.0, major * a.sin()))
        };
        (0..RING_CHORDS)
            .map(|j| {
                let (a, b) = (at(j), at(j + 1));
                let size = a.abs().max(b.abs()).max_element() + r;
                let radius = r + size * crate::bvh::SLACK;
                let pad = DVec3::splat(radius);
                Piece {
                    bounds: Aabb::new(a.min(b) - pad, a.max(b) + pad),
                    axis: (a, b),
                    radius,
                }
            })
            .collect()
    }

    /// The world outward normals (not unit) of the planes through `p` that hold the whole
    /// solid on their inner side, when `p` lies on its surface (to within the rounding of
    /// carrying `p` into object space): the tangent plane where the surface is smooth and
    /// convex (a sphere anywhere, a plane, a cube's face, a cylinder's or cone's side or
    /// cap, a torus where its tangent plane holds it all on one side), and at an edge or
    /// corner of a convex solid the plane of each face that meets there (two on a cube's
    /// edge or a cylinder's or cone's rim, three at a cube's corner; the plane of the base
    /// through a cone's apex, parallel to it, holds the cone too). Empty elsewhere (the rest of
    /// a torus) and off the surface. A light on such a plane cannot be shadowed by the solid
    /// from a point strictly on the plane's outer side: the segment stays in that open
    /// half-space but for the light.
    ///
    /// The tolerance is twice the error bound of the object-space point
    /// ([`crate::transform::Transform::to_object_error`]) plus a few ulps of it: a light the scene puts on a surface is within it, a light
    /// 1e-14 of a unit inside a unit sphere is not.
    pub fn normals_through(&self, p: DVec3) -> ArrayVec<DVec3, 3> {
        let q = self.transform.point_to_object(p);
        let err = self.transform.to_object_error(p);
        let tol = 2.0 * err.max_element() + crate::math::gamma(4) * (q.abs().max_element() + 1.0);
        let near = |a: f64, b: f64| (a - b).abs() <= tol;
        let mut normals = ArrayVec::<DVec3, 3>::new();
        match self.shape {
            Shape::Sphere => {
                if near(q.length(), 1.0) {
                    normals.push(q);
                }
            }
            Shape::Plane => {
                if near(q.y, 0.0) {
                    normals.push(DVec3::Y);
                }
            }
            Shape::Cube => {
                if q.abs().max_element() <= 1.0 + tol {
                    for i in 0..3 {
                        if near(q[i].abs(), 1.0) {
                            let mut n = DVec3::ZERO;
                            n[i] = q[i].signum();
                            normals.push(n);
                        }
                    }
                }
            }
            Shape::Cylinder => {
                let rho = q.x.hypot(q.z);
                if near(rho, 1.0) && q.y.abs() <= 1.0 + tol {
                    normals.push(DVec3::new(q.x, 0.0, q.z));
                }
                if near(q.y.abs(), 1.0) && rho <= 1.0 + tol {
                    normals.push(DVec3::new(0.0, q.y.signum(), 0.0));
                }
            }
            Shape::Cone => {
                let rho = q.x.hypot(q.z);
                if near(rho, 0.5 * (1.0 - q.y)) && q.y.abs() <= 1.0 + tol && rho > tol {
                    normals.push(DVec3::new(q.x / rho, 0.5, q.z / rho));
                }
                if near(q.y, -1.0) && rho <= 1.0 + tol {
                    normals.push(DVec3::NEG_Y);
                }
                if near(q.y, 1.0) && rho <= tol {
                    normals.push(DVec3::Y);
                }
            }
            Shape::Torus { major, minor } => {
                // Not convex: only where the tangent plane holds the whole torus on its
                // inner side (the top and bottom circles, the outer equator), which is where
                // `n·q` reaches the torus's support `R·|n_xz| + r` in the direction `n`.
                let rho = q.x.hypot(q.z);
                let core = if rho > 0.0 {
                    DVec3::new(q.x, 0.0, q.z) * (major / rho)
                } else {
                    DVec3::ZERO
                };
                let n = (q - core).normalize_or_zero();
                let support = major * n.x.hypot(n.z) + minor;
                if rho > 0.0
                    && near((q - core).length(), minor)
                    && n.dot(q) >= support - tol * (1.0 + major)
                {
                    normals.push(n);
                }
            }
        }
        normals
            .into_iter()
            .map(|n| self.transform.normal_to_world(n))
            .collect()
    }
}

/// The lone objects whose surface passes through `p`, with the normals of their supporting
/// planes there (see [`Object::normals_through`]). Only the solids whose (padded) boxes hold `p` are asked,
/// found through the BVH when the scene has one, so that a thousand lights over a million
/// objects cost a point query each, not a billion tests.
fn surfaces_through(
    objects: &[Object],
    prims: &[Prim],
    accel: &Accel,
    p: DVec3,
) -> Vec<(u32, DVec3)> {
    let mut found = Vec::new();
    let mut ask = |pi: u32| {
        // A long object is in the tree once per slice: asked once.
        if let Prim::Object(o) = prims[pi as usize]
            && !found.iter().any(|e: &(u32, DVec3)| e.0 == o)
        {
            for n in objects[o as usize].normals_through(p) {
                found.push((o, n));
            }
        }
    };
    match accel {
        Accel::Linear => (0..prims.len() as u32).for_each(&mut ask),
        Accel::Bvh { bvh, unbounded, .. } => {
            unbounded.iter().copied().for_each(&mut ask);
            bvh.any_item(
                |b| b.contains(p),
                |pi| {
                    ask(pi);
                    false
                },
            );
        }
    }
    // In the order the objects are written, whatever order the tree met them in.
    found.sort_by_key(|e| e.0);
    found
}

/// A slice of a long cylinder or cone (see [`Object::pieces`]), or a piece of a torus's
/// ring (see [`Object::outline`]): its box, and a capsule that
/// holds it: the segment `axis` between its end discs' centres, and a radius no smaller than
/// either disc's (the slice is the convex hull of its discs, so it lies in the hull of the
/// two balls), padded as [`crate::bvh::padded`] pads boxes.
#[derive(Debug, Clone, Copy)]
pub struct Piece {
    pub bounds: Aabb,
    pub axis: (DVec3, DVec3),
    pub radius: f64,
}

/// The test of [`Object::certainly_missed_by`] for centre `c` and squared radius `r2`.
/// With `r2 = ∞` it rejects nothing (the right side is ∞, or NaN when `d = 0`, and `>`
/// fails for both), which is how prims other than similarity spheres pass through it.
#[inline]
fn sphere_certainly_missed(c: DVec3, r2: f64, ray: &Ray) -> bool {
    line_clears_ball(c, r2, ray, 0.0)
}

/// Whether the ray's line passes outside the ball of centre `c` and squared radius `r2` by
/// a margin: its squared distance from `c` (Lagrange's identity, `|f×d|²/|d|²` with
/// `f = o − c`) exceeds `r2 + 1e-6·(|f|² + r2 + extra)`. `extra` widens the margin for
/// callers whose sphere test carries more rounding (see [`crate::csg::Ball`]).
#[inline]
pub(crate) fn line_clears_ball(c: DVec3, r2: f64, ray: &Ray, extra: f64) -> bool {
    let f = ray.origin - c;
    let (ff, dd, fd) = (f.dot(f), ray.dir.dot(ray.dir), f.dot(ray.dir));
    ff * dd - fd * fd > dd * (r2 + 1e-6 * (ff + r2 + extra))
}

/// What the BVH search reads first about each of its prims, packed in the tree's item
/// order so that a leaf's prims share cache lines: most candidates of a scene of many small
/// spheres are rejected here without touching the prim or its object.
#[derive(Debug, Clone, Copy)]
struct Quick {
    /// Index into `Scene::prims`.
    prim: u32,
    /// The similarity sphere's world centre and squared radius; `r2 = ∞` for every other
    /// prim (see [`sphere_certainly_missed`]).
    centre: DVec3,
    r2: f64,
}

/// A nearest hit: which object, and the hit in its object space.
#[derive(Debug, Clone, Copy)]
pub struct Hit {
    /// The primitive whose surface was hit (for a CSG, the child the surface belongs to).
    pub object: u32,
    /// The hit in that primitive's object space; its normal is the outward normal of the
    /// solid the ray met (for a difference's cutter face, the cutter's normal reversed).
    pub local: LocalHit,
}

/// A scene ready to render.
#[derive(Debug, Clone)]
pub struct Scene {
    pub width: u32,
    pub height: u32,
    pub ambient: Color,
    pub shadow: f64,
    pub background: Color,
    pub max_depth: u32,
    pub sampler: Sampler,
    pub camera: Camera,
    pub lights: Vec<Light>,
    /// Every primitive, CSG children included.
    pub objects: Vec<Object>,
    /// The solids rays are tested against, in the order written. Changing `objects` or
    /// `prims` after [`Scene::build`] leaves the BVH describing the old ones: rebuild it with
    /// [`Scene::with_acceleration`].
    pub prims: Vec<Prim>,
    /// How rays find the prims they may hit (built from `prims` by [`Scene::build`]).
    accel: Accel,
    /// What rays through the eye or a light find instead of walking the BVH.
    points: PointTables,
    /// The lights each object's shadow rays need not be traced to (see [`crate::shadow`]).
    clear_lights: ClearLights,
    /// Per light, the lone convex objects whose surface passes through it (see
    /// [`Scene::lights_on`]).
    lights_on: Vec<Vec<(u32, DVec3)>>,
    /// How many objects mirror (`mirror > 0`): whether a mirrored ray can come back to a
    /// checkered plane (see [`Scene::checker_step`]).
    pub(crate) mirrors: usize,
}

/// Below this many bounded prims a scene tests every prim for every ray: a BVH's box tests
/// and bookkeeping cost more than they save on a handful of solids (measured with
/// `tessera-bench tracer`: at 8 spheres the two are about even, at 16 the BVH is ahead).
pub const BVH_MIN_PRIMS: usize = 8;

/// ... or when testing every bounded prim costs at least as much as testing
/// [`BVH_MIN_PRIMS`] similarity spheres (`prim_cost` units: such a sphere 1, another
/// object 2, a CSG tree 2 per child it may evaluate, see [`Csg::cost`]). A few expensive
/// solids gain from a BVH long before eight do: measured with callgrind on
/// `tessera-bench tracer` scenes, four general shapes
/// (`examples/shapes.ray`, cost 8) 1.94 G → 0.87 G instructions, the CSG example 1.88 G →
/// 1.54 G, the CSG bench scene 111.5 M → 95.5 M; scenes of one or two solids (cost ≤ 4)
/// are 10–14 % slower with one and stay linear.
pub const BVH_MIN_COST: f64 = BVH_MIN_PRIMS as f64 * SPHERE_COST;

/// Which way [`Scene::intersect`] and [`Scene::occluded`] find candidate prims. Every choice
/// gives the same answers, bit for bit; only the speed differs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Acceleration {
    /// A BVH when there are at least [`BVH_MIN_PRIMS`] bounded prims or their cost is at
    /// least [`BVH_MIN_COST`], else every prim; an index in each union or difference with
    /// at least [`crate::csg::CSG_INDEX_MIN`] children to index.
    #[default]
    Auto,
    /// Every prim, in order, for every ray, and every CSG child in order (the reference
    /// the BVH and the CSG indices are checked against).
    Off,
    /// A BVH whenever there is at least one bounded prim, and an index in every union and
    /// difference.
    Always,
}

/// The acceleration structure of a scene.
#[derive(Debug, Clone, Default)]
enum Accel {
    /// Test every prim in order.
    #[default]
    Linear,
    /// A BVH over the bounded prims (items are indices into `prims`) and the prims without
    /// a usable box (planes, unbounded CSG), tested every time.
    Bvh {
        bvh: Bvh,
        unbounded: Vec<u32>,
        /// Per BVH item slot (see [`Bvh::items`]).
        quick: Vec<Quick>,
    },
}

/// Each bounded prim with its box and what testing it costs, in prim order.
fn bounded_prims(prims: &[Prim], objects: &[Object]) -> Vec<(u32, Aabb, f64)> {
    prims
        .iter()
        .enumerate()
        .filter_map(|(i, p)| {
            Some((
                u32::try_from(i).ok()?,
                p.bounds(objects)?,
                prim_cost(p, objects),
            ))
        })
        .collect()
}

/// What the BVH is built over: each bounded prim's box, or a long object's slices (see
/// [`Object::pieces`]), in prim order.
fn bvh_items(prims: &[Prim], objects: &[Object], bounded: &[(u32, Aabb, f64)]) -> Vec<Item> {
    let mut items: Vec<Item> = Vec::with_capacity(bounded.len());
    for &(id, bounds, cost) in bounded {
        let pieces = match &prims[id as usize] {
            Prim::Object(o) => objects[*o as usize].pieces(),
            Prim::Csg(_) => Vec::new(),
        };
        if pieces.is_empty() {
            items.push(Item { id, bounds, cost });
        } else {
            items.extend(pieces.into_iter().map(|bounds| Item { id, bounds, cost }));
        }
    }
    items
}

/// The tables of rays through the eye and through each light (see [`crate::point_index`]),
/// beside the BVH they stand in for.
#[derive(Debug, Clone, Default)]
struct PointTables {
    eye: Option<PointIndex>,
    /// Per light (the first [`point_index::MAX_LIGHTS`]).
    lights: Vec<Option<PointIndex>>,
    /// Per prim: a similarity sphere's centre and squared radius (`r2 = ∞` for any other
    /// prim), for the quick test of listed prims (see [`sphere_certainly_missed`]).
    quick: Vec<(DVec3, f64)>,
}

impl PointTables {
    /// The tables a scene with this BVH gains from: with `Auto`, when it has at least
    /// [`point_index::MIN_PRIMS`] bounded prims and its image at least
    /// [`point_index::PIXELS_PER_BOX`] `pixels` per box to list; with `Always`, whenever it
    /// has a BVH.
    #[allow(clippy::too_many_arguments)]
    fn new(
        prims: &[Prim],
        objects: &[Object],
        accel: &Accel,
        bvh_items: &[Item],
        eye: DVec3,
        lights: &[Light],
        mode: Acceleration,
        pixels: u64,
    ) -> PointTables {
        if accel.bvh().is_none() {
            return PointTables::default();
        }
        let wanted = match mode {
            Acceleration::Off => false,
            // The items come in prim order, a long object's pieces together.
            Acceleration::Auto => {
                bvh_items.chunk_by(|a, b| a.id == b.id).count() >= point_index::MIN_PRIMS
            }
            Acceleration::Always => true,
        };
        if !wanted {
            return PointTables::default();
        }
        // The BVH's own boxes: padded as it pads them, those it leaves out left out here too.
        let items: Vec<(u32, Aabb, f64)> = bvh_items
            .iter()
            .filter_map(|it| Some((it.id, crate::bvh::padded(&it.bounds)?, it.cost)))
            .collect();
        if mode == Acceleration::Auto
            && pixels < point_index::PIXELS_PER_BOX.saturating_mul(items.len() as u64)
        {
            return PointTables::default();
        }
        let quick = prims
            .iter()
            .map(|p| match p {
                Prim::Object(o) => objects[*o as usize].sphere,
                Prim::Csg(_) => None,
            })
            .map(|s| s.unwrap_or((DVec3::ZERO, f64::INFINITY)))
            .collect();
        // The eye's first, then the lights' in order, while the budget lasts: each table
        // lists every solid at least once, so once fewer entries than items are left, no
        // further table is tried (a scene of many solids under many lights spent seconds
        // trying, and failing, one table after another).
        let mut left = point_index::MAX_ENTRIES;
        let mut build = |p: DVec3| {
            if left < items.len() {
                return None;
            }
            let table = PointIndex::build(p, &items, left);
            left = match &table {
                Some(t) => left - t.size().0 - t.size().1,
                None => 0,
            };
            table
        };
        PointTables {
            eye: build(eye),
            lights: lights
                .iter()
                .take(point_index::MAX_LIGHTS)
                .map(|l| build(l.position))
                .collect(),
            quick,
        }
    }
}

/// What testing a prim costs in the BVH's SAH, in units of one node visit (the two-lane
/// test of two boxes, about 50 instructions). A sphere placed by a similarity is mostly
/// rejected by its packed pre-test before its object is touched, and is costed as one
/// visit (with the miss bookkeeping); any other object carries the ray into its own space
/// and solves its shape; a CSG tree does that for each child it reaches. Only the ratios
/// matter, and only roughly: they decide how many items a leaf holds. (Measured on the
/// scaling scenes, a sphere cost of 0.3, 0.5 or 1 changed instructions per ray by under 1%.)
fn prim_cost(prim: &Prim, objects: &[Object]) -> f64 {
    match prim {
        Prim::Object(o) if objects[*o as usize].sphere.is_some() => SPHERE_COST,
        Prim::Object(_) => 2.0,
        Prim::Csg(c) => c.cost(),
    }
}

/// SAH cost of a sphere placed by a similarity (see [`prim_cost`]).
const SPHERE_COST: f64 = 1.0;

impl Accel {
    /// The BVH, if there is one.
    fn bvh(&self) -> Option<&Bvh> {
        match self {
            Accel::Linear => None,
            Accel::Bvh { bvh, .. } => Some(bvh),
        }
    }

    /// The search `mode` asks for, with the items its BVH was built over (none for the plain
    /// loop), which the point tables list too.
    fn new(prims: &[Prim], objects: &[Object], mode: Acceleration) -> (Accel, Vec<Item>) {
        let bounded = bounded_prims(prims, objects);
        let wanted = match mode {
            Acceleration::Off => false,
            Acceleration::Auto => {
                bounded.len() >= BVH_MIN_PRIMS
                    || bounded.iter().map(|&(_, _, cost)| cost).sum::<f64>() >= BVH_MIN_COST
            }
            Acceleration::Always => !bounded.is_empty(),
        };
        // Prim indices fit in u32 (objects do, and every prim has at least one); a scene
        // where they did not would simply stay linear.
        if !wanted || u32::try_from(prims.len()).is_err() {
            return (Accel::Linear, Vec::new());
        }
        let items = bvh_items(prims, objects, &bounded);
        let (bvh, mut unbounded) = Bvh::build_items(&items);
        unbounded.extend(
            prims
                .iter()
                .enumerate()
                .filter(|(_, p)| p.bounds(objects).is_none())
                .map(|(i, _)| i as u32),
        );
        unbounded.sort_unstable();
        let quick = bvh
            .items()
            .iter()
            .map(|&i| {
                let sphere = match &prims[i as usize] {
                    Prim::Object(o) => objects[*o as usize].sphere,
                    Prim::Csg(_) => None,
                };
                let (centre, r2) = sphere.unwrap_or((DVec3::ZERO, f64::INFINITY));
                Quick {
                    prim: i,
                    centre,
                    r2,
                }
            })
            .collect();
        let accel = Accel::Bvh {
            bvh,
            unbounded,
            quick,
        };
        (accel, items)
    }
}

impl Scene {
    /// Parses `.ray` text and loads its textures: the one call a renderer needs.
    pub fn from_source(
        source: &str,
        limits: &Limits,
        assets: &dyn AssetSource,
        texture_limits: &TextureLimits,
    ) -> Result<Scene, SceneError> {
        let desc = scene::parse(source, limits)?;
        Scene::build(&desc, assets, texture_limits)
    }

    /// Loads the textures a description names and places its objects in the world. A texture
    /// that cannot be read or decoded is reported at the position of its name.
    pub fn build(
        desc: &SceneDesc,
        assets: &dyn AssetSource,
        texture_limits: &TextureLimits,
    ) -> Result<Scene, SceneError> {
        let (objects, prims) = Self::place(desc, assets, texture_limits)?;
        let (accel, items) = Accel::new(&prims, &objects, Acceleration::Auto);
        let clear_lights = ClearLights::find(&objects, &prims, &desc.lights, accel.bvh());
        let points = PointTables::new(
            &prims,
            &objects,
            &accel,
            &items,
            desc.camera.eye,
            &desc.lights,
            Acceleration::Auto,
            u64::from(desc.width) * u64::from(desc.height),
        );
        let lights_on = desc
            .lights
            .iter()
            .map(|l| surfaces_through(&objects, &prims, &accel, l.position))
            .collect();
        Ok(Scene {
            width: desc.width,
            height: desc.height,
            ambient: desc.ambient,
            shadow: desc.shadow,
            background: desc.background,
            max_depth: desc.max_depth,
            sampler: desc.sampler,
            camera: Camera::new(&desc.camera, desc.width, desc.height),
            lights: desc.lights.clone(),
            accel,
            points,
            clear_lights,
            lights_on,
            mirrors: objects.iter().filter(|o| o.material.mirror > 0.0).count(),
            objects,
            prims,
        })
    }

    /// Every error [`Self::build`] would report (textures that cannot be read or decoded,
    /// singular transforms), without building what only rendering needs (the BVH, the clear
    /// lights): what a service that accepts scenes but does not render them checks.
    pub fn check(
        desc: &SceneDesc,
        assets: &dyn AssetSource,
        texture_limits: &TextureLimits,
    ) -> Result<(), SceneError> {
        Self::place(desc, assets, texture_limits).map(|_| ())
    }

    /// The textures loaded and the objects placed in the world, or every error found.
    fn place(
        desc: &SceneDesc,
        assets: &dyn AssetSource,
        texture_limits: &TextureLimits,
    ) -> Result<(Vec<Object>, Vec<Prim>), SceneError> {
        let mut textures: HashMap<&str, Arc<Texture>> = HashMap::new();
        let mut errors = Vec::new();
        // Texels of the textures decoded so far, against `max_total_pixels`: each is sized
        // from its header before it is decoded, so the budget holds while loading too.
        let mut total: u64 = 0;
        for (name, pos) in desc.texture_names() {
            let loaded = assets.load(name).and_then(|bytes| {
                let (w, h) = Texture::dimensions(name, &bytes, texture_limits)?;
                let texels = u64::from(w) * u64::from(h);
                if total + texels > texture_limits.max_total_pixels {
                    return Err(TextureError::TooMuch {
                        name: name.to_string(),
                        texels,
                        total: total + texels,
                        limit: texture_limits.max_total_pixels,
                    });
                }
                total += texels;
                Texture::decode_sized(name, &bytes, texture_limits, (w, h))
            });
            match loaded {
                Ok(t) => {
                    textures.insert(name, Arc::new(t));
                }
                Err(e) => errors.push(Diagnostic::new(pos, e.to_string())),
            }
        }
        let mut objects = Vec::with_capacity(desc.primitive_count());
        let mut prims = Vec::with_capacity(desc.objects.len());
        for node in &desc.objects {
            let mut placer = Placer {
                objects: &mut objects,
                textures: &textures,
                errors: &mut errors,
            };
            if let Some(p) = placer.place(node, None) {
                prims.push(p);
            }
        }
        if !errors.is_empty() {
            return Err(SceneError::new(errors));
        }
        Ok((objects, prims))
    }

    /// The same scene with its candidate search rebuilt as `mode` says (and its clear
    /// lights found again, see [`crate::shadow`]). The images are the same whatever the
    /// mode; tests and benchmarks use [`Acceleration::Off`] as the reference.
    pub fn with_acceleration(mut self, mode: Acceleration) -> Scene {
        // CSG nodes with many children carry their own index (see `crate::csg`): kept at its
        // threshold by `Auto`, on every union and difference by `Always`, none with `Off`.
        let min = match mode {
            Acceleration::Auto => crate::csg::CSG_INDEX_MIN,
            Acceleration::Always => 1,
            Acceleration::Off => usize::MAX,
        };
        for prim in &mut self.prims {
            if let Prim::Csg(c) = prim {
                c.index_children(min);
            }
        }
        let items;
        (self.accel, items) = Accel::new(&self.prims, &self.objects, mode);
        self.points = PointTables::new(
            &self.prims,
            &self.objects,
            &self.accel,
            &items,
            self.camera.eye(),
            &self.lights,
            mode,
            u64::from(self.width) * u64::from(self.height),
        );
        self.clear_lights =
            ClearLights::find(&self.objects, &self.prims, &self.lights, self.accel.bvh());
        self
    }

    /// The same scene with its BVH but without the tables of rays through the eye and the
    /// lights ([`crate::point_index`]): every ray walks the tree. The reference the tables'
    /// tests and the benchmark compare against (the images are the same).
    pub fn without_point_tables(mut self) -> Scene {
        self.points = PointTables::default();
        self
    }

    /// Whether rays through the eye, and through how many lights, look up a table of their
    /// own (see [`crate::point_index`]).
    pub fn point_tables(&self) -> (bool, usize) {
        (
            self.points.eye.is_some(),
            self.points.lights.iter().filter(|l| l.is_some()).count(),
        )
    }

    /// The same scene tracing every shadow ray, even those [`crate::shadow`] knows cannot be
    /// blocked: the reference that tests and benchmarks compare the culling against (the
    /// images are the same).
    pub fn without_shadow_culling(mut self) -> Scene {
        self.clear_lights = ClearLights::default();
        self
    }

    /// The lone convex objects whose surface passes through light `light` (within the
    /// rounding of carrying the light into their space), each with its world outward normal
    /// there ([`Object::normals_through`]), once per supporting plane. Such an object cannot shadow its light from a
    /// point on the outer side of its tangent plane there: the object lies in the other
    /// half-space, and the segment meets it only at the light, which SCENE.md's segment
    /// does not include. Tracing it anyway decides by rounding: a shadow ray reaching the
    /// light nearly tangent meets the surface in two nearly equal roots, known only to
    /// about √ε, and some of them fell before the light.
    pub fn lights_on(&self, light: usize) -> &[(u32, DVec3)] {
        self.lights_on.get(light).map_or(&[], Vec::as_slice)
    }

    /// Whether a shadow ray from `object` (convex, left from outside) to light `light` is
    /// known not to be blocked without tracing it.
    pub fn light_is_clear(&self, object: u32, light: usize) -> bool {
        self.clear_lights.is_clear(object, light)
    }

    /// [`Self::light_is_clear`] for the first 64 lights at once, bit `l` for light `l`.
    #[inline]
    pub fn clear_lights(&self, object: u32) -> u64 {
        self.clear_lights.mask(object)
    }

    /// The same scene tested prim by prim for every ray (no BVH).
    pub fn without_acceleration(self) -> Scene {
        self.with_acceleration(Acceleration::Off)
    }

    /// The BVH and the prims it leaves out (planes, unbounded CSG), when rays use one.
    pub(crate) fn bvh_and_unbounded(&self) -> Option<(&Bvh, &[u32])> {
        match &self.accel {
            Accel::Linear => None,
            Accel::Bvh { bvh, unbounded, .. } => Some((bvh, unbounded)),
        }
    }

    /// Whether rays go through a BVH.
    pub fn uses_bvh(&self) -> bool {
        matches!(self.accel, Accel::Bvh { .. })
    }

    /// The nearest hit with `0 < t < t_max`. `skip` names an object the ray cannot meet
    /// again (see [`Shape::cannot_rehit`]), which is then not tested at all; it is only ever
    /// an object outside every CSG tree.
    ///
    /// Of hits at the very same `t`, the one on the prim written first wins, with or without
    /// a BVH: the linear loop keeps its first hit because later ones must be strictly
    /// nearer, and the BVH, which meets prims in another order, breaks ties on the prim index
    /// (see `intersect_bvh`).
    #[inline]
    pub fn intersect(&self, ray: &Ray, t_max: f64, skip: Option<u32>) -> Option<Hit> {
        self.intersect_in::<true>(ray, t_max, skip)
    }

    /// [`Self::intersect`], looking at the eye's table only if `TABLES` (for callers that
    /// know the scene has none: see [`Self::has_point_tables`]).
    #[inline]
    pub(crate) fn intersect_in<const TABLES: bool>(
        &self,
        ray: &Ray,
        t_max: f64,
        skip: Option<u32>,
    ) -> Option<Hit> {
        match &self.accel {
            Accel::Linear => self.intersect_linear(ray, t_max, skip),
            Accel::Bvh {
                bvh,
                unbounded,
                quick,
            } => {
                if TABLES
                    && let Some(eye) = &self.points.eye
                    && ray.origin == eye.point()
                    && let Some(listed) = eye.lookup(ray.dir)
                {
                    return self.intersect_listed(
                        eye.always(),
                        listed,
                        unbounded,
                        ray,
                        t_max,
                        skip,
                    );
                }
                self.intersect_bvh(bvh, unbounded, quick, ray, t_max, skip)
            }
        }
    }

    /// Offers prim `i` to a nearest-hit search whose best so far is `best` at `t_best`,
    /// unless a quick test already `rejected` it; with the tie rule of
    /// [`Self::intersect_bvh`].
    #[inline(always)]
    fn consider(
        &self,
        best: &mut Option<(Hit, u32)>,
        t_best: &mut f64,
        i: u32,
        rejected: bool,
        ray: &Ray,
        skip: Option<u32>,
    ) {
        if !rejected {
            let limit = match *best {
                Some((_, b)) if i < b => t_best.next_up(),
                _ => *t_best,
            };
            if let Some(h) = self.prim_hit(&self.prims[i as usize], ray, limit, skip) {
                *t_best = h.local.t;
                *best = Some((h, i));
            }
        }
    }

    /// The nearest hit of a ray from the eye, from the eye's table: the unbounded prims, the
    /// table's `always` prims, then the prims the direction's cell `listed` (sorted by their
    /// boxes' distance from the eye), until the next box is farther than the best hit. The
    /// same answer as [`Self::intersect_bvh`]: every prim the BVH would offer and could report
    /// a hit is offered, with the same tie rule.
    #[inline(never)]
    fn intersect_listed(
        &self,
        always: &[u32],
        listed: &[point_index::Entry],
        unbounded: &[u32],
        ray: &Ray,
        t_max: f64,
        skip: Option<u32>,
    ) -> Option<Hit> {
        let mut best: Option<(Hit, u32)> = None;
        let mut t_best = t_max;
        for &i in unbounded.iter().chain(always) {
            self.consider(&mut best, &mut t_best, i, false, ray, skip);
        }
        let dd = ray.dir.length_squared();
        for e in listed {
            // A hit at `t` lies `t·|d|` from the eye, inside the box: not nearer than the
            // box. The factor covers the rounding of `t²·|d|²` (see `point_index`) while it is
            // a normal number; below that, no stop.
            let reach = t_best * t_best * dd;
            if reach >= f64::MIN_POSITIVE && f64::from(e.near_sq) > reach * (1.0 + 1e-9) {
                break;
            }
            let (c, r2) = self.points.quick[e.prim as usize];
            let rejected = sphere_certainly_missed(c, r2, ray);
            self.consider(&mut best, &mut t_best, e.prim, rejected, ray, skip);
        }
        best.map(|(h, _)| h)
    }

    /// Every prim in order: a prim replaces the best hit only when strictly nearer.
    #[inline]
    fn intersect_linear(&self, ray: &Ray, t_max: f64, skip: Option<u32>) -> Option<Hit> {
        let mut best: Option<Hit> = None;
        let mut t_best = t_max;
        for prim in &self.prims {
            if let Some(h) = self.prim_hit(prim, ray, t_best, skip) {
                t_best = h.local.t;
                best = Some(h);
            }
        }
        best
    }

    /// The unbounded prims, then the BVH's candidates nearest first.
    ///
    /// Every prim test is a pure filter on its own `t` (a shape or CSG tree computes the
    /// same `t` whatever `t_max` it is given, and reports it iff `t < t_max`; a CSG tree's
    /// box shortcut is widened so that it cannot decide, see [`Csg::first_hit`]), so the linear
    /// loop's answer is the hit with the least `(t, prim index)`. Here prims come in another
    /// order; a prim written *before* the current best is therefore asked with the limit one
    /// ulp above `t_best`, so a hit at exactly `t_best` (and nothing beyond it) is reported
    /// and wins the tie, while a prim written after the best must still be strictly nearer.
    fn intersect_bvh(
        &self,
        bvh: &Bvh,
        unbounded: &[u32],
        quick: &[Quick],
        ray: &Ray,
        t_max: f64,
        skip: Option<u32>,
    ) -> Option<Hit> {
        let mut best: Option<(Hit, u32)> = None;
        let mut t_best = t_max;
        for &i in unbounded {
            self.consider(&mut best, &mut t_best, i, false, ray, skip);
        }
        bvh.traverse(ray.origin, ray.inv_dir(), t_max, |slot| {
            let q = &quick[slot];
            let rejected = sphere_certainly_missed(q.centre, q.r2, ray);
            self.consider(&mut best, &mut t_best, q.prim, rejected, ray, skip);
            ControlFlow::Continue(t_best)
        });
        best.map(|(h, _)| h)
    }

    /// The nearest hit on one prim with `0 < t < t_max`.
    #[inline]
    fn prim_hit(&self, prim: &Prim, ray: &Ray, t_max: f64, skip: Option<u32>) -> Option<Hit> {
        match prim {
            Prim::Object(i) => {
                if skip == Some(*i) {
                    return None;
                }
                let obj = &self.objects[*i as usize];
                if obj.certainly_missed_by(ray) {
                    return None;
                }
                let local_ray = obj.transform.ray_to_object(ray);
                obj.shape.intersect(&local_ray, t_max).map(|h| Hit {
                    object: *i,
                    local: h,
                })
            }
            Prim::Csg(c) => self.csg_hit(c, ray, t_max),
        }
    }

    /// The nearest hit on a CSG tree, as a hit on the child surface it lies on.
    fn csg_hit(&self, c: &Csg, ray: &Ray, t_max: f64) -> Option<Hit> {
        let b = c.first_hit(&self.objects, ray, t_max)?;
        let obj = &self.objects[b.surface.object as usize];
        let local_ray = obj.transform.ray_to_object(ray);
        let mut local = obj.shape.surface_at(&local_ray, b.t, b.surface.face);
        if b.surface.flip {
            local.n = -local.n;
        }
        Some(Hit {
            object: b.surface.object,
            local,
        })
    }

    /// Whether anything lies on the ray with `0 < t < t_max`. Any hit will do, so the BVH
    /// search stops at the first.
    #[inline]
    pub fn occluded(&self, ray: &Ray, t_max: f64, skip: Option<u32>) -> bool {
        self.occluded_unless(ray, t_max, move |i| skip == Some(i))
    }

    /// [`Self::occluded`], also leaving out the objects `also` (those a light lies on, for a
    /// point outside them: see [`Self::lights_on`]).
    #[inline]
    pub fn occluded_skipping(
        &self,
        ray: &Ray,
        t_max: f64,
        skip: Option<u32>,
        also: &[u32],
    ) -> bool {
        if also.is_empty() {
            return self.occluded(ray, t_max, skip);
        }
        self.occluded_unless(ray, t_max, move |i| skip == Some(i) || also.contains(&i))
    }

    /// Whether the eye or some light has a table (see [`crate::point_index`]).
    #[inline]
    pub(crate) fn has_point_tables(&self) -> bool {
        self.points.eye.is_some() || self.points.lights.iter().any(Option::is_some)
    }

    /// [`Self::occluded_skipping`] for a shadow ray towards light `light`. A ray built as the
    /// renderer builds them, `Ray::new(o, L − o)` for the light's position `L` with
    /// `t_max < 1` (see [`crate::render::SHADOW_END_REL`]), looks its candidates up in the
    /// light's table when there is one (see [`crate::point_index`]); any other ray, or a light
    /// without a table, walks the BVH. The answer is the same either way.
    #[inline]
    pub fn occluded_towards(
        &self,
        light: usize,
        ray: &Ray,
        t_max: f64,
        skip: Option<u32>,
        also: &[u32],
    ) -> bool {
        if let Accel::Bvh { unbounded, .. } = &self.accel
            && let Some(Some(table)) = self.points.lights.get(light)
            && t_max < 1.0
            && ray.dir == table.point() - ray.origin
            && table.shadow_lookup_ok(ray.dir)
            && let Some(listed) = table.lookup(-ray.dir)
        {
            let skip = move |i| skip == Some(i) || also.contains(&i);
            return self.occluded_listed(table.always(), listed, unbounded, ray, t_max, skip);
        }
        self.occluded_skipping(ray, t_max, skip, also)
    }

    /// The shadow answer from a light's table: the unbounded prims, the table's `always`
    /// prims and the prims the direction's cell `listed`, until one blocks.
    #[inline(never)]
    fn occluded_listed(
        &self,
        always: &[u32],
        listed: &[point_index::Entry],
        unbounded: &[u32],
        ray: &Ray,
        t_max: f64,
        skip: impl Fn(u32) -> bool + Copy,
    ) -> bool {
        // A point of the segment is at most `|d|` from the light (`t ≥ 0`; the rounding of
        // `d` adds 2⁻⁵³ of it, which the factor covers): listed boxes farther away, beyond
        // the ray's origin, cannot block it.
        let dd = ray.dir.length_squared();
        let reach = if dd >= f64::MIN_POSITIVE {
            dd * (1.0 + 1e-9)
        } else {
            f64::INFINITY
        };
        unbounded
            .iter()
            .chain(always)
            .any(|&i| self.prim_blocks(&self.prims[i as usize], ray, t_max, skip))
            || listed
                .iter()
                .take_while(|e| f64::from(e.near_sq) <= reach)
                .any(|e| {
                    let (c, r2) = self.points.quick[e.prim as usize];
                    !sphere_certainly_missed(c, r2, ray)
                        && self.prim_blocks(&self.prims[e.prim as usize], ray, t_max, skip)
                })
    }

    /// The any-hit search, leaving out the lone objects `skip` names. Generic so that the
    /// common search (one object left out, or none) costs no more than it did before
    /// lights on surfaces were known: each caller gets its own compiled copy.
    #[inline]
    fn occluded_unless(&self, ray: &Ray, t_max: f64, skip: impl Fn(u32) -> bool + Copy) -> bool {
        match &self.accel {
            Accel::Linear => self
                .prims
                .iter()
                .any(|prim| self.prim_blocks(prim, ray, t_max, skip)),
            Accel::Bvh {
                bvh,
                unbounded,
                quick,
            } => self.occluded_bvh(bvh, unbounded, quick, ray, t_max, skip),
        }
    }

    /// The unbounded prims, then the BVH's candidates until one blocks. Not inlined into
    /// the shading code, like [`Self::intersect_bvh`]: compiled on its own, the two-lane box
    /// test is vectorised the same way in both searches (inlined into the shader it was
    /// not, and cost half as much again).
    #[inline(never)]
    fn occluded_bvh(
        &self,
        bvh: &Bvh,
        unbounded: &[u32],
        quick: &[Quick],
        ray: &Ray,
        t_max: f64,
        skip: impl Fn(u32) -> bool + Copy,
    ) -> bool {
        unbounded
            .iter()
            .any(|&i| self.prim_blocks(&self.prims[i as usize], ray, t_max, skip))
            || bvh.traverse(ray.origin, ray.inv_dir(), t_max, |slot| {
                let q = &quick[slot];
                if !sphere_certainly_missed(q.centre, q.r2, ray)
                    && self.prim_blocks(&self.prims[q.prim as usize], ray, t_max, skip)
                {
                    ControlFlow::Break(())
                } else {
                    ControlFlow::Continue(t_max)
                }
            })
    }

    /// Whether one prim has a hit with `0 < t < t_max`.
    #[inline]
    fn prim_blocks(&self, prim: &Prim, ray: &Ray, t_max: f64, skip: impl Fn(u32) -> bool) -> bool {
        match prim {
            Prim::Object(i) => {
                let obj = &self.objects[*i as usize];
                !skip(*i)
                    && !obj.certainly_missed_by(ray)
                    && obj
                        .shape
                        .intersect(&obj.transform.ray_to_object(ray), t_max)
                        .is_some()
            }
            Prim::Csg(c) => c.first_hit(&self.objects, ray, t_max).is_some(),
        }
    }

    /// Whether a shadow ray leaving object `skip` can be blocked by anything at all.
    pub fn anything_else(&self, skip: Option<u32>) -> bool {
        match skip {
            Some(_) => self.prims.len() > 1,
            None => !self.prims.is_empty(),
        }
    }

    /// The object a ray leaving `hit` cannot meet again, if any: a convex primitive left
    /// from its outside, never a CSG child (the tree is tested as a whole).
    pub fn self_skip(&self, hit: &Hit, leaving_outside: bool) -> Option<u32> {
        let obj = &self.objects[hit.object as usize];
        (!obj.in_csg && obj.shape.cannot_rehit(leaving_outside)).then_some(hit.object)
    }
}

/// Places scene nodes in the world, flattening their primitives into `objects`.
struct Placer<'a, 'b> {
    objects: &'a mut Vec<Object>,
    textures: &'a HashMap<&'b str, Arc<Texture>>,
    errors: &'a mut Vec<Diagnostic>,
}

impl Placer<'_, '_> {
    /// The prim for a node; `outer` is the enclosing CSG's object-to-world transform.
    fn place(&mut self, node: &Node, outer: Option<&Transform>) -> Option<Prim> {
        let compose = |own: &Transform| match outer {
            Some(o) => own.then(o),
            None => *own,
        };
        match node {
            Node::Object(o) => {
                let transform = compose(&o.transform);
                if !transform.is_valid() {
                    self.errors.push(Diagnostic::new(
                        o.pos,
                        "this object's transforms and those of its [CSG] make a singular or \
                         non-finite matrix",
                    ));
                    return None;
                }
                let Ok(index) = u32::try_from(self.objects.len()) else {
                    self.errors
                        .push(Diagnostic::new(o.pos, "too many objects for one scene"));
                    return None;
                };
                self.objects.push(Object::new(
                    o.shape,
                    transform,
                    o.own_scale,
                    material(&o.material, self.textures),
                    outer.is_some(),
                ));
                Some(Prim::Object(index))
            }
            Node::Csg(c) => {
                let transform = compose(&c.transform);
                if !transform.is_valid() {
                    self.errors.push(Diagnostic::new(
                        c.pos,
                        "this [CSG]'s transforms and those of its enclosing [CSG] make a \
                         singular or non-finite matrix",
                    ));
                    return None;
                }
                let children: Vec<Prim> = c
                    .children
                    .iter()
                    .filter_map(|ch| self.place(ch, Some(&transform)))
                    .collect();
                Some(Prim::Csg(Csg::new(c.op, children, self.objects)))
            }
        }
    }
}

fn material(m: &MaterialDesc, textures: &HashMap<&str, Arc<Texture>>) -> Material {
    Material {
        color1: m.color1,
        color2: m.color2,
        texture: m
            .texture
            .as_ref()
            .and_then(|t| textures.get(t.name.as_str()).cloned()),
        mirror: m.mirror,
        diffuse: m.diffuse,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::shape::test_support::Rng;
    use crate::tile::Rect;
    use crate::{Limits, MemoryAssets, TextureLimits};

    fn build(src: &str) -> Result<Scene, SceneError> {
        Scene::from_source(
            src,
            &Limits::default(),
            &MemoryAssets::new(),
            &TextureLimits::default(),
        )
    }

    fn scene(src: &str) -> Scene {
        build(src).unwrap_or_else(|e| panic!("test scene does not build: {e}"))
    }

    fn render(s: &Scene) -> Vec<Color> {
        s.render_rect_linear(Rect::full(s.width, s.height)).0
    }

    #[test]
    fn every_shape_and_key_builds() {
        let s = scene(
            "[OBJECT]\ntype = cube\n[/OBJECT]\n\
             [OBJECT]\ntype = cylinder\nradius = 2\n[/OBJECT]\n\
             [OBJECT]\ntype = cone\n[/OBJECT]\n\
             [OBJECT]\ntype = torus\nmajor = 3\nminor = 0.5\n[/OBJECT]\n\
             [OBJECT]\ntype = torus\n[/OBJECT]\n",
        );
        let shapes: Vec<Shape> = s.objects.iter().map(|o| o.shape).collect();
        assert_eq!(
            shapes,
            [
                Shape::Cube,
                Shape::Cylinder,
                Shape::Cone,
                Shape::Torus {
                    major: 3.0,
                    minor: 0.5
                },
                Shape::Torus {
                    major: 1.0,
                    minor: 0.25
                },
            ]
        );
        // A cylinder's radius widens it in x and z only, and sizes its checker cells.
        assert_eq!(s.objects[1].own_scale, DVec3::new(2.0, 1.0, 2.0));
        let b = s.objects[1].bounds.expect("bounded");
        assert_eq!(
            (b.min, b.max),
            (DVec3::new(-2.0, -1.0, -2.0), DVec3::new(2.0, 1.0, 2.0))
        );
        // A torus's radii are its own: no scale, and its box is the ring's.
        assert_eq!(s.objects[3].own_scale, DVec3::ONE);
        let b = s.objects[3].bounds.expect("bounded");
        assert_eq!(b.max, DVec3::new(3.5, 0.5, 3.5));
    }

    #[test]
    fn spindle_and_horn_tori_are_refused_at_the_key() {
        for (keys, line) in [
            ("major = 1\nminor = 1", 3),
            ("major = 1\nminor = 2", 3),
            ("minor = 1.5", 3),
        ] {
            let e = build(&format!("[OBJECT]\ntype = torus\n{keys}\n[/OBJECT]\n"))
                .expect_err("a torus with minor >= major");
            let text = e.to_string();
            assert!(text.contains("minor") && text.contains("major"), "{text}");
            assert!(text.contains(&format!("{line}:")), "{text}");
        }
        let e = build("[OBJECT]\ntype = cube\nmajor = 2\n[/OBJECT]\n").expect_err("no major");
        assert!(e.to_string().contains("does not apply to a cube"), "{e}");
    }

    #[test]
    fn csg_children_compose_with_the_csg_transforms() {
        let s = scene(
            "[CSG]\nop = union\ntranslate = <10, 0, 0>\n\
             [CSG]\nop = union\nscale = 2\n\
             [OBJECT]\ntype = cube\ntranslate = <1, 0, 0>\n[/OBJECT]\n\
             [OBJECT]\ntype = sphere\n[/OBJECT]\n[/CSG]\n\
             [OBJECT]\ntype = cone\n[/OBJECT]\n[/CSG]\n\
             [OBJECT]\ntype = torus\n[/OBJECT]\n",
        );
        assert_eq!(s.objects.len(), 4);
        assert_eq!(s.prims.len(), 2);
        // The cube: own translate, then the inner scale, then the outer translate.
        let c = s.objects[0]
            .transform
            .to_world()
            .transform_point3(DVec3::ZERO);
        assert_eq!(c, DVec3::new(12.0, 0.0, 0.0));
        assert!(s.objects[..3].iter().all(|o| o.in_csg));
        assert!(!s.objects[3].in_csg);
        let b = s.prims[0].bounds(&s.objects).expect("bounded");
        assert_eq!((b.min.x, b.max.x), (8.0, 14.0));
        // Overflowing only once composed: refused at the object, not a panic or NaN.
        // Eleven steps of 1e15 (the largest number a scene may write) are 1e165 on each
        // side, 1e330 composed.
        let big = "scale = 1e15\n".repeat(11);
        let e = build(&format!(
            "[CSG]\nop = union\n{big}\
             [OBJECT]\ntype = cube\n{big}[/OBJECT]\n\
             [OBJECT]\ntype = cube\n[/OBJECT]\n[/CSG]\n",
        ))
        .expect_err("overflowing composite");
        assert!(e.to_string().contains("singular or non-finite"), "{e}");
    }

    /// `Scene::check` reports exactly what `Scene::build` reports (a composite transform that
    /// overflows, a texture that is missing and one that does not decode, all at once), and
    /// accepts what it accepts.
    #[test]
    fn check_reports_what_build_reports() {
        let desc = |src: &str| scene::parse(src, &Limits::default()).expect("parses");
        let mut assets = MemoryAssets::new();
        assets.insert("bad.ppm", b"P6\n2 2\n255\nxx".to_vec());
        let limits = TextureLimits::default();
        let big = "scale = 1e15\n".repeat(11);
        let bad = desc(&format!(
            "[CSG]\nop = union\n{big}[OBJECT]\ntype = cube\n{big}[/OBJECT]\n\
             [OBJECT]\ntype = cube\n[/OBJECT]\n[/CSG]\n\
             [OBJECT]\ntype = sphere\ntexture = missing.ppm\n[/OBJECT]\n\
             [OBJECT]\ntype = sphere\ntexture = bad.ppm\n[/OBJECT]\n",
        ));
        let from_build = Scene::build(&bad, &assets, &limits).expect_err("three errors");
        let from_check = Scene::check(&bad, &assets, &limits).expect_err("three errors");
        assert_eq!(from_check.to_string(), from_build.to_string());
        assert_eq!(from_check.diagnostics().len(), 3, "{from_check}");
        let good = desc("[OBJECT]\ntype = sphere\n[/OBJECT]\n");
        assert!(Scene::check(&good, &assets, &limits).is_ok());
    }

    /// The picture: a sphere minus a cube shows the cut face, lit by its own (flat)
    /// normal and coloured by the cube. The cube fills z > 0, so the sphere is cut to its
    /// back half and the camera on +z looks straight at the disc z = 0. Every pixel inside
    /// the disc must equal the exact-image value computed here from the plane z = 0 with
    /// normal +z: a sphere normal (or the sphere's colour) would be off by far more.
    #[test]
    fn sphere_minus_cube_shows_the_cut_face_lit_by_its_own_normal() {
        let s = scene(
            "[GLOBALS]\nwidth = 64\nheight = 64\nambient = 0.1\n[/GLOBALS]\n\
             [CAMERA]\neye = <0, 0, 10>\nfov = 14\n[/CAMERA]\n\
             [LIGHT]\nposition = <3, 4, 10>\n[/LIGHT]\n\
             [CSG]\nop = difference\n\
             [OBJECT]\ntype = sphere\ncolor1 = <0.8, 0.1, 0.1>\n[/OBJECT]\n\
             [OBJECT]\ntype = cube\nscale = 2\ntranslate = <0, 0, 2>\ncolor1 = <0.1, 0.7, 0.2>\n[/OBJECT]\n\
             [/CSG]\n",
        );
        let img = render(&s);
        let green = Color::new(0.1, 0.7, 0.2);
        let light = DVec3::new(3.0, 4.0, 10.0);
        let (mut inside, mut outside) = (0, 0);
        for y in 0..64u32 {
            for x in 0..64u32 {
                let r = s.camera.ray(f64::from(x) + 0.5, f64::from(y) + 0.5);
                let t = -r.origin.z / r.dir.z;
                let p = r.at(t);
                let rho = p.x.hypot(p.y);
                let got = img[(y * 64 + x) as usize];
                if rho < 0.98 {
                    let cos = DVec3::Z.dot((light - p).normalize());
                    let expect = green * (0.1 + cos);
                    assert!(
                        (got - expect).abs().max_element() < 1e-12,
                        "pixel ({x}, {y}): {got:?} vs {expect:?}"
                    );
                    inside += 1;
                } else if rho > 1.02 {
                    assert_eq!(got, Color::ZERO, "pixel ({x}, {y}) outside the disc");
                    outside += 1;
                }
            }
        }
        assert!(inside > 1500 && outside > 500, "{inside} {outside}");
    }

    /// With the only light at the eye, every point the eye sees is lit: the segment back to
    /// the light is the one the primary ray came along. So the image must not change when
    /// shadows are switched off; a pixel that does is a shadow ray hitting the surface it
    /// starts on ("acne"). Tori (which are re-tested by their own shadow rays), CSG surfaces
    /// of every kind, coincident faces, transforms and a scene 1e5 from the origin.
    #[test]
    fn a_light_at_the_eye_casts_no_visible_shadow() {
        let objects = "\
            [OBJECT]\ntype = torus\nmajor = 1.2\nminor = 0.45\nrotate = <60, 10, 0>\nscale = <1, 1.3, 0.8>\ntranslate = <-3, 1.5, 0>\n[/OBJECT]\n\
            [OBJECT]\ntype = torus\nmajor = 1\nminor = 0.02\nrotate = <75, 0, 0>\ntranslate = <3, 1.5, 0>\n[/OBJECT]\n\
            [CSG]\nop = difference\nrotate = <20, 35, 0>\ntranslate = <-3, -1.5, 0>\n\
            [OBJECT]\ntype = sphere\nradius = 1.2\n[/OBJECT]\n\
            [OBJECT]\ntype = cube\ntranslate = <1, 1, 1>\n[/OBJECT]\n\
            [OBJECT]\ntype = torus\nmajor = 1\nminor = 0.3\n[/OBJECT]\n[/CSG]\n\
            [CSG]\nop = difference\nrotate = <17, 29, 41>\n\
            [OBJECT]\ntype = cube\n[/OBJECT]\n\
            [OBJECT]\ntype = cube\nscale = <0.55, 2, 2>\ntranslate = <0.45, 0, 0>\n[/OBJECT]\n\
            [OBJECT]\ntype = cylinder\nradius = 0.4\nscale = <1, 3, 1>\n[/OBJECT]\n[/CSG]\n\
            [CSG]\nop = union\nrotate = <-20, 50, 10>\ntranslate = <3, -1.5, 0>\n\
            [OBJECT]\ntype = cube\nscale = 0.7\n[/OBJECT]\n\
            [OBJECT]\ntype = cone\nscale = 0.7\ntranslate = <0, 1.4, 0>\n[/OBJECT]\n\
            [OBJECT]\ntype = cylinder\nscale = 0.7\ntranslate = <1.4, 0, 0>\n[/OBJECT]\n[/CSG]\n";
        for offset in [DVec3::ZERO, DVec3::new(1e5, -2e5, 1e5)] {
            let (eye, at) = (DVec3::new(1.0, 2.0, 12.0) + offset, offset);
            let v = |p: DVec3| format!("<{}, {}, {}>", p.x, p.y, p.z);
            let moved = format!(
                "[CSG]\nop = union\ntranslate = {}\n{objects}[OBJECT]\ntype = sphere\nradius = 1e-3\ntranslate = <100, 0, 0>\n[/OBJECT]\n[/CSG]\n",
                v(offset)
            );
            let src = |shadow: f64| {
                format!(
                    "[GLOBALS]\nwidth = 160\nheight = 120\nambient = 0.1\nshadow = {shadow}\n[/GLOBALS]\n\
                     [CAMERA]\neye = {}\nlook_at = {}\nfov = 45\n[/CAMERA]\n\
                     [LIGHT]\nposition = {}\n[/LIGHT]\n{moved}",
                    v(eye),
                    v(at),
                    v(eye)
                )
            };
            let lit = render(&scene(&src(0.0)));
            let shadowed = render(&scene(&src(1.0)));
            let hit = lit.iter().filter(|c| c.max_element() > 0.0).count();
            assert!(hit > 2500, "only {hit} pixels show an object");
            let acne: Vec<usize> = (0..lit.len()).filter(|&i| lit[i] != shadowed[i]).collect();
            assert!(
                acne.is_empty(),
                "offset {offset:?}: {} acne pixels, first {:?}",
                acne.len(),
                &acne[..acne.len().min(5)]
            );
        }
    }

    /// The coincident-face rule seen in an image: a cube minus a cutter that shares its +x
    /// face, turned arbitrarily, with the camera looking down the turned x axis. Every pixel
    /// of the cut face shows the cutter's green; a sliver of the body's face would be red.
    #[test]
    fn coincident_difference_renders_without_speckles() {
        let rot = crate::transform::Transform::from_op(crate::transform::TransformOp::Rotate(
            DVec3::new(17.0, 29.0, 41.0),
        ));
        let eye = rot.to_world().transform_vector3(DVec3::new(10.0, 0.0, 0.0));
        let up = rot.to_world().transform_vector3(DVec3::Y);
        let s = scene(&format!(
            "[GLOBALS]\nwidth = 100\nheight = 100\nambient = 0.2\n[/GLOBALS]\n\
             [CAMERA]\neye = <{}, {}, {}>\nup = <{}, {}, {}>\nfov = 14\n[/CAMERA]\n\
             [LIGHT]\nposition = <{}, {}, {}>\n[/LIGHT]\n\
             [CSG]\nop = difference\nrotate = <17, 29, 41>\n\
             [OBJECT]\ntype = cube\ncolor1 = <1, 0, 0>\n[/OBJECT]\n\
             [OBJECT]\ntype = cube\nscale = <0.55, 2, 2>\ntranslate = <0.45, 0, 0>\ncolor1 = <0, 1, 0>\n[/OBJECT]\n\
             [/CSG]\n",
            eye.x, eye.y, eye.z, up.x, up.y, up.z, eye.x, eye.y, eye.z
        ));
        let img = render(&s);
        let mut green = 0;
        for (i, c) in img.iter().enumerate() {
            assert_eq!(c.x, 0.0, "pixel {i} shows the body's face: {c:?}");
            green += usize::from(c.y > 0.5);
        }
        // The cut face fills the middle of the view (|y|, |z| < 1 seen from 11 away).
        assert!(green > 3000, "{green}");
    }

    /// A checkered cube whose faces lie exactly on cell boundaries (x = ±1), turned so that
    /// object-space coordinates are inexact: every pixel shows the cell its analytic hit
    /// point lies in. Without snapping the face coordinate to ±1, `floor(0.999…)` would
    /// flip about half the pixels of some faces to the other colour.
    #[test]
    fn checkered_cube_faces_have_no_speckle() {
        let s = scene(
            "[GLOBALS]\nwidth = 120\nheight = 120\nambient = 1\n[/GLOBALS]\n\
             [CAMERA]\neye = <4, 5, 12>\nfov = 30\n[/CAMERA]\n\
             [OBJECT]\ntype = cube\nscale = 2.5\nrotate = <10, 25, 0>\n\
             color1 = 1\ncolor2 = 0.25\n[/OBJECT]\n",
        );
        let img = render(&s);
        let obj = &s.objects[0];
        let mut checked = 0;
        for y in 0..120u32 {
            for x in 0..120u32 {
                let r = obj
                    .transform
                    .ray_to_object(&s.camera.ray(f64::from(x) + 0.5, f64::from(y) + 0.5));
                // The nearest face plane crossing inside its face, by brute force.
                let mut best: Option<(f64, DVec3)> = None;
                for axis in 0..3 {
                    for side in [-1.0, 1.0] {
                        let t = (side - r.origin[axis]) / r.dir[axis];
                        let mut p = r.at(t);
                        p[axis] = side;
                        let on_face = (0..3).all(|i| i == axis || p[i].abs() <= 1.0);
                        if t > 0.0 && on_face && best.is_none_or(|(bt, _)| t < bt) {
                            best = Some((t, p));
                        }
                    }
                }
                let got = img[(y * 120 + x) as usize].x;
                let Some((_, p)) = best else {
                    assert_eq!(got, 0.0);
                    continue;
                };
                // Skip pixels within 1e-6 of a cell edge inside the face (x = 0 lines).
                if (0..3)
                    .any(|i| p[i].abs() < 1e-6 || (p[i].abs() > 1.0 - 1e-6 && p[i].abs() < 1.0))
                {
                    continue;
                }
                let parity = (p.x.floor() + p.y.floor() + p.z.floor()) as i64 & 1;
                let expect = if parity == 0 { 1.0 } else { 0.25 };
                assert_eq!(got, expect, "pixel ({x}, {y}) at {p:?}");
                checked += 1;
            }
        }
        assert!(checked > 4000, "{checked}");
    }

    /// Mirrors see CSG: a mirror floor under a sphere whose lower part is cut away by a
    /// green cube shows the green cut face, which the camera cannot see directly; and the
    /// mirror rays' own shadows through the CSG are consistent (the reflected face is lit by
    /// a light low enough to reach it).
    #[test]
    fn a_mirror_shows_the_cut_face_underneath() {
        let s = scene(
            "[GLOBALS]\nwidth = 120\nheight = 90\nambient = 0.2\n[/GLOBALS]\n\
             [CAMERA]\neye = <0, 3.5, 12>\nlook_at = <0, 1, 0>\nfov = 30\n[/CAMERA]\n\
             [LIGHT]\nposition = <0, 0.3, 8>\n[/LIGHT]\n\
             [OBJECT]\ntype = plane\nmirror = 1\n[/OBJECT]\n\
             [CSG]\nop = difference\ntranslate = <0, 2.5, 0>\n\
             [OBJECT]\ntype = sphere\ncolor1 = <0.9, 0.1, 0.1>\n[/OBJECT]\n\
             [OBJECT]\ntype = cube\nscale = 2\ntranslate = <0, -2.5, 0>\ncolor1 = <0.1, 0.9, 0.1>\n[/OBJECT]\n\
             [/CSG]\n",
        );
        let img = render(&s);
        // The horizon (the floor's far edge) is where camera rays turn level.
        let mut green_rows = Vec::new();
        for y in 0..90u32 {
            for x in 0..120u32 {
                let c = img[(y * 120 + x) as usize];
                if c.y > 2.0 * c.x && c.y > 0.05 {
                    green_rows.push(y);
                    let r = s.camera.ray(f64::from(x) + 0.5, f64::from(y) + 0.5);
                    assert!(r.dir.y < 0.0, "green seen directly at ({x}, {y})");
                }
            }
        }
        assert!(green_rows.len() > 50, "{}", green_rows.len());
    }

    /// The example scenes build, with their textures, and show objects mid-image.
    #[test]
    fn examples_build_and_render() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples");
        for name in ["shapes.ray", "csg.ray"] {
            let src = std::fs::read_to_string(dir.join(name))
                .unwrap_or_else(|e| panic!("examples/{name}: {e}"));
            let s = Scene::from_source(
                &src,
                &Limits::default(),
                &crate::DirAssets::new(&dir),
                &TextureLimits::default(),
            )
            .unwrap_or_else(|e| panic!("examples/{name}: {e}"));
            let rect = Rect::new(s.width / 2 - 20, s.height / 2 - 20, 40, 40);
            let (px, _) = s.render_rect_linear(rect);
            assert!(px.iter().any(|c| *c != s.background), "examples/{name}");
        }
    }

    /// The sphere pre-test never rejects a ray the exact test hits: rays grazing the
    /// silhouette within 1e-9 of the radius (either side), from near and from 1e6 radii away,
    /// on spheres large and small, near the origin and far from it.
    /// A plain white Lambertian object: the shape and placement are what a test varies.
    fn white(shape: Shape, t: Transform) -> Object {
        Object::new(
            shape,
            t,
            DVec3::ONE,
            Material {
                color1: Color::ONE,
                color2: None,
                texture: None,
                mirror: 0.0,
                diffuse: 1.0,
            },
            false,
        )
    }

    #[test]
    fn sphere_pre_test_rejects_only_misses() {
        let mut rng = Rng::new(99);
        let mut rejected = 0;
        for _ in 0..20000 {
            let r = 10f64.powf(rng.range(-3.0, 3.0));
            let c = rng.in_ball(1.0) * 10f64.powf(rng.range(0.0, 5.0));
            let t = Transform::from_op(crate::transform::TransformOp::Scale(DVec3::splat(r))).then(
                &Transform::from_op(crate::transform::TransformOp::Translate(c)),
            );
            let obj = white(Shape::Sphere, t);
            let dist = r * 10f64.powf(rng.range(0.0, 6.0));
            let o = c + rng.direction() * dist;
            let to = c - o;
            let side = to.any_orthonormal_vector();
            // Aim within 1e-9 (relative) of the silhouette, or anywhere near it.
            let offset = if rng.range(0.0, 1.0) < 0.5 {
                r * (1.0 + rng.range(-1e-9, 1e-9))
            } else {
                r * rng.range(0.0, 3.0)
            };
            let ray = Ray::new(o, (c + side * offset - o) * rng.range(0.1, 10.0));
            let exact = obj
                .shape
                .intersect(&obj.transform.ray_to_object(&ray), f64::INFINITY);
            if obj.certainly_missed_by(&ray) {
                assert!(
                    exact.is_none(),
                    "rejected a hit: {ray:?} on r = {r}, c = {c:?}"
                );
                rejected += 1;
            }
        }
        assert!(rejected > 2000, "{rejected}");
    }

    #[test]
    fn random_csg_rays_are_finite_and_within_t_max() {
        let s = scene(
            "[CSG]\nop = intersection\n\
             [CSG]\nop = difference\n[OBJECT]\ntype = torus\nmajor = 1\nminor = 0.5\n[/OBJECT]\n\
             [OBJECT]\ntype = cone\n[/OBJECT]\n[/CSG]\n\
             [OBJECT]\ntype = cylinder\nradius = 1.4\nscale = <1, 0.3, 1>\n[/OBJECT]\n[/CSG]\n",
        );
        let mut rng = Rng::new(41);
        for _ in 0..3000 {
            let o = rng.in_ball(3.0);
            let r = Ray::new(o, rng.in_ball(2.0) - o);
            let t_max = rng.range(0.0, 3.0);
            if let Some(h) = s.intersect(&r, t_max, None) {
                assert!(h.local.t > 0.0 && h.local.t < t_max);
                assert!(h.local.p.is_finite() && h.local.n.is_finite());
                assert!(s.occluded(&r, t_max, None));
            } else {
                assert!(!s.occluded(&r, t_max, None));
            }
        }
    }
    /// The slices of a cylinder or cone hold every hit on it, under transforms that turn,
    /// stretch and shear it (a CSG-free composition of scales and rotations), with rays
    /// aimed at the surface, at the rim and along the axis; and a long rod laid diagonally
    /// is cut into several slices whose boxes are far smaller in total than its own box.
    #[test]
    fn pieces_hold_every_hit() {
        use crate::transform::TransformOp;
        let mut rng = Rng::new(5);
        let mut hits = 0;
        for k in 0..400 {
            let shape = if k % 2 == 0 {
                Shape::Cylinder
            } else {
                Shape::Cone
            };
            let op = |o| Transform::from_op(o);
            let len = 10f64.powf(rng.range(-1.0, 2.0));
            let t = op(TransformOp::Scale(DVec3::new(
                rng.range(0.01, 1.0),
                len,
                rng.range(0.01, 1.0),
            )))
            .then(&op(TransformOp::Rotate(rng.in_ball(180.0))))
            .then(&op(TransformOp::Scale(DVec3::new(
                rng.range(0.5, 2.0),
                rng.range(0.5, 2.0),
                rng.range(0.5, 2.0),
            ))))
            .then(&op(TransformOp::Rotate(rng.in_ball(180.0))))
            .then(&op(TransformOp::Translate(rng.in_ball(1e3))));
            let obj = white(shape, t);
            let pieces: Vec<Aabb> = obj
                .pieces()
                .iter()
                .map(|b| crate::bvh::padded(b).expect("a finite transform gives finite slices"))
                .collect();
            assert!(!pieces.is_empty() && pieces.len() <= MAX_PIECES);
            let whole = obj.bounds.expect("bounded shape");
            for _ in 0..100 {
                // A target on the solid: its surface, rim or axis, in object space.
                let y = [-1.0, 1.0, rng.range(-1.0, 1.0)][rng.range(0.0, 3.0) as usize];
                let rho = if shape == Shape::Cone {
                    (1.0 - y) / 2.0
                } else {
                    1.0
                };
                let phi = rng.range(0.0, std::f64::consts::TAU);
                let r = rho * [1.0, rng.range(0.0, 1.0), 0.0][rng.range(0.0, 3.0) as usize];
                let target =
                    t.to_world()
                        .transform_point3(DVec3::new(r * phi.cos(), y, r * phi.sin()));
                let o = target + rng.direction() * rng.range(0.1, 1e4);
                let ray = Ray::new(o, (target - o) * rng.range(0.1, 10.0));
                let Some(h) = obj.shape.intersect(&t.ray_to_object(&ray), f64::INFINITY) else {
                    continue;
                };
                hits += 1;
                let inv = ray.inv_dir();
                assert!(
                    pieces.iter().any(|b| {
                        b.hit_interval(o, inv, h.t + h.t * crate::bvh::SLACK)
                            .is_some()
                    }),
                    "{shape:?} {k}: hit at t = {} in no slice",
                    h.t
                );
            }
            // Never looser than the box of the transformed unit cube (up to the padding).
            let (lo, hi) = pieces
                .iter()
                .fold((DVec3::INFINITY, DVec3::NEG_INFINITY), |(a, b), p| {
                    (a.min(p.min), b.max(p.max))
                });
            let pad =
                (whole.max - whole.min).max_element() * 1e-6 + whole.max.abs().max_element() * 1e-6;
            assert!(lo.cmpge(whole.min - pad).all() && hi.cmple(whole.max + pad).all());
        }
        assert!(hits > 20000, "{hits}");
        // A rod of radius 0.1 and length 14 at 35° in the xy plane: cut, and much tighter.
        let rod = scene(
            "[OBJECT]\ntype = cylinder\nradius = 0.1\nscale = <1, 7, 1>\nrotate = <0, 0, 35>\n[/OBJECT]\n",
        );
        let obj = &rod.objects[0];
        let pieces = obj.pieces();
        let area: f64 = pieces.iter().map(Aabb::surface_area).sum();
        let whole = obj.bounds.expect("bounded").surface_area();
        assert!(pieces.len() >= 8, "{}", pieces.len());
        assert!(area < 0.2 * whole, "{area} vs {whole}");
        // Shapes that are not cut.
        for shape in ["sphere", "cube", "torus\nmajor = 1\nminor = 0.2"] {
            let s = scene(&format!(
                "[OBJECT]\ntype = {shape}\nscale = <1, 9, 1>\n[/OBJECT]\n"
            ));
            assert!(s.objects[0].pieces().is_empty(), "{shape}");
        }
    }
}
