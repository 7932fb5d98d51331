//! The ring torus around the y axis: the points at distance `minor` from the circle of
//! radius `major` in the xz plane, `0 < minor < major`.
//!
//! A line meets a torus in up to four points, the real roots of a quartic. Closed-form
//! (Ferrari) solutions are known to lose real roots for oblique rays and to be off by 0.1 at
//! a distance of 1e7; this module does not use one. Instead:
//!
//! 1. **Condition the quartic.** Coordinates are divided by `major` (the torus becomes
//!    `R = 1`, `r = minor/major`, so no coefficient can overflow whatever the size), the
//!    direction is normalised, and the ray origin is moved to the middle of the line's
//!    passage through the (slightly widened) bounding box. In that frame every coefficient is
//!    of order 1, whatever the distance of the eye: a root is found to ~1e-15 of the torus's
//!    size instead of ~1e-15 of the distance.
//! 2. **Isolate every real root by bracketing.** The roots of the quartic `q` are separated
//!    by the roots of its cubic derivative `q'`, which are separated by the (closed-form,
//!    only used as split points) roots of the quadratic `q''`. Between consecutive critical
//!    points `q` is monotone, so a sign change there is exactly one root and no sign change
//!    is none; the search interval's ends lie outside the torus (q > 0), so roots come in
//!    entry/exit pairs by construction. Each root is then found by Newton's method safeguarded
//!    by bisection inside its bracket: it cannot escape the bracket or miss.
//! 3. **Polish on the geometric form.** A few Newton steps, kept inside the root's monotone
//!    interval, on the signed distance to the surface `sd(p) = |(ρ − R, y)| − r`
//!    (ρ = √(x² + z²)). The quartic `f(p) = (|p|² + R² − r²)² − 4R²(x² + z²)` factors as
//!    `g·(g + 4Rρ)` with `g = (ρ − R)² + y² − r²`, so it has the same zero set, but `sd` is
//!    its well-conditioned form: no squares of large numbers, no cancellation for thin tori,
//!    and slope 1 across the surface.
//!
//! Hit points are then projected onto the torus exactly (onto the core circle, then `minor`
//! out along the direction to the point), so they lie on the surface to a few ulps. A ray
//! tangent to the torus may be reported as touching or missing, never as NaN.
//!
//! Spindle and horn tori (`minor ≥ major`) are refused by the parser: their quartic also
//! vanishes on an inner surface that is not the solid's boundary.

use arrayvec::ArrayVec;
use glam::{DVec2, DVec3};

use super::{Crossing, LocalHit, Span, SurfaceUv, Wrap, line_box, unit_dir};
use crate::math::{EPS, Ray, gamma};

/// Signed distance from `p` to the torus surface, negative inside. It is the exact Euclidean
/// distance for a ring torus, computed without cancellation: `ρ` and the inner `hypot` are
/// accurate to an ulp, and `ρ − major` is exact when ρ ≈ major (Sterbenz).
#[inline]
pub(super) fn signed_distance(p: DVec3, major: f64, minor: f64) -> f64 {
    (p.x.hypot(p.z) - major).hypot(p.y) - minor
}

/// The crossings of a line with the torus, ascending, in the ray's own `t`; an even count
/// (entry, exit, entry, exit).
#[derive(Debug, Clone, Copy, Default)]
struct Roots {
    t: [f64; 4],
    n: usize,
}

/// `q(s)` and `q'(s)` by Horner's rule, `c[i]` the coefficient of `sⁱ`.
#[inline]
fn quartic(c: &[f64; 5], s: f64) -> (f64, f64) {
    let q = (((c[4] * s + c[3]) * s + c[2]) * s + c[1]) * s + c[0];
    let dq = ((4.0 * c[4] * s + 3.0 * c[3]) * s + 2.0 * c[2]) * s + c[1];
    (q, dq)
}

/// `q'(s)` and `q''(s)`.
#[inline]
fn cubic(c: &[f64; 5], s: f64) -> (f64, f64) {
    let d = ((4.0 * c[4] * s + 3.0 * c[3]) * s + 2.0 * c[2]) * s + c[1];
    let dd = (12.0 * c[4] * s + 6.0 * c[3]) * s + 2.0 * c[2];
    (d, dd)
}

/// The root of `f` in `[a, b]`, where `f(a)` is classified `pos_a` (`f > 0`) and `f(b)` the
/// opposite: Newton steps while they stay inside the bracket and at least halve the previous
/// step, bisection otherwise (Numerical Recipes' `rtsafe`). The bracket shrinks at every
/// step, so this ends within the iteration cap, at worst with bisection's precision.
fn bracketed_root(f: impl Fn(f64) -> (f64, f64), mut a: f64, mut b: f64, pos_a: bool) -> f64 {
    let mut x = 0.5 * (a + b);
    let mut prev_step = b - a;
    for _ in 0..100 {
        let (fx, dfx) = f(x);
        if fx == 0.0 {
            return x;
        }
        if (fx > 0.0) == pos_a {
            a = x;
        } else {
            b = x;
        }
        if !(b - a > 2.0 * EPS * a.abs().max(b.abs())) {
            break;
        }
        let newton = x - fx / dfx;
        let step = (newton - x).abs();
        let next = if newton > a && newton < b && step < 0.5 * prev_step {
            prev_step = step;
            newton
        } else {
            prev_step = b - a;
            0.5 * (a + b)
        };
        if next == x {
            break;
        }
        x = next;
    }
    x
}

/// Real roots of `A s² + B s + C` inside `(lo, hi)`, ascending, appended to `out`.
fn quadratic_roots_in(a: f64, b: f64, c: f64, lo: f64, hi: f64, out: &mut ArrayVec<f64, 4>) {
    let mut push = |r: f64| {
        if r > lo && r < hi {
            out.push(r);
        }
    };
    if a == 0.0 {
        if b != 0.0 {
            push(-c / b);
        }
        return;
    }
    let disc = b * b - 4.0 * a * c;
    if !(disc >= 0.0) {
        return;
    }
    let q = -0.5 * (b + disc.sqrt().copysign(b));
    let (r0, r1) = if q == 0.0 { (0.0, 0.0) } else { (q / a, c / q) };
    push(r0.min(r1));
    if r1 != r0 {
        push(r0.max(r1));
    }
}

/// `sd` and its derivative along unit `d` at `p` for the normalised torus (R = 1).
#[inline]
fn sd_slope(p: DVec3, d: DVec3, r: f64) -> (f64, f64) {
    let rho = p.x.hypot(p.z);
    let e = rho - 1.0;
    let h = e.hypot(p.y);
    let slope = if rho > 0.0 && h > 0.0 {
        (e * (p.x * d.x + p.z * d.z) / rho + p.y * d.y) / h
    } else {
        f64::NAN
    };
    (h - r, slope)
}

/// All crossings of the line with the torus.
fn roots(ray: &Ray, major: f64, minor: f64) -> Roots {
    let mut out = Roots::default();
    let Some((d, len)) = unit_dir(ray.dir) else {
        return out;
    };
    // Normalised frame: R = 1.
    let r = minor / major;
    let o_n = ray.origin / major;
    // The passage through the bounding box, widened by a margin so that both ends are
    // clearly outside the torus (q there is at least ~margin², far above its rounding).
    let margin = 0.05 * (1.0 + r);
    let e = DVec3::new(1.0 + r + margin, r + margin, 1.0 + r + margin);
    let Some((u0, u1)) = line_box(o_n, d, e) else {
        return out;
    };
    let um = 0.5 * (u0 + u1);
    let o = o_n + d * um;
    let (lo, hi) = (u0 - um, u1 - um);

    // q(s) = G(s)² − H(s), G = |o + s d|² + 1 − r², H = 4((ox + s dx)² + (oz + s dz)²).
    let dd = d.length_squared();
    let b = o.dot(d);
    let g0 = o.length_squared() + 1.0 - r * r;
    let a_xz = d.x * d.x + d.z * d.z;
    let b_xz = o.x * d.x + o.z * d.z;
    let c_xz = o.x * o.x + o.z * o.z;
    let c = [
        g0 * g0 - 4.0 * c_xz,
        4.0 * b * g0 - 8.0 * b_xz,
        4.0 * b * b + 2.0 * g0 * dd - 4.0 * a_xz,
        4.0 * b * dd,
        dd * dd,
    ];
    if !c.iter().all(|x| x.is_finite()) {
        return out;
    }

    // Split points where q' is monotone: the roots of q''. On the stack (at most two roots
    // between the ends), as are the critical points below: a heap allocation per ray cost
    // more than the root finding on rays that miss.
    let mut split: ArrayVec<f64, 4> = ArrayVec::new();
    split.push(lo);
    quadratic_roots_in(12.0 * c[4], 6.0 * c[3], 2.0 * c[2], lo, hi, &mut split);
    split.push(hi);
    // Critical points of q: one root of q' per sign change between split points.
    // At most one root of q' per window between split points: three, plus the ends.
    let mut crit: ArrayVec<f64, 5> = ArrayVec::new();
    crit.push(lo);
    for w in split.windows(2) {
        let (fa, fb) = (cubic(&c, w[0]).0, cubic(&c, w[1]).0);
        if (fa > 0.0) != (fb > 0.0) {
            crit.push(bracketed_root(|s| cubic(&c, s), w[0], w[1], fa > 0.0));
        }
    }
    crit.push(hi);
    // One root of q per change of "inside" (q ≤ 0) between critical points. Both ends are
    // outside by construction; classifying them so makes the count even however rounding
    // falls.
    let n = crit.len();
    let inside: ArrayVec<bool, 5> = crit
        .iter()
        .enumerate()
        .map(|(i, &s)| i != 0 && i != n - 1 && quartic(&c, s).0 <= 0.0)
        .collect();
    for i in 0..n - 1 {
        if inside[i] == inside[i + 1] || out.n == 4 {
            continue;
        }
        let (a, bnd) = (crit[i], crit[i + 1]);
        let mut s = bracketed_root(|s| quartic(&c, s), a, bnd, !inside[i]);
        // Polish on the signed distance, inside this monotone interval, only while it helps.
        // The distance at an accepted step is the next step's starting value, so each step
        // evaluates it once (two `hypot`s, the polish's whole cost).
        let (mut g, mut slope) = sd_slope(o + d * s, d, r);
        for _ in 0..4 {
            if g == 0.0 {
                break;
            }
            let next = s - g / slope;
            if !(next >= a && next <= bnd) {
                break;
            }
            let (g_next, slope_next) = sd_slope(o + d * next, d, r);
            if !(g_next.abs() < g.abs()) {
                break;
            }
            (s, g, slope) = (next, g_next, slope_next);
        }
        out.t[out.n] = (um + s) * major / len;
        out.n += 1;
    }
    // An odd count can only come from the four-root cap being hit by rounding trouble; drop
    // the unpaired crossing rather than report a span without an end.
    out.n &= !1;
    if !out.t[..out.n].iter().all(|t| t.is_finite()) {
        out.n = 0;
    }
    out
}

/// The nearest crossing with `0 < t < t_max`, of the kind the origin calls for.
///
/// Whether the origin is inside is known more reliably from `sd` at the origin itself than
/// from the sign of a crossing computed near `t = 0`; so a first crossing of the wrong kind
/// (an exit for an origin outside, an entry for one inside) is the surface the ray has just
/// left, put at a tiny positive `t` by rounding, and is skipped. That is what keeps a
/// shadow ray leaving the torus, which must test the torus again (it is not convex), from
/// shadowing its own starting point.
pub(super) fn intersect(ray: &Ray, t_max: f64, major: f64, minor: f64) -> Option<LocalHit> {
    let roots = roots(ray, major, minor);
    let ts = &roots.t[..roots.n];
    let mut k = ts.iter().position(|&t| t > 0.0)?;
    let origin_outside = !(signed_distance(ray.origin, major, minor) < 0.0);
    // Roots alternate entry, exit. When the first root ahead is not of the kind the origin
    // calls for, the origin sits on a surface within rounding, and the root nearer zero is
    // that surface: if it is the one ahead (a secondary ray lifted off the face it leaves,
    // whose crossing rounded to a tiny positive `t`), it is skipped; if it is the one behind
    // (an eye exactly on the surface, looking in: the entry rounded to a tiny negative `t`),
    // the ray has crossed it, and the root ahead is the right one. Skipping it there made
    // the tube vanish and showed the floor through it.
    if (k % 2 == 0) != origin_outside && !(k > 0 && ts[k - 1].abs() < ts[k].abs()) {
        k += 1;
    }
    let t = *ts.get(k)?;
    (t < t_max).then(|| surface_at(ray, t, major, minor))
}

pub(super) fn spans(ray: &Ray, out: &mut Vec<Span>, major: f64, minor: f64) {
    let roots = roots(ray, major, minor);
    for pair in roots.t[..roots.n].chunks_exact(2) {
        out.push(Span {
            enter: Crossing {
                t: pair[0],
                face: 0,
            },
            exit: Crossing {
                t: pair[1],
                face: 0,
            },
        });
    }
}

/// The point at `t` projected onto the torus: onto the core circle (`major` along the
/// point's azimuth), then `minor` along the unit vector from there to the point, which is
/// also the outward normal. Each coordinate is then within a few roundings of
/// `major + minor` of the exact surface point in that direction: the azimuth's unit vector
/// (hypot, division: `γ(3)`), scaled by `major` (`γ(4)`); that error also tilts the tube
/// direction by up to `γ(4)·major/|v|`, moving the point by up to `γ(4)·major` across the
/// tube; the tube vector itself and the final sum add `γ(4)·minor`. Hence `γ(8)·(major +
/// minor)` per axis.
pub(super) fn surface_at(ray: &Ray, t: f64, major: f64, minor: f64) -> LocalHit {
    let raw = ray.at(t);
    let raw = if raw.is_finite() {
        raw
    } else {
        DVec3::new(major + minor, 0.0, 0.0)
    };
    let rho = raw.x.hypot(raw.z);
    let (ax, az) = if rho > 0.0 {
        (raw.x / rho, raw.z / rho)
    } else {
        (1.0, 0.0)
    };
    let core = DVec3::new(ax * major, 0.0, az * major);
    let v = raw - core;
    let l = v.length();
    let n = if l > 0.0 {
        v / l
    } else {
        DVec3::new(ax, 0.0, az)
    };
    LocalHit {
        t,
        p: core + n * minor,
        p_err: DVec3::splat(gamma(8) * (major + minor)),
        n,
        face: 0,
    }
}

/// `u` by longitude around the y axis as on a sphere (`u = 0.5` faces +z, growing towards
/// +x); `v` by the angle around the tube, 0 on the outer equator, 0.25 on the top circle,
/// 0.5 on the inner equator, 0.75 underneath. The texture tiles once in each direction.
pub(super) fn uv(p: DVec3, major: f64) -> SurfaceUv {
    let tau = std::f64::consts::TAU;
    let u = 0.5 + p.x.atan2(p.z) / tau;
    let v = p.y.atan2(p.x.hypot(p.z) - major) / tau;
    SurfaceUv {
        uv: DVec2::new(u, if v < 0.0 { v + 1.0 } else { v }),
        wrap_u: Wrap::Repeat,
        wrap_v: Wrap::Repeat,
    }
}

#[cfg(test)]
mod tests;
