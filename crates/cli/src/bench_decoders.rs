//! `stcvae bench decoders`: the three decoders' draws per second on the CPU (one thread and
//! all) and on a GPU adapter, side by side, and whether the adapter skips the branches of an
//! `if` that no SIMD lane takes.
//!
//! The decoders are the render kernels' most favourable code for a software adapter:
//! straight-line arithmetic with the weights as constants, no memory access and no lane
//! divergence. Their ratio to the CPU is the kernels' best case there; the traversals and
//! grid queries, which load memory lane by lane, run far below it (docs/BENCHMARKS.md,
//! sixty-first session). The branch row tells why Mesa 22's lavapipe (Debian 12, CI) runs
//! the kernels at less than half the speed of Mesa 25's.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Result, bail};
use cvae::decoder::{Decoder, Draw, MAX_OUT, Output};
use rayon::prelude::*;
use render_gpu::gpu::probe::{Item, time_probe};
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
    /// round), 1 to 1,024: enough that the decoders, not a dispatch's fixed cost, fill the
    /// time (a hardware GPU wants the most draws and rounds).
    #[arg(long, allow_negative_numbers = true, default_value_t = 64,
          value_parser = crate::whole::whole::<u32>(1, 1024))]
    rounds: u32,
    /// Threads of the CPU's parallel measurement, 1 to 1,024 (default: RAYON_NUM_THREADS where set, else all cores).
    #[arg(long, value_parser = crate::generate::threads_parser())]
    threads: Option<usize>,
    /// Model file (default: models/default.stcvae).
    #[arg(long, value_parser = crate::shipped::model_arg)]
    model: Option<PathBuf>,
}

/// The CPU renderer's batch: its decoders run over the draws of up to this many waiting
/// paths at once (integrator::wavefront::SLOTS).
const CPU_BATCH: usize = render_gpu::integrator::wavefront::SLOTS;

/// Timings of each measurement; the best is kept (the VM's other load only slows one).
const REPEATS: usize = 3;

/// What the run-time branch's rate says of the adapter.
#[derive(Debug, PartialEq, Eq)]
enum Verdict {
    /// It skips a branch no lane takes (the rate of the decoder alone).
    Skips,
    /// It runs both sides of every `if` (the rate of all three decoders).
    RunsAll,
    /// Neither: the ratio sits in the middle third between the two outcomes.
    Unclear,
}

/// `ratio`: the branch's rate over the decoder alone's; `all_three`: that ratio were every
/// branch run. On a log scale (a ratio of rates), the third nearest either outcome decides
/// it; the shipped model's outcomes differ ~4× (0.23 against 1), so the middle third is
/// 0.38–0.61, where short runs landed (0.48–0.52 at --draws 1024 --rounds 1, dominated by
/// each dispatch's fixed cost), while the default runs read 0.24 and 1.2–1.3.
fn branch_verdict(ratio: f64, all_three: f64) -> Verdict {
    let t = (ratio / all_three).ln() / (1.0 / all_three).ln();
    if !t.is_finite() {
        Verdict::Unclear
    } else if t > 2.0 / 3.0 {
        Verdict::Skips
    } else if t < 1.0 / 3.0 {
        Verdict::RunsAll
    } else {
        Verdict::Unclear
    }
}

/// Items whose GPU sums the bench recomputes on the CPU.
const CHECKED_ITEMS: usize = 16;

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

/// The draws of an item's rounds, as the probe makes them: its first noise value moved
/// by 1e-3 before each round, in f32.
fn round_draws(d: &Decoder, it: &Item, rounds: u32) -> Vec<Draw> {
    let cond: Vec<f64> = it[..d.cond].iter().map(|&v| v as f64).collect();
    let mut noise = [0f32; 16];
    noise.copy_from_slice(&it[12..28]);
    (0..rounds)
        .map(|_| {
            noise[0] += 1e-3;
            d.draw(
                &cond,
                &noise[..d.latent],
                &noise[d.latent..d.latent + d.out],
            )
        })
        .collect()
}

/// Seconds of one CPU measurement at least: passes over the draws are repeated until they
/// have run this long (one pass of 65,536 draws takes ~2 ms on two threads, too short to
/// time: single passes on two threads read as slow as one thread in some runs).
const CPU_SECONDS: f64 = 0.2;

/// Draws per second of `d` on `pool`, in the CPU renderer's batches: the fastest of
/// [`REPEATS`] measurements.
fn cpu_rate(pool: &rayon::ThreadPool, d: &Decoder, draws: &[Draw]) -> f64 {
    let pass = || -> f32 {
        pool.install(|| {
            draws
                .par_chunks(CPU_BATCH)
                .map(|c| {
                    let mut out = [[0f32; MAX_OUT]; CPU_BATCH];
                    d.outputs(c, &mut out[..c.len()]);
                    out[..c.len()].iter().map(|o: &Output| o[0]).sum::<f32>()
                })
                .sum()
        })
    };
    let mut best = 0f64;
    for _ in 0..REPEATS {
        let start = Instant::now();
        let mut passes = 0u64;
        while passes == 0 || start.elapsed().as_secs_f64() < CPU_SECONDS {
            std::hint::black_box(pass());
            passes += 1;
        }
        let rate = (passes * draws.len() as u64) as f64 / start.elapsed().as_secs_f64();
        best = best.max(rate);
    }
    best
}

/// Draws per second of probe `entry` over `items` (its fastest of [`REPEATS`] dispatches,
/// compiled and uploaded once); checks the first items' sums against the CPU decoder `d`
/// so that a compiler cannot have skipped work.
fn gpu_rate(
    ctx: &GpuContext,
    model: &cvae::ModelSet,
    entry: &str,
    d: &Decoder,
    items: &[Item],
    rounds: u32,
) -> Result<f64> {
    let (out, seconds) = time_probe(ctx, entry, model, items, REPEATS)?;
    let fastest = seconds.iter().copied().fold(f64::INFINITY, f64::min);
    for (i, (it, o)) in items.iter().zip(&out).take(CHECKED_ITEMS).enumerate() {
        let draws = round_draws(d, it, rounds);
        let mut res = vec![[0f32; MAX_OUT]; draws.len()];
        d.outputs(&draws, &mut res);
        let expect: f64 = res.iter().map(|o| o[0] as f64).sum();
        // Each draw within 1e-5·(1 + |output|) of the CPU's, the bound of the GPU tests'
        // `wgsl_decoders_match_rust` (f32 sums in different orders), summed over the rounds.
        let tol: f64 = res.iter().map(|o| 1e-5 * (1.0 + o[0].abs() as f64)).sum();
        if (o[31] as f64 - expect).abs() > tol {
            bail!(
                "{entry}, item {i}: the GPU's sum {} differs from the CPU's {expect}: the \
                 adapter's decoders are wrong, so their speed means nothing",
                o[31]
            );
        }
    }
    Ok(rounds as f64 * items.len() as f64 / fastest)
}

/// The GPU adapter the bench measures, what was passed over for it, and the note on a
/// software adapter's vector width.
fn open_gpu() -> Result<GpuContext> {
    let ctx = GpuContext::new(AdapterChoice::Any).map_err(|e| {
        let e = format!("{e:#}");
        anyhow::anyhow!(
            "bench decoders needs a GPU adapter: {}",
            e.trim_end_matches(", or use --device cpu")
        )
    })?;
    for why in &ctx.passed_over {
        eprintln!("(passed over: {why})");
    }
    if let Some(note) = crate::device::vector_width_note(ctx.adapter.software) {
        eprintln!("{note}");
    }
    Ok(ctx)
}

/// The line saying whether the adapter runs the branches no lane takes: LengthGen's draws
/// again, with the decoder chosen at run time among all three (each decoder's
/// draws/s alone, `gpu_rates`).
fn branch_line(
    ctx: &GpuContext,
    model: &cvae::ModelSet,
    decoder: &Decoder,
    items: &[Item],
    rounds: u32,
    gpu_rates: &[f64; 3],
) -> Result<()> {
    // LengthGen's items again, the decoder now chosen at run time from the item's id.
    let any = gpu_rate(ctx, model, "probe_decoder_rate_any", decoder, items, rounds)?;
    let alone = gpu_rates[0];
    // Were the two untaken branches run, the draw would cost all three decoders.
    let all_three = 1.0 / gpu_rates.iter().map(|r| 1.0 / r).sum::<f64>();
    println!(
        "LengthGen chosen by a run-time branch (every lane the same): {} draws/s, {:.2}x \
         LengthGen alone (if every branch ran: {:.2}x) — {}",
        si(any),
        any / alone,
        all_three / alone,
        match branch_verdict(any / alone, all_three / alone) {
            Verdict::Skips => "the adapter skips branches no lane takes",
            Verdict::RunsAll =>
                "the adapter runs every branch of an `if`, taken or not (Mesa 22's llvmpipe \
                 does: a render kernel pays for all its code at every bounce)",
            Verdict::Unclear =>
                "inconclusive, between the two outcomes: timings this short are dominated by \
                 each dispatch's fixed cost; raise --draws and --rounds",
        }
    );
    Ok(())
}

pub fn run(a: Args) -> Result<()> {
    let model = crate::model_cmds::load_model(a.model.as_deref())?;
    let ctx = open_gpu()?;
    let single = crate::generate::pool(Some(1))?;
    let all = crate::generate::pool(a.threads)?;
    let threads = all.current_num_threads();
    let n = a.draws as usize;
    println!(
        "stcvae bench decoders: {}, {n} draws a decoder, {} each on the GPU\n  GPU: {}\n  CPU: {} (batches of {CPU_BATCH}, as the renderer's)",
        crate::model_cmds::model_path(a.model.as_deref()).display(),
        crate::progress::count(a.rounds.into(), "round"),
        ctx.adapter,
        crate::progress::count(threads as u64, "thread"),
    );
    println!(
        "{:>10} {:>16} {:>6} {:>14} {:>14} {:>12} {:>9}",
        "decoder",
        "layers",
        "MACs",
        "CPU 1 thread",
        format!("CPU {}", crate::progress::count(threads as u64, "thread")),
        "GPU",
        "GPU/CPU"
    );
    let mut rng = WalkRng::from_seed(1);
    let decoders = model.decoders();
    let mut gpu_rates = [0f64; 3];
    let items_of: Vec<Vec<Item>> = decoders
        .iter()
        .enumerate()
        .map(|(id, d)| items(d, id, n, a.rounds, &mut rng))
        .collect();
    // The CPU first, before any GPU work: a software adapter's threads share its cores.
    let cpu: Vec<(f64, f64)> = decoders
        .iter()
        .zip(&items_of)
        .map(|(d, its)| {
            // Each item's first round, as the GPU's first round draws it.
            let draws: Vec<Draw> = its.iter().flat_map(|it| round_draws(d, it, 1)).collect();
            (cpu_rate(&single, d, &draws), cpu_rate(&all, d, &draws))
        })
        .collect();
    for (id, (d, its)) in decoders.iter().zip(&items_of).enumerate() {
        let (c1, cn) = cpu[id];
        let entry = format!("probe_decoder_rate_{id}");
        let g = gpu_rate(&ctx, &model, &entry, d, its, a.rounds)?;
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
            cvae::ModelSet::DECODER_NAMES[id],
            layers.join("-"),
            macs,
            si(c1),
            si(cn),
            si(g),
            g / cn
        );
    }
    branch_line(
        &ctx,
        &model,
        decoders[0],
        &items_of[0],
        a.rounds,
        &gpu_rates,
    )?;
    println!(
        "GPU/CPU: the GPU's draws/s over the CPU's on {}; the GPU's from the \
         fastest of {REPEATS} dispatches (compiled and uploaded once, each timed from \
         submission to idle), the CPU's from the fastest of {REPEATS} runs of {CPU_SECONDS} s, measured first",
        crate::progress::count(threads as u64, "thread")
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The ratios measured on lavapipe (2026-12-05): Mesa 22 0.24 against 0.23 if every
    /// branch ran, Mesa 25 1.20–1.26, and a run too short to tell, 0.48–0.52.
    #[test]
    fn the_branch_verdict_tells_the_outcomes_apart_and_says_when_it_cannot() {
        assert_eq!(branch_verdict(0.24, 0.23), Verdict::RunsAll);
        assert_eq!(branch_verdict(1.26, 0.23), Verdict::Skips);
        assert_eq!(branch_verdict(1.20, 0.23), Verdict::Skips);
        assert_eq!(branch_verdict(0.48, 0.23), Verdict::Unclear);
        assert_eq!(branch_verdict(0.52, 0.23), Verdict::Unclear);
        // The thirds' edges on the log scale: 0.23^(2/3) ≈ 0.376, 0.23^(1/3) ≈ 0.613.
        assert_eq!(branch_verdict(0.37, 0.23), Verdict::RunsAll);
        assert_eq!(branch_verdict(0.62, 0.23), Verdict::Skips);
        assert_eq!(branch_verdict(f64::NAN, 0.23), Verdict::Unclear);
        assert_eq!(branch_verdict(0.5, 1.0), Verdict::Unclear);
    }
}
