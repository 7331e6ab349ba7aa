//! How the closed pieces of a mesh lie against each other: which pieces are around a
//! point, asked along a tree over all triangles, at probe points spread over each piece
//! and placed where pieces' surfaces cross. [`crate::mesh`] reads from it which pieces
//! overlap and how deeply each is nested.
//!
//! A point's side of a piece is counted along rays (the parity of the piece's faces
//! crossed), six of them; they must agree, and a point within `touch` of one of the
//! piece's faces along any of them is on its surface, where no side is defined. Asked of
//! every triangle by winding numbers (the first version), the cost was probes × triangles:
//! 14 s to set up 16 overlapping spheres of 189,000 triangles in all.

use glam::{DVec3, Vec3};
use obvhs::BvhBuildParams;
use obvhs::aabb::Aabb;
use obvhs::bvh2::Bvh2;
use obvhs::bvh2::builder::{build_bvh2, build_bvh2_from_tris};
use obvhs::ray::Ray;
use obvhs::triangle::Triangle;
use rayon::prelude::*;

use crate::mesh::TriMesh;

/// How close (relative to the mesh's scale, [`crate::mesh::TriMesh::scale`]) two pieces'
/// surfaces count as touching rather than crossing; `crate::thin_walls` takes faces
/// closer than this to the entry plane for a touching piece's too.
pub(crate) const TOUCH_OF_SCALE: f32 = 1e-6;

/// Most probes kept per piece from the points along its edges between meetings with other
/// pieces' faces, and most meetings of other pieces' edges with its faces (six probes
/// around each): spread evenly over those found.
const EDGE_PROBES: usize = 128;
const FACE_MEETINGS: usize = 32;
/// Sampled probes per piece: this many of its vertices, and on this many of its triangles
/// the centroid and three points halfway from it to the edges' midpoints.
const SAMPLED: usize = 64;

/// The rays' directions: three lines, both ways, about at right angles to each other, so
/// that every plane is crossed by one of them at |cos| ≥ 0.5: a point on a face is met by
/// that line's rays within touch along them (with two lines, a floor whose plane held
/// both was only grazed, its contact ~1e-7 off taken as a crossing far along the rays).
/// Irrational-ish, so that they rarely pass through an axis-aligned mesh's edges; a ray
/// that does counts a face twice and disagrees with the others.
fn directions() -> [DVec3; 6] {
    let a = DVec3::new(0.2677, 0.5345, 0.8018).normalize();
    let b = a.cross(DVec3::new(0.9134, -0.2233, 0.3402)).normalize();
    let c = a.cross(b);
    [a, -a, b, -b, c, -c]
}

/// What one edge's traversal found: its piece, the midpoints along it between meetings
/// with other pieces' faces, and the meetings (triangle, point).
struct EdgeFindings {
    piece: u32,
    mids: Vec<DVec3>,
    meetings: Vec<(usize, DVec3)>,
}

pub(crate) struct Survey<'a> {
    m: &'a TriMesh,
    pieces: &'a [Vec<usize>],
    piece_of: Vec<u32>,
    bvh: Bvh2,
    /// Each piece's bounding box (grown by touch), and a tree over them: only pieces
    /// whose box holds a point can be around it, and its rays need go no farther than
    /// those boxes. Rays run to infinity through every piece met took 9 s for a grid of
    /// 10,000 cubes.
    bounds: Vec<Aabb>,
    boxes: Bvh2,
    /// A millionth of the mesh's size (or of its coordinates' magnitude, if larger): far
    /// above f32 rounding, far below any real overlap; points closer than this to a
    /// surface are on it.
    touch: f64,
}

/// What is known of a probe against each piece: Some(true) inside, Some(false) outside,
/// None on its surface or undecided. Only the pieces whose faces its rays met are listed
/// (sorted, without the outside ones); every other piece is outside. A list of every
/// piece per probe made a mesh of 10,000 cubes hold 5.5 GB.
pub(crate) struct Sides(Vec<(u32, Option<bool>)>);

impl Sides {
    /// The probe's side of piece j.
    pub(crate) fn of(&self, j: usize) -> Option<bool> {
        match self.0.binary_search_by_key(&(j as u32), |e| e.0) {
            Ok(k) => self.0[k].1,
            Err(_) => Some(false),
        }
    }

    /// The pieces the probe is inside or on the surface of (undecided), with which.
    pub(crate) fn listed(&self) -> impl Iterator<Item = (usize, Option<bool>)> + '_ {
        self.0.iter().map(|&(j, v)| (j as usize, v))
    }
}

impl<'a> Survey<'a> {
    pub(crate) fn new(m: &'a TriMesh, pieces: &'a [Vec<usize>]) -> Self {
        let mut piece_of = vec![0u32; m.triangles.len()];
        for (k, tris) in pieces.iter().enumerate() {
            for &t in tris {
                piece_of[t] = k as u32;
            }
        }
        // Relative to the coordinates' size as well as the mesh's: f32 positions far from
        // the origin round by more than a millionth of a small mesh (a contact at 1,000
        // from the origin was taken as a crossing).
        let touch = TOUCH_OF_SCALE * m.scale().max(f32::MIN_POSITIVE);
        let tris: Vec<Triangle> = (0..m.triangles.len())
            .map(|i| {
                let [a, b, c] = m.triangle(i).map(|v| v.to_array().into());
                Triangle {
                    v0: a,
                    v1: b,
                    v2: c,
                }
            })
            .collect();
        let mut bvh = build_bvh2_from_tris(
            &tris,
            BvhBuildParams::fast_build(),
            &mut std::time::Duration::default(),
        );
        // A face in an axis plane has a flat box, which the slab test can miss by
        // rounding; the padding also keeps faces just behind a ray's origin in reach.
        for node in &mut bvh.nodes {
            node.aabb.min -= touch;
            node.aabb.max += touch;
        }
        let bounds: Vec<Aabb> = pieces
            .iter()
            .map(|tris| {
                let mut b = Aabb::empty();
                for &t in tris {
                    for v in m.triangle(t) {
                        b.extend(v.to_array().into());
                    }
                }
                Aabb::new(b.min - touch, b.max + touch)
            })
            .collect();
        let boxes = build_bvh2(
            &bounds,
            BvhBuildParams::fast_build(),
            &mut std::time::Duration::default(),
        );
        Self {
            m,
            pieces,
            piece_of,
            bvh,
            bounds,
            boxes,
            touch: touch as f64,
        }
    }

    fn corners(&self, t: usize) -> [DVec3; 3] {
        self.m.triangles[t].map(|k| self.m.positions[k as usize].as_dvec3())
    }

    /// Where the line p + s·d meets triangle t (Möller and Trumbore's test in f64, its
    /// edges included), if it does.
    fn meets(&self, p: DVec3, d: DVec3, t: usize) -> Option<f64> {
        let [x, y, z] = self.corners(t);
        let (e1, e2) = (y - x, z - x);
        let pv = d.cross(e2);
        let det = e1.dot(pv);
        if det == 0.0 {
            return None;
        }
        let tv = p - x;
        let u = tv.dot(pv) / det;
        let qv = tv.cross(e1);
        let v = d.dot(qv) / det;
        (u >= 0.0 && v >= 0.0 && u + v <= 1.0).then(|| e2.dot(qv) / det)
    }

    /// Each piece's side of `p` (see the module's doc) but piece `own`'s, the one p is a
    /// probe of (p is on its surface; listed as outside).
    pub(crate) fn sides(&self, p: DVec3, own: usize) -> Sides {
        let origin = p.as_vec3();
        let at = origin.to_array();
        // The pieces whose box holds p, sorted.
        let mut near: Vec<u32> = Vec::new();
        self.boxes.point_traverse(at.into(), |b, node| {
            let node = &b.nodes[node as usize];
            for k in node.first_index..node.first_index + node.prim_count {
                let j = b.primitive_indices[k as usize];
                if j as usize != own && self.bounds[j as usize].contains_point(at.into()) {
                    near.push(j);
                }
            }
            true
        });
        if near.is_empty() {
            return Sides(Vec::new());
        }
        near.sort_unstable();
        // (piece, ray, on its surface) for each face met.
        let mut met: Vec<(u32, usize, bool)> = Vec::new();
        for (r, d) in directions().into_iter().enumerate() {
            // To the farthest exit from the near pieces' boxes.
            let reach = near
                .iter()
                .map(|&j| {
                    let b = &self.bounds[j as usize];
                    (0..3)
                        .filter(|&a| d[a] != 0.0)
                        .map(|a| {
                            let wall = if d[a] > 0.0 { b.max[a] } else { b.min[a] };
                            (wall as f64 - p[a]) / d[a]
                        })
                        .fold(f64::INFINITY, f64::min)
                })
                .fold(0.0f64, f64::max);
            let ray = Ray::new(
                origin.to_array().into(),
                d.as_vec3().to_array().into(),
                0.0,
                (reach + self.touch) as f32,
            );
            self.bvh.ray_traverse_anyhit(ray, |_, id| {
                let t = self.bvh.primitive_indices[id] as usize;
                if near.binary_search(&self.piece_of[t]).is_err() {
                    return;
                }
                let Some(s) = self.meets(p, d, t) else {
                    return;
                };
                let on = s.abs() < self.touch;
                if on || s > 0.0 {
                    met.push((self.piece_of[t], r, on));
                }
            });
        }
        met.sort_unstable();
        let mut listed = Vec::new();
        for group in met.chunk_by(|a, b| a.0 == b.0) {
            let mut parity = [false; 6];
            let mut on = false;
            for &(_, r, o) in group {
                on |= o;
                parity[r] ^= !o;
            }
            let agree = parity.iter().all(|&x| x == parity[0]);
            let side = (!on && agree).then_some(parity[0]);
            if side != Some(false) {
                listed.push((group[0].0, side));
            }
        }
        Sides(listed)
    }

    /// Each piece's probes with their sides of every piece: sampled ones, and those where
    /// pieces' surfaces cross ([`Self::crossing_probes`]).
    pub(crate) fn classified_probes(&self) -> Vec<Vec<Sides>> {
        let crossing = self.crossing_probes();
        self.pieces
            .iter()
            .zip(crossing)
            .enumerate()
            .map(|(i, (tris, extra))| {
                let probes: Vec<DVec3> = self.sampled(tris).into_iter().chain(extra).collect();
                probes.par_iter().map(|&p| self.sides(p, i)).collect()
            })
            .collect()
    }

    /// Up to [`SAMPLED`] of a piece's vertices, and on as many of its triangles the
    /// centroid and three points halfway from it to the edges' midpoints. Two boxes whose
    /// faces lie in one plane overlap with every vertex on the other's surface, but some
    /// face points inside it; two bars crossing in a plus sign have every vertex and
    /// centroid outside the other (each long face's middle is inside the other bar: the
    /// points at barycentric (½, ¼, ¼) reach it).
    fn sampled(&self, tris: &[usize]) -> Vec<DVec3> {
        let m = self.m;
        let mut v: Vec<u32> = tris.iter().flat_map(|&t| m.triangles[t]).collect();
        v.sort_unstable();
        v.dedup();
        let every = |n: usize| n.div_ceil(SAMPLED).max(1);
        let vertices = v
            .iter()
            .step_by(every(v.len()))
            .map(|&i| m.positions[i as usize].as_dvec3());
        let faces = tris.iter().step_by(every(tris.len())).flat_map(|&t| {
            let [a, b, c] = self.corners(t);
            [
                (a + b + c) / 3.0,
                0.5 * a + 0.25 * (b + c),
                0.5 * b + 0.25 * (c + a),
                0.5 * c + 0.25 * (a + b),
            ]
        });
        vertices.chain(faces).collect()
    }

    /// Probes on each piece where other pieces' surfaces cross it, which sampled probes
    /// can all miss (a thin rod through a plate; a ball whose cap pokes out of a box; a
    /// pocket of one piece dipping through a face of another):
    /// - along each of its edges, the midpoints between consecutive meetings with other
    ///   pieces' faces (the edge's ends included; meetings closer than 2·touch leave
    ///   none between them), which lie off every surface: on a plate's grid a rod's
    ///   edges meet the plate only at its vertices, yet the midpoint between is inside;
    /// - around each point where another piece's edge meets one of its faces, six points
    ///   on that face (at half the distance to its nearest edge), some on each side of
    ///   the other piece's surface.
    fn crossing_probes(&self) -> Vec<Vec<DVec3>> {
        let m = self.m;
        let n = self.pieces.len();
        let mut edges: Vec<(u32, u32, u32)> = m
            .triangles
            .iter()
            .zip(&self.piece_of)
            .flat_map(|(t, &k)| {
                (0..3).map(move |e| {
                    let (a, b) = (t[e], t[(e + 1) % 3]);
                    (a.min(b), a.max(b), k)
                })
            })
            .collect();
        edges.sort_unstable();
        edges.dedup();
        let at = |i: u32| m.positions[i as usize].as_dvec3();
        let found: Vec<EdgeFindings> = edges
            .par_iter()
            .filter_map(|&(a, b, k)| {
                let (p, q) = (at(a), at(b));
                let (pa, pb): (Vec3, Vec3) = (m.positions[a as usize], m.positions[b as usize]);
                let ray = Ray::new(pa.to_array().into(), (pb - pa).to_array().into(), 0.0, 1.0);
                let mut hits: Vec<(f64, usize)> = Vec::new();
                self.bvh.ray_traverse_anyhit(ray, |_, id| {
                    let t = self.bvh.primitive_indices[id] as usize;
                    if self.piece_of[t] != k
                        && let Some(s) = self.meets(p, q - p, t)
                        && (0.0..=1.0).contains(&s)
                    {
                        hits.push((s, t));
                    }
                });
                if hits.is_empty() {
                    return None;
                }
                hits.sort_by(|x, y| x.0.total_cmp(&y.0));
                let gap = 2.0 * self.touch / (q - p).length().max(f64::MIN_POSITIVE);
                let mut mids = Vec::new();
                let mut last = 0.0;
                for s in hits.iter().map(|h| h.0).chain([1.0]) {
                    if s - last > gap {
                        mids.push(p + (q - p) * (0.5 * (last + s)));
                        last = s;
                    }
                }
                let meetings = hits.iter().map(|&(s, t)| (t, p + (q - p) * s)).collect();
                Some(EdgeFindings {
                    piece: k,
                    mids,
                    meetings,
                })
            })
            .collect();
        let mut along: Vec<Vec<DVec3>> = vec![Vec::new(); n];
        let mut met: Vec<Vec<(usize, DVec3)>> = vec![Vec::new(); n];
        for EdgeFindings {
            piece,
            mids,
            meetings,
        } in found
        {
            along[piece as usize].extend(mids);
            for (t, x) in meetings {
                met[self.piece_of[t] as usize].push((t, x));
            }
        }
        along
            .into_iter()
            .zip(met)
            .map(|(mids, meetings)| {
                let mut probes: Vec<DVec3> = mids
                    .iter()
                    .step_by(mids.len().div_ceil(EDGE_PROBES).max(1))
                    .copied()
                    .collect();
                for &(t, x) in meetings
                    .iter()
                    .step_by(meetings.len().div_ceil(FACE_MEETINGS).max(1))
                {
                    probes.extend(self.around_on_face(t, x));
                }
                probes
            })
            .collect()
    }

    /// Six points on triangle t around x (a point of t), at half the distance from x to
    /// t's nearest edge; none where x is within 4·touch of an edge.
    fn around_on_face(&self, t: usize, x: DVec3) -> Vec<DVec3> {
        let [a, b, c] = self.corners(t);
        let normal = (b - a).cross(c - a);
        if normal.length_squared() == 0.0 {
            return Vec::new();
        }
        let normal = normal.normalize();
        let to_edge = [(a, b), (b, c), (c, a)]
            .iter()
            .map(|&(u, v)| (v - u).cross(x - u).dot(normal) / (v - u).length())
            .fold(f64::INFINITY, f64::min);
        if !(to_edge > 4.0 * self.touch) {
            return Vec::new();
        }
        let r = 0.5 * to_edge;
        let u = (b - a).normalize();
        let v = normal.cross(u);
        (0..6)
            .map(|k| {
                let phi = std::f64::consts::PI / 3.0 * k as f64;
                x + r * (phi.cos() * u + phi.sin() * v)
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use glam::{DVec3, Vec3};

    use super::Survey;
    use crate::mesh::TriMesh;

    /// An open surface above a point (piece 1: a large triangle at z = 1, and a small one
    /// far off at z = −1 so that the piece's box holds the point): rays a, −b and −c cross
    /// it once, −a, b and c never. Rays that disagree leave the side undecided, rather
    /// than ray a's answer standing for all.
    #[test]
    fn rays_that_disagree_leave_the_side_undecided() {
        let v = Vec3::new;
        let m = TriMesh {
            positions: vec![
                v(-0.1, -0.1, 0.0),
                v(0.1, -0.1, 0.0),
                v(0.0, 0.1, 0.0),
                v(-100.0, -100.0, 1.0),
                v(100.0, -100.0, 1.0),
                v(0.0, 100.0, 1.0),
                v(50.0, 50.0, -1.0),
                v(51.0, 50.0, -1.0),
                v(50.0, 51.0, -1.0),
            ],
            triangles: vec![[0, 1, 2], [3, 4, 5], [6, 7, 8]],
        };
        let pieces = vec![vec![0], vec![1, 2]];
        let survey = Survey::new(&m, &pieces);
        assert_eq!(survey.sides(DVec3::ZERO, 0).of(1), None);
    }
}
