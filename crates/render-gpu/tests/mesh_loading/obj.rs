//! OBJ files: faces, groups and objects, indices counted forward and back, and one-line
//! errors naming the line for what tobj would take or refuse without a word.

use super::*;

/// A vertex no face uses (PLY and glTF may hold them; OBJ's reader drops them) is not
/// part of the object: it counted in the bounds, so `height` shrank a cube with a stray
/// point at y = 10 to a tenth of its size, off-centre, and rendered it almost empty.
#[test]
fn unused_vertices_are_not_part_of_the_object() {
    let d = tempfile::tempdir().unwrap();
    let cube = load_mesh(&write(&d, "cube.obj", CUBE_OBJ.as_bytes())).unwrap();
    let mut ply = String::from(
        "ply\nformat ascii 1.0\nelement vertex 9\nproperty float x\nproperty float y\n\
         property float z\nelement face 6\nproperty list uchar int vertex_indices\nend_header\n",
    );
    let (verts, faces) = CUBE_OBJ.split_at(CUBE_OBJ.find('f').unwrap());
    for v in verts.lines() {
        ply += &format!("{}\n", &v[2..]);
    }
    ply += "0 10 0\n";
    for f in faces.lines() {
        let idx: Vec<u32> = f[2..]
            .split(' ')
            .map(|i| i.parse::<u32>().unwrap() - 1)
            .collect();
        ply += &format!("4 {} {} {} {}\n", idx[0], idx[1], idx[2], idx[3]);
    }
    let m = load_mesh(&write(&d, "stray.ply", ply.as_bytes())).unwrap();
    assert_eq!(m.positions.len(), 8);
    assert_eq!(m.bounds(), cube.bounds());
    assert_eq!(m.triangles.len(), 12);
}

#[test]
fn obj_quads_load_and_an_open_mesh_is_refused() {
    let d = tempfile::tempdir().unwrap();
    let m = load_mesh(&write(&d, "cube.obj", CUBE_OBJ.as_bytes())).unwrap();
    assert_eq!(m.triangles.len(), 12);
    // The same file with a byte-order mark, with Windows and with old-Mac line ends.
    for (name, text) in [
        ("bom.obj", format!("\u{feff}{CUBE_OBJ}")),
        ("crlf.obj", CUBE_OBJ.replace('\n', "\r\n")),
        ("cr.obj", CUBE_OBJ.replace('\n', "\r")),
    ] {
        let other = load_mesh(&write(&d, name, text.as_bytes())).unwrap();
        assert_eq!(other.triangles, m.triangles, "{name}");
    }
    // A comment and an object name in Latin-1 (not UTF-8) load as the same cube; a stray
    // byte inside a number is named with its line; a NUL makes the file binary.
    let latin1 = [b"# caf\xe9\no cub\xe9\n".as_slice(), CUBE_OBJ.as_bytes()].concat();
    let other = load_mesh(&write(&d, "latin1.obj", &latin1)).unwrap();
    assert_eq!(other.triangles, m.triangles);
    let rest = &CUBE_OBJ.as_bytes()[CUBE_OBJ.find('\n').unwrap() + 1..];
    let spoilt = [b"v -1\xe9 -1 -1\n".as_slice(), rest].concat();
    let e = load_mesh(&write(&d, "spoilt.obj", &spoilt))
        .unwrap_err()
        .to_string();
    assert!(e.contains("spoilt.obj") && e.contains("line 1"), "{e}");
    let binary = [CUBE_OBJ.as_bytes(), b"\0\0"].concat();
    let e = load_mesh(&write(&d, "nul.obj", &binary))
        .unwrap_err()
        .to_string();
    assert!(e.contains("it is not text"), "{e}");
    // Remove one quad: four boundary edges.
    let open = CUBE_OBJ.replace("f 2 4 8 6\n", "");
    let e = load_mesh(&write(&d, "open.obj", open.as_bytes()))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("open.obj") && e.contains("4 boundary edges"),
        "{e}"
    );
    // Flip one quad: inconsistent orientation.
    let flipped = CUBE_OBJ.replace("f 2 4 8 6", "f 6 8 4 2");
    let e = load_mesh(&write(&d, "flip.obj", flipped.as_bytes()))
        .unwrap_err()
        .to_string();
    assert!(e.contains("consistently oriented"), "{e}");
}

/// Each `o` (object) or `g` (group) line after faces starts a new model in tobj, which
/// numbers every model's vertices from 0: the loader offsets them by the vertices of the
/// models before. Two objects, A the cube [-1, 1]³ of CUBE_OBJ and B the same cube 3 along
/// x (its vertices 9 to 16, numbered on through the file as OBJ counts), load as both: 24
/// triangles, bounds [-1, 4] × [-1, 1]², volume 2 × 2³ = 16 (without the offset B's faces
/// named A's vertices: A's faces twice). One cube split into two groups loads as the plain
/// file.
#[test]
fn obj_objects_and_groups_keep_their_own_vertices() {
    let d = tempfile::tempdir().unwrap();
    let (verts, faces) = CUBE_OBJ.split_at(CUBE_OBJ.find('f').unwrap());
    let shifted: String = verts
        .lines()
        .map(|l| {
            let c: Vec<f32> = l[2..].split(' ').map(|w| w.parse().unwrap()).collect();
            format!("v {} {} {}\n", c[0] + 3.0, c[1], c[2])
        })
        .collect();
    let numbered_on: String = faces
        .lines()
        .map(|l| {
            let idx: Vec<String> = l[2..]
                .split(' ')
                .map(|i| (i.parse::<u32>().unwrap() + 8).to_string())
                .collect();
            format!("f {}\n", idx.join(" "))
        })
        .collect();
    let two = format!("o A\n{CUBE_OBJ}o B\n{shifted}{numbered_on}");
    let m = load_mesh(&write(&d, "two.obj", two.as_bytes())).unwrap();
    assert_eq!(m.triangles.len(), 24);
    assert_eq!(
        m.bounds(),
        (
            glam::Vec3::new(-1.0, -1.0, -1.0),
            glam::Vec3::new(4.0, 1.0, 1.0)
        )
    );
    let (v, _) = volume_and_area(&m);
    assert!((v - 16.0).abs() < 1e-9, "volume {v}");
    // The first three quads in group a, the last three in group b.
    let grouped = CUBE_OBJ
        .replacen("f ", "g a\nf ", 1)
        .replace("f 3 7 8 4\n", "g b\nf 3 7 8 4\n");
    assert_eq!(grouped.matches("\ng ").count(), 2, "{grouped}");
    // The triangles by their corners' positions (the groups' vertices are welded).
    let corners = |m: &mesh::TriMesh| {
        let mut t: Vec<[[i32; 3]; 3]> = m
            .triangles
            .iter()
            .map(|t| t.map(|i| m.positions[i as usize].to_array().map(|x| x as i32)))
            .collect();
        t.sort();
        t
    };
    let plain = load_mesh(&write(&d, "cube.obj", CUBE_OBJ.as_bytes())).unwrap();
    let m = load_mesh(&write(&d, "grouped.obj", grouped.as_bytes())).unwrap();
    assert_eq!(m.positions.len(), 8);
    assert_eq!(corners(&m), corners(&plain));
}

/// A mesh file's extension is matched whatever its case: `CUBE.OBJ` (as written by tools
/// of upper-case file systems) loads as `cube.obj` does, instead of "unknown mesh format".
#[test]
fn mesh_extensions_are_read_in_any_case() {
    let d = tempfile::tempdir().unwrap();
    let lower = load_mesh(&write(&d, "cube.obj", CUBE_OBJ.as_bytes())).unwrap();
    let upper = load_mesh(&write(&d, "CUBE.OBJ", CUBE_OBJ.as_bytes())).unwrap();
    assert_eq!(upper.triangles, lower.triangles);
    assert_eq!(upper.positions, lower.positions);
}

/// Vertices are welded by position with −0 equal to +0: a tetrahedron (volume 1/6) whose
/// corner at the origin is written twice, once as `0 0 0` and once as `-0 -0 -0`, each copy
/// used by some faces, is one closed surface of 4 vertices. By their bits the two copies
/// differ (0x80000000), and the surface was refused as open.
#[test]
fn a_vertex_written_as_minus_zero_is_welded_to_zero() {
    let d = tempfile::tempdir().unwrap();
    let obj = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nv -0 -0 -0\n\
               f 1 3 2\nf 1 2 4\nf 5 4 3\nf 2 3 4\n";
    let m = load_mesh(&write(&d, "signed_zero.obj", obj.as_bytes())).unwrap();
    assert_eq!((m.positions.len(), m.triangles.len()), (4, 4));
    let (v, _) = volume_and_area(&m);
    assert!((v - 1.0 / 6.0).abs() < 1e-7, "volume {v}");
}

#[test]
fn broken_files_give_clear_errors() {
    let d = tempfile::tempdir().unwrap();
    let ply = std::fs::read(asset("bunny.ply")).unwrap();
    let e = load_mesh(&write(&d, "t.ply", &ply[..ply.len() / 2]))
        .unwrap_err()
        .to_string();
    assert!(e.contains("t.ply") && e.contains("truncated"), "{e}");
    // A fractional list length would silently shift the rest of an ASCII body.
    let tet = "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\n\
               property float z\nelement face 4\nproperty list uchar int vertex_indices\n\
               end_header\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n3 0 2 1\n3 0 1 3\n3 0 3 2\n3 1 2 3\n";
    assert!(load_mesh(&write(&d, "tet.ply", tet.as_bytes())).is_ok());
    // With a UTF-8 byte-order mark, the same tetrahedron.
    let bom = load_mesh(&write(&d, "bom.ply", format!("\u{feff}{tet}").as_bytes())).unwrap();
    assert_eq!(
        bom.triangles,
        load_mesh(&write(&d, "t2.ply", tet.as_bytes()))
            .unwrap()
            .triangles
    );
    let frac = tet.replace("3 0 1 3\n", "3.7 0 1 3\n");
    let e = load_mesh(&write(&d, "frac.ply", frac.as_bytes()))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("frac.ply") && e.contains("face 2: `3.7` is not a uchar value"),
        "{e}"
    );
    // An integer property holding a value beyond its type, or a PLY version other than
    // 1.0 (the only one): a damaged or mislabelled file.
    for (from, to, want) in [
        (
            "3 1 2 3\n",
            "300 1 2 3\n",
            "face 4: `300` is not a uchar value",
        ),
        (
            "format ascii 1.0",
            "format ascii 2.0",
            "PLY version `2.0` is not supported",
        ),
    ] {
        let text = tet.replace(from, to);
        let e = load_mesh(&write(&d, "bad.ply", text.as_bytes()))
            .unwrap_err()
            .to_string();
        assert!(e.contains("bad.ply") && e.contains(want), "{to}: {e}");
    }
    // A bad value names its element and entry: an ASCII body has no other landmark.
    let word = tet.replace("0 1 0\n", "0 a 0\n");
    let e = load_mesh(&write(&d, "word.ply", word.as_bytes()))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("word.ply") && e.contains("vertex 3: `a` is not a number"),
        "{e}"
    );
    // A face index beyond the vertices, or one that is no integer, is named with its line
    // and the allowed range (tobj says only "out of bounds" or "face parse error").
    let tet_obj = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n";
    assert!(load_mesh(&write(&d, "tet.obj", tet_obj.as_bytes())).is_ok());
    for (bad, name) in [
        ("f 2 3 9\n", "oob.obj"),
        ("f 2 3 99999999999999999999\n", "huge.obj"),
    ] {
        let text = tet_obj.replace("f 2 3 4\n", bad);
        let e = load_mesh(&write(&d, name, text.as_bytes()))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains(name) && e.contains("line 8: face index") && e.contains("allowed [1, 4] "),
            "{e}"
        );
    }
    // Faces without any vertex in the file: said so (it read "allowed 1..=0").
    let e = load_mesh(&write(&d, "nov.obj", b"f 1 2 3\n"))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("nov.obj") && e.contains("the file defines no vertex"),
        "{e}"
    );
    // A vertex that is not three numbers, and a face of two vertices (which tobj dropped
    // without a word, leaving the mesh to be reported open), by line.
    // Valid variants still load: faces naming vertices defined after them (tobj allows it),
    // negative indices, v/vt/vn references, a w coordinate, CRLF.
    let variants = [
        "f 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\n",
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf -4 -2 -3\nf -4 -3 -1\nf -4 -1 -2\nf -3 -2 -1\n",
        "v 0 0 0 1\nv 1 0 0 1\nv 0 1 0 1\nv 0 0 1 1\nvt 0 0\nvn 0 0 1\n\
         f 1/1/1 3/1/1 2/1/1\nf 1//1 2//1 4//1\nf 1/1 4/ 3//\nf 2 3 4\n",
        "v 0 0 0\r\nv 1 0 0\r\nv 0 1 0\r\nv 0 0 1\r\nf 1 3 2\r\nf 1 2 4\r\nf 1 4 3\r\nf 2 3 4\r\n",
        // Vertex colours.
        "v 0 0 0 1 0 0\nv 1 0 0 0 1 0\nv 0 1 0 0 0 1\nv 0 0 1 1 1 1\n\
         f 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n",
        // Colours on some vertices only (tobj refused it: "face vertex color index out of
        // bounds", naming no line); colours are not read.
        "v 0 0 0 1 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n",
        // A 1-D texture coordinate (`vt u`), which tobj refuses: texture coordinates are
        // not read.
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nvt 0.5\nf 1/1 3/1 2/1\nf 1 2 4\nf 1 4 3\nf 2 3 4\n",
    ];
    for (i, text) in variants.iter().enumerate() {
        let name = format!("ok{i}.obj");
        let m = load_mesh(&write(&d, &name, text.as_bytes()));
        assert!(m.is_ok_and(|m| m.triangles.len() == 4), "{name}");
    }
    // A weight divides x y z (the format's homogeneous coordinate, as tobj reads it):
    // the tetrahedron written at twice its size with w = 2 is the unit one.
    let weighted = tet_obj
        .replace("v 1 0 0\n", "v 2 0 0 2\n")
        .replace("v 0 1 0\n", "v 0 2 0 2\n")
        .replace("v 0 0 1\n", "v 0 0 2 2\n");
    assert!(
        ["v 2 0 0 2\n", "v 0 2 0 2\n", "v 0 0 2 2\n"]
            .iter()
            .all(|v| weighted.contains(v))
    );
    let (lo, hi) = load_mesh(&write(&d, "w.obj", weighted.as_bytes()))
        .unwrap()
        .bounds();
    assert_eq!((lo, hi), (glam::Vec3::ZERO, glam::Vec3::ONE), "w = 2");
    let cases = [
        (
            "v 0 0 1\n",
            "v 0 0 abc\n",
            "line 4: vertex `v 0 0 abc` needs three numbers",
        ),
        (
            "v 0 0 1\n",
            "v 0 0\n",
            "line 4: vertex `v 0 0` needs three numbers",
        ),
        // What follows x y z is a weight, a colour or nothing (tobj said "position parse
        // error" and "color parse error", naming no line).
        (
            "v 0 0 1\n",
            "v 0 0 1 x\n",
            "line 4: vertex `v 0 0 1 x` is not `v x y z`, `v x y z w` (w not 0) or",
        ),
        (
            "v 0 0 1\n",
            "v 0 0 1 0\n",
            "line 4: vertex `v 0 0 1 0` is not",
        ),
        (
            "v 0 0 1\n",
            "v 0 0 1 1 2 3 4\n",
            "line 4: vertex `v 0 0 1 1 2 3 4` is not",
        ),
        (
            "v 0 0 1\n",
            "v 0 0 1 1 2\n",
            "line 4: vertex `v 0 0 1 1 2` is not",
        ),
        (
            "f 2 3 4\n",
            "f 2 3\n",
            "line 8: face `f 2 3` has 2 vertices: a face needs at least 3",
        ),
        // References of other words than v, v/vt, v//vn, v/vt/vn (read as vertices 2, 3).
        (
            "f 2 3 4\n",
            "f 2/x/y 3 4\n",
            "line 8: face vertex `2/x/y` is not v, v/vt, v//vn or v/vt/vn",
        ),
        (
            "f 2 3 4\n",
            "f 2 3/// 4\n",
            "line 8: face vertex `3///` is not",
        ),
        // One bad part of two is enough.
        (
            "f 2 3 4\n",
            "f 2/1/x 3 4\n",
            "line 8: face vertex `2/1/x` is not v, v/vt, v//vn or v/vt/vn",
        ),
    ];
    for (i, (from, to, needle)) in cases.into_iter().enumerate() {
        let name = format!("bad{i}.obj");
        let text = tet_obj.replace(from, to);
        let e = load_mesh(&write(&d, &name, text.as_bytes()))
            .unwrap_err()
            .to_string();
        assert!(e.contains(&name) && e.contains(needle), "{e}");
    }
    let e = load_mesh(&write(&d, "g.glb", b"glTF garbage"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("g.glb"), "{e}");
    // A .glb without the binary magic: said so, not a JSON parser's complaint.
    let e = load_mesh(&write(&d, "m.glb", b"gltF\x02\0\0\0 flipped"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("m.glb") && e.contains("GLB magic"), "{e}");
    // The shipped bunny cut short: the GLB header's length says so (gltf said "could not
    // completely read the object"); bytes after its end are ignored, as gltf does.
    let glb = std::fs::read(asset("bunny.glb")).unwrap();
    let e = load_mesh(&write(&d, "cut.glb", &glb[..glb.len() - 1000]))
        .unwrap_err()
        .to_string();
    assert!(e.contains("cut.glb") && e.contains("truncated"), "{e}");
    // Cut within its 12-byte header (gltf: "failed to fill whole buffer").
    let e = load_mesh(&write(&d, "stub.glb", &glb[..11]))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("stub.glb") && e.contains("truncated GLB file: 11 bytes"),
        "{e}"
    );
    // Cut within the magic itself: 1–3 bytes of "glTF" (other short files are not GLBs).
    for n in 1..4 {
        let e = load_mesh(&write(&d, "magic.glb", &glb[..n]))
            .unwrap_err()
            .to_string();
        assert!(e.contains(&format!("truncated GLB file: {n} bytes")), "{e}");
    }
    let e = load_mesh(&write(&d, "gx.glb", b"gx"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("GLB magic"), "{e}");
    let mut long = glb.clone();
    long.extend_from_slice(&[0; 16]);
    assert!(load_mesh(&write(&d, "long.glb", &long)).is_ok());
    let e = load_mesh(&write(&d, "x.stl", b"solid"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("unknown mesh format"), "{e}");
    let e = load_mesh(&d.path().join("missing.obj"))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("missing.obj") && e.contains("cannot open") && e.contains("No such file"),
        "{e}"
    );
    std::fs::create_dir(d.path().join("dir.ply")).unwrap();
    let e = load_mesh(&d.path().join("dir.ply"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("dir.ply") && e.contains("directory"), "{e}");
}

/// Negative OBJ indices count back over the vertices defined before the face, not the
/// whole file's; an index past the file's vertices in a face before any vertex names the
/// file's range only.
#[test]
fn obj_negative_indices_count_back_over_the_vertices_before_the_face() {
    let d = tempfile::tempdir().unwrap();
    let text = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf -3 -1 -4\nv 0 0 1\nf 1 2 4\nf 1 4 3\nf 2 3 4\n";
    let e = load_mesh(&write(&d, "back.obj", text.as_bytes()))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("back.obj")
            && e.contains(
                "line 4: face index `-4` names no vertex: allowed [1, 4] for the file's 4 \
                 vertices, or [-3, -1] counting back over the 3 defined before it"
            ),
        "{e}"
    );
    let first = b"f 1 2 9\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\n";
    let e = load_mesh(&write(&d, "first.obj", first))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("first.obj")
            && e.contains(
                "line 1: face index `9` names no vertex: allowed [1, 4] for the file's 4 vertices"
            )
            && !e.contains("counting back"),
        "{e}"
    );
}
