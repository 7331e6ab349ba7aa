//! One error type for the renderer; every message is one line naming the file or field.

use std::path::Path;

use thiserror::Error;

#[derive(Debug, Error)]
pub enum RenderError {
    /// Scene file problems (the message starts with the file name).
    #[error("{0}")]
    Scene(String),
    /// Mesh file problems (the message starts with the file name).
    #[error("{0}")]
    Mesh(String),
    /// Reading or writing a file failed.
    #[error("{0}")]
    Io(String),
    /// The model file could not be used.
    #[error("{0}")]
    Model(String),
    /// Images that cannot be merged, or an unreadable image.
    #[error("{0}")]
    Image(String),
    /// No wgpu adapter of the kind asked for exists (a machine without a GPU driver):
    /// kept apart from [`RenderError::Gpu`] so that callers can fall back to the CPU, and
    /// tests skip, for this reason alone.
    #[error("{0}")]
    NoAdapter(String),
    /// The render is beyond what the GPU kernels or the adapter hold for reasons outside
    /// the scene file (the spp, the adapter's memory or bindings, an STCVAE_GPU_* switch),
    /// while the CPU integrators render it: `--device auto` falls back to the CPU.
    #[error("{0}")]
    GpuLimit(String),
    /// The scene is beyond what the GPU kernels or the adapter hold (lights, BVH depth, a
    /// buffer over the adapter's binding limit): as [`RenderError::GpuLimit`], and the
    /// CLI names the scene file, where the change goes.
    #[error("{0}")]
    SceneBeyondGpu(String),
    /// An adapter could not be opened, or the GPU failed.
    #[error("{0}")]
    Gpu(String),
}

impl RenderError {
    pub fn io(path: &Path, what: impl std::fmt::Display) -> Self {
        Self::Io(format!("{}: {what}", path.display()))
    }
    pub fn mesh(path: &Path, what: impl std::fmt::Display) -> Self {
        Self::Mesh(format!("{}: {what}", path.display()))
    }
}
