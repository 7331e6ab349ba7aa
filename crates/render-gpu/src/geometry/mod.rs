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
use obvhs::triangle::Triangle;
use obvhs::{Boundable, BvhBuildParams};

use crate::mesh::TriMesh;
use crate::watertight::RayShear;

mod distance;
mod rays;
mod spawn;

pub use distance::{EDGE_TOLERANCE, point_triangle_d2};

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
}

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
