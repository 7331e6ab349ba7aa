//! The distance grids and escape cones cached between runs (`DistanceGrid::cached`,
//! `escape_cone::cached`) are named by the code that computes them as well as by the mesh:
//! a hash of these sources, so that a changed algorithm never reads a cache its old
//! version wrote (a hand-bumped tag was all that stood in the way before, and tests
//! rendered with whatever a warm cache held).
//!
//! A second hash, of the sources that decide what a render converges to (the integrators,
//! optics, lights, camera, scene set-up, the GPU host code and every WGSL kernel, the
//! model sampling and simulator pieces they call, and Cargo.lock's versions), goes into
//! each scene's identity hash: `merge` refuses to average renders made by builds that
//! estimate differently (a render from before a bug fix with one from after), and the
//! bench's PT cache misses. A test (setup.rs, `every_source_that_decides_a_render_is_hashed`)
//! fails for a source of this crate that is neither hashed nor listed there as unable to
//! change a render.

// The crate's own FNV-1a, the hash of every other cache key.
#[path = "src/hash.rs"]
mod hash;

const SOURCES: [&str; 8] = [
    "src/distance_grid.rs",
    "src/escape_cone.rs",
    "src/geometry/mod.rs",
    "src/geometry/distance.rs",
    "src/geometry/rays.rs",
    "src/geometry/spawn.rs",
    // Geometry's ray-triangle test, which the escape cones' rays (and every render) use.
    "src/watertight.rs",
    // The mesh's scale, which sets the surface offset the grid's values are reduced by
    // and the cones' probe distances.
    "src/mesh/mod.rs",
];

/// Beyond SOURCES: single files and whole folders (their files in name order).
/// (The model's sampling and the simulator's phase function, frames and random numbers live
/// in the sibling crates. The mesh's positions and triangles are hashed with the scene,
/// but not which of its pieces overlap or nest, which the last two decide.)
const RENDER_FILES: [&str; 15] = [
    "src/light.rs",
    "src/optics.rs",
    "src/camera.rs",
    "src/setup.rs",
    "src/render.rs",
    "../cvae/src/sampler.rs",
    "../cvae/src/decoder.rs",
    "../cvae/src/features.rs",
    "../cvae/src/fastmath.rs",
    // How a model file's bytes become decoders (the scene hash holds the bytes).
    "../cvae/src/model_file.rs",
    "../scatter-sim/src/phase.rs",
    "../scatter-sim/src/frame.rs",
    "../scatter-sim/src/rng.rs",
    "src/piece_survey.rs",
    "src/mesh/pieces.rs",
];
const RENDER_DIRS: [&str; 3] = ["src/integrator", "src/gpu", "../../shaders"];

/// Hashes `path` into `h` and notes it in `hashed` (with `/`, as the test names files).
fn hash_file(h: &mut hash::Fnv64, path: &str, hashed: &mut Vec<String>) {
    hashed.push(path.replace('\\', "/"));
    println!("cargo:rerun-if-changed={path}");
    h.write(path.as_bytes());
    h.write(&std::fs::read(path).unwrap_or_else(|e| panic!("{path}: {e}")));
}

fn main() {
    let mut h = hash::Fnv64::new();
    for s in SOURCES {
        println!("cargo:rerun-if-changed={s}");
        h.write(&std::fs::read(s).unwrap_or_else(|e| panic!("{s}: {e}")));
    }
    println!("cargo:rustc-env=STCVAE_CACHE_CODE={:016x}", h.finish());

    let mut r = hash::Fnv64::new();
    let mut hashed = Vec::new();
    for s in SOURCES.iter().chain(&RENDER_FILES) {
        hash_file(&mut r, s, &mut hashed);
    }
    for dir in RENDER_DIRS {
        println!("cargo:rerun-if-changed={dir}");
        let mut files: Vec<String> = std::fs::read_dir(dir)
            .unwrap_or_else(|e| panic!("{dir}: {e}"))
            .map(|e| e.expect("a folder entry").path().display().to_string())
            .filter(|p| p.ends_with(".rs") || p.ends_with(".wgsl"))
            .collect();
        files.sort();
        for f in &files {
            hash_file(&mut r, f, &mut hashed);
        }
    }
    // The dependencies' versions (obvhs's traversal, rand_distr's normals, wgpu's shader
    // compiler): a `cargo update` can change an image as an edit can. Absent where the
    // crate is built outside this workspace.
    let lock = "../../Cargo.lock";
    if std::path::Path::new(lock).is_file() {
        hash_file(&mut r, lock, &mut hashed);
    }
    println!("cargo:rustc-env=STCVAE_RENDER_CODE={:016x}", r.finish());
    // The files hashed, for the test that every source is (setup.rs).
    println!("cargo:rustc-env=STCVAE_RENDER_FILES={}", hashed.join(";"));
}
