//! A bounding volume hierarchy over axis-aligned boxes: it answers "which items might this
//! ray meet before `t`", nearest boxes first, so that a scene of many bounded solids costs
//! about `log n` box tests per ray instead of `n` intersection tests.
//!
//! **What it is for.** [`crate::world::Scene`] builds one over its *bounded* solids (lone
//! objects and CSG trees with a finite box) when there are enough of them to gain
//! ([`crate::world::BVH_MIN_PRIMS`]). The tree is built once, top-down with the surface area
//! heuristic over [`BINS`] centroid bins (Wald 2007; pbrt §4.3.2), and stored as a flat array
//! in depth-first order (a node's first child follows it). Traversal is iterative with a
//! fixed stack, visits the nearer child first, and skips a subtree whose box starts beyond
//! the caller's current limit, so a nearest-hit query stops opening boxes once it has a hit
//! closer than everything left on the stack.
//!
//! **What it is not.** It knows nothing of shapes, hits or ties: items are caller indices,
//! and the caller's callback tests them and says how far the search still has to go. Every
//! answer is the caller's; the tree only decides which items are *not* worth asking, and it
//! only ever drops items whose (slightly enlarged) box the ray cannot enter before the limit,
//! so an item that would be hit before the limit is always offered. It does not hold
//! unbounded solids (planes, unbounded CSG): those are the caller's to test every time. It
//! is not refitted or updated; a changed scene builds a new one.

use std::ops::ControlFlow;

use glam::DVec3;

use crate::math::Aabb;

/// Centroid bins per axis for the SAH split search. 16 is the usual choice: finer binning
/// barely changes tree quality (Wald 2007) and costs build time.
pub const BINS: usize = 16;

/// Deepest leaf the builder makes; deeper subtrees become (larger) leaves. Binned SAH on
/// sane scenes stays far shallower (≈ 2 log₂ n); the cap only bounds pathological inputs
/// (exponentially spaced centroids) so the fixed traversal stack can never overflow.
pub const MAX_DEPTH: usize = 60;

/// Traversal stack: one pending far child per level at most, plus the root.
const STACK: usize = MAX_DEPTH + 2;

/// Leaves at most this large are always accepted; larger ones only when no split is
/// cheaper by the SAH or the items cannot be separated (coincident centroids).
const LEAF_MIN: usize = 2;

/// Cost of one node visit (two box tests) relative to one item test in the SAH. An item
/// test (carrying the ray into object space, solving the shape) costs several box tests.
const TRAVERSAL_COST: f64 = 0.5;

/// Relative enlargement of every item box, and of the search limit when boxes are culled.
///
/// A hit is computed in the item's own space and reported as a world `t`; rounding can put
/// that `t` a few ulps (of the size of the numbers involved, ≈ 1e-16 relative) beyond the
/// exact surface, and so a hair outside the exact box; the slab test itself rounds too. The
/// boxes are enlarged by 1e-7 of their own coordinates' magnitude and the limit by 1e-7 of
/// itself, which covers such errors by eight orders of magnitude (a ray would have to start
/// ~1e8 box-sizes away for its rounding to reach it), while enlarging boxes by so little that
/// culling is not measurably weaker. Enlarging only ever makes more items candidates, so it
/// can never change an answer, only keep one from being lost.
pub const SLACK: f64 = 1e-7;

/// One node of the flattened tree.
#[derive(Debug, Clone, Copy)]
struct Node {
    bounds: Aabb,
    /// Interior node: index of the second child (the first is the next node). Leaf: index of
    /// its first item in [`Bvh::items`].
    index: u32,
    /// Number of items of a leaf; 0 for an interior node.
    count: u32,
}

/// A bounding volume hierarchy over caller items (indices with boxes).
#[derive(Debug, Clone, Default)]
pub struct Bvh {
    nodes: Vec<Node>,
    items: Vec<u32>,
}

/// An item during the build: its id, enlarged box and centroid.
#[derive(Debug, Clone, Copy)]
struct BuildItem {
    id: u32,
    bounds: Aabb,
    centroid: DVec3,
}

/// The enlarged box of an item: every face moved out by [`SLACK`] of the box's largest
/// coordinate magnitude and extent. `None` for a box that is empty or not finite, which
/// the caller must then test every time.
pub fn padded(b: &Aabb) -> Option<Aabb> {
    if b.is_empty() || !b.min.is_finite() || !b.max.is_finite() {
        return None;
    }
    let size = b.min.abs().max(b.max.abs()).max_element() + (b.max - b.min).max_element();
    let pad = DVec3::splat(size * SLACK);
    let p = Aabb::new(b.min - pad, b.max + pad);
    // Overflow to ±∞ (a box near f64::MAX) would make a useless node; treat as unbounded.
    (p.min.is_finite() && p.max.is_finite()).then_some(p)
}

impl Bvh {
    /// Builds the tree over `(id, box)` pairs. Boxes are enlarged with [`padded`]; items
    /// whose box is empty or not finite are left out and returned, for the caller to test
    /// every time.
    pub fn build(items: &[(u32, Aabb)]) -> (Bvh, Vec<u32>) {
        let mut build = Vec::with_capacity(items.len());
        let mut left_out = Vec::new();
        for &(id, b) in items {
            match padded(&b) {
                Some(bounds) => build.push(BuildItem {
                    id,
                    bounds,
                    centroid: bounds.centroid(),
                }),
                None => left_out.push(id),
            }
        }
        let mut bvh = Bvh {
            nodes: Vec::with_capacity(2 * build.len()),
            items: Vec::with_capacity(build.len()),
        };
        if !build.is_empty() {
            bvh.build_node(&mut build, 0);
        }
        (bvh, left_out)
    }

    /// The item ids in the tree's own order: a leaf's items are consecutive. The slots
    /// [`Self::traverse`] reports index this, so a caller can keep data it tests often in
    /// the same order, where a leaf's items share cache lines.
    pub fn items(&self) -> &[u32] {
        &self.items
    }

    /// Number of items in the tree.
    pub fn len(&self) -> usize {
        self.items.len()
    }

    pub fn is_empty(&self) -> bool {
        self.items.is_empty()
    }

    /// Number of nodes (for tests and statistics).
    pub fn node_count(&self) -> usize {
        self.nodes.len()
    }

    /// Depth of the deepest leaf (the root is depth 0).
    pub fn depth(&self) -> usize {
        fn go(nodes: &[Node], i: usize) -> usize {
            let n = &nodes[i];
            if n.count > 0 {
                0
            } else {
                1 + go(nodes, i + 1).max(go(nodes, n.index as usize))
            }
        }
        if self.nodes.is_empty() {
            0
        } else {
            go(&self.nodes, 0)
        }
    }

    /// Appends the node for `items` (and its subtree); returns its index.
    fn build_node(&mut self, items: &mut [BuildItem], depth: usize) -> usize {
        let bounds = items
            .iter()
            .fold(Aabb::EMPTY, |acc, it| acc.union(&it.bounds));
        let here = self.nodes.len();
        self.nodes.push(Node {
            bounds,
            index: 0,
            count: 0,
        });
        let split = if items.len() <= LEAF_MIN || depth >= MAX_DEPTH {
            None
        } else {
            sah_split(items, &bounds)
        };
        match split {
            None => {
                // `as u32`: item counts fit, the scene refuses more than u32::MAX objects.
                self.nodes[here].index = self.items.len() as u32;
                self.nodes[here].count = items.len() as u32;
                self.items.extend(items.iter().map(|it| it.id));
            }
            Some(mid) => {
                let (left, right) = items.split_at_mut(mid);
                self.build_node(left, depth + 1);
                let second = self.build_node(right, depth + 1);
                self.nodes[here].index = second as u32;
            }
        }
        here
    }

    /// Calls `test` with the slot (index into [`Self::items`]) of every item whose box the ray (`origin`, `inv_dir` from
    /// [`crate::math::Ray::inv_dir`]) enters with `0 ≤ t ≤ limit`, nearest boxes first,
    /// skipping subtrees that start beyond the limit. `test` returns the new limit (the
    /// search only ever narrows, so it must not grow), or `Break` to stop at once (an
    /// any-hit query). Returns whether `test` broke off.
    ///
    /// A box starting exactly at the limit is still visited (`≤`): the caller may have to
    /// see an item hit at the very same `t` as its current best, to break the tie by its own
    /// rule.
    #[inline]
    pub fn traverse(
        &self,
        origin: DVec3,
        inv_dir: DVec3,
        mut limit: f64,
        mut test: impl FnMut(usize) -> ControlFlow<(), f64>,
    ) -> bool {
        if self.nodes.is_empty() {
            return false;
        }
        // The culling limit, enlarged by SLACK (see there). `limit` is ≥ 0 or +∞, so this
        // only ever grows it, and ∞ stays ∞.
        let loose = |l: f64| l + l * SLACK;
        let mut stack = [(0u32, 0.0f64); STACK];
        let Some((t0, _)) = self.nodes[0]
            .bounds
            .hit_interval(origin, inv_dir, loose(limit))
        else {
            return false;
        };
        stack[0] = (0, t0);
        let mut sp = 1;
        while sp > 0 {
            sp -= 1;
            let (mut at, t_enter) = stack[sp];
            if t_enter > loose(limit) {
                continue;
            }
            loop {
                let node = &self.nodes[at as usize];
                if node.count > 0 {
                    let first = node.index as usize;
                    for slot in first..first + node.count as usize {
                        match test(slot) {
                            ControlFlow::Break(()) => return true,
                            ControlFlow::Continue(l) => limit = l,
                        }
                    }
                    break;
                }
                let (a, b) = (at + 1, node.index);
                let l = loose(limit);
                let ea = self.nodes[a as usize]
                    .bounds
                    .hit_interval(origin, inv_dir, l);
                let eb = self.nodes[b as usize]
                    .bounds
                    .hit_interval(origin, inv_dir, l);
                match (ea, eb) {
                    (Some((ta, _)), Some((tb, _))) => {
                        let (near, far, t_far) = if ta <= tb { (a, b, tb) } else { (b, a, ta) };
                        // Cannot overflow: the builder caps the depth at MAX_DEPTH, and each
                        // level leaves at most one far child on the stack.
                        stack[sp] = (far, t_far);
                        sp += 1;
                        at = near;
                    }
                    (Some(_), None) => at = a,
                    (None, Some(_)) => at = b,
                    (None, None) => break,
                }
            }
        }
        false
    }
}

/// The best SAH split of `items` (which it partitions): the number of items that go left,
/// or `None` when a leaf is cheaper or the items cannot be told apart by their centroids.
fn sah_split(items: &mut [BuildItem], bounds: &Aabb) -> Option<usize> {
    let cb = items
        .iter()
        .fold(Aabb::EMPTY, |acc, it| acc.grow(it.centroid));
    let extent = cb.max - cb.min;
    let axis = if extent.x >= extent.y && extent.x >= extent.z {
        0
    } else if extent.y >= extent.z {
        1
    } else {
        2
    };
    // All centroids equal (coincident solids): no plane separates them.
    if !(extent[axis] > 0.0) {
        return None;
    }
    let (lo, scale) = (cb.min[axis], BINS as f64 / extent[axis]);
    // `as usize` saturates, and the `min` keeps the maximum centroid in the last bin.
    let bin_of = |it: &BuildItem| (((it.centroid[axis] - lo) * scale) as usize).min(BINS - 1);
    let mut counts = [0usize; BINS];
    let mut boxes = [Aabb::EMPTY; BINS];
    for it in items.iter() {
        let b = bin_of(it);
        counts[b] += 1;
        boxes[b] = boxes[b].union(&it.bounds);
    }
    // Sweep from the right: area × count of everything right of each plane.
    let mut right_cost = [0.0f64; BINS];
    let (mut acc, mut n) = (Aabb::EMPTY, 0usize);
    for i in (1..BINS).rev() {
        acc = acc.union(&boxes[i]);
        n += counts[i];
        right_cost[i] = acc.surface_area() * n as f64;
    }
    let (mut acc, mut n) = (Aabb::EMPTY, 0usize);
    let mut best: Option<(f64, usize)> = None;
    for i in 0..BINS - 1 {
        acc = acc.union(&boxes[i]);
        n += counts[i];
        // A plane with nothing on one side is no split at all.
        if n == 0 || n == items.len() {
            continue;
        }
        let cost = acc.surface_area() * n as f64 + right_cost[i + 1];
        if best.is_none_or(|(c, _)| cost < c) {
            best = Some((cost, i));
        }
    }
    let (cost, plane) = best?;
    let area = bounds.surface_area();
    let leaf_cost = items.len() as f64;
    let split_cost = TRAVERSAL_COST + cost / area;
    // Keep a leaf when it is cheaper, unless it would be large: a large leaf costs every ray
    // that enters it all its tests, and a split is then worth it for the rays it spares.
    if split_cost >= leaf_cost && items.len() <= 8 && area > 0.0 {
        return None;
    }
    let mut mid = 0;
    for j in 0..items.len() {
        if bin_of(&items[j]) <= plane {
            items.swap(mid, j);
            mid += 1;
        }
    }
    // Both sides are non-empty by the choice of plane, as the bin counts say.
    (mid > 0 && mid < items.len()).then_some(mid)
}

#[cfg(test)]
mod tests {
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
}
