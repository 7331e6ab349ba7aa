// Shared include of the staged ST-CVAE render, after staged.wgsl: the exact steps'
// walk stage (stcvae.wgsl, scatter_at parks a step; path.wgsl, stage_main resumes it).
// A parked exact step's record (after the query record, from WALK_AT): first the
// walk's inputs (optical radius, radius of the free ball in units of the step's, NEE
// events, channel), then its outcome: exit point and N, exit direction and the events
// used, and per event (X, weight) and (W, 0).
const WALK_AT: u32 = 4u;

fn save_walk_inputs(tau: f32, channel: u32, m: u32, f_unit: f32) {
    stage[sv_rec + WALK_AT] = vec4<f32>(tau, f_unit, bitcast<f32>(m), bitcast<f32>(channel));
}

fn load_walk() -> ExactWalk {
    let a = stage[sv_rec + WALK_AT];
    let b = stage[sv_rec + WALK_AT + 1u];
    let used = bitcast<u32>(b.w);
    for (var k = 0u; k < used; k++) {
        let x = stage[sv_rec + WALK_AT + 2u + 2u * k];
        ex_x[k] = x.xyz;
        ex_weight[k] = x.w;
        ex_w[k] = stage[sv_rec + WALK_AT + 3u + 2u * k].xyz;
    }
    return ExactWalk(a.xyz, b.xyz, a.w, used);
}

/// The parked exact steps' walks, one per invocation: each runs on its path's random
/// number stream (saved back with the path) in the frame its step computed from the
/// path's direction, exactly as scatter_at would have run it.
@compute @workgroup_size(WORKGROUP)
fn walk_main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(local_invocation_index) li: u32) {
    prof_begin(li);
    let i = invocation(gid);
    if i < atomicLoad(&queue.walk_len) {
        let lens = vec4<u32>(atomicLoad(&queue.walk_kinds[0]), atomicLoad(&queue.walk_kinds[1]), atomicLoad(&queue.walk_kinds[2]), atomicLoad(&queue.walk_kinds[3]));
        let idx = queue_entry(QUEUE_WALKS, 4u, lens, i);
        let base = idx * SLOT;
        let rec = idx * STAGE_VEC4S + WALK_AT;
        let inp = stage[rec];
        rng_s = bitcast<vec4<u32>>(accum[base + 2u]);
        let frame = walk_frame(accum[base + 1u].xyz, vec2<f32>(1.0, 0.0));
        let walk = exact_walk(inp.x, params.consts.x, bitcast<u32>(inp.w), bitcast<u32>(inp.z), frame, inp.y);
        accum[base + 2u] = bitcast<vec4<f32>>(rng_s);
        stage[rec] = vec4<f32>(walk.x, walk.n);
        stage[rec + 1u] = vec4<f32>(walk.w, bitcast<f32>(walk.used));
        for (var k = 0u; k < walk.used; k++) {
            stage[rec + 2u + 2u * k] = vec4<f32>(ex_x[k], ex_weight[k]);
            stage[rec + 3u + 2u * k] = vec4<f32>(ex_w[k], 0.0);
        }
        if loop_limit_ran_out(u32(params.consts3.z)) {
            add_counter(C_TRUNCATED, 1u);
        }
    }
    prof_end();
}

/// The parked model steps (STAGED_STEPS), one per invocation: each path is loaded at its
/// collision and its whole sphere step run, decoders and NEE events included, as
/// scatter_at would have run it in stage_main, so that the decoders run with every lane
/// on a step rather than waiting on lanes tracing or walking. stage_main then ends the
/// bounce.
@compute @workgroup_size(WORKGROUP)
fn step_main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(local_invocation_index) li: u32) {
    prof_begin(li);
    stack_base = li * STACK_STRIDE;
    let i = invocation(gid);
    if i < atomicLoad(&queue.step_len) && slot_begin(queue.items[QUEUE_STEPS * queue_slots() + i], 0u) {
        p_from_step = scatter_at(p_channel);
        if loop_limit_ran_out(u32(params.consts3.z)) {
            stats[C_TRUNCATED] = 1u;
        }
        slot_end(false, false);
    }
}
