use super::bounds::*;
use super::hit::*;
use super::*;
use crate::math::{Aabb, Ray};
use crate::scene::CsgOp;
use crate::shape::Shape;
use crate::shape::test_support::Rng;
use crate::world::Scene;
use crate::{Limits, MemoryAssets, TextureLimits};
use glam::DVec3;

pub(crate) fn scene(objects: &str) -> Scene {
    let src = format!("[GLOBALS]\nwidth = 16\nheight = 12\n[/GLOBALS]\n{objects}");
    Scene::from_source(
        &src,
        &Limits::default(),
        &MemoryAssets::new(),
        &TextureLimits::default(),
    )
    .unwrap_or_else(|e| panic!("test scene does not build: {e}"))
}

fn root(s: &Scene) -> &Csg {
    match &s.prims[0] {
        Prim::Csg(c) => c,
        Prim::Object(_) => panic!("the test scene's first solid is not a CSG"),
    }
}

fn spans_of(s: &Scene, r: &Ray) -> Vec<CsgSpan> {
    let mut out = Vec::new();
    with_scratch(|sc| s.prims[0].spans(&s.objects, r, sc, &mut out));
    out
}

/// CSG trees covering every operation, nesting, transforms on every level, curved and
/// flat children and a torus.
const TREES: &[&str] = &[
    // A sphere with a corner cut away.
    "[CSG]\nop = difference\n[OBJECT]\ntype = sphere\nradius = 1.2\n[/OBJECT]\n\
         [OBJECT]\ntype = cube\ntranslate = <1, 1, 1>\n[/OBJECT]\n[/CSG]",
    // Three-way intersection, rotated as a whole.
    "[CSG]\nop = intersection\nrotate = <20, 30, 40>\n\
         [OBJECT]\ntype = sphere\nradius = 1.3\n[/OBJECT]\n[OBJECT]\ntype = cube\n[/OBJECT]\n\
         [OBJECT]\ntype = cylinder\nradius = 0.9\nscale = <1, 2, 1>\n[/OBJECT]\n[/CSG]",
    // A torus and a crossing cylinder.
    "[CSG]\nop = union\nscale = <1, 0.7, 1.3>\n\
         [OBJECT]\ntype = torus\nmajor = 1\nminor = 0.3\n[/OBJECT]\n\
         [OBJECT]\ntype = cylinder\nradius = 0.2\nscale = <1, 1.5, 1>\nrotate = <0, 0, 90>\n[/OBJECT]\n[/CSG]",
    // Nested: (cube ∪ sphere) − (cylinder ∩ cone), each level transformed.
    "[CSG]\nop = difference\nrotate = <10, -20, 5>\ntranslate = <0.1, 0.2, -0.3>\n\
         [CSG]\nop = union\n[OBJECT]\ntype = cube\nscale = 0.8\n[/OBJECT]\n\
         [OBJECT]\ntype = sphere\ntranslate = <0.6, 0.6, 0>\n[/OBJECT]\n[/CSG]\n\
         [CSG]\nop = intersection\nscale = <0.7, 1.5, 0.7>\n[OBJECT]\ntype = cylinder\n[/OBJECT]\n\
         [OBJECT]\ntype = cone\nscale = 1.2\n[/OBJECT]\n[/CSG]\n[/CSG]",
    // A torus with a cylindrical hole through its tube, and a cone cutter.
    "[CSG]\nop = difference\n[OBJECT]\ntype = torus\nmajor = 1\nminor = 0.4\n[/OBJECT]\n\
         [OBJECT]\ntype = cylinder\nradius = 0.25\nscale = <1, 2, 1>\ntranslate = <1, 0, 0>\n[/OBJECT]\n\
         [OBJECT]\ntype = cone\nscale = 0.6\ntranslate = <-1, 0.5, 0>\n[/OBJECT]\n[/CSG]",
    // A half-space in a CSG: a sphere cut flat by a (tilted) plane.
    "[CSG]\nop = intersection\n[OBJECT]\ntype = sphere\n[/OBJECT]\n\
         [OBJECT]\ntype = plane\nrotate = <25, 0, 10>\ntranslate = <0, 0.3, 0>\n[/OBJECT]\n[/CSG]",
];

/// Along random rays, the spans a tree reports agree with membership by the set
/// definitions: a dense march finds every sample inside exactly where a span holds it,
/// and membership flips across every reported boundary.
#[test]
fn spans_agree_with_point_membership() {
    let mut rng = Rng::new(31);
    for tree in TREES {
        let s = scene(tree);
        let c = root(&s);
        let mut boundaries = 0;
        for _ in 0..400 {
            let o = rng.direction() * 4.0;
            let r = Ray::new(o, (rng.in_ball(1.2) - o) * rng.range(0.5, 2.0));
            let spans = spans_of(&s, &r);
            let eps = 1e-9 / r.dir.length();
            for w in spans.windows(2) {
                assert!(w[0].exit.t < w[1].enter.t, "{tree}: spans out of order");
            }
            for sp in &spans {
                assert!(sp.enter.t <= sp.exit.t);
                for (t, entering) in [(sp.enter.t, true), (sp.exit.t, false)] {
                    if !t.is_finite() {
                        continue;
                    }
                    boundaries += 1;
                    let before = c.contains(&s.objects, r.at(t - eps));
                    let after = c.contains(&s.objects, r.at(t + eps));
                    assert_eq!(
                        (before, after),
                        (!entering, entering),
                        "{tree}\n{r:?}: boundary at {t} ({})",
                        if entering { "entry" } else { "exit" }
                    );
                }
            }
            // March: membership at samples vs the spans, away from boundaries.
            let t_end = 2.0 * 4.0 / r.dir.length() * 2.0;
            for i in 0..400 {
                let t = t_end * f64::from(i) / 400.0 - 1.0;
                let near_boundary = spans.iter().any(|sp| {
                    (sp.enter.t - t).abs() < 1e3 * eps || (sp.exit.t - t).abs() < 1e3 * eps
                });
                if near_boundary {
                    continue;
                }
                let in_span = spans.iter().any(|sp| sp.enter.t < t && t < sp.exit.t);
                assert_eq!(
                    c.contains(&s.objects, r.at(t)),
                    in_span,
                    "{tree}\n{r:?}: at t = {t} spans {spans:?}"
                );
            }
        }
        assert!(
            boundaries > 200,
            "{tree}: only {boundaries} boundaries checked"
        );
    }
}

/// The nearest hit of the scene is the first span boundary ahead, on the surface of the
/// child that boundary names, with the normal pointing out of the combined solid.
#[test]
fn nearest_hit_is_the_first_boundary_with_an_outward_normal() {
    let mut rng = Rng::new(32);
    for tree in TREES {
        let s = scene(tree);
        let c = root(&s);
        for _ in 0..300 {
            let o = rng.direction() * 4.0;
            let r = Ray::new(o, rng.in_ball(1.2) - o);
            let spans = spans_of(&s, &r);
            let first = spans
                .iter()
                .flat_map(|sp| [sp.enter, sp.exit])
                .find(|b| b.t > 0.0);
            let hit = s.intersect(&r, f64::INFINITY, None);
            assert_eq!(hit.is_some(), first.is_some(), "{tree}\n{r:?}");
            let (Some(h), Some(b)) = (hit, first) else {
                continue;
            };
            assert_eq!(h.local.t, b.t);
            assert_eq!(h.object, b.surface.object);
            let obj = &s.objects[h.object as usize];
            let p = obj.transform.to_world().transform_point3(h.local.p);
            assert!((p - r.at(h.local.t)).length() < 1e-9, "{tree}: {p:?}");
            // Outward: a step along the normal leaves the solid, a step against it enters.
            let n = obj.transform.normal_to_world(h.local.n).normalize();
            let step = 1e-7;
            if c.contains(&s.objects, p - n * step) && !c.contains(&s.objects, p + n * step) {
                continue;
            }
            // Right at an edge of the combined solid a step may leave it both ways;
            // otherwise the normal is wrong.
            let sideways = n.any_orthonormal_vector() * 1e-6;
            let at_edge = c.contains(&s.objects, p + sideways - n * step)
                != c.contains(&s.objects, p - sideways - n * step);
            assert!(
                at_edge,
                "{tree}\n{r:?}: normal {n:?} is not outward at {p:?}"
            );
        }
    }
}

/// A difference whose cutter shares a face plane with the body (the cutter covers the
/// body's +x face and reaches in to x = 1 − 2w): that face must vanish, not flicker.
/// Seen from +x, every ray meets the cut face first, on the cutter's surface, facing +x;
/// never a sliver of the body's face at x = 1. The cutters are placed by decimal
/// scales and offsets that are inexact in binary, and the whole tree is rotated, so the
/// two copies of the face plane round differently and in both orders.
#[test]
fn coincident_cutter_face_removes_the_body_face() {
    let mut rng = Rng::new(33);
    for rot in ["<0, 0, 0>", "<17, 29, 41>", "<90, 0, 90>", "<-33, 71, 5>"] {
        for (w, cut) in [
            (0.5, 0.0),
            (0.55, -0.1),
            (0.3, 0.4),
            (0.35, 0.3),
            (0.15, 0.7),
        ] {
            let s = scene(&format!(
                "[CSG]\nop = difference\nrotate = {rot}\n\
                     [OBJECT]\ntype = cube\n[/OBJECT]\n\
                     [OBJECT]\ntype = cube\nscale = <{w}, 2, 2>\ntranslate = <{}, 0, 0>\n[/OBJECT]\n[/CSG]",
                1.0 - w
            ));
            let csg_t = s.objects[0].transform;
            for _ in 0..400 {
                let target = DVec3::new(cut, rng.range(-0.98, 0.98), rng.range(-0.98, 0.98));
                let from = DVec3::new(3.0, rng.range(-1.5, 1.5), rng.range(-1.5, 1.5));
                let (o, t) = (
                    csg_t.to_world().transform_point3(from),
                    csg_t.to_world().transform_point3(target),
                );
                let r = Ray::new(o, t - o);
                let h = s.intersect(&r, f64::INFINITY, None).expect("the cut face");
                assert_eq!(
                    h.object, 1,
                    "{rot}, w = {w}: hit the body at {:?}",
                    h.local.p
                );
                // The cutter's −x face (x = −1 in its unit space), reversed: facing +x.
                assert_eq!(h.local.p.x, -1.0);
                assert_eq!(h.local.n, DVec3::X);
                assert!((h.local.t - 1.0).abs() < 1e-9);
                assert_eq!(spans_of(&s, &r).len(), 1, "{rot}, w = {w}");
            }
        }
    }
}

/// Two cubes that touch along x = 1, in a union: the shared face is interior and is
/// never reported; rays through it see one span. And in a difference whose cutter only
/// touches the body from outside, the body's face stays, in the body's material.
#[test]
fn touching_solids_share_no_face() {
    for rot in ["<0, 0, 0>", "<13, 47, 22>", "<0, 90, 0>"] {
        let s = scene(&format!(
            "[CSG]\nop = union\nrotate = {rot}\nscale = <1.5, 1, 0.5>\n\
                 [OBJECT]\ntype = cube\n[/OBJECT]\n\
                 [OBJECT]\ntype = cube\ntranslate = <2, 0, 0>\n[/OBJECT]\n[/CSG]"
        ));
        let w = s.objects[0].transform;
        let mut rng = Rng::new(34);
        for _ in 0..1000 {
            let a = DVec3::new(-3.0, rng.range(-0.95, 0.95), rng.range(-0.95, 0.95));
            let b = DVec3::new(5.0, rng.range(-0.95, 0.95), rng.range(-0.95, 0.95));
            let (o, e) = (
                w.to_world().transform_point3(a),
                w.to_world().transform_point3(b),
            );
            let spans = spans_of(&s, &Ray::new(o, e - o));
            assert_eq!(spans.len(), 1, "{rot}: internal face reported: {spans:?}");
            // From inside the first cube, towards the second: the far end, not x = 1.
            let inside = w
                .to_world()
                .transform_point3(DVec3::new(0.5, a.y * 0.5, a.z * 0.5));
            let r = Ray::new(inside, e - inside);
            let h = s.intersect(&r, f64::INFINITY, None).expect("far face");
            assert_eq!(h.object, 1);
            assert_eq!(h.local.p.x, 1.0, "{rot}: stopped at the shared face");
        }
    }
    // A cutter touching the body from outside removes nothing.
    let s = scene(
        "[CSG]\nop = difference\nrotate = <21, 34, 55>\n\
             [OBJECT]\ntype = cube\n[/OBJECT]\n\
             [OBJECT]\ntype = cube\ntranslate = <2, 0, 0>\n[/OBJECT]\n[/CSG]",
    );
    let w = s.objects[0].transform;
    let mut rng = Rng::new(35);
    for _ in 0..1000 {
        let o = w.to_world().transform_point3(DVec3::new(
            5.0,
            rng.range(-0.9, 0.9),
            rng.range(-0.9, 0.9),
        ));
        let e = w.to_world().transform_point3(DVec3::new(
            -3.0,
            rng.range(-0.9, 0.9),
            rng.range(-0.9, 0.9),
        ));
        let h = s
            .intersect(&Ray::new(o, e - o), f64::INFINITY, None)
            .expect("the body's face");
        assert_eq!((h.object, h.local.p.x), (0, 1.0));
        assert_eq!(h.local.n, DVec3::X);
    }
}

/// A face shared by both children of an intersection is shown (the solid begins there),
/// and it belongs to the first child written, whichever copy rounding puts first.
#[test]
fn shared_face_of_an_intersection_belongs_to_the_first_child() {
    let s = scene(
        "[CSG]\nop = intersection\nrotate = <31, 17, 73>\n\
             [OBJECT]\ntype = cube\n[/OBJECT]\n\
             [OBJECT]\ntype = cube\nscale = <0.35, 2, 2>\ntranslate = <0.65, 0, 0>\n[/OBJECT]\n[/CSG]",
    );
    let w = s.objects[0].transform;
    let mut rng = Rng::new(37);
    for _ in 0..1000 {
        let from = DVec3::new(4.0, rng.range(-2.0, 2.0), rng.range(-2.0, 2.0));
        let to = DVec3::new(1.0, rng.range(-0.95, 0.95), rng.range(-0.95, 0.95));
        let (o, e) = (
            w.to_world().transform_point3(from),
            w.to_world().transform_point3(to),
        );
        let h = s
            .intersect(&Ray::new(o, e - o), f64::INFINITY, None)
            .expect("the shared face");
        assert_eq!((h.object, h.local.p.x, h.local.n), (0, 1.0, DVec3::X));
    }
}

/// A shadow ray against a difference sees its hole: a cube with a cylinder drilled along
/// y blocks the light except straight through the hole.
#[test]
fn shadow_rays_pass_through_a_hole() {
    let s = scene(
        "[CSG]\nop = difference\nrotate = <0, 30, 0>\n\
             [OBJECT]\ntype = cube\n[/OBJECT]\n\
             [OBJECT]\ntype = cylinder\nradius = 0.4\nscale = <1, 2, 1>\n[/OBJECT]\n[/CSG]",
    );
    let light = DVec3::new(0.0, 10.0, 0.0);
    for (x, z, blocked) in [
        (0.0, 0.0, false),
        (0.3, 0.1, false),
        (-0.2, -0.25, false),
        (0.5, 0.0, true),
        (0.0, -0.8, true),
        (0.6, 0.6, true),
        (1.5, 0.0, false),
    ] {
        let p = DVec3::new(x, -5.0, z);
        // Aim straight up so the ray stays at (x, z).
        let r = Ray::new(p, light.with_x(x).with_z(z) - p);
        assert_eq!(s.occluded(&r, 1.0, None), blocked, "at ({x}, {z})");
    }
}

#[test]
fn first_boundary_skips_the_surface_being_left() {
    let sf = Surface {
        object: 0,
        face: 0,
        flip: false,
    };
    let span = |a: f64, b: f64| CsgSpan {
        enter: Boundary { t: a, surface: sf },
        exit: Boundary { t: b, surface: sf },
    };
    let spans = [span(-1.0, 1e-17), span(2.0, 3.0), span(4.0, 5.0)];
    let t = |b: Option<Boundary>| b.map(|b| b.t);
    // Outside: the exit at 1e-17 is the surface just left; the entry at 2 is the hit.
    assert_eq!(t(first_boundary(&spans, 10.0, || false)), Some(2.0));
    // Inside (as the spans also say): the exit at 1e-17 is real.
    assert_eq!(t(first_boundary(&spans, 10.0, || true)), Some(1e-17));
    // Entering at a tiny t while the origin is inside: skip it, take the exit.
    let spans = [span(1e-17, 3.0), span(4.0, 5.0)];
    assert_eq!(t(first_boundary(&spans, 10.0, || true)), Some(3.0));
    assert_eq!(t(first_boundary(&spans, 10.0, || false)), Some(1e-17));
    // t_max cuts it short, and membership is not even asked when nothing is ahead.
    assert_eq!(t(first_boundary(&spans, 2.0, || true)), None);
    let behind = [span(-3.0, -1.0)];
    assert_eq!(
        t(first_boundary(&behind, 10.0, || panic!("not needed"))),
        None
    );
}

#[test]
fn bounds_follow_the_operation() {
    let b = |min: f64, max: f64| Some(Aabb::new(DVec3::splat(min), DVec3::splat(max)));
    let kids = [b(0.0, 2.0), b(1.0, 3.0)];
    assert_eq!(combine_bounds(CsgOp::Union, &kids), b(0.0, 3.0));
    assert_eq!(combine_bounds(CsgOp::Intersection, &kids), b(1.0, 2.0));
    assert_eq!(combine_bounds(CsgOp::Difference, &kids), b(0.0, 2.0));
    assert_eq!(combine_bounds(CsgOp::Union, &[b(0.0, 1.0), None]), None);
    assert_eq!(
        combine_bounds(CsgOp::Intersection, &[None, b(0.0, 1.0)]),
        b(0.0, 1.0)
    );
    // Disjoint intersection: an empty box, which no ray meets.
    let empty = combine_bounds(CsgOp::Intersection, &[b(0.0, 1.0), b(2.0, 3.0)]);
    assert!(empty.is_some_and(|e| e.is_empty()));
    // A scene's CSG bounds hold every hit.
    let mut rng = Rng::new(36);
    for tree in TREES {
        let s = scene(tree);
        let Some(bb) = root(&s).bounds else { continue };
        for _ in 0..300 {
            let o = rng.direction() * 5.0;
            let r = Ray::new(o, rng.in_ball(1.0) - o);
            if let Some(h) = s.intersect(&r, f64::INFINITY, None) {
                let p = r.at(h.local.t);
                assert!(p.cmpge(bb.min - 1e-9).all() && p.cmple(bb.max + 1e-9).all());
            }
        }
    }
}

#[test]
fn degenerate_rays_make_no_nan() {
    for tree in TREES {
        let s = scene(tree);
        for r in [
            Ray::new(DVec3::ZERO, DVec3::ZERO),
            Ray::new(DVec3::new(0.0, 0.0, 5.0), DVec3::new(0.0, -0.0, -1.0)),
            Ray::new(DVec3::new(1.0, 1.0, 5.0), DVec3::new(0.0, 0.0, -1.0)),
            Ray::new(DVec3::splat(1e300), DVec3::splat(-1.0)),
        ] {
            for sp in spans_of(&s, &r) {
                assert!(!sp.enter.t.is_nan() && !sp.exit.t.is_nan());
            }
            if let Some(h) = s.intersect(&r, f64::INFINITY, None) {
                assert!(h.local.p.is_finite() && h.local.n.is_finite());
            }
        }
    }
}

/// A direction's length does not change which boundary a tree reports, only its `t`:
/// down to directions whose squared length underflows, where `|d|` came out 0, the
/// scale infinite, and every crossing merged into one (then a tree of cubes, whose slab
/// tests need no squares, reported a boundary outside its box, and the BVH, whose box
/// shortcut dropped it, disagreed with the plain loop), and up to ones whose square
/// overflows.
#[test]
fn tiny_and_huge_directions_find_the_same_boundary() {
    let trees = [
        "[CSG]\nop = difference\n[OBJECT]\ntype = cube\nscale = 2\n[/OBJECT]\n\
             [OBJECT]\ntype = cube\ntranslate = <0.5, 0.5, 2>\n[/OBJECT]\n[/CSG]",
        "[CSG]\nop = union\n[OBJECT]\ntype = cube\n[/OBJECT]\n\
             [OBJECT]\ntype = cube\ntranslate = <1.5, 0.2, 0.1>\n[/OBJECT]\n[/CSG]",
        "[CSG]\nop = intersection\n[OBJECT]\ntype = cube\nscale = 2\n[/OBJECT]\n\
             [OBJECT]\ntype = cube\nscale = <3, 1, 3>\ntranslate = <0.3, 0.5, 0>\n[/OBJECT]\n[/CSG]",
    ];
    let mut checked = 0;
    for tree in trees {
        let s = scene(tree).without_acceleration();
        for (o, d) in [
            (DVec3::new(0.3, 0.2, 5.0), DVec3::new(0.01, -0.02, -1.0)),
            (DVec3::new(-4.0, 0.5, 0.3), DVec3::new(1.0, -0.1, -0.07)),
            (DVec3::new(0.1, 6.0, 0.2), DVec3::new(0.03, -1.0, 0.05)),
        ] {
            let unit = Ray::new(o, d.normalize());
            let want = s
                .intersect(&unit, f64::INFINITY, None)
                .expect("aimed at the tree");
            for k in [1e-201, 1e-170, 1e170, 1e200] {
                let r = Ray::new(o, unit.dir * k);
                let got = s
                    .intersect(&r, f64::INFINITY, None)
                    .unwrap_or_else(|| panic!("{tree} scale {k:e}: no hit"));
                assert_eq!(got.object, want.object, "{tree} scale {k:e}");
                let t = got.local.t * k;
                assert!(
                    (t - want.local.t).abs() <= 1e-9 * want.local.t,
                    "{tree} {k:e}: {t} against {}",
                    want.local.t
                );
                checked += 1;
            }
        }
    }
    assert_eq!(checked, 36);
}

/// A child's own crossings are never one event, however close, while crossings of
/// different children within the tolerance are: spans of one child that nearly touch,
/// or a sliver of one child, stay as they are (whether the sweep's shortcut for one
/// child copies them or the sweep runs), while the same ends from two children merge.
/// The expected spans are worked out by hand from the rule in the module comment.
#[test]
fn a_childs_own_crossings_never_merge_but_different_childrens_do() {
    let surface = |face| Surface {
        object: 0,
        face,
        flip: false,
    };
    // `ends`: (child, enter, exit) per span, in the order the children would push them.
    let run = |op: CsgOp, n: usize, ends: &[(u32, f64, f64)], shortcut: bool| {
        let mut scratch = Scratch::default();
        for &(child, a, b) in ends {
            for (t, enter, face) in [(a, true, 0), (b, false, 1)] {
                scratch.events.push(Event {
                    t,
                    child,
                    enter,
                    surface: surface(face),
                });
            }
        }
        if shortcut {
            assert!(
                lone_spans(op, n, &scratch.events).is_some(),
                "{op:?}: no shortcut"
            );
        }
        sweep(op, n, 0, 1.0, &mut scratch);
        scratch
            .spans
            .iter()
            .map(|s| (s.enter.t, s.exit.t))
            .collect::<Vec<_>>()
    };
    let gap = COINCIDENT_REL / 10.0;
    let apart = [(0, 1.0, 2.0), (0, 3.0, 4.0)];
    let touching = [(0, 1.0, 2.0), (0, 2.0 + gap, 4.0)];
    let sliver = [(0, 1.0, 1.0 + gap), (0, 3.0, 4.0)];
    for (op, n) in [
        (CsgOp::Union, 2),
        (CsgOp::Difference, 2),
        (CsgOp::Intersection, 1),
    ] {
        for ends in [&apart, &touching, &sliver] {
            let expected: Vec<(f64, f64)> = ends.iter().map(|&(_, a, b)| (a, b)).collect();
            assert_eq!(run(op, n, ends, true), expected, "{op:?}");
        }
    }
    // The sweep itself (a second child's span far away keeps the shortcut out).
    let far = (1, 10.0, 11.0);
    let with_far = |ends: &[(u32, f64, f64)]| [ends, &[far]].concat();
    for ends in [&touching, &sliver] {
        let mut expected: Vec<(f64, f64)> = ends.iter().map(|&(_, a, b)| (a, b)).collect();
        expected.push((10.0, 11.0));
        assert_eq!(run(CsgOp::Union, 2, &with_far(ends), false), expected);
    }
    // Two children whose spans nearly touch: one solid, the shared face gone.
    let two = [(0, 1.0, 2.0), (1, 2.0 + gap, 4.0)];
    assert_eq!(run(CsgOp::Union, 2, &two, false), vec![(1.0, 4.0)]);
    // A child's sliver against another child's face: the sliver's entry merges with the
    // other child's exit (one event: no boundary), its exit stands on its own.
    let grazing = [(0, 1.0, 2.0), (1, 2.0 + gap, 2.0 + 2.0 * gap)];
    assert_eq!(
        run(CsgOp::Union, 2, &grazing, false),
        vec![(1.0, 2.0 + 2.0 * gap)]
    );
}

/// A line through `c` at distance `rho` from it, leaving from `back` behind the closest
/// point along a random direction (scaled at random, as world rays are not unit).
fn line_at(rng: &mut Rng, c: DVec3, rho: f64, back: f64) -> Ray {
    let u = rng.direction();
    let w = u.any_orthonormal_vector();
    let w = w * rng.range(-1.0, 1.0) + u.cross(w) * rng.range(-1.0, 1.0);
    let closest = c + w.normalize() * rho;
    Ray::new(closest - u * back, u * rng.range(0.1, 10.0))
}

/// The failure case of a "certainly missed" test is the grazing line: one the sphere's
/// own test, rounding and all, still finds a crossing on. For spheres placed by
/// rotations, scales from 0.01 to 100 and offsets up to 10⁴ radii, lines from within a
/// hair of the tangent (distances (1 ± 10⁻¹⁶…10⁻⁶)·s), near and far: whenever the
/// sphere's spans are not empty, the ball must not reject. And it must work: a line
/// that misses by 1 % from nearby is rejected.
#[test]
fn a_rigid_ball_never_rejects_a_line_its_sphere_meets() {
    use crate::transform::{Transform, TransformOp};
    let mut rng = Rng::new(41);
    let (mut grazing_hits, mut rejected) = (0, 0);
    for case in 0..300 {
        let s = 10f64.powf(rng.range(-2.0, 2.0));
        let offset = if case % 3 == 0 { 1e4 } else { 10.0 };
        let t = [
            TransformOp::Scale(DVec3::splat(s)),
            TransformOp::Rotate(rng.in_ball(1.0) * 360.0),
            TransformOp::Translate(rng.in_ball(offset * s)),
        ]
        .iter()
        .fold(Transform::IDENTITY, |t, &op| {
            t.then(&Transform::from_op(op))
        });
        let (centre, r2) = t.rigid_ball().expect("a rotation and a uniform scale");
        assert!(
            r2 >= s * s * (1.0 - 1e-15) && r2 <= s * s * (1.0 + 1e-9),
            "{r2} vs {s}²"
        );
        let ball = Ball::new(centre, r2);
        let spans = |r: &Ray| {
            let mut out = Vec::new();
            Shape::Sphere.spans(&t.ray_to_object(r), &mut out);
            out
        };
        for back in [2.0 * s, 1e3 * s] {
            for k in -10i32..=10 {
                let rel = f64::from(k.signum()) * 10f64.powi(k.abs() - 16);
                let r = line_at(&mut rng, centre, s * (1.0 + rel), back);
                if !spans(&r).is_empty() {
                    grazing_hits += 1;
                    assert!(
                        !ball.certainly_missed(&r),
                        "{t:?}\n{r:?}: met, yet rejected"
                    );
                }
            }
        }
        if offset == 10.0 {
            let r = line_at(&mut rng, centre, s * 1.01, 2.0 * s);
            assert!(spans(&r).is_empty());
            assert!(ball.certainly_missed(&r), "{t:?}\n{r:?}: a clear miss kept");
            rejected += 1;
        }
    }
    assert!(
        grazing_hits > 3000,
        "only {grazing_hits} grazing lines met the sphere"
    );
    assert!(rejected == 200);
    // A non-uniform scale makes an ellipsoid: no ball.
    let squashed = Transform::from_op(TransformOp::Scale(DVec3::new(1.0, 2.0, 1.0)));
    assert_eq!(squashed.rigid_ball(), None);
}

/// Which balls a tree keeps: every sphere of an intersection, a difference's body's, none
/// for a union (no one child is needed) or for a squashed sphere.
#[test]
fn a_tree_keeps_the_balls_of_the_children_it_needs() {
    let sphere = |extra: &str| format!("[OBJECT]\ntype = sphere\n{extra}[/OBJECT]\n");
    let cube = "[OBJECT]\ntype = cube\n[/OBJECT]\n";
    let lens = format!(
        "[CSG]\nop = intersection\nrotate = <10, 20, 30>\n{}{}[/CSG]\n",
        sphere("translate = <0.5, 0, 0>\n"),
        sphere("translate = <-0.5, 0, 0>\n")
    );
    for (tree, balls) in [
        (lens.clone(), 2),
        (
            format!("[CSG]\nop = difference\n{lens}{}[/CSG]", sphere("")),
            2,
        ),
        (format!("[CSG]\nop = difference\n{cube}{lens}[/CSG]"), 0),
        (
            format!("[CSG]\nop = union\n{}{}[/CSG]", sphere(""), sphere("")),
            0,
        ),
        (
            format!(
                "[CSG]\nop = intersection\n{cube}{}[/CSG]",
                sphere("scale = <1, 2, 1>\n")
            ),
            0,
        ),
        (
            format!(
                "[CSG]\nop = intersection\nscale = 3\n{cube}{}[/CSG]",
                sphere("")
            ),
            1,
        ),
    ] {
        let s = scene(&tree);
        assert_eq!(root(&s).balls.len(), balls, "{tree}");
    }
}

/// The balls change no answer: for trees with rotated spheres in every role, on random
/// rays and on lines grazing each ball, the tree's first boundary is the one its spans
/// give (which are found without the balls), for every limit; and the balls do reject.
#[test]
fn balls_change_no_first_boundary() {
    let mut rng = Rng::new(42);
    let trees = [
        TREES[1],
        TREES[5],
        // The CSG example's lens and die, rotated off the axes.
        "[CSG]\nop = intersection\nrotate = <0, -70, 0>\ntranslate = <6, -0.17, 0>\n\
             [OBJECT]\ntype = sphere\nradius = 2\ntranslate = <1.5, 0, 0>\n[/OBJECT]\n\
             [OBJECT]\ntype = sphere\nradius = 2\ntranslate = <-1.5, 0, 0>\n[/OBJECT]\n[/CSG]",
        "[CSG]\nop = difference\nrotate = <25, 35, 0>\ntranslate = <-2, -0.15, 0>\n\
             [CSG]\nop = intersection\n[OBJECT]\ntype = cube\n[/OBJECT]\n\
             [OBJECT]\ntype = sphere\nradius = 1.35\n[/OBJECT]\n[/CSG]\n\
             [OBJECT]\ntype = cylinder\nradius = 0.45\nscale = <1, 1.5, 1>\n[/OBJECT]\n[/CSG]",
    ];
    let mut rejected = 0;
    for tree in trees {
        let s = scene(tree);
        let c = root(&s);
        assert!(!c.balls.is_empty(), "{tree}");
        let centre = c
            .bounds
            .map(|b| (b.min + b.max) * 0.5)
            .unwrap_or(DVec3::ZERO);
        for i in 0..2000 {
            let r = if i % 2 == 0 {
                let o = centre + rng.direction() * 8.0;
                Ray::new(o, centre + rng.in_ball(3.0) - o)
            } else {
                let b = c.balls[i / 2 % c.balls.len()];
                let rel = rng.range(-1e-6, 1e-6) * 10f64.powf(rng.range(-10.0, 0.0));
                let back = rng.range(0.0, 20.0);
                line_at(&mut rng, b.centre, b.r2.sqrt() * (1.0 + rel), back)
            };
            if c.balls.iter().any(|b| b.certainly_missed(&r)) {
                rejected += 1;
            }
            let spans = spans_of(&s, &r);
            for t_max in [f64::INFINITY, rng.range(0.0, 3.0)] {
                let expected = first_boundary(&spans, t_max, || c.contains(&s.objects, r.origin));
                assert_eq!(
                    c.first_hit(&s.objects, &r, t_max),
                    expected,
                    "{tree}\n{r:?}"
                );
            }
        }
    }
    assert!(rejected > 1000, "the balls rejected only {rejected} rays");
}

/// A ray component of one of the awkward kinds: ±0, subnormal (whose `1/d` is ±∞, and
/// `0·∞` a NaN for a face at the origin's coordinate), or ordinary.
fn awkward(rng: &mut Rng) -> f64 {
    let sign = if rng.unit() < 0.5 { -1.0 } else { 1.0 };
    match rng.next_u64() % 6 {
        0 => sign * 0.0,
        1 => sign * f64::from_bits(1 + rng.next_u64() % 1000),
        _ => rng.range(-1.0, 1.0),
    }
}

/// [`line_meets`] is monotone in the box (the property [`ChildIndex`] relies on to skip
/// a subtree by its node's box): for boxes `a ⊇ b`, a line meeting `b` meets `a`. Tried
/// exactly where rounding could break it: origins on `b`'s faces, `a` sharing faces with
/// `b`, zero and subnormal direction components.
#[test]
fn line_meets_is_monotone_in_the_box() {
    let mut rng = Rng::new(5);
    let (mut met_inner, mut missed_outer) = (0, 0);
    for _ in 0..200_000 {
        let lo = DVec3::new(
            rng.range(-3.0, 3.0),
            rng.range(-3.0, 3.0),
            rng.range(-3.0, 3.0),
        );
        let hi = lo
            + DVec3::new(
                rng.range(0.0, 2.0),
                rng.range(0.0, 2.0),
                rng.range(0.0, 2.0),
            );
        let inner = Aabb::new(lo, hi);
        // Grow some faces, keep others shared (grown by zero).
        let mut grow = || {
            if rng.unit() < 0.5 {
                0.0
            } else {
                rng.range(0.0, 1.0)
            }
        };
        let outer = Aabb::new(
            lo - DVec3::new(grow(), grow(), grow()),
            hi + DVec3::new(grow(), grow(), grow()),
        );
        // An origin with some coordinates exactly on the inner box's faces.
        let mut o = DVec3::new(
            rng.range(-6.0, 6.0),
            rng.range(-6.0, 6.0),
            rng.range(-6.0, 6.0),
        );
        for i in 0..3 {
            match rng.next_u64() % 4 {
                0 => o[i] = lo[i],
                1 => o[i] = hi[i],
                _ => {}
            }
        }
        let d = DVec3::new(awkward(&mut rng), awkward(&mut rng), awkward(&mut rng));
        if d == DVec3::ZERO {
            continue;
        }
        let r = Ray::new(o, d);
        let inv = r.inv_dir();
        let (i, a) = (line_meets(&inner, &r, inv), line_meets(&outer, &r, inv));
        assert!(!i || a, "meets {inner:?} but not {outer:?}: {r:?}");
        met_inner += usize::from(i);
        missed_outer += usize::from(!a);
    }
    assert!(
        met_inner > 10_000 && missed_outer > 10_000,
        "{met_inner} {missed_outer}"
    );
}

/// A line through a face's own plane with a subnormal component along its normal:
/// `(min − o)·(1/d)` is `0·∞`, a NaN, and the line does meet the box (from `t = 0`).
#[test]
fn a_nan_slab_end_does_not_drop_the_box() {
    let b = Aabb::new(DVec3::ZERO, DVec3::ONE);
    for x in [0.0, 1.0] {
        for sign in [1.0, -1.0] {
            let r = Ray::new(DVec3::new(x, 0.5, 0.5), DVec3::new(sign * 5e-324, 1.0, 0.0));
            assert!(line_meets(&b, &r, r.inv_dir()), "{r:?}");
        }
    }
}

/// A union (or difference) of many scattered children: spheres, boxes, a nested tree,
/// exact copies, and (`unbounded`) a plane, which has no box.
fn many_children(rng: &mut Rng, op: &str, n: usize, unbounded: bool) -> String {
    let mut kids = String::new();
    if op == "difference" {
        kids += "[OBJECT]\ntype = cube\nscale = 3\n[/OBJECT]\n";
    }
    let mut written: Vec<String> = Vec::new();
    for k in 0..n {
        let at = rng.in_ball(3.5);
        let child = match k % 7 {
            0 if !written.is_empty() => written[rng.next_u64() as usize % written.len()].clone(),
            1 => format!(
                "[OBJECT]\ntype = cube\nscale = {}\nrotate = <{}, 20, 0>\ntranslate = <{}, {}, {}>\n[/OBJECT]\n",
                rng.range(0.1, 0.5),
                rng.range(0.0, 90.0),
                at.x,
                at.y,
                at.z
            ),
            2 => format!(
                "[CSG]\nop = intersection\ntranslate = <{}, {}, {}>\n\
                     [OBJECT]\ntype = sphere\nradius = 0.4\n[/OBJECT]\n\
                     [OBJECT]\ntype = cube\nscale = 0.3\n[/OBJECT]\n[/CSG]\n",
                at.x, at.y, at.z
            ),
            _ => format!(
                "[OBJECT]\ntype = sphere\nradius = {}\ntranslate = <{}, {}, {}>\n[/OBJECT]\n",
                rng.range(0.1, 0.6),
                at.x.round(),
                at.y,
                at.z
            ),
        };
        written.push(child.clone());
        kids += &child;
    }
    if unbounded {
        kids += "[OBJECT]\ntype = plane\ntranslate = <0, -2.5, 0>\n[/OBJECT]\n";
    }
    format!("[CSG]\nop = {op}\nrotate = <5, 10, 0>\n{kids}[/CSG]\n")
}

/// The index finds exactly the children the loop evaluates (every child whose line box
/// the line meets), and a point inside a child is inside by the index too: on unions and
/// differences of many children, with rays from everywhere, of every awkward direction.
#[test]
fn the_child_index_finds_exactly_the_children_the_loop_tries() {
    let mut rng = Rng::new(17);
    for (op, n, unbounded) in [
        ("union", 40, false),
        ("union", 300, true),
        ("difference", 120, true),
    ] {
        let s = scene(&many_children(&mut rng, op, n, unbounded));
        let c = root(&s);
        let ix = c.index.as_ref().expect("indexed");
        assert_eq!(ix.always.is_empty(), !unbounded, "{op} {n}");
        let (mut found, mut inside) = (0usize, 0usize);
        for _ in 0..3000 {
            let o = rng.in_ball(6.0);
            let o = if rng.unit() < 0.2 { o.round() } else { o };
            let mut d = rng.direction();
            if rng.unit() < 0.3 {
                d[(rng.next_u64() % 3) as usize] = awkward(&mut rng);
            }
            let r = Ray::new(o, d);
            let inv = r.inv_dir();
            let first = usize::from(op == "difference");
            let expected: Vec<u32> = (first..c.children.len())
                .filter(|&k| c.line_boxes[k].is_none_or(|b| line_meets(&b, &r, inv)))
                .map(|k| k as u32)
                .collect();
            let mut got = Vec::new();
            ix.children_met(&c.line_boxes, &r, inv, &mut got);
            assert_eq!(got, expected, "{op} {n}: {r:?}");
            found += got.len();
            let p = if rng.unit() < 0.5 {
                rng.in_ball(3.5)
            } else {
                r.at(rng.range(0.0, 3.0))
            };
            let by_loop = c.children[first..]
                .iter()
                .any(|k| k.contains(&s.objects, p));
            let by_index = ix.any_holding(p, |k| c.children[k as usize].contains(&s.objects, p));
            assert_eq!(by_index, by_loop, "{op} {n}: {p:?}");
            inside += usize::from(by_loop);
        }
        assert!(
            found > 1000 && inside > 50,
            "{op} {n}: {found} children found, {inside} points inside"
        );
    }
}

/// `children_near` visits every child whose box meets a region (the adaptive
/// sampler's footprints rely on it), through the index as without it: random boxes
/// against unions and differences of many children, and the same trees unindexed.
#[test]
fn children_near_visits_every_child_whose_box_meets_the_region() {
    let mut rng = Rng::new(23);
    for (op, n, unbounded) in [("union", 200, true), ("difference", 60, false)] {
        let s = scene(&many_children(&mut rng, op, n, unbounded));
        let mut plain = root(&s).clone();
        plain.index_children(usize::MAX);
        for c in [root(&s), &plain] {
            for _ in 0..300 {
                let lo = rng.in_ball(4.0);
                let region = Aabb::new(lo, lo + DVec3::splat(rng.range(0.0, 2.0)));
                let meets = |b: &Aabb| (b.min.cmple(region.max) & region.min.cmple(b.max)).all();
                let mut visited: Vec<*const Prim> = Vec::new();
                c.children_near(meets, |p| visited.push(p as *const Prim));
                for child in &c.children {
                    let must = child.bounds(&s.objects).is_none_or(|b| meets(&b));
                    if must {
                        assert!(
                            visited.contains(&(child as *const Prim)),
                            "{op}: a child meeting {region:?} was not visited"
                        );
                    }
                }
            }
        }
    }
}

/// The threshold: a union of a few children keeps the loop, an intersection never has
/// an index, and `index_children(usize::MAX)` removes every index, nested ones too.
#[test]
fn only_large_unions_and_differences_are_indexed() {
    let mut rng = Rng::new(3);
    let few = scene(&many_children(&mut rng, "union", CSG_INDEX_MIN - 1, false));
    assert!(!root(&few).is_indexed());
    let many = scene(&many_children(&mut rng, "union", CSG_INDEX_MIN, false));
    assert!(root(&many).is_indexed());
    let cutters = scene(&many_children(&mut rng, "difference", CSG_INDEX_MIN, false));
    assert!(root(&cutters).is_indexed());
    let meet = many_children(&mut rng, "intersection", 20, false);
    assert!(!root(&scene(&meet)).is_indexed());
    let nested = format!(
        "[CSG]\nop = union\n{}[OBJECT]\ntype = cube\n[/OBJECT]\n[/CSG]\n",
        many_children(&mut rng, "union", 30, false)
    );
    let mut c = root(&scene(&nested)).clone();
    let inner = |c: &Csg| match &c.children[0] {
        Prim::Csg(inner) => inner.is_indexed(),
        Prim::Object(_) => panic!("the first child is not a tree"),
    };
    assert!(!c.is_indexed() && inner(&c));
    c.index_children(usize::MAX);
    assert!(!inner(&c));
}
