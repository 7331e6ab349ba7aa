//! Geometry that strains the kernels, each rendered as on the CPU: slivers thinner than
//! the spawn offset, media at the density bound, light after a reflection and glints off
//! the outside, thin triangles, touching and overlapping pieces, shadow rays through
//! combs.

use super::*;

/// The kernels check each entry for a sliver as the CPU does (integrators.rs,
/// paths_pass_slivers_thinner_than_the_spawn_offset, which gives the scene and the
/// bounds): at the sliver no path scatters and every pixel is exactly 1; where the wedge
/// is thicker than the offset, paths enter and scatter.
#[test]
fn gpu_paths_pass_slivers_thinner_than_the_spawn_offset() {
    let Some(ctx) = gpu() else { return };
    let ctx = ctx.lock().unwrap_or_else(|e| e.into_inner());
    common::check_slivers(|s, kind| on_gpu(&ctx, s, &settings(kind, true), &opts(12, 3)));
}

/// The image mean over 16 seeds of `spp` and the variance of that mean, estimated from the
/// spread of the seeds' means (15 degrees of freedom); no path may leak.
fn seeded_mean(render: impl Fn(u64) -> RenderOutput, what: &str) -> (f64, f64) {
    let means: Vec<f64> = (0..16)
        .map(|seed| {
            let o = render(70 + seed);
            assert_eq!(o.stats.leaks, 0, "{what}: {:?}", o.stats);
            let sum: f64 = o.image.pixels.iter().flatten().map(|&x| x as f64).sum();
            sum / (3 * o.image.pixels.len()) as f64
        })
        .collect();
    let m = means.iter().sum::<f64>() / 16.0;
    let var = means.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / 15.0;
    (m, var / 16.0)
}

/// The kernels' offset rules at the density bound (integrators.rs,
/// the_image_does_not_darken_with_density, does the same on the CPU): the sphere at σ_t =
/// 300 and at 48,000 (σ_t·eps = 0.006 and 0.96) is a half-space to the light at both, so
/// their PT images must agree. Among what this checks is the flight margin (path.wgsl,
/// flight_end): with a face found only within the margin ending the path as an exit, the
/// dense image is ~1 % dark (with the rule undone: −0.89 % against +0.07 % with it, both
/// densities on one seed set; with it on independent seeds −0.01 %; lavapipe, 2026-12-03,
/// allowed ±0.41 % and ±0.38 % by the 4 standard errors of then, ±0.50 % and ±0.46 % by
/// today's 5.2). 16 seeds × 32² pixels × 64 spp = 1,048,576 paths a density (seeds 70–85
/// and 170–185: independent means, whose difference spreads as the allowance assumes) give
/// each mean a standard error of ~0.1 %; allowed: 5.2 standard errors of the difference
/// plus the CPU test's 0.1 % for the sphere's curvature and what is left of the offset's
/// bias (+0.08 % at σ_t·eps 1 on the CPU). Each variance is estimated from 16 seeds, so
/// the difference over its standard error is Welch's t with 15–30 degrees of freedom:
/// beyond 5.2 with probability ≤ 1.1e-4 (4, as a z, allowed 3.8e-4–1.2e-3).
#[test]
fn gpu_image_does_not_darken_at_the_density_bound() {
    let Some(ctx) = gpu() else { return };
    let ctx = ctx.lock().unwrap_or_else(|e| e.into_inner());
    let set = settings(IntegratorKind::Pt, true);
    let mean_of = |sigma: f64, offset: u64| {
        let s = common::build_scene(&common::dense_sphere(sigma), false);
        seeded_mean(
            |seed| on_gpu(&ctx, &s, &set, &opts(64, offset + seed)),
            "PT",
        )
    };
    let (thin, var_thin) = mean_of(300.0, 0);
    let (dense, var_dense) = mean_of(48_000.0, 100);
    let diff = dense / thin - 1.0;
    let allowed = 5.2 * (var_thin + var_dense).sqrt() / thin + 0.001;
    let report = format!(
        "σ_t 48,000 against 300: {dense:.5} against {thin:.5} ({:+.3} %, allowed ±{:.3} %)",
        100.0 * diff,
        100.0 * allowed
    );
    eprintln!("{report}");
    assert!(diff.abs() < allowed, "{report}");
}

/// ST-CVAE with the distance grid at the density bound (σ_t·eps = 0.96): its flights near
/// the surface meet faces through the grid's cell lists, where the flight margin fires as
/// often as in PT. The model's own bias differs between densities, so the reference is the
/// CPU's image of the same scene (whose margin rule integrator/mod.rs'
/// collisions_within_the_flight_margin_stand checks). Same sample counts and allowance
/// as above but without the 0.1 %: one estimator on two devices, so only noise separates
/// them (with the rule undone on the GPU: −1.09 %, t = −9.4; with it −0.12 %, t = −1.0).
#[test]
fn gpu_stcvae_agrees_with_the_cpu_at_the_density_bound() {
    let Some(ctx) = gpu() else { return };
    let ctx = ctx.lock().unwrap_or_else(|e| e.into_inner());
    let set = settings(IntegratorKind::Stcvae, true);
    let s = common::build_scene(&common::dense_sphere(48_000.0), true);
    seeded_means_agree(&ctx, &s, &set, 64, "ST-CVAE at σ_t 48,000");
}

/// The image means of 16 CPU renders (seeds 70–85) and 16 GPU renders (seeds 170–185) of
/// `spp` agree: |t| < 5.2, each mean's variance from its seeds' spread ([`seeded_mean`]),
/// so that the statistic is Welch's t with 15–30 degrees of freedom, beyond 5.2 with
/// probability ≤ 1.1e-4 under agreement (|z| < 4 allowed up to 1.2e-3 for such a t).
fn seeded_means_agree(
    ctx: &GpuContext,
    s: &SceneData,
    set: &IntegratorSettings,
    spp: u32,
    what: &str,
) {
    let (cpu, var_cpu) = seeded_mean(|seed| on_cpu(s, set, &opts(spp, seed)), "CPU");
    let (gpu, var_gpu) = seeded_mean(|seed| on_gpu(ctx, s, set, &opts(spp, 100 + seed)), "GPU");
    let t = (gpu - cpu) / (var_cpu + var_gpu).sqrt();
    let report = format!(
        "{what}: GPU {gpu:.5} against CPU {cpu:.5} ({:+.3} %, t = {t:.2})",
        100.0 * (gpu / cpu - 1.0)
    );
    eprintln!("{report}");
    assert!(t.abs() < 5.2, "{report}");
}

/// Light reaching the medium by a reflection off the boundary (integrators.rs,
/// nee_counts_light_after_a_reflection: a prism's total internal reflection) is counted
/// by paths that escape into the sun disk after a reflection, with NEE on: the kernels
/// clear `scattered` at a reflection as the CPU does. GPU against CPU, NEE on, 16 seeds ×
/// 8² pixels × 1,280 spp each (standard error ~1.5 % of the mean each); |t| < 5.2. Keeping
/// `scattered` through reflections loses 41 % of this image.
#[test]
fn gpu_nee_counts_light_after_a_reflection() {
    let Some(ctx) = gpu() else { return };
    let ctx = ctx.lock().unwrap_or_else(|e| e.into_inner());
    let dir = tempfile::tempdir().unwrap();
    let s = common::build_scene(&common::prism_scene(dir.path()), false);
    let set = settings(IntegratorKind::Pt, true);
    seeded_means_agree(&ctx, &s, &set, 1280, "prism, NEE on");
}

/// Glints off a non-convex object (`common::glint_scene`): light that reaches the cube off
/// the glass floor's outer face is counted with NEE on by paths that leave the cube, are
/// reflected off the floor and escape into the disk. path.wgsl clears `scattered` at a
/// reflection from the air as the CPU does (integrator/mod.rs,
/// a_reflection_off_the_outside_after_scattering_sees_the_sun). That light is 19 % of the
/// CPU's image with NEE on (NEE on / off − 1 in R: −25.2 % ± 0.9 % with `scattered` kept,
/// −5.6 % ± 1.3 % without (G −7.4 %): NEE's one face leaves out the light through the
/// cube's other lit face, −8.6 % ± 1.0 % for the cube alone, as README says). GPU against CPU, NEE on, 16 seeds ×
/// 8² pixels × 1,280 spp each; |t| < 5.2.
#[test]
fn gpu_nee_counts_glints_off_the_outside() {
    let Some(ctx) = gpu() else { return };
    let ctx = ctx.lock().unwrap_or_else(|e| e.into_inner());
    let dir = tempfile::tempdir().unwrap();
    let s = common::build_scene(&common::glint_scene(dir.path()), false);
    let set = settings(IntegratorKind::Pt, true);
    seeded_means_agree(&ctx, &s, &set, 1280, "glints, NEE on");
}

/// Paths under long thin triangles do not leak on the GPU either (integrators.rs,
/// paths_under_thin_triangles_do_not_leak: the 1,000-segment cylinder's side head-on, PT
/// at σ_t = 2,000): `tri_intersect` takes its distance from the triangle's plane, as the
/// CPU does. With Woop's interpolated distance the CPU leaked 1.8·10⁻⁴ of these paths,
/// ~6 expected in these 32,768 (P(none) = e⁻⁶ = 0.25 %). NEE is off: it changes no path's
/// distribution, so not the leak rate, and its shadow ray at each of a path's hundreds of
/// events was most of this render's time.
#[test]
fn gpu_paths_under_thin_triangles_do_not_leak() {
    let Some(ctx) = gpu() else { return };
    let ctx = ctx.lock().unwrap_or_else(|e| e.into_inner());
    let dir = tempfile::tempdir().unwrap();
    let text = common::cylinder_scene(dir.path(), common::CYLINDER_SIDE_ON);
    let s = common::build_scene(&text, false);
    let out = on_gpu(&ctx, &s, &settings(IntegratorKind::Pt, false), &opts(8, 5));
    assert!(out.stats.events > 100 * out.stats.paths, "{:?}", out.stats);
    assert_eq!(out.stats.leaks, 0, "{:?}", out.stats);
}

/// Touching parts of a mesh (integrators.rs, touching_parts_render_as_one_medium, which
/// checks the CPU against the same medium in one part): paths leaving one part are spawned
/// inside the other and must go on there on the GPU too — no path found outside while
/// believed inside (the CPU without the handling had 6 % of its paths leak), and the same
/// image as the CPU's.
#[test]
fn gpu_touching_parts_render_as_on_the_cpu() {
    let dir = tempfile::tempdir().unwrap();
    let (_, two) = common::touching_parts_scenes(dir.path());
    // Enough 4 × 4 blocks with a noise estimate for assert_same_image.
    let two = two.replace("width = 16\nheight = 16", "width = 32\nheight = 32");
    {
        let Some(ctx) = gpu() else { return };
        let ctx = ctx.lock().unwrap_or_else(|e| e.into_inner());
        let s = common::build_scene(&two, true);
        for kind in [IntegratorKind::Pt, IntegratorKind::Stcvae] {
            let out = on_gpu(&ctx, &s, &settings(kind, true), &opts(32, 1));
            assert_eq!(out.stats.leaks, 0, "{kind:?}: {:?}", out.stats);
        }
    }
    compare_devices("PT, touching parts", &two, IntegratorKind::Pt, true, 64);
    compare_devices(
        "ST-CVAE, touching parts",
        &two,
        IntegratorKind::Stcvae,
        true,
        64,
    );
}

/// Overlapping pieces of a mesh (integrators.rs, overlapping_pieces_render_as_their_union,
/// which checks the CPU against the same objects made without overlaps) render as their
/// union on the GPU too: the same image as the CPU's, no leaks. The two boxes making the
/// cube (faces in shared planes) with PT and ST-CVAE; the two around a cavity with PT
/// behind a dielectric boundary (the Fresnel choice only at the union's own boundary,
/// the cavity's walls included); and with PT behind a dielectric boundary, two boxes
/// touching across a gap of 10⁻⁶ with a bar overlapping both (shadow-ray crossings within
/// the spawn offset walked together: shadow_rays.rs, touching_pieces_in_a_union_make_no_boundary).
#[test]
fn gpu_overlapping_pieces_render_as_on_the_cpu() {
    let dir = tempfile::tempdir().unwrap();
    let grow = |t: &str| t.replace("width = 16\nheight = 16", "width = 32\nheight = 32");
    let matched = common::overlapping_parts_scenes(dir.path(), "kind = \"index-matched\"");
    let cube = grow(&matched[0].2);
    let dielectric =
        common::overlapping_parts_scenes(dir.path(), "kind = \"dielectric\"\nior = 1.5");
    let hollow = grow(&dielectric[2].2);
    let obj = dir.path().join("touching.obj");
    std::fs::write(
        &obj,
        common::boxes_obj(&[
            ([-0.5, -0.5, -0.5], [0.0, 0.5, 0.5]),
            ([1e-6, -0.5, -0.5], [0.5, 0.5, 0.5]),
            ([-0.2, -0.1, 0.4], [0.2, 0.1, 0.7]),
        ]),
    )
    .unwrap();
    let touching = grow(&dielectric[0].2).replace(
        &dir.path().join("cube2.obj").display().to_string(),
        &obj.display().to_string(),
    );
    let (slabs_matched, slabs_dielectric) = (
        grow(&slabs_scene(dir.path(), "kind = \"index-matched\"")),
        grow(&slabs_scene(dir.path(), "kind = \"dielectric\"\nior = 1.5")),
    );
    // All eleven solid (depth 0), none taken for a cavity (asked before the GPU, which
    // this does not need).
    let pieces = common::build_scene(&slabs_matched, false).geo.pieces;
    assert_eq!(pieces.map(|p| p.at_depth), Some(vec![0x7FF]));
    {
        let Some(ctx) = gpu() else { return };
        let ctx = ctx.lock().unwrap_or_else(|e| e.into_inner());
        let s = common::build_scene(&cube, true);
        assert!(s.geo.pieces.is_some());
        for kind in [IntegratorKind::Pt, IntegratorKind::Stcvae] {
            let out = on_gpu(&ctx, &s, &settings(kind, true), &opts(32, 1));
            assert_eq!(out.stats.leaks, 0, "{kind:?}: {:?}", out.stats);
        }
    }
    compare_devices("PT, overlapping boxes", &cube, IntegratorKind::Pt, true, 64);
    compare_devices(
        "ST-CVAE, overlapping boxes",
        &cube,
        IntegratorKind::Stcvae,
        true,
        64,
    );
    compare_devices(
        "PT dielectric, overlapping boxes around a cavity",
        &hollow,
        IntegratorKind::Pt,
        true,
        64,
    );
    compare_devices(
        "PT dielectric, touching boxes in a union",
        &touching,
        IntegratorKind::Pt,
        true,
        64,
    );
    compare_devices(
        "ST-CVAE, eleven overlapping slabs",
        &slabs_matched,
        IntegratorKind::Stcvae,
        true,
        64,
    );
    compare_devices(
        "PT dielectric, eleven overlapping slabs",
        &slabs_dielectric,
        IntegratorKind::Pt,
        true,
        64,
    );
}

/// Shadow rays through more faces than a sorted list holds, in a render: the interleaved
/// combs (`common::combs_scene`, index-matched, σ_t 0.5, 1, 2) seen end-on from −x under
/// a sun along −x, so that the events the camera sees take their light through up to 80
/// faces (shadow_rays.rs, rays_through_more_crossings_than_the_list_holds, checks the
/// CPU's answers against their closed form). nee.wgsl walks each ray past 16 crossings
/// in order, up to nee::MAX_CROSSINGS. GPU against CPU, NEE on, 16 seeds × 8² pixels ×
/// 8 spp each; |t| < 5.2 (measured −1.3 %, t = −1.6; at 256 spp −0.14 %, t = −1.3; with
/// the kernel's walk cut at 64 crossings −9.4 %, t = −11). A probe of these rays, as for
/// the slabs, gave wrong answers on lavapipe from an invocation's later traversals (a
/// second or fourth call; the first was right), as probe.wgsl's probe_shadow notes for
/// refracted rays: hence a render, whose image the CPU's must match.
#[test]
fn gpu_shadow_rays_through_the_combs_render_as_on_the_cpu() {
    let Some(ctx) = gpu() else { return };
    let ctx = ctx.lock().unwrap_or_else(|e| e.into_inner());
    let dir = tempfile::tempdir().unwrap();
    let (text, _) = common::combs_scene(dir.path(), "kind = \"index-matched\"");
    let text = text
        .replace("origin = [1.5, 2.0, 3.0]", "origin = [-0.6, 0.05, 0.075]")
        .replace("target = [0.0, 0.0, 0.0]", "target = [0.5, 0.05, 0.075]")
        .replace("fov_deg = 30.0", "fov_deg = 6.0")
        .replace("width = 16\nheight = 16", "width = 8\nheight = 8")
        .replace("sigma_t = [4.0, 12.0, 40.0]", "sigma_t = [0.5, 1.0, 2.0]")
        .replace(
            "direction = [0.3, -1.0, -0.2]",
            "direction = [-1.0, -0.01, 0.006]",
        );
    let s = common::build_scene(&text, false);
    seeded_means_agree(
        &ctx,
        &s,
        &settings(IntegratorKind::Pt, true),
        8,
        "combs, NEE on",
    );
}
