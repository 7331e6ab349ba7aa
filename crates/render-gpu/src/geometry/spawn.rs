//! Where a path leaves the surface from, and how far a flight may reach before it must
//! stop short of the surface: the offsets that keep a ray off the triangle it left.

use glam::Vec3;

use super::{FLIGHT_MARGIN_OF_EPS, Geometry, Hit, SKIP_MIN_COS, SLIVER_REACH_OF_EPS};

impl Geometry {
    /// How far past a flight's end the integrators look for a surface, and how far short
    /// of one found there the collision then stands: a few f32 roundings of positions at
    /// the scene's scale (eps is 2e-5 of it; this is 4e-7 of it).
    #[inline]
    pub fn flight_margin(&self) -> f32 {
        self.eps * FLIGHT_MARGIN_OF_EPS
    }

    /// Where a flight of length `t` along `dir` ends, given `hit`, what the cast that looked
    /// [`Self::flight_margin`] beyond `t` found: the face it reached, or none and the
    /// distance at which the collision stands. A face found only thanks to the margin
    /// (beyond `t`) is not reached: the collision stands, moved back to the margin's
    /// distance from the face, where every collision the margin leaves alone may lie. Taken
    /// as an exit, those collisions were lost: −0.01·σ_t·eps of the image (−0.2 % at
    /// σ_t·eps = 0.2; integrator/mod.rs' `collisions_within_the_flight_margin_stand`). A
    /// face met from outside (a leak) is still the face, as is any face of overlapping
    /// pieces (their normals do not tell in from out). path.wgsl's `flight_end` does the
    /// same on the GPU.
    #[inline]
    pub fn flight_end(&self, hit: Option<Hit>, dir: Vec3, t: f32) -> (Option<Hit>, f32) {
        match hit {
            Some(h) if h.t > t && (self.pieces.is_some() || dir.dot(h.normal) >= 0.0) => {
                (None, t.min((h.t - self.flight_margin()).max(0.0)))
            }
            h => (h, t),
        }
    }

    /// Whether `p` lies in the mesh's bounding box grown by eps: every point inside the
    /// closed mesh does.
    #[inline]
    pub fn within_bounds(&self, p: Vec3) -> bool {
        p.cmpge(self.lo - self.eps).all() && p.cmple(self.hi + self.eps).all()
    }

    /// The medium a path spawned inside at a surface with normal `normal`, heading `dir`,
    /// has passed without a chance to scatter: the way along `dir` from the surface to
    /// [`Self::spawn`]'s depth eps. The next flight is measured from the surface by
    /// taking it off ([`crate::integrator`]'s `PathState::skip`). A grazing direction's
    /// credit stops at eps / [`SKIP_MIN_COS`].
    #[inline]
    pub fn spawn_skip(&self, normal: Vec3, dir: Vec3) -> f32 {
        self.eps / dir.dot(normal).abs().max(SKIP_MIN_COS)
    }

    /// A point just off the surface at `p`, on the side `dir` points to.
    #[inline]
    pub fn spawn(&self, p: Vec3, normal: Vec3, dir: Vec3) -> Vec3 {
        let side = if dir.dot(normal) >= 0.0 { 1.0 } else { -1.0 };
        p + normal * (side * self.eps)
    }

    /// Whether `q`, spawned eps inside the surface at a hit whose outward normal is
    /// `normal`, lies outside after all: beyond a sliver of medium thinner than eps along
    /// the normal (a sharp edge or a thin feature, such as the low-resolution bunny has at
    /// the top of its head). The way back to the hit point then meets another surface from outside
    /// before the one it came through. A path spawned there believed itself inside and
    /// scattered through the air with unshadowed NEE until it left the bounding box: the
    /// fireflies that made PT look 3–4 % brighter than ST-CVAE in a close-up of the top of
    /// the bunny at k = 8 (~4 in 10⁶ of its paths). On a closed, consistently oriented mesh
    /// the first surface met from a point truly inside is an exit, so the check never fires
    /// at ordinary entries. It is a ray of length ~eps: a fraction of a cast.
    /// `cast(origin, dir, tmax)` is the closest-hit query to use ([`Geometry::intersect`]
    /// or a cheaper one that finds the same hit).
    pub fn beyond_sliver(
        &self,
        q: Vec3,
        normal: Vec3,
        cast: impl FnOnce(Vec3, Vec3, f32) -> Option<Hit>,
    ) -> bool {
        cast(q, normal, self.eps * SLIVER_REACH_OF_EPS).is_some_and(|h| h.normal.dot(normal) < 0.0)
    }
}
