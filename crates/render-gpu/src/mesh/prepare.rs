//! Welding a loaded mesh and checking that it bounds a medium: closed, manifold,
//! consistently wound, of finite size; then its pieces are wound outward.

use std::collections::HashMap;

use super::pieces::{flat_pieces, orient_pieces, piece_boxes, piece_volumes, pieces};
use super::{TriMesh, bounds_of, rounded_flat, zero_area};

/// Largest vertex coordinate a mesh file may hold (see `prepare`).
pub const MAX_FILE_COORDINATE: f32 = 1e15;

/// Welds coincident vertices, drops degenerate triangles, checks that the surface is
/// closed, manifold and consistently oriented, and orients it outward.
pub fn prepare(mut m: TriMesh) -> Result<TriMesh, String> {
    if m.triangles.is_empty() {
        // (Faces whose corners coincide are dropped as they are read: a file of collapsed
        // faces lands here too.)
        return Err("the mesh has no triangles with three distinct corners".into());
    }
    if let Some(p) = m.positions.iter().find(|p| !p.is_finite()) {
        return Err(format!("a vertex position is not finite: {p}"));
    }
    // Weld by exact position: files split vertices at normal/UV seams.
    let mut index: HashMap<[u32; 3], u32> = HashMap::new();
    let mut positions = Vec::new();
    let remap: Vec<u32> = m
        .positions
        .iter()
        .map(|p| {
            let key = p.to_array().map(|x| (x + 0.0).to_bits());
            *index.entry(key).or_insert_with(|| {
                positions.push(*p);
                positions.len() as u32 - 1
            })
        })
        .collect();
    let mut triangles = Vec::with_capacity(m.triangles.len());
    for t in &m.triangles {
        let t = t.map(|i| remap[i as usize]);
        if t[0] == t[1] || t[1] == t[2] || t[0] == t[2] {
            continue;
        }
        if zero_area(t.map(|i| positions[i as usize])) {
            continue;
        }
        triangles.push(t);
    }
    if triangles.is_empty() {
        // Areas are squared in f32 (as the renderers use them): below ~10⁻¹¹ scene units
        // an edge's square underflows, and a mesh in such units read as degenerate unsaid.
        let (lo, hi) = bounds_of(positions.iter().copied());
        let side = (hi - lo).max_element();
        return Err(format!(
            "all {} triangles are degenerate (zero area){}",
            m.triangles.len(),
            if side > 0.0 && side < 1e-8 {
                format!(
                    "; the mesh is {side:e} units across, too small for single precision: \
                     scale the file up (object.height scales only after loading)"
                )
            } else {
                String::new()
            }
        ));
    }
    let dropped = m.triangles.len() - triangles.len();
    // Only the vertices the triangles use, in their order: a PLY's or glTF's stray point
    // counted in the bounds, and so scaled the object under `height` (a cube with one
    // unused vertex came out a tenth of its size, off-centre), set its offsets' scale and
    // could fail the extent check for a point that is not drawn.
    let mut new_index = vec![u32::MAX; positions.len()];
    for t in &triangles {
        for &i in t {
            new_index[i as usize] = 0;
        }
    }
    let mut used = Vec::with_capacity(positions.len());
    for (i, p) in positions.iter().enumerate() {
        if new_index[i] == 0 {
            new_index[i] = used.len() as u32;
            used.push(*p);
        }
    }
    for t in &mut triangles {
        for i in t.iter_mut() {
            *i = new_index[*i as usize];
        }
    }
    m = TriMesh {
        positions: used,
        triangles,
    };
    // Of the vertices the triangles use: the checks below square edge lengths in f32,
    // which overflow beyond ~10¹⁹ (a cube with one corner at 3·10³⁸ came out "not
    // closed"). The bound is far below the overflow and far above any size object.height
    // can bring into the renderers' range (±10⁶).
    if let Some(p) = m
        .positions
        .iter()
        .find(|p| p.abs().max_element() > MAX_FILE_COORDINATE)
    {
        return Err(format!(
            "a vertex position, {p}, lies beyond ±{MAX_FILE_COORDINATE:e}: too large for \
             single precision; scale the file down (object.height scales only after loading)"
        ));
    }
    check_closed(&m).map_err(|e| {
        if dropped > 0 && e.contains("boundary edges") {
            // A file may close its surface only through zero-area triangles (e.g. slivers
            // filling T-junctions); without them it is open, which the count alone would
            // not explain.
            format!(
                "{e}; {dropped} zero-area triangles were dropped before this check, so the \
                 file may close its surface only through them (e.g. at T-junctions)"
            )
        } else {
            e
        }
    })?;
    let pieces = pieces(&m);
    let volumes = piece_volumes(&m, &pieces);
    let boxes = piece_boxes(&m, &pieces);
    flat_pieces(&pieces, &volumes, &boxes)?;
    orient_pieces(&mut m, &pieces, &volumes, &boxes);
    Ok(m)
}

/// Every edge must be shared by exactly two triangles that traverse it in opposite
/// directions.
fn check_closed(m: &TriMesh) -> Result<(), String> {
    // Value: (uses in direction min→max, uses in direction max→min).
    let mut edges: HashMap<(u32, u32), (u32, u32)> = HashMap::new();
    for t in &m.triangles {
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            let e = edges.entry((a.min(b), a.max(b))).or_default();
            if a < b {
                e.0 += 1;
            } else {
                e.1 += 1;
            }
        }
    }
    let boundary = edges.values().filter(|(f, b)| f + b == 1).count();
    let non_manifold = edges.values().filter(|(f, b)| f + b > 2).count();
    let flipped = edges
        .values()
        .filter(|&&(f, b)| f + b == 2 && f != b)
        .count();
    if boundary == 0 && non_manifold > 0 {
        // A flat closed surface (a box of height 0) welds into faces listed twice: named
        // for its flatness, which is the cause, not for a two-sided export. Flat: every
        // vertex on the plane of the largest triangle (a signed volume could cancel
        // between pieces wound oppositely in the file).
        let (lo, hi) = m.bounds();
        let side = (hi - lo).max_element();
        let normal = m
            .triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| m.positions[i as usize]);
                ((b - a).cross(c - a), a)
            })
            .max_by(|x, y| x.0.length_squared().total_cmp(&y.0.length_squared()));
        if let Some((n, a)) = normal
            && n.length_squared() > 0.0
        {
            let n = n.normalize();
            let off = m
                .positions
                .iter()
                .map(|p| (*p - a).dot(n).abs())
                .fold(0.0f32, f32::max);
            if off <= 1e-6 * side {
                return Err(format!(
                    "the mesh encloses no volume: all its vertices lie in one plane (it is \
                     flat){}",
                    rounded_flat(lo, hi)
                ));
            }
        }
        // Closed, but parts meet along edges: welding made one edge of their two.
        return Err(format!(
            "the mesh is not a manifold surface: more than two faces share {non_manifold} of \
             its edges, where parts of it touch or overlap along a common edge (welded into \
             one there) or faces are listed twice (a two-sided export); move such parts \
             apart or join them into one closed surface, and list each face once"
        ));
    }
    if boundary > 0 || non_manifold > 0 {
        return Err(format!(
            "the mesh is not closed: {boundary} boundary edges and {non_manifold} non-manifold edges \
             (the medium needs a watertight surface)"
        ));
    }
    if flipped > 0 {
        return Err(format!(
            "the mesh is not consistently oriented: {flipped} edges are shared by triangles facing \
             opposite ways"
        ));
    }
    Ok(())
}
