//! Host mirror of `ModelParams` in `shaders/scene.wgsl`: what the kernels need of a model
//! besides its decoders, which are generated as code (`decoder_gen.rs`).

use bytemuck::{Pod, Zeroable};
use cvae::ModelSet;
use cvae::model_file::SingleScattering;

#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
pub struct ModelParams {
    /// single scattering exact (1/0), n_min, EventGen's radial map (0: atanh, feature
    /// version 2; 1: the Gaussian-edge map of version 3), 0.
    pub flags: [u32; 4],
}

pub fn model_params(m: &ModelSet) -> ModelParams {
    ModelParams {
        flags: [
            (m.single_scattering == SingleScattering::Exact) as u32,
            m.n_min() as u32,
            // A match, not a comparison: a new map must be given its WGSL code here.
            match m.event_radial() {
                cvae::features::EventRadial::Atanh => 0,
                cvae::features::EventRadial::GaussianEdge => 1,
            },
            0,
        ],
    }
}
