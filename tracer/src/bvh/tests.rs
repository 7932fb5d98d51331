use super::*;
use crate::math::Ray;
use crate::shape::test_support::Rng;

fn random_boxes(rng: &mut Rng, n: usize) -> Vec<(u32, Aabb)> {
    (0..n)
        .map(|i| {
            let c = rng.in_ball(10.0);
            let h = DVec3::new(
                rng.range(0.01, 1.0),
                rng.range(0.01, 1.0),
                rng.range(0.01, 1.0),
            );
            (i as u32, Aabb::new(c - h, c + h))
        })
        .collect()
}

/// A ray where slab tests go wrong: each origin coordinate on one of `b`'s planes or
/// anywhere within `reach`, and each direction component, a third of the time, a zero of
/// either sign.
fn awkward_ray(rng: &mut Rng, b: &Aabb, reach: f64) -> (DVec3, DVec3) {
    let mut pick = |i: usize| match rng.range(0.0, 3.0) as u32 {
        0 => b.min[i],
        1 => b.max[i],
        _ => rng.range(-reach, reach),
    };
    let o = DVec3::new(pick(0), pick(1), pick(2));
    let mut d = rng.in_ball(1.0);
    for i in 0..3 {
        if rng.range(0.0, 3.0) < 1.0 {
            d[i] = if rng.range(0.0, 1.0) < 0.5 { 0.0 } else { -0.0 };
        }
    }
    (o, d)
}

/// Every item whose box the ray enters before the limit is offered, whatever the tree.
#[test]
fn offers_every_box_the_ray_enters() {
    let mut rng = Rng::new(7);
    for n in [1, 2, 3, 17, 200] {
        let boxes = random_boxes(&mut rng, n);
        let (bvh, left_out) = Bvh::build(&boxes);
        assert!(left_out.is_empty());
        assert_eq!(bvh.len(), n);
        for _ in 0..300 {
            let o = rng.in_ball(15.0);
            let mut d = rng.in_ball(1.0);
            // Axis-parallel rays: zero components, of either sign.
            match rng.range(0.0, 4.0) as u32 {
                0 => d.x = 0.0,
                1 => {
                    d.y = -0.0;
                    d.z = 0.0
                }
                _ => {}
            }
            let r = Ray::new(o, d);
            let limit = rng.range(0.0, 40.0);
            let mut offered = vec![false; n];
            bvh.traverse(o, r.inv_dir(), limit, |slot| {
                offered[bvh.items()[slot] as usize] = true;
                ControlFlow::Continue(limit)
            });
            for (id, b) in &boxes {
                if b.hit_interval(o, r.inv_dir(), limit).is_some() {
                    assert!(offered[*id as usize], "n = {n}: box {id} not offered");
                }
            }
        }
    }
}

/// A region query finds an item exactly when brute force over the boxes does (the
/// region here is a ball, tested against boxes by their nearest point, which is exact).
#[test]
fn region_query_finds_what_brute_force_finds() {
    let mut rng = Rng::new(11);
    let near = |b: &Aabb, c: DVec3, r: f64| c.clamp(b.min, b.max).distance(c) <= r;
    let (mut found, mut missed, mut asked_200) = (0, 0, 0);
    for n in [1, 2, 17, 200] {
        let boxes = random_boxes(&mut rng, n);
        let (bvh, _) = Bvh::build(&boxes);
        for _ in 0..300 {
            let (c, r) = (rng.in_ball(12.0), rng.range(0.0, 4.0));
            // Odd ids only, so that the item test's answer matters too.
            let want = boxes.iter().any(|(id, b)| id % 2 == 1 && near(b, c, r));
            let mut asked = Vec::new();
            let got = bvh.any_item(
                |b| near(b, c, r),
                |id| {
                    asked.push(id);
                    id % 2 == 1 && near(&boxes[id as usize].1, c, r)
                },
            );
            assert_eq!(got, want, "n = {n}, ball {c} r {r}");
            if n == 200 {
                asked_200 += asked.len();
            }
            if want { found += 1 } else { missed += 1 }
        }
    }
    // The boxes prune: a query asks about a small share of 200 items on average.
    assert!(
        asked_200 < 300 * 200 / 8,
        "{asked_200} items asked in 300 queries"
    );
    // Both answers occur, so neither could be returned blindly.
    assert!(
        found > 100 && missed > 100,
        "{found} found, {missed} missed"
    );
}

#[test]
fn coincident_and_degenerate_items_build() {
    let b = Aabb::new(DVec3::ZERO, DVec3::ONE);
    let mut items: Vec<(u32, Aabb)> = (0..100).map(|i| (i, b)).collect();
    items.push((100, Aabb::EMPTY));
    items.push((101, Aabb::new(DVec3::splat(f64::NEG_INFINITY), DVec3::ZERO)));
    let (bvh, left_out) = Bvh::build(&items);
    assert_eq!(left_out, vec![100, 101]);
    assert_eq!(bvh.len(), 100);
    let mut seen = 0;
    let r = Ray::new(DVec3::splat(-1.0), DVec3::ONE);
    bvh.traverse(r.origin, r.inv_dir(), f64::INFINITY, |_| {
        seen += 1;
        ControlFlow::Continue(f64::INFINITY)
    });
    assert_eq!(seen, 100);
}

/// Exponentially spaced items would make a degenerate deep tree; the depth cap holds.
#[test]
fn depth_is_capped() {
    let items: Vec<(u32, Aabb)> = (0..200)
        .map(|i| {
            let x = 2f64.powi(i);
            (i as u32, Aabb::new(DVec3::splat(x), DVec3::splat(x * 1.01)))
        })
        .collect();
    let (bvh, _) = Bvh::build(&items);
    assert!(bvh.depth() <= MAX_DEPTH, "{}", bvh.depth());
    let r = Ray::new(DVec3::ZERO, DVec3::ONE);
    let mut seen = 0;
    bvh.traverse(r.origin, r.inv_dir(), f64::INFINITY, |_| {
        seen += 1;
        ControlFlow::Continue(f64::INFINITY)
    });
    assert!(seen > 0);
}
/// `round_out` bounds its argument on the requested side, including where rounding to
/// nearest would not: halfway and subnormal values, zero of either sign, and values
/// beyond the `f32` range (which go to ±∞ only outwards).
#[test]
fn round_out_bounds_on_the_requested_side() {
    let tiny = f64::from(f32::from_bits(1));
    let cases = [
        0.0,
        -0.0,
        1.0,
        -1.0,
        0.1,
        -0.1,
        1.0 + f64::EPSILON,
        1e-40,
        -1e-40,
        tiny * 0.5,
        -tiny * 0.5,
        tiny * 1.5,
        1e-300,
        -1e-300,
        f64::from(f32::MAX),
        f64::from(f32::MAX) * 1.0000001,
        -f64::from(f32::MAX) * 1.0000001,
        1e300,
        -1e300,
        123_456.789_012_345,
    ];
    for x in cases {
        let (lo, hi) = (round_out(x, false), round_out(x, true));
        assert!(
            f64::from(lo) <= x && x <= f64::from(hi),
            "{x}: [{lo}, {hi}]"
        );
        // And no looser than one f32 step: the neighbours outside no longer bound it
        // (unless the bound is exact, when both are `x`).
        if f64::from(lo) < x {
            assert!(
                f64::from(lo.next_up()) >= x,
                "{x}: {lo} is not the nearest below"
            );
        }
        if f64::from(hi) > x {
            assert!(
                f64::from(hi.next_down()) <= x,
                "{x}: {hi} is not the nearest above"
            );
        }
    }
    assert_eq!(round_out(1e300, true), f32::INFINITY);
    assert_eq!(round_out(1e300, false), f32::MAX);
    assert_eq!(round_out(-1e300, false), f32::NEG_INFINITY);
}

/// The stored `f32` lane test accepts every ray the exact-box `f64` test accepts, on
/// the cases that break slab tests: rays parallel to slab planes (zero components of
/// either sign), origins exactly on a face or edge, `0·∞` from an origin in a plane of
/// a slab it is parallel to, flat (zero-thickness) boxes and limits that end exactly at
/// a face.
#[test]
fn lane_test_accepts_what_the_exact_box_test_accepts() {
    let mut rng = Rng::new(31);
    let flat = Aabb::new(DVec3::new(-1.0, 0.5, -1.0), DVec3::new(1.0, 0.5, 1.0));
    let unit = Aabb::new(DVec3::splat(-1.0), DVec3::splat(1.0));
    let mut accepted = 0;
    for k in 0..20000 {
        let b = match k % 4 {
            0 => unit,
            1 => flat,
            _ => {
                let c = rng.in_ball(3.0);
                let h = DVec3::new(rng.range(0.0, 1.0), rng.range(0.0, 1.0), 0.0);
                Aabb::new(c - h, c + h)
            }
        };
        let (o, d) = awkward_ray(&mut rng, &b, 4.0);
        let inv = Ray::new(o, d).inv_dir();
        let limit = if rng.range(0.0, 4.0) < 1.0 {
            f64::INFINITY
        } else {
            rng.range(0.0, 6.0)
        };
        let node = Node::new(&[b, Aabb::EMPTY], &[Child::default(); 2]);
        let (hit, t) = node.hit(&SlabRay::new(o, inv), limit);
        assert!(
            !hit[1] && !hit[2] && !hit[3],
            "an empty lane was hit by {o:?} {d:?}"
        );
        if let Some((t0, _)) = b.hit_interval(o, inv, limit) {
            assert!(hit[0], "box {b:?}, ray {o:?} {d:?}, limit {limit}");
            assert!(t[0] <= t0, "entry {} after the exact {t0}", t[0]);
            accepted += 1;
        }
    }
    assert!(accepted > 3000, "{accepted}");
    // The `0·∞` cases by hand: along +x in the plane y = 1 of the unit box's face (and
    // in the plane of the flat box), entering and starting inside.
    for (b, y) in [(unit, 1.0), (unit, -1.0), (flat, 0.5)] {
        for x in [-5.0, 0.0, 1.0] {
            let o = DVec3::new(x, y, 0.0);
            let inv = Ray::new(o, DVec3::X).inv_dir();
            let node = Node::new(&[b, b, b, b], &[Child::default(); 4]);
            assert_eq!(
                node.hit(&SlabRay::new(o, inv), f64::INFINITY).0,
                [true; 4],
                "{b:?} from {o:?}"
            );
        }
    }
}

/// Items with weights, shared ids and non-finite or zero costs build into a tree that
/// still offers every item whose box the ray enters, once per item.
#[test]
fn weighted_items_and_shared_ids_are_all_offered() {
    let mut rng = Rng::new(12);
    let boxes = random_boxes(&mut rng, 300);
    let items: Vec<Item> = boxes
        .iter()
        .enumerate()
        .map(|(k, &(_, bounds))| Item {
            // Pairs of items share an id, as the pieces of one object do.
            id: (k / 2) as u32,
            bounds,
            cost: [0.1, 1.0, 7.0, 0.0, f64::NAN, f64::INFINITY][k % 6],
        })
        .collect();
    let (bvh, left_out) = Bvh::build_items(&items);
    assert!(left_out.is_empty());
    assert_eq!(bvh.len(), 300);
    assert!(bvh.depth() <= MAX_DEPTH);
    for _ in 0..500 {
        let o = rng.in_ball(15.0);
        let r = Ray::new(o, rng.in_ball(1.0));
        let mut offered = vec![0u32; 150];
        bvh.traverse(o, r.inv_dir(), f64::INFINITY, |slot| {
            offered[bvh.items()[slot] as usize] += 1;
            ControlFlow::Continue(f64::INFINITY)
        });
        for (k, it) in items.iter().enumerate() {
            if it
                .bounds
                .hit_interval(o, r.inv_dir(), f64::INFINITY)
                .is_some()
            {
                assert!(offered[it.id as usize] >= 1, "item {k} not offered");
            }
        }
        assert!(offered.iter().all(|&n| n <= 2));
    }
}

/// [`Node::hit`] compiled for AVX2, as [`Bvh::traverse`] runs it on a CPU that has it.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn hit_avx2(node: &Node, r: &SlabRay, limit: f64) -> ([bool; WIDTH], [f64; WIDTH]) {
    node.hit(r, limit)
}

/// The AVX2 build of the four-lane slab test gives the plain build's bits, lane for lane,
/// on the inputs where an IEEE select could differ from a compare-and-keep: zero
/// direction components of either sign (infinite `1/d`), origins on the boxes' planes
/// (`0·∞ = NaN`), flat and empty boxes, empty lanes, limits of zero and infinity.
#[cfg(target_arch = "x86_64")]
#[test]
fn avx2_slab_test_gives_the_plain_bits() {
    if !has_avx2() {
        eprintln!("no AVX2 on this CPU: only the plain slab test runs here");
        return;
    }
    let mut rng = Rng::new(41);
    let mut hits = 0;
    for _ in 0..20000 {
        let lanes = 1 + rng.range(0.0, 4.0) as usize;
        let boxes: Vec<Aabb> = (0..lanes)
            .map(|_| {
                let c = rng.in_ball(3.0);
                let mut h = DVec3::new(
                    rng.range(0.0, 1.0),
                    rng.range(0.0, 1.0),
                    rng.range(0.0, 1.0),
                );
                if rng.range(0.0, 3.0) < 1.0 {
                    h.y = 0.0;
                }
                Aabb::new(c - h, c + h)
            })
            .collect();
        let node = Node::new(&boxes, &vec![Child::default(); lanes]);
        let (o, d) = awkward_ray(&mut rng, &boxes[0], 5.0);
        let limit = match rng.range(0.0, 4.0) as u32 {
            0 => f64::INFINITY,
            1 => 0.0,
            _ => rng.range(0.0, 8.0),
        };
        let r = SlabRay::new(o, Ray::new(o, d).inv_dir());
        let (plain_hit, plain_t) = node.hit(&r, limit);
        // SAFETY: this CPU has AVX2 (checked above).
        let (wide_hit, wide_t) = unsafe { hit_avx2(&node, &r, limit) };
        assert_eq!(plain_hit, wide_hit, "{boxes:?} {o:?} {d:?} {limit}");
        assert_eq!(
            plain_t.map(f64::to_bits),
            wide_t.map(f64::to_bits),
            "{boxes:?} {o:?} {d:?} {limit}"
        );
        hits += plain_hit.iter().filter(|&&h| h).count();
    }
    assert!(hits > 5000, "{hits}");
}

/// Traversal with the AVX2 slab test offers the same items in the same order as with the
/// plain one, and so every caller gets the same answers from either.
#[test]
fn both_slab_tests_offer_the_same_items_in_the_same_order() {
    let mut rng = Rng::new(43);
    let boxes = random_boxes(&mut rng, 500);
    let (plain, _) = Bvh::build(&boxes);
    let plain = plain.with_avx2(false);
    let wide = plain.clone().with_avx2(true);
    let mut offered = 0;
    for _ in 0..500 {
        let o = rng.in_ball(15.0);
        let d = rng.in_ball(10.0) - o;
        let inv = Ray::new(o, d).inv_dir();
        // A limit that shrinks as items are offered, as a nearest-hit search's does.
        let walk = |bvh: &Bvh| {
            let mut seen = Vec::new();
            let mut limit = 40.0;
            bvh.traverse(o, inv, limit, |slot| {
                seen.push(slot);
                limit *= 0.9;
                ControlFlow::Continue(limit)
            });
            seen
        };
        let seen = walk(&plain);
        assert_eq!(seen, walk(&wide), "ray {o:?} {d:?}");
        offered += seen.len();
    }
    assert!(offered > 1000, "{offered}");
}
