//! The built-in shapes a scene can name instead of a mesh file.

use std::collections::HashMap;

use glam::Vec3;

use super::TriMesh;

/// A UV-free icosphere of the given radius (subdivision 5: 20,480 triangles, the chord
/// error is below 0.03 % of the radius).
pub fn sphere(radius: f32) -> TriMesh {
    let t = (1.0 + 5f32.sqrt()) / 2.0;
    let mut positions: Vec<Vec3> = [
        [-1.0, t, 0.0],
        [1.0, t, 0.0],
        [-1.0, -t, 0.0],
        [1.0, -t, 0.0],
        [0.0, -1.0, t],
        [0.0, 1.0, t],
        [0.0, -1.0, -t],
        [0.0, 1.0, -t],
        [t, 0.0, -1.0],
        [t, 0.0, 1.0],
        [-t, 0.0, -1.0],
        [-t, 0.0, 1.0],
    ]
    .iter()
    .map(|p| Vec3::from_array(*p).normalize())
    .collect();
    let mut tris: Vec<[u32; 3]> = vec![
        [0, 11, 5],
        [0, 5, 1],
        [0, 1, 7],
        [0, 7, 10],
        [0, 10, 11],
        [1, 5, 9],
        [5, 11, 4],
        [11, 10, 2],
        [10, 7, 6],
        [7, 1, 8],
        [3, 9, 4],
        [3, 4, 2],
        [3, 2, 6],
        [3, 6, 8],
        [3, 8, 9],
        [4, 9, 5],
        [2, 4, 11],
        [6, 2, 10],
        [8, 6, 7],
        [9, 8, 1],
    ];
    for _ in 0..5 {
        let mut mid: HashMap<(u32, u32), u32> = HashMap::new();
        let mut next = Vec::with_capacity(tris.len() * 4);
        let mut midpoint = |a: u32, b: u32, positions: &mut Vec<Vec3>| {
            *mid.entry((a.min(b), a.max(b))).or_insert_with(|| {
                positions.push(((positions[a as usize] + positions[b as usize]) * 0.5).normalize());
                positions.len() as u32 - 1
            })
        };
        for [a, b, c] in tris {
            let ab = midpoint(a, b, &mut positions);
            let bc = midpoint(b, c, &mut positions);
            let ca = midpoint(c, a, &mut positions);
            next.extend([[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]);
        }
        tris = next;
    }
    for p in &mut positions {
        *p *= radius;
    }
    TriMesh {
        positions,
        triangles: tris,
    }
}

/// An axis-aligned cube of edge `size` centred at the origin.
pub fn cube(size: f32) -> TriMesh {
    let h = size / 2.0;
    let positions = (0..8)
        .map(|i| {
            Vec3::new(
                if i & 1 != 0 { h } else { -h },
                if i & 2 != 0 { h } else { -h },
                if i & 4 != 0 { h } else { -h },
            )
        })
        .collect();
    let triangles = vec![
        [0, 2, 3],
        [0, 3, 1], // z = -h
        [4, 5, 7],
        [4, 7, 6], // z = +h
        [0, 1, 5],
        [0, 5, 4], // y = -h
        [2, 6, 7],
        [2, 7, 3], // y = +h
        [0, 4, 6],
        [0, 6, 2], // x = -h
        [1, 3, 7],
        [1, 7, 5], // x = +h
    ];
    TriMesh {
        positions,
        triangles,
    }
}

/// A closed (2, 3) torus knot: a tube of radius 0.35 swept along the knot curve
/// ((2 + cos 3t) cos 2t, (2 + cos 3t) sin 2t, −sin 3t), about 6.7 units wide; the scene's
/// `height` rescales it. The tube's frame is transported along the curve, and the faces
/// are oriented outward.
///
/// Transported once around, the frame comes back turned by ~174° (the curve's holonomy),
/// so that turn is spread evenly over the rings. Left in the last segment, as it was until
/// 2026-11-28, it folded that band of triangles through itself, and 0.6 % of all paths
/// were found outside the knot while believing themselves inside.
pub fn torus_knot() -> TriMesh {
    const SEG: usize = 240;
    const RING: usize = 12;
    const TUBE: f32 = 0.35;
    let curve = |t: f32| {
        let r = 2.0 + (3.0 * t).cos();
        Vec3::new(r * (2.0 * t).cos(), r * (2.0 * t).sin(), -(3.0 * t).sin())
    };
    let tau = std::f32::consts::TAU;
    let tangent = |t: f32| (curve(t + 1e-3) - curve(t - 1e-3)).normalize();
    // Parallel transport: remove the tangential part and renormalise.
    let transport = |normal: Vec3, t: f32| {
        let tan = tangent(t);
        (normal - tan * normal.dot(tan)).normalize()
    };
    let start = tangent(0.0).any_orthonormal_vector();
    let frames: Vec<Vec3> = (0..SEG)
        .scan(start, |normal, i| {
            *normal = transport(*normal, tau * i as f32 / SEG as f32);
            Some(*normal)
        })
        .collect();
    // Back at t = 2π (= 0): the frame's turn against the one it started from.
    let back = transport(frames[SEG - 1], tau);
    let twist = back
        .dot(tangent(0.0).cross(frames[0]))
        .atan2(back.dot(frames[0]));
    let mut positions = Vec::with_capacity(SEG * RING);
    for (i, &normal) in frames.iter().enumerate() {
        let t = tau * i as f32 / SEG as f32;
        let binormal = tangent(t).cross(normal);
        let c = curve(t);
        let turn = -twist * i as f32 / SEG as f32;
        for k in 0..RING {
            let a = tau * k as f32 / RING as f32 + turn;
            positions.push(c + (normal * a.cos() + binormal * a.sin()) * TUBE);
        }
    }
    let mut triangles = Vec::with_capacity(SEG * RING * 2);
    for i in 0..SEG {
        let i2 = (i + 1) % SEG;
        for k in 0..RING {
            let k2 = (k + 1) % RING;
            let (a, b) = ((i * RING + k) as u32, (i * RING + k2) as u32);
            let (c, d) = ((i2 * RING + k) as u32, (i2 * RING + k2) as u32);
            triangles.push([a, c, d]);
            triangles.push([a, d, b]);
        }
    }
    let mut m = TriMesh {
        positions,
        triangles,
    };
    if m.signed_volume6() < 0.0 {
        for t in &mut m.triangles {
            t.swap(1, 2);
        }
    }
    m
}
