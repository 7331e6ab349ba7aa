//! Watertight ray–triangle intersection (Woop, Benthin and Wald, "Watertight
//! Ray/Triangle Intersection", JCGT 2013), mirrored in `shaders/scene.wgsl`
//! (`tri_intersect`).
//!
//! Why not Möller–Trumbore: its barycentric test is evaluated per triangle in that
//! triangle's own arithmetic, so a ray through an edge shared by two triangles can miss
//! both. A path leaving the medium through such a crack keeps believing it is inside:
//! it then takes sphere steps in the air (the distance grid is unsigned) and sees the
//! light unoccluded at every event — the brightest fireflies of the renders before this
//! test was used. Here the edge functions are computed from the shared vertices after one
//! per-ray shear, so two triangles sharing an edge see exactly the same edge value and a
//! ray through the edge hits at least one of them.

use glam::Vec3;

/// Per-ray constants of the shear that maps the ray onto the +z axis, as three rows:
/// sheared(v) = (mx·(v − o), my·(v − o), mz·(v − o)). Each row has one or two non-zero
/// entries, so the dot products round exactly like the textbook a[kx] − Sx·a[kz], with no
/// indexing by a per-ray axis in the inner loop.
#[derive(Clone, Copy, Debug)]
pub struct RayShear {
    origin: Vec3,
    mx: Vec3,
    my: Vec3,
    mz: Vec3,
}

impl RayShear {
    pub fn new(origin: Vec3, dir: Vec3) -> Self {
        let a = dir.abs();
        let kz = if a.x >= a.y && a.x >= a.z {
            0
        } else if a.y >= a.z {
            1
        } else {
            2
        };
        let mut kx = (kz + 1) % 3;
        let mut ky = (kx + 1) % 3;
        // Keep the winding: swapping x and y when the ray points down its major axis.
        if dir[kz] < 0.0 {
            std::mem::swap(&mut kx, &mut ky);
        }
        let e = |k: usize| Vec3::AXES[k];
        Self {
            origin,
            mx: e(kx) - e(kz) * (dir[kx] / dir[kz]),
            my: e(ky) - e(kz) * (dir[ky] / dir[kz]),
            mz: e(kz) * (1.0 / dir[kz]),
        }
    }

    #[inline]
    fn shear(&self, v: Vec3) -> Vec3 {
        let p = v - self.origin;
        Vec3::new(self.mx.dot(p), self.my.dot(p), self.mz.dot(p))
    }

    /// Distance t ∈ [tmin, tmax] to the triangle (either side), or +∞.
    #[inline]
    pub fn hit(&self, v0: Vec3, v1: Vec3, v2: Vec3, tmin: f32, tmax: f32) -> f32 {
        let (a, b, c) = (self.shear(v0), self.shear(v1), self.shear(v2));
        let mut u = c.x * b.y - c.y * b.x;
        let mut v = a.x * c.y - a.y * c.x;
        let mut w = b.x * a.y - b.y * a.x;
        // Exactly on an edge in f32: decide in f64 so both triangles agree.
        if u == 0.0 || v == 0.0 || w == 0.0 {
            let f =
                |p: f32, q: f32, r: f32, s: f32| (p as f64 * q as f64 - r as f64 * s as f64) as f32;
            u = f(c.x, b.y, c.y, b.x);
            v = f(a.x, c.y, a.y, c.x);
            w = f(b.x, a.y, b.y, a.x);
        }
        if (u < 0.0 || v < 0.0 || w < 0.0) && (u > 0.0 || v > 0.0 || w > 0.0) {
            return f32::INFINITY;
        }
        let det = u + v + w;
        if det == 0.0 {
            return f32::INFINITY;
        }
        let t = (u * a.z + v * b.z + w * c.z) / det;
        if t >= tmin && t <= tmax {
            t
        } else {
            f32::INFINITY
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hits_the_centre_and_misses_outside() {
        let (a, b, c) = (
            Vec3::new(-1.0, -1.0, 2.0),
            Vec3::new(1.0, -1.0, 2.0),
            Vec3::new(0.0, 1.0, 2.0),
        );
        let r = RayShear::new(Vec3::ZERO, Vec3::Z);
        assert!((r.hit(a, b, c, 0.0, 10.0) - 2.0).abs() < 1e-6);
        // Either winding.
        assert!((r.hit(a, c, b, 0.0, 10.0) - 2.0).abs() < 1e-6);
        assert_eq!(r.hit(a, b, c, 0.0, 1.0), f32::INFINITY, "beyond tmax");
        let off = RayShear::new(Vec3::new(3.0, 0.0, 0.0), Vec3::Z);
        assert_eq!(off.hit(a, b, c, 0.0, 10.0), f32::INFINITY);
        let back = RayShear::new(Vec3::ZERO, -Vec3::Z);
        assert_eq!(back.hit(a, b, c, 0.0, 10.0), f32::INFINITY, "behind");
    }
}
