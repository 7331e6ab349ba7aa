//! Closed triangle meshes: loaders (glTF/GLB, OBJ, PLY), built-in shapes, and the
//! checks the integrators rely on (closed, manifold, consistently oriented outward).
//!
//! The medium fills the inside of the mesh, so an open mesh has no inside: it is an error,
//! reported with the number of boundary edges rather than rendered with leaks.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use glam::{Mat4, Quat, Vec3};

use crate::error::RenderError;
use crate::piece_survey::{Sides, Survey};

/// An indexed triangle mesh, outward-oriented (counter-clockwise seen from outside).
#[derive(Clone, Debug, Default)]
pub struct TriMesh {
    pub positions: Vec<Vec3>,
    pub triangles: Vec<[u32; 3]>,
}

impl TriMesh {
    pub fn bounds(&self) -> (Vec3, Vec3) {
        bounds_of(self.positions.iter().copied())
    }

    /// The larger of the mesh's extent and its coordinates' magnitude: what f32 rounding
    /// of its positions grows with, so the tolerances that must stay above that rounding
    /// (the spawn offset, box padding, the piece survey's touch distance) are fractions
    /// of it.
    pub fn scale(&self) -> f32 {
        let (lo, hi) = self.bounds();
        lo.abs()
            .max(hi.abs())
            .max_element()
            .max((hi - lo).max_element())
    }

    /// Six times the signed volume (positive for an outward-oriented closed mesh).
    fn signed_volume6(&self) -> f64 {
        (0..self.triangles.len()).map(|t| self.volume6_of(t)).sum()
    }

    /// Triangle `t`'s share of [`Self::signed_volume6`] (its tetrahedron with the origin).
    fn volume6_of(&self, t: usize) -> f64 {
        let [a, b, c] = self.triangles[t].map(|i| self.positions[i as usize].as_dvec3());
        a.dot(b.cross(c))
    }

    /// Scales the mesh so that its bounding-box height (y extent) is `height` and centres
    /// the bounding box at the origin. A mesh with no extent along y cannot be scaled.
    ///
    /// Rounding to the new positions can merge a feature smaller than f32's resolution at
    /// its distance from the centre into one point, and its triangles would get NaN
    /// normals. Such a mesh is prepared again (welded, those triangles dropped, checked
    /// closed), as a file without them would have been, and scaled again, since its
    /// bounds may have changed; a second collapse is an error.
    pub fn normalise_height(&mut self, height: f32) -> Result<(), String> {
        for attempt in 0..2 {
            let (lo, hi) = self.bounds();
            let centre = (lo + hi) * 0.5;
            let extent = hi.y - lo.y;
            if !(extent > 0.0) {
                return Err(
                    "the mesh is flat along y (zero bounding-box height), so `height` cannot \
                     scale it"
                        .into(),
                );
            }
            let s = height / extent;
            for p in &mut self.positions {
                *p = (*p - centre) * s;
            }
            let collapsed = (0..self.triangles.len())
                .filter(|&t| zero_area(self.triangle(t)))
                .count();
            if collapsed == 0 {
                return Ok(());
            }
            let why = format!(
                "scaled to height {height}, {collapsed} of its triangles collapse to no area \
                 (details below single precision's resolution where they lie)"
            );
            if attempt == 1 {
                return Err(format!("{why}: scale the file itself"));
            }
            *self = prepare(std::mem::take(self))
                .map_err(|e| format!("{why}, and without them {e}"))?;
        }
        unreachable!("the second attempt returns")
    }

    /// The object must fit the renderers' single-precision arithmetic: every coordinate
    /// within ±`max`, the bounding box's largest side at least `min_size`, and a volume
    /// that is not negligible next to that box (a closed but flat surface has no inside).
    /// `height`: the object.height it was scaled to, if any, which the advice then names
    /// (a box 10⁷ times wider than high, scaled to height 1, was told to "scale it down
    /// (object.height)").
    pub fn check_scale(&self, min_size: f32, max: f32, height: Option<f32>) -> Result<(), String> {
        let (lo, hi) = self.bounds();
        let advice = |way: &str, than: &str| match height {
            Some(h) => format!(
                "scaled to object.height = {h} (its largest side {:.3e}× its height); set {than} \
                 object.height",
                (hi - lo).max_element() / (hi.y - lo.y)
            ),
            None => format!("scale it {way} (object.height)"),
        };
        if !(lo.abs().max_element() <= max && hi.abs().max_element() <= max) {
            return Err(format!(
                "the mesh's bounding box [{lo}, {hi}] reaches beyond ±{max:e} scene units: {}",
                advice("down", "a smaller")
            ));
        }
        let side = (hi - lo).max_element();
        if !(side >= min_size) {
            return Err(format!(
                "the mesh is {side:e} scene units across, below the smallest allowed {min_size:e}: \
                 {}",
                advice("up", "a larger")
            ));
        }
        let volume = self.signed_volume6().abs() / 6.0;
        if !encloses_volume(volume, f64::from(side)) {
            return Err(format!(
                "the mesh encloses no volume ({volume:e} for a box {side:e} across): it is flat \
                 or degenerate{}",
                rounded_flat(lo, hi)
            ));
        }
        Ok(())
    }

    pub fn triangle(&self, i: usize) -> [Vec3; 3] {
        self.triangles[i].map(|k| self.positions[k as usize])
    }
}

/// Whether a closed surface `side` across encloses a volume: more than 10⁻⁹ of its box's
/// (a closed but flat surface encloses none).
fn encloses_volume(volume: f64, side: f64) -> bool {
    volume > 1e-9 * side.powi(3)
}

/// Whether a triangle has no area in single precision (as the renderers compute with it)
/// or exactly (as its normal is taken, in f64: `Geometry::new`), where either would make
/// its normal NaN.
fn zero_area([a, b, c]: [Vec3; 3]) -> bool {
    let exact = |[a, b, c]: [glam::DVec3; 3]| (b - a).cross(c - a).length_squared() == 0.0;
    (b - a).cross(c - a).length_squared() == 0.0
        || exact([a.as_dvec3(), b.as_dvec3(), c.as_dvec3()])
}

/// The bounding box of `points` (lowest and highest corner).
fn bounds_of(points: impl Iterator<Item = Vec3>) -> (Vec3, Vec3) {
    points.fold(
        (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
        |(lo, hi), p| (lo.min(p), hi.max(p)),
    )
}

/// Loads a mesh file by extension and returns it welded, checked and outward-oriented.
pub fn load_mesh(path: &Path) -> Result<TriMesh, RenderError> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(|e| e.to_ascii_lowercase())
        .unwrap_or_default();
    // Said here, plainly: the OBJ loader's own words for a missing file were "open file
    // failed".
    match std::fs::metadata(path) {
        Err(e) => {
            return Err(RenderError::mesh(
                path,
                format!("cannot open the mesh: {e}"),
            ));
        }
        Ok(m) if m.is_dir() => {
            return Err(RenderError::mesh(path, "is a directory, not a mesh file"));
        }
        Ok(_) => scatter_sim::output::check_input(path).map_err(|e| RenderError::mesh(path, e))?,
    }
    let raw = match ext.as_str() {
        "glb" | "gltf" => load_gltf(path)?,
        "obj" => load_obj(path)?,
        "ply" => load_ply(path)?,
        _ => {
            return Err(RenderError::mesh(
                path,
                "unknown mesh format: use .glb, .gltf, .obj or .ply",
            ));
        }
    };
    prepare(raw).map_err(|e| RenderError::mesh(path, e))
}

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

/// Refuses a piece that encloses no volume though the whole mesh does (which
/// `TriMesh::check_scale` alone sees): a face listed twice, once each way (a "two-sided"
/// export), is closed by the edge check, and paths entering it were spawned past it, in
/// the air, believing themselves inside the medium.
fn flat_pieces(
    pieces: &[Vec<usize>],
    volumes: &[f64],
    boxes: &[(Vec3, Vec3)],
) -> Result<(), String> {
    for (k, ((tris, v6), (lo, hi))) in pieces.iter().zip(volumes).zip(boxes).enumerate() {
        let side = f64::from((*hi - *lo).max_element());
        let volume = v6.abs() / 6.0;
        if !encloses_volume(volume, side) {
            return Err(format!(
                "piece {k} of the mesh ({} triangles, {side:e} across) encloses no volume \
                 ({volume:e}): a flat surface closed on itself, such as a face listed twice \
                 with opposite windings (a two-sided export); remove it",
                tris.len()
            ));
        }
    }
    Ok(())
}

/// Winds each closed piece of the mesh so that its faces point away from the medium.
///
/// Nested pieces alternate: a hollow shell's inner wall bounds the medium from inside
/// (faces toward the cavity), a ball in that cavity is solid again. A piece's depth is one
/// more than that of the deepest piece enclosing it (0 for none); odd depths face inward,
/// even ones outward.
/// Files wind each piece as they like (a mirrored glTF instance, or a shell exported with
/// one wall reversed), and `check_closed` only sees that each piece agrees with itself;
/// orienting the whole mesh by its total volume left such a piece inside out, rendered
/// with leaks and too bright. Pieces that merely overlap are not nested: each faces
/// outward, as before.
fn orient_pieces(m: &mut TriMesh, pieces: &[Vec<usize>], volumes: &[f64], boxes: &[(Vec3, Vec3)]) {
    // Beyond the survey's limits each piece faces outward by itself (`render` says so).
    let depths = if pieces.len() < 2 || !nesting_surveyed(boxes) {
        vec![0; pieces.len()]
    } else {
        let survey = Survey::new(m, pieces);
        nesting_depths(&survey.classified_probes(), volumes)
    };
    for ((tris, &volume), depth) in pieces.iter().zip(volumes).zip(depths) {
        if (volume > 0.0) != (depth % 2 == 0) {
            for &t in tris {
                m.triangles[t].swap(1, 2);
            }
        }
    }
}

/// Six times each piece's signed volume.
fn piece_volumes(m: &TriMesh, pieces: &[Vec<usize>]) -> Vec<f64> {
    pieces
        .iter()
        .map(|tris| tris.iter().map(|&t| m.volume6_of(t)).sum())
        .collect()
}

/// Each piece's nesting depth (see [`orient_pieces`]), whatever the pieces' winding, from
/// its probes' sides of the other pieces ([`Survey::classified_probes`]: points spread
/// over the piece and where other pieces' surfaces cross it). At each probe the deepest
/// of the pieces around it is found; the piece's depth is one more than the shallowest
/// of those, −1 for a point outside every piece. So a piece within another is one deeper
/// (a cavity inside two overlapping pieces, each solid, is one hole, not depth 2), and so
/// is one within the union of overlapping pieces but in none of them alone (a cavity
/// across their seam); a piece partly outside everything is solid (depth 0), one that
/// overlaps another.
/// - A probe on another piece's surface counts as inside it where the piece's other
///   probes say it encloses this one (a block resting on a cavity's floor, counted as
///   outside the cavity there, was taken for air), and as outside it otherwise (boxes
///   overlapping with faces in shared planes, whose side faces bound the union).
/// - The depths are settled by repeating the rule until none changes, largest piece
///   first (one round for plain nesting): a cavity across a seam can be larger than
///   either solid. Should they not settle (pieces each around the other's probes, which
///   no nesting makes), only larger pieces count as around a smaller one, which settles.
fn nesting_depths(classified: &[Vec<Sides>], volumes: &[f64]) -> Vec<usize> {
    let n = classified.len();
    let around = |i: usize, larger_only: bool| -> Vec<Vec<usize>> {
        let probes = &classified[i];
        // Per piece listed by some probe: probes inside it, probes on its surface. It
        // encloses i where every probe is one or the other, and some inside.
        let mut counts: HashMap<usize, (usize, usize)> = HashMap::new();
        for s in probes {
            for (j, v) in s.listed() {
                let c = counts.entry(j).or_default();
                if v == Some(true) {
                    c.0 += 1;
                } else {
                    c.1 += 1;
                }
            }
        }
        let encloses = |j: usize| {
            j != i
                && counts
                    .get(&j)
                    .is_some_and(|&(a, u)| a > 0 && a + u == probes.len())
        };
        probes
            .iter()
            .map(|s| {
                s.listed()
                    .filter(|&(j, v)| j != i && (v == Some(true) || v.is_none() && encloses(j)))
                    .map(|(j, _)| j)
                    .filter(|&j| !larger_only || volumes[j].abs() > volumes[i].abs())
                    .collect()
            })
            .collect()
    };
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_by(|&a, &b| volumes[b].abs().total_cmp(&volumes[a].abs()));
    let settle = |around: &[Vec<Vec<usize>>]| -> Option<Vec<usize>> {
        // Depths only grow from 0, one nesting level a round at most: n + 1 rounds
        // settle any nesting of n pieces.
        let mut depths = vec![0usize; n];
        for _ in 0..=n {
            let mut changed = false;
            for &i in &order {
                let shallowest = around[i]
                    .iter()
                    .map(|js| js.iter().map(|&j| depths[j] as i64).max().unwrap_or(-1))
                    .min();
                let d = shallowest.map_or(0, |d| (d + 1) as usize);
                changed |= d != depths[i];
                depths[i] = d;
            }
            if !changed {
                return Some(depths);
            }
        }
        None
    };
    let all: Vec<_> = (0..n).map(|i| around(i, false)).collect();
    settle(&all).unwrap_or_else(|| {
        let larger: Vec<_> = (0..n).map(|i| around(i, true)).collect();
        settle(&larger).unwrap_or_else(|| vec![0; n])
    })
}

/// Per triangle its piece's number, and per piece its nesting depth.
pub type PieceTable = (Vec<u8>, Vec<usize>);

/// The pairs of closed pieces that overlap ([`overlapping_pieces`]) and, where there are
/// any, which piece each triangle belongs to and how deep each piece is nested
/// ([`crate::geometry::Pieces`]; at most [`MAX_OVERLAP_PIECES`] pieces, so that the set
/// of pieces around a point fits in a u32's bits). Both read one survey of the pieces
/// ([`Survey`]).
pub fn overlaps_and_pieces(m: &TriMesh) -> (Vec<(usize, usize)>, Option<PieceTable>) {
    let pieces = pieces(m);
    if pieces.len() < 2
        || pieces.len() > MAX_OVERLAP_PIECES
        || m.triangles.len() > MAX_OVERLAP_CHECK_TRIANGLES
    {
        return (Vec::new(), None);
    }
    let classified = Survey::new(m, &pieces).classified_probes();
    let overlaps = overlapping(&classified);
    if overlaps.is_empty() {
        return (overlaps, None);
    }
    let depths = nesting_depths(&classified, &piece_volumes(m, &pieces));
    let mut of_tri = vec![0u8; m.triangles.len()];
    for (k, tris) in pieces.iter().enumerate() {
        for &t in tris {
            of_tri[t] = k as u8;
        }
    }
    (overlaps, Some((of_tri, depths)))
}

/// Most pairs of pieces with overlapping bounding boxes, and most pieces, whose nesting
/// [`prepare`] surveys (cavities wound inward); beyond either, each piece is wound outward
/// by itself. The survey's cost grows with the pairs that overlap: 2,000 cubes all
/// overlapping (~2·10⁶ pairs) took 168 s and 2.6 GB, 200 (19,900 pairs) 2 s; pieces apart
/// cost little each.
pub const MAX_NESTING_PAIRS: usize = 20_000;
pub const MAX_NESTING_PIECES: usize = 4096;

/// Whether [`prepare`] surveys the nesting of pieces with these bounding `boxes` (see
/// [`MAX_NESTING_PAIRS`]).
fn nesting_surveyed(boxes: &[(Vec3, Vec3)]) -> bool {
    if boxes.len() > MAX_NESTING_PIECES {
        return false;
    }
    let mut boxes = boxes.to_vec();
    boxes.sort_by(|a, b| a.0.x.total_cmp(&b.0.x));
    let mut pairs = 0;
    for (i, (lo, hi)) in boxes.iter().enumerate() {
        for (lo2, hi2) in boxes[i + 1..].iter().take_while(|b| b.0.x <= hi.x) {
            if lo2.y <= hi.y && lo.y <= hi2.y && lo2.z <= hi.z && lo.z <= hi2.z {
                pairs += 1;
                if pairs > MAX_NESTING_PAIRS {
                    return false;
                }
            }
        }
    }
    true
}

/// Whether a mesh's nesting goes unsurveyed (beyond [`MAX_NESTING_PAIRS`] or
/// [`MAX_NESTING_PIECES`]): its cavities, if any, render as medium.
pub fn nesting_unsurveyed(m: &TriMesh) -> bool {
    let pieces = pieces(m);
    pieces.len() > 1 && !nesting_surveyed(&piece_boxes(m, &pieces))
}

/// Each piece's bounding box (lowest and highest corner).
fn piece_boxes(m: &TriMesh, pieces: &[Vec<usize>]) -> Vec<(Vec3, Vec3)> {
    pieces
        .iter()
        .map(|tris| bounds_of(tris.iter().flat_map(|&t| m.triangle(t))))
        .collect()
}

/// Most pieces [`overlapping_pieces`] checks (and [`overlaps_and_pieces`] numbers).
pub const MAX_OVERLAP_PIECES: usize = 16;
/// Most triangles of a mesh of several pieces that [`overlapping_pieces`] checks.
pub const MAX_OVERLAP_CHECK_TRIANGLES: usize = 2_000_000;

/// The number of closed pieces of a mesh of several that [`overlapping_pieces`] does not
/// check (beyond its limits), so that the user hears that overlaps there would render
/// partly as air; None for one piece or a checked mesh.
pub fn unchecked_pieces(m: &TriMesh) -> Option<usize> {
    let n = pieces(m).len();
    (n > 1 && (n > MAX_OVERLAP_PIECES || m.triangles.len() > MAX_OVERLAP_CHECK_TRIANGLES))
        .then_some(n)
}

/// The triangles of each connected piece, joined through shared edges: two closed parts
/// that only touch at a vertex are separate pieces (the closedness check only ties the
/// winding of triangles across edges, so one flip decision for both could leave one
/// inside out).
fn pieces(m: &TriMesh) -> Vec<Vec<usize>> {
    fn root(parent: &mut [u32], mut x: u32) -> u32 {
        while parent[x as usize] != x {
            parent[x as usize] = parent[parent[x as usize] as usize];
            x = parent[x as usize];
        }
        x
    }
    let mut parent: Vec<u32> = (0..m.triangles.len() as u32).collect();
    let mut first: HashMap<(u32, u32), u32> = HashMap::new();
    for (k, t) in m.triangles.iter().enumerate() {
        for e in 0..3 {
            let (a, b) = (t[e], t[(e + 1) % 3]);
            let other = *first.entry((a.min(b), a.max(b))).or_insert(k as u32);
            let (r1, r2) = (root(&mut parent, other), root(&mut parent, k as u32));
            if r1 != r2 {
                parent[r2 as usize] = r1;
            }
        }
    }
    let mut piece_of: HashMap<u32, usize> = HashMap::new();
    let mut pieces: Vec<Vec<usize>> = Vec::new();
    for k in 0..m.triangles.len() {
        let r = root(&mut parent, k as u32);
        let p = *piece_of.entry(r).or_insert_with(|| {
            pieces.push(Vec::new());
            pieces.len() - 1
        });
        pieces[p].push(k);
    }
    pieces
}

/// Pairs of closed pieces (numbered in the order of their first triangle) that overlap
/// without one enclosing the other. The renderers then follow which pieces a path is in
/// ([`crate::geometry::Pieces`]) to render their union, which an inside/outside flag
/// does not (two overlapping boxes came out 4 % brighter than the one box they make).
/// Found where some of a piece's probes ([`Survey::classified_probes`]: sampled ones,
/// and where other pieces' surfaces cross it) lie clearly inside the other and some
/// clearly outside; probes on the other's surface (touching parts) count as neither.
/// Checked for meshes of at most 16 pieces (the pieces around a point are a u32's bits)
/// and 2,000,000 triangles (the survey of 1,000,000 took ~0.5 s on 2 cores); larger ones
/// are not checked.
pub fn overlapping_pieces(m: &TriMesh) -> Vec<(usize, usize)> {
    overlaps_and_pieces(m).0
}

/// [`overlapping_pieces`] from each piece's probes' sides of the others: a pair overlaps
/// where some probes of one lie clearly inside the other and some clearly outside
/// (probes on the other's surface, as where parts touch, count as neither).
fn overlapping(classified: &[Vec<Sides>]) -> Vec<(usize, usize)> {
    let n = classified.len();
    let straddles = |a: usize, b: usize| {
        let seen = |side: bool| classified[a].iter().any(|s| s.of(b) == Some(side));
        seen(true) && seen(false)
    };
    let mut found = Vec::new();
    for i in 0..n {
        for j in i + 1..n {
            if straddles(i, j) || straddles(j, i) {
                found.push((i, j));
            }
        }
    }
    found
}

/// Splits a file's polygons into triangles of the same winding.
///
/// A fan from the first vertex covers area outside a concave polygon (an L-shaped cap
/// came out with its notch partly filled), and the extra faces still pair up edge for
/// edge, so the closedness check cannot catch it. Polygons beyond triangles are therefore
/// cut by ear clipping (earcut) in their own plane; one that earcut cannot cut whole
/// (self-intersecting, or with no area) falls back to the fan.
#[derive(Default)]
pub(crate) struct Triangulator {
    earcut: earcut::Earcut<f64>,
    flat: Vec<[f64; 2]>,
    cut: Vec<u32>,
    ring: Vec<u32>,
}

/// Most vertices a file's face may have. Ear clipping a polygon costs O(n²) and more
/// when it is not simple: one face of 20,000 vertices in random order took 6 s, one of
/// 200,000 (a PLY allows lists of 10⁶) would have run for hours.
pub const MAX_FACE_VERTICES: usize = 4096;

impl Triangulator {
    /// [`Self::polygon`] for each polygon of `indices`, listed one after another with
    /// their vertex counts in `sizes` (which add up to `indices.len()`); refuses a
    /// polygon of more than [`MAX_FACE_VERTICES`], naming it (counted from 0).
    pub(crate) fn polygons(
        &mut self,
        positions: &[Vec3],
        indices: &[u32],
        sizes: impl IntoIterator<Item = usize>,
        out: &mut Vec<[u32; 3]>,
    ) -> Result<(), String> {
        let mut at = 0;
        for (k, n) in sizes.into_iter().enumerate() {
            if n > MAX_FACE_VERTICES {
                return Err(format!(
                    "face {k} has {n} vertices: at most {MAX_FACE_VERTICES} are supported \
                     (triangulate it before exporting)"
                ));
            }
            self.polygon(positions, &indices[at..at + n], out);
            at += n;
        }
        Ok(())
    }

    /// Appends the triangles of `poly` (indices into `positions`, all valid) to `out`.
    pub(crate) fn polygon(&mut self, positions: &[Vec3], poly: &[u32], out: &mut Vec<[u32; 3]>) {
        // A vertex listed twice in a row (by index or by position; welding merges the
        // latter) adds no edge and no area, but earcut drops such points and then cuts
        // fewer triangles than the fallback test expects.
        self.ring.clear();
        for &i in poly {
            if self
                .ring
                .last()
                .is_none_or(|&j| positions[j as usize] != positions[i as usize])
            {
                self.ring.push(i);
            }
        }
        while self.ring.len() > 1
            && positions[self.ring[0] as usize] == positions[*self.ring.last().unwrap() as usize]
        {
            self.ring.pop();
        }
        let ring = &self.ring;
        let n = ring.len();
        if n < 4 {
            if n == 3 {
                out.push([ring[0], ring[1], ring[2]]);
            }
            return;
        }
        let at = |k: usize| positions[ring[k] as usize].as_dvec3();
        // Newell's normal: the polygon's area vector, whatever its shape.
        let normal: glam::DVec3 = (0..n).map(|k| at(k).cross(at((k + 1) % n))).sum();
        let fan = |out: &mut Vec<[u32; 3]>| {
            out.extend((1..n - 1).map(|k| [ring[0], ring[k], ring[k + 1]]));
        };
        let Some(normal) = normal.try_normalize() else {
            return fan(out);
        };
        let (u, v) = normal.any_orthonormal_pair();
        self.flat.clear();
        self.flat
            .extend((0..n).map(|k| [at(k).dot(u), at(k).dot(v)]));
        self.earcut
            .earcut(self.flat.iter().copied(), &[] as &[u32], &mut self.cut);
        if self.cut.len() != 3 * (n - 2) {
            return fan(out);
        }
        out.extend(self.cut.chunks(3).map(|c| {
            let t = [
                ring[c[0] as usize],
                ring[c[1] as usize],
                ring[c[2] as usize],
            ];
            let [a, b, c] = t.map(|i| positions[i as usize].as_dvec3());
            // Keep the file's winding: earcut's own depends on the projection.
            if (b - a).cross(c - a).dot(normal) < 0.0 {
                [t[0], t[2], t[1]]
            } else {
                t
            }
        }));
    }
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

fn load_gltf(path: &Path) -> Result<TriMesh, RenderError> {
    let bytes = std::fs::read(path).map_err(|e| RenderError::io(path, e))?;
    // A .glb is binary and starts with the magic "glTF"; without it gltf would parse the
    // bytes as JSON and say "expected value at line 1 column 1".
    let glb = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("glb"));
    // (A JSON glTF under a .glb name, which gltf reads, is let through.)
    if glb
        && !bytes.is_empty()
        && !bytes.starts_with(b"glTF")
        && !bytes.trim_ascii_start().starts_with(b"{")
    {
        return Err(RenderError::mesh(
            path,
            "not a valid GLB file: it does not start with the GLB magic `glTF`",
        ));
    }
    // A file shorter than its GLB header's length (bytes 8..12) is cut short: said so, where
    // gltf says "could not completely read the object". Bytes after the declared end are
    // left to gltf, which ignores them (harmless, and some tools may pad).
    if bytes.starts_with(b"glTF") && bytes.len() >= 12 {
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
    let gltf::Gltf { document, blob } = gltf::Gltf::from_slice(&bytes).map_err(|e| {
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
    let mut blob = blob;
    let mut read: HashMap<(PathBuf, usize), std::rc::Rc<Vec<u8>>> = HashMap::new();
    let mut buffers: Vec<std::rc::Rc<Vec<u8>>> = Vec::new();
    for b in document.buffers() {
        let data = match b.source() {
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
            gltf::buffer::Source::Bin => std::rc::Rc::new(blob.take().ok_or_else(|| {
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
                let p = dir.join(&*name);
                if let Some(d) = read.get(&(p.clone(), b.length())) {
                    buffers.push(d.clone());
                    continue;
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
                std::io::Read::read_to_end(
                    &mut std::io::Read::take(file, b.length() as u64),
                    &mut data,
                )
                .map_err(cannot)?;
                let data = std::rc::Rc::new(data);
                read.insert((p, b.length()), data.clone());
                data
            }
        };
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
        buffers.push(data);
    }
    // Instances of one mesh (nodes naming it) are copied into the one triangle list: 5,000
    // nodes over a mesh of 10⁶ triangles asked for 5·10⁹.
    let mut instanced = [0u64; 2];
    let mut mesh = TriMesh::default();
    let scene = document
        .default_scene()
        .or_else(|| document.scenes().next());
    let roots: Vec<gltf::Node> = match scene {
        Some(s) => s.nodes().collect(),
        // No scene: every node that is no other's child (the children come through their
        // parents; started from too, they would be reached twice).
        None => {
            let mut child = vec![false; document.nodes().len()];
            for c in document.nodes().flat_map(|n| n.children()) {
                child[c.index()] = true;
            }
            document.nodes().filter(|n| !child[n.index()]).collect()
        }
    };
    let mut stack: Vec<(gltf::Node, Mat4)> =
        roots.into_iter().map(|n| (n, Mat4::IDENTITY)).collect();
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
        // A mirroring transform reverses the winding; glTF asks loaders to undo that.
        let mirrored = world.determinant() < 0.0;
        if let Some(m) = node.mesh() {
            // The morph targets' default weights (the node's, else the mesh's) shape the
            // mesh as the file shows it at rest.
            let weights = node.weights().or(m.weights()).unwrap_or(&[]);
            for prim in m.primitives() {
                if prim.mode() != gltf::mesh::Mode::Triangles {
                    return Err(RenderError::mesh(
                        path,
                        format!(
                            "primitive mode {:?} is not supported: triangles only",
                            prim.mode()
                        ),
                    ));
                }
                use gltf::accessor::{DataType, Dimensions};
                let positions = prim
                    .get(&gltf::Semantic::Positions)
                    .ok_or_else(|| RenderError::mesh(path, "a primitive has no POSITION"))?;
                check_accessor(
                    &positions,
                    "POSITION",
                    &[DataType::F32],
                    Dimensions::Vec3,
                    &buffers,
                )
                .map_err(|e| RenderError::mesh(path, e))?;
                if let Some(ind) = prim.indices() {
                    check_accessor(
                        &ind,
                        "indices",
                        &[DataType::U8, DataType::U16, DataType::U32],
                        Dimensions::Scalar,
                        &buffers,
                    )
                    .map_err(|e| RenderError::mesh(path, e))?;
                }
                // Each copy's vertices are copied too: counted apart (10⁶ vertices under 3
                // indices, placed 10⁵ times, is one triangle a copy).
                instanced[0] += prim.indices().map_or(positions.count(), |i| i.count()) as u64 / 3;
                instanced[1] += positions.count() as u64;
                if instanced.iter().any(|&n| n > MAX_GLTF_TRIANGLES) {
                    return Err(RenderError::mesh(
                        path,
                        format!(
                            "its nodes place more than {MAX_GLTF_TRIANGLES} triangles or vertices \
                             (node {} adds mesh {}'s): instance fewer copies",
                            node.index(),
                            m.index()
                        ),
                    ));
                }
                let targets: Vec<_> = prim.morph_targets().collect();
                let in_use = |k: usize| weights.get(k).is_some_and(|&w| w != 0.0);
                for (k, t) in targets.iter().enumerate().filter(|&(k, _)| in_use(k)) {
                    if let Some(acc) = t.positions() {
                        check_accessor(
                            &acc,
                            "morph target POSITION",
                            &[DataType::F32],
                            Dimensions::Vec3,
                            &buffers,
                        )
                        .map_err(|e| RenderError::mesh(path, e))?;
                        if acc.count() != positions.count() {
                            return Err(RenderError::mesh(
                                path,
                                format!(
                                    "morph target {k} has {} positions for the primitive's {}",
                                    acc.count(),
                                    positions.count()
                                ),
                            ));
                        }
                    }
                }
                let reader = prim.reader(|b| buffers.get(b.index()).map(|v| &v[..]));
                let base = mesh.positions.len() as u32;
                let mut local: Vec<Vec3> = reader
                    .read_positions()
                    .ok_or_else(|| RenderError::mesh(path, "a primitive has no POSITION"))?
                    .map(Vec3::from_array)
                    .collect();
                // The targets in use, their positions alone, each accessor checked above:
                // the reader's own walk over every target built readers for the unused
                // ones' normals and tangents too, unchecked (a count of 0 underflowed).
                for (k, t) in targets.iter().enumerate().filter(|&(k, _)| in_use(k)) {
                    let Some(acc) = t.positions() else { continue };
                    let d = gltf::accessor::Iter::<[f32; 3]>::new(acc, |b| {
                        buffers.get(b.index()).map(|v| &v[..])
                    })
                    .ok_or_else(|| {
                        RenderError::mesh(
                            path,
                            format!("morph target {k}'s positions cannot be read"),
                        )
                    })?;
                    let w = weights[k];
                    for (p, d) in local.iter_mut().zip(d) {
                        *p += w * Vec3::from_array(d);
                    }
                }
                let pos: Vec<Vec3> = local
                    .into_iter()
                    .map(|p| world.transform_point3(p))
                    .collect();
                let n = pos.len() as u32;
                mesh.positions.extend(pos);
                let idx: Vec<u32> = match reader.read_indices() {
                    Some(i) => i.into_u32().collect(),
                    None => (0..n).collect(),
                };
                if !idx.len().is_multiple_of(3) {
                    return Err(RenderError::mesh(
                        path,
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
                        path,
                        format!(
                            "mesh {} primitive {}: index {i} names no vertex: allowed 0..={} \
                             ({n} vertices)",
                            m.index(),
                            prim.index(),
                            n.saturating_sub(1)
                        ),
                    ));
                }
                mesh.triangles.extend(idx.chunks(3).map(|c| {
                    let t = [c[0] + base, c[1] + base, c[2] + base];
                    if mirrored { [t[0], t[2], t[1]] } else { t }
                }));
            }
        }
        for c in node.children() {
            stack.push((c, world));
        }
    }
    Ok(mesh)
}

/// What the `gltf` reader assumes without checking (it panics otherwise): the component
/// type and shape, a dense accessor, a stride that fits the element, and data that lies
/// inside its buffer view and buffer.
fn check_accessor(
    acc: &gltf::Accessor,
    what: &str,
    types: &[gltf::accessor::DataType],
    dims: gltf::accessor::Dimensions,
    buffers: &[std::rc::Rc<Vec<u8>>],
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

fn load_obj(path: &Path) -> Result<TriMesh, RenderError> {
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
/// with overflow checks, a message without a line elsewhere), and polylines (`l`), which
/// tobj read as faces when of three points or more (a cube with a polyline was refused as
/// "faces listed twice").
fn positions_only(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    for line in text.lines() {
        let mut words = line.split_whitespace();
        match words.next() {
            Some("l" | "vt" | "vn" | "vp") => {}
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
                                ", or -{before}..=-1 counting back over the {before} defined \
                                 before it"
                            )
                        } else {
                            String::new()
                        };
                        return Some(format!(
                            "line {at}: face index `{first}` names no vertex: allowed 1..={total} \
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

/// PLY, ASCII or binary little-endian: `vertex` with float/double x, y, z (other
/// properties skipped) and `face` with a list of vertex indices (polygons cut in their plane).
fn load_ply(path: &Path) -> Result<TriMesh, RenderError> {
    let bytes = std::fs::read(path).map_err(|e| RenderError::io(path, e))?;
    crate::ply::parse(&bytes).map_err(|e| RenderError::mesh(path, e))
}

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

/// Far from the origin, single precision may have flattened a mesh as it was read (a
/// unit cube at x = 10⁷, where f32 steps by 1, was called flat without a word on why):
/// said so where the step there exceeds 10⁻³ of the box's largest side.
fn rounded_flat(lo: Vec3, hi: Vec3) -> String {
    let reach = lo.abs().max(hi.abs()).max_element();
    let step = reach * f32::EPSILON;
    if step > (hi - lo).max_element() * 1e-3 {
        format!(
            "; or single precision rounded it flat as it was read: its coordinates reach \
             {reach:e}, where f32 steps by {step:.1e}; move it nearer the origin in the file"
        )
    } else {
        String::new()
    }
}

#[cfg(test)]
mod tests {
    use super::cube;

    /// A size out of range is told apart by how it came about: scaled by object.height,
    /// the advice names that setting and which way to change it (a box 10⁷ times wider
    /// than high, scaled to height 1, was told to "scale it down (object.height)" as if
    /// the file were too large); from the file itself, to scale it.
    #[test]
    fn the_size_checks_advice_follows_object_height() {
        let mut wide = cube(1.0);
        for p in &mut wide.positions {
            p.x *= 1e7;
            p.z *= 1e7;
        }
        let e = wide.check_scale(1e-3, 1e6, None).unwrap_err();
        assert!(
            e.ends_with("scene units: scale it down (object.height)"),
            "{e}"
        );
        let e = wide.check_scale(1e-3, 1e6, Some(1.0)).unwrap_err();
        assert!(
            e.ends_with(
                "scaled to object.height = 1 (its largest side 1.000e7× its height); set a \
                 smaller object.height"
            ),
            "{e}"
        );
        let tiny = cube(1e-4);
        let e = tiny.check_scale(1e-3, 1e6, Some(1e-4)).unwrap_err();
        assert!(
            e.contains("below the smallest allowed 1e-3")
                && e.ends_with("set a larger object.height"),
            "{e}"
        );
        assert!(cube(1.0).check_scale(1e-3, 1e6, Some(1.0)).is_ok());
    }

    /// A flat mesh far from the origin is told that single precision may have flattened
    /// it; one near the origin is not.
    #[test]
    fn a_flat_mesh_far_out_names_the_rounding() {
        let mut flat = cube(1.0);
        for p in &mut flat.positions {
            p.x = 1e7;
        }
        let e = flat.check_scale(1e-3, 1e15, None).unwrap_err();
        assert!(
            e.contains("it is flat or degenerate; or single precision rounded it flat")
                && e.contains("reach 1e7"),
            "{e}"
        );
        for p in &mut flat.positions {
            p.x = 0.0;
        }
        let e = flat.check_scale(1e-3, 1e15, None).unwrap_err();
        assert!(e.ends_with("it is flat or degenerate"), "{e}");
    }
}
