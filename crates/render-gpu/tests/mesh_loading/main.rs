//! Mesh loaders (OBJ, PLY, glTF) on valid and broken files, the closedness and piece
//! checks, the scene and view hashes of what they load, and EXR inputs. The helpers the
//! modules share are here.

mod gltf;
mod images;
mod obj;
mod pieces;
mod ply;
mod scene_hashes;
mod shapes;

use std::path::{Path, PathBuf};

use render_gpu::mesh::{self, load_mesh};

fn asset(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../assets")
        .join(name)
}

fn write(dir: &tempfile::TempDir, name: &str, text: &[u8]) -> PathBuf {
    let p = dir.path().join(name);
    std::fs::write(&p, text).unwrap();
    p
}

const CUBE_OBJ: &str = "v -1 -1 -1\nv 1 -1 -1\nv -1 1 -1\nv 1 1 -1\nv -1 -1 1\nv 1 -1 1\nv -1 1 1\nv 1 1 1\n\
f 1 3 4 2\nf 5 6 8 7\nf 1 2 6 5\nf 3 7 8 4\nf 1 5 7 3\nf 2 4 8 6\n";

/// A unit cube's buffer: 8 f32 positions (96 bytes), then 36 u16 indices (72 bytes).
fn cube_bin() -> Vec<u8> {
    let mut bin = Vec::new();
    for i in 0..8u32 {
        for bit in [1, 2, 4] {
            bin.extend_from_slice(&(if i & bit != 0 { 0.5f32 } else { -0.5 }).to_le_bytes());
        }
    }
    let tris: [u16; 36] = [
        0, 2, 3, 0, 3, 1, 4, 5, 7, 4, 7, 6, 0, 1, 5, 0, 5, 4, 2, 6, 7, 2, 7, 3, 0, 4, 6, 0, 6, 2,
        1, 3, 7, 1, 7, 5,
    ];
    for t in tris {
        bin.extend_from_slice(&t.to_le_bytes());
    }
    bin
}

/// The signed volume and the surface area of a mesh, summed over its triangles here
/// (not with the crate's own helpers), to compare with a shape's closed-form values.
fn volume_and_area(m: &mesh::TriMesh) -> (f64, f64) {
    m.triangles.iter().fold((0.0, 0.0), |(v, a), t| {
        let [p, q, r] = t.map(|i| m.positions[i as usize].as_dvec3());
        (
            v + p.dot(q.cross(r)) / 6.0,
            a + (q - p).cross(r - p).length() / 2.0,
        )
    })
}

/// A mesh piece and whether it is wound inward (reversed).
type Piece = (mesh::TriMesh, bool);

/// Pieces joined into one mesh.
fn pieces(parts: &[Piece]) -> mesh::TriMesh {
    let mut m = mesh::TriMesh::default();
    for (p, reversed) in parts {
        let base = m.positions.len() as u32;
        m.positions.extend(&p.positions);
        m.triangles.extend(p.triangles.iter().map(|t| {
            let t = t.map(|i| i + base);
            if *reversed { [t[0], t[2], t[1]] } else { t }
        }));
    }
    m
}

fn moved(mut m: mesh::TriMesh, by: glam::Vec3) -> mesh::TriMesh {
    m.positions.iter_mut().for_each(|p| *p += by);
    m
}

/// The mesh with its triangles listed in `order` (a file may list them in any order).
fn listed(mut m: mesh::TriMesh, order: &[usize]) -> mesh::TriMesh {
    m.triangles = order.iter().map(|&k| m.triangles[k]).collect();
    m
}

fn scaled(mut m: mesh::TriMesh, by: glam::Vec3) -> mesh::TriMesh {
    m.positions.iter_mut().for_each(|p| *p *= by);
    m
}

/// A GLB file of `json` and the binary chunk `bin` (each chunk padded to 4 bytes).
fn glb(json: &str, bin: &[u8]) -> Vec<u8> {
    let mut j = json.as_bytes().to_vec();
    while !j.len().is_multiple_of(4) {
        j.push(b' ');
    }
    let mut b = bin.to_vec();
    while !b.len().is_multiple_of(4) {
        b.push(0);
    }
    let total = 12 + 8 + j.len() + 8 + b.len();
    let mut out = b"glTF".to_vec();
    out.extend(2u32.to_le_bytes());
    out.extend((total as u32).to_le_bytes());
    out.extend((j.len() as u32).to_le_bytes());
    out.extend(b"JSON");
    out.extend(j);
    out.extend((b.len() as u32).to_le_bytes());
    out.extend(b"BIN\0");
    out.extend(b);
    out
}
