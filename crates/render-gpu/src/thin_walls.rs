//! Parts of an object thinner than the surface offset: a path entering there starts
//! beyond the far side ([`Geometry::beyond_sliver`] then sends it on through the air), so
//! those parts render as if they were not there. The bounding-box check of `setup` sees
//! only an object thin as a whole; a shell whose walls were 5·10⁻⁶ thick (the offset 2·10⁻⁵)
//! rendered as bare background without a word.

use crate::geometry::{EPS, Geometry, SLIVER_REACH_OF_EPS};
use crate::piece_survey::TOUCH_OF_SCALE;
use glam::Vec3;
use rayon::prelude::*;

/// The surface (by area) where an entering path would start beyond a far side, and a
/// point of the largest such face.
pub struct ThinWalls {
    /// Share of the surface's area, in [0, 1].
    pub area_share: f64,
    /// The centroid of the largest face found so, in the mesh's coordinates.
    pub at: Option<Vec3>,
}

/// Share of the surface (by area, hidden faces included) beyond which `render` notes thin
/// walls. A face is tested at its centroid only, so a sharp edge fires on faces whose
/// centroid lies within ~eps of it (small faces of a fine mesh): the threshold leaves
/// those out (the shipped bunny stays below it; see the tests), and walls thinner than
/// the offset over more than a thousandth of the surface are noted.
pub const NOTE_AREA_SHARE: f64 = 1e-3;

/// Tests each face at its centroid as an entering path meets it: spawned `eps` inside,
/// the way back out meets another surface from outside first. Faces no path enters from
/// the air are left out: where pieces of the mesh touch or overlap, the other piece's face
/// in or near the face's plane would fire the test, but the integrators cross such faces
/// within the medium.
pub fn thin_walls(geo: &Geometry) -> ThinWalls {
    let n = geo.mesh.triangles.len();
    let reach = geo.eps * SLIVER_REACH_OF_EPS;
    // The piece survey's touching distance, TOUCH_OF_SCALE of the mesh's scale.
    let touch = geo.eps / EPS * TOUCH_OF_SCALE;
    let (thin, total, best) = (0..n)
        .into_par_iter()
        .map(|i| {
            let [a, b, c] = geo.mesh.triangle(i);
            let area = f64::from((b - a).cross(c - a).length()) * 0.5;
            let normal = geo.normals[i];
            let centroid = (a + b + c) / 3.0;
            let q = geo.spawn(centroid, normal, -normal);
            // Geometry::beyond_sliver's test, less a far face within the pieces' touching
            // distance of the face itself (measured along the same ray, so that the
            // roundings of the centroid and of q cancel): another piece touching this one
            // there, or sunk into it by less than the piece survey tells from touching (a
            // box standing on a slab), is no wall, and no path enters either face from the
            // air. Walls thinner than that (5 % of the offset) go unnoticed.
            // The face's own hit is cast only behind a far face met from outside, which
            // most faces never have.
            let own = || {
                geo.closest_of(q, normal, reach, &[i as u32])
                    .map_or(geo.eps, |h| h.t)
            };
            let far = geo
                .intersect(q, normal, reach)
                .is_some_and(|h| h.normal.dot(normal) < 0.0 && h.t < own() - touch);
            // Overlapping pieces: a face within another piece's medium is crossed inside.
            let covered = || {
                geo.pieces
                    .as_ref()
                    .is_some_and(|p| geo.in_union(p, geo.spawn(centroid, normal, normal), normal))
            };
            let fires = far && !covered();
            if fires {
                (area, area, Some((area, centroid)))
            } else {
                (0.0, area, None)
            }
        })
        .reduce(
            || (0.0, 0.0, None),
            |x, y| {
                let best = match (x.2, y.2) {
                    (Some(p), Some(q)) => Some(if q.0 > p.0 { q } else { p }),
                    (p, q) => p.or(q),
                };
                (x.0 + y.0, x.1 + y.1, best)
            },
        );
    ThinWalls {
        area_share: if total > 0.0 { thin / total } else { 0.0 },
        at: best.map(|b| b.1),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::{TriMesh, cube, prepare};
    use glam::Vec3;

    /// A cube of side 1 with a cavity: the cube scaled by `inner`, wound inward.
    fn shell(inner: f32) -> Geometry {
        let outer = cube(1.0);
        let mut m = TriMesh {
            positions: outer.positions.clone(),
            triangles: outer.triangles.clone(),
        };
        let base = m.positions.len() as u32;
        m.positions
            .extend(outer.positions.iter().map(|p| *p * inner));
        m.triangles.extend(
            outer
                .triangles
                .iter()
                .map(|t| [t[0] + base, t[2] + base, t[1] + base]),
        );
        Geometry::new(prepare(m).expect("a closed shell"))
    }

    /// A unit cube scaled by `scale`, then moved by `shift`.
    fn placed_cube(scale: Vec3, shift: Vec3) -> TriMesh {
        let m = cube(1.0);
        TriMesh {
            positions: m.positions.iter().map(|p| *p * scale + shift).collect(),
            triangles: m.triangles,
        }
    }

    /// Two pieces as one mesh.
    fn joined(a: TriMesh, b: TriMesh) -> TriMesh {
        let base = a.positions.len() as u32;
        TriMesh {
            positions: [a.positions, b.positions].concat(),
            triangles: a
                .triangles
                .into_iter()
                .chain(b.triangles.iter().map(|t| t.map(|i| i + base)))
                .collect(),
        }
    }

    /// A slab 2 × 0.5 × 2 below y = 0 and a box 0.5 across standing on it, its base `sunk`
    /// below y = 0 (no edge of one lies on the other, so the two stay apart when welded).
    fn slab_and_box(sunk: f32) -> TriMesh {
        joined(
            placed_cube(Vec3::new(2.0, 0.5, 2.0), Vec3::new(0.0, -0.25, 0.0)),
            placed_cube(Vec3::splat(0.5), Vec3::new(0.0, 0.25 - sunk, 0.0)),
        )
    }

    /// Walls of a quarter of the offset are found everywhere (both of their sides, the
    /// whole surface); walls of twice the offset nowhere, nor is a plain cube, a sphere or
    /// the shipped bunny (whose thin features at the top of its head are smaller than
    /// [`NOTE_AREA_SHARE`] of its surface).
    #[test]
    fn walls_thinner_than_the_offset_are_found() {
        let eps = shell(0.5).eps;
        // Wall thickness = (1 − inner)/2.
        let thin = shell(1.0 - 0.5 * eps);
        let w = thin_walls(&thin);
        assert!(w.area_share > 0.999, "{}", w.area_share);
        assert!(w.at.is_some());
        let thick = shell(1.0 - 4.0 * eps);
        assert_eq!(thick.eps, eps);
        assert_eq!(thin_walls(&thick).area_share, 0.0);
        for m in [cube(1.0), crate::mesh::sphere(0.5)] {
            assert_eq!(thin_walls(&Geometry::new(m)).area_share, 0.0);
        }
        // A box resting on a slab, sunk into it by 3 % of the slab's offset (less than
        // the piece survey tells from touching: pieces None), and by 20 % (overlapping
        // pieces): their contact faces are not entered from the air (taken as thin walls,
        // they were 0.9 % and 1.9 % of the surface here, above NOTE_AREA_SHARE).
        let slab_eps = Geometry::new(prepare(slab_and_box(0.0)).unwrap()).eps;
        for (sunk, overlapping) in [(0.0, false), (0.03, false), (0.2, true)] {
            let m = prepare(slab_and_box(sunk * slab_eps)).expect("two closed pieces");
            let g = Geometry::new(m);
            assert_eq!(g.pieces.is_some(), overlapping, "sunk {sunk}");
            let share = thin_walls(&g).area_share;
            assert_eq!(share, 0.0, "sunk {sunk} of the offset");
        }
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../assets/bunny.glb");
        let mut bunny = crate::mesh::load_mesh(&path).expect("the shipped bunny");
        bunny.normalise_height(1.0).unwrap();
        let share = thin_walls(&Geometry::new(bunny)).area_share;
        assert!(share < NOTE_AREA_SHARE, "{share}");
    }

    /// The note's place (`at`) is the centroid of the largest face found thin, whichever
    /// way the parallel reduction pairs them. In the shell of walls a quarter of the offset
    /// thick every face is found; the outer cube's (area 0.5 each) are larger than the
    /// cavity's (0.5·(1 − eps/2)², 1·10⁻⁵ less, far above f32's resolution), and their
    /// centroids lie on the planes ±0.5 exactly (three coordinates ±0.5 summed and divided
    /// by 3), the cavity's on ±0.5·(1 − eps/2) = ±0.499995. Picking the smaller of two
    /// faces, the note pointed at the cavity.
    #[test]
    fn the_note_points_at_the_largest_thin_face() {
        let eps = shell(0.5).eps;
        let g = shell(1.0 - 0.5 * eps);
        let at = thin_walls(&g).at.expect("thin walls are found");
        assert_eq!(at.abs().max_element(), 0.5, "{at}");
        // A face's centroid, computed as thin_walls computes it (the same bits): a corner
        // of the outer cube passes the check above too.
        let centroid = |i: usize| {
            let [a, b, c] = g.mesh.triangle(i);
            (a + b + c) / 3.0
        };
        assert!(
            (0..g.mesh.triangles.len()).any(|i| centroid(i) == at),
            "{at}"
        );
    }

    /// A plate eps/2 thick and a box 0.5 across sunk 0.2·eps into it (overlapping
    /// pieces): the plate's bottom (area 1) and the box's bottom (0.25, past the thin plate
    /// from outside) count as thin, of 3.50004 in all, 35.7 %; the plate's top lies in the
    /// box's medium where the box stands and is covered. Tested from the point spawned
    /// inward instead, the top would count, and the bottom not: 1/3.50004, at y = 0.
    #[test]
    fn a_thin_face_inside_another_piece_is_not_counted() {
        let eps = Geometry::new(cube(1.0)).eps;
        let thick = 0.5 * eps;
        let m = joined(
            placed_cube(
                Vec3::new(1.0, thick, 1.0),
                Vec3::new(0.0, -0.5 * thick, 0.0),
            ),
            placed_cube(Vec3::splat(0.5), Vec3::new(0.0, 0.25 - 0.2 * eps, 0.0)),
        );
        let g = Geometry::new(prepare(m).expect("two closed pieces"));
        assert_eq!(g.eps, eps);
        assert!(g.pieces.is_some(), "the box overlaps the plate");
        let w = thin_walls(&g);
        assert!(
            (w.area_share - 1.25 / 3.50004).abs() < 1e-4,
            "{}",
            w.area_share
        );
        let at = w.at.expect("the plate's bottom is thin");
        assert!(at.y < -0.25 * eps, "{at}");
    }
}
