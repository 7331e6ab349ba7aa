//! Ray and distance queries against the closed mesh: ray casts through an obvhs 8-wide BVH
//! (CwBvh), distance searches through the binary BVH2 the GPU kernels also read.
//!
//! Rays that start on the surface are offset along the geometric normal to the side they
//! are meant to be on ([`Geometry::spawn`]), so a ray never re-hits the triangle it left.

use std::time::Duration;

use glam::{Vec3, Vec3A};

// obvhs may resolve to another glam minor version than ours: cross the boundary through
// plain arrays, which every glam version converts from and to.
#[inline]
fn arr(v: Vec3) -> [f32; 3] {
    v.to_array()
}
#[inline]
fn from_arr(a: impl Into<[f32; 3]>) -> Vec3A {
    Vec3A::from_array(a.into())
}
use obvhs::aabb::Aabb;
use obvhs::bvh2::Bvh2;
use obvhs::bvh2::builder::build_bvh2_from_tris;
use obvhs::cwbvh::CwBvh;
use obvhs::cwbvh::builder::build_cwbvh;
use obvhs::ray::{Ray, RayHit};
use obvhs::triangle::Triangle;
use obvhs::{Boundable, BvhBuildParams};

use crate::mesh::TriMesh;
use crate::watertight::RayShear;

/// A surface hit: distance along the ray, triangle and outward unit normal.
#[derive(Clone, Copy, Debug)]
pub struct Hit {
    pub t: f32,
    pub prim: u32,
    pub normal: Vec3,
}

/// Every crossing of a ray from a point, unordered ([`Geometry::crossed`]).
#[derive(Clone, Copy, Debug)]
pub struct Crossed {
    /// Σ t(exits) − Σ t(entries): the length inside when `paired`.
    pub length: f32,
    /// The crossings' factors multiplied.
    pub product: f32,
    /// Whether the crossings pair up as they must for an origin inside (one more exit
    /// than entries, a non-negative length); else a crack or an origin outside.
    pub paired: bool,
    /// The nearest crossing's distance and triangle ([`Geometry::crossed`]), or where
    /// pieces overlap the first crossing of the union's boundary if it leaves the medium
    /// ([`union_walk`]).
    pub first: Option<(f32, usize)>,
}

/// [`Geometry::flight_margin`] in units of eps (the WGSL kernels take it from here).
pub const FLIGHT_MARGIN_OF_EPS: f32 = 0.02;
/// The smallest |cos| [`Geometry::spawn_skip`] divides by (the WGSL kernels take it from
/// here).
pub const SKIP_MIN_COS: f32 = 0.05;
/// The most of a spawn's skipped way a collision drawn within it is moved back along the
/// path (the WGSL kernels take it from here): it then lies at its own depth, but at least
/// a fiftieth of the way deep (the flight margin's 4·10⁻⁷ of the object's size at normal
/// entry), where rays from it still see the face it came through. Collisions lifted to
/// the floor lie too deep: at 0.9 (and the cast below at a tenth of eps) the image was
/// +0.08 % bright at σ_t·eps = 0.2.
pub const SKIP_BACK: f32 = 0.98;
/// How far beyond a collision's way back a face must be clear, in units of eps (the WGSL
/// kernels take it from here): half the floor's depth at normal entry, so that the face
/// the path came through, (1 − SKIP_BACK)·eps/|cos| beyond, is never met by the cast (at
/// (1 − SKIP_BACK)·eps a ray met it at normal entry, leaving those collisions eps deep).
pub const SKIP_CLEAR_OF_EPS: f32 = 0.01;
/// Most mean free paths the spawn offset eps may span (σ_t·eps). With the skip, the
/// collisions within the flight margin kept and the floor above, a sphere's image moves by
/// +0.05 % at σ_t·eps = 0.2, +0.06 % at 0.5 and +0.08 % at 1 against σ_t·eps = 0.006
/// (standard error ~0.025 %; docs/BENCHMARKS.md, forty-seventh session; it was −0.33 % at
/// 0.5 when the bound was 0.25), and a cube's edge leaks 10 paths in 200,000 at 0.96.
pub const MAX_SPAWN_DEPTH: f32 = 1.0;
/// How far [`Geometry::beyond_sliver`] looks, in units of eps. What it must see is a far
/// face between the spawned point and the hit point, at t < eps; looking a little past the
/// hit point (by more than the spawned point's rounding, an ulp of the coordinates, ~1 %
/// of eps at the scene's scale) keeps a far face right at the hit point in view, and the
/// surface the path came through, met there, reads as inside either way (the WGSL kernels
/// take it from here).
pub const SLIVER_REACH_OF_EPS: f32 = 1.05;

/// A segment with both ends farther than this (in units of eps, 10⁻⁶ of the scene's size:
/// ten times the roundings of the plane distances) on one side of a triangle's plane
/// cannot meet it ([`Geometry::closest_of`]'s cull).
pub const PLANE_SLACK_OF_EPS: f32 = 0.05;

/// Two crossings of one face within this (in units of eps) are one crossing of an edge
/// two of its triangles share (the union's dedupe).
pub const CROSSING_TOL_OF_EPS: f32 = 0.01;

/// The least |cos| between a ray and a face's normal that a distance tolerance is divided
/// by to reach along the ray (the union's dedupe, a flight's crossings of one place): a
/// grazing face would otherwise reach without bound.
pub const GRAZING_COS_FLOOR: f32 = 1e-3;

pub struct Geometry {
    pub mesh: TriMesh,
    pub tris: Vec<Triangle>,
    pub normals: Vec<Vec3>,
    /// The binary BVH: the GPU kernels' node layout and the distance searches.
    pub bvh: Bvh2,
    /// The same triangles in a compressed 8-wide BVH for the CPU's ray casts, whose
    /// SIMD node tests traverse it faster than the binary tree; None (casts through the
    /// binary tree) when it is deeper than obvhs's traversal stack holds
    /// ([`MAX_WIDE_DEPTH`]).
    cwbvh: Option<CwBvh>,
    /// How far behind their origin rays enter `cwbvh` ([`Geometry::cw_ray`]): twice
    /// obvhs's node-test cut-off plus far more than the rounding of a shifted origin.
    cw_back: f32,
    pub lo: Vec3,
    pub hi: Vec3,
    /// Offset used to leave a surface, relative to the scene's size.
    pub eps: f32,
    /// Per triangle, two cheap lower bounds on a point's distance to it: its plane (unit
    /// normal, offset n·a) and a bounding sphere (centre, radius) — [nx, ny, nz, n·a, cx,
    /// cy, cz, r]. [`Geometry::nearest_of`] skips the exact point–triangle distance of
    /// every candidate whose bound already exceeds the nearest found so far;
    /// [`Geometry::closest_of`] skips the ray test of a triangle whose plane a segment
    /// does not reach.
    bounds: Vec<[f32; 8]>,
    /// The largest |coordinate| of the mesh: the scale at which `bounds` round.
    coords: f32,
    /// Per triangle, cos θ of its escape cone ([`crate::escape_cone`]).
    pub(crate) escape_cos: Vec<f32>,
    /// The pairs of closed pieces that overlap ([`crate::mesh::overlapping_pieces`]).
    pub overlaps: Vec<(usize, usize)>,
    /// Where pieces overlap, which piece each triangle belongs to: paths then follow the
    /// set of pieces they are in and cross the faces within the union without meeting
    /// a boundary. None without overlaps: the integrators' inside/outside flag suffices,
    /// and its leak checks (a face met from the wrong side) stay.
    pub pieces: Option<Pieces>,
}

/// The pieces of a mesh whose pieces overlap, for following which of them a point is
/// in: a set of pieces as the bits of a u32 ([`crate::mesh::MAX_OVERLAP_PIECES`]), one
/// bit flipped at each crossing of a piece's face (crossing a closed surface always
/// enters or leaves it, whatever its winding). A point is in the medium when the most
/// deeply nested piece around it is a solid (even depth: [`crate::mesh`]'s nesting
/// rule): in the union of overlapping solids, not in a cavity within them.
pub struct Pieces {
    /// Per triangle, its piece's bit.
    pub bit_of: Vec<u32>,
    /// Per nesting depth, the bits of the pieces at that depth.
    pub at_depth: Vec<u32>,
}

impl Pieces {
    fn new(of_tri: &[u8], depths: &[usize]) -> Self {
        let mut at_depth = vec![0u32; depths.iter().max().map_or(0, |d| d + 1)];
        for (k, &d) in depths.iter().enumerate() {
            at_depth[d] |= 1 << k;
        }
        Self {
            bit_of: of_tri.iter().map(|&k| 1u32 << k).collect(),
            at_depth,
        }
    }

    /// Whether a point inside exactly the pieces of `set` is in the medium.
    #[inline]
    pub fn medium(&self, set: u32) -> bool {
        for (d, &bits) in self.at_depth.iter().enumerate().rev() {
            if set & bits != 0 {
                return d % 2 == 0;
            }
        }
        false
    }
}

/// The length in the medium and the product of `factor` over the medium's boundary
/// along crossings (t, piece bit, dir·normal, triangle) in order of t, starting from the
/// pieces crossed an odd number of times ([`Geometry::union_inside_length`]), and the
/// first boundary crossing (t, triangle) where it leaves the medium (None where the first
/// is an entry, or there is none). The faces within
/// `gap` (the spawn offset) of a crossing along its normal are crossed with it, as the
/// path loop's point spawned past a face is past them too: pieces touching across a gap
/// thinner than that make no boundary there (crossed one by one, an exit sorted before
/// the entry passed through air, and a dielectric's Fresnel factor came twice).
pub fn union_walk(
    pieces: &Pieces,
    crossings: &[UnionCrossing],
    gap: f32,
    factor: &mut impl FnMut(f32, bool) -> f32,
) -> Crossed {
    let mut set = crossings.iter().fold(0u32, |s, c| s ^ c.1);
    let mut medium = pieces.medium(set);
    let (mut length, mut product, mut last) = (0.0f32, 1.0f32, 0.0f32);
    let (mut first, mut boundary_seen) = (None, false);
    let mut i = 0;
    while i < crossings.len() {
        let (t, _, c, prim) = crossings[i];
        if medium {
            length += t - last;
        }
        last = t;
        let reach = t + gap / c.abs().max(GRAZING_COS_FLOOR);
        while i < crossings.len() && crossings[i].0 <= reach {
            set ^= crossings[i].1;
            i += 1;
        }
        let now = pieces.medium(set);
        if now != medium {
            product *= factor(c.abs(), medium);
            if !boundary_seen && medium {
                first = Some((t, prim as usize));
            }
            boundary_seen = true;
            medium = now;
        }
    }
    Crossed {
        length,
        product,
        paired: true,
        first,
    }
}

/// One crossing of [`union_walk`]: t, the piece's bit, dir·normal, the triangle.
pub type UnionCrossing = (f32, u32, f32, u32);

/// Most crossings [`Geometry::union_inside_length`] sorts (on the stack); a shadow ray
/// with more is walked crossing by crossing.
pub const MAX_UNION_CROSSINGS: usize = 64;

/// Deepest 8-wide tree the CPU's casts use: obvhs's traversal stack holds 32 node groups
/// and, past that, silently overwrites its top (losing triangles); a traversal needs at
/// most one entry per level below the root. A deeper tree (only from pathological
/// meshes; the bunny's is 4 levels deep (`wide_and_binary_trees_cast_alike`)) leaves the
/// casts to the binary tree, whose stack grows.
const MAX_WIDE_DEPTH: u32 = 30;

/// Levels below the root of an 8-wide tree.
fn wide_depth(t: &CwBvh) -> u32 {
    let mut deepest = 0;
    let mut stack = if t.nodes.is_empty() {
        vec![]
    } else {
        vec![(0usize, 0u32)]
    };
    while let Some((i, depth)) = stack.pop() {
        deepest = deepest.max(depth);
        let node = &t.nodes[i];
        for child in 0..8 {
            if !node.is_leaf(child) {
                stack.push((node.child_node_index(child) as usize, depth + 1));
            }
        }
    }
    deepest
}

/// The closest of the triangle hits found so far along one ray, within its tmax (a tie
/// keeps the first): what every closest-hit query collects.
struct Closest {
    t: f32,
    /// u32::MAX: none yet.
    prim: u32,
}

impl Closest {
    fn new(tmax: f32) -> Self {
        Self {
            t: tmax,
            prim: u32::MAX,
        }
    }

    /// Tests triangle `prim` along the sheared ray; its distance when it is the closest
    /// so far (hit_tri returns a finite t only within the current best).
    #[inline]
    fn offer(&mut self, geo: &Geometry, shear: &RayShear, prim: u32) -> Option<f32> {
        let t = geo.hit_tri(shear, prim as usize, self.t);
        let closer = t.is_finite() && (self.prim == u32::MAX || t < self.t);
        if closer {
            (self.t, self.prim) = (t, prim);
        }
        closer.then_some(t)
    }

    fn hit(&self, geo: &Geometry) -> Option<Hit> {
        (self.prim != u32::MAX).then(|| Hit {
            t: self.t,
            prim: self.prim,
            normal: geo.normals[self.prim as usize],
        })
    }
}

/// A triangle whose bounding box is grown by a margin (see the padding in
/// [`Geometry::new`]): every node box of a tree built over these contains it.
struct PaddedTri(Triangle, f32);

impl Boundable for PaddedTri {
    fn aabb(&self) -> Aabb {
        let b = self.0.aabb();
        Aabb::new(b.min - self.1, b.max + self.1)
    }
}

/// The spawn offset `eps`, and how far the tree's boxes are grown, as fractions of the
/// mesh's scale ([`TriMesh::scale`]). The escape cones' box test reads the growth back
/// ([`Geometry::box_growth`]).
pub const EPS: f32 = 2e-5;
const BOX_GROWTH: f32 = 1e-5;

/// The spawn offset eps of a mesh: [`EPS`] of its largest coordinate or extent
/// ([`TriMesh::scale`]); `Geometry::new` and the checks made before building it
/// (`setup::object_eps`) both take it from here.
pub fn spawn_offset(mesh: &TriMesh) -> f32 {
    mesh.scale() * EPS
}

impl Geometry {
    /// How far each box of `bvh` is grown beyond the faces in it.
    pub fn box_growth(&self) -> f32 {
        self.eps / EPS * BOX_GROWTH
    }

    pub fn new(mesh: TriMesh) -> Self {
        let (overlaps, table) = crate::mesh::overlaps_and_pieces(&mesh);
        let pieces = table.map(|(of, depths)| Pieces::new(&of, &depths));
        let tris: Vec<Triangle> = (0..mesh.triangles.len())
            .map(|i| {
                let [a, b, c] = mesh.triangle(i);
                Triangle {
                    v0: arr(a).into(),
                    v1: arr(b).into(),
                    v2: arr(c).into(),
                }
            })
            .collect();
        let normals: Vec<Vec3> = (0..mesh.triangles.len())
            .map(|i| {
                // In f64: an f32 cross product of a long thin triangle's edges tilts the
                // normal by ~ε·length/width (6·10⁻⁵ at 1,000:1), which the distances
                // (`point_triangle_d2`) and the plane bounds of `nearest_of` would carry.
                let [a, b, c] = mesh.triangle(i).map(|v| v.as_dvec3());
                (b - a).cross(c - a).normalize().as_vec3()
            })
            .collect();
        let mut bvh = build_bvh2_from_tris(
            &tris,
            BvhBuildParams::medium_build(),
            &mut Duration::default(),
        );
        let (lo, hi) = mesh.bounds();
        let scale = mesh.scale();
        let eps = spawn_offset(&mesh);
        // The slab test rounds: a ray through a vertex that lies on a leaf's box face can
        // miss the box and with it the triangle the watertight test would have hit (seen
        // for ~0.1 % of rays aimed at vertices from inside). Padding every box by far more
        // than the rounding error (~1e-7 of the distances involved) makes the traversal
        // conservative; the cost is a few more box hits.
        let pad = scale * BOX_GROWTH;
        for n in &mut bvh.nodes {
            n.aabb.min -= pad;
            n.aabb.max += pad;
        }
        let padded: Vec<PaddedTri> = tris.iter().map(|&t| PaddedTri(t, pad)).collect();
        let cwbvh = Some(build_cwbvh(
            &padded,
            BvhBuildParams::medium_build(),
            &mut Duration::default(),
        ))
        .filter(|t| wide_depth(t) <= MAX_WIDE_DEPTH);
        let bounds = (0..mesh.triangles.len())
            .map(|i| {
                let [a, b, c] = mesh.triangle(i);
                let n: Vec3 = normals[i];
                let centre = (a + b + c) / 3.0;
                let r = [a, b, c]
                    .iter()
                    .map(|v| v.distance(centre))
                    .fold(0.0f32, f32::max);
                // Rounded up by far more than f32 rounding: a bound must never exceed the
                // true distance.
                let r = r * (1.0 + 1e-5) + scale * 1e-7;
                [n.x, n.y, n.z, n.dot(a), centre.x, centre.y, centre.z, r]
            })
            .collect();
        let mut geo = Self {
            mesh,
            tris,
            normals,
            bvh,
            cwbvh,
            cw_back: 2e-4 + scale * 1e-5,
            lo,
            hi,
            eps,
            bounds,
            coords: lo.abs().max(hi.abs()).max_element(),
            escape_cos: Vec::new(),
            overlaps,
            pieces,
        };
        geo.escape_cos = crate::escape_cone::cached(&geo);
        geo
    }

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
    fn hit_tri(&self, shear: &RayShear, prim: usize, tmax: f32) -> f32 {
        let t = &self.tris[prim];
        let v = |a: [f32; 3]| Vec3::from_array(a);
        let n = self.normals[prim];
        shear.hit(v(t.v0.into()), v(t.v1.into()), v(t.v2.into()), n, 0.0, tmax)
    }

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

    /// Exact unsigned distance from `p` to the surface (nearest-triangle BVH search).
    pub fn distance(&self, p: Vec3) -> f32 {
        self.distance_within(p, f32::INFINITY)
    }

    /// min(distance to the surface, `limit`): the search skips every node farther than
    /// `limit`, which near the surface prunes most of the tree from the start.
    pub fn distance_within(&self, p: Vec3, limit: f32) -> f32 {
        self.distance_search(p, limit).distance
    }

    /// [`Geometry::distance_within`] with what the search took: how many nodes it
    /// opened (what a search nearby will cost) and whether the distance is exact (a tree
    /// too deep for the stack gives a lower bound; with a finite `limit`, exact means
    /// min(distance, limit)).
    #[inline]
    pub(crate) fn distance_search(&self, p: Vec3, limit: f32) -> DistanceSearch {
        let nodes = &self.bvh.nodes;
        let mut search = DistanceSearch {
            distance: limit,
            exact: true,
            opened: 0,
        };
        if nodes.is_empty() {
            return search;
        }
        let pa = Vec3A::from(p);
        let box_d2 = |i: usize| {
            let b = &nodes[i].aabb;
            let q = pa.clamp(from_arr(b.min), from_arr(b.max));
            (q - pa).length_squared()
        };
        let mut best = limit * limit;
        // A BVH2 of up to 2^64 leaves needs at most 64 pending nodes (depth-first, one
        // sibling pushed per level); a fixed array keeps the query allocation-free.
        let mut stack = [0usize; 64];
        let mut top = 1usize;
        while top > 0 {
            top -= 1;
            let i = stack[top];
            if box_d2(i) >= best {
                continue;
            }
            let n = &nodes[i];
            search.opened += 1;
            if n.prim_count > 0 {
                for k in n.first_index..n.first_index + n.prim_count {
                    best = best.min(self.triangle_d2(pa, self.bvh.primitive_indices[k as usize]));
                }
            } else {
                let (a, b) = (n.first_index as usize, n.first_index as usize + 1);
                let (da, db) = (box_d2(a), box_d2(b));
                // Visit the nearer child first: push it last.
                let (near, far) = if da < db { (a, b) } else { (b, a) };
                if top + 2 > stack.len() {
                    // Deeper than any balanced tree: a bound below the distance, from the
                    // boxes of both children and of every node still pending.
                    let pending = stack[..top].iter().map(|&j| box_d2(j));
                    let floor = pending.fold(da.min(db), f32::min);
                    search.distance = best.min(floor).sqrt();
                    search.exact = false;
                    return search;
                }
                stack[top] = far;
                stack[top + 1] = near;
                top += 2;
            }
        }
        search.distance = best.sqrt();
        search
    }

    /// Appends to `out` every triangle within `radius` of `p` (a BVH range query), with its
    /// squared distance (what a caller sorting them would compute again); false, with
    /// `out` incomplete, once it would hold more than `most` (a caller that only wants a
    /// short list stops paying for a long one).
    pub(crate) fn triangles_within(
        &self,
        p: Vec3,
        radius: f32,
        out: &mut Vec<(f32, u32)>,
        most: usize,
    ) -> bool {
        let nodes = &self.bvh.nodes;
        if nodes.is_empty() {
            return true;
        }
        let pa = Vec3A::from(p);
        let r2 = radius * radius;
        let mut stack = vec![0usize];
        while let Some(i) = stack.pop() {
            let n = &nodes[i];
            let q = pa.clamp(from_arr(n.aabb.min), from_arr(n.aabb.max));
            if (q - pa).length_squared() > r2 {
                continue;
            }
            if n.prim_count > 0 {
                for k in n.first_index..n.first_index + n.prim_count {
                    let prim = self.bvh.primitive_indices[k as usize];
                    let d2 = self.triangle_d2(pa, prim);
                    if d2 <= r2 {
                        if out.len() >= most {
                            return false;
                        }
                        out.push((d2, prim));
                    }
                }
            } else {
                stack.extend([n.first_index as usize, n.first_index as usize + 1]);
            }
        }
        true
    }

    /// Distance from `p` to the nearest of the triangles `prims`, best listed nearest
    /// first: a candidate whose plane or bounding sphere is already farther than the
    /// nearest found so far needs no exact distance (~9 candidates a cell near the
    /// bunny's surface, of which the first is usually the nearest). The bounds skip a
    /// triangle only when, less `slack`, they exceed the best squared distance by 1e-5
    /// relative, so the result is the exact minimum over `prims`. The slack is their
    /// rounding: the plane's n·p − n·a and the sphere's centre are rounded at the scale
    /// of the coordinates, not of the distance (~2^-22 of them), and without it a
    /// bound 6 ulps above the truth skipped the nearest of two triangles 0.011 from a
    /// point at coordinates ~2.6 on the torus knot.
    #[inline]
    pub fn nearest_of(&self, p: Vec3, prims: &[u32]) -> f32 {
        let pa = Vec3A::from(p);
        let mut best = f32::INFINITY;
        let slack = 1e-6 * (p.abs().max_element() + self.coords);
        for &prim in prims {
            let b = &self.bounds[prim as usize];
            let plane = (b[0] * p.x + b[1] * p.y + b[2] * p.z - b[3]).abs();
            let sphere = Vec3::new(b[4], b[5], b[6]).distance(p) - b[7];
            let bound = (plane.max(sphere) - slack).max(0.0);
            if bound * bound > best * (1.0 + 1e-5) {
                continue;
            }
            best = best.min(self.triangle_d2(pa, prim));
        }
        best.sqrt()
    }

    #[inline]
    pub(crate) fn triangle_d2(&self, p: Vec3A, prim: u32) -> f32 {
        let t = &self.tris[prim as usize];
        let n = Vec3A::from(self.normals[prim as usize]);
        point_triangle_d2(p, from_arr(t.v0), from_arr(t.v1), from_arr(t.v2), n)
    }

    /// Whether `p` is inside the closed mesh: the majority of the parities of crossings
    /// along three rays, so that one ray grazing an edge or a vertex (and counting a
    /// crossing too many or too few) does not decide.
    pub fn inside(&self, p: Vec3) -> bool {
        // Irrational-ish directions avoid grazing edges of axis-aligned meshes.
        let dirs = [
            Vec3::new(0.5773, 0.5774, 0.5775),
            Vec3::new(-0.6133, 0.2871, -0.7358),
            Vec3::new(0.1429, -0.9217, 0.3606),
        ];
        dirs.iter()
            .filter(|d| self.inside_along(p, d.normalize()))
            .count()
            >= 2
    }

    /// Whether the crossings of the ray from `p` along `dir` put `p` inside: an odd
    /// number of them, or where pieces overlap, [`Geometry::in_union`] (one traversal: a
    /// closest-hit walk steps past the second of two faces in one plane, and took a camera
    /// outside two boxes whose faces share planes for one inside).
    fn inside_along(&self, p: Vec3, dir: Vec3) -> bool {
        if let Some(pieces) = &self.pieces {
            return self.in_union(pieces, p, dir);
        }
        let mut o = p;
        let mut crossings = 0u32;
        for _ in 0..10_000 {
            match self.intersect(o, dir, f32::INFINITY) {
                Some(h) => {
                    crossings += 1;
                    o = self.spawn(o + dir * h.t, h.normal, dir);
                }
                None => break,
            }
        }
        crossings % 2 == 1
    }
}

/// What [`Geometry::distance_search`] found and what it took.
#[derive(Clone, Copy, Debug)]
pub(crate) struct DistanceSearch {
    pub(crate) distance: f32,
    /// False where the tree was too deep for the search's stack: `distance` is then a
    /// lower bound.
    pub(crate) exact: bool,
    /// BVH nodes opened.
    pub(crate) opened: u32,
}

/// Squared distance from `p` to triangle (a, b, c) whose unit normal `n` is that of
/// (b − a) × (c − a) (computed in f64: [`Geometry::normals`]).
///
/// Ericson's Voronoi-region test (Real-Time Collision Detection §5.1.5) decides by
/// differences of products of dot products, which in f32 lose their precision on long thin
/// triangles: it put points over the face into an edge's region and overestimated their
/// distance (by 45 eps just inside a 1,000-segment cylinder's side), so balls reached
/// beyond the surface and paths leaked (2.9 % of them there). Here which side of each edge
/// the point lies is the edge function n·(e × (p − v)), whose rounding is ~ε·|e|·|p − v|
/// however thin the triangle; a point over the face, within a tolerance that errs towards
/// "over" (where the plane's distance is still a lower bound), gets its distance to the
/// plane, any other its distance to the nearest edge. So the result never exceeds the true
/// distance by more than f32 rounding at the scale of |p − v|. scene.wgsl does the same.
pub fn point_triangle_d2(p: Vec3A, a: Vec3A, b: Vec3A, c: Vec3A, n: Vec3A) -> f32 {
    let (ab, bc, ca) = (b - a, c - b, a - c);
    // For each edge: whether the point is on the face's side of its line (within the
    // tolerance), and whether beyond the line or within the tolerance of it.
    let side = |v: Vec3A, e: Vec3A| {
        let vp = p - v;
        let s = n.dot(e.cross(vp));
        let near =
            s * s <= EDGE_TOLERANCE * EDGE_TOLERANCE * e.length_squared() * vp.length_squared();
        // (A NaN, from a triangle of no area, which `mesh::prepare` drops, measures every
        // edge: the exact distance to the segments.)
        (s >= 0.0 || near, s < 0.0 || s.is_nan() || near)
    };
    let ((oa, ma), (ob, mb), (oc, mc)) = (side(a, ab), side(b, bc), side(c, ca));
    if oa && ob && oc {
        let h = n.dot(p - a);
        return h * h;
    }
    // Beside the face, the nearest point lies on an edge whose line the point is beyond or
    // on (the face is convex): those within the tolerance of their line count too,
    // whichever side rounding put the point, or an edge next to a vertex of nearly 180°
    // (a fan's rim) was left out and the distance overestimated 150-fold.
    let edge = |measure: bool, v: Vec3A, e: Vec3A| {
        if !measure {
            return f32::INFINITY;
        }
        let vp = p - v;
        let t = (vp.dot(e) / e.length_squared().max(f32::MIN_POSITIVE)).clamp(0.0, 1.0);
        (vp - e * t).length_squared()
    };
    edge(ma, a, ab).min(edge(mb, b, bc)).min(edge(mc, c, ca))
}

/// How far outside an edge, in-plane and relative to the point's distance from the edge's
/// start, a point still counts as over the face in [`point_triangle_d2`]: beyond the edge
/// function's f32 rounding (~4·6·10⁻⁸), so that no point over the face is taken for one
/// beside it (which would overestimate its distance); one beside it taken for over gets
/// the plane's distance, a lower bound. The WGSL kernels take it from here.
pub const EDGE_TOLERANCE: f32 = 4e-6;

#[cfg(test)]
mod tests {
    use super::*;
    use scatter_sim::rng::WalkRng;

    /// The capped range query: a cap at the count lists them all, one below stops with
    /// false, 0 stops at the first. Every face of a unit cube is 0.5 from its centre, so
    /// all 12 triangles are within 1 of it.
    #[test]
    fn a_capped_range_query_stops_past_its_cap() {
        let geo = Geometry::new(crate::mesh::cube(1.0));
        let (centre, reach) = (Vec3::ZERO, 1.0);
        let mut all = Vec::new();
        assert!(geo.triangles_within(centre, reach, &mut all, usize::MAX));
        assert_eq!(all.len(), 12);
        let mut list = Vec::new();
        assert!(geo.triangles_within(centre, reach, &mut list, 12));
        assert_eq!(list.len(), 12);
        for most in [0, 11] {
            list.clear();
            assert!(!geo.triangles_within(centre, reach, &mut list, most));
            assert_eq!(list.len(), most);
        }
    }

    fn bunny() -> Geometry {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../assets/bunny.glb");
        let mut m = crate::mesh::load_mesh(&path).expect("the shipped bunny");
        m.normalise_height(1.0).expect("a bunny of some height");
        Geometry::new(m)
    }

    /// The 8-wide tree (the CPU's casts) against the binary one (the fallback for deep
    /// trees; the tree the GPU kernels traverse), an independent traversal of the same
    /// triangles: the same closest hit and the same crossing sums for 20,000 random rays
    /// from inside and around the bunny and 20,000 leaving or about to meet its surface,
    /// short and unbounded, and for rays along the six
    /// axes with every sign of zero in their other components (−0 made obvhs's wide node
    /// test miss every box: a light shining straight down went unshadowed).
    #[test]
    fn wide_and_binary_trees_cast_alike() {
        let wide = bunny();
        let depth = wide_depth(wide.cwbvh.as_ref().expect("the bunny's wide tree is used"));
        assert!(depth <= MAX_WIDE_DEPTH, "depth {depth}");
        let mut binary = bunny();
        binary.cwbvh = None;
        let mut rng = WalkRng::for_walk(3, 0);
        let mut u = || rng.uniform() as f32;
        let mut rays = Vec::new();
        for _ in 0..20_000 {
            let o = wide.lo + (wide.hi - wide.lo) * Vec3::new(u(), u(), u()) * 1.2
                - (wide.hi - wide.lo) * 0.1;
            let d = Vec3::new(u() - 0.5, u() - 0.5, u() - 0.5).normalize_or(Vec3::Z);
            let tmax = if u() < 0.5 { f32::INFINITY } else { 0.05 * u() };
            rays.push((o, d, tmax));
        }
        // Rays spawned on the surface and rays that meet it within 10⁻⁴, as flights and
        // shadow rays near it do: the wide tree's node test skips boxes entered that
        // close to the origin (`cw_back`).
        for k in 0..20_000 {
            let prim = ((u() * wide.tris.len() as f32) as usize).min(wide.tris.len() - 1);
            let t = &wide.tris[prim];
            let (a, b, c) = (
                Vec3::from_array(t.v0.into()),
                Vec3::from_array(t.v1.into()),
                Vec3::from_array(t.v2.into()),
            );
            let (x, y) = (u(), u());
            let (x, y) = if x + y > 1.0 {
                (1.0 - x, 1.0 - y)
            } else {
                (x, y)
            };
            let p = a + (b - a) * x + (c - a) * y;
            let d = Vec3::new(u() - 0.5, u() - 0.5, u() - 0.5).normalize_or(Vec3::Z);
            let tmax = if k % 2 == 0 {
                f32::INFINITY
            } else {
                1e-3 * u()
            };
            // Leaving the surface, or meeting it within 10⁻⁴.
            let o = if k % 4 < 2 {
                wide.spawn(p, wide.normals[prim], d)
            } else {
                p - d * (1e-4 * u())
            };
            rays.push((o, d, tmax));
        }
        let centre = (wide.lo + wide.hi) * 0.5;
        for axis in 0..3 {
            for sign in [1.0f32, -1.0] {
                for zeros in [0.0f32, -0.0] {
                    let mut d = Vec3::splat(zeros);
                    d[axis] = sign;
                    rays.push((centre, d, f32::INFINITY));
                }
            }
        }
        let mut hits = 0;
        for &(o, d, tmax) in &rays {
            let (a, b) = (wide.intersect(o, d, tmax), binary.intersect(o, d, tmax));
            match (a, b) {
                (Some(a), Some(b)) => {
                    assert_eq!(a.t, b.t, "ray {o} {d}: {a:?} vs {b:?}");
                    hits += 1;
                }
                (None, None) => {}
                _ => panic!("ray {o} {d} (tmax {tmax}): {a:?} vs {b:?}"),
            }
            let (a, b) = (
                wide.inside_length(o, d, |_, _| 1.0),
                binary.inside_length(o, d, |_, _| 1.0),
            );
            match (a, b) {
                (Some((la, _)), Some((lb, _))) => {
                    assert!(
                        (la - lb).abs() <= 1e-5 * la.max(1e-3),
                        "ray {o} {d}: {la} vs {lb}"
                    )
                }
                (None, None) => {}
                _ => panic!("ray {o} {d}: crossings {a:?} vs {b:?}"),
            }
        }
        assert!(hits > 2_000, "{hits} hits");
        // The axis rays from the centre are inside the bunny and all leave it.
        for &(o, d, _) in &rays[rays.len() - 12..] {
            assert!(
                wide.intersect(o, d, f32::INFINITY).is_some(),
                "axis ray {d} missed"
            );
            assert!(
                wide.inside_length(o, d, |_, _| 1.0).is_some(),
                "axis ray {d}"
            );
        }
        eprintln!("wide tree depth {depth}, {hits} hits of {}", rays.len());
    }
}
