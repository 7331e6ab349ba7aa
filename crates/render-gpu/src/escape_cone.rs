//! Escape cones: per triangle, the directions about its outward normal in which a ray
//! leaving the surface from anywhere on the triangle meets the mesh nowhere.
//!
//! Every path that leaves the medium casts one ray to find out whether it meets the object
//! again. For ST-CVAE that cast is one of only ~5 rays a path casts, and skipping all of
//! them made it 10–12 % faster on the bunny (PT: one ray in 35–230). A path leaving
//! through a triangle inside that triangle's cone has escaped for certain, so its cast can
//! be skipped without changing any path's outcome (the test below is conservative, not a
//! heuristic).
//!
//! The region swept by such rays: a ray from p ∈ T along w with angle(w, n) ≤ θ reaches
//! height h above T's plane within lateral distance h·tan θ of p, so every point of it lies
//! in R(θ) = {q : h(q) ≥ h₀, q projected to the plane ∈ T ⊕ disk(h(q)·tan θ)}. The disk is
//! enclosed in a regular octagon, which makes R(θ) an intersection of 12 half-spaces (the
//! Minkowski sum of two convex polygons has the edge normals of both); a triangle meets it
//! iff clipping the triangle by the 12 planes leaves something. R grows with θ, so the
//! largest free θ of a list is found by bisection, each test a BVH walk that skips boxes
//! outside one of the planes.

use glam::{DVec2, DVec3};
use rayon::prelude::*;

use crate::geometry::Geometry;

/// Candidate tan θ of a cone, ascending (θ from 11° to 72°).
const TANS: [f64; 8] = [0.2, 0.4, 0.6, 0.8, 1.0, 1.4, 2.0, 3.0];
/// cos θ of a triangle without a cone: no unit direction has w·n above it.
pub const NO_CONE: f32 = 2.0;

/// A half-space m·q ≤ d.
type Plane = (DVec3, f64);

const MAGIC: &[u8; 8] = b"STCVEC02";

/// [`escape_cosines`], from the cache directory of the distance grids when a run before
/// has computed them for the same mesh. They cost ~17 µs a triangle on 2 cores (55 ms for
/// the bunny, ~1 s for 60,000 triangles), so results that took over 0.1 s are cached.
pub fn cached(geo: &Geometry) -> Vec<f32> {
    // The tag keeps cones apart from grids; the file's name also holds a hash of the code
    // (`cache_file`), so a change to TANS, the margins or the region is never read stale.
    let key = crate::cache::mesh_hasher(geo, b"escape-cones-v2").finish();
    let path = crate::cache::cache_file(&format!("cones-{key:016x}"));
    cached_at(geo, key, path.as_deref(), crate::cache::CACHED_FROM_SECONDS)
}

/// [`cached`] with the cache entry at `path` (None: no cache) under key `key`, new results
/// cached when they took over `cached_from` seconds.
fn cached_at(
    geo: &Geometry,
    key: u64,
    path: Option<&std::path::Path>,
    cached_from: f64,
) -> Vec<f32> {
    let Ok(cos) = crate::cache::read_or_build(
        path,
        cached_from,
        |p| read(p, key, geo.tris.len()),
        || Ok::<_, std::convert::Infallible>(escape_cosines(geo)),
        |p, cos| write(p, key, cos),
    );
    cos
}

fn write(path: &std::path::Path, key: u64, cos: &[f32]) -> std::io::Result<()> {
    let mut bytes = MAGIC.to_vec();
    bytes.extend_from_slice(&key.to_le_bytes());
    bytes.extend_from_slice(&(cos.len() as u32).to_le_bytes());
    for c in cos {
        bytes.extend_from_slice(&c.to_le_bytes());
    }
    bytes.extend_from_slice(&crc32fast::hash(&bytes).to_le_bytes());
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir)?;
    }
    scatter_sim::output::write_atomic(path, &bytes)
}

/// Cached cosines for `n` triangles under cache key `key` (held in the file too, so that
/// another mesh's file copied under this name is a miss); anything unexpected means
/// "compute them" (None).
fn read(path: &std::path::Path, key: u64, n: usize) -> Option<Vec<f32>> {
    // Anything but a regular file (a named pipe blocked, /dev/zero filled memory) is a miss.
    scatter_sim::output::check_input(path).ok()?;
    let b = std::fs::read(path).ok()?;
    if b.len() != 24 + 4 * n || &b[..8] != MAGIC {
        return None;
    }
    let (body, crc) = b.split_at(b.len() - 4);
    if crc32fast::hash(body) != u32::from_le_bytes(crc.try_into().ok()?)
        || u64::from_le_bytes(body[8..16].try_into().ok()?) != key
        || u32::from_le_bytes(body[16..20].try_into().ok()?) as usize != n
    {
        return None;
    }
    let cos: Vec<f32> = body[20..]
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes(c.try_into().unwrap()))
        .collect();
    // Only the values `escape_cosines` makes: a forged cosine of 0.01 (a valid CRC) would
    // let nearly every direction off its triangle skip the re-entry cast.
    let cones: Vec<u32> = (0..TANS.len()).map(|k| cone_cos(k).to_bits()).collect();
    let made = |c: f32| c == NO_CONE || cones.contains(&c.to_bits());
    cos.iter().all(|&c| made(c)).then_some(cos)
}

/// cos θ of the cone of tan θ = `TANS[k]`, made a little larger than the cone tested so
/// that rounding of w·n never lets a direction outside it in.
fn cone_cos(k: usize) -> f32 {
    (1.0 / (1.0 + TANS[k] * TANS[k]).sqrt() + 1e-6) as f32
}

/// cos θ of every triangle's escape cone ([`NO_CONE`] for none), made a little larger
/// than the cone tested so that rounding of w·n never lets a direction outside it in.
pub fn escape_cosines(geo: &Geometry) -> Vec<f32> {
    (0..geo.tris.len())
        .into_par_iter()
        .map(|t| {
            let free = |k: usize| !blocked(geo, &region(geo, t, TANS[k]));
            if !free(0) {
                return NO_CONE;
            }
            // Largest free index by bisection: free(lo) holds, free(hi) fails (or hi = end).
            let (mut lo, mut hi) = (0usize, TANS.len());
            while hi - lo > 1 {
                let mid = (lo + hi) / 2;
                if free(mid) { lo = mid } else { hi = mid }
            }
            cone_cos(lo)
        })
        .collect()
}

/// The 12 half-spaces of R(tan θ = `tan`) for triangle `t` (module docs).
fn region(geo: &Geometry, t: usize, tan: f64) -> [Plane; 12] {
    let [a, b, c] = geo.mesh.triangle(t).map(|v| v.as_dvec3());
    let n = (b - a).cross(c - a).normalize();
    let e1 = (b - a).normalize();
    let e2 = n.cross(e1);
    let centre = (a + b + c) / 3.0;
    let flat = |v: DVec3| DVec2::new((v - centre).dot(e1), (v - centre).dot(e2));
    let tri = [flat(a), flat(b), flat(c)];
    // The exit point is T's point rounded (a few ulps of the coordinates, ~1e-7 of the
    // scene's scale, which eps is 2e-5 of and which counts the distance from the origin
    // too): T is grown by δ = eps/10, ten times more. Spawned points sit eps above the
    // plane and rise from there, so nothing below half of eps can be met.
    let delta = 0.1 * geo.eps as f64;
    let h0 = 0.5 * geo.eps as f64;
    // Octagon circumscribing the unit disk: face normals at kπ/4 (support 1), vertices
    // at radius 1/cos(π/8) between them.
    let octagon_support = |u: DVec2| {
        (0..8)
            .map(|k| {
                let phi = std::f64::consts::FRAC_PI_8 + k as f64 * std::f64::consts::FRAC_PI_4;
                u.dot(DVec2::from_angle(phi)) / std::f64::consts::FRAC_PI_8.cos()
            })
            .fold(f64::MIN, f64::max)
    };
    let mut normals = [DVec2::ZERO; 11];
    for i in 0..3 {
        // Counter-clockwise seen from +n (n = (b − a) × (c − a)): outward is to the right.
        let d = tri[(i + 1) % 3] - tri[i];
        normals[i] = DVec2::new(d.y, -d.x).normalize();
    }
    for k in 0..8 {
        normals[3 + k] = DVec2::from_angle(k as f64 * std::f64::consts::FRAC_PI_4);
    }
    let mut planes = [(DVec3::ZERO, 0.0); 12];
    for (p, u) in planes.iter_mut().zip(normals) {
        let support = tri.iter().map(|v| u.dot(*v)).fold(f64::MIN, f64::max) + delta;
        let m = u.x * e1 + u.y * e2 - tan * octagon_support(u) * n;
        *p = (m, m.dot(centre) + support);
    }
    planes[11] = (-n, -(n.dot(centre) + h0));
    planes
}

/// Whether any triangle meets the region (touching counts as meeting).
fn blocked(geo: &Geometry, planes: &[Plane; 12]) -> bool {
    let nodes = &geo.bvh.nodes;
    if nodes.is_empty() {
        return false;
    }
    // The tree's boxes are grown by eps/2 (Geometry::box_growth), as much as the region's
    // floor h₀ lies above the triangle's plane, so a box of faces in that plane always
    // reached it and every face in it was clipped: a cylinder's fan cap of 4,000 slivers
    // took 19 s. Shrunk by 90 % of the growth, the boxes still hold their faces (with
    // 1e-6 of the scene to spare, far above rounding) and such boxes are skipped.
    let shrink = 0.9 * geo.box_growth() as f64;
    let mut stack = vec![0usize];
    while let Some(i) = stack.pop() {
        let node = &nodes[i];
        let (lo, hi) = (
            DVec3::from_array(node.aabb.min.to_array().map(f64::from)) + shrink,
            DVec3::from_array(node.aabb.max.to_array().map(f64::from)) - shrink,
        );
        // The box's lowest value of m·q: outside one plane entirely means disjoint.
        let outside = planes.iter().any(|(m, d)| {
            let lowest = (m.x * lo.x).min(m.x * hi.x)
                + (m.y * lo.y).min(m.y * hi.y)
                + (m.z * lo.z).min(m.z * hi.z);
            lowest > *d
        });
        if outside {
            continue;
        }
        if node.prim_count > 0 {
            for k in node.first_index..node.first_index + node.prim_count {
                let prim = geo.bvh.primitive_indices[k as usize] as usize;
                let tri = geo.mesh.triangle(prim).map(|v| v.as_dvec3());
                if meets(&tri, planes) {
                    return true;
                }
            }
        } else {
            stack.extend([node.first_index as usize, node.first_index as usize + 1]);
        }
    }
    false
}

/// Whether the triangle keeps a point after clipping by every plane.
fn meets(tri: &[DVec3; 3], planes: &[Plane; 12]) -> bool {
    // A triangle clipped by 12 planes has at most 15 vertices; rounding that would make
    // more counts as meeting (the safe answer).
    const CAP: usize = 24;
    let mut poly = [DVec3::ZERO; CAP];
    let mut next = [DVec3::ZERO; CAP];
    poly[..3].copy_from_slice(tri);
    let mut len = 3;
    for (m, d) in planes {
        let mut out = 0;
        for i in 0..len {
            let (p, q) = (poly[i], poly[(i + 1) % len]);
            let (fp, fq) = (m.dot(p) - d, m.dot(q) - d);
            if out + 2 > CAP {
                return true;
            }
            if fp <= 0.0 {
                next[out] = p;
                out += 1;
            }
            if (fp <= 0.0) != (fq <= 0.0) {
                next[out] = p + (q - p) * (fp / (fp - fq));
                out += 1;
            }
        }
        if out == 0 {
            return false;
        }
        len = out;
        poly[..len].copy_from_slice(&next[..len]);
    }
    true
}

#[cfg(test)]
mod tests {
    /// A cache entry that is a named pipe or a device is a miss (`distance_grid`'s test).
    #[cfg(unix)]
    #[test]
    fn a_cache_entry_that_is_no_file_is_a_miss() {
        let d = tempfile::tempdir().unwrap();
        for p in crate::not_files(d.path()) {
            assert!(super::read(&p, 7, 12).is_none(), "{}", p.display());
        }
    }

    use scatter_sim::rng::WalkRng;

    use super::{NO_CONE, TANS};
    use crate::geometry::Geometry;

    fn bunny_mesh() -> crate::mesh::TriMesh {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../assets/bunny.glb");
        let mut m = crate::mesh::load_mesh(&path).expect("the shipped bunny");
        m.normalise_height(1.0).expect("a bunny of some height");
        m
    }

    /// The geometry of `mesh` with its cones computed here and now: `Geometry::new` may
    /// read them from the cache of an earlier run, which would test that run's code.
    fn fresh(mesh: crate::mesh::TriMesh) -> Geometry {
        let mut geo = Geometry::new(mesh);
        geo.escape_cos = super::escape_cosines(&geo);
        geo
    }

    /// The fraction of the surface's area whose triangles have an escape cone of at least
    /// the angle whose cosine is `cos`.
    fn cone_area(geo: &Geometry, cos: f32) -> f64 {
        let (mut all, mut with) = (0.0f64, 0.0f64);
        for (i, &c) in geo.escape_cos.iter().enumerate() {
            let [a, b, cc] = geo.mesh.triangle(i);
            let area = (b - a).cross(cc - a).length() as f64;
            all += area;
            if c <= cos {
                with += area;
            }
        }
        with / all.max(f64::MIN_POSITIVE)
    }

    /// Rays leaving random points of random triangles in directions of their cones, half of
    /// them on the cone's rim (where a cone too wide would first show): none may meet the
    /// mesh. The cones are a proof, not an estimate, so a single hit is a failure; 40,000
    /// rays a mesh look at every triangle ~5–10 times. On the torus knot most directions
    /// re-enter the mesh, so wrong cones would not go unnoticed there. The bunny far from
    /// the origin (coarser coordinates: an ulp of 100 is 8e-6) is checked too. (The rays
    /// here do not come close enough to a neighbour to tell the δ margin from none; a
    /// region 2 % too small fails.)
    /// A unit cylinder of `n` sides from z = −1 to 1, its caps fans from their centres.
    fn fanned_cylinder(n: u32) -> crate::mesh::TriMesh {
        let mut positions = vec![
            glam::Vec3::new(0.0, 0.0, -1.0),
            glam::Vec3::new(0.0, 0.0, 1.0),
        ];
        let mut triangles = Vec::new();
        for k in 0..n {
            let a = std::f32::consts::TAU * k as f32 / n as f32;
            positions.push(glam::Vec3::new(a.cos(), a.sin(), -1.0));
            positions.push(glam::Vec3::new(a.cos(), a.sin(), 1.0));
            let (b0, b1) = (2 + 2 * k, 2 + 2 * ((k + 1) % n));
            let (t0, t1) = (b0 + 1, b1 + 1);
            triangles.extend([[0, b1, b0], [1, t0, t1], [b0, b1, t1], [b0, t1, t0]]);
        }
        crate::mesh::TriMesh {
            positions,
            triangles,
        }
    }

    #[test]
    fn rays_in_escape_cones_meet_nothing() {
        for (name, geo) in [
            ("bunny", fresh(bunny_mesh())),
            ("torus knot", fresh(crate::mesh::torus_knot())),
            // Caps fanned from their centres: coplanar slivers, whose boxes the cone
            // test now skips rather than clipping every face in them.
            ("cylinder with fanned caps", fresh(fanned_cylinder(64))),
            ("bunny at (100, 50, 0)", {
                let mut m = bunny_mesh();
                for p in &mut m.positions {
                    *p += glam::Vec3::new(100.0, 50.0, 0.0);
                }
                fresh(m)
            }),
        ] {
            let mut rng = WalkRng::from_seed(7);
            let with: Vec<usize> = (0..geo.tris.len())
                .filter(|&t| geo.escape_cos[t] < 1.0)
                .collect();
            assert!(!with.is_empty(), "{name}: no triangle has an escape cone");
            let (mut hits, mut cast) = (0, 0);
            for i in 0..40_000 {
                let t = with[(rng.next_u64() % with.len() as u64) as usize];
                let [a, b, c] = geo.mesh.triangle(t);
                let (mut u, mut v) = (rng.uniform() as f32, rng.uniform() as f32);
                if u + v > 1.0 {
                    (u, v) = (1.0 - u, 1.0 - v);
                }
                let p = a + (b - a) * u + (c - a) * v;
                let n = geo.normals[t];
                let cos_min = geo.escape_cos[t];
                let cos = if i % 2 == 0 {
                    cos_min
                } else {
                    cos_min + (1.0 - cos_min) * rng.uniform() as f32
                };
                let (tb, bb) = scatter_sim::phase::orthonormal_basis(n.as_dvec3());
                let (cp, sp) = rng.unit_circle();
                let sin = (1.0 - cos * cos).max(0.0).sqrt();
                let w = (n * cos + (tb.as_vec3() * cp as f32 + bb.as_vec3() * sp as f32) * sin)
                    .normalize();
                if !geo.escapes_from(t as u32, w) {
                    continue; // rounding put it just outside; the renderer would cast it
                }
                cast += 1;
                if geo
                    .intersect(geo.spawn(p, n, w), w, f32::INFINITY)
                    .is_some()
                {
                    hits += 1;
                }
            }
            assert_eq!(hits, 0, "{name}: rays inside escape cones met the mesh");
            // Rounding pushes some rim rays just out of their cones (~23 % on the bunny),
            // but at least half of the 20,000 rim rays must be cast for the rim to count as
            // tested.
            eprintln!("{name}: {cast} of 40,000 rays cast");
            assert!(
                cast >= 30_000,
                "{name}: only {cast} of 40,000 rays were cast"
            );
        }
    }

    /// A damaged entry is replaced by the rebuilt cones, however fast they were built: one
    /// rebuilt faster than new results are cached from (0.1 s; the bunny's take 55 ms) was
    /// not rewritten, so it stayed damaged (and its note came back every run).
    #[test]
    fn a_damaged_entry_is_replaced_however_fast_the_rebuild() {
        let geo = crate::geometry::Geometry::new(crate::mesh::cube(1.0));
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("cones.bin");
        std::fs::write(&p, b"not a cache entry").unwrap();
        // No result is fast enough to be cached as new (the test does not depend on the
        // machine's speed), but this one replaces a damaged entry.
        let cos = super::cached_at(&geo, 7, Some(&p), f64::INFINITY);
        assert_eq!(super::read(&p, 7, geo.tris.len()), Some(cos));
        // Without an entry, a fast result is not cached.
        let fresh = dir.path().join("fresh.bin");
        super::cached_at(&geo, 7, Some(&fresh), f64::INFINITY);
        assert!(!fresh.exists());
    }

    /// The cache file round-trips, and a damaged file or one for another mesh is not read:
    /// one of as many triangles but another key (a file copied under another name) too, or
    /// one of another format.
    #[test]
    fn cached_cones_round_trip_and_damage_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("c.bin");
        let cos = vec![super::cone_cos(4), NO_CONE, super::cone_cos(0)];
        super::write(&p, 7, &cos).unwrap();
        assert_eq!(super::read(&p, 7, 3), Some(cos));
        assert_eq!(super::read(&p, 7, 4), None);
        assert_eq!(super::read(&p, 8, 3), None);
        let mut b = std::fs::read(&p).unwrap();
        b[21] ^= 1;
        std::fs::write(&p, &b).unwrap();
        assert_eq!(super::read(&p, 7, 3), None);
        // Another format (an earlier version's tag, its checksum made again) is a miss.
        b[21] ^= 1;
        assert_eq!(&b[..8], b"STCVEC02");
        b[7] = b'1';
        let body = b.len() - 4;
        let crc = crc32fast::hash(&b[..body]).to_le_bytes();
        b[body..].copy_from_slice(&crc);
        std::fs::write(&p, &b).unwrap();
        assert_eq!(super::read(&p, 7, 3), None);
    }

    /// A cached cosine must be one `escape_cosines` makes (the check that refuses the
    /// file): one of 0 or below (−0 included) would let every direction off the outer
    /// side of its triangle, grazing ones included, skip its cast, and paths that must
    /// meet the object again would escape; so would, nearly, a forged 0.01 or any value
    /// between the cones'. The widest cone computed (tan θ = 3: cos θ = 0.316229) reads
    /// back; a cosine one ulp from it does not.
    #[test]
    fn only_cosines_the_cones_make_are_read_back() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("c.bin");
        let tan = TANS[TANS.len() - 1];
        let widest = (1.0 / (1.0 + tan * tan).sqrt() + 1e-6) as f32;
        assert_eq!(widest, super::cone_cos(TANS.len() - 1));
        let next = f32::from_bits(widest.to_bits() + 1);
        let cases = [
            (widest, true),
            (0.0, false),
            (-0.0, false),
            (-0.5, false),
            (0.01, false),
            (next, false),
            (0.5, false),
        ];
        for (cos, usable) in cases {
            let cones = [super::cone_cos(2), cos, NO_CONE];
            super::write(&p, 7, &cones).unwrap();
            let back = super::read(&p, 7, 3);
            assert_eq!(back.is_some(), usable, "a cached cosine of {cos}: {back:?}");
        }
    }

    /// The margin δ (eps/10) that a cone's region adds around its triangle, for an exit
    /// point rounded past the triangle's edge: a face that close beside the edge must
    /// close the cone. A unit cube with a slab 0.15 eps thick hovering beside its +x edge,
    /// 0.6–0.75 eps above its top face (above the region's floor h₀ = eps/2) and `gap`
    /// beyond the edge (eps = 3·10⁻⁵: the mesh's scale is 1.5, x from −0.5 to 1; f32
    /// rounds its coordinates by 10⁻³ eps). The narrowest cone tried (tan θ = 0.2) reaches
    /// 0.2·h, at most 0.15 eps, beyond the top's triangles at those heights, δ more with
    /// the margin: the slab 0.17 eps beyond the edge is met only thanks to δ, so both of
    /// the top's triangles (one along the edge, one touching it at a corner) have no cone;
    /// the slab 0.3 eps beyond is clear of tan θ = 0.2's region (0.25 eps) and met by tan
    /// θ = 0.4's (0.24 eps + δ at 0.6 eps), so both get tan θ = 0.2's cone. Without δ (or
    /// with the floor at eps) the slab at 0.17 eps went unseen and the top's cones opened
    /// to 11°.
    #[test]
    fn a_face_just_beside_a_triangles_edge_closes_its_cone() {
        let with_slab = |gap: f32, eps: f32| {
            let cube = crate::mesh::cube(1.0);
            let slab = cube.positions.iter().map(|p| {
                glam::Vec3::new(
                    if p.x > 0.0 { 1.0 } else { 0.5 + gap * eps },
                    if p.y > 0.0 {
                        0.5 + 0.75 * eps
                    } else {
                        0.5 + 0.6 * eps
                    },
                    1.2 * p.z,
                )
            });
            let base = cube.positions.len() as u32;
            crate::mesh::TriMesh {
                positions: cube.positions.iter().copied().chain(slab).collect(),
                triangles: cube
                    .triangles
                    .iter()
                    .copied()
                    .chain(cube.triangles.iter().map(|t| t.map(|i| i + base)))
                    .collect(),
            }
        };
        // The scale (and eps) is the same whatever the gap.
        let eps = crate::geometry::spawn_offset(&with_slab(0.0, 0.0));
        // `cube`'s top face (y = +0.5): [2, 6, 7] touches the edge x = 0.5 at a corner,
        // [2, 7, 3] lies along it.
        let top = [6usize, 7];
        let near = fresh(with_slab(0.17, eps));
        assert_eq!(near.eps, eps);
        for t in top {
            assert!(
                near.normals[t].y > 0.999,
                "triangle {t}: {}",
                near.normals[t]
            );
            assert_eq!(
                near.escape_cos[t], NO_CONE,
                "triangle {t}: a cone past a face 0.17 eps beside its edge"
            );
            // Not even the normal itself (exactly (0, 1, 0) here, w·n = 1) escapes a
            // triangle without a cone.
            assert!(
                !near.escapes_from(t as u32, near.normals[t]),
                "triangle {t}: its normal escapes though it has no cone"
            );
        }
        let far = fresh(with_slab(0.3, eps));
        let tan = TANS[0];
        let narrowest = (1.0 / (1.0 + tan * tan).sqrt() + 1e-6) as f32;
        for t in top {
            assert_eq!(far.escape_cos[t], narrowest, "triangle {t}");
        }
    }

    /// The cones must also be wide enough to spare casts: on the bunny 70 % of the area has
    /// one of at least 45° (measured when they were introduced); a bug that shrank them
    /// would leave the renderer right but slower.
    #[test]
    fn the_bunny_has_wide_escape_cones() {
        let geo = fresh(bunny_mesh());
        let at_45 = cone_area(&geo, std::f32::consts::FRAC_1_SQRT_2 + 2e-6);
        assert!(
            at_45 > 0.6,
            "only {at_45:.3} of the bunny has a 45° escape cone"
        );
        assert!(cone_area(&geo, NO_CONE) > 0.999);
        // Every face of a closed convex mesh gets the widest cone tried (tan θ = 3: 71.6°,
        // cos θ = 0.316), as no direction of its outer hemisphere meets the mesh.
        let cube = fresh(crate::mesh::cube(1.0));
        let widest = (1.0 / (1.0 + TANS[TANS.len() - 1] * TANS[TANS.len() - 1])).sqrt() as f32;
        assert!(cone_area(&cube, widest + 1e-6) > 0.999);
    }
}
