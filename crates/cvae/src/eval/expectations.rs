//! Expectations a renderer integrates, per walk: the NEE its representative event would
//! collect if the walk's sphere, or a flat surface touching it, were the object's boundary.

use glam::DVec3;

use crate::sampler::lambda;

/// Light directions of [`sphere_nee`]: a Fibonacci sphere (even, deterministic).
pub(super) const NEE_DIRECTIONS: usize = 48;

pub(super) fn fibonacci_direction(i: usize) -> DVec3 {
    fibonacci(i, NEE_DIRECTIONS)
}

/// Point i of a Fibonacci sphere of `count` points.
fn fibonacci(i: usize, count: usize) -> DVec3 {
    let z = 1.0 - (2.0 * i as f64 + 1.0) / count as f64;
    let r = (1.0 - z * z).max(0.0).sqrt();
    let phi = i as f64 * std::f64::consts::PI * (3.0 - 5f64.sqrt());
    DVec3::new(r * phi.cos(), r * phi.sin(), z)
}

/// The NEE of a walk's representative event (X, W) if the walk's sphere were the medium
/// and lights came from every direction alike: Λ(N) · mean_L ρ_g(W·L) e^{−τ·s(X, L)}, s
/// the distance from X to the unit sphere along L. It weighs the events near the sphere's
/// boundary — those whose shadow rays get out — the way a renderer does.
pub fn sphere_nee(tau: f64, g: f64, albedo: f64, n: u64, x: DVec3, w: DVec3) -> f64 {
    let x2 = x.length_squared();
    let mut sum = 0.0;
    for i in 0..NEE_DIRECTIONS {
        let l = fibonacci_direction(i);
        let xl = x.dot(l);
        let s = -xl + (xl * xl + 1.0 - x2).max(0.0).sqrt();
        sum += scatter_sim::phase::hg_pdf(g, w.dot(l).clamp(-1.0, 1.0)) * (-tau * s).exp();
    }
    lambda(albedo, n) * sum / NEE_DIRECTIONS as f64
}

/// Where [`half_space_nee`]'s surface lies seen from the walk's centre, against the
/// direction the walk arrived in (+z): behind it (normal n_z < −0.5, the side a path
/// that just entered the object came through), beside it, or ahead (n_z > 0.5).
pub const SURFACE_SIDES: [&str; 3] = ["behind", "beside", "ahead"];
/// Per side, the m_z of its normals: the mid-points of two equal-area bands (area is
/// uniform in m_z), each with [`PLANE_AZIMUTHS`] azimuths. The renderer turns every walk
/// about its arrival direction by a random ψ, so each side is averaged over stratified
/// azimuths rather than a few fixed normals (with fixed ones, turning an event about z
/// moved a side's value by up to 3.5×).
pub(super) const PLANE_BANDS: [[f64; 2]; 3] = [[-0.875, -0.625], [-0.25, 0.25], [0.625, 0.875]];
pub(super) const PLANE_AZIMUTHS: usize = 8;
/// Light directions about each normal: the Fibonacci points of a sphere of this many with
/// cos > [`MIN_LIGHT_COS`] to the normal (the same set for every normal).
const PLANE_LIGHT_POINTS: usize = 64;
pub(super) const MIN_LIGHT_COS: f64 = 0.2;

/// A plane's outward normal m and its lights: (L, L·m), in the walk's canonical frame.
pub(super) type PlaneLights = (DVec3, Vec<(DVec3, f64)>);

/// Per side, the normals and, per normal, the lights.
pub(super) fn plane_geometry() -> &'static [Vec<PlaneLights>; 3] {
    static GEOMETRY: std::sync::OnceLock<[Vec<PlaneLights>; 3]> = std::sync::OnceLock::new();
    GEOMETRY.get_or_init(|| {
        let local: Vec<DVec3> = (0..PLANE_LIGHT_POINTS)
            .map(|i| fibonacci(i, PLANE_LIGHT_POINTS))
            .filter(|l| l.z > MIN_LIGHT_COS)
            .collect();
        PLANE_BANDS.map(|zs| {
            let mut normals = Vec::new();
            for (b, &mz) in zs.iter().enumerate() {
                let r = (1.0 - mz * mz).sqrt();
                for k in 0..PLANE_AZIMUTHS {
                    // Half a step apart between the two bands of a side.
                    let phi =
                        std::f64::consts::TAU * (k as f64 + 0.5 * b as f64) / PLANE_AZIMUTHS as f64;
                    let m = DVec3::new(r * phi.cos(), r * phi.sin(), mz);
                    let (t1, t2) = m.any_orthonormal_pair();
                    let lights = local
                        .iter()
                        .map(|l| (t1 * l.x + t2 * l.y + m * l.z, l.z))
                        .collect();
                    normals.push((m, lights));
                }
            }
            normals
        })
    })
}

/// The NEE of a walk's representative event (X, W) in a renderer's situation: the
/// sphere step's ball is as large as the distance to the nearest surface, so it touches
/// it; here the surface is the plane x·m = 1 tangent to the unit sphere, with the light
/// beyond it. Λ(N) · mean ρ_g(W·L) e^{−τ·s}, s = (1 − X·m)/(L·m) the distance from X to
/// the plane along L, over the normals m of one side ([`SURFACE_SIDES`]: m_z in two
/// equal-area bands, 8 azimuths each) and, for each, the same ~25 light directions L
/// with L·m > 0.2. Unlike [`sphere_nee`] it tells the sides apart: a model can be right
/// on average and wrong behind, which is where the NEE of a path just entered through a
/// lit surface comes from (docs/BENCHMARKS.md, thirteenth session).
pub fn half_space_nee(tau: f64, g: f64, albedo: f64, n: u64, x: DVec3, w: DVec3) -> [f64; 3] {
    let weight = lambda(albedo, n);
    plane_geometry().each_ref().map(|normals| {
        let (mut sum, mut count) = (0.0f64, 0usize);
        for (m, lights) in normals {
            let depth = (1.0 - x.dot(*m)).max(0.0);
            for &(l, lm) in lights {
                count += 1;
                let optical = tau * depth / lm;
                if optical < 40.0 {
                    sum +=
                        scatter_sim::phase::hg_pdf(g, w.dot(l).clamp(-1.0, 1.0)) * (-optical).exp();
                }
            }
        }
        weight * sum / count.max(1) as f64
    })
}
