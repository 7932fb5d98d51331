//! The pinhole camera: from a position on the image plane (in pixels) to a world ray.
//!
//! Pixel `(i, j)` covers `[i, i+1) × [j, j+1)` of the image plane, with `j` counting down from
//! the top row, so the centre of the top-left pixel is `(0.5, 0.5)`. `fov` is the vertical
//! field of view; the horizontal one follows from the aspect ratio (square pixels).

use glam::DVec3;

use crate::math::Ray;
use crate::scene::CameraDesc;

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

    pub fn eye(&self) -> DVec3 {
        self.eye
    }

    pub fn forward(&self) -> DVec3 {
        self.forward
    }

    /// The ray through image-plane position `(x, y)` in pixels, direction normalised.
    #[inline]
    pub fn ray(&self, x: f64, y: f64) -> Ray {
        let d = self.corner + self.right_per_px * x + self.down_per_px * y;
        Ray::new(self.eye, d.normalize())
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
}
