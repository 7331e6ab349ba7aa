//! Rendering subsurface scattering: volumetric path tracing (the reference) and the
//! ST-CVAE sphere-tracing integrator with next-event estimation through EventGen.
//!
//! The scene side (scene files, meshes, BVH, distance grid, lights, outputs) is shared
//! by the CPU integrators here and the wgpu kernels.

mod cache;
pub mod camera;
pub mod distance_grid;
pub mod error;
pub mod escape_cone;
pub mod geometry;
pub mod gpu;
pub mod hash;
pub mod image_io;
pub mod integrator;
pub mod light;
pub mod mesh;
pub mod optics;
mod piece_survey;
pub mod render;
pub mod scene;
pub mod setup;
pub mod thin_walls;
pub mod watertight;

pub use error::RenderError;

/// Test helper: a named pipe and a link to /dev/zero in `dir`, paths that open like files
/// but block for ever or never end (for the caches' readers).
#[cfg(all(test, unix))]
pub(crate) fn not_files(dir: &std::path::Path) -> [std::path::PathBuf; 2] {
    let (fifo, zero) = (dir.join("fifo.bin"), dir.join("zero.bin"));
    let ok = std::process::Command::new("mkfifo").arg(&fifo).status();
    assert!(ok.is_ok_and(|s| s.success()), "mkfifo {}", fifo.display());
    std::os::unix::fs::symlink("/dev/zero", &zero).unwrap();
    [fifo, zero]
}
