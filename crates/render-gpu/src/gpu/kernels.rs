//! The WGSL kernels, composed from `shaders/` (WGSL has no includes: the shared files are
//! concatenated in a fixed order), and their bind-group layouts: the single kernel's, the
//! staged kernels' (two bindings more), and that of the staged render's arguments' kernels.

use std::borrow::Cow;

use crate::error::RenderError;

use super::context::GpuContext;
use super::kernel_cache::LayoutKind;

const COMMON: &str = include_str!("../../../../shaders/common.wgsl");
const SCENE: &str = include_str!("../../../../shaders/scene.wgsl");
const NEE: &str = include_str!("../../../../shaders/nee.wgsl");
const DECODER: &str = include_str!("../../../../shaders/decoder.wgsl");
const PT: &str = include_str!("../../../../shaders/pt.wgsl");
const STCVAE: &str = include_str!("../../../../shaders/stcvae.wgsl");
const PATH: &str = include_str!("../../../../shaders/path.wgsl");
const PROBE: &str = include_str!("../../../../shaders/probe.wgsl");
const STAGED: &str = include_str!("../../../../shaders/staged.wgsl");
const STAGED_STEP_KERNEL: &str = include_str!("../../../../shaders/staged_steps.wgsl");

/// Entries of each invocation's BVH traversal stack (shaders/scene.wgsl). A depth-first
/// traversal of a BVH2 of depth D needs at most D + 1; the renderer refuses deeper trees.
/// In workgroup memory, 48 × 64 invocations (the default workgroup) × 4 bytes = 12 KiB,
/// under the 16 KiB every adapter offers; larger workgroups are checked against the
/// adapter's limit ([`KernelShape::check`]).
pub const STACK_DEPTH: u32 = 48;

/// Where each invocation's BVH traversal stack lives.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum StackMemory {
    /// A slice of one workgroup array (the default, chosen when a private array indexed at
    /// run time cost llvmpipe ~25 % of PT's time; on today's kernels the two are within
    /// lavapipe's noise: docs/BENCHMARKS.md, twenty-seventh session).
    Workgroup,
    /// A private array: on hardware GPUs thread-local memory, cached, leaving the workgroup
    /// memory that may limit how many workgroups share a multiprocessor free.
    Private,
}

/// How the kernels sit on the hardware: threads per workgroup and where the traversal
/// stacks live (and test hooks). Neither changes what any path computes (seeds follow the
/// pixel and the sample, not the thread), so the image is the same bit for bit whatever
/// the shape (tested), but for two test hooks (`unwritten_pixel`, `band_slots`); they
/// differ in speed only, which hardware GPUs decide (occupancy, divergence per warp) and
/// which `STCVAE_GPU_WORKGROUP` / `STCVAE_GPU_STACK` let a device session measure without
/// a rebuild (scripts/device/check).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct KernelShape {
    /// Threads per workgroup (`@workgroup_size(WORKGROUP)` in the WGSL).
    pub workgroup: u32,
    pub stack: StackMemory,
    /// Count the SIMD lanes busy in each phase of the kernel ([`PROFILE_PHASES`];
    /// `STCVAE_GPU_PROFILE`): needs subgroup operations; changes no path either.
    pub profile: bool,
    /// Render in kernels taking turns (`STCVAE_GPU_STAGED`, shaders/staged.wgsl):
    /// `stage_main` runs every path to its next ray query or sphere step and queues it,
    /// `trace_main` traces the queued queries and `step_main` runs the queued steps. The
    /// single kernel's paths, random numbers and all, with the traversals, walks and
    /// decoders compacted so that their SIMD lanes work together; the counters are the
    /// single kernel's, and so is the image, bit for bit on lavapipe and within 1–2 ulp on
    /// the H100, whose compiler treats step_main's float arithmetic differently (tested).
    pub staged: bool,
    /// Add to the counters and queues once per subgroup instead of once per invocation
    /// (`STCVAE_GPU_AGGREGATE`, built only where the adapter offers subgroup operations):
    /// the staged render appends every running path to a queue at every turn, and a
    /// queue's length is one word that every invocation would otherwise add to atomically.
    /// Off by default: on the H100 (2026-11-27) the staged render ran 6–12 % faster
    /// without it (NVIDIA's atomics keep up; the subgroup sums cost more) and the single
    /// kernel the same within noise, as did both on lavapipe. Changes no path: only the
    /// order of a queue's entries.
    pub aggregate: bool,
    /// In the staged render, run ST-CVAE's sphere steps (exact walks, or decoders, and NEE
    /// events) in a kernel of their own (`step_main`; `STCVAE_GPU_STAGED_STEPS`, on by
    /// default), so that walks and decoders run with every lane on a step; off, they run
    /// in `stage_main`. Changes no path.
    pub steps: bool,
    /// In the staged render, send each submission of turns before waiting for the counters
    /// of the one before, where no snapshot is kept to undo from (`STCVAE_GPU_STAGED_AHEAD`,
    /// on by default; the host's dispatching only, no kernel changes).
    pub ahead: bool,
    /// A pixel whose slots the kernels leave alone (`STCVAE_GPU_TEST_UNWRITTEN_PIXEL`; a
    /// test hook, off by default): the render must then report it as unwritten, which is
    /// what the host's NaN poison is for. Off, its branch in `slot_begin` is constant
    /// false. With `band_slots`, the fields of the shape that change the image.
    pub unwritten_pixel: Option<u32>,
    /// Workgroups a dispatch lays out along x before it takes further rows along y:
    /// [`DISPATCH_ROW`], the most a dimension allows everywhere, which a band of more
    /// than 65,535 × `workgroup` path slots exceeds (a hardware band holds up to 2²² =
    /// 65,536 × 64 slots: one more workgroup than a row at the default 64, many more rows
    /// with `STCVAE_GPU_WORKGROUP` 8–32). A test hook (`STCVAE_GPU_TEST_DISPATCH_ROW`)
    /// lowers it, so that the second dimension (slot_of's `gid.y`, and the staged
    /// render's indirect dispatches) runs on images small enough for lavapipe. Changes
    /// no path.
    pub dispatch_row: u32,
    /// This many of the render's dispatches that resume paths (not a chunk's first) and
    /// keep a snapshot (a software adapter's, while the budget is above 1) are taken as
    /// cut off by the loop limit, undone and redone as a real cut-off is; a redo counts
    /// again (`STCVAE_GPU_TEST_CUT_OFFS`; a test hook, 0 by default). Resuming ones: they
    /// start with paths in flight (and, staged, in the queues), whose undo is what a real
    /// cut-off needs. A real one needs walks longer than lavapipe's limit, which of the GPU
    /// tests' scenes only PT's dense bunny has, so the undo of ST-CVAE's and the staged
    /// render's states went untested. Changes no path.
    pub cut_offs: u32,
    /// The most path slots a band holds, below the adapter's cap (bands.rs,
    /// `SOFTWARE_BAND_SLOTS`, `HARDWARE_BAND_SLOTS`) where a test hook
    /// (`STCVAE_GPU_TEST_BAND_SLOTS`) lowers it; `None` by default. So that a stop
    /// between a chunk's bands is tested on a 64² image, not a 256 × 544 one (109 s on
    /// lavapipe, 2026-12-07), and on either kind of adapter. It lowers the lanes a pixel
    /// too (at most the cap's slots over the pixels, at least 1): the same samples are
    /// drawn, but summed in other slots (other f32 roundings) and over other chunks, so
    /// the image may differ in its last bits. A test hook only.
    pub band_slots: Option<u32>,
}

/// The most workgroups a dispatch dimension may hold on any adapter (WebGPU's default
/// `max_compute_workgroups_per_dimension`).
pub const DISPATCH_ROW: u32 = 65_535;

impl Default for KernelShape {
    fn default() -> Self {
        Self {
            workgroup: 64,
            stack: StackMemory::Workgroup,
            profile: false,
            staged: false,
            aggregate: false,
            steps: true,
            ahead: true,
            unwritten_pixel: None,
            dispatch_row: DISPATCH_ROW,
            cut_offs: 0,
            band_slots: None,
        }
    }
}

/// The phases of the lane profile, in counter order: at each pass through one, the
/// subgroup's active lanes are counted against its size. A phase's lanes that are idle
/// (finished paths, lanes on another branch, loops whose other lanes run longer) are the
/// SIMD work a hardware GPU wastes there: what a split of the kernel into coherent stages
/// could win back. Shadow rays whose crossings do not pair up are walked in order by
/// closest-hit queries (nee.wgsl, `transmittance_ordered`) and count as closest-hit steps;
/// a traversal pass that a path's closest-hit query and another path's shadow ray share
/// (path.wgsl, bounce: path-level NEE) counts under the kind of the subgroup's first
/// active lane; a decoder evaluation is counted before its model is chosen.
pub const PROFILE_PHASES: [&str; 8] = [
    "bounce",
    "closest-hit traversal step",
    "shadow-ray traversal step",
    "surface-distance search step",
    "exact walk event",
    "decoder evaluation",
    "collision (PT event or sphere step)",
    "cell-list hit test",
];

/// The lane profile's WGSL: counting functions (with subgroup operations; naga takes them
/// without WGSL's `enable subgroups`, which it does not parse yet, once the device has the
/// feature) or empty ones that compile away.
fn profile_wgsl(on: bool) -> String {
    let n = PROFILE_PHASES.len();
    if !on {
        return "fn prof_begin(li: u32) {}\nfn prof(phase: u32) {}\nfn prof_end() {}\n".to_string();
    }
    format!(
        "var<private> prof_active: array<u32, {n}>;\n\
         var<private> prof_capacity: array<u32, {n}>;\n\
         var<private> prof_passes: array<u32, {n}>;\n\
         var<private> prof_size: u32;\n\
         var<private> prof_lane: u32;\n\
         fn lanes_active() -> u32 {{\n\
         \x20   let b = subgroupBallot(true);\n\
         \x20   return countOneBits(b.x) + countOneBits(b.y) + countOneBits(b.z) + countOneBits(b.w);\n\
         }}\n\
         // At the entry point's start every lane of a subgroup is active: its size.\n\
         fn prof_begin(li: u32) {{\n\
         \x20   prof_size = lanes_active();\n\
         \x20   prof_lane = li;\n\
         }}\n\
         // One lane counts for its subgroup: the first active one (naga has no\n\
         // subgroupElect; local indices are distinct within a workgroup).\n\
         fn prof(phase: u32) {{\n\
         \x20   let n = lanes_active();\n\
         \x20   if subgroupBroadcastFirst(prof_lane) == prof_lane {{\n\
         \x20       prof_active[phase] += n;\n\
         \x20       prof_capacity[phase] += prof_size;\n\
         \x20       prof_passes[phase] += 1u;\n\
         \x20   }}\n\
         }}\n\
         fn prof_end() {{\n\
         \x20   for (var i = 0u; i < {n}u; i++) {{\n\
         \x20       add_counter(PATH_COUNTERS + 3u * i, prof_active[i]);\n\
         \x20       add_counter(PATH_COUNTERS + 1u + 3u * i, prof_capacity[i]);\n\
         \x20       add_counter(PATH_COUNTERS + 2u + 3u * i, prof_passes[i]);\n\
         \x20   }}\n\
         }}\n"
    )
}

/// The subgroup primitives of the counters and queues ([`KernelShape::aggregate`]): with
/// subgroup operations, the active lanes' rank and count, a sum over them and the first
/// one's value; without, each invocation is its own group of one.
fn aggregate_wgsl(on: bool) -> &'static str {
    if on {
        "fn sg_rank() -> u32 {\n\
         \x20   return subgroupExclusiveAdd(1u);\n\
         }\n\
         fn sg_count() -> u32 {\n\
         \x20   return subgroupAdd(1u);\n\
         }\n\
         fn sg_sum(v: u32) -> u32 {\n\
         \x20   return subgroupAdd(v);\n\
         }\n\
         fn sg_first(v: u32) -> u32 {\n\
         \x20   return subgroupBroadcastFirst(v);\n\
         }\n"
    } else {
        "fn sg_rank() -> u32 {\n\
         \x20   return 0u;\n\
         }\n\
         fn sg_count() -> u32 {\n\
         \x20   return 1u;\n\
         }\n\
         fn sg_sum(v: u32) -> u32 {\n\
         \x20   return v;\n\
         }\n\
         fn sg_first(v: u32) -> u32 {\n\
         \x20   return v;\n\
         }\n"
    }
}

impl KernelShape {
    /// The shape as built on `ctx`: aggregation only where its subgroup operations exist.
    pub fn on(mut self, ctx: &GpuContext) -> Self {
        self.aggregate &= ctx.features.contains(wgpu::Features::SUBGROUP);
        self
    }

    /// The workgroup sizes offered: powers of two from lavapipe's SIMD width (8) to the
    /// 256 invocations every adapter allows.
    pub const WORKGROUPS: [u32; 6] = [8, 16, 32, 64, 128, 256];

    /// Bytes of workgroup memory a workgroup of this shape takes.
    pub fn workgroup_bytes(&self) -> u32 {
        match self.stack {
            StackMemory::Workgroup => 4 * STACK_DEPTH * self.workgroup,
            StackMemory::Private => 0,
        }
    }

    /// Refuses a shape beyond the adapter's limits, naming the limit.
    pub fn check(&self, ctx: &GpuContext) -> Result<(), RenderError> {
        let l = &ctx.limits;
        let most = l
            .max_compute_invocations_per_workgroup
            .min(l.max_compute_workgroup_size_x);
        if self.workgroup > most {
            return Err(RenderError::GpuLimit(format!(
                "a workgroup of {} threads (STCVAE_GPU_WORKGROUP) exceeds {}'s limit of {most}",
                self.workgroup, ctx.adapter.name
            )));
        }
        if self.profile && !ctx.features.contains(wgpu::Features::SUBGROUP) {
            return Err(RenderError::GpuLimit(format!(
                "STCVAE_GPU_PROFILE needs subgroup operations, which {} does not offer",
                ctx.adapter.name
            )));
        }
        // The profile takes a subgroup's size from its lanes active at the kernel's start,
        // which a workgroup narrower than the subgroup would understate.
        if self.profile && self.workgroup < ctx.subgroup_max_size {
            return Err(RenderError::GpuLimit(format!(
                "STCVAE_GPU_PROFILE needs workgroups of at least {}'s subgroup size, {} \
                 threads (STCVAE_GPU_WORKGROUP is {})",
                ctx.adapter.name, ctx.subgroup_max_size, self.workgroup
            )));
        }
        if self.workgroup_bytes() > l.max_compute_workgroup_storage_size {
            return Err(RenderError::GpuLimit(format!(
                "{} threads' traversal stacks take {} bytes of workgroup memory, over {}'s {} \
                 (a private stack takes none: STCVAE_GPU_STACK=private)",
                self.workgroup,
                self.workgroup_bytes(),
                ctx.adapter.name,
                l.max_compute_workgroup_storage_size
            )));
        }
        Ok(())
    }

    /// The WGSL that fixes the shape (prepended to every kernel).
    fn wgsl(&self) -> String {
        let (stride, stack) = match self.stack {
            StackMemory::Workgroup => (
                STACK_DEPTH,
                format!(
                    "var<workgroup> trav_stack: array<u32, {}>;",
                    STACK_DEPTH * self.workgroup
                ),
            ),
            StackMemory::Private => (
                0,
                format!("var<private> trav_stack: array<u32, {STACK_DEPTH}>;"),
            ),
        };
        format!(
            "const WORKGROUP: u32 = {}u;\nconst STACK_STRIDE: u32 = {stride}u;\n{stack}\n\
             const UNWRITTEN_PIXEL: u32 = {}u;\nconst DISPATCH_ROW: u32 = {}u;\n",
            self.workgroup,
            self.unwritten_pixel.unwrap_or(u32::MAX),
            self.dispatch_row
        )
    }
}

/// What a scene needs of the kernels, fixed when they are compiled (WGSL constants)
/// rather than read from the scene parameters: lavapipe's JIT keeps the code of a branch
/// that a run-time flag switches off, and Mesa 22's runs it too (its llvmpipe executes
/// both sides of every `if` under a mask, taken or not: `stcvae bench decoders`), so code
/// that never runs slowed the path loop. Measured on lavapipe (2026-12-02,
/// docs/BENCHMARKS.md): the overlap code as a run-time flag cost PT 13 % on every mesh;
/// the dielectric and environment-map branches as constants gained 8 % on an
/// index-matched scene without a map, and the light count and NEE another 5–9 % for
/// ST-CVAE. A kernel is compiled for its render's switches anyway (once a device, which
/// keeps the 16 used last: [`super::kernel_cache`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SceneSwitches {
    /// The mesh's pieces overlap (`OVERLAPS`; [`crate::geometry::Geometry::pieces`]).
    pub overlaps: bool,
    /// A dielectric boundary (`DIELECTRIC`; Fresnel choices and shadow-ray factors).
    pub dielectric: bool,
    /// An environment map (`ENV_MAP`; else the constant environment only).
    pub env_map: bool,
    /// The directional lights the kernels see (`LIGHTS`, at most
    /// [`super::scene_buffers::MAX_GPU_LIGHTS`]): loops over them of known length.
    pub lights: u32,
    /// Next-event estimation on (`NEE`; the render's setting).
    pub nee: bool,
    /// Per-slot squared sums for the variance image (`VARIANCE`; the render's
    /// `--variance`): three vec4s more a slot ([`slot_vec4s`]), kept only when asked.
    pub variance: bool,
}

impl SceneSwitches {
    /// The switches of `scene` rendered with NEE on or off.
    pub fn of(scene: &crate::setup::SceneData, nee: bool) -> Self {
        Self {
            overlaps: scene.geo.pieces.is_some(),
            dielectric: scene.boundary.ior().is_some(),
            env_map: scene.env.map.is_some(),
            lights: scene.lights.len().min(super::scene_buffers::MAX_GPU_LIGHTS) as u32,
            nee,
            variance: false,
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kernel {
    /// Volumetric path tracing (`render_main`).
    Pt,
    /// ST-CVAE sphere tracing with EventGen NEE (`render_main`).
    Stcvae,
    /// Test entry points (`probe_decoder`, `probe_frame`) over the PT build.
    Probe,
}

/// vec4s of one path slot's record in the staged render (`STAGE_VEC4S`, prepended to the
/// WGSL): its ray query and answer (shaders/staged.wgsl). A parked sphere step needs none:
/// its path is saved at the collision.
pub const STAGE_VEC4S: u64 = 4;

/// vec4s of one path slot in the accumulation buffer (`SLOT` in shaders/path.wgsl): the
/// path's state, the render's accumulated RGB (vec4 [`ACC_VEC4`]), two per path-level
/// NEE reservoir, with `variance` the squared sums ([`acc_sq_vec4`], [`acc_sq_lo_vec4`],
/// [`committed_sq_vec4`]), what the RGB sums rounded off ([`acc_lo_vec4`]), and last the
/// accumulated RGB as the chunk began ([`committed_vec4`]).
pub fn slot_vec4s(path_nee_m: u32, variance: bool) -> u64 {
    7 + 2 * path_nee_m as u64 + if variance { 3 } else { 0 }
}

/// Which vec4 of a path slot holds in xyz what the f32 additions to ACC's RGB rounded off
/// (`ACC_LO`, prepended to the kernels; shaders/path.wgsl, add_sample): the slot's sum is
/// ACC + ACC_LO, taken in f64 on the host. Its w counts the slot's PT events + sphere
/// steps over the render (the work map; in f32, exact to 2^24).
pub fn acc_lo_vec4(path_nee_m: u32, variance: bool) -> u64 {
    slot_vec4s(path_nee_m, variance) - 2
}

/// Which vec4 of a path slot holds its accumulated RGB and finished-sample count as they
/// were when the current chunk of samples began (`COMMITTED`, prepended to the kernels): the
/// image of the whole chunks, which a render stopped mid-chunk returns.
pub fn committed_vec4(path_nee_m: u32, variance: bool) -> u64 {
    slot_vec4s(path_nee_m, variance) - 1
}

/// With `variance`: which vec4 of a path slot holds in xyz the sum of the squares of the
/// values ACC's RGB adds (`ACC_SQ`, prepended to the kernels): each sample's estimate
/// times 3, so the host divides by 9 for `render::pixel_variance`, which reads the
/// estimates'.
pub fn acc_sq_vec4(path_nee_m: u32) -> u64 {
    slot_vec4s(path_nee_m, true) - 5
}

/// With `variance`: what the f32 additions to [`acc_sq_vec4`] rounded off (`ACC_SQ_LO`),
/// kept as for the RGB sums: a constant background's squares drift as its sums would,
/// and the variance, a difference of the two, would read that drift as noise.
pub fn acc_sq_lo_vec4(path_nee_m: u32) -> u64 {
    slot_vec4s(path_nee_m, true) - 4
}

/// With `variance`: the squared sums as the current chunk began, rounded once
/// (`SQ_COMMITTED`), beside [`committed_vec4`] for a render stopped mid-chunk. That
/// rounding (6e-8 of the sum) leaves a constant pixel of a stopped render a variance of
/// up to ~1e-7·value²/(n − 1) rather than 0.
pub fn committed_sq_vec4(path_nee_m: u32) -> u64 {
    slot_vec4s(path_nee_m, true) - 3
}

/// Which vec4 of a path slot holds the accumulated RGB and finished-sample count (`ACC`,
/// prepended to the kernels from here by `tied_constants_wgsl`).
pub const ACC_VEC4: u64 = 4;

/// The full WGSL source of a kernel with `path_nee_m` path-level NEE reservoirs (0: a
/// shadow ray at every NEE event; at most [`crate::scene::MAX_PATH_NEE_RAYS`]); the ST-CVAE
/// and probe kernels include the model's decoders, generated as straight-line code.
/// `switches` fixes what the scene needs at compile time ([`SceneSwitches`]).
pub fn source(
    kernel: Kernel,
    model: Option<&cvae::ModelSet>,
    path_nee_m: u32,
    switches: SceneSwitches,
    shape: KernelShape,
) -> Result<String, RenderError> {
    if path_nee_m > crate::scene::MAX_PATH_NEE_RAYS {
        return Err(RenderError::Scene(format!(
            "render.path_nee_rays = {path_nee_m} is out of range: allowed [0, {}]",
            crate::scene::MAX_PATH_NEE_RAYS
        )));
    }
    let decoders = match (kernel, model) {
        (Kernel::Pt, _) => String::new(),
        (_, Some(m)) => super::decoder_gen::decoders_wgsl(m)?,
        (_, None) => {
            return Err(RenderError::Model(format!(
                "the {kernel:?} kernel needs a model"
            )));
        }
    };
    // The traversal stack's size, from its one definition here (scene.wgsl uses it), the
    // shadow-ray roulette threshold, the optical-depth limits and the flight margin from
    // the CPU integrator's (nee.wgsl, path.wgsl), and the node packing's count bits from
    // GpuNode's.
    let stack = format!(
        "const STACK_DEPTH: u32 = {STACK_DEPTH}u;\n{}\
         const ROULETTE_BOUND: f32 = {:?};\nconst FLIGHT_MARGIN_OF_EPS: f32 = {:?};\n\
         const SKIP_MIN_COS: f32 = {:?};\nconst SKIP_BACK: f32 = {:?};\n\
         const SKIP_CLEAR_OF_EPS: f32 = {:?};\nconst EDGE_TOLERANCE: f32 = {:?};\n\
         const MAX_OPTICAL_DEPTH: f32 = {:?};\nconst PROXY_DEPTH_CAP: f32 = {:?};\n\
         const PHASE_BOUND_TURN: f32 = {:?};\n\
         const MAX_CROSSINGS: u32 = {}u;\n\
         const SLIVER_REACH_OF_EPS: f32 = {:?};\n\
         const PATH_NEE_M: u32 = {path_nee_m}u;\nconst SLOT: u32 = {}u;\n\
         const ACC_LO: u32 = {}u;\nconst COMMITTED: u32 = {}u;\n\
         const ACC_SQ: u32 = {}u;\nconst ACC_SQ_LO: u32 = {}u;\nconst SQ_COMMITTED: u32 = {}u;\n\
         const STAGE_VEC4S: u32 = {STAGE_VEC4S}u;\n\
         const NODE_COUNT_BITS: u32 = {}u;\nconst COUNTER_WORDS: u32 = {}u;\n\
         const PATH_COUNTERS: u32 = {}u;\n\
         const STAGED_STEPS: bool = {};\nconst OVERLAPS: bool = {};\n\
         const DIELECTRIC: bool = {};\nconst ENV_MAP: bool = {};\n\
         const LIGHTS: u32 = {}u;\nconst NEE: bool = {};\nconst VARIANCE: bool = {};\n{}{}",
        shape.wgsl(),
        crate::integrator::nee::ROULETTE_BOUND,
        crate::geometry::FLIGHT_MARGIN_OF_EPS,
        crate::geometry::SKIP_MIN_COS,
        crate::geometry::SKIP_BACK,
        crate::geometry::SKIP_CLEAR_OF_EPS,
        crate::geometry::EDGE_TOLERANCE,
        crate::integrator::nee::MAX_OPTICAL_DEPTH,
        crate::integrator::nee::PROXY_DEPTH_CAP,
        crate::integrator::nee::PHASE_BOUND_TURN,
        crate::integrator::nee::MAX_CROSSINGS,
        crate::geometry::SLIVER_REACH_OF_EPS,
        slot_vec4s(path_nee_m, switches.variance),
        acc_lo_vec4(path_nee_m, switches.variance),
        committed_vec4(path_nee_m, switches.variance),
        // The squares' vec4s as they sit when VARIANCE is on; without it the kernels
        // never read them.
        acc_sq_vec4(path_nee_m),
        acc_sq_lo_vec4(path_nee_m),
        committed_sq_vec4(path_nee_m),
        super::scene_buffers::GpuNode::COUNT_BITS,
        2 * super::resources::COUNTER_SLOTS,
        super::resources::PATH_COUNTERS,
        shape.staged && shape.steps,
        switches.overlaps,
        switches.dielectric,
        switches.env_map,
        switches.lights,
        switches.nee,
        switches.variance,
        profile_wgsl(shape.profile),
        aggregate_wgsl(shape.aggregate),
    ) + &tied_constants_wgsl();

    let parts: &[&str] = match (kernel, shape.staged) {
        (Kernel::Pt, false) => &[COMMON, &stack, SCENE, NEE, PT, PATH],
        (Kernel::Pt, true) => &[COMMON, &stack, SCENE, NEE, PT, PATH, STAGED],
        (Kernel::Stcvae, false) => &[COMMON, &stack, SCENE, NEE, DECODER, &decoders, STCVAE, PATH],
        (Kernel::Stcvae, true) => &[
            COMMON,
            &stack,
            SCENE,
            NEE,
            DECODER,
            &decoders,
            STCVAE,
            PATH,
            STAGED,
            STAGED_STEP_KERNEL,
        ],
        (Kernel::Probe, _) => &[
            COMMON, &stack, SCENE, NEE, DECODER, &decoders, PT, PATH, PROBE,
        ],
    };
    Ok(parts.join("\n"))
}

/// The kernels' constants whose one definition is on the host: the estimator's factors
/// shared with the CPU integrators (a copy in WGSL could drift from them silently, and
/// images of both devices are merged), and the sizes and slots of the buffers the host
/// writes and reads.
fn tied_constants_wgsl() -> String {
    use super::resources as r;
    use crate::{distance_grid, geometry, integrator, light};
    let mut s = format!(
        "const RR_THRESHOLD: f32 = {:?};\nconst MAX_ITERATIONS: u32 = {}u;\n\
         const SHRINK: f32 = {:?};\nconst EXACT_DISTANCE_SHRINK: f32 = {:?};\n\
         const BALL_CHORD_SHRINK: f32 = {:?};\nconst LOCAL_REACH_SHRINK: f32 = {:?};\n\
         const UPPER_BOUND_SLACK: f32 = {:?};\nconst PLANE_SLACK_OF_EPS: f32 = {:?};\n\
         const CROSSING_TOL_OF_EPS: f32 = {:?};\nconst GRAZING_COS_FLOOR: f32 = {:?};\n\
         const PHASE_SHARE: f32 = {:?};\n\
         const MAX_LIGHTS: u32 = {}u;\nconst MAX_PROXY_LIGHTS: u32 = {}u;\n\
         const MAX_EXACT_EVENTS: u32 = {}u;\nconst ACC: u32 = {}u;\n\
         const QUEUES: u32 = {}u;\nconst QUEUE_LENGTHS: u32 = {}u;\n\
         const STAGE_ARGS: u32 = {}u;\nconst STEP_ARGS: u32 = {}u;\n\
         const QUERY_ARGS: u32 = {}u;\nconst ARGS_WORDS: u32 = {}u;\n",
        integrator::RR_THRESHOLD,
        u32::try_from(integrator::MAX_ITERATIONS).expect("MAX_ITERATIONS fits a u32"),
        integrator::sphere_step::SHRINK,
        integrator::sphere_step::EXACT_DISTANCE_SHRINK,
        integrator::sphere_step::BALL_CHORD_SHRINK,
        distance_grid::LOCAL_REACH_SHRINK,
        distance_grid::UPPER_BOUND_SLACK,
        geometry::PLANE_SLACK_OF_EPS,
        geometry::CROSSING_TOL_OF_EPS,
        geometry::GRAZING_COS_FLOOR,
        light::PHASE_SHARE,
        super::scene_buffers::MAX_GPU_LIGHTS,
        integrator::event_choice::MAX_PROXY_LIGHTS,
        crate::scene::MAX_EXACT_NEE_SAMPLES,
        ACC_VEC4,
        r::QUEUES,
        r::QUEUE_LENGTHS,
        r::STAGE_ARGS_AT / 4,
        r::STEP_ARGS_AT / 4,
        r::QUERY_ARGS_AT / 4,
        r::ARGS_BYTES / 4,
    );
    for (name, slot) in r::slot::WGSL {
        s += &format!("const {name}: u32 = {slot}u;\n");
    }
    s
}

fn storage(binding: u32, read_only: bool) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Storage { read_only },
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    }
}

fn uniform(binding: u32) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Uniform,
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    }
}

/// Storage buffers the kernels bind (all but the model's uniform): 7 for the single kernels,
/// within WebGPU's default of 8; the staged render's two more exceed it, which the adapters
/// seen here allow (lavapipe 32, NVIDIA far more).
pub fn storage_buffers(staged: bool) -> u32 {
    if staged { 9 } else { 7 }
}

/// The bind-group layout of `shaders/scene.wgsl`: params, accum, counters, triangles,
/// nodes, environment map, distance grid, model params, and for the staged render
/// (`staged`) its records and queues (shaders/staged.wgsl). An adapter with fewer storage
/// buffers per shader stage than [`storage_buffers`] is refused with a clear error instead
/// of wgpu's validation panic.
pub fn bind_group_layout(
    ctx: &GpuContext,
    staged: bool,
) -> Result<wgpu::BindGroupLayout, RenderError> {
    let needed = storage_buffers(staged);
    let offered = ctx.limits.max_storage_buffers_per_shader_stage;
    if offered < needed {
        let what = if staged {
            "the staged GPU render (STCVAE_GPU_STAGED) binds"
        } else {
            "the GPU kernels bind"
        };
        return Err(RenderError::GpuLimit(format!(
            "{what} {needed} storage buffers; {} offers {offered} per shader stage; use \
             --device cpu",
            ctx.adapter.name
        )));
    }
    let mut entries = vec![
        storage(0, true),
        storage(1, false),
        storage(2, false),
        storage(3, true),
        storage(4, true),
        storage(5, true),
        storage(6, true),
        uniform(7),
    ];
    if staged {
        entries.extend([storage(8, false), storage(9, false)]);
    }
    let kind = if staged {
        LayoutKind::Staged
    } else {
        LayoutKind::Single
    };
    Ok(ctx.kernel_cache.layout(kind, || {
        ctx.device
            .create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some("stcvae scene"),
                entries: &entries,
            })
    }))
}

/// The bind-group layout of the staged render's arguments' kernels (`args_main`,
/// `list_args_main`): the counters, the queues and the indirect buffer they write the
/// dispatch arguments into. A buffer may not be bound as storage in a dispatch that reads
/// it as indirect arguments, so the other kernels' layout leaves it out.
pub fn args_layout(ctx: &GpuContext) -> wgpu::BindGroupLayout {
    ctx.kernel_cache.layout(LayoutKind::Arguments, || {
        ctx.device
            .create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some("stcvae dispatch arguments"),
                entries: &[storage(2, false), storage(9, false), storage(10, false)],
            })
    })
}

/// Compiles `entry` of `kernel` (with `path_nee_m` path-level NEE reservoirs, for a mesh
/// with overlapping pieces or not, in `shape`, see [`source`]), or finds it compiled for
/// an earlier render (the context's [`super::kernel_cache::KernelCache`]); shader or
/// pipeline errors come back as errors, not panics (wgpu's default handler would abort).
#[allow(clippy::too_many_arguments)]
pub fn pipeline(
    ctx: &GpuContext,
    layout: &wgpu::BindGroupLayout,
    kernel: Kernel,
    model: Option<&cvae::ModelSet>,
    path_nee_m: u32,
    switches: SceneSwitches,
    shape: KernelShape,
    entry: &str,
) -> Result<wgpu::ComputePipeline, RenderError> {
    shape.check(ctx)?;
    let src = source(kernel, model, path_nee_m, switches, shape.on(ctx))?;
    ctx.kernel_cache.pipeline(layout, entry, src, |src| {
        compile_pipeline(ctx, layout, kernel, src, entry)
    })
}

/// The pipeline of `entry` in the WGSL `src`, built now; every error wgpu reports while
/// building it is returned (not left to the uncaptured-error handler), so that
/// [`super::kernel_cache::KernelCache`] keeps no pipeline that failed to build. (A lost
/// device reports no error here; its context, cache and all, is then of no further use.)
pub fn compile_pipeline(
    ctx: &GpuContext,
    layout: &wgpu::BindGroupLayout,
    kernel: Kernel,
    src: &str,
    entry: &str,
) -> Result<wgpu::ComputePipeline, RenderError> {
    // Every kind of error, not only validation: a driver's internal or out-of-memory
    // failure would otherwise leave an invalid pipeline, which the cache would keep.
    use wgpu::ErrorFilter as F;
    let scopes =
        [F::Validation, F::OutOfMemory, F::Internal].map(|f| ctx.device.push_error_scope(f));
    let module = ctx
        .device
        .create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some(entry),
            source: wgpu::ShaderSource::Wgsl(Cow::Borrowed(src)),
        });
    let pl = ctx
        .device
        .create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some(entry),
            bind_group_layouts: &[Some(layout)],
            immediate_size: 0,
        });
    let p = ctx
        .device
        .create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some(entry),
            layout: Some(&pl),
            module: &module,
            entry_point: Some(entry),
            // The only workgroup memory is the traversal stacks, always written before
            // they are read: zero-filling them (12 KiB a workgroup of 64) would be wasted.
            compilation_options: wgpu::PipelineCompilationOptions {
                zero_initialize_workgroup_memory: false,
                ..Default::default()
            },
            cache: None,
        });
    // Innermost first, as scopes must pop; every error kept, one line each.
    let [validation, memory, internal] = scopes;
    let errors: Vec<String> = [internal, memory, validation]
        .into_iter()
        .filter_map(|s| pollster::block_on(s.pop()))
        .map(|e| super::context::one_line(&e.to_string()))
        .collect();
    if !errors.is_empty() {
        return Err(RenderError::Gpu(format!(
            "the {kernel:?} kernel did not compile on {}: {}",
            ctx.adapter,
            errors.join("; ")
        )));
    }
    Ok(p)
}
