//! The Tessera ray tracer: the ray tracer of Weicher's 2002 thesis on distributed ray
//! tracing, extended with an arbitrary camera, many lights, more shapes and CSG.
//!
//! This crate turns `.ray` scene text into pixels. It parses and validates scenes
//! ([`scene`]), places unit shapes with composite and inverse matrices ([`transform`],
//! [`shape`]), shades them exactly as the format's "exact image" defines ([`render`]),
//! samples pixels deterministically ([`sampler`]; the adaptive sampler ends a pixel after one
//! ray where the geometry proves it smooth, and refines one where a thin sphere or rod may
//! hide between its first rays, [`footprint`]), and encodes sRGB PNGs ([`png_out`]).
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

pub mod bvh;
pub mod camera;
pub mod csg;
pub mod diag;
pub mod exact;
pub mod footprint;
pub mod math;
pub mod png_out;
pub mod point_index;
pub mod render;
pub mod sampler;
pub mod scene;
pub mod shadow;
pub mod shape;
pub mod srgb;
pub mod texture;
pub mod tile;
pub mod transform;
pub mod world;

pub use diag::{Diagnostic, Pos, SceneError, scene_text};
pub use png_out::{PngError, PngWriter, SharedBuffer, encode_png};
pub use render::RayStats;
pub use sampler::Sampler;
pub use scene::{Limits, MAX_SCENE_FILE_BYTES, SceneDesc, parse};
pub use texture::{AssetSource, DirAssets, MemoryAssets, Texture, TextureError, TextureLimits};
pub use tile::{Rect, tile_count, tiles};
pub use world::{Acceleration, Scene};

/// Most threads a command line may ask one process to render with (`tessera-render
/// --threads`, `tessera-worker --threads`, `tessera-service --local-workers`): far more than
/// a machine has cores, and few enough that a mistyped count neither exhausts the process's
/// threads nor leaves thousands of idle threads spinning over a small image.
pub const MAX_THREADS: u16 = 1024;
