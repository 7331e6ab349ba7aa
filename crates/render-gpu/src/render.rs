//! The CPU render loop: tiles in parallel (rayon), samples in passes, one RNG stream per
//! (pixel, sample) so the image is the same whatever the thread count.

use std::sync::atomic::{AtomicBool, AtomicU64, AtomicUsize, Ordering};
use std::time::Instant;

use glam::Vec3;
use scatter_sim::rng::{WalkRng, splitmix64};

use crate::geometry::Hit;
use crate::image_io::RgbImage;
use crate::integrator::wavefront::{Sample, trace_many};
use crate::integrator::{IntegratorSettings, PathStats};
use crate::setup::SceneData;

/// Fewest tiles of 16 pixels an image must make to be rendered in them (see [`tile_side`]).
const MIN_TILES: usize = 64;
/// Tile side: 16 pixels, or 8 where 16 leaves fewer than `MIN_TILES` tiles. A pass ends
/// when its dearest tile does, and the object's tiles cost ~100× the background's: at
/// 64×64 (16 tiles, a handful on the object) 16 threads rendered no faster than 4
/// (H200 machine's Xeon, docs/BENCHMARKS.md). Smaller tiles everywhere would cost on few
/// cores instead (each tile's pass ends with its wavefront draining). The side depends on
/// the image alone, never on the thread count, so a render stays the same on any.
fn tile_side(w: usize, h: usize) -> usize {
    if w.div_ceil(16) * h.div_ceil(16) >= MIN_TILES {
        16
    } else {
        8
    }
}
/// Fewest samples a pixel per pass (unless spp is smaller): see `render`.
const MIN_PASS: u32 = 16;
/// Most samples a pixel per pass: a stop request waits for the tiles being traced, one
/// pass's worth of samples each (at 1/16 of 100,000 spp, Ctrl-C took 14 s to answer).
const MAX_PASS: u32 = 256;

/// A pixel's radiance sum over a pass, its count of events + sphere steps, and (for
/// [`RenderOptions::variance`]) the sum of its samples' squared estimates per channel.
type PixelSum = ([f64; 3], u64, [f64; 3]);

pub struct RenderOptions {
    pub spp: u32,
    pub seed: u64,
    /// Stop after the pass during which this many seconds have passed.
    pub time_budget: Option<f64>,
    /// Also estimate each pixel's variance ([`RenderOutput::variance`]): the CPU renderer
    /// sums its samples' squares in f64, the GPU kernels per path slot in compensated f32
    /// (`gpu::kernels::acc_sq_vec4`).
    pub variance: bool,
}

/// Bytes a pixel more that [`RenderOptions::variance`] takes (squared sums in f64, the
/// variance image and its encoded file; the tile results' squares are always counted in
/// [`BYTES_PER_PIXEL`]), for [`check_image_memory_with`].
pub const VARIANCE_BYTES_PER_PIXEL: u64 = 48;

pub struct RenderOutput {
    pub image: RgbImage,
    /// Samples per pixel actually rendered (fewer than asked if the budget ran out).
    pub spp: u32,
    /// Rendering time; excludes `compile_seconds`.
    pub seconds: f64,
    /// Time the GPU driver took to compile the kernel before the clock of `seconds` started
    /// (0 on the CPU). llvmpipe compiles at the first dispatch: 2–11 s for ST-CVAE on a cold
    /// shader cache, which would otherwise count as rendering; ~0 where the device built
    /// the kernel for an earlier render (`gpu::kernel_cache`).
    pub compile_seconds: f64,
    pub stats: PathStats,
    /// Per pixel, the mean number of PT scattering events plus sphere steps per path —
    /// where the work goes (paper Fig. 8/9). Both devices fill it (the GPU from each path
    /// slot's counts, `gpu::kernels::acc_lo_vec4`'s w). A GPU render stopped mid-chunk
    /// keeps the dropped chunk's counts in it (the CPU drops that pass's): a little high
    /// there, and no longer the counters' sum.
    pub work: Vec<f32>,
    /// How the GPU ran the render (all zero on the CPU).
    pub dispatch: DispatchStats,
    /// With [`RenderOptions::variance`], per pixel and channel the estimated variance of
    /// the pixel's value (the squared standard error of its mean over the samples that
    /// traced that channel). None without the option, or below 6 spp, where some channel
    /// has fewer than 2 samples.
    pub variance: Option<RgbImage>,
}

impl RenderOutput {
    /// Paths traced per second of rendering (the kernel's compilation left out).
    pub fn paths_per_second(&self) -> f64 {
        self.stats.paths as f64 / self.seconds.max(1e-9)
    }
}

/// How a GPU render was dispatched. The fallbacks it counts (dispatches redone after a
/// software adapter's loop limit cut them off, images split into bands) leave the expected
/// image unchanged, so only these counts show that they ran.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct DispatchStats {
    /// Kernel dispatches, redone ones included.
    pub dispatches: u64,
    /// Dispatches cut off by the loop limit, undone and redone with half the bounce budget.
    pub redone: u64,
    /// Bands of rows the image was rendered in (1: one storage binding held it all).
    pub bands: u32,
    /// The most rows of workgroups (the dispatch's y) a band took: 1 unless a band held
    /// more than 65,535 workgroups (`KernelShape::dispatch_row`).
    pub grid_rows: u32,
    /// Samples per pixel of the first chunk: a pixel's path slots times the samples each
    /// renders in it (`STCVAE_GPU_LANE_SAMPLES`, else 1), at most the spp asked for. A
    /// time budget shorter than this chunk's time still gets the chunk whole.
    pub first_chunk_spp: u32,
    /// Bounces a dispatch advanced each path by, at the end of the render.
    pub bounce_budget: u32,
    /// Threads per workgroup of the kernel (`STCVAE_GPU_WORKGROUP`).
    pub workgroup: u32,
    /// Where its traversal stacks lived (`STCVAE_GPU_STACK`); None on the CPU.
    pub stack: Option<crate::gpu::kernels::StackMemory>,
    /// Whether it ran as the staged render (`STCVAE_GPU_STAGED`).
    pub staged: bool,
    /// Whether its counters and queues were added to once per subgroup
    /// (`STCVAE_GPU_AGGREGATE` and the adapter's subgroup operations).
    pub aggregate: bool,
    /// Whether the staged render ran ST-CVAE's sphere steps, exact and the model's, in
    /// their own kernel (`STCVAE_GPU_STAGED_STEPS`).
    pub staged_steps: bool,
    /// The SIMD lanes busy in each phase of the kernel (`STCVAE_GPU_PROFILE`).
    pub lanes: Option<LaneProfile>,
    /// Whether each submission of the staged render was sent before the host waited for the
    /// counters of the one before (where no snapshot is kept to undo from: hardware GPUs,
    /// or a software adapter at one bounce a dispatch).
    pub ahead: bool,
    /// Microseconds the host spent encoding and submitting the dispatches, and waiting for
    /// their counters: a GPU that finishes a submission before the host has sent the next
    /// idles in between (the staged render submits a turn's four dispatches at a time).
    pub host_encode_us: u64,
    pub host_wait_us: u64,
}

/// Per phase of the kernel ([`crate::gpu::kernels::PROFILE_PHASES`]), the subgroup lanes
/// active at its passes and the lanes those subgroups had.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct LaneProfile {
    pub phases: [PhaseLanes; crate::gpu::kernels::PROFILE_PHASES.len()],
}

#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct PhaseLanes {
    pub phase: &'static str,
    /// Σ over the subgroups' passes of their active lanes.
    pub active: u64,
    /// Σ over the same passes of the subgroup's size.
    pub capacity: u64,
    /// The subgroups' passes through the phase.
    pub passes: u64,
}

impl LaneProfile {
    /// No passes yet, each phase named (the names travel into the JSON).
    pub fn new() -> Self {
        let mut p = Self::default();
        for (lanes, name) in p.phases.iter_mut().zip(crate::gpu::kernels::PROFILE_PHASES) {
            lanes.phase = name;
        }
        p
    }
}

impl PhaseLanes {
    /// The share of the phase's SIMD lanes doing work (None: never reached).
    pub fn efficiency(&self) -> Option<f64> {
        (self.capacity > 0).then(|| self.active as f64 / self.capacity as f64)
    }
}

/// lowbias32 (Wellons): the kernels' `mix32` (shaders/common.wgsl).
fn mix32(mut x: u32) -> u32 {
    x ^= x >> 16;
    x = x.wrapping_mul(0x7feb_352d);
    x ^= x >> 15;
    x = x.wrapping_mul(0x846c_a68b);
    x ^= x >> 16;
    x
}

/// The colour channel of a pixel's sample 0; sample s traces (offset + s) % 3, so each
/// channel gets ⌊spp/3⌋ or ⌈spp/3⌉ of a pixel's samples ([`resolve_pixel`] averages each
/// channel over its own). The offset is uniform over pixels and over seeds, so every
/// sample's channel is uniform, which keeps renders below 3 spp unbiased over seeds. It
/// once took two bits of a product, which made
/// channel 0 twice as likely and tinted renders whose spp is not a multiple of 3 (a
/// `--time-budget` render can stop at any spp). The kernels compute the same
/// (`channel_offset` in shaders/common.wgsl).
pub fn channel_offset(seed: u64, pixel: u32) -> u32 {
    let s = mix32(seed as u32 ^ mix32((seed >> 32) as u32 ^ 0x4348_4e4c));
    mix32(pixel.wrapping_mul(0x9e37_79b9) ^ s) % 3
}

/// A pixel's colour from its sums over `spp` samples, each sample's estimate added times 3
/// to its hero channel: every channel's mean over the samples that traced it. With spp not
/// a multiple of 3 the channels have spp/3 rounded up or down samples, and dividing each
/// sum by spp (the plain estimator) left every pixel off by up to ±2/spp in each channel
/// around its value: a white furnace at 64 spp gave 1.031 in one channel and 0.984 in
/// the others, pixel by pixel. Each channel's own mean is unbiased per pixel. Below 3 spp
/// some channel has no sample, and the plain estimator (unbiased over the offsets) is kept.
pub fn resolve_pixel(sum: [f64; 3], spp: u32, seed: u64, pixel: u32) -> [f32; 3] {
    if spp < 3 {
        return sum.map(|v| (v / spp.max(1) as f64) as f32);
    }
    let counts = channel_counts(spp, seed, pixel);
    std::array::from_fn(|c| (sum[c] / (3.0 * counts[c] as f64)) as f32)
}

/// Sample `s` of pixel `pixel`: its random stream, its jitter within the pixel and its hero
/// channel. The three samples 3j, 3j + 1, 3j + 2 share one jitter (their channels are the
/// three colours), so they share one camera ray, which the renderer casts once for them
/// (`CameraRays`). Per channel the jitters stay independent and uniform, so each
/// channel's estimate is as before; only the channels of a pixel become correlated. (The
/// GPU kernels jitter each sample on its own.)
pub fn pixel_sample(seed: u64, pixel: u64, s: u32) -> (WalkRng, f32, f32, usize) {
    let rng = WalkRng::for_walk(seed, (pixel << 32) | s as u64);
    let h = splitmix64(splitmix64(seed ^ JITTER_STREAM) ^ ((pixel << 32) | (s / 3) as u64));
    let unit = |bits: u64| (bits >> 40) as f32 * (1.0 / (1u32 << 24) as f32);
    let (jx, jy) = (unit(h), unit(h << 24));
    // s % 3 first: s + offset wraps for the last samples of 2^32 − 1.
    let channel = (s % 3 + channel_offset(seed, pixel as u32)) % 3;
    (rng, jx, jy, channel as usize)
}

/// Keeps the jitter hash apart from the walks' streams.
const JITTER_STREAM: u64 = 0x4a49_5454_4552_0001;

/// The camera ray's first hit, cast once for the samples that share the ray (see
/// [`pixel_sample`]): the samples of a pixel come one after another, so the last one is
/// all there is to keep. Casting it once instead of three times made ST-CVAE 2.5 % faster.
#[derive(Default)]
struct CameraRays {
    last: Option<((u64, u32), Option<Hit>)>,
}

impl CameraRays {
    fn first_hit(&mut self, scene: &SceneData, pixel: u64, s: u32, dir: Vec3) -> Option<Hit> {
        let key = (pixel, s / 3);
        match self.last {
            Some((k, hit)) if k == key => hit,
            _ => {
                let origin = scene.camera.ray_origin(dir);
                let hit = scene.geo.intersect(origin, dir, f32::INFINITY);
                self.last = Some((key, hit));
                hit
            }
        }
    }
}

/// Bytes a CPU render of a `width` × `height` image holds at once, per pixel: its sums (24)
/// and work counts (8), a pass's tile results (56: sums, count, squared sums), the image
/// (12) and its encoded EXR and PNG (~16), rounded up. (A GPU render's path slots live on
/// the device; a software adapter's in host memory as well, which this does not count.)
pub const BYTES_PER_PIXEL: u64 = 124;

/// Refuses an image whose buffers the process cannot allocate (a memory limit, a small
/// machine), naming the size, before any work: Rust aborts on a failed allocation, so a
/// 16,384² image (~33 GB) under a limit would otherwise end in "memory allocation of
/// 6442450944 bytes failed" halfway. The space is reserved and given back at once, not
/// touched.
pub fn check_image_memory(width: u32, height: u32) -> Result<(), crate::error::RenderError> {
    check_image_memory_with(width, height, 0)
}

/// [`check_image_memory`] with `extra` more bytes a pixel: a software adapter's path
/// slots, which live in host memory (`gpu::kernels::slot_vec4s`, 16 bytes each), or a
/// variance image's buffers ([`VARIANCE_BYTES_PER_PIXEL`]).
pub fn check_image_memory_with(
    width: u32,
    height: u32,
    extra: u64,
) -> Result<(), crate::error::RenderError> {
    let bytes = width as u64 * height as u64 * (BYTES_PER_PIXEL + extra);
    if reservable(bytes) {
        Ok(())
    } else {
        Err(crate::error::RenderError::Scene(format!(
            "a {width} x {height} image needs about {:.1} GB of memory, which could not be \
             allocated: render a smaller one",
            bytes as f64 / 1e9
        )))
    }
}

/// Whether `bytes` can be allocated now: reserved and given back at once, not touched
/// (Rust aborts on a failed allocation, so sizes taken from input are tried first).
pub fn reservable(bytes: u64) -> bool {
    usize::try_from(bytes).is_ok_and(|n| Vec::<u8>::new().try_reserve_exact(n).is_ok())
}

/// Renders the scene. `progress(done, total)` counts pixel-samples; `cancel` stops within
/// the tiles being traced (the image then holds the passes completed before).
pub fn render(
    scene: &SceneData,
    set: &IntegratorSettings,
    opts: &RenderOptions,
    progress: &(dyn Fn(u64, u64) + Sync),
    cancel: &AtomicBool,
) -> RenderOutput {
    let cam = &scene.camera;
    let (w, h) = (cam.width as usize, cam.height as usize);
    let tile = tile_side(w, h);
    let tiles: Vec<(usize, usize)> = (0..h.div_ceil(tile))
        .flat_map(|ty| (0..w.div_ceil(tile)).map(move |tx| (tx * tile, ty * tile)))
        .collect();
    let mut sums = Sums::new(w * h, opts.variance);
    let start = Instant::now();
    // Passes let a time budget or Ctrl-C stop between complete sets of samples. A pass
    // must not be small either: each tile's pass ends with its wavefront draining (the
    // last paths' sphere steps in ever smaller batches), which cost ~17 % at 4 samples a
    // pixel per pass against 32 (default scene). So at least MIN_PASS samples a pass, at
    // most 16 passes unless that would exceed MAX_PASS samples a pass. With a time budget
    // (spp only a cap) the first pass takes one sample and later ones `next_budget_pass`.
    let mut pass = if opts.time_budget.is_some() {
        1
    } else {
        opts.spp.div_ceil(16).clamp(MIN_PASS, MAX_PASS)
    };
    let total = w as u64 * h as u64 * opts.spp as u64;
    let done = AtomicU64::new(0);
    let mut s0 = 0u32;
    let mut order: Vec<usize> = (0..tiles.len()).collect();
    let mut cost = vec![0f64; tiles.len()];
    // Until the end of the last whole pass: a pass cut short by a stop request is
    // dropped, and its time must not count against the samples kept (paths/s read up to
    // 18 % low after Ctrl-C).
    let mut seconds = 0.0;
    while s0 < opts.spp {
        let s1 = s0.saturating_add(pass).min(opts.spp);
        // Tiles are handed out one at a time from a queue, dearest first (by the last
        // pass's times): a thread that finishes early takes the next tile, and the pass
        // ends with cheap tiles. Splitting the tiles evenly among the threads instead left
        // a core idle 12 % of a 64×64 PT render (object tiles cost ~100× background ones).
        // A tile's result does not depend on the thread that traced it.
        let cursor = AtomicUsize::new(0);
        let finished: Vec<(usize, Vec<PixelSum>, PathStats, f64)> = rayon::broadcast(|_| {
            let mut mine = Vec::new();
            loop {
                // A stop request ends the pass early; its tiles are then discarded below,
                // so a render of many samples a pass stops within a tile, not a pass.
                if cancel.load(Ordering::Relaxed) {
                    break;
                }
                let k = cursor.fetch_add(1, Ordering::Relaxed);
                let Some(&t) = order.get(k) else { break };
                let (x0, y0) = tiles[t];
                let t0 = Instant::now();
                let (x1, y1) = ((x0 + tile).min(w), (y0 + tile).min(h));
                let rect = TileRect { x0, y0, x1, y1 };
                let Some((out, st)) = trace_tile(scene, set, opts.seed, rect, s0..s1, cancel)
                else {
                    // Stopped inside a long path: the tile is incomplete, so the pass is.
                    break;
                };
                let n = ((x1 - x0) * (y1 - y0)) as u64 * (s1 - s0) as u64;
                progress(done.fetch_add(n, Ordering::Relaxed) + n, total);
                mine.push((t, out, st, t0.elapsed().as_secs_f64()));
            }
            mine
        })
        .into_iter()
        .flatten()
        .collect();
        if finished.len() < tiles.len() {
            // Stopped mid-pass: every pixel must have the same samples, so the pass's
            // finished tiles are dropped and the image is that of the passes before.
            break;
        }
        for (t, out, st, secs) in finished {
            cost[t] = secs;
            let (x0, y0) = tiles[t];
            sums.add_tile(x0, y0, (x0 + tile).min(w), w, out, &st);
        }
        order.sort_by(|&a, &b| cost[b].total_cmp(&cost[a]).then(a.cmp(&b)));
        s0 = s1;
        let elapsed = start.elapsed().as_secs_f64();
        seconds = elapsed;
        let out_of_time = opts.time_budget.is_some_and(|b| elapsed >= b);
        if out_of_time || cancel.load(Ordering::Relaxed) {
            break;
        }
        if let Some(b) = opts.time_budget {
            pass = next_budget_pass(b, elapsed, s0, pass);
        }
    }
    let seconds = if s0 == 0 {
        start.elapsed().as_secs_f64()
    } else {
        seconds
    };
    sums.output(w, h, s0, opts, seconds)
}

/// Under a time budget of `budget` seconds, the samples a pixel of the next pass: as many
/// as fit in a twentieth of the budget at the rate so far (`elapsed` seconds for `done`
/// samples), so that the last pass overshoots the budget by about 5 %; at least 1, and at
/// most twice `last`, against a misestimate from a short first pass.
fn next_budget_pass(budget: f64, elapsed: f64, done: u32, last: u32) -> u32 {
    let per_sample = elapsed / done.max(1) as f64;
    ((0.05 * budget / per_sample) as u32).clamp(1, last.saturating_mul(2).max(1))
}

/// A tile's pixels: columns `x0..x1` of rows `y0..y1`.
#[derive(Clone, Copy)]
struct TileRect {
    x0: usize,
    y0: usize,
    x1: usize,
    y1: usize,
}

/// One pass over a tile: samples `passes` of each of its pixels, each with its own random
/// stream; the wavefront traces wavefront::SLOTS (256) at a time and batches their decoder
/// draws. The sums come in the tile's row order; `None` when a stop request came inside a
/// long path (the tile is then incomplete).
fn trace_tile(
    scene: &SceneData,
    set: &IntegratorSettings,
    seed: u64,
    rect: TileRect,
    passes: std::ops::Range<u32>,
    cancel: &AtomicBool,
) -> Option<(Vec<PixelSum>, PathStats)> {
    let cam = &scene.camera;
    let w = cam.width as usize;
    let TileRect { x0, y0, x1, y1 } = rect;
    let tw = x1 - x0;
    let mut st = PathStats::default();
    let mut out: Vec<PixelSum> = vec![([0f64; 3], 0, [0f64; 3]); tw * (y1 - y0)];
    let mut samples = (y0..y1)
        .flat_map(|y| (x0..x1).map(move |x| (x, y)))
        .flat_map(|(x, y)| passes.clone().map(move |s| (x, y, s)));
    let mut camera_rays = CameraRays::default();
    let next = || {
        let (x, y, s) = samples.next()?;
        let pixel = (y * w + x) as u64;
        let (rng, jx, jy, channel) = pixel_sample(seed, pixel, s);
        let dir = cam.ray_dir(x as f32 + jx, y as f32 + jy);
        Some(Sample {
            origin: cam.ray_origin(dir),
            dir,
            first_hit: Some(camera_rays.first_hit(scene, pixel, s, dir)),
            channel,
            rng,
            tag: ((y - y0) * tw + (x - x0)) as u64,
        })
    };
    let whole = trace_many(
        scene,
        set,
        next,
        |tag, channel, l, path| {
            let px = &mut out[tag as usize];
            px.0[channel] += 3.0 * l as f64;
            px.1 += path.events + path.steps;
            px.2[channel] += (l as f64) * (l as f64);
            st.add(path);
        },
        cancel,
    );
    whole.then_some((out, st))
}

/// A render's sums by pixel, in image order, over the passes finished so far.
struct Sums {
    sum: Vec<[f64; 3]>,
    /// Empty without a variance image.
    squares: Vec<[f64; 3]>,
    /// Events and sphere steps.
    work: Vec<u64>,
    stats: PathStats,
}

impl Sums {
    fn new(pixels: usize, variance: bool) -> Self {
        Self {
            sum: vec![[0f64; 3]; pixels],
            squares: if variance {
                vec![[0f64; 3]; pixels]
            } else {
                Vec::new()
            },
            work: vec![0u64; pixels],
            stats: PathStats::default(),
        }
    }

    /// Adds a tile's pass (`out` in the tile's row order; columns `x0..x1` from row `y0`
    /// of an image `w` wide). Each pixel gets one addition a pass, from its one tile, so
    /// the order in which the tiles finished does not matter.
    fn add_tile(
        &mut self,
        x0: usize,
        y0: usize,
        x1: usize,
        w: usize,
        out: Vec<PixelSum>,
        st: &PathStats,
    ) {
        self.stats.add(st);
        for (i, (v, n, q)) in out.into_iter().enumerate() {
            let (dx, dy) = (i % (x1 - x0), i / (x1 - x0));
            let at = (y0 + dy) * w + x0 + dx;
            for (s, v) in self.sum[at].iter_mut().zip(v) {
                *s += v;
            }
            if let Some(sq) = self.squares.get_mut(at) {
                for (s, q) in sq.iter_mut().zip(q) {
                    *s += q;
                }
            }
            self.work[at] += n;
        }
    }

    /// The image of `spp` samples a pixel, its variance image where asked for and
    /// possible, and the work per path.
    fn output(
        self,
        w: usize,
        h: usize,
        spp: u32,
        opts: &RenderOptions,
        seconds: f64,
    ) -> RenderOutput {
        let mut image = RgbImage::new(w, h);
        for (i, (px, s)) in image.pixels.iter_mut().zip(&self.sum).enumerate() {
            *px = resolve_pixel(*s, spp, opts.seed, i as u32);
        }
        let variance = (opts.variance && spp >= MIN_VARIANCE_SPP).then(|| {
            let mut v = RgbImage::new(w, h);
            for (i, px) in v.pixels.iter_mut().enumerate() {
                *px = pixel_variance(self.sum[i], self.squares[i], spp, opts.seed, i as u32);
            }
            v
        });
        RenderOutput {
            image,
            spp,
            seconds,
            compile_seconds: 0.0,
            stats: self.stats,
            work: self
                .work
                .iter()
                .map(|&n| (n as f64 / spp.max(1) as f64) as f32)
                .collect(),
            dispatch: DispatchStats::default(),
            variance,
        }
    }
}

/// Fewest spp for a variance image: every channel then has at least 2 samples.
pub const MIN_VARIANCE_SPP: u32 = 6;

/// How many of `spp` samples of a pixel traced each channel (the hero channel of sample s
/// is `(s % 3 + offset) % 3`; see [`resolve_pixel`]).
fn channel_counts(spp: u32, seed: u64, pixel: u32) -> [u32; 3] {
    let offset = channel_offset(seed, pixel);
    std::array::from_fn(|c| {
        // Samples s < spp with (s + offset) % 3 == c: the first is (c − offset) mod 3.
        let first = (c as u32 + 3 - offset) % 3;
        if spp > first {
            (spp - 1 - first) / 3 + 1
        } else {
            0
        }
    })
}

/// The variance of a pixel's value per channel from its sums (each sample's estimate
/// added ×3 to `sum`, squared to `squares`): the unbiased sample variance of the channel's
/// n estimates over n. Needs n ≥ 2 in every channel ([`MIN_VARIANCE_SPP`]).
pub fn pixel_variance(
    sum: [f64; 3],
    squares: [f64; 3],
    spp: u32,
    seed: u64,
    pixel: u32,
) -> [f32; 3] {
    let counts = channel_counts(spp, seed, pixel);
    std::array::from_fn(|c| {
        let n = counts[c] as f64;
        let mean = sum[c] / (3.0 * n);
        let s2 = ((squares[c] - n * mean * mean) / (n - 1.0)).max(0.0);
        // Scenes bound every radiance (scene::MAX_RADIANCE), so this stays far below
        // f32::MAX; the clamp keeps a variance image finite should a path bring more.
        (s2 / n).min(f64::from(f32::MAX)) as f32
    })
}

#[cfg(test)]
mod tests {
    use super::{
        MIN_VARIANCE_SPP, next_budget_pass, pixel_sample, pixel_variance, resolve_pixel, tile_side,
    };
    use scatter_sim::rng::splitmix64;

    /// `pixel_variance` from the renderers' running sums (×3 estimates in `sum`, squares
    /// in `squares`, channels from `pixel_sample`) equals the textbook variance of the
    /// channel's mean, Σ(x − x̄)²/(n − 1)/n, computed here in two passes from the samples
    /// themselves, to f32 rounding (1e-5 relative). The seed-spread test in integrators.rs
    /// cannot see an n against n − 1 (8/7 at its 8 samples a channel); this sees any
    /// such factor.
    #[test]
    fn the_variance_is_that_of_each_channels_mean() {
        for seed in [1u64, 9] {
            for pixel in 0..20u32 {
                for spp in [MIN_VARIANCE_SPP, 7, 13, 40] {
                    let mut samples: [Vec<f64>; 3] = Default::default();
                    let (mut sum, mut squares) = ([0f64; 3], [0f64; 3]);
                    for s in 0..spp {
                        let c = pixel_sample(seed, pixel as u64, s).3;
                        let bits = splitmix64(seed ^ ((pixel as u64) << 32 | s as u64));
                        // Estimates from 0 to 5, with a spike now and then.
                        let l = (bits >> 11) as f64 / (1u64 << 53) as f64 * 5.0;
                        let l = if bits.is_multiple_of(7) { 40.0 * l } else { l };
                        samples[c].push(l);
                        sum[c] += 3.0 * l;
                        squares[c] += l * l;
                    }
                    let got = pixel_variance(sum, squares, spp, seed, pixel);
                    for c in 0..3 {
                        let x = &samples[c];
                        let n = x.len() as f64;
                        let mean = x.iter().sum::<f64>() / n;
                        let want =
                            x.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0) / n;
                        assert!(
                            (got[c] as f64 - want).abs() <= 1e-5 * want.max(1e-12),
                            "seed {seed} pixel {pixel} spp {spp} channel {c}: {} vs {want}",
                            got[c]
                        );
                    }
                }
            }
        }
    }

    /// Samples whose estimates are all 1 (a white furnace) resolve to exactly 1 in every
    /// channel at any spp from 3, whichever channel a pixel starts with; the sums are
    /// built sample by sample with `pixel_sample`'s channels, as the renderers build them.
    /// Below 3 spp a channel without a sample is 0 and the others 3/spp.
    #[test]
    fn each_channel_is_the_mean_of_its_own_samples() {
        for seed in [1u64, 7] {
            for pixel in 0..30u32 {
                for spp in 1..40u32 {
                    let mut sum = [0f64; 3];
                    for s in 0..spp {
                        sum[pixel_sample(seed, pixel as u64, s).3] += 3.0;
                    }
                    let got = resolve_pixel(sum, spp, seed, pixel);
                    if spp >= 3 {
                        assert_eq!(got, [1.0; 3], "seed {seed} pixel {pixel} spp {spp}");
                    } else {
                        // One channel 3 (1 spp) or two 1.5 (2 spp), the rest 0.
                        let mut sorted = got;
                        sorted.sort_by(f32::total_cmp);
                        let want = if spp == 1 {
                            [0.0, 0.0, 3.0]
                        } else {
                            [0.0, 1.5, 1.5]
                        };
                        assert_eq!(sorted, want, "seed {seed} pixel {pixel} spp {spp}");
                    }
                }
            }
        }
    }

    /// The three samples of a triple share their jitter and cover the three channels, and
    /// each channel's jitters are uniform over the pixel: a Kolmogorov–Smirnov test of
    /// 20,000 jitters per axis and channel (pixels 0..10,000, two triples each). At this
    /// size the statistic √n·D exceeds 2.23 with probability 10⁻⁴ for uniform draws, ~6·10⁻⁴
    /// over the six tests; a jitter that covers only part of the pixel or crowds one side of
    /// it fails (0.9 of its width gives √n·D ≈ 14, 4 bits of the hash ≈ 8.8).
    #[test]
    fn triples_share_a_uniform_jitter() {
        for channel in 0..3 {
            let (mut xs, mut ys) = (Vec::new(), Vec::new());
            for pixel in 0..10_000u64 {
                for triple in 0..2u32 {
                    let samples: Vec<_> = (3 * triple..3 * triple + 3)
                        .map(|s| pixel_sample(5, pixel, s))
                        .collect();
                    let mut channels: Vec<_> = samples.iter().map(|t| t.3).collect();
                    channels.sort();
                    assert_eq!(channels, [0, 1, 2]);
                    assert!(
                        samples
                            .iter()
                            .all(|t| (t.1, t.2) == (samples[0].1, samples[0].2))
                    );
                    let mine = samples.iter().find(|t| t.3 == channel).unwrap();
                    xs.push(mine.1 as f64);
                    ys.push(mine.2 as f64);
                }
            }
            for v in [&mut xs, &mut ys] {
                let n = v.len() as f64;
                let d = scatter_sim::stats::ks_one_sample(v, |x| x);
                assert!(
                    n.sqrt() * d < 2.23,
                    "channel {channel}: KS √n·D = {}",
                    n.sqrt() * d
                );
            }
        }
    }

    /// A time budget's passes: a twentieth of the budget at the rate measured so far,
    /// never below 1 sample and never more than double the last pass.
    #[test]
    fn budget_passes_take_a_twentieth_of_the_budget() {
        // A 16 s budget, 64 samples in 0.5 s: 0.8 s holds 102.4 samples, below 2 × 64.
        assert_eq!(next_budget_pass(16.0, 0.5, 64, 64), 102);
        // The same after a pass of 32: capped at 64.
        assert_eq!(next_budget_pass(16.0, 0.5, 64, 32), 64);
        // Slower than a twentieth of the budget a sample (1.5 s of 0.5 s): still 1.
        assert_eq!(next_budget_pass(10.0, 3.0, 2, 8), 1);
    }

    /// 16-pixel tiles wherever they make at least 64 tiles, else 8.
    #[test]
    fn small_images_get_smaller_tiles() {
        assert_eq!(tile_side(128, 128), 16); // 64 tiles
        assert_eq!(tile_side(127, 127), 16); // 8 × 8 tiles, the last ones partial
        assert_eq!(tile_side(112, 128), 8); // 7 × 8 = 56 tiles
        assert_eq!(tile_side(64, 64), 8);
        assert_eq!(tile_side(1024, 16), 16); // 64 × 1
    }
}
