//! Distance queries through the binary BVH (what the sphere steps' free balls and the
//! distance grid are built on), and inside/outside tests.

use glam::{Vec3, Vec3A};

use super::{Geometry, from_arr};

impl Geometry {
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
