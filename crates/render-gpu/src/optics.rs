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

#[cfg(test)]
mod tests {
    use super::{fresnel, reflect, refract};
    use glam::Vec3;

    /// Fresnel's equations in their angle form, R_s = sin²(θi − θt)/sin²(θi + θt) and
    /// R_p = tan²(θi − θt)/tan²(θi + θt), in f64: an independent route to the reflectance
    /// that `fresnel` computes from cosines and indices.
    fn fresnel_by_angles(theta_i: f64, n_i: f64, n_t: f64) -> f64 {
        let theta_t = (n_i / n_t * theta_i.sin()).asin();
        let (d, s) = (theta_i - theta_t, theta_i + theta_t);
        let rs = (d.sin() / s.sin()).powi(2);
        let rp = (d.tan() / s.tan()).powi(2);
        0.5 * (rs + rp)
    }

    /// Textbook values for glass (n = 1.5): 4 % at normal incidence, 5.0 % at 45°, and at
    /// Brewster's angle (atan 1.5) only the s-polarised half, R = R_s/2 = 0.0740; the angle
    /// form over 1°–89° both ways, below the critical angle from inside. f32 arithmetic
    /// near 1 − cos² loses ~1e-6 relative; 1e-5 absolute leaves room and would still catch
    /// a swapped index or a sign (errors of 1e-3 and more at every angle tried).
    #[test]
    fn fresnel_matches_its_angle_form_and_textbook_values() {
        assert!((fresnel(1.0, 1.0, 1.5) - 0.04).abs() < 1e-6);
        assert!((fresnel(1.0, 1.5, 1.0) - 0.04).abs() < 1e-6);
        assert!((fresnel(std::f32::consts::FRAC_1_SQRT_2, 1.0, 1.5) - 0.050_24).abs() < 1e-5);
        let brewster = 1.5f64.atan();
        let theta_t = std::f64::consts::FRAC_PI_2 - brewster;
        let rs_brewster = (brewster - theta_t).sin().powi(2);
        assert!((rs_brewster - 0.1479).abs() < 1e-4);
        let r = fresnel(brewster.cos() as f32, 1.0, 1.5) as f64;
        assert!((r - rs_brewster / 2.0).abs() < 1e-5, "{r}");
        let critical = (1.0f64 / 1.5).asin();
        for deg in 1..90 {
            let theta = (deg as f64).to_radians();
            let outside = fresnel(theta.cos() as f32, 1.0, 1.5) as f64;
            let expected = fresnel_by_angles(theta, 1.0, 1.5);
            assert!(
                (outside - expected).abs() < 1e-5,
                "{deg}°: {outside} vs {expected}"
            );
            if theta < critical - 1e-3 {
                let inside = fresnel(theta.cos() as f32, 1.5, 1.0) as f64;
                let expected = fresnel_by_angles(theta, 1.5, 1.0);
                assert!((inside - expected).abs() < 1e-5, "{deg}° inside");
            }
        }
    }

    /// Light going the other way along the same ray sees the same reflectance (Stokes'
    /// reciprocity), and beyond the critical angle asin(1/1.5) = 41.8° from the denser side
    /// all of it is reflected, where `refract` finds no transmitted ray.
    #[test]
    fn fresnel_is_reciprocal_and_total_beyond_the_critical_angle() {
        for deg in 0..90 {
            let theta = (deg as f64).to_radians();
            let theta_t = (theta.sin() / 1.5).asin();
            let there = fresnel(theta.cos() as f32, 1.0, 1.5);
            let back = fresnel(theta_t.cos() as f32, 1.5, 1.0);
            assert!((there - back).abs() < 1e-5, "{deg}°: {there} vs {back}");
        }
        let n = Vec3::Z;
        for deg in [42.0f32, 50.0, 70.0, 89.0] {
            let t = deg.to_radians();
            assert_eq!(fresnel(t.cos(), 1.5, 1.0), 1.0, "{deg}°");
            let d = Vec3::new(t.sin(), 0.0, -t.cos());
            assert!(refract(d, n, 1.5, 1.0).is_none(), "{deg}°");
        }
        let t = 41.0f32.to_radians();
        assert!(fresnel(t.cos(), 1.5, 1.0) < 1.0);
        assert!(refract(Vec3::new(t.sin(), 0.0, -t.cos()), n, 1.5, 1.0).is_some());
    }

    /// The refracted ray obeys Snell's law (n_i sin θi = n_t sin θt), stays in the plane of
    /// incidence on the far side of the surface, and the normal may be given from either
    /// side; the reflected ray mirrors the incident one.
    #[test]
    fn refraction_obeys_snell_and_reflection_mirrors() {
        let mut rng = scatter_sim::rng::WalkRng::from_seed(3);
        for _ in 0..1000 {
            let n = Vec3::new(
                rng.uniform() as f32 - 0.5,
                rng.uniform() as f32 - 0.5,
                rng.uniform() as f32 - 0.5,
            )
            .normalize();
            let d = Vec3::new(
                rng.uniform() as f32 - 0.5,
                rng.uniform() as f32 - 0.5,
                rng.uniform() as f32 - 0.5,
            )
            .normalize();
            let (n_i, n_t) = (1.0 + rng.uniform() as f32, 1.0 + rng.uniform() as f32);
            let sin_i = d.cross(n).length();
            let flipped = refract(d, -n, n_i, n_t);
            let Some(t) = refract(d, n, n_i, n_t) else {
                assert!(
                    n_i * sin_i > n_t * (1.0 - 1e-4),
                    "no ray below the critical angle"
                );
                assert!(flipped.is_none());
                continue;
            };
            let sin_t = t.cross(n).length();
            assert!(
                (n_i * sin_i - n_t * sin_t).abs() < 1e-4,
                "Snell: {sin_i} → {sin_t}"
            );
            assert!(d.dot(n) * t.dot(n) > 0.0, "the ray crosses the surface");
            assert!(t.dot(d.cross(n)).abs() < 1e-4, "in the plane of incidence");
            assert!((flipped.unwrap() - t).length() < 1e-6);
            let r = reflect(d, n);
            assert!((r.dot(n) + d.dot(n)).abs() < 1e-6);
            assert!((r - d).cross(n).length() < 1e-6);
        }
    }
}
