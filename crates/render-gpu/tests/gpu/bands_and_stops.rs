//! Images beyond the binding limit rendered in bands of rows, and renders stopped part
//! way: which chunks they keep, what progress says, how the work map is divided.

use super::*;

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
