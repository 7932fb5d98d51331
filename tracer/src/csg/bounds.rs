//! Bounds of CSG trees: the box a set operation's result lies in, the bounding balls that
//! reject lines cheaply, and the line-box test the sweep uses to skip children.

use glam::DVec3;

use crate::math::{Aabb, Ray};
use crate::scene::CsgOp;

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
/// [`crate::object::Object::certainly_missed_by`], whose computed form is off by at most
/// `2γ(6)·|f|²|d|²`). An overflow or a NaN fails the comparison and rejects nothing.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ball {
    pub centre: DVec3,
    pub r2: f64,
    /// `|c|²`, which every test's margin uses: computed once here.
    pub(super) c2: f64,
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
        crate::object::line_clears_ball(self.centre, self.r2, ray, extra)
    }
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
pub(super) fn enlarged(b: &Aabb) -> Aabb {
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
pub(super) fn line_meets(b: &Aabb, ray: &Ray, inv: DVec3) -> bool {
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

#[cfg(test)]
mod tests;
