//! `stcvae bench`: throughput measurements, printed side by side in one run.

use std::time::Instant;

use anyhow::Result;
use rayon::prelude::*;
use scatter_sim::conditions::ConditionSampler;
use scatter_sim::dataset::walk_row;

use crate::generate::{DEFAULT_WALKS, pool};
use crate::progress::si;

#[derive(clap::Args)]
pub struct Args {
    #[command(subcommand)]
    what: What,
}

#[derive(clap::Subcommand)]
enum What {
    /// Scattering events per second of the simulator, on one thread and on all threads,
    /// and the projected time of the default 2^22-walk dataset.
    Sim {
        /// Walks per measurement (the authors' condition distribution, seed 1; at least
        /// 1,024: fewer take too little time to measure, and one walk read as a 171× parallel
        /// speed-up; at most 2^24, four times the default dataset, which one thread takes
        /// about an hour over: 2^64 was taken and would never have finished).
        #[arg(long, allow_negative_numbers = true, default_value_t = 16384,
              value_parser = crate::whole::whole::<u64>(1024, 1 << 24))]
        walks: u64,
        /// Threads of the parallel measurement, 1 to 1,024 (default: RAYON_NUM_THREADS where set, else all cores).
        #[arg(long, value_parser = crate::generate::threads_parser())]
        threads: Option<usize>,
    },
    /// PT vs ST-CVAE on the bunny at the teaser's density ladder σ_t = k·(150, 187.5, 125):
    /// speed-up at equal spp, variance ratio, events/steps per path and the bias.
    Render(crate::bench_render::Args),
    /// The same renders (PT and ST-CVAE) on the GPU and on the CPU, side by side: paths/s
    /// of each and their ratio.
    Devices(crate::bench_devices::Args),
    /// The three decoders' draws per second on the CPU and on a GPU adapter (the kernels'
    /// best case on a software adapter), and whether the adapter skips untaken branches.
    Decoders(crate::bench_decoders::Args),
    /// Images of any renderer against a reference (the mean of independent renders, its
    /// noise subtracted): RMSE, MSE × seconds and the time each needs for equal error.
    Error(crate::bench_error::Args),
}

pub fn run(a: Args) -> Result<()> {
    match a.what {
        What::Sim { walks, threads } => bench_sim(walks, threads),
        What::Render(r) => crate::bench_render::run(r),
        What::Devices(d) => crate::bench_devices::run(d),
        What::Decoders(d) => crate::bench_decoders::run(d),
        What::Error(e) => crate::bench_error::run(e),
    }
}

/// Runs walks 0..n of the default run on the pool; returns (seconds, events).
fn time_walks(pool: &rayon::ThreadPool, sampler: &ConditionSampler, n: u64) -> (f64, u64) {
    let start = Instant::now();
    let events = pool.install(|| {
        (0..n)
            .into_par_iter()
            .map(|i| walk_row(1, sampler, i).1)
            .sum::<u64>()
    });
    (start.elapsed().as_secs_f64(), events)
}

fn bench_sim(walks: u64, threads: Option<usize>) -> Result<()> {
    let sampler = ConditionSampler::authors();
    let single = pool(Some(1))?;
    // Warm-up: page in code and let the CPU clock settle.
    time_walks(&single, &sampler, walks.min(512));
    let (t1, events) = time_walks(&single, &sampler, walks);
    // Made after the one-thread pass: a pool's idle workers spin a while after its last
    // job, and 1,024 of them on two cores made that pass read 5-8x slow (and the
    // speed-up ~1.3x).
    let all = pool(threads)?;
    let (tn, _) = time_walks(&all, &sampler, walks);
    let per_walk = events as f64 / walks as f64;
    println!(
        "stcvae bench sim: {walks} walks of the authors' distribution (seed 1), {events} events ({per_walk:.0} per walk)"
    );
    println!(
        "{:>10} {:>12} {:>14} {:>12}",
        "threads", "seconds", "events/s", "walks/s"
    );
    for (n, t) in [(1, t1), (all.current_num_threads(), tn)] {
        println!(
            "{:>10} {:>12.3} {:>14} {:>12.0}",
            n,
            t,
            si(events as f64 / t),
            walks as f64 / t
        );
    }
    // One thread against one thread is the noise of two timings, not a speed-up.
    if all.current_num_threads() > 1 {
        println!("parallel speed-up: {:.2}x", t1 / tn);
    }
    let projected = DEFAULT_WALKS as f64 * tn / walks as f64;
    println!(
        "projected time of the default {DEFAULT_WALKS}-walk dataset on {}: {:.0} s ({:.1} min)",
        crate::progress::count(all.current_num_threads() as u64, "thread"),
        projected,
        projected / 60.0
    );
    Ok(())
}
