//! Test support: scene construction, and a reference tracer written independently from the
//! crate, straight from SCENE.md's formulas (textbook quadratics, no matrices, no error
//! bounds), to check rendered pixels against a second method.
//!
//! The reference also reports whether any decision it made was close to a tie (a ray nearly
//! tangent to a sphere, a shadow ray grazing an occluder, a point near a checker line):
//! there the two methods may legitimately disagree, so comparisons skip those pixels.

#![allow(dead_code)]

use glam::DVec3;
use tessera_tracer::{Limits, MemoryAssets, Scene, TextureLimits};

pub fn scene(src: &str) -> Scene {
    scene_with(src, &MemoryAssets::new())
}

pub fn scene_with(src: &str, assets: &MemoryAssets) -> Scene {
    match Scene::from_source(src, &Limits::default(), assets, &TextureLimits::default()) {
        Ok(s) => s,
        Err(e) => panic!("test scene does not parse:\n{e}\n---\n{src}"),
    }
}

/// sRGB encoding straight from its definition, for independent expectations.
pub fn srgb_byte(linear: f64) -> u8 {
    let x = linear.clamp(0.0, 1.0);
    let v = if x <= 0.0031308 {
        12.92 * x
    } else {
        1.055 * x.powf(1.0 / 2.4) - 0.055
    };
    (v * 255.0).round() as u8
}

#[derive(Debug, Clone, Copy)]
pub struct RefSphere {
    pub centre: DVec3,
    pub radius: f64,
    pub color: DVec3,
    pub mirror: f64,
}

#[derive(Debug, Clone, Copy)]
pub struct RefPlane {
    pub y: f64,
    pub color1: DVec3,
    pub color2: Option<DVec3>,
    pub mirror: f64,
}

#[derive(Debug, Clone)]
pub struct Reference {
    pub eye: DVec3,
    pub look_at: DVec3,
    pub up: DVec3,
    pub fov: f64,
    pub width: u32,
    pub height: u32,
    pub ambient: DVec3,
    pub shadow: f64,
    pub background: DVec3,
    pub max_depth: u32,
    pub lights: Vec<(DVec3, DVec3)>,
    pub spheres: Vec<RefSphere>,
    pub plane: Option<RefPlane>,
}

/// Relative closeness below which a decision counts as a near-tie.
const TIE: f64 = 1e-7;

/// Both roots of `|o + t·d − c|² = r²` for unit `d` (textbook: `t² + 2bt + c = 0`), if the
/// line meets the sphere, and whether the line is within a near-tie of tangency.
fn sphere_roots(o: DVec3, d: DVec3, s: &RefSphere) -> (Option<(f64, f64)>, bool) {
    let oc = o - s.centre;
    let b = oc.dot(d);
    let c = oc.length_squared() - s.radius * s.radius;
    let disc = b * b - c;
    let tie = disc.abs() < TIE * s.radius * s.radius;
    if disc < 0.0 {
        return (None, tie);
    }
    let sq = disc.sqrt();
    (Some((-b - sq, -b + sq)), tie)
}

impl Reference {
    pub fn new(width: u32, height: u32) -> Self {
        Reference {
            eye: DVec3::new(0.0, 0.0, 100.0),
            look_at: DVec3::ZERO,
            up: DVec3::Y,
            fov: 30.0,
            width,
            height,
            ambient: DVec3::splat(0.1),
            shadow: 1.0,
            background: DVec3::ZERO,
            max_depth: 5,
            lights: Vec::new(),
            spheres: Vec::new(),
            plane: None,
        }
    }

    /// The primary ray through image position `(sx, sy)` in pixels: the image plane at unit
    /// distance spans `±tan(fov/2)` vertically and `±tan(fov/2)·W/H` horizontally.
    pub fn primary(&self, sx: f64, sy: f64) -> (DVec3, DVec3) {
        let f = (self.look_at - self.eye).normalize();
        let r = f.cross(self.up).normalize();
        let u = r.cross(f);
        let th = (self.fov.to_radians() / 2.0).tan();
        let (w, h) = (f64::from(self.width), f64::from(self.height));
        let nx = (2.0 * sx / w - 1.0) * th * w / h;
        let ny = (1.0 - 2.0 * sy / h) * th;
        (self.eye, (f + r * nx + u * ny).normalize())
    }

    /// Nearest hit: (t, point, outward normal, colour, mirror, near-tie).
    fn hit(&self, o: DVec3, d: DVec3) -> Option<(f64, DVec3, DVec3, DVec3, f64, bool)> {
        let mut best: Option<(f64, DVec3, DVec3, DVec3, f64, bool)> = None;
        let mut tie = false;
        for s in &self.spheres {
            let (roots, near) = sphere_roots(o, d, s);
            tie |= near;
            let Some((t0, t1)) = roots else { continue };
            let t = if t0 > 1e-9 { t0 } else { t1 };
            if t > 1e-9 && best.is_none_or(|h| t < h.0) {
                let p = o + d * t;
                best = Some((t, p, (p - s.centre) / s.radius, s.color, s.mirror, false));
            }
        }
        if let Some(pl) = self.plane
            && d.y != 0.0
        {
            let t = (pl.y - o.y) / d.y;
            if t > 1e-9 && best.is_none_or(|h| t < h.0) {
                let p = o + d * t;
                let mut color = pl.color1;
                let mut near_line = false;
                if let Some(c2) = pl.color2 {
                    let (fx, fz) = (p.x - p.x.floor(), p.z - p.z.floor());
                    near_line = [fx, 1.0 - fx, fz, 1.0 - fz].iter().any(|f| *f < TIE * 10.0);
                    if (p.x.floor() + p.z.floor()).rem_euclid(2.0) == 1.0 {
                        color = c2;
                    }
                }
                best = Some((t, p, DVec3::Y, color, pl.mirror, near_line));
            }
        }
        best.map(|mut h| {
            h.5 |= tie;
            h
        })
    }

    /// Whether the open segment from `p` to `light` is blocked, and whether that was close.
    fn blocked(&self, p: DVec3, light: DVec3) -> (bool, bool) {
        let seg = light - p;
        let len = seg.length();
        let d = seg / len;
        let mut tie = false;
        for s in &self.spheres {
            let (roots, near) = sphere_roots(p, d, s);
            tie |= near;
            let Some((t0, t1)) = roots else { continue };
            for t in [t0, t1] {
                // A root at t ≈ 0 is the point itself, on this sphere; one near the light
                // end is a sphere touching the light: a tie.
                if (t - len).abs() < 1e-6 * len {
                    tie = true;
                }
                if t > 1e-6 * len && t < len * (1.0 - 1e-6) {
                    return (true, tie);
                }
            }
        }
        if let Some(pl) = self.plane {
            let (a, b) = (p.y - pl.y, light.y - pl.y);
            if a * b < 0.0 && a.abs() > 1e-9 && b.abs() > 1e-9 {
                return (true, tie);
            }
        }
        (false, tie)
    }

    /// Radiance (unclamped) and whether any decision on the way was a near-tie.
    pub fn radiance(&self, o: DVec3, d: DVec3, bounces_left: u32) -> (DVec3, bool) {
        let Some((_, p, outward, c, m, mut tie)) = self.hit(o, d) else {
            return (self.background, false);
        };
        let n = if outward.dot(d) > 0.0 {
            -outward
        } else {
            outward
        };
        let mut sum = DVec3::ZERO;
        for &(lp, lc) in &self.lights {
            let l = lp - p;
            let cos = n.dot(l.normalize());
            if cos.abs() < 1e-9 {
                tie = true;
            }
            if cos <= 0.0 {
                continue;
            }
            let (blocked, t) = self.blocked(p, lp);
            tie |= t;
            let v = if blocked { 1.0 - self.shadow } else { 1.0 };
            sum += lc * cos * v;
        }
        let local = c * (self.ambient + sum);
        let mut l = local * (1.0 - m);
        if m > 0.0 && bounces_left > 0 {
            let r = d - n * 2.0 * d.dot(n);
            let (lr, t) = self.radiance(p, r, bounces_left - 1);
            tie |= t;
            l += lr * m;
        }
        (l, tie)
    }

    /// Clamped radiance of the centre ray of pixel `(i, j)`.
    pub fn pixel_center(&self, i: u32, j: u32) -> (DVec3, bool) {
        let (o, d) = self.primary(f64::from(i) + 0.5, f64::from(j) + 0.5);
        let (l, tie) = self.radiance(o, d, self.max_depth);
        (l.min(DVec3::ONE), tie)
    }

    /// The thesis's five-ray average for pixel `(i, j)`.
    pub fn pixel_thesis(&self, i: u32, j: u32) -> (DVec3, bool) {
        let mut sum = DVec3::ZERO;
        let mut tie = false;
        for (dx, dy) in [
            (0.5, 0.5),
            (0.25, 0.25),
            (0.75, 0.25),
            (0.25, 0.75),
            (0.75, 0.75),
        ] {
            let (o, d) = self.primary(f64::from(i) + dx, f64::from(j) + dy);
            let (l, t) = self.radiance(o, d, self.max_depth);
            sum += l.min(DVec3::ONE);
            tie |= t;
        }
        (sum / 5.0, tie)
    }
}

/// Compares a rendered linear image with the reference pixel by pixel; returns how many
/// pixels were compared (near-ties skipped). Panics on the first mismatch beyond `tol`.
pub fn compare_with_reference(
    rendered: &[DVec3],
    reference: &Reference,
    thesis: bool,
    tol: f64,
) -> usize {
    let mut compared = 0;
    for j in 0..reference.height {
        for i in 0..reference.width {
            let (expected, tie) = if thesis {
                reference.pixel_thesis(i, j)
            } else {
                reference.pixel_center(i, j)
            };
            let got = rendered[(j * reference.width + i) as usize];
            assert!(got.is_finite(), "pixel ({i}, {j}) is not finite: {got:?}");
            if tie {
                continue;
            }
            compared += 1;
            assert!(
                (got - expected).abs().max_element() <= tol,
                "pixel ({i}, {j}): rendered {got:?}, reference {expected:?}"
            );
        }
    }
    compared
}

/// SplitMix64: a small deterministic generator, so failures reproduce.
pub struct Rng(pub u64);

impl Rng {
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    pub fn unit(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }

    pub fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.unit()
    }

    pub fn below(&mut self, n: u64) -> u64 {
        self.next_u64() % n
    }

    pub fn vec(&mut self, r: f64) -> DVec3 {
        DVec3::new(self.range(-r, r), self.range(-r, r), self.range(-r, r))
    }
}
