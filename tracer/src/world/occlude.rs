//! The any-hit queries shadow rays make: whether anything blocks a ray before a distance,
//! and which objects a ray leaving a surface may skip.

use std::ops::ControlFlow;

use glam::DVec3;

use crate::bvh::Bvh;
use crate::csg::Prim;
use crate::math::Ray;
use crate::object::quick_missed;
use crate::point_index::{self};

use super::accel::{Accel, Quick};
use super::{Hit, Scene};

impl Scene {
    /// Whether anything lies on the ray with `0 < t < t_max`. Any hit will do, so the BVH
    /// search stops at the first.
    #[inline]
    pub(crate) fn occluded(&self, ray: &Ray, t_max: f64, skip: Option<u32>) -> bool {
        self.occluded_unless(ray, t_max, move |i| skip == Some(i))
    }

    /// [`Self::occluded`], also leaving out the objects `also` (those a light lies on, for a
    /// point outside them: see [`Self::lights_on`]).
    #[inline]
    pub(crate) fn occluded_skipping(
        &self,
        ray: &Ray,
        t_max: f64,
        skip: Option<u32>,
        also: &[u32],
    ) -> bool {
        if also.is_empty() {
            return self.occluded(ray, t_max, skip);
        }
        self.occluded_unless(ray, t_max, move |i| skip == Some(i) || also.contains(&i))
    }

    /// Whether the eye or some light has a table (see [`crate::point_index`]).
    #[inline]
    pub(crate) fn has_point_tables(&self) -> bool {
        self.points.eye.is_some() || self.points.lights.iter().any(Option::is_some)
    }

    /// [`Self::occluded_skipping`] for a shadow ray towards light `light`. A ray built as the
    /// renderer builds them, `Ray::new(o, L − o)` for the light's position `L` with
    /// `t_max < 1` (see [`crate::render::SHADOW_END_REL`]), looks its candidates up in the
    /// light's table when there is one (see [`crate::point_index`]); any other ray, or a light
    /// without a table, walks the BVH. The answer is the same either way.
    #[inline]
    pub(crate) fn occluded_towards(
        &self,
        light: usize,
        ray: &Ray,
        t_max: f64,
        skip: Option<u32>,
        also: &[u32],
    ) -> bool {
        if let Accel::Bvh { unbounded, .. } = &self.accel
            && let Some(Some(table)) = self.points.lights.get(light)
            && t_max < 1.0
            && ray.dir == table.point() - ray.origin
            && table.shadow_lookup_ok(ray.dir)
            && let Some(listed) = table.lookup(-ray.dir)
        {
            let skip = move |i| skip == Some(i) || also.contains(&i);
            return self.occluded_listed(table.always(), listed, unbounded, ray, t_max, skip);
        }
        self.occluded_skipping(ray, t_max, skip, also)
    }

    /// The shadow answer from a light's table: the unbounded prims, the table's `always`
    /// prims and the prims the direction's cell `listed`, until one blocks.
    #[inline(never)]
    pub(super) fn occluded_listed(
        &self,
        always: &[u32],
        listed: &[point_index::Entry],
        unbounded: &[u32],
        ray: &Ray,
        t_max: f64,
        skip: impl Fn(u32) -> bool + Copy,
    ) -> bool {
        // A point of the segment is at most `|d|` from the light (`t ≥ 0`; the rounding of
        // `d` adds 2⁻⁵³ of it, which the factor covers): listed boxes farther away, beyond
        // the ray's origin, cannot block it.
        let dd = ray.dir.length_squared();
        let reach = if dd >= f64::MIN_POSITIVE {
            dd * (1.0 + 1e-9)
        } else {
            f64::INFINITY
        };
        unbounded
            .iter()
            .chain(always)
            .any(|&i| self.prim_blocks(&self.prims[i as usize], ray, t_max, skip))
            || listed
                .iter()
                .take_while(|e| f64::from(e.near_sq) <= reach)
                .any(|e| {
                    let (c, r2) = self.points.quick[e.prim as usize];
                    !quick_missed(c, r2, ray)
                        && self.prim_blocks(&self.prims[e.prim as usize], ray, t_max, skip)
                })
    }

    /// The any-hit search, leaving out the lone objects `skip` names. Generic so that the
    /// common search (one object left out, or none) pays nothing for the rarer list of
    /// objects a light lies on: each caller gets its own compiled copy.
    #[inline]
    pub(super) fn occluded_unless(
        &self,
        ray: &Ray,
        t_max: f64,
        skip: impl Fn(u32) -> bool + Copy,
    ) -> bool {
        match &self.accel {
            Accel::Linear(_) => self.prims.iter().any(|prim| {
                !self.lone_sphere_missed(prim, ray) && self.prim_blocks(prim, ray, t_max, skip)
            }),
            Accel::Bvh {
                bvh,
                unbounded,
                quick,
            } => self.occluded_bvh(bvh, unbounded, quick, ray, t_max, skip),
        }
    }

    /// The unbounded prims, then the BVH's candidates until one blocks. Not inlined into
    /// the shading code, like [`Self::intersect_bvh`]: compiled on its own, the four-lane
    /// box test is vectorised the same way in both searches (inlined into the shader it is
    /// not, and costs half as much again).
    #[inline(never)]
    pub(super) fn occluded_bvh(
        &self,
        bvh: &Bvh,
        unbounded: &[u32],
        quick: &[Quick],
        ray: &Ray,
        t_max: f64,
        skip: impl Fn(u32) -> bool + Copy,
    ) -> bool {
        unbounded
            .iter()
            .any(|&i| self.prim_blocks(&self.prims[i as usize], ray, t_max, skip))
            || bvh.traverse(ray.origin, ray.inv_dir(), t_max, |slot| {
                let q = &quick[slot];
                if !quick_missed(q.centre, q.r2, ray)
                    && self.prim_blocks(&self.prims[q.prim as usize], ray, t_max, skip)
                {
                    ControlFlow::Break(())
                } else {
                    ControlFlow::Continue(t_max)
                }
            })
    }

    /// Whether one prim has a hit with `0 < t < t_max`.
    #[inline]
    pub(super) fn prim_blocks(
        &self,
        prim: &Prim,
        ray: &Ray,
        t_max: f64,
        skip: impl Fn(u32) -> bool,
    ) -> bool {
        match prim {
            Prim::Object(i) => {
                let obj = &self.objects[*i as usize];
                !skip(*i)
                    && !obj.certainly_missed_by(ray)
                    && obj
                        .shape
                        .intersect(&obj.transform.ray_to_object(ray), t_max)
                        .is_some()
            }
            Prim::Csg(c) => c.first_hit(&self.objects, ray, t_max).is_some(),
        }
    }

    /// Whether a shadow ray towards `light` from any origin within `reach()` of `p` certainly
    /// meets nothing but the object `skip`: in a scene searched by the plain loop, when
    /// every other prim has a ball (a sphere's own, a CSG tree's first) that the line from
    /// `p` to the light misses grown by `reach`, by the margin of the prim's own test. Each
    /// point of the segment from such an origin `o` to the light lies within `|o − p|` of
    /// the segment from `p` (the two meet at the light), so the shadow ray misses every such
    /// ball by the ball's own margin, and no prim's test can report a hit there
    /// ([`Self::occluded`] answers `false`, as the ball's test would have it). `false`
    /// wherever that is not shown: a scene with a BVH, a prim with no known ball (a plane, a
    /// box, a union), a line through a ball.
    ///
    /// It spares the shadow rays of the usual lit point, far from every solid's shadow, the
    /// origin's offset and the ray's scale, which are long chains of dependent arithmetic.
    #[inline]
    pub(crate) fn shadow_certainly_clear(
        &self,
        p: DVec3,
        reach: impl FnOnce() -> f64,
        light: DVec3,
        skip: Option<u32>,
    ) -> bool {
        let Accel::Linear(lone) = &self.accel else {
            return false;
        };
        let reach = reach();
        let line = Ray::new(p, light - p);
        let o2 = p.length_squared();
        lone.balls
            .iter()
            .all(|b| Some(b.object) == skip || b.missed_grown(&line, o2, reach))
    }

    /// Whether a shadow ray leaving object `skip` can be blocked by anything at all.
    pub(crate) fn anything_else(&self, skip: Option<u32>) -> bool {
        match skip {
            Some(_) => self.prims.len() > 1,
            None => !self.prims.is_empty(),
        }
    }

    /// The object a ray leaving `hit` cannot meet again, if any: a convex primitive left
    /// from its outside, never a CSG child (the tree is tested as a whole).
    pub(crate) fn self_skip(&self, hit: &Hit, leaving_outside: bool) -> Option<u32> {
        let obj = &self.objects[hit.object as usize];
        (!obj.in_csg && obj.shape.cannot_rehit(leaving_outside)).then_some(hit.object)
    }
}
