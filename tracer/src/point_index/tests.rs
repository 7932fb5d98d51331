use super::*;
use crate::shape::test_support::Rng;

/// Whether the table, asked for direction `w`, offers `prim` (or leaves the question to
/// the BVH, or tests it every time).
fn offers(t: &PointIndex, w: DVec3, prim: u32) -> bool {
    t.always().contains(&prim) || t.lookup(w).is_none_or(|l| l.iter().any(|e| e.prim == prim))
}

/// A point of the box: inside, on a face, an edge or a corner.
fn point_in(rng: &mut Rng, b: &Aabb) -> DVec3 {
    let mut p = DVec3::ZERO;
    for k in 0..3 {
        p[k] = match rng.next_u64() % 4 {
            0 => b.min[k],
            1 => b.max[k],
            _ => rng.range(b.min[k], b.max[k]),
        };
    }
    p
}

fn random_boxes(rng: &mut Rng, n: usize, point: DVec3) -> Vec<(u32, Aabb, f64)> {
    (0..n as u32)
        .map(|i| {
            // Small and large boxes, some on the point's axis planes or around it, some
            // centred on a cube edge or corner direction from it.
            let c = match rng.next_u64() % 5 {
                0 => point + DVec3::splat(rng.range(-5.0, 5.0)),
                1 => point + DVec3::new(rng.range(-5.0, 5.0), 0.0, rng.range(-5.0, 5.0)),
                2 => point + DVec3::new(rng.range(-5.0, 5.0), rng.range(-5.0, 5.0), 0.0),
                _ => point + rng.in_ball(20.0),
            };
            let h = DVec3::new(rng.unit(), rng.unit(), rng.unit())
                * [1e-4, 0.01, 0.5, 3.0][(rng.next_u64() % 4) as usize];
            (i, Aabb::new(c - h, c + h), 1.0)
        })
        .collect()
}

#[test]
fn every_direction_into_a_box_is_offered_it() {
    let mut rng = Rng::new(41);
    let (mut listed, mut looked_up) = (0, 0);
    for round in 0..40 {
        let point = [DVec3::ZERO, rng.in_ball(1e3), DVec3::new(1e6, -3.0, 0.25)][round % 3];
        let items = random_boxes(&mut rng, [10, 200, 2000][round % 3], point);
        let t = PointIndex::build(point, &items, MAX_ENTRIES).expect("a table");
        for _ in 0..4000 {
            let (prim, b, _) = items[(rng.next_u64() % items.len() as u64) as usize];
            let q = point_in(&mut rng, &b);
            let w = q - point;
            if w == DVec3::ZERO {
                continue;
            }
            assert!(
                offers(&t, w, prim),
                "round {round}: {w:?} into {b:?} not offered"
            );
            if let Some(l) = t.lookup(w) {
                looked_up += 1;
                listed += l.len();
            }
        }
    }
    // The lists are short (the point of the table): about two solids a lookup here.
    assert!(looked_up > 100_000, "{looked_up} lookups answered");
    assert!(
        listed < 8 * looked_up,
        "{listed} listed over {looked_up} lookups"
    );
}

#[test]
fn lists_are_sorted_by_a_lower_bound_of_the_distance() {
    let mut rng = Rng::new(7);
    let point = DVec3::new(0.5, -2.0, 3.0);
    let items = random_boxes(&mut rng, 500, point);
    let t = PointIndex::build(point, &items, MAX_ENTRIES).expect("a table");
    for &(s, l) in &t.cells {
        if l == FALLBACK {
            continue;
        }
        let list = &t.entries[s as usize..(s + l) as usize];
        assert!(list.windows(2).all(|w| w[0].near_sq <= w[1].near_sq));
        for e in list {
            let b = items[e.prim as usize].1;
            // The box's nearest point, computed directly.
            let nearest = point.clamp(b.min, b.max);
            let exact = (nearest - point).length_squared();
            assert!(f64::from(e.near_sq) <= exact);
            assert!(f64::from(e.near_sq) >= exact * (1.0 - 1e-6));
        }
    }
}

#[test]
fn boxes_around_or_beside_the_point_are_tested_every_time() {
    let point = DVec3::new(1.0, 2.0, 3.0);
    let mut items: Vec<(u32, Aabb, f64)> = (0..100)
        .map(|i| {
            let c = point + DVec3::new(f64::from(i) - 50.0, 7.0, 0.0);
            (i, Aabb::new(c - 0.1, c + 0.1), 1.0)
        })
        .collect();
    // One box holds the point, one touches it at a corner.
    items.push((100, Aabb::new(point - 1.0, point + 2.0), 1.0));
    items.push((101, Aabb::new(point, point + 0.5), 1.0));
    let t = PointIndex::build(point, &items, MAX_ENTRIES).expect("a table");
    assert_eq!(t.always(), &[100, 101]);
    for e in &t.entries {
        assert!(e.prim < 100);
    }
}

#[test]
fn a_table_over_its_budget_is_built_coarser_or_not_at_all() {
    let mut rng = Rng::new(19);
    let items = random_boxes(&mut rng, 2000, DVec3::ZERO);
    let full = PointIndex::build(DVec3::ZERO, &items, MAX_ENTRIES).expect("a table");
    let (cells, entries) = full.size();
    let coarse = PointIndex::build(DVec3::ZERO, &items, entries / 2).expect("a coarser one");
    assert!(coarse.size().0 < cells && coarse.size().1 <= entries / 2);
    // Still sound: every direction into a box is offered it.
    for _ in 0..2000 {
        let (prim, b, _) = items[(rng.next_u64() % items.len() as u64) as usize];
        let w = point_in(&mut rng, &b);
        assert!(w == DVec3::ZERO || offers(&coarse, w, prim));
    }
    assert!(PointIndex::build(DVec3::ZERO, &items, 100).is_none());
}

#[test]
fn zero_infinite_and_nan_directions_take_the_tree() {
    let mut rng = Rng::new(3);
    let items = random_boxes(&mut rng, 50, DVec3::ZERO);
    let t = PointIndex::build(DVec3::ZERO, &items, MAX_ENTRIES).expect("a table");
    for w in [
        DVec3::ZERO,
        DVec3::new(-0.0, 0.0, -0.0),
        DVec3::new(f64::INFINITY, 1.0, 0.0),
        DVec3::new(1.0, f64::NAN, 0.0),
        DVec3::new(f64::NAN, f64::NAN, f64::NAN),
    ] {
        assert!(t.lookup(w).is_none(), "{w:?}");
    }
    // A direction so small that 1/|w_i| overflows, or so large that squared lengths along
    // it overflow, is the BVH's too.
    for w in [
        DVec3::new(3e-309, 6e-311, 0.0),
        DVec3::X * 1e-78,
        DVec3::X * 1e78,
    ] {
        assert!(t.lookup(w).is_none(), "{w:?}");
    }
    // ±0 components and exact cube-edge directions are ordinary directions.
    for w in [
        DVec3::new(1.0, -0.0, 0.0),
        DVec3::new(-1.0, 1.0, 1.0),
        DVec3::X * 1e-70,
    ] {
        assert!(t.lookup(w).is_some(), "{w:?}");
    }
}

#[test]
fn cells_that_cost_more_than_a_walk_take_the_tree() {
    // Forty boxes one behind the other along +x: the cell that sees them all lists
    // more than CELL_COST_MAX, the cells beside them nothing.
    let items: Vec<(u32, Aabb, f64)> = (0..40)
        .map(|i| {
            let c = DVec3::new(2.0 + f64::from(i), 0.0, 0.0);
            (i, Aabb::new(c - 0.2, c + 0.2), 1.0)
        })
        .collect();
    let t = PointIndex::build(DVec3::ZERO, &items, MAX_ENTRIES).expect("a table");
    assert!(t.lookup(DVec3::X).is_none());
    // At the rim of the nearest box only the nearest few are listed.
    let rim = t.lookup(DVec3::new(1.0, 0.1, 0.0)).expect("a short list");
    assert!(!rim.is_empty() && rim.len() < 16, "{rim:?}");
}

/// A shadow ray from far away misses its light by the rounding of `L − o`, which can be
/// far more than a box near the light is wide: seen from the light, a box on the ray can
/// lie in another direction than `−d`, and the table must not be asked.
#[test]
fn a_shadow_ray_from_far_away_is_not_looked_up() {
    let (light, o) = (DVec3::new(0.3, 0.7, 0.1), DVec3::new(-1e15, -1e15, 0.0));
    let d = light - o;
    // `fl(L − o)` rounds x down and y up: the ray passes (−0.05, 0.05, 0) from the light,
    // and `−d` lies on the −y face.
    assert_eq!(d, DVec3::new(1e15 + 0.25, 1e15 + 0.75, 0.1));
    // In exact arithmetic `o + (1 − τ)·d = (0.25, 0.75, 0.1) − τ·d`: at τ = 4·10⁻¹⁴ the
    // ray is within 10⁻¹³ of (−39.75, −39.25, 0.1), inside this box.
    let q = DVec3::new(-39.75, -39.25, 0.1);
    let blocker = Aabb::new(q - 0.01, q + 0.01);
    // Filler boxes around the light, so that the table has cells everywhere.
    let mut rng = Rng::new(5);
    let mut items = vec![(0, blocker, 1.0)];
    items.extend((1..2000).map(|i| {
        let c = light + rng.direction() * rng.range(5.0, 40.0);
        (i, Aabb::new(c - 0.005, c + 0.005), 1.0)
    }));
    let t = PointIndex::build(light, &items, MAX_ENTRIES).expect("a table");
    assert!(offers(&t, q - light, 0));
    // Looked up, the cell of −d would not offer the blocker...
    assert!(!offers(&t, -d, 0), "the test no longer shows the rounding");
    // ... so such a ray takes the tree, while a ray from nearby is looked up.
    assert!(!t.shadow_lookup_ok(d));
    assert!(t.shadow_lookup_ok(light - DVec3::new(30.0, -20.0, 5.0)));
}
