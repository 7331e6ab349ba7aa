// Shared include of the staged render (STCVAE_GPU_STAGED; gpu/renderer.rs), after
// path.wgsl: its bindings, queues and kernels. The single kernel (render_main) is built
// without it. Kernels take turns (a wavefront): stage_main runs each running path up to
// its next ray query or sphere step and queues it; trace_main traces the queued queries
// and step_main (staged_steps.wgsl, ST-CVAE) runs the queued sphere steps, one per
// invocation, so that their loops and decoders run with every lane on the same kind of
// work instead of waiting on lanes elsewhere in the bounce. The next stage_main visits
// the slots of this turn's queue of running paths alone (its list): a chunk's first
// stage_main starts every slot, later ones see only paths still running. The paths and
// their random numbers are the single kernel's, and so is the image, bit for bit.
//
// The queues' lengths and the running paths' queue come in two copies that alternate by
// turn (`Queue.turn`), and args_main writes the dispatch arguments straight into the
// indirect buffer, so that a turn is its four dispatches and nothing else: stage_main
// reads the last turn's running paths while it queues this turn's, and args_main empties
// the other copy for the next turn once stage_main has read it. A hardware GPU pays for
// every pass in a turn, full or empty (~85 µs each on the H100 when a turn also held the
// host's clears and copies and wgpu's argument checks, 2026-11-27).
//
// `stage` holds per slot STAGE_VEC4S vec4s (prepended by kernels.rs): the query's origin
// and tmax; its direction and flight length; (unused: the free distance is saved with the
// path), the triangle the path left through (the single kernel forgets it on resuming,
// which only costs a cast), the shadow ray's weight and the query's flags; then the path's
// channel, replaced by the answer (hit t, triangle, found, transmittance).
struct Queue {
    // Turns that args_main has closed: stage_main queues into copy `turn % 2` and reads
    // its list from the other; trace_main and step_main, after args_main, read copy
    // `(turn + 1) % 2`, the one stage_main just filled.
    turn: u32,
    // The sphere steps (their five queues together) and the queries (their three) queued
    // in this turn.
    step_len: u32,
    query_len: u32,
    // Each queue's length by its number (QUEUE_*), in the two copies; room for QUEUES ≤
    // QUEUE_LENGTHS (gpu/resources.rs, whose QUEUE_HEAD the layout test checks).
    counts: array<array<atomic<u32>, QUEUE_LENGTHS>, 2>,
    // QUEUES + 1 regions of `slots` entries, one per queue, and the running paths' second
    // copy last.
    items: array<u32>,
}
@group(0) @binding(8) var<storage, read_write> stage: array<vec4<f32>>;
@group(0) @binding(9) var<storage, read_write> queue: Queue;
// Workgroups (x, y, z) for the indirect dispatches over the running paths (the next
// stage_main's), the parked sphere steps and the ray queries: written by the arguments'
// kernels alone, which have a layout of their own (gpu/kernels.rs, args_layout).
@group(0) @binding(10) var<storage, read_write> indirect: array<u32, ARGS_WORDS>;

const Q_PENDING: u32 = 1u;
const Q_SHADOW: u32 = 2u;
const Q_QUERY: u32 = 4u;
const Q_LOCAL: u32 = 8u;
const Q_LAST_LIGHT: u32 = 16u;
const Q_STEP: u32 = 32u;

// The queues, in the order of their items, each in a region of its own so that a
// kernel's subgroups run one kind of work: the running paths; the parked exact steps by
// optical radius (WALK_BUCKETS: a walk's length follows τ²), then the model's steps
// (step_main); the ray queries by kind: local (a grid cell's list first), closest-hit,
// shadow ray (trace_main).
const QUEUE_RUNNING: u32 = 0u;
const QUEUE_WALKS: u32 = 1u;
const QUEUE_STEPS: u32 = 5u;
const QUEUE_LOCAL: u32 = 6u;
const QUEUE_CLOSEST: u32 = 7u;
const QUEUE_SHADOW: u32 = 8u;
// QUEUES, the host's count (gpu/resources.rs), is prepended.
const_assert QUEUES == QUEUE_SHADOW + 1u;
const_assert QUEUES <= QUEUE_LENGTHS;
// step_main's queues (from QUEUE_WALKS) and trace_main's (from QUEUE_LOCAL).
const STEP_QUEUES: u32 = 5u;
const QUERY_QUEUES: u32 = 3u;
// The optical radii that divide the exact steps' four queues.
const WALK_BUCKETS: vec3<f32> = vec3<f32>(2.0, 5.0, 10.0);

/// The copy of the queues that stage_main fills in this turn (`Queue.turn`).
fn filling() -> u32 {
    return queue.turn % 2u;
}

/// The copy that stage_main filled before args_main closed the turn: what trace_main and
/// step_main read, and the next stage_main's list.
fn filled() -> u32 {
    return 1u - queue.turn % 2u;
}

/// The region of queue `which` in copy `copy`: the running paths' queue has two, the
/// others one each.
fn queue_region(which: u32, copy: u32) -> u32 {
    return select(which, QUEUES, which == QUEUE_RUNNING && copy == 1u);
}

/// The entry of invocation `i` in the `count` queues from `first` on, taken one after
/// another, in the copy just filled.
fn queue_entry(first: u32, count: u32, i: u32) -> u32 {
    let copy = filled();
    var k = 0u;
    var j = i;
    loop {
        let len = atomicLoad(&queue.counts[copy][first + k]);
        if k + 1u >= count || j < len {
            break;
        }
        j -= len;
        k++;
    }
    return queue.items[queue_region(first + k, copy) * queue_slots() + j];
}

/// The entries in the `count` queues from `first` on, in copy `copy`.
fn queued(first: u32, count: u32, copy: u32) -> u32 {
    var n = 0u;
    for (var k = 0u; k < count; k++) {
        n += atomicLoad(&queue.counts[copy][first + k]);
    }
    return n;
}

/// Path slots per queue region (the largest band's).
fn queue_slots() -> u32 {
    return arrayLength(&queue.items) / (QUEUES + 1u);
}

/// Appends slot `idx` to queue `which`: one atomic add per subgroup (its first active
/// lane's, for all), the lanes' places following in rank order, where the kernel
/// aggregates (gpu/kernels.rs, aggregate_wgsl); otherwise one add per invocation. The
/// active lanes of a call must all pass the same `which` (one call site per queue).
fn enqueue(which: u32, idx: u32) {
    let copy = filling();
    let rank = sg_rank();
    let n = sg_count();
    var at = 0u;
    if rank == 0u {
        at = atomicAdd(&queue.counts[copy][which], n);
    }
    queue.items[queue_region(which, copy) * queue_slots() + sg_first(at) + rank] = idx;
}

/// A slot's saved query read back.
fn load_query(rec: u32) -> Query {
    let a = stage[rec];
    let b = stage[rec + 1u];
    let c = stage[rec + 2u];
    let f = bitcast<u32>(c.w);
    return Query(a.xyz, a.w, b.xyz, b.w, c.z, f >> 8u, (f & Q_LAST_LIGHT) != 0u,
        (f & Q_SHADOW) != 0u, (f & Q_QUERY) != 0u, (f & Q_LOCAL) != 0u, false);
}

/// The list's length: the paths the last turn left running.
fn list_len() -> u32 {
    return atomicLoad(&queue.counts[filled()][QUEUE_RUNNING]);
}

/// Slot `i` of the list.
fn list_entry(i: u32) -> u32 {
    return queue.items[queue_region(QUEUE_RUNNING, filled()) * queue_slots() + i];
}

/// Writes the dispatch arguments for `n` invocations at word `at` of the indirect buffer:
/// WORKGROUP-sized groups as (x, y), DISPATCH_ROW of them (65,535, the most a dimension
/// allows, unless a test lowers it) a row, as the host lays out direct dispatches.
fn dispatch_args(at: u32, n: u32) {
    let groups = (n + WORKGROUP - 1u) / WORKGROUP;
    let y = max((groups + DISPATCH_ROW - 1u) / DISPATCH_ROW, 1u);
    indirect[at] = select(groups, DISPATCH_ROW, y > 1u);
    indirect[at + 1u] = y;
    indirect[at + 2u] = 1u;
}

// Where each kernel's arguments lie in the indirect buffer (words): STAGE_ARGS,
// STEP_ARGS and QUERY_ARGS, prepended from gpu/resources.rs.
const_assert STEP_ARGS >= STAGE_ARGS + 3u && QUERY_ARGS >= STEP_ARGS + 3u;
const_assert ARGS_WORDS >= QUERY_ARGS + 3u;

/// Closes the turn: dispatch arguments for the queues stage_main just filled
/// (trace_main's, step_main's, and the next stage_main's over the running paths), then the
/// other copy of the queues, which stage_main has read its list from, emptied for the next
/// turn.
@compute @workgroup_size(1)
fn args_main() {
    let copy = filling();
    let running = atomicLoad(&queue.counts[copy][QUEUE_RUNNING]);
    dispatch_args(STAGE_ARGS, running);
    let steps = queued(QUEUE_WALKS, STEP_QUEUES, copy);
    queue.step_len = steps;
    dispatch_args(STEP_ARGS, steps);
    let queries = queued(QUEUE_LOCAL, QUERY_QUEUES, copy);
    queue.query_len = queries;
    dispatch_args(QUERY_ARGS, queries);
    for (var k = 0u; k < QUEUES; k++) {
        atomicStore(&queue.counts[1u - copy][k], 0u);
    }
    queue.turn += 1u;
    // The invocations still pending are the running paths: counted once here rather than
    // by an atomic add in every stage_main invocation (both words of the 64-bit counter,
    // so that the host need not clear it before each turn).
    atomicStore(&counters[2u * C_PENDING], running);
    atomicStore(&counters[2u * C_PENDING + 1u], 0u);
}

/// Dispatch arguments for the list (the first stage_main of a submission where a snapshot
/// may have restored the queues: the arguments may be from an undone turn).
@compute @workgroup_size(1)
fn list_args_main() {
    dispatch_args(STAGE_ARGS, list_len());
}

/// The linear index of invocation `gid` (dispatched as in render_main).
fn invocation(gid: vec3<u32>) -> u32 {
    return (gid.x / WORKGROUP + gid.y * DISPATCH_ROW) * WORKGROUP + gid.x % WORKGROUP;
}

@compute @workgroup_size(WORKGROUP)
fn stage_main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(local_invocation_index) li: u32) {
    prof_begin(li);
    stack_base = li * STACK_STRIDE;
    var idx = NO_SLOT;
    if params.misc.w != 0u {
        idx = slot_of(gid);
    } else {
        let i = invocation(gid);
        if i < list_len() {
            idx = list_entry(i);
        }
    }
    if idx == NO_SLOT || !slot_begin(idx, params.misc.w) {
        return;
    }
    let was_done = sl_done;
    let rec = idx * STAGE_VEC4S;
    park_steps = STAGED_STEPS;
    // What the path left off at: a query answered since (Q_PENDING) or a sphere step that
    // step_main has run (Q_STEP). One call site each for bounce_begin and bounce_end:
    // llvmpipe inlines everything, and a second copy of the bounce's end makes the kernel
    // slower still.
    var resume = 0u;
    if !sl_done && params.misc.w == 0u {
        let c = stage[rec + 2u];
        p_left_through = bitcast<u32>(c.y);
        resume = bitcast<u32>(c.w) & (Q_PENDING | Q_STEP);
    }
    var flags = 0u;
    var weight = 0.0;
    let budget = u32(params.consts2.z);
    for (var b = 0u; b < budget && !sl_done; b++) {
        var q = Query(ps.pos, 0.0, ps.dir, 0.0, 0.0, 0u, false, false, false, false, false);
        var h = Hit(0.0, 0u, false);
        var tr = 0.0;
        if resume == Q_PENDING {
            q = load_query(rec);
            let ans = stage[rec + 3u];
            h = Hit(ans.x, bitcast<u32>(ans.y), bitcast<u32>(ans.z) != 0u);
            tr = ans.w;
        } else if resume == Q_STEP {
            // step_main ran the sphere step: the bounce is over.
            q.ended = true;
        } else {
            q = bounce_begin();
            if q.query && !q.ended {
                flags = Q_PENDING | Q_QUERY | (q.k << 8u);
                if q.shadow { flags |= Q_SHADOW; }
                if q.local { flags |= Q_LOCAL; }
                if q.last_light { flags |= Q_LAST_LIGHT; }
                weight = q.weight;
                stage[rec] = vec4<f32>(q.o, q.tmax);
                stage[rec + 1u] = vec4<f32>(q.d, q.t);
                stage[rec + 3u] = vec4<f32>(bitcast<f32>(p_channel), 0.0, 0.0, 0.0);
                // One call per kind: enqueue's lanes must share their queue.
                if q.local {
                    enqueue(QUEUE_LOCAL, idx);
                } else if q.shadow {
                    enqueue(QUEUE_SHADOW, idx);
                } else {
                    enqueue(QUEUE_CLOSEST, idx);
                }
                break;
            }
        }
        resume = 0u;
        if !q.ended {
            bounce_end(q, h, tr);
        }
        if step_parked {
            // The step waits for step_main; the next visit ends its bounce. One call per
            // queue: enqueue's lanes must share theirs.
            flags = Q_STEP;
            if step_tau < 0.0 {
                enqueue(QUEUE_STEPS, idx);
            } else if step_tau < WALK_BUCKETS.x {
                enqueue(QUEUE_WALKS, idx);
            } else if step_tau < WALK_BUCKETS.y {
                enqueue(QUEUE_WALKS + 1u, idx);
            } else if step_tau < WALK_BUCKETS.z {
                enqueue(QUEUE_WALKS + 2u, idx);
            } else {
                enqueue(QUEUE_WALKS + 3u, idx);
            }
            break;
        }
        bounce_done(q.shadow);
    }
    if !sl_done {
        // Every running path is in the next turn's list; those with a query or a parked
        // step are in that queue too.
        stage[rec + 2u] = vec4<f32>(0.0, bitcast<f32>(p_left_through), weight, bitcast<f32>(flags));
        enqueue(QUEUE_RUNNING, idx);
    }
    if loop_limit_ran_out(u32(params.consts3.z)) {
        stats[C_TRUNCATED] = 1u;
    }
    // The pending count is args_main's (the running queue's length): not one atomic add
    // per invocation.
    slot_end(was_done, false);
}

@compute @workgroup_size(WORKGROUP)
fn trace_main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(local_invocation_index) li: u32) {
    prof_begin(li);
    stack_base = li * STACK_STRIDE;
    let i = invocation(gid);
    if i < queue.query_len {
        let rec = queue_entry(QUEUE_LOCAL, QUERY_QUEUES, i) * STAGE_VEC4S;
        let q = load_query(rec);
        let channel = bitcast<u32>(stage[rec + 3u].x);
        var h = answer_query(q, channel);
        var tr = 0.0;
        if q.shadow {
            tr = shadow_of(tr_cross, q.o, q.d, channel);
            h = refraction_hit();
        }
        stage[rec + 3u] = vec4<f32>(h.t, bitcast<f32>(h.prim), bitcast<f32>(select(0u, 1u, h.found)), tr);
        if loop_limit_ran_out(u32(params.consts3.z)) {
            add_counter(C_TRUNCATED, 1u);
        }
    }
    prof_end();
}
