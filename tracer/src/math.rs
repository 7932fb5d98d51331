//! Rays, boxes and the floating-point error bounds that keep secondary rays off their surface.
//!
//! The tracer works in `f64` throughout. Rounding error is bounded the way pbrt does it
//! (Pharr, Jakob, Humphreys, *Physically Based Rendering*, 3rd ed., §3.9): every arithmetic
//! operation is exact up to a factor `(1 ± ε)` with `ε = 2⁻⁵³`, so `n` chained operations
//! stay within `γ(n) = nε / (1 − nε)` relative error. Hit points carry such an absolute error
//! bound per axis, and [`offset_ray_origin`] moves the origin of a secondary ray just outside
//! that box along the surface normal (Ray Tracing Gems ch. 6 discusses the same problem).
//! That is what prevents "shadow acne" at any distance from the origin, where a fixed epsilon
//! is too large near the origin and too small far from it.

use glam::DVec3;

/// Linear RGB colour, components ≥ 0 (may exceed 1 before the final clamp).
pub type Color = DVec3;

/// Unit roundoff of `f64`: every basic operation is exact up to a factor `1 ± EPS`.
pub const EPS: f64 = f64::EPSILON * 0.5;

/// pbrt's γ(n): a bound on the relative error of `n` chained floating-point operations.
#[inline]
pub const fn gamma(n: u32) -> f64 {
    let ne = n as f64 * EPS;
    ne / (1.0 - ne)
}

/// `x.floor()`, bit for bit, without a call. The baseline x86-64 target has no rounding
/// instruction (`roundsd` is SSE4.1), so `f64::floor` is a library call of a dozen branches;
/// the checker and the cell sums floor several coordinates per hit.
///
/// Below 2⁵² in magnitude the truncation through `i64` is exact, and a negative non-integer
/// truncates up, so one step down fixes it. From 2⁵² on every `f64` is an integer, and
/// infinities and NaN pass through unchanged as `floor` leaves them. `floor(x)` has the
/// sign of `x` (`floor(−0.0) = −0.0`, and a negative non-integer floors to −1 or less),
/// which the final `copysign` restores where truncation gave `+0.0`.
#[inline(always)]
pub fn floor(x: f64) -> f64 {
    const INTEGRAL: f64 = 4_503_599_627_370_496.0; // 2⁵²
    if x.abs() < INTEGRAL {
        let t = x as i64 as f64;
        (if t > x { t - 1.0 } else { t }).copysign(x)
    } else {
        x
    }
}

/// A ray `origin + t · dir`. `dir` need not be normalised; `t` is measured in units of `dir`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ray {
    /// Where the ray starts (`t = 0`).
    pub origin: DVec3,
    /// Its direction; `t = 1` is `origin + dir`.
    pub dir: DVec3,
}

impl Ray {
    #[inline]
    /// The ray from `origin` along `dir`.
    pub const fn new(origin: DVec3, dir: DVec3) -> Self {
        Ray { origin, dir }
    }

    #[inline]
    /// The point `origin + t · dir`.
    pub fn at(&self, t: f64) -> DVec3 {
        self.origin + self.dir * t
    }

    /// `1 / dir` for slab tests, with `-0.0` components made `+0.0` first (see
    /// [`Aabb::hit_interval`]).
    #[inline]
    pub fn inv_dir(&self) -> DVec3 {
        DVec3::ONE / (self.dir + DVec3::ZERO)
    }
}

/// An axis-aligned bounding box.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Aabb {
    /// The corner with the smallest coordinates.
    pub min: DVec3,
    /// The corner with the largest coordinates.
    pub max: DVec3,
}

impl Aabb {
    /// The box that holds nothing: the union with it leaves a box unchanged.
    pub const EMPTY: Aabb = Aabb {
        min: DVec3::splat(f64::INFINITY),
        max: DVec3::splat(f64::NEG_INFINITY),
    };

    /// The box from `min` to `max`.
    pub fn new(min: DVec3, max: DVec3) -> Self {
        Aabb { min, max }
    }

    /// The smallest box holding both.
    pub fn union(&self, other: &Aabb) -> Aabb {
        Aabb::new(self.min.min(other.min), self.max.max(other.max))
    }

    /// The smallest box holding this one and `p`.
    pub fn grow(&self, p: DVec3) -> Aabb {
        Aabb::new(self.min.min(p), self.max.max(p))
    }

    /// Whether the closed box holds `p`.
    pub fn contains(&self, p: DVec3) -> bool {
        (self.min.cmple(p) & p.cmple(self.max)).all()
    }

    /// Whether the box holds no point (`min > max` on some axis).
    pub fn is_empty(&self) -> bool {
        self.min.x > self.max.x || self.min.y > self.max.y || self.min.z > self.max.z
    }

    /// The box's centre.
    pub fn centroid(&self) -> DVec3 {
        (self.min + self.max) * 0.5
    }

    /// The area of its six faces.
    pub fn surface_area(&self) -> f64 {
        if self.is_empty() {
            return 0.0;
        }
        let e = self.max - self.min;
        2.0 * (e.x * e.y + e.y * e.z + e.z * e.x)
    }

    /// The eight corners, for transforming a box.
    pub fn corners(&self) -> [DVec3; 8] {
        let (a, b) = (self.min, self.max);
        [
            DVec3::new(a.x, a.y, a.z),
            DVec3::new(b.x, a.y, a.z),
            DVec3::new(a.x, b.y, a.z),
            DVec3::new(b.x, b.y, a.z),
            DVec3::new(a.x, a.y, b.z),
            DVec3::new(b.x, a.y, b.z),
            DVec3::new(a.x, b.y, b.z),
            DVec3::new(b.x, b.y, b.z),
        ]
    }

    /// Slab test: the parameter interval `[t0, t1]` (clipped to `[0, t_max]`) where the ray
    /// is inside the box, if any. `inv_dir` must come from [`Ray::inv_dir`], which turns
    /// `-0.0` into `+0.0`: then a zero direction component gives infinities of the right sign,
    /// and the one NaN (`0 · ∞`, for an origin exactly in a slab's plane) fails both
    /// comparisons below and so leaves the interval alone, which is right: such a ray lies in
    /// the closed slab for every `t`. The far bound is widened by `1 + 2γ(3)` so that a ray
    /// touching the box is not lost to rounding (pbrt §3.9.2).
    #[inline]
    pub fn hit_interval(&self, origin: DVec3, inv_dir: DVec3, t_max: f64) -> Option<(f64, f64)> {
        let mut t0 = 0.0f64;
        let mut t1 = t_max;
        for i in 0..3 {
            let mut near = (self.min[i] - origin[i]) * inv_dir[i];
            let mut far = (self.max[i] - origin[i]) * inv_dir[i];
            if near > far {
                std::mem::swap(&mut near, &mut far);
            }
            far *= 1.0 + 2.0 * gamma(3);
            if near > t0 {
                t0 = near;
            }
            if far < t1 {
                t1 = far;
            }
        }
        (t0 <= t1).then_some((t0, t1))
    }
}

/// Moves a point on a surface to just outside its error box, on the side of the surface that
/// `dir` leaves towards, so that a ray from the returned origin cannot hit the surface it
/// starts on at `t ≈ 0`.
///
/// `p_err` is an absolute per-axis bound on the error of `p`; `n` is the surface normal
/// (any length, any orientation). The offset is `dot(|n̂|, p_err)` along `n̂`, the distance
/// from `p` to the far face of the error box measured along the normal; each component is
/// then rounded one more ulp away from `p` so that the addition itself cannot round back
/// into the box (pbrt §3.9.5).
#[inline]
pub fn offset_ray_origin(p: DVec3, p_err: DVec3, n: DVec3, dir: DVec3) -> DVec3 {
    let mut n = n.normalize();
    if dir.dot(n) < 0.0 {
        n = -n;
    }
    let d = n.abs().dot(p_err);
    let mut po = p + n * d;
    // One more ulp outwards on every axis the normal has a component along, even when the
    // bound is zero (an exactly representable point on an axis-aligned face), so the origin
    // is strictly off the surface.
    for i in 0..3 {
        if n[i] > 0.0 {
            po[i] = po[i].next_up();
        } else if n[i] < 0.0 {
            po[i] = po[i].next_down();
        }
    }
    po
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn floor_gives_the_bits_of_f64_floor() {
        let two52 = 4_503_599_627_370_496.0_f64;
        let mut xs = vec![
            0.0,
            0.5,
            1.0,
            1.5,
            2.0 - f64::EPSILON,
            two52 - 0.5,
            two52,
            two52 + 1.0,
            2.0 * two52,
            1e300,
            f64::MAX,
            f64::MIN_POSITIVE,
            5e-324,
            f64::INFINITY,
            (i64::MAX as f64),
        ];
        // Pseudo-random values over many magnitudes (xorshift), and their neighbours.
        let mut r = 0x9e37_79b9_7f4a_7c15_u64;
        for _ in 0..10_000 {
            r ^= r << 13;
            r ^= r >> 7;
            r ^= r << 17;
            let mantissa = (r >> 11) as f64 / (1u64 << 53) as f64;
            let x = mantissa * 2f64.powi((r % 130) as i32 - 60);
            xs.extend([
                x,
                x.next_up(),
                x.next_down(),
                x.round(),
                x.round().next_down(),
            ]);
        }
        for x in xs.iter().flat_map(|&x| [x, -x]) {
            assert_eq!(floor(x).to_bits(), x.floor().to_bits(), "floor({x:e})");
        }
        assert!(floor(f64::NAN).is_nan());
    }

    #[test]
    fn gamma_grows_with_the_operation_count() {
        assert!(gamma(1) > EPS && gamma(1) < 1.0001 * EPS);
        assert!(gamma(3) > 3.0 * EPS);
        assert!(gamma(5) > gamma(3));
    }

    #[test]
    fn offset_origin_leaves_the_error_box_on_the_requested_side() {
        let p = DVec3::new(1e5, -3.0, 2.5e5);
        let err = DVec3::splat(1e-9);
        let n = DVec3::new(0.0, 1.0, 0.0);
        let up = offset_ray_origin(p, err, n, DVec3::new(0.3, 1.0, 0.0));
        assert!(up.y > p.y + 1e-9);
        let down = offset_ray_origin(p, err, n, DVec3::new(0.3, -1.0, 0.0));
        assert!(down.y < p.y - 1e-9);
        // No movement along the tangent plane.
        assert_eq!(up.x, p.x);
        assert_eq!(up.z, p.z);
    }

    #[test]
    fn offset_origin_with_zero_error_still_moves_one_ulp() {
        let p = DVec3::new(0.0, 1.0, 0.0);
        let o = offset_ray_origin(p, DVec3::ZERO, DVec3::Y, DVec3::Y);
        assert_eq!(o.y, 1.0f64.next_up());
    }

    #[test]
    fn slab_test_hits_touching_and_axis_parallel_rays() {
        let b = Aabb::new(DVec3::splat(-1.0), DVec3::splat(1.0));
        let inv = |d: DVec3| Ray::new(DVec3::ZERO, d).inv_dir();
        // A ray along +x, exactly in the plane y = 1 of a face: touching counts.
        let o = DVec3::new(-5.0, 1.0, 0.0);
        assert!(b.hit_interval(o, inv(DVec3::X), f64::INFINITY).is_some());
        // A ray parallel to the x axis outside the box misses.
        let o = DVec3::new(-5.0, 1.5, 0.0);
        assert!(b.hit_interval(o, inv(DVec3::X), f64::INFINITY).is_none());
        // t_max before the box: miss.
        let o = DVec3::new(-5.0, 0.0, 0.0);
        assert!(b.hit_interval(o, inv(DVec3::X), 3.0).is_none());
        assert!(b.hit_interval(o, inv(DVec3::X), 4.5).is_some());
        // Negative zero components behave like positive ones, on both faces of a slab.
        let d = DVec3::new(1.0, -0.0, 0.0);
        for y in [-1.0, 1.0] {
            let o = DVec3::new(-5.0, y, 0.0);
            assert!(
                b.hit_interval(o, inv(d), f64::INFINITY).is_some(),
                "y = {y}"
            );
        }
    }
}
