//! A bounding volume hierarchy over axis-aligned boxes: it answers "which items might this
//! ray meet before `t`", nearest boxes first, so that a scene of many bounded solids costs
//! about `log n` box tests per ray instead of `n` intersection tests.
//!
//! **What it is for.** [`crate::world::Scene`] builds one over its *bounded* solids (lone
//! objects and CSG trees with a finite box) when there are enough of them to gain
//! ([`crate::bvh::BVH_MIN_PRIMS`]). The tree is built once, top-down with the surface area
//! heuristic over [`BINS`] centroid bins on each of the three axes (Wald 2007; pbrt §4.3.2),
//! each item weighted by what testing it costs, and stored as a flat array of interior
//! nodes in depth-first order. Each node has up to four children, the two levels of binary
//! SAH splits below it (Wald, Benthin, Boulos 2008: a wide node per two binary levels), and
//! holds all four children's boxes (in `f32`, rounded outwards: 128 bytes, two cache lines),
//! so a visit is one four-lane slab test in `f64`: with AVX2, where the CPU has it (checked at
//! run time), one 256-bit register per quantity; otherwise the same arithmetic lane by lane,
//! with the same bits. Traversal is iterative with a fixed stack, goes to the nearest child
//! first, and skips a subtree whose box starts beyond the caller's current limit, so a
//! nearest-hit query stops opening boxes once it has a hit closer than everything left on
//! the stack.
//!
//! **What it is not.** It knows nothing of shapes, hits or ties: items are caller indices,
//! and the caller's callback tests them and says how far the search still has to go. Every
//! answer is the caller's; the tree only decides which items are *not* worth asking, and it
//! only ever drops items whose (slightly enlarged) box the ray cannot enter before the limit,
//! so an item that would be hit before the limit is always offered. It does not hold
//! unbounded solids (planes, unbounded CSG): those are the caller's to test every time. It
//! is not refitted or updated; a changed scene builds a new one.

use std::ops::ControlFlow;

use arrayvec::ArrayVec;
use glam::DVec3;

use crate::math::{Aabb, gamma};

/// Centroid bins per axis for the SAH split search. 16 is the usual choice: finer binning
/// barely changes tree quality (Wald 2007) and costs build time.
pub const BINS: usize = 16;

/// Deepest interior node the builder makes; a subtree that would go deeper becomes a
/// (larger) leaf. Binned SAH on sane scenes stays far shallower (≈ 2 log₂ n); the cap only
/// bounds pathological inputs (exponentially spaced centroids) so that the fixed traversal
/// stack can never overflow.
pub const MAX_DEPTH: usize = 60;

/// Children of an interior node: the lanes of its slab test.
const WIDTH: usize = 4;

/// Traversal stack: at most `WIDTH − 1` pending siblings per interior level of the current
/// path, and no path has more than `MAX_DEPTH` interior levels (each wide level is at least
/// one binary split, and the builder caps those).
const STACK: usize = (WIDTH - 1) * MAX_DEPTH + 1;

/// Leaves at most this large are made whenever the SAH says a split does not pay; larger
/// sets are split whenever their centroids can be told apart, since every ray that enters a
/// leaf pays for all its items.
pub const LEAF_MAX: usize = 8;

/// Cost of visiting a binary interior node (a two-way split) in the
/// SAH, the unit in which item costs ([`Item::cost`]) are given.
pub const NODE_COST: f64 = 1.0;

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

/// Widening of a slab's far distance (pbrt §3.9.2): `(b − o)·(1/d)` is two roundings off
/// the exact `(b − o)/d` and `1/d` one more, so the computed far distance is within `γ(3)`
/// of the true one; `1 + 2γ(3)` covers it with room to spare.
const FAR_WIDEN: f64 = 1.0 + 2.0 * gamma(3);

/// One item to build the tree over.
#[derive(Debug, Clone, Copy)]
pub struct Item {
    /// The caller's id, reported back through [`Bvh::items`]. Several items may share an
    /// id (pieces of one long object, each with its own box): the caller is then offered it
    /// once per piece the ray enters, and must give the same answer each time.
    pub id: u32,
    pub bounds: Aabb,
    /// What testing the item costs, in units of [`NODE_COST`]; the SAH weighs leaves by it.
    pub cost: f64,
}

/// A child of an interior node, or the root: an interior node (`count == 0`, `index` into
/// [`Bvh::nodes`]) or a leaf (`count` items from slot `index` of [`Bvh::items`]).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
struct Child {
    index: u32,
    count: u32,
}

impl Child {
    /// The child of a lane that has none (its box is empty, so traversal never reaches it).
    const NONE: Child = Child {
        index: u32::MAX,
        count: 0,
    };

    fn is_none(self) -> bool {
        self == Child::NONE
    }
}

/// An interior node: the boxes of its children (two to four), side by side so that one
/// four-lane pass of the slab test answers for all of them.
///
/// `b[0]` holds the minima and `b[1]` the maxima, each as `[axis][child]`. The corners are
/// stored as `f32`, rounded *outwards* from the `f64` boxes (see [`round_out`]), so a stored
/// box always contains the `f64` one and culling stays conservative; the slab test widens
/// them back to `f64`, exactly, and does its arithmetic there. A lane without a child holds
/// the empty box (`+∞` minima, `−∞` maxima), which no ray enters.
#[derive(Debug, Clone, Copy)]
#[repr(C, align(64))]
struct Node {
    b: [[[f32; WIDTH]; 3]; 2],
    child: [Child; WIDTH],
}

/// A bounding volume hierarchy over caller items (indices with boxes).
#[derive(Debug, Clone)]
pub struct Bvh {
    /// Interior nodes in depth-first order: a node's first child, when interior, follows it.
    nodes: Vec<Node>,
    items: Vec<u32>,
    root: Child,
    /// Box of the whole tree (padded, `f64`), tested once per ray.
    root_bounds: Aabb,
    /// Whether traversal runs the AVX2 build of the slab test: set where the CPU has AVX2.
    avx2: bool,
}

impl Default for Bvh {
    /// The empty tree: every query returns at once.
    fn default() -> Bvh {
        Bvh {
            nodes: Vec::new(),
            items: Vec::new(),
            root: Child::default(),
            root_bounds: Aabb::EMPTY,
            avx2: has_avx2(),
        }
    }
}

/// Whether this CPU runs AVX2 (always `false` off x86-64).
fn has_avx2() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx2")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// An item during the build: its id, enlarged box, centroid and cost.
#[derive(Debug, Clone, Copy)]
struct BuildItem {
    id: u32,
    bounds: Aabb,
    centroid: DVec3,
    cost: f64,
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

/// `x` as an `f32` no greater (`up = false`) or no less (`up = true`) than `x`.
///
/// `as f32` rounds to nearest (and saturates to ±∞ beyond `f32::MAX`, which only ever lies
/// further out); the result is then stepped one `f32` ulp outwards if it fell on the wrong
/// side. The comparison is exact (`f32 → f64` is), so the result bounds `x` in every case:
/// subnormal results step to the next subnormal or through zero to `∓f32::from_bits(1)`.
pub fn round_out(x: f64, up: bool) -> f32 {
    let r = x as f32;
    if up && f64::from(r) < x {
        r.next_up()
    } else if !up && f64::from(r) > x {
        r.next_down()
    } else {
        r
    }
}

/// A ray prepared for the four-lane slab test: origin, `1/d`, and per axis which of a box's
/// two planes it meets first (`0`: the minimum, for `1/d ≥ +0`; `1`: the maximum).
///
/// [`crate::math::Ray::inv_dir`] has turned `−0` components into `+0`, so a zero direction
/// component gives `1/d = +∞` and picks the minimum as near plane, which is what
/// [`Aabb::hit_interval`]'s swap picks too (it swaps only when `near > far`, never for a
/// NaN). Choosing by sign instead of comparing gives the same two numbers without a
/// data-dependent branch per box.
#[derive(Debug, Clone, Copy)]
struct SlabRay {
    origin: [f64; 3],
    inv: [f64; 3],
    near: [usize; 3],
}

impl SlabRay {
    #[inline]
    fn new(origin: DVec3, inv_dir: DVec3) -> SlabRay {
        let near = |i: f64| usize::from(i < 0.0);
        SlabRay {
            origin: origin.to_array(),
            inv: inv_dir.to_array(),
            near: [near(inv_dir.x), near(inv_dir.y), near(inv_dir.z)],
        }
    }
}

impl Node {
    /// The node over `children` (two to four) with their boxes; lanes past them hold the
    /// empty box.
    fn new(bounds: &[Aabb], child: &[Child]) -> Node {
        debug_assert!(bounds.len() == child.len() && child.len() <= WIDTH);
        let mut b = [[[f32::INFINITY; WIDTH]; 3], [[f32::NEG_INFINITY; WIDTH]; 3]];
        for (c, bb) in bounds.iter().enumerate() {
            for (a, (lo, hi)) in bb
                .min
                .to_array()
                .into_iter()
                .zip(bb.max.to_array())
                .enumerate()
            {
                b[0][a][c] = round_out(lo, false);
                b[1][a][c] = round_out(hi, true);
            }
        }
        let mut children = [Child::NONE; WIDTH];
        children[..child.len()].copy_from_slice(child);
        Node { b, child: children }
    }

    /// The slab test of every lane's box against `[0, limit]`: for each, whether the ray
    /// enters it there, and its entry distance.
    ///
    /// Per lane this is [`Aabb::hit_interval`] with the near plane chosen by the ray's sign
    /// (see [`SlabRay`]): the same products, so the same treatment of the special values.
    /// A zero direction component gives `±∞` distances of the right signs, so the slab
    /// either constrains nothing or rejects everything; an origin exactly in a plane with
    /// a zero component gives `0·∞ = NaN`, which fails both comparisons and leaves the
    /// interval alone (the ray lies in the closed slab for every `t`); an empty box (a
    /// minimum above its maximum) gives `near > far` along that axis and so no hit.
    ///
    /// The lanes are independent and every step is one IEEE operation (a widening, a
    /// subtraction, products, and selects that keep the old value unless the comparison
    /// holds, which is exactly `maxpd`/`minpd` with the new value first), so the compiler's
    /// four-wide AVX2 version gives the same bits as this code run lane by lane.
    #[inline(always)]
    fn hit(&self, r: &SlabRay, limit: f64) -> ([bool; WIDTH], [f64; WIDTH]) {
        let mut t0 = [0.0f64; WIDTH];
        let mut t1 = [limit; WIDTH];
        for a in 0..3 {
            let near = &self.b[r.near[a]][a];
            let far = &self.b[1 - r.near[a]][a];
            for c in 0..WIDTH {
                let tn = (f64::from(near[c]) - r.origin[a]) * r.inv[a];
                let tf = (f64::from(far[c]) - r.origin[a]) * r.inv[a] * FAR_WIDEN;
                t0[c] = if tn > t0[c] { tn } else { t0[c] };
                t1[c] = if tf < t1[c] { tf } else { t1[c] };
            }
        }
        (std::array::from_fn(|c| t0[c] <= t1[c]), t0)
    }
}

impl Bvh {
    /// Builds the tree over `(id, box)` pairs, each of unit cost. Boxes are enlarged with
    /// [`padded`]; items whose box is empty or not finite are left out and returned, for
    /// the caller to test every time.
    pub fn build(items: &[(u32, Aabb)]) -> (Bvh, Vec<u32>) {
        let items: Vec<Item> = items
            .iter()
            .map(|&(id, bounds)| Item {
                id,
                bounds,
                cost: 1.0,
            })
            .collect();
        Bvh::build_items(&items)
    }

    /// Builds the tree over items with their own costs (see [`Item`]); as [`Self::build`]
    /// otherwise. A left-out id is returned once however many of its items were left out.
    pub fn build_items(items: &[Item]) -> (Bvh, Vec<u32>) {
        let mut build = Vec::with_capacity(items.len());
        let mut left_out = Vec::new();
        for it in items {
            match padded(&it.bounds) {
                Some(bounds) => build.push(BuildItem {
                    id: it.id,
                    bounds,
                    centroid: bounds.centroid(),
                    // A cost that is not a positive finite number would break the SAH's
                    // comparisons; such an item is costed as one node visit.
                    cost: if it.cost > 0.0 && it.cost.is_finite() {
                        it.cost
                    } else {
                        NODE_COST
                    },
                }),
                None => left_out.push(it.id),
            }
        }
        left_out.sort_unstable();
        left_out.dedup();
        let mut bvh = Bvh {
            nodes: Vec::with_capacity(build.len()),
            items: Vec::with_capacity(build.len()),
            ..Bvh::default()
        };
        if !build.is_empty() {
            let bounds = bounds_of(&build);
            bvh.root_bounds = bounds;
            bvh.root = bvh.build_node(&mut build, &bounds, 0);
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

    /// The same tree traversed by the AVX2 build of the slab test or by the plain one
    /// (`avx2` is ignored where the CPU has no AVX2).
    #[cfg(test)]
    fn with_avx2(mut self, avx2: bool) -> Bvh {
        self.avx2 = avx2 && has_avx2();
        self
    }

    /// Depth of the deepest leaf (a root leaf is depth 0).
    #[cfg(test)]
    pub fn depth(&self) -> usize {
        fn go(nodes: &[Node], c: Child) -> usize {
            if c.count > 0 {
                0
            } else {
                let n = &nodes[c.index as usize];
                let below = n.child.iter().filter(|c| !c.is_none());
                1 + below.map(|&c| go(nodes, c)).max().unwrap_or(0)
            }
        }
        if self.items.is_empty() {
            0
        } else {
            go(&self.nodes, self.root)
        }
    }

    /// The subtree for `items` (whose union box is `bounds`): a leaf, or an interior node
    /// appended before its children. The node's children are the two binary SAH splits
    /// below it: each half of the first split is split again where the SAH says it pays,
    /// so the leaves are exactly those of the binary tree, in the same order.
    fn build_node(&mut self, items: &mut [BuildItem], bounds: &Aabb, depth: usize) -> Child {
        let Some(mid) = split(items, bounds, depth) else {
            return self.leaf(items);
        };
        // Up to four groups, each with its box and whether it is split further.
        let mut groups: ArrayVec<(&mut [BuildItem], Aabb, bool), WIDTH> = ArrayVec::new();
        let (left, right) = items.split_at_mut(mid);
        for half in [left, right] {
            let half_bounds = bounds_of(half);
            match split(half, &half_bounds, depth + 1) {
                Some(m) => {
                    let (a, b) = half.split_at_mut(m);
                    let (ba, bb) = (bounds_of(a), bounds_of(b));
                    groups.push((a, ba, true));
                    groups.push((b, bb, true));
                }
                None => groups.push((half, half_bounds, false)),
            }
        }
        let here = self.nodes.len();
        let boxes: ArrayVec<Aabb, WIDTH> = groups.iter().map(|g| g.1).collect();
        self.nodes
            .push(Node::new(&boxes, &[Child::NONE; WIDTH][..boxes.len()]));
        let mut children: ArrayVec<Child, WIDTH> = ArrayVec::new();
        for (group, group_bounds, deeper) in groups {
            children.push(if deeper {
                self.build_node(group, &group_bounds, depth + 2)
            } else {
                self.leaf(group)
            });
        }
        self.nodes[here].child[..children.len()].copy_from_slice(&children);
        Child {
            index: here as u32,
            count: 0,
        }
    }

    /// A leaf of `items`, appended to [`Self::items`].
    fn leaf(&mut self, items: &[BuildItem]) -> Child {
        // `as u32`: item counts fit, the scene refuses more than u32::MAX objects and
        // splits each into a bounded number of pieces (see `world::Accel`).
        let leaf = Child {
            index: self.items.len() as u32,
            count: items.len() as u32,
        };
        self.items.extend(items.iter().map(|it| it.id));
        leaf
    }

    /// Calls `test` with the slot (index into [`Self::items`]) of every item whose box the
    /// ray (`origin`, `inv_dir` from [`crate::math::Ray::inv_dir`]) enters with
    /// `0 ≤ t ≤ limit`, nearest boxes first, skipping subtrees that start beyond the limit.
    /// `test` returns the new limit (the search only ever narrows, so it must not grow), or
    /// `Break` to stop at once (an any-hit query). Returns whether `test` broke off.
    ///
    /// A box starting exactly at the limit is still visited (`≤`): the caller may have to
    /// see an item hit at the very same `t` as its current best, to break the tie by its own
    /// rule.
    #[inline]
    pub fn traverse(
        &self,
        origin: DVec3,
        inv_dir: DVec3,
        limit: f64,
        test: impl FnMut(usize) -> ControlFlow<(), f64>,
    ) -> bool {
        #[cfg(target_arch = "x86_64")]
        if self.avx2 {
            // SAFETY: `avx2` is only ever true where the CPU reported AVX2 (`has_avx2`).
            return unsafe { self.traverse_avx2(origin, inv_dir, limit, test) };
        }
        self.traverse_in(origin, inv_dir, limit, test)
    }

    /// [`Self::traverse`] compiled for AVX2, with the slab test and the caller's `test`
    /// inlined into it. The same operations as [`Self::traverse_in`], so the same answers.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn traverse_avx2(
        &self,
        origin: DVec3,
        inv_dir: DVec3,
        limit: f64,
        test: impl FnMut(usize) -> ControlFlow<(), f64>,
    ) -> bool {
        self.traverse_in(origin, inv_dir, limit, test)
    }

    /// The traversal itself, for [`Self::traverse`].
    #[inline(always)]
    fn traverse_in(
        &self,
        origin: DVec3,
        inv_dir: DVec3,
        mut limit: f64,
        mut test: impl FnMut(usize) -> ControlFlow<(), f64>,
    ) -> bool {
        if self.items.is_empty() {
            return false;
        }
        // The culling limit, enlarged by SLACK (see there). `limit` is ≥ 0 or +∞, so this
        // only ever grows it, and ∞ stays ∞.
        let loose = |l: f64| l + l * SLACK;
        if self
            .root_bounds
            .hit_interval(origin, inv_dir, loose(limit))
            .is_none()
        {
            return false;
        }
        let ray = SlabRay::new(origin, inv_dir);
        // Not an array: `[(Child, f64); STACK]` would be zero-filled (976 bytes) on every
        // query, a `memset` that costs a visible share of a scene of small spheres. An
        // `ArrayVec` leaves its slots uninitialised until pushed. It cannot
        // overflow: the builder caps the interior depth at MAX_DEPTH, and each interior
        // level of the path leaves at most one entry.
        let mut stack: ArrayVec<(Child, f64), STACK> = ArrayVec::new();
        let mut at = self.root;
        'visit: loop {
            if at.count > 0 {
                let first = at.index as usize;
                for slot in first..first + at.count as usize {
                    match test(slot) {
                        ControlFlow::Break(()) => return true,
                        ControlFlow::Continue(l) => limit = l,
                    }
                }
            } else {
                let node = &self.nodes[at.index as usize];
                let (hit, t) = node.hit(&ray, loose(limit));
                // The entered children by entry distance; on a tie, in lane order.
                let mut entered: ArrayVec<(f64, Child), WIDTH> = ArrayVec::new();
                for c in 0..WIDTH {
                    if hit[c] {
                        let at = entered.iter().position(|e| t[c] < e.0);
                        entered.insert(at.unwrap_or(entered.len()), (t[c], node.child[c]));
                    }
                }
                if let Some(&(_, nearest)) = entered.first() {
                    // The others wait, the farthest deepest in the stack.
                    for &(t_enter, c) in entered[1..].iter().rev() {
                        stack.push((c, t_enter));
                    }
                    at = nearest;
                    continue 'visit;
                }
            }
            // Next pending subtree that may still start before the limit.
            loop {
                let Some((next, t_enter)) = stack.pop() else {
                    return false;
                };
                if t_enter <= loose(limit) {
                    at = next;
                    continue 'visit;
                }
            }
        }
    }
}

impl Bvh {
    /// Whether `item` answers `true` for some item whose path of boxes all pass `touches`:
    /// a query by region rather than by ray (for example "might anything lie in this
    /// capsule?"). `touches` gets the root's box and then each child box on the way down, in
    /// `f64`, each containing its subtree's (padded) item boxes; `item` gets the caller's ids
    /// of the leaves reached, and the search stops at its first `true`. Both must be
    /// conservative for the answer to be: a `false` from `touches` drops the whole subtree.
    pub fn any_item(
        &self,
        mut touches: impl FnMut(&Aabb) -> bool,
        mut item: impl FnMut(u32) -> bool,
    ) -> bool {
        if self.items.is_empty() || !touches(&self.root_bounds) {
            return false;
        }
        // At most `WIDTH − 1` pending siblings per interior level of the current path, as
        // in `traverse`, so the depth cap bounds it.
        let mut stack: ArrayVec<Child, STACK> = ArrayVec::new();
        let mut at = Some(self.root);
        loop {
            let Some(here) = at.take().or_else(|| stack.pop()) else {
                return false;
            };
            if here.count > 0 {
                let first = here.index as usize;
                if self.items[first..first + here.count as usize]
                    .iter()
                    .any(|&id| item(id))
                {
                    return true;
                }
                continue;
            }
            let node = &self.nodes[here.index as usize];
            // Children in lane order: the first one that touches is visited next, the
            // others wait on the stack in order.
            let touching: ArrayVec<Child, WIDTH> = (0..WIDTH)
                .filter(|&c| !node.child[c].is_none() && touches(&node.child_bounds(c)))
                .map(|c| node.child[c])
                .collect();
            stack.extend(touching.iter().skip(1).rev().copied());
            at = touching.first().copied();
        }
    }
}

impl Node {
    /// Child `c`'s stored box, widened back to `f64` (exactly).
    fn child_bounds(&self, c: usize) -> Aabb {
        let axis = |side: usize| {
            DVec3::new(
                f64::from(self.b[side][0][c]),
                f64::from(self.b[side][1][c]),
                f64::from(self.b[side][2][c]),
            )
        };
        Aabb::new(axis(0), axis(1))
    }
}

/// Where to split `items` (whose union box is `bounds`) at binary depth `depth`, if at all:
/// never a single item, nor below [`MAX_DEPTH`]; otherwise as the SAH says ([`sah_split`]).
fn split(items: &mut [BuildItem], bounds: &Aabb, depth: usize) -> Option<usize> {
    if items.len() <= 1 || depth >= MAX_DEPTH {
        None
    } else {
        sah_split(items, bounds)
    }
}

/// The union of the items' boxes.
fn bounds_of(items: &[BuildItem]) -> Aabb {
    items
        .iter()
        .fold(Aabb::EMPTY, |acc, it| acc.union(&it.bounds))
}

/// The best SAH split of `items` (which it partitions) over [`BINS`] centroid bins on each
/// axis: the number of items that go first, or `None` when a leaf is cheaper (and at most
/// [`LEAF_MAX`] items) or the items cannot be told apart by their centroids.
///
/// Costs are compared multiplied by the node's area (`NODE_COST·A + Σ A_side·C_side`
/// against `C_leaf·A`), so a box of zero area needs no division: it is a leaf when small
/// enough, else split like any other.
fn sah_split(items: &mut [BuildItem], bounds: &Aabb) -> Option<usize> {
    let cb = items
        .iter()
        .fold(Aabb::EMPTY, |acc, it| acc.grow(it.centroid));
    let mut best: Option<(f64, usize, usize)> = None;
    for axis in 0..3 {
        let extent = cb.max[axis] - cb.min[axis];
        // All centroids in one plane across this axis: no plane on it separates them.
        if !(extent > 0.0) {
            continue;
        }
        let (lo, scale) = (cb.min[axis], BINS as f64 / extent);
        // `as usize` saturates, and the `min` keeps the maximum centroid in the last bin.
        let bin_of = |it: &BuildItem| (((it.centroid[axis] - lo) * scale) as usize).min(BINS - 1);
        let mut counts = [0usize; BINS];
        let mut costs = [0.0f64; BINS];
        let mut boxes = [Aabb::EMPTY; BINS];
        for it in items.iter() {
            let b = bin_of(it);
            counts[b] += 1;
            costs[b] += it.cost;
            boxes[b] = boxes[b].union(&it.bounds);
        }
        // Sweep from the right: area × cost of everything right of each plane.
        let mut right = [0.0f64; BINS];
        let (mut acc, mut c) = (Aabb::EMPTY, 0.0f64);
        for i in (1..BINS).rev() {
            acc = acc.union(&boxes[i]);
            c += costs[i];
            right[i] = acc.surface_area() * c;
        }
        let (mut acc, mut c, mut n) = (Aabb::EMPTY, 0.0f64, 0usize);
        for i in 0..BINS - 1 {
            acc = acc.union(&boxes[i]);
            c += costs[i];
            n += counts[i];
            // A plane with nothing on one side is no split at all.
            if n == 0 || n == items.len() {
                continue;
            }
            let cost = acc.surface_area() * c + right[i + 1];
            if best.is_none_or(|(b, _, _)| cost < b) {
                best = Some((cost, axis, i));
            }
        }
    }
    let (cost, axis, plane) = best?;
    let area = bounds.surface_area();
    let leaf_cost: f64 = items.iter().map(|it| it.cost).sum();
    if items.len() <= LEAF_MAX && NODE_COST * area + cost >= leaf_cost * area {
        return None;
    }
    let (lo, scale) = (cb.min[axis], BINS as f64 / (cb.max[axis] - cb.min[axis]));
    let bin_of = |it: &BuildItem| (((it.centroid[axis] - lo) * scale) as usize).min(BINS - 1);
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

/// Below this many bounded prims a scene tests every prim for every ray: a BVH's box tests
/// and bookkeeping cost more than they save on a handful of solids (`tessera-bench tracer`
/// puts the break-even near eight spheres; docs/PERFORMANCE.md has the figures).
pub const BVH_MIN_PRIMS: usize = 8;

#[cfg(test)]
mod tests;
