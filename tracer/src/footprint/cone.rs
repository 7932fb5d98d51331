//! Cones of rays around a pixel's rays, and the tests that compare them with spheres,
//! capsules and planes as sines and cosines with a margin (see the module above).

use glam::DVec3;

/// Radians every angular comparison keeps to spare (see the module comment). A pixel of a
/// 7680-pixel-wide image at a 1° field of view still spans 2e-6 radians, 2,000 times this.
pub const ANGLE_MARGIN: f64 = 1e-9;

/// A cone's half-angle with what its tests need of it, computed once per tile.
#[derive(Debug, Clone, Copy)]
pub struct Aperture {
    /// The half-angle, widened as the module comment says.
    pub(super) half_angle: f64,
    pub(super) sin: f64,
    pub(super) cos: f64,
}

impl Aperture {
    /// The aperture of half-angle `half_angle`, widened as the module comment says.
    pub fn new(half_angle: f64) -> Aperture {
        let half_angle = half_angle * (1.0 + 1e-6) + ANGLE_MARGIN;
        Aperture {
            half_angle,
            sin: half_angle.sin(),
            cos: half_angle.cos(),
        }
    }
}

/// The cone from `origin` around the unit direction `axis`.
#[derive(Debug, Clone, Copy)]
pub struct Cone {
    pub(super) origin: DVec3,
    pub(super) axis: DVec3,
    pub(super) aperture: Aperture,
}

/// How a cone meets a plane.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PlaneView {
    /// No direction of the cone reaches the plane.
    Misses,
    /// Some do, some do not: the horizon is inside the cone.
    Horizon,
    /// Every direction reaches it.
    Covers,
}

impl Cone {
    /// The cone of `aperture` from `origin` around the unit direction `axis`.
    pub fn new(origin: DVec3, axis: DVec3, aperture: Aperture) -> Cone {
        Cone {
            origin,
            axis,
            aperture,
        }
    }

    /// Whether some direction of the cone meets the ball of centre `c` and radius `r`. The
    /// footprints prepare a [`BallTest`] once per ball instead; this is the tests' form.
    #[cfg(test)]
    pub fn meets_sphere(&self, c: DVec3, r: f64) -> bool {
        BallTest::new(self.origin, self.aperture, c, r).meets(self.axis)
    }

    /// Whether every direction of the cone meets the ball of centre `c` and radius `r`, the
    /// origin being outside it.
    pub fn inside_sphere(&self, c: DVec3, r: f64) -> bool {
        let Some(seen) = sphere_seen(self.origin, c, r) else {
            return false;
        };
        let ap = &self.aperture;
        // γ = α − φ − margin, which must be positive; below 90° since α is.
        let sin_g0 = seen.sin_a * ap.cos - seen.cos_a * ap.sin;
        let cos_g0 = seen.cos_a * ap.cos + seen.sin_a * ap.sin;
        let sin_g = sin_g0 * MARGIN_COS - cos_g0 * MARGIN_SIN;
        sin_g > 0.0 && seen.within(self.axis, sin_g)
    }

    /// Whether the cone may meet the capsule of radius `r` around the segment from `a` to
    /// `b`: unless the segment's distance from the axis exceeds `r` by more than the cone's
    /// radius at the capsule's farthest point (a point of the capsule in the cone would be
    /// within that radius of the axis, and it is within `r` of the segment). The distance is
    /// that of the closest points of the segment and the axis up to that farthest distance,
    /// which holds the axis points nearest to every point of the capsule (Ericson, *Real-Time
    /// Collision Detection*, 5.1.9); the comparison keeps 1e-9 of that distance to spare.
    ///
    /// The footprints prepare a [`CapsuleTest`] once per capsule instead; this is the tests'
    /// form.
    #[cfg(test)]
    pub fn may_meet_capsule(&self, a: DVec3, b: DVec3, r: f64) -> bool {
        CapsuleTest::new(self.origin, self.aperture, a, b, r).meets(self.axis)
    }

    /// How the cone meets the plane through `p0` with normal `n` (any length).
    pub fn view_of_plane(&self, p0: DVec3, n: DVec3) -> PlaneView {
        let h = (self.origin - p0).dot(n);
        if !(h != 0.0) || !n.is_finite() {
            return PlaneView::Horizon;
        }
        // The direction straight towards the plane, and the cone axis's angle from it: a
        // direction reaches the plane exactly when that angle is below 90°.
        let towards = if h > 0.0 { -n } else { n };
        let beta = angle_between(self.axis, towards);
        let right = std::f64::consts::FRAC_PI_2;
        let phi = self.aperture.half_angle;
        if beta + phi <= right - ANGLE_MARGIN {
            PlaneView::Covers
        } else if beta - phi >= right + ANGLE_MARGIN {
            PlaneView::Misses
        } else {
            PlaneView::Horizon
        }
    }
}

/// [`Cone::meets_sphere`] for every cone of one origin and aperture, with what depends on
/// the axis alone left to [`BallTest::meets`]: a tile's pixels ask it of one ball with many
/// axes.
#[derive(Debug, Clone, Copy)]
pub(super) enum BallTest {
    /// The origin is inside (or on) the ball, or something is NaN: every direction meets it.
    Always,
    /// The axis meets it when its angle from the centre has a sine at most `sin_b`.
    Sine { seen: SphereSeen, sin_b: f64 },
    /// β = α + φ is too near 90° for sines: the angle itself, at most `limit`.
    Angle { v: DVec3, limit: f64 },
}

impl BallTest {
    pub(super) fn new(origin: DVec3, ap: Aperture, c: DVec3, r: f64) -> BallTest {
        let Some(seen) = sphere_seen(origin, c, r) else {
            return BallTest::Always;
        };
        // β = α + φ + margin; as sines only while β stays well below 90°.
        let sin_b0 = seen.sin_a * ap.cos + seen.cos_a * ap.sin;
        let cos_b0 = seen.cos_a * ap.cos - seen.sin_a * ap.sin;
        let sin_b = sin_b0 * MARGIN_COS + cos_b0 * MARGIN_SIN;
        if !(sin_b < 0.9) {
            let alpha = seen.sin_a.asin();
            return BallTest::Angle {
                v: seen.v,
                limit: alpha + ap.half_angle + ANGLE_MARGIN,
            };
        }
        BallTest::Sine { seen, sin_b }
    }

    /// Whether some direction of the cone around unit `axis` meets the ball.
    #[inline]
    pub(super) fn meets(&self, axis: DVec3) -> bool {
        match self {
            BallTest::Always => true,
            BallTest::Sine { seen, sin_b } => seen.within(axis, *sin_b),
            BallTest::Angle { v, limit } => angle_between(axis, *v) <= *limit,
        }
    }
}

/// [`Cone::may_meet_capsule`] for every cone of one origin and aperture, with what depends
/// on the axis alone left to [`CapsuleTest::meets`].
#[derive(Debug, Clone, Copy)]
pub(super) struct CapsuleTest {
    origin: DVec3,
    a: DVec3,
    r: f64,
    /// The farthest distance from the origin of a point of the capsule.
    far: f64,
    /// `b − a`, `w = origin − a`, and their products.
    d2: DVec3,
    w: DVec3,
    ee: f64,
    ff: f64,
    /// The cone's radius at `far`, with 1e-9 of `far` to spare.
    slack: f64,
}

impl CapsuleTest {
    pub(super) fn new(origin: DVec3, ap: Aperture, a: DVec3, b: DVec3, r: f64) -> CapsuleTest {
        let far = (a - origin).length().max((b - origin).length()) + r;
        let d2 = b - a;
        let w = origin - a;
        let width = ap.half_angle.tan() * far;
        CapsuleTest {
            origin,
            a,
            r,
            far,
            d2,
            w,
            ee: d2.dot(d2),
            ff: d2.dot(w),
            slack: width + 1e-9 * far,
        }
    }

    /// Whether the cone around unit `axis` may meet the capsule (see
    /// [`Cone::may_meet_capsule`]).
    #[inline]
    pub(super) fn meets(&self, axis: DVec3) -> bool {
        let CapsuleTest {
            origin,
            a,
            r,
            far,
            d2,
            w,
            ee,
            ff,
            slack,
        } = *self;
        let d1 = axis * far;
        let aa = d1.dot(d1);
        let c = d1.dot(w);
        let (s, t) = if ee <= f64::MIN_POSITIVE {
            ((-c / aa).clamp(0.0, 1.0), 0.0)
        } else {
            let bb = d1.dot(d2);
            let denom = aa * ee - bb * bb;
            let mut s = if denom > 0.0 {
                ((bb * ff - c * ee) / denom).clamp(0.0, 1.0)
            } else {
                0.0
            };
            let mut t = (bb * s + ff) / ee;
            if t < 0.0 {
                t = 0.0;
                s = (-c / aa).clamp(0.0, 1.0);
            } else if t > 1.0 {
                t = 1.0;
                s = ((bb - c) / aa).clamp(0.0, 1.0);
            }
            (s, t)
        };
        let gap = ((origin + d1 * s) - (a + d2 * t)).length();
        // NaN anywhere: "may".
        !(gap - r > slack)
    }
}

/// The ball of centre `c` and radius `r` as seen from `origin`: `None` from inside it (or
/// for NaN).
pub(super) fn sphere_seen(origin: DVec3, c: DVec3, r: f64) -> Option<SphereSeen> {
    let v = c - origin;
    let d2 = v.length_squared();
    if !(d2 > r * r) {
        return None;
    }
    let d = d2.sqrt();
    let sin_a = r / d;
    Some(SphereSeen {
        v,
        d,
        sin_a,
        cos_a: (1.0 - sin_a * sin_a).max(0.0).sqrt(),
    })
}

/// A ball seen from a cone's origin: the direction `v` and distance `d` to its centre, and
/// the sine and cosine of the angle `α` it fills around that direction.
#[derive(Debug, Clone, Copy)]
pub(super) struct SphereSeen {
    pub(super) v: DVec3,
    pub(super) d: f64,
    pub(super) sin_a: f64,
    pub(super) cos_a: f64,
}

impl SphereSeen {
    /// Whether the angle from unit `axis` to the centre is below 90° and has sine at most
    /// `sin` (`|axis × v| = d·sin θ`, exact to a few ulps even for tiny angles).
    pub(super) fn within(&self, axis: DVec3, sin: f64) -> bool {
        axis.dot(self.v) > 0.0 && axis.cross(self.v).length() <= sin * self.d
    }
}

/// `sin` and `cos` of [`ANGLE_MARGIN`] (its sine is itself to 17 digits, its cosine 1).
pub(super) const MARGIN_SIN: f64 = ANGLE_MARGIN;
pub(super) const MARGIN_COS: f64 = 1.0;

/// The angle between two non-zero vectors, to a few ulps at any size (`atan2` of the cross
/// and dot products).
pub(super) fn angle_between(a: DVec3, b: DVec3) -> f64 {
    a.cross(b).length().atan2(a.dot(b))
}
