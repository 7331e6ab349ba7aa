//! The wgpu renderer on Vulkan (Mesa's lavapipe in CI): WGSL building blocks equal the
//! Rust ones, the white furnace holds, every pixel is written and finite, and CPU and GPU
//! converge to the same image. Without a Vulkan adapter these tests print why and pass,
//! except under CI (CI=true), where a missing adapter is a failure.

mod common;

use std::ops::{Deref, DerefMut};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Mutex, OnceLock};

use glam::DVec3;
use render_gpu::RenderError;
use render_gpu::gpu::kernels::StackMemory;
use render_gpu::gpu::probe::{Item, run_probe};
use render_gpu::gpu::{AdapterChoice, GpuContext, render_gpu};
use render_gpu::integrator::{IntegratorKind, IntegratorSettings};
use render_gpu::render::{RenderOptions, RenderOutput, render};
use render_gpu::setup::SceneData;
use scatter_sim::WalkRng;
use scatter_sim::frame::{CanonicalExit, WalkFrame, from_canonical};
use scatter_sim::phase::{hg_pdf, hg_sample_cos, orthonormal_basis};

/// One device for all tests of this file; tests share it one at a time (lavapipe uses
/// every core for one dispatch anyway). None, with the reason printed for each test that
/// asks, only where no Vulkan adapter exists and not under CI; an adapter that exists but
/// cannot be opened fails every test.
fn gpu() -> Option<&'static Mutex<GpuContext>> {
    static CTX: OnceLock<Result<Mutex<GpuContext>, String>> = OnceLock::new();
    let ctx = CTX.get_or_init(|| {
        match GpuContext::with_backends(AdapterChoice::Any, Some(wgpu::Backends::VULKAN)) {
            Ok(c) => {
                eprintln!("GPU tests on {}", c.adapter);
                Ok(Mutex::new(c))
            }
            Err(RenderError::NoAdapter(e)) => {
                assert!(
                    std::env::var_os("CI").is_none(),
                    "CI must have a Vulkan adapter (mesa-vulkan-drivers): {e}"
                );
                Err(e)
            }
            Err(e) => panic!("a Vulkan adapter exists but cannot be used: {e}"),
        }
    });
    match ctx {
        Ok(c) => Some(c),
        Err(reason) => {
            let test = std::thread::current()
                .name()
                .unwrap_or("a GPU test")
                .to_owned();
            common::skip(&format!("{test}: {reason}"));
            None
        }
    }
}

fn model() -> &'static cvae::ModelSet {
    static M: OnceLock<cvae::ModelSet> = OnceLock::new();
    M.get_or_init(common::load_model)
}

/// The WGSL HG sampling, density, deflection and canonical-frame mapping equal the Rust
/// (f64, textbook) ones to f32 precision, including |g| up to 0.999, where the textbook forms
/// in f32 lost ~10 % of the density's peak: a quarter of the items take g = ±0.99, ±0.995 or
/// ±0.999. Both sides get the same ξ. The WGSL forms are products and sums of non-negative
/// terms, so each is within ~10 ulps (6e-7) relative: HG's cos θ within 2e-6 absolute and
/// sin θ within 4e-6 relative (plus 1e-8 for the f64 reference's own rounding of 1 − cos θ
/// at the lobe's tip); the density from dir to the sampled direction within 1e-5 relative
/// (its m = 1 − cos θ from f32 directions of length 1 ± 2e-7, d^(−3/2) of it); unit
/// vectors within 2e-5 (a few ulps after a handful of operations).
#[test]
fn wgsl_hg_and_frame_match_rust() {
    let Some(ctx) = gpu() else { return };
    let ctx = ctx.lock().unwrap_or_else(|e| e.into_inner());
    let mut rng = WalkRng::from_seed(17);
    let mut items = Vec::new();
    let mut expect = Vec::new();
    for n in 0..4096 {
        let g = if rng.uniform() < 0.25 {
            let edge = [0.99, 0.995, 0.999][(rng.uniform() * 3.0) as usize % 3];
            if rng.uniform() < 0.5 { -edge } else { edge }
        } else {
            (rng.uniform() * 1.8 - 0.9) as f32
        };
        let xi = rng.uniform() as f32;
        let dir = loop {
            let v = DVec3::new(rng.uniform(), rng.uniform(), rng.uniform()) * 2.0 - 1.0;
            if v.length_squared() > 0.01 && v.length_squared() < 1.0 {
                break v.normalize().as_vec3().as_dvec3();
            }
        };
        // Every 128th direction in the plane z = ±0: the basis's sign must follow the
        // sign bit of a −0.0 as the CPU's copysign does, or the GPU deflects it otherwise.
        let dir = match n % 256 {
            0 => DVec3::new(dir.x, dir.y, -0.0)
                .normalize()
                .as_vec3()
                .as_dvec3(),
            128 => DVec3::new(dir.x, dir.y, 0.0)
                .normalize()
                .as_vec3()
                .as_dvec3(),
            _ => dir,
        };
        let (c, s) = rng.unit_circle();
        let (c, s) = (c as f32 as f64, s as f32 as f64);
        let ct = (rng.uniform() * 2.0 - 1.0) as f32 as f64;
        let (a, b) = rng.unit_circle();
        let r = rng.uniform().sqrt() as f32 as f64;
        let exit = CanonicalExit {
            cos_theta: ct,
            alpha: (a * r) as f32 as f64,
            beta: (b * r) as f32 as f64,
        };
        let x = DVec3::new(rng.uniform(), rng.uniform(), rng.uniform()) - 0.5;
        let x = x.as_vec3().as_dvec3();
        let mut it: Item = [0.0; 32];
        it[0] = g;
        it[1] = xi;
        it[4..7].copy_from_slice(&dir.as_vec3().to_array());
        it[8] = c as f32;
        it[9] = s as f32;
        it[12] = ct as f32;
        it[13] = exit.alpha as f32;
        it[14] = exit.beta as f32;
        it[16..19].copy_from_slice(&x.as_vec3().to_array());
        items.push(it);
        let hg = hg_sample_cos(g as f64, xi as f64);
        let f = WalkFrame::new(dir, (c, s));
        let (p, w) = from_canonical(exit);
        expect.push((hg, f.to_world(p), f.to_world(w), f.to_world(x)));
    }
    let out = run_probe(&ctx, "probe_frame", model(), &items).unwrap();
    let v = |o: &Item, k: usize| DVec3::new(o[k] as f64, o[k + 1] as f64, o[k + 2] as f64);
    for (i, (o, e)) in out.iter().zip(&expect).enumerate() {
        let g = items[i][0] as f64;
        assert!(
            (o[0] as f64 - e.0).abs() < 2e-6,
            "item {i}, g {g}: HG cos {} vs {}",
            o[0],
            e.0
        );
        let sin = ((1.0 - e.0) * (1.0 + e.0)).max(0.0).sqrt();
        assert!(
            (o[1] as f64 - sin).abs() < 4e-6 * sin + 1e-8,
            "item {i}, g {g}, xi {}: HG (cos, sin) ({}, {}) vs ({}, {sin})",
            items[i][1],
            o[0],
            o[1],
            e.0
        );
        // The deflection of the GPU's own (cos θ, sin θ), written out: scatter_sim's
        // deflect would take sin θ from the f32 cos θ, which holds it to ~10 % at g = 0.999.
        let dir = DVec3::from_array([items[i][4], items[i][5], items[i][6]].map(|q| q as f64));
        let (t, b) = orthonormal_basis(dir);
        let d = dir * o[0] as f64 + (t * items[i][8] as f64 + b * items[i][9] as f64) * o[1] as f64;
        assert!((v(o, 4) - d).length() < 2e-5, "item {i}: deflect");
        // The single-scattering branch's exit point (0, sin θ, cos θ) keeps hg_sample's
        // sin θ (from the cosine alone it would be f32 rounding near the poles).
        let x = v(o, 24);
        assert!(
            x.x == 0.0 && x.y == o[1] as f64 && x.z == o[0] as f64,
            "item {i}: single-scattering exit {x} from ({}, {})",
            o[0],
            o[1]
        );
        let l = v(o, 20);
        let pdf = hg_pdf(g, dir.dot(l) / (dir.length() * l.length()));
        assert!(
            (o[2] as f64 / pdf - 1.0).abs() < 1e-5,
            "item {i}, g {g}: HG density {} vs {pdf}",
            o[2]
        );
        assert!((v(o, 8) - e.1).length() < 2e-5, "item {i}: exit point");
        assert!((v(o, 12) - e.2).length() < 2e-5, "item {i}: exit dir");
        assert!((v(o, 16) - e.3).length() < 2e-5, "item {i}: event position");
    }
}

/// A read-back in pieces returns the buffer's bytes in order, whatever the piece: one that
/// divides the size, one that leaves a short last piece, one below wgpu's map alignment
/// (rounded up to it) and one beyond the size; an empty read-back and one of part of a word
/// are handled. Each word holds its own index mixed, so a
/// piece copied to the wrong place or twice is seen.
#[test]
fn read_back_in_pieces_returns_every_byte_in_order() {
    use render_gpu::gpu::resources::read_back_in_pieces;
    use wgpu::util::DeviceExt;
    let Some(ctx) = gpu() else { return };
    let ctx = ctx.lock().unwrap_or_else(|e| e.into_inner());
    let words: Vec<u32> = (0..1000u32)
        .map(|i| i.wrapping_mul(0x9e37_79b9) ^ 0x5bd1_e995)
        .collect();
    let buf = ctx
        .device
        .create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("read-back test"),
            contents: bytemuck::cast_slice(&words),
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
        });
    let expect: &[u8] = bytemuck::cast_slice(&words);
    for piece in [400, 96, 1, 1 << 20] {
        let got = read_back_in_pieces(&ctx, &buf, 4000, piece).expect("read back");
        assert!(got == expect, "piece {piece}: the bytes differ");
    }
    // A prefix: only the bytes asked for.
    let got = read_back_in_pieces(&ctx, &buf, 1204, 96).expect("read back");
    assert!(got == expect[..1204], "prefix: the bytes differ");
    // Nothing, and part of a word (which wgpu cannot copy) refused, not a panic.
    assert!(
        read_back_in_pieces(&ctx, &buf, 0, 96)
            .expect("empty")
            .is_empty()
    );
    assert!(read_back_in_pieces(&ctx, &buf, 6, 96).is_err());
}

/// The WGSL decoders (vec4 rows, softplus, log-variance clamp, de-standardisation) equal
/// the Rust decoder on random inputs within 1e-5 (relative to the output's size: both are
/// f32 with different summation orders, so the difference is a few ulps of the larger
/// partial sums).
#[test]
fn wgsl_decoders_match_rust() {
    let Some(ctx) = gpu() else { return };
    let ctx = ctx.lock().unwrap_or_else(|e| e.into_inner());
    let m = model();
    let decs = [&m.length, &m.path, &m.event];
    let mut rng = WalkRng::from_seed(5);
    let mut items = Vec::new();
    let mut expect = Vec::new();
    for i in 0..3000 {
        let id = i % 3;
        let d = decs[id];
        let mut it: Item = [0.0; 32];
        let mut cond = [0f64; 12];
        for k in 0..d.cond {
            // Raw features around their training scale.
            let v = (d.cond_shift[k] + d.cond_scale[k] * (rng.uniform() as f32 * 4.0 - 2.0)) as f64;
            cond[k] = v;
            it[k] = v as f32;
        }
        let mut noise = [0f32; 16];
        cvae::sampler::normals(&mut rng, &mut noise[..d.latent + d.out]);
        it[12..28].copy_from_slice(&noise);
        it[28] = id as f32;
        let mut res = [0f64; 8];
        d.sample(
            &cond[..d.cond],
            &noise[..d.latent],
            &noise[d.latent..d.latent + d.out],
            &mut res[..d.out],
        );
        items.push(it);
        expect.push((d.out, res));
    }
    let out = run_probe(&ctx, "probe_decoder", m, &items).unwrap();
    for (i, (o, (n, e))) in out.iter().zip(&expect).enumerate() {
        for k in 0..*n {
            let tol = 1e-5 * (1.0 + e[k].abs());
            assert!(
                (o[k] as f64 - e[k]).abs() < tol,
                "item {i} output {k}: WGSL {} vs Rust {}",
                o[k],
                e[k]
            );
        }
    }
}

/// The kernel's loop-limit probe (path.wgsl, `loop_limit_ran_out`), on which the renderer's
/// redo of cut-off dispatches rests: lavapipe stops an invocation's loops after 65,535
/// iterations in total, so a loop of 70,000 stops short and the probe that follows must
/// say so; after a loop of 1,000 it must not. Hardware GPUs have no limit: the long loop
/// runs to its end and the probe says nothing. 64 identical items, so that every SIMD
/// batch (which shares one counter) holds one kind of loop; each kind in its own dispatch.
#[test]
fn loop_limit_probe_sees_the_limit_run_out() {
    let Some(ctx) = gpu() else { return };
    let ctx = ctx.lock().unwrap_or_else(|e| e.into_inner());
    let software = ctx.adapter.software;
    for (n, cut) in [(1_000u32, false), (70_000, software)] {
        let mut item: Item = [0.0; 32];
        item[0] = n as f32;
        item[1] = render_gpu::gpu::scene_buffers::LOOP_PROBE_PASSES;
        let out = run_probe(&ctx, "probe_loop_limit", model(), &vec![item; 64]).unwrap();
        for o in &out {
            let ran = o[0] as u32;
            assert_eq!(
                (ran < n, o[1] == 1.0),
                (cut, cut),
                "a loop of {n} ran {ran} iterations, probe {} ({})",
                o[1],
                ctx.adapter.name
            );
        }
    }
}

/// The path counters the kernels add to (shaders/path.wgsl, add_stats), once per subgroup
/// (its lanes' sum, in 16-bit halves) or once per invocation: both give the exact 64-bit
/// totals. 203 items, so the last subgroup of each workgroup is partly empty; counts of 0,
/// small ones, and ones near 2^32, so that the counters' low words carry; the first 64
/// alternate 2^32 − 1 and 2^16 − 1, so that a subgroup's sum of halves carries too (8
/// lanes: low halves 0x7fff8, high halves 0x3fffc, 0x7fff8 + 0xfffc·2^16 ≥ 2^32; 32
/// lanes: 0x1fffe0 + 0xfff0·2^16). Integer sums, compared exactly.
#[test]
fn path_counters_add_up_per_subgroup_and_per_invocation() {
    let Some(ctx) = gpu() else { return };
    let ctx = ctx.lock().unwrap_or_else(|e| e.into_inner());
    let mut rng = WalkRng::from_seed(41);
    use render_gpu::gpu::probe::PROBE_COUNTERS;
    assert_eq!(
        PROBE_COUNTERS, 10,
        "every path counter, the walks' events too"
    );
    let counts: Vec<[u32; PROBE_COUNTERS]> = (0..203)
        .map(|i| {
            std::array::from_fn(|k| match (i + k) % 4 {
                _ if i < 64 => [u32::MAX, 0xffff][i % 2],
                0 => 0,
                1 => (rng.uniform() * 100.0) as u32,
                2 => u32::MAX - (rng.uniform() * 1000.0) as u32,
                _ => rng.next_u64() as u32,
            })
        })
        .collect();
    let want: [u64; PROBE_COUNTERS] =
        std::array::from_fn(|k| counts.iter().map(|c| c[k] as u64).sum());
    assert!(
        want.iter().all(|&w| w > u32::MAX as u64),
        "every total carries"
    );
    for aggregate in [true, false] {
        let got =
            render_gpu::gpu::probe::run_counter_probe(&ctx, model(), &counts, aggregate).unwrap();
        assert_eq!(got, want, "aggregate {aggregate} on {}", ctx.adapter.name);
    }
}

/// The WGSL antithetic EventGen pair: the partner's latent and output normals are
/// exactly the first draw's negated (the decoders only read the noise, so it survives the
/// first draw), and its event equals the Rust decoder's for that mirrored noise within
/// 1e-4 (f32 against f64 through the decoder and the event transforms).
#[test]
fn wgsl_event_pairs_are_mirrored() {
    let Some(ctx) = gpu() else { return };
    let ctx = ctx.lock().unwrap_or_else(|e| e.into_inner());
    // Both radial maps of EventGen's output (feature versions 2 and 3): the shipped
    // decoders read under each, which tests the transforms whatever the weights.
    for version in [2, 3] {
        let mut set = model().clone();
        set.feature_version = version;
        // Learned mode: no exact centre event (at the probe's φ = 0 exact mode always
        // picks it, the limit of φ/Λ(N)), so every draw goes through the decoder.
        set.single_scattering = cvae::model_file::SingleScattering::Learned;
        event_pairs_match(&ctx, &set);
    }
}

/// The WGSL read-outs of LengthGen (N = ⌊exp(y + prior)⌋ clamped to [n_min, 10^15]) and
/// PathGen (logit → cos θ, the disk's radial map → (β, α), repaired into the disk) equal
/// the Rust ones (`length_result`, `path_result`) for the noise the WGSL drew, in both
/// single-scattering modes (n_min 2 and 1). Tolerances: the decoder outputs agree within
/// ~1e-5 (`wgsl_decoders_match_rust`), which exp carries into N as a relative 1e-5, plus
/// f32's rounding of y + prior (|y + prior| < 20 here: 20 × 6e-8) and of N itself, and the
/// floor can step by one: |ΔN| ≤ 1 + 3e-5 N. The exit's maps have slopes below 1 in y and
/// (β, α), so 1e-4 absolute covers the 1e-5 of the outputs with f32 rounding to spare. A
/// tenth of the items move the prior by ±60 to reach both clamps, which the shipped
/// model's draws seldom do.
#[test]
fn wgsl_length_and_exit_read_outs_match_rust() {
    let Some(ctx) = gpu() else { return };
    let ctx = ctx.lock().unwrap_or_else(|e| e.into_inner());
    for mode in [
        cvae::model_file::SingleScattering::Exact,
        cvae::model_file::SingleScattering::Learned,
    ] {
        let mut set = model().clone();
        set.single_scattering = mode;
        length_and_exit_match(&ctx, &set);
    }
}

/// The WGSL conditioning features of a sphere step (τ feature ln(1 + τ) and the log prior
/// of N) equal cvae::features' (f64) on τ from 0 to 10⁴ and g across (−1, 1): the two are
/// written apart (decoder.wgsl and features.rs), and a change to one alone would feed the
/// GPU's decoders other inputs than the ones the model was trained on. Tolerance: the
/// inputs are exact f32 values on both sides; Vulkan's log is exact to 2⁻²¹ absolute near 1
/// and to 3 ulp of its result elsewhere (3 × 2⁻²³ ≈ 3.6e-7 relative), and the prior's
/// argument (up to ~10⁸) is a few f32 operations (each 6e-8 relative, which ln turns into
/// ≤ 3e-7 absolute): 2e-6 absolute plus 4e-7 of the value. A change of either coefficient
/// of the prior by 1 % moves it by far more for some items: the 0.5's by ~1e-2 at τ = 10⁴,
/// the 0.71's by ~9e-3 at τ = 10 with g near 1.
#[test]
fn wgsl_walk_features_match_rust() {
    let Some(ctx) = gpu() else { return };
    let ctx = ctx.lock().unwrap_or_else(|e| e.into_inner());
    let mut rng = WalkRng::from_seed(43);
    let items: Vec<Item> = (0..2000)
        .map(|i| {
            let mut it: Item = [0.0; 32];
            it[0] = match i % 10 {
                0 => 0.0,
                1 => 1e-6 * rng.uniform() as f32,
                _ => 10f64.powf(4.0 * rng.uniform()) as f32,
            };
            it[1] = (1.998 * rng.uniform() - 0.999) as f32;
            it
        })
        .collect();
    let out = render_gpu::gpu::probe::run_probe(&ctx, "probe_features", model(), &items).unwrap();
    for (i, (o, it)) in out.iter().zip(&items).enumerate() {
        let (tau, g) = (it[0] as f64, it[1] as f64);
        let f = cvae::features::WalkFeatures::new(tau, g, 1.0);
        for (k, (got, want)) in [(o[0], f.tau), (o[1], f.log_prior)].into_iter().enumerate() {
            assert!(
                (got as f64 - want).abs() < 2e-6 + 4e-7 * want.abs(),
                "item {i} (τ {tau}, g {g}): feature {k} {got} vs {want}"
            );
        }
    }
}

fn length_and_exit_match(ctx: &GpuContext, m: &cvae::ModelSet) {
    let (l0, l1) = (m.length.latent + m.length.out, m.path.latent + m.path.out);
    assert!(
        l0 <= 11 && l1 <= 16,
        "the probe's layout holds 11 + 16 normals"
    );
    let mut rng = WalkRng::from_seed(31);
    let items: Vec<Item> = (0..600)
        .map(|i| {
            let mut it: Item = [0.0; 32];
            let tau = 300.0 * rng.uniform().powi(2);
            let g = 1.8 * rng.uniform() - 0.9;
            let f = cvae::features::WalkFeatures::new(tau, g, 1.0);
            let shift = match i % 20 {
                0 => 60.0,
                1 => -60.0,
                _ => 0.0,
            };
            let rel = f.relative_log_n(1 + (200.0 * rng.uniform()) as u64);
            it[..4].copy_from_slice(&[
                f.tau as f32,
                g as f32,
                (f.log_prior + shift) as f32,
                rel as f32,
            ]);
            it[8] = i as f32;
            it
        })
        .collect();
    let out = render_gpu::gpu::probe::run_probe(ctx, "probe_length_path", m, &items).unwrap();
    let (mut low, mut high) = (0, 0);
    for (i, (o, it)) in out.iter().zip(&items).enumerate() {
        let f = cvae::features::WalkFeatures {
            tau: it[0] as f64,
            g: it[1] as f64,
            albedo: 0.0,
            log_prior: it[2] as f64,
        };
        let (z, eps) = o[1..1 + l0].split_at(m.length.latent);
        let n = m.length_result(
            &f,
            &m.length.output(&m.length.draw(&f.length_cond(), z, eps)),
        );
        let got = o[0] as f64;
        assert!(
            (got - n as f64).abs() <= 1.0 + 3e-5 * n as f64,
            "item {i} (n_min {}): N {got} vs {n}",
            m.n_min()
        );
        low += usize::from(n == m.n_min());
        high += usize::from(n == cvae::features::MAX_DECODED_N);
        let (z, eps) = o[16..16 + l1].split_at(m.path.latent);
        let cond = f.path_cond(it[3] as f64);
        let e = m.path_result(&m.path.output(&m.path.draw(&cond, z, eps)));
        let want = [e.cos_theta, e.alpha, e.beta];
        for (k, w) in want.iter().enumerate() {
            assert!(
                (o[12 + k] as f64 - w).abs() < 1e-4,
                "item {i}: exit {k} {} vs {w}",
                o[12 + k]
            );
        }
    }
    // Every item shifted by ±60 lands on a clamp (e^±60 beyond both ends).
    assert!(
        low >= 30 && high >= 30,
        "clamps reached: {low} at n_min, {high} at 10^15"
    );
}

fn event_pairs_match(ctx: &GpuContext, m: &cvae::ModelSet) {
    let (latent, out_n) = (m.event.latent, m.event.out);
    assert_eq!(latent + out_n, 11, "the probe's layout holds 11 normals");
    let mut rng = WalkRng::from_seed(8);
    let items: Vec<Item> = (0..500)
        .map(|i| {
            let mut it: Item = [0.0; 32];
            let tau = 2.0 + 100.0 * rng.uniform();
            let g = 1.6 * rng.uniform() - 0.8;
            let f = cvae::features::WalkFeatures::new(tau, g, 1.0);
            let rel = f.relative_log_n(2 + (50.0 * rng.uniform()) as u64);
            it[..4].copy_from_slice(&[f.tau as f32, g as f32, f.log_prior as f32, rel as f32]);
            let exit = [
                2.0 * rng.uniform() - 1.0,
                0.4 * rng.uniform() - 0.2,
                0.4 * rng.uniform() - 0.2,
            ];
            it[4..7].copy_from_slice(&exit.map(|v| v as f32));
            it[8] = i as f32;
            it
        })
        .collect();
    let out = run_probe(ctx, "probe_event_pair", m, &items).unwrap();
    for (i, (o, it)) in out.iter().zip(&items).enumerate() {
        for k in 0..11 {
            assert_eq!(o[11 + k], -o[k], "item {i} normal {k}");
        }
        // The Rust event of the mirrored draw: the WGSL condition (albedo feature 0: the
        // probe's params hold φ = 0 and feature 0) with the partner's noise.
        let cond: Vec<f64> = [it[0], it[1], 0.0, it[3], it[4], it[6], it[5]]
            .iter()
            .map(|&v| v as f64)
            .collect();
        let mut res = [0f64; 8];
        m.event.sample(
            &cond,
            &o[11..11 + latent],
            &o[11 + latent..22],
            &mut res[..out_n],
        );
        let mut raw = [0f32; cvae::decoder::MAX_OUT];
        for (r, v) in raw.iter_mut().zip(&res) {
            *r = *v as f32;
        }
        let (x, w) = m.event_result(&raw);
        let v = |k: usize| DVec3::new(o[k] as f64, o[k + 1] as f64, o[k + 2] as f64);
        assert!(
            (v(22) - x).length() < 1e-4,
            "v{}: item {i}: X {:?} vs {x:?}",
            m.feature_version,
            v(22)
        );
        assert!(
            (v(25) - w).length() < 1e-4,
            "item {i}: W {:?} vs {w:?}",
            v(25)
        );
    }
}

fn settings(kind: IntegratorKind, nee: bool) -> IntegratorSettings<'static> {
    let m = (kind == IntegratorKind::Stcvae).then(model);
    IntegratorSettings {
        kind,
        nee,
        model: m,
        min_tau: 1.0,
        max_tau: m.map_or(300.0, |m| m.training.tau_range[1] as f32),
        exact_tau: 0.0,
        nee_samples: 2,
        exact_nee_samples: 1,
        path_nee_rays: 1,
    }
}

fn opts(spp: u32, seed: u64) -> RenderOptions {
    RenderOptions {
        spp,
        seed,
        time_budget: None,
        variance: false,
    }
}

/// Environment variables set until this is dropped, and removed then even where a test
/// panics: the tests after it take the context's lock past the poisoning, and would read
/// them.
struct EnvVars<'a>(&'a [(&'a str, &'a str)]);

impl<'a> EnvVars<'a> {
    /// The caller holds the context's lock, as every render of this binary does, so no
    /// render reads the variables while they change.
    fn set(vars: &'a [(&'a str, &'a str)]) -> Self {
        for (name, value) in vars {
            // SAFETY: as above; nothing else in this binary reads the environment meanwhile.
            unsafe { std::env::set_var(name, value) };
        }
        Self(vars)
    }
}

impl Drop for EnvVars<'_> {
    fn drop(&mut self) {
        for (name, _) in self.0 {
            // SAFETY: as in `EnvVars::set`.
            unsafe { std::env::remove_var(name) };
        }
    }
}

/// The context with its limits (and largest subgroup) to be lowered or pretended, restored
/// when this is dropped, even where a test panics: the tests after it take the context's
/// lock past the poisoning, and would render under the changed limits.
struct Limits<'a> {
    ctx: &'a mut GpuContext,
    // Named apart from the context's own fields: `guard.limits` must reach the context's
    // (through DerefMut), not the copy kept for the restore.
    saved_limits: wgpu::Limits,
    saved_subgroup_max_size: u32,
}

impl<'a> Limits<'a> {
    fn new(ctx: &'a mut GpuContext) -> Self {
        Self {
            saved_limits: ctx.limits.clone(),
            saved_subgroup_max_size: ctx.subgroup_max_size,
            ctx,
        }
    }
}

impl Deref for Limits<'_> {
    type Target = GpuContext;
    fn deref(&self) -> &GpuContext {
        self.ctx
    }
}

impl DerefMut for Limits<'_> {
    fn deref_mut(&mut self) -> &mut GpuContext {
        self.ctx
    }
}

impl Drop for Limits<'_> {
    fn drop(&mut self) {
        self.ctx.limits = self.saved_limits.clone();
        self.ctx.subgroup_max_size = self.saved_subgroup_max_size;
    }
}

/// `render_gpu` with the environment variables `vars` set for this render only.
fn render_gpu_with_env(
    ctx: &GpuContext,
    s: &SceneData,
    set: &IntegratorSettings,
    o: &RenderOptions,
    vars: &[(&str, &str)],
) -> Result<RenderOutput, RenderError> {
    let _env = EnvVars::set(vars);
    render_gpu(ctx, s, set, o, &|_, _| {}, &AtomicBool::new(false))
}

/// The message of a render that must have been refused (`what` names it otherwise).
fn refusal(r: Result<RenderOutput, RenderError>, what: &str) -> String {
    match r {
        Ok(_) => panic!("{what} rendered"),
        Err(e) => e.to_string(),
    }
}

/// Two renders that must have taken the same paths: equal counters, equal pixels.
fn assert_same_render(base: &RenderOutput, out: &RenderOutput, what: &str) {
    assert_eq!(
        (out.stats.paths, out.stats.events),
        (base.stats.paths, base.stats.events),
        "{what}: other paths"
    );
    let differ = differing_pixels(base, out);
    assert_eq!(differ, 0, "{what}: {differ} pixels differ");
}

/// Pixels whose values differ at all between two renders of one size.
fn differing_pixels(a: &RenderOutput, b: &RenderOutput) -> usize {
    assert_eq!(a.image.pixels.len(), b.image.pixels.len());
    let pairs = a.image.pixels.iter().zip(&b.image.pixels);
    pairs.filter(|(p, q)| p != q).count()
}

/// The largest difference between two images' channels relative to the larger of the two
/// values (0 where both are equal, infinite where either is NaN and they differ): how far
/// apart two renders that should agree are.
fn largest_relative_difference(a: &RenderOutput, b: &RenderOutput) -> f32 {
    let channels = a
        .image
        .pixels
        .iter()
        .flatten()
        .zip(b.image.pixels.iter().flatten());
    channels
        .map(|(&x, &y)| {
            let relative = (x - y).abs() / x.abs().max(y.abs());
            if x == y {
                0.0
            } else if relative.is_nan() {
                f32::INFINITY
            } else {
                relative
            }
        })
        .fold(0.0, f32::max)
}

fn on_gpu(
    ctx: &GpuContext,
    s: &SceneData,
    set: &IntegratorSettings,
    o: &RenderOptions,
) -> RenderOutput {
    render_gpu(ctx, s, set, o, &|_, _| {}, &AtomicBool::new(false)).unwrap()
}

fn on_cpu(s: &SceneData, set: &IntegratorSettings, o: &RenderOptions) -> RenderOutput {
    render(s, set, o, &|_, _| {}, &AtomicBool::new(false))
}

/// White furnace on the GPU (design §5): albedo 1, constant environment 0.7, no lights:
/// every path weight is 1 and every path ends in the environment, so every pixel is 0.7
/// up to f32 rounding — for PT and ST-CVAE, index-matched and dielectric, and from a
/// camera 10⁵ away. A leak, a lost path or a NaN shows. At 13 spp the channels have 5, 4
/// and 4 samples, and each channel's own mean (`resolve_pixel`) is 0.7 exactly, where
/// dividing by the spp was not.
#[test]
fn white_furnace_gpu() {
    let Some(ctx) = gpu() else { return };
    let ctx = ctx.lock().unwrap_or_else(|e| e.into_inner());
    let matched = "kind = \"index-matched\"";
    for (boundary, text) in [
        (matched, common::furnace_scene(matched)),
        (
            "dielectric",
            common::furnace_scene("kind = \"dielectric\"\nior = 1.5"),
        ),
        ("far camera", common::far_furnace_scene(matched)),
    ] {
        // ST-CVAE with the models for every step, and with exact steps below τ = 50.
        let exact = IntegratorSettings {
            exact_tau: 50.0,
            ..settings(IntegratorKind::Stcvae, true)
        };
        for (kind, set) in [
            (IntegratorKind::Pt, settings(IntegratorKind::Pt, true)),
            (
                IntegratorKind::Stcvae,
                settings(IntegratorKind::Stcvae, true),
            ),
            (IntegratorKind::Stcvae, exact),
        ] {
            let s = common::build_scene(&text, kind == IntegratorKind::Stcvae);
            let out = on_gpu(&ctx, &s, &set, &opts(13, 3));
            let st = out.stats;
            assert_eq!(
                st.capped + st.non_finite + st.leaks,
                0,
                "{kind:?} {boundary}: {st:?}"
            );
            assert_eq!(st.paths, 12 * 12 * 13, "every sample traced once: {st:?}");
            if kind == IntegratorKind::Stcvae {
                assert!(st.steps > st.paths / 4, "sphere steps must run: {st:?}");
                if set.exact_tau > 0.0 {
                    assert!(
                        st.exact_steps > st.steps / 2,
                        "exact steps must run: {st:?}"
                    );
                }
            }
            for (i, p) in out.image.pixels.iter().enumerate() {
                for (c, v) in p.iter().enumerate() {
                    assert!(
                        (v - 0.7).abs() < 1e-4,
                        "{kind:?} {boundary}: pixel {i} channel {c} = {v}",
                    );
                }
            }
        }
    }
}

/// `RenderOptions::variance` on the GPU: the kernels' per-slot squared sums
/// (`kernels::acc_sq_vec4`), checked as integrators.rs checks the CPU renderer's
/// (`the_variance_image_matches_the_spread_between_seeds`). In a white furnace every
/// sample is 0.9, so each pixel's variance is 0 up to rounding, which the compensated
/// squares keep below 1e-10 (PT and ST-CVAE, the single kernel and the staged render;
/// the bound is one-sided, since `pixel_variance` clamps below at 0, and squares lost
/// altogether pass it: `staged_render_equals_one_kernel` holds the schedules' variance
/// images equal, and a stop mid-chunk's is checked in `a_stop_mid_chunk_keeps_the_whole_chunks`).
/// On the lit sphere (configs/scenes/sphere.toml at 12², PT + NEE, 24 spp: 8 samples a
/// channel) the reported variances, summed over pixels and channels, match (a) the
/// spread of each pixel's value over K = 12 seeds and (b) the CPU renderer's reported
/// variances of the same scene (12 other seeds), both as ratios in the CPU test's band
/// [0.6, 1.6]: each side pools ~60 object pixels × 3 channels × 12 renders, whose ratio
/// the CPU test measured at 1.025; noise of the pooled sums from heavy-tailed NEE samples
/// is what the band's width allows for. The hero channel's factor 3 squared into the sums
/// (9×) or a sample's variance for the mean's (8×) lands far outside it. The formula the
/// host applies to the sums is `render::pixel_variance`, checked exactly in render.rs.
#[test]
fn gpu_variance_image_matches_the_spread_and_the_cpu() {
    let Some(ctx) = gpu() else { return };
    let ctx = ctx.lock().unwrap_or_else(|e| e.into_inner());
    let with_variance = |spp: u32, seed: u64| RenderOptions {
        variance: true,
        ..opts(spp, seed)
    };
    // At 0.9 each sample adds x = 3·0.9 = 2.6999998 in f32, whose f32 square is 3.8e-8
    // above x²: squares rounded so (no exact_square in path.wgsl) leave each pixel a
    // variance of ~1.4e-9, above the bound. (At the usual furnace's 0.7 the rounding is
    // downward and the variance is clamped to 0, so that could not show it.)
    let furnace = common::furnace_scene("kind = \"index-matched\"")
        .replace("radiance = [0.7, 0.7, 0.7]", "radiance = [0.9, 0.9, 0.9]");
    assert!(furnace.contains("[0.9, 0.9, 0.9]"));
    for kind in [IntegratorKind::Pt, IntegratorKind::Stcvae] {
        let s = common::build_scene(&furnace, kind == IntegratorKind::Stcvae);
        for staged in [false, true] {
            let vars: &[(&str, &str)] = if staged {
                &[("STCVAE_GPU_STAGED", "1")]
            } else {
                &[]
            };
            let out =
                render_gpu_with_env(&ctx, &s, &settings(kind, true), &with_variance(13, 3), vars)
                    .unwrap();
            common::assert_noiseless(
                &out.variance.expect("a variance image at 13 spp"),
                &format!("{kind:?}, staged {staged}"),
            );
        }
        // Below 6 spp some channel has one sample: no variance image, as on the CPU.
        let few = on_gpu(&ctx, &s, &settings(kind, true), &with_variance(5, 3));
        assert!(few.variance.is_none(), "{kind:?}");
    }

    let text = std::fs::read_to_string(
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs/scenes/sphere.toml"),
    )
    .unwrap()
    .replace("width = 128", "width = 12")
    .replace("height = 128", "height = 12");
    assert!(text.contains("width = 12\n") && text.contains("height = 12\n"));
    let s = common::build_scene(&text, false);
    let set = settings(IntegratorKind::Pt, true);
    let k = 12u64;
    let gpu_outs: Vec<RenderOutput> = (0..k)
        .map(|seed| on_gpu(&ctx, &s, &set, &with_variance(24, 100 + seed)))
        .collect();
    let cpu_outs: Vec<RenderOutput> = (0..k)
        .map(|seed| on_cpu(&s, &set, &with_variance(24, 200 + seed)))
        .collect();
    let reported = |outs: &[RenderOutput]| -> f64 {
        let var = outs.iter().map(|o| o.variance.as_ref().unwrap());
        var.flat_map(|v| v.pixels.iter().flatten().map(|&x| x as f64))
            .sum::<f64>()
            / outs.len() as f64
    };
    let mut spread = 0f64;
    for p in 0..gpu_outs[0].image.pixels.len() {
        for c in 0..3 {
            let vals: Vec<f64> = gpu_outs
                .iter()
                .map(|o| o.image.pixels[p][c] as f64)
                .collect();
            let mean = vals.iter().sum::<f64>() / k as f64;
            // Background pixels (the constant sky) add 0 here and to the reported sums.
            spread += vals.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (k - 1) as f64;
        }
    }
    let (gpu_reported, cpu_reported) = (reported(&gpu_outs), reported(&cpu_outs));
    let (to_spread, to_cpu) = (spread / gpu_reported, gpu_reported / cpu_reported);
    eprintln!(
        "GPU variance: spread over seeds / reported = {to_spread:.3}, GPU / CPU reported = \
         {to_cpu:.3} (Σ reported {gpu_reported:.3e})"
    );
    assert!(
        gpu_reported > 0.0 && (0.6..1.6).contains(&to_spread) && (0.6..1.6).contains(&to_cpu),
        "spread / reported {to_spread}, GPU / CPU {to_cpu}"
    );
}

/// The kernels count the scattering events inside exact steps' walks (`exact_events`, the
/// walks' N), as the CPU does (integrators.rs, `exact_walk_events_add_up_to_pts_events`):
/// with every step exact, albedo 1 and NEE off, they and the fallback events add up in
/// expectation to PT's events per path. Eight renders of 24² × 30 spp on each side (on
/// different seeds) give the batch means' spread; with its ~11 degrees of freedom (Welch,
/// measured spreads) |t| > 5.5 has probability ~2e-4 under agreement. Uncounted, the walks'
/// events would leave ST-CVAE's total at ~1 a path against PT's ~15; each walk counted one
/// short would move it by the exact steps a path (~3), checked to be above 7.5 standard
/// errors of the difference (the bound plus 2: such a shift fails ~92 % of the time as a t
/// with ~11 degrees of freedom; at 4,
/// below the bound, it could pass).
#[test]
fn gpu_exact_walk_events_add_up_to_pts_events() {
    let Some(ctx) = gpu() else { return };
    let ctx = ctx.lock().unwrap_or_else(|e| e.into_inner());
    let text = r#"
[camera]
origin = [0.0, 0.0, 4.0]
target = [0.0, 0.0, 0.0]
fov_deg = 18.0
width = 24
height = 24
[object]
shape = "sphere"
radius = 0.5
[medium]
sigma_t = [20.0, 40.0, 80.0]
albedo = [1.0, 1.0, 1.0]
g = 0.5
[environment]
radiance = [1.0, 1.0, 1.0]
[render]
grid_resolution = 64
"#;
    let exact = IntegratorSettings {
        exact_tau: 50.0,
        max_tau: 49.0,
        min_tau: 0.0,
        ..settings(IntegratorKind::Stcvae, false)
    };
    let pt = settings(IntegratorKind::Pt, false);
    let mut means = Vec::new();
    let mut steps = 0.0;
    for (set, seed) in [(&pt, 40), (&exact, 60)] {
        let s = common::build_scene(text, set.kind == IntegratorKind::Stcvae);
        let batches: Vec<f64> = (0..8)
            .map(|b| {
                let st = on_gpu(&ctx, &s, set, &opts(30, seed + b)).stats;
                if set.kind == IntegratorKind::Stcvae {
                    assert!(
                        st.exact_steps == st.steps
                            && st.steps > st.paths / 4
                            && st.exact_events >= st.exact_steps,
                        "every step exact, each walk of at least one event: {st:?}"
                    );
                    steps = st.exact_steps as f64 / st.paths as f64;
                }
                (st.events + st.exact_events) as f64 / st.paths as f64
            })
            .collect();
        means.push(common::batch_mean_se(&batches));
    }
    let ((a, sa), (b, sb)) = (means[0], means[1]);
    let t = (a - b) / (sa * sa + sb * sb).sqrt();
    eprintln!(
        "GPU events a path: PT {a:.3} ± {sa:.3}, ST-CVAE {b:.3} ± {sb:.3}, t = {t:.2}; exact steps a path {steps:.3}"
    );
    assert!(
        steps > 7.5 * (sa * sa + sb * sb).sqrt(),
        "an off-by-one a walk ({steps:.3} a path) would not show"
    );
    assert!(
        t.abs() < 5.5 && a > 5.0,
        "PT {a:.3} ± {sa:.3} events a path, ST-CVAE's exact walks and fallbacks {b:.3} ± {sb:.3} (t = {t:.2})"
    );
}

/// The kernels pick each sample's hero channel with the same function as the CPU
/// (`channel_offset`): in a 1-spp furnace render every pixel is 3L in exactly the channel
/// the CPU would have traced there, for two seeds.
#[test]
fn gpu_hero_channels_equal_the_cpu_ones() {
    let Some(ctx) = gpu() else { return };
    let ctx = ctx.lock().unwrap_or_else(|e| e.into_inner());
    let text = common::furnace_scene("kind = \"index-matched\"");
    let s = common::build_scene(&text, false);
    for seed in [5u64, 1 << 40 | 7] {
        let out = on_gpu(
            &ctx,
            &s,
            &settings(IntegratorKind::Pt, true),
            &opts(1, seed),
        );
        for (i, p) in out.image.pixels.iter().enumerate() {
            let c = render_gpu::render::channel_offset(seed, i as u32) as usize;
            for k in 0..3 {
                let want = if k == c { 2.1 } else { 0.0 };
                assert!(
                    (p[k] - want).abs() < 1e-4,
                    "seed {seed} pixel {i}: {p:?}, the CPU traces channel {c}"
                );
            }
        }
    }
}

/// Per-channel block means over K renders with different seeds: (mean, variance of the
/// mean, q) with the variance from the spread of the K renders (K − 1 degrees of freedom
/// per pixel) and q = Σ (its pixels' terms)²/(K − 1), so that Welch–Satterthwaite gives
/// the degrees of freedom of a sum of such variances as (Σ v)²/Σ q.
fn blocks(r: &[RenderOutput], size: usize) -> Vec<(f64, f64, f64)> {
    let w = r[0].image.width;
    let h = r[0].image.height;
    let k = r.len() as f64;
    let mut out = Vec::new();
    for by in (0..h).step_by(size) {
        for bx in (0..w).step_by(size) {
            for c in 0..3 {
                let (mut m, mut v, mut q, mut n) = (0.0, 0.0, 0.0, 0.0);
                for y in by..(by + size).min(h) {
                    for x in bx..(bx + size).min(w) {
                        let vals: Vec<f64> = r
                            .iter()
                            .map(|o| o.image.pixels[y * w + x][c] as f64)
                            .collect();
                        let mean = vals.iter().sum::<f64>() / k;
                        let var =
                            vals.iter().map(|q| (q - mean) * (q - mean)).sum::<f64>() / (k - 1.0);
                        m += mean;
                        v += var / k;
                        q += (var / k) * (var / k) / (k - 1.0);
                        n += 1.0;
                    }
                }
                out.push((m / n, v / (n * n), q / (n * n * n * n)));
            }
        }
    }
    out
}

/// Fewest Welch degrees of freedom of a block's noise estimate for its z to count. A block
/// at the silhouette whose noise comes from one pixel has 2·(K − 1) = 6: its z is t₆,
/// beyond 6.5 with probability 6e-4, and its z² has mean ν/(ν − 2) = 1.5 and variance
/// 2ν²(ν − 1)/((ν − 2)²(ν − 4)) = 11.25. At ν ≥ 20, P(|t| > 6.5) < 3e-6 and z² has mean
/// ≤ 1.11 and variance ≤ 2.93.
const MIN_BLOCK_DOF: f64 = 20.0;

/// CPU and GPU converge to the same image: block-mean differences divided by their
/// estimated noise are z-scores, each a t-variable with the block's Welch degrees of
/// freedom ν (up to 16 pixels × 3 per device); blocks with ν < MIN_BLOCK_DOF are left
/// out. Under noise alone E z² ≤ 1.11 and the mean of z² over k blocks has sd ≤ √(2.93/k)
/// (more with the heavy tails of paths that find the sun disk). A wrong estimator (a
/// missed Fresnel factor, a lost NEE term, a wrong Λ(N)) shifts whole regions by many σ;
/// the thresholds (mean z² < 1.5 + 4√(2/k): (0.39 + 4√(2/k))/√(2.93/k) ≥ 4.5 sd above the
/// null for k ≥ 30, ≥ 5 sd for k ≥ 56, and max
/// |z| < 6.5) fail it while noise alone passes with a wide margin.
///
/// Across the file (counted 2026-12-07): 44 render comparisons at 24² or 32² (at most 64
/// blocks × 3 channels each) and three work maps at 48² (144 blocks, channel 0 only), at
/// most ~8,900 block z's in all. At the floor ν = 20 each passes 6.5 with probability
/// 2.5e-6 (≈ 2 % over the file if every block sat there); most blocks have ν near 90
/// (16 pixels × 3 per device), where it is 4e-9. The seeds are fixed, so that is the chance that a reseed or a change that only
/// redraws the random numbers trips it, not a flaky run.
///
/// Those two see a difference's size, not its sign, so a small bias of the same sign in
/// every block (δ block-σ) raises mean z² only by δ² and passes them up to δ ≈ 1.0–1.2.
/// The signed sum catches it: the blocks are disjoint and a path adds to one channel, so
/// the z are independent (nearly: on the CPU a pixel's three channels share their jitters,
/// which correlates them where the image changes within a pixel, at silhouettes); CPU and GPU run the same estimator, so each z is symmetric
/// about 0 (swapping the devices flips its sign). S = Σz / √(k·s²), with s² the z's
/// spread about their mean floored at the t-variance bound 1.11, is then about N(0, 1)
/// for k ≥ 30, and |S| < 4.5 is a false alarm with probability ~7·10⁻⁶; a shift δ makes
/// S ≈ δ√k/1.05, failing from δ ≈ 0.86 at k = 30 and δ ≈ 0.45 at k = 108. Measured on
/// lavapipe (2026-11-28): S from −0.81 to 1.40 over the 18 comparisons the file made then.
fn assert_same_image(name: &str, cpu: &[RenderOutput], gpu: &[RenderOutput]) {
    let a = blocks(cpu, 4);
    let b = blocks(gpu, 4);
    let mut z2 = 0.0;
    let mut zsum = 0.0;
    let mut k = 0.0;
    let mut zmax: f64 = 0.0;
    for (&(ma, va, qa), &(mb, vb, qb)) in a.iter().zip(&b) {
        // Background blocks are noiseless up to rounding (the GPU sums in f32, the CPU in
        // f64): a relative 1e-5 floor on the deviation keeps rounding from counting as noise.
        let v = va + vb;
        let floor = 1e-5 * ma.abs().max(mb.abs());
        if v <= floor * floor {
            assert!(
                (ma - mb).abs() < 1e-5,
                "{name}: noiseless block differs: {ma} vs {mb}"
            );
            continue;
        }
        if v * v / (qa + qb) < MIN_BLOCK_DOF {
            continue;
        }
        let z = (ma - mb) / v.sqrt();
        z2 += z * z;
        zsum += z;
        zmax = zmax.max(z.abs());
        k += 1.0;
    }
    assert!(
        k >= 30.0,
        "{name}: only {k} blocks with enough noise estimate"
    );
    let mean_z2 = z2 / k;
    let spread = ((z2 - zsum * zsum / k) / (k - 1.0)).max(1.11);
    let signed = zsum / (k * spread).sqrt();
    let mean = |o: &[RenderOutput]| {
        let n = o[0].image.pixels.len() as f64 * o.len() as f64;
        [0, 1, 2].map(|c| {
            o.iter()
                .flat_map(|r| r.image.pixels.iter().map(move |p| p[c] as f64))
                .sum::<f64>()
                / n
        })
    };
    eprintln!(
        "{name}: {k} blocks, mean z² {mean_z2:.2}, max |z| {zmax:.2}, signed sum {signed:.2}; \
         image mean CPU {:?} GPU {:?}",
        mean(cpu),
        mean(gpu)
    );
    assert!(
        mean_z2 < 1.5 + 4.0 * (2.0 / k).sqrt() && zmax < 6.5 && signed.abs() < 4.5,
        "{name}: CPU and GPU images differ beyond noise (mean z² {mean_z2:.2}, max |z| \
         {zmax:.2}, signed sum {signed:.2})"
    );
    for o in gpu {
        assert_eq!(
            o.stats.capped + o.stats.non_finite,
            0,
            "{name}: {:?}",
            o.stats
        );
    }
}

fn sphere_scene(boundary: &str) -> String {
    format!(
        r#"
[camera]
origin = [0.0, 0.0, 3.0]
target = [0.0, 0.0, 0.0]
fov_deg = 22.0
width = 24
height = 24
[object]
shape = "sphere"
radius = 0.5
[medium]
sigma_t = [8.0, 15.0, 30.0]
albedo = [0.99, 0.95, 0.9]
g = 0.5
[boundary]
{boundary}
{SPHERE_SCENE_DISK}[environment]
radiance = [0.1, 0.1, 0.1]
[render]
grid_resolution = 64
"#
    )
}

/// `sphere_scene`'s one light (tests replace it in the text).
const SPHERE_SCENE_DISK: &str = "[[light]]\nkind = \"directional\"\n\
    direction = [-0.5, -0.6, -0.62]\nirradiance = [2.0, 2.0, 2.0]\nangular_diameter_deg = 40.0\n";

/// `text` (a `sphere_scene`) with another extinction and albedo.
fn with_medium(text: String, sigma_t: &str, albedo: &str) -> String {
    text.replace(
        "sigma_t = [8.0, 15.0, 30.0]",
        &format!("sigma_t = {sigma_t}"),
    )
    .replace("albedo = [0.99, 0.95, 0.9]", &format!("albedo = {albedo}"))
}

fn compare_devices(name: &str, text: &str, kind: IntegratorKind, nee: bool, spp: u32) {
    compare_devices_with(name, text, &settings(kind, nee), spp);
}

/// Returns the GPU renders (None where the tests are skipped).
fn compare_devices_with(
    name: &str,
    text: &str,
    set: &IntegratorSettings,
    spp: u32,
) -> Option<Vec<RenderOutput>> {
    let ctx = gpu()?;
    let ctx = ctx.lock().unwrap_or_else(|e| e.into_inner());
    let s = common::build_scene(text, set.kind == IntegratorKind::Stcvae);
    let set = *set;
    // `STCVAE_GPU_TEST_SPP` (undocumented, for looking closer by hand) may only raise the
    // spp each comparison was sized for: fewer samples would weaken it unseen.
    let spp = match std::env::var("STCVAE_GPU_TEST_SPP") {
        Ok(v) => {
            let more: u32 = v.parse().expect("STCVAE_GPU_TEST_SPP: a whole number");
            assert!(
                more >= spp,
                "STCVAE_GPU_TEST_SPP {more} is below {name}'s {spp}"
            );
            more
        }
        Err(_) => spp,
    };
    let cpu: Vec<_> = (1..=4)
        .map(|seed| on_cpu(&s, &set, &opts(spp, seed)))
        .collect();
    let gpu: Vec<_> = (5..=8)
        .map(|seed| on_gpu(&ctx, &s, &set, &opts(spp, seed)))
        .collect();
    for o in &gpu {
        assert_eq!(o.stats.paths, (o.image.pixels.len() as u64) * spp as u64);
    }
    assert_same_image(name, &cpu, &gpu);
    Some(gpu)
}

/// The per-pixel work map (`RenderOutput::work`: PT events + sphere steps a path, the
/// paper's Fig. 8), which the kernels count per path slot (`kernels::acc_lo_vec4`'s w).
/// Exactly: on each device the map times the spp sums to the render's counters (events +
/// steps), to f32 rounding of the per-pixel means (1e-5 relative), for the single kernel
/// and the staged render, whose sphere steps run in a kernel of their own. In distribution:
/// the GPU's maps against the CPU's, K = 4 renders a device, with the image test's
/// block z-scores (`assert_same_image`; the map in channel 0, the other two 0 and so
/// noiseless, skipped), on the sphere at 48² so that ≥ 30 4×4 blocks cover it: a count
/// put to the wrong pixel or path, or a visit counted twice, moves whole blocks by many σ.
#[test]
fn gpu_work_map_matches_the_counters_and_the_cpu() {
    let Some(ctx) = gpu() else { return };
    let ctx = ctx.lock().unwrap_or_else(|e| e.into_inner());
    let text = sphere_scene("kind = \"index-matched\"")
        .replace("width = 24\nheight = 24", "width = 48\nheight = 48");
    assert!(text.contains("width = 48"));
    let summed = |o: &RenderOutput, what: &str| {
        let map: f64 = o.work.iter().map(|&w| w as f64 * o.spp as f64).sum();
        let counted = (o.stats.events + o.stats.steps) as f64;
        assert_eq!(o.work.len(), o.image.pixels.len(), "{what}");
        assert!(
            counted > 0.0 && (map - counted).abs() <= 1e-5 * counted,
            "{what}: the map sums to {map}, the counters to {counted}"
        );
    };
    let as_image = |o: &RenderOutput| {
        let mut m = RenderOutput {
            image: o.image.clone(),
            work: Vec::new(),
            variance: None,
            ..*o
        };
        for (p, &w) in m.image.pixels.iter_mut().zip(&o.work) {
            *p = [w, 0.0, 0.0];
        }
        m
    };
    // min_tau 0 as well, in a medium 5× denser: there a free bound of 0 must still be
    // refined by the exact distance (sphere_step.rs; stcvae.wgsl, scatter_at), or the path
    // falls back to PT events where the CPU takes a sphere step, which the image barely
    // shows but the map does (with the kernels' guard dropped: mean z² 13.5, signed sum
    // −30.6 here; −4.4, a pass, in the base scene).
    let min_tau_0 = IntegratorSettings {
        min_tau: 0.0,
        ..settings(IntegratorKind::Stcvae, true)
    };
    let dense = with_medium(text.clone(), "[40.0, 80.0, 160.0]", "[0.99, 0.95, 0.9]");
    assert!(dense.contains("sigma_t = [40.0, 80.0, 160.0]"));
    let cases = [
        (settings(IntegratorKind::Pt, true), &text),
        (settings(IntegratorKind::Stcvae, true), &text),
        (min_tau_0, &dense),
    ];
    for (set, text) in cases {
        let kind = set.kind;
        let s = common::build_scene(text, kind == IntegratorKind::Stcvae);
        let cpu: Vec<_> = (1..=4)
            .map(|seed| on_cpu(&s, &set, &opts(16, seed)))
            .collect();
        let gpu: Vec<_> = (5..=8)
            .map(|seed| on_gpu(&ctx, &s, &set, &opts(16, seed)))
            .collect();
        for (i, o) in cpu.iter().chain(&gpu).enumerate() {
            summed(o, &format!("{kind:?}, render {i} (CPU first)"));
        }
        let staged =
            render_gpu_with_env(&ctx, &s, &set, &opts(16, 9), &[("STCVAE_GPU_STAGED", "1")])
                .unwrap();
        summed(&staged, &format!("{kind:?}, staged"));
        let maps = |r: &[RenderOutput]| r.iter().map(as_image).collect::<Vec<_>>();
        let what = format!("{kind:?} work map, min_tau {}", set.min_tau);
        assert_same_image(&what, &maps(&cpu), &maps(&gpu));
    }
}

#[test]
fn cpu_gpu_agree_pt_sphere() {
    let im = sphere_scene("kind = \"index-matched\"");
    compare_devices("PT, NEE", &im, IntegratorKind::Pt, true, 96);
    compare_devices("PT, no NEE", &im, IntegratorKind::Pt, false, 96);
    let di = sphere_scene("kind = \"dielectric\"\nior = 1.5");
    compare_devices("PT dielectric, NEE", &di, IntegratorKind::Pt, true, 96);
    // Without NEE a path reaches the sun only by escaping toward it, through the Fresnel
    // choices alone.
    compare_devices("PT dielectric, no NEE", &di, IntegratorKind::Pt, false, 96);
}

/// NEE through a dielectric cube under a sun 60° off its top face's normal, where the
/// shadow ray's refraction (nee.rs, `shadow`; nee.wgsl, `shadow_of`) changes the image most
/// (the straight ray read it 7–12 % brighter): the kernels must refract as the CPU does,
/// one shadow ray at every event (PT) and through the path's reservoirs (ST-CVAE), seen
/// 30° off the top face's normal (its mirror image of the sun misses the camera) through
/// a lens that sees its middle half. The image test as in `cpu_gpu_agree_pt_sphere`: with
/// the kernels' shadow rays straight it failed (mean z² 9.1, signed sum −27.4: the image
/// +8 %), as it did with only the phase function's refracted reading left out (on the
/// signed sum, −7.4).
#[test]
fn cpu_gpu_agree_on_refracted_nee_through_flat_faces() {
    let cube = &common::dielectric_cube_scene(8.0, 24, 0.3, "[0.0, 0.8660254, -0.5]");
    compare_devices(
        "PT, NEE, cube, oblique sun",
        cube,
        IntegratorKind::Pt,
        true,
        96,
    );
    compare_devices(
        "ST-CVAE, NEE, cube, oblique sun",
        cube,
        IntegratorKind::Stcvae,
        true,
        64,
    );
}

/// A 16×8 environment map with pixel (x, y) = `f(x, y)`, written as `sky.exr` in `d`.
fn sky(d: &tempfile::TempDir, f: impl Fn(usize, usize) -> [f32; 3]) -> std::path::PathBuf {
    use render_gpu::image_io::{RenderTag, RgbImage, write_exr};
    let mut map = RgbImage::new(16, 8);
    for (i, p) in map.pixels.iter_mut().enumerate() {
        *p = f(i % 16, i / 16);
    }
    let path = d.path().join("sky.exr");
    let tag = RenderTag {
        spp: 1,
        scene_hash: 0,
        seeds: Vec::new(),
        partial: false,
        unknown_digests: Vec::new(),
        view_hash: None,
    };
    write_exr(&path, &map, &tag).unwrap();
    path
}

/// An environment map is read the same way on both devices (light.rs, Environment::lookup;
/// its orientation is tested there): a map that changes along both its axes and in every
/// channel, seen directly around −z (where u wraps from the last column to the first) and
/// through the sphere. PT without NEE: the map, and the sun disk that escaping paths find,
/// are the light. The image is wide (32 × 16), as no other comparison's is: the kernels'
/// camera rays for a non-square image (a height/width ratio turned over leaves square ones
/// alike; `camera::tests::pixels_are_square_in_any_image_shape` checks the CPU's).
#[test]
fn cpu_gpu_agree_under_an_environment_map() {
    let d = tempfile::tempdir().unwrap();
    let path = sky(&d, |x, y| {
        [
            (x + 1) as f32 / 8.0,
            if y < 4 { 1.0 } else { 0.2 },
            if x < 8 { 1.5 } else { 0.1 },
        ]
    });
    let text = sphere_scene("kind = \"index-matched\"")
        .replace(
            "radiance = [0.1, 0.1, 0.1]",
            &format!("file = {:?}", path.to_str().unwrap()),
        )
        .replace("width = 24\nheight = 24", "width = 32\nheight = 16");
    assert!(text.contains("height = 16"));
    compare_devices(
        "PT under an environment map",
        &text,
        IntegratorKind::Pt,
        false,
        48,
    );
}

#[test]
fn cpu_gpu_agree_stcvae_sphere() {
    let im = sphere_scene("kind = \"index-matched\"");
    compare_devices("ST-CVAE, NEE", &im, IntegratorKind::Stcvae, true, 96);
    compare_devices("ST-CVAE, no NEE", &im, IntegratorKind::Stcvae, false, 96);
    // Path-level NEE (integrator::nee::PathNee; shaders/nee.wgsl) with two reservoirs, and
    // a shadow ray at every event (0), on both devices.
    for rays in [0, 2] {
        let set = IntegratorSettings {
            path_nee_rays: rays,
            ..settings(IntegratorKind::Stcvae, true)
        };
        compare_devices_with(&format!("ST-CVAE, NEE, {rays} path rays"), &im, &set, 96);
    }
    let di = sphere_scene("kind = \"dielectric\"\nior = 1.5");
    // The models' steps inside a dielectric, the light found by escaping alone.
    compare_devices(
        "ST-CVAE dielectric, no NEE",
        &di,
        IntegratorKind::Stcvae,
        false,
        96,
    );
    // With NEE: its 1/ior² and its crossings' Fresnel weights (Boundary::nee_scale,
    // crossing_transmittance) in every NEE route, path-level reservoirs and exact walks
    // included.
    compare_devices(
        "ST-CVAE dielectric, NEE",
        &di,
        IntegratorKind::Stcvae,
        true,
        96,
    );
    // Exact sphere steps (the kernels' exact_walk against sphere_step::ExactStep): below
    // the default threshold with one NEE event each, and every step (min_tau 0, max_tau
    // 49 < exact_tau 50) with two (two reservoirs, merged when they hold one event).
    let exact = IntegratorSettings {
        exact_tau: render_gpu::scene::DEFAULT_EXACT_TAU as f32,
        ..settings(IntegratorKind::Stcvae, true)
    };
    compare_devices_with("ST-CVAE exact steps, NEE", &im, &exact, 96);
    let all_exact = IntegratorSettings {
        exact_tau: 50.0,
        max_tau: 49.0,
        min_tau: 0.0,
        exact_nee_samples: 2,
        path_nee_rays: 1,
        ..exact
    };
    compare_devices_with("ST-CVAE all steps exact, NEE", &im, &all_exact, 96);
    let no_nee = IntegratorSettings {
        nee: false,
        ..all_exact
    };
    compare_devices_with("ST-CVAE all steps exact, no NEE", &im, &no_nee, 96);
}

/// A sun disk in view with NEE on, as `integrators.rs`'s
/// `a_sun_disk_in_view_is_seen_with_nee_on`: a camera ray that escapes without scattering
/// sees L = E/(π sin²θ) over the sky (path.wgsl's escape, `ps.scattered`), in every
/// sample, to f32 rounding (1e-4); PT and ST-CVAE, NEE on and off. No other GPU scene has
/// a disk in view.
#[test]
fn gpu_sees_a_sun_disk_in_view_with_nee_on() {
    let Some(ctx) = gpu() else { return };
    let ctx = ctx.lock().unwrap_or_else(|e| e.into_inner());
    let text = sphere_scene("kind = \"index-matched\"")
        .replace("target = [0.0, 0.0, 0.0]", "target = [1.0, 0.0, 3.0]")
        .replace("fov_deg = 22.0", "fov_deg = 1.0")
        .replace("width = 24\nheight = 24", "width = 4\nheight = 4")
        .replace(
            SPHERE_SCENE_DISK,
            "[[light]]\nkind = \"directional\"\ndirection = [-1.0, 0.0, 0.0]\n\
             irradiance = [1.0, 2.0, 3.0]\nangular_diameter_deg = 10.0\n",
        );
    assert!(text.contains("target = [1.0, 0.0, 3.0]") && text.contains("= 10.0"));
    for kind in [IntegratorKind::Pt, IntegratorKind::Stcvae] {
        let s = common::build_scene(&text, kind == IntegratorKind::Stcvae);
        for nee in [true, false] {
            let out = on_gpu(&ctx, &s, &settings(kind, nee), &opts(3, 1));
            common::assert_sun_disk_seen(&out.image, &format!("{kind:?}, NEE {nee}"));
        }
    }
}

/// NEE inside a dielectric from a sun disk wider than the phase lobe (g = 0.9 under
/// `sphere_scene`'s 40° disk: the lobe's π(1 − g)² = 0.03 sr against the disk's 0.38), so
/// every light direction comes from the mixture of the disk and the phase function
/// (light.rs, sample_from; nee.wgsl, nee_light_ray), whose weight carries the boundary's
/// 1/ior² of its own. The other dielectric comparisons have lobes wider than their disks
/// and never take that branch. PT (a shadow ray at every event) and ST-CVAE (EventGen's
/// events and the exact N = 1 walk); the image test as in `cpu_gpu_agree_pt_sphere`.
#[test]
fn cpu_gpu_agree_on_a_dielectric_under_a_disk_wider_than_the_lobe() {
    // 32² rather than 24², and ST-CVAE at 192 spp: at 24² and 96 spp its image had only 20
    // blocks with noise enough to estimate (28 at 32²), next to the 30 the check asks.
    let di = sphere_scene("kind = \"dielectric\"\nior = 1.5")
        .replace("g = 0.5", "g = 0.9")
        .replace("width = 24\nheight = 24", "width = 32\nheight = 32");
    assert!(di.contains("g = 0.9") && di.contains("width = 32"));
    assert!(di.contains("angular_diameter_deg = 40.0"));
    compare_devices(
        "PT dielectric, NEE, g 0.9",
        &di,
        IntegratorKind::Pt,
        true,
        96,
    );
    compare_devices(
        "ST-CVAE dielectric, NEE, g 0.9",
        &di,
        IntegratorKind::Stcvae,
        true,
        192,
    );
}

/// The shipped model read in learned single-scattering mode (n_min 1: N = 1 comes from
/// LengthGen, no exact branch; model_file::SingleScattering::Learned), as a model trained
/// that way would be: the kernels must take their N = 1 walks as the CPU's sampler does
/// (`model.flags.x`; sampler.rs, sample_walk), which the other comparisons, all in exact
/// mode, never see. The image test as in `cpu_gpu_agree_pt_sphere`.
#[test]
fn cpu_gpu_agree_with_a_learned_single_scattering_model() {
    static LEARNED: OnceLock<cvae::ModelSet> = OnceLock::new();
    let learned = LEARNED.get_or_init(|| {
        let mut m = model().clone();
        m.single_scattering = cvae::model_file::SingleScattering::Learned;
        m
    });
    assert_eq!(learned.n_min(), 1);
    let set = IntegratorSettings {
        model: Some(learned),
        ..settings(IntegratorKind::Stcvae, true)
    };
    let im = sphere_scene("kind = \"index-matched\"");
    compare_devices_with("ST-CVAE, learned N = 1, NEE", &im, &set, 96);
}

/// Settings and scenes the other comparisons leave out (a review listed them): a delta
/// light beside a disk that is dark in one channel, g = 0.9, albedo 1 with lights (Λ(N) =
/// N), three EventGen draws a step (one unpaired), four events an exact step, two path
/// reservoirs and a max_tau below the model's; then a dielectric of ior 1.33 under an
/// environment map with two delta lights, g = −0.4, one EventGen draw a step, three events
/// an exact step and a shadow ray at every event; then g = 0.999 under a 30° disk (NEE's
/// mixture of disk and phase directions, and a lobe ~1e-3 rad wide, in which the kernels'
/// f32 textbook HG lost 3.5 % of its integral), PT and ST-CVAE with exact steps; and
/// g = −0.99 with every step from the models, NEE off. The first
/// case's 20° disk under g = 0.9 takes the mixture too.
#[test]
fn cpu_gpu_agree_in_less_common_settings() {
    let lights = "[[light]]\nkind = \"directional\"\ndirection = [-0.5, -0.6, -0.62]\n\
                  irradiance = [2.0, 2.0, 2.0]\n";
    let base = sphere_scene("kind = \"index-matched\"");
    let disk = SPHERE_SCENE_DISK;
    assert!(base.contains(disk));
    // 32² rather than 24²: at 24² only 31 of the 4×4 blocks had noise enough to estimate
    // (heavy-tailed paths at albedo 1 and g 0.9), next to the 30 the check asks.
    let many = with_medium(base.clone(), "[20.0, 30.0, 50.0]", "[1.0, 0.95, 0.9]")
        .replace("g = 0.5", "g = 0.9")
        .replace("width = 24\nheight = 24", "width = 32\nheight = 32")
        .replace(
            disk,
            &format!(
                "{lights}[[light]]\nkind = \"directional\"\ndirection = [0.7, 0.2, -0.3]\n\
                 irradiance = [1.0, 0.0, 0.5]\nangular_diameter_deg = 20.0\n"
            ),
        );
    let set = IntegratorSettings {
        nee_samples: 3,
        exact_nee_samples: 4,
        path_nee_rays: 2,
        exact_tau: 5.0,
        max_tau: 30.0,
        ..settings(IntegratorKind::Stcvae, true)
    };
    compare_devices_with(
        "ST-CVAE, delta + dark disk, g 0.9, albedo 1",
        &many,
        &set,
        96,
    );

    let d = tempfile::tempdir().unwrap();
    let path = sky(&d, |x, y| {
        [(x + 1) as f32 / 8.0, if y < 4 { 1.0 } else { 0.2 }, 0.5]
    });
    let dielectric = with_medium(
        sphere_scene("kind = \"dielectric\"\nior = 1.33"),
        "[20.0, 40.0, 80.0]",
        "[0.999, 0.98, 0.9]",
    )
    .replace("g = 0.5", "g = -0.4")
    .replace(
        disk,
        &format!(
            "{lights}[[light]]\nkind = \"directional\"\ndirection = [0.6, -0.3, -0.5]\n\
             irradiance = [1.0, 1.5, 0.5]\n"
        ),
    )
    .replace(
        "radiance = [0.1, 0.1, 0.1]",
        &format!(
            "file = {:?}\nradiance = [0.5, 0.5, 0.5]",
            path.to_str().unwrap()
        ),
    );
    let set = IntegratorSettings {
        nee_samples: 1,
        exact_nee_samples: 3,
        path_nee_rays: 0,
        exact_tau: render_gpu::scene::DEFAULT_EXACT_TAU as f32,
        ..settings(IntegratorKind::Stcvae, true)
    };
    compare_devices_with(
        "ST-CVAE dielectric 1.33, environment map, two delta lights",
        &dielectric,
        &set,
        96,
    );

    // A phase lobe far narrower than a 30° disk: NEE's directions come from the mixture
    // of the disk and the phase function (light.rs, sample_from), and path-level NEE's
    // proxy takes the phase function's largest value over the disk.
    let narrow = base
        .replace("g = 0.5", "g = 0.999")
        .replace("angular_diameter_deg = 40.0", "angular_diameter_deg = 30.0")
        .replace("width = 24\nheight = 24", "width = 32\nheight = 32");
    assert!(narrow.contains("g = 0.999"));
    compare_devices(
        "PT, g 0.999 under a 30° disk",
        &narrow,
        IntegratorKind::Pt,
        true,
        96,
    );
    let set = IntegratorSettings {
        exact_tau: 50.0,
        max_tau: 49.0,
        min_tau: 0.0,
        ..settings(IntegratorKind::Stcvae, true)
    };
    compare_devices_with(
        "ST-CVAE exact steps, g 0.999 under a 30° disk",
        &narrow,
        &set,
        96,
    );
    // g = −0.99, every step from the models (exact_tau 0; the CLI would simulate them all,
    // |g| being above MODEL_MAX_G, but the devices must agree on the models' steps too), so their single-scattering branch, whose exit
    // keeps HG's own sin θ, runs at a lobe ~0.01 rad wide. NEE off: with it, the backward
    // lobe's shadow-ray weights left only 11 blocks with noise estimates of 10 dof here.
    let backward = narrow.replace("g = 0.999", "g = -0.99");
    assert!(backward.contains("g = -0.99"));
    let set = IntegratorSettings {
        exact_tau: 0.0,
        ..settings(IntegratorKind::Stcvae, false)
    };
    compare_devices_with(
        "ST-CVAE model steps, no NEE, g −0.99 under a 30° disk",
        &backward,
        &set,
        96,
    );
}

/// `sphere_scene` under six lights instead of its one disk: delta lights and disks, one dark
/// in G, from every side (three travel toward the camera, lighting mostly the sphere's far
/// side).
fn six_lights_scene(boundary: &str) -> String {
    let lights: String = [
        ([-0.5, -0.6, -0.62], [0.6, 0.6, 0.6], 40.0),
        ([0.7, 0.2, -0.3], [0.5, 0.0, 0.3], 20.0),
        ([0.0, 0.0, -1.0], [0.3, 0.4, 0.5], 0.0),
        ([0.3, -0.9, 0.2], [0.4, 0.4, 0.2], 10.0),
        ([-0.8, 0.3, 0.4], [0.2, 0.3, 0.4], 0.0),
        ([0.1, 0.6, 0.7], [0.5, 0.5, 0.5], 30.0),
    ]
    .iter()
    .map(|(d, e, disk)| {
        format!(
            "[[light]]\nkind = \"directional\"\ndirection = {d:?}\nirradiance = {e:?}\n\
             angular_diameter_deg = {disk:?}\n"
        )
    })
    .collect();
    let disk = SPHERE_SCENE_DISK;
    let text = sphere_scene(boundary);
    assert!(text.contains(disk));
    text.replace(disk, &lights)
}

/// Six lights (`six_lights_scene`): more than the exact steps' proxy weighs
/// (`MAX_PROXY_LIGHTS` = 4; beyond it both devices weigh every walk event alike) and than
/// the GPU kernels took before (4; such scenes were refused on the GPU). PT with NEE
/// through an index-matched boundary, then ST-CVAE through a dielectric with exact steps
/// (four events each) and two path-level reservoirs, so every loop over the lights (NEE,
/// the reservoirs' shadow rays, the refracted rays) runs six times. The check is
/// `assert_same_image`'s, which catches a light left out (seeing five of the six fails it
/// at mean z² 72) but not which proxy chose the walks' NEE events: any positive proxy gives
/// the same expectation, so the flat proxy beyond four lights (stcvae.wgsl, exact_walk) is
/// held to the CPU's by reading, not by this test. `staged_render_equals_one_kernel`
/// renders the scene staged too.
#[test]
fn cpu_gpu_agree_under_six_lights() {
    let im = six_lights_scene("kind = \"index-matched\"");
    assert_eq!(common::build_scene(&im, false).lights.len(), 6);
    if compare_devices_with(
        "PT, NEE, six lights",
        &im,
        &settings(IntegratorKind::Pt, true),
        96,
    )
    .is_none()
    {
        return;
    }
    let set = IntegratorSettings {
        exact_tau: render_gpu::scene::DEFAULT_EXACT_TAU as f32,
        exact_nee_samples: 4,
        path_nee_rays: 2,
        ..settings(IntegratorKind::Stcvae, true)
    };
    compare_devices_with(
        "ST-CVAE dielectric, exact steps, path NEE, six lights",
        &six_lights_scene("kind = \"dielectric\"\nior = 1.33"),
        &set,
        96,
    );
}

#[test]
fn cpu_gpu_agree_bunny() {
    let text = sphere_scene("kind = \"index-matched\"").replace(
        "shape = \"sphere\"\nradius = 0.5",
        "mesh = \"../../assets/bunny.glb\"\nheight = 1.0",
    );
    compare_devices("bunny PT, NEE", &text, IntegratorKind::Pt, true, 96);
    compare_devices(
        "bunny ST-CVAE, NEE",
        &text,
        IntegratorKind::Stcvae,
        true,
        96,
    );
    let exact = IntegratorSettings {
        exact_tau: render_gpu::scene::DEFAULT_EXACT_TAU as f32,
        ..settings(IntegratorKind::Stcvae, true)
    };
    compare_devices_with("bunny ST-CVAE exact steps, NEE", &text, &exact, 96);
    // The rest of the issue's matrix on the bunny: without NEE, and inside a dielectric
    // with and without it.
    let dielectric = text.replace(
        "kind = \"index-matched\"",
        "kind = \"dielectric\"\nior = 1.5",
    );
    assert_ne!(dielectric, text, "the bunny scene names its boundary");
    for (boundary, scene) in [("index-matched", &text), ("dielectric", &dielectric)] {
        for (kind, label) in [
            (IntegratorKind::Pt, "PT"),
            (IntegratorKind::Stcvae, "ST-CVAE"),
        ] {
            for nee in [false, true] {
                if boundary == "index-matched" && nee {
                    continue; // compared above
                }
                let name = format!("bunny {label} {boundary}, NEE {nee}");
                compare_devices(&name, scene, kind, nee, 96);
            }
        }
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

/// The furnace scene's bunny (index-matched), with or without its distance grid: the
/// geometry the probe tests of ray queries and of the grid run on.
fn furnace_bunny(grid: bool) -> render_gpu::setup::SceneData {
    let text = common::furnace_scene(r#"kind = "index-matched""#);
    common::build_scene(&text, grid)
}

/// The WGSL ray queries are watertight like the Rust ones (render_gpu::watertight): no
/// ray from inside the bunny aimed at one of its vertices or edge midpoints misses the
/// surface, the closest hits agree with the CPU's, and so do the one-traversal inside
/// lengths of the shadow rays; the path loop's shared traversal equals both.
#[test]
fn wgsl_rays_are_watertight_and_match_rust() {
    let Some(ctx) = gpu() else { return };
    let ctx = ctx.lock().unwrap_or_else(|e| e.into_inner());
    let scene = furnace_bunny(false);
    let geo = &scene.geo;
    let mut rng = WalkRng::from_seed(23);
    let mut items: Vec<Item> = Vec::new();
    let mut rays = Vec::new();
    while items.len() < 20_000 {
        let p = common::random_interior(geo, &mut rng);
        for _ in 0..50 {
            let i = (rng.uniform() * geo.mesh.triangles.len() as f64) as usize;
            let [a, b, c] = geo.mesh.triangle(i.min(geo.mesh.triangles.len() - 1));
            let target = [a, b, c, (a + b) * 0.5, (b + c) * 0.5, (c + a) * 0.5]
                [(rng.uniform() * 6.0) as usize % 6];
            let d = (target - p).normalize();
            let mut it = [0.0f32; 32];
            it[..3].copy_from_slice(&p.to_array());
            it[4..7].copy_from_slice(&d.to_array());
            items.push(it);
            rays.push((p, d, (target - p).length()));
        }
    }
    let out =
        render_gpu::gpu::probe::run_probe_on(&ctx, "probe_ray", model(), &items, Some(&scene))
            .unwrap();
    let (mut misses, mut t_off, mut len_off, mut paired) = (0, 0, 0, 0);
    let mut touch = 0;
    for ((p, d, aim), o) in rays.iter().zip(&out) {
        // The path loop's shared traversal (scene.wgsl, trace) runs the same arithmetic in
        // the same order as the specialised loops, in both modes: equal to the bit.
        assert!(
            o[4..7] == [o[0], o[1], o[7]] && o[8..11] == [o[2], o[3], o[11]],
            "trace differs from intersect/crossings for the ray from {p} along {d}: {:?}",
            &o[..12]
        );
        let cpu = geo.intersect(*p, *d, f32::INFINITY);
        if o[0] != 1.0 {
            misses += 1;
            continue;
        }
        // Both tests are watertight but round differently (WGSL may fuse multiply-adds):
        // at an edge they may pick different triangles at the same t. And where the ray
        // only touches the surface at the aimed vertex or edge (a silhouette seen from
        // inside), f32 rounding decides whether it counts: NVIDIA's fused shear counted
        // 65 of 20,000 such touches differently from the CPU (H200, 2026-11-26). A touch
        // leaves the ray inside, so the point halfway to the farther hit is inside; had
        // one side slipped through a crossing there, that point would be outside.
        if let Some(h) = cpu
            && (h.t - o[1]).abs() > 1e-4 * h.t.max(1e-2)
        {
            let (near, far) = (h.t.min(o[1]), h.t.max(o[1]));
            let at_aim = (near - aim).abs() <= 1e-4 * aim.max(1e-2);
            if at_aim && geo.inside(*p + *d * (0.5 * (near + far))) {
                touch += 1;
            } else {
                t_off += 1;
            }
        }
        if o[2] == 1.0 && o[3] >= 0.0 {
            paired += 1;
            if let Some((len, _)) = geo.inside_length(*p, *d, |_, _| 1.0)
                && (len - o[3]).abs() > 1e-4 * len.max(1e-2)
            {
                len_off += 1;
            }
        }
    }
    eprintln!(
        "{} rays: {misses} misses, {t_off} closest hits off ({touch} more where one side counts a touch at the aimed point), {paired} paired crossings, {len_off} lengths off",
        rays.len()
    );
    assert_eq!(
        misses,
        0,
        "{misses} of {} WGSL rays slipped through the mesh",
        rays.len()
    );
    // Closest hits and lengths are the same quantities computed in f32 on both sides. Every
    // ray is aimed at a vertex or an edge, where rounding decides between triangles; with
    // fused multiply-adds (hardware drivers) a few may come out otherwise beyond the touches
    // set apart above, so 0.1 % (20 of 20,000) may differ. lavapipe gives 0 of each
    // (2026-11-27); a wrong hit formula or triangle index puts thousands off.
    assert!(
        t_off * 1000 <= rays.len(),
        "{t_off} closest hits differ from the CPU's"
    );
    // Touches at the aimed point: 65 of 20,000 on the H200, 0 on lavapipe. 1 % (3× the
    // worst seen) bounds them, so that a GPU that counts every silhouette touch, or none
    // where the CPU counts them, is not waved through as rounding.
    assert!(
        touch * 100 <= rays.len(),
        "{touch} of {} rays count a touch at the aimed point differently from the CPU",
        rays.len()
    );
    assert!(
        len_off * 1000 <= paired,
        "{len_off} inside lengths differ from the CPU's"
    );
    // Rays exactly through a vertex may hit every triangle around it (the sum then falls
    // back to the ordered walk), but most must pair up or the test checks nothing.
    assert!(
        paired * 2 > rays.len(),
        "only {paired} of {} rays paired up",
        rays.len()
    );
}

/// The WGSL distance grid reads the same cells as the CPU: equal radii, a candidate list
/// exactly where the CPU has one, and from it the same distance as the BVH search. Both
/// sides evaluate the same point–triangle formula in f32 (WGSL may fuse multiply-adds), so
/// they agree to ~1e-5 relative; a wrong triangle remapping (the GPU's triangles are in
/// BVH order) or a wrong offset into the lists gives distances off by whole triangles.
/// Points near the surface (where the lists are used) and anywhere inside.
#[test]
fn wgsl_grid_and_candidate_lists_match_rust() {
    let Some(ctx) = gpu() else { return };
    let ctx = ctx.lock().unwrap_or_else(|e| e.into_inner());
    let scene = furnace_bunny(true);
    let geo = &scene.geo;
    let mut rng = WalkRng::from_seed(29);
    let mut points = Vec::new();
    while points.len() < 4_000 {
        let p = common::random_interior(geo, &mut rng);
        // Pushed toward the surface along a random ray (to its first crossing, scaled).
        let d = common::uniform_direction(&mut rng);
        let near = geo
            .intersect(p, d, f32::INFINITY)
            .map_or(p, |h| p + d * (h.t * (1.0 - 0.1 * rng.uniform() as f32)));
        points.push(p);
        points.push(near);
    }
    let listed = grid_probe_matches(&ctx, &scene, &points);
    assert!(listed > 1_000, "only {listed} points near the surface");
    // Long thin triangles (tests/distance_grid.rs, thin_triangles_never_overestimate_the_
    // distance, checks the CPU's distances there against f64): a 1,000-segment cylinder,
    // points 10⁻⁷ to 10⁻³ inside its surface, where the old f32 formula was 45 eps off.
    let dir = tempfile::tempdir().unwrap();
    let obj = dir.path().join("cylinder.obj");
    std::fs::write(&obj, common::cylinder_obj(1000)).unwrap();
    let text = common::furnace_scene("kind = \"index-matched\"").replace(
        "mesh = \"../../assets/bunny.glb\"",
        &format!("mesh = {:?}", obj.display().to_string()),
    );
    let scene = common::build_scene(&text, true);
    let geo = &scene.geo;
    let mut points = Vec::new();
    for k in 0..geo.tris.len() {
        let t = &geo.tris[k];
        let [a, b, c] = [t.v0, t.v1, t.v2].map(|v| glam::Vec3::from_array(v.into()));
        let on = (a + b + c) / 3.0;
        let depth = [1e-7, 1e-6, 1e-5, 1e-4, 1e-3][k % 5];
        points.push(on - geo.normals[k] * depth);
    }
    let listed = grid_probe_matches(&ctx, &scene, &points);
    assert!(
        listed > 3_000,
        "only {listed} points near the cylinder's surface"
    );
}

/// Runs `probe_grid` at `points` and checks its radius, list distance and search against
/// the CPU's; returns how many points had a candidate list.
fn grid_probe_matches(ctx: &GpuContext, scene: &SceneData, points: &[glam::Vec3]) -> usize {
    let (geo, grid) = (&scene.geo, scene.grid.as_ref().unwrap());
    let items: Vec<Item> = points
        .iter()
        .map(|p| {
            let mut it = [0.0f32; 32];
            it[..3].copy_from_slice(&p.to_array());
            it
        })
        .collect();
    let out = render_gpu::gpu::probe::run_probe_on(ctx, "probe_grid", model(), &items, Some(scene))
        .unwrap();
    let mut listed = 0;
    for (p, o) in points.iter().zip(&out) {
        let close = |a: f32, b: f32| (a - b).abs() <= 1e-5 * a.abs().max(1e-2);
        assert!(
            close(grid.radius(*p), o[0]),
            "radius at {p}: {} vs {}",
            grid.radius(*p),
            o[0]
        );
        match grid.exact_distance(geo, *p) {
            Some(d) => {
                listed += 1;
                assert!(close(d, o[1]), "listed distance at {p}: {d} vs {}", o[1]);
                assert!(close(d, o[2]), "search at {p}: {d} vs {}", o[2]);
            }
            None => assert_eq!(o[1], -1.0, "a WGSL list where the CPU has none, at {p}"),
        }
    }
    listed
}

/// The WGSL cell-list hit (scene.wgsl, `grid_local_hit`: ST-CVAE's flights near the
/// surface and its sliver checks) is the BVH's hit: the same watertight test over a
/// superset of the triangles the segment can meet, so the same distance to the bit and the
/// same triangle (`closer`: ties to the lower index) wherever a list answers (DistanceGrid::local_hit's argument; tests/distance_grid.rs
/// checks the CPU's). A list whose coverage were too generous (a triangle missing from it
/// that the segment meets), a wrong offset into the lists or a wrong triangle remapping
/// gives other hits. Segments as the renderer casts them: from points near the surface,
/// up to a near-surface distance long, in random directions. Most must be answered (the
/// point of the lists; 66 % at this seed) and over 1,000 must hit, so that the equality is
/// tested on hits and not only on misses (~10 % of the answered segments cross the
/// surface: 1,310 at this seed).
#[test]
fn wgsl_cell_list_hits_equal_bvh_casts() {
    let Some(ctx) = gpu() else { return };
    let ctx = ctx.lock().unwrap_or_else(|e| e.into_inner());
    let scene = furnace_bunny(true);
    let geo = &scene.geo;
    let near_surface = scene.grid.as_ref().unwrap().near_surface;
    let mut rng = WalkRng::from_seed(37);
    let mut items = Vec::new();
    while items.len() < 20_000 {
        let p = common::random_interior(geo, &mut rng);
        let d = common::uniform_direction(&mut rng);
        let Some(h) = geo.intersect(p, d, f32::INFINITY) else {
            continue;
        };
        // Within a near-surface distance of the surface, on either side.
        let q = p + d * (h.t + (2.0 * rng.uniform() as f32 - 1.0) * near_surface);
        let dir = common::uniform_direction(&mut rng);
        let mut it = [0.0f32; 32];
        it[..3].copy_from_slice(&q.to_array());
        it[4..7].copy_from_slice(&dir.to_array());
        it[8] = rng.uniform() as f32 * near_surface;
        items.push(it);
    }
    let out = render_gpu::gpu::probe::run_probe_on(
        &ctx,
        "probe_local_hit",
        model(),
        &items,
        Some(&scene),
    )
    .unwrap();
    let (mut answered, mut hits) = (0, 0);
    for (it, o) in items.iter().zip(&out) {
        if o[0] == 0.0 {
            continue;
        }
        answered += 1;
        hits += (o[4] == 1.0) as u32;
        // Found, distance and triangle (ties go to the lower index on both sides).
        assert_eq!(
            (o[1], o[1] * o[2], o[1] * o[3]),
            (o[4], o[4] * o[5], o[4] * o[6]),
            "segment from {:?} along {:?}, length {}: list {:?}, BVH {:?}",
            &it[..3],
            &it[4..7],
            it[8],
            &o[1..4],
            &o[4..7]
        );
    }
    let n = items.len();
    assert!(
        answered > n / 2 && hits > 1_000,
        "{answered} of {n} answered by lists, {hits} hits"
    );
    eprintln!("{answered} of {n} answered by lists, {hits} hits");
}

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

/// Eleven slabs stacked up a cube, each overlapping the next by half, lit from above: a
/// shadow ray toward the sun from low in the cube crosses up to 22 faces, beyond the 16
/// crossings the GPU sorts (scene.wgsl, union_keep), so its answers there come from the
/// walk past each crossing (and in_union's every-hit-flips fallback); the CPU's list
/// holds 64. The medium is thinner than the other scenes', so that the deep shadow rays
/// carry weight (with σ_t = 4 to 40 a halved answer beyond 16 crossings went unseen).
/// The OBJ is written into `dir`.
fn slabs_scene(dir: &std::path::Path, boundary: &str) -> String {
    let slabs: Vec<([f32; 3], [f32; 3])> = (0..11)
        .map(|k| {
            let y = -0.5 + k as f32 / 12.0;
            // (0.17 tall, not 2/12: a slab's top corners on the next but one's bottom
            // corners would weld into edges of four faces.)
            ([-0.5, y, -0.5], [0.5, y + 0.17, 0.5])
        })
        .collect();
    let obj = dir.join("slabs.obj");
    std::fs::write(&obj, common::boxes_obj(&slabs)).unwrap();
    common::overlapping_parts_scenes(dir, boundary)[0]
        .2
        .replace(
            &dir.join("cube2.obj").display().to_string(),
            &obj.display().to_string(),
        )
        .replace("sigma_t = [4.0, 12.0, 40.0]", "sigma_t = [1.0, 2.0, 3.0]")
}

/// The GPU's shadow rays where pieces overlap (nee.wgsl, transmittance: the sorted walk of
/// up to 16 crossings, the ordered walk beyond) equal the CPU's (nee.rs: transmittance,
/// whose list holds 64, and transmittance_ordered for the rays the GPU walked in order),
/// and in_union equals Geometry::in_union, for random rays from inside the eleven slabs
/// (dielectric: Fresnel's factor only where the union's medium changes); so do the
/// refracted ones the renders cast (nee.wgsl, shadow; nee.rs, transmittance_refracted),
/// whose ordered walk scales the depth inside by r where it leaves.
#[test]
fn wgsl_shadow_rays_through_overlaps_match_rust() {
    use render_gpu::integrator::nee::{
        transmittance, transmittance_ordered, transmittance_refracted,
    };
    let Some(ctx) = gpu() else { return };
    let ctx = ctx.lock().unwrap_or_else(|e| e.into_inner());
    let dir = tempfile::tempdir().unwrap();
    let scene = common::build_scene(
        &slabs_scene(dir.path(), "kind = \"dielectric\"\nior = 1.5"),
        false,
    );
    let geo = &scene.geo;
    let pieces = geo.pieces.as_ref().expect("the slabs overlap");
    let mut rng = WalkRng::from_seed(31);
    let rays: Vec<(glam::Vec3, glam::Vec3)> = (0..4000)
        .map(|_| {
            let x = common::random_interior(geo, &mut rng);
            (x, common::uniform_direction(&mut rng))
        })
        .collect();
    // Each ray's refracted answer in one channel, the three in turn (probe_shadow).
    let refracted_channel = |k: usize| k % 3;
    let items: Vec<Item> = rays
        .iter()
        .enumerate()
        .map(|(k, (x, d))| {
            let mut it = [0.0f32; 32];
            it[..3].copy_from_slice(&x.to_array());
            it[3] = refracted_channel(k) as f32;
            it[4..7].copy_from_slice(&d.to_array());
            it
        })
        .collect();
    let out =
        render_gpu::gpu::probe::run_probe_on(&ctx, "probe_shadow", model(), &items, Some(&scene))
            .unwrap();
    let (mut off, mut refracted_off, mut more, mut inside_off) = (0, 0, 0, 0);
    // The two devices round differently (WGSL may fuse multiply-adds); the bound is
    // shadow_rays.rs's for the sorted against the ordered walk, which differ by eps/cos per
    // crossing. Written so that a NaN counts as off.
    let differ = |gpu: f32, cpu: f32| !((gpu - cpu).abs() <= 2e-3 * cpu.max(1e-3) + 1e-6);
    for (k, ((x, d), o)) in rays.iter().zip(&out).enumerate() {
        let walked = o[4] == 1.0;
        more += walked as usize;
        for (c, &gpu) in o[..3].iter().enumerate() {
            let cpu = if walked {
                transmittance_ordered(&scene, *x, *d, c)
            } else {
                transmittance(&scene, *x, *d, c)
            };
            off += differ(gpu, cpu) as usize;
        }
        let c = refracted_channel(k);
        let refracted = transmittance_refracted(&scene, *x, *d, c, walked);
        refracted_off += differ(o[5], refracted) as usize;
        inside_off += ((o[3] == 1.0) != geo.in_union(pieces, *x, *d)) as usize;
    }
    // Grazing crossings may differ by more (rare for uniform directions): allow 0.1 %.
    assert!(
        off * 1000 <= 3 * rays.len(),
        "{off} of {} shadow-ray answers differ from the CPU's ({more} rays walked in order)",
        3 * rays.len()
    );
    // The refracted ones (the shadow rays the renders cast): the depth inside and the
    // beam's factor r where the ray leaves, in both walks.
    assert!(
        refracted_off * 1000 <= rays.len(),
        "{refracted_off} of {} refracted shadow-ray answers differ from the CPU's",
        rays.len()
    );
    assert!(
        inside_off * 1000 <= rays.len(),
        "in_union differs for {inside_off} of {} origins",
        rays.len()
    );
    // The rays beyond the sorted list must be tested: those from low in the slabs
    // toward the top (254 of the 4,000; at least 100 asked).
    assert!(more >= 100, "only {more} rays crossed more than 16 faces");
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

/// The kernels' path-NEE proxy (nee.wgsl, nee_proxy) equals the CPU's (nee::proxy, with
/// the step's free-ball chord as sphere_step.rs gives it) on random events of a dense
/// sphere: under a disk wider than the phase lobe (the largest phase value over the disk,
/// `extreme_cos`, for g of either sign), a narrower one and a delta light, index-matched
/// and dielectric (`phase_bound`'s refraction turn), and with the depth past
/// nee::PROXY_DEPTH_CAP for many, where exp of the plain depth is 0 in f32 and the event
/// would never be offered. No image test sees the cap: with it removed from the kernel a
/// σ_t 200–600 sphere under an 80° disk rendered within noise of the CPU (signed sum
/// −0.26), the events it saves carrying little light there.
///
/// Tolerance: the proxy is a product of f32 factors: exp of a depth of up to 40 (the cap),
/// rounded to a few ulps (40 × 4e-7 relative), HG densities (1e-5 relative,
/// `wgsl_hg_and_frame_match_rust`), and in `extreme_cos` and `phase_bound` an acos whose
/// f32 error near cos = 1 is ~3e-4 rad, which moves HG's density by ≤ 2 × 10⁻³ relative
/// at these g: 2e-3 relative, with a 1e-30 floor for f32's smallest values.
#[test]
fn wgsl_path_nee_proxy_matches_rust() {
    use render_gpu::integrator::nee::{PROXY_DEPTH_CAP, proxy};
    use render_gpu::integrator::sphere_step::BALL_CHORD_SHRINK;
    let Some(ctx) = gpu() else { return };
    let ctx = ctx.lock().unwrap_or_else(|e| e.into_inner());
    let delta = "[[light]]\nkind = \"directional\"\ndirection = [0.3, -0.8, 0.5]\n\
                 irradiance = [1.0, 2.0, 0.5]\n";
    let disk = |deg: f64, dir: &str| {
        format!(
            "[[light]]\nkind = \"directional\"\ndirection = {dir}\n\
             irradiance = [2.0, 1.0, 3.0]\nangular_diameter_deg = {deg}\n"
        )
    };
    let dense = |boundary: &str, g: &str, lights: String| {
        let text = with_medium(
            sphere_scene(boundary),
            "[60.0, 200.0, 600.0]",
            "[0.99, 0.95, 0.9]",
        )
        .replace("g = 0.5", &format!("g = {g}"))
        .replace(SPHERE_SCENE_DISK, &lights);
        assert!(text.contains(&lights) && text.contains(&format!("g = {g}")));
        text
    };
    // g 0.5: the 80° disk (1.47 sr against the lobe's π(1 − g)² = 0.79) takes the largest
    // value; g −0.6 (lobe 0.50 sr): the 80° disk does, the 40° one (0.38 sr) does not.
    let scenes = [
        dense(
            "kind = \"index-matched\"",
            "0.5",
            format!("{}{delta}", disk(80.0, "[-0.5, -0.6, -0.62]")),
        ),
        dense(
            "kind = \"dielectric\"\nior = 1.33",
            "-0.6",
            format!(
                "{}{}{delta}",
                disk(80.0, "[0.0, -1.0, 0.0]"),
                disk(40.0, "[0.6, 0.2, -0.77]")
            ),
        ),
    ];
    let mut rng = WalkRng::from_seed(47);
    for (n, text) in scenes.iter().enumerate() {
        let scene = common::build_scene(text, false);
        // (x, w, the free ball's centre c and radius f, the grid's ball at x, channel).
        let events: Vec<(glam::Vec3, glam::Vec3, glam::Vec3, f32, f32, usize)> = (0..3000)
            .map(|k| {
                // A free ball inside the sphere, the event inside it.
                let c = common::uniform_direction(&mut rng) * 0.45 * rng.uniform() as f32;
                let f = (0.5 - c.length()) * rng.uniform() as f32;
                let x = c + common::uniform_direction(&mut rng) * f * rng.uniform() as f32;
                let grid_free = 0.02 * rng.uniform() as f32;
                (
                    x,
                    common::uniform_direction(&mut rng),
                    c,
                    f,
                    grid_free,
                    k % 3,
                )
            })
            .collect();
        let items: Vec<Item> = events
            .iter()
            .map(|&(x, w, c, f, grid_free, channel)| {
                let mut it = [0.0f32; 32];
                it[..3].copy_from_slice(&x.to_array());
                it[3] = channel as f32;
                it[4..7].copy_from_slice(&w.to_array());
                it[7] = grid_free;
                it[8..11].copy_from_slice(&c.to_array());
                it[11] = f;
                it
            })
            .collect();
        let out = render_gpu::gpu::probe::run_probe_on(
            &ctx,
            "probe_proxy",
            model(),
            &items,
            Some(&scene),
        )
        .unwrap();
        let (mut worst, mut capped) = (0.0f32, 0);
        for (&(x, w, c, f, grid_free, channel), o) in events.iter().zip(&out) {
            // The chord from x along ω_l to the free ball's edge (sphere_step.rs, complete),
            // written out: d = x − c, chord = −d·ω + √((d·ω)² + f² − |d|²).
            let free = |wl: glam::Vec3| {
                let d = x - c;
                let b = d.dot(wl);
                let chord = -b + (b * b + (f * f - d.dot(d)).max(0.0)).sqrt();
                (chord * BALL_CHORD_SHRINK).min(2.0 * f).max(grid_free)
            };
            let sigma = scene.sigma_t[channel];
            capped += scene
                .lights
                .iter()
                .any(|l| sigma * free(l.to_light) > PROXY_DEPTH_CAP) as usize;
            let cpu = proxy(&scene, w, free, channel);
            let relative = (o[0] - cpu).abs() / cpu.max(1e-30);
            // Written so that a NaN fails.
            assert!(
                relative <= 2e-3,
                "scene {n}: proxy {} on the GPU, {cpu} on the CPU at x {x}, w {w}, c {c}, \
                 f {f}, channel {channel}",
                o[0]
            );
            worst = worst.max(relative);
        }
        eprintln!("scene {n}: largest relative difference {worst:.1e}, {capped} events capped");
        // Events past the cap must be tested (891 and 945 of the 3,000; 500 asked).
        assert!(
            capped >= 500,
            "scene {n}: only {capped} events past the cap"
        );
    }
}

/// An image whose path slots exceed the adapter's storage binding limit renders in bands of
/// rows (gpu/bands.rs), and the bands give the image one binding gives, bit for bit: PT
/// resumes a path exactly, and the seeds follow a pixel's index in the image, not in its
/// band. The limit is lowered so that the same 256² image takes one band, then three of 80
/// rows and one of 16, with one lane a pixel both times (a lane count that differed would
/// draw other samples), over several chunks of samples. (A band must stay above the
/// sphere's 1.3 MB of triangles, which the lowered limit binds too.)
#[test]
fn images_beyond_the_binding_limit_render_in_bands() {
    let Some(ctx) = gpu() else { return };
    let mut ctx = ctx.lock().unwrap_or_else(|e| e.into_inner());
    let text = sphere_scene("kind = \"index-matched\"")
        .replace("width = 24\nheight = 24", "width = 256\nheight = 256");
    let s = common::build_scene(&text, false);
    let set = settings(IntegratorKind::Pt, true);
    // PT carries no path-level NEE reservoirs.
    let slot = 16 * render_gpu::gpu::kernels::slot_vec4s(0, false);
    let mut run = |slots: u64| {
        let mut ctx = Limits::new(&mut ctx);
        ctx.limits.max_storage_buffer_binding_size = slots * slot;
        ctx.limits.max_buffer_size = slots * slot;
        render_gpu(
            &ctx,
            &s,
            &set,
            &opts(6, 3),
            &|_, _| {},
            &AtomicBool::new(false),
        )
        .unwrap()
    };
    let whole = run(256 * 256);
    let banded = run(256 * 80);
    // 80 rows a band: 256 rows take 4 bands (three of 80, one of 16).
    assert_eq!((whole.dispatch.bands, banded.dispatch.bands), (1, 4));
    assert_eq!(whole.stats.paths, 256 * 256 * 6);
    assert_eq!(banded.stats.paths, whole.stats.paths);
    assert_eq!(banded.stats.events, whole.stats.events);
    let differ = differing_pixels(&whole, &banded);
    assert_eq!(
        differ, 0,
        "{differ} of 65536 pixels differ between bands and one binding"
    );
    assert!(whole.image.pixels.iter().any(|p| p[0] > 0.0));
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

/// A stop request mid-chunk drops the chunk, as the CPU drops an unfinished pass: the
/// image holds the whole chunks before it, bit for bit a render of that many spp, and so
/// do the counters. The 64² image renders in three bands of at most 1,536 slots (the test
/// hook `STCVAE_GPU_TEST_BAND_SLOTS` lowers the cap that keeps a dispatch short, 65,536
/// slots on a software adapter: gpu/bands.rs; a 256 × 544 image took 109 s here on
/// lavapipe), with one lane a pixel (as on any adapter where a band holds fewer slots than
/// the image has pixels), so with one sample a slot a chunk is one spp. The stop comes
/// from the progress report after the second chunk's first band, so in that chunk one
/// band has finished (its slots give back the accumulators committed at the chunk's
/// start), one has begun (a stop is looked at after each submission: four bounces a
/// dispatch here, fewer than many paths take) and one has not (its accumulators already
/// hold the first chunk alone); it leaves 1 of 4 spp. A stop before the first chunk ends
/// leaves no image (0 spp). Covered: ST-CVAE with a path-level NEE reservoir (the
/// committed vec4 comes after the reservoirs), PT (in a thinner medium, for speed on
/// lavapipe), and the staged ST-CVAE render, whose first turn commits, with a snapshot and
/// sent ahead (one bounce a visit keeps no snapshot; the stop then also waits for the
/// submission sent ahead). A hardware adapter keeps no snapshot and may finish a band in
/// fewer submissions, so the stopped spp are asserted on a software adapter (CI's
/// lavapipe); elsewhere the test checks that a render stopped is whole. Last, with
/// `--variance` at 6 samples a slot and chunk, the variance image of a render stopped in
/// its second chunk equals that of the first chunk's whole render (below).
#[test]
fn a_stop_mid_chunk_keeps_the_whole_chunks() {
    let Some(ctx) = gpu() else { return };
    let ctx = ctx.lock().unwrap_or_else(|e| e.into_inner());
    let text = sphere_scene("kind = \"index-matched\"")
        .replace("width = 24\nheight = 24", "width = 64\nheight = 64");
    // Bands of 24, 24 and 16 rows of 64 slots.
    let (band_slots, bands) = (("STCVAE_GPU_TEST_BAND_SLOTS", "1536"), 3);
    // The hook lowers the lanes too, as a large image's pixels would: a 32² image's 1,024
    // pixels would take 4 lanes at 4 spp (of 4,096 target threads, 2²⁰ on hardware), 8
    // bands of 4 rows under a cap of 512 slots; one lane a pixel makes 2 bands of 16.
    {
        let small = text.replace("width = 64\nheight = 64", "width = 32\nheight = 32");
        let s = common::build_scene(&small, false);
        let hook = [("STCVAE_GPU_TEST_BAND_SLOTS", "512")];
        let set = settings(IntegratorKind::Pt, true);
        let out = render_gpu_with_env(&ctx, &s, &set, &opts(4, 8), &hook).unwrap();
        assert_eq!(out.dispatch.bands, 2, "{:?}", out.dispatch);
    }
    let thin = with_medium(text.clone(), "[1.0, 2.0, 3.0]", "[0.9, 0.9, 0.9]");
    let stcvae = settings(IntegratorKind::Stcvae, true);
    let staged = ("STCVAE_GPU_STAGED", "1");
    type Vars<'a> = &'a [(&'a str, &'a str)];
    let cases: [(&String, IntegratorSettings, Vars); 4] = [
        (&text, stcvae, &[]),
        (&thin, settings(IntegratorKind::Pt, true), &[]),
        (&text, stcvae, &[staged]),
        (&text, stcvae, &[staged, ("STCVAE_GPU_BOUNCES", "1")]),
    ];
    for (text, set, extra) in cases {
        let s = common::build_scene(text, true);
        let mut vars = vec![
            ("STCVAE_GPU_LANE_SAMPLES", "1"),
            ("STCVAE_GPU_BOUNCES", "4"),
            band_slots,
        ];
        vars.extend_from_slice(extra);
        let env = EnvVars::set(&vars);
        let stopped_after =
            |reports: usize, spp: u32| stopped_at(&ctx, &s, &set, &opts(spp, 8), reports);
        // A report a band: the one after the first chunk's is the second chunk's first.
        let stopped = stopped_after(bands + 1, 4);
        let none = stopped_after(1, 4);
        let whole = stopped_after(0, stopped.spp.max(1));
        drop(env);
        let what = format!("{:?} {extra:?}", set.kind);
        assert_eq!(stopped.dispatch.bands as usize, bands, "{what}");
        assert_eq!(stopped.dispatch.staged, !extra.is_empty(), "{what}");
        if ctx.adapter.software {
            assert_eq!((stopped.spp, none.spp), (1, 0), "{what}");
            assert_eq!(stopped.dispatch.ahead, extra.len() == 2, "{what}");
        }
        assert_eq!(whole.spp, stopped.spp.max(1));
        if stopped.spp == 0 {
            continue;
        }
        assert_same_render(&whole, &stopped, &format!("{what}, the whole chunks"));
        assert!(whole.image.pixels.iter().any(|p| p[0] > 0.0));
    }

    // The variance's squares as the chunk began (kernels::committed_sq_vec4): ST-CVAE at 6
    // samples a slot and chunk, stopped in its second chunk, against a whole render of the
    // first. The committed sums are rounded once to f32 (6e-8 of Σl² = n·m² + (n − 1)·s²),
    // which moves a pixel's variance (s²/n) by at most ~1.2e-7·(m² + n·v)/(n − 1) with n·v
    // = s²: allowed 1e-6·(m² + spp·v), a wide margin. A wrong slot index or a missing write
    // (the chunk's own squares, or the poison) misses that by orders of magnitude.
    let s = common::build_scene(&text, true);
    let vars = [
        ("STCVAE_GPU_LANE_SAMPLES", "6"),
        ("STCVAE_GPU_BOUNCES", "4"),
        band_slots,
    ];
    let env = EnvVars::set(&vars);
    let render = |reports: usize, spp: u32| {
        let o = RenderOptions {
            variance: true,
            ..opts(spp, 8)
        };
        stopped_at(&ctx, &s, &stcvae, &o, reports)
    };
    let stopped = render(bands + 1, 12);
    let whole = render(0, stopped.spp.max(1));
    drop(env);
    if ctx.adapter.software {
        assert_eq!(stopped.spp, 6);
    }
    if stopped.spp >= 6 {
        // The committed RGB is rounded once too (where one sample a slot and chunk above
        // leaves nothing to round): the image agrees to f32 rounding, not bit for bit.
        assert_eq!(stopped.stats, whole.stats);
        let largest = largest_relative_difference(&whole, &stopped);
        assert!(
            largest < 1e-6,
            "variance: the images differ by {largest:.2e}"
        );
        let (a, b) = (whole.variance.unwrap(), stopped.variance.unwrap());
        let spp = whole.spp as f32;
        for (i, ((va, vb), m)) in a
            .pixels
            .iter()
            .zip(&b.pixels)
            .zip(&whole.image.pixels)
            .enumerate()
        {
            for c in 0..3 {
                let allowed = 1e-6 * (m[c] * m[c] + spp * va[c]);
                assert!(
                    (va[c] - vb[c]).abs() <= allowed,
                    "pixel {i} channel {c}: variance {} whole, {} stopped",
                    va[c],
                    vb[c]
                );
            }
        }
    }
}

/// A GPU render that asks to stop at its `reports`-th progress report (0: never); the
/// renderer reports after each band of each chunk.
fn stopped_at(
    ctx: &GpuContext,
    s: &SceneData,
    set: &IntegratorSettings,
    o: &RenderOptions,
    reports: usize,
) -> RenderOutput {
    let cancel = AtomicBool::new(false);
    let seen = std::sync::atomic::AtomicUsize::new(0);
    let progress = |_: u64, _: u64| {
        if seen.fetch_add(1, Ordering::Relaxed) + 1 == reports {
            cancel.store(true, Ordering::Relaxed);
        }
    };
    render_gpu(ctx, s, set, o, &progress, &cancel).unwrap()
}

/// A stop requested before the first submission (in the CLI: while the kernels compile,
/// up to minutes for a large model on lavapipe) submits nothing and gives no image
/// (0 spp), as the CPU path does; it used to render the whole image.
#[test]
fn a_stop_before_the_first_submission_renders_nothing() {
    let Some(ctx) = gpu() else { return };
    let ctx = ctx.lock().unwrap_or_else(|e| e.into_inner());
    let s = common::build_scene(&sphere_scene("kind = \"index-matched\""), true);
    for kind in [IntegratorKind::Pt, IntegratorKind::Stcvae] {
        let cancel = AtomicBool::new(true);
        let out = render_gpu(
            &ctx,
            &s,
            &settings(kind, true),
            &opts(4, 8),
            &|_, _| {},
            &cancel,
        )
        .unwrap();
        assert_eq!((out.spp, out.dispatch.dispatches), (0, 0), "{kind:?}");
    }
}

/// A PT render (whose path slots, without the variance's squares, are
/// `slot_vec4s(0, false)` vec4s) with the environment `vars`, in bands of `rows` rows of
/// one lane a pixel on any adapter: the adapter's largest buffer is lowered to that many
/// slots (renderer.rs, plan_slots: a band's slots fit the smaller of the storage binding
/// and the largest buffer), its storage binding left as it is, so that the scene's
/// triangles, bound too, still fit it (`images_beyond_the_binding_limit_render_in_bands`
/// lowers both limits to one value, on a 256² image). A stop is asked at the `stop_at`-th
/// progress report (0: never). Returns the render and its progress reports (done, total),
/// the limit and the variables restored first. The bands are checked: a band sized by the
/// binding alone, or by the larger of the two limits, holds the whole image, and no test
/// before lowered one limit without the other.
fn render_in_bands(
    ctx: &mut GpuContext,
    rows: u64,
    s: &SceneData,
    set: &IntegratorSettings,
    o: &RenderOptions,
    vars: &[(&str, &str)],
    stop_at: usize,
) -> (RenderOutput, Vec<(u64, u64)>) {
    assert!(
        set.kind == IntegratorKind::Pt && !o.variance,
        "PT's plain slots"
    );
    let (width, height) = (s.camera.width as u64, s.camera.height as u64);
    assert!(rows < height, "fewer slots than pixels: one lane a pixel");
    let slot = 16 * render_gpu::gpu::kernels::slot_vec4s(0, false);
    let reports = Mutex::new(Vec::new());
    let cancel = AtomicBool::new(false);
    let progress = |done: u64, total: u64| {
        let mut r = reports.lock().unwrap();
        r.push((done, total));
        if r.len() == stop_at {
            cancel.store(true, Ordering::Relaxed);
        }
    };
    let out = {
        let mut ctx = Limits::new(ctx);
        ctx.limits.max_buffer_size = rows * width * slot;
        let _env = EnvVars::set(vars);
        render_gpu(&ctx, s, set, o, &progress, &cancel).unwrap()
    };
    assert_eq!(
        out.dispatch.bands as u64,
        height.div_ceil(rows),
        "bands of {rows} rows: {:?}",
        out.dispatch
    );
    (out, reports.into_inner().unwrap())
}

/// The white furnace with its camera turned away from the bunny (as in
/// `long_slot_sums_do_not_drift`): every camera ray meets the sky of 0.7 at its first
/// bounce, so every slot finishes a chunk of one sample in one dispatch.
fn furnace_looking_away() -> String {
    let text = common::furnace_scene("kind = \"index-matched\"")
        .replace("target = [0.0, 0.0, 0.0]", "target = [0.0, 0.0, 10.0]");
    assert!(text.contains("target = [0.0, 0.0, 10.0]"));
    text
}

/// Every pixel of a render in bands is resolved with its own hero channels: a channel's
/// mean divides its sum by that channel's samples, which follow the pixel's index in the
/// image (`render::resolve_pixel`, `channel_offset`), not its index within its band
/// (readout.rs, SlotReadout::read). The white furnace (every sample 0.7 in its channel)
/// at 4 spp, whose channels have 2, 1 and 1 samples in the order the pixel's offset sets,
/// in 3 bands of 4 rows: every pixel is 0.7 to f32 rounding (1e-4, as in
/// `white_furnace_gpu`). A pixel resolved with another pixel's offset reads 1.4 or 0.35 in
/// two channels, as about 2 in 3 of the 96 pixels past the first band would. The banded
/// renders before could not see it: `images_beyond_the_binding_limit_render_in_bands`
/// renders 6 spp, where every channel has 2 samples whatever the offset, and
/// `a_stop_mid_chunk_keeps_the_whole_chunks` compares two banded renders (1 and 6 spp),
/// which would share the mistake.
#[test]
fn banded_pixels_resolve_with_their_own_hero_channels() {
    let Some(ctx) = gpu() else { return };
    let mut ctx = ctx.lock().unwrap_or_else(|e| e.into_inner());
    let s = common::build_scene(&common::furnace_scene("kind = \"index-matched\""), false);
    let set = settings(IntegratorKind::Pt, true);
    let (out, _) = render_in_bands(&mut ctx, 4, &s, &set, &opts(4, 3), &[], 0);
    assert_eq!((out.spp, out.stats.paths), (4, 12 * 12 * 4));
    for (i, p) in out.image.pixels.iter().enumerate() {
        for (c, v) in p.iter().enumerate() {
            assert!(
                (v - 0.7).abs() < 1e-4,
                "pixel {i} (band {}) channel {c} = {v}",
                i / 48
            );
        }
    }
}

/// The progress reported after each band of each chunk counts the pixel-samples done: the
/// chunks before in full, and this chunk's samples for every row up to the end of this
/// band (renderer.rs, render_chunks), not for this band's own rows alone. The furnace
/// looking away from its bunny, 12² pixels at 4 spp, 2 samples a slot and chunk, in 3
/// bands of 4 rows: after the first chunk's bands 96, 192 and 288 of 576, after the
/// second's 384, 480 and 576, each with the total 576, exactly (the chunks are fixed by
/// STCVAE_GPU_LANE_SAMPLES, the bands and one lane a pixel by the lowered limit, on any
/// adapter). A band's own rows would give 96, 96, 96, 384, 384, 384: a progress bar that
/// falls back between bands and never reaches its end. The stop tests count the reports
/// and nothing else reads them.
#[test]
fn progress_counts_every_row_up_to_the_band_done() {
    let Some(ctx) = gpu() else { return };
    let mut ctx = ctx.lock().unwrap_or_else(|e| e.into_inner());
    let s = common::build_scene(&furnace_looking_away(), false);
    let set = settings(IntegratorKind::Pt, true);
    let vars = [("STCVAE_GPU_LANE_SAMPLES", "2")];
    let (out, reports) = render_in_bands(&mut ctx, 4, &s, &set, &opts(4, 1), &vars, 0);
    assert_eq!(out.spp, 4);
    let want: Vec<(u64, u64)> = [96, 192, 288, 384, 480, 576]
        .into_iter()
        .map(|done| (done, 576))
        .collect();
    assert_eq!(reports, want);
}

/// A stop asked while a chunk's last band renders, which that band's one submission
/// finishes, keeps the chunk: every band has then finished it, and only a stop seen
/// after a band that has one after it (not yet begun) drops the chunk (renderer.rs,
/// render_chunks). The stop is asked here at the report after the band before, which
/// comes after that band's own look at the stop request; a band that finishes in one
/// submission looks at none, so it is first seen after the last band, as one asked while
/// that band renders would be, whatever the timing. The furnace looking away from its
/// bunny (every slot done in one dispatch) in 3 bands of 4 rows, stopped at the report
/// after the first chunk's second band: the third band renders and reports, and the render
/// keeps that chunk's 1 spp (one lane a pixel, one sample a slot in the first chunk) and
/// its 144 paths. Dropping it, as a check that took the last band for one with a band
/// after it would, leaves 0 spp (a black image) and two reports. (In
/// `a_stop_mid_chunk_keeps_the_whole_chunks` the stop comes before the last band, whose
/// chunk is dropped either way.)
#[test]
fn a_stop_during_the_last_band_keeps_its_finished_chunk() {
    let Some(ctx) = gpu() else { return };
    let mut ctx = ctx.lock().unwrap_or_else(|e| e.into_inner());
    let s = common::build_scene(&furnace_looking_away(), false);
    let set = settings(IntegratorKind::Pt, true);
    let vars = [("STCVAE_GPU_LANE_SAMPLES", "1")];
    let (out, reports) = render_in_bands(&mut ctx, 4, &s, &set, &opts(4, 1), &vars, 2);
    assert_eq!(out.stats.events, 0, "no camera ray may reach the object");
    assert_eq!(
        (out.spp, out.stats.paths, reports.len()),
        (1, 144, 3),
        "{:?}",
        out.dispatch
    );
}

/// The work map of a render stopped mid-chunk (`RenderOutput::work`: PT events + sphere
/// steps a path) divides each slot's events, which count every visit, the dropped
/// chunk's too, by the paths that made them: the samples the slot finished (ACC's count),
/// not the whole chunks' (COMMITTED's count, which the image of a band that had begun the
/// dropped chunk reads; readout.rs, SlotReadout::pixel_slots). The sphere (PT) in 3 bands
/// of 11, 11 and 2 rows, 2 samples a slot and chunk, asked to stop at the report after
/// the second chunk's first band: that band had finished the chunk, so its slots hold 4
/// finished samples and their events, exactly those of a whole 4-spp render's first band
/// (the samples and their paths follow the pixel and the sample index, and the event
/// counts are whole numbers in f32), and its work map must equal that render's there, bit
/// for bit. Divided by the 2 committed samples it doubles wherever the sphere is. The
/// stop tests compare images and counters, never the work map, and the work-map test
/// stops nothing.
#[test]
fn a_stopped_renders_work_map_divides_by_the_samples_finished() {
    let Some(ctx) = gpu() else { return };
    let mut ctx = ctx.lock().unwrap_or_else(|e| e.into_inner());
    let s = common::build_scene(&sphere_scene("kind = \"index-matched\""), false);
    let set = settings(IntegratorKind::Pt, true);
    let vars = [("STCVAE_GPU_LANE_SAMPLES", "2")];
    // Reports 1–3: the first chunk's bands; 4: the second chunk's first band.
    let (stopped, _) = render_in_bands(&mut ctx, 11, &s, &set, &opts(4, 8), &vars, 4);
    let (whole, _) = render_in_bands(&mut ctx, 11, &s, &set, &opts(4, 8), &vars, 0);
    assert_eq!((stopped.spp, whole.spp), (2, 4));
    let band = 11 * 24;
    let sum = |o: &RenderOutput| o.work[..band].iter().map(|&w| w as f64).sum::<f64>();
    assert!(sum(&whole) > 0.0, "the first band sees the sphere");
    assert!(
        stopped.work[..band] == whole.work[..band],
        "the first band's work map sums to {} stopped, {} whole",
        sum(&stopped),
        sum(&whole)
    );
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

/// The kernels against an absolute reference: the half-space of
/// `common::half_space_scene` sends back Chandrasekhar's r(μ) = 1 − H(μ)√(1 − w), seen
/// along its normal and at 60° (integrators.rs, `a_half_space_reflects_chandrasekhars_albedo`,
/// argues the scene and the thresholds). Two renders of 64² pixels × 32 spp here (~260,000
/// paths, standard errors 0.12–0.55 %); |z| < 4.5 per channel, plus the 3 % allowance for
/// the models' steps.
#[test]
fn gpu_half_space_reflects_chandrasekhars_albedo() {
    let Some(ctx) = gpu() else { return };
    let ctx = ctx.lock().unwrap_or_else(|e| e.into_inner());
    // Every step exact (integrators.rs says why).
    let exact = IntegratorSettings {
        exact_tau: 50.0,
        max_tau: 49.0,
        ..settings(IntegratorKind::Stcvae, true)
    };
    let cases = [
        ("PT", settings(IntegratorKind::Pt, true), 0.0),
        ("ST-CVAE, exact steps", exact, 0.0),
        (
            "ST-CVAE, the models",
            settings(IntegratorKind::Stcvae, true),
            0.03,
        ),
    ];
    common::check_half_space_cases("GPU ", 64, &cases, 12, &|s, set, seed| {
        on_gpu(&ctx, s, set, &opts(32, seed))
    });
}

/// The kernels against the independent walk of `common::SphereWalk` (integrators.rs,
/// `a_sphere_matches_an_independent_walk`, argues the scene and the thresholds: 1.5 % for
/// NEE's refraction at a facet's plane through the dielectric, 3 % for the models' steps); two
/// renders of 64² × 24 spp here (standard errors 0.06–0.62 %; ~50 s on lavapipe).
#[test]
fn gpu_sphere_matches_an_independent_walk() {
    let Some(ctx) = gpu() else { return };
    let ctx = ctx.lock().unwrap_or_else(|e| e.into_inner());
    let exact = IntegratorSettings {
        exact_tau: 50.0,
        ..settings(IntegratorKind::Stcvae, true)
    };
    let matched = [
        ("PT", settings(IntegratorKind::Pt, true), 0.0),
        ("ST-CVAE, exact steps", exact, 0.0),
        (
            "ST-CVAE, the models",
            settings(IntegratorKind::Stcvae, true),
            0.03,
        ),
    ];
    let dielectric = [
        ("PT without NEE", settings(IntegratorKind::Pt, false), 0.0),
        (
            "ST-CVAE without NEE, exact steps",
            IntegratorSettings {
                nee: false,
                ..exact
            },
            0.0,
        ),
        ("PT", settings(IntegratorKind::Pt, true), 0.015),
    ];
    common::check_sphere_walk_cases("GPU ", &matched, &dielectric, 14, &|s, set, seed| {
        on_gpu(&ctx, s, set, &opts(24, seed))
    });
}
