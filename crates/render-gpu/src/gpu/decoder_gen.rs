//! Straight-line WGSL for a model's three decoders, weights as constants.
//!
//! A generic decoder would loop over layers, rows and vec4s and read every weight from a
//! buffer (the first version did; ST-CVAE ran 2.2× slower on lavapipe). Generated for one
//! model's architecture, the same arithmetic has no loops (lavapipe counts every loop
//! iteration against its 65,535 limit, and SIMD lanes never diverge in it) and its
//! constants fold at compile time. Each output is a row of zero-padded vec4 dot products
//! plus the bias, like the Rust decoder (checked against it in the tests).

use std::fmt::Write;

use cvae::ModelSet;
use cvae::decoder::{Decoder, LOGVAR_CLAMP};

use crate::error::RenderError;

/// Sizes of the kernels' decoder scratch (`dec_cond`, `dec_noise`, `dec_out` in
/// shaders/decoder.wgsl, sized by these as `DEC_MAX_COND`, `DEC_MAX_NOISE` and
/// `DEC_MAX_OUT`; the probe's item layout asserts them).
const MAX_COND: usize = 12;
const MAX_NOISE: usize = 16;
const MAX_OUT: usize = 8;

/// An f32 as a WGSL literal that round-trips exactly.
fn lit(v: f32) -> String {
    let s = format!("{v:?}");
    if s.contains('.') || s.contains('e') || s.contains("inf") || s.contains("NaN") {
        s
    } else {
        format!("{s}.0")
    }
}

fn vec4_lit(v: &[f32]) -> String {
    let mut q = [0f32; 4];
    q[..v.len()].copy_from_slice(v);
    format!(
        "vec4<f32>({}, {}, {}, {})",
        lit(q[0]),
        lit(q[1]),
        lit(q[2]),
        lit(q[3])
    )
}

fn gen_decoder(out: &mut String, idx: usize, d: &Decoder) {
    let _ = writeln!(out, "fn decoder_sample_{idx}() {{");
    // Input: standardised conditions, then the latent normals, packed into vec4s.
    let n_in = d.cond + d.latent;
    let input: Vec<String> = (0..n_in.div_ceil(4) * 4)
        .map(|i| {
            if i < d.cond {
                format!(
                    "((dec_cond[{i}] - {}) / {})",
                    lit(d.cond_shift[i]),
                    lit(d.cond_scale[i])
                )
            } else if i < n_in {
                format!("dec_noise[{}]", i - d.cond)
            } else {
                "0.0".into()
            }
        })
        .collect();
    for (k, c) in input.chunks(4).enumerate() {
        let _ = writeln!(out, "    let a0_{k} = vec4<f32>({});", c.join(", "));
    }
    let last = d.layers.len() - 1;
    for (l, layer) in d.layers.iter().enumerate() {
        let in4 = layer.inputs.div_ceil(4);
        let mut names = Vec::new();
        for o in 0..layer.outputs {
            let row = &layer.weight[o * layer.inputs..(o + 1) * layer.inputs];
            let mut expr = lit(layer.bias[o]);
            for k in 0..in4 {
                let chunk = &row[4 * k..(4 * k + 4).min(layer.inputs)];
                let _ = write!(expr, " + dot({}, a{l}_{k})", vec4_lit(chunk));
            }
            if l < last {
                expr = format!("softplus({expr})");
            }
            let _ = writeln!(out, "    let h{l}_{o} = {expr};");
            names.push(format!("h{l}_{o}"));
        }
        while names.len() % 4 != 0 {
            names.push("0.0".into());
        }
        for (k, c) in names.chunks(4).enumerate() {
            let _ = writeln!(out, "    let a{}_{k} = vec4<f32>({});", l + 1, c.join(", "));
        }
    }
    let head = d.layers.len();
    for j in 0..d.out {
        let k = d.out + j;
        let _ = writeln!(
            out,
            "    dec_out[{j}] = (a{head}_{}[{}] + exp(0.5 * clamp(a{head}_{}[{}], {}, {})) * dec_noise[{}]) * {} + {};",
            j / 4,
            j % 4,
            k / 4,
            k % 4,
            lit(-LOGVAR_CLAMP),
            lit(LOGVAR_CLAMP),
            d.latent + j,
            lit(d.out_scale[j]),
            lit(d.out_shift[j])
        );
    }
    let _ = writeln!(out, "}}\n");
}

/// Whether a decoder of these sizes fits the kernels' scratch; the error completes a
/// sentence that starts with the decoder's name. `train` asks it before training, so
/// that a model too large for the GPU is known as such before hours of work.
pub fn fits_kernels(cond: usize, latent: usize, out: usize) -> Result<(), String> {
    if cond > MAX_COND || latent + out > MAX_NOISE || out > MAX_OUT {
        return Err(format!(
            "is too large for the GPU kernels ({cond} conditions, {latent} latent, {out} \
             outputs; at most {MAX_COND} conditions, {MAX_OUT} outputs, {MAX_NOISE} latent + \
             outputs)"
        ));
    }
    Ok(())
}

/// The decoder scratch's sizes and the features' constants whose one definition is in
/// Rust (cvae::features), for shaders/decoder.wgsl: a WGSL copy could drift from them
/// silently, and only the GPU tests would see it.
fn feature_constants_wgsl() -> String {
    use cvae::features as f;
    format!(
        "const DEC_MAX_COND: u32 = {MAX_COND}u;\nconst DEC_MAX_NOISE: u32 = {MAX_NOISE}u;\n\
         const DEC_MAX_OUT: u32 = {MAX_OUT}u;\nconst MAX_DECODED_N: f32 = {};\n\
         const PRIOR_QUADRATIC: f32 = {};\nconst PRIOR_LINEAR: f32 = {};\n\n",
        lit(f::MAX_DECODED_N as f32),
        lit(f::PRIOR_QUADRATIC as f32),
        lit(f::PRIOR_LINEAR as f32),
    )
}

/// `decoder_sample(d)`, its three straight-line variants for `m` and their sizes
/// (`DEC_LATENT_i`, `DEC_OUT_i`).
pub fn decoders_wgsl(m: &ModelSet) -> Result<String, RenderError> {
    let mut out = String::from("// Generated from the model file: do not edit.\n\n");
    out += &feature_constants_wgsl();
    for (i, (d, name)) in m.decoders().iter().zip(ModelSet::DECODER_NAMES).enumerate() {
        fits_kernels(d.cond, d.latent, d.out)
            .map_err(|e| RenderError::Model(format!("{name} {e}")))?;
        let _ = writeln!(out, "const DEC_LATENT_{i}: u32 = {}u;", d.latent);
        let _ = writeln!(out, "const DEC_OUT_{i}: u32 = {}u;\n", d.out);
        gen_decoder(&mut out, i, d);
    }
    out.push_str(
        "fn decoder_sample(d: u32) {\n    prof(5u);\n    switch d {\n        case 0u: { decoder_sample_0(); }\n        case 1u: { decoder_sample_1(); }\n        default: { decoder_sample_2(); }\n    }\n}\n",
    );
    Ok(out)
}
