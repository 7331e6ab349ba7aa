//! Cutting a file's polygons into triangles.

use glam::Vec3;

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
