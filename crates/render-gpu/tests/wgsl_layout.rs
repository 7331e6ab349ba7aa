//! The host's structs and buffer sizes against the layouts that naga gives the WGSL
//! kernels, as wgpu compiles them: no adapter is needed, so this runs wherever the tests
//! do. A field added, moved or resized on one side only (or an array size such as the
//! lights' changed in Rust alone) would make the kernels read every later field from the
//! wrong bytes, which the image tests would show only as a wrong picture on a machine with
//! an adapter.

mod common;

use std::mem::{offset_of, size_of};

use render_gpu::gpu::kernels::{self, Kernel, KernelShape, SceneSwitches};
use render_gpu::gpu::model_buffers::ModelParams;
use render_gpu::gpu::resources;
use render_gpu::gpu::scene_buffers::{GpuLight, GpuNode, GpuTri, Params};
use wgpu::naga;

/// A Rust struct's fields with their byte offsets, in declaration order.
macro_rules! fields {
    ($t:ty; $($f:ident),* $(,)?) => {
        vec![$((stringify!($f), offset_of!($t, $f))),*]
    };
}

/// Every kernel the renderer builds, in each shape that changes its source's structs or
/// bindings: PT, ST-CVAE and the probes; single kernel and staged; with and without
/// path-level NEE reservoirs; each scene switch on and off.
fn sources() -> Vec<(String, String)> {
    let model = common::load_model();
    let mut out = Vec::new();
    for kernel in [Kernel::Pt, Kernel::Stcvae, Kernel::Probe] {
        for staged in [false, true] {
            for path_nee_m in [0, 2] {
                for on in [false, true] {
                    let switches = SceneSwitches {
                        overlaps: on,
                        dielectric: on,
                        env_map: on,
                        lights: if on { 6 } else { 1 },
                        nee: on,
                        variance: on,
                    };
                    let shape = KernelShape {
                        staged,
                        ..KernelShape::default()
                    };
                    let src =
                        kernels::source(kernel, Some(&model), path_nee_m, switches, shape).unwrap();
                    let name = format!("{kernel:?} staged {staged} m {path_nee_m} switches {on}");
                    out.push((name, src));
                }
            }
        }
    }
    out
}

fn parse(name: &str, src: &str) -> naga::Module {
    let module = naga::front::wgsl::parse_str(src)
        .unwrap_or_else(|e| panic!("{name}: {}", e.emit_to_string(src)));
    naga::valid::Validator::new(
        naga::valid::ValidationFlags::all(),
        naga::valid::Capabilities::all(),
    )
    .validate(&module)
    .unwrap_or_else(|e| panic!("{name}: {}", e.emit_to_string(src)));
    module
}

/// The members (name, offset) and size of the WGSL struct `name`.
fn wgsl_struct(module: &naga::Module, name: &str) -> (Vec<(String, usize)>, usize) {
    let (_, ty) = module
        .types
        .iter()
        .find(|(_, t)| t.name.as_deref() == Some(name))
        .unwrap_or_else(|| panic!("no struct {name} in the WGSL"));
    match &ty.inner {
        naga::TypeInner::Struct { members, span } => (
            members
                .iter()
                .map(|m| (m.name.clone().unwrap_or_default(), m.offset as usize))
                .collect(),
            *span as usize,
        ),
        other => panic!("{name} is not a struct: {other:?}"),
    }
}

/// The byte size of one element of the storage buffer at `binding` (of the array's
/// element for a runtime-sized array, else of the whole variable's type).
fn element_size(module: &naga::Module, binding: u32) -> usize {
    let mut layouter = naga::proc::Layouter::default();
    layouter.update(module.to_ctx()).unwrap();
    let (_, var) = module
        .global_variables
        .iter()
        .find(|(_, v)| v.binding.as_ref().is_some_and(|b| b.binding == binding))
        .unwrap_or_else(|| panic!("no binding {binding}"));
    let ty = match module.types[var.ty].inner {
        naga::TypeInner::Array {
            base,
            size: naga::ArraySize::Dynamic,
            ..
        } => base,
        _ => var.ty,
    };
    layouter[ty].size as usize
}

fn assert_layout(
    kernel: &str,
    module: &naga::Module,
    wgsl: &str,
    rust: Vec<(&str, usize)>,
    size: usize,
) {
    let (members, span) = wgsl_struct(module, wgsl);
    let members: Vec<(&str, usize)> = members.iter().map(|(n, o)| (n.as_str(), *o)).collect();
    assert_eq!(
        members, rust,
        "{kernel}: WGSL {wgsl}'s fields and offsets against the host's"
    );
    assert_eq!(
        span, size,
        "{kernel}: WGSL {wgsl}'s size against the host's"
    );
}

/// The host mirrors of the kernels' structs (`#[repr(C)]`, uploaded with bytemuck) have
/// the WGSL structs' fields in the same order at the same offsets, and the same size; the
/// storage buffers' elements (triangles, packed BVH nodes) are as large as the host's; the
/// staged render's queue header is where the host puts the queues' items. Exact byte
/// counts: any difference is a misread buffer.
#[test]
fn host_structs_match_the_wgsl_layouts() {
    for (name, src) in sources() {
        let module = parse(&name, &src);
        assert_layout(
            &name,
            &module,
            "Light",
            fields!(GpuLight; to_light, irradiance, radiance),
            size_of::<GpuLight>(),
        );
        assert_layout(
            &name,
            &module,
            "Params",
            fields!(Params; cam_origin, cam_forward, cam_right, cam_up, sigma_t, albedo,
                ln_albedo, one_minus_albedo, albedo_feature, env_radiance, grid_lo, grid_dims,
                lights, image, sampling, flags, misc, consts, consts2, consts3, consts4,
                pieces),
            size_of::<Params>(),
        );
        assert_layout(
            &name,
            &module,
            "Tri",
            fields!(GpuTri; v0, v1, v2, n),
            size_of::<GpuTri>(),
        );
        assert_layout(
            &name,
            &module,
            "ModelParams",
            fields!(ModelParams; flags),
            size_of::<ModelParams>(),
        );
        assert_eq!(
            element_size(&module, 3),
            size_of::<GpuTri>(),
            "{name}: tris"
        );
        assert_eq!(
            element_size(&module, 4),
            size_of::<GpuNode>(),
            "{name}: nodes"
        );
        assert_eq!(
            element_size(&module, 0),
            size_of::<Params>(),
            "{name}: params"
        );
        if name.contains("staged true") && !name.starts_with("Probe") {
            let (members, _) = wgsl_struct(&module, "Queue");
            let items = members.iter().find(|(n, _)| n == "items").unwrap().1;
            assert_eq!(
                items as u64,
                resources::QUEUE_HEAD,
                "{name}: the queues' items after the header"
            );
            assert_eq!(
                element_size(&module, 10) as u64,
                resources::ARGS_BYTES,
                "{name}: the indirect arguments"
            );
        }
    }
}

/// A kernel's source with the host's constants removed no longer compiles: the WGSL has
/// no copies of its own to fall back on (a copy would drift from the host's value
/// silently). Each name below is used by the kernels and defined only on the host
/// (gpu/kernels.rs, or gpu/decoder_gen.rs for the decoders' scratch and features): no
/// file in shaders/ defines it (the assembled source's one definition could otherwise
/// be a shader's own, with the host's prepending dropped).
#[test]
fn the_kernels_take_these_constants_from_the_host_alone() {
    let (name, src) = sources()
        .into_iter()
        .find(|(n, _)| n.starts_with("Stcvae staged true m 2 switches true"))
        .unwrap();
    parse(&name, &src);
    let shader_dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shaders");
    let shaders: Vec<(String, String)> = std::fs::read_dir(&shader_dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|x| x == "wgsl"))
        .map(|p| {
            (
                p.display().to_string(),
                std::fs::read_to_string(&p).unwrap(),
            )
        })
        .collect();
    assert!(shaders.len() >= 8, "{}: the shaders", shader_dir.display());
    for constant in [
        "RR_THRESHOLD",
        "MAX_ITERATIONS",
        "SHRINK",
        "EXACT_DISTANCE_SHRINK",
        "BALL_CHORD_SHRINK",
        "LOCAL_REACH_SHRINK",
        "UPPER_BOUND_SLACK",
        "PLANE_SLACK_OF_EPS",
        "CROSSING_TOL_OF_EPS",
        "GRAZING_COS_FLOOR",
        "PHASE_SHARE",
        "MAX_LIGHTS",
        "MAX_PROXY_LIGHTS",
        "MAX_EXACT_EVENTS",
        "ACC",
        "ACC_LO",
        "COMMITTED",
        "ACC_SQ",
        "ACC_SQ_LO",
        "SQ_COMMITTED",
        "QUEUES",
        "QUEUE_LENGTHS",
        "STAGE_ARGS",
        "STEP_ARGS",
        "QUERY_ARGS",
        "ARGS_WORDS",
        "C_PATHS",
        "C_PENDING",
        "C_EXACT_EVENTS",
        "DEC_MAX_COND",
        "DEC_MAX_NOISE",
        "DEC_MAX_OUT",
        "MAX_DECODED_N",
        "PRIOR_QUADRATIC",
        "PRIOR_LINEAR",
    ] {
        let definition = format!("const {constant}: ");
        assert_eq!(
            src.matches(&definition).count(),
            1,
            "{constant} is defined once"
        );
        for (file, text) in &shaders {
            assert!(
                !text.contains(&definition),
                "{file} defines {constant}: it must come from the host (gpu/kernels.rs or gpu/decoder_gen.rs)"
            );
        }
        let without: String = src
            .lines()
            .filter(|l| !l.starts_with(&definition))
            .collect::<Vec<_>>()
            .join("\n");
        assert!(
            naga::front::wgsl::parse_str(&without).is_err(),
            "{constant}: the kernels compile without the host's definition"
        );
    }
}
