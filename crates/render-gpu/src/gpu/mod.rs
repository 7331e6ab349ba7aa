//! The wgpu compute renderer: the CPU integrators' estimators as WGSL kernels
//! (`shaders/`), progressive accumulation in short dispatches, the same outputs.

mod bands;
pub mod context;
pub mod decoder_gen;
pub mod kernel_cache;
pub mod kernels;
pub mod model_buffers;
pub mod probe;
mod readout;
pub mod renderer;
pub mod resources;
pub mod scene_buffers;
mod switches;

pub use context::{AdapterChoice, AdapterSummary, GpuContext};
pub use renderer::render_gpu;
