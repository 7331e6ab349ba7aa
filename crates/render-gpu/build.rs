//! The distance grids and escape cones cached between runs (`DistanceGrid::cached`,
//! `escape_cone::cached`) are named by the code that computes them as well as by the mesh:
//! a hash of these sources, so that a changed algorithm never reads a cache its old
//! version wrote (a hand-bumped tag was all that stood in the way before, and tests
//! rendered with whatever a warm cache held).

// The crate's own FNV-1a, the hash of every other cache key.
#[path = "src/hash.rs"]
mod hash;

const SOURCES: [&str; 3] = [
    "src/distance_grid.rs",
    "src/escape_cone.rs",
    "src/geometry.rs",
];

fn main() {
    let mut h = hash::Fnv64::new();
    for s in SOURCES {
        println!("cargo:rerun-if-changed={s}");
        h.write(&std::fs::read(s).unwrap_or_else(|e| panic!("{s}: {e}")));
    }
    println!("cargo:rustc-env=STCVAE_CACHE_CODE={:016x}", h.finish());
}
