//! The scene ready to render: objects placed in the world with their materials and loaded
//! textures, CSG trees over them, and the queries rays make of them (nearest hit, any hit).
//!
//! This is where a [`SceneDesc`] meets its assets. Every primitive, inside a CSG tree or
//! not, is an [`Object`] with its full object-to-world transform (a CSG child's own
//! transform followed by those of every enclosing `[CSG]`); the solids a ray is tested
//! against are the [`Prim`]s, each a lone object or a CSG tree over objects. What a pixel
//! looks like is [`crate::render`]'s business; this module only answers "what does this ray
//! hit".
//!
//! Its parts: `build` places a description's objects and loads their textures, `accel`
//! holds how rays find candidate prims (the BVH and the point tables), `intersect` answers
//! nearest hits and `occlude` the shadow rays' any-hit queries. [`Object`] itself lives in
//! `crate::object`, below this module and the CSG and shadow modules that read it.

use glam::DVec3;

use crate::camera::Camera;
use crate::csg::Prim;
use crate::math::Color;
use crate::object::Object;
use crate::sampler::Sampler;
use crate::scene::Light;
use crate::shadow::ClearLights;
use crate::shape::LocalHit;

mod accel;
mod build;
mod intersect;
mod occlude;

use accel::{Accel, PointTables};

/// A nearest hit: which object, and the hit in its object space.
#[derive(Debug, Clone, Copy)]
pub struct Hit {
    /// The primitive whose surface was hit (for a CSG, the child the surface belongs to).
    pub object: u32,
    /// The hit in that primitive's object space; its normal is the outward normal of the
    /// solid the ray met (for a difference's cutter face, the cutter's normal reversed).
    pub local: LocalHit,
}

/// A scene ready to render: built once from a `SceneDesc` and its assets, then shared by
/// every thread that renders a tile of it.
#[derive(Debug, Clone)]
pub struct Scene {
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Ambient light colour: every surface shows its colour times this, lit or not.
    pub ambient: Color,
    /// Fraction of a light's contribution removed where that light is blocked, in [0, 1].
    pub shadow: f64,
    /// Colour of rays that hit nothing.
    pub background: Color,
    /// Most mirror bounces a ray takes.
    pub max_depth: u32,
    /// How pixels are sampled.
    pub sampler: Sampler,
    pub(crate) camera: Camera,
    pub(crate) lights: Vec<Light>,
    /// Every primitive, CSG children included.
    pub(crate) objects: Vec<Object>,
    /// The solids rays are tested against, in the order written. Changing `objects` or
    /// `prims` after [`Scene::build`] leaves the BVH describing the old ones: rebuild it with
    /// [`Scene::with_acceleration`].
    pub(crate) prims: Vec<Prim>,
    /// How rays find the prims they may hit (built from `prims` by [`Scene::build`]).
    accel: Accel,
    /// What rays through the eye or a light find instead of walking the BVH.
    points: PointTables,
    /// The lights each object's shadow rays need not be traced to (see [`crate::shadow`]).
    clear_lights: ClearLights,
    /// Per light, the lone convex objects whose surface passes through it (see
    /// [`Scene::lights_on`]).
    lights_on: Vec<Vec<(u32, DVec3)>>,
    /// How many objects mirror (`mirror > 0`): whether a mirrored ray can come back to a
    /// checkered plane (see [`Scene::checker_step`]).
    pub(crate) mirrors: usize,
    /// Whether the adaptive sampler may sum a checkered plane's cell areas in a pixel
    /// instead of tracing rays there (see `crate::footprint`).
    pub(crate) cell_areas: bool,
}

/// Which way `Scene::intersect` and `Scene::occluded` find candidate prims. Every choice
/// gives the same answers, bit for bit; only the speed differs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Acceleration {
    /// A BVH when there are at least `BVH_MIN_PRIMS` bounded prims or their cost is at
    /// least `BVH_MIN_COST`, else every prim; an index in each union or difference with
    /// at least `crate::csg::CSG_INDEX_MIN` children to index.
    #[default]
    Auto,
    /// Every prim, in order, for every ray, and every CSG child in order (the reference
    /// the BVH and the CSG indices are checked against).
    Off,
    /// A BVH whenever there is at least one bounded prim, and an index in every union and
    /// difference.
    Always,
}

/// Read access for benchmarks and tests to what the scene holds.
#[cfg(feature = "bench")]
impl Scene {
    /// The camera primary rays leave from.
    pub fn camera(&self) -> &Camera {
        &self.camera
    }

    /// The point lights, in the order written.
    pub fn lights(&self) -> &[Light] {
        &self.lights
    }

    /// Every primitive, CSG children included; [`Hit::object`] indexes it.
    pub fn objects(&self) -> &[Object] {
        &self.objects
    }

    /// The solids rays are tested against, in the order written.
    pub fn prims(&self) -> &[Prim] {
        &self.prims
    }
}

#[cfg(test)]
mod tests;
