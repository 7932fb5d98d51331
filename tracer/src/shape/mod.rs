//! Unit shapes in their own object space: where a ray meets them, and what the surface is
//! like there (normal, texture coordinates, error bound of the hit point).
//!
//! Every shape answers two questions about an object-space ray:
//! - [`Shape::intersect`]: the nearest hit with `0 < t < t_max` (the fast path for plain
//!   objects and shadow rays);
//! - [`Shape::spans`]: every parameter interval along the whole line where the ray is inside
//!   the solid, which is what CSG combines.
//!
//! A hit is reported as a [`LocalHit`]: the parameter, the point *projected back onto the
//! surface* (so its error is the small, shape-specific bound in `p_err`, not the error of
//! `o + t·d`), and the outward normal. Placing shapes in the world is
//! [`crate::transform`]'s job; choosing colours is [`crate::world::Material`]'s.
//!
//! Adding a shape means adding a variant here and a module implementing the same functions;
//! the scene parser maps the `type` keyword to the variant.

mod cone;
mod cube;
mod cylinder;
mod plane;
mod sphere;
mod torus;

use glam::{DVec2, DVec3};

use crate::math::{Aabb, Ray};

/// The unit shapes of the `.ray` format.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Shape {
    /// Unit sphere at the origin.
    Sphere,
    /// The plane y = 0, normal +y; as a solid (for CSG) the half-space y ≤ 0.
    Plane,
    /// The cube [-1, 1]³. Faces: `2·axis + (side > 0)`, so 0 = −x, 1 = +x, … 5 = +z.
    Cube,
    /// The cylinder of radius 1 around the y axis, y in [-1, 1], with both caps.
    /// Faces: 0 side, 1 bottom cap (y = -1), 2 top cap (y = 1).
    Cylinder,
    /// The cone with apex (0, 1, 0) and base radius 1 at y = -1, base capped.
    /// Faces: 0 side, 1 base.
    Cone,
    /// The ring torus around the y axis in the xz plane: points at distance `minor` from the
    /// circle of radius `major`. `0 < minor < major` (the parser refuses the others).
    Torus {
        /// Radius of the core circle.
        major: f64,
        /// Radius of the tube.
        minor: f64,
    },
}

/// A ray–surface hit in object space.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LocalHit {
    /// Where along the ray, in units of its direction.
    pub t: f64,
    /// The hit point, projected onto the surface.
    pub p: DVec3,
    /// Absolute per-axis bound on the error of `p`.
    pub p_err: DVec3,
    /// Outward normal (not necessarily unit length).
    pub n: DVec3,
    /// Which face of a shape with several (cube sides, caps); 0 for single-surface shapes.
    pub face: u8,
}

/// One end of a [`Span`]: where the ray crosses the surface, and which face it crosses.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Crossing {
    pub t: f64,
    pub face: u8,
}

/// An interval of the ray parameter inside a solid. Ends may be infinite (a half-space).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Span {
    pub enter: Crossing,
    pub exit: Crossing,
}

/// How texture coordinates continue past the `[0, 1]` square.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Wrap {
    /// The texture tiles (longitude around a sphere; the unit squares of a plane).
    Repeat,
    /// The edge texel continues (latitude at a sphere's poles).
    Clamp,
}

/// Texture coordinates of a surface point, in `[0, 1]²`, with their wrap modes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SurfaceUv {
    pub uv: DVec2,
    pub wrap_u: Wrap,
    pub wrap_v: Wrap,
}

impl Shape {
    /// The `type` keyword for this shape.
    pub fn keyword(&self) -> &'static str {
        match self {
            Shape::Sphere => "sphere",
            Shape::Plane => "plane",
            Shape::Cube => "cube",
            Shape::Cylinder => "cylinder",
            Shape::Cone => "cone",
            Shape::Torus { .. } => "torus",
        }
    }

    /// The nearest hit with `0 < t < t_max`, if any. NaN parameters are never hits.
    #[inline]
    pub fn intersect(&self, ray: &Ray, t_max: f64) -> Option<LocalHit> {
        match self {
            Shape::Sphere => sphere::intersect(ray, t_max),
            Shape::Plane => plane::intersect(ray, t_max),
            Shape::Cube => cube::intersect(ray, t_max),
            Shape::Cylinder => cylinder::intersect(ray, t_max),
            Shape::Cone => cone::intersect(ray, t_max),
            Shape::Torus { major, minor } => torus::intersect(ray, t_max, *major, *minor),
        }
    }

    /// Appends, in increasing order, every interval of the whole line (any `t`, negative too)
    /// along which the ray is inside the solid.
    pub fn spans(&self, ray: &Ray, out: &mut Vec<Span>) {
        match self {
            Shape::Sphere => sphere::spans(ray, out),
            Shape::Plane => plane::spans(ray, out),
            Shape::Cube => cube::spans(ray, out),
            Shape::Cylinder => cylinder::spans(ray, out),
            Shape::Cone => cone::spans(ray, out),
            Shape::Torus { major, minor } => torus::spans(ray, out, *major, *minor),
        }
    }

    /// The surface point where the ray crosses `face` at `t` (as reported by [`Self::spans`]),
    /// projected onto the surface, with its error bound and normal.
    pub fn surface_at(&self, ray: &Ray, t: f64, face: u8) -> LocalHit {
        match self {
            Shape::Sphere => sphere::surface_at(ray, t),
            Shape::Plane => plane::surface_at(ray, t, face),
            Shape::Cube => cube::surface_at(ray, t, face),
            Shape::Cylinder => cylinder::surface_at(ray, t, face),
            Shape::Cone => cone::surface_at(ray, t, face),
            Shape::Torus { major, minor } => torus::surface_at(ray, t, *major, *minor),
        }
    }

    /// Texture coordinates of a surface point.
    pub fn uv(&self, p: DVec3, face: u8) -> SurfaceUv {
        match self {
            Shape::Sphere => sphere::uv(p),
            Shape::Plane => plane::uv(p, face),
            Shape::Cube => cube::uv(p, face),
            Shape::Cylinder => cylinder::uv(p, face),
            Shape::Cone => cone::uv(p, face),
            Shape::Torus { major, .. } => torus::uv(p, *major),
        }
    }

    /// Object-space bounds; `None` for unbounded shapes.
    pub fn bounds(&self) -> Option<Aabb> {
        match self {
            Shape::Sphere | Shape::Cube | Shape::Cylinder | Shape::Cone => {
                Some(Aabb::new(DVec3::splat(-1.0), DVec3::splat(1.0)))
            }
            Shape::Plane => None,
            Shape::Torus { major, minor } => {
                let e = DVec3::new(major + minor, *minor, major + minor);
                Some(Aabb::new(-e, e))
            }
        }
    }

    /// Whether a ray that starts on this surface can meet the surface again, given the side
    /// it leaves on. A convex solid cannot be met again by a ray leaving its outside; a plane
    /// cannot be met again from either side. The tracer then skips the test altogether, which
    /// is both faster and immune to self-intersection. A torus is not convex: a ray leaving
    /// it can meet it again across the hole, so it is always tested.
    pub fn cannot_rehit(&self, leaving_outside: bool) -> bool {
        match self {
            Shape::Plane => true,
            Shape::Sphere | Shape::Cube | Shape::Cylinder | Shape::Cone => leaving_outside,
            Shape::Torus { .. } => false,
        }
    }

    /// Whether an object-space point is inside the closed solid (for CSG tests).
    pub fn contains(&self, p: DVec3) -> bool {
        match self {
            Shape::Sphere => p.length_squared() <= 1.0,
            Shape::Plane => p.y <= 0.0,
            Shape::Cube => p.abs().max_element() <= 1.0,
            Shape::Cylinder => cylinder::contains(p),
            Shape::Cone => cone::contains(p),
            Shape::Torus { major, minor } => torus::signed_distance(p, *major, *minor) <= 0.0,
        }
    }
}

/// The nearest hit of a convex solid whose line span is `(enter, exit)`: the entry when the
/// origin is outside, the exit when it is inside. Choosing by where the origin *is* (a
/// membership test on the same object-space coordinates the span came from) rather than by
/// the sign of the computed entry keeps a ray that starts just inside the surface, lifted
/// there by [`crate::math::offset_ray_origin`], from meeting the face it left when rounding
/// puts that face's crossing at a tiny positive `t`.
#[inline]
fn convex_pick(
    enter: Crossing,
    exit: Crossing,
    origin_inside: bool,
    t_max: f64,
) -> Option<Crossing> {
    let c = if origin_inside { exit } else { enter };
    (c.t > 0.0 && c.t < t_max).then_some(c)
}

/// `dir` as a unit vector and its length, without overflow or underflow for any finite,
/// non-zero vector (it is scaled by its largest component first). `None` for a zero or
/// non-finite direction: such a ray meets nothing.
#[inline]
fn unit_dir(dir: DVec3) -> Option<(DVec3, f64)> {
    let m = dir.abs().max_element();
    if !(m > 0.0 && m.is_finite()) {
        return None;
    }
    let scaled = dir / m;
    let len = scaled.length();
    Some((scaled / len, m * len))
}

/// The parameter interval `[t0, t1]` along the whole line (any `t`) inside the box
/// `[-e, e]`, or `None` when the line misses it. A zero direction component leaves that
/// slab unbounded when the origin lies in it (closed), and misses otherwise, without the
/// `0 · ∞` NaN of the reciprocal form.
#[inline]
fn line_box(origin: DVec3, dir: DVec3, e: DVec3) -> Option<(f64, f64)> {
    let (mut t0, mut t1) = (f64::NEG_INFINITY, f64::INFINITY);
    for i in 0..3 {
        let (o, d) = (origin[i], dir[i]);
        if d == 0.0 {
            if !(o.abs() <= e[i]) {
                return None;
            }
            continue;
        }
        let (a, b) = ((-e[i] - o) / d, (e[i] - o) / d);
        let (near, far) = if a < b { (a, b) } else { (b, a) };
        t0 = t0.max(near);
        t1 = t1.min(far);
    }
    (t0 <= t1 && t0.is_finite() && t1.is_finite()).then_some((t0, t1))
}

#[cfg(test)]
pub(crate) mod test_support {
    //! Helpers shared by the per-shape tests.
    use super::*;

    /// A small deterministic generator (SplitMix64), so random tests are reproducible and
    /// need no dependency.
    pub struct Rng(u64);

    impl Rng {
        pub fn new(seed: u64) -> Self {
            Rng(seed)
        }

        pub fn next_u64(&mut self) -> u64 {
            self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
            let mut z = self.0;
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            z ^ (z >> 31)
        }

        /// Uniform in [0, 1).
        pub fn unit(&mut self) -> f64 {
            (self.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
        }

        /// Uniform in [lo, hi).
        pub fn range(&mut self, lo: f64, hi: f64) -> f64 {
            lo + (hi - lo) * self.unit()
        }

        /// Uniform in the ball of radius `r` (by rejection).
        pub fn in_ball(&mut self, r: f64) -> DVec3 {
            loop {
                let p = DVec3::new(
                    self.range(-1.0, 1.0),
                    self.range(-1.0, 1.0),
                    self.range(-1.0, 1.0),
                );
                if p.length_squared() <= 1.0 {
                    return p * r;
                }
            }
        }

        /// A uniformly distributed unit vector.
        pub fn direction(&mut self) -> DVec3 {
            loop {
                let p = self.in_ball(1.0);
                let l = p.length();
                if l > 0.1 {
                    return p / l;
                }
            }
        }
    }

    /// Checks that texture coordinates on a patch of surface read as an upright image from
    /// outside: `uv_at(a, b)` is the u,v of the surface point offset from the patch centre by
    /// `a` along the viewer's right and `b` along the viewer's up (each scaled by s ∈ [−1, 1]);
    /// `n` is the outward normal there. Then u must grow with `a`, v with `b`, and both stay
    /// in [0, 1].
    pub fn check_uv_orientation(n: DVec3, up: DVec3, uv_at: impl Fn(DVec3, DVec3) -> DVec2) {
        let right = (-n).cross(up);
        let steps = [-1.0, -0.5, 0.0, 0.5, 1.0];
        for &b in &steps {
            let mut prev: Option<f64> = None;
            for &a in &steps {
                let uv = uv_at(right * a, up * b);
                assert!(
                    (0.0..=1.0).contains(&uv.x) && (0.0..=1.0).contains(&uv.y),
                    "n = {n:?}: uv {uv:?} out of range"
                );
                if let Some(p) = prev {
                    assert!(uv.x > p, "n = {n:?}: u does not grow to the right");
                }
                prev = Some(uv.x);
            }
        }
        for &a in &steps {
            let mut prev: Option<f64> = None;
            for &b in &steps {
                let v = uv_at(right * a, up * b).y;
                if let Some(p) = prev {
                    assert!(v > p, "n = {n:?}: v does not grow upwards");
                }
                prev = Some(v);
            }
        }
    }

    /// Asserts the invariants every hit must satisfy: finite values, `t` in range, the
    /// point on the ray within its error bound plus the ray's own rounding.
    pub fn check_hit(shape: Shape, ray: &Ray, hit: &LocalHit, t_max: f64) {
        assert!(
            hit.t > 0.0 && hit.t < t_max,
            "t = {} out of (0, {t_max})",
            hit.t
        );
        assert!(hit.p.is_finite() && hit.n.is_finite() && hit.p_err.is_finite());
        assert!(hit.n.length() > 0.0);
        let on_ray = ray.at(hit.t);
        let scale = ray.origin.abs().max_element() + (ray.dir * hit.t).abs().max_element();
        let tol = 1e-12 * scale.max(1.0);
        assert!(
            (on_ray - hit.p).abs().max_element() <= tol,
            "{shape:?}: point {:?} is not on the ray at t = {} ({on_ray:?})",
            hit.p,
            hit.t
        );
    }
}

#[cfg(test)]
mod tests {
    use super::test_support::Rng;
    use super::*;
    use crate::transform::{Transform, TransformOp};

    const ALL: [Shape; 6] = [
        Shape::Sphere,
        Shape::Plane,
        Shape::Cube,
        Shape::Cylinder,
        Shape::Cone,
        Shape::Torus {
            major: 1.0,
            minor: 0.3,
        },
    ];

    /// Under a non-uniform scale and a rotation, the world normal of every shape is
    /// perpendicular to the surface: two neighbouring hits (rays moved by δ) lie in its
    /// tangent plane up to the curvature term O(δ), while a normal carried by the forward
    /// matrix instead of the inverse transpose would be off by tens of degrees.
    #[test]
    fn world_normals_are_perpendicular_under_non_uniform_scale() {
        let t = [
            TransformOp::Scale(DVec3::new(3.0, 0.5, 1.5)),
            TransformOp::Rotate(DVec3::new(20.0, 40.0, 60.0)),
            TransformOp::Translate(DVec3::new(1.0, -2.0, 3.0)),
        ]
        .iter()
        .fold(Transform::IDENTITY, |acc, &op| {
            acc.then(&Transform::from_op(op))
        });
        let centre = DVec3::new(1.0, -2.0, 3.0);
        let mut rng = Rng::new(21);
        for shape in ALL {
            let mut checked = 0;
            for _ in 0..300 {
                let o = centre + rng.direction() * 10.0;
                let target = centre + rng.in_ball(1.0);
                let d = (target - o).normalize();
                let hit = |origin: DVec3| {
                    let r = Ray::new(origin, d);
                    shape.intersect(&t.ray_to_object(&r), f64::INFINITY)
                };
                let Some(h0) = hit(o) else { continue };
                let e1 = d.any_orthonormal_vector();
                let e2 = d.cross(e1);
                let delta = 1e-6;
                let (Some(h1), Some(h2)) = (hit(o + e1 * delta), hit(o + e2 * delta)) else {
                    continue;
                };
                if h1.face != h0.face || h2.face != h0.face {
                    continue;
                }
                let p0 = t.to_world().transform_point3(h0.p);
                let n = t.normal_to_world(h0.n).normalize();
                for h in [h1, h2] {
                    let step = t.to_world().transform_point3(h.p) - p0;
                    // Tangent steps of 1e-6 stay in the tangent plane up to the curvature
                    // term (≲ 1e-5 relative here; a sharp torus-inner point is the worst).
                    if step.length() > 0.0 && step.length() < 1e-3 {
                        assert!(
                            n.dot(step).abs() <= 1e-4 * step.length(),
                            "{shape:?}: n·step = {} for |step| = {}",
                            n.dot(step),
                            step.length()
                        );
                        checked += 1;
                    }
                }
            }
            assert!(checked > 50, "{shape:?}: only {checked} normals checked");
        }
    }

    /// A ray's direction may be of any length: an object scaled by 1e200 sees the eye's
    /// unit directions at 1e-200, and one scaled by 1e-200 at 1e200. Every shape finds the
    /// same hit, face and spans for the direction scaled by `k`, with `t` scaled by `1/k`.
    /// The sphere squared the direction's length, which underflowed to 0 below about
    /// 1e-154 (and overflowed above 1e154): it found no hit at all.
    #[test]
    fn hits_do_not_depend_on_the_direction_s_length() {
        let mut rng = Rng::new(23);
        for shape in ALL {
            let mut hits = 0;
            for _ in 0..200 {
                let o = rng.direction() * 5.0;
                let d = (rng.in_ball(1.0) - o).normalize();
                let unit = Ray::new(o, d);
                let want = shape.intersect(&unit, f64::INFINITY);
                let mut want_spans = Vec::new();
                shape.spans(&unit, &mut want_spans);
                hits += usize::from(want.is_some());
                for k in [1e-201, 1e-160, 1e-100, 1e100, 1e160, 1e200] {
                    let r = Ray::new(o, d * k);
                    let got = shape.intersect(&r, f64::INFINITY);
                    let close = |a: f64, b: f64| (a - b).abs() <= 1e-12 * a.abs().max(1.0);
                    match (&want, &got) {
                        (None, None) => {}
                        (Some(w), Some(g)) => {
                            assert!(
                                close(w.t, g.t * k) && w.face == g.face,
                                "{shape:?} at {k:e}: t {} against {}",
                                g.t * k,
                                w.t
                            );
                            assert!((w.p - g.p).length() <= 1e-12, "{shape:?} at {k:e}");
                        }
                        _ => panic!("{shape:?} at {k:e}: {got:?} against {want:?}"),
                    }
                    let mut spans = Vec::new();
                    shape.spans(&r, &mut spans);
                    assert_eq!(spans.len(), want_spans.len(), "{shape:?} at {k:e}");
                    for (g, w) in spans.iter().zip(&want_spans) {
                        for (gc, wc) in [(g.enter, w.enter), (g.exit, w.exit)] {
                            assert!(
                                wc.t.is_infinite() && gc.t == wc.t
                                    || close(wc.t, gc.t * k) && gc.face == wc.face,
                                "{shape:?} at {k:e}: span {g:?} against {w:?}"
                            );
                        }
                    }
                }
            }
            assert!(hits > 20, "{shape:?}: only {hits} rays hit");
        }
    }

    #[test]
    fn bounds_contain_every_hit() {
        let mut rng = Rng::new(22);
        for shape in ALL {
            let Some(b) = shape.bounds() else { continue };
            for _ in 0..500 {
                let o = rng.direction() * 5.0;
                let r = Ray::new(o, rng.in_ball(1.0) - o);
                if let Some(h) = shape.intersect(&r, f64::INFINITY) {
                    let slack = DVec3::splat(1e-12);
                    assert!(
                        h.p.cmpge(b.min - slack).all() && h.p.cmple(b.max + slack).all(),
                        "{shape:?}: {:?} outside {b:?}",
                        h.p
                    );
                }
            }
        }
    }
}
