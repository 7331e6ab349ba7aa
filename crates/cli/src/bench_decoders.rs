//! `stcvae bench decoders`: the three decoders' draws per second on the CPU (one thread and
//! all) and on a GPU adapter, side by side, and whether the adapter skips the branches of an
//! `if` that no SIMD lane takes.
//!
//! The decoders are the render kernels' most favourable code for a software adapter:
//! straight-line arithmetic with the weights as constants, no memory access and no lane
//! divergence. Their ratio to the CPU bounds what the whole kernel could reach there,
//! whose traversals and grid queries load memory lane by lane (docs/BENCHMARKS.md,
//! sixty-first session). The branch row tells why Mesa 22's lavapipe (Debian 12, CI) runs
//! the kernels at less than half the speed of Mesa 25's.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Result, bail};
use cvae::decoder::{Decoder, Draw, MAX_OUT, Output};
use rayon::prelude::*;
use render_gpu::gpu::probe::{Item, run_probe};
use render_gpu::gpu::{AdapterChoice, GpuContext};
use scatter_sim::WalkRng;

use crate::progress::si;

#[derive(clap::Args)]
pub struct Args {
    /// Draws of each decoder per timing, 1,024 to 262,144 (each GPU item holds 128 bytes).
    #[arg(long, allow_negative_numbers = true, default_value_t = 65536,
          value_parser = crate::whole::whole::<u32>(1024, 1 << 18))]
    draws: u32,
    /// Rounds each GPU invocation evaluates its draw (its first noise value moved each
    /// round), 1 to 1,024: enough that the dispatch, not the upload, is timed.
    #[arg(long, allow_negative_numbers = true, default_value_t = 64,
          value_parser = crate::whole::whole::<u32>(1, 1024))]
    rounds: u32,
    /// Threads of the CPU's parallel measurement (default: all cores).
    #[arg(long, value_parser = crate::generate::threads_parser())]
    threads: Option<usize>,
    /// Model file (default: models/default.stcvae).
    #[arg(long)]
    model: Option<PathBuf>,
}

/// The CPU renderer's batch: its decoders run over the draws of up to this many waiting
/// paths at once (integrator::wavefront::SLOTS).
const CPU_BATCH: usize = render_gpu::integrator::wavefront::SLOTS;

/// Timings of each measurement; the best is kept (the VM's other load only slows one).
const REPEATS: usize = 3;

/// GPU items of the probe's small dispatch, whose time (compilation from the driver's cache,
/// upload, read-back) is subtracted from the large one's.
const SMALL_ITEMS: usize = 256;

/// Probe items of decoder `id` (layout of shaders/probe.wgsl, `decoder_rate`): raw
/// conditions within ±2 of each feature's training scale, normal noise.
fn items(d: &Decoder, id: usize, n: usize, rounds: u32, rng: &mut WalkRng) -> Vec<Item> {
    (0..n)
        .map(|_| {
            let mut it: Item = [0.0; 32];
            for (v, (shift, scale)) in it.iter_mut().zip(d.cond_shift.iter().zip(&d.cond_scale)) {
                *v = shift + scale * (rng.uniform() as f32 * 4.0 - 2.0);
            }
            cvae::sampler::normals(rng, &mut it[12..12 + d.latent + d.out]);
            it[28] = id as f32;
            it[29] = rounds as f32;
            it
        })
        .collect()
}

/// The draw an item stands for at round `r` (the probe moves its first noise value).
fn draw(d: &Decoder, it: &Item, r: u32) -> Draw {
    let cond: Vec<f64> = it[..d.cond].iter().map(|&v| v as f64).collect();
    let mut noise = [0f32; 16];
    noise.copy_from_slice(&it[12..28]);
    for _ in 0..=r {
        noise[0] += 1e-3;
    }
    d.draw(
        &cond,
        &noise[..d.latent],
        &noise[d.latent..d.latent + d.out],
    )
}

/// Draws per second of `d` on `pool`, in the CPU renderer's batches.
fn cpu_rate(pool: &rayon::ThreadPool, d: &Decoder, draws: &[Draw]) -> f64 {
    let mut best = 0f64;
    for _ in 0..REPEATS {
        let start = Instant::now();
        let sum: f32 = pool.install(|| {
            draws
                .par_chunks(CPU_BATCH)
                .map(|c| {
                    let mut out = [[0f32; MAX_OUT]; CPU_BATCH];
                    d.outputs(c, &mut out[..c.len()]);
                    out[..c.len()].iter().map(|o: &Output| o[0]).sum::<f32>()
                })
                .sum()
        });
        std::hint::black_box(sum);
        best = best.max(draws.len() as f64 / start.elapsed().as_secs_f64());
    }
    best
}

/// Draws per second of probe `entry` over `big`, timed against `small`; checks the first
/// items' sums against the CPU decoder `d` so that a compiler cannot have skipped work.
fn gpu_rate(
    ctx: &GpuContext,
    model: &cvae::ModelSet,
    entry: &str,
    d: &Decoder,
    big: &[Item],
    small: &[Item],
    rounds: u32,
) -> Result<f64> {
    // Untimed: the kernel's first compilation.
    run_probe(ctx, entry, model, small)?;
    let mut best = 0f64;
    let mut out = Vec::new();
    for _ in 0..REPEATS {
        let start = Instant::now();
        run_probe(ctx, entry, model, small)?;
        let t_small = start.elapsed().as_secs_f64();
        let start = Instant::now();
        out = run_probe(ctx, entry, model, big)?;
        let t_big = start.elapsed().as_secs_f64();
        let work = rounds as f64 * (big.len() - small.len()) as f64;
        best = best.max(work / (t_big - t_small).max(1e-9));
    }
    for (i, (it, o)) in big.iter().zip(&out).take(16).enumerate() {
        let draws: Vec<Draw> = (0..rounds).map(|r| draw(d, it, r)).collect();
        let mut res = vec![[0f32; MAX_OUT]; draws.len()];
        d.outputs(&draws, &mut res);
        let expect: f64 = res.iter().map(|o| o[0] as f64).sum();
        // Each draw within 1e-5·(1 + |output|) of the CPU's, the bound of the GPU tests'
        // `wgsl_decoders_match_rust` (f32 sums in different orders), summed over the rounds.
        let tol: f64 = res.iter().map(|o| 1e-5 * (1.0 + o[0].abs() as f64)).sum();
        if (o[0] as f64 - expect).abs() > tol {
            bail!(
                "{entry}, item {i}: the GPU's sum {} differs from the CPU's {expect}: the \
                 adapter's decoders are wrong, so their speed means nothing",
                o[0]
            );
        }
    }
    Ok(best)
}

pub fn run(a: Args) -> Result<()> {
    let model = crate::model_cmds::load_model(a.model.as_deref())?;
    let ctx = GpuContext::new(AdapterChoice::Any).map_err(|e| {
        let e = format!("{e:#}");
        anyhow::anyhow!(
            "bench decoders needs a GPU adapter: {}",
            e.trim_end_matches(", or use --device cpu")
        )
    })?;
    let single = crate::generate::pool(Some(1))?;
    let all = crate::generate::pool(a.threads)?;
    let threads = all.current_num_threads();
    let n = a.draws as usize;
    println!(
        "stcvae bench decoders: {}, {n} draws a decoder, {} rounds each on the GPU\n  GPU: {}\n  CPU: {} (batches of {CPU_BATCH}, as the renderer's)",
        crate::model_cmds::model_path(a.model.as_deref()).display(),
        a.rounds,
        ctx.adapter,
        crate::progress::count(threads as u64, "thread"),
    );
    println!(
        "{:>10} {:>16} {:>6} {:>14} {:>14} {:>12} {:>9}",
        "decoder",
        "layers",
        "MACs",
        "CPU 1 thread",
        format!("CPU {threads} threads"),
        "GPU",
        "GPU/CPU"
    );
    let mut rng = WalkRng::from_seed(1);
    let decoders = model.decoders();
    let names = ["LengthGen", "PathGen", "EventGen"];
    let mut gpu_rates = [0f64; 3];
    let mut first_items = None;
    for (id, d) in decoders.iter().enumerate() {
        let big = items(d, id, n, a.rounds, &mut rng);
        let small = items(d, id, SMALL_ITEMS.min(n / 2), a.rounds, &mut rng);
        let draws: Vec<Draw> = big.iter().map(|it| draw(d, it, 0)).collect();
        let c1 = cpu_rate(&single, d, &draws);
        let cn = cpu_rate(&all, d, &draws);
        let entry = format!("probe_decoder_rate_{id}");
        let g = gpu_rate(&ctx, &model, &entry, d, &big, &small, a.rounds)?;
        gpu_rates[id] = g;
        let layers: Vec<String> = std::iter::once(d.layers[0].inputs)
            .chain(d.layers.iter().map(|l| l.outputs))
            .map(|w| w.to_string())
            .collect();
        // Multiply-adds as the kernels run them: each row in vec4s, zero-padded.
        let macs: usize = d
            .layers
            .iter()
            .map(|l| l.inputs.div_ceil(4) * 4 * l.outputs)
            .sum();
        println!(
            "{:>10} {:>16} {:>6} {:>14} {:>14} {:>12} {:>8.2}x",
            names[id],
            layers.join("-"),
            macs,
            si(c1),
            si(cn),
            si(g),
            g / cn
        );
        if id == 0 {
            first_items = Some((big, small));
        }
    }
    // LengthGen's items again, the decoder now chosen at run time from the item's id.
    let Some((big, small)) = &first_items else {
        bail!("no LengthGen items");
    };
    let any = gpu_rate(
        &ctx,
        &model,
        "probe_decoder_rate_any",
        decoders[0],
        big,
        small,
        a.rounds,
    )?;
    let alone = gpu_rates[0];
    // Were the two untaken branches run, the draw would cost all three decoders.
    let all_three = 1.0 / gpu_rates.iter().map(|r| 1.0 / r).sum::<f64>();
    // Between the two outcomes by their geometric mean: a ratio of rates, and the two
    // differ ~4× for the shipped model.
    let skips = any > (alone * all_three).sqrt();
    println!(
        "LengthGen chosen by a run-time branch (every lane the same): {} draws/s, {:.2}x \
         LengthGen alone (if every branch ran: {:.2}x) — the adapter {}",
        si(any),
        any / alone,
        all_three / alone,
        if skips {
            "skips branches no lane takes"
        } else {
            "runs every branch of an `if`, taken or not (Mesa 22's llvmpipe does: a render \
             kernel pays for all its code at every bounce)"
        }
    );
    println!(
        "GPU/CPU: the GPU's draws/s over the CPU's on {threads} threads; each GPU draw is \
         timed as a large dispatch less a small one (compilation, upload and read-back cancel)"
    );
    Ok(())
}
