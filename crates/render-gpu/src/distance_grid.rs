//! The conservative distance grid of the sphere-tracing integrator (design §4).
//!
//! Each cell stores the exact distance d(c) from its centre c to the surface. For a query
//! point p in that cell the returned radius is d(c) − |p − c|, which never exceeds the
//! true distance d(p) because the distance function is 1-Lipschitz — so a sphere of
//! that radius around p never crosses the mesh. Outside the grid the radius is 0 (the
//! integrator then falls back to ordinary PT events).

use std::path::Path;
use std::sync::atomic::{AtomicU64, Ordering};

use glam::{UVec3, Vec3};
use rayon::prelude::*;

use crate::geometry::{Geometry, Hit};

pub struct DistanceGrid {
    pub lo: Vec3,
    pub cell: f32,
    /// 1/cell: a lookup multiplies (a division was ~10 % of a sphere step's completion).
    /// Rounding may put a point on a cell boundary into the neighbouring cell, which is
    /// harmless: d(c) − |p − c| bounds d(p) for any centre c, and a cell's candidate list
    /// covers its points with padding for such rounding.
    inv_cell: f32,
    pub dims: UVec3,
    /// Radii below this (two cell diagonals) are worth refining with an exact query.
    pub near_surface: f32,
    /// Per cell (x fastest) [d(c) as f32 bits, already reduced by the rounding margin;
    /// where the cell's candidate list starts], plus one closing entry [0, end of the
    /// last list]. The value and its list's bounds share a cache line: a sphere step
    /// reads both, and the grid is too large for the caches. The WGSL kernels read the
    /// same array.
    pub cells: Vec<[u32; 2]>,
    /// For each cell where that refinement can happen, the triangles that can be nearest
    /// to a point in it: cell i's are `candidates[cells[i][1]..cells[i + 1][1]]` (none
    /// elsewhere). The nearest of a dozen listed triangles is the exact distance at a
    /// fraction of a nearest-triangle search through the BVH, which must also prove that
    /// the neighbours, all about as near, are not nearer.
    pub candidates: Vec<u32>,
}

const MAGIC: &[u8; 8] = b"STCVDG05";

/// Cells a side of the blocks that share one triangle list while their centres'
/// distances are found ([`DistanceGrid::centre_distances`]).
const BLOCK: u32 = 4;

/// Most listed triangles a block's cells scan per node its centre's search opened
/// (measured, list length over nodes opened: the sphere's blocks 3.0 at the median and 4.5
/// at the 99th percentile, the bunny's 1.5 and 2.9, a 499k-triangle sphere's 36 to 270;
/// docs/BENCHMARKS.md).
const LIST_PER_NODE: usize = 4;

/// Every triangle within `reach` of `c`, padded for f32 rounding (1e-5 relative, 1e-4 of a
/// `cell` and the scene's offset eps, ~100 ulps), nearest first (ties by index, for a
/// deterministic file), so that a query's first exact distance lets the cheap bounds
/// skip most others. A non-negative f32's bits order as its value. None past `most`.
fn nearest_first(geo: &Geometry, c: Vec3, reach: f32, cell: f32, most: usize) -> Option<Vec<u32>> {
    // (d², triangle) pairs in a buffer each thread keeps: one a list, freed among the
    // lists that stay until they are joined, left the heap in pieces (+175 MB of peak
    // memory for a 499k-triangle sphere's grid over the cells' own searches; +43 MB with
    // the buffer).
    thread_local! {
        static PAIRS: std::cell::RefCell<Vec<(f32, u32)>> = const { std::cell::RefCell::new(Vec::new()) };
    }
    PAIRS.with_borrow_mut(|list| {
        list.clear();
        let reach = reach * (1.0 + 1e-5) + 1e-4 * cell + geo.eps;
        if !geo.triangles_within(c, reach, list, most) {
            return None;
        }
        // The distance as `nearest_of(c, &[prim])` gives it, from the query's own d².
        list.sort_unstable_by_key(|&(d2, prim)| (d2.sqrt().to_bits(), prim));
        Some(list.iter().map(|&(_, prim)| prim).collect())
    })
}

/// Most triangle references the cell lists may hold: their offsets are u32 (in the cache
/// file and in the kernels' buffer). At ~300 references a triangle, a mesh of ~14 M
/// triangles reaches it; past it the offsets wrapped (a panic at the wrapped cell, wrong
/// lists after it) where a clear error is due.
pub const MAX_CANDIDATES: u64 = u32::MAX as u64;

/// A cell's coverage, in f32, is shrunk by this factor (far more than its rounding) before
/// a local hit test trusts that its candidate list holds every triangle within reach.
pub const LOCAL_REACH_SHRINK: f32 = 1.0 - 1e-5;

/// The slack of [`DistanceGrid::distance_upper_bound`]: 1 % covers the rounding margin
/// (eps/2, below 1 % of √3·cell for any grid under 1,000 cells a side).
pub const UPPER_BOUND_SLACK: f32 = 1.01;

impl DistanceGrid {
    /// Builds the grid with `resolution` cells along the longest side of the bounds; an
    /// error when its cell lists would exceed [`MAX_CANDIDATES`] (the lists stop being
    /// built once past it, so the error comes instead of wrapped offsets; the lists alone
    /// are 16 GiB by then, which a smaller machine may not reach).
    pub fn build(geo: &Geometry, resolution: u32) -> Result<Self, String> {
        Self::build_within(geo, resolution, MAX_CANDIDATES)
    }

    /// The grid's corner, cell size and cell counts for `geo` at `resolution`.
    fn frame(geo: &Geometry, resolution: u32) -> (Vec3, f32, UVec3) {
        let extent = geo.hi - geo.lo;
        let cell = extent.max_element() / resolution as f32;
        let dims = (extent / cell).ceil().as_uvec3().max(UVec3::ONE);
        (geo.lo, cell, dims)
    }

    fn build_within(geo: &Geometry, resolution: u32, most: u64) -> Result<Self, String> {
        let (lo, cell, dims) = Self::frame(geo, resolution);
        let n = (dims.x * dims.y * dims.z) as usize;
        // Relative margin for f32 rounding in the distance computation.
        let margin = geo.eps * 0.5;
        let exact = Self::centre_distances(geo, (lo, cell, dims), LIST_PER_NODE);
        let near_surface = 2.0 * 3f32.sqrt() * cell;
        // A point p of cell c (|p − c| ≤ h, the half-diagonal) is refined when its radius
        // value − |p − c| is below near_surface, so only cells with value < near_surface + h
        // need lists. p's nearest triangle T lies within d(p) ≤ d(c) + h of p, hence within
        // d(c) + 2h of c: listing every triangle that near c lists T. The padding covers
        // f32 rounding of p's cell and of the distances (1e-4 of a cell, ~100 ulps).
        let h = 0.5 * 3f32.sqrt() * cell;
        let listed = AtomicU64::new(0);
        let lists: Vec<Vec<u32>> = exact
            .par_iter()
            .enumerate()
            .map(|(i, &d)| {
                let mut list = Vec::new();
                if d * (1.0 - 1e-5) - margin < near_surface + h
                    && listed.load(Ordering::Relaxed) <= most
                {
                    let c = Self::centre_of(lo, cell, dims, i);
                    list = nearest_first(geo, c, d + 2.0 * h, cell, usize::MAX)
                        .expect("an uncapped list");
                    listed.fetch_add(list.len() as u64, Ordering::Relaxed);
                }
                list
            })
            .collect();
        let listed = listed.into_inner();
        if listed > most {
            return Err(format!(
                "the distance grid of {} triangles at render.grid_resolution = {resolution} \
                 would list more than {most} triangle references (offsets are 32-bit): lower \
                 render.grid_resolution or simplify the mesh",
                geo.tris.len()
            ));
        }
        let mut cells = Vec::with_capacity(n + 1);
        let mut candidates = Vec::new();
        for (d, list) in exact.iter().zip(lists) {
            let value = (d * (1.0 - 1e-5) - margin).max(0.0);
            cells.push([value.to_bits(), candidates.len() as u32]);
            candidates.extend_from_slice(&list);
        }
        cells.push([0, candidates.len() as u32]);
        Ok(Self {
            lo,
            cell,
            inv_cell: 1.0 / cell,
            dims,
            near_surface,
            cells,
            candidates,
        })
    }

    /// The index of the cell holding `p` (None outside the grid).
    #[inline]
    fn cell_of(&self, p: Vec3) -> Option<(usize, Vec3)> {
        let q = (p - self.lo) * self.inv_cell;
        if !(q.x >= 0.0 && q.y >= 0.0 && q.z >= 0.0) {
            return None;
        }
        let c = q.as_uvec3();
        if c.x >= self.dims.x || c.y >= self.dims.y || c.z >= self.dims.z {
            return None;
        }
        let i = (c.x + self.dims.x * (c.y + self.dims.y * c.z)) as usize;
        Some((i, self.lo + (c.as_vec3() + 0.5) * self.cell))
    }

    /// The exact distance from `p` to the surface, from the candidate triangles of its
    /// cell; None where the cell has no list (away from the surface, outside the grid).
    #[inline]
    pub fn exact_distance(&self, geo: &Geometry, p: Vec3) -> Option<f32> {
        let (i, _) = self.cell_of(p)?;
        let (a, b) = (self.cells[i][1] as usize, self.cells[i + 1][1] as usize);
        (b > a).then(|| geo.nearest_of(p, &self.candidates[a..b]))
    }

    /// The closest hit along `origin + t·dir`, t ∈ [0, tmax], from the candidate list of
    /// `origin`'s cell instead of a BVH traversal; None when the list cannot be trusted
    /// to hold every triangle the segment can meet (no list, or a segment reaching
    /// beyond it), and the caller casts through the BVH.
    ///
    /// A cell's list holds every triangle within d(c) + 2h of its centre c (h: the
    /// half-diagonal; `build`), and the cell's value is at most d(c), so a segment
    /// within value + 2h of c — |origin − c| + tmax below that — can meet no triangle
    /// outside the list. Flights near the surface (where they need a cast at all) are
    /// ~1/σ_t long against lists that reach a cell or more, so nearly all qualify, and a
    /// dozen watertight triangle tests cost a fraction of a traversal from the root. The
    /// same test as the BVH's, over a superset of what the segment can meet: the same
    /// hit.
    #[inline]
    pub fn local_hit(
        &self,
        geo: &Geometry,
        origin: Vec3,
        dir: Vec3,
        tmax: f32,
    ) -> Option<Option<Hit>> {
        let (i, centre) = self.cell_of(origin)?;
        let (a, b) = (self.cells[i][1] as usize, self.cells[i + 1][1] as usize);
        if b == a {
            return None;
        }
        // The coverage in f32, shrunk by far more than its rounding.
        let reach =
            (f32::from_bits(self.cells[i][0]) + self.near_surface * 0.5) * LOCAL_REACH_SHRINK;
        if (origin - centre).length() + tmax > reach {
            return None;
        }
        Some(geo.closest_of(origin, dir, tmax, &self.candidates[a..b]))
    }

    /// Cells with candidate lists and the lists' mean length (for reports and tests).
    pub fn candidate_stats(&self) -> (usize, f64) {
        let cells = self.cells.windows(2).filter(|w| w[1][1] > w[0][1]).count();
        (cells, self.candidates.len() as f64 / cells.max(1) as f64)
    }

    /// d(c) for every cell centre c, as [`Geometry::distance`] gives it, bit for bit, but
    /// found block by block. A nearest-triangle search through the BVH must prove that no
    /// other triangle is nearer, and inside a curved surface the boxes of the triangles
    /// beside the nearest are all about as near: the search opened hundreds of leaves a
    /// cell, and the sphere's grid took 12–16 s to build. Instead one search per block of
    /// [`BLOCK`]³ cells finds the distance D of the block's centre C; every cell centre c of
    /// the block (|c − C| ≤ h) has d(c) ≤ D + h, so its nearest triangle lies within
    /// D + 2h of C, and the nearest of the triangles that near C ([`nearest_first`]) is the
    /// same triangle at the same f32 distance. Where that list is long against the nodes
    /// the block's search opened (a dense mesh, whose small boxes bound tightly), or the
    /// search was not exact, the block's cells are searched one by one as before. (A cell
    /// whose own search would overflow its stack, in a tree deeper than any balanced one,
    /// gets the exact distance from a list where the search gave a lower bound.)
    /// `list_per_node`: [`LIST_PER_NODE`] (a test sets it to take either way everywhere).
    fn centre_distances(
        geo: &Geometry,
        (lo, cell, dims): (Vec3, f32, UVec3),
        list_per_node: usize,
    ) -> Vec<f32> {
        let mut exact = vec![0f32; (dims.x * dims.y * dims.z) as usize];
        let plane = (dims.x * dims.y) as usize;
        let (bx, by) = (dims.x.div_ceil(BLOCK), dims.y.div_ceil(BLOCK));
        // A slab of BLOCK planes at a time, written in place: its blocks' lists first, then
        // its cells (a list of (cell, value) pairs for the whole grid cost 12 bytes a cell
        // more).
        exact
            .par_chunks_mut(plane * BLOCK as usize)
            .enumerate()
            .for_each(|(slab, values)| {
                let lists: Vec<Option<Vec<u32>>> = (0..bx * by)
                    .into_par_iter()
                    .map(|b| {
                        let first = UVec3::new(b % bx, b / bx, slab as u32) * BLOCK;
                        Self::block_list(geo, (lo, cell, dims), first, list_per_node)
                    })
                    .collect();
                let base = slab * plane * BLOCK as usize;
                values.par_iter_mut().enumerate().for_each(|(j, v)| {
                    let (x, y) = (j as u32 % dims.x, (j as u32 / dims.x) % dims.y);
                    let c = Self::centre_of(lo, cell, dims, base + j);
                    *v = match &lists[(x / BLOCK + bx * (y / BLOCK)) as usize] {
                        Some(list) => geo.nearest_of(c, list),
                        None => geo.distance(c),
                    };
                });
            });
        exact
    }

    /// The triangle list of [`Self::centre_distances`]'s block whose first cell is
    /// `first`; None where its cells are searched one by one.
    fn block_list(
        geo: &Geometry,
        (lo, cell, dims): (Vec3, f32, UVec3),
        first: UVec3,
        list_per_node: usize,
    ) -> Option<Vec<u32>> {
        let last = (first + BLOCK).min(dims) - UVec3::ONE;
        // The first and last cells' centres, as `centre_of` gives them.
        let (c0, c1) = (
            lo + (first.as_vec3() + 0.5) * cell,
            lo + (last.as_vec3() + 0.5) * cell,
        );
        let centre = (c0 + c1) * 0.5;
        let h = 0.5 * (c1 - c0).length();
        let search = geo.distance_search(centre, f32::INFINITY);
        // A listed triangle's bounds cost a fraction of an opened node (its box test and
        // the leaf's exact distances): past LIST_PER_NODE of them a cell's own search is
        // the cheaper (a 499k-triangle sphere's grid took 38.1 s by the lists, 27.2 s by
        // the cells' own searches before this build, 28.5 s with the fallback, which
        // still pays for each block's search and capped list).
        let most = list_per_node.saturating_mul(search.opened as usize);
        (search.exact && search.distance.is_finite())
            .then(|| nearest_first(geo, centre, search.distance + 2.0 * h, cell, most))
            .flatten()
    }

    fn centre_of(lo: Vec3, cell: f32, dims: UVec3, i: usize) -> Vec3 {
        let i = i as u32;
        let x = i % dims.x;
        let y = (i / dims.x) % dims.y;
        let z = i / (dims.x * dims.y);
        lo + (Vec3::new(x as f32, y as f32, z as f32) + 0.5) * cell
    }

    /// A radius r with the ball B(p, r) free of the surface (0 outside the grid).
    #[inline]
    pub fn radius(&self, p: Vec3) -> f32 {
        match self.cell_of(p) {
            Some((i, centre)) => {
                (f32::from_bits(self.cells[i][0]) - (p - centre).length()).max(0.0)
            }
            None => 0.0,
        }
    }

    /// Asks the CPU to bring `p`'s cell into the cache, for a [`Self::radius`] a while
    /// later: the grid is larger than the caches, and its lookups at sphere-step exits
    /// were cache misses.
    #[inline]
    pub fn prefetch(&self, p: Vec3) {
        #[cfg(target_arch = "x86_64")]
        if let Some((i, _)) = self.cell_of(p) {
            use std::arch::x86_64::{_MM_HINT_T0, _mm_prefetch};
            // SAFETY: a prefetch never faults, and the address is inside `cells` anyway.
            unsafe { _mm_prefetch::<_MM_HINT_T0>(self.cells.as_ptr().add(i).cast()) };
        }
        #[cfg(not(target_arch = "x86_64"))]
        let _ = p;
    }

    /// An upper bound on the true distance at a point whose grid radius is `radius`:
    /// d(p) ≤ d(c) + |p − c| = radius + 2|p − c| + margin ≤ radius + √3·cell + margin
    /// (half of `near_surface`). The 1 % slack covers the rounding margin (eps/2, below
    /// 1 % of √3·cell for any grid under 1,000 cells a side). An exact search limited to
    /// this bound returns the exact distance while visiting only the nodes near p.
    #[inline]
    pub fn distance_upper_bound(&self, radius: f32) -> f32 {
        radius + 0.5 * self.near_surface * UPPER_BOUND_SLACK
    }

    /// Loads the grid from the cache or builds and caches it when building takes long.
    pub fn cached(geo: &Geometry, resolution: u32) -> Result<Self, String> {
        let key = cache_key(geo, resolution);
        let path = crate::cache::cache_file(&format!("grid-{key:016x}-{resolution}"));
        crate::cache::read_or_build(
            path.as_deref(),
            crate::cache::CACHED_FROM_SECONDS,
            |p| Self::read(p, key, geo, resolution),
            || Self::build(geo, resolution),
            |p, g| g.write(p, key),
        )
    }

    fn write(&self, path: &Path, key: u64) -> std::io::Result<()> {
        let mut bytes = Vec::with_capacity(56 + 8 * self.cells.len() + 4 * self.candidates.len());
        bytes.extend_from_slice(MAGIC);
        bytes.extend_from_slice(&key.to_le_bytes());
        for v in [self.lo.x, self.lo.y, self.lo.z, self.cell] {
            bytes.extend_from_slice(&v.to_le_bytes());
        }
        for d in [self.dims.x, self.dims.y, self.dims.z] {
            bytes.extend_from_slice(&d.to_le_bytes());
        }
        bytes.extend_from_slice(&(self.candidates.len() as u32).to_le_bytes());
        for v in self.cells.as_flattened().iter().chain(&self.candidates) {
            bytes.extend_from_slice(&v.to_le_bytes());
        }
        let crc = crc32fast::hash(&bytes);
        bytes.extend_from_slice(&crc.to_le_bytes());
        if let Some(dir) = path.parent() {
            std::fs::create_dir_all(dir)?;
        }
        scatter_sim::output::write_atomic(path, &bytes)
    }

    /// Reads the cached grid of `geo` at `resolution` (cache key `key`); anything
    /// unexpected means "rebuild" (None). A file with a valid checksum is still checked:
    /// its key and frame must be this mesh's at this resolution (a file of another mesh
    /// with as many triangles, copied under this name, was read, and rendered 24× too
    /// bright), and nothing may break a render: dimensions whose cell count overflows or
    /// is 0, a candidate beyond the mesh (an index out of bounds), or a distance that is
    /// not finite and ≥ 0.
    fn read(path: &Path, key: u64, geo: &Geometry, resolution: u32) -> Option<Self> {
        let triangles = geo.tris.len();
        // A named pipe blocked the render and a link to /dev/zero read until memory ran out:
        // anything but a regular file is a miss, replaced when the grid is written.
        scatter_sim::output::check_input(path).ok()?;
        let b = std::fs::read(path).ok()?;
        if b.len() < 48 + 4 || &b[..8] != MAGIC {
            return None;
        }
        let (body, crc) = b.split_at(b.len() - 4);
        if crc32fast::hash(body) != u32::from_le_bytes(crc.try_into().ok()?)
            || u64::from_le_bytes(body[8..16].try_into().ok()?) != key
        {
            return None;
        }
        // From here the offsets are those of a file without the key, which sits where the
        // magic did.
        let body = &body[8..];
        let f = |i: usize| f32::from_le_bytes(body[8 + 4 * i..12 + 4 * i].try_into().unwrap());
        let u = |i: usize| u32::from_le_bytes(body[8 + 4 * i..12 + 4 * i].try_into().unwrap());
        let dims = UVec3::new(u(4), u(5), u(6));
        let (lo, cell, want) = Self::frame(geo, resolution);
        let same = |a: f32, b: f32| a.to_bits() == b.to_bits();
        if dims != want || !same(f(3), cell) || !(0..3).all(|i| same(f(i), lo[i])) {
            return None;
        }
        // Cells are indexed in u32 (`cell_of`): a product that overflows it, or wraps in
        // usize, would pass the length check below and index out of bounds.
        let n = (dims.x as usize)
            .checked_mul(dims.y as usize)?
            .checked_mul(dims.z as usize)?;
        if dims.min_element() == 0 || n >= u32::MAX as usize {
            return None;
        }
        let words = |from: usize, count: usize| {
            body.get(from..from + 4 * count)
                .map(|b| b.chunks_exact(4).map(|c| c.try_into().unwrap()))
        };
        let m = u32::from_le_bytes(words(36, 1)?.next()?) as usize;
        if body.len() != 40 + 4 * (2 * (n + 1) + m) {
            return None;
        }
        let flat: Vec<u32> = words(40, 2 * (n + 1))?.map(u32::from_le_bytes).collect();
        let cells: Vec<[u32; 2]> = flat.chunks_exact(2).map(|c| [c[0], c[1]]).collect();
        let candidates: Vec<u32> = words(40 + 8 * (n + 1), m)?
            .map(u32::from_le_bytes)
            .collect();
        let ordered = cells[0][1] == 0
            && cells.windows(2).all(|w| w[0][1] <= w[1][1])
            && cells[n][1] == m as u32
            && cells
                .iter()
                .all(|c| f32::from_bits(c[0]) >= 0.0 && f32::from_bits(c[0]).is_finite())
            && candidates.iter().all(|&t| (t as usize) < triangles)
            && (0..4).all(|i| f(i).is_finite())
            && f(3) > 0.0;
        if !ordered {
            return None;
        }
        Some(Self {
            lo: Vec3::new(f(0), f(1), f(2)),
            cell: f(3),
            inv_cell: 1.0 / f(3),
            dims,
            near_surface: 2.0 * 3f32.sqrt() * f(3),
            cells,
            candidates,
        })
    }
}

fn cache_key(geo: &Geometry, resolution: u32) -> u64 {
    let mut h = crate::cache::mesh_hasher(geo, b"distance-grid-v4");
    h.write(&resolution.to_le_bytes());
    h.finish()
}

#[cfg(test)]
mod tests {
    /// The block-wise centre distances equal the nearest of all the triangles at every
    /// cell, bit for bit (so the grid, and every render, is what the per-cell BVH searches
    /// gave, which take the same f32 minimum): on a sphere,
    /// where every triangle is about as near to the centre, a cube's flat faces and sharp
    /// edges, the torus knot's close strands and the bunny; at resolutions whose cell counts
    /// leave partial blocks at the far faces. A block bound too tight (h = 0) fails it at
    /// thousands of cells. Each block's cells take the list or their own searches as the
    /// lists' lengths decide: both ways are checked everywhere (a cap of 0 searches every
    /// cell, none lists every block), and the build's cap between them.
    #[test]
    fn block_distances_equal_the_nearest_of_all_triangles() {
        use rayon::prelude::*;
        let bunny = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../assets/bunny.ply");
        let meshes = [
            ("sphere", crate::mesh::sphere(0.5)),
            ("cube", crate::mesh::cube(1.0)),
            ("torus knot", crate::mesh::torus_knot()),
            ("bunny", crate::mesh::load_mesh(&bunny).unwrap()),
        ];
        for (name, mesh) in meshes {
            let geo = crate::geometry::Geometry::new(mesh);
            let all: Vec<u32> = (0..geo.tris.len() as u32).collect();
            // Every cell at 23; at 42 every fifth (the reference is the slow part; 5 being
            // prime to the block's 4 cells a side, the sample still meets every position
            // in a block).
            for (resolution, every) in [(23, 1), (42, 5)] {
                let (lo, cell, dims) = DistanceGrid::frame(&geo, resolution);
                let cells = (dims.x * dims.y * dims.z) as usize;
                // The reference looks at every triangle, no tree and no bound: the cap-0
                // build (the BVH search cell by cell) is checked against it too.
                let exact: Vec<(usize, f32)> = (0..cells)
                    .into_par_iter()
                    .step_by(every)
                    .map(|i| {
                        let c = glam::Vec3A::from(DistanceGrid::centre_of(lo, cell, dims, i));
                        let d2 = all.iter().map(|&t| geo.triangle_d2(c, t));
                        (i, d2.fold(f32::INFINITY, f32::min).sqrt())
                    })
                    .collect();
                for cap in [super::LIST_PER_NODE, 0, usize::MAX] {
                    let blocks = DistanceGrid::centre_distances(&geo, (lo, cell, dims), cap);
                    assert_eq!(blocks.len(), cells);
                    let differ = exact
                        .iter()
                        .filter(|&&(i, e)| blocks[i].to_bits() != e.to_bits())
                        .count();
                    assert_eq!(
                        differ, 0,
                        "{name} at {resolution}, cap {cap}: {differ} differ"
                    );
                }
            }
        }
    }

    /// A cache entry that is a named pipe or a device is a miss, not a wait or a read
    /// without end (a FIFO blocked the render; a link to /dev/zero filled memory).
    #[cfg(unix)]
    #[test]
    fn a_cache_entry_that_is_no_file_is_a_miss() {
        let d = tempfile::tempdir().unwrap();
        let geo = crate::geometry::Geometry::new(crate::mesh::cube(1.0));
        for p in crate::not_files(d.path()) {
            assert!(
                DistanceGrid::read(&p, 7, &geo, 8).is_none(),
                "{}",
                p.display()
            );
        }
    }

    use super::DistanceGrid;

    /// Cell lists beyond the cap (u32 offsets in the real build) are an error naming the
    /// grid resolution, not wrapped offsets; at the cap exactly the grid builds. The cube's
    /// grid at 8 cells a side holds a few thousand references, so caps just below and at
    /// that count decide it.
    #[test]
    fn too_many_references_are_refused() {
        let geo = crate::geometry::Geometry::new(crate::mesh::cube(1.0));
        let n = DistanceGrid::build(&geo, 8).unwrap().candidates.len() as u64;
        assert!(n > 100, "{n}");
        assert_eq!(
            DistanceGrid::build_within(&geo, 8, n)
                .unwrap()
                .candidates
                .len() as u64,
            n
        );
        let e = DistanceGrid::build_within(&geo, 8, n - 1).err().unwrap();
        assert!(e.contains("render.grid_resolution = 8"), "{e}");
    }

    /// A cached grid with a valid checksum is still refused (rebuilt) where its contents
    /// would break a render: a candidate index beyond the mesh (it panicked with an index
    /// out of bounds) or a negative distance; and where it is not this mesh's grid at this
    /// resolution: another key (another mesh's file of as many triangles, copied under this
    /// name, rendered 24× too bright), another resolution's grid, or a frame edited. The
    /// file as written reads back as it was.
    #[test]
    fn forged_cache_contents_are_rebuilt() {
        let geo = crate::geometry::Geometry::new(crate::mesh::cube(1.0));
        let grid = DistanceGrid::build(&geo, 8).unwrap();
        let d = tempfile::tempdir().unwrap();
        let path = d.path().join("grid.bin");
        let key = 7;
        grid.write(&path, key).unwrap();
        let back = DistanceGrid::read(&path, key, &geo, 8).expect("its own file");
        assert!(DistanceGrid::read(&path, key + 1, &geo, 8).is_none());
        assert!(DistanceGrid::read(&path, key, &geo, 16).is_none());
        let moved = crate::geometry::Geometry::new(crate::mesh::cube(1.5));
        assert_eq!(moved.tris.len(), geo.tris.len());
        assert!(DistanceGrid::read(&path, key, &moved, 8).is_none());
        assert_eq!(
            (back.cells, back.candidates),
            (grid.cells.clone(), grid.candidates.clone())
        );
        let forge = |edit: &dyn Fn(&mut DistanceGrid)| {
            let mut g = DistanceGrid::build(&geo, 8).unwrap();
            edit(&mut g);
            g.write(&path, key).unwrap();
            DistanceGrid::read(&path, key, &geo, 8)
        };
        assert!(forge(&|g| g.cell *= 3.0).is_none());
        assert!(forge(&|g| g.lo.x += 0.25).is_none());
        assert!(forge(&|g| g.dims = glam::UVec3::new(g.dims.z, g.dims.y, g.dims.x + 1)).is_none());
        assert!(!grid.candidates.is_empty());
        assert!(forge(&|g| g.candidates[0] = 1_000_000_000).is_none());
        assert!(forge(&|g| g.cells[0][0] = (-1.0f32).to_bits()).is_none());
        assert!(forge(&|g| g.cells[0][0] = f32::NAN.to_bits()).is_none());
        assert!(forge(&|g| g.cells[0][0] = f32::INFINITY.to_bits()).is_none());
        // Each edit breaks one check of the list offsets only: on the cube at 8 cells,
        // cells 0, 1 and the last have lists (their centres lie 1/16 from a face).
        assert!(forge(&|g| g.cells[0][1] = 1).is_none());
        // Offsets that run backwards.
        assert!(forge(&|g| g.cells[1][1] = g.candidates.len() as u32).is_none());
        assert!(
            forge(&|g| {
                let n = g.cells.len() - 1;
                g.cells[n][1] -= 1;
            })
            .is_none()
        );
        // Dimensions whose product wraps to the file's cell count (2^64 → 0 in usize).
        let wrapped = forge(&|g| {
            g.dims = glam::UVec3::new(1 << 22, 1 << 22, 1 << 20);
            g.cells.truncate(1);
            g.cells[0][1] = 0;
            g.candidates.clear();
        });
        assert!(wrapped.is_none());
    }

    /// The box of `a_grid_read_back_answers_as_the_built_one`: a cube squashed to
    /// 1 × 0.6 × 0.3 and moved off the origin, so that its grid's corner, cell counts
    /// (8 × 5 × 3 at 8 cells) and axes all differ.
    fn squashed_box() -> crate::geometry::Geometry {
        let mut m = crate::mesh::cube(1.0);
        for p in &mut m.positions {
            *p = *p * glam::Vec3::new(1.0, 0.6, 0.3) + glam::Vec3::new(0.2, -0.1, 0.05);
        }
        crate::geometry::Geometry::new(m)
    }

    /// A grid read from the cache is the grid built: besides the cells and lists that the
    /// file holds (`forged_cache_contents_are_rebuilt`), what `read` derives from them —
    /// 1/cell, by which every lookup finds its cell, and near_surface, which decides where
    /// lists are asked and how far a local hit trusts them — bit for bit, and so the same
    /// radius and exact distance at 2,000 points of the box (all of its cells have lists,
    /// the box being 2.4 cells thick). With 1/cell read as the cell, every point read cell
    /// 0: radii from its centre stay below the distance, but its list's nearest triangle
    /// is not every point's (an exact distance too large: a sphere step across the
    /// surface). The renders read such files only where a build took over 0.1 s, into a
    /// cache that begins empty for each version of this file.
    #[test]
    fn a_grid_read_back_answers_as_the_built_one() {
        let geo = squashed_box();
        let grid = DistanceGrid::build(&geo, 8).unwrap();
        let d = tempfile::tempdir().unwrap();
        let path = d.path().join("grid.bin");
        grid.write(&path, 7).unwrap();
        let back = DistanceGrid::read(&path, 7, &geo, 8).expect("its own file");
        assert_eq!((back.lo, back.dims), (grid.lo, grid.dims));
        for (what, got, built) in [
            ("cell", back.cell, grid.cell),
            ("1/cell", back.inv_cell, grid.inv_cell),
            ("near_surface", back.near_surface, grid.near_surface),
        ] {
            assert_eq!(
                got.to_bits(),
                built.to_bits(),
                "{what}: read {got}, built {built}"
            );
        }
        let mut rng = scatter_sim::rng::WalkRng::from_seed(5);
        let mut listed = 0;
        for _ in 0..2000 {
            let u = glam::Vec3::new(
                rng.uniform() as f32,
                rng.uniform() as f32,
                rng.uniform() as f32,
            );
            let p = geo.lo + (geo.hi - geo.lo) * u;
            assert_eq!(back.radius(p).to_bits(), grid.radius(p).to_bits(), "at {p}");
            let exact = grid.exact_distance(&geo, p);
            assert_eq!(back.exact_distance(&geo, p), exact, "at {p}");
            listed += exact.is_some() as u32;
        }
        assert!(listed > 1000, "{listed} of 2,000 points have lists");
    }

    /// `geo`'s grid of 8 cells along its longest side (8 × 5 × 3 for `squashed_box`),
    /// edited, written to `path` under key 7 and read back: None where `read` refuses the
    /// file.
    fn edited_read_back(
        geo: &crate::geometry::Geometry,
        path: &std::path::Path,
        edit: &dyn Fn(&mut DistanceGrid),
    ) -> Option<DistanceGrid> {
        let mut g = DistanceGrid::build(geo, 8).unwrap();
        edit(&mut g);
        g.write(path, 7).unwrap();
        DistanceGrid::read(path, 7, geo, 8)
    }

    /// The checks of a cached grid's contents hold exactly at their limits: a candidate
    /// equal to the mesh's triangle count (the first index out of bounds; the forged file
    /// above used 10⁹, which a bound one too far also refuses) is refused, the last
    /// triangle (11 of the cube's 12) read.
    #[test]
    fn a_candidate_one_past_the_last_triangle_is_rebuilt() {
        let geo = crate::geometry::Geometry::new(crate::mesh::cube(1.0));
        let d = tempfile::tempdir().unwrap();
        let path = d.path().join("grid.bin");
        let forge = |edit: &dyn Fn(&mut DistanceGrid)| edited_read_back(&geo, &path, edit);
        let last = geo.tris.len() as u32 - 1;
        assert!(forge(&|g| g.candidates[0] = last).is_some());
        assert!(forge(&|g| g.candidates[0] = last + 1).is_none());
    }

    /// A cached grid's corner must be this mesh's along every axis: the forged file above
    /// moved it along x only. Read with its corner moved 0.25 (two cells) along z, every
    /// point would take the distance stored for a centre two cells away, less its distance
    /// from the moved centre: a radius that may exceed the point's distance.
    #[test]
    fn a_frame_moved_along_any_axis_is_rebuilt() {
        let geo = squashed_box();
        let d = tempfile::tempdir().unwrap();
        let path = d.path().join("grid.bin");
        let forge = |edit: &dyn Fn(&mut DistanceGrid)| edited_read_back(&geo, &path, edit);
        assert!(forge(&|_| {}).is_some());
        for axis in 0..3 {
            assert!(
                forge(&|g| g.lo[axis] += 0.25).is_none(),
                "corner moved along {axis}"
            );
        }
    }
}
