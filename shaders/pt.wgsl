// Kernel: volumetric path tracing, the reference. Composed as common + scene + nee +
// pt + path (crates/render-gpu/src/gpu/kernels.rs).

fn scatter_at(channel: u32) -> bool {
    pt_event(channel);
    return false;
}
