//! The shipped and generated shapes, and what every loaded mesh must be: closed, wound
//! outward, of some volume, centred and scaled as documented, its faces cut inside their
//! outlines.

use super::*;

#[test]
fn shipped_bunny_loads_closed_from_glb_and_ply() {
    let a = load_mesh(&asset("bunny.glb")).unwrap();
    let b = load_mesh(&asset("bunny.ply")).unwrap();
    // A closed genus-0 surface: V − E + F = 2 with E = 3F/2.
    for m in [&a, &b] {
        let (v, f) = (m.positions.len() as i64, m.triangles.len() as i64);
        assert_eq!(v - 3 * f / 2 + f, 2, "Euler characteristic");
    }
    assert_eq!(a.triangles.len(), b.triangles.len());
    let (lo, hi) = b.bounds();
    assert!(
        (hi.y - lo.y - 1.0).abs() < 1e-3,
        "the shipped PLY has height 1"
    );
}

/// The built-in shapes face outward as built, checked here without the crate's own
/// orientation code (which `prepare` uses, so `prepare(m) == m` alone would pass inward
/// shapes if it never turned anything): both are convex and centred at the origin, so
/// every face's normal points away from it, and the signed volume is the shape's
/// (the cube's exactly, the triangulated sphere's a little under 4/3·π·0.5³).
#[test]
fn shapes_are_closed_and_outward() {
    let ball = 4.0 / 3.0 * std::f64::consts::PI * 0.125;
    for (m, volume, tol) in [
        (mesh::sphere(0.5), ball, 0.02 * ball),
        (mesh::cube(1.0), 1.0, 1e-6),
    ] {
        let mut v6 = 0.0;
        for t in &m.triangles {
            let [a, b, c] = t.map(|i| m.positions[i as usize].as_dvec3());
            let outward = (b - a).cross(c - a).dot((a + b + c) / 3.0);
            assert!(outward > 0.0, "a face turned inward: {t:?}");
            v6 += a.dot(b.cross(c));
        }
        let v = v6 / 6.0;
        assert!(
            v <= volume + 1e-9 && v > volume - tol,
            "volume {v}, expected {volume} − [0, {tol}]"
        );
        let p = mesh::prepare(m.clone()).unwrap();
        assert_eq!(p.triangles, m.triangles, "already outward-oriented");
    }
}

/// `object.height` scales the mesh about its box's centre and puts that centre at the
/// origin: a box from (4, 6, −3) to (6, 10, −2) made 1 high spans ±0.25 × ±0.5 × ±0.125.
/// (Every other mesh it is tested on is centred already, where scaling first and moving
/// after gives the same box.)
#[test]
fn height_scales_about_the_centre_and_centres_the_mesh() {
    let mut m = mesh::cube(1.0);
    for p in &mut m.positions {
        *p = *p * glam::Vec3::new(2.0, 4.0, 1.0) + glam::Vec3::new(5.0, 8.0, -2.5);
    }
    m.normalise_height(1.0).unwrap();
    let (lo, hi) = m.bounds();
    let want = glam::Vec3::new(0.25, 0.5, 0.125);
    assert!(
        (lo + want).abs().max_element() < 1e-6 && (hi - want).abs().max_element() < 1e-6,
        "{lo}..{hi}"
    );
}

/// A mesh with no inside is refused: every triangle degenerate, or a closed but flat
/// surface (two faces of one triangle), or one that `height` cannot scale.
#[test]
fn meshes_without_volume_are_refused() {
    let d = tempfile::tempdir().unwrap();
    let e = load_mesh(&write(
        &d,
        "line.obj",
        b"v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\nf 1 3 2\n",
    ))
    .unwrap_err()
    .to_string();
    assert!(e.contains("line.obj") && e.contains("degenerate"), "{e}");
    let flat = write(
        &d,
        "flat.obj",
        b"v 0 0 0\nv 1 0 0\nv 0 0 1\nf 1 2 3\nf 1 3 2\n",
    );
    let scene = |extra: &str| {
        render_gpu::scene::SceneFile::parse(
            &d.path().join("s.toml"),
            &format!(
                "[camera]\norigin = [0.0, 0.0, 4.0]\ntarget = [0.0, 0.0, 0.0]\nfov_deg = 20.0\n\
                 width = 8\nheight = 8\n[object]\nmesh = \"flat.obj\"\n{extra}\n\
                 [medium]\nsigma_t = [1.0, 1.0, 1.0]\nalbedo = [1.0, 1.0, 1.0]\n"
            ),
        )
        .unwrap()
    };
    assert!(flat.exists());
    let e = render_gpu::setup::object_mesh(&scene(""), d.path())
        .unwrap_err()
        .to_string();
    assert!(e.contains("flat.obj") && e.contains("no volume"), "{e}");
    // With a height to scale to as well: a flat mesh has none (refused as flat first).
    let e = render_gpu::setup::object_mesh(&scene("height = 1.0"), d.path())
        .unwrap_err()
        .to_string();
    assert!(e.contains("flat.obj") && e.contains("no volume"), "{e}");
    // A cube near f32's largest value is refused by its size, before the checks that
    // square edge lengths (which called one "not closed"); 10¹⁵ across is still loaded,
    // for object.height to scale.
    for (size, refused) in [("3e38", true), ("1e16", true), ("1e15", false)] {
        let text: String = CUBE_OBJ
            .lines()
            .map(|l| match l.strip_prefix("v ") {
                Some(v) => {
                    // Every coordinate of CUBE_OBJ is ±1.
                    let v: Vec<String> = v
                        .split(' ')
                        .map(|x| format!("{}{size}", if x.starts_with('-') { "-" } else { "" }))
                        .collect();
                    format!("v {}\n", v.join(" "))
                }
                None => format!("{l}\n"),
            })
            .collect();
        assert!(
            text.contains(&format!("v -{size} -{size} -{size}\n")),
            "{text}"
        );
        let r = load_mesh(&write(&d, "far.obj", text.as_bytes()));
        assert_eq!(
            r.is_err(),
            refused,
            "{size}: {:?}",
            r.err().map(|e| e.to_string())
        );
        if let Err(e) = r {
            let e = e.to_string();
            assert!(e.contains("far.obj") && e.contains("beyond ±1e15"), "{e}");
        }
    }
    // The cube passes the same checks.
    write(&d, "flat.obj", CUBE_OBJ.as_bytes());
    let m = render_gpu::setup::object_mesh(&scene("height = 1.0"), d.path()).unwrap();
    let (lo, hi) = m.bounds();
    assert!((hi.y - lo.y - 1.0).abs() < 1e-6);
}

/// An L-shaped prism (a 2×2 square less a 1×1 corner, 1 deep) whose end caps are
/// hexagons listed from each of their six vertices in turn: every listing must cut into
/// the same area, 2·3 + 8·1 = 14, and volume 3. A fan from the first vertex covers the
/// notch from some starts (15 instead of 14 from the first), and its extra faces still
/// pair up, so the mesh passes as closed.
#[test]
fn concave_faces_are_cut_inside_their_outline() {
    let outline = [(0, 0), (2, 0), (2, 1), (1, 1), (1, 2), (0, 2)];
    let d = tempfile::tempdir().unwrap();
    for start in 0..6 {
        // Vertices 1..=6 at z = 0, 7..=12 at z = 1 (OBJ numbering).
        let mut verts = Vec::new();
        for z in [0, 1] {
            for (x, y) in outline {
                verts.push(format!("{x} {y} {z}"));
            }
        }
        let rot = |k: usize, z: usize| (k + start) % 6 + 1 + 6 * z;
        // Bottom cap seen from below (clockwise from above), top cap counter-clockwise.
        let mut bottom: Vec<usize> = (0..6).rev().map(|k| rot(k, 0)).collect();
        // The bottom cap closed by listing its first vertex again at its end (as other
        // exporters write), which must not send it back to the fan either.
        bottom.push(bottom[0]);
        let mut top: Vec<usize> = (0..6).map(|k| rot(k, 1)).collect();
        // One vertex listed twice in a row on the top cap (as some exporters write): it
        // adds nothing, and must not send the cap back to the fan.
        top.insert(start % 5 + 1, top[start % 5]);
        let mut faces = vec![bottom, top];
        for k in 0..6 {
            let k2 = (k + 1) % 6;
            faces.push(vec![k + 1, k2 + 1, k2 + 7, k + 7]);
        }
        let obj: String = verts.iter().map(|v| format!("v {v}\n")).collect::<String>()
            + &faces
                .iter()
                .map(|f| {
                    format!(
                        "f {}\n",
                        f.iter()
                            .map(|i| i.to_string())
                            .collect::<Vec<_>>()
                            .join(" ")
                    )
                })
                .collect::<String>();
        let ply = format!(
            "ply\nformat ascii 1.0\nelement vertex 12\nproperty float x\nproperty float y\n\
             property float z\nelement face {}\nproperty list uchar int vertex_indices\n\
             end_header\n{}\n{}\n",
            faces.len(),
            verts.join("\n"),
            faces
                .iter()
                .map(|f| format!(
                    "{} {}",
                    f.len(),
                    f.iter()
                        .map(|i| (i - 1).to_string())
                        .collect::<Vec<_>>()
                        .join(" ")
                ))
                .collect::<Vec<_>>()
                .join("\n")
        );
        for (name, text) in [("l.obj", obj), ("l.ply", ply)] {
            let m = load_mesh(&write(&d, name, text.as_bytes())).unwrap();
            let (v, a) = volume_and_area(&m);
            assert!(
                (v - 3.0).abs() < 1e-5 && (a - 14.0).abs() < 1e-5,
                "{name} listed from vertex {start}: volume {v} (want 3), area {a} (want 14)"
            );
            assert_eq!(m.triangles.len(), 2 * 4 + 6 * 2, "{name}");
        }
    }
}

/// A closed mesh flattened to a plane (its top and bottom weld into faces listed twice)
/// is named flat, as the README says, not "a two-sided export".
#[test]
fn a_flat_closed_mesh_is_named_flat() {
    let d = tempfile::tempdir().unwrap();
    // CUBE_OBJ with each vertex moved by `f`.
    let moved = |f: fn([f64; 3]) -> [f64; 3]| -> String {
        CUBE_OBJ
            .lines()
            .map(|l| match l.strip_prefix("v ") {
                Some(v) => {
                    let xyz: Vec<f64> = v.split(' ').map(|w| w.parse().unwrap()).collect();
                    let [x, y, z] = f([xyz[0], xyz[1], xyz[2]]);
                    format!("v {x} {y} {z}\n")
                }
                None => format!("{l}\n"),
            })
            .collect()
    };
    let flat = moved(|[x, y, _]| [x, y, 0.0]);
    let e = load_mesh(&write(&d, "flat.obj", flat.as_bytes()))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("encloses no volume") && e.ends_with("(it is flat)"),
        "{e}"
    );
    // A unit cube moved to x = 10⁷ in the file, where f32 steps by 1: read flat, and
    // said why it may be.
    let far = moved(|[x, y, z]| [0.5 * x + 1e7, y, z]);
    let e = load_mesh(&write(&d, "far.obj", far.as_bytes()))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("single precision rounded it flat as it was read: its coordinates reach 1e7"),
        "{e}"
    );
}

/// A surface closed only through a zero-area triangle (a T-junction's filler) is open
/// once that triangle is dropped, and the message says why.
#[test]
fn a_surface_closed_by_zero_area_triangles_is_explained() {
    let mut m = mesh::cube(1.0);
    // Split the edge a→b of the first triangle at its midpoint on the other side only.
    let [a, b, _] = m.triangles[0];
    let k = m
        .triangles
        .iter()
        .position(|t| (0..3).any(|i| t[i] == b && t[(i + 1) % 3] == a))
        .unwrap();
    let t = m.triangles[k];
    let i = (0..3).find(|&i| t[i] == b).unwrap();
    let other = t[(i + 2) % 3];
    let mid = m.positions.len() as u32;
    m.positions
        .push((m.positions[a as usize] + m.positions[b as usize]) / 2.0);
    m.triangles[k] = [b, mid, other];
    m.triangles.push([mid, a, other]);
    m.triangles.push([b, a, mid]); // the filler: edges b→a, a→mid, mid→b
    let e = mesh::prepare(m).unwrap_err();
    assert!(
        e.contains("3 boundary edges") && e.contains("1 zero-area triangles were dropped"),
        "{e}"
    );
}

/// The torus knot is a tube around its curve: every triangle lies about the tube's radius
/// (0.35) from the curve and faces away from it. Its closing band, which carried the whole
/// ~174° turn of the transported frame until 2026-11-28, folded through the tube (paths
/// then leaked in 0.6 % of samples); such triangles face the curve or cut across the tube.
/// The nearest curve point is searched among 4,800 samples (spacing ~0.006): the radius is
/// held to 0.30–0.36 (a flat facet's centroid sits at most ~4 % inside the circle of a
/// 12-sided ring).
#[test]
fn the_torus_knot_is_a_tube_around_its_curve() {
    let m = mesh::torus_knot();
    let curve: Vec<glam::Vec3> = (0..4800)
        .map(|i| {
            let t = std::f32::consts::TAU * i as f32 / 4800.0;
            let r = 2.0 + (3.0 * t).cos();
            glam::Vec3::new(r * (2.0 * t).cos(), r * (2.0 * t).sin(), -(3.0 * t).sin())
        })
        .collect();
    for (k, t) in m.triangles.iter().enumerate() {
        let [a, b, c] = t.map(|i| m.positions[i as usize]);
        let centroid = (a + b + c) / 3.0;
        let normal = (b - a).cross(c - a).normalize();
        let nearest = curve
            .iter()
            .copied()
            .min_by(|p, q| {
                p.distance_squared(centroid)
                    .total_cmp(&q.distance_squared(centroid))
            })
            .unwrap();
        let out = centroid - nearest;
        assert!(
            (0.30..0.36).contains(&out.length()) && normal.dot(out.normalize()) > 0.5,
            "triangle {k}: {} from the curve, facing {:.2} away from it",
            out.length(),
            normal.dot(out.normalize())
        );
    }
}

/// Inputs whose size grew without bound in memory or time are refused by name: a GLB
/// listing 100,000 buffers that each named its binary chunk (each copied it: 100 GB from
/// 1 MB), nodes placing a mesh more often than the triangle limit allows, a face of more
/// vertices than ear clipping is given. A piece with no volume beside one that has it
/// (a two-sided face) is refused, where the whole mesh's volume let it through.
#[test]
fn inputs_that_grow_without_bound_or_hide_a_flat_piece_are_refused() {
    let d = tempfile::tempdir().unwrap();
    let bin = cube_bin();
    let doc = |buffers: &str, nodes: &str, primitives: usize| {
        let prim = r#"{"attributes":{"POSITION":0},"indices":1}"#;
        let prims = vec![prim; primitives].join(",");
        format!(
            r#"{{"asset":{{"version":"2.0"}},"scene":0,"scenes":[{{"nodes":[{nodes}]}}],
            "nodes":[{}],"meshes":[{{"primitives":[{prims}]}}],
            "buffers":[{buffers}],
            "bufferViews":[{{"buffer":0,"byteOffset":0,"byteLength":96}},
                           {{"buffer":0,"byteOffset":96,"byteLength":72}}],
            "accessors":[{{"bufferView":0,"componentType":5126,"count":8,"type":"VEC3",
                           "min":[-0.5,-0.5,-0.5],"max":[0.5,0.5,0.5]}},
                         {{"bufferView":1,"componentType":5123,"count":36,"type":"SCALAR"}}]}}"#,
            vec![r#"{"mesh":0}"#; nodes.split(',').count()].join(",")
        )
    };
    // The plain GLB loads.
    let one = r#"{"byteLength":168}"#;
    let ok = write(&d, "one.glb", &glb(&doc(one, "0", 1), &bin));
    assert_eq!(load_mesh(&ok).unwrap().triangles.len(), 12);
    let many = [one, &vec![r#"{"byteLength":1}"#; 100_000].join(",")].join(",");
    let e = load_mesh(&write(&d, "many.glb", &glb(&doc(&many, "0", 1), &bin)))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("many.glb") && e.contains("buffer 1 refers to the GLB binary chunk"),
        "{e}"
    );
    // Buffers declaring more than memory holds (two of 2^62 bytes: their sum overflowed u64
    // in a build with overflow checks) are refused before any is read.
    let huge = r#"{"byteLength":4611686018427387904},{"byteLength":4611686018427387904}"#;
    let huge = [one, huge].join(",").replace(
        r#"{"byteLength":4611"#,
        r#"{"uri":"x.bin","byteLength":4611"#,
    );
    let e = load_mesh(&write(&d, "huge.glb", &glb(&doc(&huge, "0", 1), &bin)))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("huge.glb: its buffers declare") && e.contains("more than can be allocated"),
        "{e}"
    );
    // 140 nodes over a mesh of 20,000 primitives of 12 triangles each: 33.6 M > 2^25.
    let nodes: Vec<String> = (0..140).map(|i| i.to_string()).collect();
    let e = load_mesh(&write(
        &d,
        "copies.glb",
        &glb(&doc(one, &nodes.join(","), 20_000), &bin),
    ))
    .unwrap_err()
    .to_string();
    assert!(
        e.contains("copies.glb")
            && e.contains(&format!(
                "its nodes place more than {} triangles or vertices",
                mesh::MAX_GLTF_TRIANGLES
            )),
        "{e}"
    );
    // One face of 5,000 vertices (a circle): refused, naming the face.
    let n = mesh::MAX_FACE_VERTICES + 904;
    let mut obj = String::new();
    for k in 0..n {
        let a = k as f64 / n as f64 * std::f64::consts::TAU;
        obj += &format!("v {} {} 0\n", a.cos(), a.sin());
    }
    obj += "v 0 0 1\nf";
    for k in 1..=n {
        obj += &format!(" {k}");
    }
    obj += "\n";
    for k in 1..=n {
        obj += &format!("f {} {k} {}\n", n + 1, k % n + 1);
    }
    let e = load_mesh(&write(&d, "cone.obj", obj.as_bytes()))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("cone.obj") && e.contains(&format!("face 0 has {n} vertices: at most 4096")),
        "{e}"
    );
    // A cube beside a face listed twice, once each way: every edge is used once in each
    // direction, so only the piece's own volume tells.
    let cube = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nv 0 0 1\nv 1 0 1\nv 0 1 1\nv 1 1 1\n\
                f 1 3 4\nf 1 4 2\nf 5 6 8\nf 5 8 7\nf 1 2 6\nf 1 6 5\nf 3 7 8\nf 3 8 4\n\
                f 1 5 7\nf 1 7 3\nf 2 4 8\nf 2 8 6\n";
    let two_sided = format!("{cube}v 3 0 0\nv 4 0 0\nv 3 1 0\nf 9 10 11\nf 9 11 10\n");
    let e = load_mesh(&write(&d, "twosided.obj", two_sided.as_bytes()))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("twosided.obj")
            && e.contains("2 triangles")
            && e.contains("encloses no volume")
            && e.contains("two-sided"),
        "{e}"
    );
    // What the renderer does not read is not read: a polyline of three points (read as a
    // face, and the cube refused as "faces listed twice"), texture-coordinate references
    // counting back past the `vt` lines (an overflow in the reader).
    let polyline = format!("{cube}l 1 2 3\n");
    let m = load_mesh(&write(&d, "polyline.obj", polyline.as_bytes())).unwrap();
    assert_eq!(m.triangles.len(), 12);
    let uv = cube.replace(
        "f 1 3 4\n",
        "vt 0 0\nvn 0 0 1\nf 1/-3/-5 3/-3/7 4//9223372036854775807\n",
    );
    assert_ne!(uv, cube);
    let m = load_mesh(&write(&d, "uv.obj", uv.as_bytes())).unwrap();
    assert_eq!(m.triangles.len(), 12);
    // Files that hold no faces the loader reads say why, not "no triangles".
    let e = load_mesh(&write(
        &d,
        "empty.gltf",
        br#"{"asset":{"version":"2.0"},"scenes":[{"nodes":[]}]}"#,
    ))
    .unwrap_err()
    .to_string();
    assert!(e.contains("empty.gltf: the glTF file holds no mesh"), "{e}");
    let strips = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n\
                  property float z\nelement tristrips 1\nproperty list int int vertex_indices\n\
                  end_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n";
    let e = load_mesh(&write(&d, "strips.ply", strips.as_bytes()))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("strips.ply: the PLY file has no `face` element (element `tristrips`"),
        "{e}"
    );
    // A tetrahedron 10⁻⁹ across at the origin beside a cube from 0.1 to 1.1: loaded, but
    // scaled to a height (centred at 0.55) its corners round into one point, which gave
    // its triangles NaN normals. The scaled mesh is prepared again: the speck's triangles
    // dropped, the cube stays.
    let cube_and_speck = "v 0.1 0.1 0.1\nv 1.1 0.1 0.1\nv 0.1 1.1 0.1\nv 1.1 1.1 0.1\n\
         v 0.1 0.1 1.1\nv 1.1 0.1 1.1\nv 0.1 1.1 1.1\nv 1.1 1.1 1.1\n\
         f 1 3 4\nf 1 4 2\nf 5 6 8\nf 5 8 7\nf 1 2 6\nf 1 6 5\nf 3 7 8\nf 3 8 4\n\
         f 1 5 7\nf 1 7 3\nf 2 4 8\nf 2 8 6\n\
         v 0 0 0\nv 1e-9 0 0\nv 0 1e-9 0\nv 0 0 1e-9\nf 9 11 10\nf 9 10 12\nf 9 12 11\nf 10 11 12\n";
    write(&d, "speck.obj", cube_and_speck.as_bytes());
    assert_eq!(
        load_mesh(&d.path().join("speck.obj"))
            .unwrap()
            .triangles
            .len(),
        16
    );
    let scene = render_gpu::scene::SceneFile::parse(
        &d.path().join("s.toml"),
        "[camera]\norigin = [0.0, 0.0, 4.0]\ntarget = [0.0, 0.0, 0.0]\nfov_deg = 20.0\n\
         width = 8\nheight = 8\n[object]\nmesh = \"speck.obj\"\nheight = 1.0\n\
         [medium]\nsigma_t = [1.0, 1.0, 1.0]\nalbedo = [1.0, 1.0, 1.0]\n",
    )
    .unwrap();
    let m = render_gpu::setup::object_mesh(&scene, d.path()).unwrap();
    assert_eq!(m.triangles.len(), 12);
    let (lo, hi) = m.bounds();
    assert!((hi.y - lo.y - 1.0).abs() < 1e-6, "{lo} {hi}");
    // A cube 10⁻¹³ across: its areas vanish in single precision.
    let tiny: String = cube
        .lines()
        .map(|l| match l.strip_prefix("v ") {
            Some(v) => {
                let xyz: Vec<String> = v.split(' ').map(|x| format!("{x}e-13")).collect();
                format!("v {}\n", xyz.join(" "))
            }
            None => format!("{l}\n"),
        })
        .collect();
    let e = load_mesh(&write(&d, "tiny.obj", tiny.as_bytes()))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("all 12 triangles are degenerate")
            && e.contains("too small for single precision"),
        "{e}"
    );
}

/// The built-in sphere is the icosphere `mesh::sphere` documents: subdivision 5, 20,480
/// triangles, every face within 0.03 % of the radius from the sphere (its plane's distance
/// from the centre; at most 2.85e-4 of the radius here, computed by hand in python from the
/// same construction), which the renders of `shape = "sphere"` and the tests that compare
/// them with an exact sphere take for granted. One subdivision fewer passes
/// `shapes_are_closed_and_outward` (its volume is 0.22 % short, within that test's 2 %) but
/// sags by 1.14e-3 of the radius, 5,120 triangles; one more has 81,920.
#[test]
fn the_sphere_is_as_fine_as_documented() {
    let r = 0.5f64;
    let m = mesh::sphere(r as f32);
    assert_eq!(m.triangles.len(), 20_480);
    for t in &m.triangles {
        let [a, b, c] = t.map(|i| m.positions[i as usize].as_dvec3());
        let n = (b - a).cross(c - a).normalize();
        let sag = 1.0 - n.dot(a).abs() / r;
        assert!(
            sag < 3e-4,
            "face {t:?} lies {sag:.3e} of the radius inside the sphere"
        );
    }
}
