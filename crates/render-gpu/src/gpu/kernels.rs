//! The WGSL kernels, composed from `shaders/` (WGSL has no includes: the shared files are
//! concatenated in a fixed order), and the one bind-group layout they all share.

use std::borrow::Cow;

use crate::error::RenderError;

use super::context::GpuContext;

const COMMON: &str = include_str!("../../../../shaders/common.wgsl");
const SCENE: &str = include_str!("../../../../shaders/scene.wgsl");
const NEE: &str = include_str!("../../../../shaders/nee.wgsl");
const DECODER: &str = include_str!("../../../../shaders/decoder.wgsl");
const PT: &str = include_str!("../../../../shaders/pt.wgsl");
const STCVAE: &str = include_str!("../../../../shaders/stcvae.wgsl");
const PATH: &str = include_str!("../../../../shaders/path.wgsl");
const PROBE: &str = include_str!("../../../../shaders/probe.wgsl");

/// Threads per workgroup of every kernel (`@workgroup_size(64)` in the WGSL).
pub const WORKGROUP: u32 = 64;

/// Entries of each invocation's BVH traversal stack (workgroup memory, shaders/scene.wgsl).
/// A depth-first traversal of a BVH2 of depth D needs at most D + 1; the renderer refuses
/// deeper trees. 48 × 64 invocations × 4 bytes = 12 KiB, under the 16 KiB of workgroup
/// memory every adapter offers.
pub const STACK_DEPTH: u32 = 48;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kernel {
    /// Volumetric path tracing (`render_main`).
    Pt,
    /// ST-CVAE sphere tracing with EventGen NEE (`render_main`).
    Stcvae,
    /// Test entry points (`probe_decoder`, `probe_frame`) over the PT build.
    Probe,
}

/// vec4s of one path slot in the accumulation buffer (`SLOT` in shaders/path.wgsl): the
/// path's state, the render's accumulated RGB (vec4 [`ACC_VEC4`]), and two per path-level
/// NEE reservoir.
pub fn slot_vec4s(path_nee_m: u32) -> u64 {
    5 + 2 * path_nee_m as u64
}

/// Which vec4 of a path slot holds the accumulated RGB and finished-sample count (`ACC`
/// in shaders/path.wgsl).
pub const ACC_VEC4: u64 = 4;

/// The full WGSL source of a kernel with `path_nee_m` path-level NEE reservoirs (0: a
/// shadow ray at every NEE event; at most [`crate::scene::MAX_PATH_NEE_RAYS`]); the ST-CVAE
/// and probe kernels include the model's decoders, generated as straight-line code.
pub fn source(
    kernel: Kernel,
    model: Option<&cvae::ModelSet>,
    path_nee_m: u32,
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
    // shadow-ray roulette threshold and flight margin from the CPU integrator's (nee.wgsl,
    // path.wgsl), and the node packing's count bits from GpuNode's.
    let stack = format!(
        "const STACK_DEPTH: u32 = {STACK_DEPTH}u;\nvar<workgroup> wg_stack: array<u32, {}>;\n\
         const ROULETTE_BOUND: f32 = {:?};\nconst FLIGHT_MARGIN_OF_EPS: f32 = {:?};\n\
         const EXIT_REFINE_TAU: f32 = {:?};\nconst SLIVER_REACH_OF_EPS: f32 = {:?};\n\
         const PATH_NEE_M: u32 = {path_nee_m}u;\nconst SLOT: u32 = {}u;\n\
         const NODE_COUNT_BITS: u32 = {}u;\n",
        STACK_DEPTH * WORKGROUP,
        crate::integrator::nee::ROULETTE_BOUND,
        crate::geometry::FLIGHT_MARGIN_OF_EPS,
        crate::integrator::sphere_step::EXIT_REFINE_TAU,
        crate::geometry::SLIVER_REACH_OF_EPS,
        slot_vec4s(path_nee_m),
        super::scene_buffers::GpuNode::COUNT_BITS,
    );
    let parts: &[&str] = match kernel {
        Kernel::Pt => &[COMMON, &stack, SCENE, NEE, PT, PATH],
        Kernel::Stcvae => &[COMMON, &stack, SCENE, NEE, DECODER, &decoders, STCVAE, PATH],
        Kernel::Probe => &[
            COMMON, &stack, SCENE, NEE, DECODER, &decoders, PT, PATH, PROBE,
        ],
    };
    Ok(parts.join("\n"))
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

/// The bind-group layout of `shaders/scene.wgsl`: params, accum, counters, triangles,
/// nodes, environment map, distance grid, model params.
pub fn bind_group_layout(ctx: &GpuContext) -> wgpu::BindGroupLayout {
    ctx.device
        .create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("stcvae scene"),
            entries: &[
                uniform(0),
                storage(1, false),
                storage(2, false),
                storage(3, true),
                storage(4, true),
                storage(5, true),
                storage(6, true),
                uniform(7),
            ],
        })
}

/// Compiles `entry` of `kernel` (with `path_nee_m` path-level NEE reservoirs, see
/// [`source`]); shader or pipeline errors come back as errors, not panics (wgpu's default
/// handler would abort).
pub fn pipeline(
    ctx: &GpuContext,
    layout: &wgpu::BindGroupLayout,
    kernel: Kernel,
    model: Option<&cvae::ModelSet>,
    path_nee_m: u32,
    entry: &str,
) -> Result<wgpu::ComputePipeline, RenderError> {
    let src = source(kernel, model, path_nee_m)?;
    let scope = ctx.device.push_error_scope(wgpu::ErrorFilter::Validation);
    let module = ctx
        .device
        .create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some(entry),
            source: wgpu::ShaderSource::Wgsl(Cow::Owned(src)),
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
            // they are read: zero-filling 12 KiB per workgroup would be wasted work.
            compilation_options: wgpu::PipelineCompilationOptions {
                zero_initialize_workgroup_memory: false,
                ..Default::default()
            },
            cache: None,
        });
    if let Some(e) = pollster::block_on(scope.pop()) {
        return Err(RenderError::Gpu(format!(
            "the {kernel:?} kernel did not compile on {}: {e}",
            ctx.adapter
        )));
    }
    Ok(p)
}
