//! Placement of unit shapes in the world: a composite matrix and its inverse, as the thesis
//! builds them, plus the error bounds of applying them.
//!
//! Transforms compose in the order written in the scene file (`scale`, then `rotate`, then
//! `translate`, or any order and repetition). The inverse is composed alongside from the
//! inverse of each step (the transpose of a rotation, the reciprocal of a scale, the negated
//! translation) rather than by inverting the product, so it stays as accurate as the forward
//! matrix. Transforms that are only a uniform scale and a translation (most spheres) are
//! recognised, so intersection code can skip the general matrix products.

use glam::{DAffine3, DMat3, DVec3};

use crate::math::{Aabb, Ray, gamma};

/// One transform step as written in a scene file.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum TransformOp {
    /// Per-axis scale; no component is zero.
    Scale(DVec3),
    /// Rotation in degrees about X, then Y, then Z (right-hand rule).
    Rotate(DVec3),
    /// Translation by the vector.
    Translate(DVec3),
}

/// The largest componentwise condition ([`Transform::condition`]) of an accepted transform.
/// Past it the stored inverse undoes the matrix to fewer than about eight digits in either
/// space, and a ray carried into object space lands measurably off the surface it aims at.
pub const MAX_CONDITION: f64 = 1e8;

/// `m` with every entry replaced by its magnitude.
fn abs(m: &DMat3) -> DMat3 {
    DMat3::from_cols(m.x_axis.abs(), m.y_axis.abs(), m.z_axis.abs())
}

/// The largest sum of magnitudes along a row of `m` (its ∞-norm): `|M|·v` has no component
/// above it times `max(v)` for `v ≥ 0`. NaN when an entry is.
fn row_sum_max(m: &DMat3) -> f64 {
    let a = abs(m);
    let rows = a.x_axis + a.y_axis + a.z_axis;
    if rows.is_nan() {
        return f64::NAN;
    }
    rows.max_element()
}

/// Whether every entry of `m` off its diagonal is zero.
fn is_diagonal(m: &DMat3) -> bool {
    let c = m.to_cols_array_2d();
    (0..3).all(|i| (0..3).all(|j| i == j || c[i][j] == 0.0))
}

/// An affine object-to-world transform with its inverse.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Transform {
    to_world: DAffine3,
    to_object: DAffine3,
    /// Transposed inverse linear part: maps object normals to world normals.
    normal: DMat3,
    /// `Some((s, t))` when the transform is `p ↦ s·p + t` exactly.
    similarity: Option<(f64, DVec3)>,
    /// `1 / s` of the similarity, computed once here rather than for every ray (the same
    /// correctly rounded value, so rays come out bit for bit as if divided per ray).
    inv_scale: f64,
    /// Whether both linear parts are diagonal (every entry off the diagonal is zero): their
    /// products with a vector of error bounds are then per-axis scalings (see
    /// [`Self::origin_error`]).
    diagonal: bool,
    /// The largest row sums of the magnitudes of the forward and inverse linear parts, and
    /// the largest magnitudes of their translations, for [`Self::origin_error_max`].
    error_norms: [f64; 4],
}

impl Default for Transform {
    fn default() -> Self {
        Transform::IDENTITY
    }
}

impl Transform {
    /// The transform that leaves every point where it is.
    pub const IDENTITY: Transform = Transform {
        to_world: DAffine3::IDENTITY,
        to_object: DAffine3::IDENTITY,
        normal: DMat3::IDENTITY,
        similarity: Some((1.0, DVec3::ZERO)),
        inv_scale: 1.0,
        diagonal: true,
        error_norms: [1.0, 1.0, 0.0, 0.0],
    };

    fn from_parts(to_world: DAffine3, to_object: DAffine3) -> Transform {
        let m = to_world.matrix3;
        let uniform = m.x_axis.x;
        let is_similarity = m == DMat3::from_diagonal(DVec3::splat(uniform));
        Transform {
            to_world,
            to_object,
            normal: to_object.matrix3.transpose(),
            similarity: is_similarity.then_some((uniform, to_world.translation)),
            inv_scale: 1.0 / uniform,
            diagonal: is_diagonal(&m) && is_diagonal(&to_object.matrix3),
            error_norms: [
                row_sum_max(&m),
                row_sum_max(&to_object.matrix3),
                to_world.translation.abs().max_element(),
                to_object.translation.abs().max_element(),
            ],
        }
    }

    /// The transform of one step.
    pub fn from_op(op: TransformOp) -> Transform {
        match op {
            TransformOp::Scale(s) => Transform::from_parts(
                DAffine3::from_scale(s),
                DAffine3::from_scale(DVec3::ONE / s),
            ),
            TransformOp::Translate(t) => Transform::from_parts(
                DAffine3::from_translation(t),
                DAffine3::from_translation(-t),
            ),
            TransformOp::Rotate(deg) => {
                let r = rotation_z(deg.z) * rotation_y(deg.y) * rotation_x(deg.x);
                Transform::from_parts(DAffine3::from_mat3(r), DAffine3::from_mat3(r.transpose()))
            }
        }
    }

    /// `self` followed by `next` (as in the file: `next` is written after `self`).
    pub fn then(&self, next: &Transform) -> Transform {
        Transform::from_parts(
            next.to_world * self.to_world,
            self.to_object * next.to_object,
        )
    }

    /// True when every matrix entry is finite and the composite is not too ill-conditioned
    /// for its stored inverse to undo it: the smaller of its two componentwise condition
    /// numbers ([`Self::condition`]) is at most `MAX_CONDITION`. A zero or overflowing
    /// scale (1e200 twice gives ∞, its inverse 0) fails the first test; a rotation between
    /// two opposite extreme scales fails the second.
    pub fn is_valid(&self) -> bool {
        let finite = |a: &DAffine3| a.matrix3.is_finite() && a.translation.is_finite();
        finite(&self.to_world) && finite(&self.to_object) && self.condition() <= MAX_CONDITION
    }

    /// The componentwise condition of the linear part `M` with its stored inverse `N`, in
    /// `f64`: the smaller of `‖|N|·|M|‖∞` (object space) and `‖|M|·|N|‖∞` (world space).
    /// Rounding leaves `N·M` within `γ(3)` times the first of the identity, and `M·N` within
    /// `γ(3)` times the second, so one of them small means `N` inverts `M` to within rounding
    /// in one space; the tracer's error bounds carry `|M|` and `|N|` for the other. Any
    /// scale alone, before or after a rotation, keeps one of them near 1 however extreme.
    pub fn condition(&self) -> f64 {
        let (m, n) = (abs(&self.to_world.matrix3), abs(&self.to_object.matrix3));
        let norm = |p: DMat3| {
            let r = p.transpose();
            [r.x_axis, r.y_axis, r.z_axis]
                .iter()
                .map(|row| row.element_sum())
                .fold(0.0, f64::max)
        };
        norm(n * m).min(norm(m * n))
    }

    /// Object space to world space.
    pub fn to_world(&self) -> &DAffine3 {
        &self.to_world
    }

    /// World space to object space (the inverse).
    pub fn to_object(&self) -> &DAffine3 {
        &self.to_object
    }

    /// `Some((s, t))` when the transform is exactly `p ↦ s·p + t` (a uniform scale and a
    /// translation).
    pub fn similarity(&self) -> Option<(f64, DVec3)> {
        self.similarity
    }

    /// Transforms a world ray into object space. The direction is not renormalised, so `t`
    /// means the same point in both spaces.
    #[inline]
    pub fn ray_to_object(&self, ray: &Ray) -> Ray {
        if let Some((_, t)) = self.similarity {
            let inv = self.inv_scale;
            return Ray::new((ray.origin - t) * inv, ray.dir * inv);
        }
        Ray::new(
            self.to_object.transform_point3(ray.origin),
            self.to_object.transform_vector3(ray.dir),
        )
    }

    /// World position of an object-space point and an absolute per-axis bound on its error,
    /// given the object-space error `p_err` (pbrt §3.9.3: `γ(3)·(|M|·|p| + |t|)` for the
    /// product itself plus `(1 + γ(3))·|M|·p_err` for the carried error).
    #[inline]
    pub fn point_to_world(&self, p: DVec3, p_err: DVec3) -> (DVec3, DVec3) {
        (
            self.to_world.transform_point3(p),
            self.error_to_world(p, p_err),
        )
    }

    /// The error bound half of [`Self::point_to_world`], on its own: for callers that need
    /// the point at once and its bound only sometimes.
    #[inline]
    pub fn error_to_world(&self, p: DVec3, p_err: DVec3) -> DVec3 {
        let abs_m = abs(&self.to_world.matrix3);
        self.error_to_world_by(p, p_err, |v| abs_m * v)
    }

    /// [`Self::error_to_world`] with `by(v)` for the product `|M|·v`.
    #[inline]
    fn error_to_world_by(&self, p: DVec3, p_err: DVec3, by: impl Fn(DVec3) -> DVec3) -> DVec3 {
        gamma(3) * (by(p.abs()) + self.to_world.translation.abs()) + (1.0 + gamma(3)) * by(p_err)
    }

    /// What a secondary ray's origin must clear, per axis, at the world point `world` of the
    /// object-space hit `p` whose error bound is `p_err`: the world point's own error
    /// ([`Self::error_to_world`]) plus the rounding of carrying it back
    /// ([`Self::round_trip_error`]). Bounds are never negative (`p_err` included).
    ///
    /// For a diagonal transform (a scale and a translation) the matrix products become
    /// per-axis products with the same bits: the terms they drop are `0·v`, which is `+0`
    /// for a finite `v ≥ 0`, and adding `+0` to a sum of non-negative terms changes nothing.
    /// A non-finite input would make `0·v` a NaN there; it also makes the short form's
    /// result non-finite, and then the full products give the answer.
    #[inline]
    pub fn origin_error(&self, p: DVec3, p_err: DVec3, world: DVec3) -> DVec3 {
        if self.diagonal {
            let abs_diag = |m: &DMat3| DVec3::new(m.x_axis.x, m.y_axis.y, m.z_axis.z).abs();
            let (m, n) = (
                abs_diag(&self.to_world.matrix3),
                abs_diag(&self.to_object.matrix3),
            );
            let e = self.error_to_world_by(p, p_err, |v| m * v)
                + m * self.object_error_by(world, |v| n * v);
            if e.is_finite() {
                return e;
            }
        }
        self.error_to_world(p, p_err) + self.round_trip_error(world)
    }

    /// A bound on every component of [`Self::origin_error`]`(p, p_err, world)` from the
    /// largest components `p_max`, `p_err_max` and `world_max` of `|p|`, `p_err` and
    /// `|world|` alone: each product `|M|·v` of that bound is at most `‖M‖∞·max(v)` per
    /// axis, with the norms computed once with the transform. Its own rounding is a few
    /// ulps, which a caller's factor must cover. NaN when an input is.
    #[inline]
    pub fn origin_error_max(&self, p_max: f64, p_err_max: f64, world_max: f64) -> f64 {
        let [m, n, t, ti] = self.error_norms;
        gamma(3) * (m * p_max + t)
            + (1.0 + gamma(3)) * (m * p_err_max)
            + m * (gamma(3) * (n * world_max + ti))
    }

    /// A world-space bound on the error made when a world point `p` is carried back into
    /// object space (the first step of every intersection test), expressed in world units.
    /// The origin of a secondary ray must clear this as well as its own error, or the
    /// object-space test may see it back on the surface it left.
    #[inline]
    pub fn round_trip_error(&self, p: DVec3) -> DVec3 {
        abs(&self.to_world.matrix3) * self.to_object_error(p)
    }

    /// An object-space bound on the error of carrying world point `p` into object space
    /// (`γ(3)·(|M⁻¹|·|p| + |t⁻¹|)`, the products of the inverse matrix), per axis.
    #[inline]
    pub fn to_object_error(&self, p: DVec3) -> DVec3 {
        let abs_inv = abs(&self.to_object.matrix3);
        self.object_error_by(p, |v| abs_inv * v)
    }

    /// [`Self::to_object_error`] with `by(v)` for the product `|M⁻¹|·v`.
    #[inline]
    fn object_error_by(&self, p: DVec3, by: impl Fn(DVec3) -> DVec3) -> DVec3 {
        gamma(3) * (by(p.abs()) + self.to_object.translation.abs())
    }

    /// World point `p` in object space, computed as the ray tests compute a ray's origin
    /// ([`Self::ray_to_object`]).
    #[inline]
    pub fn point_to_object(&self, p: DVec3) -> DVec3 {
        match self.similarity {
            Some((_, t)) => (p - t) * self.inv_scale,
            None => self.to_object.transform_point3(p),
        }
    }

    /// World normal (unnormalised) of an object-space normal.
    #[inline]
    pub fn normal_to_world(&self, n: DVec3) -> DVec3 {
        self.normal * n
    }

    /// For a transform that is a uniform scale times a rotation (plus a translation): the
    /// world centre and a squared radius of a ball that holds the image of the unit ball.
    /// `None` for any other linear part (a non-uniform scale or a shear), whose image of the
    /// unit ball is an ellipsoid that no ball fits closely.
    ///
    /// "Uniform scale times a rotation" means that the columns of the linear part `M` are
    /// orthogonal and of one length `s`, to within `1e-6·s²` in every entry of their Gram
    /// matrix `MᵀM` (exact `s²·I` for a rotation; the composed sines and cosines leave a few
    /// ulps). The squared radius is Gershgorin's bound on the largest eigenvalue of `MᵀM`,
    /// the largest row sum of its absolute entries, so it holds `|M·u|²` for every unit `u`
    /// however the entries were rounded, enlarged by `1e-12` of itself for the rounding of
    /// the Gram matrix.
    pub fn rigid_ball(&self) -> Option<(DVec3, f64)> {
        let m = &self.to_world.matrix3;
        let cols = [m.x_axis, m.y_axis, m.z_axis];
        let gram = |i: usize, j: usize| cols[i].dot(cols[j]);
        let s2 = gram(0, 0);
        if !(s2 > 0.0 && s2.is_finite()) {
            return None;
        }
        let tol = 1e-6 * s2;
        let mut bound = 0.0f64;
        for i in 0..3 {
            let mut row = 0.0;
            for j in 0..3 {
                let g = gram(i, j);
                let off = if i == j { g - s2 } else { g };
                if !(off.abs() <= tol) {
                    return None;
                }
                row += g.abs();
            }
            bound = bound.max(row);
        }
        Some((self.to_world.translation, bound * (1.0 + 1e-12)))
    }

    /// World bounds of an object-space box (the box of its transformed corners).
    pub fn bounds_to_world(&self, b: &Aabb) -> Aabb {
        b.corners().iter().fold(Aabb::EMPTY, |acc, &c| {
            acc.grow(self.to_world.transform_point3(c))
        })
    }
}

/// `(sin, cos)` of an angle in degrees, exact at multiples of 90° so that axis-aligned
/// rotations map axes to axes exactly (a face at x = 1 stays at exactly ±1).
fn sin_cos_degrees(deg: f64) -> (f64, f64) {
    let r = deg.rem_euclid(360.0);
    match r {
        0.0 => (0.0, 1.0),
        90.0 => (1.0, 0.0),
        180.0 => (0.0, -1.0),
        270.0 => (-1.0, 0.0),
        _ => r.to_radians().sin_cos(),
    }
}

fn rotation_x(deg: f64) -> DMat3 {
    let (s, c) = sin_cos_degrees(deg);
    DMat3::from_cols(
        DVec3::new(1.0, 0.0, 0.0),
        DVec3::new(0.0, c, s),
        DVec3::new(0.0, -s, c),
    )
}

fn rotation_y(deg: f64) -> DMat3 {
    let (s, c) = sin_cos_degrees(deg);
    DMat3::from_cols(
        DVec3::new(c, 0.0, -s),
        DVec3::new(0.0, 1.0, 0.0),
        DVec3::new(s, 0.0, c),
    )
}

fn rotation_z(deg: f64) -> DMat3 {
    let (s, c) = sin_cos_degrees(deg);
    DMat3::from_cols(
        DVec3::new(c, s, 0.0),
        DVec3::new(-s, c, 0.0),
        DVec3::new(0.0, 0.0, 1.0),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    fn chain(ops: &[TransformOp]) -> Transform {
        ops.iter().fold(Transform::IDENTITY, |t, &op| {
            t.then(&Transform::from_op(op))
        })
    }

    /// The short form of [`Transform::origin_error`] for a scale and a translation gives the
    /// bits of the full matrix products: error bounds with zeros, subnormals and huge values,
    /// points on the axes (`±0`), scales of either sign; an infinite input takes the full
    /// products (a NaN), as it would without the short form.
    #[test]
    fn diagonal_origin_error_has_the_bits_of_the_full_products() {
        use crate::shape::test_support::Rng;
        let full = |t: &Transform, p: DVec3, e: DVec3, w: DVec3| {
            t.error_to_world(p, e) + t.round_trip_error(w)
        };
        let bits = |v: DVec3| v.to_array().map(f64::to_bits);
        let mut rng = Rng::new(5);
        let special = [0.0, -0.0, f64::MIN_POSITIVE / 8.0, 1e-300, 1e300];
        let pick = |rng: &mut Rng| -> f64 {
            let k = rng.range(0.0, 8.0) as usize;
            special
                .get(k)
                .copied()
                .unwrap_or_else(|| rng.range(-1.0, 1.0) * 10f64.powf(rng.range(-8.0, 8.0)))
        };
        for _ in 0..20000 {
            let mut v = || DVec3::new(pick(&mut rng), pick(&mut rng), pick(&mut rng));
            let (scale, shift, p, e, w) = (v(), v(), v(), v(), v());
            let t = chain(&[
                TransformOp::Scale(scale.map(|c| if c == 0.0 { 1.0 } else { c })),
                TransformOp::Translate(shift),
            ]);
            if !t.is_valid() {
                continue;
            }
            assert!(t.diagonal);
            let e = e.abs();
            assert_eq!(
                bits(t.origin_error(p, e, w)),
                bits(full(&t, p, e, w)),
                "{t:?} {p:?} {e:?} {w:?}"
            );
        }
        let t = chain(&[TransformOp::Scale(DVec3::new(2.0, 3.0, 4.0))]);
        let inf = DVec3::new(f64::INFINITY, 1.0, 1.0);
        assert!(t.origin_error(inf, DVec3::ZERO, DVec3::ONE).is_nan());
        let turned = chain(&[TransformOp::Rotate(DVec3::new(0.0, 30.0, 0.0))]);
        assert!(!turned.diagonal);
    }

    #[test]
    fn rotations_follow_the_right_hand_rule() {
        let rx = Transform::from_op(TransformOp::Rotate(DVec3::new(90.0, 0.0, 0.0)));
        assert_eq!(rx.to_world().transform_vector3(DVec3::Y), DVec3::Z);
        let ry = Transform::from_op(TransformOp::Rotate(DVec3::new(0.0, 90.0, 0.0)));
        assert_eq!(ry.to_world().transform_vector3(DVec3::Z), DVec3::X);
        let rz = Transform::from_op(TransformOp::Rotate(DVec3::new(0.0, 0.0, 90.0)));
        assert_eq!(rz.to_world().transform_vector3(DVec3::X), DVec3::Y);
    }

    #[test]
    fn rotate_applies_x_then_y_then_z() {
        // X then Y: +y → (X 90°) +z → (Y 90°) +x.
        let r = Transform::from_op(TransformOp::Rotate(DVec3::new(90.0, 90.0, 0.0)));
        assert_eq!(r.to_world().transform_vector3(DVec3::Y), DVec3::X);
    }

    #[test]
    fn steps_apply_in_the_order_written() {
        let p = DVec3::new(1.0, 0.0, 0.0);
        let st = chain(&[
            TransformOp::Scale(DVec3::splat(2.0)),
            TransformOp::Translate(DVec3::new(10.0, 0.0, 0.0)),
        ]);
        assert_eq!(
            st.to_world().transform_point3(p),
            DVec3::new(12.0, 0.0, 0.0)
        );
        let ts = chain(&[
            TransformOp::Translate(DVec3::new(10.0, 0.0, 0.0)),
            TransformOp::Scale(DVec3::splat(2.0)),
        ]);
        assert_eq!(
            ts.to_world().transform_point3(p),
            DVec3::new(22.0, 0.0, 0.0)
        );
    }

    #[test]
    fn inverse_undoes_the_composite() {
        let t = chain(&[
            TransformOp::Scale(DVec3::new(2.0, 0.5, 3.0)),
            TransformOp::Rotate(DVec3::new(10.0, 20.0, 30.0)),
            TransformOp::Translate(DVec3::new(1.0, -2.0, 3.0)),
            TransformOp::Rotate(DVec3::new(-45.0, 0.0, 5.0)),
        ]);
        let p = DVec3::new(0.3, -0.7, 1.9);
        let back = t
            .to_object()
            .transform_point3(t.to_world().transform_point3(p));
        assert!((back - p).length() < 1e-14, "{back:?}");
        assert!(t.is_valid());
        assert!(t.similarity().is_none());
    }

    #[test]
    fn uniform_scale_and_translation_is_recognised() {
        let t = chain(&[
            TransformOp::Scale(DVec3::splat(5.25)),
            TransformOp::Translate(DVec3::new(10.0, -10.0, 10.0)),
        ]);
        assert_eq!(t.similarity(), Some((5.25, DVec3::new(10.0, -10.0, 10.0))));
        let r = Ray::new(DVec3::new(0.0, 0.0, 100.0), DVec3::new(0.1, -0.1, -0.9));
        let fast = t.ray_to_object(&r);
        let general = Ray::new(
            t.to_object().transform_point3(r.origin),
            t.to_object().transform_vector3(r.dir),
        );
        assert!((fast.origin - general.origin).length() < 1e-13);
        assert!((fast.dir - general.dir).length() < 1e-15);
    }

    #[test]
    fn overflowing_transforms_are_invalid() {
        let big = chain(&[TransformOp::Scale(DVec3::splat(1e200))]);
        assert!(big.is_valid(), "large but representable");
        for s in [1e200, 1e-200] {
            let t = chain(&[
                TransformOp::Scale(DVec3::splat(s)),
                TransformOp::Scale(DVec3::splat(s)),
            ]);
            assert!(!t.is_valid(), "scale {s} twice");
        }
    }

    #[test]
    fn an_extreme_scale_is_judged_by_the_space_it_stays_accurate_in() {
        let rotate = TransformOp::Rotate(DVec3::new(10.0, 20.0, 30.0));
        let scale = TransformOp::Scale(DVec3::new(1e4, 1e-4, 1.0));
        let big = TransformOp::Scale(DVec3::new(1e6, 1e-6, 1.0));
        let unbig = TransformOp::Scale(DVec3::new(1e-6, 1e6, 1.0));
        for (ops, valid) in [
            (vec![scale], true),
            (vec![rotate, scale], true),
            (vec![scale, rotate], true),
            (vec![big, rotate], true),
            // A rotation between opposite extreme scales mixes axes 1e12 apart.
            (vec![big, rotate, unbig], false),
        ] {
            let t = chain(&ops);
            assert_eq!(t.is_valid(), valid, "{ops:?}: condition {}", t.condition());
            if valid {
                // The stored inverse undoes the matrix to within the accepted condition in the
                // space it is judged in.
                let (m, n) = (t.to_world().matrix3, t.to_object().matrix3);
                let worst = |p: DMat3| {
                    (p - DMat3::IDENTITY)
                        .to_cols_array()
                        .iter()
                        .fold(0.0f64, |a, e| a.max(e.abs()))
                };
                let residual = worst(n * m).min(worst(m * n));
                assert!(residual <= gamma(3) * MAX_CONDITION, "{ops:?}: {residual}");
            }
        }
    }

    #[test]
    fn normals_stay_perpendicular_under_non_uniform_scale() {
        let t = chain(&[TransformOp::Scale(DVec3::new(4.0, 1.0, 1.0))]);
        // The tangent (1, -1, 0)/√2 of the unit sphere at (1,1,0)/√2 and its normal.
        let tangent = t.to_world().transform_vector3(DVec3::new(1.0, -1.0, 0.0));
        let normal = t.normal_to_world(DVec3::new(1.0, 1.0, 0.0));
        assert!(tangent.dot(normal).abs() < 1e-15);
    }

    #[test]
    fn world_error_bound_covers_the_actual_error() {
        let t = chain(&[
            TransformOp::Rotate(DVec3::new(13.0, 27.0, 71.0)),
            TransformOp::Translate(DVec3::new(1e5, 1e5, 1e5)),
        ]);
        let p = DVec3::new(0.6, 0.0, 0.8);
        let (w, err) = t.point_to_world(p, DVec3::ZERO);
        // Adding a translation of 1e5 alone can round by half an ulp of 1e5 (≈ 7e-12), so a
        // bound below that would be wrong; one far above the few ulps involved is useless.
        assert!(err.min_element() >= 1e5 * gamma(1));
        assert!(err.max_element() < 1e-9);
        assert!(w.is_finite());
    }
}
