//! The plane y = 0 with normal +y. As a solid (in CSG) it is the half-space y ≤ 0.
//!
//! The hit point is snapped to y = 0 exactly. That matters twice: the offset of a secondary
//! ray then only has to clear the transform's rounding, and a checker evaluated on the
//! plane's own x, z never sees the `floor(±1e-17)` flicker between cells −1 and 0 that a
//! solid checker evaluated at a computed y ≈ 0 would.

use glam::{DVec2, DVec3};

use super::{Crossing, LocalHit, Span, SurfaceUv, Wrap};
use crate::math::{Ray, floor, gamma};

#[inline]
pub(super) fn intersect(ray: &Ray, t_max: f64) -> Option<LocalHit> {
    // A ray parallel to the plane gives ±∞ or NaN here, and both fail the range test.
    let t = -ray.origin.y / ray.dir.y;
    if !(t > 0.0 && t < t_max) {
        return None;
    }
    Some(surface_at(ray, t, 0))
}

pub(super) fn spans(ray: &Ray, out: &mut Vec<Span>) {
    let (o, d) = (ray.origin.y, ray.dir.y);
    let all = |t0: f64, t1: f64| Span {
        enter: Crossing { t: t0, face: 0 },
        exit: Crossing { t: t1, face: 0 },
    };
    if d == 0.0 {
        if o <= 0.0 {
            out.push(all(f64::NEG_INFINITY, f64::INFINITY));
        }
        return;
    }
    let t = -o / d;
    if d > 0.0 {
        out.push(all(f64::NEG_INFINITY, t));
    } else {
        out.push(all(t, f64::INFINITY));
    }
}

/// The point at `t` with y snapped to 0. `o + t·d` in x and z has three roundings on the way
/// (the division for `t`, the product, the sum), hence `γ(3)` of the magnitudes involved.
#[inline]
pub(super) fn surface_at(ray: &Ray, t: f64, face: u8) -> LocalHit {
    let raw = ray.at(t);
    let p = DVec3::new(raw.x, 0.0, raw.z);
    let mag = ray.origin.abs() + (ray.dir * t).abs();
    LocalHit {
        t,
        p,
        p_err: DVec3::new(gamma(3) * mag.x, 0.0, gamma(3) * mag.z),
        n: DVec3::Y,
        face,
    }
}

/// Unit squares of x, z: a texture's top-left corner at (0, 0, 0), columns along +x, rows
/// along +z, repeating every unit.
pub(super) fn uv(p: DVec3, _face: u8) -> SurfaceUv {
    SurfaceUv {
        uv: DVec2::new(p.x - floor(p.x), 1.0 - (p.z - floor(p.z))),
        wrap_u: Wrap::Repeat,
        wrap_v: Wrap::Repeat,
    }
}

#[cfg(test)]
mod tests {
    use super::super::Shape;
    use super::super::test_support::check_hit;
    use super::*;

    const P: Shape = Shape::Plane;

    #[test]
    fn hits_from_above_and_below() {
        let down = Ray::new(DVec3::new(0.5, 2.0, -3.0), DVec3::new(0.0, -1.0, 0.0));
        let h = P.intersect(&down, f64::INFINITY).expect("hit");
        assert_eq!(h.t, 2.0);
        assert_eq!(h.p, DVec3::new(0.5, 0.0, -3.0));
        check_hit(P, &down, &h, f64::INFINITY);
        let up = Ray::new(DVec3::new(0.5, -2.0, -3.0), DVec3::new(1.0, 1.0, 0.0));
        let h = P.intersect(&up, f64::INFINITY).expect("hit");
        assert_eq!(h.p, DVec3::new(2.5, 0.0, -3.0));
        assert_eq!(h.n, DVec3::Y, "the normal is +y from either side");
    }

    #[test]
    fn parallel_rays_miss_without_nan() {
        for y in [1.0, 0.0, -1.0, 1e-300] {
            for dy in [0.0, -0.0] {
                let r = Ray::new(DVec3::new(0.0, y, 0.0), DVec3::new(1.0, dy, 0.3));
                assert!(
                    P.intersect(&r, f64::INFINITY).is_none(),
                    "y = {y}, dy = {dy}"
                );
            }
        }
    }

    #[test]
    fn nearly_parallel_rays_hit_far_away_with_finite_values() {
        let r = Ray::new(DVec3::new(0.0, 1.0, 0.0), DVec3::new(1.0, -1e-12, 0.0));
        let h = P.intersect(&r, f64::INFINITY).expect("hit");
        assert!((h.p.x - 1e12).abs() < 1e-3);
        assert_eq!(h.p.y, 0.0);
        check_hit(P, &r, &h, f64::INFINITY);
    }

    #[test]
    fn spans_are_the_lower_half_space() {
        let mut s = Vec::new();
        P.spans(&Ray::new(DVec3::new(0.0, 1.0, 0.0), -DVec3::Y), &mut s);
        assert_eq!((s[0].enter.t, s[0].exit.t), (1.0, f64::INFINITY));
        s.clear();
        P.spans(&Ray::new(DVec3::new(0.0, -1.0, 0.0), DVec3::X), &mut s);
        assert_eq!(
            (s[0].enter.t, s[0].exit.t),
            (f64::NEG_INFINITY, f64::INFINITY)
        );
        s.clear();
        P.spans(&Ray::new(DVec3::new(0.0, 1.0, 0.0), DVec3::X), &mut s);
        assert!(s.is_empty());
        assert!(P.contains(DVec3::new(5.0, -0.1, 2.0)));
        assert!(!P.contains(DVec3::new(5.0, 0.1, 2.0)));
    }

    #[test]
    fn uv_tiles_unit_squares() {
        let a = uv(DVec3::new(0.25, 0.0, 0.75), 0).uv;
        let b = uv(DVec3::new(-2.75, 0.0, 10.75), 0).uv;
        assert!((a - b).length() < 1e-12);
        assert!((a - DVec2::new(0.25, 0.25)).length() < 1e-15);
    }
}
