//! How rays find the prims they may hit: every prim in turn, or a BVH over the bounded
//! ones, and the point tables for rays from the eye or a light. Built once by
//! [`Scene::build`](super::Scene::build); read by the hit and shadow queries.

use glam::DVec3;

use crate::bvh::{Bvh, Item};
#[cfg(doc)]
use crate::csg::Ball;
use crate::csg::Prim;
use crate::math::{Aabb, Ray};
use crate::object::{Object, line_clears_ball};
use crate::point_index::{self, PointIndex};
use crate::scene::Light;

use super::Acceleration;
use crate::bvh::BVH_MIN_PRIMS;

/// What the BVH search reads first about each of its prims, packed in the tree's item
/// order so that a leaf's prims share cache lines: most candidates of a scene of many small
/// spheres are rejected here without touching the prim or its object.
#[derive(Debug, Clone, Copy)]
pub(super) struct Quick {
    /// Index into `Scene::prims`.
    pub(super) prim: u32,
    /// The similarity sphere's world centre and squared radius; `r2 = ∞` for every other
    /// prim (see [`crate::object::quick_missed`]).
    pub(super) centre: DVec3,
    pub(super) r2: f64,
}

/// ... or when testing every bounded prim costs at least as much as testing
/// [`BVH_MIN_PRIMS`] similarity spheres (`prim_cost` units: such a sphere 1, another
/// object 2, a CSG tree 2 per child it may evaluate, see [`Csg::cost`]). A few expensive
/// solids gain from a BVH long before eight do (four general shapes, as in
/// `examples/shapes.ray`, cost 8), while scenes of one or two solids (cost ≤ 4) are slower
/// with one and stay linear; docs/PERFORMANCE.md has the figures.
pub(super) const BVH_MIN_COST: f64 = BVH_MIN_PRIMS as f64 * SPHERE_COST;

/// What the plain loop reads of each prim, in prim order.
#[derive(Debug, Clone, Default)]
pub(super) struct Lone {
    /// Per prim, a ball every line meeting it meets, for
    /// [`Scene::shadow_certainly_clear`](super::Scene::shadow_certainly_clear).
    pub(super) balls: Vec<ShadowBall>,
}

/// A ball about a prim, with the margin its test needs: a lone sphere placed by a
/// similarity has its own ball, tested as its quick test is
/// ([`crate::object::quick_missed`]); another sphere turned as well, and a CSG tree, the
/// first of the balls of `Prim::balls`, tested as a tree tests them ([`Ball`], whose margin
/// grows with the coordinates' magnitude); any other prim (a plane, a box, a union) a ball
/// of infinite radius, which no line misses.
#[derive(Debug, Clone, Copy)]
pub(super) struct ShadowBall {
    /// The object the prim is (`u32::MAX` for a CSG tree).
    pub(super) object: u32,
    pub(super) centre: DVec3,
    pub(super) r2: f64,
    /// For a [`Ball`]: `|c|²`, which its margin adds to `|o|²`.
    ball_c2: Option<f64>,
}

impl ShadowBall {
    /// The ball of `prim`.
    fn of(prim: &Prim, objects: &[Object]) -> ShadowBall {
        let object = match prim {
            Prim::Object(o) => *o,
            Prim::Csg(_) => u32::MAX,
        };
        if let Prim::Object(o) = prim
            && let Some((centre, r2)) = objects[*o as usize].sphere
        {
            return ShadowBall {
                object,
                centre,
                r2,
                ball_c2: None,
            };
        }
        match prim.balls(objects).first() {
            Some(b) => ShadowBall {
                object,
                centre: b.centre,
                r2: b.r2,
                ball_c2: Some(b.centre.length_squared()),
            },
            None => ShadowBall {
                object,
                centre: DVec3::ZERO,
                r2: f64::INFINITY,
                ball_c2: None,
            },
        }
    }

    /// The ball that no line is ever shown to miss.
    #[cfg(feature = "bench")]
    pub(super) fn never_missed(self) -> ShadowBall {
        ShadowBall {
            r2: f64::INFINITY,
            ..self
        }
    }

    /// Whether the line of `ray` certainly misses this ball grown by `reach`, by the margin
    /// of the prim's own test: then so does every segment each of whose points lies within
    /// `reach` of the line, and the prim's test finds no hit on it. `o2` is
    /// `|ray.origin|²`. The grown ball's squared radius is bounded above by
    /// `(1 + η)·r² + (1 + 1/η)·reach²` (as `2·r·reach ≤ η·r² + reach²/η`), with
    /// `η = 10⁻⁶`, which keeps the test free of a square root. A NaN or infinite `reach`
    /// or radius shows nothing missed.
    #[inline]
    pub(super) fn missed_grown(&self, ray: &Ray, o2: f64, reach: f64) -> bool {
        let r2 = self.r2 * (1.0 + 1e-6) + reach * reach * (1.0 + 1e6);
        let extra = self.ball_c2.map_or(0.0, |c2| o2 + c2);
        line_clears_ball(self.centre, r2, ray, extra)
    }
}

/// The acceleration structure of a scene.
#[derive(Debug, Clone)]
pub(super) enum Accel {
    /// Test every prim in order, a similarity sphere first by its quick test.
    Linear(Lone),
    /// A BVH over the bounded prims (items are indices into `prims`) and the prims without
    /// a usable box (planes, unbounded CSG), tested every time.
    Bvh {
        bvh: Bvh,
        unbounded: Vec<u32>,
        /// Per BVH item slot (see [`Bvh::items`]).
        quick: Vec<Quick>,
    },
}

/// Each bounded prim with its box and what testing it costs, in prim order.
pub(super) fn bounded_prims(prims: &[Prim], objects: &[Object]) -> Vec<(u32, Aabb, f64)> {
    prims
        .iter()
        .enumerate()
        .filter_map(|(i, p)| {
            Some((
                u32::try_from(i).ok()?,
                p.bounds(objects)?,
                prim_cost(p, objects),
            ))
        })
        .collect()
}

/// What the BVH is built over: each bounded prim's box, or a long object's slices (see
/// [`Object::pieces`]), in prim order.
pub(super) fn bvh_items(
    prims: &[Prim],
    objects: &[Object],
    bounded: &[(u32, Aabb, f64)],
) -> Vec<Item> {
    let mut items: Vec<Item> = Vec::with_capacity(bounded.len());
    for &(id, bounds, cost) in bounded {
        let pieces = match &prims[id as usize] {
            Prim::Object(o) => objects[*o as usize].pieces(),
            Prim::Csg(_) => Vec::new(),
        };
        if pieces.is_empty() {
            items.push(Item { id, bounds, cost });
        } else {
            items.extend(pieces.into_iter().map(|bounds| Item { id, bounds, cost }));
        }
    }
    items
}

/// The tables of rays through the eye and through each light (see [`crate::point_index`]),
/// beside the BVH they stand in for.
#[derive(Debug, Clone, Default)]
pub(super) struct PointTables {
    pub(super) eye: Option<PointIndex>,
    /// Per light (the first [`point_index::MAX_LIGHTS`]).
    pub(super) lights: Vec<Option<PointIndex>>,
    /// Per prim: a similarity sphere's centre and squared radius (`r2 = ∞` for any other
    /// prim), for the quick test of listed prims (see [`crate::object::quick_missed`]).
    pub(super) quick: Vec<(DVec3, f64)>,
}

impl PointTables {
    /// The tables a scene with this BVH gains from: with `Auto`, when it has at least
    /// [`point_index::MIN_BOXES`] BVH boxes and its image at least
    /// [`point_index::PIXELS_PER_BOX`] `pixels` per box to list; with `Always`, whenever it
    /// has a BVH.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn new(
        prims: &[Prim],
        objects: &[Object],
        accel: &Accel,
        bvh_items: &[Item],
        eye: DVec3,
        lights: &[Light],
        mode: Acceleration,
        pixels: u64,
    ) -> PointTables {
        if accel.bvh().is_none() {
            return PointTables::default();
        }
        let wanted = match mode {
            Acceleration::Off => false,
            Acceleration::Auto => bvh_items.len() >= point_index::MIN_BOXES,
            Acceleration::Always => true,
        };
        if !wanted {
            return PointTables::default();
        }
        // The BVH's own boxes: padded as it pads them, those it leaves out left out here too.
        let items: Vec<(u32, Aabb, f64)> = bvh_items
            .iter()
            .filter_map(|it| Some((it.id, crate::bvh::padded(&it.bounds)?, it.cost)))
            .collect();
        if mode == Acceleration::Auto
            && pixels < point_index::PIXELS_PER_BOX.saturating_mul(items.len() as u64)
        {
            return PointTables::default();
        }
        let quick = prims.iter().map(|p| quick_of(p, objects)).collect();
        // The eye's first, then the lights' in order, while the budget lasts: each table
        // lists every solid at least once, so once fewer entries than items are left, no
        // further table is tried (a scene of many solids under many lights spent seconds
        // trying, and failing, one table after another).
        let mut left = point_index::MAX_ENTRIES;
        let mut build = |p: DVec3| {
            if left < items.len() {
                return None;
            }
            let table = PointIndex::build(p, &items, left);
            left = match &table {
                Some(t) => left - t.size().0 - t.size().1,
                None => 0,
            };
            table
        };
        PointTables {
            eye: build(eye),
            lights: lights
                .iter()
                .take(point_index::MAX_LIGHTS)
                .map(|l| build(l.position))
                .collect(),
            quick,
        }
    }
}

/// What testing a prim costs in the BVH's SAH, in units of one binary split's node visit
/// (a two-box slab test, about 50 instructions; the tree's four-wide nodes test two such
/// splits at once). A sphere placed by a similarity is mostly
/// rejected by its packed pre-test before its object is touched, and is costed as one
/// visit (with the miss bookkeeping); any other object carries the ray into its own space
/// and solves its shape; a CSG tree does that for each child it reaches. Only the ratios
/// matter, and only roughly: they decide how many items a leaf holds, and the scaling
/// scenes barely tell a sphere cost of 0.3 from one of 1.
pub(super) fn prim_cost(prim: &Prim, objects: &[Object]) -> f64 {
    match prim {
        Prim::Object(o) if objects[*o as usize].sphere.is_some() => SPHERE_COST,
        Prim::Object(_) => 2.0,
        Prim::Csg(c) => c.cost(),
    }
}

/// SAH cost of a sphere placed by a similarity (see [`prim_cost`]).
pub(super) const SPHERE_COST: f64 = 1.0;

impl Default for Accel {
    /// The plain loop over no prims.
    fn default() -> Accel {
        Accel::Linear(Lone::default())
    }
}

/// A prim's quick test: a similarity sphere's world centre and squared radius, `r2 = ∞` for
/// every other prim (see [`crate::object::quick_missed`]).
fn quick_of(prim: &Prim, objects: &[Object]) -> (DVec3, f64) {
    let sphere = match prim {
        Prim::Object(o) => objects[*o as usize].sphere,
        Prim::Csg(_) => None,
    };
    sphere.unwrap_or((DVec3::ZERO, f64::INFINITY))
}

impl Accel {
    /// The BVH, if there is one.
    pub(super) fn bvh(&self) -> Option<&Bvh> {
        match self {
            Accel::Linear(_) => None,
            Accel::Bvh { bvh, .. } => Some(bvh),
        }
    }

    /// The search `mode` asks for, with the items its BVH was built over (none for the plain
    /// loop), which the point tables list too.
    pub(super) fn new(
        prims: &[Prim],
        objects: &[Object],
        mode: Acceleration,
    ) -> (Accel, Vec<Item>) {
        let bounded = bounded_prims(prims, objects);
        let wanted = match mode {
            Acceleration::Off => false,
            Acceleration::Auto => {
                bounded.len() >= BVH_MIN_PRIMS
                    || bounded.iter().map(|&(_, _, cost)| cost).sum::<f64>() >= BVH_MIN_COST
            }
            Acceleration::Always => !bounded.is_empty(),
        };
        // Prim indices fit in u32 (objects do, and every prim has at least one); a scene
        // where they did not would simply stay linear.
        if !wanted || u32::try_from(prims.len()).is_err() {
            let lone = Lone {
                balls: prims.iter().map(|p| ShadowBall::of(p, objects)).collect(),
            };
            return (Accel::Linear(lone), Vec::new());
        }
        let items = bvh_items(prims, objects, &bounded);
        let (bvh, mut unbounded) = Bvh::build_items(&items);
        unbounded.extend(
            prims
                .iter()
                .enumerate()
                .filter(|(_, p)| p.bounds(objects).is_none())
                .map(|(i, _)| i as u32),
        );
        unbounded.sort_unstable();
        let quick = bvh
            .items()
            .iter()
            .map(|&i| {
                let (centre, r2) = quick_of(&prims[i as usize], objects);
                Quick {
                    prim: i,
                    centre,
                    r2,
                }
            })
            .collect();
        let accel = Accel::Bvh {
            bvh,
            unbounded,
            quick,
        };
        (accel, items)
    }
}
