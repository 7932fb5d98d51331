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
//! [`crate::transform`]'s job; choosing colours is [`crate::material`]'s.
//!
//! Adding a shape means adding a variant here and a module implementing the same functions;
//! the scene parser maps the `type` keyword to the variant.

mod plane;
mod sphere;

use glam::{DVec2, DVec3};

use crate::math::{Aabb, Ray};

/// The unit shapes of the `.ray` format.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Shape {
    /// Unit sphere at the origin.
    Sphere,
    /// The plane y = 0, normal +y; as a solid (for CSG) the half-space y ≤ 0.
    Plane,
}

/// A ray–surface hit in object space.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LocalHit {
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
        }
    }

    /// The nearest hit with `0 < t < t_max`, if any. NaN parameters are never hits.
    #[inline]
    pub fn intersect(&self, ray: &Ray, t_max: f64) -> Option<LocalHit> {
        match self {
            Shape::Sphere => sphere::intersect(ray, t_max),
            Shape::Plane => plane::intersect(ray, t_max),
        }
    }

    /// Appends, in increasing order, every interval of the whole line (any `t`, negative too)
    /// along which the ray is inside the solid.
    pub fn spans(&self, ray: &Ray, out: &mut Vec<Span>) {
        match self {
            Shape::Sphere => sphere::spans(ray, out),
            Shape::Plane => plane::spans(ray, out),
        }
    }

    /// The surface point where the ray crosses `face` at `t` (as reported by [`Self::spans`]),
    /// projected onto the surface, with its error bound and normal.
    pub fn surface_at(&self, ray: &Ray, t: f64, face: u8) -> LocalHit {
        match self {
            Shape::Sphere => sphere::surface_at(ray, t),
            Shape::Plane => plane::surface_at(ray, t, face),
        }
    }

    /// Texture coordinates of a surface point.
    pub fn uv(&self, p: DVec3, face: u8) -> SurfaceUv {
        match self {
            Shape::Sphere => sphere::uv(p),
            Shape::Plane => plane::uv(p, face),
        }
    }

    /// Object-space bounds; `None` for unbounded shapes.
    pub fn bounds(&self) -> Option<Aabb> {
        match self {
            Shape::Sphere => Some(Aabb::new(DVec3::splat(-1.0), DVec3::splat(1.0))),
            Shape::Plane => None,
        }
    }

    /// Whether a ray that starts on this surface can meet the surface again, given the side
    /// it leaves on. A convex solid cannot be met again by a ray leaving its outside; a plane
    /// cannot be met again from either side. The tracer then skips the test altogether, which
    /// is both faster and immune to self-intersection.
    pub fn cannot_rehit(&self, leaving_outside: bool) -> bool {
        match self {
            Shape::Plane => true,
            Shape::Sphere => leaving_outside,
        }
    }

    /// Whether an object-space point is inside the closed solid (for CSG tests).
    pub fn contains(&self, p: DVec3) -> bool {
        match self {
            Shape::Sphere => p.length_squared() <= 1.0,
            Shape::Plane => p.y <= 0.0,
        }
    }
}

#[cfg(test)]
pub(crate) mod test_support {
    //! Helpers shared by the per-shape tests.
    use super::*;

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
