//! Checker and texture cells as a pixel sees them: the step between checker cells along the
//! image, and whether one pixel's square lies within one cell of a solid's pattern.

use glam::DVec3;

use crate::math::floor;
use crate::object::Object;
use crate::shape::Shape;
use crate::world::Scene;

use super::Cone;
use super::cone::PlaneView;

impl Scene {
    /// An upper bound on how far apart a checkered plane's two colours can shade at any
    /// point a primary ray meets it, in the channel where they are farthest apart, after
    /// clamping: `|c1 − c2| · (1 − mirror) · (ambient + diffuse · Σ colour)` over the lights
    /// on the eye's side of the plane, at most 1. Every point of a whole plane that any ray
    /// from the eye reaches, by mirrors or not, faces the eye's side (a ray cannot cross the
    /// plane without meeting it), and a light on the other side lights none of them
    /// (`n · l ≤ 0`); shadows only lower the sum. The mirrored part is the same for both
    /// colours unless the mirrored ray can come back to the plane by another mirror: then the
    /// difference `D` along any ray obeys `D ≤ (1 − m) S + m D`, so `D ≤ S`, and the factor
    /// `1 − mirror` is dropped; and for a plane in a CSG tree, whose gaps let a returning ray
    /// meet it from the other side, every light counts. 0 for an object without a checker,
    /// or whose colours are the same.
    pub(crate) fn checker_step(&self, obj: &Object) -> f64 {
        let m = &obj.material;
        let Some(c2) = m.color2 else {
            return 0.0;
        };
        // Whether a ray the plane mirrors can come back to it (by another mirror).
        let returns = m.mirror > 0.0 && self.mirrors > 1;
        let (p0, n) = plane_of(obj);
        let eye = self.camera.ray(0.0, 0.0).origin;
        let side = n.dot(eye - p0);
        let mut light = self.ambient;
        for l in &self.lights {
            let d = l.position - p0;
            // Lights on the plane, within rounding, or an eye on it: counted.
            let margin = 1e-9 * (1.0 + d.length() + (eye - p0).length());
            let eye_side = side.abs() <= margin || n.dot(d) * side.signum() > -margin;
            if eye_side || (returns && obj.in_csg) {
                light += l.color * m.diffuse;
            }
        }
        let kept = if returns { 1.0 } else { 1.0 - m.mirror };
        let step = (m.color1 - c2).abs() * light * kept;
        step.max_element().min(1.0)
    }

    /// Whether object `o` shades smoothly: a sphere placed by a similarity or a plane,
    /// outside any CSG tree, plain (no texture or mirror, a checker only on a plane), with
    /// no shadow ray to trace.
    pub(super) fn plain(&self, o: u32) -> bool {
        self.plain_but_shadows(o) && self.casts_no_shadow_on(o)
    }

    /// [`Scene::plain`] but for shadows: they may fall on the object.
    pub(super) fn plain_but_shadows(&self, o: u32) -> bool {
        let obj = &self.objects[o as usize];
        let m = &obj.material;
        let shape_ok = match obj.shape {
            Shape::Sphere => obj.similarity_sphere().is_some(),
            Shape::Plane => true,
            _ => false,
        };
        // A checker only on a plane, where `one_cell` can tell whether a pixel crosses it.
        let checker_ok = m.color2.is_none() || matches!(obj.shape, Shape::Plane);
        shape_ok && checker_ok && !obj.in_csg && m.texture.is_none() && m.mirror <= 0.0
    }

    /// Whether no shadow ray from object `o` needs tracing: no light, no shadow, nothing
    /// else in the scene, or every light known clear of it.
    pub(super) fn casts_no_shadow_on(&self, o: u32) -> bool {
        self.casts_no_shadow_at(o, self.clear_lights(o))
    }

    /// [`Scene::casts_no_shadow_on`] for the slice of a cylinder or cone at object-space
    /// height `y` (see `Scene::clear_lights_at`).
    pub(super) fn casts_no_shadow_on_slice(&self, o: u32, y: f64) -> bool {
        self.casts_no_shadow_at(o, self.clear_lights_at(o, y))
    }

    /// Whether no shadow ray from object `o` needs tracing, given `clear`, the lights known
    /// clear of it (or of the part of it asked about).
    fn casts_no_shadow_at(&self, o: u32, clear: u64) -> bool {
        let m = &self.objects[o as usize].material;
        // A sphere seen from outside (`covers` requires it) and a plane are left without
        // re-hitting themselves, so their shadow rays skip them, as `crate::shadow` assumes.
        let n = self.lights.len();
        let all_clear = n <= 64 && clear == u64::MAX >> (64 - n.max(1));
        let traces_shadows = self.shadow > 0.0 && m.diffuse > 0.0 && self.anything_else(Some(o));
        n == 0 || !traces_shadows || all_clear
    }
}

/// Whether every direction of the cone meets `obj` (a similarity sphere or a plane).
pub(super) fn covers(obj: &Object, cone: &Cone) -> bool {
    match (obj.shape, obj.similarity_sphere()) {
        (Shape::Sphere, Some((c, r2))) => cone.inside_sphere(c, r2.sqrt()),
        (Shape::Plane, _) => {
            let (p0, n) = plane_of(obj);
            cone.view_of_plane(p0, n) == PlaneView::Covers
        }
        _ => false,
    }
}

/// Whether pixel `(px, py)`'s square, on checkered plane `obj` (which its every ray meets:
/// `covers`), lies in one checker cell.
///
/// The rays through the square's corners meet the plane at the corners of the square's
/// image, a convex quadrilateral (a projective map takes the square to the convex hull of
/// its corners' images while no ray of it is parallel to the plane). The cells are the unit
/// squares of the plane's own `x`, `z` (its `y` is 0 on every hit), so the pixel sees one
/// cell when the corners' bounds, widened by 1e-9 of their magnitude (against the rounding
/// of these intersections and of the renderer's), fit between the same integers.
pub(super) fn one_cell(scene: &Scene, obj: &Object, px: i64, py: i64) -> bool {
    cell_edges(scene, obj, px, py) == Some(0)
}

/// How many lines between cells (`x` or `z` an integer) may cross pixel `(px, py)`'s square
/// on checkered plane `obj`: those between the bounds of its corners' images, widened as in
/// [`one_cell`]; `None` where a corner's ray misses the plane (the square may then hold the
/// horizon, and any number). Each such line is straight in the image too (a projective map
/// keeps lines), so it passes through at most `2m − 1` cells of an `m × m` grid over the
/// square.
pub(super) fn cell_edges(scene: &Scene, obj: &Object, px: i64, py: i64) -> Option<u32> {
    let (mut lo, mut hi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
    for (dx, dy) in [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0)] {
        let p = plane_point(scene, obj, px as f64 + dx, py as f64 + dy)?;
        lo = lo.min(p);
        hi = hi.max(p);
    }
    let pad = 1e-9 * (1.0 + lo.abs().max(hi.abs()).max_element());
    // Floors of huge coordinates saturate; so does the count.
    let lines = |a: f64, b: f64| (floor(b + pad) - floor(a - pad)).clamp(0.0, 1e9) as u32;
    Some(lines(lo.x, hi.x).saturating_add(lines(lo.z, hi.z)))
}

/// Which colour of checkered plane `obj` the primary ray through image position `(x, y)`
/// meets (`false`: `color1`), as the shader picks it from the hit's own coordinates; `None`
/// where the ray misses the plane or meets it within 1e-9 of a cell's edge (relative to the
/// coordinates' magnitude: the shader's own hit may round to the other side there).
pub(super) fn cell_parity(scene: &Scene, obj: &Object, x: f64, y: f64) -> Option<bool> {
    let p = plane_point(scene, obj, x, y)?;
    let pad = 1e-9 * (1.0 + p.x.abs().max(p.z.abs()));
    let clear = |v: f64| v - floor(v) > pad && v.ceil() - v > pad;
    (clear(p.x) && clear(p.z)).then(|| (floor(p.x) as i64).wrapping_add(floor(p.z) as i64) & 1 != 0)
}

/// Where the primary ray through image position `(x, y)` meets plane `obj`, in the plane's
/// own coordinates scaled to its checker's unit cells (`y` is 0); `None` where it misses.
pub(super) fn plane_point(scene: &Scene, obj: &Object, x: f64, y: f64) -> Option<DVec3> {
    let ray = obj.transform.ray_to_object(&scene.camera.ray(x, y));
    let t = -ray.origin.y / ray.dir.y;
    (t > 0.0 && t.is_finite()).then(|| ray.at(t) * obj.own_scale)
}

/// A plane object's world point and normal.
pub(super) fn plane_of(obj: &Object) -> (DVec3, DVec3) {
    let (p0, _) = obj.transform.point_to_world(DVec3::ZERO, DVec3::ZERO);
    (p0, obj.transform.normal_to_world(DVec3::Y))
}
