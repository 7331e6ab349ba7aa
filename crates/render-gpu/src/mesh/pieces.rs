//! A mesh's closed pieces: their volumes and boxes, how they nest (cavities are wound
//! inward) and which of them overlap (rendered as their union).

use std::collections::HashMap;

use glam::Vec3;

use super::{TriMesh, bounds_of, encloses_volume};
use crate::piece_survey::{Sides, Survey};

/// Refuses a piece that encloses no volume though the whole mesh does (which
/// `TriMesh::check_scale` alone sees): a face listed twice, once each way (a "two-sided"
/// export), is closed by the edge check, and paths entering it were spawned past it, in
/// the air, believing themselves inside the medium.
pub(super) fn flat_pieces(
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
pub(super) fn orient_pieces(
    m: &mut TriMesh,
    pieces: &[Vec<usize>],
    volumes: &[f64],
    boxes: &[(Vec3, Vec3)],
) {
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
pub(super) fn piece_volumes(m: &TriMesh, pieces: &[Vec<usize>]) -> Vec<f64> {
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
/// (`Survey`).
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
/// [`prepare`](super::prepare()) surveys (cavities wound inward); beyond either, each piece
/// is wound outward by itself. The survey's cost grows with the pairs that overlap: 2,000
/// cubes all overlapping (~2·10⁶ pairs) took 168 s and 2.6 GB, 200 (19,900 pairs) 2 s;
/// pieces apart cost little each.
pub const MAX_NESTING_PAIRS: usize = 20_000;
pub const MAX_NESTING_PIECES: usize = 4096;

/// Whether [`prepare`](super::prepare()) surveys the nesting of pieces with these bounding
/// `boxes` (see [`MAX_NESTING_PAIRS`]).
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
pub(super) fn piece_boxes(m: &TriMesh, pieces: &[Vec<usize>]) -> Vec<(Vec3, Vec3)> {
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
pub(super) fn pieces(m: &TriMesh) -> Vec<Vec<usize>> {
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
/// Found where some of a piece's probes (`Survey::classified_probes`: sampled ones,
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
