use super::super::Shape;
use super::super::test_support::{Rng, check_hit};
use super::*;
use crate::math::offset_ray_origin;

fn torus(major: f64, minor: f64) -> Shape {
    Shape::Torus { major, minor }
}

/// The torus's quartic in its textbook form, for checks independent of the solver.
fn quartic_f(p: DVec3, big: f64, small: f64) -> (f64, f64) {
    let k = p.length_squared() + big * big - small * small;
    let f = k * k - 4.0 * big * big * (p.x * p.x + p.z * p.z);
    let grad = DVec3::new(
        4.0 * k * p.x - 8.0 * big * big * p.x,
        4.0 * k * p.y,
        4.0 * k * p.z - 8.0 * big * big * p.z,
    );
    (f, grad.length())
}

/// The crossings of the line with the torus, by a dense march over the signed distance,
/// independent of the quartic. `sd` is 1-Lipschitz, so between two samples `h` apart with
/// the same sign there is no crossing when `|sd₀| + |sd₁| > h`; where that certificate
/// fails the interval is subdivided, and if it still fails at 1e-10 of the torus's size
/// the ray grazes the surface too closely to count its roots and `None` is returned.
/// Returns crossing distances along the unit direction from `o`, each to ~1e-15.
fn march(o: DVec3, d: DVec3, big: f64, small: f64) -> Option<Vec<f64>> {
    let sd = |u: f64| signed_distance(o + d * u, big, small);
    let uc = -o.dot(d);
    let reach = big + small;
    let h = small / 4.0;
    let n = (2.0 * reach / h).ceil() as usize + 2;
    let start = uc - reach - h;
    let mut roots = Vec::new();
    fn interval(
        sd: &dyn Fn(f64) -> f64,
        a: f64,
        b: f64,
        fa: f64,
        fb: f64,
        floor: f64,
        roots: &mut Vec<f64>,
    ) -> bool {
        if (fa > 0.0) != (fb > 0.0) {
            // Bisect to the crossing.
            let (mut a, mut b, mut fa) = (a, b, fa);
            for _ in 0..200 {
                let m = 0.5 * (a + b);
                if m <= a || m >= b {
                    break;
                }
                let fm = sd(m);
                if (fm > 0.0) == (fa > 0.0) {
                    a = m;
                    fa = fm;
                } else {
                    b = m;
                }
            }
            roots.push(0.5 * (a + b));
            return true;
        }
        if fa.abs() + fb.abs() > (b - a) * (1.0 + 1e-9) {
            return true;
        }
        if b - a < floor {
            return false;
        }
        let m = 0.5 * (a + b);
        let fm = sd(m);
        interval(sd, a, m, fa, fm, floor, roots) && interval(sd, m, b, fm, fb, floor, roots)
    }
    let floor = 1e-10 * (big + small);
    let mut prev = (start, sd(start));
    for i in 1..=n {
        let u = start + h * i as f64;
        let f = sd(u);
        if !interval(&sd, prev.0, u, prev.1, f, floor, &mut roots) {
            return None;
        }
        prev = (u, f);
    }
    Some(roots)
}

/// Runs the solver against the march on one ray; returns whether the march could decide.
/// Checks: the same number of crossings; each within `tol` (distance along the ray,
/// scaled by the slope of `sd` there) of the marched one; every ray point at a reported
/// `t` on the surface; every projected hit point on the surface; the nearest hit equal to
/// the first marched crossing ahead of the origin.
fn check_against_march(s: Shape, r: &Ray, tol: f64) -> bool {
    let Shape::Torus { major, minor } = s else {
        unreachable!("torus tests only")
    };
    let len = r.dir.length();
    let d = r.dir / len;
    let Some(marched) = march(r.origin, d, major, minor) else {
        return false;
    };
    let mut spans = Vec::new();
    s.spans(r, &mut spans);
    let found: Vec<f64> = spans
        .iter()
        .flat_map(|sp| [sp.enter.t * len, sp.exit.t * len])
        .collect();
    assert_eq!(
        found.len(),
        marched.len(),
        "{r:?} ({major}, {minor}): solver {found:?} vs march {marched:?}"
    );
    let scale = r.origin.length() + major + minor;
    for (f, m) in found.iter().zip(&marched) {
        let p = r.origin + d * *m;
        let (_, slope) = sd_slope(p / major, d, minor / major);
        let slack = tol * scale / slope.abs().max(1e-6);
        assert!(
            (f - m).abs() <= slack,
            "{r:?} ({major}, {minor}): root {f} vs marched {m} (slack {slack})"
        );
        // The ray's own point at the root is on the surface, to the ray's precision.
        let q = r.origin + d * *f;
        assert!(
            signed_distance(q, major, minor).abs() <= tol * scale,
            "sd {} at root {f}",
            signed_distance(q, major, minor)
        );
        let (fq, gq) = quartic_f(q, major, minor);
        assert!(
            (fq / gq).abs() <= 2.0 * tol * scale + 1e-12 * major,
            "quartic residual {} at root {f}",
            fq / gq
        );
    }
    let first_ahead = marched.iter().copied().find(|&m| m > 1e-9 * scale);
    match (s.intersect(r, f64::INFINITY), first_ahead) {
        (Some(h), Some(m)) => {
            check_hit(s, r, &h, f64::INFINITY);
            assert!(signed_distance(h.p, major, minor).abs() <= 8.0 * gamma(8) * (major + minor));
            let p = r.origin + d * m;
            let (_, slope) = sd_slope(p / major, d, minor / major);
            assert!(
                (h.t * len - m).abs() <= tol * scale / slope.abs().max(1e-6),
                "{r:?}: nearest {} vs {m}",
                h.t * len
            );
        }
        (None, None) => {}
        (h, m) => panic!("{r:?} ({major}, {minor}): nearest hit {h:?} vs marched {m:?}"),
    }
    true
}

#[test]
fn axis_rays_cross_at_the_known_radii() {
    let s = torus(2.0, 0.5);
    // Along x through the centre: crossings at ±2.5 and ±1.5.
    let r = Ray::new(DVec3::new(-10.0, 0.0, 0.0), DVec3::X);
    let mut sp = Vec::new();
    s.spans(&r, &mut sp);
    let ts: Vec<f64> = sp.iter().flat_map(|s| [s.enter.t, s.exit.t]).collect();
    let expect = [7.5, 8.5, 11.5, 12.5];
    assert_eq!(ts.len(), 4, "{ts:?}");
    for (t, e) in ts.iter().zip(expect) {
        assert!((t - e).abs() < 1e-14, "{ts:?}");
    }
    let h = s.intersect(&r, f64::INFINITY).expect("hit");
    assert!((h.t - 7.5).abs() < 1e-14);
    assert!((h.p - DVec3::new(-2.5, 0.0, 0.0)).length() < 1e-15);
    assert!((h.n - DVec3::new(-1.0, 0.0, 0.0)).length() < 1e-15);
    // Down through the tube at x = 2: enters at y = 0.5, leaves at y = -0.5.
    let r = Ray::new(DVec3::new(2.0, 5.0, 0.0), DVec3::new(0.0, -2.0, 0.0));
    let h = s.intersect(&r, f64::INFINITY).expect("hit");
    assert!((h.t - 2.25).abs() < 1e-15);
    assert!((h.n - DVec3::Y).length() < 1e-15);
    // Down the axis, through the hole: nothing.
    let r = Ray::new(DVec3::new(0.0, 5.0, 0.0), -DVec3::Y);
    assert!(s.intersect(&r, f64::INFINITY).is_none());
    // Across the hole's top, just above the tube: nothing.
    let r = Ray::new(DVec3::new(-5.0, 0.5001, 0.0), DVec3::X);
    assert!(s.intersect(&r, f64::INFINITY).is_none());
}

#[test]
fn from_inside_the_tube_and_from_the_hole() {
    let s = torus(2.0, 0.5);
    // Inside the tube at (2, 0, 0), heading +x: leaves at x = 2.5.
    let r = Ray::new(DVec3::new(2.0, 0.0, 0.0), DVec3::X);
    let h = s.intersect(&r, f64::INFINITY).expect("hit");
    assert!((h.t - 0.5).abs() < 1e-15);
    // Heading -x: leaves at x = 1.5, then meets the far side of the ring at x = -1.5.
    let r = Ray::new(DVec3::new(2.0, 0.0, 0.0), -DVec3::X);
    let h = s.intersect(&r, f64::INFINITY).expect("hit");
    assert!((h.t - 0.5).abs() < 1e-15);
    let r = Ray::new(DVec3::ZERO, DVec3::new(0.0, 0.0, 3.0));
    let h = s.intersect(&r, f64::INFINITY).expect("hit");
    assert!((h.t - 0.5).abs() < 1e-15, "{h:?}");
    // t_max before the hit.
    assert!(s.intersect(&r, 0.49).is_none());
}

#[test]
fn degenerate_rays_make_no_nan() {
    let s = torus(1.0, 0.25);
    for r in [
        Ray::new(DVec3::ZERO, DVec3::ZERO),
        Ray::new(DVec3::new(1.25, 0.0, 5.0), -DVec3::Z), // tangent to the outer equator
        Ray::new(DVec3::new(0.75, 0.0, 5.0), -DVec3::Z), // tangent to the inner equator
        Ray::new(DVec3::new(-5.0, 0.25, 0.0), DVec3::X), // along the top circle's plane
        Ray::new(DVec3::new(1.0, 0.25, 0.0), DVec3::X),  // starting on the top circle
        Ray::new(DVec3::new(1.0, 0.0, 0.0), DVec3::Y),   // starting on the core circle
        Ray::new(DVec3::new(1e300, 0.0, 0.0), -DVec3::X),
        Ray::new(DVec3::new(0.0, 0.0, 5.0), DVec3::new(0.0, -0.0, -1e-300)),
    ] {
        let mut sp = Vec::new();
        s.spans(&r, &mut sp);
        for x in &sp {
            assert!(x.enter.t.is_finite() && x.exit.t.is_finite() && x.enter.t <= x.exit.t);
        }
        if let Some(h) = s.intersect(&r, f64::INFINITY) {
            assert!(
                h.p.is_finite() && h.n.is_finite() && h.t.is_finite(),
                "{r:?}"
            );
        }
    }
}

/// Random oblique rays from nearby, against the dense march.
#[test]
fn oblique_rays_match_a_dense_march() {
    let mut rng = Rng::new(1);
    let mut decided = 0;
    for i in 0..1500 {
        let (big, small) = if i % 3 == 0 { (1.0, 0.25) } else { (2.0, 0.9) };
        let s = torus(big, small);
        let o = rng.in_ball(4.0 * (big + small));
        let target = rng.in_ball(big + small) * DVec3::new(1.0, small / (big + small), 1.0);
        let r = Ray::new(o, (target - o) * rng.range(0.1, 10.0));
        if check_against_march(s, &r, 1e-13) {
            decided += 1;
        }
    }
    assert!(decided > 1450, "only {decided} of 1500 rays were decidable");
}

/// From 1e7 away (the scale where closed-form solvers are off by 0.1): crossings still
/// match the march to the ray's own precision (1e7 · ε ≈ 1e-9).
#[test]
fn rays_from_far_away_match_a_dense_march() {
    let mut rng = Rng::new(2);
    let s = torus(1.0, 0.25);
    let mut hits = 0;
    for _ in 0..400 {
        let o = rng.direction() * 1e7;
        let target = rng.in_ball(1.25) * DVec3::new(1.0, 0.2, 1.0);
        let r = Ray::new(o, (target - o).normalize());
        assert!(check_against_march(s, &r, 1e-15));
        hits += usize::from(s.intersect(&r, f64::INFINITY).is_some());
    }
    assert!(hits > 100, "{hits}");
}

/// Thin tori (minor = 1e-3 · major) and a scaled-down and scaled-up torus.
#[test]
fn thin_and_scaled_tori_match_a_dense_march() {
    let mut rng = Rng::new(3);
    let mut hits = 0;
    for i in 0..300 {
        let big = [1.0, 1e-3, 1e4][i % 3];
        let small = 1e-3 * big;
        let s = torus(big, small);
        // Aim at a point near the tube so that many rays hit.
        let a = rng.range(0.0, std::f64::consts::TAU);
        let near = DVec3::new(a.cos(), 0.0, a.sin()) * big + rng.in_ball(2.0 * small);
        let o = rng.direction() * 3.0 * big;
        let r = Ray::new(o, near - o);
        assert!(check_against_march(s, &r, 1e-13), "{r:?}");
        hits += usize::from(s.intersect(&r, f64::INFINITY).is_some());
    }
    assert!(hits > 100, "{hits}");
}

/// Grazing rays: tangent to the surface at a random point, moved off it by ±1e-4 of the
/// tube radius (inside: the line must cross near there; outside: the march decides).
#[test]
fn grazing_rays_match_a_dense_march() {
    let mut rng = Rng::new(4);
    let mut decided = 0;
    for i in 0..600 {
        let (big, small) = if i % 2 == 0 { (1.0, 0.25) } else { (1.0, 1e-3) };
        let s = torus(big, small);
        let (a, b) = (
            rng.range(0.0, std::f64::consts::TAU),
            rng.range(0.0, std::f64::consts::TAU),
        );
        let radial = DVec3::new(a.cos(), 0.0, a.sin());
        let n = radial * b.cos() + DVec3::Y * b.sin();
        let p = radial * big + n * small;
        let t = n.any_orthonormal_vector();
        let t2 = n.cross(t);
        let c = rng.range(0.0, std::f64::consts::TAU);
        let dir = t * c.cos() + t2 * c.sin();
        let off = if i % 4 < 2 { -1e-4 } else { 1e-4 } * small;
        let r = Ray::new(p + n * off - dir * 3.0 * big, dir);
        if check_against_march(s, &r, 1e-13) {
            decided += 1;
            if off < 0.0 {
                let mut sp = Vec::new();
                s.spans(&r, &mut sp);
                // The point at t = 3 is inside the solid: some span must hold it.
                assert!(
                    sp.iter().any(|x| x.enter.t < 3.0 && x.exit.t > 3.0),
                    "{r:?}: no span around the grazed point: {sp:?}"
                );
            }
        }
    }
    assert!(
        decided > 550,
        "only {decided} of 600 grazing rays were decidable"
    );
}

/// A ray leaving the surface from a lifted origin (as shadow and mirror rays do) never
/// meets the surface it left, on either side, anywhere on the torus, far from the origin
/// of object space or near it.
#[test]
fn rays_leaving_the_surface_do_not_hit_it_again() {
    let mut rng = Rng::new(5);
    for i in 0..3000 {
        let (big, small) = [(1.0, 0.25), (1.0, 1e-3), (1e5, 2e4)][i % 3];
        let s = torus(big, small);
        let o = rng.direction() * big * 4.0;
        let target = rng.in_ball(big + small) * DVec3::new(1.0, small / big, 1.0);
        let r = Ray::new(o, target - o);
        let Some(h) = s.intersect(&r, f64::INFINITY) else {
            continue;
        };
        for _ in 0..2 {
            let dir = rng.direction();
            let origin = offset_ray_origin(h.p, 2.0 * h.p_err, h.n, dir);
            let leaving = Ray::new(origin, dir);
            if let Some(h2) = s.intersect(&leaving, f64::INFINITY) {
                let moved = (h2.p - h.p).length();
                assert!(
                    moved > 1e-6 * small,
                    "self-hit at {:?} (moved {moved}) leaving {:?} towards {dir:?}",
                    h2.p,
                    h.p
                );
            }
        }
    }
}

#[test]
fn membership_flips_across_every_crossing() {
    let mut rng = Rng::new(6);
    let s = torus(1.0, 0.3);
    for _ in 0..2000 {
        let o = rng.in_ball(4.0);
        let r = Ray::new(o, rng.in_ball(1.3) - o);
        let mut sp = Vec::new();
        s.spans(&r, &mut sp);
        let eps = 1e-9 / r.dir.length();
        for x in &sp {
            if x.exit.t - x.enter.t > 4.0 * eps {
                assert!(!s.contains(r.at(x.enter.t - eps)));
                assert!(s.contains(r.at(x.enter.t + eps)));
                assert!(s.contains(r.at(x.exit.t - eps)));
                assert!(!s.contains(r.at(x.exit.t + eps)));
            }
        }
    }
}

#[test]
fn uv_runs_around_the_ring_and_the_tube() {
    let near = |a: DVec2, b: DVec2| (a - b).length() < 1e-15;
    assert!(near(
        uv(DVec3::new(0.0, 0.0, 1.25), 1.0).uv,
        DVec2::new(0.5, 0.0)
    ));
    assert!(near(
        uv(DVec3::new(0.0, 0.25, 1.0), 1.0).uv,
        DVec2::new(0.5, 0.25)
    ));
    assert!(near(
        uv(DVec3::new(0.0, 0.0, 0.75), 1.0).uv,
        DVec2::new(0.5, 0.5)
    ));
    assert!(near(
        uv(DVec3::new(0.0, -0.25, 1.0), 1.0).uv,
        DVec2::new(0.5, 0.75)
    ));
    assert!(near(
        uv(DVec3::new(1.25, 0.0, 0.0), 1.0).uv,
        DVec2::new(0.75, 0.0)
    ));
    let mut rng = Rng::new(9);
    for _ in 0..1000 {
        let d = rng.direction();
        let uv = uv(d, 1.0).uv;
        assert!((0.0..=1.0).contains(&uv.x) && (0.0..1.0).contains(&uv.y));
    }
}
