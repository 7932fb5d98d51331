//! A ceiling for the tracer: the same picture traced by Intel Embree 3, one thread, for rays
//! per second against Tessera's own.
//!
//! Embree finds the nearest hit of each ray and answers the shadow queries (primary rays in
//! packets of eight with `rtcIntersect8`, the others one by one with `rtcIntersect1` and
//! `rtcOccluded1`, in single precision, using AVX2 where the CPU has it); everything else is
//! Tessera's, done here the way the tracer does it: the camera's rays (the tracer's own
//! [`Camera`]), one ray through each pixel's centre, the same shading (ambient, Lambert,
//! hard shadows, checkers, mirrors to `max_depth`) and the same sRGB encoding. So both sides
//! trace the same rays for the same image, and the image difference says how close the
//! pictures are (Embree's hits are single precision; Tessera's are double).
//!
//! What it covers: spheres placed by a similarity (Embree's sphere primitives) and planes
//! (two large triangles each, with the hit point taken back onto the exact plane), in plain
//! colours or checkers, mirrors or not. A scene with anything else (another shape, a CSG
//! tree, a texture) is skipped with a note, as is the whole comparison where the Embree
//! library (`libembree3.so.3`, Debian's `libembree3-3`) is not installed: it is loaded when
//! this runs, not linked, so the benchmarks build without it.

use std::ffi::{c_char, c_void};
use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result, anyhow, bail};
use glam::DVec3;
use tessera_tracer::internals::{Camera, encode_rgb8};
use tessera_tracer::{
    Color, MemoryAssets, Node, ObjectDesc, Rect, Sampler, Scene, SceneDesc, Shape, TextureLimits,
};

use crate::povray::image_difference;
use crate::stats::{Spread, median};

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Scenes (`.ray` files or directories of them).
    #[arg(long, default_values = ["bench/scenes", "examples/thesis.ray"])]
    scenes: Vec<PathBuf>,
    /// Each side of the image this many times the scene's (default 4; quick: 1).
    #[arg(long)]
    scale: Option<u32>,
    /// Timed runs of each side; the median is reported.
    #[arg(long, default_value_t = 3)]
    repeats: usize,
    /// The scenes at their own size, one run each (for CI).
    #[arg(long)]
    quick: bool,
}

// --- The part of Embree 3's C API this uses (rtcore_*.h, RTC_MAX_INSTANCE_LEVEL_COUNT 1) ---

type Handle = *mut c_void;

const GEOMETRY_TYPE_TRIANGLE: u32 = 0;
const GEOMETRY_TYPE_SPHERE_POINT: u32 = 50;
const BUFFER_TYPE_INDEX: u32 = 0;
const BUFFER_TYPE_VERTEX: u32 = 1;
const FORMAT_UINT3: u32 = 0x5003;
const FORMAT_FLOAT3: u32 = 0x9003;
const FORMAT_FLOAT4: u32 = 0x9004;
const INVALID_GEOMETRY_ID: u32 = u32::MAX;
const CONTEXT_INCOHERENT: u32 = 0;
const CONTEXT_COHERENT: u32 = 1;

/// `struct RTCIntersectContext`: flags, filter function, the instance stack of one level.
#[repr(C)]
struct IntersectContext {
    flags: u32,
    filter: *const c_void,
    inst_id: [u32; 1],
}

/// `struct RTCRay`.
#[repr(C, align(16))]
#[derive(Clone, Copy)]
struct RtcRay {
    org: [f32; 3],
    tnear: f32,
    dir: [f32; 3],
    time: f32,
    tfar: f32,
    mask: u32,
    id: u32,
    flags: u32,
}

/// `struct RTCHit`.
#[repr(C, align(16))]
#[derive(Clone, Copy)]
struct RtcHit {
    ng: [f32; 3],
    u: f32,
    v: f32,
    prim_id: u32,
    geom_id: u32,
    inst_id: [u32; 1],
}

/// `struct RTCRayHit`.
#[repr(C)]
#[derive(Clone, Copy)]
struct RayHit {
    ray: RtcRay,
    hit: RtcHit,
}

/// `struct RTCRayHit8`: eight rays and their hits, each field one lane a ray.
#[repr(C, align(32))]
#[derive(Clone, Copy)]
struct RayHit8 {
    org: [[f32; 8]; 3],
    tnear: [f32; 8],
    dir: [[f32; 8]; 3],
    time: [f32; 8],
    tfar: [f32; 8],
    mask: [u32; 8],
    id: [u32; 8],
    flags: [u32; 8],
    ng: [[f32; 8]; 3],
    u: [f32; 8],
    v: [f32; 8],
    prim_id: [u32; 8],
    geom_id: [u32; 8],
    inst_id: [u32; 8],
}

/// The valid mask of a packet of eight: Embree loads it as one aligned vector.
#[repr(C, align(32))]
struct Valid8([i32; 8]);

/// The library's entry points, looked up once.
struct Api {
    new_device: unsafe extern "C" fn(*const c_char) -> Handle,
    release_device: unsafe extern "C" fn(Handle),
    device_error: unsafe extern "C" fn(Handle) -> u32,
    new_scene: unsafe extern "C" fn(Handle) -> Handle,
    release_scene: unsafe extern "C" fn(Handle),
    commit_scene: unsafe extern "C" fn(Handle),
    new_geometry: unsafe extern "C" fn(Handle, u32) -> Handle,
    new_buffer: unsafe extern "C" fn(Handle, u32, u32, u32, usize, usize) -> *mut c_void,
    commit_geometry: unsafe extern "C" fn(Handle),
    attach_geometry: unsafe extern "C" fn(Handle, Handle) -> u32,
    release_geometry: unsafe extern "C" fn(Handle),
    intersect1: unsafe extern "C" fn(Handle, *mut IntersectContext, *mut RayHit),
    intersect8: unsafe extern "C" fn(*const Valid8, Handle, *mut IntersectContext, *mut RayHit8),
    occluded1: unsafe extern "C" fn(Handle, *mut IntersectContext, *mut RtcRay),
    // Kept loaded for as long as the pointers above are used.
    _lib: libloading::Library,
}

impl Api {
    /// Embree 3, loaded once and never unloaded: its thread pool outlives every device, and
    /// would run unmapped code after the library's unloading. An error says that it is not
    /// installed (or not usable).
    fn get() -> Result<&'static Api> {
        static API: std::sync::OnceLock<Result<Api, String>> = std::sync::OnceLock::new();
        API.get_or_init(|| Api::load().map_err(|e| format!("{e:#}")))
            .as_ref()
            .map_err(|e| anyhow!("{e}"))
    }

    /// Loads Embree 3.
    fn load() -> Result<Api> {
        // SAFETY: loading Embree runs its library constructors, which only set up its own
        // state; the symbols are looked up with the signatures of Embree 3's headers.
        unsafe {
            let lib = libloading::Library::new("libembree3.so.3")
                .map_err(|e| anyhow!("Embree 3 is not installed (libembree3.so.3: {e})"))?;
            macro_rules! sym {
                ($name:literal) => {
                    *lib.get(concat!($name, "\0").as_bytes())
                        .with_context(|| format!("Embree has no {}", $name))?
                };
            }
            Ok(Api {
                new_device: sym!("rtcNewDevice"),
                release_device: sym!("rtcReleaseDevice"),
                device_error: sym!("rtcGetDeviceError"),
                new_scene: sym!("rtcNewScene"),
                release_scene: sym!("rtcReleaseScene"),
                commit_scene: sym!("rtcCommitScene"),
                new_geometry: sym!("rtcNewGeometry"),
                new_buffer: sym!("rtcSetNewGeometryBuffer"),
                commit_geometry: sym!("rtcCommitGeometry"),
                attach_geometry: sym!("rtcAttachGeometry"),
                release_geometry: sym!("rtcReleaseGeometry"),
                intersect1: sym!("rtcIntersect1"),
                intersect8: sym!("rtcIntersect8"),
                occluded1: sym!("rtcOccluded1"),
                _lib: lib,
            })
        }
    }
}

// --- The scene as Embree sees it ---------------------------------------------------------

/// What a primitive is, for shading.
#[derive(Clone, Copy)]
enum Kind {
    Sphere {
        centre: DVec3,
        radius: f64,
    },
    /// The plane through `point` with unit normal `normal`.
    Plane {
        point: DVec3,
        normal: DVec3,
    },
}

/// One object of the scene: its shape for shading, where its checker cells are, and its
/// material.
struct Prim<'a> {
    kind: Kind,
    desc: &'a ObjectDesc,
}

/// A committed Embree scene, with the objects its primitives stand for.
struct Traced<'a> {
    api: &'a Api,
    device: Handle,
    scene: Handle,
    /// Objects by Embree geometry, then primitive.
    geoms: Vec<Vec<Prim<'a>>>,
    /// How far a secondary ray starts from its surface: single precision needs a margin of
    /// about 1e-6 of the scene's size.
    eps: f64,
}

impl Drop for Traced<'_> {
    fn drop(&mut self) {
        // SAFETY: both were created by this API and are released once.
        unsafe {
            (self.api.release_scene)(self.scene);
            (self.api.release_device)(self.device);
        }
    }
}

/// What this comparison takes of an object: a similarity sphere or a plane, untextured.
fn prim(o: &ObjectDesc) -> Result<Kind> {
    if o.material.texture.is_some() {
        bail!("a texture");
    }
    match o.shape {
        Shape::Sphere => {
            // `p ↦ s·p + t` exactly, or a rotation and a uniform scale (whose ball's squared
            // radius is given, a few ulps large).
            let (centre, radius) = match o.transform.similarity() {
                Some((s, t)) => (t, s.abs()),
                None => o
                    .transform
                    .rigid_ball()
                    .map(|(c, r2)| (c, r2.sqrt()))
                    .ok_or_else(|| anyhow!("a sphere placed by more than a similarity"))?,
            };
            Ok(Kind::Sphere { centre, radius })
        }
        Shape::Plane => Ok(Kind::Plane {
            point: o.transform.to_world().transform_point3(DVec3::ZERO),
            normal: o.transform.normal_to_world(DVec3::Y).normalize(),
        }),
        other => bail!("a {}", other.keyword()),
    }
}

impl<'a> Traced<'a> {
    fn build(api: &'a Api, desc: &'a SceneDesc) -> Result<Traced<'a>> {
        let mut spheres = Vec::new();
        let mut planes = Vec::new();
        for node in &desc.objects {
            let Node::Object(o) = node else {
                bail!("a CSG tree");
            };
            let kind = prim(o)?;
            match kind {
                Kind::Sphere { .. } => spheres.push(Prim { kind, desc: o }),
                Kind::Plane { .. } => planes.push(Prim { kind, desc: o }),
            }
        }
        // The scene's size, for the planes' extent and the secondary rays' margin.
        let mut size = desc.camera.eye.length().max(1.0);
        for s in &spheres {
            if let Kind::Sphere { centre, radius } = s.kind {
                size = size.max(centre.length() + radius);
            }
        }
        for l in &desc.lights {
            size = size.max(l.position.length());
        }
        // SAFETY: the calls follow Embree's API: a device, a scene on it, geometries whose
        // buffers are filled within the sizes asked for, committed, attached and released.
        unsafe {
            let device = (api.new_device)(std::ptr::null());
            if device.is_null() {
                bail!("Embree could not make a device");
            }
            let scene = (api.new_scene)(device);
            let mut traced = Traced {
                api,
                device,
                scene,
                geoms: Vec::new(),
                eps: size * 2e-6,
            };
            let mut attach = |geom: Handle, prims: Vec<Prim<'a>>| {
                (api.commit_geometry)(geom);
                let id = (api.attach_geometry)(scene, geom) as usize;
                (api.release_geometry)(geom);
                if traced.geoms.len() <= id {
                    traced.geoms.resize_with(id + 1, Vec::new);
                }
                traced.geoms[id] = prims;
            };
            if !spheres.is_empty() {
                let geom = (api.new_geometry)(device, GEOMETRY_TYPE_SPHERE_POINT);
                let v = (api.new_buffer)(
                    geom,
                    BUFFER_TYPE_VERTEX,
                    0,
                    FORMAT_FLOAT4,
                    16,
                    spheres.len(),
                )
                .cast::<[f32; 4]>();
                for (i, s) in spheres.iter().enumerate() {
                    if let Kind::Sphere { centre, radius } = s.kind {
                        *v.add(i) = [
                            centre.x as f32,
                            centre.y as f32,
                            centre.z as f32,
                            radius as f32,
                        ];
                    }
                }
                attach(geom, spheres);
            }
            if !planes.is_empty() {
                // Two triangles a plane, reaching far past everything else.
                let geom = (api.new_geometry)(device, GEOMETRY_TYPE_TRIANGLE);
                let n = planes.len();
                let v = (api.new_buffer)(geom, BUFFER_TYPE_VERTEX, 0, FORMAT_FLOAT3, 12, 4 * n)
                    .cast::<[f32; 3]>();
                let ix = (api.new_buffer)(geom, BUFFER_TYPE_INDEX, 0, FORMAT_UINT3, 12, 2 * n)
                    .cast::<[u32; 3]>();
                let reach = size * 1e4;
                let mut prims = Vec::new();
                for (i, p) in planes.into_iter().enumerate() {
                    let Kind::Plane { point, normal } = p.kind else {
                        continue;
                    };
                    let u = normal.any_orthonormal_vector();
                    let w = normal.cross(u);
                    for (k, (a, b)) in [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)]
                        .into_iter()
                        .enumerate()
                    {
                        let c = point + (u * a + w * b) * reach;
                        *v.add(4 * i + k) = [c.x as f32, c.y as f32, c.z as f32];
                    }
                    let base = 4 * i as u32;
                    *ix.add(2 * i) = [base, base + 1, base + 2];
                    *ix.add(2 * i + 1) = [base, base + 2, base + 3];
                    // Both triangles of the plane stand for it.
                    prims.push(Prim {
                        kind: p.kind,
                        desc: p.desc,
                    });
                    prims.push(p);
                }
                attach(geom, prims);
            }
            (api.commit_scene)(scene);
            let err = (api.device_error)(device);
            if err != 0 {
                bail!("Embree error {err} building the scene");
            }
            Ok(traced)
        }
    }

    fn context() -> IntersectContext {
        IntersectContext {
            flags: CONTEXT_INCOHERENT,
            filter: std::ptr::null(),
            inst_id: [INVALID_GEOMETRY_ID],
        }
    }

    fn ray(org: DVec3, dir: DVec3, tnear: f64, tfar: f64) -> RtcRay {
        RtcRay {
            org: [org.x as f32, org.y as f32, org.z as f32],
            tnear: tnear as f32,
            dir: [dir.x as f32, dir.y as f32, dir.z as f32],
            time: 0.0,
            tfar: tfar as f32,
            mask: u32::MAX,
            id: 0,
            flags: 0,
        }
    }

    /// The nearest hit along the ray: the object and the distance, in units of `dir`.
    fn intersect(&self, org: DVec3, dir: DVec3) -> Option<(&Prim<'a>, f64)> {
        let mut rh = RayHit {
            ray: Self::ray(org, dir, 0.0, f64::INFINITY),
            hit: RtcHit {
                ng: [0.0; 3],
                u: 0.0,
                v: 0.0,
                prim_id: INVALID_GEOMETRY_ID,
                geom_id: INVALID_GEOMETRY_ID,
                inst_id: [INVALID_GEOMETRY_ID],
            },
        };
        let mut ctx = Self::context();
        // SAFETY: a committed scene, a context as `rtcInitIntersectContext` makes it, and a
        // ray-hit structure of Embree's layout and alignment.
        unsafe { (self.api.intersect1)(self.scene, &mut ctx, &mut rh) };
        if rh.hit.geom_id == INVALID_GEOMETRY_ID {
            return None;
        }
        let prim = self
            .geoms
            .get(rh.hit.geom_id as usize)?
            .get(rh.hit.prim_id as usize)?;
        Some((prim, f64::from(rh.ray.tfar)))
    }

    /// The nearest hits of up to eight coherent rays (neighbouring pixels' primary rays) in
    /// one packet, as [`Traced::intersect`] finds them one by one.
    fn intersect8(&self, rays: &[(DVec3, DVec3)]) -> [Option<(&Prim<'a>, f64)>; 8] {
        let mut p = RayHit8 {
            org: [[0.0; 8]; 3],
            tnear: [0.0; 8],
            dir: [[0.0; 8]; 3],
            time: [0.0; 8],
            tfar: [f32::INFINITY; 8],
            mask: [u32::MAX; 8],
            id: [0; 8],
            flags: [0; 8],
            ng: [[0.0; 8]; 3],
            u: [0.0; 8],
            v: [0.0; 8],
            prim_id: [INVALID_GEOMETRY_ID; 8],
            geom_id: [INVALID_GEOMETRY_ID; 8],
            inst_id: [INVALID_GEOMETRY_ID; 8],
        };
        let mut valid = Valid8([0; 8]);
        for (i, (org, dir)) in rays.iter().take(8).enumerate() {
            for k in 0..3 {
                p.org[k][i] = org[k] as f32;
                p.dir[k][i] = dir[k] as f32;
            }
            valid.0[i] = -1;
        }
        let mut ctx = IntersectContext {
            flags: CONTEXT_COHERENT,
            ..Self::context()
        };
        // SAFETY: a committed scene, a context as `rtcInitIntersectContext` makes it (the
        // coherent flag set), a packet of Embree's layout and alignment, and its valid mask.
        unsafe { (self.api.intersect8)(&valid, self.scene, &mut ctx, &mut p) };
        std::array::from_fn(|i| {
            if valid.0[i] == 0 || p.geom_id[i] == INVALID_GEOMETRY_ID {
                return None;
            }
            let prim = self
                .geoms
                .get(p.geom_id[i] as usize)?
                .get(p.prim_id[i] as usize)?;
            Some((prim, f64::from(p.tfar[i])))
        })
    }

    /// Whether anything lies on the segment from `org` to `org + dir·tfar`.
    fn occluded(&self, org: DVec3, dir: DVec3, tfar: f64) -> bool {
        let mut ray = Self::ray(org, dir, 0.0, tfar);
        let mut ctx = Self::context();
        // SAFETY: as in `intersect`; a hit sets `tfar` to −∞.
        unsafe { (self.api.occluded1)(self.scene, &mut ctx, &mut ray) };
        ray.tfar == f32::NEG_INFINITY
    }
}

// --- Shading: the tracer's, for these objects -------------------------------------------

/// The scene, its Embree form and the rays traced.
struct Shader<'a> {
    desc: &'a SceneDesc,
    traced: &'a Traced<'a>,
    rays: u64,
}

impl Shader<'_> {
    fn surface_color(o: &ObjectDesc, p: DVec3) -> Color {
        let m = &o.material;
        if let Some(c2) = m.color2 {
            let mut local = o.transform.point_to_object(p);
            if o.shape == Shape::Plane {
                // On the unit plane, as the tracer's hit is: a height of −1e-17 would be
                // in the cells below it.
                local.y = 0.0;
            }
            let local = local * o.own_scale;
            let cell = (local.x.floor() as i64)
                .wrapping_add(local.y.floor() as i64)
                .wrapping_add(local.z.floor() as i64);
            if cell & 1 != 0 {
                return c2;
            }
        }
        m.color1
    }

    fn radiance(&mut self, org: DVec3, dir: DVec3, bounces_left: u32) -> Color {
        let hit = self.traced.intersect(org, dir);
        self.shade(org, dir, hit, bounces_left)
    }

    /// The radiance of the ray from `org` along `dir`, whose nearest hit is `hit`.
    fn shade(
        &mut self,
        org: DVec3,
        dir: DVec3,
        hit: Option<(&Prim<'_>, f64)>,
        bounces_left: u32,
    ) -> Color {
        self.rays += 1;
        let Some((prim, t)) = hit else {
            return self.desc.background;
        };
        let (p, outward) = match prim.kind {
            Kind::Sphere { centre, radius } => {
                let p = org + dir * t;
                (p, (p - centre) / radius)
            }
            // Back onto the exact plane: single precision leaves the hit off it.
            Kind::Plane { point, normal } => {
                let t = (point - org).dot(normal) / dir.dot(normal);
                (org + dir * t, normal)
            }
        };
        let n = if outward.dot(dir) <= 0.0 {
            outward
        } else {
            -outward
        };
        let ahead = p + n * self.traced.eps;
        let m = &prim.desc.material;
        let mut color = Color::ZERO;
        if m.mirror < 1.0 {
            let mut light_sum = Color::ZERO;
            if m.diffuse > 0.0 {
                for light in &self.desc.lights {
                    let to_light = light.position - p;
                    let cos = n.dot(to_light);
                    // As the tracer: NaN (a light on the surface) counts as unlit.
                    if cos.is_nan() || cos <= 0.0 {
                        continue;
                    }
                    let cos = cos / to_light.length();
                    let mut v = 1.0;
                    if self.desc.shadow > 0.0 {
                        self.rays += 1;
                        if self
                            .traced
                            .occluded(ahead, light.position - ahead, 1.0 - 1e-6)
                        {
                            v = 1.0 - self.desc.shadow;
                        }
                    }
                    light_sum += light.color * (cos * v);
                }
            }
            let local =
                Self::surface_color(prim.desc, p) * (self.desc.ambient + light_sum * m.diffuse);
            color += local * (1.0 - m.mirror);
        }
        if m.mirror > 0.0 && bounces_left > 0 {
            let d = dir.normalize();
            let r = d - n * (2.0 * d.dot(n));
            color += self.radiance(ahead, r, bounces_left - 1) * m.mirror;
        }
        color
    }

    /// The whole image, one ray through each pixel's centre: sRGB bytes. The primary rays
    /// go to Embree in packets of eight neighbours along a row, its fastest way with rays
    /// that coherent; the others one by one.
    fn image(&mut self, camera: &Camera) -> Vec<u8> {
        let (w, h) = (self.desc.width, self.desc.height);
        let mut rgb = Vec::with_capacity(3 * w as usize * h as usize);
        let mut rays = Vec::with_capacity(8);
        for y in 0..h {
            for x0 in (0..w).step_by(8) {
                rays.clear();
                for x in x0..(x0 + 8).min(w) {
                    let ray = camera.ray(f64::from(x) + 0.5, f64::from(y) + 0.5);
                    rays.push((ray.origin, ray.dir));
                }
                let traced = self.traced;
                let hits = traced.intersect8(&rays);
                for (&(org, dir), hit) in rays.iter().zip(hits) {
                    let c = self.shade(org, dir, hit, self.desc.max_depth);
                    rgb.extend_from_slice(&encode_rgb8(c.min(Color::ONE)));
                }
            }
        }
        rgb
    }
}

pub fn run(args: &Args) -> Result<()> {
    let api = match Api::get() {
        Ok(api) => api,
        Err(e) => {
            println!("{e}: the Embree reference is skipped");
            return Ok(());
        }
    };
    let files = crate::scenes::scene_files(&args.scenes)?;
    let scale = args.scale.unwrap_or(if args.quick { 1 } else { 4 });
    let repeats = if args.quick { 1 } else { args.repeats.max(1) };
    println!(
        "{:<18} {:>9} {:>11} {:>11} {:>8} {:>15} {:>9} {:>9} {:>9} {:>8}",
        "scene",
        "size",
        "tessera ms",
        "embree ms",
        "speed",
        "speed range",
        "tessera",
        "embree",
        "mean |Δ|",
        "Δ>2 px"
    );
    for path in files {
        let name = crate::scenes::scene_name(&path);
        let mut desc = crate::scenes::read_desc(&path)?;
        desc.width = desc.width.saturating_mul(scale);
        desc.height = desc.height.saturating_mul(scale);
        desc.sampler = Sampler::Center;
        let traced = match Traced::build(api, &desc) {
            Ok(t) => t,
            Err(e) => {
                println!("{name:<18} skipped: {e}");
                continue;
            }
        };
        let scene = Scene::build(&desc, &MemoryAssets::new(), &TextureLimits::default())
            .map_err(|e| anyhow!("{e}"))?;
        let camera = Camera::new(&desc.camera, desc.width, desc.height);
        let full = Rect::full(desc.width, desc.height);
        // Back-to-back pairs, as the POV-Ray comparison times them.
        let (mut ours, mut theirs, mut speeds) = (Vec::new(), Vec::new(), Vec::new());
        let (mut our_rgb, mut their_rgb) = (Vec::new(), Vec::new());
        let (mut our_rays, mut their_rays) = (0, 0);
        for _ in 0..repeats {
            let start = Instant::now();
            let (rgb, stats) = scene.render_rect_stats(full);
            let ours_s = start.elapsed().as_secs_f64();
            let mut shader = Shader {
                desc: &desc,
                traced: &traced,
                rays: 0,
            };
            let start = Instant::now();
            let rgb2 = shader.image(&camera);
            let theirs_s = start.elapsed().as_secs_f64();
            speeds.push(theirs_s / ours_s);
            ours.push(ours_s * 1e3);
            theirs.push(theirs_s * 1e3);
            (our_rgb, their_rgb) = (rgb, rgb2);
            (our_rays, their_rays) = (stats.total(), shader.rays);
        }
        let (ours, theirs) = (median(ours), median(theirs));
        let (mean, off) = image_difference(&our_rgb, &their_rgb);
        let speed = Spread::of(speeds);
        let rate = |rays: u64, ms: f64| format!("{:.1} Mr/s", rays as f64 / ms / 1e3);
        println!(
            "{name:<18} {:>9} {ours:>11.1} {theirs:>11.1} {:>7.2}× {:>15} {:>9} {:>9} {mean:>9.2} {:>7.2}%",
            format!("{}×{}", desc.width, desc.height),
            speed.median,
            format!("{:.2}–{:.2}×", speed.lo, speed.hi),
            rate(our_rays, ours),
            rate(their_rays, theirs),
            off * 100.0
        );
    }
    println!(
        "(one thread, one ray per pixel; speed = Embree's time / Tessera's for the same \
         picture, the median of {repeats} back-to-back pairs; Mr/s = millions of rays a second \
         as each side counts them: primary, shadow and mirror rays, of which Tessera skips the \
         shadow rays it knows clear)"
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use tessera_tracer::{Limits, parse};

    /// Spheres on a checkered plane, one of them a mirror, two lights casting shadows: every
    /// part of the shading this reference does.
    const SCENE: &str = "[GLOBALS]\nwidth = 96\nheight = 72\nambient = 0.1\nshadow = 0.8\n\
        max_depth = 3\nbackground = <0.2, 0.3, 0.5>\n[/GLOBALS]\n\
        [CAMERA]\neye = <0, 3, 10>\nlook_at = <0, 1, 0>\nfov = 50\n[/CAMERA]\n\
        [LIGHT]\nposition = <6, 10, 6>\n[/LIGHT]\n[LIGHT]\nposition = <-8, 6, 4>\ncolor = 0.5\n[/LIGHT]\n\
        [OBJECT]\ntype = plane\ncolor1 = 0.9\ncolor2 = 0.1\n[/OBJECT]\n\
        [OBJECT]\ntype = sphere\nradius = 1\ntranslate = <-1.5, 1, 0>\ncolor1 = <0.9, 0.2, 0.2>\n[/OBJECT]\n\
        [OBJECT]\ntype = sphere\nradius = 1.2\nrotate = <10, 20, 30>\ntranslate = <1.5, 1.2, -1>\nmirror = 0.7\n[/OBJECT]\n";

    /// The reference traces the picture Tessera renders: an independent implementation of
    /// the same shading on another kernel, so a difference in either shows here.
    #[test]
    fn embree_traces_the_picture_tessera_renders() {
        let api = match Api::get() {
            Ok(api) => api,
            Err(e) => {
                eprintln!("note: {e}; the reference is untested");
                return;
            }
        };
        let mut desc = parse(SCENE, &Limits::default()).expect("the scene parses");
        desc.sampler = Sampler::Center;
        let traced = Traced::build(api, &desc).expect("Embree takes the scene");
        let scene = Scene::build(&desc, &MemoryAssets::new(), &TextureLimits::default())
            .expect("the scene builds");
        let ours = scene.render_rect(Rect::full(desc.width, desc.height));
        let camera = Camera::new(&desc.camera, desc.width, desc.height);
        let mut shader = Shader {
            desc: &desc,
            traced: &traced,
            rays: 0,
        };
        let theirs = shader.image(&camera);
        let (mean, off) = image_difference(&ours, &theirs);
        assert!(
            mean < 0.5 && off < 0.02,
            "mean difference {mean:.2} steps, {:.1}% of pixels off",
            off * 100.0
        );
        // Every pixel's primary ray, and at least one shadow ray a lit pixel.
        let pixels = u64::from(desc.width * desc.height);
        assert!(shader.rays > pixels, "{} rays", shader.rays);
    }

    /// Shapes and materials the reference does not trace are named, and the scene skipped.
    #[test]
    fn what_it_does_not_trace_is_named() {
        let with = |object: &str| {
            let text = format!("[OBJECT]\n{object}\n[/OBJECT]\n");
            let desc = parse(&text, &Limits::default()).expect("the scene parses");
            let Node::Object(o) = &desc.objects[0] else {
                panic!("one object")
            };
            prim(o).map(|_| ()).map_err(|e| e.to_string())
        };
        assert_eq!(with("type = cube"), Err("a cube".into()));
        assert_eq!(
            with("type = sphere\nscale = <1, 2, 1>"),
            Err("a sphere placed by more than a similarity".into())
        );
        assert!(with("type = sphere\nradius = 2\nrotate = <0, 45, 0>").is_ok());
        assert!(with("type = plane\nrotate = <30, 0, 0>").is_ok());
    }
}
