//! The distance grids and escape cones cached between runs (`DistanceGrid::cached`,
//! `escape_cone::cached`) are named by the code that computes them as well as by the mesh:
//! a hash of these sources, so that a changed algorithm never reads a cache its old
//! version wrote (a hand-bumped tag was all that stood in the way before, and tests
//! rendered with whatever a warm cache held).

const SOURCES: [&str; 3] = [
    "src/distance_grid.rs",
    "src/escape_cone.rs",
    "src/geometry.rs",
];

fn main() {
    // FNV-1a, 64 bits.
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for s in SOURCES {
        println!("cargo:rerun-if-changed={s}");
        let bytes = std::fs::read(s).unwrap_or_else(|e| panic!("{s}: {e}"));
        for b in bytes {
            h ^= u64::from(b);
            h = h.wrapping_mul(0x0000_0100_0000_01b3);
        }
    }
    println!("cargo:rustc-env=STCVAE_CACHE_CODE={h:016x}");
}
