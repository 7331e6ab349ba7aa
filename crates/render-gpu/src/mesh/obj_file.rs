//! The OBJ loader: `tobj` reads the text after it is checked line by line, so that a bad
//! line is named.

use std::path::Path;

use glam::Vec3;

use super::TriMesh;
use super::triangulate::Triangulator;
use crate::error::RenderError;

pub(super) fn load_obj(path: &Path) -> Result<TriMesh, RenderError> {
    // tobj's own triangulation is a fan, wrong for concave faces: faces come whole and
    // are cut here (Triangulator).
    let opts = tobj::LoadOptions {
        triangulate: false,
        single_index: false,
        ignore_points: true,
        ignore_lines: true,
    };
    let bytes = std::fs::read(path).map_err(|e| RenderError::io(path, e))?;
    // tobj reads line by line: bytes that are not UTF-8 text stop it. A NUL marks a
    // binary file; other stray bytes are a comment's or a name's in another encoding
    // (Latin-1 "# café" was refused as "not text"), which no vertex or face reads: they
    // become U+FFFD, and a number spoilt by one is named with its line by `obj_problem`.
    if bytes.contains(&0) {
        return Err(RenderError::mesh(
            path,
            "not a valid OBJ file: it is not text (an OBJ mesh is a text file of 'v' and 'f' \
             lines)",
        ));
    }
    let text = match String::from_utf8(bytes) {
        Ok(t) => t,
        Err(e) => String::from_utf8_lossy(e.as_bytes()).into_owned(),
    };
    // A UTF-8 byte-order mark hid the first line ("face index 8 names no vertex"), and
    // tobj splits lines at '\n' only (old Mac files end them with '\r').
    let text = text.strip_prefix('\u{feff}').unwrap_or(&text);
    let text = if text.contains('\r') {
        text.replace("\r\n", "\n").replace('\r', "\n")
    } else {
        text.to_string()
    };
    // tobj names neither the line nor the value at fault, and drops faces of fewer than
    // three vertices without a word (the mesh is then reported open): checked here first.
    if let Some(problem) = obj_problem(&text) {
        return Err(RenderError::mesh(path, problem));
    }
    let text = positions_only(&text);
    // Materials are not used: the medium comes from the scene file.
    let (models, _) = tobj::load_obj_buf(&mut text.as_bytes(), &opts, |_| {
        Err(tobj::LoadError::OpenFileFailed)
    })
    .map_err(|e| RenderError::mesh(path, format!("not a valid OBJ file: {e}")))?;
    let mut mesh = TriMesh::default();
    let mut cut = Triangulator::default();
    for m in models {
        let base = mesh.positions.len() as u32;
        let n = (m.mesh.positions.len() / 3) as u32;
        mesh.positions.extend(
            m.mesh
                .positions
                .chunks(3)
                .map(|p| Vec3::new(p[0], p[1], p[2])),
        );
        if m.mesh.indices.iter().any(|&i| i >= n) {
            return Err(RenderError::mesh(path, "a face refers to a missing vertex"));
        }
        let indices: Vec<u32> = m.mesh.indices.iter().map(|&i| i + base).collect();
        // No arities means every face is a triangle.
        let arities = if m.mesh.face_arities.is_empty() {
            vec![3; indices.len() / 3]
        } else {
            m.mesh.face_arities.clone()
        };
        if arities.iter().map(|&a| a as usize).sum::<usize>() != indices.len() {
            return Err(RenderError::mesh(
                path,
                "not a valid OBJ file: its faces do not add up",
            ));
        }
        cut.polygons(
            &mesh.positions,
            &indices,
            arities.iter().map(|&a| a as usize),
            &mut mesh.triangles,
        )
        .map_err(|e| RenderError::mesh(path, e))?;
    }
    Ok(mesh)
}

/// The OBJ text with what the renderer does not use taken out before tobj reads it: its
/// texture-coordinate and normal lines and the faces' references to them (tobj computed
/// their offsets unchecked: an index of −3 into one `vt` overflowed, a panic in a build
/// with overflow checks, a message without a line elsewhere), polylines (`l`), which
/// tobj read as faces when of three points or more (a cube with a polyline was refused as
/// "faces listed twice"), and vertex colours (a file with colours on some vertices only
/// was refused as "face vertex color index out of bounds"). A weight stays: tobj divides
/// x y z by it.
fn positions_only(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    for line in text.lines() {
        let mut words = line.split_whitespace();
        match words.next() {
            Some("l" | "vt" | "vn" | "vp") => {}
            // `obj_problem` has checked the line: x y z and a colour r g b.
            Some("v") if words.clone().count() == 6 => {
                out.push('v');
                for w in words.take(3) {
                    out.push(' ');
                    out.push_str(w);
                }
            }
            Some("f") => {
                out.push('f');
                for w in words {
                    out.push(' ');
                    out.push_str(w.split('/').next().unwrap_or(""));
                }
            }
            _ => out.push_str(line),
        }
        out.push('\n');
    }
    out
}

/// The first line of an OBJ text that tobj would refuse without saying where, or read
/// wrongly, as "line N: ...": a vertex without three numbers or with values after them
/// other than a weight (not 0) or a colour, a face of fewer than three vertices, or a
/// face index that names no vertex: a positive one is allowed up to the file's vertex
/// count (tobj, like the format, lets a face name vertices defined after it), a negative
/// one counts back from the vertices defined before its line. None if there is none.
fn obj_problem(text: &str) -> Option<String> {
    let is_vertex = |line: &str| line.split_whitespace().next() == Some("v");
    let total = text.lines().filter(|l| is_vertex(l)).count() as i64;
    let mut before: i64 = 0;
    for (n, line) in text.lines().enumerate() {
        let at = n + 1;
        let mut words = line.split_whitespace();
        match words.next() {
            Some("v") => {
                let coords: Vec<&str> = words.collect();
                if coords.len() < 3 || coords[..3].iter().any(|w| w.parse::<f32>().is_err()) {
                    return Some(format!(
                        "line {at}: vertex `{}` needs three numbers x y z",
                        line.trim()
                    ));
                }
                // What tobj takes after x y z: nothing, a weight w ≠ 0, or a colour r g b
                // (its own errors name no line).
                let numbers: Option<Vec<f32>> = coords.iter().map(|w| w.parse().ok()).collect();
                let fits = match numbers.as_deref() {
                    Some([_, _, _] | [_, _, _, _, _, _]) => true,
                    Some([_, _, _, w]) => *w != 0.0,
                    _ => false,
                };
                if !fits {
                    return Some(format!(
                        "line {at}: vertex `{}` is not `v x y z`, `v x y z w` (w not 0) or \
                         `v x y z r g b` in numbers",
                        line.trim()
                    ));
                }
                before += 1;
            }
            Some("f") => {
                let refs: Vec<&str> = words.collect();
                if refs.len() < 3 {
                    return Some(format!(
                        "line {at}: face `{}` has {} vertices: a face needs at least 3",
                        line.trim(),
                        refs.len()
                    ));
                }
                for w in refs {
                    // v, v/vt, v//vn or v/vt/vn: the texture and normal indices are not
                    // used, but a reference of other words is not a face (`2/x/y` and
                    // `3///` were read as vertices 2 and 3); an empty part is let through.
                    let parts: Vec<&str> = w.split('/').collect();
                    if parts.len() > 3
                        || parts[1..]
                            .iter()
                            .any(|p| !p.is_empty() && p.parse::<i64>().is_err())
                    {
                        return Some(format!(
                            "line {at}: face vertex `{w}` is not v, v/vt, v//vn or v/vt/vn \
                             (indices as integers)"
                        ));
                    }
                    let first = parts[0];
                    let ok = first
                        .parse::<i64>()
                        .is_ok_and(|i| (1..=total).contains(&i) || (-before..=-1).contains(&i));
                    if !ok && total == 0 {
                        return Some(format!(
                            "line {at}: face `{}` but the file defines no vertex (`v x y z` lines)",
                            line.trim()
                        ));
                    }
                    if !ok {
                        let back = if before > 0 {
                            format!(
                                ", or [-{before}, -1] counting back over the {before} \
                                 defined before it"
                            )
                        } else {
                            String::new()
                        };
                        return Some(format!(
                            "line {at}: face index `{first}` names no vertex: allowed [1, {total}] \
                             for the file's {total} vertices{back}"
                        ));
                    }
                }
            }
            _ => {}
        }
    }
    None
}
