//! Building a [`Scene`](super::Scene) from a description: placing objects and CSG trees
//! with their composite transforms and materials, loading textures, and the switches that
//! choose how rays find prims.

use std::collections::HashMap;
use std::sync::Arc;

use glam::DVec3;

use crate::bvh::Bvh;
use crate::camera::Camera;
use crate::csg::{Csg, Prim};
use crate::diag::{Diagnostic, SceneError};
use crate::object::{Material, Object};
use crate::scene::{self, Limits, MaterialDesc, Node, SceneDesc};
use crate::shadow::ClearLights;
use crate::texture::{AssetSource, Texture, TextureError, TextureLimits};
use crate::transform::Transform;

use super::accel::{Accel, PointTables};
use super::{Acceleration, Scene};

impl Scene {
    /// Parses `.ray` text and loads its textures: the one call a renderer needs.
    pub fn from_source(
        source: &str,
        limits: &Limits,
        assets: &dyn AssetSource,
        texture_limits: &TextureLimits,
    ) -> Result<Scene, SceneError> {
        let desc = scene::parse(source, limits)?;
        Scene::build(&desc, assets, texture_limits)
    }

    /// Loads the textures a description names and places its objects in the world. A texture
    /// that cannot be read or decoded is reported at the position of its name.
    pub fn build(
        desc: &SceneDesc,
        assets: &dyn AssetSource,
        texture_limits: &TextureLimits,
    ) -> Result<Scene, SceneError> {
        let (objects, prims) = Self::place(desc, assets, texture_limits)?;
        let (accel, items) = Accel::new(&prims, &objects, Acceleration::Auto);
        let clear_lights = ClearLights::find(&objects, &prims, &desc.lights, accel.bvh());
        let points = PointTables::new(
            &prims,
            &objects,
            &accel,
            &items,
            desc.camera.eye,
            &desc.lights,
            Acceleration::Auto,
            u64::from(desc.width) * u64::from(desc.height),
        );
        let lights_on = desc
            .lights
            .iter()
            .map(|l| surfaces_through(&objects, &prims, &accel, l.position))
            .collect();
        Ok(Scene {
            width: desc.width,
            height: desc.height,
            ambient: desc.ambient,
            shadow: desc.shadow,
            background: desc.background,
            max_depth: desc.max_depth,
            sampler: desc.sampler,
            camera: Camera::new(&desc.camera, desc.width, desc.height),
            lights: desc.lights.clone(),
            accel,
            points,
            clear_lights,
            lights_on,
            mirrors: objects.iter().filter(|o| o.material.mirror > 0.0).count(),
            cell_areas: true,
            objects,
            prims,
        })
    }

    /// Every error [`Self::build`] would report (textures that cannot be read or decoded,
    /// singular transforms), without building what only rendering needs: no object is
    /// placed (so checking a scene costs its textures, not a second copy of its objects),
    /// and no BVH or clear lights are built. What a service that accepts scenes but does
    /// not render them checks.
    pub fn check(
        desc: &SceneDesc,
        assets: &dyn AssetSource,
        texture_limits: &TextureLimits,
    ) -> Result<(), SceneError> {
        let (_, mut errors) = Self::load_textures(desc, assets, texture_limits);
        let mut objects = 0usize;
        for node in &desc.objects {
            check_node(node, None, &mut objects, &mut errors);
        }
        if errors.is_empty() {
            Ok(())
        } else {
            Err(SceneError::new(errors))
        }
    }

    /// The scene's textures, loaded and decoded within `texture_limits`, with an error for
    /// each that could not be.
    fn load_textures<'d>(
        desc: &'d SceneDesc,
        assets: &dyn AssetSource,
        texture_limits: &TextureLimits,
    ) -> (HashMap<&'d str, Arc<Texture>>, Vec<Diagnostic>) {
        let mut textures: HashMap<&str, Arc<Texture>> = HashMap::new();
        let mut errors = Vec::new();
        // Texels of the textures decoded so far, against `max_total_pixels`: each is sized
        // from its header before it is decoded, so the budget holds while loading too.
        let mut total: u64 = 0;
        for (name, pos) in desc.texture_names() {
            let loaded = assets.load(name).and_then(|bytes| {
                let (w, h) = Texture::dimensions(name, &bytes, texture_limits)?;
                let texels = u64::from(w) * u64::from(h);
                if total + texels > texture_limits.max_total_pixels {
                    return Err(TextureError::TooMuch {
                        name: name.to_string(),
                        texels,
                        total: total + texels,
                        limit: texture_limits.max_total_pixels,
                    });
                }
                total += texels;
                Texture::decode_sized(name, &bytes, texture_limits, (w, h))
            });
            match loaded {
                Ok(t) => {
                    textures.insert(name, Arc::new(t));
                }
                Err(e) => errors.push(Diagnostic::new(pos, e.to_string())),
            }
        }
        (textures, errors)
    }

    /// The textures loaded and the objects placed in the world, or every error found.
    pub(super) fn place(
        desc: &SceneDesc,
        assets: &dyn AssetSource,
        texture_limits: &TextureLimits,
    ) -> Result<(Vec<Object>, Vec<Prim>), SceneError> {
        let (textures, mut errors) = Self::load_textures(desc, assets, texture_limits);
        let mut objects = Vec::with_capacity(desc.primitive_count());
        let mut prims = Vec::with_capacity(desc.objects.len());
        for node in &desc.objects {
            let mut placer = Placer {
                objects: &mut objects,
                textures: &textures,
                errors: &mut errors,
            };
            if let Some(p) = placer.place(node, None) {
                prims.push(p);
            }
        }
        if !errors.is_empty() {
            return Err(SceneError::new(errors));
        }
        Ok((objects, prims))
    }

    /// The same scene with its candidate search rebuilt as `mode` says (and its clear
    /// lights found again, see `crate::shadow`). The images are the same whatever the
    /// mode; tests and benchmarks use [`Acceleration::Off`] as the reference.
    pub fn with_acceleration(mut self, mode: Acceleration) -> Scene {
        // CSG nodes with many children carry their own index (see `crate::csg`): kept at its
        // threshold by `Auto`, on every union and difference by `Always`, none with `Off`.
        let min = match mode {
            Acceleration::Auto => crate::csg::CSG_INDEX_MIN,
            Acceleration::Always => 1,
            Acceleration::Off => usize::MAX,
        };
        for prim in &mut self.prims {
            if let Prim::Csg(c) = prim {
                c.index_children(min);
            }
        }
        let items;
        (self.accel, items) = Accel::new(&self.prims, &self.objects, mode);
        self.points = PointTables::new(
            &self.prims,
            &self.objects,
            &self.accel,
            &items,
            self.camera.eye(),
            &self.lights,
            mode,
            u64::from(self.width) * u64::from(self.height),
        );
        self.clear_lights =
            ClearLights::find(&self.objects, &self.prims, &self.lights, self.accel.bvh());
        self
    }

    /// The same scene with its BVH but without the tables of rays through the eye and the
    /// lights (`crate::point_index`): every ray walks the tree. The reference the tables'
    /// tests and the benchmark compare against (the images are the same).
    #[cfg(feature = "bench")]
    pub fn without_point_tables(mut self) -> Scene {
        self.points = PointTables::default();
        self
    }

    /// Whether rays through the eye, and through how many lights, look up a table of their
    /// own (see `crate::point_index`).
    #[cfg(feature = "bench")]
    pub fn point_tables(&self) -> (bool, usize) {
        (
            self.points.eye.is_some(),
            self.points.lights.iter().filter(|l| l.is_some()).count(),
        )
    }

    /// The same scene without the adaptive sampler's sums of checker cell areas: its
    /// checkered planes are refined by rays alone, as on any other surface. What the tests of
    /// the ray rules render.
    #[cfg(feature = "bench")]
    pub fn without_cell_areas(mut self) -> Scene {
        self.cell_areas = false;
        self
    }

    /// The same scene tracing every shadow ray, even those `crate::shadow` knows cannot be
    /// blocked and those `Scene::shadow_certainly_clear` shows clear: the reference that
    /// tests and benchmarks compare the culling against (the images are the same).
    #[cfg(feature = "bench")]
    pub fn without_shadow_culling(mut self) -> Scene {
        self.clear_lights = ClearLights::default();
        if let Accel::Linear(lone) = &mut self.accel {
            for ball in &mut lone.balls {
                *ball = ball.never_missed();
            }
        }
        self
    }

    /// The lone convex objects whose surface passes through light `light` (within the
    /// rounding of carrying the light into their space), each with its world outward normal
    /// there ([`Object::normals_through`]), once per supporting plane. Such an object cannot
    /// shadow its light from a point on the outer side of its tangent plane there: the object lies in the other
    /// half-space, and the segment meets it only at the light, which SCENE.md's segment
    /// does not include. Tracing it anyway decides by rounding: a shadow ray reaching the
    /// light nearly tangent meets the surface in two nearly equal roots, known only to
    /// about √ε, and some of them fall before the light.
    pub(crate) fn lights_on(&self, light: usize) -> &[(u32, DVec3)] {
        self.lights_on.get(light).map_or(&[], Vec::as_slice)
    }

    /// Whether a shadow ray from `object` (convex, left from outside) to light `light` is
    /// known not to be blocked without tracing it.
    #[cfg(test)]
    pub(crate) fn light_is_clear(&self, object: u32, light: usize) -> bool {
        self.clear_lights.is_clear(object, light)
    }

    /// [`Self::light_is_clear`] for the first 64 lights at once, bit `l` for light `l`.
    #[inline]
    pub(crate) fn clear_lights(&self, object: u32) -> u64 {
        self.clear_lights.mask(object)
    }

    /// [`Self::clear_lights`] at the point of object-space height `y` on `object`: a long
    /// cylinder's or cone's slice may have lights clear that the whole has not (see
    /// `ClearLights::mask_at`).
    #[inline]
    pub(crate) fn clear_lights_at(&self, object: u32, y: f64) -> u64 {
        self.clear_lights.mask_at(object, y)
    }

    /// The same scene tested prim by prim for every ray (no BVH).
    #[cfg(feature = "bench")]
    pub fn without_acceleration(self) -> Scene {
        self.with_acceleration(Acceleration::Off)
    }

    /// The BVH and the prims it leaves out (planes, unbounded CSG), when rays use one.
    pub(crate) fn bvh_and_unbounded(&self) -> Option<(&Bvh, &[u32])> {
        match &self.accel {
            Accel::Linear(_) => None,
            Accel::Bvh { bvh, unbounded, .. } => Some((bvh, unbounded)),
        }
    }

    /// Whether rays go through a BVH.
    #[cfg(feature = "bench")]
    pub fn uses_bvh(&self) -> bool {
        matches!(self.accel, Accel::Bvh { .. })
    }
}

/// The lone objects whose surface passes through `p`, with the normals of their supporting
/// planes there (see [`Object::normals_through`]). Only the solids whose (padded) boxes hold `p` are asked,
/// found through the BVH when the scene has one, so that a thousand lights over a million
/// objects cost a point query each, not a billion tests.
fn surfaces_through(
    objects: &[Object],
    prims: &[Prim],
    accel: &Accel,
    p: DVec3,
) -> Vec<(u32, DVec3)> {
    let mut found = Vec::new();
    let mut ask = |pi: u32| {
        // A long object is in the tree once per slice: asked once.
        if let Prim::Object(o) = prims[pi as usize]
            && !found.iter().any(|e: &(u32, DVec3)| e.0 == o)
        {
            for n in objects[o as usize].normals_through(p) {
                found.push((o, n));
            }
        }
    };
    match accel {
        Accel::Linear(_) => (0..prims.len() as u32).for_each(&mut ask),
        Accel::Bvh { bvh, unbounded, .. } => {
            unbounded.iter().copied().for_each(&mut ask);
            bvh.any_item(
                |b| b.contains(p),
                |pi| {
                    ask(pi);
                    false
                },
            );
        }
    }
    // In the order the objects are written, whatever order the tree met them in.
    found.sort_by_key(|e| e.0);
    found
}

/// The message of an object whose composed transform cannot be used.
const SINGULAR_OBJECT: &str =
    "this object's transforms and those of its [CSG] make a singular or non-finite matrix";

/// The message of a [CSG] whose composed transform cannot be used.
const SINGULAR_CSG: &str = "this [CSG]'s transforms and those of its enclosing [CSG] make a \
                            singular or non-finite matrix";

/// The message of the object past the most one scene can index.
const TOO_MANY: &str = "too many objects for one scene";

/// The transform of a node placed inside `outer` (its enclosing CSG's), if any.
fn composed(own: &Transform, outer: Option<&Transform>) -> Transform {
    match outer {
        Some(o) => own.then(o),
        None => *own,
    }
}

/// The errors [`Placer::place`] would find in `node`, found without placing it: the same
/// transforms composed in the same order, the same count of objects. `objects` counts the
/// objects met so far.
fn check_node(
    node: &Node,
    outer: Option<&Transform>,
    objects: &mut usize,
    errors: &mut Vec<Diagnostic>,
) {
    match node {
        Node::Object(o) => {
            if !composed(&o.transform, outer).is_valid() {
                errors.push(Diagnostic::new(o.pos, SINGULAR_OBJECT));
            } else if u32::try_from(*objects).is_err() {
                errors.push(Diagnostic::new(o.pos, TOO_MANY));
            } else {
                *objects += 1;
            }
        }
        Node::Csg(c) => {
            let transform = composed(&c.transform, outer);
            if !transform.is_valid() {
                errors.push(Diagnostic::new(c.pos, SINGULAR_CSG));
                return;
            }
            for ch in &c.children {
                check_node(ch, Some(&transform), objects, errors);
            }
        }
    }
}

/// Places scene nodes in the world, flattening their primitives into `objects`.
struct Placer<'a, 'b> {
    objects: &'a mut Vec<Object>,
    textures: &'a HashMap<&'b str, Arc<Texture>>,
    errors: &'a mut Vec<Diagnostic>,
}

impl Placer<'_, '_> {
    /// The prim for a node; `outer` is the enclosing CSG's object-to-world transform.
    pub(super) fn place(&mut self, node: &Node, outer: Option<&Transform>) -> Option<Prim> {
        match node {
            Node::Object(o) => {
                let transform = composed(&o.transform, outer);
                if !transform.is_valid() {
                    self.errors.push(Diagnostic::new(o.pos, SINGULAR_OBJECT));
                    return None;
                }
                let Ok(index) = u32::try_from(self.objects.len()) else {
                    self.errors.push(Diagnostic::new(o.pos, TOO_MANY));
                    return None;
                };
                self.objects.push(Object::new(
                    o.shape,
                    transform,
                    o.own_scale,
                    material(&o.material, self.textures),
                    outer.is_some(),
                ));
                Some(Prim::Object(index))
            }
            Node::Csg(c) => {
                let transform = composed(&c.transform, outer);
                if !transform.is_valid() {
                    self.errors.push(Diagnostic::new(c.pos, SINGULAR_CSG));
                    return None;
                }
                let children: Vec<Prim> = c
                    .children
                    .iter()
                    .filter_map(|ch| self.place(ch, Some(&transform)))
                    .collect();
                Some(Prim::Csg(Csg::new(c.op, children, self.objects)))
            }
        }
    }
}

fn material(m: &MaterialDesc, textures: &HashMap<&str, Arc<Texture>>) -> Material {
    Material {
        color1: m.color1,
        color2: m.color2,
        texture: m
            .texture
            .as_ref()
            .and_then(|t| textures.get(t.name.as_str()).cloned()),
        mirror: m.mirror,
        diffuse: m.diffuse,
    }
}
