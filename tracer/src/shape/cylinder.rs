//! The capped unit cylinder: radius 1 around the y axis, y in [-1, 1].
//!
//! Faces: 0 = side, 1 = bottom cap (y = −1), 2 = top cap (y = +1). A scene's `radius = r`
//! is not seen here: it is the scale `(r, 1, r)` folded into the transform.
//!
//! The line meets the solid where it is both inside the infinite tube `x² + z² ≤ 1` and
//! inside the slab `|y| ≤ 1`; the span is the intersection of those two intervals. The tube
//! interval is the sphere's stable quadratic in two dimensions (see `sphere.rs`): the
//! discriminant is computed from the ray's perpendicular offset to the axis, `1 − |f⊥|²`,
//! which does not cancel when the cylinder is small and far away the way `b² − 4ac` does,
//! and the roots are `q` and `c/q` so neither is a difference of nearly equal numbers.
//!
//! Hit points are projected onto their face: radially in xz onto the side (pbrt §3.9.4),
//! y set to exactly ±1 on a cap, so the error along the normal is a few ulps, and a checker
//! or cap texture never flickers at y = ±1.

use glam::{DVec2, DVec3};

use super::{Crossing, LocalHit, Span, SurfaceUv, Wrap, convex_pick};
use crate::math::{Ray, gamma};

pub(super) const SIDE: u8 = 0;
pub(super) const BOTTOM: u8 = 1;
pub(super) const TOP: u8 = 2;

/// Where the line is inside the infinite tube `x² + z² ≤ 1`.
enum Tube {
    Never,
    Always,
    Between(f64, f64),
}

#[inline]
fn tube(ray: &Ray) -> Tube {
    let (ox, oz) = (ray.origin.x, ray.origin.z);
    let (dx, dz) = (ray.dir.x, ray.dir.z);
    // Scale by the larger component first so the length neither overflows nor underflows.
    let m = dx.abs().max(dz.abs());
    if !(m > 0.0) {
        // Parallel to the axis (or NaN): inside for every t, or never.
        return if ox * ox + oz * oz <= 1.0 {
            Tube::Always
        } else {
            Tube::Never
        };
    }
    let (sx, sz) = (dx / m, dz / m);
    let l = (sx * sx + sz * sz).sqrt();
    let (ux, uz) = (sx / l, sz / l);
    let len = m * l;
    let b = -(ox * ux + oz * uz);
    let (px, pz) = (ox + ux * b, oz + uz * b);
    let disc = 1.0 - (px * px + pz * pz);
    if !(disc >= 0.0) {
        return Tube::Never;
    }
    let c = ox * ox + oz * oz - 1.0;
    let q = b + disc.sqrt().copysign(b);
    // q = 0 only when b = 0 and disc = 0: the origin is the tangent point, a double root at 0.
    let (mut t0, mut t1) = if q == 0.0 { (0.0, 0.0) } else { (c / q, q) };
    if t0 > t1 {
        std::mem::swap(&mut t0, &mut t1);
    }
    let (t0, t1) = (t0 / len, t1 / len);
    if t0.is_finite() && t1.is_finite() {
        Tube::Between(t0, t1)
    } else {
        Tube::Never
    }
}

/// The line's interval inside the solid, with the faces it crosses. When the tube and the
/// slab bound the interval at the same `t` (a ray through the rim), the cap is reported.
#[inline]
fn span(ray: &Ray) -> Option<(Crossing, Crossing)> {
    let (oy, dy) = (ray.origin.y, ray.dir.y);
    let (mut enter, mut exit) = if dy == 0.0 {
        if !(oy.abs() <= 1.0) {
            return None;
        }
        (
            Crossing {
                t: f64::NEG_INFINITY,
                face: BOTTOM,
            },
            Crossing {
                t: f64::INFINITY,
                face: TOP,
            },
        )
    } else {
        let (a, b) = ((-1.0 - oy) / dy, (1.0 - oy) / dy);
        if dy > 0.0 {
            (
                Crossing { t: a, face: BOTTOM },
                Crossing { t: b, face: TOP },
            )
        } else {
            (
                Crossing { t: b, face: TOP },
                Crossing { t: a, face: BOTTOM },
            )
        }
    };
    match tube(ray) {
        Tube::Never => return None,
        Tube::Always => {}
        Tube::Between(t0, t1) => {
            if t0 > enter.t {
                enter = Crossing { t: t0, face: SIDE };
            }
            if t1 < exit.t {
                exit = Crossing { t: t1, face: SIDE };
            }
        }
    }
    (enter.t <= exit.t && enter.t.is_finite() && exit.t.is_finite()).then_some((enter, exit))
}

pub(super) fn contains(p: DVec3) -> bool {
    p.y.abs() <= 1.0 && p.x * p.x + p.z * p.z <= 1.0
}

#[inline]
pub(super) fn intersect(ray: &Ray, t_max: f64) -> Option<LocalHit> {
    let (enter, exit) = span(ray)?;
    let c = convex_pick(enter, exit, contains(ray.origin), t_max)?;
    Some(surface_at(ray, c.t, c.face))
}

pub(super) fn spans(ray: &Ray, out: &mut Vec<Span>) {
    if let Some((enter, exit)) = span(ray) {
        out.push(Span { enter, exit });
    }
}

/// The point at `t` projected onto `face`.
///
/// Side: x and z are divided by their radius (pbrt's cylinder reprojection: error `γ(3)` of
/// the coordinate); y is `o + t·d`, clamped into [-1, 1], with `γ(5)` of the magnitudes. The
/// error of `t` itself slides the point along the side, in y, which the radial normal does
/// not see. Caps: y is exact; x and z as for a cube face, pulled onto the disc if rounding
/// put them just outside it.
#[inline]
pub(super) fn surface_at(ray: &Ray, t: f64, face: u8) -> LocalHit {
    let raw = ray.at(t);
    let mag = gamma(5) * (ray.origin.abs() + (ray.dir * t).abs());
    let (p, p_err, n) = if face == SIDE {
        let r = (raw.x * raw.x + raw.z * raw.z).sqrt();
        let (x, z) = if r > 0.0 && r.is_finite() {
            (raw.x / r, raw.z / r)
        } else {
            (1.0, 0.0)
        };
        let y = if raw.y.is_finite() {
            raw.y.clamp(-1.0, 1.0)
        } else {
            0.0
        };
        let p = DVec3::new(x, y, z);
        let err = DVec3::new(gamma(3) * x.abs(), mag.y, gamma(3) * z.abs());
        (p, err, DVec3::new(x, 0.0, z))
    } else {
        let y = if face == TOP { 1.0 } else { -1.0 };
        let (mut x, mut z) = (raw.x, raw.z);
        let r2 = x * x + z * z;
        if r2 > 1.0 {
            let r = r2.sqrt();
            (x, z) = (x / r, z / r);
        }
        if !(x.is_finite() && z.is_finite()) {
            (x, z) = (0.0, 0.0);
        }
        (
            DVec3::new(x, y, z),
            DVec3::new(mag.x, 0.0, mag.z),
            DVec3::new(0.0, y, 0.0),
        )
    };
    LocalHit {
        t,
        p,
        p_err,
        n,
        face,
    }
}

/// Side: the whole texture wrapped once around, `u` by longitude as on a sphere (`u = 0.5`
/// faces +z, growing towards +x), `v` from 0 at the bottom rim to 1 at the top rim. Caps: the
/// texture's unit square spread over the disc's bounding square, upright as seen from
/// outside (top cap from above with −z up, bottom cap from below with +z up), like a cube's
/// top and bottom faces.
pub(super) fn uv(p: DVec3, face: u8) -> SurfaceUv {
    let h = |a: f64| (0.5 * (a + 1.0)).clamp(0.0, 1.0);
    match face {
        SIDE => SurfaceUv {
            uv: DVec2::new(0.5 + p.x.atan2(p.z) / std::f64::consts::TAU, h(p.y)),
            wrap_u: Wrap::Repeat,
            wrap_v: Wrap::Clamp,
        },
        TOP => SurfaceUv {
            uv: DVec2::new(h(p.x), h(-p.z)),
            wrap_u: Wrap::Clamp,
            wrap_v: Wrap::Clamp,
        },
        _ => SurfaceUv {
            uv: DVec2::new(h(p.x), h(p.z)),
            wrap_u: Wrap::Clamp,
            wrap_v: Wrap::Clamp,
        },
    }
}

#[cfg(test)]
mod tests {
    use super::super::Shape;
    use super::super::test_support::{Rng, check_hit, check_uv_orientation};
    use super::*;

    const C: Shape = Shape::Cylinder;

    #[test]
    fn hits_side_and_caps_from_outside() {
        let side = Ray::new(DVec3::new(0.0, 0.5, 5.0), -DVec3::Z);
        let h = C.intersect(&side, f64::INFINITY).expect("hit");
        assert_eq!((h.t, h.face), (4.0, SIDE));
        assert_eq!(h.p, DVec3::new(0.0, 0.5, 1.0));
        assert_eq!(h.n, DVec3::Z);
        check_hit(C, &side, &h, f64::INFINITY);

        let top = Ray::new(DVec3::new(0.5, 4.0, -0.25), -DVec3::Y);
        let h = C.intersect(&top, f64::INFINITY).expect("hit");
        assert_eq!((h.t, h.face), (3.0, TOP));
        assert_eq!(h.p, DVec3::new(0.5, 1.0, -0.25));
        assert_eq!(h.n, DVec3::Y);
        assert_eq!(h.p_err.y, 0.0);

        let bottom = Ray::new(DVec3::new(0.5, -4.0, -0.25), DVec3::Y);
        let h = C.intersect(&bottom, f64::INFINITY).expect("hit");
        assert_eq!((h.t, h.face), (3.0, BOTTOM));
        assert_eq!(h.n, -DVec3::Y);

        // Oblique, entering the side at 45° in xz: expected point (√½, 0, √½)·…
        let d = DVec3::new(-1.0, 0.0, -1.0);
        let o = DVec3::new(3.0, 0.0, 3.0);
        let h = C.intersect(&Ray::new(o, d), f64::INFINITY).expect("hit");
        let s = std::f64::consts::FRAC_1_SQRT_2;
        assert!((h.p - DVec3::new(s, 0.0, s)).length() < 1e-15);
        assert!((h.t - (3.0 - s)).abs() < 1e-15);
    }

    #[test]
    fn misses_beside_above_and_behind() {
        let beside = Ray::new(DVec3::new(1.0001, 0.0, 5.0), -DVec3::Z);
        assert!(C.intersect(&beside, f64::INFINITY).is_none());
        let above = Ray::new(DVec3::new(0.0, 1.0001, 5.0), -DVec3::Z);
        assert!(C.intersect(&above, f64::INFINITY).is_none());
        let behind = Ray::new(DVec3::new(0.0, 0.0, 5.0), DVec3::Z);
        assert!(C.intersect(&behind, f64::INFINITY).is_none());
        // Down the axis outside the tube.
        let outside = Ray::new(DVec3::new(1.5, 5.0, 0.0), -DVec3::Y);
        assert!(C.intersect(&outside, f64::INFINITY).is_none());
        // Through the corner region of the bounding box, past the rim.
        let corner = Ray::new(DVec3::new(0.9, 3.0, 0.9), -DVec3::Y);
        assert!(C.intersect(&corner, f64::INFINITY).is_none());
    }

    #[test]
    fn hits_from_inside_at_the_far_surface() {
        let r = Ray::new(DVec3::new(0.0, 0.0, 0.0), DVec3::new(0.0, 0.0, 2.0));
        let h = C.intersect(&r, f64::INFINITY).expect("hit");
        assert_eq!((h.t, h.face), (0.5, SIDE));
        let r = Ray::new(DVec3::new(0.0, 0.0, 0.0), DVec3::Y);
        let h = C.intersect(&r, f64::INFINITY).expect("hit");
        assert_eq!((h.t, h.face), (1.0, TOP));
        // Starting just inside the side, heading across: the far side, not the near one.
        let o = DVec3::new(1.0f64.next_down(), 0.0, 0.0);
        let h = C
            .intersect(&Ray::new(o, DVec3::new(-1.0, 0.2, 0.01)), f64::INFINITY)
            .expect("hit");
        assert!(h.t > 1.9 && h.p.x < -0.99, "{h:?}");
    }

    #[test]
    fn tangent_and_rim_rays_never_make_nan() {
        // Tangent to the side along z at x = 1.
        let r = Ray::new(DVec3::new(1.0, 0.0, 5.0), -DVec3::Z);
        if let Some(h) = C.intersect(&r, f64::INFINITY) {
            assert!((h.p - DVec3::X).length() < 1e-7 && h.t.is_finite(), "{h:?}");
        }
        // Starting at the tangent point: q = 0.
        let r = Ray::new(DVec3::X, DVec3::Z);
        let mut s = Vec::new();
        C.spans(&r, &mut s);
        assert!(
            s.iter()
                .all(|s| s.enter.t.is_finite() && s.exit.t.is_finite())
        );
        // Through the top rim exactly: enters at (1, 1, 0).
        let r = Ray::new(DVec3::new(3.0, 3.0, 0.0), DVec3::new(-1.0, -1.0, 0.0));
        let h = C.intersect(&r, f64::INFINITY).expect("rim");
        assert!((h.p - DVec3::new(1.0, 1.0, 0.0)).length() < 1e-15, "{h:?}");
        // Along the rim's plane y = 1 with a -0.0 component: touches the top cap.
        let r = Ray::new(DVec3::new(0.0, 1.0, 5.0), DVec3::new(0.0, -0.0, -1.0));
        let h = C
            .intersect(&r, f64::INFINITY)
            .expect("touching the cap plane counts");
        assert!(h.p.is_finite());
        // Parallel to the axis, on the surface.
        let r = Ray::new(DVec3::new(0.0, 5.0, 1.0), -DVec3::Y);
        let h = C.intersect(&r, f64::INFINITY).expect("hit");
        assert_eq!((h.t, h.face), (4.0, TOP));
    }

    /// The small-and-far failure of the textbook quadratic, in the tube: radius 1 seen from
    /// 1e8 away must still separate offsets 0.999 and 1.001.
    #[test]
    fn small_cylinder_from_far_away() {
        let far = 1e8;
        for (offset, expect) in [(0.0, true), (0.999, true), (1.001, false)] {
            let axis = DVec3::new(2.0, 0.3, -1.0).normalize();
            let origin = axis * far;
            let side = DVec3::Y.cross(axis).normalize();
            let target = side * offset;
            let r = Ray::new(origin, target - origin);
            let h = C.intersect(&r, f64::INFINITY);
            assert_eq!(h.is_some(), expect, "offset {offset}");
            if let Some(h) = h {
                assert_eq!(h.face, SIDE);
                assert!((h.p.x * h.p.x + h.p.z * h.p.z - 1.0).abs() < 1e-15);
                // The point on the ray at t is on the surface to within the ray's own rounding.
                let q = r.at(h.t);
                let rr = (q.x * q.x + q.z * q.z).sqrt();
                assert!((rr - 1.0).abs() < 1e-7, "radius {rr}");
            }
        }
    }

    #[test]
    fn random_hits_lie_on_their_face_and_flip_membership() {
        let mut rng = Rng::new(11);
        for _ in 0..4000 {
            let o = rng.in_ball(5.0);
            let r = Ray::new(o, rng.in_ball(1.3) - o);
            let found = C.intersect(&r, f64::INFINITY);
            if let Some(h) = found {
                check_hit(C, &r, &h, f64::INFINITY);
                match h.face {
                    SIDE => assert!((h.p.x * h.p.x + h.p.z * h.p.z - 1.0).abs() < 1e-15),
                    TOP => assert_eq!(h.p.y, 1.0),
                    _ => assert_eq!(h.p.y, -1.0),
                }
                assert!(h.p.y.abs() <= 1.0 && h.p.x * h.p.x + h.p.z * h.p.z <= 1.0 + 1e-15);
            }
            let mut s = Vec::new();
            C.spans(&r, &mut s);
            for span in &s {
                let eps = 1e-9 / r.dir.length();
                if span.exit.t - span.enter.t > 4.0 * eps {
                    assert!(!C.contains(r.at(span.enter.t - eps)));
                    assert!(C.contains(r.at(span.enter.t + eps)));
                    assert!(C.contains(r.at(span.exit.t - eps)));
                    assert!(!C.contains(r.at(span.exit.t + eps)));
                }
            }
            let marched = (0..=2000).any(|i| C.contains(r.at(f64::from(i) * 0.01)));
            if marched {
                assert!(found.is_some(), "march found the cylinder along {r:?}");
            }
        }
    }

    #[test]
    fn uv_ranges_and_orientation() {
        // Side at +z: u = 0.5; the texture wraps once around.
        let f = uv(DVec3::new(0.0, -1.0, 1.0), SIDE);
        assert_eq!(f.uv, DVec2::new(0.5, 0.0));
        assert_eq!(
            uv(DVec3::new(1.0, 1.0, 0.0), SIDE).uv,
            DVec2::new(0.75, 1.0)
        );
        // Seen from the front, u grows to the right across the +z side.
        check_uv_orientation(DVec3::Z, DVec3::Y, |a, b| {
            let p = (DVec3::Z + a * 0.5).normalize();
            uv(DVec3::new(p.x, b.y, p.z), SIDE).uv
        });
        check_uv_orientation(DVec3::Y, -DVec3::Z, |a, b| {
            uv(DVec3::Y + (a + b) * 0.7, TOP).uv
        });
        check_uv_orientation(-DVec3::Y, DVec3::Z, |a, b| {
            uv(-DVec3::Y + (a + b) * 0.7, BOTTOM).uv
        });
    }
}
