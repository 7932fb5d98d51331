//! Where a ray's line is inside a CSG tree: every child's spans swept in `t` order, with
//! coincident crossings of different children taken as one event (see the module above),
//! and the first boundary a ray meets.

use std::cell::RefCell;

use glam::DVec3;

use crate::math::{Aabb, Ray};
use crate::object::Object;
use crate::scene::CsgOp;
use crate::shape::{Shape, Span};

use super::bounds::{Ball, line_meets};
use super::{Boundary, COINCIDENT_REL, Csg, CsgSpan, Prim, Surface};

/// One end point of a child's span, tagged with the child it came from.
#[derive(Debug, Clone, Copy)]
pub(super) struct Event {
    pub(super) t: f64,
    pub(super) child: u32,
    pub(super) enter: bool,
    pub(super) surface: Surface,
}

/// Buffers reused from ray to ray, so evaluating a tree allocates nothing once they have
/// grown to the size the scene needs. Nodes use them as stacks: each node appends above
/// what its ancestors hold and truncates back when done.
#[derive(Debug, Default)]
pub struct Scratch {
    pub(super) spans: Vec<CsgSpan>,
    pub(super) events: Vec<Event>,
    pub(super) shape: Vec<Span>,
    pub(super) inside: Vec<bool>,
    /// Children an indexed node found for the current ray (see [`ChildIndex`]).
    pub(super) kids: Vec<u32>,
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
    pub(crate) fn balls(&self, objects: &[Object]) -> Vec<Ball> {
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
    #[cfg(test)]
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
    /// surface there. See `first_boundary` for how the surface a ray leaves is told apart.
    ///
    /// The tree's balls (`Ball`) and its box are tested first: only a ray that passes
    /// both takes this thread's scratch buffers (see `with_scratch`) and evaluates the
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
pub(super) fn eval(
    prim: &Prim,
    objects: &[Object],
    ray: &Ray,
    inv: DVec3,
    scale: f64,
    scratch: &mut Scratch,
) {
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
pub(super) fn eval_csg(
    c: &Csg,
    objects: &[Object],
    ray: &Ray,
    inv: DVec3,
    scale: f64,
    scratch: &mut Scratch,
) {
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
pub(super) fn take_events(
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
pub(super) fn pushes_towards(op: CsgOp, e: &Event, entering: bool) -> bool {
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
pub(super) fn ray_scale(ray: &Ray) -> f64 {
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
pub(super) fn tolerance(t0: f64, scale: f64) -> f64 {
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
pub(super) fn lone_spans(
    op: CsgOp,
    n: usize,
    events: &[Event],
) -> Option<impl Iterator<Item = CsgSpan> + '_> {
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
pub(super) fn sweep(op: CsgOp, n: usize, ev_start: usize, scale: f64, scratch: &mut Scratch) {
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
