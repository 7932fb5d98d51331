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

use crate::math::Aabb;
use crate::scene::CsgOp;
use tree::ChildIndex;

mod bounds;
mod hit;
mod tree;

pub use bounds::Ball;

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
/// than it is merged away. Near the world origin any small tolerance is invisible, but far
/// from it `|origin|` dominates: at 1e-10 a scene at 1e9 would lose its 0.05-deep pockets
/// (the tolerance is 0.1 of a unit there), and a union at 1e10 would show the wrong child's
/// surface, while lone objects render exactly as at the origin. At 1e-12 the same scenes
/// keep pockets, gaps and walls down to 1e-3 of a unit at 1e9 and 1e-2 at 1e10
/// (`tests/numerics.rs` renders them moved there and compares).
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
    /// A set operation over other prims.
    Csg(Csg),
}

/// A CSG node: a set operation over two or more children.
#[derive(Debug, Clone)]
pub struct Csg {
    /// The set operation.
    pub op: CsgOp,
    /// The children, in the order written (for a difference, the body first).
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
/// ([`crate::bvh::BVH_MIN_PRIMS`]), for the same reason (below it the loop's box tests
/// are cheaper than the tree's bookkeeping). Above it the index wins by orders of
/// magnitude: a union of thousands of small spheres would test every child for every ray.
pub const CSG_INDEX_MIN: usize = crate::bvh::BVH_MIN_PRIMS;

#[cfg(test)]
mod tests;
