//! Smooth dielectric boundary: Fresnel reflectance and Snell refraction.

use glam::Vec3;

/// Unpolarised Fresnel reflectance for light arriving with |cos| = `cos_i` on the side of
/// index `n_i`, going into index `n_t`. Returns 1 under total internal reflection.
pub fn fresnel(cos_i: f32, n_i: f32, n_t: f32) -> f32 {
    let cos_i = cos_i.clamp(0.0, 1.0);
    let eta = n_i / n_t;
    let sin2_t = eta * eta * (1.0 - cos_i * cos_i);
    if sin2_t >= 1.0 {
        return 1.0;
    }
    let cos_t = (1.0 - sin2_t).sqrt();
    let rs = (n_i * cos_i - n_t * cos_t) / (n_i * cos_i + n_t * cos_t);
    let rp = (n_t * cos_i - n_i * cos_t) / (n_t * cos_i + n_i * cos_t);
    0.5 * (rs * rs + rp * rp)
}

/// Mirror reflection of `d` about the plane with normal `n`.
pub fn reflect(d: Vec3, n: Vec3) -> Vec3 {
    d - n * (2.0 * d.dot(n))
}

/// Refraction of unit `d` through the surface with unit normal `n` (either side),
/// from index `n_i` into `n_t`; None under total internal reflection.
pub fn refract(d: Vec3, n: Vec3, n_i: f32, n_t: f32) -> Option<Vec3> {
    let n = if d.dot(n) > 0.0 { -n } else { n };
    let cos_i = -d.dot(n);
    let eta = n_i / n_t;
    let sin2_t = eta * eta * (1.0 - cos_i * cos_i);
    if sin2_t >= 1.0 {
        return None;
    }
    let cos_t = (1.0 - sin2_t).sqrt();
    Some((d * eta + n * (eta * cos_i - cos_t)).normalize())
}
