//! Directional lights (delta or sun disk) and the environment.

use std::f32::consts::PI;
use std::path::Path;

use glam::Vec3;

use crate::error::RenderError;
use crate::image_io::{MAX_ENV_PIXELS, RgbImage, read_exr_at_most};
use crate::scene::{EnvironmentDesc, LightDesc};

/// The share of NEE's directions drawn from the phase function where its lobe is
/// narrower than a sun disk ([`DirectionalLight::phase_share`]).
pub const PHASE_SHARE: f32 = 0.5;

#[derive(Clone, Copy, Debug)]
pub struct DirectionalLight {
    /// Unit vector pointing toward the light (minus the travel direction).
    pub to_light: Vec3,
    pub irradiance: [f32; 3],
    /// 1 − cos θ_max of the disk's angular radius θ_max (0 for a delta light), computed
    /// as 2 sin²(θ_max/2): for the sun's 0.27°, 1 − cos in f32 is off by up to 0.6 %
    /// (cos θ_max = 0.99998930 has 7 digits), and with it NEE's solid angle and the seen
    /// disk's size, which made the disk 0.25 % too dim through NEE and 0.27 % too bright
    /// seen directly (`a_sun_disk_gives_its_irradiance`).
    pub one_minus_cos: f32,
    /// sin²θ_max: the disk's edge for `radiance_toward`, tested on |dir × to_light|², which
    /// keeps its precision at small angles where the dot product rounds to 1.
    pub sin2_max: f32,
    /// Radiance of the disk, E / (π sin²θ_max); 0 for a delta light.
    pub radiance: [f32; 3],
    /// θ_max in radians (0 for a delta light), for [`Self::extreme_cos`]'s per-event bound.
    pub half_angle: f32,
}

/// sin² of a sun disk's half-angle, or None for a delta light. Below a micro-radian
/// (0.2″) the disk is a delta light: its radiance E/(π sin²θ) would overflow f32 (a
/// 1e-18° disk rendered NaN), and no image could tell.
pub fn disk_sin2(d: &LightDesc) -> Option<f64> {
    let half = (d.angular_diameter_deg * 0.5).to_radians();
    (half >= 1e-6).then(|| half.sin().powi(2))
}

/// A sun disk's radiance from its irradiance on a plane facing it:
/// E = ∫ L cos θ dω = L π sin²θ_max.
pub fn disk_radiance(irradiance: f64, sin2: f64) -> f64 {
    irradiance / (std::f64::consts::PI * sin2)
}

impl DirectionalLight {
    pub fn new(d: &LightDesc) -> Self {
        // In f64 (scene::unit_f32, which checked it): in f32 tiny components square to
        // subnormals and the result is not of unit length.
        let dir = glam::DVec3::from_array(d.direction).normalize().as_vec3();
        let half = (d.angular_diameter_deg * 0.5).to_radians();
        let irradiance = d.irradiance.map(|v| v as f32);
        let (one_minus_cos, sin2_max, radiance) = if let Some(s2) = disk_sin2(d) {
            (
                (2.0 * (half / 2.0).sin().powi(2)) as f32,
                s2 as f32,
                d.irradiance.map(|e| disk_radiance(e, s2) as f32),
            )
        } else {
            (0.0, 0.0, [0.0; 3])
        };
        Self {
            to_light: -dir,
            irradiance,
            one_minus_cos,
            sin2_max,
            radiance,
            half_angle: if one_minus_cos > 0.0 {
                half as f32
            } else {
                0.0
            },
        }
    }

    pub fn is_delta(&self) -> bool {
        self.one_minus_cos <= 0.0
    }

    /// A direction toward the light and the factor that multiplies phase × transmittance
    /// in the NEE estimate: E for a delta light, L / pdf for a disk sampled uniformly in
    /// solid angle.
    pub fn sample(&self, u1: f32, u2: f32, channel: usize) -> (Vec3, f32) {
        if self.is_delta() {
            return (self.to_light, self.irradiance[channel]);
        }
        // 1 − cos θ uniform in [0, 1 − cos θ_max]; sin from it as √(v(2 − v)), exact
        // at small angles where 1 − cos² cancels.
        let v = u1 * self.one_minus_cos;
        let cos = 1.0 - v;
        let sin = (v * (2.0 - v)).max(0.0).sqrt();
        let phi = 2.0 * PI * u2;
        let (t, b) = basis(self.to_light);
        let dir = (t * (sin * phi.cos()) + b * (sin * phi.sin()) + self.to_light * cos).normalize();
        let solid_angle = 2.0 * PI * self.one_minus_cos;
        (dir, self.radiance[channel] * solid_angle)
    }

    /// Solid angle of the disk (0 for a delta light).
    pub fn solid_angle(&self) -> f32 {
        2.0 * PI * self.one_minus_cos
    }

    /// The share of NEE's directions toward this light drawn from the phase function
    /// around the scattering direction instead of uniformly in the disk (one-sample
    /// mixture; the estimate divides by the mixture's density, so it stays unbiased).
    /// Where the phase lobe (~π(1 − |g|)² sr) is narrower than the disk, the disk's
    /// uniform samples find it rarely and with huge weights (a physics review: renders of
    /// 16,384 spp 5–18 % off at |g| = 0.999 under a 30° disk); phase samples then carry
    /// it. Elsewhere 0, so the common scenes (the sun under |g| ≤ 0.99) draw exactly
    /// what they did.
    pub fn phase_share(&self, g: f32) -> f32 {
        let lobe = PI * (1.0 - g.abs()).powi(2);
        if self.solid_angle() > lobe {
            PHASE_SHARE
        } else {
            0.0
        }
    }

    /// NEE's direction toward this light from an event scattering along `w` in a medium
    /// of phase function `g`, and its factor (see [`Self::sample`]): [`Self::sample`]'s
    /// where [`Self::phase_share`] is 0; else the mixture, whose third uniform `u0` picks
    /// the strategy, and either direction is weighed by L over the mixture's density.
    pub fn sample_from(
        &self,
        w: Vec3,
        g: f32,
        (u1, u2): (f32, f32),
        u0: impl FnOnce() -> f32,
        channel: usize,
    ) -> (Vec3, f32) {
        let share = self.phase_share(g);
        if share <= 0.0 {
            return self.sample(u1, u2, channel);
        }
        let dir = if u0() < share {
            // In f64: a lobe of 10⁻³ rad has 1 − cos² ~ 10⁻⁶, which f32 holds to ~10 %.
            let cos = scatter_sim::phase::hg_sample_cos(g as f64, u1 as f64);
            let phi = std::f64::consts::TAU * u2 as f64;
            scatter_sim::phase::deflect(w.as_dvec3(), cos, (phi.cos(), phi.sin()))
                .as_vec3()
                .normalize()
        } else {
            self.sample(u1, u2, channel).0
        };
        let phase =
            scatter_sim::phase::hg_pdf_between(g as f64, w.as_dvec3(), dir.as_dvec3()) as f32;
        let density = share * phase + (1.0 - share) / self.solid_angle();
        (dir, self.radiance_toward(dir, channel) / density)
    }

    /// The cosine, with the direction `w`, of the disk's direction that maximises the HG
    /// phase function of `g` (the nearest to `w` for g ≥ 0, the farthest for g < 0): the
    /// phase function's largest value over the disk, for a proxy that bounds NEE's
    /// estimate over the whole disk.
    pub fn extreme_cos(&self, w: Vec3, g: f32) -> f32 {
        let centre = w.dot(self.to_light).clamp(-1.0, 1.0).acos();
        let angle = if g >= 0.0 {
            (centre - self.half_angle).max(0.0)
        } else {
            (centre + self.half_angle).min(PI)
        };
        angle.cos()
    }

    /// Radiance seen along `dir` (the disk; a delta light cannot be seen).
    pub fn radiance_toward(&self, dir: Vec3, channel: usize) -> f32 {
        // θ ≤ θ_max ≤ 45° (the diameter is at most 90°): in front, and sin²θ ≤ sin²θ_max.
        if !self.is_delta()
            && dir.dot(self.to_light) > 0.0
            && dir.cross(self.to_light).length_squared() <= self.sin2_max
        {
            self.radiance[channel]
        } else {
            0.0
        }
    }
}

/// An orthonormal pair perpendicular to unit `n` (Duff et al. 2017).
pub fn basis(n: Vec3) -> (Vec3, Vec3) {
    let s = 1f32.copysign(n.z);
    let a = -1.0 / (s + n.z);
    let b = n.x * n.y * a;
    (
        Vec3::new(1.0 + s * n.x * n.x * a, s * b, -s * n.x),
        Vec3::new(b, s + n.y * n.y * a, -n.y),
    )
}

/// Constant radiance, optionally times a lat-long map (y up; u = atan2(x, −z)/2π mod 1,
/// v = acos(y)/π, row 0 at the top): Mitsuba 3's `envmap` convention, with −z at the left
/// edge and +x a quarter across, so that a map lights a scene as it does there (nearest
/// texel, where Mitsuba interpolates).
pub struct Environment {
    pub radiance: [f32; 3],
    pub map: Option<RgbImage>,
}

/// Every pixel of an environment map must be a radiance the renderers can sum: finite,
/// non-negative and within the scene file's radiance bound.
fn check_radiance_map(m: &RgbImage) -> Result<(), String> {
    let max = crate::scene::MAX_RADIANCE as f32;
    if let Some((x, y, v)) = m.first_value(|v| !(v >= 0.0 && v <= max)) {
        return Err(format!(
            "environment pixel ({x}, {y}) = {} is out of range: allowed [0, {max:e}]",
            scatter_sim::ranges::num(v)
        ));
    }
    if m.width == 0 || m.height == 0 {
        return Err("the environment map is empty".into());
    }
    Ok(())
}

impl Environment {
    pub fn new(d: &EnvironmentDesc, scene_dir: &Path) -> Result<Self, RenderError> {
        let map = match &d.file {
            Some(f) => {
                let path = scene_dir.join(f);
                let map = read_exr_at_most(&path, MAX_ENV_PIXELS)?.0;
                check_radiance_map(&map)
                    .map_err(|e| RenderError::Image(format!("{}: {e}", path.display())))?;
                Some(map)
            }
            None => None,
        };
        let radiance = d.radiance_or_default().map(|v| v as f32);
        // The radiance seen is the scale times the pixel, each within the bound alone; a
        // product beyond it (1e12 × 1e12) overflowed f32 in `--variance`'s squared sums.
        if let (Some(m), Some(f)) = (&map, &d.file) {
            for (k, &r) in radiance.iter().enumerate() {
                let top = m.pixels.iter().map(|p| p[k]).fold(0.0f32, f32::max);
                let seen = r as f64 * top as f64;
                if seen > crate::scene::MAX_RADIANCE {
                    return Err(RenderError::Image(format!(
                        "{}: environment.radiance[{k}] = {} times the map's largest value \
                         {} there is {seen:.4e}, beyond the radiance bound: the product must be at \
                         most {:e}",
                        scene_dir.join(f).display(),
                        scatter_sim::ranges::num(r),
                        scatter_sim::ranges::num(top),
                        crate::scene::MAX_RADIANCE
                    )));
                }
            }
        }
        Ok(Self { radiance, map })
    }

    pub fn is_black(&self) -> bool {
        self.radiance == [0.0; 3]
    }

    pub fn lookup(&self, dir: Vec3, channel: usize) -> f32 {
        let base = self.radiance[channel];
        match &self.map {
            None => base,
            Some(m) => {
                let a = dir.x.atan2(-dir.z) / (2.0 * PI);
                let u = a - a.floor();
                let v = dir.y.clamp(-1.0, 1.0).acos() / PI;
                let x = ((u * m.width as f32) as usize).min(m.width - 1);
                let y = ((v * m.height as f32) as usize).min(m.height - 1);
                base * m.pixels[y * m.width + x][channel]
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The map's azimuth is Mitsuba 3's (envmap.cpp: u = atan2(x, −z)/2π, wrapped): −z
    /// reads column 0, +x a quarter across, +z the middle, −x three quarters (so a mirrored
    /// or half-turned map fails), and up/down the top/bottom rows.
    #[test]
    fn map_directions_follow_mitsuba() {
        let mut m = RgbImage::new(16, 8);
        for (col, v) in [(0, 1.0), (4, 2.0), (8, 3.0), (12, 4.0)] {
            for row in 2..6 {
                m.pixels[row * 16 + col] = [v; 3];
            }
        }
        for col in 0..16 {
            m.pixels[col] = [5.0; 3];
            m.pixels[7 * 16 + col] = [6.0; 3];
        }
        let env = Environment {
            radiance: [1.0; 3],
            map: Some(m),
        };
        // Just inside each column, on the horizon (rows 2..6).
        let at = |x: f32, z: f32| env.lookup(Vec3::new(x, 0.0, z).normalize(), 0);
        assert_eq!(at(0.01, -1.0), 1.0, "−z: column 0");
        assert_eq!(at(1.0, 0.01), 2.0, "+x: column 4");
        assert_eq!(at(-0.01, 1.0), 3.0, "+z: column 8");
        assert_eq!(at(-1.0, -0.01), 4.0, "−x: column 12");
        // The seam: just left of −z wraps to the last column.
        assert_eq!(at(-0.01, -1.0), 0.0, "−z from the other side: column 15");
        assert_eq!(env.lookup(Vec3::new(0.01, 1.0, -0.01).normalize(), 0), 5.0);
        assert_eq!(env.lookup(Vec3::new(0.01, -1.0, -0.01).normalize(), 0), 6.0);
    }

    /// A disk of `diameter` degrees from above and to one side, unequal in its channels.
    fn light(diameter: f64) -> DirectionalLight {
        DirectionalLight::new(&LightDesc {
            kind: crate::scene::LightKind::Directional,
            direction: [0.3, -1.0, -0.2],
            irradiance: [2.0, 1.0, 0.5],
            angular_diameter_deg: diameter,
        })
    }

    /// NEE's mixture (`sample_from`) estimates ∫_disk L ρ_g(w·ω) dω without bias, with
    /// bounded weights where the phase lobe is narrower than the disk. Concentric cases
    /// have closed forms through HG's cosine CDF: w = ω_c (the disk's centre) gives
    /// L·(1 − F(cos θ_max)) and w = −ω_c gives L·F(−cos θ_max), for g = ±0.999 and 0.99
    /// under a 30° disk (the lobe on the disk or away from it; a g < 0 lobe points
    /// against w). An off-centre case (g 0.9, 60° disk, w 20° off the centre) is
    /// compared with the disk's uniform draws, whose weights are moderate there. 10⁶ draws
    /// each; |z| < 4.5 over the 7 comparisons (a false alarm ~1e-4). Where the lobe is on
    /// the disk, the mixture's weights are at most 2L (relative sd < 2); the uniform draws'
    /// relative sd is of order √(Ω·ρ_peak) ~ 10² at g = 0.999, which is what made such renders
    /// converge so slowly. Where the disk is narrower than the lobe (the sun at g = 0.9)
    /// the draws are `sample`'s, bit for bit.
    #[test]
    fn nee_mixture_is_unbiased_and_tames_narrow_lobes() {
        use scatter_sim::phase::{hg_cos_cdf, hg_pdf_between};
        let mut rng = scatter_sim::WalkRng::from_seed(17);
        let mut u = move || crate::integrator::uniform(&mut rng);
        // Mean, standard error and relative sd of the NEE estimate factor · ρ_g.
        let mut estimate = |l: &DirectionalLight, w: Vec3, g: f32, mixture: bool| {
            let n = 1_000_000;
            let (mut s, mut s2) = (0f64, 0f64);
            for _ in 0..n {
                let (u1, u2) = (u(), u());
                let (dir, factor) = if mixture {
                    l.sample_from(w, g, (u1, u2), &mut u, 0)
                } else {
                    l.sample(u1, u2, 0)
                };
                // The phase value as NEE takes it (integrator/nee.rs, light_sample).
                let f = factor as f64 * hg_pdf_between(g as f64, w.as_dvec3(), dir.as_dvec3());
                s += f;
                s2 += f * f;
            }
            let mean = s / n as f64;
            let var = (s2 / n as f64 - mean * mean).max(0.0);
            (mean, (var / n as f64).sqrt(), var.sqrt() / mean)
        };
        let disk = light(30.0);
        let cos_max = (15.0f64).to_radians().cos();
        let radiance = disk.radiance[0] as f64;
        for g in [0.999f32, -0.999, 0.99] {
            assert_eq!(disk.phase_share(g), 0.5);
            // The lobe on the disk: along w for g > 0, against it for g < 0.
            let toward = if g > 0.0 {
                disk.to_light
            } else {
                -disk.to_light
            };
            for (w, expect) in [
                (
                    disk.to_light,
                    radiance * (1.0 - hg_cos_cdf(g as f64, cos_max)),
                ),
                (-disk.to_light, radiance * hg_cos_cdf(g as f64, -cos_max)),
            ] {
                let (mean, se, rel) = estimate(&disk, w, g, true);
                let z = (mean - expect) / se;
                assert!(
                    z.abs() < 4.5,
                    "g {g}, w {w}: {mean} ± {se} against {expect}"
                );
                if w == toward {
                    assert!(rel < 2.0, "g {g}: relative sd {rel}");
                }
            }
        }
        let (_, _, rel) = estimate(&disk, disk.to_light, 0.999, false);
        assert!(rel > 20.0, "the disk's uniform draws: relative sd {rel}");
        // Off the centre, against the uniform draws.
        let wide = light(60.0);
        let (t, _) = basis(wide.to_light);
        let off =
            (wide.to_light * 20f32.to_radians().cos() + t * 20f32.to_radians().sin()).normalize();
        let (a, sa, _) = estimate(&wide, off, 0.9, true);
        let (b, sb, _) = estimate(&wide, off, 0.9, false);
        let z = (a - b) / (sa * sa + sb * sb).sqrt();
        assert!(z.abs() < 4.5, "mixture {a} ± {sa}, uniform {b} ± {sb}");
        // The sun under g = 0.9: no mixture, the same draw as `sample`.
        let sun = light(0.53);
        assert_eq!(sun.phase_share(0.9), 0.0);
        let w = Vec3::new(0.0, 1.0, 0.0);
        assert_eq!(
            sun.sample_from(w, 0.9, (0.3, 0.7), || unreachable!(), 1),
            sun.sample(0.3, 0.7, 1)
        );
    }

    /// `phase_share` switches the mixture on exactly where the lobe's π(1 − |g|)² sr is
    /// below the disk's solid angle (cases on both sides of it, which a lobe of π(1 − |g|)
    /// would put on the other side for the 80° disk at g = 0.5 and the sun at 0.999), and
    /// `extreme_cos` gives the phase function's largest value over the disk, the path
    /// proxy's bound: for 300 random w per case, at least the largest over 2,000 of the
    /// disk's own draws, and at most the largest over 3,600 points of its edge (or HG's
    /// peak where w's lobe direction lies in the disk), for g of both signs. Tolerance
    /// 2e-3: f32's acos and cos err by ~1e-6 rad where HG at g = ±0.95 is steepest (29
    /// per radian), ~3e-5 of the density; the edge's 0.1° spacing leaves its maximum below
    /// the true one, on the safe side of the upper check, by at most the same order.
    #[test]
    fn the_phase_share_and_the_extreme_cosine_follow_the_lobe() {
        use scatter_sim::phase::{hg_pdf, hg_pdf_between};
        // (diameter, g, share): the 80° disk holds 1.47 sr, the 40° one 0.38, the sun
        // 6.7e-5; lobes 0.785 (g 0.5), 0.283 (0.7), 3.1e-6 (0.999), 3.1e-4 (0.99).
        for (diameter, g, share) in [
            (80.0, 0.5, PHASE_SHARE),
            (40.0, 0.5, 0.0),
            (40.0, -0.7, PHASE_SHARE),
            (0.53, 0.999, PHASE_SHARE),
            (0.53, -0.99, 0.0),
        ] {
            assert_eq!(light(diameter).phase_share(g), share, "{diameter}°, g {g}");
        }
        let mut rng = scatter_sim::WalkRng::from_seed(29);
        let mut u = move || crate::integrator::uniform(&mut rng);
        for diameter in [80.0, 40.0] {
            let l = light(diameter);
            for g in [0.5f32, -0.6, 0.95, -0.95] {
                for _ in 0..300 {
                    let z = 2.0 * u() - 1.0;
                    let phi = std::f32::consts::TAU * u();
                    let r = (1.0 - z * z).max(0.0).sqrt();
                    let w = Vec3::new(r * phi.cos(), r * phi.sin(), z);
                    let bound = hg_pdf(g as f64, l.extreme_cos(w, g) as f64);
                    let most = (0..2000)
                        .map(|_| {
                            let (dir, _) = l.sample(u(), u(), 0);
                            hg_pdf_between(g as f64, w.as_dvec3(), dir.as_dvec3())
                        })
                        .fold(0.0, f64::max);
                    assert!(
                        bound >= (1.0 - 2e-3) * most,
                        "{diameter}° disk, g {g}, w {w}: bound {bound}, a draw {most}"
                    );
                    // The largest is on the edge, or HG's peak where the direction the
                    // lobe points to (w, or −w for g < 0) lies in the disk.
                    let lobe = if g >= 0.0 { w } else { -w };
                    let peak = if lobe.dot(l.to_light) >= l.half_angle.cos() {
                        hg_pdf(g as f64, if g >= 0.0 { 1.0 } else { -1.0 })
                    } else {
                        0.0
                    };
                    let (t, b) = basis(l.to_light);
                    let (sin, cos) = l.half_angle.sin_cos();
                    let edge = (0..3600)
                        .map(|k| {
                            let phi = k as f32 * std::f32::consts::TAU / 3600.0;
                            let d = l.to_light * cos + (t * phi.cos() + b * phi.sin()) * sin;
                            hg_pdf_between(g as f64, w.as_dvec3(), d.as_dvec3())
                        })
                        .fold(peak, f64::max);
                    assert!(
                        bound <= (1.0 + 2e-3) * edge,
                        "{diameter}° disk, g {g}, w {w}: bound {bound}, the edge's largest {edge}"
                    );
                }
            }
        }
    }

    /// NEE's draws (`sample`) are uniform over the disk whatever the light's direction, so
    /// that their mean is the disk's integral for any integrand. The other tests here weigh
    /// the draws by cos θ alone or by integrands symmetric about the disk's centre, under
    /// lights from above (to_light.z > 0), where Duff's basis takes its + sign; lights from
    /// below and along the horizon (to_light.z = −0) take its − sign, where a sign dropped
    /// from one of its terms left the pair non-orthogonal and the draws off the disk. Here,
    /// for a 40° disk from seven directions, every draw must lie in the disk
    /// (`radiance_toward` sees it), and over 200 × 50 strata of (u1, u2) the draws'
    /// moments in a frame about to_light built here (not by `basis`) must be the uniform
    /// cap's: E[ω·n] = 1 − V/2 = 0.969846, E[(ω·e1)²] = E[(ω·e2)²] = (V − V²/3)/2 =
    /// 0.029548 and E[ω·e1] = E[ω·e2] = E[(ω·e1)(ω·e2)] = 0, with V = 1 − cos 20° =
    /// 0.060307. The strata make them exact (the azimuths' cosines sum to 0) but for the
    /// midpoint rule's 4·10⁻⁹ in the second moments; 10⁻⁵ leaves room for f32 directions
    /// (~10⁻⁷), and is far below what a sign dropped from any one term of the basis moves
    /// them by: 6·10⁻³ to 5·10⁻² at the worst of the seven directions (computed in python).
    #[test]
    fn disk_draws_are_uniform_around_every_direction() {
        use glam::DVec3;
        let v = 1.0 - 20f64.to_radians().cos();
        let side = (v - v * v / 3.0) / 2.0;
        for direction in [
            [0.3, -1.0, -0.2],
            [0.3, -1.0, 0.4],
            [-0.6, -0.7, 0.4],
            [-0.8, 0.6, 0.0],
            [0.8, 0.6, 0.0],
            [0.0, 0.0, 1.0],
            [0.0, 0.0, -1.0],
        ] {
            let l = DirectionalLight::new(&LightDesc {
                kind: crate::scene::LightKind::Directional,
                direction,
                irradiance: [1.0; 3],
                angular_diameter_deg: 40.0,
            });
            let n = l.to_light.as_dvec3();
            let axis = if n.x.abs() < 0.9 { DVec3::X } else { DVec3::Y };
            let e1 = (axis - n * n.dot(axis)).normalize();
            let e2 = n.cross(e1);
            let (n1, n2) = (200u32, 50u32);
            // Sums of ω·e1, ω·e2, (ω·e1)², (ω·e2)², (ω·e1)(ω·e2) and ω·n.
            let mut sums = [0f64; 6];
            for i in 0..n1 {
                for j in 0..n2 {
                    let u1 = (i as f32 + 0.5) / n1 as f32;
                    let u2 = (j as f32 + 0.5) / n2 as f32;
                    let (dir, _) = l.sample(u1, u2, 0);
                    assert!(
                        l.radiance_toward(dir, 0) > 0.0,
                        "light along {direction:?}: the draw {dir} lies outside its disk"
                    );
                    let w = dir.as_dvec3();
                    let (x, y) = (w.dot(e1), w.dot(e2));
                    for (s, t) in sums.iter_mut().zip([x, y, x * x, y * y, x * y, w.dot(n)]) {
                        *s += t;
                    }
                }
            }
            let count = f64::from(n1 * n2);
            let want = [0.0, 0.0, side, side, 0.0, 1.0 - v / 2.0];
            let names = ["ω·e1", "ω·e2", "(ω·e1)²", "(ω·e2)²", "(ω·e1)(ω·e2)", "ω·n"];
            for ((sum, want), name) in sums.iter().zip(want).zip(names) {
                let got = sum / count;
                assert!(
                    (got - want).abs() < 1e-5,
                    "light along {direction:?}: mean {name} = {got}, uniform over the disk {want}"
                );
            }
        }
    }

    /// A sun disk's irradiance on a plane facing it is the scene's E: ∫ L cos θ dω over the
    /// disk, summed here by the midpoint rule in θ (20,000 rings; its error is ~1e-9) with
    /// the radiance read through `radiance_toward` at each ring, so the disk's edge and
    /// radiance are both checked. The bound 1e-3 is the f32 ring edges' (the disk's edge
    /// cuts one ring of 20,000). A radiance of E/Ω (solid angle) instead of E/(π sin²θ)
    /// is off by (1 − cos θ)/2 at half-angle θ: 5e-6 for the sun's 0.53°, 0.2 % at 10°,
    /// 3 % at 40° and 15 % at 90°, so the 40° and 90° disks are the ones that catch it;
    /// NEE on/off tests cannot see it (both use L).
    /// NEE's draws (`sample`) must average to E too: L/pdf·cos, checked by the same sum.
    #[test]
    fn a_sun_disk_gives_its_irradiance() {
        // A disk too small for f32 (E/(π sin²θ) would overflow: NaN images) is a delta
        // light, with finite factors.
        let tiny = DirectionalLight::new(&LightDesc {
            kind: crate::scene::LightKind::Directional,
            direction: [0.0, -1.0, 0.0],
            irradiance: [1.0; 3],
            angular_diameter_deg: 1e-18,
        });
        assert!(tiny.is_delta() && tiny.sample(0.5, 0.5, 0).1 == 1.0);
        for diameter in [0.53, 10.0, 40.0, 90.0] {
            let light = light(diameter);
            let half = (diameter / 2.0f64).to_radians();
            let (t, _) = basis(light.to_light);
            let rings = 20_000;
            for channel in 0..3 {
                let mut sum = 0.0f64;
                for k in 0..rings {
                    // Rings out to 1.01 × the radius: outside it the radiance must be 0.
                    let theta = (k as f64 + 0.5) / rings as f64 * half * 1.01;
                    let dtheta = half * 1.01 / rings as f64;
                    let dir =
                        (t * theta.sin() as f32 + light.to_light * theta.cos() as f32).normalize();
                    let l = f64::from(light.radiance_toward(dir, channel));
                    sum += l * theta.cos() * theta.sin() * dtheta * std::f64::consts::TAU;
                }
                let e = [2.0, 1.0, 0.5][channel];
                assert!(
                    (sum / e - 1.0).abs() < 1e-3,
                    "{diameter}° disk, channel {channel}: ∫ L cos dω = {sum}, E = {e}"
                );
                // NEE's estimate of the same integral: the mean of factor · cos over
                // stratified draws (2,000 × 50 strata; its error is far below 1e-3).
                let (n1, n2) = (2000, 50);
                let mut est = 0.0f64;
                for i in 0..n1 {
                    for j in 0..n2 {
                        let u1 = (i as f32 + 0.5) / n1 as f32;
                        let u2 = (j as f32 + 0.5) / n2 as f32;
                        let (dir, f) = light.sample(u1, u2, channel);
                        est += f64::from(f) * f64::from(dir.dot(light.to_light));
                    }
                }
                est /= f64::from(n1 * n2);
                assert!(
                    (est / e - 1.0).abs() < 1e-3,
                    "{diameter}° disk, channel {channel}: NEE's mean L/pdf·cos = {est}, E = {e}"
                );
            }
        }
    }

    /// Directions that land exactly on the map's far edges read its last row and column:
    /// straight down, v = acos(−1)/π is exactly 1 (f32's acos(−1) is its π), the bottom
    /// row; just left of −z, u = 1 − 1.6·10⁻¹⁰ rounds to exactly 1 in f32, the last
    /// column (of the horizon's row 4, v = 0.5). Without the clamp on the row the first
    /// indexes past the map's end (a panic mid-render); without the one on the column the
    /// second reads the next row's first pixel (80 for 79). Each pixel here holds its index.
    #[test]
    fn map_edges_read_the_last_row_and_column() {
        let mut m = RgbImage::new(16, 8);
        for (i, p) in m.pixels.iter_mut().enumerate() {
            *p = [i as f32; 3];
        }
        let env = Environment {
            radiance: [1.0; 3],
            map: Some(m),
        };
        let down = env.lookup(Vec3::NEG_Y, 0);
        assert_eq!(down as usize / 16, 7, "straight down reads pixel {down}");
        let seam = Vec3::new(-1e-9, 0.0, -1.0);
        assert_eq!(env.lookup(seam, 0), (4 * 16 + 15) as f32, "just left of −z");
    }
}
