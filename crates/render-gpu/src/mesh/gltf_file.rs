//! The glTF/GLB loader: every node's meshes placed by its transform, with the checks the
//! `gltf` crate leaves to its caller.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::rc::Rc;

use glam::{Mat4, Quat, Vec3};

use super::TriMesh;
use crate::error::RenderError;

/// Most triangles, and most vertices, a glTF file's nodes may place in all (2^25, ~1.6 GB
/// of mesh before the BVH and the distance grid are built).
pub const MAX_GLTF_TRIANGLES: u64 = 1 << 25;

/// The files a glTF/GLB mesh reads its buffers from (not the mesh file itself; none for a
/// file that is not glTF or cannot be parsed, which loading the mesh reports), so that a
/// command can refuse an output that would replace one: `render --out gb` wrote its
/// `gb.exr` over a buffer of that name and the mesh read as garbage from then on.
pub fn gltf_buffer_files(path: &Path) -> Vec<PathBuf> {
    let gltf_ext = path
        .extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("gltf") || e.eq_ignore_ascii_case("glb"));
    if !gltf_ext || scatter_sim::output::check_input(path).is_err() {
        return Vec::new();
    }
    let Ok(json) = gltf_json_bytes(path) else {
        return Vec::new();
    };
    let Ok(g) = gltf::Gltf::from_slice_without_validation(&json) else {
        return Vec::new();
    };
    let dir = path.parent().unwrap_or(Path::new("."));
    g.document
        .buffers()
        .filter_map(|b| match b.source() {
            gltf::buffer::Source::Uri(uri) if !uri.starts_with("data:") => {
                Some(dir.join(&*percent_encoding::percent_decode_str(uri).decode_utf8_lossy()))
            }
            _ => None,
        })
        .collect()
}

/// A glTF file's JSON: a GLB's first chunk alone (its binary chunk may be large), or the
/// whole of a .gltf.
fn gltf_json_bytes(path: &Path) -> std::io::Result<Vec<u8>> {
    use std::io::Read;
    let mut f = std::fs::File::open(path)?;
    let mut head = [0u8; 20];
    let n = f.read(&mut head)?;
    if n == 20 && &head[..4] == b"glTF" && &head[16..20] == b"JSON" {
        let len = u32::from_le_bytes(head[12..16].try_into().unwrap()) as u64;
        let mut json = Vec::new();
        f.take(len).read_to_end(&mut json)?;
        return Ok(json);
    }
    let mut all = head[..n].to_vec();
    f.read_to_end(&mut all)?;
    Ok(all)
}

/// A node's local transform. glTF 2.0 allows a unit-quaternion rotation and an affine
/// matrix (decomposable into translation, rotation and scale) only; gltf turned a zero or
/// unnormalised quaternion into the identity and dropped a projective matrix's last row
/// without a word. Checked only for nodes with a mesh or children (which may place meshes
/// below them): a camera's or a light's leaf node places nothing. A rotation within
/// [`UNIT_QUATERNION_SLACK`] of unit length is normalised (exporters round it).
fn node_matrix(node: &gltf::Node) -> Result<Mat4, String> {
    let places = node.mesh().is_some() || node.children().next().is_some();
    match node.transform() {
        gltf::scene::Transform::Decomposed {
            translation,
            rotation,
            scale,
        } => {
            let q = Quat::from_array(rotation);
            if places && !((q.length() - 1.0).abs() <= UNIT_QUATERNION_SLACK) {
                return Err(format!(
                    "node {}: rotation {rotation:?} is not a unit quaternion (length {}); glTF \
                     rotations are unit quaternions [x, y, z, w]",
                    node.index(),
                    q.length()
                ));
            }
            // gltf's own product, as before, of the rotation made unit where rounding left
            // it off (a unit one is kept bit for bit: the meshes, and so the scene hashes
            // and caches, of existing files stay as they were).
            let rotation = if (q.length() - 1.0).abs() > 1e-6 && q.length() > 0.0 && q.is_finite() {
                q.normalize().to_array()
            } else {
                rotation
            };
            let t = gltf::scene::Transform::Decomposed {
                translation,
                rotation,
                scale,
            };
            Ok(Mat4::from_cols_array_2d(&t.matrix()))
        }
        gltf::scene::Transform::Matrix { matrix: m } => {
            let last = [m[0][3], m[1][3], m[2][3], m[3][3]];
            let affine = last
                .iter()
                .zip([0.0, 0.0, 0.0, 1.0])
                .all(|(x, want)| (x - want).abs() <= AFFINE_ROW_SLACK);
            if places && !affine {
                return Err(format!(
                    "node {}: matrix's last row is {last:?}, not [0.0, 0.0, 0.0, 1.0]: glTF \
                     node matrices are affine (translation, rotation and scale)",
                    node.index()
                ));
            }
            Ok(Mat4::from_cols_array_2d(&m))
        }
    }
}

/// How far from 1 a node rotation's length may be: exporters write quaternions rounded to
/// a few digits, which scale by as little; anything farther is not a rotation.
const UNIT_QUATERNION_SLACK: f32 = 1e-3;

/// How far a node matrix's last row may be from [0, 0, 0, 1]: exporters write it exactly,
/// or rounded from a product of matrices in f32.
const AFFINE_ROW_SLACK: f32 = 1e-6;

pub(super) fn load_gltf(path: &Path) -> Result<TriMesh, RenderError> {
    let bytes = std::fs::read(path).map_err(|e| RenderError::io(path, e))?;
    let (document, blob) = parse_document(path, &bytes)?;
    let buffers = read_buffers(path, &bytes, &document, blob)?;
    let scene = document
        .default_scene()
        .or_else(|| document.scenes().next());
    let mut stack: Vec<(gltf::Node, Mat4)> = root_nodes(&document, scene.as_ref())
        .into_iter()
        .map(|n| (n, Mat4::IDENTITY))
        .collect();
    let mut reading = Reading {
        path,
        buffers: &buffers,
        mesh: TriMesh::default(),
        instanced: [0; 2],
    };
    // glTF nodes form a tree: a node reached twice means a cycle (which would loop
    // forever) or a node with two parents, both invalid.
    let mut visited = vec![false; document.nodes().len()];
    while let Some((node, parent)) = stack.pop() {
        if std::mem::replace(&mut visited[node.index()], true) {
            return Err(RenderError::mesh(
                path,
                format!(
                    "node {} is reached twice: the node hierarchy has a cycle or a node with two parents",
                    node.index()
                ),
            ));
        }
        let world = parent * node_matrix(&node).map_err(|e| RenderError::mesh(path, e))?;
        if let Some(m) = node.mesh() {
            // The morph targets' default weights (the node's, else the mesh's) shape the
            // mesh as the file shows it at rest.
            let weights = node.weights().or(m.weights()).unwrap_or(&[]);
            for prim in m.primitives() {
                reading.add(node.index(), &m, &prim, weights, world)?;
            }
        }
        for c in node.children() {
            stack.push((c, world));
        }
    }
    // Without a scene every node is to be placed: one the walk from the roots never
    // reached is on a cycle of children that no root leads into (every node of a file
    // that is one such cycle read as "no triangles", a cycle beside a root's tree was
    // dropped without a word).
    if scene.is_none()
        && let Some(n) = visited.iter().position(|&v| !v)
    {
        return Err(RenderError::mesh(
            path,
            format!(
                "node {n} is reached from no root node (the file has no scene): the node \
                 hierarchy has a cycle"
            ),
        ));
    }
    Ok(reading.mesh)
}

/// The file's glTF document and GLB binary chunk, with the faults gltf reports obscurely
/// (or panics on) named first.
fn parse_document(
    path: &Path,
    bytes: &[u8],
) -> Result<(gltf::Document, Option<Vec<u8>>), RenderError> {
    // A .glb is binary and starts with the magic "glTF"; without it gltf would parse the
    // bytes as JSON and say "expected value at line 1 column 1".
    let glb = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("glb"));
    // A .glb of 1–3 bytes that begin the magic is one cut within it.
    let header_begun =
        bytes.starts_with(b"glTF") || (glb && !bytes.is_empty() && b"glTF".starts_with(bytes));
    // (A JSON glTF under a .glb name, which gltf reads, is let through.)
    if glb && !bytes.is_empty() && !header_begun && !bytes.trim_ascii_start().starts_with(b"{") {
        return Err(RenderError::mesh(
            path,
            "not a valid GLB file: it does not start with the GLB magic `glTF`",
        ));
    }
    // A file shorter than its GLB header's length (bytes 8..12), or than the header itself,
    // is cut short: said so, where gltf says "could not completely read the object" (or
    // "failed to fill whole buffer"). Bytes after the declared end are left to gltf, which
    // ignores them (harmless, and some tools may pad).
    if header_begun {
        if bytes.len() < 12 {
            return Err(RenderError::mesh(
                path,
                format!(
                    "truncated GLB file: {} bytes, shorter than the 12-byte GLB header",
                    bytes.len()
                ),
            ));
        }
        let declared = u32::from_le_bytes(bytes[8..12].try_into().unwrap()) as usize;
        if declared > bytes.len() {
            return Err(RenderError::mesh(
                path,
                format!(
                    "truncated GLB file: its header gives {declared} bytes, the file has {}",
                    bytes.len()
                ),
            ));
        }
    }
    if let Some(e) = unnamed_position_accessor(bytes) {
        return Err(RenderError::mesh(path, e));
    }
    let gltf::Gltf { document, blob } = gltf::Gltf::from_slice(bytes).map_err(|e| {
        let what = if bytes.is_empty() {
            "the file is empty".to_string()
        } else {
            e.to_string()
        };
        RenderError::mesh(path, format!("not a valid glTF/GLB file: {what}"))
    })?;
    if document.meshes().len() == 0 {
        return Err(RenderError::mesh(path, "the glTF file holds no mesh"));
    }
    Ok((document, blob))
}

/// The nodes a walk starts from: the scene's, or without a scene every node that is no
/// other's child (the children come through their parents; started from too, they would
/// be reached twice).
fn root_nodes<'a>(
    document: &'a gltf::Document,
    scene: Option<&gltf::Scene<'a>>,
) -> Vec<gltf::Node<'a>> {
    match scene {
        Some(s) => s.nodes().collect(),
        None => {
            let mut child = vec![false; document.nodes().len()];
            for c in document.nodes().flat_map(|n| n.children()) {
                child[c.index()] = true;
            }
            document.nodes().filter(|n| !child[n.index()]).collect()
        }
    }
}

/// The triangle list being read from a glTF file's primitives.
struct Reading<'a> {
    path: &'a Path,
    buffers: &'a [Rc<Vec<u8>>],
    mesh: TriMesh,
    /// Triangles and vertices placed so far. Instances of one mesh (nodes naming it) are
    /// copied into the one triangle list: 5,000 nodes over a mesh of 10⁶ triangles asked
    /// for 5·10⁹.
    instanced: [u64; 2],
}

impl Reading<'_> {
    /// Appends primitive `prim` of mesh `m`, placed by node `node` at `world` with the
    /// morph `weights`.
    fn add(
        &mut self,
        node: usize,
        m: &gltf::Mesh,
        prim: &gltf::Primitive,
        weights: &[f32],
        world: Mat4,
    ) -> Result<(), RenderError> {
        // A mirroring transform reverses the winding; glTF asks loaders to undo that.
        let mirrored = world.determinant() < 0.0;
        let targets = self.check_primitive(node, m, prim, weights)?;
        let pos = self.placed_positions(prim, &targets, weights, world)?;
        self.append_triangles(m, prim, pos, mirrored)
    }

    /// What the `gltf` reader would otherwise assume of `prim` (see [`check_accessor`]),
    /// and the count of what the nodes place so far; returns the primitive's morph
    /// targets.
    fn check_primitive<'g>(
        &mut self,
        node: usize,
        m: &gltf::Mesh,
        prim: &gltf::Primitive<'g>,
        weights: &[f32],
    ) -> Result<Vec<gltf::mesh::MorphTarget<'g>>, RenderError> {
        if prim.mode() != gltf::mesh::Mode::Triangles {
            return Err(RenderError::mesh(
                self.path,
                format!(
                    "primitive mode {:?} is not supported: triangles only",
                    prim.mode()
                ),
            ));
        }
        use gltf::accessor::{DataType, Dimensions};
        let positions = prim
            .get(&gltf::Semantic::Positions)
            .ok_or_else(|| RenderError::mesh(self.path, "a primitive has no POSITION"))?;
        check_accessor(
            &positions,
            "POSITION",
            &[DataType::F32],
            Dimensions::Vec3,
            self.buffers,
        )
        .map_err(|e| RenderError::mesh(self.path, e))?;
        if let Some(ind) = prim.indices() {
            check_accessor(
                &ind,
                "indices",
                &[DataType::U8, DataType::U16, DataType::U32],
                Dimensions::Scalar,
                self.buffers,
            )
            .map_err(|e| RenderError::mesh(self.path, e))?;
        }
        // Each copy's vertices are copied too: counted apart (10⁶ vertices under 3
        // indices, placed 10⁵ times, is one triangle a copy).
        self.instanced[0] += prim.indices().map_or(positions.count(), |i| i.count()) as u64 / 3;
        self.instanced[1] += positions.count() as u64;
        if self.instanced.iter().any(|&n| n > MAX_GLTF_TRIANGLES) {
            return Err(RenderError::mesh(
                self.path,
                format!(
                    "its nodes place more than {MAX_GLTF_TRIANGLES} triangles or vertices \
                     (node {} adds mesh {}'s): instance fewer copies",
                    node,
                    m.index()
                ),
            ));
        }
        let targets: Vec<_> = prim.morph_targets().collect();
        for (k, t) in targets
            .iter()
            .enumerate()
            .filter(|&(k, _)| in_use(weights, k))
        {
            if let Some(acc) = t.positions() {
                check_accessor(
                    &acc,
                    "morph target POSITION",
                    &[DataType::F32],
                    Dimensions::Vec3,
                    self.buffers,
                )
                .map_err(|e| RenderError::mesh(self.path, e))?;
                if acc.count() != positions.count() {
                    return Err(RenderError::mesh(
                        self.path,
                        format!(
                            "morph target {k} has {} positions for the primitive's {}",
                            acc.count(),
                            positions.count()
                        ),
                    ));
                }
            }
        }
        Ok(targets)
    }

    /// The primitive's positions, morphed by the targets in use and placed at `world`.
    fn placed_positions(
        &self,
        prim: &gltf::Primitive,
        targets: &[gltf::mesh::MorphTarget],
        weights: &[f32],
        world: Mat4,
    ) -> Result<Vec<Vec3>, RenderError> {
        let reader = prim.reader(|b| self.buffers.get(b.index()).map(|v| &v[..]));
        let mut local: Vec<Vec3> = reader
            .read_positions()
            .ok_or_else(|| RenderError::mesh(self.path, "a primitive has no POSITION"))?
            .map(Vec3::from_array)
            .collect();
        // The targets in use, their positions alone, each accessor checked above:
        // the reader's own walk over every target built readers for the unused
        // ones' normals and tangents too, unchecked (a count of 0 underflowed).
        for (k, t) in targets
            .iter()
            .enumerate()
            .filter(|&(k, _)| in_use(weights, k))
        {
            let Some(acc) = t.positions() else { continue };
            let d = gltf::accessor::Iter::<[f32; 3]>::new(acc, |b| {
                self.buffers.get(b.index()).map(|v| &v[..])
            })
            .ok_or_else(|| {
                RenderError::mesh(
                    self.path,
                    format!("morph target {k}'s positions cannot be read"),
                )
            })?;
            let w = weights[k];
            for (p, d) in local.iter_mut().zip(d) {
                *p += w * Vec3::from_array(d);
            }
        }
        Ok(local
            .into_iter()
            .map(|p| world.transform_point3(p))
            .collect())
    }

    /// Appends the positions `pos` and the primitive's triangles over them, each index
    /// checked, reversing the winding where the placement `mirrored` it.
    fn append_triangles(
        &mut self,
        m: &gltf::Mesh,
        prim: &gltf::Primitive,
        pos: Vec<Vec3>,
        mirrored: bool,
    ) -> Result<(), RenderError> {
        let reader = prim.reader(|b| self.buffers.get(b.index()).map(|v| &v[..]));
        let base = self.mesh.positions.len() as u32;
        let n = pos.len() as u32;
        self.mesh.positions.extend(pos);
        let idx: Vec<u32> = match reader.read_indices() {
            Some(i) => i.into_u32().collect(),
            None => (0..n).collect(),
        };
        if !idx.len().is_multiple_of(3) {
            return Err(RenderError::mesh(
                self.path,
                format!(
                    "mesh {} primitive {}: {} triangle indices, not a multiple of 3",
                    m.index(),
                    prim.index(),
                    idx.len()
                ),
            ));
        }
        if let Some(&i) = idx.iter().find(|&&i| i >= n) {
            return Err(RenderError::mesh(
                self.path,
                format!(
                    "mesh {} primitive {}: index {i} names no vertex: allowed [0, {}] \
                     ({n} vertices)",
                    m.index(),
                    prim.index(),
                    n.saturating_sub(1)
                ),
            ));
        }
        self.mesh.triangles.extend(idx.chunks(3).map(|c| {
            let t = [c[0] + base, c[1] + base, c[2] + base];
            if mirrored { [t[0], t[2], t[1]] } else { t }
        }));
        Ok(())
    }
}

/// Whether morph target `k` is in use: it has a weight, and the weight is not 0.
fn in_use(weights: &[f32], k: usize) -> bool {
    weights.get(k).is_some_and(|&w| w != 0.0)
}

/// A primitive whose POSITION names no accessor, in a file that parses (its other faults
/// are left to gltf's validation): that validation looks the accessor up unchecked
/// (gltf-json 1.4), and such a file panicked.
fn unnamed_position_accessor(bytes: &[u8]) -> Option<String> {
    let g = gltf::Gltf::from_slice_without_validation(bytes).ok()?;
    let root = g.document.as_json();
    let positions = gltf::json::validation::Checked::Valid(gltf::Semantic::Positions);
    root.meshes.iter().enumerate().find_map(|(m, mesh)| {
        mesh.primitives.iter().enumerate().find_map(|(p, prim)| {
            let i = prim.attributes.get(&positions)?.value();
            (i >= root.accessors.len()).then(|| {
                format!(
                    "not a valid glTF/GLB file: mesh {m} primitive {p}: POSITION names accessor \
                     {i}, but the file has {} accessors",
                    root.accessors.len()
                )
            })
        })
    })
}

/// Every buffer of a glTF file, held while its mesh is read: the GLB's binary chunk
/// (`blob`; `bytes` is the file) or the files beside it that the buffers name.
fn read_buffers(
    path: &Path,
    bytes: &[u8],
    document: &gltf::Document,
    mut blob: Option<Vec<u8>>,
) -> Result<Vec<Rc<Vec<u8>>>, RenderError> {
    let dir = path.parent().unwrap_or(Path::new("."));
    // Every buffer is held while the mesh is read. Only buffer 0 may be the GLB's binary
    // chunk (glTF 2.0, 5.5), taken once: each entry naming it copied it, and a 1 MB file
    // listing 100,000 buffers asked 100 GB (an abort, not an error). Buffers naming one
    // file share one read of it; what all of them declare must be allocatable.
    let declared = document
        .buffers()
        .fold(0u64, |sum, b| sum.saturating_add(b.length() as u64));
    if !crate::render::reservable(declared) {
        return Err(RenderError::mesh(
            path,
            format!(
                "its buffers declare {:.1} GB in all, more than can be allocated",
                declared as f64 / 1e9
            ),
        ));
    }
    let mut read: HashMap<(PathBuf, usize), Rc<Vec<u8>>> = HashMap::new();
    let mut buffers: Vec<Rc<Vec<u8>>> = Vec::new();
    for b in document.buffers() {
        let data = buffer_data(path, bytes, dir, &b, &mut blob, &mut read)?;
        check_buffer_length(path, dir, &b, &data)?;
        buffers.push(data);
    }
    Ok(buffers)
}

/// Where buffer `b` is held: the GLB's binary chunk (`blob`, taken), or a file beside
/// `path` (read once for all the buffers naming it, `read`).
fn buffer_data(
    path: &Path,
    bytes: &[u8],
    dir: &Path,
    b: &gltf::Buffer,
    blob: &mut Option<Vec<u8>>,
    read: &mut HashMap<(PathBuf, usize), Rc<Vec<u8>>>,
) -> Result<Rc<Vec<u8>>, RenderError> {
    Ok(match b.source() {
        gltf::buffer::Source::Bin if b.index() != 0 => {
            return Err(RenderError::mesh(
                path,
                if bytes.starts_with(b"glTF") {
                    format!(
                        "buffer {} refers to the GLB binary chunk, which only buffer 0 may",
                        b.index()
                    )
                } else {
                    format!(
                        "buffer {} names no file (it has no uri): a .gltf keeps its \
                         buffers in files beside it",
                        b.index()
                    )
                },
            ));
        }
        gltf::buffer::Source::Bin => Rc::new(blob.take().ok_or_else(|| {
            // gltf reads a buffer without a uri as the chunk.
            RenderError::mesh(
                path,
                if bytes.starts_with(b"glTF") {
                    "the GLB binary chunk is missing"
                } else {
                    "buffer 0 names no file (it has no uri): a .gltf keeps its buffers \
                     in files beside it"
                },
            )
        })?),
        gltf::buffer::Source::Uri(uri) if uri.starts_with("data:") => {
            return Err(RenderError::mesh(
                path,
                "embedded base64 buffers are not supported: convert to .glb",
            ));
        }
        gltf::buffer::Source::Uri("") => {
            return Err(RenderError::mesh(
                path,
                format!(
                    "buffer {} names no file (its uri is empty): a .gltf keeps its \
                     buffers in files beside it",
                    b.index()
                ),
            ));
        }
        gltf::buffer::Source::Uri(uri) => {
            // URIs are percent-encoded (RFC 3986): exporters write a space as %20.
            let name = percent_encoding::percent_decode_str(uri).decode_utf8_lossy();
            read_file_buffer(path, dir.join(&*name), b.length(), read)?
        }
    })
}

/// A buffer held in the file `p` (its declared `length` at most), read once for every
/// buffer naming that file with that length.
fn read_file_buffer(
    path: &Path,
    p: PathBuf,
    length: usize,
    read: &mut HashMap<(PathBuf, usize), Rc<Vec<u8>>>,
) -> Result<Rc<Vec<u8>>, RenderError> {
    if let Some(d) = read.get(&(p.clone(), length)) {
        return Ok(d.clone());
    }
    let cannot = |e: std::io::Error| {
        RenderError::mesh(
            path,
            format!("its buffer {} cannot be read: {e}", p.display()),
        )
    };
    // Only what the buffer declares, from a regular file: a URI naming
    // /dev/zero read until memory ran out (and opening a FIFO waits for a
    // writer, so the kind is looked at first).
    if !std::fs::metadata(&p).map_err(cannot)?.is_file() {
        return Err(RenderError::mesh(
            path,
            format!("its buffer {} is not a regular file", p.display()),
        ));
    }
    let file = std::fs::File::open(&p).map_err(cannot)?;
    let mut data = Vec::new();
    std::io::Read::read_to_end(&mut std::io::Read::take(file, length as u64), &mut data)
        .map_err(cannot)?;
    let data = Rc::new(data);
    read.insert((p, length), data.clone());
    Ok(data)
}

/// Refuses buffer `b` when `data`, what holds it, is shorter than it declares.
fn check_buffer_length(
    path: &Path,
    dir: &Path,
    b: &gltf::Buffer,
    data: &[u8],
) -> Result<(), RenderError> {
    if data.len() < b.length() {
        let held = match b.source() {
            gltf::buffer::Source::Uri(uri) => {
                let name = percent_encoding::percent_decode_str(uri).decode_utf8_lossy();
                format!("its file {}", dir.join(&*name).display())
            }
            gltf::buffer::Source::Bin => "the GLB binary chunk".to_string(),
        };
        return Err(RenderError::mesh(
            path,
            format!(
                "buffer {} declares {} bytes, but {held} holds {}",
                b.index(),
                b.length(),
                data.len()
            ),
        ));
    }
    Ok(())
}

/// What the `gltf` reader assumes without checking (it panics otherwise): the component
/// type and shape, a dense accessor, a stride that fits the element, and data that lies
/// inside its buffer view and buffer.
fn check_accessor(
    acc: &gltf::Accessor,
    what: &str,
    types: &[gltf::accessor::DataType],
    dims: gltf::accessor::Dimensions,
    buffers: &[Rc<Vec<u8>>],
) -> Result<(), String> {
    let id = format!("{what} accessor {}", acc.index());
    if acc.sparse().is_some() {
        return Err(format!("{id} is sparse: not supported"));
    }
    if !types.contains(&acc.data_type()) || acc.dimensions() != dims {
        return Err(format!(
            "{id} has {:?} {:?} components: expected {dims:?} of {types:?}",
            acc.dimensions(),
            acc.data_type()
        ));
    }
    let view = acc
        .view()
        .ok_or_else(|| format!("{id} has no bufferView"))?;
    if acc.count() == 0 {
        return Err(format!("{id} is empty (count 0)"));
    }
    let size = acc.size();
    let stride = view.stride().unwrap_or(size);
    if stride < size {
        return Err(format!(
            "{id}: byteStride {stride} is smaller than its {size}-byte elements"
        ));
    }
    let view_end = view.offset().checked_add(view.length());
    let end = (acc.count() - 1)
        .checked_mul(stride)
        .and_then(|x| x.checked_add(size))
        .and_then(|x| x.checked_add(acc.offset()))
        .and_then(|x| x.checked_add(view.offset()));
    let buffer_len = buffers.get(view.buffer().index()).map_or(0, |b| b.len());
    match (end, view_end) {
        (Some(end), Some(view_end)) if end <= view_end && view_end <= buffer_len => Ok(()),
        _ => Err(format!(
            "{id} reaches past the end of its bufferView {} or buffer {}",
            view.index(),
            view.buffer().index()
        )),
    }
}
