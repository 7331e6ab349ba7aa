//! Ray casts against the mesh: the nearest hit, the crossings along a segment, and the
//! union of overlapping pieces, through the 8-wide BVH and the watertight triangle test.

use glam::Vec3;
use obvhs::ray::{Ray, RayHit};

use crate::watertight::RayShear;

use super::{
    CROSSING_TOL_OF_EPS, Closest, Crossed, GRAZING_COS_FLOOR, Geometry, Hit, MAX_UNION_CROSSINGS,
    PLANE_SLACK_OF_EPS, Pieces, UnionCrossing, arr, union_walk,
};

impl Geometry {
    /// Whether a ray spawned on the outer side of triangle `prim` along unit `dir` meets
    /// the mesh nowhere, known without a cast: `dir` lies in the triangle's escape cone.
    #[inline]
    pub fn escapes_from(&self, prim: u32, dir: Vec3) -> bool {
        dir.dot(self.normals[prim as usize]) >= self.escape_cos[prim as usize]
    }

    /// Closest hit along `origin + t·dir`, t ∈ [0, tmax].
    pub fn intersect(&self, origin: Vec3, dir: Vec3, tmax: f32) -> Option<Hit> {
        let shear = RayShear::new(origin, dir);
        let mut hit = RayHit::none();
        let mut best = Closest::new(tmax);
        let mut visit = |prim: u32| best.offer(self, &shear, prim);
        match &self.cwbvh {
            Some(cw) => {
                let back = self.cw_back;
                cw.ray_traverse(self.cw_ray(origin, dir, tmax), &mut hit, |_, id| {
                    visit(cw.primitive_indices[id]).map_or(f32::INFINITY, |t| t + back)
                });
            }
            None => {
                let ray = Ray::new(arr(origin).into(), arr(dir).into(), 0.0, tmax);
                self.bvh.ray_traverse(ray, &mut hit, |_, id| {
                    visit(self.bvh.primitive_indices[id]).unwrap_or(f32::INFINITY)
                });
            }
        }
        best.hit(self)
    }

    /// The closest hit along `origin + t·dir`, t ∈ [0, tmax], among the triangles
    /// `prims` (the same watertight test as [`Geometry::intersect`]; a tie keeps the
    /// first). A triangle whose plane the segment does not reach is skipped before the
    /// watertight test: both ends on one side of it, farther than 10⁻⁶ of the scene's
    /// size (ten times the roundings of the plane distances), which a hit cannot be.
    pub fn closest_of(&self, origin: Vec3, dir: Vec3, tmax: f32, prims: &[u32]) -> Option<Hit> {
        let shear = RayShear::new(origin, dir);
        let slack = self.eps * PLANE_SLACK_OF_EPS;
        let mut best = Closest::new(tmax);
        for &prim in prims {
            let b = &self.bounds[prim as usize];
            let s0 = b[0] * origin.x + b[1] * origin.y + b[2] * origin.z - b[3];
            let s1 = s0 + best.t * (b[0] * dir.x + b[1] * dir.y + b[2] * dir.z);
            if (s0 > slack && s1 > slack) || (s0 < -slack && s1 < -slack) {
                continue;
            }
            best.offer(self, &shear, prim);
        }
        best.hit(self)
    }

    /// The ray `origin + t·dir` (t ≤ tmax) for the 8-wide BVH, started `cw_back` behind
    /// its origin: obvhs's node test skips every box that the ray enters beyond 10⁻⁴ only
    /// (its `EPSILON`, an absolute distance that ignores the ray's tmin), which at high
    /// density loses the surface that most flights near it meet (seen as ~6·10⁻⁵ of the
    /// bunny's paths found outside at k = 2). The callers test the triangles along the
    /// true ray from t = 0 and report their distances along the shifted one.
    ///
    /// Its direction's zero components are made +0: obvhs inverts a −0 to −1/ε but picks
    /// each slab's near side by `direction < 0`, false for −0, so a ray along an axis
    /// with a −0 component (a light shining straight down: to_light = (−0, 1, −0)) met no
    /// box at all. (−0 + 0 = +0; every other value is unchanged.)
    #[inline]
    fn cw_ray(&self, origin: Vec3, dir: Vec3, tmax: f32) -> Ray {
        let back = self.cw_back;
        Ray::new(
            arr(origin - dir * back).into(),
            arr(dir + Vec3::ZERO).into(),
            0.0,
            tmax + back,
        )
    }

    /// Every surface crossing of the ray `origin + t·dir` (t ≥ 0) in one BVH traversal,
    /// without the closest-hit ordering: the length inside a closed mesh is
    /// Σ t(exits) − Σ t(entries) in whatever order the crossings are found, so a shadow
    /// ray needs one traversal instead of one per crossing (plus the one that confirms
    /// the escape). `factor(cos, exiting)` is multiplied over the crossings (Fresnel
    /// transmittance). None when the crossings do not pair up as they must for an origin
    /// inside (one more exit than entries, non-negative length): a ray through a crack
    /// between triangles, or an origin that is not inside; callers then walk the
    /// crossings one by one.
    pub fn inside_length(
        &self,
        origin: Vec3,
        dir: Vec3,
        factor: impl FnMut(f32, bool) -> f32,
    ) -> Option<(f32, f32)> {
        let c = self.crossed(origin, dir, factor);
        c.paired.then_some((c.length, c.product))
    }

    /// [`Self::inside_length`]'s traversal, with the nearest crossing (NEE's refraction
    /// happens there) and whether the crossings paired up.
    pub fn crossed(
        &self,
        origin: Vec3,
        dir: Vec3,
        mut factor: impl FnMut(f32, bool) -> f32,
    ) -> Crossed {
        let shear = RayShear::new(origin, dir);
        let mut length = 0.0f32;
        let mut balance = 0i32;
        let mut product = 1.0f32;
        let mut first: Option<(f32, usize)> = None;
        let mut visit = |prim: u32| {
            let prim = prim as usize;
            let t = self.hit_tri(&shear, prim, f32::INFINITY);
            if t.is_finite() {
                // The nearest, the lower triangle index on a tie: the same whatever
                // order the traversal finds them in (scene.wgsl does the same in its own
                // triangle order, so an exact tie, a set of measure zero, may pick
                // another face there).
                if first.is_none_or(|(ft, fp)| t < ft || (t == ft && prim < fp)) {
                    first = Some((t, prim));
                }
                let c = dir.dot(self.normals[prim]);
                let exiting = c > 0.0;
                if exiting {
                    length += t;
                    balance += 1;
                } else {
                    length -= t;
                    balance -= 1;
                }
                product *= factor(c.abs(), exiting);
            }
        };
        match &self.cwbvh {
            Some(cw) => {
                let ray = self.cw_ray(origin, dir, f32::INFINITY);
                cw.ray_traverse_anyhit(ray, |_, id| visit(cw.primitive_indices[id]));
            }
            None => {
                let ray = Ray::new(arr(origin).into(), arr(dir).into(), 0.0, f32::INFINITY);
                let mut hit = RayHit::none();
                self.bvh.ray_traverse(ray, &mut hit, |_, id| {
                    visit(self.bvh.primitive_indices[id]);
                    // Never a closest hit: the traversal keeps its full range and visits
                    // every node the ray crosses.
                    f32::INFINITY
                });
            }
        }
        Crossed {
            length,
            product,
            paired: balance == 1 && length >= 0.0,
            first,
        }
    }

    /// Whether `p` is in the medium of a mesh whose pieces overlap: the pieces whose
    /// faces the ray from `p` along `dir` crosses an odd number of times are those
    /// around `p` ([`Pieces::medium`]). Asked at a point spawned past a face, this holds
    /// where the path has got to even when another piece's face lies in the same plane
    /// (overlapping boxes often share face planes), which flipping one piece at each
    /// crossing would miss: the second face lies behind the spawned point.
    pub fn in_union(&self, pieces: &Pieces, p: Vec3, dir: Vec3) -> bool {
        let mut crossings = [(0.0f32, 0u32, 0.0f32, 0u32); MAX_UNION_CROSSINGS];
        let set = match self.union_crossings(pieces, p, dir, &mut crossings) {
            Some(n) => crossings[..n].iter().fold(0, |s, c| s ^ c.1),
            // More than the list holds: every hit flips its piece, a face met twice
            // through an edge included (rare: an exact edge among so many crossings).
            None => {
                let shear = RayShear::new(p, dir);
                let mut set = 0u32;
                self.each_hit(p, dir, |prim| {
                    if self.hit_tri(&shear, prim, f32::INFINITY).is_finite() {
                        set ^= pieces.bit_of[prim];
                    }
                });
                set
            }
        };
        pieces.medium(set)
    }

    /// Every triangle whose box the ray from `origin` along `dir` meets, in one traversal.
    fn each_hit(&self, origin: Vec3, dir: Vec3, mut visit: impl FnMut(usize)) {
        match &self.cwbvh {
            Some(cw) => {
                let ray = self.cw_ray(origin, dir, f32::INFINITY);
                cw.ray_traverse_anyhit(ray, |_, id| visit(cw.primitive_indices[id] as usize));
            }
            None => {
                let ray = Ray::new(arr(origin).into(), arr(dir).into(), 0.0, f32::INFINITY);
                let mut hit = RayHit::none();
                self.bvh.ray_traverse(ray, &mut hit, |_, id| {
                    visit(self.bvh.primitive_indices[id] as usize);
                    // Never a closest hit: the traversal keeps its full range.
                    f32::INFINITY
                });
            }
        }
    }

    /// The crossings (t, piece bit, dir·normal) of the ray from `origin` along `dir`,
    /// sorted by t, into `out`: how many, or None beyond its [`MAX_UNION_CROSSINGS`].
    /// A face met twice at one point is kept once: a ray through the edge (or vertex)
    /// that triangles of one face share hits each of them (the watertight test has no
    /// tie rule), and counted twice its piece's parity came out wrong, e.g. for a ray
    /// aimed at a box face's centre, on its diagonal. Twice means the same piece, the
    /// same side (both entries or both exits) and t within a hundredth of the spawn
    /// offset over |cos| (the face's distance along the normal); an entry and an exit at
    /// one point (a ray grazing an edge) stay both.
    fn union_crossings(
        &self,
        pieces: &Pieces,
        origin: Vec3,
        dir: Vec3,
        out: &mut [UnionCrossing; MAX_UNION_CROSSINGS],
    ) -> Option<usize> {
        let shear = RayShear::new(origin, dir);
        let mut n = 0usize;
        let mut overflow = false;
        self.each_hit(origin, dir, |prim| {
            let t = self.hit_tri(&shear, prim, f32::INFINITY);
            if t.is_finite() {
                if n == MAX_UNION_CROSSINGS {
                    overflow = true;
                } else {
                    out[n] = (
                        t,
                        pieces.bit_of[prim],
                        dir.dot(self.normals[prim]),
                        prim as u32,
                    );
                    n += 1;
                }
            }
        });
        if overflow {
            return None;
        }
        out[..n].sort_unstable_by(|a, b| a.0.total_cmp(&b.0));
        let tol = self.eps * CROSSING_TOL_OF_EPS;
        let mut kept = 0usize;
        for i in 0..n {
            let c = out[i];
            // Along the ray: two planes through one edge give distances that differ by
            // their roundings over |cos|, as union_walk's reach.
            let reach = tol / c.2.abs().max(GRAZING_COS_FLOOR);
            let twice = out[..kept]
                .iter()
                .rev()
                .take_while(|k| c.0 - k.0 <= reach)
                .any(|k| k.1 == c.1 && (k.2 > 0.0) == (c.2 > 0.0));
            if !twice {
                out[kept] = c;
                kept += 1;
            }
        }
        Some(kept)
    }

    /// [`Geometry::inside_length`] for a mesh whose pieces overlap ([`Pieces`]): the
    /// crossings, gathered in one traversal, are sorted and walked with the set of
    /// pieces around the ray, which starts as the pieces crossed an odd number of times
    /// (those around the origin). Length counts where that set is in the medium and
    /// `factor(cos, exiting)` only where that changes (the union's own boundary). The
    /// plain sum Σ t(exits) − Σ t(entries) would count an overlap once per piece. None
    /// beyond [`MAX_UNION_CROSSINGS`] crossings (callers then walk them in order).
    pub fn union_inside_length(
        &self,
        pieces: &Pieces,
        origin: Vec3,
        dir: Vec3,
        factor: impl FnMut(f32, bool) -> f32,
    ) -> Option<(f32, f32)> {
        self.union_crossed(pieces, origin, dir, factor)
            .map(|c| (c.length, c.product))
    }

    /// [`Self::union_inside_length`] with the first crossing of the union's boundary
    /// where it leaves the medium (t, triangle; [`union_walk`]).
    pub fn union_crossed(
        &self,
        pieces: &Pieces,
        origin: Vec3,
        dir: Vec3,
        mut factor: impl FnMut(f32, bool) -> f32,
    ) -> Option<Crossed> {
        let mut crossings = [(0.0f32, 0u32, 0.0f32, 0u32); MAX_UNION_CROSSINGS];
        let n = self.union_crossings(pieces, origin, dir, &mut crossings)?;
        Some(union_walk(pieces, &crossings[..n], self.eps, &mut factor))
    }

    /// Watertight distance to triangle `prim` along the sheared ray, in [0, tmax] (∞: no hit).
    #[inline]
    pub(super) fn hit_tri(&self, shear: &RayShear, prim: usize, tmax: f32) -> f32 {
        let t = &self.tris[prim];
        let v = |a: [f32; 3]| Vec3::from_array(a);
        let n = self.normals[prim];
        shear.hit(v(t.v0.into()), v(t.v1.into()), v(t.v2.into()), n, 0.0, tmax)
    }
}
