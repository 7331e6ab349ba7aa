//! How the work is cut changes no image: long paths resumed across dispatches, a
//! dispatch the loop limit cut off redone with fewer bounces, rows of workgroups, samples
//! per chunk, kernel shapes, the staged render and the lane profile. And what the device
//! is owed: each kernel compiled once, no more samples than the slots hold, sums that do
//! not drift, errors reported rather than panics, no pixel left unwritten.

use super::*;

/// The message of a render that must have been refused (`what` names it otherwise).
fn refusal(r: Result<RenderOutput, RenderError>, what: &str) -> String {
    match r {
        Ok(_) => panic!("{what} rendered"),
        Err(e) => e.to_string(),
    }
}

/// A pixel the kernels never write is an error, not a black pixel: the host poisons the
/// accumulation with NaN before the first dispatch, and a test hook has the kernels leave
/// one pixel's slots alone, in the single kernel and in the staged render. Without the
/// poison those slots would read as zeros and fail the finished-sample count instead, with
/// another message, so this holds the poison in place as well as the check. The same
/// render without the hook succeeds.
#[test]
fn an_unwritten_pixel_is_an_error() {
    let Some(ctx) = gpu() else {
        return;
    };
    let ctx = ctx.lock().unwrap_or_else(|e| e.into_inner());
    let s = common::build_scene(&sphere_scene("kind = \"index-matched\""), false);
    let set = settings(IntegratorKind::Pt, true);
    for staged in ["0", "1"] {
        let vars = [
            ("STCVAE_GPU_TEST_UNWRITTEN_PIXEL", "300"),
            ("STCVAE_GPU_STAGED", staged),
        ];
        let Err(err) = render_gpu_with_env(&ctx, &s, &set, &opts(3, 1), &vars) else {
            panic!("staged {staged}: a pixel left unwritten rendered without an error");
        };
        let err = err.to_string();
        assert!(
            err.contains("1 of 576 pixels came back unwritten or non-finite"),
            "staged {staged}: {err}"
        );
        let fine = render_gpu_with_env(&ctx, &s, &set, &opts(3, 1), &vars[1..]).unwrap();
        assert!(fine.image.pixels.iter().flatten().all(|v| v.is_finite()));
    }
    // A pixel beyond the image would leave every pixel written and test nothing.
    let beyond = [("STCVAE_GPU_TEST_UNWRITTEN_PIXEL", "576")];
    let Err(err) = render_gpu_with_env(&ctx, &s, &set, &opts(3, 1), &beyond) else {
        panic!("a hook beyond the image was taken");
    };
    assert!(
        err.to_string().contains("beyond the image's 576 pixels"),
        "{err}"
    );
}

/// Long paths (τ = 500, albedo 0.999: ~180 events on average, heavy-tailed, many beyond
/// the ~650 PT events one invocation could loop on lavapipe, whose shaders stop after
/// 65,535 loop iterations in total) must resume across dispatches (128 bounces each on a
/// software adapter, fewer after a cut-off), every sample must finish (the renderer errors otherwise), and the
/// image mean must agree with the CPU's. The z-score of the difference of the two image
/// means uses the spread of 8 seeds per device, so it is Welch's t with at least 7 degrees
/// of freedom: |t₇| > 5.4 has probability 1e-3. A truncated or lost path population
/// darkens the object by far more.
///
/// The same for ST-CVAE with every collision a PT fallback (min_tau beyond any ball) and
/// path-level NEE: its reservoirs must travel with the path between dispatches (path.wgsl,
/// save_path / load_path_nee). Reservoirs reset at each dispatch instead lose the NEE of
/// every event before a path's last dispatch: z = 7.0 when checked at 24 spp a render,
/// which a t₇ bound of 5.4 (the spread itself estimated from 8 seeds) misses ~15 % of the
/// time; at [`MEANS_SPP`] = 96 the shift doubles to ~14.
#[test]
fn long_paths_resume_across_dispatches() {
    let pt = settings(IntegratorKind::Pt, true);
    long_paths_agree("PT", &pt);
    let st = IntegratorSettings {
        min_tau: 1e30,
        ..settings(IntegratorKind::Stcvae, true)
    };
    long_paths_agree("ST-CVAE fallbacks, path-level NEE", &st);
}

fn long_paths_agree(name: &str, set: &IntegratorSettings) {
    let text = with_medium(
        sphere_scene("kind = \"index-matched\""),
        "[1000.0, 1000.0, 1000.0]",
        "[0.999, 0.999, 0.999]",
    )
    .replace("width = 24\nheight = 24", "width = 8\nheight = 8")
    .replace("fov_deg = 22.0", "fov_deg = 12.0");
    let s = common::build_scene(&text, set.kind == IntegratorKind::Stcvae);
    image_means_agree(name, &s, set, &[], 150.0);
}

/// Path-level NEE's shadow rays are cast one per bounce after the path's end (path.wgsl,
/// bounce), so a dispatch can end between them: the rays left and the partial sums travel
/// with the path (save_path). With one bounce per dispatch (STCVAE_GPU_BOUNCES=1) and two
/// reservoirs, every path's rays are split across dispatches, and the image mean must
/// agree with the CPU's (Welch's t as in `long_paths_resume_across_dispatches`; z = -1.5
/// on lavapipe at 24 spp a render). A sum lost between dispatches drops a reservoir's NEE
/// from every path: not restoring p_nee_sum gave z = 34 at 24 spp (image mean 0.141
/// against the CPU's 0.214).
#[test]
fn path_nee_rays_resume_across_dispatches() {
    let text = sphere_scene("kind = \"index-matched\"")
        .replace("width = 24\nheight = 24", "width = 8\nheight = 8")
        .replace("fov_deg = 22.0", "fov_deg = 12.0");
    let s = common::build_scene(&text, true);
    let set = IntegratorSettings {
        path_nee_rays: 2,
        ..settings(IntegratorKind::Stcvae, true)
    };
    image_means_agree(
        "ST-CVAE, two path-level NEE rays, one bounce per dispatch",
        &s,
        &set,
        &[("STCVAE_GPU_BOUNCES", "1")],
        0.0,
    );
}

/// Samples per pixel of each of [`image_means_agree`]'s renders.
const MEANS_SPP: u32 = 96;

/// The image means of 8 CPU renders (seeds 1–8) and 8 GPU renders (seeds 9–16, with the
/// environment `vars`) agree: |Welch's t| < 5.4 (at least 7 degrees of freedom:
/// probability 1e-3). `min_events`: PT events per path the scene must make.
fn image_means_agree(
    name: &str,
    s: &SceneData,
    set: &IntegratorSettings,
    vars: &[(&str, &str)],
    min_events: f64,
) {
    let Some(ctx) = gpu() else { return };
    let ctx = ctx.lock().unwrap_or_else(|e| e.into_inner());
    let mean = |o: &RenderOutput| {
        o.image
            .pixels
            .iter()
            .map(|p| (p[0] + p[1] + p[2]) as f64)
            .sum::<f64>()
            / (3 * o.image.pixels.len()) as f64
    };
    let stats = |v: &[f64]| {
        let m = v.iter().sum::<f64>() / v.len() as f64;
        let var = v.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / (v.len() as f64 - 1.0);
        (m, var / v.len() as f64)
    };
    let cpu: Vec<f64> = (1..=8)
        .map(|k| mean(&on_cpu(s, set, &opts(MEANS_SPP, k))))
        .collect();
    let mut gpu_means = Vec::new();
    for k in 9..=16 {
        let o = render_gpu_with_env(&ctx, s, set, &opts(MEANS_SPP, k), vars).unwrap();
        assert_eq!(o.stats.paths, 64 * MEANS_SPP as u64);
        // The switches took effect (a renamed variable would leave the test unsplit).
        if let Some((_, b)) = vars.iter().find(|(k, _)| *k == "STCVAE_GPU_BOUNCES") {
            assert_eq!(o.dispatch.bounce_budget.to_string(), *b, "{name}");
        }
        assert!(
            o.stats.events as f64 / o.stats.paths as f64 >= min_events,
            "{name}: the scene must make long paths: {:?}",
            o.stats
        );
        gpu_means.push(mean(&o));
    }
    let (mc, vc) = stats(&cpu);
    let (mg, vg) = stats(&gpu_means);
    let z = (mc - mg) / (vc + vg).sqrt();
    eprintln!("{name}: image mean CPU {mc:.5} GPU {mg:.5}, z = {z:.2}");
    assert!(z.abs() < 5.4, "{name}: CPU {mc} vs GPU {mg}: z = {z}");
}

/// A dispatch cut off by lavapipe's loop limit is undone and redone with half the bounce
/// budget until it fits (gpu/switches.rs, bounce_budget), and the image is the one a
/// budget of 64 gives from the start, bit for bit (PT resumes a path exactly where it
/// stopped). The dense bunny (teaser ×8, 143 events per path) at 100,000 bounces per
/// dispatch was cut off before the fallback existed ("12 invocations were stopped by
/// llvmpipe's loop limit", same scene, size and spp); on a hardware GPU both budgets
/// simply run.
#[test]
fn loop_limit_cut_off_is_redone_with_fewer_bounces() {
    let Some(ctx) = gpu() else { return };
    let ctx = ctx.lock().unwrap_or_else(|e| e.into_inner());
    let text = with_medium(
        sphere_scene("kind = \"index-matched\""),
        "[1200.0, 1500.0, 1000.0]",
        "[0.99999, 0.99995, 0.975]",
    )
    .replace(
        "shape = \"sphere\"\nradius = 0.5",
        "mesh = \"../../assets/bunny.glb\"\nheight = 1.0",
    )
    .replace("g = 0.5", "g = 0.875")
    .replace("width = 24\nheight = 24", "width = 12\nheight = 12");
    let s = common::build_scene(&text, false);
    let set = settings(IntegratorKind::Pt, true);
    let mut images = Vec::new();
    let mut dispatches = Vec::new();
    // 65,535 is the most STCVAE_GPU_BOUNCES allows; far more than a dispatch fits.
    for bounces in ["65535", "64"] {
        let out = render_gpu_with_env(
            &ctx,
            &s,
            &set,
            &opts(3, 9),
            &[("STCVAE_GPU_BOUNCES", bounces)],
        )
        .expect("a cut-off dispatch must be redone, not reported");
        images.push(out.image);
        dispatches.push(out.dispatch);
    }
    assert!(
        images[0].pixels == images[1].pixels,
        "the image depends on the bounce budget"
    );
    // Only a software adapter has the loop limit; there the first render must have been
    // cut off and redone, or this test checked nothing.
    if ctx.adapter.software {
        let d = dispatches[0];
        assert!(
            d.redone > 0 && d.bounce_budget < 65535,
            "65,535 bounces were never cut off: {d:?}"
        );
        // Each redo halves the budget, which nothing else changes: as many halvings of
        // 65,535 as redos (a budget cut faster would skip budgets that fit, leaving fewer
        // bounces a dispatch than fit for the rest of the render).
        assert_eq!(d.bounce_budget, 65535u32 >> d.redone, "{d:?}");
    }
}

/// Long exact walks exceed lavapipe's loop limit at any budget above a few bounces: every
/// step exact up to τ = 49 (exact_tau 50) with g = 0 is a walk of ~1,200 events, ~6 loop
/// iterations each. The renderer halves the bounce budget of a cut-off dispatch until one
/// fits (gpu/switches.rs, bounce_budget); the fourteenth session's binary, which fell back
/// once to 64 bounces, failed on this scene ("3 invocations were stopped by llvmpipe's
/// loop limit"). The images must still agree with the CPU's within noise
/// (`assert_same_image`).
#[test]
fn long_exact_walks_shrink_the_bounce_budget() {
    let text = with_medium(
        sphere_scene("kind = \"index-matched\""),
        "[300.0, 300.0, 300.0]",
        "[0.999, 0.999, 0.999]",
    )
    .replace("g = 0.5", "g = 0.0");
    let set = IntegratorSettings {
        exact_tau: 50.0,
        max_tau: 49.0,
        min_tau: 0.0,
        ..settings(IntegratorKind::Stcvae, true)
    };
    let Some(gpu_runs) = compare_devices_with("long exact walks", &text, &set, 24) else {
        return;
    };
    // At the default budget these walks are cut off only now and then (lavapipe, Mesa 22:
    // when the chunks, grown toward a second of work, give an invocation several paths).
    // So that the halving surely runs on exact walks, one more GPU render starts at 65,535
    // bounces a dispatch with 64 paths an invocation in every chunk, whatever the machine's
    // speed. llvmpipe's limit is one budget of 65,535 loop passes an invocation, shared by
    // all its loops: each path's walks take thousands of passes, so a dispatch that runs
    // all 64 must be cut off (redone 10 times, down to 63 bounces, ~10 s on lavapipe).
    // With 8 paths an invocation it was cut off until the light count became a kernel
    // constant (2026-12-02): the loops over the lights, unrolled, no longer spend passes. It must finish every path (the
    // renderer refuses a pixel short of samples) with a finite image. (It is not compared
    // with the first render's, which ran on other seeds; that a schedule changes no pixel
    // is `samples_per_chunk_change_no_pixel`'s and `staged_render_equals_one_kernel`'s.)
    let ctx = gpu().unwrap().lock().unwrap_or_else(|e| e.into_inner());
    let s = common::build_scene(&text, true);
    let vars = [
        ("STCVAE_GPU_BOUNCES", "65535"),
        ("STCVAE_GPU_LANE_SAMPLES", "64"),
    ];
    let out = render_gpu_with_env(&ctx, &s, &set, &opts(192, 5), &vars)
        .expect("a cut-off dispatch must be redone, not reported");
    assert_eq!(out.stats.paths, out.image.pixels.len() as u64 * 192);
    assert!(out.image.pixels.iter().flatten().all(|v| v.is_finite()));
    if ctx.adapter.software {
        let d = out.dispatch;
        assert!(
            d.redone > 0 && d.bounce_budget < 65535,
            "65,535 bounces were never cut off: {d:?}"
        );
    }
    eprintln!(
        "long exact walks: default budget {:?}; from 65,535: {:?}",
        gpu_runs[0].dispatch, out.dispatch
    );
}

/// PT and ST-CVAE (NEE on) in the single kernel, and ST-CVAE staged: the settings and
/// `STCVAE_GPU_STAGED`'s value of each.
fn every_kernel() -> [(IntegratorSettings<'static>, &'static str); 3] {
    [
        (settings(IntegratorKind::Pt, true), "0"),
        (settings(IntegratorKind::Stcvae, true), "0"),
        (settings(IntegratorKind::Stcvae, true), "1"),
    ]
}

/// A dispatch of more workgroups than a dimension holds (65,535: a hardware band of 2²²
/// path slots at the default 64 threads a workgroup, or of fewer at 8–32) lays them out in
/// rows along y
/// (bands.rs, plan_bands; slot_of's `gid.y`, the staged render's indirect dispatches in
/// dispatch_args and `invocation`), and renders what one row renders, bit for bit: the
/// slots are the same, only the invocations they run on differ. On images small enough
/// for lavapipe the test hook shortens a row to 5 workgroups, leaving the last row part
/// full (the invocations past the band's slots must do nothing): PT and ST-CVAE in the single kernel,
/// ST-CVAE staged.
#[test]
fn dispatches_in_rows_of_workgroups_render_as_in_one() {
    let Some(ctx) = gpu() else { return };
    let ctx = ctx.lock().unwrap_or_else(|e| e.into_inner());
    let text = sphere_scene("kind = \"index-matched\"");
    for (set, staged) in every_kernel() {
        let what = format!("{:?}, staged {staged}", set.kind);
        let s = common::build_scene(&text, set.kind == IntegratorKind::Stcvae);
        let staged = [("STCVAE_GPU_STAGED", staged)];
        let one = render_gpu_with_env(&ctx, &s, &set, &opts(16, 4), &staged).unwrap();
        let rows = [staged[0], ("STCVAE_GPU_TEST_DISPATCH_ROW", "5")];
        let out = render_gpu_with_env(&ctx, &s, &set, &opts(16, 4), &rows).unwrap();
        assert_eq!(one.dispatch.grid_rows, 1, "{what}");
        // On lavapipe 24² pixels at 7 lanes are 63 workgroups of 64: 13 rows of 5, the
        // last of 3.
        assert!(out.dispatch.grid_rows > 1, "{what}: {:?}", out.dispatch);
        assert_same_render(&one, &out, &what);
    }
    for bad in ["0", "65536", "x"] {
        let s = common::build_scene(&text, false);
        let set = settings(IntegratorKind::Pt, true);
        let e = refusal(
            render_gpu_with_env(
                &ctx,
                &s,
                &set,
                &opts(1, 1),
                &[("STCVAE_GPU_TEST_DISPATCH_ROW", bad)],
            ),
            bad,
        );
        assert!(
            e.contains("STCVAE_GPU_TEST_DISPATCH_ROW") && e.contains("allowed 1 to 65535"),
            "{e}"
        );
    }
}

/// A dispatch undone from the snapshot and redone with half the bounce budget renders
/// what that budget renders from the start, bit for bit, in every kernel: the snapshot
/// holds what a dispatch writes (path states, accumulators, the staged render's queues,
/// whose arguments are listed again before the redo's first turn). A real cut-off needs
/// walks past lavapipe's loop limit, which `loop_limit_cut_off_is_redone_with_fewer_bounces`
/// has for PT alone, so the test hook pretends that the first dispatch that resumes paths,
/// and then its redo, were cut off: 8 bounces a dispatch halved twice, against 2 from the
/// start (a dispatch resumes only where some walk outlasts 8 bounces; the counts below
/// fail otherwise). PT and ST-CVAE with NEE in the single kernel, ST-CVAE staged. Only a
/// software adapter keeps a snapshot (a hardware GPU has no loop limit); there the hook
/// pretends nothing, and the two budgets render the same image all the same (paths
/// resume where they stopped). The hook's values are checked in switches.rs's
/// `kernel_shape_takes_only_the_offered_values`, which needs no GPU.
#[test]
fn a_dispatch_undone_renders_as_the_halved_budget_from_the_start() {
    let Some(ctx) = gpu() else { return };
    let ctx = ctx.lock().unwrap_or_else(|e| e.into_inner());
    let text = sphere_scene("kind = \"index-matched\"");
    for (set, staged) in every_kernel() {
        let what = format!("{:?}, staged {staged}", set.kind);
        let s = common::build_scene(&text, set.kind == IntegratorKind::Stcvae);
        let halved = [
            ("STCVAE_GPU_STAGED", staged),
            ("STCVAE_GPU_BOUNCES", "8"),
            ("STCVAE_GPU_TEST_CUT_OFFS", "2"),
        ];
        let out = render_gpu_with_env(&ctx, &s, &set, &opts(4, 5), &halved).unwrap();
        let from_start = [("STCVAE_GPU_STAGED", staged), ("STCVAE_GPU_BOUNCES", "2")];
        let base = render_gpu_with_env(&ctx, &s, &set, &opts(4, 5), &from_start).unwrap();
        let d = out.dispatch;
        let want = if ctx.adapter.software { (2, 2) } else { (0, 8) };
        assert_eq!((d.redone, d.bounce_budget), want, "{what}: {d:?}");
        assert_eq!(base.dispatch.redone, 0, "{what}: {:?}", base.dispatch);
        assert_same_render(&base, &out, &what);
        assert!(out.image.pixels.iter().any(|p| p[0] > 0.0), "{what}");
    }
}

/// A device compiles each kernel once (gpu/kernel_cache.rs: building the pipelines took
/// 1.2–2.3 s a render on lavapipe): a second render of a scene finds every pipeline of the
/// first and renders it bit for bit again, with new buffers and bind groups; another
/// kernel (ST-CVAE after PT; the staged render's five: stage, trace, sphere step and the
/// two arguments' kernels) is built. On a device of its own, whose cache no other test
/// has filled; the shared one's lock is held so that the tests still take turns.
#[test]
fn a_device_compiles_each_kernel_once() {
    let Some(shared) = gpu() else { return };
    let _turn = shared.lock().unwrap_or_else(|e| e.into_inner());
    let ctx = GpuContext::with_backends(AdapterChoice::Any, Some(wgpu::Backends::VULKAN))
        .expect("a second device on the adapter");
    let s = common::build_scene(&sphere_scene("kind = \"index-matched\""), true);
    let (pt, st) = (
        settings(IntegratorKind::Pt, true),
        settings(IntegratorKind::Stcvae, true),
    );
    let counts = || ctx.kernel_cache.counts();
    let first = on_gpu(&ctx, &s, &pt, &opts(2, 1));
    assert_eq!(counts(), (0, 1), "(found, built)");
    on_gpu(&ctx, &s, &st, &opts(2, 1));
    assert_eq!(counts(), (0, 2), "(found, built)");
    let again = on_gpu(&ctx, &s, &pt, &opts(2, 1));
    assert_eq!(counts(), (1, 2), "(found, built)");
    assert_same_render(&first, &again, "PT, its kernel found");
    let staged = [("STCVAE_GPU_STAGED", "1")];
    let first = render_gpu_with_env(&ctx, &s, &st, &opts(2, 1), &staged).unwrap();
    assert_eq!(counts(), (1, 7), "(found, built)");
    let again = render_gpu_with_env(&ctx, &s, &st, &opts(2, 1), &staged).unwrap();
    assert_eq!(counts(), (6, 7), "(found, built)");
    assert_same_render(&first, &again, "staged ST-CVAE, its kernels found");
    // A kernel that does not compile is an error, and not kept: asked for again, it is
    // built again.
    use render_gpu::gpu::kernels::{Kernel, bind_group_layout, compile_pipeline};
    let layout = bind_group_layout(&ctx, false).unwrap();
    for built in [8, 9] {
        let e = ctx
            .kernel_cache
            .pipeline(&layout, "render_main", "fn broken(".into(), |src| {
                compile_pipeline(&ctx, &layout, Kernel::Pt, src, "render_main")
            })
            .unwrap_err();
        assert!(e.to_string().contains("did not compile"), "{e}");
        assert_eq!(counts(), (6, built), "(found, built)");
    }
    ctx.poll(wgpu::PollType::wait_indefinitely())
        .expect("no error left uncaptured");
}

/// A path resumes exactly where it stopped, so the image does not depend on the dispatch
/// schedule, and the staged render (`STCVAE_GPU_STAGED`: paths advanced to their next ray
/// query or sphere step by one kernel, the queued queries traced by another and the queued
/// sphere steps, exact and the model's, run whole by a third, each dispatched over its
/// queues) runs the single kernel's paths: the same random numbers in the same order, the
/// same hits. Four renders must therefore take the same paths (equal counters) and agree
/// bit for bit: the single kernel at one bounce per dispatch (every bounce resumes a path),
/// the single kernel at its default schedule, the staged render, and the staged render
/// with queue adds once per subgroup, the sphere steps run in place and one bounce a
/// visit, its submissions sent ahead of their readbacks (`STCVAE_GPU_AGGREGATE=1`,
/// `STCVAE_GPU_STAGED_STEPS=0`, `STCVAE_GPU_BOUNCES=1`). One exception: the staged
/// render's sphere steps run in a pipeline of their own (`step_main`), which a hardware
/// driver may compile into other float instructions (most likely multiply-adds fused
/// elsewhere) than the same WGSL in the single kernel; on the H100 (2026-11-27) 31–47 of
/// 576 pixels differed, by at most 1.7e-7 relative (1–2 ulp), where lavapipe agreed bit
/// for bit. On hardware adapters that render may differ by up to
/// [`STEP_KERNEL_RELATIVE`]; on software adapters it must still agree bit for bit.
/// Most take 2 samples per slot and chunk (a slot starts its second path inside a
/// dispatch or turn); ST-CVAE takes 1 at 12 spp, two chunks on a software adapter (a later
/// chunk's first turn). Covered: PT (a shadow ray at every event), ST-CVAE with one and two
/// path-level NEE reservoirs, exact walks, without NEE, a dielectric boundary, and six
/// lights (each reservoir's shadow rays queued one a light). Half the cases keep the
/// variance's squared sums (`--variance`), the rest the plain slot layout, each layout
/// with 0, 1 and 2 reservoirs; where the images must agree bit for bit so must the
/// variance images and the work maps, which the slots carry too.
/// (Before the thirtieth session a resumed ST-CVAE path forgot its free distance, and the
/// one-bounce render differed.)
/// The relative difference allowed between the staged render with its step kernel and
/// the single kernel: 1e-6, ~6× the H100's 1.7e-7. A path that went wrong (another random
/// number, a lost NEE contribution, a state not restored) moves a pixel of 12 samples by
/// a good part of one sample's ~8 %, and the counters must still be equal.
const STEP_KERNEL_RELATIVE: f32 = 1e-6;

#[test]
fn staged_render_equals_one_kernel() {
    let Some(ctx) = gpu() else { return };
    let ctx = ctx.lock().unwrap_or_else(|e| e.into_inner());
    let matched = common::build_scene(&sphere_scene("kind = \"index-matched\""), true);
    let dielectric = common::build_scene(&sphere_scene("kind = \"dielectric\"\nior = 1.5"), true);
    let six_lights =
        common::build_scene(&six_lights_scene("kind = \"dielectric\"\nior = 1.5"), true);
    let st = settings(IntegratorKind::Stcvae, true);
    // (name, scene, settings, samples per slot and chunk)
    let cases = [
        ("PT", &matched, settings(IntegratorKind::Pt, true), "2"),
        ("ST-CVAE", &matched, st, "1"),
        (
            "ST-CVAE, no NEE",
            &matched,
            settings(IntegratorKind::Stcvae, false),
            "2",
        ),
        (
            "ST-CVAE, exact walks",
            &matched,
            IntegratorSettings {
                exact_tau: 8.0,
                ..st
            },
            "2",
        ),
        (
            "ST-CVAE dielectric, 2 reservoirs",
            &dielectric,
            IntegratorSettings {
                path_nee_rays: 2,
                ..st
            },
            "2",
        ),
        // More lights than the exact steps' proxy weighs: each reservoir's six shadow rays
        // are queued one a visit, the last light's flagged (staged.wgsl, Q_LAST_LIGHT).
        (
            "ST-CVAE dielectric, six lights, 2 reservoirs, exact walks",
            &six_lights,
            IntegratorSettings {
                path_nee_rays: 2,
                exact_tau: 8.0,
                ..st
            },
            "2",
        ),
    ];
    let mut mismatches = Vec::new();
    for (i, (name, s, set, per_slot)) in cases.into_iter().enumerate() {
        let lanes = ("STCVAE_GPU_LANE_SAMPLES", per_slot);
        // Half the cases with the variance's squared sums, which travel in the slots too
        // and must come out the same whatever the schedule; the others in the plain slot
        // layout most renders use. Each layout with 0, 1 and 2 reservoirs (`settings`
        // takes 1; PT and no NEE none), PT in the plain one.
        let variance = matches!(i, 1 | 2 | 4);
        let options = RenderOptions {
            variance,
            ..opts(12, 5)
        };
        let name = &format!("{name}{}", if variance { ", variance" } else { "" });
        let render =
            |vars: &[(&str, &str)]| render_gpu_with_env(&ctx, s, &set, &options, vars).unwrap();
        let one_bounce = render(&[lanes, ("STCVAE_GPU_BOUNCES", "1")]);
        let default = render(&[lanes]);
        let staged = render(&[lanes, ("STCVAE_GPU_STAGED", "1")]);
        // One lane per subgroup adding to the queues and counters for all (another order
        // of the queues' entries), the sphere steps run in stage_main rather than in
        // their own kernel, and one bounce a visit, which on a software adapter keeps no
        // snapshot, so each submission is sent ahead of the last one's readback as on
        // hardware: the same paths.
        let staged_plain = render(&[
            lanes,
            ("STCVAE_GPU_STAGED", "1"),
            ("STCVAE_GPU_AGGREGATE", "1"),
            ("STCVAE_GPU_STAGED_STEPS", "0"),
            ("STCVAE_GPU_BOUNCES", "1"),
        ]);
        // Every bounce was a dispatch of its own: more dispatches than samples per slot.
        assert!(one_bounce.dispatch.dispatches > 12, "{name}");
        assert!(!default.dispatch.staged && staged.dispatch.staged);
        let subgroups = ctx.features.contains(wgpu::Features::SUBGROUP);
        assert!(!staged.dispatch.aggregate);
        assert_eq!(staged_plain.dispatch.aggregate, subgroups);
        assert!(staged_plain.dispatch.ahead && !default.dispatch.ahead);
        assert_eq!(staged.dispatch.ahead, !ctx.adapter.software);
        // ST-CVAE's model steps (steps that are not exact) are what step_main runs.
        let stcvae = set.kind == IntegratorKind::Stcvae;
        assert_eq!(staged.dispatch.staged_steps, stcvae, "{name}");
        assert!(!staged_plain.dispatch.staged_steps);
        assert_eq!(
            default.stats.steps > default.stats.exact_steps,
            stcvae,
            "{name}: model steps"
        );
        assert!(default.image.pixels.iter().any(|p| p[0] > 0.0), "{name}");
        // Exact steps are parked too (queued by optical radius).
        assert_eq!(default.stats.exact_steps > 0, set.exact_tau > 0.0, "{name}");
        // (what, render, the relative difference allowed)
        let step_kernel = if ctx.adapter.software {
            0.0
        } else {
            STEP_KERNEL_RELATIVE
        };
        for (what, out, allowed) in [
            ("one bounce a dispatch", &one_bounce, 0.0),
            ("staged", &staged, step_kernel),
            (
                "staged, aggregated, steps in place, sent ahead",
                &staged_plain,
                0.0,
            ),
        ] {
            assert_eq!(out.stats, default.stats, "{name}, {what}");
            if allowed == 0.0 {
                // (On hardware the step kernel's few ulps are not compared here: the
                // variance, a difference of sums, would magnify them.)
                let var = |o: &RenderOutput| o.variance.as_ref().map(|v| v.pixels.clone());
                assert_eq!(var(out).is_some(), variance, "{name}, {what}");
                assert!(
                    var(out) == var(&default),
                    "{name}, {what}: the variance images differ"
                );
                assert!(
                    out.work == default.work,
                    "{name}, {what}: the work maps differ"
                );
            }
            let differ = differing_pixels(&default, out);
            let largest = largest_relative_difference(&default, out);
            if largest > allowed {
                mismatches.push(format!(
                    "{name}: {differ} of {} pixels differ between the {what} render and the \
                     default, by up to {largest:.2e} relative (allowed {allowed:.0e})",
                    default.image.pixels.len(),
                ));
            }
        }
    }
    // Every case and render is compared before failing, so that a failure on a new adapter
    // says which kernels disagree and by how much.
    assert!(mismatches.is_empty(), "{}", mismatches.join("\n"));
}

/// How many samples a chunk gives each slot (`STCVAE_GPU_LANE_SAMPLES`; unset, the
/// renderer grows chunks toward a target duration, so the split depends on the machine's
/// speed) changes no pixel: a pixel's lane l always renders samples l, l + lanes, … in
/// that order, each seeded by the pixel and the sample index, and adds them to its own
/// slot in the same order. The statistical tests above leave the chunks to the clock and
/// rely on this for their fixed seeds to fix their images. On a software adapter the 24²
/// image gets 7 lanes a pixel (4,096 invocations), so 21 spp at 1, 2 and 3 samples a slot
/// take 3, 2 and 1 chunks, and the clock's choice whatever it takes; PT, ST-CVAE and exact
/// walks. (A hardware adapter gives every sample a lane of its own, one chunk: there the
/// test checks only that renders repeat.)
#[test]
fn samples_per_chunk_change_no_pixel() {
    let Some(ctx) = gpu() else { return };
    let ctx = ctx.lock().unwrap_or_else(|e| e.into_inner());
    let s = common::build_scene(&sphere_scene("kind = \"index-matched\""), true);
    let exact = IntegratorSettings {
        exact_tau: 8.0,
        ..settings(IntegratorKind::Stcvae, true)
    };
    for set in [
        settings(IntegratorKind::Pt, true),
        settings(IntegratorKind::Stcvae, true),
        exact,
    ] {
        let run = |vars: &[(&str, &str)]| {
            render_gpu_with_env(&ctx, &s, &set, &opts(21, 4), vars).unwrap()
        };
        let base = run(&[("STCVAE_GPU_LANE_SAMPLES", "1")]);
        assert_eq!(base.spp, 21);
        if ctx.adapter.software {
            assert!(base.dispatch.dispatches >= 3, "three chunks at least");
        }
        assert!(base.image.pixels.iter().any(|p| p[0] > 0.0));
        for vars in [
            &[("STCVAE_GPU_LANE_SAMPLES", "2")][..],
            &[("STCVAE_GPU_LANE_SAMPLES", "3")],
            &[],
        ] {
            let what = format!("{:?} {vars:?} against one sample a chunk", set.kind);
            assert_same_render(&base, &run(vars), &what);
        }
    }
}

/// The kernels' shape (threads per workgroup, traversal stacks in workgroup or private
/// memory: `STCVAE_GPU_WORKGROUP`, `STCVAE_GPU_STACK`) changes which thread runs a path,
/// never what the path computes: seeds follow the pixel and the sample. So every shape
/// renders the same image bit for bit, for PT and for ST-CVAE (model steps and exact
/// walks). The samples per chunk are fixed (`STCVAE_GPU_LANE_SAMPLES`), though the image no
/// longer depends on the schedule (`staged_render_equals_one_kernel`).
#[test]
fn kernel_shapes_render_the_same_image() {
    let Some(ctx) = gpu() else { return };
    let mut ctx = ctx.lock().unwrap_or_else(|e| e.into_inner());
    let s = common::build_scene(&sphere_scene("kind = \"index-matched\""), true);
    let exact = IntegratorSettings {
        exact_tau: 8.0,
        ..settings(IntegratorKind::Stcvae, true)
    };
    // 128 threads with workgroup stacks: the largest array lavapipe's 32 KiB holds.
    // An empty value is the default, as unset (it was refused as out of range).
    let shapes: [&[(&str, &str)]; 5] = [
        &[("STCVAE_GPU_WORKGROUP", ""), ("STCVAE_GPU_STACK", " ")],
        &[("STCVAE_GPU_WORKGROUP", "8")],
        &[("STCVAE_GPU_WORKGROUP", "128")],
        &[
            ("STCVAE_GPU_WORKGROUP", "32"),
            ("STCVAE_GPU_STACK", "private"),
        ],
        &[
            ("STCVAE_GPU_WORKGROUP", "128"),
            ("STCVAE_GPU_STACK", "private"),
        ],
    ];
    for set in [
        settings(IntegratorKind::Pt, true),
        settings(IntegratorKind::Stcvae, true),
        exact,
    ] {
        let run = |vars: &[(&str, &str)]| {
            let mut all = vec![("STCVAE_GPU_LANE_SAMPLES", "2")];
            all.extend_from_slice(vars);
            render_gpu_with_env(&ctx, &s, &set, &opts(6, 9), &all).unwrap()
        };
        let base = run(shapes[0]);
        assert_eq!(base.dispatch.workgroup, 64);
        assert_eq!(base.dispatch.stack, Some(StackMemory::Workgroup));
        assert!(base.image.pixels.iter().any(|p| p[0] > 0.0));
        for vars in &shapes[1..] {
            let out = run(vars);
            let workgroup: u32 = vars[0].1.parse().unwrap();
            let private = vars.len() == 2;
            assert_eq!(out.dispatch.workgroup, workgroup);
            assert_eq!(
                out.dispatch.stack,
                Some(if private {
                    StackMemory::Private
                } else {
                    StackMemory::Workgroup
                })
            );
            assert_eq!(
                (out.stats.paths, out.stats.events),
                (base.stats.paths, base.stats.events)
            );
            let differ = differing_pixels(&base, &out);
            assert_eq!(
                differ, 0,
                "{:?} {vars:?}: {differ} pixels differ from the default shape",
                set.kind
            );
        }
    }
    // A shape beyond the adapter's workgroup memory is refused, naming the way out.
    let refused = {
        let mut ctx = Limits::new(&mut ctx);
        ctx.limits.max_compute_workgroup_storage_size = 1024;
        render_gpu_with_env(
            &ctx,
            &s,
            &settings(IntegratorKind::Pt, true),
            &opts(1, 1),
            &[],
        )
    };
    let e = refusal(refused, "a kernel over the workgroup memory limit");
    assert!(
        e.contains("workgroup memory") && e.contains("STCVAE_GPU_STACK=private"),
        "{e}"
    );
    // So is an adapter with fewer storage buffers per shader stage than the kernels bind:
    // 7 (WebGPU's default of 8 allows it), 9 for the staged render.
    for (offered, staged, needed) in [(6, "0", "bind 7"), (8, "1", "binds 9")] {
        let refused = {
            let mut ctx = Limits::new(&mut ctx);
            ctx.limits.max_storage_buffers_per_shader_stage = offered;
            render_gpu_with_env(
                &ctx,
                &s,
                &settings(IntegratorKind::Pt, true),
                &opts(1, 1),
                &[("STCVAE_GPU_STAGED", staged)],
            )
        };
        let e = refusal(refused, "an adapter short of storage buffers");
        assert!(
            e.contains(needed) && e.contains(&format!("offers {offered}")),
            "{e}"
        );
    }
}

/// The lane profile (`STCVAE_GPU_PROFILE=1`) counts, per phase of the kernel, its subgroup
/// passes, their active lanes and their lanes in all. Each pass has at least its counting
/// lane active and at most the whole subgroup, so passes ≤ active ≤ capacity, and every
/// pass adds the subgroup's size, one size for all phases (a power of two from 4 to 128,
/// Vulkan's range). The phases each integrator must run are reached, those it cannot are
/// not, and counting changes no path: the image is the same bit for bit.
#[test]
fn lane_profile_counts_and_changes_nothing() {
    let Some(ctx) = gpu() else { return };
    let mut ctx = ctx.lock().unwrap_or_else(|e| e.into_inner());
    if !ctx.features.contains(wgpu::Features::SUBGROUP) {
        common::skip(&format!(
            "lane_profile_counts_and_changes_nothing: {} offers no subgroup operations",
            ctx.adapter
        ));
        assert!(std::env::var_os("CI").is_none(), "lavapipe offers them");
        return;
    }
    let s = common::build_scene(&sphere_scene("kind = \"index-matched\""), true);
    let exact = IntegratorSettings {
        exact_tau: 8.0,
        ..settings(IntegratorKind::Stcvae, true)
    };
    // Phases (kernels::PROFILE_PHASES): bounce, closest hit, shadow ray, surface
    // distance, exact walk, decoder, collision, cell-list hit test. The surface-distance
    // search is a fallback for grid cells without candidate lists, which this sphere's
    // grid does not need. This scene carries a grid for both integrators, so PT's flights
    // near the surface test cell lists too (as on the CPU; PT renders build none).
    for (set, reached) in [
        (
            settings(IntegratorKind::Pt, true),
            [true, true, true, false, false, false, true, true],
        ),
        (exact, [true, true, true, false, true, true, true, true]),
    ] {
        let fixed = ("STCVAE_GPU_LANE_SAMPLES", "2");
        let plain = render_gpu_with_env(&ctx, &s, &set, &opts(6, 4), &[fixed]).unwrap();
        let counted = render_gpu_with_env(
            &ctx,
            &s,
            &set,
            &opts(6, 4),
            &[fixed, ("STCVAE_GPU_PROFILE", "1")],
        )
        .unwrap();
        assert!(plain.dispatch.lanes.is_none());
        assert_eq!(differing_pixels(&plain, &counted), 0, "{:?}", set.kind);
        let lanes = counted.dispatch.lanes.expect("a lane profile");
        let size = lanes.phases[0].capacity / lanes.phases[0].passes.max(1);
        assert!(
            size.is_power_of_two() && (4..=128).contains(&size),
            "subgroup size {size}"
        );
        for (p, must) in lanes.phases.iter().zip(reached) {
            assert_eq!(p.passes > 0, must, "{:?}: {p:?}", set.kind);
            assert!(p.passes <= p.active && p.active <= p.capacity, "{p:?}");
            assert_eq!(p.capacity, size * p.passes, "{p:?}");
        }
    }
    // A workgroup narrower than the adapter's subgroups would understate their size: such a
    // profile is refused (an adapter with 64-lane subgroups is pretended here).
    let narrow = {
        let mut ctx = Limits::new(&mut ctx);
        ctx.subgroup_max_size = 64;
        render_gpu_with_env(
            &ctx,
            &s,
            &settings(IntegratorKind::Pt, true),
            &opts(1, 1),
            &[("STCVAE_GPU_PROFILE", "1"), ("STCVAE_GPU_WORKGROUP", "32")],
        )
    };
    let e = refusal(narrow, "a profile with workgroups narrower than a subgroup");
    assert!(
        e.contains("subgroup size, 64") && e.contains("is 32"),
        "{e}"
    );
}

/// A path slot counts its samples in f32, which counts 2^24 of them: more samples a
/// pixel than the image's slots can hold is a clear error before any work, not pixels
/// "with fewer finished samples" at the end. A 128² image has at most 2^20 / 2^14 = 64
/// slots a pixel on any adapter, so 2^32 − 1 spp (what a time budget asks when nothing
/// caps it) is over 64 · 2^24 = 2^30.
#[test]
fn more_samples_than_the_slots_hold_are_refused() {
    let Some(ctx) = gpu() else { return };
    let ctx = ctx.lock().unwrap_or_else(|e| e.into_inner());
    let text = common::furnace_scene("kind = \"index-matched\"")
        .replace("width = 12", "width = 128")
        .replace("height = 12", "height = 128");
    let s = common::build_scene(&text, false);
    // Were it not refused, the render is stopped at its first progress report (and fails
    // the test) instead of running for days.
    let stop = AtomicBool::new(false);
    let Err(e) = render_gpu(
        &ctx,
        &s,
        &settings(IntegratorKind::Pt, true),
        &opts(u32::MAX, 1),
        &|_, _| stop.store(true, Ordering::Relaxed),
        &stop,
    ) else {
        panic!("a render of 2^32 − 1 spp began");
    };
    assert!(
        matches!(e, RenderError::GpuLimit(_)) && e.to_string().contains("2^24 per path slot"),
        "{e}"
    );
}

/// A path slot sums its samples in f32, and a plain f32 sum of many equal samples drifts:
/// each addition rounds to the sum's ulp, the same way every time. Here every camera ray
/// misses the object (the camera looks away from it) and meets a sky of 0.7, so every
/// sample is 3 × 0.7 in its channel and every pixel's mean is 0.7 up to the final
/// division's rounding. On a software adapter the 64 × 64 image takes one lane a pixel
/// (gpu/bands.rs, target_threads), so each slot sums all 16,384 samples of its pixel
/// (a hardware adapter gives it 256 lanes, 64 samples each: a weak check there). The
/// plain sum was 2.1·10⁻⁵ off here (8.3·10⁻⁵ at 65,536 samples); a compensated sum is
/// within a few ulps of the exact one (Neumaier: 2ε|sum| + O(nε²)), and f32(2.1)/3 is
/// 0.7 to within one ulp (6·10⁻⁸), so 3·10⁻⁷ (five ulps) is the bound.
#[test]
fn long_slot_sums_do_not_drift() {
    let Some(ctx) = gpu() else { return };
    let ctx = ctx.lock().unwrap_or_else(|e| e.into_inner());
    let text = common::furnace_scene("kind = \"index-matched\"")
        .replace("target = [0.0, 0.0, 0.0]", "target = [0.0, 0.0, 10.0]")
        .replace("width = 12\nheight = 12", "width = 64\nheight = 64");
    assert!(text.contains("10.0]") && text.contains("width = 64"));
    let s = common::build_scene(&text, false);
    let spp = 16384;
    let out = on_gpu(&ctx, &s, &settings(IntegratorKind::Pt, true), &opts(spp, 1));
    assert_eq!(out.stats.paths, 64 * 64 * spp as u64);
    assert_eq!(out.stats.events, 0, "no camera ray may reach the object");
    let worst = out
        .image
        .pixels
        .iter()
        .flatten()
        .map(|v| (v - 0.7).abs())
        .fold(0.0, f32::max);
    assert!(worst <= 3e-7, "a pixel is {worst:e} from 0.7");
}

/// An error wgpu meets outside an error scope is reported by the next wait as one line
/// naming the adapter (wgpu's default handler panicked), and once: the wait after it is
/// clean, so a shared context goes on working. The error here: a buffer that may be both
/// mapped for reading and bound as storage, which WebGPU forbids.
#[test]
fn uncaptured_gpu_errors_are_reported_not_panics() {
    let Some(ctx) = gpu() else { return };
    let ctx = ctx.lock().unwrap_or_else(|e| e.into_inner());
    let _bad = ctx.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("forbidden usages"),
        size: 16,
        usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::STORAGE,
        mapped_at_creation: false,
    });
    let e = ctx
        .poll(wgpu::PollType::wait_indefinitely())
        .unwrap_err()
        .to_string();
    assert!(
        e.contains(&ctx.adapter.name) && e.contains("reported an error") && !e.contains('\n'),
        "{e}"
    );
    ctx.poll(wgpu::PollType::wait_indefinitely()).unwrap();
}
