// Shared include: the generic decoder evaluation, reading the packed weight buffer with
// loops (used where no model is bound; with a model the kernels use straight-line code
// generated from it, crates/render-gpu/src/gpu/decoder_gen.rs).

fn weight_at(vec4_offset: u32, i: u32) -> f32 {
    return weights[vec4_offset + i / 4u][i % 4u];
}

/// Runs decoder `d` on dec_cond/dec_noise and writes dec_out.
fn decoder_sample(d: u32) {
    let desc = model.decoders[d];
    let n_cond = desc.dims.x;
    let n_latent = desc.dims.y;
    let n_out = desc.dims.z;
    let n_layers = desc.dims.w;
    var a: array<vec4<f32>, 16>;
    var b: array<vec4<f32>, 16>;
    for (var i = 0u; i < n_cond; i++) {
        let v = (dec_cond[i] - weight_at(desc.norm.x, i)) / weight_at(desc.norm.y, i);
        a[i / 4u][i % 4u] = v;
    }
    for (var i = 0u; i < n_latent; i++) {
        let k = n_cond + i;
        a[k / 4u][k % 4u] = dec_noise[i];
    }
    for (var l = 0u; l < n_layers; l++) {
        let layer = desc.layers[l];
        let last = l + 1u == n_layers;
        for (var o = 0u; o < layer.outputs; o++) {
            let row = layer.w_offset + o * layer.in4;
            var acc = weight_at(layer.b_offset, o);
            for (var k = 0u; k < layer.in4; k++) {
                acc += dot(weights[row + k], a[k]);
            }
            if !last {
                acc = softplus(acc);
            }
            b[o / 4u][o % 4u] = acc;
        }
        a = b;
    }
    for (var j = 0u; j < n_out; j++) {
        let mean = a[j / 4u][j % 4u];
        let k = n_out + j;
        let logvar = clamp(a[k / 4u][k % 4u], -LOGVAR_CLAMP, LOGVAR_CLAMP);
        let v = mean + exp(0.5 * logvar) * dec_noise[n_latent + j];
        dec_out[j] = v * weight_at(desc.norm.w, j) + weight_at(desc.norm.z, j);
    }
}

