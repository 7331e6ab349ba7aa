// Shared include of the staged ST-CVAE render, after staged.wgsl: the sphere-step stage.
// stage_main parks every sphere step, exact or the model's, at the start of its branch in
// scatter_at (stcvae.wgsl; nothing before that point changes the path), queued by kind;
// step_main runs each whole, and stage_main's next visit ends the bounce (Q_STEP).

/// The parked sphere steps (STAGED_STEPS), one per invocation, the exact ones by optical
/// radius and then the model's: each path is loaded at its collision and its step run as
/// scatter_at would have run it in stage_main, random numbers and all, so that the walks'
/// loops and the decoders run with every lane on a step of one kind rather than waiting
/// on lanes tracing or bouncing.
@compute @workgroup_size(WORKGROUP)
fn step_main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(local_invocation_index) li: u32) {
    prof_begin(li);
    stack_base = li * STACK_STRIDE;
    let i = invocation(gid);
    if i < queue.step_len && slot_begin(queue_entry(QUEUE_WALKS, STEP_QUEUES, i), 0u) {
        p_from_step = scatter_at(p_channel);
        if loop_limit_ran_out(u32(params.consts3.z)) {
            stats[C_TRUNCATED] = 1u;
        }
        slot_end(false, false);
    }
}
