//! Closed triangle meshes: loaders (glTF/GLB, OBJ, PLY), built-in shapes, and the
//! checks the integrators rely on (closed, manifold, consistently oriented outward).
//!
//! The medium fills the inside of the mesh, so an open mesh has no inside: it is an error,
//! reported with the number of boundary edges rather than rendered with leaks.
//!
//! Each file format has its loader (`gltf_file`, `obj_file`, `ply_file`), which reads
//! triangles as the file lists them; [`prepare()`] then welds and checks them, and the
//! `pieces` module winds nested pieces and finds overlapping ones.

mod gltf_file;
mod obj_file;
mod pieces;
mod ply_file;
mod prepare;
mod shapes;
mod triangulate;

use std::path::Path;

use glam::Vec3;

use crate::error::RenderError;

pub use gltf_file::{MAX_GLTF_TRIANGLES, gltf_buffer_files};
pub use pieces::{
    MAX_NESTING_PAIRS, MAX_NESTING_PIECES, MAX_OVERLAP_CHECK_TRIANGLES, MAX_OVERLAP_PIECES,
    PieceTable, nesting_unsurveyed, overlapping_pieces, overlaps_and_pieces, unchecked_pieces,
};
pub use prepare::{MAX_FILE_COORDINATE, prepare};
pub use shapes::{cube, sphere, torus_knot};
pub use triangulate::MAX_FACE_VERTICES;
pub(crate) use triangulate::Triangulator;

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
    load_mesh_as(path, "the mesh")
}

/// [`load_mesh`], a missing file refused as "cannot open `what`" (a scene names the field
/// the path came from).
pub(crate) fn load_mesh_as(path: &Path, what: &str) -> Result<TriMesh, RenderError> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(|e| e.to_ascii_lowercase())
        .unwrap_or_default();
    // Said here, plainly: the OBJ loader's own words for a missing file were "open file
    // failed".
    match std::fs::metadata(path) {
        Err(e) => {
            return Err(RenderError::mesh(path, format!("cannot open {what}: {e}")));
        }
        Ok(m) if m.is_dir() => {
            return Err(RenderError::mesh(path, "is a directory, not a mesh file"));
        }
        Ok(_) => scatter_sim::output::check_input(path).map_err(|e| RenderError::mesh(path, e))?,
    }
    let raw = match ext.as_str() {
        "glb" | "gltf" => gltf_file::load_gltf(path)?,
        "obj" => obj_file::load_obj(path)?,
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

/// PLY, ASCII or binary little-endian: `vertex` with float/double x, y, z (other
/// properties skipped) and `face` with a list of vertex indices (polygons cut in their plane).
fn load_ply(path: &Path) -> Result<TriMesh, RenderError> {
    let bytes = std::fs::read(path).map_err(|e| RenderError::io(path, e))?;
    ply_file::parse(&bytes).map_err(|e| RenderError::mesh(path, e))
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
