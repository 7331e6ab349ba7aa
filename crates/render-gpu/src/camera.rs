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
    /// How far along its direction every camera ray starts ([`Camera::start_before`];
    /// 0 until the object is known).
    pub start: f32,
}

impl Camera {
    pub fn new(d: &CameraDesc) -> Self {
        let v = |a: [f64; 3]| Vec3::new(a[0] as f32, a[1] as f32, a[2] as f32);
        let origin = v(d.origin);
        // Normalised in f64, as the scene check does (scene::unit_f32): in f32 tiny
        // components square to subnormals and the result is not of unit length.
        let unit = |w: Vec3| w.as_dvec3().normalize().as_vec3();
        let forward = unit(v(d.target) - origin);
        // `up` normalised first, as the scene check does (scene::camera_basis_f32): the
        // raw cross product of a valid but tiny up ([0, 1e-24, 1e-22]) squared to 0 in
        // f32 and every ray was NaN.
        let up_dir = glam::DVec3::from_array(d.up).normalize().as_vec3();
        let right = forward.cross(up_dir).normalize();
        let up = right.cross(forward);
        Self {
            origin,
            forward,
            right,
            up,
            // In f64: just under 180° the f32 angle rounds to π or past it, and the
            // tangent of its half turned negative (the image rotated by 180°).
            tan_half: (d.fov_deg.to_radians() * 0.5).tan() as f32,
            width: d.width,
            height: d.height,
            start: 0.0,
        }
    }

    /// Starts the camera rays just outside the sphere around the box `lo`..`hi` (the
    /// object's bounds), where nothing lies before them. From a camera far away (the scene
    /// allows ±10⁶) a hit computed as origin + t·dir carries the rounding of the large
    /// origin and t: from 10³ object sizes on it fell beyond the surface's offset, paths
    /// entered believing themselves outside or the reverse (1.5 million leaks in 1,872
    /// paths at 10⁵), and the image showed background crosses through the object. From the
    /// start the hit is as precise as from a near camera. The start itself carries the
    /// rounding of origin + start·dir, ~6·10⁻⁸ of the larger of the camera's and the
    /// object's distances from 0, and the directions of neighbouring pixels round alike:
    /// the image shifts by a fraction of a pixel up to ~10⁴ object sizes away and by
    /// pixels at 10⁶. The margin (1 % of the radius, and 10⁻⁶ of those distances, 16× the
    /// rounding) keeps the start outside the sphere.
    pub fn start_before(&mut self, lo: Vec3, hi: Vec3) {
        let (lo, hi, origin) = (lo.as_dvec3(), hi.as_dvec3(), self.origin.as_dvec3());
        let centre = 0.5 * (lo + hi);
        let radius = 0.5 * (hi - lo).length();
        let distance = (origin - centre).length();
        let scale = origin.length() + centre.length() + distance;
        let start = distance - 1.01 * radius - 1e-6 * scale;
        self.start = start.max(0.0) as f32;
    }

    /// Where the camera ray along `dir` starts.
    #[inline]
    pub fn ray_origin(&self, dir: Vec3) -> Vec3 {
        self.origin + dir * self.start
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

#[cfg(test)]
mod tests {
    use super::*;

    fn desc(up: [f64; 3], fov_deg: f64) -> CameraDesc {
        CameraDesc {
            origin: [0.0, 0.0, 4.0],
            target: [0.0, 0.0, 0.0],
            up,
            fov_deg,
            width: 8,
            height: 8,
        }
    }

    /// Scenes the check accepts give a camera whose top-left ray points up and left: an up
    /// vector valid but tiny (NaN rays before), and a field of view just under 180° (the
    /// image rotated by 180° before).
    #[test]
    fn accepted_extremes_keep_the_image_upright() {
        let shipped = concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../configs/scenes/sphere.toml"
        );
        let mut f = crate::scene::SceneFile::load(std::path::Path::new(shipped)).unwrap();
        for (up, fov) in [
            ([0.0, 1.0, 0.0], 40.0),
            ([0.0, 1e-24, 1e-22], 40.0),
            ([0.0, 1.0, 0.0], 179.999999),
        ] {
            let d = desc(up, fov);
            f.camera = d.clone();
            assert!(f.validate().is_ok(), "{up:?} {fov}: the check refuses it");
            let c = Camera::new(&d);
            let r = c.ray_dir(0.0, 0.0);
            assert!(r.is_finite(), "{up:?} {fov}: {r}");
            // The camera looks along −z with +y up and +x right: top-left is −x, +y.
            assert!(r.x < 0.0 && r.y > 0.0, "{up:?} {fov}: {r}");
        }
    }

    /// Pixels are square whatever the image's shape, the field of view horizontal
    /// (Mitsuba's `fov_axis = "x"`): through a 60° camera, the rays through the middles of
    /// the left and right edges are 30° off the axis, and those through the middles of the
    /// top and bottom edges atan(tan 30° · h/w) off it, in the wide image (200 × 100:
    /// 16.1°) and the tall one (100 × 200: 49.1°). The shipped scenes and the renders the
    /// other tests compare are square, where a height/width ratio turned over gives the
    /// same rays. 1e-4 rad: f32
    /// directions of unit length.
    #[test]
    fn pixels_are_square_in_any_image_shape() {
        for (width, height) in [(200, 100), (100, 200)] {
            let c = Camera::new(&CameraDesc {
                width,
                height,
                ..desc([0.0, 1.0, 0.0], 60.0)
            });
            let (w, h) = (width as f32, height as f32);
            let off_axis = |x: f32, y: f32| {
                (c.ray_dir(x, y).as_dvec3().dot(glam::DVec3::NEG_Z))
                    .clamp(-1.0, 1.0)
                    .acos()
            };
            let half_x = 30f64.to_radians();
            let half_y = (half_x.tan() * height as f64 / width as f64).atan();
            for (x, y, want) in [
                (0.0, h / 2.0, half_x),
                (w, h / 2.0, half_x),
                (w / 2.0, 0.0, half_y),
                (w / 2.0, h, half_y),
            ] {
                let got = off_axis(x, y);
                assert!(
                    (got - want).abs() < 1e-4,
                    "{width}×{height} at ({x}, {y}): {:.3}° off the axis, want {:.3}°",
                    got.to_degrees(),
                    want.to_degrees()
                );
            }
        }
    }

    /// Camera rays start just short of the sphere around the object's box (by 1 % of its
    /// radius and 10⁻⁶ of the distances), or at the camera itself (0) when the camera is
    /// within that sphere: a negative start put the rays' origins behind the camera, where
    /// they could begin inside the object or meet what lies behind it. From (0, 0, 4): the
    /// box ±5 (radius 5√3 ≈ 8.66 > 4) gives 0; the box ±1 gives
    /// 4 − 1.01·√3 − 10⁻⁶·(4 + 0 + 4) ≈ 2.2506 (f32: within 10⁻⁶).
    #[test]
    fn rays_start_at_the_camera_within_the_objects_sphere() {
        let mut c = Camera::new(&desc([0.0, 1.0, 0.0], 40.0));
        c.start_before(Vec3::splat(-5.0), Vec3::splat(5.0));
        assert_eq!(c.start, 0.0);
        let dir = c.ray_dir(4.0, 4.0);
        assert_eq!(c.ray_origin(dir), c.origin);
        c.start_before(Vec3::splat(-1.0), Vec3::splat(1.0));
        let want = 4.0 - 1.01 * 3f64.sqrt() - 8e-6;
        assert!(
            (f64::from(c.start) - want).abs() < 1e-6,
            "start {}, want {want}",
            c.start
        );
    }

    /// The start is measured from the object's centre, not from the scene's origin:
    /// setup::recentre moves a mesh to the origin only when its centre lies farther off,
    /// along some axis, than its largest side, so a box off the origin by up to its size
    /// reaches the camera as it is. From (0, 0, 4), the box [−0.5, 0.5]² × [2.5, 3.5]
    /// (centre (0, 0, 3), radius √3/2) gives 1 − 1.01·√3/2 − 10⁻⁶·(4 + 3 + 1) = 0.125306
    /// (f32: within 10⁻⁶), and the ray through the image's centre starts before the box's
    /// near face (z = 3.5). Measured from the origin instead (distance 4), the start would
    /// be 3.1253, beyond the whole box: the camera's rays would start behind the object.
    #[test]
    fn rays_start_before_an_object_off_the_origin() {
        let mut c = Camera::new(&desc([0.0, 1.0, 0.0], 40.0));
        c.start_before(Vec3::new(-0.5, -0.5, 2.5), Vec3::new(0.5, 0.5, 3.5));
        let want = 1.0 - 1.01 * 3f64.sqrt() / 2.0 - 8e-6;
        assert!(
            (f64::from(c.start) - want).abs() < 1e-6,
            "start {}, want {want}",
            c.start
        );
        let o = c.ray_origin(c.ray_dir(4.0, 4.0));
        assert!(
            o.z > 3.5,
            "the centre ray starts at {o}, not before the box"
        );
    }
}
