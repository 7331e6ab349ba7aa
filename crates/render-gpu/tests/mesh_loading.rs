//! Mesh loaders on valid and broken files, and the closedness check.

use std::path::{Path, PathBuf};

use render_gpu::mesh::{self, load_mesh};

fn asset(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../assets")
        .join(name)
}

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

#[test]
fn shapes_are_closed_and_outward() {
    for m in [mesh::sphere(0.5), mesh::cube(1.0)] {
        let p = mesh::prepare(m.clone()).unwrap();
        assert_eq!(p.triangles, m.triangles, "already outward-oriented");
    }
}

fn write(dir: &tempfile::TempDir, name: &str, text: &[u8]) -> PathBuf {
    let p = dir.path().join(name);
    std::fs::write(&p, text).unwrap();
    p
}

const CUBE_OBJ: &str = "v -1 -1 -1\nv 1 -1 -1\nv -1 1 -1\nv 1 1 -1\nv -1 -1 1\nv 1 -1 1\nv -1 1 1\nv 1 1 1\n\
f 1 3 4 2\nf 5 6 8 7\nf 1 2 6 5\nf 3 7 8 4\nf 1 5 7 3\nf 2 4 8 6\n";

#[test]
fn obj_quads_load_and_an_open_mesh_is_refused() {
    let d = tempfile::tempdir().unwrap();
    let m = load_mesh(&write(&d, "cube.obj", CUBE_OBJ.as_bytes())).unwrap();
    assert_eq!(m.triangles.len(), 12);
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

#[test]
fn broken_files_give_clear_errors() {
    let d = tempfile::tempdir().unwrap();
    let ply = std::fs::read(asset("bunny.ply")).unwrap();
    let e = load_mesh(&write(&d, "t.ply", &ply[..ply.len() / 2]))
        .unwrap_err()
        .to_string();
    assert!(e.contains("t.ply") && e.contains("truncated"), "{e}");
    let e = load_mesh(&write(&d, "g.glb", b"glTF garbage"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("g.glb"), "{e}");
    let e = load_mesh(&write(&d, "x.stl", b"solid"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("unknown mesh format"), "{e}");
    let e = load_mesh(&d.path().join("missing.obj"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("missing.obj"), "{e}");
}
