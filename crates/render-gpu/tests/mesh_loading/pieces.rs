//! Meshes of several closed pieces: their winding by nesting, overlaps and contacts, and
//! the limits of the survey.

use super::*;

/// Each piece is wound by how deeply it is nested, whatever the file's winding: the
/// medium's volume comes out as the shape's (a piece left inside out rendered leaks and a
/// brighter image). The expected volumes are the boxes' closed-form ones.
#[test]
fn pieces_are_wound_by_their_nesting() {
    let c = mesh::cube;
    let bar = |along: glam::Vec3| scaled(c(1.0), glam::Vec3::splat(0.6) + 1.4 * along);
    let cases: [(&str, Vec<Piece>, f64); 16] = [
        // A hollow box: the inner wall bounds the medium from inside (8 − 1).
        (
            "shell, walls wound alike",
            vec![(c(2.0), false), (c(1.0), false)],
            7.0,
        ),
        (
            "shell, walls opposite",
            vec![(c(2.0), false), (c(1.0), true)],
            7.0,
        ),
        (
            "shell, both reversed",
            vec![(c(2.0), true), (c(1.0), true)],
            7.0,
        ),
        // A solid cube in the hollow box's cavity: 27 − 8 + 1.
        (
            "ball in a shell",
            vec![(c(3.0), true), (c(2.0), false), (c(1.0), true)],
            20.0,
        ),
        // Apart, one reversed (a mirrored instance): both solid.
        (
            "apart",
            vec![
                (moved(c(1.0), glam::Vec3::X * 2.0), false),
                (moved(c(1.0), -glam::Vec3::X * 2.0), true),
            ],
            2.0,
        ),
        // Overlapping is not nesting: each solid on its own (as the integrators see it).
        (
            "overlapping",
            vec![
                (c(1.0), true),
                (moved(c(1.0), glam::Vec3::splat(0.5)), true),
            ],
            2.0,
        ),
        // Touching at one corner only: two pieces, each solid (joined through the shared
        // vertex they were one piece with one winding decision).
        (
            "touching at a corner",
            vec![
                (c(1.0), false),
                (moved(c(0.8), glam::Vec3::splat(0.9)), true),
            ],
            1.0 + 0.512,
        ),
        // A cavity inside two overlapping solids is one hole (depth 1), not solid again.
        (
            "cavity in an overlapping pair",
            vec![
                (c(2.0), false),
                (moved(c(2.0), glam::Vec3::X * 0.5), false),
                (moved(c(0.5), glam::Vec3::X * 0.25), false),
            ],
            16.0 - 0.125,
        ),
        // A cavity inside the union of two overlapping solids but in neither alone (it
        // crosses their seam) is a hole too; asked of one container at a time it was
        // taken for solid.
        (
            "cavity across the seam of an overlapping pair",
            vec![
                (c(2.0), false),
                (moved(c(2.0), glam::Vec3::X), false),
                (
                    moved(
                        scaled(c(1.0), glam::Vec3::new(2.0, 0.5, 0.5)),
                        glam::Vec3::X * 0.5,
                    ),
                    false,
                ),
            ],
            16.0 - 0.5,
        ),
        // Two bars crossing in a plus sign: each solid; every vertex and centroid of each
        // lies outside the other, yet they overlap.
        (
            "crossing bars",
            vec![(bar(glam::Vec3::X), false), (bar(glam::Vec3::Y), true)],
            2.0 * 2.0 * 0.36,
        ),
        // Boxes overlapping with four faces in shared planes: every probe of the smaller
        // one that is not outside the larger lies on its faces, where the winding number
        // is 0 or 1 by rounding; read as inside, the smaller box was taken for a cavity.
        // (Its triangles are listed so that the first, fourth, seventh and tenth, where
        // the depth used to be judged, are on its +z and +y faces, in A's planes.)
        (
            "overlapping, faces in shared planes",
            vec![
                (scaled(c(1.0), glam::Vec3::new(2.0, 1.0, 1.0)), false),
                (
                    listed(
                        moved(c(1.0), glam::Vec3::X * 0.7),
                        &[2, 0, 1, 3, 4, 5, 6, 8, 9, 7, 10, 11],
                    ),
                    false,
                ),
            ],
            2.0 + 1.0,
        ),
        // A cavity across the seam of two solids, larger than one of them (1.472 against
        // 2.0 and 0.7): settled largest first, it was reached before the smaller solid
        // around part of it and taken for solid.
        (
            "cavity across the seam, larger than a solid",
            vec![
                (
                    moved(
                        scaled(c(1.0), glam::Vec3::new(2.0, 1.0, 1.0)),
                        -glam::Vec3::X * 0.5,
                    ),
                    false,
                ),
                (
                    moved(
                        scaled(c(1.0), glam::Vec3::new(0.7, 1.0, 1.0)),
                        glam::Vec3::X * 0.65,
                    ),
                    false,
                ),
                // (Listed from its +x face, inside the smaller solid only.)
                (
                    listed(
                        moved(
                            scaled(c(1.0), glam::Vec3::new(2.3, 0.8, 0.8)),
                            -glam::Vec3::X * 0.25,
                        ),
                        &[10, 11, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9],
                    ),
                    false,
                ),
            ],
            2.0 + 0.7 - 2.3 * 0.8 * 0.8,
        ),
        // Three slabs stacked up, each overlapping the next, their side faces in shared
        // planes: the middle one's probes are in a neighbour or on the neighbours' side
        // faces, which bound the union (counted as inside them it was a cavity).
        (
            "stacked slabs, side faces in shared planes",
            (0..3)
                .map(|k| {
                    let slab = scaled(c(1.0), glam::Vec3::new(1.0, 0.5, 1.0));
                    (moved(slab, glam::Vec3::Y * (0.3 * k as f32)), false)
                })
                .collect(),
            1.5,
        ),
        // A rod whose ends lie in two boxes and whose middle is bare: every point where
        // its edges leave one box is followed by a point in the other, and midpoints
        // taken between meetings with one box at a time all lay in a box: the rod was
        // taken for a cavity, its bare middle air.
        (
            "rod between two boxes",
            vec![
                (scaled(c(1.0), glam::Vec3::new(2.0, 0.1, 0.1)), false),
                (moved(c(1.0), -glam::Vec3::X * 0.7), false),
                (moved(c(1.0), glam::Vec3::X * 0.7), false),
            ],
            2.0 * 0.1 * 0.1 + 2.0,
        ),
        // A block resting on the floor of a box's cavity (its bottom face on the floor),
        // with an overlapping pair elsewhere: the probes on the floor, taken as outside
        // the cavity, made the block a cavity itself.
        (
            "block on a cavity's floor",
            vec![
                (c(2.0), false),
                (c(1.6), false),
                (
                    moved(
                        scaled(c(1.0), glam::Vec3::new(0.6, 0.6, 0.6)),
                        -glam::Vec3::Y * 0.5,
                    ),
                    false,
                ),
                (moved(c(1.0), glam::Vec3::X * 3.5), false),
                (
                    moved(
                        scaled(c(1.0), glam::Vec3::new(1.0, 1.0, 0.8)),
                        glam::Vec3::new(4.0, 0.2, 0.0),
                    ),
                    false,
                ),
            ],
            8.0 - 1.6 * 1.6 * 1.6 + 0.216 + 1.0 + 0.8,
        ),
        // A thin rod through a plate, off its middle: none of either's probes (vertices,
        // centroids, points halfway to the edges' midpoints; the rod's at heights −1,
        // −0.425, −0.233, 0.15, 0.533, 0.725, 1.3, the plate 0.1 thick about 0) lies
        // inside the other, but the rod's edges pass through the plate's faces.
        (
            "rod through a plate",
            vec![
                (scaled(c(1.0), glam::Vec3::new(10.0, 10.0, 0.1)), false),
                (
                    moved(
                        scaled(c(1.0), glam::Vec3::new(0.1, 0.1, 2.3)),
                        glam::Vec3::new(3.1, 2.7, 0.15),
                    ),
                    false,
                ),
            ],
            10.0 + 0.1 * 0.1 * 2.3,
        ),
    ];
    for (what, parts, want) in cases {
        let m = mesh::prepare(pieces(&parts)).unwrap();
        let (v, _) = volume_and_area(&m);
        // f32 corners (0.9 + 0.4) round at 1e-7; a piece left inside out is off by its
        // whole volume.
        assert!(
            (v - want).abs() < 1e-6 * want,
            "{what}: volume {v}, want {want}"
        );
        // Overlaps (rendered as the union by following the pieces around a path) are
        // found and named; nesting, pieces apart and pieces touching at a corner are not
        // overlaps.
        let overlaps = mesh::overlapping_pieces(&m);
        let want_overlaps: &[(usize, usize)] = match what {
            "overlapping" => &[(0, 1)],
            "cavity in an overlapping pair" => &[(0, 1)],
            "cavity across the seam of an overlapping pair" => &[(0, 1), (0, 2), (1, 2)],
            "crossing bars" => &[(0, 1)],
            "rod through a plate" => &[(0, 1)],
            "rod between two boxes" => &[(0, 1), (0, 2)],
            "stacked slabs, side faces in shared planes" => &[(0, 1), (1, 2)],
            "block on a cavity's floor" => &[(3, 4)],
            "overlapping, faces in shared planes" => &[(0, 1)],
            "cavity across the seam, larger than a solid" => &[(0, 1), (0, 2), (1, 2)],
            _ => &[],
        };
        assert_eq!(overlaps, want_overlaps, "{what}");
        if what == "overlapping" {
            // Two boxes in an L, overlapping from one corner edge (one edge of four faces
            // once welded), are refused with the reason, not as "not closed".
            let e = mesh::prepare(pieces(&[
                (
                    moved(
                        scaled(c(1.0), glam::Vec3::new(2.0, 1.0, 1.0)),
                        -glam::Vec3::Y * 0.5,
                    ),
                    false,
                ),
                (
                    moved(
                        scaled(c(1.0), glam::Vec3::new(1.0, 2.0, 1.0)),
                        -glam::Vec3::X * 0.5,
                    ),
                    false,
                ),
            ]))
            .unwrap_err();
            assert!(
                e.contains("more than two faces share 1 of its edges"),
                "{e}"
            );
        }
        if what == "rod through a plate" {
            // Where the rod is within the plate the point is in the medium: by crossing
            // parity (the overlap missed) it was air, two faces ahead of it.
            let geo = render_gpu::geometry::Geometry::new(m.clone());
            let p = glam::Vec3::new;
            for (at, inside) in [
                (p(3.1, 2.7, 0.0), true),
                (p(3.1, 2.7, 0.5), true),
                (p(0.0, 0.0, 0.0), true),
                (p(3.1, 2.7, 1.4), false),
                (p(3.3, 2.7, 0.5), false),
            ] {
                assert_eq!(geo.inside(at), inside, "{what}: at {at}");
            }
        }
    }
}

/// A box over `lo..hi` whose faces are grids of `n` cells along each axis (welded on
/// loading): its vertices are at lo + (hi − lo)·k/n, computed by one formula so that
/// faces meet exactly and other meshes can be placed on the grid.
fn gridded_box(lo: glam::Vec3, hi: glam::Vec3, n: [u32; 3]) -> mesh::TriMesh {
    let at = |k: [u32; 3]| {
        glam::Vec3::from_array(std::array::from_fn(|a| {
            lo[a] + (hi[a] - lo[a]) * (k[a] as f32 / n[a] as f32)
        }))
    };
    let mut m = mesh::TriMesh::default();
    // Each face: the fixed axis and side, and the two axes it runs along, in the order
    // that makes their cross product point outward.
    for (fixed, side, u, v) in [
        (2, 1, 0, 1),
        (2, 0, 1, 0),
        (0, 1, 1, 2),
        (0, 0, 2, 1),
        (1, 1, 2, 0),
        (1, 0, 0, 2),
    ] {
        for i in 0..n[u] {
            for j in 0..n[v] {
                let base = m.positions.len() as u32;
                for (di, dj) in [(0, 0), (1, 0), (1, 1), (0, 1)] {
                    let mut k = [0; 3];
                    k[fixed] = side * n[fixed];
                    k[u] = i + di;
                    k[v] = j + dj;
                    m.positions.push(at(k));
                }
                m.triangles.push([base, base + 1, base + 2]);
                m.triangles.push([base, base + 2, base + 3]);
            }
        }
    }
    m
}

/// A solid made of the cells of a grid (cell (i, j, k) spans xs[i]..xs[i + 1] and so on)
/// that `filled` says are in it: the faces between a filled cell and an empty one (or the
/// outside), each a quad of two triangles facing out of the solid.
fn grid_solid(axes: [&[f32]; 3], filled: impl Fn([usize; 3]) -> bool) -> mesh::TriMesh {
    let n = axes.map(|a| a.len() - 1);
    let inside = |c: [i64; 3]| {
        (0..3).all(|a| c[a] >= 0 && (c[a] as usize) < n[a]) && filled(c.map(|x| x as usize))
    };
    let mut m = mesh::TriMesh::default();
    for i in 0..n[0] {
        for j in 0..n[1] {
            for k in 0..n[2] {
                let cell = [i, j, k];
                if !filled(cell) {
                    continue;
                }
                for axis in 0..3 {
                    for dir in [-1i64, 1] {
                        let mut next = cell.map(|x| x as i64);
                        next[axis] += dir;
                        if inside(next) {
                            continue;
                        }
                        // The face's plane, and its two other axes in the order whose
                        // cross product is +axis.
                        let at = if dir > 0 { cell[axis] + 1 } else { cell[axis] };
                        let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
                        let corner = |du: usize, dv: usize| {
                            let mut p = [0.0f32; 3];
                            p[axis] = axes[axis][at];
                            p[u] = axes[u][cell[u] + du];
                            p[v] = axes[v][cell[v] + dv];
                            glam::Vec3::from_array(p)
                        };
                        let base = m.positions.len() as u32;
                        m.positions.extend([
                            corner(0, 0),
                            corner(1, 0),
                            corner(1, 1),
                            corner(0, 1),
                        ]);
                        if dir > 0 {
                            m.triangles.push([base, base + 1, base + 2]);
                            m.triangles.push([base, base + 2, base + 3]);
                        } else {
                            m.triangles.push([base, base + 2, base + 1]);
                            m.triangles.push([base, base + 3, base + 2]);
                        }
                    }
                }
            }
        }
    }
    m
}

/// Overlaps that sampled probes miss are found where the pieces' edges pass in and out
/// of each other, and an overlapping piece is never taken for a cavity.
#[test]
fn overlaps_are_found_where_edges_cross() {
    // A rod through a 20 × 20-cell plate on the plate's grid: its edges meet the plate
    // only at the plate's vertices, where no edge passes strictly through a face, and
    // none of either's sampled probes lies inside the other (the rod's are at heights
    // −1, −0.425, −0.233, 0.15, 0.533, 0.725, 1.3; the plate's cells inside the rod are
    // 4 of its 1,760 triangles).
    let (lo, hi) = (
        glam::Vec3::new(-1.0, -1.0, -0.05),
        glam::Vec3::new(1.0, 1.0, 0.05),
    );
    let plate = gridded_box(lo, hi, [20, 20, 1]);
    let grid = |k: f32| -1.0 + 2.0 * (k / 20.0);
    let rod = gridded_box(
        glam::Vec3::new(grid(13.0), grid(7.0), -1.0),
        glam::Vec3::new(grid(14.0), grid(8.0), 1.3),
        [1, 1, 1],
    );
    let m = mesh::prepare(pieces(&[(plate, false), (rod, false)])).unwrap();
    let (v, _) = volume_and_area(&m);
    let want = 2.0 * 2.0 * 0.1 + 0.1 * 0.1 * 2.3;
    assert!(
        (v - want).abs() < 1e-5,
        "rod on the grid: volume {v}, want {want}"
    );
    assert_eq!(mesh::overlapping_pieces(&m), [(0, 1)], "rod on the grid");
    // A ball poking out of a box by a cap 0.3 deep, its triangles listed from several
    // starts: the ball was taken for a cavity whenever the 4 centroids that judged its
    // depth all lay inside the box (air where it pokes out, the rest of the box carved).
    let ball = mesh::sphere(0.5);
    let ball_volume = volume_and_area(&ball).0;
    let b = moved(
        scaled(mesh::cube(1.0), glam::Vec3::new(1.2, 1.6, 1.6)),
        glam::Vec3::X * 0.4,
    );
    let n = ball.triangles.len();
    for start in (0..n).step_by(n / 12) {
        let mut turned = ball.clone();
        turned.triangles.rotate_left(start);
        let m = mesh::prepare(pieces(&[(b.clone(), false), (turned, false)])).unwrap();
        let (v, _) = volume_and_area(&m);
        let want = 1.2 * 1.6 * 1.6 + ball_volume;
        assert!(
            (v - want).abs() < 1e-5,
            "ball listed from triangle {start}: volume {v}, want {want}"
        );
        assert_eq!(mesh::overlapping_pieces(&m), [(0, 1)], "ball from {start}");
    }
    // A 12-triangle cube inside a larger box but for a blind well of the box that dips
    // through one of the cube's top triangles: none of the cube's edges meets the box,
    // and every sampled probe of the cube is inside it, so only points on the cube's face
    // around where the well's edges meet it show the cube partly outside the box. The
    // cube was taken for a cavity (the medium a shell 0.2 thick).
    let cube = mesh::cube(2.0);
    let well = grid_solid(
        [
            &[-1.2, -0.8, -0.6, 1.2],
            &[-1.2, 0.8, 1.2],
            &[-1.2, 0.0, 0.2, 1.2],
        ],
        |c| c != [1, 1, 1],
    );
    let m = mesh::prepare(pieces(&[(cube, false), (well, false)])).unwrap();
    let (v, _) = volume_and_area(&m);
    let want = 8.0 + 2.4f64.powi(3) - 0.2 * 0.4 * 0.2;
    assert!(
        (v - want).abs() < 1e-5,
        "cube and well: volume {v}, want {want}"
    );
    assert_eq!(mesh::overlapping_pieces(&m), [(0, 1)], "cube and well");
}

/// The block resting on a cavity's floor (pieces_are_wound_by_their_nesting) turned so
/// that the floor's plane holds the lines of two of the survey's rays (piece_survey.rs,
/// `directions`), or nearly, and far from the origin: its contact is still found on the
/// surface, so the block stays solid. Along those rays a contact ~1e-7 off the plane lay
/// more than the touch distance away, and at 1,000 from the origin f32 rounding exceeded
/// a millionth of the mesh's size; either way the block was taken for air.
#[test]
fn contacts_are_found_along_grazing_rays_and_far_from_the_origin() {
    let c = mesh::cube;
    let a = glam::Vec3::new(0.2677, 0.5345, 0.8018).normalize();
    let b = glam::Vec3::new(-0.6133, 0.2871, -0.7358).normalize();
    let n = a.cross(b).normalize();
    let block = moved(
        scaled(c(1.0), glam::Vec3::new(0.6, 0.6, 0.6)),
        -glam::Vec3::Y * 0.5,
    );
    let parts = [c(2.0), c(1.6), block];
    let want = 8.0 - 1.6 * 1.6 * 1.6 + 0.216;
    for (what, turn, offset) in [
        ("as built", glam::Quat::IDENTITY, 0.0),
        (
            "floor along two rays",
            glam::Quat::from_rotation_arc(glam::Vec3::Y, n),
            0.0,
        ),
        (
            "floor 3e-3 off two rays",
            glam::Quat::from_rotation_arc(glam::Vec3::Y, n) * glam::Quat::from_rotation_x(3e-3),
            0.0,
        ),
        (
            "at 1,000 from the origin",
            glam::Quat::from_rotation_arc(glam::Vec3::Y, n),
            1000.0,
        ),
    ] {
        let placed: Vec<Piece> = parts
            .iter()
            .map(|p| {
                let mut p = p.clone();
                p.positions
                    .iter_mut()
                    .for_each(|v| *v = turn * *v + glam::Vec3::X * offset);
                (p, false)
            })
            .collect();
        let m = mesh::prepare(pieces(&placed)).unwrap();
        let (v, _) = volume_and_area(&m);
        // The volume sums about 1,000·area terms at the offset: f32 positions there are
        // 6e-5 apart, so 1e-3 of the volume bounds their rounding; a block taken for air
        // is off by 0.432.
        assert!(
            (v - want).abs() < 1e-3 * want,
            "{what}: volume {v}, want {want}"
        );
    }
}

/// Nesting is surveyed while at most `MAX_NESTING_PAIRS` pairs of pieces have overlapping
/// boxes (the survey's cost grows with them: 2,000 cubes all overlapping took 168 s and
/// 2.6 GB); beyond, each piece is solid, wound outward, and `render` notes it. A hollow
/// box (8 − 1, one pair) beside `n` cubes of 10⁻³ each: its cavity is wound inward with
/// 300 cubes apart (a piece count, the first limit tried, left it solid), and with 199
/// cubes all overlapping (19,701 + 1 pairs); solid with 201 (20,101).
#[test]
fn nesting_is_surveyed_up_to_its_overlap_limit() {
    let c = mesh::cube;
    let volume_with = |n: usize, step: f32| {
        let mut parts: Vec<Piece> = vec![(c(2.0), false), (c(1.0), false)];
        for k in 0..n {
            // Shifted along every axis, so that no two cubes share a face's plane.
            let s = step * k as f32;
            let at = glam::Vec3::new(3.0 + s, 0.7 * s, 0.3 * s);
            parts.push((moved(c(0.1), at), false));
        }
        let m = mesh::prepare(pieces(&parts)).unwrap();
        volume_and_area(&m).0 - n as f64 * 1e-3
    };
    for (n, step, want) in [(300, 0.2, 7.0), (199, 1e-4, 7.0), (201, 1e-4, 9.0)] {
        let v = volume_with(n, step);
        assert!((v - want).abs() < 1e-4, "{n} cubes {step} apart: {v}");
    }
}
