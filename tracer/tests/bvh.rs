//! The BVH (and the culling of shadow rays nothing can block) changes speed, never answers: on random scenes of every shape, CSG trees and
//! planes, with coincident copies (ties at equal `t`), rays starting inside boxes and rays
//! with zero direction components, the nearest hit and the any-hit answer are the same, bit
//! for bit, as testing every prim in order; and whole images are byte-identical.

mod common;

use common::Rng;

use glam::DVec3;
use tessera_tracer::internals::{Ray, SceneInternals};
use tessera_tracer::{Acceleration, Rect, Scene};

fn v(p: DVec3) -> String {
    format!("<{}, {}, {}>", p.x, p.y, p.z)
}

/// One random object: a shape, a transform (sometimes only scale and translation, sometimes
/// on integer coordinates so axis-parallel rays meet faces and edges exactly) and a colour.
fn object(rng: &mut Rng, extent: f64) -> String {
    let shape = match rng.below(6) {
        0 | 1 => "type = sphere\n".to_string(),
        2 => "type = cube\n".to_string(),
        3 => "type = cylinder\n".to_string(),
        4 => "type = cone\n".to_string(),
        _ => "type = torus\nmajor = 1\nminor = 0.3\n".to_string(),
    };
    let mut t = String::new();
    match rng.below(3) {
        0 => {
            t += &format!("scale = {}\n", rng.range(0.2, 1.5));
        }
        1 => {
            let s = DVec3::new(
                rng.range(0.2, 1.5),
                rng.range(0.2, 1.5),
                rng.range(0.2, 1.5),
            );
            t += &format!("scale = {}\nrotate = {}\n", v(s), v(rng.vec(180.0)));
        }
        _ => {}
    }
    let at = if rng.below(3) == 0 {
        rng.vec(extent).round()
    } else {
        rng.vec(extent)
    };
    t += &format!("translate = {}\n", v(at));
    let c = DVec3::new(rng.unit(), rng.unit(), rng.unit());
    let mirror = if rng.below(5) == 0 {
        "mirror = 0.5\n"
    } else {
        ""
    };
    format!("[OBJECT]\n{shape}{t}color1 = {}\n{mirror}[/OBJECT]\n", v(c))
}

/// A random scene of `n` solids: objects, CSG trees (of every operation, one of them
/// possibly unbounded through a plane), ground planes (unless `planes` is false: then every
/// solid is bounded), and exact copies of earlier solids.
fn random_scene(rng: &mut Rng, n: usize, extent: f64, planes: bool) -> String {
    let mut solids: Vec<String> = Vec::new();
    for _ in 0..n {
        let s = match rng.below(10) {
            0 if !solids.is_empty() => {
                // An exact copy of an earlier solid: every hit on it ties.
                let k = rng.below(solids.len() as u64) as usize;
                solids[k].clone()
            }
            1 if planes => format!(
                "[OBJECT]\ntype = plane\nrotate = {}\ntranslate = <0, {}, 0>\ncolor1 = <0.5, 0.5, 0.5>\ncolor2 = <0.1, 0.1, 0.1>\n[/OBJECT]\n",
                v(rng.vec(10.0)),
                -extent
            ),
            2 | 3 => {
                let op = ["union", "intersection", "difference"][rng.below(3) as usize];
                let mut kids = object(rng, 0.7) + &object(rng, 0.7);
                if planes && rng.below(4) == 0 {
                    kids += "[OBJECT]\ntype = plane\n[/OBJECT]\n";
                }
                format!(
                    "[CSG]\nop = {op}\nrotate = {}\ntranslate = {}\n{kids}[/CSG]\n",
                    v(rng.vec(90.0)),
                    v(rng.vec(extent))
                )
            }
            _ => object(rng, extent),
        };
        solids.push(s);
    }
    format!(
        "[GLOBALS]\nwidth = 64\nheight = 48\nambient = 0.15\nshadow = 0.7\n[/GLOBALS]\n\
         [CAMERA]\neye = <3, 5, {}>\nfov = 60\n[/CAMERA]\n\
         [LIGHT]\nposition = <10, 20, 15>\n[/LIGHT]\n\
         [LIGHT]\nposition = <-15, 5, 5>\ncolor = <0.3, 0.3, 0.5>\n[/LIGHT]\n{}",
        extent * 2.5,
        solids.concat()
    )
}

/// A ray of one of the awkward kinds: from outside, from a solid's centre (inside its box),
/// with one or two zero direction components (of either sign), or aimed at an integer point.
fn random_ray(rng: &mut Rng, s: &Scene, extent: f64) -> Ray {
    let origin = match rng.below(3) {
        0 => {
            let k = rng.below(s.objects().len() as u64) as usize;
            s.objects()[k].transform.to_world().translation
        }
        1 => rng.vec(extent * 1.5).round(),
        _ => rng.vec(extent * 2.0),
    };
    let mut d = match rng.below(4) {
        0 => rng.vec(extent).round() - origin,
        _ => rng.vec(1.0),
    };
    match rng.below(5) {
        0 => d.x = 0.0,
        1 => d.y = -0.0,
        2 => {
            d.x = -0.0;
            d.z = 0.0;
        }
        _ => {}
    }
    if d == DVec3::ZERO || !d.is_finite() {
        d = DVec3::X;
    }
    Ray::new(origin, d)
}

#[test]
fn bvh_answers_equal_brute_force_on_random_scenes() {
    let mut rng = Rng(2024);
    let (mut hits, mut ties, mut rays) = (0, 0, 0);
    for round in 0..24 {
        let n = [3, 9, 40, 150][round % 4];
        let extent = [2.0, 4.0, 8.0][round % 3];
        let src = random_scene(&mut rng, n, extent, true);
        let linear = common::scene(&src).without_acceleration();
        let bvh = common::scene(&src).with_acceleration(Acceleration::Always);
        assert!(!linear.uses_bvh());
        assert!(
            bvh.uses_bvh()
                || linear
                    .prims()
                    .iter()
                    .all(|p| p.bounds(linear.objects()).is_none())
        );
        for _ in 0..500 {
            let r = random_ray(&mut rng, &linear, extent);
            let t_max = match rng.below(3) {
                0 => rng.range(0.0, 3.0),
                _ => f64::INFINITY,
            };
            // `skip` is only ever an object outside every CSG tree.
            let free: Vec<u32> = (0..linear.objects().len() as u32)
                .filter(|&i| !linear.objects()[i as usize].in_csg)
                .collect();
            let skip = (rng.below(4) == 0 && !free.is_empty())
                .then(|| free[rng.below(free.len() as u64) as usize]);
            let a = linear.intersect(&r, t_max, skip);
            let b = bvh.intersect(&r, t_max, skip);
            rays += 1;
            match (a, b) {
                (None, None) => {}
                (Some(a), Some(b)) => {
                    assert_eq!(
                        (a.object, a.local),
                        (b.object, b.local),
                        "round {round}, ray {r:?}, t_max {t_max}, skip {skip:?}\n{src}"
                    );
                    hits += 1;
                    // A tie: another solid also has a hit at exactly this t.
                    let others = linear.objects().len();
                    let tied = (0..others as u32).any(|k| {
                        k != a.object
                            && !linear.objects()[k as usize].in_csg
                            && Some(k) != skip
                            && {
                                let o = &linear.objects()[k as usize];
                                o.shape
                                    .intersect(&o.transform.ray_to_object(&r), t_max)
                                    .is_some_and(|h| h.t == a.local.t)
                            }
                    });
                    ties += usize::from(tied);
                }
                (a, b) => panic!(
                    "round {round}: linear {a:?} but BVH {b:?} for {r:?}, t_max {t_max}\n{src}"
                ),
            }
            assert_eq!(
                linear.occluded(&r, t_max, skip),
                bvh.occluded(&r, t_max, skip),
                "round {round}: occluded differs for {r:?}, t_max {t_max}\n{src}"
            );
        }
    }
    assert!(hits > rays / 4, "{hits} hits of {rays}");
    eprintln!("{rays} rays, {hits} hits, {ties} ties");
    assert!(ties > 50, "only {ties} tied hits");
}

/// Whole images, by the scene's own sampler, with mirrors and shadows: the same bytes.
#[test]
fn images_are_identical_with_and_without_the_bvh() {
    let mut rng = Rng(77);
    let mut total = tessera_tracer::RayStats::default();
    for n in [12, 60, 300] {
        let src = random_scene(&mut rng, n, 6.0, true);
        let auto = common::scene(&src);
        assert!(auto.uses_bvh(), "{n} solids");
        let linear = auto.clone().without_acceleration();
        let rect = Rect::full(auto.width, auto.height);
        let (a, sa) = auto.render_rect_stats(rect);
        let (b, sb) = linear.render_rect_stats(rect);
        assert_eq!(sa, sb, "{n} solids: ray counts differ");
        assert!(a == b, "{n} solids: images differ");
        total.add(&sa);
    }
    assert!(total.shadow > 1000 && total.mirror > 100, "{total:?}");
}

/// A lattice of `k × k` solids (mostly spheres, some cubes and long rods) of random sizes
/// and heights, seen from above, under three lights low enough that many shadow rays skim
/// the neighbours: some are blocked, many pass close by, and many are clear.
fn lattice_scene(rng: &mut Rng, k: u32, floor: bool) -> String {
    let mut s = format!(
        "[GLOBALS]\nwidth = 64\nheight = 48\nambient = 0.1\nshadow = 0.8\n[/GLOBALS]\n\
         [CAMERA]\neye = <0, {}, 1>\nlook_at = <0, 0, 0>\nfov = 50\n[/CAMERA]\n",
        2.5 * f64::from(k)
    );
    for _ in 0..3 {
        let a = rng.range(0.0, std::f64::consts::TAU);
        let (d, h) = (rng.range(5.0, 30.0), rng.range(2.0, 40.0));
        s += &format!(
            "[LIGHT]\nposition = <{}, {h}, {}>\ncolor = 0.4\n[/LIGHT]\n",
            d * a.cos(),
            d * a.sin()
        );
    }
    if floor {
        s += "[OBJECT]\ntype = plane\ntranslate = <0, -1, 0>\n[/OBJECT]\n";
    }
    let half = f64::from(k - 1);
    for i in 0..k {
        for j in 0..k {
            let at = DVec3::new(
                2.0 * f64::from(i) - half + rng.range(-0.3, 0.3),
                rng.range(0.0, 1.0),
                2.0 * f64::from(j) - half + rng.range(-0.3, 0.3),
            );
            let size = rng.range(0.2, 0.8);
            let shape = match rng.below(6) {
                0 => format!("type = cube\nscale = {size}\n"),
                // A long rod (the BVH cuts it into slices), lying at a random angle.
                1 => format!(
                    "type = cylinder\nscale = <{}, {}, {}>\nrotate = {}\n",
                    size / 4.0,
                    rng.range(1.0, 3.0),
                    size / 4.0,
                    v(rng.vec(90.0))
                ),
                _ => format!("type = sphere\nscale = {size}\n"),
            };
            s += &format!("[OBJECT]\n{shape}translate = {}\n[/OBJECT]\n", v(at));
        }
    }
    s
}

/// A few spheres (turned and uniformly scaled, some of them mirrors) and a sphere less a
/// cube, standing on a checkered floor under two lights, one low: the kind of scene the
/// thesis draws, small enough to be searched solid by solid, whose floor's shadow rays pass
/// every distance from the solids.
fn few_on_a_floor(rng: &mut Rng) -> String {
    let mut s = String::from(
        "[GLOBALS]\nwidth = 64\nheight = 48\nambient = 0.2\nshadow = 0.7\nmax_depth = 3\n[/GLOBALS]\n\
         [CAMERA]\neye = <0, 3, 9>\nlook_at = <0, 0.5, 0>\nfov = 55\n[/CAMERA]\n\
         [OBJECT]\ntype = plane\ncolor1 = 0.9\ncolor2 = 0.15\n[/OBJECT]\n",
    );
    for height in [rng.range(6.0, 20.0), rng.range(0.5, 2.0)] {
        let a = rng.range(0.0, std::f64::consts::TAU);
        let d = rng.range(2.0, 10.0);
        s += &format!(
            "[LIGHT]\nposition = <{}, {height}, {}>\ncolor = 0.5\n[/LIGHT]\n",
            d * a.cos(),
            d * a.sin()
        );
    }
    for _ in 0..3 {
        let r = rng.range(0.3, 1.2);
        let mirror = if rng.below(3) == 0 {
            "mirror = 0.6\n"
        } else {
            ""
        };
        s += &format!(
            "[OBJECT]\ntype = sphere\nradius = {r}\nrotate = {}\ntranslate = <{}, {}, {}>\n{mirror}[/OBJECT]\n",
            v(rng.vec(90.0)),
            rng.range(-3.0, 3.0),
            r + rng.range(0.0, 0.5),
            rng.range(-3.0, 2.0)
        );
    }
    s += &format!(
        "[CSG]\nop = difference\nrotate = {}\ntranslate = <{}, 1.2, {}>\n\
         [OBJECT]\ntype = sphere\nradius = 1\n[/OBJECT]\n\
         [OBJECT]\ntype = cube\nscale = 0.6\ntranslate = <0.5, 0.5, 0.5>\n[/OBJECT]\n[/CSG]\n",
        v(rng.vec(90.0)),
        rng.range(-3.0, 3.0),
        rng.range(-3.0, 1.0)
    );
    s
}

/// Shadow rays that nothing can block are not traced (see `tessera_tracer::shadow`), nor
/// those a scene of few solids shows clear of every solid's ball (see
/// `Scene::shadow_certainly_clear`), and no pixel changes: lattices of solids whose shadow
/// rays skim one another, with a floor and without, from four solids (searched in turn)
/// to 144 (through the BVH), and random scenes of every kind, few and many, against the
/// same scenes tracing every shadow ray.
#[test]
fn culling_clear_shadow_rays_changes_no_pixel() {
    let mut rng = Rng(31);
    let (mut culled, mut kept) = (0, 0);
    let (mut culled_lone, mut kept_lone) = (0, 0);
    let mut scenes: Vec<String> = Vec::new();
    for k in [2, 3, 6, 12] {
        scenes.push(lattice_scene(&mut rng, k, false));
        scenes.push(lattice_scene(&mut rng, k, true));
    }
    for _ in 0..4 {
        scenes.push(few_on_a_floor(&mut rng));
        scenes.push(random_scene(&mut rng, 4, 3.0, true));
    }
    scenes.push(random_scene(&mut rng, 12, 6.0, false));
    scenes.push(random_scene(&mut rng, 60, 10.0, true));
    for src in &scenes {
        let s = common::scene(src);
        let all = s.clone().without_shadow_culling();
        let rect = Rect::full(s.width, s.height);
        let ((a, sa), (b, sb)) = (s.render_rect_stats(rect), all.render_rect_stats(rect));
        assert!(a == b, "images differ:\n{src}");
        assert_eq!((sa.primary, sa.mirror), (sb.primary, sb.mirror));
        assert!(sa.shadow <= sb.shadow);
        culled += sb.shadow - sa.shadow;
        kept += sa.shadow;
        if !s.uses_bvh() {
            culled_lone += sb.shadow - sa.shadow;
            kept_lone += sa.shadow;
        }
    }
    // Both kinds occur in numbers, in the scenes of few solids too: the culling works, and
    // it keeps the rays that matter.
    assert!(culled > 2000 && kept > 2000, "{culled} culled, {kept} kept");
    assert!(
        culled_lone > 2000 && kept_lone > 2000,
        "{culled_lone} culled, {kept_lone} kept without a BVH"
    );
}

/// The benchmark's many-small-spheres scene, where the BVH does its work.
#[test]
fn small_spheres_bench_scene_is_identical() {
    let path =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../bench/scenes/small-spheres.ray");
    let src = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{path:?}: {e}"));
    let s = common::scene(&src);
    assert!(s.uses_bvh());
    let rect = Rect::new(0, 0, s.width, s.height / 2);
    let linear = s.clone().without_acceleration();
    assert!(s.render_rect(rect) == linear.render_rect(rect));
}

/// The fan of thin rods, whose cylinders the BVH holds as several slices each: the same
/// bytes as testing every rod, with the shadow rays the rods' slices leave to trace, and
/// with every shadow ray traced.
#[test]
fn thin_cylinders_bench_scene_is_identical() {
    let path =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../bench/scenes/thin-cylinders.ray");
    let src = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{path:?}: {e}"));
    let s = common::scene(&src);
    assert!(s.uses_bvh());
    let rect = Rect::full(s.width, s.height);
    let linear = s.clone().without_acceleration();
    let ((a, sa), (b, sb)) = (s.render_rect_stats(rect), linear.render_rect_stats(rect));
    assert_eq!(sa, sb);
    assert!(a == b);
    let (s, linear) = (s.without_shadow_culling(), linear.without_shadow_culling());
    let ((c, sc), (d, sd)) = (s.render_rect_stats(rect), linear.render_rect_stats(rect));
    assert_eq!(sc, sd);
    // Every lit rod pixel casts one (955 in all), some of them culled above.
    assert!(sc.shadow > 900 && sa.shadow < sc.shadow, "{sa:?} {sc:?}");
    assert!(c == d && c == a);
}

/// Small scenes stay linear under the default mode; the thresholds are the ones documented
/// (`BVH_MIN_PRIMS` solids, or their cost, `BVH_MIN_COST`).
#[test]
fn few_prims_stay_linear() {
    let mut src = String::from("[OBJECT]\ntype = plane\n[/OBJECT]\n");
    for i in 0..tessera_tracer::internals::BVH_MIN_PRIMS - 1 {
        src += &format!(
            "[OBJECT]\ntype = sphere\ntranslate = <{}, 1, 0>\n[/OBJECT]\n",
            3 * i
        );
    }
    assert!(!common::scene(&src).uses_bvh());
    src += "[OBJECT]\ntype = sphere\ntranslate = <-3, 1, 0>\n[/OBJECT]\n";
    assert!(common::scene(&src).uses_bvh());
    // Fewer but costlier solids: three cubes and a sphere (cost 7) stay linear, four cubes
    // (cost 8, as much as eight spheres) take a BVH.
    let cube = |x: i32| format!("[OBJECT]\ntype = cube\ntranslate = <{x}, 1, 0>\n[/OBJECT]\n");
    let three: String = (0..3).map(|i| cube(3 * i)).collect();
    let sphere = "[OBJECT]\ntype = sphere\ntranslate = <-3, 1, 0>\n[/OBJECT]\n";
    assert!(!common::scene(&(three.clone() + sphere)).uses_bvh());
    assert!(common::scene(&(three + &cube(9))).uses_bvh());
}

/// A union or difference of many children: random objects of every shape, exact copies
/// (coincident surfaces, which the sweep merges), a nested tree, and sometimes a plane
/// (a child with no box). Big enough for the tree's child index.
fn big_csg(rng: &mut Rng, op: &str, n: usize, extent: f64, plane: bool) -> String {
    let mut kids: Vec<String> = Vec::new();
    if op == "difference" {
        kids.push(format!(
            "[OBJECT]\ntype = cube\nscale = {extent}\ncolor1 = <0.4, 0.6, 0.8>\n[/OBJECT]\n"
        ));
    }
    for i in 0..n {
        let kid = match rng.below(12) {
            0 if kids.len() > 1 => kids[1 + rng.below(kids.len() as u64 - 1) as usize].clone(),
            1 => format!(
                "[CSG]\nop = union\ntranslate = {}\n{}{}[/CSG]\n",
                v(rng.vec(extent)),
                object(rng, 0.5),
                object(rng, 0.5)
            ),
            _ => object(rng, extent),
        };
        kids.push(kid);
        if plane && i == n / 2 {
            kids.push("[OBJECT]\ntype = plane\ntranslate = <0, -3, 0>\n[/OBJECT]\n".into());
        }
    }
    format!(
        "[CSG]\nop = {op}\nrotate = {}\n{}[/CSG]\n",
        v(rng.vec(30.0)),
        kids.concat()
    )
}

/// A CSG tree with many children finds them through its index (see `tessera_tracer::csg`),
/// and answers exactly as the plain loop over its children: the nearest hit and the any-hit
/// answer for awkward rays, and whole images, bit for bit.
#[test]
fn big_csg_trees_answer_the_same_with_and_without_their_index() {
    let mut rng = Rng(4242);
    let (mut hits, mut blocked, mut rays) = (0, 0, 0);
    for (round, (op, n, plane)) in [
        ("union", 60, false),
        ("union", 200, true),
        ("difference", 80, false),
        ("difference", 150, true),
    ]
    .into_iter()
    .enumerate()
    {
        let extent = 4.0;
        let src = format!(
            "[GLOBALS]\nwidth = 48\nheight = 36\nshadow = 0.7\n[/GLOBALS]\n\
             [CAMERA]\neye = <2, 4, 12>\nfov = 60\n[/CAMERA]\n\
             [LIGHT]\nposition = <10, 20, 15>\n[/LIGHT]\n{}{}",
            big_csg(&mut rng, op, n, extent, plane),
            object(&mut rng, extent)
        );
        let indexed = common::scene(&src);
        let plain = indexed.clone().without_acceleration();
        let root = |s: &Scene| match &s.prims()[0] {
            tessera_tracer::internals::Prim::Csg(c) => c.is_indexed(),
            tessera_tracer::internals::Prim::Object(_) => panic!("round {round}: no tree first"),
        };
        assert!(root(&indexed) && !root(&plain), "round {round}");
        for _ in 0..1500 {
            let r = random_ray(&mut rng, &plain, extent);
            let t_max = match rng.below(3) {
                0 => rng.range(0.0, 3.0),
                _ => f64::INFINITY,
            };
            let (a, b) = (
                plain.intersect(&r, t_max, None),
                indexed.intersect(&r, t_max, None),
            );
            assert_eq!(
                a.map(|h| (h.object, h.local)),
                b.map(|h| (h.object, h.local)),
                "round {round}: {r:?}, t_max {t_max}\n{src}"
            );
            let occluded = plain.occluded(&r, t_max, None);
            assert_eq!(
                occluded,
                indexed.occluded(&r, t_max, None),
                "round {round}: {r:?}"
            );
            rays += 1;
            hits += usize::from(a.is_some());
            blocked += usize::from(occluded);
        }
        let rect = Rect::full(indexed.width, indexed.height);
        let ((a, sa), (b, sb)) = (
            indexed.render_rect_stats(rect),
            plain.render_rect_stats(rect),
        );
        assert_eq!(sa, sb, "round {round}: ray counts differ");
        assert!(a == b, "round {round}: images differ");
    }
    assert!(
        hits > rays / 4 && blocked > rays / 4,
        "{hits} hits, {blocked} blocked of {rays}"
    );
}

/// A shadow ray from `o` to light `li` as the renderer builds it, with its segment's end.
fn shadow_ray(s: &Scene, li: usize, o: DVec3) -> (Ray, f64) {
    let ray = Ray::new(o, s.lights()[li].position - o);
    let scale = o.length() / ray.dir.length() + 1.0;
    (ray, 1.0 - tessera_tracer::internals::SHADOW_END_REL * scale)
}

/// Rays through the eye look their candidates up in the eye's table, shadow rays in their
/// light's (see `tessera_tracer::point_index`): the same nearest hits and the same shadow
/// answers, bit for bit, as testing every prim. The eye and the lights sit where they
/// usually do, inside a solid, on a box's corner and on a solid's surface; the rays go
/// everywhere, to box corners and cube-face edges, axis-parallel with `±0` components.
#[test]
fn rays_through_the_eye_and_the_lights_answer_as_every_prim_does() {
    let mut rng = Rng(808);
    let (mut hits, mut blocked, mut shadow_rays) = (0, 0, 0);
    for round in 0..18 {
        let n = [40, 150, 600][round % 3];
        let extent = [4.0, 8.0][round % 2];
        let mut src = random_scene(&mut rng, n, extent, round % 4 != 0);
        let base = common::scene(&src);
        // Where the eye and the first light go: their usual places, a solid's centre (inside
        // it), or a corner of a solid's box.
        let k = rng.below(base.objects().len() as u64) as usize;
        let centre = base.objects()[k].transform.to_world().translation;
        match round % 3 {
            1 => {
                src = src.replace(
                    &format!("eye = <3, 5, {}>", extent * 2.5),
                    &format!("eye = {}\nlook_at = {}", v(centre), v(centre + DVec3::ONE)),
                );
                src = src.replace(
                    "position = <10, 20, 15>",
                    &format!("position = {}", v(centre)),
                );
            }
            2 => {
                if let Some(b) = base.objects()[k].bounds {
                    src = src.replace(
                        "position = <10, 20, 15>",
                        &format!("position = {}", v(b.max)),
                    );
                }
            }
            _ => {}
        }
        let linear = common::scene(&src).without_acceleration();
        let tables = common::scene(&src).with_acceleration(Acceleration::Always);
        if !tables.uses_bvh() {
            continue;
        }
        assert_eq!(tables.point_tables(), (true, 2), "round {round}");
        let eye = tables.camera().eye();
        for _ in 0..1500 {
            let target = match rng.below(5) {
                0 => {
                    let o = &linear.objects()[rng.below(linear.objects().len() as u64) as usize];
                    o.transform.to_world().translation
                }
                1 => {
                    let o = &linear.objects()[rng.below(linear.objects().len() as u64) as usize];
                    match o.bounds {
                        Some(b) if rng.below(2) == 0 => b.min,
                        Some(b) => b.max,
                        None => rng.vec(extent),
                    }
                }
                _ => eye + rng.vec(1.0),
            };
            let mut d = target - eye;
            match rng.below(8) {
                0 => d.x = 0.0,
                1 => d.y = -0.0,
                // A cube-face edge and a cube corner, seen from the eye.
                2 => d.y = d.x,
                3 => d = DVec3::splat(d.x),
                _ => {}
            }
            if d == DVec3::ZERO {
                continue;
            }
            // Unit directions, as the camera makes them, and others: the early stop compares
            // squared lengths along the ray, and directions too small or too large for the
            // table (or whose squares underflow) go to the BVH.
            let scale =
                [1.0, 1.0, 1.0, 1e-3, 1e3, 1e-70, 1e70, 1e-200, 1e200][rng.below(9) as usize];
            let r = Ray::new(eye, d.normalize() * scale);
            let (a, b) = (
                linear.intersect(&r, f64::INFINITY, None),
                tables.intersect(&r, f64::INFINITY, None),
            );
            assert_eq!(
                a.map(|h| (h.object, h.local)),
                b.map(|h| (h.object, h.local)),
                "round {round}: primary {r:?}\n{src}"
            );
            hits += usize::from(a.is_some());
            // Shadow rays from the hit (lifted off the surface as the renderer does, or
            // not), from inside solids and from anywhere, to every light.
            let from = match (a, rng.below(3)) {
                (Some(h), 0) => r.origin + r.dir * h.local.t,
                (Some(h), 1) => r.origin + r.dir * (h.local.t * (1.0 - 1e-9)),
                _ => rng.vec(extent * 2.0),
            };
            for li in 0..tables.lights().len() {
                let (sr, end) = shadow_ray(&tables, li, from);
                let skip = a
                    .map(|h| h.object)
                    .filter(|&o| !linear.objects()[o as usize].in_csg && rng.below(2) == 0);
                let want = linear.occluded(&sr, end, skip);
                assert_eq!(
                    tables.occluded_towards(li, &sr, end, skip, &[]),
                    want,
                    "round {round}: shadow ray {sr:?} to light {li}, end {end}, skip {skip:?}\n{src}"
                );
                shadow_rays += 1;
                blocked += usize::from(want);
            }
        }
    }
    eprintln!("{hits} primary hits, {blocked} of {shadow_rays} shadow rays blocked");
    assert!(hits > 5000 && blocked > 5000 && shadow_rays - blocked > 5000);
}

/// A shadow ray from very far away misses its light by the rounding of `L − o`, more than
/// a small solid near the light is wide: the light's table must not be asked for it (see
/// `point_index`'s module comment). Here the ray passes 0.07 from the light and runs through
/// a sphere 56 units before it, in another direction from the light than the ray's own.
#[test]
fn a_shadow_ray_from_far_away_still_finds_its_blocker() {
    let light = DVec3::new(0.3, 0.7, 0.1);
    let mut src = format!(
        "[GLOBALS]\nwidth = 48\nheight = 36\nlight = {}\n[/GLOBALS]\n\
         [OBJECT]\ntype = sphere\nscale = 0.01\ntranslate = <-39.75, -39.25, 0.1>\n[/OBJECT]\n",
        v(light)
    );
    let mut rng = Rng(12);
    for _ in 0..300 {
        src += &format!(
            "[OBJECT]\ntype = sphere\nscale = 0.01\ntranslate = {}\n[/OBJECT]\n",
            v(light + rng.vec(1.0).normalize() * rng.range(5.0, 40.0))
        );
    }
    let s = common::scene(&src);
    assert_eq!(s.point_tables(), (true, 1));
    let (ray, end) = shadow_ray(&s, 0, DVec3::new(-1e15, -1e15, 0.0));
    let linear = s.clone().without_acceleration();
    assert!(
        linear.occluded(&ray, end, None),
        "the sphere blocks the segment"
    );
    assert!(s.occluded_towards(0, &ray, end, None, &[]));
}

/// The cloud the scaling benchmark renders: the tables are built from `point_index::MIN_BOXES`
/// solids on, and whole images, by every sampler, are the same bytes with and without them,
/// with a light lying on one of the spheres (whose shadow rays leave that sphere out).
#[test]
fn images_are_identical_with_and_without_the_point_tables() {
    let mut rng = Rng(4242);
    let min = tessera_tracer::internals::point_index::MIN_BOXES;
    for (n, sampler) in [
        (min - 2, "sampler = center"),
        (min - 1, "sampler = center"),
        (400, "sampler = jitter\nsamples = 2"),
        (400, "sampler = adaptive\nsamples = 6\nthreshold = 0.05"),
    ] {
        let mut src = format!(
            "[GLOBALS]\nwidth = 48\nheight = 36\nambient = 0.1\nshadow = 0.8\n{sampler}\n[/GLOBALS]\n\
             [CAMERA]\neye = <0, 4, 30>\nlook_at = <0, 2, 0>\nfov = 40\n[/CAMERA]\n\
             [LIGHT]\nposition = <20, 30, 10>\n[/LIGHT]\n\
             [LIGHT]\nposition = <0, 3, 0>\ncolor = 0.3\n[/LIGHT]\n\
             [OBJECT]\ntype = plane\ncolor1 = 0.9\ncolor2 = 0.2\n[/OBJECT]\n\
             [OBJECT]\ntype = sphere\ntranslate = <-1, 3, 0>\n[/OBJECT]\n"
        );
        // `n` spheres, the one the second light lies on, and the floor.
        let r = 3.0 / (n as f64).sqrt();
        for _ in 0..n {
            let at = DVec3::new(
                rng.range(-10.0, 10.0),
                rng.range(0.0, 8.0),
                rng.range(-10.0, 10.0),
            );
            src += &format!(
                "[OBJECT]\ntype = sphere\nscale = {r}\ntranslate = {}\n[/OBJECT]\n",
                v(at)
            );
        }
        let s = common::scene(&src);
        assert_eq!(
            s.point_tables(),
            if n + 1 < min { (false, 0) } else { (true, 2) },
            "{n} spheres"
        );
        assert_eq!(
            s.lights_on(1).len(),
            1,
            "the light on the sphere's +x point"
        );
        let plain = s.clone().without_point_tables();
        let rect = Rect::full(s.width, s.height);
        let ((a, sa), (b, sb)) = (s.render_rect_stats(rect), plain.render_rect_stats(rect));
        assert_eq!(sa, sb, "{n} spheres, {sampler}");
        assert!(sa.shadow > 1000, "{sa:?}");
        assert!(a == b, "{n} spheres, {sampler}: images differ");
    }
}

/// Tables are built only for images with `point_index::PIXELS_PER_BOX` pixels per box to list
/// (a table of many boxes for a handful of rays cost more to build than it saved), and by
/// `Acceleration::Always` whatever the image.
#[test]
fn small_images_of_many_solids_build_no_tables() {
    let per_box = tessera_tracer::internals::point_index::PIXELS_PER_BOX;
    let mut rng = Rng(99);
    let mut solids = String::new();
    for _ in 0..400 {
        solids += &format!(
            "[OBJECT]\ntype = sphere\nscale = 0.1\ntranslate = {}\n[/OBJECT]\n",
            v(rng.vec(10.0))
        );
    }
    // 400 boxes: 40 × 40 pixels is exactly four a box, one row fewer is short of it.
    for (w, h, tables) in [(40u32, 40u32, true), (40, 39, false)] {
        assert_eq!(u64::from(w) * u64::from(h) >= per_box * 400, tables);
        let src = format!(
            "[GLOBALS]\nwidth = {w}\nheight = {h}\nlight = <0, 20, 0>\n[/GLOBALS]\n[CAMERA]\neye = <0, 0, 40>\n[/CAMERA]\n{solids}"
        );
        let s = common::scene(&src);
        assert_eq!(s.point_tables(), (tables, usize::from(tables)), "{w}×{h}");
        let always = s.with_acceleration(Acceleration::Always);
        assert_eq!(always.point_tables(), (true, 1), "{w}×{h}");
    }
}

/// A long object's slices count as boxes towards `point_index::MIN_BOXES`: sixteen long thin
/// rods, each cut into many slices, build the tables that sixteen spheres do not, and render
/// the same bytes with and without them.
#[test]
fn long_rods_count_their_slices_towards_the_tables() {
    let fan = |shape: &str| -> String {
        (0..16)
            .map(|i| {
                format!(
                    "[OBJECT]\ntype = {shape}\nradius = 0.05\nscale = <1, 7, 1>\n\
                     rotate = <0, 0, {}>\ntranslate = <{}, 0, 0>\n[/OBJECT]\n",
                    -35.0 + 4.5 * f64::from(i),
                    -9.0 + 1.2 * f64::from(i)
                )
            })
            .collect()
    };
    for (shape, tables) in [("cylinder", true), ("sphere", false)] {
        let src = format!(
            "[GLOBALS]\nwidth = 64\nheight = 48\nlight = <5, 10, 30>\nsampler = adaptive\n\
             samples = 4\nthreshold = 0.05\n[/GLOBALS]\n\
             [CAMERA]\neye = <0, 0, 30>\nfov = 30\n[/CAMERA]\n{}",
            fan(shape)
        );
        let s = common::scene(&src);
        assert_eq!(s.point_tables(), (tables, usize::from(tables)), "{shape}");
        let plain = s.clone().without_point_tables();
        let rect = Rect::full(s.width, s.height);
        let ((a, sa), (b, sb)) = (s.render_rect_stats(rect), plain.render_rect_stats(rect));
        assert_eq!(sa, sb, "{shape}");
        // Where the tables are built, they answer refined rays too, not only probes (the
        // fan of spheres, which builds none, is mostly blank pixels that trace nothing).
        assert!(
            !tables || sa.primary > u64::from(s.width * s.height),
            "{shape}: {sa:?}"
        );
        assert!(a == b, "{shape}: images differ");
    }
}
