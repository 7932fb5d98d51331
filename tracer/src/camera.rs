//! The pinhole camera: from a position on the image plane (in pixels) to a world ray.
//!
//! Pixel `(i, j)` covers `[i, i+1) × [j, j+1)` of the image plane, with `j` counting down from
//! the top row, so the centre of the top-left pixel is `(0.5, 0.5)`. `fov` is the vertical
//! field of view; the horizontal one follows from the aspect ratio (square pixels).

use glam::DVec3;

use crate::math::Ray;
use crate::scene::CameraDesc;

/// The pinhole camera: the eye, the image plane at unit distance along the view, and the
/// primary ray through any point of the image.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Camera {
    eye: DVec3,
    /// Direction through the image centre (unit).
    forward: DVec3,
    /// Image-plane step per pixel to the right and downwards, at unit distance.
    right_per_px: DVec3,
    down_per_px: DVec3,
    /// Direction through the top-left corner of the image (at unit distance).
    corner: DVec3,
}

impl Camera {
    /// A camera for an image of `width × height` pixels. The description is assumed valid
    /// (the parser refuses `eye == look_at` and an `up` parallel to the view direction).
    pub fn new(desc: &CameraDesc, width: u32, height: u32) -> Camera {
        let forward = (desc.look_at - desc.eye).normalize();
        let right = forward.cross(desc.up).normalize();
        let up = right.cross(forward);
        let half_h = (desc.fov_degrees.to_radians() * 0.5).tan();
        let half_w = half_h * f64::from(width) / f64::from(height);
        let right_per_px = right * (2.0 * half_w / f64::from(width));
        let down_per_px = -up * (2.0 * half_h / f64::from(height));
        Camera {
            eye: desc.eye,
            forward,
            right_per_px,
            down_per_px,
            corner: forward - right * half_w + up * half_h,
        }
    }

    /// Where primary rays start.
    pub fn eye(&self) -> DVec3 {
        self.eye
    }

    /// An upper bound on the angle between two rays through the same pixel, anywhere in the
    /// image: the angle a pixel's diagonal subtends seen square-on from the image centre.
    ///
    /// The image plane lies at unit distance, perpendicular to `forward` through the image
    /// centre. A segment of length `L` in that plane subtends at most `2·atan(L/2)`, the angle
    /// it subtends when centred on the foot of the perpendicular, and two points of one
    /// pixel's square are at most its diagonal apart.
    pub fn pixel_angle(&self) -> f64 {
        self.widest_angle(1.0)
    }

    /// An upper bound on the angle between the ray through a pixel's centre and any other ray
    /// through that pixel: as [`Camera::pixel_angle`], for half the diagonal.
    pub fn pixel_angle_from_centre(&self) -> f64 {
        self.widest_angle(0.5)
    }

    /// An upper bound on the angle between the ray through the centre of a quarter of a
    /// pixel's square (half its side each way) and any other ray through that quarter: as
    /// [`Camera::pixel_angle`], for a quarter of the diagonal.
    pub fn quadrant_angle_from_centre(&self) -> f64 {
        self.widest_angle(0.25)
    }

    /// The widest angle a segment of `fraction` of a pixel's diagonal subtends (see
    /// [`Camera::pixel_angle`]).
    fn widest_angle(&self, fraction: f64) -> f64 {
        let length = (self.right_per_px + self.down_per_px).length() * fraction;
        2.0 * (length * 0.5).atan()
    }

    /// The image-plane position `(x, y)` in pixels of world point `p`, with its depth along
    /// `forward` (for depth > 0 only; otherwise `None`: no primary ray reaches such a point,
    /// since every primary direction has forward component 1 before normalisation).
    pub fn project(&self, p: DVec3) -> Option<(f64, f64)> {
        let v = p - self.eye;
        let depth = v.dot(self.forward);
        if !(depth > 0.0) {
            return None;
        }
        let q = v / depth - self.corner;
        Some((
            q.dot(self.right_per_px) / self.right_per_px.length_squared(),
            q.dot(self.down_per_px) / self.down_per_px.length_squared(),
        ))
    }

    /// The direction, not normalised, of the ray through image position `(x, y)`: affine in
    /// `(x, y)`, with [`Camera::steps`] its steps per pixel.
    #[inline]
    pub(crate) fn direction(&self, x: f64, y: f64) -> DVec3 {
        self.corner + self.right_per_px * x + self.down_per_px * y
    }

    /// The unit direction through the image centre, perpendicular to the image plane.
    pub(crate) fn forward(&self) -> DVec3 {
        self.forward
    }

    /// How [`Camera::direction`] changes per pixel to the right and per pixel down.
    pub(crate) fn steps(&self) -> (DVec3, DVec3) {
        (self.right_per_px, self.down_per_px)
    }

    /// The ray through image-plane position `(x, y)` in pixels, direction normalised.
    #[inline]
    pub fn ray(&self, x: f64, y: f64) -> Ray {
        Ray::new(self.eye, self.direction(x, y).normalize())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn default_camera(w: u32, h: u32) -> Camera {
        Camera::new(&CameraDesc::default(), w, h)
    }

    #[test]
    fn centre_of_the_image_looks_at_the_target() {
        let c = default_camera(640, 480);
        let r = c.ray(320.0, 240.0);
        assert_eq!(r.origin, DVec3::new(0.0, 0.0, 100.0));
        assert!((r.dir - DVec3::new(0.0, 0.0, -1.0)).length() < 1e-15);
    }

    #[test]
    fn top_edge_is_half_the_vertical_fov_up() {
        let c = default_camera(640, 480);
        let r = c.ray(320.0, 0.0);
        let angle = r.dir.angle_between(DVec3::new(0.0, 0.0, -1.0)).to_degrees();
        assert!((angle - 15.0).abs() < 1e-12);
        assert!(r.dir.y > 0.0, "row 0 is the top of the image");
        let left = c.ray(0.0, 240.0);
        assert!(left.dir.x < 0.0, "column 0 is the left of the image");
    }

    #[test]
    fn pixels_are_square() {
        let c = default_camera(400, 100);
        // One pixel right and one pixel down subtend the same angle at the centre.
        let a = c.ray(200.0, 50.0).dir;
        let r = c.ray(201.0, 50.0).dir;
        let d = c.ray(200.0, 51.0).dir;
        assert!((a.angle_between(r) - a.angle_between(d)).abs() < 1e-12);
    }

    #[test]
    fn arbitrary_orientation_keeps_up_upwards() {
        let desc = CameraDesc {
            eye: DVec3::new(10.0, 5.0, -3.0),
            look_at: DVec3::new(-2.0, 0.0, 4.0),
            up: DVec3::Y,
            fov_degrees: 60.0,
        };
        let c = Camera::new(&desc, 100, 100);
        let centre = c.ray(50.0, 50.0).dir;
        assert!((centre - (desc.look_at - desc.eye).normalize()).length() < 1e-14);
        let top = c.ray(50.0, 0.0).dir;
        assert!(top.y > centre.y);
    }

    /// A `w × h` camera looking down and sideways at an angle, with field of view `fov`.
    fn tilted(w: u32, h: u32, fov: f64) -> Camera {
        let desc = CameraDesc {
            eye: DVec3::new(1.0, 2.0, 3.0),
            look_at: DVec3::new(-4.0, 0.5, -2.0),
            up: DVec3::Y,
            fov_degrees: fov,
        };
        Camera::new(&desc, w, h)
    }

    /// Two rays through one pixel are never further apart than `pixel_angle`, anywhere in
    /// the image, and the bound is reached (within 1e-3) at the centre.
    #[test]
    fn pixel_angle_bounds_every_pixel() {
        let c = tilted(64, 48, 100.0);
        let bound = c.pixel_angle();
        let mut widest: f64 = 0.0;
        for (px, py) in [
            (0.0, 0.0),
            (63.0, 47.0),
            (32.0, 24.0),
            (31.0, 23.0),
            (-2.0, 50.0),
        ] {
            // Opposite corners are the farthest apart two points of the square.
            for ((ax, ay), (bx, by)) in [((0.0, 0.0), (1.0, 1.0)), ((1.0, 0.0), (0.0, 1.0))] {
                let a = c.ray(px + ax, py + ay).dir;
                let b = c.ray(px + bx, py + by).dir;
                let angle = a.angle_between(b);
                assert!(angle <= bound, "pixel ({px}, {py}): {angle} > {bound}");
                widest = widest.max(angle);
            }
        }
        assert!(widest > bound * (1.0 - 1e-3), "{widest} vs {bound}");
        // From the centre to the corners, the same for half the diagonal.
        let from_centre = c.pixel_angle_from_centre();
        let mut widest: f64 = 0.0;
        for (px, py) in [(0.0, 0.0), (63.0, 47.0), (32.0, 24.0), (31.0, 23.0)] {
            let centre = c.ray(px + 0.5, py + 0.5).dir;
            for (dx, dy) in [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0)] {
                let angle = centre.angle_between(c.ray(px + dx, py + dy).dir);
                assert!(angle <= from_centre, "pixel ({px}, {py}): {angle}");
                widest = widest.max(angle);
            }
        }
        assert!(
            widest > from_centre * (1.0 - 1e-3),
            "{widest} vs {from_centre}"
        );
    }

    /// `project` is the inverse of `ray`, and refuses points behind the eye.
    #[test]
    fn projection_inverts_the_rays() {
        let c = tilted(64, 48, 50.0);
        for (x, y) in [(0.0, 0.0), (12.25, 40.5), (63.9, 47.9), (-5.0, 60.0)] {
            let r = c.ray(x, y);
            for t in [0.5, 10.0, 1e4] {
                let (px, py) = c.project(r.origin + r.dir * t).expect("in front");
                assert!(
                    (px - x).abs() < 1e-9 && (py - y).abs() < 1e-9,
                    "({x}, {y}) at {t}"
                );
            }
            assert_eq!(c.project(r.origin - r.dir), None);
        }
    }
}
