//! The GPU render loop: dispatches of a few samples per pixel each (no dispatch runs long
//! enough for a GPU watchdog), counters read back after every dispatch (u32 lo/hi pairs
//! on the GPU, u64 here), the image reduced over lanes in f64 at the end.

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use crate::error::RenderError;
use crate::image_io::RgbImage;
use crate::integrator::{IntegratorKind, IntegratorSettings, PathStats};
use crate::render::{DispatchStats, LaneProfile, RenderOptions, RenderOutput};
use crate::setup::SceneData;

use super::context::GpuContext;
use super::kernels::{self, Kernel, KernelShape, StackMemory};

use super::model_buffers::model_params;
use super::resources::{
    COUNTER_BYTES, Inputs, QUEUE_SLOT_BYTES, Readback, Resources, STAGE_SLOT_BYTES, StagedKernels,
    Turn, read_back, slot, start_read_back, wait,
};
use super::scene_buffers::{
    GpuNode, GpuTri, Params, bvh_depth, env_buffer, geometry_buffers, grid_buffer, scene_params,
};

/// Wall time a chunk of samples aims at (progress, time budget and Ctrl-C are checked
/// between chunks). A chunk takes several dispatches of bounded work each.
const TARGET_CHUNK_SECONDS: f64 = 1.0;

/// Most samples one path slot accumulates (an f32 count; see where `lanes` is chosen).
pub const MAX_SLOT_SAMPLES: u64 = 1 << 24;

/// Bounces each invocation runs per dispatch at first. llvmpipe (lavapipe) stops a shader
/// after 65,535 loop iterations in total, counted per SIMD batch (a loop runs as long as
/// its slowest lane); the loops left in a bounce are BVH traversals and exact sphere steps' walks (~6 an
/// event), the decoders being straight-line code. 64 never ran into it on the bunny
/// ladder; 128 is 8–12 % faster but was cut off on the default bunny once chunks grew to
/// 3 s (more lanes busy in every bounce), and a scene whose exact walks are long (a large
/// `exact_tau` with small g: ~(1 − g)τ²/2 events a walk) is cut off at any budget above a
/// few bounces. So software adapters start at 128 with a snapshot of the path states before
/// every dispatch: a dispatch that hits the limit (counted by the kernel) is undone from the
/// snapshot and redone with half the budget, down to one bounce; the budget reached stays
/// for the rest of the render. The kernel also sees a limit that ran out inside a
/// dispatch's last bounce (path.wgsl, `loop_limit_ran_out`), so at one bounce a cut-off is
/// an error, never a silently shortened path. The image does not depend on the budget, bit
/// for bit: paths resume exactly where they stopped, the free distance of an ST-CVAE path
/// included (tested; until the thirtieth session a resumed path forgot it, and its samples
/// differed). Hardware GPUs have no such limit; 256
/// keeps each dispatch far below watchdogs. `STCVAE_GPU_BOUNCES` sets the first value.
fn bounce_budget(ctx: &GpuContext) -> Result<u32, RenderError> {
    match env_value("STCVAE_GPU_BOUNCES") {
        None => Ok(if ctx.adapter.software { 128 } else { 256 }),
        Some(v) => parse_bounces(&v),
    }
}

/// `STCVAE_GPU_BOUNCES`' value, or the error that names its range.
fn parse_bounces(v: &str) -> Result<u32, RenderError> {
    parse_count("STCVAE_GPU_BOUNCES", v, MAX_BOUNCES, "bounces per dispatch")
}

/// `STCVAE_GPU_LANE_SAMPLES`: the samples every invocation takes per chunk, fixed. Unset,
/// they start at 1 and grow toward [`TARGET_CHUNK_SECONDS`] of work a chunk, so how much a
/// dispatch holds depends on the machine's speed; tests that must reach a software
/// adapter's loop limit fix it instead.
fn fixed_lane_samples() -> Result<Option<u32>, RenderError> {
    env_value("STCVAE_GPU_LANE_SAMPLES").map_or(Ok(None), |v| parse_lane_samples(&v))
}

fn parse_lane_samples(v: &str) -> Result<Option<u32>, RenderError> {
    parse_count(
        "STCVAE_GPU_LANE_SAMPLES",
        v,
        MAX_LANE_SAMPLES,
        "samples per invocation and chunk",
    )
    .map(Some)
}

/// The kernels' shape from `STCVAE_GPU_WORKGROUP` (threads per workgroup) and
/// `STCVAE_GPU_STACK` (`workgroup` or `private`), each [`KernelShape::default`]'s when
/// unset. For measuring on hardware GPUs: the image does not depend on them. (Also the
/// test hook `STCVAE_GPU_TEST_UNWRITTEN_PIXEL`, [`KernelShape::unwritten_pixel`], which
/// makes the render fail, `STCVAE_GPU_TEST_DISPATCH_ROW`, [`KernelShape::dispatch_row`],
/// `STCVAE_GPU_TEST_CUT_OFFS`, [`KernelShape::cut_offs`], and
/// `STCVAE_GPU_TEST_BAND_SLOTS`, [`KernelShape::band_slots`].)
pub fn kernel_shape() -> Result<KernelShape, RenderError> {
    let mut shape = KernelShape::default();
    if let Some(v) = env_value("STCVAE_GPU_WORKGROUP") {
        shape.workgroup = v
            .trim()
            .parse::<u32>()
            .ok()
            .filter(|n| KernelShape::WORKGROUPS.contains(n))
            .ok_or_else(|| {
                RenderError::Gpu(format!(
                    "STCVAE_GPU_WORKGROUP={v:?} is out of range: allowed {:?} threads per \
                     workgroup (unset it for the default, {})",
                    KernelShape::WORKGROUPS,
                    shape.workgroup
                ))
            })?;
    }
    // The switches: (variable, field, what 1 means).
    let switches = [
        (
            "STCVAE_GPU_PROFILE",
            &mut shape.profile,
            "count the SIMD lanes busy in each phase of the kernel",
        ),
        (
            "STCVAE_GPU_STAGED",
            &mut shape.staged,
            "render in kernels taking turns: paths to their next ray query or sphere step, \
             then the queued queries traced and steps run",
        ),
        (
            "STCVAE_GPU_STAGED_STEPS",
            &mut shape.steps,
            "the staged render runs the sphere steps in their own kernel (the default)",
        ),
        (
            "STCVAE_GPU_AGGREGATE",
            &mut shape.aggregate,
            "add to counters and queues once per subgroup where the adapter has subgroup \
             operations",
        ),
        (
            "STCVAE_GPU_STAGED_AHEAD",
            &mut shape.ahead,
            "the staged render sends each submission of turns before waiting for the last \
             one's counters (the default)",
        ),
    ];
    // An empty value is unset (the default): `STCVAE_GPU_STAGED_AHEAD=` turned a
    // default-on switch off.
    for (name, field, what) in switches {
        if let Some(v) = env_value(name) {
            *field = parse_switch(name, &v, what)?;
        }
    }
    if let Some(v) = env_value("STCVAE_GPU_TEST_UNWRITTEN_PIXEL") {
        shape.unwritten_pixel = Some(
            v.trim()
                .parse::<u32>()
                .ok()
                .filter(|&p| p < u32::MAX)
                .ok_or_else(|| {
                    RenderError::Gpu(format!(
                        "STCVAE_GPU_TEST_UNWRITTEN_PIXEL={v:?} is not a pixel index (a test \
                         hook: unset it)"
                    ))
                })?,
        );
    }
    if let Some(v) = env_value("STCVAE_GPU_TEST_DISPATCH_ROW") {
        shape.dispatch_row = v
            .trim()
            .parse::<u32>()
            .ok()
            .filter(|n| (1..=kernels::DISPATCH_ROW).contains(n))
            .ok_or_else(|| {
                RenderError::Gpu(format!(
                    "STCVAE_GPU_TEST_DISPATCH_ROW={v:?} is out of range: allowed 1 to {} \
                     workgroups a row (a test hook: unset it)",
                    kernels::DISPATCH_ROW
                ))
            })?;
    }
    if let Some(v) = env_value("STCVAE_GPU_TEST_CUT_OFFS") {
        shape.cut_offs = v
            .trim()
            .parse::<u32>()
            .ok()
            // More could never act: the budget, at most 65,535, halves to 1, where no
            // snapshot is kept, within 16 redos.
            .filter(|n| *n <= 16)
            .ok_or_else(|| {
                RenderError::Gpu(format!(
                    "STCVAE_GPU_TEST_CUT_OFFS={v:?} is out of range: allowed 0 to 16 \
                     dispatches (a test hook: unset it)"
                ))
            })?;
    }
    if let Some(v) = env_value("STCVAE_GPU_TEST_BAND_SLOTS") {
        shape.band_slots = Some(parse_count(
            "STCVAE_GPU_TEST_BAND_SLOTS",
            &v,
            HARDWARE_BAND_SLOTS as u32,
            "path slots a band, a test hook",
        )?);
    }
    if let Some(v) = env_value("STCVAE_GPU_STACK") {
        shape.stack = parse_choice(
            "STCVAE_GPU_STACK",
            &v,
            &[
                ("workgroup", StackMemory::Workgroup),
                ("private", StackMemory::Private),
            ],
            "a stack memory: allowed workgroup or private (unset it for the default, workgroup)",
        )?;
    }
    Ok(shape)
}

/// The switch `name` = `v`: 1 or true (`what`), 0, false or empty.
fn parse_switch(name: &str, v: &str, what: &str) -> Result<bool, RenderError> {
    parse_choice(
        name,
        v,
        &[("1", true), ("true", true), ("0", false), ("false", false)],
        &format!("a switch: allowed 1 or true ({what}), 0 or false, empty for the default"),
    )
}

/// The value `v` of the variable `name` among the named `choices`, or the error that says
/// it is not `what`.
fn parse_choice<T: Copy>(
    name: &str,
    v: &str,
    choices: &[(&str, T)],
    what: &str,
) -> Result<T, RenderError> {
    choices
        .iter()
        .find(|(word, _)| *word == v.trim())
        .map(|&(_, value)| value)
        .ok_or_else(|| RenderError::Gpu(format!("{name}={v:?} is not {what}")))
}

/// The environment variable `name`, None when unset or empty (`STCVAE_GPU_BOUNCES=` in a
/// script that clears a setting means the default, as a shell's unset would; a value that
/// is not Unicode is passed on lossily, so that the range error shows it).
fn env_value(name: &str) -> Option<String> {
    match std::env::var(name) {
        Ok(v) if v.trim().is_empty() => None,
        Ok(v) => Some(v),
        Err(std::env::VarError::NotPresent) => None,
        Err(std::env::VarError::NotUnicode(v)) => Some(v.to_string_lossy().into_owned()),
    }
}

/// A whole number in 1..=`max` from the variable `name`, or the error that names it, its
/// range and its `unit`.
fn parse_count(name: &str, v: &str, max: u32, unit: &str) -> Result<u32, RenderError> {
    v.trim()
        .parse::<u32>()
        .ok()
        .filter(|n| (1..=max).contains(n))
        .ok_or_else(|| {
            RenderError::Gpu(format!(
                "{name}={v:?} is out of range: allowed 1 to {max} {unit} (unset it for the default)"
            ))
        })
}

/// The most samples an invocation may take in one chunk (a chunk's sample range is u32).
const MAX_LANE_SAMPLES: u32 = 65_536;

/// The most path slots a software adapter's dispatch covers (more render in bands): lavapipe
/// on 2 cores runs 65,536 ST-CVAE paths in ~1 s, PT's in ~5 s (k = 1, 2026-11-27). A
/// dispatch cannot be interrupted, so this bounds how long a stop request waits.
const SOFTWARE_BAND_SLOTS: u64 = 1 << 16;

/// The most path slots a hardware GPU's dispatch covers. A band was as large as a storage
/// binding allows: 16.8 M slots for a 4096² PT render, 16× the 2^20 invocations that the
/// bounce budget's "far below watchdogs" was reckoned for (an H100's PT at k = 8, ~10⁹
/// events/s, would take ~4 s a dispatch, beyond Windows' 2 s watchdog, and a stop request
/// would wait as long).
const HARDWARE_BAND_SLOTS: u64 = 1 << 22;

/// The most path slots a dispatch covers: a `software` or hardware adapter's cap
/// ([`SOFTWARE_BAND_SLOTS`], [`HARDWARE_BAND_SLOTS`]), or less where the test hook
/// [`KernelShape::band_slots`] (`hook`) asks.
fn band_cap(software: bool, hook: Option<u32>) -> u64 {
    let cap = if software {
        SOFTWARE_BAND_SLOTS
    } else {
        HARDWARE_BAND_SLOTS
    };
    hook.map_or(cap, |n| cap.min(n as u64))
}

/// Rows of `row_slots` path slots a band holds: what one binding of `fit` slots takes, at
/// most the image's `height`, and no more than the per-dispatch `cap` ([`band_cap`])
/// allows but one row; 0 where not even a row fits a binding.
fn band_rows(fit: u64, row_slots: u64, height: u32, cap: u64) -> u32 {
    let rows = fit / row_slots;
    rows.min((cap / row_slots).max(1)).min(height as u64) as u32
}

/// The most bounces a dispatch may be given: lavapipe's loop limit, which every bounce
/// takes at least one iteration of. Hardware GPUs gained < 6 % from 256 to 1024.
const MAX_BOUNCES: u32 = 65_535;

/// Invocations a dispatch aims to have in flight: a big GPU needs ~10⁶ to be busy; a
/// software adapter gains nothing beyond a few per core.
fn target_threads(ctx: &GpuContext) -> u64 {
    if ctx.adapter.software {
        1 << 12
    } else {
        1 << 20
    }
}

/// The stride of the workgroup → tile permutation (shaders/path.wgsl, render_main): near
/// n·(√5 − 1)/2, so consecutive workgroups land far apart, and coprime with n, so the map
/// w ↦ w·P mod n is a bijection. Kept below 2^24 to travel exactly as an f32.
fn tile_stride(n: u64) -> u64 {
    fn gcd(a: u64, b: u64) -> u64 {
        if b == 0 { a } else { gcd(b, a % b) }
    }
    if n <= 2 {
        return 1;
    }
    let mut p = ((n as f64 * 0.618_034) as u64).clamp(1, (1 << 24) - 1);
    while gcd(p, n) != 1 {
        p -= 1;
    }
    p
}

/// Has the driver compile `pipeline` now, outside the render's clock, and returns how long
/// that took. llvmpipe (lavapipe) compiles a pipeline at its first dispatch, not when it is
/// created: on a cold shader cache 1–4 s (Mesa 22) to 6–19 s (Mesa 25) for the default
/// scene's kernels, which the first chunk's time, the paths/s and a `--time-budget` would
/// otherwise count. The dispatch is empty: with a zero image height no workgroup has a tile
/// (`render_main` returns at once), so no buffer is touched, but for the staged render's
/// arguments' kernels (`args_kernel`), which close a turn over empty queues.
fn compile(
    ctx: &GpuContext,
    res: &Resources,
    pipeline: &wgpu::ComputePipeline,
    params: &Params,
    args_kernel: bool,
) -> Result<f64, RenderError> {
    let t0 = Instant::now();
    let mut empty = *params;
    empty.image[1] = 0;
    ctx.queue
        .write_buffer(&res.params, 0, bytemuck::bytes_of(&empty));
    if args_kernel {
        res.dispatch_args_kernel(ctx, pipeline);
    } else {
        res.dispatch(ctx, pipeline, (1, 1), 0);
    }
    wait(ctx)?;
    Ok(t0.elapsed().as_secs_f64())
}

/// One band of rows of the image: its first row and count, its workgroups and the stride
/// of their scattered order, and its accumulation buffer (index and size).
struct Band {
    index: usize,
    row0: u32,
    rows: u32,
    groups: (u32, u32),
    stride: f32,
    bytes: u64,
}

/// Turns of the staged render per submission: the pending count is read back after each
/// submission; turns after the chunk's last path ended dispatch nothing (their queues are
/// empty). `STCVAE_GPU_STAGED_ROUNDS` sets it (1 to [`MAX_STAGED_ROUNDS`]), for measuring
/// what the readbacks cost on hardware.
const STAGED_ROUNDS: u32 = 8;
const MAX_STAGED_ROUNDS: u32 = 4096;

fn staged_rounds() -> Result<u32, RenderError> {
    env_value("STCVAE_GPU_STAGED_ROUNDS").map_or(Ok(STAGED_ROUNDS), |v| {
        parse_count(
            "STCVAE_GPU_STAGED_ROUNDS",
            &v,
            MAX_STAGED_ROUNDS,
            "turns of the staged render per submission",
        )
    })
}

/// A render's kernels: the single kernel (`render_main`), or the staged render's.
enum Kernels {
    Single(wgpu::ComputePipeline),
    Staged(StagedKernels),
}

/// The path states before the dispatch in flight (software adapters): the accumulation
/// slots, and a staged render's records and queues.
struct Snapshot {
    accum: wgpu::Buffer,
    staged: Option<[wgpu::Buffer; 2]>,
}

impl Snapshot {
    /// The staged render's buffers paired with their copies here.
    fn staged_pairs<'a>(
        &'a self,
        res: &'a Resources,
    ) -> impl Iterator<Item = (&'a wgpu::Buffer, &'a wgpu::Buffer)> {
        let live = [&res.stage, &res.queue];
        self.staged.iter().flatten().zip(live)
    }

    /// Copies `band`'s path states (and the staged render's records) here.
    fn save(&self, ctx: &GpuContext, res: &Resources, band: &Band) {
        res.copy(
            ctx,
            (&res.accums[band.index], 0),
            (&self.accum, 0),
            band.bytes,
        );
        for (copy, live) in self.staged_pairs(res) {
            res.copy(ctx, (live, 0), (copy, 0), copy.size());
        }
    }

    /// Puts back what [`Self::save`] copied, undoing the dispatches since.
    fn restore(&self, ctx: &GpuContext, res: &Resources, band: &Band) {
        res.copy(
            ctx,
            (&self.accum, 0),
            (&res.accums[band.index], 0),
            band.bytes,
        );
        for (copy, live) in self.staged_pairs(res) {
            res.copy(ctx, (copy, 0), (live, 0), copy.size());
        }
    }
}

/// What every dispatch of a render uses.
struct Dispatcher<'a> {
    ctx: &'a GpuContext,
    res: &'a Resources,
    kernels: &'a Kernels,
    snapshot: Option<&'a Snapshot>,
    /// The staged render's turns per submission after a chunk's first.
    rounds: u32,
    /// Whether each submission goes out before the host waits for the counters of the one
    /// before (one in flight ahead), so that the GPU need not idle while the host encodes
    /// the next turns and reads the pending count: a staged render ([`KernelShape::ahead`])
    /// without a snapshot to undo from.
    ahead: bool,
    /// A stop request, looked at after each submission.
    cancel: &'a AtomicBool,
    /// The test hook's cut-offs still to pretend ([`KernelShape::cut_offs`]).
    pretended_cut_offs: std::cell::Cell<u32>,
}

impl Dispatcher<'_> {
    /// Encodes and submits one dispatch of `band` (the staged render: one turn when it is
    /// a chunk's `first`, whose dispatch kind params holds, else `rounds` turns).
    fn submit(&self, band: &Band, first: bool, dispatch: &mut DispatchStats) {
        let (ctx, res) = (self.ctx, self.res);
        let encoding = Instant::now();
        match self.kernels {
            Kernels::Staged(staged) => {
                let rounds = if first { 1 } else { self.rounds };
                let turn = Turn {
                    index: band.index,
                    groups: band.groups,
                    first,
                    relist: self.snapshot.is_some(),
                };
                dispatch.dispatches += res.staged_rounds(ctx, staged, turn, rounds);
            }
            Kernels::Single(pipeline) => {
                res.dispatch(ctx, pipeline, band.groups, band.index);
                dispatch.dispatches += 1;
            }
        }
        dispatch.host_encode_us += encoding.elapsed().as_micros() as u64;
    }

    /// Dispatches the chunk of samples in `params` over `band` until no path of it is
    /// pending (`first`: the render's first chunk, whose first dispatch clears the
    /// accumulator). A dispatch cut off by a software adapter's loop limit (or pretended
    /// so, [`KernelShape::cut_offs`]) is undone from the snapshot and redone with half the
    /// `budget`, which stays halved for the rest of the render. Returns false, with
    /// nothing left in flight, when `cancel` was set before the chunk finished: the band's
    /// paths are then left where they were.
    fn run_band(
        &self,
        band: &Band,
        first: bool,
        params: &mut Params,
        budget: &mut u32,
        stats: &mut PathStats,
        dispatch: &mut DispatchStats,
    ) -> Result<bool, RenderError> {
        let Self {
            ctx,
            res,
            snapshot,
            ahead,
            cancel,
            ..
        } = *self;
        params.image[1] = band.rows;
        params.cam_right[3] = band.row0 as f32;
        params.consts2[3] = band.stride;
        // Dispatch kind: 2: first dispatch of the render, 1: of a chunk, 0: resume.
        params.misc[3] = if first { 2 } else { 1 };
        let mut in_flight: Option<Readback> = None;
        loop {
            ctx.queue
                .write_buffer(&res.params, 0, bytemuck::bytes_of(params));
            ctx.queue
                .write_buffer(&res.counters, 0, &[0u8; COUNTER_BYTES as usize]);
            let snap = snapshot.filter(|_| *budget > 1);
            if let Some(snap) = snap {
                snap.save(ctx, res, band);
            }
            self.submit(band, params.misc[3] != 0, dispatch);
            let mut read = start_read_back(ctx, &res.counters, COUNTER_BYTES);
            if ahead {
                // The counters of the submission before this one, if any: this one is
                // already on its way.
                match in_flight.replace(read) {
                    Some(before) => read = before,
                    None => {
                        params.misc[3] = 0;
                        continue;
                    }
                }
            }
            let c = wait_for(ctx, read, dispatch)?;
            let pair = |k: u64| counter(&c, k);
            if let Some(snap) = snap
                && (pair(slot::TRUNCATED) > 0 || (params.misc[3] == 0 && self.pretend_cut_off()))
            {
                // Undo the cut-off dispatch and redo it with half the budget.
                snap.restore(ctx, res, band);
                dispatch.redone += 1;
                *budget /= 2;
                params.consts2[2] = *budget as f32;
                continue;
            }
            // Counted once a dispatch stands (an undone one is not).
            tally(ctx, &c, *budget, stats, dispatch)?;
            params.misc[3] = 0;
            if pair(slot::PENDING) == 0 {
                // The submission sent ahead ran its turns over empty queues; its counters
                // are read all the same, so that nothing it did goes uncounted.
                if let Some(last) = in_flight.take() {
                    let c = wait_for(ctx, last, dispatch)?;
                    tally(ctx, &c, *budget, stats, dispatch)?;
                }
                return Ok(true);
            }
            if cancel.load(Ordering::Relaxed) {
                // The chunk is dropped; what was sent ahead only runs on into ACC.
                if let Some(last) = in_flight.take() {
                    wait_for(ctx, last, dispatch)?;
                }
                return Ok(false);
            }
        }
    }

    /// Whether the test hook pretends this dispatch was cut off (one of its cut-offs used).
    fn pretend_cut_off(&self) -> bool {
        let left = self.pretended_cut_offs.get();
        self.pretended_cut_offs.set(left.saturating_sub(1));
        left > 0
    }
}

/// The bytes of `read`, the host's wait for them counted in `dispatch.host_wait_us`.
fn wait_for(
    ctx: &GpuContext,
    read: Readback,
    dispatch: &mut DispatchStats,
) -> Result<Vec<u8>, RenderError> {
    let waiting = Instant::now();
    let bytes = read.finish(ctx)?;
    dispatch.host_wait_us += waiting.elapsed().as_micros() as u64;
    Ok(bytes)
}

/// Counter slot `k` (a lo/hi pair of u32 words) of the counters `c` read back.
fn counter(c: &[u8], k: u64) -> u64 {
    let k = k as usize;
    let word = |i: usize| u32::from_le_bytes(c[4 * i..4 * i + 4].try_into().unwrap()) as u64;
    word(2 * k) | (word(2 * k + 1) << 32)
}

/// Adds the counters `c` of a submission that stands to the render's path statistics and
/// lane profile; invocations stopped by the adapter's loop limit (at `budget` bounces a
/// dispatch) are an error.
fn tally(
    ctx: &GpuContext,
    c: &[u8],
    budget: u32,
    stats: &mut PathStats,
    dispatch: &mut DispatchStats,
) -> Result<(), RenderError> {
    let pair = |k: u64| counter(c, k);
    if let Some(lanes) = &mut dispatch.lanes {
        for (i, p) in lanes.phases.iter_mut().enumerate() {
            let k = super::resources::PATH_COUNTERS + 3 * i as u64;
            p.active += pair(k);
            p.capacity += pair(k + 1);
            p.passes += pair(k + 2);
        }
    }
    stats.add(&PathStats {
        paths: pair(slot::PATHS),
        events: pair(slot::EVENTS),
        steps: pair(slot::STEPS),
        leaks: pair(slot::LEAKS),
        capped: pair(slot::CAPPED),
        non_finite: pair(slot::NON_FINITE),
        exact_steps: pair(slot::EXACT),
        exact_events: pair(slot::EXACT_EVENTS),
    });
    if pair(slot::TRUNCATED) > 0 {
        let hint = if budget > 1 {
            format!("set STCVAE_GPU_BOUNCES below {budget}")
        } else {
            // One bounce's loops: exact walks (exact_tau; past MODEL_MAX_G every step is
            // exact, and only max_tau bounds a walk: a hint of exact_tau alone sent users
            // to a setting with no effect there), or hit tests over a coarse grid cell's
            // long triangle list (a fine mesh under a low grid_resolution).
            format!(
                "a single bounce exceeded it: lower render.exact_tau (render.max_tau where \
                 |medium.g| > {}: every step is exact there), raise render.grid_resolution",
                crate::scene::MODEL_MAX_G
            )
        };
        return Err(RenderError::Gpu(format!(
            "{} invocations were stopped by {}'s loop limit (lavapipe stops a shader \
             after 65,535 loop iterations); {hint} or use --device cpu",
            pair(slot::TRUNCATED),
            ctx.adapter.name,
        )));
    }
    Ok(())
}

/// The bands of rows an image is rendered in, one after another within every chunk of
/// samples, each with its own accumulation buffer of `slot_bytes` a path slot (`lanes`
/// slots a pixel), at most `cap` slots a band ([`band_cap`]). An image whose slots exceed
/// one binding (`fit` slots; lavapipe's 128 MiB holds 0.76–1.2 M pixels, 0.6–0.84 M with
/// the variance's squares) takes several. Seeds follow the pixel's index in the image, so
/// a band renders what the whole image would. A software adapter also bands an image of
/// more than
/// [`SOFTWARE_BAND_SLOTS`] slots, so that a dispatch stays short enough for a stop
/// request, answered between dispatches, to be answered within seconds.
fn plan_bands(
    ctx: &GpuContext,
    cam: &crate::camera::Camera,
    lanes: u32,
    (fit, cap): (u64, u64),
    binding_bytes: u64,
    slot_bytes: u64,
    shape: &KernelShape,
) -> Result<Vec<Band>, RenderError> {
    let row_slots = cam.width as u64 * lanes as u64;
    let band_rows = band_rows(fit, row_slots, cam.height, cap);
    if band_rows == 0 {
        return Err(RenderError::SceneBeyondGpu(format!(
            "one row of {} pixels needs {} bytes of path state, over {}'s storage binding \
             limit of {} bytes; use --device cpu",
            cam.width,
            cam.width as u64 * binding_bytes,
            ctx.adapter.name,
            ctx.limits.max_storage_buffer_binding_size
        )));
    }
    (0..cam.height)
        .step_by(band_rows as usize)
        .enumerate()
        .map(|(index, row0)| {
            let rows = band_rows.min(cam.height - row0);
            let threads = cam.width as u64 * rows as u64 * lanes as u64;
            // Workgroups as (x, y): rows of `dispatch_row` (65,535, the most a dimension
            // allows, unless a test lowers it).
            let groups = threads.div_ceil(shape.workgroup as u64);
            let row = shape.dispatch_row as u64;
            let grid = if groups <= row {
                (groups as u32, 1)
            } else {
                (row as u32, groups.div_ceil(row))
            };
            if grid.1 > kernels::DISPATCH_ROW as u64 {
                return Err(RenderError::Gpu(format!(
                    "a band of {groups} workgroups takes {} rows of {row} \
                     (STCVAE_GPU_TEST_DISPATCH_ROW), over the {} a dispatch allows",
                    grid.1,
                    kernels::DISPATCH_ROW
                )));
            }
            Ok(Band {
                index,
                row0,
                rows,
                groups: (grid.0, grid.1 as u32),
                stride: tile_stride(groups) as f32,
                bytes: threads * slot_bytes,
            })
        })
        .collect()
}

/// Poisons the accumulation buffers: a pixel the kernel never wrote stays NaN and is
/// reported when the image is read back ([`SlotReadout::read`]) instead of passing as
/// black. A piece at a time, each submitted and
/// waited for: wgpu keeps every write's staging copy until a submission completes, and
/// written whole those copies doubled the host memory of the largest images (on
/// lavapipe, where the buffers are host memory too, ~190 bytes a pixel instead of ~95).
fn poison(
    ctx: &GpuContext,
    accums: &[wgpu::Buffer],
    accum_bytes: &[u64],
) -> Result<(), RenderError> {
    const POISON_PIECE: u64 = 64 << 20;
    let largest = accum_bytes.iter().copied().max().unwrap_or(0);
    let nan = vec![0xffu8; POISON_PIECE.min(largest) as usize]; // all-ones f32 bits = NaN
    for (buf, &bytes) in accums.iter().zip(accum_bytes) {
        let mut at = 0;
        while at < bytes {
            let n = (bytes - at).min(POISON_PIECE);
            ctx.queue.write_buffer(buf, at, &nan[..n as usize]);
            ctx.queue.submit([]);
            super::resources::wait(ctx)?;
            at += n;
        }
    }
    Ok(())
}

/// How a render's path slots are laid out and how far it got: what reading them back
/// into images needs.
struct SlotReadout {
    width: u32,
    height: u32,
    lanes: u32,
    slot_vec4s: u64,
    path_nee_m: u32,
    squares_kept: bool,
    /// Whole samples a pixel.
    spp: u32,
    /// The bands that had begun a chunk a stop request dropped (see `render_gpu`).
    dropped: Option<usize>,
    seed: u64,
}

impl SlotReadout {
    /// The image, the variance image (where asked for and `spp` allows) and the work map
    /// from the bands' slots; a pixel unwritten, non-finite or short of `spp` finished
    /// samples is an error.
    fn read(
        &self,
        ctx: &GpuContext,
        res: &Resources,
        bands: &[Band],
    ) -> Result<(RgbImage, Option<RgbImage>, Vec<f32>), RenderError> {
        let pixels = self.width as u64 * self.height as u64;
        let mut image = RgbImage::new(self.width as usize, self.height as usize);
        // Squared sums only where asked and where every channel has two samples, as the CPU
        // renderer gives its variance image (render::MIN_VARIANCE_SPP).
        let mut variance = (self.squares_kept && self.spp >= crate::render::MIN_VARIANCE_SPP)
            .then(|| RgbImage::new(self.width as usize, self.height as usize));
        // Per pixel the PT events + sphere steps a path, as the CPU renderer's `work`.
        let mut work = vec![0f32; pixels as usize];
        // Stopped in the first chunk: no sample is whole (slots of bands not yet reached still
        // hold the poison), so there is no image, as on the CPU.
        let bands = if self.spp == 0 { &[][..] } else { bands };
        let mut bad = 0usize;
        let mut short = 0usize;
        for band in bands {
            let bytes = read_back(ctx, &res.accums[band.index], band.bytes)?;
            // A Vec<u8> need not be aligned for f32s (cast_slice would panic): copied where not.
            let copied: Vec<f32>;
            let vals: &[f32] = match bytemuck::try_cast_slice(&bytes) {
                Ok(v) => v,
                Err(_) => {
                    copied = bytemuck::pod_collect_to_vec(&bytes);
                    &copied
                }
            };
            let committed = self.dropped.is_some_and(|started| band.index < started);
            let vectors = self.band_vectors(committed);
            let first = band.row0 as usize * self.width as usize;
            let count = band.rows as usize * self.width as usize;
            for (p, px) in image.pixels[first..first + count].iter_mut().enumerate() {
                let PixelSlots {
                    sum,
                    squares,
                    finished,
                    events,
                    paths,
                } = self.pixel_slots(vals, p, &vectors, variance.is_some());
                work[first + p] = (events / paths.max(1.0)) as f32;
                if !sum.iter().chain(&squares).all(|v| v.is_finite()) {
                    bad += 1;
                } else if finished != self.spp as f64 {
                    short += 1;
                }
                let pixel = (first + p) as u32;
                *px = crate::render::resolve_pixel(sum, self.spp, self.seed, pixel);
                if let Some(var) = &mut variance {
                    // The slots square the ×3 values they sum (kernels::acc_sq_vec4).
                    let squares = squares.map(|q| q / 9.0);
                    var.pixels[first + p] =
                        crate::render::pixel_variance(sum, squares, self.spp, self.seed, pixel);
                }
            }
        }
        if bad > 0 {
            return Err(RenderError::Gpu(format!(
                "{bad} of {pixels} pixels came back unwritten or non-finite from {}",
                ctx.adapter
            )));
        }
        if short > 0 {
            return Err(RenderError::Gpu(format!(
                "{short} of {pixels} pixels came back with a finished-sample count other than \
                 {} from {}",
                self.spp, ctx.adapter
            )));
        }
        Ok((image, variance, work))
    }

    /// Which vec4s of a band's slots hold its sums. A band whose chunk was dropped
    /// (`committed`) gives back the whole chunks' sums, rounded once to f32; the others their
    /// sums and what those rounded off.
    fn band_vectors(&self, committed: bool) -> BandVectors {
        // The work counts every visit, a dropped chunk's too: read from the live sums'
        // round-off vec4 in either case.
        let acc_lo = kernels::acc_lo_vec4(self.path_nee_m, self.squares_kept);
        if committed {
            BandVectors {
                acc: kernels::committed_vec4(self.path_nee_m, self.squares_kept),
                lo: None,
                squares: [Some(kernels::committed_sq_vec4(self.path_nee_m)), None],
                events: acc_lo,
            }
        } else {
            BandVectors {
                acc: kernels::ACC_VEC4,
                lo: Some(acc_lo),
                squares: [
                    Some(kernels::acc_sq_vec4(self.path_nee_m)),
                    Some(kernels::acc_sq_lo_vec4(self.path_nee_m)),
                ],
                events: acc_lo,
            }
        }
    }

    /// Pixel `p` of a band (`vals`, its slots' floats), summed over its lanes in f64;
    /// the squared sums only `with_squares`.
    fn pixel_slots(
        &self,
        vals: &[f32],
        p: usize,
        vectors: &BandVectors,
        with_squares: bool,
    ) -> PixelSlots {
        // xyz of vec4 `v` of `slot`, added to `to` in f64.
        let add = |to: &mut [f64; 3], slot: usize, v: u64| {
            let q = &vals[(slot + v as usize) * 4..][..3];
            for (t, q) in to.iter_mut().zip(q) {
                *t += *q as f64;
            }
        };
        let mut out = PixelSlots::default();
        for l in 0..self.lanes as usize {
            let slot = (p * self.lanes as usize + l) * self.slot_vec4s as usize;
            for v in std::iter::once(vectors.acc).chain(vectors.lo) {
                add(&mut out.sum, slot, v);
            }
            // The work counts every visit, a dropped chunk's too, so it is read per
            // path over every finished sample (ACC's count), not over the whole chunks'.
            out.events += vals[(slot + vectors.events as usize) * 4 + 3] as f64;
            out.paths += vals[(slot + kernels::ACC_VEC4 as usize) * 4 + 3] as f64;
            if with_squares {
                for v in vectors.squares.into_iter().flatten() {
                    add(&mut out.squares, slot, v);
                }
            }
            out.finished += vals[(slot + vectors.acc as usize) * 4 + 3] as f64;
        }
        out
    }
}

/// The vec4s of a slot that hold a band's sums ([`SlotReadout::band_vectors`]).
struct BandVectors {
    /// The sums, with the finished-sample count in w.
    acc: u64,
    /// What the sums rounded off, where kept.
    lo: Option<u64>,
    /// The squared sums and what they rounded off.
    squares: [Option<u64>; 2],
    /// The vec4 whose w counts the PT events and sphere steps.
    events: u64,
}

/// One pixel's slots summed over its lanes.
#[derive(Default)]
struct PixelSlots {
    sum: [f64; 3],
    squares: [f64; 3],
    /// Finished samples.
    finished: f64,
    /// PT events and sphere steps, and the paths that made them.
    events: f64,
    paths: f64,
}

/// Renders on the GPU with the estimators of the CPU integrators. `progress(done, total)`
/// counts pixel-samples after each band of each chunk; `cancel` stops after the submission
/// under way (and, where the staged render sent one ahead, that one too), dropping the
/// unfinished chunk (the image then holds the chunks completed before, and 0 spp when
/// none was).
pub fn render_gpu(
    ctx: &GpuContext,
    scene: &SceneData,
    set: &IntegratorSettings,
    opts: &RenderOptions,
    progress: &(dyn Fn(u64, u64) + Sync),
    cancel: &AtomicBool,
) -> Result<RenderOutput, RenderError> {
    let kernel = match set.kind {
        IntegratorKind::Pt => Kernel::Pt,
        IntegratorKind::Stcvae => Kernel::Stcvae,
    };
    let model = set.model.map(model_params).unwrap_or_default();
    let shape = kernel_shape()?.on(ctx);
    let cam = &scene.camera;
    let pixels = cam.width as u64 * cam.height as u64;
    check_scene(scene, &shape, pixels)?;
    // Every variable read now, before buffers and the kernels' compilation (seconds to
    // minutes on lavapipe): a bad value was refused only after them.
    let first_budget = bounce_budget(ctx)?;
    let rounds = staged_rounds()?;
    let fixed_per_lane = fixed_lane_samples()?;
    let layout = kernels::bind_group_layout(ctx, shape.staged)?;
    // Path-level NEE (ST-CVAE only, as on the CPU): its reservoirs travel with each path.
    let path_nee_m = set.path_nee() as u32;
    // The variance image's squared sums travel in the slots too (kernels::acc_sq_vec4).
    // (Not where no variance image can come out: fewer spp than it needs, and no budget.)
    let squares_kept = opts.variance
        && (opts.time_budget.is_some() || opts.spp >= crate::render::MIN_VARIANCE_SPP);
    let slot_vec4s = kernels::slot_vec4s(path_nee_m, squares_kept);
    let args_layout = shape.staged.then(|| kernels::args_layout(ctx));
    let build = KernelBuild {
        ctx,
        kernel,
        model: set.model,
        path_nee_m,
        switches: kernels::SceneSwitches {
            variance: squares_kept,
            ..kernels::SceneSwitches::of(scene, set.nee)
        },
        shape,
    };
    let kernels = build.kernels(&layout, args_layout.as_ref())?;
    let slot_bytes = 16 * slot_vec4s;
    let (lanes, spp, bands) = plan_slots(ctx, cam, &shape, slot_bytes, opts)?;
    let accum_bytes: Vec<u64> = bands.iter().map(|b| b.bytes).collect();
    // The staged render's records serve every band in turn.
    let largest_slots = accum_bytes.iter().copied().max().unwrap_or(0) / slot_bytes;
    let mut params: Params = scene_params(scene, set, opts.seed);
    let arrays = SceneArrays::of(scene)?;
    let inputs = Inputs {
        params: &params,
        accum_bytes: &accum_bytes,
        nodes: &arrays.nodes,
        tris: &arrays.tris,
        env: &arrays.env,
        grid: &arrays.grid,
        model: &model,
        stage_slots: if shape.staged { largest_slots } else { 0 },
    };
    let (res, snapshot) = upload(
        ctx,
        &layout,
        args_layout.as_ref(),
        &inputs,
        shape.staged,
        first_budget,
        pixels,
    )?;
    let mut budget = first_budget;
    params.consts2[2] = budget as f32;
    let compile_seconds = compile_kernels(ctx, &res, &kernels, &params)?;
    let gpu = Dispatcher {
        ctx,
        res: &res,
        kernels: &kernels,
        snapshot: snapshot.as_ref(),
        rounds,
        ahead: shape.ahead && shape.staged && snapshot.is_none(),
        cancel,
        pretended_cut_offs: shape.cut_offs.into(),
    };
    let mut dispatch = first_dispatch_stats(&shape, &bands, &kernels, gpu.ahead);
    let plan = ChunkPlan {
        lanes,
        spp,
        fixed_per_lane,
        pixels,
        width: cam.width,
        time_budget: opts.time_budget,
        progress,
    };
    let Chunks {
        spp: s0,
        dropped,
        kept_seconds,
        start,
        stats,
    } = gpu.render_chunks(&bands, &plan, &mut params, &mut budget, &mut dispatch)?;
    wait(ctx)?;
    let readout = SlotReadout {
        width: cam.width,
        height: cam.height,
        lanes,
        slot_vec4s,
        path_nee_m,
        squares_kept,
        spp: s0,
        dropped,
        seed: opts.seed,
    };
    let (image, variance, work) = readout.read(ctx, &res, &bands)?;
    Ok(RenderOutput {
        image,
        spp: s0,
        seconds: if dropped.is_some() && s0 > 0 {
            kept_seconds
        } else {
            start.elapsed().as_secs_f64()
        },
        compile_seconds,
        stats,
        work,
        dispatch: DispatchStats {
            bounce_budget: budget,
            ..dispatch
        },
        variance,
    })
}

/// Refuses a scene the kernels cannot take (too many lights, a BVH deeper than their
/// traversal stack) and a test hook that misses the image, before any buffer is made or
/// kernel compiled.
fn check_scene(scene: &SceneData, shape: &KernelShape, pixels: u64) -> Result<(), RenderError> {
    if scene.lights.len() > super::scene_buffers::MAX_GPU_LIGHTS {
        return Err(RenderError::SceneBeyondGpu(format!(
            "the GPU kernels take at most {} [[light]] entries (the scene has {}); use \
             --device cpu",
            super::scene_buffers::MAX_GPU_LIGHTS,
            scene.lights.len()
        )));
    }
    if let Some(p) = shape.unwritten_pixel.filter(|&p| p as u64 >= pixels) {
        // A hook that misses the image would test nothing while seeming to.
        return Err(RenderError::Gpu(format!(
            "STCVAE_GPU_TEST_UNWRITTEN_PIXEL={p} is beyond the image's {pixels} pixels"
        )));
    }
    let depth = bvh_depth(&scene.geo.bvh);
    if depth + 1 > kernels::STACK_DEPTH as usize {
        return Err(RenderError::SceneBeyondGpu(format!(
            "the mesh's BVH is {depth} levels deep; the GPU kernels' traversal stack holds {} \
             entries; use --device cpu",
            kernels::STACK_DEPTH
        )));
    }
    Ok(())
}

/// What every pipeline of one render is built from.
struct KernelBuild<'a> {
    ctx: &'a GpuContext,
    kernel: Kernel,
    model: Option<&'a cvae::ModelSet>,
    path_nee_m: u32,
    switches: kernels::SceneSwitches,
    shape: KernelShape,
}

impl KernelBuild<'_> {
    fn pipeline(
        &self,
        layout: &wgpu::BindGroupLayout,
        entry: &str,
    ) -> Result<wgpu::ComputePipeline, RenderError> {
        kernels::pipeline(
            self.ctx,
            layout,
            self.kernel,
            self.model,
            self.path_nee_m,
            self.switches,
            self.shape,
            entry,
        )
    }

    /// The single kernel, or, given the staged render's `args_layout`, its kernels (the
    /// step kernel only for ST-CVAE with `shape.steps`).
    fn kernels(
        &self,
        layout: &wgpu::BindGroupLayout,
        args_layout: Option<&wgpu::BindGroupLayout>,
    ) -> Result<Kernels, RenderError> {
        let Some(args_layout) = args_layout else {
            return Ok(Kernels::Single(self.pipeline(layout, "render_main")?));
        };
        Ok(Kernels::Staged(StagedKernels {
            stage: self.pipeline(layout, "stage_main")?,
            trace: self.pipeline(layout, "trace_main")?,
            args: self.pipeline(args_layout, "args_main")?,
            list_args: self.pipeline(args_layout, "list_args_main")?,
            step: match self.kernel {
                Kernel::Stcvae if self.shape.steps => Some(self.pipeline(layout, "step_main")?),
                _ => None,
            },
        }))
    }
}

/// Path slots per pixel, samples per pixel, and the bands of rows the slots are kept in,
/// for slots of `slot_bytes`.
fn plan_slots(
    ctx: &GpuContext,
    cam: &crate::camera::Camera,
    shape: &KernelShape,
    slot_bytes: u64,
    opts: &RenderOptions,
) -> Result<(u32, u32, Vec<Band>), RenderError> {
    // Every path slot of a band lives in one storage binding: adapters offer 128 MiB to
    // several GiB, and a 1024² image at 2²⁰ invocations with two path-level NEE
    // reservoirs needs 185 MB.
    let limits = &ctx.limits;
    // The staged render's records and its queues take one binding each too, at fewer bytes
    // a slot than the path state today.
    let binding_bytes = if shape.staged {
        slot_bytes.max(STAGE_SLOT_BYTES).max(QUEUE_SLOT_BYTES)
    } else {
        slot_bytes
    };
    let fit = limits
        .max_storage_buffer_binding_size
        .min(limits.max_buffer_size)
        / binding_bytes;
    let cap = band_cap(ctx.adapter.software, shape.band_slots);
    let (lanes, spp) = lanes_and_spp(ctx, cam, fit.min(cap), opts)?;
    let bands = plan_bands(
        ctx,
        cam,
        lanes,
        (fit, cap),
        binding_bytes,
        slot_bytes,
        shape,
    )?;
    Ok((lanes, spp, bands))
}

/// The scene's arrays as the kernels read them.
struct SceneArrays {
    nodes: Vec<GpuNode>,
    tris: Vec<GpuTri>,
    env: Vec<[f32; 4]>,
    /// Empty where the scene has no distance grid (PT).
    grid: Vec<u32>,
}

impl SceneArrays {
    fn of(scene: &SceneData) -> Result<Self, RenderError> {
        let (nodes, tris) = geometry_buffers(scene)?;
        Ok(Self {
            nodes,
            tris,
            env: env_buffer(scene),
            grid: scene
                .grid
                .as_ref()
                .map_or_else(Vec::new, |g| grid_buffer(g, &scene.geo)),
        })
    }
}

/// The dispatch statistics known before the first dispatch.
fn first_dispatch_stats(
    shape: &KernelShape,
    bands: &[Band],
    kernels: &Kernels,
    ahead: bool,
) -> DispatchStats {
    DispatchStats {
        bands: bands.len() as u32,
        grid_rows: bands.iter().map(|b| b.groups.1).max().unwrap_or(1),
        workgroup: shape.workgroup,
        stack: Some(shape.stack),
        staged: shape.staged,
        aggregate: shape.aggregate,
        staged_steps: matches!(kernels, Kernels::Staged(k) if k.step.is_some()),
        lanes: shape.profile.then(LaneProfile::new),
        ahead,
        ..Default::default()
    }
}

/// The number of path slots per pixel (lanes) and the samples per pixel to render: as asked,
/// or, under a time budget, at most what the slots' counts hold. `fit`: the slots a band
/// may hold (a binding's, at most the band cap, which exceeds [`target_threads`] unless a
/// test lowers it: then one lane a pixel, as on a large image).
fn lanes_and_spp(
    ctx: &GpuContext,
    cam: &crate::camera::Camera,
    fit: u64,
    opts: &RenderOptions,
) -> Result<(u32, u32), RenderError> {
    let spp = opts.spp.max(1);
    let pixels = cam.width as u64 * cam.height as u64;
    let lanes = (target_threads(ctx).min(fit) / pixels.max(1)).clamp(1, spp as u64) as u32;
    // A slot counts its samples in f32, which stops at 2^24 (its sums keep what they
    // round off, shaders/path.wgsl add_sample). A time budget's render stops at 2^24 a
    // slot (days to weeks on today's GPUs); asking for more is refused before any
    // dispatch.
    let most = lanes as u64 * MAX_SLOT_SAMPLES;
    let spp = if (spp as u64) <= most {
        spp
    } else if opts.time_budget.is_some() {
        most as u32
    } else {
        return Err(RenderError::GpuLimit(format!(
            "{spp} samples per pixel exceed the {most} the GPU's f32 counts hold for a \
             {}x{} image on {} (2^24 per path slot); render several seeds and merge \
             them, or use --device cpu",
            cam.width, cam.height, ctx.adapter.name
        )));
    };
    Ok((lanes, spp))
}

/// The render's buffers, filled, the path state poisoned, and the snapshot buffers where a
/// cut-off dispatch may be redone. Out of memory is this device's limit, said as such.
fn upload(
    ctx: &GpuContext,
    layout: &wgpu::BindGroupLayout,
    args_layout: Option<&wgpu::BindGroupLayout>,
    inputs: &Inputs,
    staged: bool,
    budget: u32,
    pixels: u64,
) -> Result<(Resources, Option<Snapshot>), RenderError> {
    // Bands keep each binding within its limit, not the whole within the GPU's memory: an
    // allocation that fails is a limit of this device (the CPU may render the scene), not
    // a panic in wgpu's default error handler.
    // A buffer whose allocation failed is invalid, and filling it through the queue is a
    // validation error: caught by the outer scope, so the out-of-memory error (inner) is
    // what is reported, not wgpu's panic on the validation error it causes.
    let follow_on = ctx.device.push_error_scope(wgpu::ErrorFilter::Validation);
    let scope = ctx.device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
    let res = Resources::new(ctx, layout, args_layout, inputs)?;
    let accum_bytes = inputs.accum_bytes;
    // A failed wait is reported after the error scopes: an out-of-memory error they hold
    // says more than "the GPU did not finish".
    let poisoned = poison(ctx, &res.accums, accum_bytes);
    let largest = accum_bytes.iter().copied().max().unwrap_or(0);
    // The path states before the dispatch in flight, kept on software adapters while a
    // cut-off dispatch can be redone with a smaller budget.
    let snapshot = (ctx.adapter.software && budget > 1).then(|| Snapshot {
        accum: res.snapshot_buffer(ctx, largest),
        staged: staged
            .then(|| [&res.stage, &res.queue].map(|b| res.snapshot_buffer(ctx, b.size()))),
    });
    let out_of_memory = pollster::block_on(scope.pop());
    let invalid = pollster::block_on(follow_on.pop());
    if let Some(e) = out_of_memory {
        let total: u64 = accum_bytes.iter().sum();
        return Err(RenderError::GpuLimit(format!(
            "{} is out of memory for this render's buffers ({} MB of path state for {} \
             pixels): {}; lower the image size or use --device cpu",
            ctx.adapter.name,
            total / 1_000_000,
            pixels,
            super::context::one_line(&e.to_string())
        )));
    }
    if let Some(e) = invalid {
        return Err(RenderError::Gpu(format!(
            "setting up the render's buffers on {} failed: {}",
            ctx.adapter.name,
            super::context::one_line(&e.to_string())
        )));
    }
    poisoned?;
    Ok((res, snapshot))
}

/// Compiles every kernel of the render ([`compile`]) and returns the seconds it took.
fn compile_kernels(
    ctx: &GpuContext,
    res: &Resources,
    kernels: &Kernels,
    params: &Params,
) -> Result<f64, RenderError> {
    let mut compile_seconds = 0.0;
    match kernels {
        // The queues start zeroed: trace_main and step_main find nothing to do, and the
        // arguments' kernels write arguments the first turn overwrites (args_main also
        // closes a turn of empty queues, which only changes which copy comes next).
        Kernels::Staged(k) => {
            for p in [&k.stage, &k.trace].into_iter().chain(&k.step) {
                compile_seconds += compile(ctx, res, p, params, false)?;
            }
            for p in [&k.args, &k.list_args] {
                compile_seconds += compile(ctx, res, p, params, true)?;
            }
        }
        Kernels::Single(p) => compile_seconds = compile(ctx, res, p, params, false)?,
    }
    Ok(compile_seconds)
}

/// How a render deals its samples out in chunks.
struct ChunkPlan<'p> {
    lanes: u32,
    spp: u32,
    /// `STCVAE_GPU_LANE_SAMPLES`: each lane's samples a chunk, fixed; else sized to
    /// [`TARGET_CHUNK_SECONDS`].
    fixed_per_lane: Option<u32>,
    pixels: u64,
    width: u32,
    time_budget: Option<f64>,
    progress: &'p (dyn Fn(u64, u64) + Sync),
}

/// What the chunks rendered.
struct Chunks {
    /// The samples per pixel of the whole chunks.
    spp: u32,
    /// Set when a stop request dropped the chunk under way, to the number of bands that
    /// had begun it.
    dropped: Option<usize>,
    /// When the last whole chunk ended.
    kept_seconds: f64,
    start: Instant,
    stats: PathStats,
}

impl Dispatcher<'_> {
    /// Renders the plan's samples chunk by chunk over the bands, until done, out of time or
    /// stopped.
    fn render_chunks(
        &self,
        bands: &[Band],
        plan: &ChunkPlan,
        params: &mut Params,
        budget: &mut u32,
        dispatch: &mut DispatchStats,
    ) -> Result<Chunks, RenderError> {
        let &ChunkPlan {
            lanes,
            spp,
            fixed_per_lane,
            pixels,
            width,
            time_budget,
            progress,
        } = plan;
        let cancel = self.cancel;
        let start = Instant::now();
        let mut stats = PathStats::default();
        let mut s0 = 0u32;
        let mut per_lane = fixed_per_lane.unwrap_or(1);
        let total = pixels * spp as u64;
        // Set when a stop request drops the chunk under way, to the number of bands that had
        // begun it: their image is then the slots' committed accumulators
        // (kernels::committed_vec4), the whole chunks before it; the bands after them have not
        // begun the chunk, and their accumulators hold exactly those chunks.
        let mut dropped: Option<usize> = None;
        // When the last whole chunk ended: a dropped chunk's time does not count against the
        // samples kept (paths/s read ~30 % low after Ctrl-C on lavapipe).
        let mut kept_seconds = 0.0;
        while s0 < spp {
            // A stop requested before the first chunk (while the kernels compiled, which on
            // lavapipe takes seconds, minutes for a large model) renders nothing, as on the
            // CPU; later ones are seen after each submission and each chunk.
            if s0 == 0 && cancel.load(Ordering::Relaxed) {
                break;
            }
            let s1 = (s0 as u64 + lanes as u64 * per_lane as u64).min(spp as u64) as u32;
            if s0 == 0 {
                dispatch.first_chunk_spp = s1;
            }
            params.image[2] = lanes;
            params.image[3] = per_lane;
            params.sampling[0] = s0;
            params.sampling[1] = s1;
            let t0 = Instant::now();
            let stats_before = stats;
            for band in bands {
                // A stop request is looked at after each submission (in run_band) and after
                // each band: a band reached after one still begins the chunk (one submission
                // more to wait for), so that which bands had begun it follows from their
                // submissions alone.
                let finished =
                    self.run_band(band, s0 == 0, params, budget, &mut stats, dispatch)?;
                if !finished {
                    dropped = Some(band.index + 1);
                    break;
                }
                // A band that finished in one submission never looked at the stop request
                // (run_band returns when its paths are done): without this, a stop waited for
                // every band of the chunk, ~15 s at 1024² on lavapipe. The next band has not
                // begun the chunk, which `dropped` says as for a band cut short.
                if cancel.load(Ordering::Relaxed) && band.index + 1 < bands.len() {
                    dropped = Some(band.index + 1);
                    break;
                }
                let done_rows = (band.row0 + band.rows) as u64;
                progress(
                    pixels * s0 as u64 + width as u64 * done_rows * (s1 - s0) as u64,
                    total,
                );
            }
            if dropped.is_some() {
                // Its paths are not counted either, as the CPU does not count a dropped pass's
                // (its dispatches, which ran, stay in `dispatch`).
                stats = stats_before;
                break;
            }
            let dt = t0.elapsed().as_secs_f64();
            kept_seconds = start.elapsed().as_secs_f64();
            s0 = s1;
            // Grow (or shrink) the next chunk toward the target duration: under a time budget
            // at most what is left of it, shrinking at once (a fixed second overshot
            // `--time-budget 0.3` to 0.43 s on lavapipe; a twentieth of the budget, as the CPU
            // sizes its passes, cost a quarter of the samples of a 2 s budget there).
            let (target, least) = time_budget.map_or((TARGET_CHUNK_SECONDS, 0.5), |b| {
                let left = b - start.elapsed().as_secs_f64();
                (TARGET_CHUNK_SECONDS.min(left).max(1e-3), 0.02)
            });
            let scale = (target / dt.max(1e-4)).clamp(least, 4.0);
            per_lane = fixed_per_lane
                .unwrap_or(((per_lane as f64 * scale) as u32).clamp(1, MAX_LANE_SAMPLES));
            let out_of_time = time_budget.is_some_and(|b| start.elapsed().as_secs_f64() >= b);
            if out_of_time || cancel.load(Ordering::Relaxed) {
                break;
            }
        }
        Ok(Chunks {
            spp: s0,
            dropped,
            kept_seconds,
            start,
            stats,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn kernel_shape_takes_only_the_offered_values() {
        // SAFETY: no other test of this binary reads these variables.
        let with = |wg: &str, stack: &str| {
            unsafe {
                std::env::set_var("STCVAE_GPU_WORKGROUP", wg);
                std::env::set_var("STCVAE_GPU_STACK", stack);
            }
            let r = kernel_shape();
            unsafe {
                std::env::remove_var("STCVAE_GPU_WORKGROUP");
                std::env::remove_var("STCVAE_GPU_STACK");
            }
            r
        };
        let s = with("128", "private").unwrap();
        assert_eq!((s.workgroup, s.stack), (128, StackMemory::Private));
        // `with` leaves both unset: the defaults.
        assert_eq!(kernel_shape().unwrap(), KernelShape::default());
        assert_eq!(with(" 8 ", "workgroup").unwrap().workgroup, 8);
        // Empty is unset, as for every variable here.
        assert_eq!(with("", " ").unwrap(), KernelShape::default());
        for bad in ["0", "48", "512", "-64", "sixty-four"] {
            let e = with(bad, "workgroup").unwrap_err().to_string();
            assert!(
                e.contains("STCVAE_GPU_WORKGROUP") && e.contains("[8, 16, 32, 64, 128, 256]"),
                "{e}"
            );
        }
        // The shape with one variable set (and unset again after).
        let with_one = |name: &str, v: &str| {
            unsafe { std::env::set_var(name, v) };
            let r = kernel_shape();
            unsafe { std::env::remove_var(name) };
            r
        };
        for (v, on) in [("1", true), ("true", true), ("0", false), ("", false)] {
            let r = with_one("STCVAE_GPU_PROFILE", v);
            assert_eq!(r.unwrap().profile, on, "{v:?}");
        }
        // Empty is the default, also where the default is on.
        for (v, on) in [("", true), (" ", true), ("0", false)] {
            let r = with_one("STCVAE_GPU_STAGED_AHEAD", v);
            assert_eq!(r.unwrap().ahead, on, "{v:?}");
        }
        assert!(KernelShape::default().ahead);
        let e = with_one("STCVAE_GPU_PROFILE", "yes")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("STCVAE_GPU_PROFILE") && e.contains("1 or true"),
            "{e}"
        );
        // Each of `bad` refused, the message naming the variable and its `allowed` range.
        let refused = |name: &str, bad: &[&str], allowed: &str| {
            for b in bad {
                let e = with_one(name, b).unwrap_err().to_string();
                assert!(e.contains(name) && e.contains(allowed), "{e}");
            }
        };
        // The test hook: a pixel index, u32::MAX (its "none") refused.
        for (v, want) in [("7", Some(7)), (" 0 ", Some(0)), ("", None)] {
            let r = with_one("STCVAE_GPU_TEST_UNWRITTEN_PIXEL", v);
            assert_eq!(r.unwrap().unwritten_pixel, want, "{v:?}");
        }
        for bad in ["-1", "4294967295", "x"] {
            let e = with_one("STCVAE_GPU_TEST_UNWRITTEN_PIXEL", bad)
                .unwrap_err()
                .to_string();
            assert!(e.contains("STCVAE_GPU_TEST_UNWRITTEN_PIXEL"), "{e}");
        }
        // The dispatch row's hook: 1 to 65,535 workgroups, unset the most a dimension holds.
        for (v, want) in [("5", 5), (" 1 ", 1), ("65535", 65_535), ("", 65_535)] {
            let r = with_one("STCVAE_GPU_TEST_DISPATCH_ROW", v);
            assert_eq!(r.unwrap().dispatch_row, want, "{v:?}");
        }
        refused(
            "STCVAE_GPU_TEST_DISPATCH_ROW",
            &["0", "65536", "-1", "x"],
            "allowed 1 to 65535",
        );
        // The cut-offs' hook: 0 to 16 dispatches, unset none.
        for (v, want) in [("2", 2), (" 16 ", 16), ("0", 0), ("", 0)] {
            let r = with_one("STCVAE_GPU_TEST_CUT_OFFS", v);
            assert_eq!(r.unwrap().cut_offs, want, "{v:?}");
        }
        refused(
            "STCVAE_GPU_TEST_CUT_OFFS",
            &["17", "-1", "x"],
            "allowed 0 to 16",
        );
        // The band cap's hook: 1 to 2^22 slots (a hardware band's most), unset none.
        for (v, want) in [("1536", Some(1536)), (" 1 ", Some(1)), ("", None)] {
            let r = with_one("STCVAE_GPU_TEST_BAND_SLOTS", v);
            assert_eq!(r.unwrap().band_slots, want, "{v:?}");
        }
        let r = with_one("STCVAE_GPU_TEST_BAND_SLOTS", "4194304");
        assert_eq!(r.unwrap().band_slots, Some(1 << 22));
        refused(
            "STCVAE_GPU_TEST_BAND_SLOTS",
            &["0", "4194305", "-1", "x"],
            "allowed 1 to 4194304",
        );
        let e = with("64", "shared").unwrap_err().to_string();
        assert!(
            e.contains("STCVAE_GPU_STACK") && e.contains("workgroup or private"),
            "{e}"
        );
    }

    #[test]
    fn lane_samples_take_only_counts_in_range() {
        assert_eq!(parse_lane_samples("8").unwrap(), Some(8));
        for bad in ["0", "-1", "65537", "x", ""] {
            let e = parse_lane_samples(bad).unwrap_err().to_string();
            assert!(
                e.contains("STCVAE_GPU_LANE_SAMPLES") && e.contains("1 to 65536"),
                "{e}"
            );
        }
    }

    #[test]
    fn bands_are_capped_per_dispatch() {
        // A 4096² image at one lane a pixel, a 2 GiB binding of 112-byte slots: one band of
        // every row before the cap; now 1,024 rows (4 M slots) a band.
        let fit = ((1u64 << 31) - 1) / 112;
        let (hard, soft) = (HARDWARE_BAND_SLOTS, SOFTWARE_BAND_SLOTS);
        assert_eq!(band_rows(fit, 4096, 4096, hard), 1024);
        assert_eq!(band_rows(fit, 4096, 4096, soft), 16);
        // A binding smaller than the cap decides; a row wider than the cap is a band alone;
        // a short image is one band; no row fits: 0.
        assert_eq!(band_rows(1 << 20, 4096, 4096, hard), 256);
        assert_eq!(band_rows(fit, 1 << 23, 4096, hard), 1);
        assert_eq!(band_rows(fit, 4096, 100, hard), 100);
        assert_eq!(band_rows(100, 4096, 4096, hard), 0);
        // Each kind of adapter its own cap; the test hook only lowers it.
        assert_eq!((band_cap(false, None), band_cap(true, None)), (hard, soft));
        assert_eq!(band_cap(true, Some(1536)), 1536);
        assert_eq!(band_cap(true, Some(1 << 22)), soft);
        assert_eq!(band_cap(false, Some(1 << 22)), hard);
    }

    /// A counter is a pair of u32 words, low then high (the kernels carry into the high
    /// one: path.wgsl, add_counter_wide), read as one u64: a long render's events pass
    /// 2^32 (1024² pixels × 256 spp × ~20 PT events a path), and the low word alone would
    /// report them wrapped. Every render of the tests counts below 2^32, so only this
    /// reads a high word that is not 0.
    #[test]
    fn counters_read_both_words_of_their_pair() {
        let words: [u32; 6] = [u32::MAX, 0, 7, 3, 0, 1];
        let c: Vec<u8> = words.iter().flat_map(|w| w.to_le_bytes()).collect();
        assert_eq!(counter(&c, 0), u32::MAX as u64);
        assert_eq!(counter(&c, 1), (3u64 << 32) | 7);
        assert_eq!(counter(&c, 2), 1u64 << 32);
    }

    #[test]
    fn bounce_budget_takes_only_counts_in_range() {
        assert_eq!(parse_bounces("64").unwrap(), 64);
        assert_eq!(parse_bounces(" 1 ").unwrap(), 1);
        assert_eq!(parse_bounces("65535").unwrap(), MAX_BOUNCES);
        for bad in ["0", "-1", "abc", "", "65536", "1e3"] {
            let e = parse_bounces(bad).unwrap_err().to_string();
            assert!(e.contains("allowed 1 to 65535"), "{bad:?}: {e}");
        }
    }
}
