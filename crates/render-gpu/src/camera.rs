//! Pinhole camera with Mitsuba's orientation: (target − origin) × up points right,
//! row 0 is the top of the image, the field of view is horizontal.

use glam::Vec3;

use crate::scene::CameraDesc;

#[derive(Clone, Copy, Debug)]
pub struct Camera {
    pub origin: Vec3,
    forward: Vec3,
    right: Vec3,
    up: Vec3,
    tan_half: f32,
    pub width: u32,
    pub height: u32,
}

impl Camera {
    pub fn new(d: &CameraDesc) -> Self {
        let v = |a: [f64; 3]| Vec3::new(a[0] as f32, a[1] as f32, a[2] as f32);
        let origin = v(d.origin);
        let forward = (v(d.target) - origin).normalize();
        let right = forward.cross(v(d.up)).normalize();
        let up = right.cross(forward);
        Self {
            origin,
            forward,
            right,
            up,
            tan_half: (d.fov_deg.to_radians() as f32 * 0.5).tan(),
            width: d.width,
            height: d.height,
        }
    }

    pub fn forward(&self) -> Vec3 {
        self.forward
    }
    pub fn right(&self) -> Vec3 {
        self.right
    }
    pub fn up(&self) -> Vec3 {
        self.up
    }
    /// tan of half the horizontal field of view.
    pub fn tan_half(&self) -> f32 {
        self.tan_half
    }

    /// Direction through image position (x, y) in pixels (continuous; (0, 0) is the
    /// top-left corner).
    pub fn ray_dir(&self, x: f32, y: f32) -> Vec3 {
        let w = self.width as f32;
        let h = self.height as f32;
        let u = (2.0 * x / w - 1.0) * self.tan_half;
        let v = (1.0 - 2.0 * y / h) * self.tan_half * h / w;
        (self.forward + self.right * u + self.up * v).normalize()
    }
}
