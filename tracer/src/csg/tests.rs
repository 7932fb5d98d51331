use super::bounds::*;
use super::hit::*;
use super::*;
use crate::math::{Aabb, Ray};
use crate::scene::CsgOp;
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

pub(super) fn root(s: &Scene) -> &Csg {
    match &s.prims[0] {
        Prim::Csg(c) => c,
        Prim::Object(_) => panic!("the test scene's first solid is not a CSG"),
    }
}

pub(super) fn spans_of(s: &Scene, r: &Ray) -> Vec<CsgSpan> {
    let mut out = Vec::new();
    with_scratch(|sc| s.prims[0].spans(&s.objects, r, sc, &mut out));
    out
}

/// CSG trees covering every operation, nesting, transforms on every level, curved and
/// flat children and a torus.
pub(super) const TREES: &[&str] = &[
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
