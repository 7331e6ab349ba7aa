//! Host mirror of `ModelParams` in `shaders/scene.wgsl` and the packed weight buffer that
//! `shaders/decoder.wgsl` reads: every decoder row padded with zeros to whole vec4s, the
//! normalisation vectors likewise.

use bytemuck::{Pod, Zeroable};
use cvae::ModelSet;
use cvae::decoder::Decoder;
use cvae::model_file::SingleScattering;

use crate::error::RenderError;

/// Layers per decoder the kernels accept (hidden layers + the head).
pub const MAX_GPU_LAYERS: usize = 8;
/// Widest layer (inputs or outputs) the kernels accept: 16 vec4s of activations.
pub const MAX_GPU_WIDTH: usize = 64;

#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
pub struct GpuLayer {
    /// First vec4 of row 0 in the weight buffer.
    pub w_offset: u32,
    /// First vec4 of the bias.
    pub b_offset: u32,
    /// vec4s per row (inputs rounded up to a multiple of 4).
    pub in4: u32,
    pub outputs: u32,
}

#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
pub struct GpuDecoder {
    /// cond, latent, out, layers.
    pub dims: [u32; 4],
    /// vec4 offsets of cond shift, cond scale, out shift, out scale.
    pub norm: [u32; 4],
    pub layers: [GpuLayer; MAX_GPU_LAYERS],
}

#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
pub struct ModelParams {
    pub decoders: [GpuDecoder; 3],
    /// single scattering exact (1/0), n_min, 0, 0.
    pub flags: [u32; 4],
}

fn push_padded(buf: &mut Vec<[f32; 4]>, v: &[f32]) -> u32 {
    let at = buf.len() as u32;
    for chunk in v.chunks(4) {
        let mut q = [0.0; 4];
        q[..chunk.len()].copy_from_slice(chunk);
        buf.push(q);
    }
    if v.is_empty() {
        buf.push([0.0; 4]);
    }
    at
}

fn pack_decoder(
    d: &Decoder,
    name: &str,
    buf: &mut Vec<[f32; 4]>,
) -> Result<GpuDecoder, RenderError> {
    if d.layers.len() > MAX_GPU_LAYERS {
        return Err(RenderError::Model(format!(
            "{name} has {} layers; the GPU kernels take at most {MAX_GPU_LAYERS}",
            d.layers.len()
        )));
    }
    let widest = d
        .layers
        .iter()
        .map(|l| l.inputs.max(l.outputs))
        .max()
        .unwrap_or(0);
    if widest > MAX_GPU_WIDTH || d.cond > 12 || d.latent + d.out > 16 || d.out > 8 {
        return Err(RenderError::Model(format!(
            "{name} is too wide for the GPU kernels (widest layer {widest}, at most \
             {MAX_GPU_WIDTH}; at most 12 conditions, 8 outputs, 16 latent + outputs)"
        )));
    }
    let mut g = GpuDecoder {
        dims: [
            d.cond as u32,
            d.latent as u32,
            d.out as u32,
            d.layers.len() as u32,
        ],
        ..Default::default()
    };
    g.norm = [
        push_padded(buf, &d.cond_shift),
        push_padded(buf, &d.cond_scale),
        push_padded(buf, &d.out_shift),
        push_padded(buf, &d.out_scale),
    ];
    for (gl, l) in g.layers.iter_mut().zip(&d.layers) {
        let in4 = l.inputs.div_ceil(4);
        let w_offset = buf.len() as u32;
        for o in 0..l.outputs {
            let row = &l.weight[o * l.inputs..(o + 1) * l.inputs];
            let mut padded = row.to_vec();
            padded.resize(in4 * 4, 0.0);
            push_padded(buf, &padded);
        }
        let b_offset = push_padded(buf, &l.bias);
        *gl = GpuLayer {
            w_offset,
            b_offset,
            in4: in4 as u32,
            outputs: l.outputs as u32,
        };
    }
    Ok(g)
}

/// The model's uniform block and weight buffer.
pub fn model_buffers(m: &ModelSet) -> Result<(ModelParams, Vec<[f32; 4]>), RenderError> {
    let mut buf = Vec::new();
    let decoders = [
        pack_decoder(&m.length, "LengthGen", &mut buf)?,
        pack_decoder(&m.path, "PathGen", &mut buf)?,
        pack_decoder(&m.event, "EventGen", &mut buf)?,
    ];
    Ok((
        ModelParams {
            decoders,
            flags: [
                (m.single_scattering == SingleScattering::Exact) as u32,
                m.n_min() as u32,
                0,
                0,
            ],
        },
        buf,
    ))
}
