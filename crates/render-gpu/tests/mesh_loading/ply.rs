//! PLY files, ASCII and binary: header rules, property types and widths, face lists and
//! their indices, and data beyond the declared elements.

use super::*;

/// A tetrahedron (volume 1/6) as an ASCII PLY file.
const TETRA_PLY: &str = "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\n\
                         property float y\nproperty float z\nelement face 4\n\
                         property list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n\
                         0 1 0\n0 0 1\n3 0 2 1\n3 0 1 3\n3 0 3 2\n3 1 2 3\n";

/// The same tetrahedron as a binary PLY file: `header_tail` before its elements, `end` as
/// the header's last line, `eol` ending each header line (LF, CRLF or a lone CR: all three
/// are in use).
fn tetra_ply_binary(header_tail: &str, end: &str, eol: &str) -> Vec<u8> {
    let mut b = format!(
        "ply\nformat binary_little_endian 1.0\n{header_tail}element vertex 4\n\
         property float x\nproperty float y\nproperty float z\nelement face 4\n\
         property list uchar int vertex_indices\n{end}\n"
    )
    .replace('\n', eol)
    .into_bytes();
    for p in [[0f32, 0., 0.], [1., 0., 0.], [0., 1., 0.], [0., 0., 1.]] {
        p.iter().for_each(|x| b.extend_from_slice(&x.to_le_bytes()));
    }
    for f in [[0i32, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]] {
        b.push(3);
        f.iter().for_each(|i| b.extend_from_slice(&i.to_le_bytes()));
    }
    b
}

/// A `format` line without its version is named for that (it read as "format `ascii` is
/// not supported"), and a file of faces that all collapse to a point says why it has no
/// triangles.
#[test]
fn ply_format_without_version_and_collapsed_faces_are_named() {
    let d = tempfile::tempdir().unwrap();
    let tetra = TETRA_PLY;
    let e = load_mesh(&write(
        &d,
        "v.ply",
        tetra.replace("ascii 1.0", "ascii").as_bytes(),
    ))
    .unwrap_err()
    .to_string();
    assert!(e.contains("`format ascii` lacks its version"), "{e}");
    let point = tetra.replace("1 0 0\n0 1 0\n0 0 1\n", "0 0 0\n0 0 0\n0 0 0\n");
    let e = load_mesh(&write(&d, "p.ply", point.as_bytes()))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("no triangles with three distinct corners"),
        "{e}"
    );
}

/// Loading `text`, an edit of TETRA_PLY (checked to differ from it), as `name` fails
/// with an error that names the file and says `want`.
fn assert_ply_refused(d: &tempfile::TempDir, name: &str, text: &str, want: &str) {
    assert_ne!(text, TETRA_PLY, "{name}: the edit did not apply");
    let e = load_mesh(&write(d, name, text.as_bytes()))
        .unwrap_err()
        .to_string();
    assert!(e.contains(name) && e.contains(want), "{e}");
}

/// A header that repeats an element or a property, or whose faces have no
/// `vertex_indices` list, is named for it: the first two were read without a word (a
/// second `property float x` over the first), the last said "no triangles".
#[test]
fn ply_headers_repeating_names_or_without_a_face_list_are_named() {
    let d = tempfile::tempdir().unwrap();
    assert!(load_mesh(&write(&d, "ok.ply", TETRA_PLY.as_bytes())).is_ok());
    let vertex = "element vertex 4\nproperty float x\nproperty float y\nproperty float z\n";
    for (name, text, want) in [
        (
            "px.ply",
            TETRA_PLY.replace("property float x\n", "property float x\nproperty float x\n"),
            "element `vertex` declares property `x` twice",
        ),
        (
            "v2.ply",
            TETRA_PLY.replace(vertex, &format!("{vertex}{vertex}")),
            "element `vertex` is declared twice",
        ),
        (
            "nolist.ply",
            TETRA_PLY.replace("vertex_indices", "corners"),
            "the face element has no `vertex_indices` (or `vertex_index`) list",
        ),
    ] {
        assert_ply_refused(&d, name, &text, want);
    }
}

/// A face list named `vertex_index` (some exporters' name) is read as `vertex_indices`.
#[test]
fn ply_face_lists_named_vertex_index_are_read() {
    let d = tempfile::tempdir().unwrap();
    let text = TETRA_PLY.replace("vertex_indices", "vertex_index");
    let m = load_mesh(&write(&d, "vi.ply", text.as_bytes())).unwrap();
    let (v, _) = volume_and_area(&m);
    assert!((v - 1.0 / 6.0).abs() < 1e-7, "volume {v}");
}

/// A face index at or beyond the vertex count, a negative or fractional one, or a face of
/// two vertices is named (the first panicked in the triangulation; a negative index read
/// as vertex 0).
#[test]
fn ply_face_indices_out_of_range_negative_fractional_or_short_are_named() {
    let d = tempfile::tempdir().unwrap();
    let bad_index = "face 1: a face has a negative or fractional index";
    for (name, text, want) in [
        (
            "idx4.ply",
            TETRA_PLY.replace("3 1 2 3\n", "3 1 2 4\n"),
            "a face refers to a vertex beyond the 4 vertices",
        ),
        (
            "neg.ply",
            TETRA_PLY.replace("3 0 2 1\n", "3 -1 2 1\n"),
            bad_index,
        ),
        (
            "frac.ply",
            TETRA_PLY
                .replace("list uchar int", "list uchar float")
                .replace("3 0 2 1\n", "3 0.5 2 1\n"),
            bad_index,
        ),
        (
            "two.ply",
            TETRA_PLY.replace("3 1 2 3\n", "2 1 2\n"),
            "face 4: a face has fewer than 3 vertices",
        ),
    ] {
        assert_ply_refused(&d, name, &text, want);
    }
}

/// Binary PLY's sized type names (int8 … uint32, float32, float64) read as their widths:
/// a tetrahedron whose x is float32, y float64, z int16, beside properties of the other
/// sized types, and faces of uint8 counts and int32 indices.
#[test]
fn binary_ply_reads_the_sized_type_names() {
    let d = tempfile::tempdir().unwrap();
    let mut b = b"ply\nformat binary_little_endian 1.0\nelement vertex 4\n\
        property float32 x\nproperty float64 y\nproperty int16 z\nproperty uint8 r\n\
        property int8 s\nproperty uint16 t\nproperty uint32 u\nelement face 4\n\
        property list uint8 int32 vertex_indices\nend_header\n"
        .to_vec();
    for [x, y, z] in [[0i16, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]] {
        b.extend_from_slice(&f32::from(x).to_le_bytes());
        b.extend_from_slice(&f64::from(y).to_le_bytes());
        b.extend_from_slice(&z.to_le_bytes());
        b.push(200);
        b.extend_from_slice(&(-5i8).to_le_bytes());
        b.extend_from_slice(&60_000u16.to_le_bytes());
        b.extend_from_slice(&4_000_000_000u32.to_le_bytes());
    }
    for f in [[0i32, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]] {
        b.push(3);
        f.iter().for_each(|i| b.extend_from_slice(&i.to_le_bytes()));
    }
    let m = load_mesh(&write(&d, "sized.ply", &b)).unwrap_or_else(|e| panic!("{e}"));
    let mut corners: Vec<[f32; 3]> = m.positions.iter().map(|p| p.to_array()).collect();
    corners.sort_by(|p, q| p.partial_cmp(q).unwrap());
    assert_eq!(
        corners,
        [[0f32, 0., 0.], [0., 0., 1.], [0., 1., 0.], [1., 0., 0.]]
    );
    let (v, _) = volume_and_area(&m);
    assert!((v - 1.0 / 6.0).abs() < 1e-7, "volume {v}");
}

/// The header ends only at an `end_header` line of its own (trailing blanks allowed): not
/// at a comment that mentions it, and a binary body starts right after the line.
#[test]
fn ply_header_ends_at_its_own_line() {
    let d = tempfile::tempdir().unwrap();
    let tetra = tetra_ply_binary;
    let ascii = |eol: &str| TETRA_PLY.replace('\n', eol).into_bytes();
    for (name, text) in [
        ("plain.ply", tetra("", "end_header", "\n")),
        (
            "comment.ply",
            tetra(
                "comment written before end_header by a tool\n",
                "end_header",
                "\n",
            ),
        ),
        ("blank.ply", tetra("", "end_header \r", "\n")),
        ("crlf.ply", tetra("", "end_header", "\r\n")),
        // A lone CR ends a line too (it was read as one long line: "no end_header").
        ("cr.ply", tetra("", "end_header", "\r")),
        ("ascii_crlf.ply", ascii("\r\n")),
        ("ascii_cr.ply", ascii("\r")),
    ] {
        let m = load_mesh(&write(&d, name, &text)).unwrap_or_else(|e| panic!("{name}: {e}"));
        let (v, _) = volume_and_area(&m);
        assert!((v - 1.0 / 6.0).abs() < 1e-7, "{name}: volume {v}");
    }
}

/// Binary vertex coordinates of 8 bytes (`double`, or its other name `float64`) and face
/// indices of 2 or 4 bytes (`ushort`, `uint`) are read at their own widths: the
/// tetrahedron of TETRA_PLY loads with its corners exactly and volume 1/6. Doubles read as
/// 4-byte floats misread the coordinates and the faces after them, and left bytes over.
#[test]
fn binary_ply_reads_doubles_and_unsigned_indices() {
    let d = tempfile::tempdir().unwrap();
    // (name, coordinate type, index type, bytes of an index)
    type Case = (&'static str, &'static str, &'static str, fn(u32) -> Vec<u8>);
    let cases: [Case; 2] = [
        ("double.ply", "double", "uint", |i| i.to_le_bytes().to_vec()),
        ("float64.ply", "float64", "ushort", |i| {
            (i as u16).to_le_bytes().to_vec()
        }),
    ];
    for (name, coord, index, index_bytes) in cases {
        let mut b = format!(
            "ply\nformat binary_little_endian 1.0\nelement vertex 4\nproperty {coord} x\n\
             property {coord} y\nproperty {coord} z\nelement face 4\n\
             property list uchar {index} vertex_indices\nend_header\n"
        )
        .into_bytes();
        for p in [[0f64, 0., 0.], [1., 0., 0.], [0., 1., 0.], [0., 0., 1.]] {
            p.iter().for_each(|x| b.extend_from_slice(&x.to_le_bytes()));
        }
        for f in [[0u32, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]] {
            b.push(3);
            f.iter().for_each(|&i| b.extend_from_slice(&index_bytes(i)));
        }
        let m = load_mesh(&write(&d, name, &b)).unwrap_or_else(|e| panic!("{name}: {e}"));
        let mut corners: Vec<[f32; 3]> = m.positions.iter().map(|p| p.to_array()).collect();
        corners.sort_by(|p, q| p.partial_cmp(q).unwrap());
        assert_eq!(
            corners,
            [[0f32, 0., 0.], [0., 0., 1.], [0., 1., 0.], [1., 0., 0.]],
            "{name}"
        );
        let (v, _) = volume_and_area(&m);
        assert!((v - 1.0 / 6.0).abs() < 1e-7, "{name}: volume {v}");
    }
}

/// Data after the last declared element means the header's counts are short of the body
/// (the mesh read would lack the rest): refused, ASCII and binary alike, while padding (a
/// final newline, NULs, an end-of-file mark) is accepted.
#[test]
fn ply_data_beyond_the_declared_elements_is_refused() {
    let d = tempfile::tempdir().unwrap();
    let ascii = TETRA_PLY;
    load_mesh(&write(&d, "ok.ply", ascii.as_bytes())).expect("the tetrahedron reads");
    // Old Windows tools end a text file with 0x1A: padding, not data.
    load_mesh(&write(&d, "eof.ply", format!("{ascii}\x1a").as_bytes()))
        .expect("an end-of-file mark is no data");
    let e = load_mesh(&write(
        &d,
        "more.ply",
        format!("{ascii}3 1 2 0\n").as_bytes(),
    ))
    .unwrap_err()
    .to_string();
    assert!(
        e.contains("more.ply") && e.contains("`3` after the last element"),
        "{e}"
    );
    let bin = tetra_ply_binary("", "end_header", "\n");
    let mut newline = bin.clone();
    newline.push(b'\n');
    load_mesh(&write(&d, "nl.ply", &newline)).expect("a final newline is no data");
    let mut nuls = bin.clone();
    nuls.extend_from_slice(&[0, 0, 0, 0]);
    load_mesh(&write(&d, "nul.ply", &nuls)).expect("NUL padding is no data");
    let mut tail = bin.clone();
    tail.extend_from_slice(&7f32.to_le_bytes());
    let e = load_mesh(&write(&d, "tail.ply", &tail))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("tail.ply") && e.contains("4 bytes after the last element"),
        "{e}"
    );
}

/// Binary vertex coordinates of the signed integer types (`char`, `short`, `int`, as
/// quantising exporters write them) keep their sign: the cube [-1, 1]³ of CUBE_OBJ written
/// with each loads with those bounds and its volume of 8. Read as unsigned, −1 becomes
/// 255, 65,535 or 4,294,967,295, and the file still loads as a closed cube, [1, 255]³ and
/// so on: far from where it was and ~10²–10⁹ times its size, without a word.
#[test]
fn binary_ply_reads_signed_integer_coordinates() {
    let d = tempfile::tempdir().unwrap();
    let (verts, faces) = CUBE_OBJ.split_at(CUBE_OBJ.find('f').unwrap());
    let corners: Vec<Vec<i32>> = verts
        .lines()
        .map(|l| {
            l[2..]
                .split(' ')
                .map(|w| w.parse::<i32>().unwrap())
                .collect::<Vec<i32>>()
        })
        .collect();
    // (name, coordinate type, bytes of a coordinate)
    type Case = (&'static str, &'static str, fn(i32) -> Vec<u8>);
    let cases: [Case; 3] = [
        ("char.ply", "char", |x| (x as i8).to_le_bytes().to_vec()),
        ("short.ply", "short", |x| (x as i16).to_le_bytes().to_vec()),
        ("int.ply", "int", |x| x.to_le_bytes().to_vec()),
    ];
    for (name, coord, coord_bytes) in cases {
        let mut b = format!(
            "ply\nformat binary_little_endian 1.0\nelement vertex 8\nproperty {coord} x\n\
             property {coord} y\nproperty {coord} z\nelement face 6\n\
             property list uchar int vertex_indices\nend_header\n"
        )
        .into_bytes();
        for p in &corners {
            p.iter().for_each(|&x| b.extend_from_slice(&coord_bytes(x)));
        }
        for f in faces.lines() {
            b.push(4);
            for i in f[2..].split(' ') {
                b.extend_from_slice(&(i.parse::<i32>().unwrap() - 1).to_le_bytes());
            }
        }
        let m = load_mesh(&write(&d, name, &b)).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(
            m.bounds(),
            (glam::Vec3::splat(-1.0), glam::Vec3::ONE),
            "{name}"
        );
        let (v, _) = volume_and_area(&m);
        assert!((v - 8.0).abs() < 1e-9, "{name}: volume {v}");
    }
}
