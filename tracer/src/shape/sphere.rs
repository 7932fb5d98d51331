//! The unit sphere, intersected the numerically stable way (Ray Tracing Gems ch. 7,
//! "Precision Improvements for Ray/Sphere Intersection").
//!
//! The textbook discriminant `b² − 4ac` cancels catastrophically when the sphere is small
//! compared with its distance: seen from 1e7 away, `b²` and `4ac` agree in every digit and
//! the difference is noise, so small spheres break up or vanish. Instead the discriminant is
//! computed geometrically as `r² − |f − (f·d̂)d̂|²`, from the ray's perpendicular offset to the
//! centre, which has no such cancellation. The two roots are then taken as `q` and `c/q` with
//! `q = b + sign(b)·√Δ`, so neither is a difference of nearly equal numbers.

use glam::{DVec2, DVec3};

use super::{Crossing, LocalHit, Span, SurfaceUv, Wrap};
use crate::math::{Ray, gamma};

/// Both roots along the ray (in units of `ray.dir`), ascending, if the line meets the
/// sphere. NaN roots (a degenerate direction, or `0/0` for a ray that starts exactly at the
/// tangent point) are dropped.
#[inline]
fn roots(ray: &Ray) -> Option<(f64, f64)> {
    let len2 = ray.dir.length_squared();
    // `|d|²` underflows to 0 for directions shorter than about 1e-154 and overflows past
    // 1e154, which an object scaled by as much makes of the eye's unit directions: the
    // sphere would then have no hit at all. Such directions are scaled by their largest
    // component first; every other ray keeps the one square root (and so its exact bits).
    let (d, len) = if len2 > 1e-300 && len2 < 1e300 {
        let len = len2.sqrt();
        (ray.dir / len, len)
    } else {
        super::unit_dir(ray.dir)?
    };
    let f = ray.origin;
    let b = -f.dot(d);
    let perp = f + d * b;
    let disc = 1.0 - perp.length_squared();
    if !(disc >= 0.0) {
        return None;
    }
    let c = f.length_squared() - 1.0;
    let q = b + disc.sqrt().copysign(b);
    let (mut t0, mut t1) = (c / q, q);
    if t0 > t1 {
        std::mem::swap(&mut t0, &mut t1);
    }
    let (t0, t1) = (t0 / len, t1 / len);
    (t0.is_finite() && t1.is_finite()).then_some((t0, t1))
}

#[inline]
pub(super) fn intersect(ray: &Ray, t_max: f64) -> Option<LocalHit> {
    let (t0, t1) = roots(ray)?;
    let t = if t0 > 0.0 { t0 } else { t1 };
    if !(t > 0.0 && t < t_max) {
        return None;
    }
    Some(surface_at(ray, t))
}

pub(super) fn spans(ray: &Ray, out: &mut Vec<Span>) {
    if let Some((t0, t1)) = roots(ray) {
        out.push(Span {
            enter: Crossing { t: t0, face: 0 },
            exit: Crossing { t: t1, face: 0 },
        });
    }
}

/// The point at `t`, projected radially onto the sphere. After the projection the error is
/// within `γ(5)·|p|` per axis (pbrt §3.9.4), whatever the error of `t` was.
#[inline]
pub(super) fn surface_at(ray: &Ray, t: f64) -> LocalHit {
    let raw = ray.at(t);
    let len = raw.length();
    let p = if len > 0.0 { raw / len } else { DVec3::Y };
    LocalHit {
        t,
        p,
        p_err: gamma(5) * p.abs(),
        n: p,
        face: 0,
    }
}

/// Longitude and latitude: `u = 0.5` faces +z (the default camera), growing towards +x;
/// `v` runs from 0 at the south pole (y = −1) to 1 at the north pole.
pub(super) fn uv(p: DVec3) -> SurfaceUv {
    let u = 0.5 + p.x.atan2(p.z) / std::f64::consts::TAU;
    let v = 0.5 + p.y.clamp(-1.0, 1.0).asin() / std::f64::consts::PI;
    SurfaceUv {
        uv: DVec2::new(u, v),
        wrap_u: Wrap::Repeat,
        wrap_v: Wrap::Clamp,
    }
}

#[cfg(test)]
mod tests {
    use super::super::Shape;
    use super::super::test_support::check_hit;
    use super::*;

    const S: Shape = Shape::Sphere;

    #[test]
    fn hits_from_outside_at_the_near_side() {
        let r = Ray::new(DVec3::new(0.0, 0.0, 5.0), DVec3::new(0.0, 0.0, -1.0));
        let h = S.intersect(&r, f64::INFINITY).expect("hit");
        assert_eq!(h.t, 4.0);
        assert_eq!(h.p, DVec3::Z);
        assert_eq!(h.n, DVec3::Z);
        check_hit(S, &r, &h, f64::INFINITY);
    }

    #[test]
    fn misses_beside_and_behind() {
        let beside = Ray::new(DVec3::new(1.001, 0.0, 5.0), DVec3::new(0.0, 0.0, -1.0));
        assert!(S.intersect(&beside, f64::INFINITY).is_none());
        let behind = Ray::new(DVec3::new(0.0, 0.0, 5.0), DVec3::new(0.0, 0.0, 1.0));
        assert!(S.intersect(&behind, f64::INFINITY).is_none());
        let short = Ray::new(DVec3::new(0.0, 0.0, 5.0), DVec3::new(0.0, 0.0, -1.0));
        assert!(S.intersect(&short, 3.9).is_none());
    }

    #[test]
    fn hits_from_inside_at_the_far_side() {
        let r = Ray::new(DVec3::new(0.0, 0.5, 0.0), DVec3::new(0.0, 2.0, 0.0));
        let h = S.intersect(&r, f64::INFINITY).expect("hit");
        assert!((h.t - 0.25).abs() < 1e-15);
        assert_eq!(h.p, DVec3::Y);
    }

    #[test]
    fn tangent_ray_touches_or_misses_but_never_makes_nan() {
        // Exactly tangent at (1, 0, 0).
        let r = Ray::new(DVec3::new(1.0, 0.0, 5.0), DVec3::new(0.0, 0.0, -1.0));
        if let Some(h) = S.intersect(&r, f64::INFINITY) {
            assert!((h.t - 5.0).abs() < 1e-7, "{h:?}");
            check_hit(S, &r, &h, f64::INFINITY);
        }
        // Starting exactly at the tangent point: `c/q` is 0/0 and must not leak out.
        let r = Ray::new(DVec3::new(1.0, 0.0, 0.0), DVec3::new(0.0, 0.0, -1.0));
        let mut spans = Vec::new();
        S.spans(&r, &mut spans);
        assert!(
            spans
                .iter()
                .all(|s| !s.enter.t.is_nan() && !s.exit.t.is_nan())
        );
        if let Some(h) = S.intersect(&r, f64::INFINITY) {
            assert!(h.t.is_finite());
        }
    }

    #[test]
    fn unnormalised_directions_measure_t_in_their_own_units() {
        let r = Ray::new(DVec3::new(0.0, 0.0, 5.0), DVec3::new(0.0, 0.0, -4.0));
        let h = S.intersect(&r, f64::INFINITY).expect("hit");
        assert_eq!(h.t, 1.0);
    }

    #[test]
    fn spans_cover_the_whole_line() {
        let r = Ray::new(DVec3::ZERO, DVec3::X);
        let mut spans = Vec::new();
        S.spans(&r, &mut spans);
        assert_eq!(spans.len(), 1);
        assert_eq!((spans[0].enter.t, spans[0].exit.t), (-1.0, 1.0));
    }

    /// The failure case of the textbook quadratic: a sphere of radius 0.1 seen from 1e7 away
    /// (in object space: the unit sphere from 1e8). The geometric discriminant must still
    /// separate rays passing at 0.999 and 1.001 radii.
    #[test]
    fn small_sphere_from_far_away_is_hit_where_it_should_be() {
        let far = 1e8;
        for (offset, expect_hit) in [
            (0.0, true),
            (0.5, true),
            (0.999, true),
            (1.001, false),
            (1.5, false),
        ] {
            // A ray aimed from far along an oblique axis, passing `offset` from the centre.
            let axis = DVec3::new(1.0, 2.0, -2.0).normalize();
            let side = axis.any_orthonormal_vector();
            let origin = axis * far;
            let target = side * offset;
            let r = Ray::new(origin, target - origin);
            let hit = S.intersect(&r, f64::INFINITY);
            assert_eq!(hit.is_some(), expect_hit, "offset {offset}");
            if let Some(h) = hit {
                let expected_t =
                    (far - (1.0 - offset * offset).sqrt()) / (target - origin).length();
                assert!(
                    (h.t - expected_t).abs() < 1e-15 * 8.0,
                    "offset {offset}: t = {} vs {expected_t}",
                    h.t
                );
                assert!((h.p.length() - 1.0).abs() < 1e-15);
            }
        }
    }

    /// The textbook formula on the same ray fails, which is why the test above matters.
    #[test]
    fn textbook_discriminant_fails_where_the_stable_one_works() {
        let far = 1e8;
        let axis = DVec3::new(1.0, 2.0, -2.0).normalize();
        let side = axis.any_orthonormal_vector();
        let origin = axis * far;
        let mut wrong = 0;
        for i in 0..200 {
            let offset = 0.005 * f64::from(i);
            let d = (side * offset - origin).normalize();
            let b = origin.dot(d);
            let c = origin.length_squared() - 1.0;
            let textbook_hit = b * b - c >= 0.0;
            if textbook_hit != (offset <= 1.0) {
                wrong += 1;
            }
            let r = Ray::new(origin, d);
            assert_eq!(S.intersect(&r, f64::INFINITY).is_some(), offset <= 1.0);
        }
        assert!(
            wrong > 10,
            "the textbook formula was right {} of 200 times",
            200 - wrong
        );
    }

    #[test]
    fn uv_is_longitude_and_latitude() {
        let at = |p: DVec3| uv(p).uv;
        assert!((at(DVec3::Z) - DVec2::new(0.5, 0.5)).length() < 1e-15);
        assert!((at(DVec3::X) - DVec2::new(0.75, 0.5)).length() < 1e-15);
        assert!((at(DVec3::Y).y - 1.0).abs() < 1e-15);
        assert!((at(-DVec3::Y).y).abs() < 1e-15);
        for p in [
            DVec3::X,
            -DVec3::X,
            DVec3::Z,
            -DVec3::Z,
            DVec3::new(0.6, 0.0, -0.8),
        ] {
            let u = at(p).x;
            assert!((0.0..=1.0).contains(&u));
        }
    }
}
