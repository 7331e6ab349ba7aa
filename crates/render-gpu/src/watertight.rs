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
//!
//! The distance, though, is taken from the triangle's plane, not from Woop's barycentric
//! interpolation of the sheared depths: on a long thin triangle the weights u, v, w are
//! differences of nearly equal products, and (u·a.z + v·b.z + w·c.z)/det put hits up to
//! 5·10⁻⁶ of the scene's size off the plane (on a 1,000-segment cylinder, 1,000:1
//! triangles) — ten times the flight margin that keeps collisions inside, so paths
//! leaked through faces they had found. The sign test decides whether the ray meets the
//! triangle; n·(v − o)/(n·d), with the f64-derived unit normal and the vertex of largest
//! weight (the nearest to the hit, so the fewest roundings), says where.

use glam::{Vec3, Vec3Swizzles};

/// Per-ray constants of the shear that maps the ray onto the +z axis: the axis
/// permutation (kx, ky, kz), one of six, and the shear factors. Each vertex is permuted
/// with a swizzle chosen once per ray (a perfectly predicted branch), then sheared with
/// two multiplies: the textbook `a[kx] − Sx·a[kz]`, rounded the same way for every
/// triangle that shares the vertex.
#[derive(Clone, Copy, Debug)]
pub struct RayShear {
    origin: Vec3,
    dir: Vec3,
    perm: Perm,
    sx: f32,
    sy: f32,
    sz: f32,
}

/// (kx, ky, kz) as a swizzle.
#[derive(Clone, Copy, Debug)]
enum Perm {
    Yzx,
    Zyx,
    Zxy,
    Xzy,
    Xyz,
    Yxz,
}

impl Perm {
    #[inline(always)]
    fn apply(self, v: Vec3) -> Vec3 {
        match self {
            Perm::Yzx => v.yzx(),
            Perm::Zyx => v.zyx(),
            Perm::Zxy => v.zxy(),
            Perm::Xzy => v.xzy(),
            Perm::Xyz => v,
            Perm::Yxz => v.yxz(),
        }
    }
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
        // kx, ky follow kz cyclically; swapped when the ray points down its major axis
        // to keep the winding.
        let flip = dir[kz] < 0.0;
        let perm = match (kz, flip) {
            (0, false) => Perm::Yzx,
            (0, true) => Perm::Zyx,
            (1, false) => Perm::Zxy,
            (1, true) => Perm::Xzy,
            (_, false) => Perm::Xyz,
            (_, true) => Perm::Yxz,
        };
        let d = perm.apply(dir);
        Self {
            origin,
            dir,
            perm,
            sx: d.x / d.z,
            sy: d.y / d.z,
            sz: 1.0 / d.z,
        }
    }

    #[inline]
    fn shear(&self, v: Vec3) -> Vec3 {
        let p = self.perm.apply(v - self.origin);
        Vec3::new(p.x - self.sx * p.z, p.y - self.sy * p.z, self.sz * p.z)
    }

    /// Distance t ∈ [tmin, tmax] to the triangle (either side), or +∞; `n` is its unit
    /// normal (either orientation).
    #[inline]
    pub fn hit(&self, v0: Vec3, v1: Vec3, v2: Vec3, n: Vec3, tmin: f32, tmax: f32) -> f32 {
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
        // The hit is a convex combination of the vertices, so its sheared depth lies
        // between theirs: that bounds the plane's answer on rays that graze the plane,
        // where n·d is tiny. A degenerate normal (NaN) or n·d = 0 keeps Woop's t.
        let (au, av, aw) = (u.abs(), v.abs(), w.abs());
        let nearest = if au >= av && au >= aw {
            v0
        } else if av >= aw {
            v1
        } else {
            v2
        };
        let planar = n.dot(nearest - self.origin) / n.dot(self.dir);
        let t = if planar.is_finite() {
            // (max/min, not clamp: clamp panics on NaN bounds.)
            planar.max(a.z.min(b.z).min(c.z)).min(a.z.max(b.z).max(c.z))
        } else {
            (u * a.z + v * b.z + w * c.z) / det
        };
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
        let n = Vec3::Z;
        let r = RayShear::new(Vec3::ZERO, Vec3::Z);
        assert!((r.hit(a, b, c, n, 0.0, 10.0) - 2.0).abs() < 1e-6);
        // Either winding, either normal.
        assert!((r.hit(a, c, b, -n, 0.0, 10.0) - 2.0).abs() < 1e-6);
        assert_eq!(r.hit(a, b, c, n, 0.0, 1.0), f32::INFINITY, "beyond tmax");
        let off = RayShear::new(Vec3::new(3.0, 0.0, 0.0), Vec3::Z);
        assert_eq!(off.hit(a, b, c, n, 0.0, 10.0), f32::INFINITY);
        let back = RayShear::new(Vec3::ZERO, -Vec3::Z);
        assert_eq!(back.hit(a, b, c, n, 0.0, 10.0), f32::INFINITY, "behind");
        // Slanted: the distance to the plane, whichever vertex is nearest.
        let d = Vec3::new(0.3, -0.2, 1.0).normalize();
        let (b, c) = (b + Vec3::Z * 0.5, c - Vec3::Z * 0.25);
        let n = (b - a).cross(c - a).normalize();
        let t = RayShear::new(Vec3::ZERO, d).hit(a, b, c, n, 0.0, 10.0);
        assert!(n.dot(d * t - a).abs() < 1e-6, "{t}");
        // A degenerate normal falls back to Woop's distance.
        let t2 = RayShear::new(Vec3::ZERO, d).hit(a, b, c, Vec3::NAN, 0.0, 10.0);
        assert!((t - t2).abs() < 1e-5, "{t} {t2}");
    }
}
