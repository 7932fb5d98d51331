//! The nearest-hit query: which surface a ray meets first, through the point tables, the
//! BVH or the plain list of prims.

use std::ops::ControlFlow;

use crate::bvh::Bvh;
use crate::csg::{Csg, Prim};
use crate::math::Ray;
use crate::object::{quick_missed, sphere_certainly_missed};
use crate::point_index::{self};

use super::accel::{Accel, Quick};
use super::{Hit, Scene};

impl Scene {
    /// The nearest hit with `0 < t < t_max`. `skip` names an object the ray cannot meet
    /// again (see [`Shape::cannot_rehit`]), which is then not tested at all; it is only ever
    /// an object outside every CSG tree.
    ///
    /// Of hits at the very same `t`, the one on the prim written first wins, with or without
    /// a BVH: the linear loop keeps its first hit because later ones must be strictly
    /// nearer, and the BVH, which meets prims in another order, breaks ties on the prim index
    /// (see `intersect_bvh`).
    // Used through `crate::internals` (feature `bench`) and by the tests.
    #[cfg_attr(not(feature = "bench"), allow(dead_code))]
    #[inline]
    pub(crate) fn intersect(&self, ray: &Ray, t_max: f64, skip: Option<u32>) -> Option<Hit> {
        self.intersect_in::<true>(ray, t_max, skip)
    }

    /// [`Self::intersect`], looking at the eye's table only if `TABLES` (for callers that
    /// know the scene has none: see [`Self::has_point_tables`]).
    #[inline]
    pub(crate) fn intersect_in<const TABLES: bool>(
        &self,
        ray: &Ray,
        t_max: f64,
        skip: Option<u32>,
    ) -> Option<Hit> {
        match &self.accel {
            Accel::Linear(_) => self.intersect_linear(ray, t_max, skip),
            Accel::Bvh {
                bvh,
                unbounded,
                quick,
            } => {
                if TABLES
                    && let Some(eye) = &self.points.eye
                    && ray.origin == eye.point()
                    && let Some(listed) = eye.lookup(ray.dir)
                {
                    return self.intersect_listed(
                        eye.always(),
                        listed,
                        unbounded,
                        ray,
                        t_max,
                        skip,
                    );
                }
                self.intersect_bvh(bvh, unbounded, quick, ray, t_max, skip)
            }
        }
    }

    /// Offers prim `i` to a nearest-hit search whose best so far is `best` at `t_best`,
    /// unless a quick test already `rejected` it; with the tie rule of
    /// [`Self::intersect_bvh`].
    #[inline(always)]
    pub(super) fn consider(
        &self,
        best: &mut Option<(Hit, u32)>,
        t_best: &mut f64,
        i: u32,
        rejected: bool,
        ray: &Ray,
        skip: Option<u32>,
    ) {
        if !rejected {
            let limit = match *best {
                Some((_, b)) if i < b => t_best.next_up(),
                _ => *t_best,
            };
            if let Some(h) = self.prim_hit(&self.prims[i as usize], ray, limit, skip) {
                *t_best = h.local.t;
                *best = Some((h, i));
            }
        }
    }

    /// The nearest hit of a ray from the eye, from the eye's table: the unbounded prims, the
    /// table's `always` prims, then the prims the direction's cell `listed` (sorted by their
    /// boxes' distance from the eye), until the next box is farther than the best hit. The
    /// same answer as [`Self::intersect_bvh`]: every prim the BVH would offer and could report
    /// a hit is offered, with the same tie rule.
    #[inline(never)]
    pub(super) fn intersect_listed(
        &self,
        always: &[u32],
        listed: &[point_index::Entry],
        unbounded: &[u32],
        ray: &Ray,
        t_max: f64,
        skip: Option<u32>,
    ) -> Option<Hit> {
        let mut best: Option<(Hit, u32)> = None;
        let mut t_best = t_max;
        for &i in unbounded.iter().chain(always) {
            self.consider(&mut best, &mut t_best, i, false, ray, skip);
        }
        let dd = ray.dir.length_squared();
        for e in listed {
            // A hit at `t` lies `t·|d|` from the eye, inside the box: not nearer than the
            // box. The factor covers the rounding of `t²·|d|²` (see `point_index`) while it is
            // a normal number; below that, no stop.
            let reach = t_best * t_best * dd;
            if reach >= f64::MIN_POSITIVE && f64::from(e.near_sq) > reach * (1.0 + 1e-9) {
                break;
            }
            let (c, r2) = self.points.quick[e.prim as usize];
            let rejected = quick_missed(c, r2, ray);
            self.consider(&mut best, &mut t_best, e.prim, rejected, ray, skip);
        }
        best.map(|(h, _)| h)
    }

    /// Every prim in order: a prim replaces the best hit only when strictly nearer. A sphere
    /// placed by a similarity that its quick test rejects (see
    /// [`Object::certainly_missed_by`](crate::object::Object::certainly_missed_by)) has no
    /// hit and is not asked: the test runs here, in the loop, rather than behind a call.
    #[inline(always)]
    pub(super) fn intersect_linear(&self, ray: &Ray, t_max: f64, skip: Option<u32>) -> Option<Hit> {
        let mut best: Option<Hit> = None;
        let mut t_best = t_max;
        for prim in &self.prims {
            if self.lone_sphere_missed(prim, ray) {
                continue;
            }
            if let Some(h) = self.prim_hit(prim, ray, t_best, skip) {
                t_best = h.local.t;
                best = Some(h);
            }
        }
        best
    }

    /// Whether `prim` is a sphere placed by a similarity whose quick test rejects the ray
    /// (see [`Object::certainly_missed_by`](crate::object::Object::certainly_missed_by)):
    /// the plain loops' test, read from the object and inlined into them.
    #[inline(always)]
    pub(super) fn lone_sphere_missed(&self, prim: &Prim, ray: &Ray) -> bool {
        match prim {
            Prim::Object(i) => self.objects[*i as usize]
                .sphere
                .is_some_and(|(c, r2)| sphere_certainly_missed(c, r2, ray)),
            Prim::Csg(_) => false,
        }
    }

    /// The unbounded prims, then the BVH's candidates nearest first.
    ///
    /// Every prim test is a pure filter on its own `t` (a shape or CSG tree computes the
    /// same `t` whatever `t_max` it is given, and reports it iff `t < t_max`; a CSG tree's
    /// box shortcut is widened so that it cannot decide, see [`Csg::first_hit`]), so the linear
    /// loop's answer is the hit with the least `(t, prim index)`. Here prims come in another
    /// order; a prim written *before* the current best is therefore asked with the limit one
    /// ulp above `t_best`, so a hit at exactly `t_best` (and nothing beyond it) is reported
    /// and wins the tie, while a prim written after the best must still be strictly nearer.
    pub(super) fn intersect_bvh(
        &self,
        bvh: &Bvh,
        unbounded: &[u32],
        quick: &[Quick],
        ray: &Ray,
        t_max: f64,
        skip: Option<u32>,
    ) -> Option<Hit> {
        let mut best: Option<(Hit, u32)> = None;
        let mut t_best = t_max;
        for &i in unbounded {
            self.consider(&mut best, &mut t_best, i, false, ray, skip);
        }
        bvh.traverse(ray.origin, ray.inv_dir(), t_max, |slot| {
            let q = &quick[slot];
            let rejected = quick_missed(q.centre, q.r2, ray);
            self.consider(&mut best, &mut t_best, q.prim, rejected, ray, skip);
            ControlFlow::Continue(t_best)
        });
        best.map(|(h, _)| h)
    }

    /// The nearest hit on one prim with `0 < t < t_max`.
    #[inline]
    pub(super) fn prim_hit(
        &self,
        prim: &Prim,
        ray: &Ray,
        t_max: f64,
        skip: Option<u32>,
    ) -> Option<Hit> {
        match prim {
            Prim::Object(i) => {
                if skip == Some(*i) {
                    return None;
                }
                let obj = &self.objects[*i as usize];
                if obj.certainly_missed_by(ray) {
                    return None;
                }
                let local_ray = obj.transform.ray_to_object(ray);
                obj.shape.intersect(&local_ray, t_max).map(|h| Hit {
                    object: *i,
                    local: h,
                })
            }
            Prim::Csg(c) => self.csg_hit(c, ray, t_max),
        }
    }

    /// The nearest hit on a CSG tree, as a hit on the child surface it lies on.
    pub(super) fn csg_hit(&self, c: &Csg, ray: &Ray, t_max: f64) -> Option<Hit> {
        let b = c.first_hit(&self.objects, ray, t_max)?;
        let obj = &self.objects[b.surface.object as usize];
        let local_ray = obj.transform.ray_to_object(ray);
        let mut local = obj.shape.surface_at(&local_ray, b.t, b.surface.face);
        if b.surface.flip {
            local.n = -local.n;
        }
        Some(Hit {
            object: b.surface.object,
            local,
        })
    }
}
