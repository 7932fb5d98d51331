//! A checkered plane's exact average over a pixel's square, without tracing: the cells'
//! areas in the image, exactly, and the smooth shading at each piece's centroid.
//!
//! **What it is for.** Where a checkered plane alone shows in a pixel's square, with no
//! texture, the plane's own light there is `(1 − mirror) · c(p) · S(p)`: the cell's colour
//! `c` times a shading `S` that varies smoothly (with no light shadowed). The cells' edges
//! are what rays estimate badly (a ray on the wrong side of one errs by the whole step
//! between the colours); the shading is what one point estimates well. So the square's
//! mean of that light is computed as `Σ_pieces area · c_piece · S(centroid)` over the
//! pieces into which the cells' edges cut the square ([`cell_sums`]). Two uses:
//!
//! - where nothing else changes in the square (no mirror, no shadow, no clamp's kink), the
//!   same sum with each piece clamped is the pixel's value;
//! - elsewhere (a mirrored floor, a shadow on it) it is a control variate: a ray's colour
//!   `f` less the plane's own light at its point ([`PlaneImage::direct`]) plus the exact
//!   mean has the mean of `f`, and only the shadows and reflections left in its spread.
//!
//! **Why the areas are exact.** A pinhole camera's ray through image position `(x, y)`
//! meets the plane (its own `y = 0`, in checker units) at `u = U/W`, `v = V/W`, where `U`,
//! `V` and `W` are affine in `(x, y)` (the ray's direction is, and the hit is a ratio of
//! linear functions of it). A cell `i ≤ u < i + 1`, `j ≤ v < j + 1` is therefore, with
//! `W > 0` across the square, the intersection of four half-planes of the image: the square
//! clipped by them is a convex polygon whose area and centroid the shoelace formula gives.
//! The areas are exact to rounding, however the cells are foreshortened.
//!
//! **What it is not.** It estimates the shading by one point per piece: exact where the
//! shading is linear across the piece, off by its curvature elsewhere. It is used only where
//! the shading's curvature is small (the square's corners' mean within the sampler's
//! threshold of its centre: three times the centre's own error for a quadratic shading),
//! and only up to a number of cells (beyond it, rays are cheaper).

use glam::DVec3;

use crate::math::{Color, floor};
use crate::world::Scene;

/// An affine function `a + b·x + c·y` of a position in a pixel's square (`x`, `y` in
/// `[0, 1]`).
#[derive(Debug, Clone, Copy)]
struct Affine {
    a: f64,
    b: f64,
    c: f64,
}

impl Affine {
    #[inline]
    fn at(self, (x, y): (f64, f64)) -> f64 {
        self.a + self.b * x + self.c * y
    }

    /// `self − k · other`.
    #[inline]
    fn minus(self, k: f64, other: Affine) -> Affine {
        Affine {
            a: self.a - k * other.a,
            b: self.b - k * other.b,
            c: self.c - k * other.c,
        }
    }

    /// `k · self`.
    #[inline]
    fn scaled(self, k: f64) -> Affine {
        Affine {
            a: k * self.a,
            b: k * self.b,
            c: k * self.c,
        }
    }
}

/// A convex polygon of the square, at most 4 + 4 vertices (each half-plane adds at most one).
#[derive(Clone, Copy)]
struct Polygon {
    v: [(f64, f64); 10],
    n: usize,
}

impl Polygon {
    const SQUARE: Polygon = Polygon {
        v: [
            (0.0, 0.0),
            (1.0, 0.0),
            (1.0, 1.0),
            (0.0, 1.0),
            (0.0, 0.0),
            (0.0, 0.0),
            (0.0, 0.0),
            (0.0, 0.0),
            (0.0, 0.0),
            (0.0, 0.0),
        ],
        n: 4,
    };

    /// The part where `f ≥ 0` (Sutherland–Hodgman against one line).
    fn clip(&self, f: Affine) -> Polygon {
        let mut out = Polygon {
            v: [(0.0, 0.0); 10],
            n: 0,
        };
        if self.n == 0 {
            return out;
        }
        let mut push = |p: (f64, f64)| {
            // A convex polygon clipped by a line gains at most one vertex; the bound only
            // guards against rounding placing a vertex on both sides.
            if out.n < out.v.len() {
                out.v[out.n] = p;
                out.n += 1;
            }
        };
        for k in 0..self.n {
            let p = self.v[k];
            let q = self.v[(k + 1) % self.n];
            let (fp, fq) = (f.at(p), f.at(q));
            if fp >= 0.0 {
                push(p);
            }
            if (fp >= 0.0) != (fq >= 0.0) {
                let t = fp / (fp - fq);
                push((p.0 + t * (q.0 - p.0), p.1 + t * (q.1 - p.1)));
            }
        }
        out
    }

    /// Area and centroid (shoelace), the centroid `None` for an empty or degenerate piece.
    fn area_centroid(&self) -> (f64, Option<(f64, f64)>) {
        if self.n < 3 {
            return (0.0, None);
        }
        let (mut a, mut cx, mut cy) = (0.0, 0.0, 0.0);
        let o = self.v[0];
        for k in 1..self.n - 1 {
            let (p, q) = (self.v[k], self.v[k + 1]);
            // Triangles fanned from the first vertex: convexity makes every one positive.
            let cross = (p.0 - o.0) * (q.1 - o.1) - (q.0 - o.0) * (p.1 - o.1);
            a += cross;
            cx += cross * (o.0 + p.0 + q.0);
            cy += cross * (o.1 + p.1 + q.1);
        }
        if a.abs() <= 1e-300 {
            return (0.0, None);
        }
        (a.abs() * 0.5, Some((cx / (3.0 * a), cy / (3.0 * a))))
    }
}

/// What summing a checkered plane's cells over a pixel's square gives (see
/// [`cell_sums`]).
pub(super) struct Sums {
    /// `Σ area · min(c · S(centroid), 1)`: the pixel's value where nothing but the cells
    /// and smooth shading change in it.
    pub(super) clamped: Color,
    /// `(1 − mirror) · Σ area · c · S(centroid)`: the mean over the square of [`direct`],
    /// the plane's own unshadowed light, unclamped.
    pub(super) direct: Color,
    /// Whether the colour clamp switches on or off inside the square, channel by channel,
    /// at its centre or corners: no point rule follows that kink, so `clamped` is not
    /// exact there (`direct`, unclamped, is unaffected).
    pub(super) kink: bool,
    /// Where the square's corners' rays meet the plane, and its normal facing the eye: what
    /// [`may_be_shadowed`] tests.
    quad: [DVec3; 4],
    n: DVec3,
}

/// How the rays of pixel `(px, py)`'s square meet plane `object`: `u = U/W`, `v = V/W` in
/// its checker units, with `U`, `V`, `W` affine in the position `(x, y)` relative to the
/// pixel's corner (`[0, 1]²` for its square), and the world point and shading there.
#[derive(Debug, Clone, Copy)]
pub(super) struct PlaneImage<'s> {
    scene: &'s Scene,
    m: &'s crate::object::Material,
    u: Affine,
    v: Affine,
    w: Affine,
    eye: DVec3,
    d0: DVec3,
    right: DVec3,
    down: DVec3,
    /// The ray parameter at `(x, y)` is `−oy / ty(x, y)`.
    oy: f64,
    ty: Affine,
    /// The plane's normal, facing the eye.
    n: DVec3,
}

impl<'s> PlaneImage<'s> {
    /// The map relative to pixel `(px, py)`'s corner, for any image position: `(0, 0)`
    /// gives it in image coordinates.
    pub(super) fn frame(scene: &'s Scene, object: u32, px: i64, py: i64) -> PlaneImage<'s> {
        let obj = &scene.objects[object as usize];
        let cam = &scene.camera;
        let (right, down) = cam.steps();
        let eye = cam.eye();
        // The world direction through the pixel's corner, unnormalised (affine in the
        // image).
        let d0 = cam.direction(px as f64, py as f64);
        let o = obj.transform.ray_to_object(&crate::math::Ray::new(eye, d0));
        let to_object = |d: DVec3| {
            obj.transform
                .ray_to_object(&crate::math::Ray::new(eye, d))
                .dir
        };
        let (a0, ax, ay) = (o.dir, to_object(right), to_object(down));
        let s = obj.own_scale;
        let o = o.origin;
        let coefficient = |d: DVec3| {
            (
                s.x * (o.x * d.y - o.y * d.x),
                s.z * (o.z * d.y - o.y * d.z),
                d.y,
            )
        };
        let (k0, kx, ky) = (coefficient(a0), coefficient(ax), coefficient(ay));
        let affine = |a: f64, b: f64, c: f64| Affine { a, b, c };
        let (p0, n) = super::cells::plane_of(obj);
        let n = n.normalize();
        // Every ray that meets the plane ahead comes from the eye's side.
        let n = if n.dot(eye - p0) < 0.0 { -n } else { n };
        PlaneImage {
            scene,
            m: &obj.material,
            u: affine(k0.0, kx.0, ky.0),
            v: affine(k0.1, kx.1, ky.1),
            w: affine(k0.2, kx.2, ky.2),
            eye,
            d0,
            right,
            down,
            oy: o.y,
            ty: affine(a0.y, ax.y, ay.y),
            n,
        }
    }

    /// [`PlaneImage::frame`] for pixel `(px, py)`, with `W > 0` over its square; `None`
    /// where some ray of the square misses the plane (`W` keeps one sign over the square
    /// if it does at the corners).
    fn new(scene: &'s Scene, object: u32, px: i64, py: i64) -> Option<PlaneImage<'s>> {
        let mut image = PlaneImage::frame(scene, object, px, py);
        if image.w.at((0.5, 0.5)) < 0.0 {
            (image.u, image.v, image.w) = (
                image.u.scaled(-1.0),
                image.v.scaled(-1.0),
                image.w.scaled(-1.0),
            );
        }
        CORNERS
            .iter()
            .all(|&c| image.w.at(c) > 0.0)
            .then_some(image)
    }

    /// The world point the ray through `(x, y)` meets.
    fn point(&self, (x, y): (f64, f64)) -> DVec3 {
        let t = -self.oy / self.ty.at((x, y));
        self.eye + (self.d0 + self.right * x + self.down * y) * t
    }

    /// The Lambertian shading at `(x, y)` with no light shadowed: `ambient + diffuse ·
    /// Σ colour · cos / distance` over the lights the plane's eye side faces, as the
    /// renderer shades.
    fn shading(&self, at: (f64, f64)) -> Color {
        let p = self.point(at);
        let mut sum = Color::ZERO;
        for l in &self.scene.lights {
            let to_light = l.position - p;
            let cos = self.n.dot(to_light);
            if cos > 0.0 {
                sum += l.color * (cos / to_light.length());
            }
        }
        self.scene.ambient + sum * self.m.diffuse
    }

    /// The cell colour at `(x, y)`, from the same `U/W`, `V/W` the pieces are cut by.
    fn colour(&self, at: (f64, f64), c2: Color) -> Color {
        let w = self.w.at(at);
        let (i, j) = (floor(self.u.at(at) / w), floor(self.v.at(at) / w));
        cell_colour(i, j, self.m.color1, c2)
    }
}

/// The square's corners, in its own coordinates.
const CORNERS: [(f64, f64); 4] = [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0)];

/// Cell `(i, j)`'s colour, as the shader picks it: `as i64` saturates, the sum wraps.
fn cell_colour(i: f64, j: f64, c1: Color, c2: Color) -> Color {
    if (i as i64).wrapping_add(j as i64) & 1 != 0 {
        c2
    } else {
        c1
    }
}

/// Pixel `(px, py)`'s sums over checkered plane `object`'s cells (see [`Sums`]), each piece
/// into which the cells' edges cut the square weighted by its exact area and shaded at its
/// centroid, with no light shadowed. The caller checks what the sums assume: that every ray
/// of the square meets the plane first, no texture, and (for `clamped`) no mirror, no
/// shadow and no kink. `None` where some ray of the square misses the plane, where more
/// than `max_cells` cells meet the square, or where the shading's curvature across the
/// square (its corners' mean less its centre, times the brighter colour and `1 − mirror`)
/// exceeds `threshold` in a channel.
pub(super) fn cell_sums(
    scene: &Scene,
    object: u32,
    px: i64,
    py: i64,
    threshold: f64,
    max_cells: u32,
) -> Option<Sums> {
    let m = &scene.objects[object as usize].material;
    let c2 = m.color2?;
    let image = PlaneImage::new(scene, object, px, py)?;
    let (u, v, w) = (image.u, image.v, image.w);

    // Step 1: the cells the square meets, from its corners' images (a convex quadrilateral
    // holding the square's whole image).
    let (mut ulo, mut uhi, mut vlo, mut vhi) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for c in CORNERS {
        let wc = w.at(c);
        let (uc, vc) = (u.at(c) / wc, v.at(c) / wc);
        (ulo, uhi, vlo, vhi) = (ulo.min(uc), uhi.max(uc), vlo.min(vc), vhi.max(vc));
    }
    if ![ulo, uhi, vlo, vhi].iter().all(|c| c.is_finite()) {
        return None;
    }
    let (i0, i1) = (floor(ulo), floor(uhi));
    let (j0, j1) = (floor(vlo), floor(vhi));
    if (i1 - i0 + 1.0) * (j1 - j0 + 1.0) > f64::from(max_cells) {
        return None;
    }

    // Step 2: the shading's curvature. For a quadratic across the square, the corners'
    // mean exceeds the centre by three times the error of taking the centre for the whole
    // square (a piece's centroid errs less, and a linear shading not at all). And the
    // clamp's kink: at these five points the brighter colour is clamped in all or in none,
    // channel by channel.
    let kept = 1.0 - m.mirror;
    let brighter = m.color1.max(c2);
    let points = [(0.5, 0.5), (0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0)];
    let values = points.map(|p| image.shading(p) * brighter);
    let corners_mean = (values[1] + values[2] + values[3] + values[4]) * 0.25;
    if ((corners_mean - values[0]).abs() * kept).max_element() > threshold {
        return None;
    }
    let kink = (0..3).any(|k| {
        let over = values.iter().filter(|v| v[k] > 1.0).count();
        over != 0 && over != values.len()
    });

    // Step 3: the pieces, strip by strip.
    let (mut total, mut clamped, mut direct) = (0.0, Color::ZERO, Color::ZERO);
    // A square within one column or row of cells (its corners' bounds say so, and the
    // square's image is their convex hull) needs no cut along that axis.
    let mut i = i0;
    while i <= i1 {
        let strip = if i0 == i1 {
            Polygon::SQUARE
        } else {
            Polygon::SQUARE
                .clip(u.minus(i, w))
                .clip(w.scaled(i + 1.0).minus(1.0, u))
        };
        let mut j = j0;
        while j <= j1 {
            let piece = if j0 == j1 {
                strip
            } else {
                strip
                    .clip(v.minus(j, w))
                    .clip(w.scaled(j + 1.0).minus(1.0, v))
            };
            if let (area, Some(centroid)) = piece.area_centroid() {
                let lit = cell_colour(i, j, m.color1, c2) * image.shading(centroid);
                clamped += lit.min(Color::ONE) * area;
                direct += lit * area;
                total += area;
            }
            j += 1.0;
        }
        i += 1.0;
    }
    (total > 0.5).then(|| Sums {
        clamped: clamped / total,
        direct: direct * kept / total,
        kink,
        quad: CORNERS.map(|c| image.point(c)),
        n: image.n,
    })
}

impl PlaneImage<'_> {
    /// The value at `at` (relative to the frame's pixel) of the function whose mean
    /// [`Sums::direct`] is: the checkered plane's own light there, `(1 − mirror) · c · S`,
    /// unshadowed and unclamped. Zero where that ray misses the plane, or for a plane
    /// without a checker.
    pub(super) fn direct(&self, at: (f64, f64)) -> Color {
        let Some(c2) = self.m.color2 else {
            return Color::ZERO;
        };
        if !(-self.oy / self.ty.at(at) > 0.0) {
            return Color::ZERO;
        }
        self.colour(at, c2) * self.shading(at) * (1.0 - self.m.mirror)
    }
}

/// Whether the square whose [`Sums`] are `sums`, on plane `object`, may be shadowed (see
/// [`unshadowed`]); `solids` are the scene's [`Solids`].
pub(super) fn may_be_shadowed(scene: &Scene, object: u32, sums: &Sums, solids: &Solids) -> bool {
    !unshadowed(scene, object, sums.quad, sums.n, solids)
}

/// The scene's solids as [`unshadowed`] tests them: each prim's object (`None` for a CSG
/// tree) and bounding ball (`None` where unbounded). `None` for more than
/// [`MAX_SHADOW_SOLIDS`] besides one plane: testing every solid per pixel is only cheaper
/// than the shadow rays it replaces for few.
pub(super) type Solids = Option<Vec<(Option<u32>, Option<(DVec3, f64)>)>>;

/// The scene's [`Solids`], once per tile.
pub(super) fn solids(scene: &Scene) -> Solids {
    if scene.prims.len() > MAX_SHADOW_SOLIDS + 1 {
        return None;
    }
    let solids = scene
        .prims
        .iter()
        .map(|p| {
            let object = match p {
                crate::csg::Prim::Object(i) => Some(*i),
                crate::csg::Prim::Csg(_) => None,
            };
            let ball = p
                .bounds(&scene.objects)
                .map(|b| ((b.min + b.max) * 0.5, (b.max - b.min).length() * 0.5));
            (object, ball)
        })
        .collect();
    Some(solids)
}

/// Whether no solid but plane `o` can shadow any point of the convex quadrilateral with
/// corners `quad` (on the plane, whose normal facing the eye is `n`) from any light on that
/// side: every segment from the quadrilateral to such a light lies in the circular cone
/// from the light around the corners' directions (a convex set holding the corners and its
/// apex holds their hull), and each other solid's bounding ball lies outside that cone by
/// more than a margin. Unbounded solids (another plane), more than [`MAX_SHADOW_SOLIDS`]
/// others, a light inside a ball, or a cone of half-angle 60° or more: no.
fn unshadowed(scene: &Scene, o: u32, quad: [DVec3; 4], n: DVec3, solids: &Solids) -> bool {
    let Some(solids) = solids else {
        return false;
    };
    let others = || solids.iter().filter(|(object, _)| *object != Some(o));
    if others().count() > MAX_SHADOW_SOLIDS || others().any(|(_, ball)| ball.is_none()) {
        return false;
    }
    let balls = || others().filter_map(|(_, ball)| *ball);
    for l in &scene.lights {
        // A light behind the plane lights none of it: no shadow ray.
        if quad.iter().all(|p| n.dot(l.position - p) <= 0.0) {
            continue;
        }
        let dirs = quad.map(|p| (p - l.position).normalize());
        let axis = (dirs[0] + dirs[1] + dirs[2] + dirs[3]).normalize();
        let cos_half = dirs.iter().map(|d| d.dot(axis)).fold(1.0f64, f64::min);
        if !(cos_half > 0.5) {
            return false;
        }
        let half = cos_half.clamp(-1.0, 1.0).acos();
        for (c, r) in balls() {
            let v = c - l.position;
            let d = v.length();
            if !(d > r * (1.0 + 1e-9)) {
                return false;
            }
            let angle = (v.dot(axis) / d).clamp(-1.0, 1.0).acos();
            // The margin dwarfs the rounding of these angles and of the shadow rays.
            if angle <= half + (r / d).asin() + 1e-7 {
                return false;
            }
        }
    }
    true
}

/// The most other solids [`unshadowed`] tests one by one for a pixel.
const MAX_SHADOW_SOLIDS: usize = 32;
