//! The unit cone: apex (0, 1, 0), base of radius 1 at y = −1, base capped.
//!
//! Faces: 0 = side (the apex counts as side), 1 = base.
//!
//! The solid is the double cone `x² + z² ≤ ((1 − y)/2)²` cut by the slab `|y| ≤ 1`: inside
//! the slab `1 − y ≥ 0`, so only the lower nappe is there and no root on the upper nappe has
//! to be recognised and thrown away. The double cone meets a line in `{t : f(t) ≤ 0}` for a
//! quadratic `f`, which is an interval or the outside of one; either piece clipped by the
//! slab, and since the cone is convex the (at most two, touching at the apex) clipped pieces
//! join into one span.
//!
//! Numerics. The quadratic is set up after moving the ray origin to the line's point nearest
//! the apex and normalising the direction, so its coefficients are of the size of the cone
//! whatever the distance of the eye (from 1e7 away the raw coefficients would be 1e14 and
//! their differences noise), and small for a line passing near the apex, whose two roots
//! nearly coincide there and would otherwise come out only to √ε. Roots use the cancellation-free pair `q/a`,
//! `c/q`, then one Newton polish on the well-conditioned form `ρ − (1 − y)/2` (ρ the distance
//! from the axis), which is the horizontal distance to the surface, not its square. Hit points
//! are then projected onto the side's profile line in their (ρ, y) half-plane, so they lie on
//! the surface to a few ulps; base hits have y set to exactly −1.

use glam::{DVec2, DVec3};

use super::{Crossing, LocalHit, Span, SurfaceUv, Wrap, convex_pick, line_box, unit_dir};
use crate::math::{Ray, gamma};

pub(super) const SIDE: u8 = 0;
pub(super) const BASE: u8 = 1;

/// Whether a point is in the closed solid.
pub(super) fn contains(p: DVec3) -> bool {
    let w = 0.5 * (1.0 - p.y);
    p.y.abs() <= 1.0 && p.x * p.x + p.z * p.z <= w * w
}

/// `ρ − |1 − y|/2` and its derivative along unit direction `d` at `p`: the horizontal signed
/// distance to the surface of the double cone (both nappes, as the quadratic's roots lie on
/// either), negative inside. NaN slope on the axis and in the apex plane, where it has none.
#[inline]
fn radial(p: DVec3, d: DVec3) -> (f64, f64) {
    let rho = p.x.hypot(p.z);
    let w = 1.0 - p.y;
    let g = rho - 0.5 * w.abs();
    let dg = if rho > 0.0 && w != 0.0 {
        (p.x * d.x + p.z * d.z) / rho + 0.5 * d.y.copysign(w)
    } else {
        f64::NAN
    };
    (g, dg)
}

/// One Newton step on [`radial`] from `s` along the local ray, kept only if it lowers the
/// residual and moves less than `reach` (near the axis or at grazing incidence the step is
/// unreliable, and it must not jump to the other root).
#[inline]
fn polish(o: DVec3, d: DVec3, s: f64, reach: f64) -> f64 {
    let (g, dg) = radial(o + d * s, d);
    let next = s - g / dg;
    if next.is_finite() && (next - s).abs() <= reach && radial(o + d * next, d).0.abs() < g.abs() {
        next
    } else {
        s
    }
}

/// The line's span in the solid, with the faces crossed, in the ray's own `t`.
fn span(ray: &Ray) -> Option<(Crossing, Crossing)> {
    let (d, len) = unit_dir(ray.dir)?;
    // Lines that miss the bounding box [-1, 1]³ miss the cone.
    line_box(ray.origin, d, DVec3::ONE)?;
    // The local origin: the line's point nearest the apex. Within the box's reach of the
    // cone (the line meets the box), so the coefficients stay of the cone's size however far
    // the eye is; and a line passing near the apex has small coefficients there, whose
    // roots come out to a few ulps of its distance from the apex. (From the middle of the
    // line's passage through the box, the two roots of a line passing 1e-9 from the apex,
    // nearly a double root, would come out only to √ε ≈ 1e-8: a light just above the apex
    // would be shadowed by the cone on a random half of the floor.)
    let um = (DVec3::Y - ray.origin).dot(d);
    let o = ray.origin + d * um;

    // The slab |y| ≤ 1 in the local parameter s. Leaving by y = +1 means leaving through the
    // apex, the one point of the solid in that plane: reported as the side. (The box passage
    // only served to place the origin: the slab, or a bounded piece when the line is
    // horizontal, bounds the span by itself.)
    let inf = f64::INFINITY;
    let (s_lo, f_lo, s_hi, f_hi) = if d.y != 0.0 {
        let (a, b) = ((-1.0 - o.y) / d.y, (1.0 - o.y) / d.y);
        if d.y > 0.0 {
            (a, BASE, b, SIDE)
        } else {
            (b, SIDE, a, BASE)
        }
    } else if o.y.abs() <= 1.0 {
        (-inf, SIDE, inf, SIDE)
    } else {
        return None;
    };

    // f(s) = x² + z² − (w/2)², w = 1 − y, as a s² + 2 b s + c.
    let w0 = 1.0 - o.y;
    let a = d.x * d.x + d.z * d.z - 0.25 * d.y * d.y;
    let b = o.x * d.x + o.z * d.z + 0.25 * w0 * d.y;
    let c = o.x * o.x + o.z * o.z - 0.25 * w0 * w0;
    let disc = b * b - a * c;
    // The pieces of the line where f ≤ 0, as (start, end) with ±∞ for unbounded ends.
    let mut pieces = [(f64::NAN, f64::NAN); 2];
    if a == 0.0 {
        // Parallel to a generator: f is linear, 2 b s + c.
        if b == 0.0 {
            if c <= 0.0 {
                pieces[0] = (-inf, inf);
            }
        } else {
            let r = polish(o, d, -c / (2.0 * b), f64::INFINITY);
            pieces[0] = if b > 0.0 { (-inf, r) } else { (r, inf) };
        }
    } else if !(disc >= 0.0) {
        if a < 0.0 {
            pieces[0] = (-inf, inf);
        }
    } else {
        let q = -(b + disc.sqrt().copysign(b));
        let (mut r0, mut r1) = if q == 0.0 { (0.0, 0.0) } else { (q / a, c / q) };
        if r0 > r1 {
            std::mem::swap(&mut r0, &mut r1);
        }
        // A polish step may move a root by less than half the gap to the other one, so the
        // two can never swap or merge.
        let reach = 0.25 * (r1 - r0);
        let (r0, r1) = (polish(o, d, r0, reach), polish(o, d, r1, reach));
        if a > 0.0 {
            pieces[0] = (r0, r1);
        } else {
            pieces = [(-inf, r0), (r1, inf)];
        }
    }

    // Clip each piece by the slab (and box); join what is left (the solid is convex).
    let mut enter = Crossing {
        t: f64::INFINITY,
        face: SIDE,
    };
    let mut exit = Crossing {
        t: f64::NEG_INFINITY,
        face: SIDE,
    };
    for (p0, p1) in pieces {
        if p0.is_nan() || p1.is_nan() {
            continue;
        }
        let (a0, fa) = if p0 > s_lo { (p0, SIDE) } else { (s_lo, f_lo) };
        let (a1, fb) = if p1 < s_hi { (p1, SIDE) } else { (s_hi, f_hi) };
        if a0 > a1 {
            continue;
        }
        if a0 < enter.t {
            enter = Crossing { t: a0, face: fa };
        }
        if a1 > exit.t {
            exit = Crossing { t: a1, face: fb };
        }
    }
    if !(enter.t <= exit.t) {
        return None;
    }
    // Back to the ray's own parameter: t = (um + s) / |dir|.
    enter.t = (um + enter.t) / len;
    exit.t = (um + exit.t) / len;
    (enter.t.is_finite() && exit.t.is_finite()).then_some((enter, exit))
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
/// Side: in the half-plane of the point, (ρ, y) is projected orthogonally onto the profile
/// segment from the apex (0, 1) to the rim (1, −1): `ρ' = (ρ + 2(1 − y))/5` clamped to
/// [0, 1], `y' = 1 − 2ρ'`, then x and z are scaled from ρ to ρ'. `1 − y' = 2ρ'` holds exactly
/// up to the one rounding of `y'`, so the point is on the surface to within a few ulps of its
/// coordinates, hence `γ(6)·|p|`; the outward normal `(x/ρ', 1/2, z/ρ')` (the gradient of
/// `ρ − (1 − y)/2`) is then well defined everywhere but at the apex, where +y is used.
/// Base: y is exactly −1; x, z as for a cube face, pulled onto the disc if just outside it.
pub(super) fn surface_at(ray: &Ray, t: f64, face: u8) -> LocalHit {
    let raw = ray.at(t);
    if face == BASE {
        let (mut x, mut z) = (raw.x, raw.z);
        let r2 = x * x + z * z;
        if r2 > 1.0 {
            let r = r2.sqrt();
            (x, z) = (x / r, z / r);
        }
        if !(x.is_finite() && z.is_finite()) {
            (x, z) = (0.0, 0.0);
        }
        let mag = gamma(5) * (ray.origin.abs() + (ray.dir * t).abs());
        return LocalHit {
            t,
            p: DVec3::new(x, -1.0, z),
            p_err: DVec3::new(mag.x, 0.0, mag.z),
            n: -DVec3::Y,
            face,
        };
    }
    let rho = raw.x.hypot(raw.z);
    let (cx, cz) = if rho > 0.0 && rho.is_finite() {
        (raw.x / rho, raw.z / rho)
    } else {
        (1.0, 0.0)
    };
    let y = if raw.y.is_finite() { raw.y } else { 0.0 };
    let rho_in = if rho.is_finite() { rho } else { 0.0 };
    let r = ((rho_in + 2.0 * (1.0 - y)) * 0.2).clamp(0.0, 1.0);
    let p = DVec3::new(cx * r, 1.0 - 2.0 * r, cz * r);
    let n = if r > 0.0 {
        DVec3::new(cx, 0.5, cz)
    } else {
        DVec3::Y
    };
    LocalHit {
        t,
        p,
        p_err: gamma(6) * p.abs().max(DVec3::splat(r)),
        n,
        face,
    }
}

/// Side: `u` by longitude as on a sphere (`u = 0.5` faces +z), `v` from 0 at the base rim to
/// 1 at the apex; the texture wraps once around and pinches to the apex. Base: the texture's
/// square over the disc's bounding square, upright as seen from below with +z up.
pub(super) fn uv(p: DVec3, face: u8) -> SurfaceUv {
    let h = |a: f64| (0.5 * (a + 1.0)).clamp(0.0, 1.0);
    if face == BASE {
        return SurfaceUv {
            uv: DVec2::new(h(p.x), h(p.z)),
            wrap_u: Wrap::Clamp,
            wrap_v: Wrap::Clamp,
        };
    }
    SurfaceUv {
        uv: DVec2::new(0.5 + p.x.atan2(p.z) / std::f64::consts::TAU, h(p.y)),
        wrap_u: Wrap::Repeat,
        wrap_v: Wrap::Clamp,
    }
}

#[cfg(test)]
mod tests {
    use super::super::Shape;
    use super::super::test_support::{Rng, check_hit, check_uv_orientation};
    use super::*;

    const K: Shape = Shape::Cone;

    /// Distance from a point to the cone's side surface along the horizontal, for checks
    /// independent of the code under test: |ρ − (1 − y)/2|.
    fn off_side(p: DVec3) -> f64 {
        (p.x.hypot(p.z) - 0.5 * (1.0 - p.y)).abs()
    }

    #[test]
    fn hits_side_base_and_apex() {
        // Horizontally at height 0: the radius there is 1/2.
        let r = Ray::new(DVec3::new(0.0, 0.0, 5.0), -DVec3::Z);
        let h = K.intersect(&r, f64::INFINITY).expect("hit");
        assert_eq!(h.face, SIDE);
        assert!((h.t - 4.5).abs() < 1e-15, "{h:?}");
        assert!((h.p - DVec3::new(0.0, 0.0, 0.5)).length() < 1e-15);
        // The outward normal leans up by the half-angle: (0, 1/2, 1) normalised.
        let n = h.n.normalize();
        assert!((n - DVec3::new(0.0, 0.5, 1.0).normalize()).length() < 1e-15);
        check_hit(K, &r, &h, f64::INFINITY);

        let r = Ray::new(DVec3::new(0.3, -5.0, 0.2), DVec3::Y);
        let h = K.intersect(&r, f64::INFINITY).expect("hit");
        assert_eq!((h.t, h.face, h.p), (4.0, BASE, DVec3::new(0.3, -1.0, 0.2)));
        assert_eq!(h.n, -DVec3::Y);

        // Straight down the axis: the apex, then out through the base.
        let r = Ray::new(DVec3::new(0.0, 5.0, 0.0), -DVec3::Y);
        let h = K.intersect(&r, f64::INFINITY).expect("apex");
        assert_eq!(h.face, SIDE);
        assert!((h.t - 4.0).abs() < 1e-15 && h.p.is_finite() && h.n.is_finite());
        let mut s = Vec::new();
        K.spans(&r, &mut s);
        assert_eq!(s.len(), 1);
        assert!((s[0].enter.t - 4.0).abs() < 1e-15);
        assert_eq!((s[0].exit.t, s[0].exit.face), (6.0, BASE));
    }

    #[test]
    fn misses_the_upper_nappe_and_beside() {
        // Above the apex inside the mirror-image (upper) nappe of the double cone: nothing.
        let r = Ray::new(DVec3::new(-5.0, 2.0, 0.0), DVec3::X);
        assert!(K.intersect(&r, f64::INFINITY).is_none());
        // Horizontal at y = 0 passing at 0.51 > 0.5 from the axis.
        let r = Ray::new(DVec3::new(0.51, 0.0, 5.0), -DVec3::Z);
        assert!(K.intersect(&r, f64::INFINITY).is_none());
        // Below the base.
        let r = Ray::new(DVec3::new(-5.0, -1.001, 0.0), DVec3::X);
        assert!(K.intersect(&r, f64::INFINITY).is_none());
        // Steep ray through the upper nappe and down beside the cone.
        let r = Ray::new(DVec3::new(0.1, 3.0, 0.0), DVec3::new(0.5, -1.0, 0.0));
        // At y = -1 it is at x = 2.1; at y = 1, x = 1.1 > 0: outside all along.
        assert!(K.intersect(&r, f64::INFINITY).is_none());
    }

    #[test]
    fn hits_from_inside() {
        let r = Ray::new(DVec3::new(0.0, -0.5, 0.0), DVec3::X);
        let h = K.intersect(&r, f64::INFINITY).expect("hit");
        assert_eq!(h.face, SIDE);
        assert!((h.t - 0.75).abs() < 1e-15);
        let r = Ray::new(DVec3::new(0.0, -0.5, 0.0), -DVec3::Y);
        let h = K.intersect(&r, f64::INFINITY).expect("hit");
        assert_eq!((h.t, h.face), (0.5, BASE));
        let r = Ray::new(DVec3::new(0.0, -0.5, 0.0), DVec3::Y);
        let h = K.intersect(&r, f64::INFINITY).expect("apex from inside");
        assert!((h.t - 1.5).abs() < 1e-15);
    }

    /// Rays along a generator line of the cone (a = 0 in the quadratic) and tangent to the side.
    #[test]
    fn generator_and_tangent_rays() {
        // The generator through the apex and (0, -1, 1), extended: lies on the surface.
        let r = Ray::new(DVec3::new(0.0, 3.0, -1.0), DVec3::new(0.0, -2.0, 1.0));
        let mut s = Vec::new();
        K.spans(&r, &mut s);
        for sp in &s {
            assert!(sp.enter.t.is_finite() && sp.exit.t.is_finite());
        }
        // Parallel to a generator, inside: crosses the side once and the base once.
        let r = Ray::new(DVec3::new(0.0, 3.0, -1.5), DVec3::new(0.0, -2.0, 1.0));
        let h = K.intersect(&r, f64::INFINITY).expect("hit");
        assert!(off_side(h.p) < 1e-15 || h.face == BASE);
        // Horizontal tangent at y = 0, x = 0.5: touching counts, or a miss; never NaN.
        let r = Ray::new(DVec3::new(0.5, 0.0, 5.0), -DVec3::Z);
        if let Some(h) = K.intersect(&r, f64::INFINITY) {
            assert!((h.p - DVec3::new(0.5, 0.0, 0.0)).length() < 1e-7, "{h:?}");
        }
        // Through the base rim exactly.
        let r = Ray::new(DVec3::new(3.0, -3.0, 0.0), DVec3::new(-1.0, 1.0, 0.0));
        let h = K.intersect(&r, f64::INFINITY).expect("rim");
        assert!((h.p - DVec3::new(1.0, -1.0, 0.0)).length() < 1e-12, "{h:?}");
    }

    /// From 1e7 away, a cone of unit size: the shifted quadratic keeps hits exact where the
    /// raw coefficients (≈1e14) would lose the surface entirely.
    #[test]
    fn far_away_rays_hit_where_they_should() {
        let mut rng = Rng::new(5);
        for _ in 0..500 {
            let origin = rng.direction() * 1e7;
            let target = rng.in_ball(1.0);
            let r = Ray::new(origin, (target - origin).normalize());
            let inside_target = K.contains(target);
            let h = K.intersect(&r, f64::INFINITY);
            if inside_target {
                let h = h.expect("the ray passes through a point inside the cone");
                // The point on the ray is on the surface to the ray's own precision (1e7·ε).
                let q = r.at(h.t);
                let off = if h.face == BASE {
                    (q.y + 1.0).abs()
                } else {
                    off_side(q)
                };
                assert!(off < 1e-7, "{off} for {r:?}");
                assert!(off_side(h.p) < 1e-15 || h.face == BASE);
            }
        }
    }

    #[test]
    fn random_hits_lie_on_the_surface_and_flip_membership() {
        let mut rng = Rng::new(3);
        for _ in 0..4000 {
            let o = rng.in_ball(5.0);
            let r = Ray::new(o, rng.in_ball(1.3) - o);
            let found = K.intersect(&r, f64::INFINITY);
            if let Some(h) = found {
                check_hit(K, &r, &h, f64::INFINITY);
                if h.face == SIDE {
                    assert!(off_side(h.p) < 4e-16, "{h:?}");
                } else {
                    assert_eq!(h.p.y, -1.0);
                }
                // The ray's own point at t is on the surface too (the root is right).
                let q = r.at(h.t);
                let off = if h.face == BASE {
                    (q.y + 1.0).abs()
                } else {
                    off_side(q)
                };
                assert!(off < 1e-13, "{off}: {r:?} {h:?}");
            }
            let mut s = Vec::new();
            K.spans(&r, &mut s);
            for span in &s {
                let eps = 1e-9 / r.dir.length();
                if span.exit.t - span.enter.t > 4.0 * eps {
                    assert!(!K.contains(r.at(span.enter.t - eps)), "{r:?}");
                    assert!(K.contains(r.at(span.enter.t + eps)), "{r:?}");
                    assert!(K.contains(r.at(span.exit.t - eps)), "{r:?}");
                    assert!(!K.contains(r.at(span.exit.t + eps)), "{r:?}");
                }
            }
            let marched = (0..=2000).any(|i| K.contains(r.at(f64::from(i) * 0.01)));
            if marched {
                assert!(found.is_some(), "march found the cone along {r:?}");
            }
        }
    }

    #[test]
    fn uv_ranges_and_orientation() {
        assert_eq!(
            uv(DVec3::new(0.0, -1.0, 1.0), SIDE).uv,
            DVec2::new(0.5, 0.0)
        );
        assert_eq!(uv(DVec3::new(0.0, 1.0, 0.0), SIDE).uv.y, 1.0);
        check_uv_orientation(DVec3::Z, DVec3::Y, |a, b| {
            let y = b.y * 0.9;
            let w = 0.5 * (1.0 - y);
            let p = (DVec3::Z + a * 0.5).normalize() * w;
            uv(DVec3::new(p.x, y, p.z), SIDE).uv
        });
        check_uv_orientation(-DVec3::Y, DVec3::Z, |a, b| {
            uv(-DVec3::Y + (a + b) * 0.7, BASE).uv
        });
    }
}
