//! GPU buffers of one render (or probe run) and their bind groups: one per band, and one
//! for the staged render's arguments' kernels.

use std::sync::mpsc;

use crate::error::RenderError;

use super::context::GpuContext;
use super::model_buffers::ModelParams;
use super::scene_buffers::{GpuNode, GpuTri, Params};

pub struct Resources {
    pub params: wgpu::Buffer,
    /// One accumulation buffer per band of the image, each within the binding limit.
    pub accums: Vec<wgpu::Buffer>,
    pub counters: wgpu::Buffer,
    /// The staged render's records (one per path slot of the largest band) and its queues
    /// (running paths, parked steps and queries by kind, their lengths in two copies that
    /// alternate by turn: shaders/staged.wgsl), bound for the staged kernels alone; 16- and
    /// 108-byte dummies otherwise.
    pub stage: wgpu::Buffer,
    pub queue: wgpu::Buffer,
    /// The indirect dispatch arguments of the staged render's kernels, written by its
    /// arguments' kernels, which alone bind it (a dispatch may not both bind a buffer as
    /// storage and read it as arguments), with the counters and queues.
    args: wgpu::Buffer,
    args_bind_group: Option<wgpu::BindGroup>,
    /// One bind group per band: the same inputs, that band's accumulation buffer.
    bind_groups: Vec<wgpu::BindGroup>,
    /// Kept alive for the bind groups.
    _inputs: Vec<wgpu::Buffer>,
}

/// The path counters' slots (lo/hi u32 pairs), read by the host here and named `C_*` in
/// the kernels, which get them from [`slot::WGSL`] (gpu/kernels.rs): one definition, so a
/// counter cannot be written under one number and read under another.
pub mod slot {
    pub const PATHS: u64 = 0;
    pub const EVENTS: u64 = 1;
    pub const STEPS: u64 = 2;
    pub const LEAKS: u64 = 3;
    pub const CAPPED: u64 = 4;
    pub const NON_FINITE: u64 = 5;
    /// Invocations that still have work after a dispatch.
    pub const PENDING: u64 = 6;
    /// Invocations whose bounce loop a driver's loop limit ended early.
    pub const TRUNCATED: u64 = 7;
    pub const EXACT: u64 = 8;
    /// Scattering events simulated inside exact steps' walks (their N).
    pub const EXACT_EVENTS: u64 = 9;
    /// Every path counter under its kernels' name, in slot order.
    pub const WGSL: [(&str, u64); 10] = [
        ("C_PATHS", PATHS),
        ("C_EVENTS", EVENTS),
        ("C_STEPS", STEPS),
        ("C_LEAKS", LEAKS),
        ("C_CAPPED", CAPPED),
        ("C_NON_FINITE", NON_FINITE),
        ("C_PENDING", PENDING),
        ("C_TRUNCATED", TRUNCATED),
        ("C_EXACT", EXACT),
        ("C_EXACT_EVENTS", EXACT_EVENTS),
    ];
}

/// The path counters (`PATH_COUNTERS` in the kernels): the first counter slots.
pub const PATH_COUNTERS: u64 = slot::WGSL.len() as u64;
const _: () = {
    let mut i = 0;
    while i < slot::WGSL.len() {
        assert!(
            slot::WGSL[i].1 == i as u64,
            "slot::WGSL lists the slots in order"
        );
        i += 1;
    }
};

/// Counter slots (lo/hi u32 pairs): the path counters, then per lane-profile phase its
/// active lanes, its lane capacity and its subgroup passes
/// ([`super::kernels::PROFILE_PHASES`]).
pub const COUNTER_SLOTS: u64 = PATH_COUNTERS + 3 * super::kernels::PROFILE_PHASES.len() as u64;

/// Bytes of the staged render's `stage` buffer per path slot: its query record.
pub const STAGE_SLOT_BYTES: u64 = 16 * super::kernels::STAGE_VEC4S;

/// Lengths `Queue.counts` holds per copy (`QUEUE_LENGTHS` in the kernels).
pub const QUEUE_LENGTHS: u64 = 12;

/// Bytes before the queues' slot indices (`Queue` in shaders/staged.wgsl): the turn, the
/// parked sphere steps' and the ray queries' totals, then every queue's length in two
/// copies of [`QUEUE_LENGTHS`] words. Checked against the WGSL struct's layout by
/// `host_structs_match_the_wgsl_layouts` (tests/wgsl_layout.rs).
pub const QUEUE_HEAD: u64 = 4 * (1 + 2 + 2 * QUEUE_LENGTHS);

/// The queues (`QUEUES`, prepended to the kernels from Rust): running paths, parked exact
/// steps by optical radius (four), parked model steps, and ray queries by kind (three).
pub const QUEUES: u64 = 9;
const _: () = assert!(
    QUEUES <= QUEUE_LENGTHS,
    "Queue.counts holds QUEUE_LENGTHS lengths"
);

/// Where in the indirect buffer each kernel's dispatch arguments lie, in bytes (the
/// kernels get them in words as `STAGE_ARGS` etc.), and its size.
pub const STAGE_ARGS_AT: u64 = 0;
pub const STEP_ARGS_AT: u64 = 12;
pub const QUERY_ARGS_AT: u64 = 24;
pub const ARGS_BYTES: u64 = QUERY_ARGS_AT + 12;

/// Bytes of the staged render's queues per path slot: one entry in each queue, two in the
/// running paths' (its copies alternate by turn).
pub const QUEUE_SLOT_BYTES: u64 = 4 * (QUEUES + 1);

/// Byte size of the counter buffer.
pub const COUNTER_BYTES: u64 = 8 * COUNTER_SLOTS;

/// Everything the kernels read; empty slices get a one-element dummy (wgpu forbids
/// zero-sized bindings).
pub struct Inputs<'a> {
    pub params: &'a Params,
    /// The size of each band's accumulation buffer.
    pub accum_bytes: &'a [u64],
    pub nodes: &'a [GpuNode],
    pub tris: &'a [GpuTri],
    pub env: &'a [[f32; 4]],
    /// The distance grid's cells, then its candidate lists ([`super::scene_buffers::grid_buffer`]).
    pub grid: &'a [u32],
    pub model: &'a ModelParams,
    /// Path slots of the largest band with a query record (0: not a staged render).
    pub stage_slots: u64,
}

/// A buffer holding `bytes`, created unmapped and filled through the queue. wgpu's
/// `create_buffer_init` maps the new buffer at creation and panics when the allocation
/// failed (out of memory), before the renderer's error scope can turn that into its
/// one-line "out of memory" error; a failed unmapped buffer is only invalid, and the
/// scope reports it.
fn init(ctx: &GpuContext, label: &str, bytes: &[u8], usage: wgpu::BufferUsages) -> wgpu::Buffer {
    let dummy = [0u8; 64];
    let contents = if bytes.is_empty() { &dummy[..] } else { bytes };
    // write_buffer needs a multiple of 4 bytes (COPY_BUFFER_ALIGNMENT).
    let size = (contents.len() as u64).next_multiple_of(wgpu::COPY_BUFFER_ALIGNMENT);
    let buffer = ctx.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some(label),
        size,
        usage: usage | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    if size == contents.len() as u64 {
        ctx.queue.write_buffer(&buffer, 0, contents);
    } else {
        let mut padded = contents.to_vec();
        padded.resize(size as usize, 0);
        ctx.queue.write_buffer(&buffer, 0, &padded);
    }
    buffer
}

/// Refuses inputs that one storage binding of the adapter cannot hold, named with what
/// would make them smaller: the message blamed the grid and mesh for an environment map too
/// large.
fn check_binding_sizes(ctx: &GpuContext, i: &Inputs) -> Result<(), RenderError> {
    let max = ctx.limits.max_storage_buffer_binding_size;
    let sizes = [
        (
            i.accum_bytes.iter().copied().max().unwrap_or(0),
            "the image's band of samples (a smaller image)",
        ),
        (
            std::mem::size_of_val(i.tris) as u64,
            "the mesh's triangles (fewer triangles)",
        ),
        (
            std::mem::size_of_val(i.nodes) as u64,
            "the mesh's BVH (fewer triangles)",
        ),
        (
            std::mem::size_of_val(i.grid) as u64,
            "the distance grid (a lower render.grid_resolution or fewer triangles)",
        ),
        (
            std::mem::size_of_val(i.env) as u64,
            "the environment map (a smaller map)",
        ),
    ];
    if let Some((biggest, what)) = sizes.into_iter().filter(|s| s.0 > max).max_by_key(|s| s.0) {
        return Err(RenderError::SceneBeyondGpu(format!(
            "a buffer of {biggest} bytes exceeds {}'s storage binding limit of {max} bytes: \
             {what}, or use --device cpu",
            ctx.adapter.name
        )));
    }
    Ok(())
}

/// A storage buffer the kernels write and the host copies to and from, of at least 16 bytes
/// (wgpu forbids zero-sized bindings).
fn rw_buffer(ctx: &GpuContext, label: &str, size: u64) -> wgpu::Buffer {
    ctx.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some(label),
        size: size.max(16),
        usage: wgpu::BufferUsages::STORAGE
            | wgpu::BufferUsages::COPY_SRC
            | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    })
}

/// The bind group of the staged render's argument kernels ([`super::kernels::args_layout`]).
fn args_bind_group(
    ctx: &GpuContext,
    layout: &wgpu::BindGroupLayout,
    counters: &wgpu::Buffer,
    queue: &wgpu::Buffer,
    args: &wgpu::Buffer,
) -> wgpu::BindGroup {
    let entries =
        [(2, counters), (9, queue), (10, args)].map(|(binding, b)| wgpu::BindGroupEntry {
            binding,
            resource: b.as_entire_binding(),
        });
    ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some("stcvae dispatch arguments"),
        layout,
        entries: &entries,
    })
}

/// One band's bind group: `buffers` in binding order, the staged render's two last ones
/// bound only where its kernels are (`staged`; their layout).
fn scene_bind_group(
    ctx: &GpuContext,
    layout: &wgpu::BindGroupLayout,
    buffers: [&wgpu::Buffer; 10],
    staged: bool,
) -> wgpu::BindGroup {
    let bound = if staged { 10 } else { 8 };
    let entries: Vec<wgpu::BindGroupEntry> = buffers
        .iter()
        .take(bound)
        .enumerate()
        .map(|(k, b)| wgpu::BindGroupEntry {
            binding: k as u32,
            resource: b.as_entire_binding(),
        })
        .collect();
    ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some("stcvae scene"),
        layout,
        entries: &entries,
    })
}

impl Resources {
    /// The buffers of `i` and their bind groups: one per band in `layout`, and, for the
    /// staged render, one in `args_layout` ([`super::kernels::args_layout`]).
    pub fn new(
        ctx: &GpuContext,
        layout: &wgpu::BindGroupLayout,
        args_layout: Option<&wgpu::BindGroupLayout>,
        i: &Inputs,
    ) -> Result<Self, RenderError> {
        check_binding_sizes(ctx, i)?;
        let ro = wgpu::BufferUsages::STORAGE;
        let uni = wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST;
        let params = init(
            ctx,
            "params",
            bytemuck::bytes_of(i.params),
            wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
        );
        let accums: Vec<wgpu::Buffer> = i
            .accum_bytes
            .iter()
            .map(|&bytes| rw_buffer(ctx, "accum", bytes))
            .collect();
        let counters = rw_buffer(ctx, "counters", COUNTER_BYTES);
        let stage = rw_buffer(ctx, "stage", STAGE_SLOT_BYTES * i.stage_slots);
        let queue = rw_buffer(ctx, "queue", QUEUE_HEAD + QUEUE_SLOT_BYTES * i.stage_slots);
        let args = ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("dispatch args"),
            size: ARGS_BYTES,
            usage: wgpu::BufferUsages::INDIRECT | wgpu::BufferUsages::STORAGE,
            mapped_at_creation: false,
        });
        let args_bind_group =
            args_layout.map(|layout| args_bind_group(ctx, layout, &counters, &queue, &args));
        let tris = init(ctx, "tris", bytemuck::cast_slice(i.tris), ro);
        let nodes = init(ctx, "nodes", bytemuck::cast_slice(i.nodes), ro);
        let env = init(ctx, "env", bytemuck::cast_slice(i.env), ro);
        let grid = init(ctx, "grid", bytemuck::cast_slice(i.grid), ro);
        let model = init(ctx, "model", bytemuck::bytes_of(i.model), uni);
        let bind_groups = accums
            .iter()
            .map(|accum| {
                let buffers = [
                    &params, accum, &counters, &tris, &nodes, &env, &grid, &model, &stage, &queue,
                ];
                scene_bind_group(ctx, layout, buffers, i.stage_slots > 0)
            })
            .collect();
        Ok(Self {
            params,
            accums,
            counters,
            stage,
            queue,
            args,
            args_bind_group,
            bind_groups,
            _inputs: vec![tris, nodes, env, grid, model],
        })
    }
}

impl Resources {
    /// A buffer of `bytes` to copy a band's path states to and from.
    pub fn snapshot_buffer(&self, ctx: &GpuContext, bytes: u64) -> wgpu::Buffer {
        ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("accum snapshot"),
            size: bytes.max(16),
            usage: wgpu::BufferUsages::COPY_SRC | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        })
    }

    /// Submits a copy of `bytes` of `src` from `src_at` to `dst` at `dst_at` (ordered with
    /// dispatches).
    pub fn copy(
        &self,
        ctx: &GpuContext,
        (src, src_at): (&wgpu::Buffer, u64),
        (dst, dst_at): (&wgpu::Buffer, u64),
        bytes: u64,
    ) {
        let mut enc = ctx
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: None });
        enc.copy_buffer_to_buffer(src, src_at, dst, dst_at, bytes.max(16));
        ctx.queue.submit([enc.finish()]);
    }

    /// Submits `rounds` turns of the staged render over band `turn.index`: `stage` (the
    /// listed slots to their next ray query or sphere step, queued; in a chunk's first turn,
    /// `turn.first`, every slot of the band, over `turn.groups`), then `trace` (the
    /// queries) and `step` (the sphere steps, ST-CVAE); the next turn's stage lists the
    /// running paths this one queued. The kernels are dispatched indirectly over the slots
    /// they have, from the arguments that `args` writes into the indirect buffer (and
    /// `list_args` before a submission's first turn where `turn.relist`). `args` also
    /// closes the turn: it empties the queues' other copy for the next and sets the pending
    /// counter, so that after the last turn it counts the slots still pending. Four
    /// dispatches a turn: each costs a hardware GPU time whether it has work or not.
    /// Returns the dispatches submitted.
    pub fn staged_rounds(
        &self,
        ctx: &GpuContext,
        k: &StagedKernels,
        turn: Turn,
        rounds: u32,
    ) -> u64 {
        let mut enc = ctx
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: None });
        // One compute pass for the whole submission: wgpu orders its dispatches as it would
        // separate passes (each dispatch is a usage scope of its own, so the indirect
        // arguments written by `args` are visible to the next dispatch), and the host pays
        // for beginning and ending a pass once instead of per dispatch.
        let mut cpass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor::default());
        let mut dispatches = 0;
        let mut counted = |p, groups, bind_group| {
            self.encode(&mut cpass, p, groups, bind_group);
            dispatches += 1;
        };
        let band = &self.bind_groups[turn.index];
        // An arguments' kernel runs in its own bind group (list_args writes only the running
        // paths' arguments, the only ones used before args runs).
        let args = self.args_group();
        for r in 0..rounds {
            if r == 0 && turn.first {
                let groups = Groups::Direct(turn.groups.0, turn.groups.1);
                counted(&k.stage, groups, band);
            } else {
                if r == 0 && turn.relist {
                    counted(&k.list_args, Groups::Direct(1, 1), args);
                }
                counted(&k.stage, Groups::Indirect(STAGE_ARGS_AT), band);
            }
            counted(&k.args, Groups::Direct(1, 1), args);
            counted(&k.trace, Groups::Indirect(QUERY_ARGS_AT), band);
            if let Some(step) = &k.step {
                counted(step, Groups::Indirect(STEP_ARGS_AT), band);
            }
        }
        drop(cpass);
        ctx.queue.submit([enc.finish()]);
        dispatches
    }

    /// Submits one dispatch of `pipeline` over `groups` (x, y) workgroups on these buffers,
    /// with band `band`'s accumulation buffer bound.
    pub fn dispatch(
        &self,
        ctx: &GpuContext,
        pipeline: &wgpu::ComputePipeline,
        groups: (u32, u32),
        band: usize,
    ) {
        let direct = Groups::Direct(groups.0, groups.1);
        self.submit_pass(ctx, pipeline, direct, &self.bind_groups[band]);
    }

    /// The staged render's arguments' bind group.
    fn args_group(&self) -> &wgpu::BindGroup {
        self.args_bind_group
            .as_ref()
            .expect("a staged render's resources have the arguments' bind group")
    }

    /// Submits one dispatch of one workgroup of the staged render's arguments' kernel
    /// `pipeline` (in its own bind group).
    pub fn dispatch_args_kernel(&self, ctx: &GpuContext, pipeline: &wgpu::ComputePipeline) {
        self.submit_pass(ctx, pipeline, Groups::Direct(1, 1), self.args_group());
    }

    /// Submits one compute pass of `pipeline` with `bind_group`.
    fn submit_pass(
        &self,
        ctx: &GpuContext,
        pipeline: &wgpu::ComputePipeline,
        groups: Groups,
        bind_group: &wgpu::BindGroup,
    ) {
        let mut enc = ctx
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: None });
        let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor::default());
        self.encode(&mut pass, pipeline, groups, bind_group);
        drop(pass);
        ctx.queue.submit([enc.finish()]);
    }

    /// Encodes a dispatch of `pipeline` with `bind_group` into `pass`.
    fn encode(
        &self,
        pass: &mut wgpu::ComputePass,
        pipeline: &wgpu::ComputePipeline,
        groups: Groups,
        bind_group: &wgpu::BindGroup,
    ) {
        pass.set_pipeline(pipeline);
        pass.set_bind_group(0, bind_group, &[]);
        match groups {
            Groups::Direct(x, y) => pass.dispatch_workgroups(x, y, 1),
            Groups::Indirect(at) => pass.dispatch_workgroups_indirect(&self.args, at),
        }
    }
}

/// A dispatch's workgroups: (x, y), or read from the staged render's argument buffer at a
/// byte offset.
#[derive(Clone, Copy)]
enum Groups {
    Direct(u32, u32),
    Indirect(u64),
}

/// The staged render's kernels (gpu/renderer.rs; shaders/path.wgsl).
pub struct StagedKernels {
    pub stage: wgpu::ComputePipeline,
    pub trace: wgpu::ComputePipeline,
    pub args: wgpu::ComputePipeline,
    pub list_args: wgpu::ComputePipeline,
    /// The parked sphere steps (ST-CVAE's kernel, [`super::kernels::KernelShape::steps`]).
    pub step: Option<wgpu::ComputePipeline>,
}

/// What one submission of the staged render covers: the band's bind group (`index`), its
/// workgroups for a direct dispatch over all its slots, whether it starts a chunk, and
/// whether its first turn recomputes the running paths' arguments from the list
/// (`relist`: where a snapshot may have restored the queues since `args` wrote them).
#[derive(Clone, Copy)]
pub struct Turn {
    pub index: usize,
    pub groups: (u32, u32),
    pub first: bool,
    pub relist: bool,
}

/// The most bytes [`read_back`] stages at a time. An image's band is up to the binding
/// limit (~0.9 GB on hardware GPUs) and was staged whole: a second band-sized allocation in
/// host-visible memory after the render, and on lavapipe, where GPU buffers are host
/// memory, a third copy of the band beside the buffer and the bytes returned.
pub const READ_PIECE: u64 = 64 << 20;

/// Copies `size` bytes of `buf` to the host (blocking), [`READ_PIECE`] bytes at a time.
pub fn read_back(ctx: &GpuContext, buf: &wgpu::Buffer, size: u64) -> Result<Vec<u8>, RenderError> {
    read_back_in_pieces(ctx, buf, size, READ_PIECE)
}

/// As [`read_back`], through one staging buffer of at most `piece` bytes (rounded up to
/// wgpu's map alignment) that is filled, mapped and read once per piece; one such buffer a
/// call (the final read-back makes one a band of the image). `size` is a
/// multiple of 4, as every buffer of f32s and u32s is (wgpu copies whole words); any other
/// is refused.
///
/// The staging buffer is made inside an out-of-memory scope: a failed allocation is this
/// device's limit, said in one line, not an invalid buffer whose map fails later.
pub fn read_back_in_pieces(
    ctx: &GpuContext,
    buf: &wgpu::Buffer,
    size: u64,
    piece: u64,
) -> Result<Vec<u8>, RenderError> {
    if !size.is_multiple_of(wgpu::COPY_BUFFER_ALIGNMENT) {
        return Err(RenderError::Gpu(format!(
            "a read-back of {size} bytes, not whole 4-byte words (a bug in stcvae)"
        )));
    }
    if size == 0 {
        return Ok(Vec::new());
    }
    let piece = piece
        .max(1)
        .next_multiple_of(wgpu::MAP_ALIGNMENT)
        .min(size.next_multiple_of(wgpu::MAP_ALIGNMENT))
        .max(wgpu::MAP_ALIGNMENT);
    let scope = ctx.device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
    let staging = staging_buffer(ctx, piece);
    if let Some(e) = pollster::block_on(scope.pop()) {
        return Err(RenderError::GpuLimit(format!(
            "{} is out of memory for the {} MB buffer that reads the results back: {}; use \
             --device cpu",
            ctx.adapter.name,
            piece.div_ceil(1_000_000),
            super::context::one_line(&e.to_string())
        )));
    }
    let mut data = Vec::with_capacity(size as usize);
    let mut at = 0;
    while at < size {
        let n = (size - at).min(piece);
        let (submission, mapped) = copy_and_map(ctx, buf, at, &staging, n);
        Readback::wait_mapped(ctx, &staging, submission, &mapped, n, |bytes| {
            data.extend_from_slice(bytes)
        })?;
        at += n;
    }
    Ok(data)
}

/// A copy of a buffer on its way to the host: submitted after everything submitted before
/// it, not yet waited for.
pub struct Readback {
    staging: wgpu::Buffer,
    submission: wgpu::SubmissionIndex,
    mapped: mpsc::Receiver<Result<(), wgpu::BufferAsyncError>>,
}

/// Submits a copy of `size` bytes of `buf` for the host to read once the GPU gets there.
pub fn start_read_back(ctx: &GpuContext, buf: &wgpu::Buffer, size: u64) -> Readback {
    let staging = staging_buffer(ctx, size);
    let (submission, mapped) = copy_and_map(ctx, buf, 0, &staging, size);
    Readback {
        staging,
        submission,
        mapped,
    }
}

/// A buffer of `size` bytes the host can map to read what a copy put there.
fn staging_buffer(ctx: &GpuContext, size: u64) -> wgpu::Buffer {
    ctx.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("readback"),
        size,
        usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    })
}

/// Submits a copy of `n` bytes of `buf` from byte `at` to the start of `staging`, and asks
/// for those bytes of `staging` to be mapped once the copy is done; the receiver gets the
/// mapping's outcome.
fn copy_and_map(
    ctx: &GpuContext,
    buf: &wgpu::Buffer,
    at: u64,
    staging: &wgpu::Buffer,
    n: u64,
) -> (
    wgpu::SubmissionIndex,
    mpsc::Receiver<Result<(), wgpu::BufferAsyncError>>,
) {
    let mut enc = ctx
        .device
        .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: None });
    enc.copy_buffer_to_buffer(buf, at, staging, 0, n);
    let submission = ctx.queue.submit([enc.finish()]);
    let (tx, mapped) = mpsc::channel();
    staging.map_async(wgpu::MapMode::Read, ..n, move |r| {
        let _ = tx.send(r);
    });
    (submission, mapped)
}

impl Readback {
    /// Waits for the copy (and what was submitted before it, not after) and returns the
    /// bytes.
    pub fn finish(self, ctx: &GpuContext) -> Result<Vec<u8>, RenderError> {
        let size = self.staging.size();
        let mut data = Vec::new();
        Self::wait_mapped(
            ctx,
            &self.staging,
            self.submission,
            &self.mapped,
            size,
            |b| data = b.to_vec(),
        )?;
        Ok(data)
    }

    /// Waits for `submission` and the mapping of `staging`'s first `size` bytes, hands them
    /// to `take` and unmaps `staging` for its next use.
    fn wait_mapped(
        ctx: &GpuContext,
        staging: &wgpu::Buffer,
        submission: wgpu::SubmissionIndex,
        mapped: &mpsc::Receiver<Result<(), wgpu::BufferAsyncError>>,
        size: u64,
        take: impl FnOnce(&[u8]),
    ) -> Result<(), RenderError> {
        let failed = |e: &dyn std::fmt::Display| {
            RenderError::Gpu(format!("reading GPU results failed: {e}"))
        };
        ctx.poll(wgpu::PollType::Wait {
            submission_index: Some(submission),
            timeout: None,
        })?;
        match mapped.recv() {
            Ok(Ok(())) => {}
            Ok(Err(e)) => return Err(failed(&e)),
            Err(e) => return Err(failed(&e)),
        }
        let view = staging.get_mapped_range(..size).map_err(|e| failed(&e))?;
        take(&view);
        drop(view);
        staging.unmap();
        Ok(())
    }
}

/// Blocks until the queue is idle.
pub fn wait(ctx: &GpuContext) -> Result<(), RenderError> {
    ctx.poll(wgpu::PollType::wait_indefinitely())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gpu::context::AdapterChoice;

    /// `check_binding_sizes` on inputs of the given sizes (no buffer is made).
    fn check(
        ctx: &GpuContext,
        accum_bytes: &[u64],
        env: &[[f32; 4]],
        grid: &[u32],
    ) -> Result<(), RenderError> {
        let params = Params::default();
        let model = ModelParams::default();
        check_binding_sizes(
            ctx,
            &Inputs {
                params: &params,
                accum_bytes,
                nodes: &[],
                tris: &[],
                env,
                grid,
                model: &model,
                stage_slots: 0,
            },
        )
    }

    /// The message of a refusal as beyond the GPU.
    fn refused(r: Result<(), RenderError>) -> String {
        match r {
            Err(RenderError::SceneBeyondGpu(m)) => m,
            other => panic!("not refused as beyond the GPU: {other:?}"),
        }
    }

    /// Inputs that one storage binding cannot hold are refused before any buffer is made,
    /// naming the biggest of them and what would make it smaller; inputs exactly at the
    /// limit bind. (The message once blamed the grid and mesh for an environment map too
    /// large.) Skipped, saying so, only where no Vulkan adapter exists outside CI.
    #[test]
    fn inputs_beyond_the_binding_limit_are_named() {
        let vulkan = Some(wgpu::Backends::VULKAN);
        let mut ctx = match GpuContext::with_backends(AdapterChoice::Any, vulkan) {
            Ok(c) => c,
            Err(RenderError::NoAdapter(e)) => {
                assert!(std::env::var_os("CI").is_none(), "CI must have Vulkan: {e}");
                use std::io::Write;
                let _ = writeln!(
                    std::io::stderr(),
                    "skipping inputs_beyond_the_binding_limit_are_named: {e}"
                );
                return;
            }
            Err(e) => panic!("{e}"),
        };
        // A limit of 1,024 bytes (64 texels of 16 bytes, 256 grid words), so that small
        // inputs reach it; only check_binding_sizes reads it here.
        ctx.limits.max_storage_buffer_binding_size = 1024;
        let texels = |n: usize| vec![[0.0f32; 4]; n];
        // Exactly at the limit: binds.
        assert!(check(&ctx, &[1024], &texels(64), &[0; 256]).is_ok());
        // 65 texels are 1,040 bytes, 16 over.
        let m = refused(check(&ctx, &[16], &texels(65), &[]));
        assert!(
            m.contains("a buffer of 1040 bytes") && m.contains("the environment map"),
            "{m}"
        );
        // Two too large: the grid's 300 words (1,200 bytes) are named, not the map's 1,040.
        let m = refused(check(&ctx, &[16], &texels(65), &[0; 300]));
        assert!(
            m.contains("a buffer of 1200 bytes") && m.contains("the distance grid"),
            "{m}"
        );
        // The largest band is checked, wherever it lies in the list.
        let m = refused(check(&ctx, &[16, 1028], &[], &[]));
        assert!(
            m.contains("a buffer of 1028 bytes") && m.contains("band of samples"),
            "{m}"
        );
    }
}
