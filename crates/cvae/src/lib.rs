//! The three CVAEs of stcvae — LengthGen, PathGen, EventGen (paper §3.2, design §3).
//!
//! The burn-free part (always compiled; what the renderers link): the feature
//! transforms, the model file, plain-Rust decoder evaluation and the sampling API.
//! The `train` feature adds the burn models, the Adamax optimiser, training and export.

pub mod decoder;
pub mod eval;
pub mod fastmath;
pub mod features;
pub mod model_file;
pub mod sampler;

pub use model_file::{ModelError, ModelSet, SingleScattering};
pub use sampler::ModelWalk;

#[cfg(feature = "train")]
pub mod train;
