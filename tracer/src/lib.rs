//! The Tessera ray tracer: the ray tracer of Weicher's 2002 thesis on distributed ray
//! tracing, extended with an arbitrary camera, many lights, more shapes and CSG.
//!
//! This crate turns `.ray` scene text into pixels. It parses and validates scenes
//! ([`parse`], [`SceneDesc`]), places unit shapes with composite and inverse matrices
//! ([`Transform`], [`Shape`]), shades them exactly as the format's "exact image" defines
//! ([`Scene::render_rect`]), samples pixels deterministically ([`Sampler`]; the adaptive
//! sampler ends a pixel after one ray where the geometry proves it smooth, and refines one
//! where a thin sphere or rod may hide between its first rays), and encodes sRGB PNGs
//! ([`PngWriter`], [`encode_png`]). Everything public is re-exported here; the modules
//! behind it are private.
//! It knows nothing of networks, databases or job queues: the farm's service and workers
//! call [`Scene::render_rect`] on tiles, and a tile's pixels never depend on the tile.
//!
//! ```
//! use tessera_tracer::{Limits, MemoryAssets, Rect, Scene, TextureLimits};
//!
//! let src = "[GLOBALS]\nwidth = 8\nheight = 6\nlight = <0, 0, 100>\n[/GLOBALS]\n\
//!            [OBJECT]\ntype = sphere\nradius = 20\n[/OBJECT]\n";
//! let scene = Scene::from_source(src, &Limits::default(), &MemoryAssets::new(),
//!                                &TextureLimits::default()).expect("valid scene");
//! let whole = scene.render_rect(Rect::full(8, 6));
//! let corner = scene.render_rect(Rect::new(5, 3, 3, 3));
//! assert_eq!(&whole[(3 * 8 + 5) * 3..(3 * 8 + 6) * 3], &corner[..3]);
//! ```

// `!(x > 0.0)` is this crate's idiom for "not a positive number, NaN included": NaN fails every
// comparison, so the negated form rejects it where `x <= 0.0` would let it through.
#![allow(clippy::neg_cmp_op_on_partial_ord)]
#![warn(missing_docs)]

mod bvh;
mod camera;
mod csg;
mod diag;
#[cfg(feature = "bench")]
mod exact;
mod footprint;
mod math;
mod object;
mod png_out;
mod point_index;
mod render;
mod sampler;
mod scene;
mod shadow;
mod shape;
mod srgb;
mod texture;
mod tile;
mod transform;
mod world;

pub use diag::{Diagnostic, MAX_DIAGNOSTICS, Pos, SceneError, WithFile, scene_text};
pub use math::Color;
pub use png_out::{PngError, PngWriter, SharedBuffer, encode_png};
pub use render::RayStats;
pub use sampler::Sampler;
pub use scene::{
    CameraDesc, CsgDesc, CsgOp, Light, Limits, MAX_BLOCK_ENTRIES, MAX_NUMBER, MAX_SCENE_FILE_BYTES,
    MaterialDesc, Node, ObjectDesc, SceneDesc, TextureRef, parse,
};
pub use shape::Shape;
pub use texture::{
    AssetSource, DirAssets, MemoryAssets, Texture, TextureError, TextureLimits,
    lexical as lexical_texture_path,
};
pub use tile::{Rect, local_tile, tile_count, tiles};
pub use transform::{Transform, TransformOp};
pub use world::{Acceleration, Scene};

/// The tracer's building blocks, for `tessera-bench` and the tracer's own tests: the pieces
/// the benchmarks time and the tests check one by one, and the switches that turn a
/// speed-up off to compare against it.
///
/// **Not part of the stable API.** These change with the implementation; they exist only
/// with the cargo feature `bench`, which no program that renders scenes needs.
#[cfg(feature = "bench")]
pub mod internals {
    pub use crate::bvh::BVH_MIN_PRIMS;
    pub use crate::camera::Camera;
    pub use crate::csg::{Csg, Prim};
    pub use crate::footprint::{Footprints, PixelRegion};
    pub use crate::math::{Aabb, Ray};
    pub use crate::object::{Material, Object};
    pub use crate::render::{SHADOW_END_REL, SurfacePoint};
    pub use crate::sampler::{Coverage, Sample};
    pub use crate::shape::LocalHit;
    pub use crate::srgb::encode_rgb8;
    pub use crate::world::Hit;

    use glam::DVec3;

    use crate::Scene;

    /// The queries shading makes of a [`Scene`], for tests that check them one ray at a
    /// time. Each forwards to the crate's own method of the same name.
    pub trait SceneInternals {
        /// The nearest hit along `ray` before `t_max`, leaving out lone object `skip`.
        fn intersect(&self, ray: &Ray, t_max: f64, skip: Option<u32>) -> Option<Hit>;
        /// Whether anything blocks `ray` before `t_max`, leaving out lone object `skip`.
        fn occluded(&self, ray: &Ray, t_max: f64, skip: Option<u32>) -> bool;
        /// The shadow query towards light `light`, through its point table where it has
        /// one, leaving out `skip` and the objects `also` names.
        fn occluded_towards(
            &self,
            light: usize,
            ray: &Ray,
            t_max: f64,
            skip: Option<u32>,
            also: &[u32],
        ) -> bool;
        /// The lone convex objects whose surface passes through light `light`, each with
        /// its world outward normal there.
        fn lights_on(&self, light: usize) -> &[(u32, DVec3)];
        /// The step between checker cells of `obj` along the image that the adaptive
        /// sampler bounds its search by (0 for an object without a checker).
        fn checker_step(&self, obj: &Object) -> f64;
    }

    impl SceneInternals for Scene {
        fn intersect(&self, ray: &Ray, t_max: f64, skip: Option<u32>) -> Option<Hit> {
            Scene::intersect(self, ray, t_max, skip)
        }

        fn occluded(&self, ray: &Ray, t_max: f64, skip: Option<u32>) -> bool {
            Scene::occluded(self, ray, t_max, skip)
        }

        fn occluded_towards(
            &self,
            light: usize,
            ray: &Ray,
            t_max: f64,
            skip: Option<u32>,
            also: &[u32],
        ) -> bool {
            Scene::occluded_towards(self, light, ray, t_max, skip, also)
        }

        fn lights_on(&self, light: usize) -> &[(u32, DVec3)] {
            Scene::lights_on(self, light)
        }

        fn checker_step(&self, obj: &Object) -> f64 {
            Scene::checker_step(self, obj)
        }
    }

    /// The exact image's building blocks: what every sampler is measured against.
    pub mod exact {
        pub use crate::exact::{disc_coverage, error, sphere_disc_radius};
    }

    /// The point tables' thresholds: when a scene lists the solids around the eye and the
    /// lights instead of searching the BVH.
    pub mod point_index {
        pub use crate::point_index::{MIN_BOXES, PIXELS_PER_BOX};
    }
}

/// Most threads a command line may ask one process to render with (`tessera-render
/// --threads`, `tessera-worker --threads`, `tessera-service --local-workers`): far more than
/// a machine has cores, and few enough that a mistyped count neither exhausts the process's
/// threads nor leaves thousands of idle threads spinning over a small image.
pub const MAX_THREADS: u16 = 1024;
