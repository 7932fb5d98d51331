//! The scene ready to render: objects placed in the world with their materials and loaded
//! textures, and the queries rays make of them (nearest hit, any hit).
//!
//! This is where a [`SceneDesc`] meets its assets. What a pixel looks like is
//! [`crate::render`]'s business; this module only answers "what does this ray hit".

use std::collections::HashMap;
use std::sync::Arc;

use glam::DVec3;

use crate::camera::Camera;
use crate::diag::{Diagnostic, SceneError};
use crate::math::{Aabb, Color, Ray};
use crate::sampler::Sampler;
use crate::scene::{self, Light, Limits, MaterialDesc, Node, SceneDesc};
use crate::shape::{LocalHit, Shape};
use crate::texture::{AssetSource, Texture, TextureLimits};
use crate::transform::Transform;

/// Surface properties with textures loaded.
#[derive(Debug, Clone)]
pub struct Material {
    pub color1: Color,
    pub color2: Option<Color>,
    pub texture: Option<Arc<Texture>>,
    pub mirror: f64,
    pub diffuse: f64,
}

/// A primitive placed in the world.
#[derive(Debug, Clone)]
pub struct Object {
    pub shape: Shape,
    pub transform: Transform,
    /// Unit shape to the shape's own space (where checker cells are unit cubes).
    pub own_scale: DVec3,
    pub material: Material,
    /// World bounds; `None` when unbounded.
    pub bounds: Option<Aabb>,
}

/// A nearest hit: which object, and the hit in its object space.
#[derive(Debug, Clone, Copy)]
pub struct Hit {
    pub object: u32,
    pub local: LocalHit,
}

/// A scene ready to render.
#[derive(Debug, Clone)]
pub struct Scene {
    pub width: u32,
    pub height: u32,
    pub ambient: Color,
    pub shadow: f64,
    pub background: Color,
    pub max_depth: u32,
    pub sampler: Sampler,
    pub camera: Camera,
    pub lights: Vec<Light>,
    pub objects: Vec<Object>,
}

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
        let mut textures: HashMap<&str, Arc<Texture>> = HashMap::new();
        let mut errors = Vec::new();
        for (name, pos) in desc.texture_names() {
            let loaded = assets
                .load(name)
                .and_then(|bytes| Texture::decode(name, &bytes, texture_limits));
            match loaded {
                Ok(t) => {
                    textures.insert(name, Arc::new(t));
                }
                Err(e) => errors.push(Diagnostic::new(pos, e.to_string())),
            }
        }
        let mut objects = Vec::with_capacity(desc.primitive_count());
        for node in &desc.objects {
            match node {
                Node::Object(o) => {
                    let material = material(&o.material, &textures);
                    let bounds = o.shape.bounds().map(|b| o.transform.bounds_to_world(&b));
                    objects.push(Object {
                        shape: o.shape,
                        transform: o.transform,
                        own_scale: o.own_scale,
                        material,
                        bounds,
                    });
                }
                Node::Csg(c) => errors.push(Diagnostic::new(
                    c.pos,
                    "[CSG] is not supported by this build of the tracer",
                )),
            }
        }
        if !errors.is_empty() {
            return Err(SceneError::new(errors));
        }
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
            objects,
        })
    }

    /// The nearest hit with `0 < t < t_max`. `skip` names an object the ray cannot meet
    /// again (see [`Shape::cannot_rehit`]), which is then not tested at all.
    #[inline]
    pub fn intersect(&self, ray: &Ray, t_max: f64, skip: Option<u32>) -> Option<Hit> {
        let mut best: Option<Hit> = None;
        let mut t_best = t_max;
        for (i, obj) in self.objects.iter().enumerate() {
            let i = i as u32;
            if skip == Some(i) {
                continue;
            }
            let local_ray = obj.transform.ray_to_object(ray);
            if let Some(h) = obj.shape.intersect(&local_ray, t_best) {
                t_best = h.t;
                best = Some(Hit {
                    object: i,
                    local: h,
                });
            }
        }
        best
    }

    /// Whether anything lies on the ray with `0 < t < t_max`.
    #[inline]
    pub fn occluded(&self, ray: &Ray, t_max: f64, skip: Option<u32>) -> bool {
        self.objects.iter().enumerate().any(|(i, obj)| {
            skip != Some(i as u32)
                && obj
                    .shape
                    .intersect(&obj.transform.ray_to_object(ray), t_max)
                    .is_some()
        })
    }

    /// Whether a shadow ray leaving object `skip` can be blocked by anything at all.
    pub fn anything_else(&self, skip: Option<u32>) -> bool {
        match skip {
            Some(_) => self.objects.len() > 1,
            None => !self.objects.is_empty(),
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
