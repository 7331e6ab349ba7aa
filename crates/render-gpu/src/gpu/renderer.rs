//! The GPU render loop: dispatches of a few samples per pixel each (no dispatch runs long
//! enough for a GPU watchdog), in bands of rows (bands.rs), counters read back after every
//! dispatch (u32 lo/hi pairs on the GPU, u64 here) and the image reduced over lanes in f64
//! at the end (readout.rs), under the `STCVAE_GPU_*` switches (switches.rs).

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use crate::error::RenderError;
use crate::integrator::{IntegratorKind, IntegratorSettings, PathStats};
use crate::render::{DispatchStats, LaneProfile, RenderOptions, RenderOutput};
use crate::setup::SceneData;

use super::context::GpuContext;
use super::kernels::{self, Kernel, KernelShape};

use super::bands::{Band, band_cap, plan_bands, target_threads};
use super::model_buffers::model_params;
use super::readout::{SlotReadout, counter, poison, tally};
use super::resources::{
    COUNTER_BYTES, Inputs, QUEUE_SLOT_BYTES, Readback, Resources, STAGE_SLOT_BYTES, StagedKernels,
    Turn, slot, start_read_back, wait,
};
use super::scene_buffers::{
    GpuNode, GpuTri, Params, bvh_depth, env_buffer, geometry_buffers, grid_buffer, scene_params,
};
use super::switches::{
    MAX_LANE_SAMPLES, bounce_budget, fixed_lane_samples, kernel_shape, staged_rounds,
};

/// Wall time a chunk of samples aims at (progress, time budget and Ctrl-C are checked
/// between chunks). A chunk takes several dispatches of bounded work each.
const TARGET_CHUNK_SECONDS: f64 = 1.0;

/// Most samples one path slot accumulates (an f32 count; see where `lanes` is chosen).
pub const MAX_SLOT_SAMPLES: u64 = 1 << 24;

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
