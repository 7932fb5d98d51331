//! Building a CSG tree: a node over its children, its cost estimate, and the index over
//! many children's boxes (`ChildIndex`) that finds the children a ray's line may meet.

use glam::DVec3;

use crate::bvh::Bvh;
use crate::math::{Aabb, Ray};
use crate::object::Object;
use crate::scene::CsgOp;

use super::bounds::{combine_bounds, enlarged, line_meets};
use super::{CSG_INDEX_MIN, Csg, Prim};

/// The children of a union (or the cutters of a difference) in a [`Bvh`], so that a ray or
/// a point meets only the children whose boxes it reaches.
///
/// Items are child indices. The tree is built over the children's [`Csg::line_boxes`]
/// (already enlarged), which [`crate::bvh::padded`] enlarges again and the nodes round
/// outwards, so every node box holds the line boxes of the children under it: a line that
/// meets a child's box meets every node box above it (see [`line_meets`] for why the
/// computed test keeps that order), and no child the loop would evaluate is missed.
#[derive(Debug, Clone)]
pub(super) struct ChildIndex {
    pub(super) bvh: Bvh,
    /// Indexable children without a usable box (unbounded ones), tried every time.
    pub(super) always: Vec<u32>,
}

impl ChildIndex {
    /// The index over children `first..` of `children`, or `None` when fewer than `min`
    /// of them are there to index.
    pub(super) fn build(
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
    pub(super) fn any(
        &self,
        touches: impl FnMut(&Aabb) -> bool,
        mut item: impl FnMut(u32) -> bool,
    ) -> bool {
        self.always.iter().any(|&k| item(k)) || self.bvh.any_item(touches, item)
    }

    /// Appends to `out`, in increasing order, every indexed child whose line box the line
    /// meets (exactly the children the plain loop evaluates).
    pub(super) fn children_met(
        &self,
        line_boxes: &[Option<Aabb>],
        ray: &Ray,
        inv: DVec3,
        out: &mut Vec<u32>,
    ) {
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
    pub(super) fn any_holding(&self, p: DVec3, inside: impl FnMut(u32) -> bool) -> bool {
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
    /// a region, as `Bvh::any_item` takes): through the index where there is one, so a
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
    // Used through `crate::internals` (feature `bench`) and by the tests.
    #[cfg_attr(not(feature = "bench"), allow(dead_code))]
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
