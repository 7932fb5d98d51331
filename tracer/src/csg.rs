//! Constructive solid geometry: trees of placed primitives combined by union, intersection
//! and difference, and the one query rays make of them, "where along this line is the
//! combined solid, and whose surface bounds it there".
//!
//! Every primitive reports all its inside-intervals along the whole line
//! ([`crate::shape::Shape::spans`]), in the world ray's own parameter `t` (object-space rays
//! are not renormalised, so `t` is the same in every space). A CSG node combines its
//! children's intervals with a sweep over their end points in `t` order, keeping for each
//! child whether the line is inside it and evaluating the set operation on those states:
//! a boundary of the node is where the combined state changes. Each boundary remembers the
//! primitive surface it lies on (which gives the hit its material, normal and u,v) and
//! whether that normal must be reversed: the surface of a difference's cutter bounds the
//! result from the other side, so it shows its inside.
//!
//! **Coincident surfaces.** A cutter that shares a face with the body, or two solids that
//! touch, give crossings that are equal in exact arithmetic but differ by rounding, in either
//! order. Applied one at a time they would open a sliver of the wrong state between them,
//! and a surface would flicker in and out pixel by pixel. The rule here: crossings of
//! different children closer than [`COINCIDENT_REL`] of the ray's scale are **one event**;
//! their changes are applied together, and a boundary is reported only if the combined
//! state differs across the whole group. A child's own crossings are never one event: its
//! entry and exit bound real matter however close they are (a ray grazing the edge of a
//! box), as they do for the same shape outside a tree, so a group ends before a second
//! crossing of a child already in it. So a body face covered by a cutter face vanishes
//! (nothing is left there to see), and the shared face of two touching solids in a union
//! vanishes too (it is interior). When a group does change the state, the surface reported
//! is that of the first child (in the order written) whose own crossing in the group moves
//! the result the same way (an entering body or leaving cutter for an entry into a
//! difference, and so on), at the group's first `t`.
//!
//! **Many children.** A union or a difference with many children (a union of thousands of
//! spheres, a block with hundreds of holes) keeps a [`Bvh`] over its children's boxes
//! (`ChildIndex`): a ray evaluates only the children whose boxes its line meets, found in
//! about `log n` box tests instead of `n`, and a point is tested only against the children
//! whose boxes hold it. The index only *finds* the children the plain loop would evaluate
//! (every child whose box the line meets); they are then evaluated in the order written,
//! exactly as the loop does, so the answer is the same bit for bit. An intersection needs
//! every child, so it has no index.
//!
//! This module does not shade or own the primitives; it borrows them from the
//! [`crate::world::Scene`].

use std::cell::RefCell;

use glam::DVec3;

use crate::bvh::Bvh;
use crate::math::{Aabb, Ray};
use crate::scene::CsgOp;
use crate::shape::{Shape, Span};
use crate::world::Object;

/// Crossings of different children closer than this fraction of `|origin|/|dir| + |t|`
/// (the size of the numbers `t` was computed from, in units of `t`) are one event.
///
/// A crossing is computed to a few ulps of that scale, but a child's transform, composed
/// with the CSG's, adds its own rounding (of the size of the coordinates, wherever the tree
/// stands), and at an angle θ to the surface an error in position becomes an error in `t`
/// larger by 1/cos θ. 1e-12 leaves about 10⁴ ulps of room for those: a face seen at 89.9°
/// still merges with its coincident copy, with room to spare (the coincidence tests pass
/// down to 1e-15).
///
/// **Why no larger.** The tolerance is real geometry lost: a pocket, a gap or a wall thinner
/// than it is merged away. It was 1e-10, which was invisible near the world origin (4e-9
/// of a unit for a camera 40 units out) but not far from it, where `|origin|` dominates: a
/// scene at 1e9 lost its 0.05-deep pockets (the tolerance was 0.1 of a unit there), and a
/// union at 1e10 showed the wrong child's surface, while lone objects rendered exactly as at
/// the origin. At 1e-12 the same scenes keep pockets, gaps and walls down to 1e-3 of a unit
/// at 1e9 and 1e-2 at 1e10 (`tests/numerics.rs` renders them moved there and compares).
pub const COINCIDENT_REL: f64 = 1e-12;

/// Which primitive surface a CSG boundary lies on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Surface {
    /// Index into [`crate::world::Scene::objects`].
    pub object: u32,
    /// The face of that primitive's shape.
    pub face: u8,
    /// Whether the combined solid lies on the primitive's outer side here (a cutter's face),
    /// so that its outward normal must be reversed.
    pub flip: bool,
}

/// One end of a [`CsgSpan`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Boundary {
    pub t: f64,
    pub surface: Surface,
}

/// An interval of the ray parameter inside a CSG solid.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CsgSpan {
    pub enter: Boundary,
    pub exit: Boundary,
}

/// A solid in the world: one primitive, or a CSG combination.
#[derive(Debug, Clone)]
pub enum Prim {
    /// Index into [`crate::world::Scene::objects`].
    Object(u32),
    Csg(Csg),
}

/// A CSG node: a set operation over two or more children.
#[derive(Debug, Clone)]
pub struct Csg {
    pub op: CsgOp,
    pub children: Vec<Prim>,
    /// World bounds of the combined solid; `None` when unbounded.
    pub bounds: Option<Aabb>,
    /// Each child's bounds enlarged for [`line_meets`] (computed once here rather than on
    /// every ray); `None` for an unbounded child, which is always evaluated.
    line_boxes: Vec<Option<Aabb>>,
    /// Balls that every line meeting the solid meets (see [`Ball`]): tested before the box
    /// and the tree. Empty when none is known.
    balls: Vec<Ball>,
    /// The children's BVH, for a union or difference with many children (see the module
    /// comment); `None` when every child is tried in turn. Boxed: most trees have none, and
    /// a [`Prim`] stays small.
    index: Option<Box<ChildIndex>>,
}

/// A union or difference with at least this many children it can index (every child of a
/// union, the cutters of a difference) finds the ones a ray meets through a [`Bvh`] rather
/// than by testing every child's box: the same threshold as the scene's own
/// ([`crate::world::BVH_MIN_PRIMS`]), for the same reason (below it the loop's box tests
/// are cheaper than the tree's bookkeeping). Measured on a union of 10,000 small spheres at
/// 320×240, one thread: 45 s with the loop, under a second with the index.
pub const CSG_INDEX_MIN: usize = crate::world::BVH_MIN_PRIMS;

/// The children of a union (or the cutters of a difference) in a [`Bvh`], so that a ray or
/// a point meets only the children whose boxes it reaches.
///
/// Items are child indices. The tree is built over the children's [`Csg::line_boxes`]
/// (already enlarged), which [`crate::bvh::padded`] enlarges again and the nodes round
/// outwards, so every node box holds the line boxes of the children under it: a line that
/// meets a child's box meets every node box above it (see [`line_meets`] for why the
/// computed test keeps that order), and no child the loop would evaluate is missed.
#[derive(Debug, Clone)]
struct ChildIndex {
    bvh: Bvh,
    /// Indexable children without a usable box (unbounded ones), tried every time.
    always: Vec<u32>,
}

impl ChildIndex {
    /// The index over children `first..` of `children`, or `None` when fewer than `min`
    /// of them are there to index.
    fn build(
        children: &[Prim],
        line_boxes: &[Option<Aabb>],
        first: usize,
        min: usize,
    ) -> Option<ChildIndex> {
        if children.len().saturating_sub(first) < min.max(1) {
            return None;
        }
        let mut always = Vec::new();
        let mut boxed = Vec::new();
        for (k, b) in line_boxes.iter().enumerate().skip(first) {
            // `as u32`: a node's children are some of the scene's objects, whose number
            // the parser keeps far below u32::MAX.
            match b {
                Some(b) => boxed.push((k as u32, *b)),
                None => always.push(k as u32),
            }
        }
        // An empty or non-finite box is left out of the tree and tried every time, where
        // the exact test (`line_meets` on its line box) decides, as in the loop.
        let (bvh, left_out) = Bvh::build(&boxed);
        always.extend(left_out);
        always.sort_unstable();
        Some(ChildIndex { bvh, always })
    }

    /// Whether `item` holds for some indexed child: those without a box, then those in the
    /// tree whose path of node boxes all pass `touches` ([`Bvh::any_item`]). Stops at the
    /// first `true`.
    fn any(&self, touches: impl FnMut(&Aabb) -> bool, mut item: impl FnMut(u32) -> bool) -> bool {
        self.always.iter().any(|&k| item(k)) || self.bvh.any_item(touches, item)
    }

    /// Appends to `out`, in increasing order, every indexed child whose line box the line
    /// meets (exactly the children the plain loop evaluates).
    fn children_met(&self, line_boxes: &[Option<Aabb>], ray: &Ray, inv: DVec3, out: &mut Vec<u32>) {
        let start = out.len();
        let meets = |k: u32| line_boxes[k as usize].is_none_or(|b| line_meets(&b, ray, inv));
        self.any(
            |b| line_meets(b, ray, inv),
            |k| {
                if meets(k) {
                    out.push(k);
                }
                false
            },
        );
        out[start..].sort_unstable();
    }

    /// Whether `inside` holds for some indexed child whose box may hold `p`.
    fn any_holding(&self, p: DVec3, inside: impl FnMut(u32) -> bool) -> bool {
        self.any(|b| b.contains(p), inside)
    }
}

impl Csg {
    /// The node `op` over `children`, which are placed among `objects`.
    pub fn new(op: CsgOp, children: Vec<Prim>, objects: &[Object]) -> Csg {
        let child_bounds: Vec<Option<Aabb>> = children.iter().map(|p| p.bounds(objects)).collect();
        // A line that misses a ball some child needs misses that child, and so the whole
        // solid when the solid lies inside that child: any child of an intersection, the
        // body of a difference. A union needs no one child, so it has no such ball.
        let balls = match op {
            CsgOp::Union => Vec::new(),
            CsgOp::Intersection => children.iter().flat_map(|c| c.balls(objects)).collect(),
            CsgOp::Difference => children
                .first()
                .map(|c| c.balls(objects))
                .unwrap_or_default(),
        };
        let mut csg = Csg {
            op,
            bounds: combine_bounds(op, &child_bounds),
            line_boxes: child_bounds
                .iter()
                .map(|b| b.map(|b| enlarged(&b)))
                .collect(),
            balls,
            children,
            index: None,
        };
        csg.index_children(CSG_INDEX_MIN);
        csg
    }

    /// Gives this node a `ChildIndex` when it has at least `min` children to index (a
    /// union's children, a difference's cutters), and takes it away otherwise; then the
    /// same for every CSG below. `usize::MAX` removes every index: the plain loop that
    /// tests and benchmarks compare against.
    pub fn index_children(&mut self, min: usize) {
        for child in &mut self.children {
            if let Prim::Csg(c) = child {
                c.index_children(min);
            }
        }
        let first = match self.op {
            CsgOp::Union => 0,
            CsgOp::Difference => 1,
            CsgOp::Intersection => {
                self.index = None;
                return;
            }
        };
        self.index = ChildIndex::build(&self.children, &self.line_boxes, first, min).map(Box::new);
    }

    /// Calls `visit` with every child whose box may pass `touches` (a conservative test of
    /// a region, as [`Bvh::any_item`] takes): through the index where there is one, so a
    /// tree of thousands of children costs about `log n` box tests plus the children
    /// found; otherwise every child. Children without a box are always visited.
    pub fn children_near<'a>(
        &'a self,
        touches: impl FnMut(&Aabb) -> bool,
        mut visit: impl FnMut(&'a Prim),
    ) {
        let Some(ix) = &self.index else {
            self.children.iter().for_each(visit);
            return;
        };
        if self.op == CsgOp::Difference
            && let Some(body) = self.children.first()
        {
            visit(body);
        }
        ix.any(touches, |k| {
            visit(&self.children[k as usize]);
            false
        });
    }

    /// Whether this node finds its children through an index (see [`Self::index_children`]).
    pub fn is_indexed(&self) -> bool {
        self.index.is_some()
    }

    /// What testing the tree costs a ray, roughly, in the units of the scene's SAH (see
    /// `world::prim_cost`): 2 per child the ray may evaluate, which with an index is the
    /// children tried every time and about `log₂ n` node visits (a difference's body too).
    pub fn cost(&self) -> f64 {
        match &self.index {
            None => 2.0 * self.children.len() as f64,
            Some(ix) => {
                let body = usize::from(self.op == CsgOp::Difference);
                2.0 * (body + ix.always.len()) as f64 + 2.0 + (ix.bvh.len().max(1) as f64).log2()
            }
        }
    }
}

/// A ball that holds a sphere placed in a CSG tree by a rotation, a uniform scale and a
/// translation ([`crate::transform::Transform::rigid_ball`]): a line that passes clearly
/// outside it has no spans on that sphere, so a tree that needs the sphere (see
/// [`Csg::new`]) is answered "no boundary" without evaluating any child.
///
/// **Why it never changes an answer.** The sphere's own test ([`crate::shape::Shape::spans`])
/// runs on the object-space ray, `N·o + t'` and `N·d` with `N` the inverse linear part. That
/// ray carries rounding of about `γ(3)·(|o| + |c|)/s` (the products with the inverse,
/// which [`crate::transform::Transform::is_valid`] also holds to `1e-9` of the forward
/// matrix), and the root finder decides "hit" to a few ulps of `|f|/s`. The ball's squared
/// radius already bounds the sphere's from above; the test rejects a line only when its
/// squared distance from the centre exceeds it by `1e-6·(|f|² + r² + |o|² + |c|²)`
/// (`f = o − c`), which is millions of times those errors (Lagrange's identity as in
/// [`crate::world::Object::certainly_missed_by`], whose computed form is off by at most
/// `2γ(6)·|f|²|d|²`). An overflow or a NaN fails the comparison and rejects nothing.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ball {
    pub centre: DVec3,
    pub r2: f64,
    /// `|c|²`, which every test's margin uses: computed once here.
    c2: f64,
}

impl Ball {
    /// The ball of centre `centre` and squared radius `r2`.
    pub fn new(centre: DVec3, r2: f64) -> Ball {
        Ball {
            centre,
            r2,
            c2: centre.length_squared(),
        }
    }

    /// Whether the ray's line certainly misses the ball (see the type's comment).
    #[inline]
    pub fn certainly_missed(&self, ray: &Ray) -> bool {
        let extra = ray.origin.length_squared() + self.c2;
        crate::world::line_clears_ball(self.centre, self.r2, ray, extra)
    }
}

/// One end point of a child's span, tagged with the child it came from.
#[derive(Debug, Clone, Copy)]
struct Event {
    t: f64,
    child: u32,
    enter: bool,
    surface: Surface,
}

/// Buffers reused from ray to ray, so evaluating a tree allocates nothing once they have
/// grown to the size the scene needs. Nodes use them as stacks: each node appends above
/// what its ancestors hold and truncates back when done.
#[derive(Debug, Default)]
pub struct Scratch {
    spans: Vec<CsgSpan>,
    events: Vec<Event>,
    shape: Vec<Span>,
    inside: Vec<bool>,
    /// Children an indexed node found for the current ray (see [`ChildIndex`]).
    kids: Vec<u32>,
}

thread_local! {
    static SCRATCH: RefCell<Scratch> = RefCell::new(Scratch::default());
}

/// Runs `f` with this thread's scratch buffers (or fresh ones, should a call ever nest).
pub fn with_scratch<R>(f: impl FnOnce(&mut Scratch) -> R) -> R {
    SCRATCH.with(|cell| match cell.try_borrow_mut() {
        Ok(mut s) => f(&mut s),
        Err(_) => f(&mut Scratch::default()),
    })
}

/// Bounds of a set operation over children's bounds (`None` = unbounded): a union is
/// bounded by the union of its children's boxes (unbounded if any child is); an
/// intersection by the overlap of its bounded children's boxes; a difference by its first
/// child's box.
pub fn combine_bounds(op: CsgOp, children: &[Option<Aabb>]) -> Option<Aabb> {
    match op {
        CsgOp::Union => children
            .iter()
            .try_fold(Aabb::EMPTY, |acc, b| b.map(|b| acc.union(&b))),
        CsgOp::Intersection => children.iter().flatten().fold(None, |acc, b| {
            Some(match acc {
                None => *b,
                Some(a) => Aabb::new(a.min.max(b.min), a.max.min(b.max)),
            })
        }),
        CsgOp::Difference => children.first().copied().flatten(),
    }
}

/// A box enlarged so that rounding in [`line_meets`] never drops a child the line touches
/// (by 1e-9 of its size and 1e-12 of its coordinates); an empty box stays empty.
fn enlarged(b: &Aabb) -> Aabb {
    if b.is_empty() {
        return *b;
    }
    let pad = (b.max - b.min) * 1e-9 + (b.max.abs().max(b.min.abs())) * 1e-12;
    Aabb::new(b.min - pad, b.max + pad)
}

/// Whether the whole line (any `t`) meets the (already [`enlarged`]) box. `inv` is the
/// ray's `1/dir`: a product with it is one rounding more than a division, some 1e-16 of
/// `t`, far inside the enlargement.
///
/// **An axis with a NaN end constrains nothing.** `0·∞` arises when a face lies exactly at
/// the origin's coordinate and `1/d` is infinite (a subnormal `d`): the exact slab interval
/// then starts (or ends) at `t = 0` and reaches some 1e300, and keeping only its other
/// end, as `f64::min` would, could drop a box the line does meet.
///
/// **Monotone in the box**, which is what lets [`ChildIndex`] skip a subtree on its node's
/// box: if box `A` holds box `B`, a line this test says meets `B` it also says meets `A`.
/// Per axis, `A.min − o ≤ B.min − o` and `A.max − o ≥ B.max − o` survive rounding (it is
/// monotone), and so do the products with one `1/d`, so `A`'s computed slab interval holds
/// `B`'s (or `A`'s has a NaN end and constrains nothing); the intersection over the axes
/// keeps that.
fn line_meets(b: &Aabb, ray: &Ray, inv: DVec3) -> bool {
    if b.is_empty() {
        return false;
    }
    let (mut t0, mut t1) = (f64::NEG_INFINITY, f64::INFINITY);
    for i in 0..3 {
        let (o, d) = (ray.origin[i], ray.dir[i]);
        if d == 0.0 {
            if !(o >= b.min[i] && o <= b.max[i]) {
                return false;
            }
            continue;
        }
        let (a, c) = ((b.min[i] - o) * inv[i], (b.max[i] - o) * inv[i]);
        if a.is_nan() || c.is_nan() {
            continue;
        }
        t0 = t0.max(a.min(c));
        t1 = t1.min(a.max(c));
    }
    t0 <= t1
}

impl Prim {
    /// World bounds of the solid.
    pub fn bounds(&self, objects: &[Object]) -> Option<Aabb> {
        match self {
            Prim::Object(i) => objects[*i as usize].bounds,
            Prim::Csg(c) => c.bounds,
        }
    }

    /// The balls every line meeting the solid meets: a sphere's own ball when it is placed
    /// by a rotation, uniform scale and translation; a tree's [`Csg::balls`].
    fn balls(&self, objects: &[Object]) -> Vec<Ball> {
        match self {
            Prim::Object(i) => {
                let o = &objects[*i as usize];
                match o.shape {
                    Shape::Sphere => o
                        .transform
                        .rigid_ball()
                        .map(|(centre, r2)| Ball::new(centre, r2)),
                    _ => None,
                }
                .into_iter()
                .collect()
            }
            Prim::Csg(c) => c.balls.clone(),
        }
    }

    /// Whether a world point is in the closed solid.
    pub fn contains(&self, objects: &[Object], p: DVec3) -> bool {
        match self {
            Prim::Object(i) => {
                let o = &objects[*i as usize];
                o.shape
                    .contains(o.transform.to_object().transform_point3(p))
            }
            Prim::Csg(c) => c.contains(objects, p),
        }
    }

    /// Appends the solid's spans along the whole line to `out`, in increasing `t`.
    pub fn spans(
        &self,
        objects: &[Object],
        ray: &Ray,
        scratch: &mut Scratch,
        out: &mut Vec<CsgSpan>,
    ) {
        let start = scratch.spans.len();
        let scale = ray_scale(ray);
        eval(self, objects, ray, ray.inv_dir(), scale, scratch);
        out.extend_from_slice(&scratch.spans[start..]);
        scratch.spans.truncate(start);
    }
}

impl Csg {
    /// Whether a world point is in the closed solid, by the set definitions.
    pub fn contains(&self, objects: &[Object], p: DVec3) -> bool {
        if let Some(ix) = &self.index {
            let inside = |k: u32| self.children[k as usize].contains(objects, p);
            return match self.op {
                CsgOp::Union => ix.any_holding(p, inside),
                // `index_children` gives an intersection no index.
                CsgOp::Intersection => self.children.iter().all(|k| k.contains(objects, p)),
                CsgOp::Difference => {
                    self.children
                        .first()
                        .is_some_and(|b| b.contains(objects, p))
                        && !ix.any_holding(p, inside)
                }
            };
        }
        let mut kids = self.children.iter().map(|k| k.contains(objects, p));
        match self.op {
            CsgOp::Union => kids.any(|x| x),
            CsgOp::Intersection => kids.all(|x| x),
            CsgOp::Difference => kids.next().unwrap_or(false) && !kids.any(|x| x),
        }
    }

    /// The nearest boundary of the solid with `0 < t < t_max`: its `t` and the primitive
    /// surface there. See [`first_boundary`] for how the surface a ray leaves is told apart.
    ///
    /// The tree's balls ([`Ball`]) and its box are tested first: only a ray that passes
    /// both takes this thread's scratch buffers (see [`with_scratch`]) and evaluates the
    /// tree.
    pub fn first_hit(&self, objects: &[Object], ray: &Ray, t_max: f64) -> Option<Boundary> {
        // The balls first: they need no division, and they are the tighter test.
        if self.balls.iter().any(|b| b.certainly_missed(ray)) {
            return None;
        }
        // The box is only a shortcut: it must never decide between hits. Against `t_max`
        // itself it could, by rounding: a boundary on the box's own face can come out an ulp
        // before the slab test's entry, and a `t_max` in that gap (another solid's hit on a
        // coincident face) would drop it. With `t_max` widened by `bvh::SLACK` (1e-7) that
        // gap would have to be ~10⁹ ulps wide, so the answer is "the first boundary, if
        // before `t_max`" whatever `t_max` is, which is what lets the BVH visit solids in
        // any order and still agree with the plain loop (see `Scene::intersect`).
        let inv = ray.inv_dir();
        if let Some(b) = self.bounds
            && b.hit_interval(ray.origin, inv, t_max + t_max * crate::bvh::SLACK)
                .is_none()
        {
            return None;
        }
        with_scratch(|scratch| {
            let start = scratch.spans.len();
            let scale = ray_scale(ray);
            eval_csg(self, objects, ray, inv, scale, scratch);
            let found = first_boundary(&scratch.spans[start..], t_max, || {
                self.contains(objects, ray.origin)
            });
            scratch.spans.truncate(start);
            found
        })
    }
}

/// The first boundary in `(0, t_max)` of the kind the origin calls for: an entry when the
/// origin is outside the solid, an exit when it is inside.
///
/// Whether the origin is inside is decided directly, by membership of the origin
/// (`origin_inside`, asked only if some boundary lies ahead). A secondary ray starts just
/// off the surface it leaves; if rounding put that surface's crossing at a tiny positive
/// `t`, the first boundary ahead is of the wrong kind, and it is skipped as the surface
/// being left; the next one alternates back to the right kind. This is defence in depth:
/// the lift of [`crate::math::offset_ray_origin`] already clears the crossing in every case
/// the tests produce, but a CSG surface, unlike a convex primitive's, cannot simply be left
/// out of its own shadow test, so a second, independent guard is cheap insurance.
pub fn first_boundary(
    spans: &[CsgSpan],
    t_max: f64,
    origin_inside: impl Fn() -> bool,
) -> Option<Boundary> {
    let mut want_entry: Option<bool> = None;
    for s in spans {
        for (b, is_entry) in [(s.enter, true), (s.exit, false)] {
            if !(b.t > 0.0) {
                continue;
            }
            if !(b.t < t_max) {
                return None;
            }
            let want = *want_entry.get_or_insert_with(|| !origin_inside());
            if is_entry == want {
                return Some(b);
            }
        }
    }
    None
}

/// Appends the spans of `prim` to `scratch.spans`.
/// `inv` is the ray's `1/dir` ([`Ray::inv_dir`]), computed once per tree.
fn eval(prim: &Prim, objects: &[Object], ray: &Ray, inv: DVec3, scale: f64, scratch: &mut Scratch) {
    match prim {
        Prim::Object(i) => {
            let obj = &objects[*i as usize];
            let local = obj.transform.ray_to_object(ray);
            scratch.shape.clear();
            obj.shape.spans(&local, &mut scratch.shape);
            for s in &scratch.shape {
                // A NaN end or an inverted span would corrupt the sweep; shapes do not make
                // them, and this keeps it that way whatever a future shape does.
                if !(s.enter.t <= s.exit.t) {
                    continue;
                }
                let tag = |face| Surface {
                    object: *i,
                    face,
                    flip: false,
                };
                scratch.spans.push(CsgSpan {
                    enter: Boundary {
                        t: s.enter.t,
                        surface: tag(s.enter.face),
                    },
                    exit: Boundary {
                        t: s.exit.t,
                        surface: tag(s.exit.face),
                    },
                });
            }
        }
        Prim::Csg(c) => eval_csg(c, objects, ray, inv, scale, scratch),
    }
}

/// Appends the spans of a CSG node to `scratch.spans`: evaluates each child, turns its
/// spans into tagged events, and sweeps them.
/// A child whose box the line misses has no spans and is not evaluated (its parent, or
/// [`Csg::first_hit`] for the root, has already tested this node's own box). With an index
/// (see [`ChildIndex`]) the children whose boxes the line meets are found through it, and
/// then evaluated in the same order as by the loop, so the events, and the sweep's answer,
/// are the same.
fn eval_csg(c: &Csg, objects: &[Object], ray: &Ray, inv: DVec3, scale: f64, scratch: &mut Scratch) {
    let span_start = scratch.spans.len();
    let ev_start = scratch.events.len();
    let meets = |k: usize| c.line_boxes[k].is_none_or(|b| line_meets(&b, ray, inv));
    let Some(index) = &c.index else {
        for k in 0..c.children.len() {
            if meets(k) {
                eval(&c.children[k], objects, ray, inv, scale, scratch);
            }
            if !take_events(c.op, k, span_start, ev_start, scratch) {
                return;
            }
        }
        sweep(c.op, c.children.len(), ev_start, scale, scratch);
        scratch.events.truncate(ev_start);
        return;
    };
    // A difference's body first, as in the loop: the cutters only matter if it is met.
    if c.op == CsgOp::Difference {
        if meets(0) {
            eval(&c.children[0], objects, ray, inv, scale, scratch);
        }
        if !take_events(c.op, 0, span_start, ev_start, scratch) {
            return;
        }
    }
    // The candidates go on the scratch stack above any an enclosing node holds; a child
    // evaluated below pushes its own above these and truncates back.
    let kid_start = scratch.kids.len();
    index.children_met(&c.line_boxes, ray, inv, &mut scratch.kids);
    for i in kid_start..scratch.kids.len() {
        let k = scratch.kids[i] as usize;
        eval(&c.children[k], objects, ray, inv, scale, scratch);
        // An indexed child (a union's, a difference's cutter) never empties the node.
        take_events(c.op, k, span_start, ev_start, scratch);
    }
    scratch.kids.truncate(kid_start);
    sweep(c.op, c.children.len(), ev_start, scale, scratch);
    scratch.events.truncate(ev_start);
}

/// Turns the spans child `k` just appended (above `span_start`) into events and removes
/// them. Returns false when the node is empty whatever its other children hold (an
/// intersection with a child the line misses, a difference whose body it misses); the
/// node's events are then dropped too and it must add nothing.
fn take_events(
    op: CsgOp,
    k: usize,
    span_start: usize,
    ev_start: usize,
    scratch: &mut Scratch,
) -> bool {
    let got = scratch.spans.len() - span_start;
    let empty = got == 0
        && match op {
            CsgOp::Intersection => true,
            CsgOp::Difference => k == 0,
            CsgOp::Union => false,
        };
    if empty {
        scratch.events.truncate(ev_start);
        return false;
    }
    let flip = op == CsgOp::Difference && k > 0;
    for i in span_start..scratch.spans.len() {
        let s = scratch.spans[i];
        for (b, enter) in [(s.enter, true), (s.exit, false)] {
            let mut surface = b.surface;
            surface.flip ^= flip;
            scratch.events.push(Event {
                t: b.t,
                // `as u32`: see `ChildIndex::build`.
                child: k as u32,
                enter,
                surface,
            });
        }
    }
    scratch.spans.truncate(span_start);
    true
}

/// Whether event `e` moves the result the same way as the new combined state `entering`.
fn pushes_towards(op: CsgOp, e: &Event, entering: bool) -> bool {
    match op {
        CsgOp::Difference if e.child > 0 => e.enter != entering,
        _ => e.enter == entering,
    }
}

/// The ray's scale in units of its `t`, `|o| / |d|`, for [`tolerance`]. Computed directly
/// while `|d|²` and `|o|²` are normal finite numbers (every ray the renderer makes); past
/// that, with each vector divided by its largest component first. A direction of about
/// 10⁻²⁰¹ made `|d|` underflow to 0 and the scale infinite, which merged every crossing of a
/// tree into one: the tree then reported a boundary outside its own box, and the BVH, whose
/// box shortcut dropped it, disagreed with the plain loop.
fn ray_scale(ray: &Ray) -> f64 {
    let (oo, dd) = (ray.origin.length_squared(), ray.dir.length_squared());
    if (f64::MIN_POSITIVE..f64::INFINITY).contains(&dd) && oo < f64::INFINITY {
        return ray.origin.length() / ray.dir.length();
    }
    let length = |v: DVec3| {
        let m = v.abs().max_element();
        if m > 0.0 && m < f64::INFINITY {
            m * (v / m).length()
        } else {
            v.length()
        }
    };
    length(ray.origin) / length(ray.dir)
}

/// How far past a group's first crossing at `t0` other crossings still join it: the
/// coincidence tolerance of the module comment ([`COINCIDENT_REL`]); none at an infinite end.
fn tolerance(t0: f64, scale: f64) -> f64 {
    if t0.is_finite() {
        COINCIDENT_REL * (scale + t0.abs())
    } else {
        0.0
    }
}

/// The node's spans when the sweep could only copy them: when every event comes from one
/// child whose state is the node's (a union's child, a difference's body, an intersection's
/// only child) and the events are in order. A child's own crossings never share a group
/// (see the module comment), so every group is a single event that changes the state, and
/// the sweep would report each event as a boundary, unchanged; events already in order
/// need no sorting. `None` when the sweep must run.
fn lone_spans(op: CsgOp, n: usize, events: &[Event]) -> Option<impl Iterator<Item = CsgSpan> + '_> {
    let child = events.first()?.child;
    let follows = match op {
        CsgOp::Union => true,
        CsgOp::Difference => child == 0,
        CsgOp::Intersection => n == 1,
    };
    if !follows || events.iter().any(|e| e.child != child) {
        return None;
    }
    // A NaN fails `<=` and so falls back to the sweep.
    let in_order = events.windows(2).all(|w| w[0].t <= w[1].t);
    in_order.then(|| {
        events.chunks_exact(2).map(|pair| CsgSpan {
            enter: Boundary {
                t: pair[0].t,
                surface: pair[0].surface,
            },
            exit: Boundary {
                t: pair[1].t,
                surface: pair[1].surface,
            },
        })
    })
}

/// The sweep over `scratch.events[ev_start..]` (children's span ends): appends the node's
/// spans to `scratch.spans`, applying the coincident-surface rule of the module comment.
fn sweep(op: CsgOp, n: usize, ev_start: usize, scale: f64, scratch: &mut Scratch) {
    let Scratch {
        spans,
        events,
        inside,
        ..
    } = scratch;
    let events = &mut events[ev_start..];
    if let Some(alone) = lone_spans(op, n, events) {
        spans.extend(alone);
        return;
    }
    // Stable: a child's own end points keep their order when equal.
    events.sort_by(|a, b| a.t.total_cmp(&b.t));
    // Only the flags of children with events here are ever read, so only they are
    // cleared: clearing all `n` per ray cost a union of 16,384 children some 16 KB of
    // stores for the few dozen it met.
    if inside.len() < n {
        inside.resize(n, false);
    }
    for e in events.iter() {
        inside[e.child as usize] = false;
    }
    // Children inside: all of them for union and intersection; the cutters for difference.
    let mut count = 0usize;
    let mut body = false;
    let state = |count: usize, body: bool| match op {
        CsgOp::Union => count > 0,
        CsgOp::Intersection => count == n,
        CsgOp::Difference => body && count == 0,
    };
    let mut current = false;
    let mut open: Option<Boundary> = None;
    let mut i = 0;
    while i < events.len() {
        let t0 = events[i].t;
        let tol = tolerance(t0, scale);
        let mut j = i;
        // The group: events[i] and every later one within `tol` of it (at least one, so
        // the sweep always advances), up to a second crossing of a child already in it.
        while j == i
            || (j < events.len()
                && (events[j].t == t0 || events[j].t - t0 <= tol)
                && events[i..j].iter().all(|e| e.child != events[j].child))
        {
            let e = events[j];
            let k = e.child as usize;
            if inside[k] != e.enter {
                inside[k] = e.enter;
                if op == CsgOp::Difference && k == 0 {
                    body = e.enter;
                } else if e.enter {
                    count += 1;
                } else {
                    count = count.saturating_sub(1);
                }
            }
            j += 1;
        }
        let next = state(count, body);
        if next != current {
            let group = &events[i..j];
            // The first child in the order written whose crossing both stands (the child
            // ends the group in the state it moved to) and moves the result this way; one
            // always exists, as each operation is monotone in every child.
            let chosen = group
                .iter()
                .filter(|e| inside[e.child as usize] == e.enter && pushes_towards(op, e, next))
                .min_by_key(|e| e.child)
                .or_else(|| group.iter().find(|e| pushes_towards(op, e, next)))
                .unwrap_or(&group[0]);
            let b = Boundary {
                t: t0,
                surface: chosen.surface,
            };
            if next {
                open = Some(b);
            } else if let Some(enter) = open.take() {
                spans.push(CsgSpan { enter, exit: b });
            }
            current = next;
        }
        i = j;
    }
    // Children's spans are closed, so the state ends outside; should it not, close the
    // last span at infinity rather than lose it.
    if let Some(enter) = open {
        spans.push(CsgSpan {
            enter,
            exit: Boundary {
                t: f64::INFINITY,
                surface: enter.surface,
            },
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::shape::test_support::Rng;
    use crate::world::Scene;
    use crate::{Limits, MemoryAssets, TextureLimits};

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
                    let expected =
                        first_boundary(&spans, t_max, || c.contains(&s.objects, r.origin));
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
                0 if !written.is_empty() => {
                    written[rng.next_u64() as usize % written.len()].clone()
                }
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
                let by_index =
                    ix.any_holding(p, |k| c.children[k as usize].contains(&s.objects, p));
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
                    let meets =
                        |b: &Aabb| (b.min.cmple(region.max) & region.min.cmple(b.max)).all();
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
}
