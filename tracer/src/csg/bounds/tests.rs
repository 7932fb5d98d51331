//! Tests of the bounds that let a ray skip a CSG tree or its children: the bounding balls
//! of spheres a tree needs, and the line-against-box test its child index relies on.

use super::super::hit::*;
use super::super::tests::{TREES, root, scene, spans_of};
use super::super::*;
use super::*;
use crate::math::{Aabb, Ray};
use crate::shape::Shape;
use crate::shape::test_support::Rng;
use glam::DVec3;

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
