//! Runs the test entry points of `shaders/probe.wgsl` so tests can compare the WGSL
//! building blocks (decoders, HG sampling, canonical frame, ray queries) with the Rust
//! ones.

use crate::error::RenderError;

use super::context::GpuContext;
use super::kernels::{self, Kernel, KernelShape};
use super::model_buffers::model_params;
use super::resources::{COUNTER_BYTES, Inputs, Resources, read_back, wait};
use super::scene_buffers::{GpuNode, GpuTri, Params, geometry_buffers, grid_buffer};

/// One probe item: 32 floats in, 32 floats out (layouts in `shaders/probe.wgsl`).
pub type Item = [f32; 32];

/// Runs `entry` (a probe kernel of shaders/probe.wgsl that needs no scene) over `items`.
pub fn run_probe(
    ctx: &GpuContext,
    entry: &str,
    model: &cvae::ModelSet,
    items: &[Item],
) -> Result<Vec<Item>, RenderError> {
    run_probe_on(ctx, entry, model, items, None)
}

/// Runs `entry` over `items` with a scene's geometry (and distance grid, if built)
/// uploaded ("probe_ray", "probe_grid", "probe_local_hit", "probe_shadow").
pub fn run_probe_on(
    ctx: &GpuContext,
    entry: &str,
    model: &cvae::ModelSet,
    items: &[Item],
    scene: Option<&crate::setup::SceneData>,
) -> Result<Vec<Item>, RenderError> {
    probe(ctx, entry, model, items, scene, KernelShape::default()).map(|(items, _)| items)
}

/// The path counters the counter probe fills ([`super::resources::PATH_COUNTERS`]).
pub const PROBE_COUNTERS: usize = super::resources::PATH_COUNTERS as usize;

/// Runs "probe_counters": item i's counts are added to the path counters as a
/// path slot adds its own (shaders/path.wgsl, add_stats), once per subgroup if
/// `aggregate` (and the adapter has subgroup operations), else once per item. Returns
/// the counters' totals.
pub fn run_counter_probe(
    ctx: &GpuContext,
    model: &cvae::ModelSet,
    counts: &[[u32; PROBE_COUNTERS]],
    aggregate: bool,
) -> Result<[u64; PROBE_COUNTERS], RenderError> {
    let items: Vec<Item> = counts
        .iter()
        .map(|c| std::array::from_fn(|k| f32::from_bits(c.get(k).copied().unwrap_or(0))))
        .collect();
    let shape = KernelShape {
        aggregate,
        ..KernelShape::default()
    };
    let (_, counters) = probe(ctx, "probe_counters", model, &items, None, shape)?;
    let word = |i: usize| u32::from_le_bytes(counters[4 * i..4 * i + 4].try_into().unwrap());
    Ok(std::array::from_fn(|k| {
        word(2 * k) as u64 | ((word(2 * k + 1) as u64) << 32)
    }))
}

/// Runs `entry` over `items` (which it must leave as inputs) `times` times in a row, with
/// one compilation and one upload, after an untimed first dispatch (lavapipe compiles a
/// kernel at its first): the seconds of each timed dispatch, from its submission until the
/// GPU is idle, and the items after the last. For throughput (`stcvae bench decoders`):
/// fresh buffers a run, as [`run_probe`] makes (its pipeline the device's kept one after
/// the first), put their cost and its jitter into the time.
pub fn time_probe(
    ctx: &GpuContext,
    entry: &str,
    model: &cvae::ModelSet,
    items: &[Item],
    times: usize,
) -> Result<(Vec<Item>, Vec<f64>), RenderError> {
    let set = ProbeSetup::new(ctx, entry, model, items, None, KernelShape::default())?;
    set.dispatch(ctx);
    wait(ctx)?;
    let mut seconds = Vec::with_capacity(times);
    for _ in 0..times {
        let start = std::time::Instant::now();
        set.dispatch(ctx);
        wait(ctx)?;
        seconds.push(start.elapsed().as_secs_f64());
    }
    Ok((set.items(ctx)?, seconds))
}

/// Runs `entry` over `items` in kernels of `shape`: the items and the counter buffer after.
fn probe(
    ctx: &GpuContext,
    entry: &str,
    model: &cvae::ModelSet,
    items: &[Item],
    scene: Option<&crate::setup::SceneData>,
    shape: KernelShape,
) -> Result<(Vec<Item>, Vec<u8>), RenderError> {
    let set = ProbeSetup::new(ctx, entry, model, items, scene, shape)?;
    set.dispatch(ctx);
    let items = set.items(ctx)?;
    let counters = read_back(ctx, &set.res.counters, COUNTER_BYTES)?;
    Ok((items, counters))
}

/// A probe kernel compiled, its buffers made and its items uploaded.
struct ProbeSetup {
    pipeline: wgpu::ComputePipeline,
    res: Resources,
    bytes: u64,
    groups: u32,
}

impl ProbeSetup {
    fn new(
        ctx: &GpuContext,
        entry: &str,
        model: &cvae::ModelSet,
        items: &[Item],
        scene: Option<&crate::setup::SceneData>,
        shape: KernelShape,
    ) -> Result<Self, RenderError> {
        let (nodes, tris) = match scene {
            Some(s) => geometry_buffers(s)?,
            // A root and the two bounds entries (scene.wgsl, `mesh_bounds`).
            None => (vec![GpuNode::default(); 3], vec![GpuTri::default()]),
        };
        let layout = kernels::bind_group_layout(ctx, false)?;
        let pipeline = kernels::pipeline(
            ctx,
            &layout,
            Kernel::Probe,
            Some(model),
            0,
            scene
                .map(|s| kernels::SceneSwitches::of(s, true))
                .unwrap_or_default(),
            shape,
            entry,
        )?;
        // A scene's constants as a render has them (its medium, boundary and pieces, which
        // the shadow-ray probe reads), or none.
        let mut params = match scene {
            Some(s) => {
                let set = crate::integrator::IntegratorSettings {
                    kind: crate::integrator::IntegratorKind::Pt,
                    nee: true,
                    model: None,
                    min_tau: 0.0,
                    max_tau: 0.0,
                    exact_tau: 0.0,
                    nee_samples: 1,
                    exact_nee_samples: 1,
                    path_nee_rays: 0,
                };
                super::scene_buffers::scene_params(s, &set, 0)
            }
            None => Params::default(),
        };
        params.image[0] = items.len() as u32;
        // (scene_params above set the grid's placement, eps and near_surface.)
        let grid = match scene.and_then(|s| s.grid.as_ref().map(|g| (s, g))) {
            Some((s, g)) => grid_buffer(g, &s.geo),
            None => vec![0],
        };
        let bytes = std::mem::size_of_val(items) as u64;
        let res = Resources::new(
            ctx,
            &layout,
            None,
            &Inputs {
                params: &params,
                accum_bytes: &[bytes],
                nodes: &nodes,
                tris: &tris,
                env: &[[0.0; 4]],
                grid: &grid,
                model: &model_params(model),
                stage_slots: 0,
            },
        )?;
        ctx.queue
            .write_buffer(&res.accums[0], 0, bytemuck::cast_slice(items));
        Ok(Self {
            pipeline,
            res,
            bytes,
            groups: (items.len() as u32).div_ceil(shape.workgroup),
        })
    }

    /// Submits one dispatch over every item.
    fn dispatch(&self, ctx: &GpuContext) {
        self.res.dispatch(ctx, &self.pipeline, (self.groups, 1), 0);
    }

    /// The items as the dispatches left them.
    fn items(&self, ctx: &GpuContext) -> Result<Vec<Item>, RenderError> {
        let out = read_back(ctx, &self.res.accums[0], self.bytes)?;
        // Copied into f32s: a Vec<u8> need not be aligned for them (cast_slice panics).
        Ok(bytemuck::pod_collect_to_vec::<u8, f32>(&out)
            .chunks_exact(32)
            .map(|c| c.try_into().unwrap())
            .collect())
    }
}
