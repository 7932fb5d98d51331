//! The scene as written: the `.ray` language's data model and its parser.
//!
//! [`parse`] turns `.ray` text into a [`SceneDesc`], checking everything that can be checked
//! without reading other files: tags, keys, value types and ranges, required keys, the
//! camera, singular transforms and the configured [`Limits`]. Texture files are only named
//! here; [`crate::Scene::build`] loads them through an [`crate::AssetSource`]. This module
//! does not trace rays.

mod blocks;
mod lex;
mod parse;
mod value;

use glam::DVec3;

pub use blocks::MAX_BLOCK_ENTRIES;
pub use parse::parse;
pub use value::MAX_NUMBER;

use crate::diag::Pos;
use crate::math::Color;
use crate::sampler::Sampler;
use crate::shape::Shape;
use crate::transform::Transform;

/// The largest scene file `tessera-render` reads, in bytes. A scene at the object limit
/// (1,000,000 objects) is about 70 MB as usually written; the cap is there for the wrong
/// file (`/dev/zero`, a disk image), which would be read until memory ran out. The service's
/// request-body limit bounds what it accepts.
pub const MAX_SCENE_FILE_BYTES: u64 = 256 * 1024 * 1024;

/// Caps on what a scene may ask for, so that hostile input cannot exhaust memory or time.
/// The defaults suit a local renderer; a service may configure tighter ones.
#[derive(Debug, Clone, PartialEq)]
pub struct Limits {
    /// Largest `width` or `height`.
    pub max_dimension: u32,
    /// Largest `width × height`.
    pub max_pixels: u64,
    /// Most `[OBJECT]` blocks in the file, CSG children included.
    pub max_objects: usize,
    /// Deepest nesting of `[CSG]` blocks.
    pub max_csg_depth: usize,
    /// Most lights (`[LIGHT]` blocks plus the globals' `light`).
    pub max_lights: usize,
    /// Most distinct texture files.
    pub max_textures: usize,
    /// Largest `max_depth` (mirror bounces).
    pub max_bounces: u32,
    /// Largest `samples` (per axis: the sample count per pixel is its square).
    pub max_samples: u32,
}

impl Default for Limits {
    fn default() -> Self {
        Limits {
            max_dimension: 32_768,
            max_pixels: 268_435_456, // 16384 × 16384
            max_objects: 1_000_000,
            max_csg_depth: 64,
            max_lights: 1_024,
            max_textures: 256,
            max_bounces: 64,
            max_samples: 32,
        }
    }
}

/// A parsed, validated scene, before its textures are loaded.
#[derive(Debug, Clone, PartialEq)]
pub struct SceneDesc {
    /// Image width in pixels (`width` in `[GLOBALS]`).
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
    /// The camera.
    pub camera: CameraDesc,
    /// The point lights: the globals' `light` first, then each `[LIGHT]` in order.
    pub lights: Vec<Light>,
    /// The top-level objects and CSG trees, in the order written.
    pub objects: Vec<Node>,
}

impl SceneDesc {
    /// Every texture file name the scene uses, each once, with the position of its first use.
    pub fn texture_names(&self) -> Vec<(&str, Pos)> {
        let mut out: Vec<(&str, Pos)> = Vec::new();
        fn walk<'a>(node: &'a Node, out: &mut Vec<(&'a str, Pos)>) {
            match node {
                Node::Object(o) => {
                    if let Some(t) = &o.material.texture
                        && !out.iter().any(|(n, _)| *n == t.name)
                    {
                        out.push((&t.name, t.pos));
                    }
                }
                Node::Csg(c) => c.children.iter().for_each(|ch| walk(ch, out)),
            }
        }
        self.objects.iter().for_each(|n| walk(n, &mut out));
        out
    }

    /// Number of primitive objects (CSG children counted, CSG nodes not).
    pub fn primitive_count(&self) -> usize {
        fn count(n: &Node) -> usize {
            match n {
                Node::Object(_) => 1,
                Node::Csg(c) => c.children.iter().map(count).sum(),
            }
        }
        self.objects.iter().map(count).sum()
    }
}

/// The camera as given: eye, target, up and vertical field of view in degrees.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CameraDesc {
    /// Where the camera is.
    pub eye: DVec3,
    /// The point the view is centred on.
    pub look_at: DVec3,
    /// Which way is up in the image (need not be perpendicular to the view).
    pub up: DVec3,
    /// Vertical field of view, in degrees.
    pub fov_degrees: f64,
}

impl Default for CameraDesc {
    fn default() -> Self {
        CameraDesc {
            eye: DVec3::new(0.0, 0.0, 100.0),
            look_at: DVec3::ZERO,
            up: DVec3::Y,
            fov_degrees: 30.0,
        }
    }
}

/// A point light, no fall-off.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Light {
    /// Where the light is.
    pub position: DVec3,
    /// Its colour and strength (components may exceed 1).
    pub color: Color,
}

/// An object or a CSG combination of them.
#[derive(Debug, Clone, PartialEq)]
pub enum Node {
    /// One primitive.
    Object(ObjectDesc),
    /// A set operation over its children.
    Csg(CsgDesc),
}

/// One `[OBJECT]`: a unit shape, its material, and where it is placed.
#[derive(Debug, Clone, PartialEq)]
pub struct ObjectDesc {
    /// Position of the `[OBJECT]` tag.
    pub pos: Pos,
    /// The unit shape.
    pub shape: Shape,
    /// Scale from the unit shape to the shape's own space, from its own keys (a sphere of
    /// `radius = r` is the unit sphere scaled by `r`). Checker cells are unit cubes of the
    /// own space.
    pub own_scale: DVec3,
    /// Unit shape to world (or to the enclosing CSG's space), own scale included.
    pub transform: Transform,
    /// How its surface looks.
    pub material: MaterialDesc,
}

/// Surface properties of an object.
#[derive(Debug, Clone, PartialEq)]
pub struct MaterialDesc {
    /// The colour, or a checker's first colour.
    pub color1: Color,
    /// A checker's second colour: with it, the surface is a checker of unit cells of the
    /// shape's own space.
    pub color2: Option<Color>,
    /// An image mapped onto the surface by its u, v coordinates (instead of the colours).
    pub texture: Option<TextureRef>,
    /// Mirror weight `m` in [0, 1]: a pixel is `(1 − m)·local + m·(what the mirror ray sees)`.
    pub mirror: f64,
    /// Weight `k` of the lights' Lambertian term in the local colour.
    pub diffuse: f64,
}

impl Default for MaterialDesc {
    fn default() -> Self {
        MaterialDesc {
            color1: Color::ONE,
            color2: None,
            texture: None,
            mirror: 0.0,
            diffuse: 1.0,
        }
    }
}

/// A texture file named by a scene, with the position of the name.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TextureRef {
    /// The file name as written, relative to the scene's folder.
    pub name: String,
    /// Where the name is written.
    pub pos: Pos,
}

/// The CSG set operations.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CsgOp {
    /// Inside any child.
    Union,
    /// Inside every child.
    Intersection,
    /// The first child minus all the others.
    Difference,
}

/// One `[CSG]` block.
#[derive(Debug, Clone, PartialEq)]
pub struct CsgDesc {
    /// Position of the `[CSG]` tag.
    pub pos: Pos,
    /// The set operation.
    pub op: CsgOp,
    /// CSG space to world (or to the enclosing CSG's space).
    pub transform: Transform,
    /// The children, in the order written (for a difference, the body first).
    pub children: Vec<Node>,
}
