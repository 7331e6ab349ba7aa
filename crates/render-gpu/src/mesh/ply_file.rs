//! A small PLY reader: enough for closed triangle meshes (no well-kept crate covers PLY).
//!
//! Supports `format ascii 1.0` and `format binary_little_endian 1.0`, a `vertex` element
//! with x, y, z of any scalar type (other properties skipped), and a `face` element with
//! a `vertex_indices`/`vertex_index` list (polygons cut into triangles in their plane, see
//! `mesh::Triangulator`). Other elements are skipped when their layout allows it.

use glam::Vec3;

use super::TriMesh;

#[derive(Clone, Copy, Debug, PartialEq)]
enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Scalar {
    fn parse(s: &str) -> Result<Self, String> {
        Ok(match s {
            "char" | "int8" => Self::I8,
            "uchar" | "uint8" => Self::U8,
            "short" | "int16" => Self::I16,
            "ushort" | "uint16" => Self::U16,
            "int" | "int32" => Self::I32,
            "uint" | "uint32" => Self::U32,
            "float" | "float32" => Self::F32,
            "double" | "float64" => Self::F64,
            _ => return Err(format!("unknown PLY scalar type `{s}`")),
        })
    }
    fn size(self) -> usize {
        match self {
            Self::I8 | Self::U8 => 1,
            Self::I16 | Self::U16 => 2,
            Self::I32 | Self::U32 | Self::F32 => 4,
            Self::F64 => 8,
        }
    }
    /// Whether an ASCII value fits the declared type: a `uchar` property holding `1.5` or
    /// `300` is a damaged or mislabelled file (a binary reader would read other bytes).
    fn holds(self, v: f64) -> bool {
        let (lo, hi) = match self {
            Self::I8 => (i8::MIN as f64, i8::MAX as f64),
            Self::U8 => (0.0, u8::MAX as f64),
            Self::I16 => (i16::MIN as f64, i16::MAX as f64),
            Self::U16 => (0.0, u16::MAX as f64),
            Self::I32 => (i32::MIN as f64, i32::MAX as f64),
            Self::U32 => (0.0, u32::MAX as f64),
            Self::F32 | Self::F64 => return true,
        };
        v.fract() == 0.0 && (lo..=hi).contains(&v)
    }
    /// The type's PLY name.
    fn name(self) -> &'static str {
        match self {
            Self::I8 => "char",
            Self::U8 => "uchar",
            Self::I16 => "short",
            Self::U16 => "ushort",
            Self::I32 => "int",
            Self::U32 => "uint",
            Self::F32 => "float",
            Self::F64 => "double",
        }
    }
    fn read(self, b: &[u8]) -> f64 {
        match self {
            Self::I8 => b[0] as i8 as f64,
            Self::U8 => b[0] as f64,
            Self::I16 => i16::from_le_bytes([b[0], b[1]]) as f64,
            Self::U16 => u16::from_le_bytes([b[0], b[1]]) as f64,
            Self::I32 => i32::from_le_bytes(b[..4].try_into().unwrap()) as f64,
            Self::U32 => u32::from_le_bytes(b[..4].try_into().unwrap()) as f64,
            Self::F32 => f32::from_le_bytes(b[..4].try_into().unwrap()) as f64,
            Self::F64 => f64::from_le_bytes(b[..8].try_into().unwrap()),
        }
    }
}

#[derive(Debug)]
enum Property {
    Scalar(String, Scalar),
    List(String, Scalar, Scalar),
}

#[derive(Debug)]
struct Element {
    name: String,
    count: usize,
    props: Vec<Property>,
}

/// Names the header must not repeat, and the face list the reader looks for: a second
/// `element vertex` was read as more vertices and a second `property float x` over the
/// first, without a word; a face element whose list had another name gave "no triangles
/// with three distinct corners".
fn check_names(elements: &[Element]) -> Result<(), String> {
    for (i, el) in elements.iter().enumerate() {
        if elements[..i].iter().any(|e| e.name == el.name) {
            return Err(format!("element `{}` is declared twice", el.name));
        }
        fn name(p: &Property) -> &str {
            match p {
                Property::Scalar(n, _) | Property::List(n, _, _) => n,
            }
        }
        for (k, p) in el.props.iter().enumerate() {
            if el.props[..k].iter().any(|q| name(q) == name(p)) {
                return Err(format!(
                    "element `{}` declares property `{}` twice",
                    el.name,
                    name(p)
                ));
            }
        }
        let face_list = |p: &Property| matches!(p, Property::List(n, _, _) if n == "vertex_indices" || n == "vertex_index");
        if el.name == "face" && el.count > 0 && !el.props.iter().any(face_list) {
            return Err(
                "the face element has no `vertex_indices` (or `vertex_index`) list: faces \
                 must be `property list <count type> <index type> vertex_indices`"
                    .into(),
            );
        }
    }
    Ok(())
}

/// Reads values one at a time from the body, ASCII or binary.
enum Body<'a> {
    Ascii(std::str::SplitAsciiWhitespace<'a>),
    Binary(&'a [u8], usize),
}

impl Body<'_> {
    /// Refuses data after the last element: the header's counts are then smaller than
    /// what the body holds (a count edited by hand, or faces appended without it), and
    /// the mesh read would silently lack the rest. Padding is no data: whitespace (a final
    /// newline after binary data), NULs, and the end-of-file mark (0x1A) old Windows
    /// tools append.
    fn finish(self) -> Result<(), String> {
        let padding = |c: &u8| c.is_ascii_whitespace() || *c == 0 || *c == 0x1a;
        let extra = match self {
            Body::Ascii(it) => it
                .flat_map(|tok| tok.split(['\0', '\x1a']))
                .find(|tok| !tok.is_empty())
                .map(|tok| format!("`{tok}`")),
            Body::Binary(b, pos) => b[pos..]
                .iter()
                .any(|c| !padding(c))
                .then(|| format!("{} bytes", b.len() - pos)),
        };
        match extra {
            None => Ok(()),
            Some(what) => Err(format!(
                "{what} after the last element the header declares: its element counts do \
                 not match the body"
            )),
        }
    }

    fn next(&mut self, t: Scalar) -> Result<f64, String> {
        match self {
            Body::Ascii(it) => {
                let tok = it.next().ok_or("the file ends early (truncated?)")?;
                let v = tok
                    .parse::<f64>()
                    .map_err(|_| format!("`{tok}` is not a number"))?;
                if !t.holds(v) {
                    return Err(format!("`{tok}` is not a {} value", t.name()));
                }
                Ok(v)
            }
            Body::Binary(b, pos) => {
                let n = t.size();
                if *pos + n > b.len() {
                    return Err("the file ends early (truncated?)".into());
                }
                let v = t.read(&b[*pos..*pos + n]);
                *pos += n;
                Ok(v)
            }
        }
    }
}

pub fn parse(bytes: &[u8]) -> Result<TriMesh, String> {
    // A UTF-8 byte-order mark before `ply` (some editors write one) is no part of it.
    let bytes = bytes.strip_prefix(b"\xEF\xBB\xBF").unwrap_or(bytes);
    let (binary, elements, body_start) = parse_header(bytes)?;
    let mut body = if binary {
        Body::Binary(bytes, body_start)
    } else {
        let text =
            std::str::from_utf8(&bytes[body_start..]).map_err(|_| "the PLY body is not text")?;
        Body::Ascii(text.split_ascii_whitespace())
    };
    let mut mesh = TriMesh::default();
    // Faces as read (flat indices, and each face's vertex count): cut into triangles once
    // every vertex is known, since a face's shape decides its cut.
    let (mut face_indices, mut face_sizes) = (Vec::<u32>::new(), Vec::<usize>::new());
    for el in &elements {
        // Guard against absurd counts before allocating.
        if el.count > bytes.len() {
            return Err(format!(
                "element {} claims {} entries, more than the file can hold",
                el.name, el.count
            ));
        }
        let (is_vertex, is_face) = (el.name == "vertex", el.name == "face");
        if is_vertex {
            check_vertex_properties(el)?;
            // Each vertex takes at least 6 bytes ("0 0 0\n" in ASCII, 12 in binary), so a
            // header that lies about the count cannot make this reserve more than the file.
            mesh.positions.reserve(el.count.min(bytes.len() / 6));
        }
        for k in 0..el.count {
            // Which entry a bad value is in: an ASCII body has no other landmark.
            read_entry(
                el,
                (is_vertex, is_face),
                &mut body,
                &mut mesh,
                &mut face_indices,
                &mut face_sizes,
            )
            .map_err(|e| format!("{} {}: {e}", el.name, k + 1))?;
        }
    }
    body.finish()?;
    let nv = mesh.positions.len() as u32;
    if face_indices.iter().any(|&i| i >= nv) {
        return Err(format!(
            "a face refers to a vertex beyond the {nv} vertices"
        ));
    }
    crate::mesh::Triangulator::default().polygons(
        &mesh.positions,
        &face_indices,
        face_sizes,
        &mut mesh.triangles,
    )?;
    Ok(mesh)
}

/// The header: whether the body is binary, the elements, and where the body starts.
fn parse_header(bytes: &[u8]) -> Result<(bool, Vec<Element>, usize), String> {
    let (end, body_start) = header_end(bytes).ok_or("not a PLY file: no end_header line")?;
    let header = std::str::from_utf8(&bytes[..end]).map_err(|_| "the PLY header is not text")?;
    // Split at CR as well as LF: see `header_end` (the blank pieces of CRLF are skipped).
    let mut lines = header.split(['\r', '\n']);
    if lines.next().map(str::trim) != Some("ply") {
        return Err("not a PLY file: the first line is not `ply`".into());
    }
    let mut binary = None;
    let mut elements: Vec<Element> = Vec::new();
    for line in lines {
        let w: Vec<&str> = line.split_whitespace().collect();
        match w.as_slice() {
            ["format", _, v] if *v != "1.0" => {
                return Err(format!("PLY version `{v}` is not supported (1.0 is)"));
            }
            ["format", "ascii", _] => binary = Some(false),
            ["format", "binary_little_endian", _] => binary = Some(true),
            ["format", f @ ("ascii" | "binary_little_endian")] => {
                return Err(format!(
                    "`format {f}` lacks its version: write `format {f} 1.0`"
                ));
            }
            ["format", f, ..] => return Err(format!("PLY format `{f}` is not supported")),
            ["element", name, count] => elements.push(Element {
                name: name.to_string(),
                count: count
                    .parse()
                    .map_err(|_| format!("bad element count `{count}`"))?,
                props: Vec::new(),
            }),
            ["property", "list", c, t, name] => elements
                .last_mut()
                .ok_or("property before any element")?
                .props
                .push(Property::List(
                    name.to_string(),
                    Scalar::parse(c)?,
                    Scalar::parse(t)?,
                )),
            ["property", t, name] => elements
                .last_mut()
                .ok_or("property before any element")?
                .props
                .push(Property::Scalar(name.to_string(), Scalar::parse(t)?)),
            _ => {}
        }
    }
    let binary = binary.ok_or("the PLY header has no format line")?;
    check_names(&elements)?;
    // Faces come as `face` lists only: a file of triangle strips read as "no triangles".
    if !elements.iter().any(|e| e.name == "face")
        && let Some(e) = elements.iter().find(|e| e.name != "vertex" && e.count > 0)
    {
        return Err(format!(
            "the PLY file has no `face` element (element `{}` is not read): faces must be \
             `element face` with a vertex-index list",
            e.name
        ));
    }
    Ok((binary, elements, body_start))
}

fn check_vertex_properties(el: &Element) -> Result<(), String> {
    for axis in ["x", "y", "z"] {
        if !el
            .props
            .iter()
            .any(|p| matches!(p, Property::Scalar(n, _) if n == axis))
        {
            return Err(format!("the vertex element has no `{axis}` property"));
        }
    }
    Ok(())
}

/// One entry of an element: a vertex's position, or a face's vertex indices (kept with
/// its vertex count); other properties and elements are read past. Whether the element is
/// the vertices or the faces is decided once per element, by the caller.
fn read_entry(
    el: &Element,
    (is_vertex, is_face): (bool, bool),
    body: &mut Body,
    mesh: &mut TriMesh,
    face_indices: &mut Vec<u32>,
    face_sizes: &mut Vec<usize>,
) -> Result<(), String> {
    let mut p = [0f32; 3];
    for prop in &el.props {
        match prop {
            Property::Scalar(name, t) => {
                let v = body.next(*t)?;
                if is_vertex {
                    match name.as_str() {
                        "x" => p[0] = v as f32,
                        "y" => p[1] = v as f32,
                        "z" => p[2] = v as f32,
                        _ => {}
                    }
                }
            }
            Property::List(name, ct, it) => {
                let n = body.next(*ct)?;
                if !(0.0..=1e6).contains(&n) || n.fract() != 0.0 {
                    return Err(format!("bad list length {n}"));
                }
                let mut idx = Vec::with_capacity(n as usize);
                for _ in 0..n as usize {
                    idx.push(body.next(*it)?);
                }
                if is_face && (name == "vertex_indices" || name == "vertex_index") {
                    if idx.len() < 3 {
                        return Err("a face has fewer than 3 vertices".into());
                    }
                    if idx.iter().any(|&v| v < 0.0 || v.fract() != 0.0) {
                        return Err("a face has a negative or fractional index".into());
                    }
                    face_indices.extend(idx.iter().map(|&v| v as u32));
                    face_sizes.push(idx.len());
                }
            }
        }
    }
    if is_vertex {
        mesh.positions.push(Vec3::from_array(p));
    }
    Ok(())
}

/// Where the header ends (the start of its `end_header` line) and the body begins (after
/// that line's end). The keyword counts only as a line of its own, trailing blanks allowed:
/// a comment that mentions it must not cut the header short, and a binary body starts
/// exactly after the line break. Lines end with LF, CRLF or a lone CR (old Mac tools):
/// a CR followed by LF is one line end, so a CR-only header before a binary body whose
/// first byte is 0x0A would lose that byte (an ambiguity of such files; none seen).
fn header_end(bytes: &[u8]) -> Option<(usize, usize)> {
    let mut start = 0;
    while start < bytes.len() {
        let len = bytes[start..]
            .iter()
            .position(|&b| b == b'\n' || b == b'\r')
            .unwrap_or(bytes.len() - start);
        let line = &bytes[start..start + len];
        let crlf = bytes.get(start + len..start + len + 2) == Some(b"\r\n");
        let next = (start + len + 1 + usize::from(crlf)).min(bytes.len());
        if line.trim_ascii() == b"end_header" {
            return Some((start, next));
        }
        start = next;
    }
    None
}
