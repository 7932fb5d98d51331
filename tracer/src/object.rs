//! A primitive placed in the world: its shape, its object-to-world transform, its material
//! with textures loaded, its world bounds, and the cheap world-space tests and boxes that
//! the BVH, the CSG index, shadow culling and the pixel footprints build on.
//!
//! This module sits below [`crate::world`], [`crate::csg`] and [`crate::shadow`], which all
//! read objects; it knows nothing of scenes, trees or lights.

use std::sync::Arc;

use arrayvec::ArrayVec;
use glam::DVec3;

use crate::math::{Aabb, Color, Ray};
use crate::shape::Shape;
use crate::texture::Texture;
use crate::transform::Transform;

/// Surface properties with textures loaded.
#[derive(Debug, Clone)]
pub struct Material {
    /// The colour, or a checker's first colour.
    pub color1: Color,
    /// A checker's second colour.
    pub color2: Option<Color>,
    /// The loaded texture, shared by every object that names the same file.
    pub texture: Option<Arc<Texture>>,
    /// Mirror weight in [0, 1].
    pub mirror: f64,
    /// Weight of the lights' Lambertian term.
    pub diffuse: f64,
}

/// A primitive placed in the world.
#[derive(Debug, Clone)]
pub struct Object {
    /// The unit shape.
    pub shape: Shape,
    /// Unit shape to world, every enclosing CSG's transform included.
    pub transform: Transform,
    /// Unit shape to the shape's own space (where checker cells are unit cubes).
    pub own_scale: DVec3,
    /// How its surface looks.
    pub material: Material,
    /// World bounds; `None` when unbounded.
    pub bounds: Option<Aabb>,
    /// Whether the object is part of a CSG tree (then the ray meets the tree, not the
    /// object, and the object's own convexity says nothing about hitting it again).
    pub in_csg: bool,
    /// For a sphere placed by a similarity (uniform scale and translation): its world centre
    /// and squared radius, for [`Object::certainly_missed_by`].
    pub(crate) sphere: Option<(DVec3, f64)>,
    /// For a cylinder or cone: the tube around its axis that holds it, for the same test.
    rod: Option<Rod>,
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
        let rod = match shape {
            Shape::Cylinder | Shape::Cone => Rod::around(&transform),
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
            rod,
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
    ///
    /// For a cylinder or cone, whether the ray's line passes clearly outside the tube around
    /// its axis that holds it (see `Rod`): rays that pass near a thin rod's box, most of
    /// them missing the rod, are turned away before their object-space ray is made.
    #[inline]
    pub fn certainly_missed_by(&self, ray: &Ray) -> bool {
        if let Some((c, r2)) = self.sphere {
            return sphere_certainly_missed(c, r2, ray);
        }
        self.rod.as_ref().is_some_and(|rod| rod.clears(ray))
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
    /// across its axis into up to `MAX_PIECES` slices, each bounded exactly; empty for
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
    /// (`crate::bvh::SLACK`), a margin nine orders wider, and the slices share their end
    /// discs, so the padded boxes together hold the solid and every computed hit on it.
    pub fn pieces(&self) -> Vec<Aabb> {
        self.slices().into_iter().map(|p| p.bounds).collect()
    }

    /// The same slices as [`Object::pieces`], each with its box and a capsule that holds it
    /// (see `Piece`); empty for shapes that are not cut.
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
    /// footprints (`crate::footprint`): a long cylinder's or cone's slices
    /// ([`Object::slices`]), and for a torus one capsule per chord of its core circle
    /// (`RING_CHORDS`); empty for every other shape.
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

/// The infinite tube around a cylinder's or cone's axis that holds the whole solid: the
/// axis line through `a` along `u`, and a squared radius `r2`.
///
/// The unit solid lies in `x² + z² ≤ 1` (the cone's radius `(1 − y)/2` is at most 1 in the
/// slab `|y| ≤ 1`). Its point `M·(x, y, z) + t` lies `|M·(x, 0, z)|` or less from the axis
/// point `M·(0, y, 0) + t`, and `|M·(x, 0, z)| ≤ σ` for `x² + z² ≤ 1`, where `σ²` is the
/// largest eigenvalue of the Gram matrix of `M·x̂` and `M·ẑ`. So `a = t`, `u = M·ŷ`,
/// `r2 = σ²` bound any linear part, sheared or not. A tube rather than a capsule: the test
/// is a line against a line, cheaper than against a segment, and only rays passing the
/// axis's extension beyond the solid's ends are left to the exact test for nothing.
#[derive(Debug, Clone, Copy)]
struct Rod {
    a: DVec3,
    u: DVec3,
    uu: f64,
    r2: f64,
}

impl Rod {
    /// The tube of the unit cylinder or cone placed by `transform`; `None` when its figures
    /// are not finite (the test would then reject nothing anyway).
    fn around(transform: &Transform) -> Option<Rod> {
        let m = transform.to_world().matrix3;
        let (x, z) = (m.x_axis, m.z_axis);
        let (p, q, r) = (x.dot(x), z.dot(z), x.dot(z));
        let half = 0.5 * (p - q);
        let r2 = 0.5 * (p + q) + (half * half + r * r).sqrt();
        let rod = Rod {
            a: transform.to_world().translation,
            u: m.y_axis,
            uu: m.y_axis.dot(m.y_axis),
            r2,
        };
        (rod.a.is_finite() && rod.u.is_finite() && rod.uu.is_finite() && r2.is_finite())
            .then_some(rod)
    }

    /// Whether the ray's line passes outside the tube by a margin.
    ///
    /// With `f = o − a` and `w = d × u`, the line's distance from the axis is `|f·w|/|w|`,
    /// so it clears the tube when `(f·w)² > r2·|w|²`. The test asks for more: a margin of
    /// `1e-9·S·|d|²|u|²` with `S = |f|² + |o|² + |a|² + r2`. Computed, `(f·w)²` is off by
    /// some `10ε·S·|d|²|u|²`; the exact test, through a matrix of condition up to
    /// [`crate::transform::MAX_CONDITION`] (1e8), places a line within about `1e-8·√S` of
    /// where it is, a squared distance of `1e-16·S` beside the margin's `1e-9·S`. A line
    /// nearly along the axis (`|w|` near 0) never clears, nor does one whose figures
    /// overflow (∞ or NaN fail `>`).
    #[inline]
    fn clears(&self, ray: &Ray) -> bool {
        let (o, d) = (ray.origin, ray.dir);
        let f = o - self.a;
        let w = d.cross(self.u);
        let fw = f.dot(w);
        let scale = f.dot(f) + o.dot(o) + self.a.dot(self.a) + self.r2;
        fw * fw > w.dot(w) * self.r2 + 1e-9 * scale * d.dot(d) * self.uu
    }
}

/// The test of [`Object::certainly_missed_by`] for centre `c` and squared radius `r2`.
/// With `r2 = ∞` it rejects nothing (the right side is ∞, or NaN when `d = 0`, and `>`
/// fails for both).
#[inline]
pub(crate) fn sphere_certainly_missed(c: DVec3, r2: f64, ray: &Ray) -> bool {
    line_clears_ball(c, r2, ray, 0.0)
}

/// [`sphere_certainly_missed`] for the per-prim quick tests of the BVH's items and the
/// point tables' entries, where prims other than similarity spheres carry `r2 = ∞`: for
/// those it answers before any arithmetic (a rod's slices list it several times to a ray).
#[inline]
pub(crate) fn quick_missed(c: DVec3, r2: f64, ray: &Ray) -> bool {
    r2 < f64::INFINITY && sphere_certainly_missed(c, r2, ray)
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
