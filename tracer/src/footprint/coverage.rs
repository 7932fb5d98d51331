//! The share of a pixel's square in which primary rays meet a similarity sphere, or a
//! circular cylinder away from its ends, exact to rounding: what the adaptive sampler weighs
//! a silhouette pixel's rays by. Not whether anything else shows in the square
//! ([`super::Footprints::coverage`] decides that). The sphere's outline is below; the
//! cylinder's is at [`Band`].
//!
//! A ray through image position `q` meets the sphere (centre `c`, radius `r`, seen from the
//! eye `e`) when its line passes within `r` of the centre: `|w × d(q)|² ≤ r² |d(q)|²`, with
//! `w = c − e` and `d(q)` the camera's unnormalised direction, affine in `q`. Both sides are
//! quadratic in `q`, so the outline is a conic. With the sphere wholly in front of the eye's
//! plane it is an ellipse, and a line that meets the sphere meets it in front of the eye
//! (the point nearest the centre lies in front). An affine map takes the ellipse to the unit
//! disc and the square to a parallelogram, keeping ratios of areas; the disc's area inside
//! a polygon is a sum over the polygon's edges of triangles and circular sectors.

use arrayvec::ArrayVec;
use glam::{DVec2, DVec3};

use super::{CSG, Footprints, PlaneSide};
use crate::camera::Camera;
use crate::sampler::Coverage;
use crate::shape::Shape;

/// A sphere's outline in the image: `(v − m)ᵀ T (v − m) ≤ 1` for `v = q − o`, written as the
/// map `u = Lᵀ (v − m)` onto the unit disc (`T = L Lᵀ`).
#[derive(Debug, Clone, Copy)]
pub(super) struct Ellipse {
    /// The image position whose ray passes through the centre: the origin of `v`. Working
    /// relative to it keeps the conic's coefficients free of cancellation.
    o: DVec2,
    /// The ellipse's centre, relative to `o`.
    m: DVec2,
    /// `Lᵀ = [[l11, l21], [0, l22]]`.
    l11: f64,
    l21: f64,
    l22: f64,
    /// Half the width and height of the box around the ellipse, with a margin.
    half: DVec2,
}

impl Ellipse {
    /// The outline of the sphere of centre `c` and radius `r`; `None` unless the sphere lies
    /// wholly in front of the eye's plane (by a margin of a millionth of its radius) and
    /// every number is finite.
    pub(super) fn new(camera: &Camera, c: DVec3, r: f64) -> Option<Ellipse> {
        let w = c - camera.eye();
        if !(r > 0.0 && w.dot(camera.forward()) > r * (1.0 + 1e-6)) {
            return None;
        }
        let (ox, oy) = camera.project(c)?;
        let o = DVec2::new(ox, oy);
        let (right, down) = camera.steps();
        let dc = camera.direction(ox, oy);
        // |w × d|² ≤ r²|d|² with d = dc + right·v.x + down·v.y, w × dc = 0, divided by r²:
        // vᵀ S v − 2 g·v ≤ |dc|², S = G/r² − RᵀR, G the Gram matrix of w × right, w × down.
        let (a, b) = (w.cross(right) / r, w.cross(down) / r);
        let s11 = a.dot(a) - right.dot(right);
        let s12 = a.dot(b) - right.dot(down);
        let s22 = b.dot(b) - down.dot(down);
        let g = DVec2::new(right.dot(dc), down.dot(dc));
        let det = s11 * s22 - s12 * s12;
        if !(s11 > 0.0 && det > 0.0) {
            return None;
        }
        // m = S⁻¹ g; then (v − m)ᵀ S (v − m) ≤ |dc|² + g·m = k.
        let m = DVec2::new(s22 * g.x - s12 * g.y, s11 * g.y - s12 * g.x) / det;
        let k = dc.dot(dc) + g.dot(m);
        // T = S / k, by Cholesky.
        let (t11, t12, t22) = (s11 / k, s12 / k, s22 / k);
        let l11 = t11.sqrt();
        let l21 = t12 / l11;
        let l22 = (t22 - l21 * l21).sqrt();
        // The box around the ellipse: half-sides √(T⁻¹)ᵢᵢ.
        let tdet = t11 * t22 - t12 * t12;
        let half = DVec2::new((t22 / tdet).sqrt(), (t11 / tdet).sqrt()) * (1.0 + 1e-9) + 1e-9;
        let e = Ellipse {
            o,
            m,
            l11,
            l21,
            l22,
            half,
        };
        let finite = [o.x, o.y, m.x, m.y, l11, l21, l22, half.x, half.y]
            .iter()
            .all(|v| v.is_finite());
        (finite && l22 > 0.0).then_some(e)
    }

    /// The share of pixel `(px, py)`'s square inside the outline, in `[0, 1]`: exactly 0
    /// where the square misses the box around it, exactly 1 where all four corners lie
    /// inside (the ellipse is convex), and otherwise the disc's area in the square's image
    /// over the image's area.
    pub(super) fn share(&self, px: i64, py: i64) -> f64 {
        let lo = DVec2::new(px as f64, py as f64) - self.o - self.m;
        let hi = lo + DVec2::ONE;
        if lo.x > self.half.x || lo.y > self.half.y || hi.x < -self.half.x || hi.y < -self.half.y {
            return 0.0;
        }
        let map = |v: DVec2| DVec2::new(self.l11 * v.x + self.l21 * v.y, self.l22 * v.y);
        let corners = [
            map(lo),
            map(DVec2::new(hi.x, lo.y)),
            map(hi),
            map(DVec2::new(lo.x, hi.y)),
        ];
        if corners.iter().all(|u| u.length_squared() < 1.0) {
            return 1.0;
        }
        let mut area = 0.0;
        for k in 0..4 {
            area += disc_in_triangle(corners[k], corners[(k + 1) % 4]);
        }
        // The parallelogram's area is det Lᵀ times the square's.
        (area.abs() / (self.l11 * self.l22)).clamp(0.0, 1.0)
    }
}

/// The coverage queries of [`Footprints`]: which pixels show one solid's silhouette alone,
/// and the outlines the per-tile projection records for them.
impl Footprints<'_> {
    /// What pixel `(px, py)`'s square shows where it is one plain solid's silhouette
    /// against the background: a similarity sphere, or a circular cylinder whose ends' slices
    /// do not meet the square, outside any CSG tree, wholly in front of the eye, with a
    /// plain material and no shadow ray to trace (as a pixel that ends after one ray needs),
    /// the only solid whose footprint meets the square, and no plane can show in it. Its
    /// rays then see the solid's smooth shading inside its outline and the background
    /// outside, and the share of the square inside is known exactly (see `coverage`).
    /// `None` elsewhere, and outside the region.
    pub fn coverage(&self, px: i64, py: i64) -> Option<Coverage> {
        let i = self.index(px, py)?;
        let o = self.shown[i];
        // One solid, counted by its cone alone, by pieces that all have the outline.
        if o >= CSG || self.flags[i] != 0 {
            return None;
        }
        let slot = self.near[i][0].checked_sub(1)?;
        let silhouette = self.outlines[slot as usize].silhouette?;
        let outlined = |&s: &u32| s == 0 || self.outlines[s as usize - 1].silhouette.is_some();
        if !self.near[i].iter().all(outlined) {
            return None;
        }
        let misses = |side: &Option<PlaneSide>| side.is_some_and(|s| s.misses(px, py));
        if !self.plane_sides.iter().all(misses) || !self.smooth_alone(o) {
            return None;
        }
        Some(Coverage {
            object: o,
            share: silhouette.share(px, py),
            backdrop: self.scene.background_sample().color,
        })
    }

    /// Whether object `o`'s shading is smooth: no texture, checker or mirror, outside any
    /// CSG tree, and for a sphere or plane no shadow ray to trace ([`Scene::plain`]); a
    /// cylinder's slices have their outline only where no shadow ray needs tracing.
    fn smooth_alone(&self, o: u32) -> bool {
        let obj = &self.scene.objects[o as usize];
        let m = &obj.material;
        match obj.shape {
            Shape::Sphere | Shape::Plane => self.scene.plain(o),
            _ => m.texture.is_none() && m.color2.is_none() && m.mirror <= 0.0 && !obj.in_csg,
        }
    }

    /// The outline of a cylinder whose cross-section is a circle (the transform's images of
    /// the object's x and z axes of one length and square to each other and to its axis, to
    /// 1e-12 of their lengths) and which lies wholly in front of the eye's plane; `None` for
    /// any other solid.
    pub(super) fn cylinder_band(&self, obj: &crate::object::Object) -> Option<Band> {
        if !matches!(obj.shape, Shape::Cylinder) {
            return None;
        }
        let m = obj.transform.to_world();
        let (c0, c1, c2) = (m.matrix3.x_axis, m.matrix3.y_axis, m.matrix3.z_axis);
        let r = c0.length();
        let tol = 1e-12 * r * (r + c1.length());
        let circular = (c2.length() - r).abs() <= 1e-12 * r
            && c0.dot(c2).abs() <= tol
            && c0.dot(c1).abs() <= tol
            && c2.dot(c1).abs() <= tol;
        let camera = &self.scene.camera;
        let depth = |p: DVec3| (p - camera.eye()).dot(camera.forward());
        let (a, e) = (m.translation - c1, m.translation + c1);
        let in_front = depth(a) > r * (1.0 + 1e-6) && depth(e) > r * (1.0 + 1e-6);
        (circular && in_front)
            .then(|| Band::new(camera, m.translation, c1.normalize(), r))
            .flatten()
    }
}

/// A circular cylinder's outline in the image, away from its ends: the rays that meet the
/// infinite cylinder in front of the eye are those between its two tangent planes through
/// the eye, and each plane's side is an affine function of the image position, `c + a·x +
/// b·y ≥ 0`. The share of a square is then the area of a polygon, exact to rounding.
///
/// Projected along the axis `u`, the cylinder (radius `r`, axis through `p`) is a disc of
/// radius `r` about `w′`, the part of `w = p − eye` across the axis, and a line from the
/// eye meets the cylinder where its projection meets the disc: within the wedge of the two
/// tangents from the eye, whose unit normals are `(r/L)·ŵ′ ± √(1 − r²/L²)·(u × ŵ′)`,
/// `L = |w′|`. A ray whose projection heads away from the disc never meets the cylinder.
#[derive(Debug, Clone, Copy)]
pub(super) struct Band {
    sides: [(f64, f64, f64); 2],
}

impl Band {
    /// The outline of the cylinder of radius `r` around the line through `p` along the unit
    /// vector `u`; `None` where the eye lies within `r` of the line (by a millionth of `r`)
    /// or a number is not finite.
    pub(super) fn new(camera: &Camera, p: DVec3, u: DVec3, r: f64) -> Option<Band> {
        let w = p - camera.eye();
        let across = w - u * w.dot(u);
        let l = across.length();
        if !(r > 0.0 && l > r * (1.0 + 1e-6)) {
            return None;
        }
        let (toward, side) = (across / l, u.cross(across / l));
        let (cos, sin) = (r / l, (1.0 - (r / l) * (r / l)).sqrt());
        let (right, down) = camera.steps();
        let corner = camera.direction(0.0, 0.0);
        let plane = |n: DVec3| (n.dot(corner), n.dot(right), n.dot(down));
        let sides = [
            plane(toward * cos + side * sin),
            plane(toward * cos - side * sin),
        ];
        let finite = sides
            .iter()
            .all(|&(c, a, b)| [c, a, b].iter().all(|v| v.is_finite()));
        finite.then_some(Band { sides })
    }

    /// The share of pixel `(px, py)`'s square between the two planes, in `[0, 1]`: the
    /// square clipped by each side in turn, its area by the shoelace formula.
    pub(super) fn share(&self, px: i64, py: i64) -> f64 {
        let (x0, y0) = (px as f64, py as f64);
        // A square clipped by two half-planes keeps at most six corners: no allocation.
        let mut poly: ArrayVec<DVec2, 8> = [
            DVec2::new(x0, y0),
            DVec2::new(x0 + 1.0, y0),
            DVec2::new(x0 + 1.0, y0 + 1.0),
            DVec2::new(x0, y0 + 1.0),
        ]
        .into_iter()
        .collect();
        for &(c, a, b) in &self.sides {
            let h = |q: DVec2| c + a * q.x + b * q.y;
            let mut kept = ArrayVec::<DVec2, 8>::new();
            for k in 0..poly.len() {
                let (p, q) = (poly[k], poly[(k + 1) % poly.len()]);
                let (hp, hq) = (h(p), h(q));
                if hp >= 0.0 {
                    kept.push(p);
                }
                if (hp >= 0.0) != (hq >= 0.0) {
                    kept.push(p + (q - p) * (hp / (hp - hq)));
                }
            }
            poly = kept;
            if poly.is_empty() {
                return 0.0;
            }
        }
        let n = poly.len();
        let twice: f64 = (0..n).map(|k| poly[k].perp_dot(poly[(k + 1) % n])).sum();
        (0.5 * twice.abs()).clamp(0.0, 1.0)
    }
}

/// A solid's outline in the image, for [`super::Footprints::coverage`].
#[derive(Debug, Clone, Copy)]
pub(super) enum Silhouette {
    /// A sphere's.
    Ellipse(Ellipse),
    /// A cylinder's, away from its ends.
    Band(Band),
}

impl Silhouette {
    /// The share of pixel `(px, py)`'s square inside the outline.
    pub(super) fn share(&self, px: i64, py: i64) -> f64 {
        match self {
            Silhouette::Ellipse(e) => e.share(px, py),
            Silhouette::Band(b) => b.share(px, py),
        }
    }
}

/// The signed area of the unit disc inside the triangle of the origin, `a` and `b`: a
/// triangle where the segment runs inside the disc, a circular sector where it runs
/// outside. Summed over a polygon's edges, the disc's area inside the polygon.
fn disc_in_triangle(a: DVec2, b: DVec2) -> f64 {
    let sector = |p: DVec2, q: DVec2| 0.5 * p.perp_dot(q).atan2(p.dot(q));
    let d = b - a;
    let dd = d.dot(d);
    if dd == 0.0 {
        return 0.0;
    }
    // |a + t·d|² = 1 at t = (−(a·d) ± √disc) / |d|².
    let ad = a.dot(d);
    let disc = ad * ad - dd * (a.dot(a) - 1.0);
    if disc <= 0.0 {
        return sector(a, b);
    }
    let root = disc.sqrt();
    let t0 = ((-ad - root) / dd).clamp(0.0, 1.0);
    let t1 = ((-ad + root) / dd).clamp(0.0, 1.0);
    let (p0, p1) = (a + d * t0, a + d * t1);
    sector(a, p0) + 0.5 * p0.perp_dot(p1) + sector(p1, b)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The disc inside squares and triangles whose areas are known in closed form.
    #[test]
    fn the_disc_s_area_in_a_polygon_is_exact() {
        let area = |poly: &[DVec2]| {
            let n = poly.len();
            (0..n)
                .map(|k| disc_in_triangle(poly[k], poly[(k + 1) % n]))
                .sum::<f64>()
                .abs()
        };
        let square = |x0: f64, y0: f64, x1: f64, y1: f64| {
            [
                DVec2::new(x0, y0),
                DVec2::new(x1, y0),
                DVec2::new(x1, y1),
                DVec2::new(x0, y1),
            ]
        };
        let pi = std::f64::consts::PI;
        // Around the disc, inside it, a half-plane's share, a quarter, and far away.
        assert!((area(&square(-2.0, -2.0, 2.0, 2.0)) - pi).abs() < 1e-14);
        assert!((area(&square(-0.5, -0.5, 0.5, 0.5)) - 1.0).abs() < 1e-14);
        assert!((area(&square(0.0, -2.0, 3.0, 2.0)) - pi / 2.0).abs() < 1e-14);
        assert!((area(&square(0.0, 0.0, 3.0, 3.0)) - pi / 4.0).abs() < 1e-14);
        assert!(area(&square(2.0, 2.0, 3.0, 3.0)).abs() < 1e-15);
        // A strip 0 ≤ y ≤ h across the disc: h√(1−h²) + asin h.
        let h: f64 = 0.3;
        let strip = h * (1.0 - h * h).sqrt() + h.asin();
        assert!((area(&square(-2.0, 0.0, 2.0, h)) - strip).abs() < 1e-14);
        // The same strip turned and reversed: area keeps its size.
        let (c, s) = (0.6f64, 0.8f64);
        let turned: Vec<DVec2> = square(-2.0, 0.0, 2.0, h)
            .iter()
            .rev()
            .map(|p| DVec2::new(c * p.x - s * p.y, s * p.x + c * p.y))
            .collect();
        assert!((area(&turned) - strip).abs() < 1e-14);
    }
}
