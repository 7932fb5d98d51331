//! The cube [-1, 1]³, by the slab method.
//!
//! Faces are numbered `2·axis + (side > 0)`: 0 = −x, 1 = +x, 2 = −y, 3 = +y, 4 = −z, 5 = +z.
//!
//! The hit point is snapped onto its face: the face coordinate is set to exactly ±1 and the
//! other two are clamped into [-1, 1]. That does two things. The error along the face normal
//! becomes zero, so a secondary ray only has to clear the transform's rounding. And a checker
//! evaluated on the face sees `floor(1.0)` everywhere instead of `floor(0.9999999999999998)`
//! on some pixels and `floor(1.0000000000000002)` on others: a face at x = ±1 lies exactly on
//! a cell boundary, and without the snap it speckles between two colours.
//!
//! This module knows the unit cube only; sizes and placement come from the transform.

use glam::{DVec2, DVec3};

use super::{Crossing, LocalHit, Span, SurfaceUv, Wrap, convex_pick};
use crate::math::{Ray, gamma};

/// The line's interval inside the closed cube, with the faces it enters and leaves by.
/// `None` when the line misses, including a zero (or non-finite) direction.
///
/// A zero direction component is handled apart: the line then lies in that slab for every
/// `t` when `|o| ≤ 1` (touching a face counts), and misses otherwise. The reciprocal form
/// would compute `(1 − 1) · ∞ = NaN` for a ray lying exactly in a face plane. Ties between
/// axes (a ray through an edge or corner) keep the first axis; the snapped point is the
/// corner either way.
#[inline]
fn span(ray: &Ray) -> Option<(Crossing, Crossing)> {
    let mut enter = Crossing {
        t: f64::NEG_INFINITY,
        face: 0,
    };
    let mut exit = Crossing {
        t: f64::INFINITY,
        face: 1,
    };
    for axis in 0..3 {
        let (o, d) = (ray.origin[axis], ray.dir[axis]);
        if d == 0.0 {
            if !(o.abs() <= 1.0) {
                return None;
            }
            continue;
        }
        let inv = 1.0 / d;
        let lo_face = 2 * axis as u8;
        let (mut near, mut far) = ((-1.0 - o) * inv, (1.0 - o) * inv);
        let (mut near_face, mut far_face) = (lo_face, lo_face + 1);
        if d < 0.0 {
            std::mem::swap(&mut near, &mut far);
            std::mem::swap(&mut near_face, &mut far_face);
        }
        if near > enter.t {
            enter = Crossing {
                t: near,
                face: near_face,
            };
        }
        if far < exit.t {
            exit = Crossing {
                t: far,
                face: far_face,
            };
        }
    }
    (enter.t <= exit.t && enter.t.is_finite() && exit.t.is_finite()).then_some((enter, exit))
}

#[inline]
pub(super) fn intersect(ray: &Ray, t_max: f64) -> Option<LocalHit> {
    let (enter, exit) = span(ray)?;
    let inside = ray.origin.abs().max_element() <= 1.0;
    let c = convex_pick(enter, exit, inside, t_max)?;
    Some(surface_at(ray, c.t, c.face))
}

pub(super) fn spans(ray: &Ray, out: &mut Vec<Span>) {
    if let Some((enter, exit)) = span(ray) {
        out.push(Span { enter, exit });
    }
}

/// The point at `t` snapped onto `face`. The face coordinate is exact. The other two are
/// `o + t·d` with `t = (±1 − o)·(1/d)` (three roundings: the difference, the reciprocal, the
/// product) followed by a product and a sum, hence `γ(5)` of `|o| + |t·d|`; clamping into
/// [-1, 1] only moves them towards the true point, which lies on the face.
#[inline]
pub(super) fn surface_at(ray: &Ray, t: f64, face: u8) -> LocalHit {
    let axis = usize::from(face / 2).min(2);
    let side = if face & 1 == 1 { 1.0 } else { -1.0 };
    let mut p = ray.at(t).clamp(DVec3::splat(-1.0), DVec3::splat(1.0));
    p[axis] = side;
    let mut p_err = gamma(5) * (ray.origin.abs() + (ray.dir * t).abs());
    p_err[axis] = 0.0;
    let mut n = DVec3::ZERO;
    n[axis] = side;
    // A NaN coordinate (a degenerate ray) would survive `clamp`; put it on the face centre
    // line instead so that nothing downstream sees NaN.
    if !p.is_finite() {
        p = n;
    }
    LocalHit {
        t,
        p,
        p_err,
        n,
        face,
    }
}

/// Every face shows the whole texture, upright as seen from outside the cube: `u` grows to
/// the viewer's right and `v` upwards, the side faces with +y up, the top (+y) face as seen
/// from above with −z up (its far edge, seen from the default camera, is the texture's top),
/// the bottom face as seen from below with +z up.
pub(super) fn uv(p: DVec3, face: u8) -> SurfaceUv {
    let h = |a: f64| 0.5 * (a + 1.0);
    let uv = match face {
        0 => DVec2::new(h(p.z), h(p.y)),  // −x: right is +z
        1 => DVec2::new(h(-p.z), h(p.y)), // +x: right is −z
        2 => DVec2::new(h(p.x), h(p.z)),  // −y: right +x, up +z
        3 => DVec2::new(h(p.x), h(-p.z)), // +y: right +x, up −z
        4 => DVec2::new(h(-p.x), h(p.y)), // −z: right is −x
        _ => DVec2::new(h(p.x), h(p.y)),  // +z: right is +x
    };
    SurfaceUv {
        uv,
        wrap_u: Wrap::Clamp,
        wrap_v: Wrap::Clamp,
    }
}

#[cfg(test)]
mod tests {
    use super::super::Shape;
    use super::super::test_support::{Rng, check_hit, check_uv_orientation};
    use super::*;

    const C: Shape = Shape::Cube;

    #[test]
    fn hits_each_face_from_outside() {
        for axis in 0..3 {
            for side in [-1.0, 1.0] {
                let mut o = DVec3::new(0.25, -0.5, 0.125);
                o[axis] = 3.0 * side;
                let mut d = DVec3::ZERO;
                d[axis] = -side;
                let r = Ray::new(o, d);
                let h = C.intersect(&r, f64::INFINITY).expect("hit");
                assert_eq!(h.t, 2.0);
                let mut expect = o;
                expect[axis] = side;
                assert_eq!(h.p, expect);
                assert_eq!(h.n, -d);
                assert_eq!(h.face, 2 * axis as u8 + u8::from(side > 0.0));
                assert_eq!(h.p_err[axis], 0.0);
                check_hit(C, &r, &h, f64::INFINITY);
            }
        }
    }

    #[test]
    fn misses_beside_behind_and_short() {
        let beside = Ray::new(DVec3::new(1.0001, 0.0, 5.0), DVec3::new(0.0, 0.0, -1.0));
        assert!(C.intersect(&beside, f64::INFINITY).is_none());
        let behind = Ray::new(DVec3::new(0.0, 0.0, 5.0), DVec3::Z);
        assert!(C.intersect(&behind, f64::INFINITY).is_none());
        let short = Ray::new(DVec3::new(0.0, 0.0, 5.0), -DVec3::Z);
        assert!(C.intersect(&short, 4.0).is_none());
        assert!(C.intersect(&short, 4.0f64.next_up()).is_some());
        // An oblique ray that passes beyond the corner (1, 1, z): x + y = 2.1 > 2 on the line.
        let past = Ray::new(DVec3::new(3.1, -1.0, 0.0), DVec3::new(-1.0, 1.0, 0.0));
        assert!(C.intersect(&past, f64::INFINITY).is_none());
    }

    #[test]
    fn hits_from_inside_at_the_far_face() {
        let r = Ray::new(DVec3::new(0.5, 0.0, 0.0), DVec3::new(2.0, 0.0, 0.0));
        let h = C.intersect(&r, f64::INFINITY).expect("hit");
        assert_eq!(h.t, 0.25);
        assert_eq!(h.p, DVec3::new(1.0, 0.0, 0.0));
        assert_eq!(h.face, 1);
        // The outward normal, which faces away from a ray arriving from inside.
        assert_eq!(h.n, DVec3::X);
    }

    /// A ray that starts just inside a face, as a lifted secondary ray does, must not meet that
    /// face again whatever rounding does to its crossing, and must find the opposite face.
    #[test]
    fn ray_starting_just_inside_a_face_finds_the_far_face() {
        let o = DVec3::new(1.0f64.next_down(), 0.3, -0.2);
        let r = Ray::new(o, DVec3::new(-1.0, 0.1, 0.0));
        let h = C.intersect(&r, f64::INFINITY).expect("hit");
        assert_eq!(h.face, 0);
        assert!(h.t > 1.9);
    }

    #[test]
    fn edge_and_corner_rays_touch_without_nan() {
        // Along the edge x = 1, y = 1: the closed cube is touched along the whole edge.
        let r = Ray::new(DVec3::new(1.0, 1.0, 5.0), -DVec3::Z);
        let h = C
            .intersect(&r, f64::INFINITY)
            .expect("touching an edge counts");
        assert_eq!(h.p, DVec3::new(1.0, 1.0, 1.0));
        assert_eq!(h.t, 4.0);
        // Lying in the face plane y = 1, -0.0 direction component included.
        let r = Ray::new(DVec3::new(-3.0, 1.0, 0.0), DVec3::new(1.0, -0.0, 0.0));
        let h = C.intersect(&r, f64::INFINITY).expect("hit");
        assert_eq!(h.p, DVec3::new(-1.0, 1.0, 0.0));
        // Straight at a corner along the diagonal: enters at the corner, whichever face.
        let r = Ray::new(DVec3::splat(3.0), DVec3::splat(-1.0));
        let h = C.intersect(&r, f64::INFINITY).expect("hit");
        assert_eq!(h.p, DVec3::ONE);
        assert_eq!(h.t, 2.0);
        assert_eq!(h.n.length(), 1.0);
        // Through a corner at an angle, grazing the cube at that single point.
        let r = Ray::new(DVec3::new(3.0, 1.0, 1.0), DVec3::new(-1.0, 0.5, 0.0));
        if let Some(h) = C.intersect(&r, f64::INFINITY) {
            assert!(h.p.is_finite() && h.t.is_finite());
            assert!((h.p - DVec3::new(1.0, 2.0, 1.0)).length() < 1.0 + 1e-12);
        }
        // Spans never carry NaN, even for a ray lying exactly in two face planes.
        let mut s = Vec::new();
        C.spans(
            &Ray::new(DVec3::new(1.0, -1.0, 7.0), DVec3::new(0.0, 0.0, -2.0)),
            &mut s,
        );
        assert_eq!(s.len(), 1);
        assert_eq!((s[0].enter.t, s[0].exit.t), (3.0, 4.0));
    }

    #[test]
    fn zero_direction_meets_nothing() {
        let r = Ray::new(DVec3::ZERO, DVec3::ZERO);
        assert!(C.intersect(&r, f64::INFINITY).is_none());
        let mut s = Vec::new();
        C.spans(&r, &mut s);
        assert!(s.is_empty());
    }

    /// Thousands of random rays: the snapped face coordinate is exactly ±1 (so a checker of
    /// unit cells cannot flicker along the face), the point is the ray's within tolerance,
    /// and membership flips across every reported crossing.
    #[test]
    fn random_hits_are_snapped_and_consistent_with_membership() {
        let mut rng = Rng::new(7);
        for _ in 0..4000 {
            let o = rng.in_ball(6.0);
            let target = rng.in_ball(1.2);
            let r = Ray::new(o, target - o);
            let mut s = Vec::new();
            C.spans(&r, &mut s);
            if let Some(h) = C.intersect(&r, f64::INFINITY) {
                check_hit(C, &r, &h, f64::INFINITY);
                let axis = usize::from(h.face / 2);
                assert_eq!(h.p[axis].abs(), 1.0);
                assert!(h.p.abs().max_element() <= 1.0);
                // The cell index along the face axis is the same for every hit on the face.
                let expected = if h.p[axis] > 0.0 { 1.0 } else { -1.0 };
                assert_eq!(h.p[axis].floor(), expected);
            }
            for span in &s {
                for (c, entering) in [(span.enter, true), (span.exit, false)] {
                    let eps = 1e-9 * r.dir.length().recip();
                    let before = C.contains(r.at(c.t - eps));
                    let after = C.contains(r.at(c.t + eps));
                    if span.exit.t - span.enter.t > 4.0 * eps {
                        assert_eq!((before, after), (!entering, entering), "{r:?} {span:?}");
                    }
                }
            }
            // Hit/miss agrees with a slow march over membership.
            let marched = (0..=2000).any(|i| C.contains(r.at(f64::from(i) * 0.01)));
            let found = C.intersect(&r, f64::INFINITY).is_some();
            if marched {
                assert!(found, "march found the cube along {r:?}");
            }
        }
    }

    #[test]
    fn uv_corners_and_orientation() {
        // The +z face (towards the default camera) shows the texture upright.
        assert_eq!(uv(DVec3::new(-1.0, -1.0, 1.0), 5).uv, DVec2::new(0.0, 0.0));
        assert_eq!(uv(DVec3::new(1.0, 1.0, 1.0), 5).uv, DVec2::new(1.0, 1.0));
        // Every face: u grows to the right and v upwards as seen from outside, within [0, 1].
        for face in 0..6u8 {
            let axis = usize::from(face / 2);
            let mut n = DVec3::ZERO;
            n[axis] = if face & 1 == 1 { 1.0 } else { -1.0 };
            // The viewer's up: +y for side faces, −z above, +z below.
            let up = match face {
                2 => DVec3::Z,
                3 => -DVec3::Z,
                _ => DVec3::Y,
            };
            check_uv_orientation(n, up, |a, b| {
                let mut p = n + a + b;
                p[axis] = n[axis];
                uv(p, face).uv
            });
        }
    }
}
