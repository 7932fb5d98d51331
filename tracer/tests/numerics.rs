//! The tracer at the places where textbook numerics fail: tiny spheres far away, scenes far
//! from the origin or scaled up, self-shadowing ("acne"), grazing and parallel rays, and a
//! checker on the plane y = 0. Each test also shows, where it can, that the naive method
//! fails on the same input, so the test is known to sit at the failure case.

mod common;

use common::{RefPlane, RefSphere, Reference, compare_with_reference, scene};
use glam::DVec3;
use tessera_tracer::Rect;
use tessera_tracer::internals::{Ray, SurfacePoint};

/// A sphere of radius 0.1 seen from 1e7 away, framed to fill the image: every pixel centre is
/// hit or missed exactly as the geometry says, and lit with the right cosine.
#[test]
fn small_sphere_from_ten_million_away() {
    let (w, h) = (41u32, 41u32);
    let distance = 1e7;
    // Half the image height spans 0.2 at the sphere: tan(fov/2) = 0.2 / 1e7.
    let fov = 2.0 * (0.2f64 / distance).atan().to_degrees();
    let src = format!(
        "[GLOBALS]\nwidth = {w}\nheight = {h}\nambient = 0.1\nbackground = <0, 0, 1>\n[/GLOBALS]\n\
         [CAMERA]\neye = <0, 0, {distance}>\nfov = {fov:e}\n[/CAMERA]\n\
         [LIGHT]\nposition = <0, 0, {distance}>\n[/LIGHT]\n\
         [OBJECT]\ntype = sphere\nradius = 0.1\ncolor1 = 0.5\n[/OBJECT]\n"
    );
    let (linear, _) = scene(&src).render_rect_linear(Rect::full(w, h));
    let th = 0.2 / distance;
    let (mut hits, mut misses) = (0, 0);
    for j in 0..h {
        for i in 0..w {
            // Where the centre ray crosses z = 0 (the image plane through the sphere).
            let nx = (2.0 * (f64::from(i) + 0.5) / f64::from(w) - 1.0) * th;
            let ny = (1.0 - 2.0 * (f64::from(j) + 0.5) / f64::from(h)) * th;
            let rho = distance * nx.hypot(ny);
            let got = linear[(j * w + i) as usize];
            if (rho - 0.1).abs() < 1e-6 {
                continue;
            }
            if rho < 0.1 {
                hits += 1;
                // The ray is parallel to z to within 1e-8, and so is the light direction.
                let cos = (1.0 - (rho / 0.1).powi(2)).sqrt();
                let expected = 0.5 * (0.1 + cos);
                assert!(
                    (got - DVec3::splat(expected)).abs().max_element() < 1e-6,
                    "({i}, {j}) at ρ = {rho}: {got:?} vs {expected}"
                );
            } else {
                misses += 1;
                assert_eq!(got, DVec3::new(0.0, 0.0, 1.0), "({i}, {j}) at ρ = {rho}");
            }
        }
    }
    assert!(hits > 300 && misses > 1000, "{hits} hits, {misses} misses");
}

/// A scene with everything the tracer does: checker plane, mirror, shadows, a rotated and
/// non-uniformly scaled object, several lights. `k` scales the whole world and `offset` then
/// moves it.
fn world_scene(k: f64, offset: DVec3) -> String {
    let p = |v: DVec3| {
        let w = v * k + offset;
        format!("<{:e}, {:e}, {:e}>", w.x, w.y, w.z)
    };
    let place = format!("scale = {k:e}\ntranslate = {}\n", p(DVec3::ZERO));
    format!(
        "[GLOBALS]\nwidth = 96\nheight = 72\nshadow = 0.8\nbackground = <0.1, 0.2, 0.3>\n[/GLOBALS]\n\
         [CAMERA]\neye = {}\nlook_at = {}\nfov = 45\n[/CAMERA]\n\
         [LIGHT]\nposition = {}\n[/LIGHT]\n\
         [LIGHT]\nposition = {}\ncolor = 0.3\n[/LIGHT]\n\
         [OBJECT]\ntype = plane\ncolor1 = 1\ncolor2 = 0.1\n{place}[/OBJECT]\n\
         [OBJECT]\ntype = sphere\nradius = 2\ntranslate = <-3, 2, 0>\nmirror = 0.5\n{place}[/OBJECT]\n\
         [OBJECT]\ntype = sphere\nradius = 1.5\nscale = <1, 2, 1>\nrotate = <0, 0, 30>\n\
         translate = <3, 3, 0>\ncolor1 = <0.9, 0.4, 0.2>\ncolor2 = <0.2, 0.4, 0.9>\n{place}[/OBJECT]\n",
        p(DVec3::new(3.0, 6.0, 20.0)),
        p(DVec3::new(0.0, 1.0, 0.0)),
        p(DVec3::new(10.0, 20.0, 10.0)),
        p(DVec3::new(-10.0, 5.0, 5.0)),
    )
}

/// Byte differences between two RGB8 images: (pixels that differ, largest channel difference).
fn diff(a: &[u8], b: &[u8]) -> (usize, u8) {
    let mut pixels = 0;
    let mut max = 0;
    for (pa, pb) in a.chunks_exact(3).zip(b.chunks_exact(3)) {
        let d = pa
            .iter()
            .zip(pb)
            .map(|(x, y)| x.abs_diff(*y))
            .max()
            .unwrap_or(0);
        if d > 0 {
            pixels += 1;
            max = max.max(d);
        }
    }
    (pixels, max)
}

/// Moving the whole scene by (1e5, 1e5, 1e5), or scaling it by 1e4, renders the same image.
///
/// Tolerance: at most one pixel in a thousand may differ, by at most one 8-bit step. Why: at
/// 1e5 every coordinate carries an absolute rounding error near 1e5 · 2⁻⁵³ ≈ 1e-11 (relative
/// error 2⁻⁵³ after scaling), so a pixel can only change where its sample lands within
/// ~1e-11 of a silhouette or checker line, or its value within ~1e-11 of an 8-bit rounding
/// threshold: chances near 1e-9 per pixel. In practice the images come out identical.
#[test]
fn far_from_the_origin_or_scaled_up_renders_the_same_image() {
    let base = scene(&world_scene(1.0, DVec3::ZERO));
    let image = base.render_rect(Rect::full(96, 72));
    for (k, offset) in [
        (1.0, DVec3::splat(1e5)),
        (1e4, DVec3::ZERO),
        (1e4, DVec3::new(-3e5, 2e5, 1e5)),
    ] {
        let moved = scene(&world_scene(k, offset)).render_rect(Rect::full(96, 72));
        let (pixels, max) = diff(&image, &moved);
        assert!(
            pixels <= 96 * 72 / 1000 && max <= 1,
            "scale {k}, offset {offset:?}: {pixels} pixels differ, by up to {max}"
        );
    }
    // The same comparison does catch real changes: a light moved by 1 %.
    let nudged = world_scene(1.0, DVec3::ZERO).replace("<1e1, 2e1, 1e1>", "<1.01e1, 2e1, 1e1>");
    let (pixels, _) = diff(&image, &scene(&nudged).render_rect(Rect::full(96, 72)));
    assert!(pixels > 100, "the comparison is not sensitive: {pixels}");
}

/// Seen from inside, a sphere lit by a light inside it must be lit everywhere: every shadow
/// ray starts on the sphere and must not meet it again at t ≈ 0. The secondary-ray origins are
/// what prevent that, near the origin and 1e5 away alike.
#[test]
fn no_self_shadowing_inside_a_lit_sphere_near_and_far() {
    for offset in [DVec3::ZERO, DVec3::splat(1e5), DVec3::new(-7e5, 3e5, 1e6)] {
        let o = |v: DVec3| {
            let w = v + offset;
            format!("<{:e}, {:e}, {:e}>", w.x, w.y, w.z)
        };
        let src = format!(
            "[GLOBALS]\nwidth = 40\nheight = 30\nambient = 0.05\n[/GLOBALS]\n\
             [CAMERA]\neye = {}\nlook_at = {}\nfov = 90\n[/CAMERA]\n\
             [LIGHT]\nposition = {}\n[/LIGHT]\n\
             [OBJECT]\ntype = sphere\nradius = 50\ncolor1 = 0.7\ntranslate = {}\n[/OBJECT]\n",
            o(DVec3::new(0.0, 0.0, 20.0)),
            o(DVec3::new(5.0, -3.0, 0.0)),
            o(DVec3::new(10.0, 20.0, 5.0)),
            o(DVec3::ZERO),
        );
        let s = scene(&src);
        let (linear, stats) = s.render_rect_linear(Rect::full(40, 30));
        assert_eq!(stats.shadow, 40 * 30, "every pixel tests its light");
        let mut r = Reference::new(40, 30);
        r.eye = DVec3::new(0.0, 0.0, 20.0);
        r.look_at = DVec3::new(5.0, -3.0, 0.0);
        r.fov = 90.0;
        r.ambient = DVec3::splat(0.05);
        r.lights = vec![(DVec3::new(10.0, 20.0, 5.0), DVec3::ONE)];
        r.spheres = vec![RefSphere {
            centre: DVec3::ZERO,
            radius: 50.0,
            color: DVec3::splat(0.7),
            mirror: 0.0,
        }];
        let compared = compare_with_reference(&linear, &r, false, 1e-6);
        assert_eq!(compared, 40 * 30, "offset {offset:?}");
    }
}

/// The same inside view of a rotated, non-uniformly scaled sphere (an ellipsoid) far from the
/// origin: no pixel may show the shadowed value `c · ambient`.
#[test]
fn no_self_shadowing_inside_a_far_ellipsoid() {
    let src = "[GLOBALS]\nwidth = 64\nheight = 48\nambient = 0.05\nshadow = 1\n[/GLOBALS]\n\
               [CAMERA]\neye = <100000, 100000, 100020>\nlook_at = <100003, 99997, 100000>\nfov = 100\n[/CAMERA]\n\
               [LIGHT]\nposition = <100010, 100020, 100005>\n[/LIGHT]\n\
               [OBJECT]\ntype = sphere\nradius = 50\nscale = <1, 0.6, 1.7>\nrotate = <20, 35, -10>\n\
               translate = <100000, 100000, 100000>\ncolor1 = 1\n[/OBJECT]\n";
    let (linear, stats) = scene(src).render_rect_linear(Rect::full(64, 48));
    assert_eq!(stats.shadow, 64 * 48);
    let dark = linear.iter().filter(|c| c.x <= 0.05 + 1e-12).count();
    assert_eq!(dark, 0, "{dark} self-shadowed pixels");
}

/// Spawning shadow rays from the raw hit point (no offset) does self-intersect: the failure
/// the offsets exist for. From the lifted origin, the same rays never meet the surface again
/// near t = 0.
#[test]
fn offsets_prevent_the_self_hits_that_raw_hit_points_make() {
    let src = "[OBJECT]\ntype = sphere\nradius = 3\nscale = <1, 0.3, 2>\nrotate = <10, 20, 30>\n\
               translate = <123456.7, -98765.4, 55555.5>\n[/OBJECT]\n";
    let s = scene(src);
    let obj = &s.objects()[0];
    let centre = DVec3::new(123456.7, -98765.4, 55555.5);
    let (mut raw_self_hits, mut lifted_self_hits, mut tested) = (0, 0, 0);
    for i in 0..2000u32 {
        // Rays from points on a large shell around the object, aimed at points inside it.
        let a = f64::from(i) * 2.399_963;
        let z = 1.0 - 2.0 * (f64::from(i) + 0.5) / 2000.0;
        let dir_out = DVec3::new(
            (1.0 - z * z).sqrt() * a.cos(),
            z,
            (1.0 - z * z).sqrt() * a.sin(),
        );
        let from = centre + dir_out * 50.0;
        let aim = centre + DVec3::new((a * 3.1).sin(), (a * 1.7).cos(), (a * 0.3).sin()) * 0.5;
        let ray = Ray::new(from, aim - from);
        let local = obj.transform.ray_to_object(&ray);
        let Some(hit) = obj.shape.intersect(&local, f64::INFINITY) else {
            continue;
        };
        let sp = SurfacePoint::new(obj, &hit, ray.dir);
        // Leave towards a direction in the outer hemisphere, as a shadow ray does.
        let out = (sp.n + DVec3::new(a.cos(), a.sin(), (2.0 * a).cos()) * 0.9).normalize();
        if out.dot(sp.n) <= 0.01 {
            continue;
        }
        tested += 1;
        let self_hit = |origin: DVec3| {
            let r = obj.transform.ray_to_object(&Ray::new(origin, out));
            obj.shape.intersect(&r, f64::INFINITY).is_some()
        };
        raw_self_hits += usize::from(self_hit(sp.p));
        lifted_self_hits += usize::from(self_hit(sp.origin_towards(out)));
        // The shader lifts once per hit, for every ray leaving on the incoming side.
        assert_eq!(sp.origin_ahead(), sp.origin_towards(out));
    }
    assert!(tested > 1000, "{tested}");
    assert_eq!(lifted_self_hits, 0);
    assert!(
        raw_self_hits > tested / 10,
        "raw origins self-hit only {raw_self_hits} of {tested}"
    );
}

/// A secondary ray's origin lies within `SurfacePoint::reach` of its hit point, which the
/// shadow pre-test of scenes of few solids relies on: hits on spheres, planes, boxes and
/// rods scaled unevenly by up to a thousand, turned, and placed up to 1e9 from the origin,
/// among them planes hit a billion units from their own origin (whose error bound is then
/// far larger than the hit point's own ulps), seen from near and far.
#[test]
fn lifted_origins_lie_within_their_reach() {
    let mut rng = common::Rng(17);
    let mut tested = 0;
    for i in 0..400 {
        let shape = ["sphere", "plane", "cube", "cylinder"][i % 4];
        let big = 10f64.powf(rng.range(0.0, 9.0));
        let at = |p: DVec3| format!("<{:e}, {:e}, {:e}>", p.x, p.y, p.z);
        let scale = DVec3::new(
            rng.range(-3.0, 3.0),
            rng.range(-3.0, 3.0),
            rng.range(-3.0, 3.0),
        );
        let scale = scale.map(|e| 10f64.powf(e.clamp(-1.0, 3.0)));
        let place = rng.vec(1.0) * big;
        let src = format!(
            "[OBJECT]\ntype = {shape}\nscale = {}\nrotate = {}\ntranslate = {}\n[/OBJECT]\n",
            at(scale),
            at(rng.vec(180.0)),
            at(place)
        );
        let s = scene(&src);
        let obj = &s.objects()[0];
        // Aim at the solid's own centre, or (a plane) at the world origin's foot on it.
        let aim = if shape == "plane" { DVec3::ZERO } else { place };
        for _ in 0..20 {
            let far = scale.max_element() * 10f64.powf(rng.range(0.0, 4.0));
            let from = aim + rng.vec(1.0) * far;
            let ray = Ray::new(from, aim + rng.vec(0.5) * scale.min_element() - from);
            let local = obj.transform.ray_to_object(&ray);
            let Some(hit) = obj.shape.intersect(&local, f64::INFINITY) else {
                continue;
            };
            let sp = SurfacePoint::new(obj, &hit, ray.dir);
            let moved = (sp.origin_ahead() - sp.p).length();
            assert!(
                moved <= sp.reach(),
                "origin {moved:e} from the hit, reach {:e}: {src}",
                sp.reach()
            );
            tested += 1;
        }
    }
    assert!(tested > 4000, "{tested}");
}

/// A camera zoomed onto a sphere's limb: hundreds of rays graze it. Every pixel is finite and
/// equals the reference (hit and lit, or background) except the few within 1e-7 of tangency.
#[test]
fn grazing_rays_at_the_limb_give_no_speckles_or_nan() {
    let src = "[GLOBALS]\nwidth = 64\nheight = 64\nbackground = <0, 0, 1>\n[/GLOBALS]\n\
               [CAMERA]\neye = <0.99995, 0.01, 10>\nlook_at = <0.99995, 0.01, 0>\nfov = 0.002\n[/CAMERA]\n\
               [LIGHT]\nposition = <20, 3, 1>\n[/LIGHT]\n\
               [OBJECT]\ntype = sphere\ncolor1 = <1, 0.5, 0.25>\n[/OBJECT]\n\
               [OBJECT]\ntype = sphere\nradius = 0.5\ntranslate = <-3, 0, -3>\n[/OBJECT]\n";
    let (linear, _) = scene(src).render_rect_linear(Rect::full(64, 64));
    let mut r = Reference::new(64, 64);
    r.eye = DVec3::new(0.99995, 0.01, 10.0);
    r.look_at = DVec3::new(0.99995, 0.01, 0.0);
    r.fov = 0.002;
    r.background = DVec3::new(0.0, 0.0, 1.0);
    r.lights = vec![(DVec3::new(20.0, 3.0, 1.0), DVec3::ONE)];
    r.spheres = vec![
        RefSphere {
            centre: DVec3::ZERO,
            radius: 1.0,
            color: DVec3::new(1.0, 0.5, 0.25),
            mirror: 0.0,
        },
        RefSphere {
            centre: DVec3::new(-3.0, 0.0, -3.0),
            radius: 0.5,
            color: DVec3::ONE,
            mirror: 0.0,
        },
    ];
    let compared = compare_with_reference(&linear, &r, false, 1e-6);
    let hit = linear.iter().filter(|c| c.z < 1.0).count();
    assert!(compared > 64 * 60, "{compared}");
    assert!(
        hit > 500 && hit < 64 * 64 - 500,
        "the limb is not in view: {hit} hits"
    );
}

/// A camera 1e-3 above the plane y = 0, looking along it: rays nearly parallel to the plane
/// hit it up to ~1e6 away or not at all. No NaN, no value that is neither plane nor sky.
#[test]
fn rays_parallel_to_a_plane_give_no_speckles_or_nan() {
    let src = "[GLOBALS]\nwidth = 64\nheight = 48\nbackground = <0, 0, 1>\nlight = <3, 10, -4>\n[/GLOBALS]\n\
               [CAMERA]\neye = <0.3, 0.001, 0.7>\nlook_at = <0.3, 0.001, -100>\nfov = 20\n[/CAMERA]\n\
               [OBJECT]\ntype = plane\ncolor1 = 0.9\ncolor2 = 0.2\n[/OBJECT]\n";
    let (linear, _) = scene(src).render_rect_linear(Rect::full(64, 48));
    let mut r = Reference::new(64, 48);
    r.eye = DVec3::new(0.3, 0.001, 0.7);
    r.look_at = DVec3::new(0.3, 0.001, -100.0);
    r.fov = 20.0;
    r.background = DVec3::new(0.0, 0.0, 1.0);
    r.lights = vec![(DVec3::new(3.0, 10.0, -4.0), DVec3::ONE)];
    r.plane = Some(RefPlane {
        y: 0.0,
        color1: DVec3::splat(0.9),
        color2: Some(DVec3::splat(0.2)),
        mirror: 0.0,
    });
    let compared = compare_with_reference(&linear, &r, false, 1e-9);
    assert!(compared > 64 * 46, "{compared}");
}

/// A checkered plane at y = 0 seen obliquely: every pixel is exactly one of the two checker
/// shades the reference predicts from the cell of the hit point. A solid checker evaluated at
/// the computed hit point `o + t·d` would see y = ±1e-17 instead of 0 and flip cells.
#[test]
fn a_checkered_plane_at_y_zero_has_no_noise_along_its_cells() {
    let src = "[GLOBALS]\nwidth = 80\nheight = 60\nambient = 0.2\nlight = <0, 50, 0>\n[/GLOBALS]\n\
               [CAMERA]\neye = <0.37, 3.3, 7.9>\nlook_at = <0.1, 0, -0.2>\nfov = 50\n[/CAMERA]\n\
               [OBJECT]\ntype = plane\ncolor1 = 1\ncolor2 = 0.05\n[/OBJECT]\n";
    let (linear, _) = scene(src).render_rect_linear(Rect::full(80, 60));
    let mut r = Reference::new(80, 60);
    r.eye = DVec3::new(0.37, 3.3, 7.9);
    r.look_at = DVec3::new(0.1, 0.0, -0.2);
    r.fov = 50.0;
    r.ambient = DVec3::splat(0.2);
    r.lights = vec![(DVec3::new(0.0, 50.0, 0.0), DVec3::ONE)];
    r.plane = Some(RefPlane {
        y: 0.0,
        color1: DVec3::ONE,
        color2: Some(DVec3::splat(0.05)),
        mirror: 0.0,
    });
    let compared = compare_with_reference(&linear, &r, false, 1e-9);
    assert!(compared > 80 * 58, "{compared}");

    // The naive solid checker's failure on the same rays: computed y is often not 0.
    let mut flips = 0;
    for j in 0..60 {
        for i in 0..80 {
            let (o, d) = r.primary(f64::from(i) + 0.5, f64::from(j) + 0.5);
            let t = -o.y / d.y;
            if t > 0.0 && (o + d * t).y < 0.0 {
                flips += 1; // floor(y) = -1: the solid checker's parity flips here
            }
        }
    }
    assert!(
        flips > 100,
        "the naive checker would flip in only {flips} pixels"
    );
}

/// CSG solids whose details are small beside their distance from the world origin: a
/// pocket 0.05 deep cut into a cube (a difference), two overlapping spheres of different
/// colours (a union: the nearer surface must show its own colour), a rotated cube minus a
/// sphere it does not touch (whose silhouette must be the cube's), under a light that
/// skims the cube's top, and a rotated cube notched by a cutter whose face lies on the
/// cube's own (coincident faces, which must still merge far away: no speck of the cube's
/// face may show in the notch). Everything sits at `offset` plus integer coordinates, so moving
/// the scene changes no coordinate but the offset's, exactly.
fn csg_scene(offset: f64) -> String {
    let at = |x: i64, y: i64, z: i64| format!("<{}, {}, {}>", offset + x as f64, y, z);
    format!(
        "[GLOBALS]\nwidth = 96\nheight = 72\nambient = 0.1\nshadow = 1\n[/GLOBALS]\n\
         [CAMERA]\neye = {}\nlook_at = {}\nfov = 40\n[/CAMERA]\n\
         [LIGHT]\nposition = {}\n[/LIGHT]\n\
         [CSG]\nop = difference\ntranslate = {}\n\
         [OBJECT]\ntype = cube\ncolor1 = <1, 0.5, 0>\n[/OBJECT]\n\
         [OBJECT]\ntype = cube\nscale = <0.5, 0.5, 1>\ntranslate = <0, 0, 1.95>\ncolor1 = <0, 1, 1>\n[/OBJECT]\n\
         [/CSG]\n\
         [CSG]\nop = union\ntranslate = {}\n\
         [OBJECT]\ntype = sphere\ntranslate = <-0.3, 0, 0>\ncolor1 = <0.2, 0.9, 0.2>\n[/OBJECT]\n\
         [OBJECT]\ntype = sphere\ntranslate = <0.3, 0, 0.05>\ncolor1 = <0.2, 0.2, 0.9>\n[/OBJECT]\n[/CSG]\n\
         [CSG]\nop = difference\nrotate = <20, 35, 10>\ntranslate = {}\n\
         [OBJECT]\ntype = cube\nscale = 0.8\ncolor1 = <0.9, 0.7, 0.1>\n[/OBJECT]\n\
         [OBJECT]\ntype = sphere\nradius = 0.5\ntranslate = <3, 0, 0>\n[/OBJECT]\n[/CSG]\n\
         [CSG]\nop = difference\nrotate = <0, -50, 0>\ntranslate = {}\n\
         [OBJECT]\ntype = cube\nscale = 0.6\ncolor1 = <0.8, 0.8, 0.8>\n[/OBJECT]\n\
         [OBJECT]\ntype = cube\nscale = <0.3, 0.2, 0.2>\ntranslate = <0.3, 0, 0>\ncolor1 = <1, 0, 1>\n[/OBJECT]\n[/CSG]\n",
        at(0, 2, 9),
        at(0, 0, 0),
        at(-6, 2, 8),
        at(-3, 0, 0),
        at(0, 0, 0),
        at(3, 0, 0),
        at(-1, -2, 1),
    )
}

/// The CSG scene above moved 1e8, 1e9 and 1e10 along x renders the image it renders at the
/// origin. Lone objects do that (see above); CSG trees can lose geometry there, because
/// their tolerance for coincident surfaces grows with the distance from the world origin: a
/// tolerance of 1e-10 would be 0.1 of a unit at 1e9, and the pocket, the nearer sphere's
/// colour and pixels of the cube's silhouette would go.
///
/// Tolerance: at 1e10 every coordinate carries a rounding error near 1e10 · 2⁻⁵³ ≈ 1e-6,
/// and a composed transform a few times that, so a pixel may change where its sample lands
/// within ~1e-5 of a silhouette, an edge or the light's terminator: some 2e-4 of a pixel's
/// footprint here (0.04 of a unit), about one pixel in a few thousand along the edges. At
/// most one pixel in a thousand may differ, by any amount.
#[test]
fn csg_far_from_the_origin_renders_the_same_image() {
    let image = scene(&csg_scene(0.0)).render_rect(Rect::full(96, 72));
    for offset in [1e8, 1e9, 1e10] {
        let moved = scene(&csg_scene(offset)).render_rect(Rect::full(96, 72));
        let (pixels, _) = diff(&image, &moved);
        assert!(
            pixels <= 96 * 72 / 1000,
            "offset {offset:e}: {pixels} pixels differ"
        );
    }
    // The scene shows what it is for: the pocket's (cyan) floor and walls, both spheres'
    // colours and the notch's (magenta) walls, each on a good number of pixels.
    let count = |pick: fn(i32, i32, i32) -> bool| {
        image
            .chunks_exact(3)
            .filter(|p| pick(i32::from(p[0]), i32::from(p[1]), i32::from(p[2])))
            .count()
    };
    let cyan = count(|r, g, b| g > r + 40 && b > r + 40);
    let green = count(|r, g, b| g > r + 40 && g > b + 40);
    let blue = count(|r, g, b| b > r + 40 && b > g + 40);
    let magenta = count(|r, g, b| r > g + 40 && b > g + 40);
    assert!(
        cyan > 20 && green > 20 && blue > 20 && magenta > 5,
        "{cyan} {green} {blue} {magenta}"
    );
}

/// A light placed exactly on a surface (a sphere's +x point; a point of a cube's face) is
/// not shadowed by that surface: SCENE.md's segment from a point to its light ends at the
/// light, and the surface meets it only there. The crossing at the light comes out a few
/// ulps either side of the end of the shadow ray, which would shadow a random quarter of
/// the floor behind the light. The reference: the same
/// scene with the light moved 1e-6 off the surface, outwards, where no rounding can reach.
#[test]
fn a_light_on_a_surface_is_not_shadowed_by_it() {
    let frame = "[GLOBALS]\nwidth = 64\nheight = 48\nambient = 0.05\nshadow = 0.5\n[/GLOBALS]\n\
                 [CAMERA]\neye = <0, 6, 10>\nlook_at = <0, 0.5, 0>\nfov = 40\n[/CAMERA]\n\
                 [OBJECT]\ntype = plane\ncolor1 = <0.8, 0.6, 0.4>\n[/OBJECT]\n";
    for (solid, on, off) in [
        (
            "[OBJECT]\ntype = sphere\ntranslate = <0, 1, 0>\n[/OBJECT]\n",
            "<1, 1, 0>",
            "<1.000001, 1, 0>",
        ),
        (
            "[OBJECT]\ntype = cube\nscale = <1, 1.5, 1>\ntranslate = <0, 1.5, 0>\n[/OBJECT]\n",
            "<1, 1.5, 0.2>",
            "<1.000001, 1.5, 0.2>",
        ),
    ] {
        let with_light = |at: &str, shadow: &str| {
            let src = format!("{frame}[LIGHT]\nposition = {at}\n[/LIGHT]\n{solid}")
                .replace("shadow = 0.5", shadow);
            scene(&src).render_rect(Rect::full(64, 48))
        };
        let on_surface = with_light(on, "shadow = 0.5");
        let reference = with_light(off, "shadow = 0.5");
        let (pixels, _) = diff(&on_surface, &reference);
        assert!(pixels <= 64 * 48 / 1000, "{on}: {pixels} pixels differ");
        // The scene does cast shadows (the floor on the far side of the solid).
        let (shadowed, _) = diff(&reference, &with_light(off, "shadow = 0"));
        assert!(shadowed > 100, "{on}: only {shadowed} pixels in shadow");
    }
}

/// The other side of the light's end: a light just behind a surface (1e-3 under a plane,
/// with a sphere above whose lower half faces the light) stays behind it, at the origin and
/// with the scene moved to 1e9, where 1e-3 is some 8,000 ulps of the coordinates. With the
/// shadow ray's stop at 1e-12 of its scale, 1.7e-3 of a unit there, the light shone through
/// the plane onto the sphere's whole lower half (133 pixels).
#[test]
fn a_light_just_behind_a_surface_stays_behind_it_far_away() {
    let at = |offset: f64, x: f64, y: f64, z: f64| {
        format!("<{}, {}, {}>", offset + x, offset + y, offset + z)
    };
    let src = |offset: f64| {
        format!(
            "[GLOBALS]\nwidth = 60\nheight = 45\nambient = 0.1\n[/GLOBALS]\n\
             [CAMERA]\neye = {}\nlook_at = {}\nfov = 40\n[/CAMERA]\n\
             [LIGHT]\nposition = {}\n[/LIGHT]\n\
             [OBJECT]\ntype = plane\ncolor1 = 0.8\ntranslate = {}\n[/OBJECT]\n\
             [OBJECT]\ntype = sphere\ncolor1 = <1, 0.3, 0.3>\ntranslate = <0, 1.5, 0>\n\
             translate = {}\n[/OBJECT]\n",
            at(offset, 0.0, 1.5, 8.0),
            at(offset, 0.0, 1.2, 0.0),
            at(offset, 0.7, -0.001, 0.3),
            at(offset, 0.0, 0.0, 0.0),
            at(offset, 0.0, 0.0, 0.0),
        )
    };
    let near = scene(&src(0.0)).render_rect(Rect::full(60, 45));
    let far = scene(&src(1e9)).render_rect(Rect::full(60, 45));
    let (pixels, _) = diff(&near, &far);
    assert!(pixels <= 60 * 45 / 1000, "{pixels} pixels differ at 1e9");
    // The light under the plane lights nothing but the plane's underside, which the camera
    // above does not see: every pixel is ambient only, sphere or plane alike.
    let unlit = scene(&src(0.0).replace("[LIGHT]\nposition", "[LIGHT]\ncolor = 0\nposition"))
        .render_rect(Rect::full(60, 45));
    assert_eq!(diff(&near, &unlit).0, 0);
}

/// A light on a cone's axis just above its apex (1e-9), on the apex, and just inside it
/// (1e-9 below). A line passing that near the apex has two roots that nearly coincide, and
/// from the middle of the bounding box they came out only to √ε ≈ 1e-8: the cone shadowed
/// a random half of the floor from the light above it (2,478 of 7,500 pixels) and let the
/// light inside it through to 2,378. 1e-9 above the apex the floor must be lit as by a light
/// 1e-7 above it (the shading differs by at most one 8-bit step), and on the apex but for
/// the edge of the cone's shadow; from inside, every segment to the floor crosses the cone,
/// so nothing is lit at all.
#[test]
fn a_light_at_a_cones_apex_casts_no_speckles() {
    let src = |y: &str, color: &str| {
        format!(
            "[GLOBALS]\nwidth = 100\nheight = 75\nambient = 0.1\n[/GLOBALS]\n\
             [CAMERA]\neye = <3, 4, 6>\nlook_at = <0, -0.5, 0>\nfov = 40\n[/CAMERA]\n\
             [LIGHT]\nposition = <0, {y}, 0>\ncolor = {color}\n[/LIGHT]\n\
             [OBJECT]\ntype = plane\ncolor1 = 0.8\ntranslate = <0, -2, 0>\n[/OBJECT]\n\
             [OBJECT]\ntype = cone\ncolor1 = <0.3, 0.6, 1>\n[/OBJECT]\n"
        )
    };
    let render = |y: &str, color: &str| scene(&src(y, color)).render_rect(Rect::full(100, 75));
    let reference = render("1.0000001", "1");
    let (pixels, max) = diff(&render("1.000000001", "1"), &reference);
    assert!(
        max <= 1,
        "1e-9 above: {pixels} pixels differ, by up to {max}"
    );
    // Exactly on the apex, the segments along the cone's generators lie on its surface:
    // pixels on the edge of the cone's shadow may go either way (ten do), no others.
    let (pixels, _) = diff(&render("1", "1"), &reference);
    assert!(
        pixels <= 100 * 75 / 500,
        "on the apex: {pixels} pixels differ"
    );
    assert_eq!(
        diff(&render("0.999999999", "1"), &render("0.999999999", "0")).0,
        0
    );
    // Not vacuous: the floor is lit, and the cone does cast a shadow.
    assert!(diff(&reference, &render("1.0000001", "0")).0 > 3000);
}

/// A light exactly on a curved surface, seen zoomed in (the image spans 0.02 of a unit of
/// the wall beside the solid) where the shadow rays reach the light nearly tangent to it:
/// such a ray meets the surface in two nearly equal roots, known only to about √ε, and the
/// stop short of the light did not clear them (163, 120, 124 and 51 wrong pixels by a sphere's
/// pole, a cylinder's and a cone's side and a torus's top). The solid lies on one side of
/// its tangent plane at the light and the wall on the other, so SCENE.md lights the wall as
/// by a light 1e-12 outside the surface. And a light 1e-12 inside a sphere lights nothing.
#[test]
fn a_light_on_a_curved_surface_is_not_shadowed_by_grazing_rays() {
    let frame = |w: u32, eye: &str, at: &str, light: &str, solid: &str, wall: &str| {
        format!(
            "[GLOBALS]\nwidth = {w}\nheight = 60\nambient = 0.1\nshadow = 1\n[/GLOBALS]\n\
             [CAMERA]\neye = {eye}\nlook_at = {at}\nfov = 1.146\n[/CAMERA]\n\
             [LIGHT]\nposition = {light}\n[/LIGHT]\n\
             [OBJECT]\n{solid}color1 = <0.9, 0.5, 0.2>\n[/OBJECT]\n\
             [OBJECT]\ntype = plane\n{wall}color1 = <0.8, 0.6, 0.6>\n[/OBJECT]\n"
        )
    };
    let cases = [
        (
            ("<-5, 1, -4.38>", "<-6, 1, -4.38>", "type = sphere\n"),
            (
                "rotate = <0, 0, -90>\ntranslate = <-6, 0, 0>\n",
                "<0, 1, 0>",
                "<0, 1.000000000001, 0>",
            ),
        ),
        (
            ("<1, 0.5, -4>", "<1, 0.5, -5>", "type = cylinder\n"),
            (
                "rotate = <90, 0, 0>\ntranslate = <0, 0, -5>\n",
                "<1, 0, 0>",
                "<1.000000000001, 0, 0>",
            ),
        ),
        (
            ("<0.5, 0, -4>", "<0.5, 0, -5>", "type = cone\n"),
            (
                "rotate = <90, 0, 0>\ntranslate = <0, 0, -5>\n",
                "<0.5, 0, 0>",
                "<0.500000000002, 1e-12, 0>",
            ),
        ),
        (
            ("<5, 0.25, 0.3>", "<6, 0.25, 0.3>", "type = torus\n"),
            (
                "rotate = <0, 0, 90>\ntranslate = <6, 0, 0>\n",
                "<1, 0.25, 0>",
                "<1, 0.250000000001, 0>",
            ),
        ),
    ];
    // Ten far spheres behind the camera put the scene in a BVH, whose point query finds
    // the objects a light lies on; without them the scene tests every solid.
    let far: String = (0..10)
        .map(|i| {
            format!("[OBJECT]\ntype = sphere\nradius = 0.1\ntranslate = <{i}, 40, 40>\n[/OBJECT]\n")
        })
        .collect();
    for (((eye, at, solid), (wall, on, off)), extra) in
        cases.into_iter().flat_map(|c| [(c, ""), (c, far.as_str())])
    {
        let render = |light: &str| {
            let s = scene(&(frame(60, eye, at, light, solid, wall) + extra));
            assert_eq!(s.uses_bvh(), !extra.is_empty());
            s.render_rect(Rect::full(60, 60))
        };
        let (pixels, _) = diff(&render(on), &render(off));
        assert!(
            pixels <= 60 * 60 / 1000,
            "{solid}light {on}: {pixels} pixels differ"
        );
        // Not vacuous: the view holds the solid's shadow edge (lit and unlit wall).
        let dark = scene(&frame(60, eye, at, on, solid, wall).replace("shadow = 1", "shadow = 0"))
            .render_rect(Rect::full(60, 60));
        let (shadowed, _) = diff(&render(on), &dark);
        assert!(
            shadowed > 60 && shadowed < 60 * 60 - 60,
            "{solid}{shadowed} in shadow"
        );
    }
    // Inside by 1e-12: every segment from the wall crosses the sphere.
    let inside = frame(
        40,
        "<-5, 1, -4.38>",
        "<-6, 1, -4.38>",
        "<0, 0.999999999999, 0>",
        "type = sphere\n",
        "rotate = <0, 0, -90>\ntranslate = <-6, 0, 0>\n",
    );
    let unlit = inside.replace("[LIGHT]\n", "[LIGHT]\ncolor = 0\n");
    assert_eq!(
        diff(
            &scene(&inside).render_rect(Rect::full(40, 60)),
            &scene(&unlit).render_rect(Rect::full(40, 60))
        )
        .0,
        0
    );
}

/// The eye exactly on a torus (the top of its tube, the outer and the inner equator),
/// looking along the tube: every ray into the tube must meet the torus again from inside.
/// The tube's entry at the eye rounds to a tiny `t` of either sign; when it falls behind the
/// eye, the exit ahead must not be skipped as if it were the surface the ray had just left,
/// or most pixels looking into the tube would show the floor through the solid. (A ray
/// whose entry rounds ahead of the eye may still stop on the surface at the eye.)
#[test]
fn an_eye_on_a_torus_never_sees_through_it() {
    for (eye, look) in [
        ("<1, 0.25, 0>", "<1, 0.25, 4>"),
        ("<1.25, 0, 0>", "<1.25, 0, 4>"),
        ("<0.75, 0, 0>", "<0.75, 0, 4>"),
    ] {
        let src = format!(
            "[GLOBALS]\nwidth = 64\nheight = 48\nambient = 0.1\nbackground = <0, 0, 1>\n[/GLOBALS]\n\
             [CAMERA]\neye = {eye}\nlook_at = {look}\nfov = 60\n[/CAMERA]\n\
             [LIGHT]\nposition = <5, 8, 6>\n[/LIGHT]\n\
             [OBJECT]\ntype = torus\ncolor1 = <1, 0.2, 0.1>\n[/OBJECT]\n\
             [OBJECT]\ntype = plane\ncolor1 = <0, 1, 0>\ntranslate = <0.37, -3.13, 0.21>\n[/OBJECT]\n"
        );
        let s = scene(&src);
        let mut into_tube = 0;
        for py in 0..48u32 {
            for px in 0..64u32 {
                let r = s.camera().ray(f64::from(px) + 0.5, f64::from(py) + 0.5);
                let (o, d) = (r.origin, r.dir);
                // Into the tube: against the outward normal at the eye (the tube's centre
                // circle is at distance 1 from the axis, in the plane y = 0).
                let rho = o.x.hypot(o.z);
                let centre = glam::DVec3::new(o.x / rho, 0.0, o.z / rho);
                if d.dot(o - centre) >= -1e-9 * d.length() {
                    continue;
                }
                into_tube += 1;
                let rgb = s.render_rect(Rect::new(px, py, 1, 1));
                // The torus is red in every light; the floor and the sky have no red.
                assert!(
                    rgb[0] > rgb[1] && rgb[0] > rgb[2],
                    "{eye}: pixel ({px}, {py}) {rgb:?}"
                );
            }
        }
        assert!(into_tube > 500, "{eye}: {into_tube} rays into the tube");
    }
}

/// A light exactly on an edge or a corner of a convex solid (a cube's corner and edge, a
/// cylinder's rim, a cone's base rim) lights a point outside any one face plane through it:
/// the solid lies on the inner side of that plane and the segment on the outer side, but
/// for the light (SCENE.md's segment ends there). Traced, segments reaching the light at
/// grazing angles to a face would cross its plane a rounding error before the light, inside
/// the face, and notch the shadow's edge on the wall and floor. The reference is the light
/// moved 1e-9 outwards, off every face. The edge and rim cases check that the planes listed
/// there (a cube's two faces, a rim's cap and side) light nothing the solid shadows.
#[test]
fn a_light_on_an_edge_or_corner_is_not_shadowed_by_it() {
    let src = |light: &str, solid: &str| {
        format!(
            "[GLOBALS]\nwidth = 160\nheight = 120\nbackground = <0.1, 0.2, 0.3>\n[/GLOBALS]\n\
             [CAMERA]\neye = <2, 3, 8>\nlook_at = <0, -0.5, 0>\nfov = 50\n[/CAMERA]\n\
             [LIGHT]\nposition = {light}\n[/LIGHT]\n\
             [OBJECT]\ntype = {solid}\nscale = 0.7\ncolor1 = <0.2, 0.9, 0.3>\n[/OBJECT]\n\
             [OBJECT]\ntype = plane\ncolor1 = 0.8\ntranslate = <0, -1.5, 0>\n[/OBJECT]\n\
             [OBJECT]\ntype = plane\ncolor1 = <0.7, 0.7, 0.9>\nrotate = <90, 0, 0>\n\
             translate = <0, 0, -3>\n[/OBJECT]\n"
        )
    };
    let render =
        |light: &str, solid: &str| scene(&src(light, solid)).render_rect(Rect::full(160, 120));
    for (solid, on, off) in [
        (
            "cube",
            "<0.7, 0.7, 0.7>",
            "<0.700000001, 0.700000001, 0.700000001>",
        ),
        ("cube", "<0.7, 0.7, 0.1>", "<0.700000001, 0.700000001, 0.1>"),
        ("cylinder", "<0.7, 0.7, 0>", "<0.700000001, 0.700000001, 0>"),
        ("cone", "<0.7, -0.7, 0>", "<0.700000001, -0.700000001, 0>"),
    ] {
        let reference = render(off, solid);
        let (pixels, max) = diff(&render(on, solid), &reference);
        assert!(
            max <= 1,
            "{solid} light {on}: {pixels} pixels differ, by up to {max}"
        );
        // Not vacuous: the solid does cast a shadow.
        let unlit = src(off, solid).replace("[LIGHT]\n", "[LIGHT]\ncolor = 0\n");
        let (lit, _) = diff(&reference, &scene(&unlit).render_rect(Rect::full(160, 120)));
        let (shadowed, _) = diff(
            &reference,
            &scene(&src(off, solid).replace(
                &format!("type = {solid}\n"),
                "type = sphere\nradius = 0.001\n",
            ))
            .render_rect(Rect::full(160, 120)),
        );
        assert!(
            lit > 1000 && shadowed > 100,
            "{solid}: {lit} lit, {shadowed} in its shadow"
        );
    }
}
