use super::cone::*;
use super::*;
use crate::sampler::{Sample, UnseenPattern};
use crate::world::Scene;
use glam::DVec3;

fn scene(src: &str) -> Scene {
    Scene::from_source(
        src,
        &crate::Limits::default(),
        &crate::texture::MemoryAssets::new(),
        &crate::texture::TextureLimits::default(),
    )
    .unwrap_or_else(|e| panic!("test scene does not build: {e}"))
}

/// A checker plane at y = 0, white and `color2`, ambient 0.2, one light of colour 1.5
/// above it at y = 5, seen from `eye`, with `extra` material keys.
fn lit_checker(eye: &str, color2: f64, extra: &str) -> Scene {
    scene(&format!(
        "[GLOBALS]\nwidth = 32\nheight = 24\nambient = 0.2\n[/GLOBALS]\n\
             [CAMERA]\neye = {eye}\nlook_at = <0, 0, 0>\n[/CAMERA]\n\
             [LIGHT]\nposition = <1, 5, 2>\ncolor = 1.5\n[/LIGHT]\n\
             [OBJECT]\ntype = plane\ncolor1 = 1\ncolor2 = {color2}\n{extra}[/OBJECT]\n"
    ))
}

/// The step between the two colours, worked out by hand from the shading formula: the
/// light counts only on the eye's side (from below, the points seen face away from it),
/// a mirror keeps its share of the difference, equal colours make none, and clamping
/// caps it at 1.
#[test]
fn a_checker_s_step_counts_the_lights_on_the_eye_s_side_only() {
    let step = |eye: &str, extra: &str| {
        let s = lit_checker(eye, 0.25, extra);
        s.checker_step(&s.objects[0])
    };
    let close = |a: f64, b: f64| (a - b).abs() < 1e-12;
    assert!(close(step("<0, 3, 6>", ""), 1.0), "0.75 · 1.7, clamped");
    assert!(close(step("<0, -3, 6>", ""), 0.75 * 0.2));
    assert!(close(
        step("<0, 3, 6>", "diffuse = 0.2\n"),
        0.75 * (0.2 + 0.3)
    ));
    assert!(close(
        step("<0, 3, 6>", "diffuse = 0.2\nmirror = 0.5\n"),
        0.75 * 0.5 * 0.5
    ));
    let same = lit_checker("<0, 3, 6>", 1.0, "");
    assert_eq!(same.checker_step(&same.objects[0]), 0.0);
    // A plane turned upside down (its normal −y): the eye's side is still the one lit.
    assert!(close(
        step("<0, 3, 6>", "diffuse = 0.2\nrotate = <180, 0, 0>\n"),
        0.75 * 0.5
    ));
}

/// Rays that met cells of both colours leave no side unseen; rays all in one colour
/// leave the other, where the square crosses an edge; a square inside one cell has none.
#[test]
fn the_unseen_step_is_the_side_no_first_ray_met() {
    // Seen straight down, 20 units of the plane over the image's 24 rows, so a cell (2
    // units) is 2.4 pixels wide, with the eye above a cell's corner at the image's
    // centre (16, 12): cells meet at x = 13.6 and 16, y = 9.6 and 12. Pixel (13, 10)
    // crosses the edge x = 13.6 alone, pixel (14, 10) lies inside one cell.
    let s = scene(
        "[GLOBALS]\nwidth = 32\nheight = 24\nambient = 1\n[/GLOBALS]\n\
             [CAMERA]\neye = <0, 10, 0>\nlook_at = <0, 0, 0>\nup = <0, 0, -1>\nfov = 90\n[/CAMERA]\n\
             [OBJECT]\ntype = plane\ncolor1 = 1\ncolor2 = 0\nscale = 2\n[/OBJECT]\n",
    );
    let fp = Footprints::new(
        &s,
        PixelRegion {
            x: 0,
            y: 0,
            width: 32,
            height: 24,
        },
    );
    let (a, b) = ((13.9, 10.5), (13.1, 10.5));
    let parity = |(x, y): (f64, f64)| cell_parity(&s, &s.objects[0], x, y);
    assert!(parity(a).is_some() && parity(b).is_some() && parity(a) != parity(b));
    let one_edge = Some(UnseenPattern {
        step: 1.0,
        edges: Some(1),
    });
    assert_eq!(fp.unseen_pattern(13, 10, 0, &[b, b, b, b]), one_edge);
    assert_eq!(fp.unseen_pattern(13, 10, 0, &[a, a, a, a]), one_edge);
    assert_eq!(fp.unseen_pattern(13, 10, 0, &[b, b, a, b]), None);
    assert_eq!(fp.unseen_pattern(14, 10, 0, &[(14.5, 10.5); 4]), None);
    // Pixel (13, 9) holds a corner: the edges x = 13.6 and y = 9.6.
    let corner = fp.unseen_pattern(13, 9, 0, &[(13.1, 9.1); 4]);
    assert_eq!(corner.and_then(|p| p.edges), Some(2));
    // A ray on the edge tells no side: the others decide.
    assert_eq!(parity((13.6, 10.5)), None);
    assert_eq!(
        fp.unseen_pattern(13, 10, 0, &[b, (13.6, 10.5), b, b]),
        one_edge
    );
    assert_eq!(fp.unseen_pattern(13, 10, Sample::BACKGROUND, &[b; 4]), None);
}

fn cone(axis: DVec3, half_angle: f64) -> Cone {
    // Aperture::new widens by 1e-6 relative and the margin; the tests below keep 1e-7
    // radians from every boundary, far more than either.
    Cone::new(DVec3::ZERO, axis, Aperture::new(half_angle))
}

#[test]
fn sphere_tests_are_exact_up_to_the_margin() {
    // A sphere of radius 1 at distance 10 fills α = asin(0.1) around its centre.
    let alpha = 0.1f64.asin();
    let c = DVec3::new(0.0, 0.0, -10.0);
    let phi = 1e-3;
    for (theta, meets, inside) in [
        (alpha + phi - 1e-7, true, false),
        (alpha + phi + 1e-7, false, false),
        (alpha - phi - 1e-7, true, true),
        (alpha - phi + 1e-7, true, false),
    ] {
        let axis = DVec3::new(theta.sin(), 0.0, -theta.cos());
        let k = cone(axis, phi);
        assert_eq!(k.meets_sphere(c, 1.0), meets, "θ = {theta}");
        assert_eq!(k.inside_sphere(c, 1.0), inside, "θ = {theta}");
    }
    // From inside the ball: meets, never "inside" (the far wall is not a silhouette,
    // but the probe saw the wall from inside, which a convex test cannot vouch for).
    let k = cone(DVec3::Z, phi);
    assert!(k.meets_sphere(DVec3::ZERO, 1.0));
    assert!(!k.inside_sphere(DVec3::ZERO, 1.0));
}

/// A point with every coordinate in `[−0.5, 0.5)`.
fn half_cube(rng: &mut crate::shape::test_support::Rng) -> DVec3 {
    DVec3::new(
        rng.range(-0.5, 0.5),
        rng.range(-0.5, 0.5),
        rng.range(-0.5, 0.5),
    )
}

/// Against brute force: whenever some point of a capsule lies in the cone, the capsule
/// test says "may meet"; and it says "no" for most capsules clear of the cone.
#[test]
fn capsule_test_never_misses_a_point_in_the_cone() {
    let mut rng = crate::shape::test_support::Rng::new(0x1234_5678);
    let (mut met, mut cleared) = (0, 0);
    for _ in 0..4000 {
        let axis = (DVec3::new(0.0, 0.0, -1.0) + half_cube(&mut rng) * 0.3).normalize();
        let k = cone(axis, 0.02 * rng.unit() + 1e-4);
        let centre = axis * (2.0 + 20.0 * rng.unit()) + half_cube(&mut rng) * 2.0;
        let a = centre + half_cube(&mut rng) * 3.0 * rng.unit();
        let b = centre + half_cube(&mut rng) * 3.0 * rng.unit();
        let r = 0.2 * rng.unit() + 1e-3;
        let says = k.may_meet_capsule(a, b, r);
        // Points of the capsule: on the segment, then moved up to r in a direction.
        let mut inside = false;
        for _ in 0..400 {
            let along = a + (b - a) * rng.unit();
            let q = along + half_cube(&mut rng).normalize_or_zero() * r * rng.unit().sqrt();
            if angle_between(axis, q) <= k.aperture.half_angle {
                inside = true;
                break;
            }
        }
        assert!(
            !inside || says,
            "a capsule point in the cone, but the test said no"
        );
        met += u32::from(inside);
        cleared += u32::from(!says);
    }
    assert!(met > 100 && cleared > 1000, "met {met}, cleared {cleared}");
}

#[test]
fn pixel_sized_angles_keep_their_digits() {
    // acos of the dot product would give 0 or 1.5e-8 here; atan2 gives the angle.
    let a = DVec3::new(0.0, 0.0, 1.0);
    let b = DVec3::new(1e-10, 0.0, 1.0);
    assert!((angle_between(a, b) - 1e-10).abs() < 1e-24);
}

#[test]
fn a_plane_s_horizon_is_seen_only_when_the_cone_straddles_it() {
    // The plane y = 0 seen from y = 1: directions below the horizontal reach it.
    let phi = 1e-3;
    let view = |elevation: f64| {
        let axis = DVec3::new(0.0, elevation.sin(), -elevation.cos());
        let mut k = cone(axis, phi);
        k.origin = DVec3::Y;
        k.view_of_plane(DVec3::ZERO, DVec3::Y)
    };
    assert_eq!(view(-2e-3), PlaneView::Covers);
    assert_eq!(view(-0.5e-3), PlaneView::Horizon);
    assert_eq!(view(0.5e-3), PlaneView::Horizon);
    assert_eq!(view(2e-3), PlaneView::Misses);
}

/// The geometry answers for a pixel only where a checkered plane alone fills it: not where
/// a sphere may show, not on a mirror, not on a plane without a checker, not past the cap
/// on cells; where it answers, a square inside one cell is that cell's colour times the
/// shading, which (no light reaching this plane from below) is the ambient alone.
#[test]
fn exact_values_only_where_a_checker_plane_is_alone() {
    let plane = Sample {
        color: DVec3::ZERO,
        object: 0,
    };
    let region = PixelRegion {
        x: 0,
        y: 0,
        width: 32,
        height: 24,
    };
    let answers = |s: &Scene, x: i64, y: i64, cells: u32| {
        let fp = Footprints::new(s, region);
        fp.exact(x, y, (x as f64 + 0.5, y as f64 + 0.5), &plane, 0.05, cells)
    };
    let alone = lit_checker("<0, 3, 6>", 0.25, "");
    assert!(answers(&alone, 16, 20, 64).is_some());
    assert!(
        answers(&alone, 16, 20, 0).is_none(),
        "past the cap on cells"
    );
    let mirror = lit_checker("<0, 3, 6>", 0.25, "mirror = 0.5\n");
    assert!(answers(&mirror, 16, 20, 64).is_none(), "a mirror");
    let plain = scene(
        "[GLOBALS]\nwidth = 32\nheight = 24\n[/GLOBALS]\n[CAMERA]\neye = <0, 3, 6>\n\
         look_at = <0, 0, 0>\n[/CAMERA]\n[OBJECT]\ntype = plane\n[/OBJECT]\n",
    );
    assert!(answers(&plain, 16, 20, 64).is_none(), "no checker");
    let with_sphere = scene(
        "[GLOBALS]\nwidth = 32\nheight = 24\nambient = 0.2\n[/GLOBALS]\n\
         [CAMERA]\neye = <0, 3, 6>\nlook_at = <0, 0, 0>\n[/CAMERA]\n\
         [OBJECT]\ntype = plane\ncolor1 = 1\ncolor2 = 0.25\n[/OBJECT]\n\
         [OBJECT]\ntype = sphere\nradius = 0.5\ntranslate = <0, 0.5, 0>\n[/OBJECT]\n",
    );
    let fp = Footprints::new(&with_sphere, region);
    let centre = with_sphere.camera.project(DVec3::new(0.0, 0.5, 0.0));
    let (cx, cy) = centre.expect("the sphere is in view");
    let (x, y) = (cx.floor() as i64, cy.floor() as i64);
    assert!(
        fp.exact(x, y, (cx, cy), &plane, 0.05, 64).is_none(),
        "a sphere in the square"
    );

    // Seen from below, no light reaches the plane's seen side: every piece is its colour
    // times the ambient, so a square in one cell is exactly 0.2 or 0.05.
    let below = lit_checker("<0.3, -3, 6.2>", 0.25, "");
    let fp = Footprints::new(&below, region);
    let mut one_colour = 0;
    for y in 0..24 {
        for x in 0..32 {
            let at = (x as f64 + 0.5, y as f64 + 0.5);
            if let Some(c) = fp.exact(x, y, at, &plane, 0.05, 64) {
                assert!(c.max_element() <= 0.2 + 1e-12 && c.min_element() >= 0.05 - 1e-12);
                if one_cell(&below, &below.objects[0], x, y) {
                    let v = c.x;
                    assert!((v - 0.2).abs() < 1e-12 || (v - 0.05).abs() < 1e-12, "{v}");
                    one_colour += 1;
                }
            }
        }
    }
    assert!(one_colour > 0);
}

/// A pixel the footprints call blank returns the background's sample to every ray through
/// its closed square (its corners, where a plane's horizon or a silhouette would first
/// enter, and a grid inside), bit for bit, clamped as a primary sample is; and blank
/// pixels exist where nothing shows, so the sampler has rays to save.
#[test]
fn a_blank_pixel_s_every_ray_sees_the_background() {
    let spheres: String = (0..12)
        .map(|k| {
            let (x, y) = (f64::from(k % 4) * 2.5 - 3.75, f64::from(k / 4) * 2.5 - 2.5);
            let r = 0.05 + 0.1 * f64::from(k);
            format!("[OBJECT]\ntype = sphere\nradius = {r}\ntranslate = <{x}, {y}, 0>\n[/OBJECT]\n")
        })
        .collect();
    let cloud = scene(&format!(
        "[GLOBALS]\nwidth = 40\nheight = 30\nbackground = <1.5, 0.4, 0.2>\n[/GLOBALS]\n\
         [CAMERA]\neye = <0, 0, 12>\n[/CAMERA]\n{spheres}"
    ));
    // A checker floor and a wall to the right, the camera rolled so that the horizon
    // crosses pixels at a slant: blank is what lies above the floor's horizon and left of
    // the wall's.
    let floor = "[OBJECT]\ntype = plane\ncolor1 = 1\ncolor2 = 0\n[/OBJECT]\n\
                 [OBJECT]\ntype = sphere\nradius = 0.7\ntranslate = <0.5, 0.7, 0>\n[/OBJECT]\n";
    let rolled = scene(&format!(
        "[GLOBALS]\nwidth = 40\nheight = 30\nbackground = <0.2, 0.3, 0.9>\n[/GLOBALS]\n\
         [CAMERA]\neye = <0, 1.5, 8>\nlook_at = <0, 1.2, 0>\nup = <0.35, 1, 0>\n[/CAMERA]\n\
         {floor}[OBJECT]\ntype = plane\nrotate = <0, 0, 90>\ntranslate = <3, 0, 0>\n\
         color1 = 0.5\n[/OBJECT]\n"
    ));
    // Seen from below, looking down at the horizon from under the floor.
    let below = scene(&format!(
        "[GLOBALS]\nwidth = 40\nheight = 30\nbackground = 0.6\n[/GLOBALS]\n\
         [CAMERA]\neye = <0, -1, 8>\nlook_at = <0, -1.3, 0>\n[/CAMERA]\n{floor}"
    ));
    for (name, s, least) in [
        ("cloud", &cloud, 600),
        ("rolled", &rolled, 1),
        ("below", &below, 1),
    ] {
        let region = PixelRegion {
            x: -2,
            y: -2,
            width: 44,
            height: 34,
        };
        let fp = Footprints::new(s, region);
        let (mut blank, mut other) = (0, 0);
        for py in -2..32 {
            for px in -2..42 {
                let Some(sample) = fp.blank(px, py) else {
                    other += 1;
                    continue;
                };
                blank += 1;
                assert_eq!(sample.object, Sample::BACKGROUND, "{name}");
                assert_eq!(sample.color, s.background.min(DVec3::ONE), "{name}");
                for j in 0..=4 {
                    for i in 0..=4 {
                        let (x, y) = (
                            px as f64 + f64::from(i) / 4.0,
                            py as f64 + f64::from(j) / 4.0,
                        );
                        let traced = s.primary_sample(x, y);
                        assert_eq!(
                            (traced.object, traced.color),
                            (sample.object, sample.color),
                            "{name}: pixel ({px}, {py}), ray through ({x}, {y})"
                        );
                    }
                }
            }
        }
        assert!(
            blank >= least && other > 0,
            "{name}: {blank} blank, {other} not"
        );
    }
    // Outside the region nothing is known: a pixel blank in the whole image's region, in
    // a region of its own, and its neighbours outside that.
    let whole = Footprints::new(
        &cloud,
        PixelRegion {
            x: 0,
            y: 0,
            width: 40,
            height: 30,
        },
    );
    let (px, py) = (1..39)
        .flat_map(|y| (1..39).map(move |x| (x, y)))
        .find(|&(x, y)| {
            whole.blank(x - 1, y).is_some()
                && whole.blank(x, y).is_some()
                && whole.blank(x + 1, y).is_some()
        })
        .expect("three blank pixels in a row");
    let alone = PixelRegion {
        x: px,
        y: py,
        width: 1,
        height: 1,
    };
    let fp = Footprints::new(&cloud, alone);
    assert!(fp.blank(px, py).is_some());
    assert!(fp.blank(px - 1, py).is_none() && fp.blank(px + 1, py).is_none());
}
